#!/usr/bin/env bash
# The "Relief from the LOLA DEM" table of docs/VALIDATION.md: both bundled
# AMIE images, relief none / shadows / full, the 105° image also with a
# Gaussian PSF of 0.7, 1.0 and 1.5 px; every render at 4 caps per pixel
# (converged for the displaced DEM, BENCHMARKS.md "Relief: per-pixel
# error"). Usage: tools/amie_relief_table.sh [OUT_DIR]   (default out/amie_relief)
set -euo pipefail
out=${1:-out/amie_relief}
bin=target/release/optistim
cargo build --release --quiet
mkdir -p "$out"
row() { # image label relief psf
  local img=$1 label=$2 relief=$3 psf=$4 dir="$out/${1}_${3}_${4}"
  local extra=()
  [ "$psf" != "-" ] && extra=(--psf-sigma "$psf")
  "$bin" validate amie "data/amie/$img.IMG" --model moon --relief "$relief" \
    --caps-per-pixel 4 "${extra[@]}" --out "$dir" --overwrite >/dev/null
  python3 - "$dir/report.json" "$label" "$relief" "$psf" <<'PY'
import json, sys
r = json.load(open(sys.argv[1])); s, d = r["ssim"], r["ssim_disk"]
a, g = r["alignment"], r.get("relief_signal")
rs = f"{g['correlation']:.3f} / {g['gain']:.3f} / {100 * g['residual_change']:+.1f} %" if g else "–"
hp = " ".join(f"{h['correlation']:.3f} / {h['gain']:.3f} / {100 * h['residual_change']:+.1f} % ;" for h in g["high_pass"]).rstrip(" ;") if g else "–"
b = g["high_pass"][0] if g else None
bs = f"({b['best_shift_px'][0]}, {b['best_shift_px'][1]}) → {b['best_shift_correlation']:.3f}" if b else "–"
print(f"| {sys.argv[2]} | {sys.argv[3]} | {sys.argv[4].replace('-', '–')} | ({a['dx']:.2f}, {a['dy']:.2f}) "
      f"| {s['luminance']:.5f} / {s['contrast']:.5f} / {s['structure']:.5f} | {s['mssim']:.5f} "
      f"| {d['luminance']:.4f} / {d['contrast']:.4f} / **{d['structure']:.4f}** | {d['mssim']:.4f} | {rs} | {hp} | {bs} |")
PY
}
echo "| image | relief | PSF σ [px] | shift (dx, dy) px | l / c / s full frame | SSIM | disk l / c / s | disk SSIM | relief vs residual: corr / gain / rms change | the same high-passed, σ = 2 ; 4 ; 8 px | σ = 2 px: best shift (dx, dy) px → corr |"
echo "|---|---|---|---|---|---|---|---|---|---|---|"
for psf in - 0.7 1.0 1.5; do
  for relief in none shadows full; do
    row AMI_EE3_040819_00208_00030 "00208_00030 (105°)" "$relief" "$psf"
  done
done
for relief in none shadows full; do
  row AMI_EE3_041028_00101_00010 "00101_00010 (9.3°, eclipse)" "$relief" -
done
