#!/usr/bin/env python3
"""Benchmark of the frame-time governor (BENCHMARKS.md, "Frame-time governor").

Runs the README's main job (configs/facility.toml: the bundled approach, a
95 -> 630 px Moon on a 1920x1080 60 Hz simulated screen) RUNS times in each
of four conditions -- governor off / auto, machine idle / with one
competing CPU-bound process (a busy loop pinned to nothing, which takes one
of the two cores) -- and prints a Markdown table: missed deadlines,
latency state -> present p50 / p99, frames per rung, frames degraded (rung
beyond timing.governor_max_pixel_error), frames predicted not to fit, and
the largest predicted per-pixel and flux error of the frames shown.
Medians over the runs; every run's numbers go to out/bench_governor/.

usage: python3 tools/bench_governor.py [RUNS]   (after cargo build --release)
"""
import json
import multiprocessing
import os
import statistics
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "target", "release", "optistim")
OUT = os.path.join(ROOT, "out", "bench_governor")


def busy(stop):
    while not stop.is_set():
        pass


def facility_file(governor, tmp):
    """configs/facility.toml with timing.governor set, paths absolute."""
    text = open(os.path.join(ROOT, "configs", "facility.toml")).read()
    lines = [l for l in text.splitlines() if not l.startswith("governor =")]
    text = "\n".join(lines) + "\n"
    text = text.replace("[timing]\n", f'[timing]\ngovernor = "{governor}"\n')
    for key in ("scene", "trajectory"):
        text = text.replace(f'{key} = "', f'{key} = "{ROOT}/configs/')
    text = text.replace('"../calib', f'"{ROOT}/calib')
    path = os.path.join(tmp, f"facility_{governor}.toml")
    open(path, "w").write(text)
    return path


def run_once(config, tag):
    log = os.path.join(OUT, f"{tag}.jsonl")
    summary = os.path.join(OUT, f"{tag}.json")
    for p in (log, summary):
        if os.path.exists(p):
            os.remove(p)
    subprocess.run(
        [BIN, "run", config, "--log", log, "--summary", summary],
        check=False,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    return json.load(open(summary))


def row(name, summaries):
    med = lambda f: statistics.median(f(s) for s in summaries)
    missed = [s["missed_deadlines"] for s in summaries]
    p50 = med(lambda s: s["latency_state_to_present"]["p50"]) * 1e3
    p99 = med(lambda s: s["latency_state_to_present"]["p99"]) * 1e3
    g = [s.get("governor") for s in summaries]
    if g[0] is None:
        rungs = degraded = unfit = pix = flux = "-"
    else:
        n = len(g[0]["rungs"])
        rungs = " / ".join(
            str(int(statistics.median(x["rungs"][i]["frames"] for x in g))) for i in range(n)
        )
        degraded = int(statistics.median(x["degraded_frames"] for x in g))
        unfit = int(statistics.median(x["unfit_frames"] for x in g))
        pix = f'{max(r["max_pixel_error"] for x in g for r in x["rungs"] if r["frames"]):.2g}'
        flux = f'{max(r["max_flux_error"] for x in g for r in x["rungs"] if r["frames"]):.1e}'
    return (
        f"| {name} | {', '.join(map(str, missed))} / {summaries[0]['frames']} | "
        f"{p50:.1f} / {p99:.1f} | {rungs} | {degraded} | {unfit} | {pix} | {flux} |"
    )


def main():
    runs = int(sys.argv[1]) if len(sys.argv) > 1 else 3
    os.makedirs(OUT, exist_ok=True)
    print(f"machine: {os.cpu_count()} cores; {runs} runs per row", file=sys.stderr)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for load in ("idle", "one busy process"):
            stop = multiprocessing.Event()
            proc = None
            if load != "idle":
                proc = multiprocessing.Process(target=busy, args=(stop,))
                proc.start()
            try:
                for governor in ("off", "auto"):
                    config = facility_file(governor, tmp)
                    tag = f"{governor}_{'idle' if load == 'idle' else 'busy'}"
                    summaries = []
                    for k in range(runs):
                        print(f"{tag} run {k + 1}/{runs}", file=sys.stderr)
                        summaries.append(run_once(config, f"{tag}_{k}"))
                    rows.append(row(f"{load}, governor {governor}", summaries))
            finally:
                if proc:
                    stop.set()
                    proc.join()
    print("| condition | missed deadlines (each run) | latency p50 / p99 [ms] | frames per rung | degraded | predicted not to fit | max predicted pixel p99 | max predicted flux error |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(r)


if __name__ == "__main__":
    main()
