#!/bin/sh
# Regenerates the bundled synthetic crater-field tile of
# configs/examples/moon_polar_crater_field.toml (docs/SCENE.md, DEM tiles):
# 1000 simple craters, N(>D) ∝ D^-2 for D in 80 … 2500 m, seed 26, on a
# 256 × 256 tile of 40 m cells centred on (-85.5°, 0°), over the bundled
# LOLA 4 ppd DEM. Run from the repository root.
set -e
cargo run --release --example crater_field -- \
    --out data/tiles/crater_field_s85.tif \
    --lat -85.5 --lon 0.0 --cells 256 --cell-m 40 --seed 26 \
    --count 1000 --b 2 --d-min 80 --d-max 2500 \
    --base data/maps/ldem_4.tif --base-scale 1000 "$@"
