#!/usr/bin/env bash
# The θ̄ experiment of docs/VALIDATION.md ("Relief from the LOLA DEM"):
# `validate amie --model moon` on image 00208_00030 with relief none and
# shadows, the bundled Moon's macroscopic roughness θ̄ as fitted (23.66°)
# and replaced by each value given (degrees; default 15 and 8). The body
# file is not edited: each value gets a scratch data directory (symbolic
# links to data/) next to a copy of configs/bodies/moon.toml with its
# `theta_bar` replaced, which `--data` points the validation at.
# Usage: tools/amie_theta_bar.sh [DEG ...]   (about 1 min per value)
set -euo pipefail
bin=target/release/optistim
cargo build --release --quiet
img=data/amie/AMI_EE3_040819_00208_00030.IMG
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
echo "| θ̄ [deg] | relief | disk l / c / s | total signal real/render | relief vs residual: corr / gain / rms change |"
echo "|---|---|---|---|---|"
for deg in fitted "${@:-15 8}"; do
  for t in $deg; do
    data=data
    if [ "$t" != fitted ]; then
      mkdir -p "$work/$t/configs/bodies" "$work/$t/data"
      for f in "$PWD"/data/*; do ln -s "$f" "$work/$t/data/"; done
      rad=$(python3 -c "import math; print(f'{math.radians($t):.6f}')")
      sed "s/^theta_bar = .*/theta_bar = $rad/" configs/bodies/moon.toml >"$work/$t/configs/bodies/moon.toml"
      data="$work/$t/data"
    fi
    for relief in none shadows; do
      out="$work/out_${t}_$relief"
      "$bin" validate amie "$img" --model moon --relief "$relief" --caps-per-pixel 4 \
        --data "$data" --out "$out" >/dev/null
      python3 - "$out/report.json" "$t" "$relief" <<'PY'
import json, sys
r = json.load(open(sys.argv[1])); d, g = r["ssim_disk"], r.get("relief_signal")
t = "23.66 (fitted)" if sys.argv[2] == "fitted" else sys.argv[2]
rs = f"{g['correlation']:.3f} / {g['gain']:.3f} / {100 * g['residual_change']:+.1f} %" if g else "–"
print(f"| {t} | {sys.argv[3]} | {d['luminance']:.4f} / {d['contrast']:.4f} / **{d['structure']:.4f}** "
      f"| {r['total_signal_ratio']:.4f} | {rs} |")
PY
    done
  done
done
