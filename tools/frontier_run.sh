#!/bin/sh
# The speed/error frontier of optistim against Mitsuba 3 on the mapped Moon
# (BENCHMARKS.md, "Frontier against Mitsuba 3", issue 18 item 4), in one
# session: optistim's bench sweep and Mitsuba's spp sweep back to back at
# each phase, then Mitsuba's converged references, then the scoring and the
# figure. Both renderers run at the same niceness. Needs
# tools/mitsuba_setup.sh first. Outputs under out/frontier/ (git-ignored)
# and docs/frontier_mitsuba.png. About 40 min on 2 shared cores.
set -eu
PHASES=${PHASES:-"30 105"}
REF_SPP=${REF_SPP:-9216}
OUT=out/frontier
cargo build --release
mkdir -p $OUT/opt $OUT/mitsuba $OUT/ref
nice ./target/release/optistim bench --scene configs/moon_bench_lambert.toml \
    --phases "$(echo $PHASES | tr ' ' ,)" --interior pixels,caps --densities 0.5,1,2 \
    --texture-samples 1,2,3,4 --repeats 21 --json $OUT/opt/bench.json --images $OUT/opt
for p in $PHASES; do
    nice python3 tools/mitsuba_moon.py sweep --state $OUT/opt/phase${p}_state.json \
        --spp 1,2,4,8,16,32,64,128,256 --repeats 7 --out-dir $OUT/mitsuba
done
for p in $PHASES; do  # references are kept between runs: delete to redo
    [ -e $OUT/ref/phase${p}.npy ] || nice python3 tools/mitsuba_moon.py reference --state $OUT/opt/phase${p}_state.json \
        --spp $REF_SPP --pass-spp 256 --out $OUT/ref/phase${p}.npy
done
mkdir -p $OUT/quad
for p in $PHASES; do  # the independent float64 reference both are scored against
    [ -e $OUT/quad/phase${p}.npy ] || nice python3 tools/moon_quadrature.py --state $OUT/opt/phase${p}_state.json --out $OUT/quad/phase${p}.npy
done
python3 tools/frontier.py --opt-dir $OUT/opt --mit-dir $OUT/mitsuba --ref-dir $OUT/quad \
    --mitsuba-ref-dir $OUT/ref \
    --png docs/frontier_mitsuba.png --json $OUT/frontier.json
