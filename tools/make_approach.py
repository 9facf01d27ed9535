#!/usr/bin/env python3
"""Write the bundled Moon-approach trajectory (configs/moon_approach.csv).

A straight approach along the world -z axis from 400 000 km to 60 000 km in
5 s of facility time (300 states at 60 Hz), the camera boresight (+z)
sweeping 0.5 deg in yaw so the Moon drifts across the screen, the Sun at
60 deg phase. Units as in the scene files: m, s, scalar-first quaternions
rotating camera vectors into the world frame.
"""
import math
import sys

N = 300
RATE = 60.0
R0, R1 = 4.0e8, 6.0e7
AU = 1.495978707e11
PHASE = math.radians(60.0)

out = open(sys.argv[1] if len(sys.argv) > 1 else "configs/moon_approach.csv", "w")
out.write("t,cam_x,cam_y,cam_z,cam_qw,cam_qx,cam_qy,cam_qz,sun_x,sun_y,sun_z\n")
sun = (AU * math.sin(PHASE), 0.0, -AU * math.cos(PHASE))
for k in range(N):
    t = k / RATE
    f = k / (N - 1)
    r = R0 * (R1 / R0) ** f  # geometric: the apparent size grows steadily
    yaw = math.radians(0.25) * math.sin(2 * math.pi * f)
    q = (math.cos(yaw / 2), 0.0, math.sin(yaw / 2), 0.0)  # about camera/world y
    out.write(
        f"{t:.6f},0.0,0.0,{-r:.6e},{q[0]:.12f},{q[1]:.1f},{q[2]:.12f},{q[3]:.1f},"
        f"{sun[0]:.6e},{sun[1]:.1f},{sun[2]:.6e}\n"
    )
