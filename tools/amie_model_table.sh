#!/usr/bin/env bash
# The model table of docs/VALIDATION.md: every reflection model on both
# bundled AMIE images, each validation kept in OUT_DIR/<image>_<model>/.
# Usage: tools/amie_model_table.sh [OUT_DIR]   (default out/amie_models)
set -euo pipefail
out=${1:-out/amie_models}
bin=target/release/optistim
cargo build --release --quiet
mkdir -p "$out"
echo "| image | model | shift (dx, dy) px | luminance | contrast | structure | SSIM | unnorm. SSIM | real/render | disk l / c / s |"
echo "|---|---|---|---|---|---|---|---|---|---|"
for img in "AMI_EE3_040819_00208_00030 00208_00030 (105°)" "AMI_EE3_041028_00101_00010 00101_00010 (9.3°, eclipse)"; do
  product=${img%% *} label=${img#* }
  for model in moon oren_nayar hapke lambert lommel_seeliger; do
    dir="$out/${product}_$model"
    "$bin" validate amie "data/amie/$product.IMG" --model "$model" --out "$dir" --overwrite >/dev/null
    python3 - "$dir/report.json" "$label" "$model" <<'PY'
import json, sys
r = json.load(open(sys.argv[1])); s, u, d, a = r["ssim"], r["ssim_unnormalised"], r["ssim_disk"], r["alignment"]
ratio = f"**{r['total_signal_ratio']:.4f}**" if sys.argv[3] == "moon" else f"{r['total_signal_ratio']:.4f}"
print(f"| {sys.argv[2]} | {sys.argv[3]} | ({a['dx']:.2f}, {a['dy']:.2f}) | {s['luminance']:.5f} | {s['contrast']:.5f} "
      f"| {s['structure']:.5f} | {s['mssim']:.5f} | {u['mssim']:.5f} | {ratio} "
      f"| {d['luminance']:.4f} / {d['contrast']:.4f} / {d['structure']:.4f} |")
PY
  done
done
