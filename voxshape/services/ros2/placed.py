"""`voxshape placed`: a teacher says a real robot is back at its start, from a terminal (the
web page has a button for it). `voxshape ros2` waits for it between episodes with
`--reset wait`, or when it could not drive back by itself.

    voxshape placed --robot r1 [--teacher ana]
"""

from __future__ import annotations

import argparse
import getpass
import os
import time

from voxshape.protocol import Placed, check_id
from voxshape.runtime import Node, add_bus_arguments, bus_config, fields

SETTLE_S = 0.5  # for the subscription of a bridge to meet this short-lived publisher


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    env = os.environ.get
    parser.add_argument("--robot", default=env("VOXSHAPE_ROBOT", "r1"), help="(VOXSHAPE_ROBOT)")
    parser.add_argument(
        "--teacher",
        default=env("VOXSHAPE_TEACHER"),
        help="your id in the session (VOXSHAPE_TEACHER; default: --user, else your login)",
    )


def run(args: argparse.Namespace) -> int:
    bus = bus_config("teacher", args, fail_fast=True)
    teacher = check_id(args.teacher or bus.user or _login(), "teacher")
    robot = check_id(args.robot, "robot")
    with Node("teacher", bus, quiet=True) as node:
        out = node.advertise("placed", teacher)
        time.sleep(SETTLE_S)
        out.put(Placed(teacher=teacher, robot=robot))
        node.log.info("said it is placed", extra=fields(robot=robot, teacher=teacher))
        time.sleep(SETTLE_S)
    print(f"told the session: robot {robot} is at its start ({teacher})")
    return 0


def _login() -> str:
    name = "".join(c for c in getpass.getuser() if c.isalnum() or c in "_-.")
    return name or "teacher"
