#!/usr/bin/env python3
"""Closed-loop example: plays a trajectory CSV to `optistim run --listen`
as a simulator would, one JSON datagram per state at its own time.

    optistim run configs/facility.toml --listen udp://127.0.0.1:5555 --sender 127.0.0.1:0 &
    python3 tools/udp_sender.py configs/moon_approach.csv 127.0.0.1:5555
"""
import csv, json, socket, sys, time

path, target = sys.argv[1], sys.argv[2].rsplit(":", 1)
sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
start = time.monotonic()
for row in csv.DictReader(open(path)):
    v = {k: float(x) for k, x in row.items() if x != ""}
    state = {"t": v["t"],
             "camera_position": [v["cam_x"], v["cam_y"], v["cam_z"]],
             "camera_attitude": [v["cam_qw"], v["cam_qx"], v["cam_qy"], v["cam_qz"]],
             "sun_position": [v["sun_x"], v["sun_y"], v["sun_z"]]}
    time.sleep(max(0.0, start + v["t"] - time.monotonic()))
    sock.sendto(json.dumps(state).encode(), (target[0], int(target[1])))
