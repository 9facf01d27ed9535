#!/usr/bin/env bash
# Facility benchmark of BENCHMARKS.md: a 400 px Moon (full Oren-Nayar, albedo
# map) on a 60 Hz screen, sim display and serial, N frames; prints the run
# summary (missed deadlines, latency state->present), the per-stage times,
# and the resident memory sampled every second (steady after the first?).
# With N > 1 each frame is shown for N refreshes ([timing]
# refreshes_per_frame), the trajectory sampled at 60/N Hz. With BLOCK > 1
# the renderer integrates BLOCK x BLOCK screen pixels per rendered pixel
# ([screen] render_block). With TOL the scene's interior pixels use that
# quadrature tolerance ([render] pixel_tolerance, default 1e-4).
# usage: tools/bench_facility.sh [1920|2560|3840] [FRAMES] [N] [BLOCK] [TOL]
set -euo pipefail
cd "$(dirname "$0")/.."
screen=${1:-1920}
frames=${2:-3600}
per_frame=${3:-1}
block=${4:-1}
tol=${5:-}
mkdir -p out/bench
case $screen in
  1920) range=9.415e7 ;;   # 400 px at 92.3 µrad/px
  2560) range=1.1181e8 ;;  # 400 px at 77.7 µrad/px
  3840) range=1.4125e8 ;;  # 400 px at 61.5 µrad/px
  *) echo "screen must be 1920, 2560 or 3840" >&2; exit 2 ;;
esac
rate=$(python3 -c "print(60.0 / $per_frame)")
python3 tools/make_hold.py out/bench/hold_$screen.csv "$frames" "$range" "$rate"
config=configs/bench_facility_$screen.toml
if [ "$per_frame" != 1 ] || [ "$block" != 1 ] || [ -n "$tol" ]; then
  # The same facility with the frame clock divided, render blocks and/or
  # the scene's pixel tolerance; paths made absolute.
  config=out/bench/bench_facility_${screen}_n${per_frame}_b$block${tol:+_t$tol}.toml
  scene_dir=$PWD/configs
  if [ -n "$tol" ]; then
    scene_dir=$PWD/out/bench
    # The benchmark's own scene (named in its config), paths made absolute.
    scene=$(sed -n 's/^scene = "\(.*\)"/\1/p' configs/bench_facility_$screen.toml)
    sed -e "s#\"\.\./data#\"$PWD/data#" -e "s#file = \"bodies/#file = \"$PWD/configs/bodies/#" \
      "configs/$scene" > "$scene_dir/$scene"
    printf '\n[render]\npixel_tolerance = %s\n' "$tol" >> "$scene_dir/$scene"
  fi
  sed -e "s#^scene = \"#scene = \"$scene_dir/#" -e "s#\"\.\./calib#\"$PWD/calib#" \
      -e "s#^\[timing\]#[timing]\nrefreshes_per_frame = $per_frame#" \
      -e "s#^refresh_hz = \(.*\)#refresh_hz = \1\nrender_block = $block#" \
      configs/bench_facility_$screen.toml > "$config"
fi
cargo build --release -q
rm -f out/bench/frames_$screen.jsonl
rss=out/bench/rss_$screen.txt
/usr/bin/time -v ./target/release/optistim run "$config" \
  --trajectory out/bench/hold_$screen.csv --log out/bench/frames_$screen.jsonl \
  --summary out/bench/summary_$screen.json 2> out/bench/time_$screen.txt &
timer=$!
# Resident set of the optistim process, once a second: "seconds kB".
: > "$rss"
start=$(date +%s)
while kill -0 "$timer" 2>/dev/null; do
  pid=$(pgrep -P "$timer" -x optistim || true)
  if [ -n "$pid" ]; then
    kb=$(awk '/^VmRSS/ {print $2}' "/proc/$pid/status" 2>/dev/null || true)
    [ -n "$kb" ] && echo "$(( $(date +%s) - start )) $kb" >> "$rss"
  fi
  sleep 1
done
wait "$timer"
grep -E "Maximum resident|Elapsed" out/bench/time_$screen.txt
awk 'NR == 2 {first = $2} {last = $2; if ($2 > max) max = $2}
     END {if (NR) printf "RSS after ~1 s %.1f MB, last %.1f MB, max %.1f MB (%d samples, %s)\n",
          first / 1024, last / 1024, max / 1024, NR, FILENAME}' "$rss"
cat out/bench/summary_$screen.json
python3 tools/frame_log_stats.py out/bench/frames_$screen.jsonl
