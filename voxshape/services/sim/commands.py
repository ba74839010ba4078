"""`voxshape map`: a picture of a task."""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

from voxshape.services.sim.render import render_map
from voxshape.services.sim.sensors import Sensors
from voxshape.world.maps import Pose, load_map
from voxshape.world.robot import RobotModel


def add_map_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("task", help="task number (1-4) or map file")
    parser.add_argument("--png", type=Path, required=True, help="where to write the picture")
    parser.add_argument("--trajectory", type=Path, help="CSV file with x,y columns (metres)")
    parser.add_argument("--scan-at", metavar="X,Y,DEG", help="draw the robot and its laser scan")


def map_command(args: argparse.Namespace) -> int:
    m = load_map(args.task)
    trajectory = None
    if args.trajectory:
        with args.trajectory.open() as f:
            trajectory = [(float(row["x"]), float(row["y"])) for row in csv.DictReader(f)]
    pose = scan = None
    if args.scan_at:
        x, y, deg = (float(v) for v in args.scan_at.split(","))
        pose = Pose(x, y, math.radians(deg))
        laser, _ = Sensors(m, RobotModel()).scan([pose])
        scan = laser[0]
    render_map(m, trajectory=trajectory, pose=pose, scan=scan, path=args.png)
    print(f"wrote {args.png}")
    return 0
