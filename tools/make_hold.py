#!/usr/bin/env python3
"""Trajectory for the facility benchmark: the Moon held at a constant range
(so it spans a chosen number of screen pixels) while the camera boresight
drifts slowly, so every frame differs.

usage: make_hold.py OUT.csv FRAMES RANGE_M [RATE_HZ]
"""
import math
import sys

out, frames, rng = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
rate = float(sys.argv[4]) if len(sys.argv) > 4 else 60.0
AU = 1.495978707e11
phase = math.radians(60.0)
sun = (AU * math.sin(phase), 0.0, -AU * math.cos(phase))
with open(out, "w") as f:
    f.write("t,cam_x,cam_y,cam_z,cam_qw,cam_qx,cam_qy,cam_qz,sun_x,sun_y,sun_z\n")
    for k in range(frames):
        t = k / rate
        yaw = math.radians(0.3) * math.sin(2 * math.pi * t / 20.0)
        pitch = math.radians(0.2) * math.sin(2 * math.pi * t / 13.0)
        cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
        cx, sx = math.cos(pitch / 2), math.sin(pitch / 2)
        # q = q_yaw(y) * q_pitch(x), scalar first
        q = (cy * cx, cy * sx, sy * cx, -sy * sx)
        f.write(
            f"{t:.6f},0.0,0.0,{-rng:.6e},{q[0]:.12f},{q[1]:.12f},{q[2]:.12f},{q[3]:.12f},"
            f"{sun[0]:.6e},{sun[1]:.1f},{sun[2]:.6e}\n"
        )
