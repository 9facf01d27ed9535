#!/usr/bin/env python3
"""Render optistim's benchmark Moon in Mitsuba 3, for the speed/error
frontier of BENCHMARKS.md (issue 18, item 4).

The scene is the one `optistim bench --images DIR` rendered: the camera pose
and pinhole of each phase come from DIR/phase{P}_state.json, the body radius
and the albedo map (path, min/max stretch) from the scene TOML. Mitsuba gets
a sphere with the map as a bitmap albedo on a diffuse (Lambert) BSDF, a
directional emitter, a perspective camera with the same intrinsics, the box
pixel filter (pixel values are pixel-area means, like optistim's) and the
multijitter sampler.

Units: the emitter's irradiance is (1 au / d_sun)^2 W m^-2, so the image is
radiance per unit solar irradiance at 1 au, the quantity `bench --images`
writes for optistim (its flux over each pixel's exact solid angle).

Map orientation (docs/CONVENTIONS.md: longitude 0 at the map centre, north
up): Mitsuba's sphere has u = atan2(y, x)/2pi in [0, 1) and v = colatitude/pi
in its local frame, which is the body-fixed frame (+z north, +x lon 0); the
map is rolled by half its width so u = 0 is longitude 0. `check` compares a
render with optistim's at phase 0 (correlation, relative RMS, a difference
PNG); see BENCHMARKS.md for the numbers.

Usage (after tools/mitsuba_setup.sh):
  tools/mitsuba_moon.py render --state out/frontier/opt/phase30_state.json --spp 16 --out x.npy
  tools/mitsuba_moon.py sweep  --state ... --spp 1,2,4,...,256 --out-dir out/frontier/mitsuba
  tools/mitsuba_moon.py reference --state ... --spp 4096 --out ref.npy
  tools/mitsuba_moon.py check --state out/frontier/opt0/phase0_state.json --optistim out/frontier/opt0/phase0_ref.tiff
"""
import argparse
import json
import os
import statistics
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

AU = 1.495978707e11
# Scene lengths in Mm: keeps Mitsuba's float32 geometry well conditioned
# (the camera is 8e7 m away); radiance does not depend on the unit.
SCALE = 1e-6

if "DRJIT_LIBLLVM_PATH" not in os.environ:
    # LLVM 15 aborts on drjit 1.5's llvm.maximum (tools/mitsuba_setup.sh).
    if os.path.exists("/usr/lib/x86_64-linux-gnu/libLLVM-19.so"):
        os.environ["DRJIT_LIBLLVM_PATH"] = "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402


def load_albedo(scene_toml):
    """The body radius and the stretched albedo map as optistim loads them:
    colour channels averaged, then stretched linearly to [min, max]."""
    from PIL import Image
    cfg = tomllib.loads(Path(scene_toml).read_text())
    body = cfg["body"]
    model = body["reflectance"]["model"]
    if model != "lambert":
        sys.exit(f"{scene_toml}: body.reflectance.model = {model}: Mitsuba 3 has only Lambert here")
    amap = body["albedo_map"]
    path = (Path(scene_toml).parent / amap["path"]).resolve()
    img = np.asarray(Image.open(path), dtype=np.float64)
    if img.ndim == 3:
        img = img[..., :3].mean(axis=2)
    lo, hi = img.min(), img.max()
    t = (img - lo) / (hi - lo) if hi > lo else np.full_like(img, 0.5)
    albedo = amap["min"] + t * (amap["max"] - amap["min"])
    return float(body["radius"]), albedo


def quat_matrix(q):
    """Rotation matrix of a scalar-first quaternion (normalised)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def build_scene(state, radius, albedo, spp, flip_v=False, roll=True):
    """The Mitsuba scene dict of one bench phase."""
    body = np.asarray(state["body_position"]) * SCALE
    cam = np.asarray(state["camera_position"]) * SCALE
    sun = np.asarray(state["sun_position"], dtype=np.float64)
    rc = quat_matrix(state["camera_attitude"])  # camera (x right, y down, z fwd) -> world
    rb = quat_matrix(state["body_attitude"])
    w, h = state["width"], state["height"]
    fov_y = 2 * np.degrees(np.arctan(h / (2 * state["fy"])))
    if abs(state["fx"] - state["fy"]) > 1e-9 * state["fy"]:
        sys.exit("non-square pixels: not supported by this script")
    tex = albedo
    if roll:  # column 0 of Mitsuba's texture = longitude 0
        tex = np.roll(tex, -tex.shape[1] // 2, axis=1)
    if flip_v:
        tex = tex[::-1]
    tex = np.ascontiguousarray(tex[..., None], dtype=np.float32)
    to_body = np.eye(4)
    to_body[:3, :3] = rb * radius * SCALE
    to_body[:3, 3] = body
    d_sun = np.linalg.norm(sun - np.asarray(state["body_position"]))
    light_dir = (np.asarray(state["body_position"]) - sun) / d_sun
    return {
        "type": "scene",
        "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0},
        "sensor": {
            "type": "perspective",
            "fov": fov_y,
            "fov_axis": "y",
            # Mitsuba's camera: +x left, +y up, +z forward.
            "to_world": mi.ScalarTransform4f().look_at(
                origin=cam.tolist(), target=(cam + rc[:, 2]).tolist(), up=(-rc[:, 1]).tolist()),
            "principal_point_offset_x": (state["cx"] - w / 2) / w,
            "principal_point_offset_y": (state["cy"] - h / 2) / h,
            "near_clip": 1.0,
            "far_clip": 1e4,
            "sampler": {"type": "multijitter", "sample_count": spp},
            "film": {
                "type": "hdrfilm", "width": w, "height": h,
                "rfilter": {"type": "box"}, "pixel_format": "luminance",
                "component_format": "float32",
            },
        },
        "moon": {
            "type": "sphere",
            "to_world": mi.ScalarTransform4f(to_body.tolist()),
            "bsdf": {
                "type": "diffuse",
                "reflectance": {
                    "type": "bitmap", "data": mi.TensorXf(tex), "raw": True,
                    "filter_type": "bilinear", "wrap_mode": "repeat",
                },
            },
        },
        "sun": {
            "type": "directional",
            "direction": light_dir.tolist(),
            "irradiance": {"type": "spectrum", "value": (AU / d_sun) ** 2},
        },
    }


def load(args, spp):
    mi.set_variant(args.variant)
    state = json.loads(Path(args.state).read_text())
    radius, albedo = load_albedo(args.scene)
    return mi.load_dict(build_scene(state, radius, albedo, spp,
                                    flip_v=args.flip_v, roll=not args.no_roll))


def render_once(scene, spp, seed=0):
    img = mi.render(scene, spp=spp, seed=seed)
    dr.eval(img)
    dr.sync_thread()
    return img


def timed(scene, spp, repeats):
    """Median wall time [ms] of `repeats` renders after one warm-up render
    (scene load and JIT compilation excluded), and the last image."""
    render_once(scene, spp, seed=10_000)
    times = []
    img = None
    for k in range(repeats):
        t = time.perf_counter()
        img = render_once(scene, spp, seed=k)
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times), times, np.array(img, dtype=np.float64)[..., 0]


def cmd_render(args):
    scene = load(args, args.spp)
    med, times, img = timed(scene, args.spp, args.repeats)
    np.save(args.out, img.astype(np.float32))
    print(f"{args.variant} spp {args.spp}: median {med:.2f} ms over {args.repeats} "
          f"(min {min(times):.2f}), wrote {args.out}")


def actual_spp(spp):
    """The sample count the multijitter sampler really takes for `spp`
    (it rounds up to a near-square grid: 32 -> 35, 128 -> 132)."""
    return mi.load_dict({"type": "multijitter", "sample_count": spp}).sample_count()


def cmd_sweep(args):
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    state = json.loads(Path(args.state).read_text())
    phase = state["phase_deg"]
    scene = load(args, 1)
    rows = []
    for spp in [int(s) for s in args.spp.split(",")]:
        med, times, img = timed(scene, spp, args.repeats)
        name = f"mitsuba_phase{phase:g}_spp{spp}.npy"
        np.save(out / name, img.astype(np.float32))
        rows.append({"phase_deg": phase, "spp": spp, "spp_actual": actual_spp(spp),
                     "median_ms": med,
                     "min_ms": min(times), "times_ms": times, "image": name})
        print(f"phase {phase:g} spp {spp}: median {med:.2f} ms (min {min(times):.2f})", flush=True)
    path = out / f"mitsuba_phase{phase:g}.json"
    path.write_text(json.dumps({"variant": args.variant, "mitsuba": mi.__version__,
                                "drjit": dr.__version__, "rows": rows}, indent=1))
    print(f"wrote {path}")


def cmd_reference(args):
    """The converged image: the mean of passes of `pass_spp` samples with
    distinct seeds (one pass of 9216 spp would exceed a wavefront)."""
    scene = load(args, args.pass_spp)
    passes = max(1, args.spp // args.pass_spp)
    acc = None
    t = time.perf_counter()
    for k in range(passes):
        img = np.array(render_once(scene, args.pass_spp, seed=1_000_003 * (k + 1)),
                       dtype=np.float64)[..., 0]
        acc = img if acc is None else acc + img
        print(f"pass {k + 1}/{passes} ({time.perf_counter() - t:.0f} s)", flush=True)
    np.save(args.out, acc / passes)
    print(f"wrote {args.out}: {passes * args.pass_spp} spp in {time.perf_counter() - t:.0f} s")


def read_tiff(path):
    from PIL import Image
    return np.asarray(Image.open(path), dtype=np.float64)


def cmd_check(args):
    """Map orientation check: a Mitsuba render against optistim's image of
    the same phase (normally phase 0, the Sun behind the camera)."""
    opt = read_tiff(args.optistim)
    scene = load(args, args.spp)
    mit = np.array(render_once(scene, args.spp), dtype=np.float64)[..., 0]
    lit = (opt > 0.01 * opt.max()) & (mit > 0.01 * mit.max())
    a, b = opt[lit], mit[lit]
    corr = np.corrcoef(a, b)[0, 1]
    rel_rms = np.sqrt(np.mean((b - a) ** 2)) / np.sqrt(np.mean(a ** 2))
    # Noise level: the same render with another seed, against the first.
    mit2 = np.array(render_once(scene, args.spp, seed=7), dtype=np.float64)[..., 0]
    noise = np.sqrt(np.mean((mit2[lit] - b) ** 2) / 2) / np.sqrt(np.mean(a ** 2))
    print(f"flip_v={args.flip_v} roll={not args.no_roll} spp={args.spp}: pixels {lit.sum()}, "
          f"correlation {corr:.6f}, relative RMS {rel_rms:.3e} "
          f"(Mitsuba's own noise {noise:.3e}), flux ratio {b.sum() / a.sum():.6f}")
    if args.diff_png:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(1, 3, figsize=(15, 5))
        peak = a.max()
        for k, (im, title) in enumerate([(opt, "optistim"), (mit, f"Mitsuba 3, {args.spp} spp")]):
            m = ax[k].imshow(im / peak, cmap="gray", vmin=0, vmax=1)
            ax[k].set_title(f"{title} (radiance / optistim peak)")
            fig.colorbar(m, ax=ax[k], fraction=0.046)
        d = np.where(lit, (mit - opt) / peak, 0)
        lim = max(5 * noise, 1e-4) * np.sqrt(np.mean(a ** 2)) / peak
        m = ax[2].imshow(d, cmap="RdBu_r", vmin=-lim, vmax=lim)
        ax[2].set_title("(Mitsuba - optistim) / peak")
        fig.colorbar(m, ax=ax[2], fraction=0.046)
        for x in ax:
            x.set_xlabel("column [px]")
            x.set_ylabel("row [px]")
        fig.suptitle(f"Map orientation check, phase {json.loads(Path(args.state).read_text())['phase_deg']:g}°: "
                     f"correlation {corr:.5f}, relative RMS {rel_rms:.2e}")
        fig.tight_layout()
        fig.savefig(args.diff_png, dpi=80)
        print(f"wrote {args.diff_png}")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)

    def common(q):
        q.add_argument("--state", required=True, help="phase{P}_state.json from bench --images")
        q.add_argument("--scene", default="configs/moon_bench_lambert.toml")
        q.add_argument("--variant", default="llvm_ad_mono")
        q.add_argument("--flip-v", action="store_true", help="diagnostic: flip the map vertically")
        q.add_argument("--no-roll", action="store_true", help="diagnostic: do not roll the map")

    q = sub.add_parser("render")
    common(q)
    q.add_argument("--spp", type=int, default=16)
    q.add_argument("--repeats", type=int, default=5)
    q.add_argument("--out", required=True)
    q.set_defaults(func=cmd_render)
    q = sub.add_parser("sweep")
    common(q)
    q.add_argument("--spp", default="1,2,4,8,16,32,64,128,256")
    q.add_argument("--repeats", type=int, default=5)
    q.add_argument("--out-dir", required=True)
    q.set_defaults(func=cmd_sweep)
    q = sub.add_parser("reference")
    common(q)
    q.add_argument("--spp", type=int, default=4096)
    q.add_argument("--pass-spp", type=int, default=256)
    q.add_argument("--out", required=True)
    q.set_defaults(func=cmd_reference)
    q = sub.add_parser("check")
    common(q)
    q.add_argument("--optistim", required=True, help="optistim image (f32 TIFF) of the same phase")
    q.add_argument("--spp", type=int, default=256)
    q.add_argument("--diff-png", help="write optistim, Mitsuba and their difference here")
    q.set_defaults(func=cmd_check)
    args = p.parse_args()
    args.func(args)


if __name__ == "__main__":
    main()
