#!/usr/bin/env python3
"""Per-stage times of the last run in an optistim frame log (JSON lines).

usage: tools/frame_log_stats.py FRAMES.jsonl [SKIP]

Prints p50/p99/max of render, conversion (incl. frame id), render start ->
presented, state -> presented, and the missed deadlines, over the run's
frames after the first SKIP (default 10, the warm-up).
"""
import json
import sys


def pct(values, q):
    values = sorted(values)
    return values[min(len(values) - 1, int(q * len(values)))]


def main():
    path = sys.argv[1]
    skip = int(sys.argv[2]) if len(sys.argv) > 2 else 10
    records = [json.loads(line) for line in open(path) if '"frame"' in line]
    run = records[-1]["run"]
    frames = [r for r in records if r["run"] == run][skip:]
    stages = {
        "render": [r["t_render_end"] - r["t_render_start"] for r in frames],
        "convert": [r["t_convert_end"] - r["t_render_end"] for r in frames],
        "start->present": [r["t_presented"] - r["t_render_start"] for r in frames],
        "state->present": [
            r["t_presented"] - r["t_state_received"]
            for r in frames
            if r["t_state_received"] is not None
        ],
    }
    print(f"run {run}: {len(frames)} frames after the first {skip}")
    for name, v in stages.items():
        ms = [x * 1e3 for x in v]
        print(f"  {name:15s} p50 {pct(ms, .5):7.2f} ms  p99 {pct(ms, .99):7.2f} ms  max {max(ms):7.2f} ms")
    missed = sum(r["missed"] for r in frames)
    print(f"  missed deadlines {missed}/{len(frames)}")


if __name__ == "__main__":
    main()
