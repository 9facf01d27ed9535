#!/usr/bin/env python3
"""The speed/error frontier of optistim against Mitsuba 3 on the mapped Moon
(BENCHMARKS.md, issue 18 item 4): per-frame time against per-pixel error,
both renderers scored with the same metric against the same reference.

Inputs (see BENCHMARKS.md for the commands that make them):
  OPT_DIR      `optistim bench --json OPT_DIR/bench.json --images OPT_DIR`
  MIT_DIR      `tools/mitsuba_moon.py sweep --out-dir MIT_DIR` per phase
  REF_DIR      phase{P}.npy: the reference per phase: the independent
               float64 quadrature (`tools/moon_quadrature.py`); Mitsuba's
               converged image (`tools/mitsuba_moon.py reference`, given as
               --mitsuba-ref-dir) and optistim's own bench reference are
               scored against it too, to show how far each is converged.

Metric, for every image against the reference of its phase, with
ref_peak the reference's brightest pixel:
  error = |img - ref| / ref_peak per pixel;
  interior pixels: wholly lit and visible (8x8 sub-pixel rays through the
  pixel, every one hits the sphere with the Sun above the horizon) and more
  than 2 px from any pixel that is not;  edge pixels: partly lit or
  partly covered, and their 8-neighbours that are lit;
  p50/p99 over each set, the edge pixels' mean signed error (bias), and the
  total flux error |sum img - sum ref| / sum ref.
Prints markdown tables and the time ratio at equal interior p99 and at
equal edge p99 (Mitsuba's time interpolated in log-log along its spp
curve; beyond it a bound, '>' or '<', no extrapolation),
and draws the PNG.
"""
import argparse
import json
from pathlib import Path

import numpy as np

SUB = 8  # sub-pixel rays per axis for the masks


def quat_matrix(q):
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def lit_fraction(state, radius):
    """Per pixel, the fraction of SUB x SUB sub-pixel rays that hit the
    sphere where the Sun is above the horizon, and of rays that hit it."""
    w, h = state["width"], state["height"]
    rc = quat_matrix(state["camera_attitude"])
    cam = np.asarray(state["camera_position"], dtype=np.float64)
    body = np.asarray(state["body_position"], dtype=np.float64)
    sun = np.asarray(state["sun_position"], dtype=np.float64)
    lit = np.zeros((h, w))
    hit = np.zeros((h, w))
    off = (np.arange(SUB) + 0.5) / SUB
    for r in range(h):  # row by row: bounded memory
        u = (np.arange(w)[:, None] + off[None, :]).ravel()
        for dv in off:
            v = np.full_like(u, r + dv)
            d = np.stack([(u - state["cx"]) / state["fx"], (v - state["cy"]) / state["fy"],
                          np.ones_like(u)], axis=1) @ rc.T
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            oc = cam - body
            b = d @ oc
            disc = b * b - (oc @ oc - radius * radius)
            ok = disc > 0
            t = -b - np.sqrt(np.where(ok, disc, 0))
            p = cam + t[:, None] * d
            n = (p - body) / radius
            s = sun - p
            mu0 = np.einsum("ij,ij->i", n, s) / np.linalg.norm(s, axis=1)
            hit[r] += ok.reshape(w, SUB).sum(axis=1)
            lit[r] += (ok & (mu0 > 0)).reshape(w, SUB).sum(axis=1)
    return lit / SUB**2, hit / SUB**2


def dilate(mask, k):
    out = mask.copy()
    for dy in range(-k, k + 1):
        for dx in range(-k, k + 1):
            out |= np.roll(np.roll(mask, dy, axis=0), dx, axis=1)
    return out


def masks(state, radius):
    lit, hit = lit_fraction(state, radius)
    full = (lit == 1.0) & (hit == 1.0)
    interior = full & ~dilate(~full, 2)
    partial = ((lit > 0) & (lit < 1)) | ((hit > 0) & (hit < 1))
    edge = dilate(partial, 1) & (lit > 0)
    return interior, edge


def cached_masks(stem, state, radius):
    """masks(), kept in STEM_masks.npz beside the state it was made from."""
    path = Path(f"{stem}_masks.npz")
    key = json.dumps(state, sort_keys=True) + f"{radius} {SUB}"
    if path.exists():
        z = np.load(path)
        if str(z["key"]) == key:
            return z["interior"], z["edge"]
    interior, edge = masks(state, radius)
    np.savez(path, interior=interior, edge=edge, key=key)
    return interior, edge


def score(img, ref, interior, edge):
    peak = ref.max()
    e = (img - ref) / peak
    ai, ae = np.abs(e[interior]), np.abs(e[edge])
    return {
        "int_p50": float(np.percentile(ai, 50)), "int_p99": float(np.percentile(ai, 99)),
        "edge_p50": float(np.percentile(ae, 50)), "edge_p99": float(np.percentile(ae, 99)),
        "edge_bias": float(e[edge].mean()),
        "flux": float(abs(img.sum() - ref.sum()) / ref.sum()),
    }


def read_tiff(path):
    from PIL import Image
    return np.asarray(Image.open(path), dtype=np.float64)


def interp_time(curve, err):
    """Mitsuba's time at error `err` along its (err, time) curve, log-log.
    Beyond the curve no extrapolation: below Mitsuba's smallest error (its
    converged floor, see BENCHMARKS.md) the time of its most accurate point
    is a lower bound ('>'); above its largest (1 spp), the 1-spp time is an
    upper bound ('<')."""
    pts = sorted(curve)
    e = np.log([c[0] for c in pts])
    t = np.log([c[1] for c in pts])
    x = np.log(err)
    if x < e[0]:
        return float(np.exp(t[0])), ">"
    if x > e[-1]:
        return float(np.exp(t[-1])), "<"
    return float(np.exp(np.interp(x, e, t))), ""


def setting_name(r):
    return f"{r['interior']} {r['caps_per_pixel']:g} caps/px {r['texture_samples']}x{r['texture_samples']}"


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--opt-dir", default="out/frontier/opt")
    p.add_argument("--mit-dir", default="out/frontier/mitsuba")
    p.add_argument("--ref-dir", default="out/frontier/quad")
    p.add_argument("--mitsuba-ref-dir", default="out/frontier/ref",
                   help="Mitsuba's high-spp images, scored against the reference")
    p.add_argument("--scene", default="configs/moon_bench_lambert.toml")
    p.add_argument("--png", default="docs/frontier_mitsuba.png")
    p.add_argument("--json", default="out/frontier/frontier.json")
    p.add_argument("--default", default="pixels 1 caps/px 2x2",
                   help="the optistim setting the headline ratio is quoted for")
    args = p.parse_args()
    import tomllib
    radius = float(tomllib.loads(Path(args.scene).read_text())["body"]["radius"])
    opt_rows = json.loads((Path(args.opt_dir) / "bench.json").read_text())
    phases = sorted({r["phase_deg"] for r in opt_rows})
    result = {}
    for ph in phases:
        state = json.loads((Path(args.opt_dir) / f"phase{ph:g}_state.json").read_text())
        interior, edge = cached_masks(Path(args.opt_dir) / f"phase{ph:g}", state, radius)
        ref = np.load(Path(args.ref_dir) / f"phase{ph:g}.npy").astype(np.float64)
        opt_ref = read_tiff(Path(args.opt_dir) / f"phase{ph:g}_ref.tiff")
        pts = {"interior_px": int(interior.sum()), "edge_px": int(edge.sum()),
               "optistim_reference": score(opt_ref, ref, interior, edge), "optistim": [],
               "mitsuba": []}
        mref = Path(args.mitsuba_ref_dir) / f"phase{ph:g}.npy"
        if mref.exists():
            pts["mitsuba_reference"] = score(np.load(mref).astype(np.float64), ref, interior, edge)
        for r in opt_rows:
            if r["phase_deg"] != ph:
                continue
            s = score(read_tiff(Path(args.opt_dir) / r["image"]), ref, interior, edge)
            pts["optistim"].append({"setting": setting_name(r), "ms": r["median_ms"], **s})
        mit = json.loads((Path(args.mit_dir) / f"mitsuba_phase{ph:g}.json").read_text())
        for r in mit["rows"]:
            s = score(np.load(Path(args.mit_dir) / r["image"]).astype(np.float64), ref,
                      interior, edge)
            spp = r.get("spp_actual", r["spp"])  # multijitter rounds 32 and 128 up
            pts["mitsuba"].append({"spp": spp, "ms": r["median_ms"], **s})
        for o in pts["optistim"]:
            for key in ("int_p99", "edge_p99"):
                curve = [(m[key], m["ms"]) for m in pts["mitsuba"]]
                t, bound = interp_time(curve, o[key])
                o[f"ratio_{key}"] = t / o["ms"]
                o[f"ratio_{key}_bound"] = bound
        result[ph] = pts
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps({str(k): v for k, v in result.items()}, indent=1))
    print_tables(result)
    plot(result, args.png, args.default)
    plot_floor(phases, args, str(Path(args.png).with_name(Path(args.png).stem + "_floor.png")))


def fmt_ratio(o, key):
    return f"{o[f'ratio_{key}_bound']}{o[f'ratio_{key}']:.1f}"


def print_tables(result):
    for ph, pts in result.items():
        print(f"\nphase {ph:g}°: {pts['interior_px']} interior px, {pts['edge_px']} edge px")
        for key, what in [("optistim_reference", "optistim's own bench reference (caps, 8/px)"),
                          ("mitsuba_reference", "Mitsuba's high-spp image")]:
            if key in pts:
                o = pts[key]
                print(f"{what} against the reference: interior p50 {o['int_p50']:.2e} p99 "
                      f"{o['int_p99']:.2e}, edge p50 {o['edge_p50']:.2e} p99 {o['edge_p99']:.2e} "
                      f"bias {o['edge_bias']:+.1e}, flux {o['flux']:.1e}")
        print("| renderer | setting | time [ms] | interior p50 | interior p99 | edge p50 | edge p99 "
              "| edge bias | flux error | Mitsuba/optistim time at equal interior p99 | at equal edge p99 |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for o in pts["optistim"]:
            print(f"| optistim | {o['setting']} | {o['ms']:.1f} | {o['int_p50']:.2e} | {o['int_p99']:.2e} "
                  f"| {o['edge_p50']:.2e} | {o['edge_p99']:.2e} | {o['edge_bias']:+.1e} | {o['flux']:.1e} "
                  f"| {fmt_ratio(o, 'int_p99')} | {fmt_ratio(o, 'edge_p99')} |")
        for m in pts["mitsuba"]:
            print(f"| Mitsuba 3 | {m['spp']} spp | {m['ms']:.1f} | {m['int_p50']:.2e} | {m['int_p99']:.2e} "
                  f"| {m['edge_p50']:.2e} | {m['edge_p99']:.2e} | {m['edge_bias']:+.1e} | {m['flux']:.1e} | | |")


def pareto(points, key):
    """The settings no other setting beats in both time and error."""
    front, best = [], np.inf
    for x in sorted(points, key=lambda x: (x["ms"], x[key])):
        if x[key] < best:
            front.append(x)
            best = x[key]
    return front


def plot_floor(phases, args, png):
    """Mitsuba's converged image minus the reference, cropped to the disk:
    where Mitsuba's error floor sits."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(phases), figsize=(7 * len(phases), 6.5))
    for ax, ph in zip(np.atleast_1d(axes), phases):
        mref = Path(args.mitsuba_ref_dir) / f"phase{ph:g}.npy"
        if not mref.exists():
            continue
        ref = np.load(Path(args.ref_dir) / f"phase{ph:g}.npy")
        d = (np.load(mref) - ref) / ref.max()
        ys, xs = np.nonzero(ref > 0)
        y0, x0 = ys.min() - 3, xs.min() - 3
        im = ax.imshow(d[y0:ys.max() + 4, x0:xs.max() + 4], cmap="RdBu_r", vmin=-3e-3, vmax=3e-3,
                       extent=(x0, xs.max() + 4, ys.max() + 4, y0))
        fig.colorbar(im, ax=ax, label="(Mitsuba − quadrature) / peak")
        ax.set_title(f"{ph:g}°: Mitsuba 3 converged (9216 spp) − float64 quadrature")
        ax.set_xlabel("column [px]")
        ax.set_ylabel("row [px]")
    fig.tight_layout()
    fig.savefig(png, dpi=80)
    print(f"wrote {png}")


def plot(result, png, default):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(14, 8.5))
    colours = {ph: c for ph, c in zip(result, ["tab:blue", "tab:red", "tab:green", "tab:purple"])}
    for ax, key, what in [(axes[0], "int_p99", "interior"), (axes[1], "edge_p99", "edge")]:
        for ph, pts in result.items():
            c = colours[ph]
            m = pts["mitsuba"]
            ax.plot([x[key] for x in m], [x["ms"] for x in m], "-o", color=c, mfc="none",
                    label=f"Mitsuba 3, {ph:g}° (1–{m[-1]['spp']} spp)")
            for x in m:
                ax.annotate(f"{x['spp']}", (x[key], x["ms"]), textcoords="offset points",
                            xytext=(4, -10), fontsize=7, color=c)
            o = pts["optistim"]
            ax.plot([x[key] for x in o], [x["ms"] for x in o], "s", color=c, alpha=0.5,
                    label=f"optistim, {ph:g}° (bench sweep: pixels/caps, 0.5–2 caps/px, 1²–4² map samples)")
            front = pareto(o, key)
            ax.plot([x[key] for x in front], [x["ms"] for x in front], "--", color=c,
                    label=f"optistim frontier, {ph:g}°")
            d = [x for x in o if x["setting"] == default]
            if d:
                ax.plot([d[0][key]], [d[0]["ms"]], "*", ms=16, color=c, mec="k",
                        label=f"optistim default ({default}), {ph:g}°: "
                              f"{d[0][f'ratio_{key}_bound']}{d[0][f'ratio_{key}']:.3g}× faster")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(f"{what} per-pixel error p99, |img − ref| / ref peak "
                      "(ref: float64 quadrature)")
        ax.set_ylabel("render time per frame [ms] (median)")
        ax.set_title(f"Time against {what} error")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=1)
    fig.suptitle("Mapped Lambert Moon (configs/moon_bench_lambert.toml, 1024², 410 px disk), "
                 "optistim against Mitsuba 3 llvm_ad_mono, same machine and session")
    fig.tight_layout()
    fig.savefig(png, dpi=90)
    print(f"wrote {png}")


if __name__ == "__main__":
    main()
