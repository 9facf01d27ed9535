#!/usr/bin/env python3
"""What cast shadows cost in the facility loop (BENCHMARKS.md, issue 26).

Runs the README's main job (configs/facility.toml: the bundled 300-state
approach, a 95 -> 630 px Moon on a 1920x1080 60 Hz simulated screen) with
the governor off (every frame at the configured fidelity, so render times
compare frame by frame), RUNS times without and RUNS times with the LOLA
DEM's cast shadows on the bundled Moon ([body] shadows, mode "auto", no
displacement), alternating. Pairs each frame with the same frame of the
other run (same state) and prints a Markdown table: frames whose shadows
were applied, median render time per frame without / with, the median of
the per-frame ratios (p10 - p90), the share of the 16.7 ms slot, missed
deadlines, edge pixels refined. Every run's log goes to
out/bench_facility_shadows/. The horizon map comes from the cache (built
once before the runs, its time printed).

usage: python3 tools/bench_facility_shadows.py [RUNS]   (after cargo build --release)
"""
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_governor  # noqa: E402  (its facility file)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "target", "release", "optistim")
OUT = os.path.join(ROOT, "out", "bench_facility_shadows")
SHADOWS = ('shadows = { dem = "%s/data/maps/ldem_4.tif", scale = 1000.0, '
           'azimuths = 16, mode = "auto" }\n' % ROOT)


def scene_file(tmp, shadows):
    """configs/moon_plain.toml (the facility's scene: the bundled Moon
    without its relief), paths absolute, with or without the shadows."""
    text = open(os.path.join(ROOT, "configs", "moon_plain.toml")).read()
    assert "\nshadows =" not in text, "moon_plain.toml has gained a relief"
    text = text.replace('"../data', f'"{ROOT}/data')
    text = text.replace('file = "bodies/', f'file = "{ROOT}/configs/bodies/')
    if shadows:
        text = text.replace("[body]\n", "[body]\n" + SHADOWS, 1)
    path = os.path.join(tmp, f"moon_{'shadows' if shadows else 'plain'}.toml")
    open(path, "w").write(text)
    return path


def facility_file(tmp, scene, tag):
    """configs/facility.toml with the governor off and `scene` (the
    governor benchmark's file, its scene replaced)."""
    text = open(bench_governor.facility_file("off", tmp)).read()
    old = f'scene = "{ROOT}/configs/moon_plain.toml"'
    assert old in text, "configs/facility.toml no longer renders moon_plain.toml"
    text = text.replace(old, f'scene = "{scene}"')
    path = os.path.join(tmp, f"facility_{tag}.toml")
    open(path, "w").write(text)
    return path


def run_once(config, tag):
    log = os.path.join(OUT, f"{tag}.jsonl")
    summary = os.path.join(OUT, f"{tag}.json")
    for p in (log, summary):
        if os.path.exists(p):
            os.remove(p)
    subprocess.run([BIN, "run", config, "--log", log, "--summary", summary],
                   check=False, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    frames = [json.loads(l) for l in open(log)]
    frames = [f for f in frames if "frame" in f and "t_render_end" in f]
    return json.load(open(summary)), frames


def render_ms(f):
    return (f["t_render_end"] - f["t_render_start"]) * 1e3


def pct(xs, q):
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(q * (len(xs) - 1) + 0.5))]


def main():
    runs = int(sys.argv[1]) if len(sys.argv) > 1 else 3
    if runs < 1:
        sys.exit("RUNS must be at least 1")
    os.makedirs(OUT, exist_ok=True)
    tmp = tempfile.mkdtemp()
    configs = {s: facility_file(tmp, scene_file(tmp, s), "shadows" if s else "plain")
               for s in (False, True)}
    start = time.time()
    subprocess.run([BIN, "run", configs[True], "--frames", "1", "--log",
                    os.path.join(tmp, "warm.jsonl"), "--summary", os.path.join(tmp, "warm.json")],
                   check=False, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    print(f"horizon map ready (cache or built) and one frame: {time.time() - start:.1f} s wall")
    results = {False: [], True: []}
    for r in range(runs):
        for s in (False, True):
            tag = f"{'shadows' if s else 'plain'}_{r}"
            results[s].append(run_once(configs[s], tag))
            print(f"run {tag}: {results[s][-1][0]['verdict']}", file=sys.stderr)
    ratios, applied_ratios, plain_ms, shadow_ms = [], [], [], []
    applied, edges = [], []
    for (_, plain), (_, shadow) in zip(results[False], results[True]):
        by_frame = {f["frame"]: f for f in plain}
        for f in shadow:
            p = by_frame.get(f["frame"])
            if p is None or render_ms(p) <= 0:
                continue
            ratio = render_ms(f) / render_ms(p)
            ratios.append(ratio)
            plain_ms.append(render_ms(p))
            shadow_ms.append(render_ms(f))
            rec = f.get("shadows") or {}
            if rec.get("applied"):
                applied_ratios.append(ratio)
                edges.append(rec.get("edge_pixels", 0))
            applied.append(bool(rec.get("applied")))
    missed = {s: [x[0]["missed_deadlines"] for x in results[s]] for s in (False, True)}
    slot_ms = 1e3 / 60.0
    print()
    print("| frames | shadows applied | render without / with [ms, median] | with / without (p10 - p90) | "
          "added, share of the 16.7 ms slot | missed deadlines without / with | edge pixels (median) |")
    print("|---|---|---|---|---|---|---|")
    added = statistics.median(s - p for s, p in zip(shadow_ms, plain_ms))
    print(f"| all ({len(ratios)}) | {sum(applied)} | {statistics.median(plain_ms):.2f} / "
          f"{statistics.median(shadow_ms):.2f} | {statistics.median(ratios):.3f} "
          f"({pct(ratios, 0.1):.3f} - {pct(ratios, 0.9):.3f}) | {added:.2f} ms, "
          f"{100 * added / slot_ms:.1f} % | {statistics.median(missed[False])} / "
          f"{statistics.median(missed[True])} | {statistics.median(edges) if edges else 0} |")
    if applied_ratios:
        print(f"| shadows applied ({len(applied_ratios)}) | {len(applied_ratios)} | | "
              f"{statistics.median(applied_ratios):.3f} ({pct(applied_ratios, 0.1):.3f} - "
              f"{pct(applied_ratios, 0.9):.3f}) | | | |")
    print(f"\nload average: {os.getloadavg()[0]:.1f}; logs in {OUT}")


if __name__ == "__main__":
    main()
