#!/usr/bin/env python3
"""An independent float64 reference of the mapped Lambert Moon: each pixel's
mean radiance by an N x N midpoint rule over the pixel (rays through the
sub-pixel centres, exact ray-sphere hits, the map's bilinear interpolant
at each hit, r = rho mu0 / pi), written with numpy alone, to arbitrate
between optistim and Mitsuba 3 where they disagree (the edges).

Same geometry as tools/mitsuba_moon.py (the bench's phase{P}_state.json and
the scene TOML), same units: radiance per unit solar irradiance at 1 au.
Pixels wholly off the disk are 0; pixels touching the limb or the terminator
(a coarse 4x4 probe is mixed, and their neighbours) get --edge-n (default 96,
as many rays as Mitsuba's 9216-spp reference) per axis,
the others --n (default 16).

  tools/moon_quadrature.py --state out/frontier/opt/phase30_state.json --out out/frontier/quad/phase30.npy
"""
import argparse
import json
import time
from pathlib import Path

import numpy as np

AU = 1.495978707e11


def quat_matrix(q):
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def load_albedo(scene_toml):
    """Colour channels averaged, stretched linearly to [min, max]
    (docs/CONVENTIONS.md)."""
    import tomllib
    from PIL import Image
    cfg = tomllib.loads(Path(scene_toml).read_text())
    amap = cfg["body"]["albedo_map"]
    img = np.asarray(Image.open((Path(scene_toml).parent / amap["path"]).resolve()),
                     dtype=np.float64)
    if img.ndim == 3:
        img = img[..., :3].mean(axis=2)
    t = (img - img.min()) / (img.max() - img.min())
    return float(cfg["body"]["radius"]), amap["min"] + t * (amap["max"] - amap["min"])


def bilinear(albedo, lat, lon):
    """The map's bilinear interpolant, texel centres at (i + 0.5) / W in
    longitude from -180 deg and (j + 0.5) / H in colatitude; wrapped in
    longitude, clamped at the poles."""
    h, w = albedo.shape
    x = (lon + np.pi) / (2 * np.pi) * w - 0.5
    y = (np.pi / 2 - lat) / np.pi * h - 0.5
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx, fy = x - x0, y - y0
    x0 = x0.astype(np.int64) % w
    x1 = (x0 + 1) % w
    y0i = np.clip(y0.astype(np.int64), 0, h - 1)
    y1i = np.clip(y0.astype(np.int64) + 1, 0, h - 1)
    top = albedo[y0i, x0] * (1 - fx) + albedo[y0i, x1] * fx
    bot = albedo[y1i, x0] * (1 - fx) + albedo[y1i, x1] * fx
    return top * (1 - fy) + bot * fy


class Scene:
    def __init__(self, state, radius, albedo):
        self.s = state
        self.rc = quat_matrix(state["camera_attitude"])
        self.rb = quat_matrix(state["body_attitude"])
        self.cam = np.asarray(state["camera_position"], dtype=np.float64)
        self.body = np.asarray(state["body_position"], dtype=np.float64)
        self.sun = np.asarray(state["sun_position"], dtype=np.float64)
        self.radius = radius
        self.albedo = albedo

    def radiance(self, u, v):
        """Radiance along the rays through continuous pixel coords (u, v)."""
        s = self.s
        d = np.stack([(u - s["cx"]) / s["fx"], (v - s["cy"]) / s["fy"], np.ones_like(u)],
                     axis=1) @ self.rc.T
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        oc = self.cam - self.body
        b = d @ oc
        disc = b * b - (oc @ oc - self.radius**2)
        hit = disc > 0
        t = -b - np.sqrt(np.where(hit, disc, 0))
        p = self.cam + t[:, None] * d
        n = (p - self.body) / self.radius
        to_sun = self.sun - p
        dist = np.linalg.norm(to_sun, axis=1)
        mu0 = np.einsum("ij,ij->i", n, to_sun) / dist
        nb = n @ self.rb  # body-fixed: rb^T n
        lat = np.arcsin(np.clip(nb[:, 2], -1, 1))
        lon = np.arctan2(nb[:, 1], nb[:, 0])
        rho = bilinear(self.albedo, lat, lon)
        return np.where(hit & (mu0 > 0), rho * mu0 / np.pi * (AU / dist) ** 2, 0.0)

    def pixel_means(self, cols, rows, n, chunk=1 << 21):
        """Mean radiance of pixels (cols, rows) by an n x n midpoint rule."""
        off = (np.arange(n) + 0.5) / n
        ou, ov = [a.ravel() for a in np.meshgrid(off, off)]
        out = np.empty(len(cols))
        per = max(1, chunk // (n * n))
        for k in range(0, len(cols), per):
            c, r = cols[k:k + per], rows[k:k + per]
            u = (c[:, None] + ou[None, :]).ravel()
            v = (r[:, None] + ov[None, :]).ravel()
            out[k:k + per] = self.radiance(u, v).reshape(len(c), n * n).mean(axis=1)
        return out


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--state", required=True)
    p.add_argument("--scene", default="configs/moon_bench_lambert.toml")
    p.add_argument("--n", type=int, default=16)
    p.add_argument("--edge-n", type=int, default=96)
    p.add_argument("--out", required=True)
    args = p.parse_args()
    state = json.loads(Path(args.state).read_text())
    radius, albedo = load_albedo(args.scene)
    sc = Scene(state, radius, albedo)
    w, h = state["width"], state["height"]
    t0 = time.perf_counter()
    rows, cols = [a.ravel().astype(np.float64) for a in np.mgrid[0:h, 0:w]]
    # A 4x4 probe per pixel: touched (any ray lit) and mixed (some not).
    off = (np.arange(4) + 0.5) / 4
    ou, ov = [a.ravel() for a in np.meshgrid(off, off)]
    touched = np.zeros(h * w, dtype=bool)
    mixed = np.zeros(h * w, dtype=bool)
    for k in range(0, h * w, 1 << 16):
        j = slice(k, k + (1 << 16))
        lit = sc.radiance((cols[j, None] + ou).ravel(), (rows[j, None] + ov).ravel()) > 0
        lit = lit.reshape(-1, 16)
        touched[j] = lit.any(axis=1)
        mixed[j] = lit.any(axis=1) & ~lit.all(axis=1)
    # The probe can miss a sliver: every neighbour of a mixed or touched
    # pixel that is not wholly lit by the probe, and every neighbour of a
    # mixed pixel, is treated as an edge pixel.
    grid_t, grid_m = touched.reshape(h, w), mixed.reshape(h, w)
    near_t = np.zeros_like(grid_t)
    near_m = np.zeros_like(grid_m)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            near_t |= np.roll(np.roll(grid_t, dy, 0), dx, 1)
            near_m |= np.roll(np.roll(grid_m, dy, 0), dx, 1)
    mixed = (grid_m | near_m | (near_t & ~grid_t)).ravel()
    touched = touched | mixed
    full = touched & ~mixed
    img = np.zeros(h * w)
    img[full] = sc.pixel_means(cols[full], rows[full], args.n)
    img[mixed] = sc.pixel_means(cols[mixed], rows[mixed], args.edge_n)
    np.save(args.out, img.reshape(h, w))
    print(f"wrote {args.out}: {full.sum()} pixels at {args.n}², {mixed.sum()} edge pixels at "
          f"{args.edge_n}², {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
