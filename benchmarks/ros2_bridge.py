"""The ROS 2 bridge's added latency: from a scan leaving the robot to the cmd_vel it causes
reaching the robot, less the learner's own decision time, through real buses: a robot (this
process, as its own rmw_zenohd router, publishing /scan and /odom with rmw_zenoh's
attachments), `voxshape ros2` (its own process), a session's router (a LoopbackSession's) and
a learner (this process) that answers each observation at once. What is left is the bridge's
work and its four hops. One scan a control period (0.1 s at --rtf 1); an observation is of
the last scan sent before it arrived (the bridge steps as a scan comes, well within a
period; a second one of the same scan is a step the bridge took without a new scan, not
counted), and its action carries its step in its speed, so each cmd_vel is matched to its
scan.

    .venv/bin/python benchmarks/ros2_bridge.py [--samples 300] [--rtf 1] [--target-ms 10]

Prints the sample count and p50/p99/max in ms; exits 1 if p99 is above the target or fewer
than 95% of the scans came back as commands.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import is_max, percentile, spread
from voxshape.launcher import LoopbackSession
from voxshape.protocol import Action, Observation
from voxshape.runtime import Input, Node, free_loopback_port
from voxshape.services.ros2 import msgs, rmw

SESSION = "bench-ros2"
UNIT = 0.001  # m/s of speed per step number in the learner's answers
CYCLE = 500  # step numbers repeat after this many


def robot_session(endpoint: str) -> zenoh.Session:
    conf = {"mode": "router", "listen": {"endpoints": [endpoint]},
            "scouting": {"multicast": {"enabled": False}}}  # fmt: skip
    return zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))


def scan_and_odom(seq: int) -> tuple[bytes, bytes, bytes]:
    header = msgs.HeaderMsg(msgs.TimeMsg.of(time.time()), "base_scan")
    ranges = np.full(360, 3.0, np.float32)
    scan = msgs.LaserScanMsg(header, 0.0, math.tau, math.tau / 360, 0, 0.1, 0.12, 3.5, ranges)
    odom = msgs.OdometryMsg(header, "base_link", (1.0, 1.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    attachment = rmw.encode_attachment(rmw.Attachment(seq, time.time_ns(), bytes(16)))
    return msgs.encode_laser_scan(scan), msgs.encode_odometry(odom), attachment


def robot_keys() -> dict[str, str]:
    """rmw_zenoh's keys of the robot's scan, odometry and cmd_vel (domain 0, no namespace)."""
    return {t: rmw.topic_key(0, f"/{n}", ty) for t, n, ty in (
        ("scan", "scan", msgs.LASER_SCAN), ("odom", "odom", msgs.ODOMETRY),
        ("cmd", "cmd_vel", msgs.TWIST))}  # fmt: skip


def bridge_command(args: argparse.Namespace, robot_endpoint: str) -> list[str]:
    """`voxshape ros2` bringing the robot at `robot_endpoint` into the session."""
    bridge = ["voxshape", "ros2", "--connect", robot_endpoint, "--goal", "100,100"]
    return [*bridge, "--rtf", str(args.rtf), "--max-speed", "1.0", "--radius", "0.05"]


def measure(
    args: argparse.Namespace, robot: zenoh.Session, session: LoopbackSession
) -> list[float]:
    """The bridge's added latency (seconds) of each scan after the warm-up, the robot
    publishing on `robot` and this process's learner answering on the session's bus."""
    keys = robot_keys()
    t_scan: list[float] = []  # each scan's send time
    of_step: dict[int, tuple[float, float, float]] = {}  # step -> (its scan's, obs, action)
    added: list[float] = []

    def on_cmd(sample: zenoh.Sample) -> None:
        now = time.perf_counter()
        v = msgs.decode_twist(sample.payload.to_bytes()).linear[0]
        if v <= 0:
            return
        step = round(v / UNIT) - 1
        candidates = [s for s in of_step if s % CYCLE == step]
        if candidates:
            scan, obs, act = of_step[max(candidates)]
            added.append((now - scan) - (act - obs))

    cmd = robot.declare_subscriber(keys["cmd"], on_cmd)
    scan_pub, odom_pub = (
        robot.declare_publisher(keys["scan"]),
        robot.declare_publisher(keys["odom"]),
    )
    with Node("bench", session.client_config("learner"), quiet=True) as learner:
        learner.subscribe("obs", "r1")
        out = learner.advertise("action", "r1")
        stop = threading.Event()
        seen: set[int] = set()  # scans (by count) whose observation came

        def answer() -> None:
            while not stop.is_set():
                event = learner.poll(0.1)
                if isinstance(event, Input) and isinstance(event.message, Observation):
                    obs, arrived = event.message, time.perf_counter()
                    if not t_scan or len(t_scan) in seen:
                        continue  # before the first scan, or no new scan: not a scan's step
                    seen.add(len(t_scan))
                    scan = t_scan[-1]
                    if obs.outcome == "running":
                        v = UNIT * (obs.step % CYCLE + 1)
                        out.put(Action(robot="r1", episode=obs.episode, step=obs.step,
                                       discrete=1, v=v, omega=0.0, chooser="policy"))  # fmt: skip
                        of_step[obs.step] = (scan, arrived, time.perf_counter())

        threading.Thread(target=answer, daemon=True).start()
        period = 0.1 / args.rtf
        time.sleep(2.0)  # the bridge's subscriptions meet the robot's publishers
        for i in range(args.samples + args.warmup):
            scan, odom, attachment = scan_and_odom(i + 1)
            odom_pub.put(odom, attachment=attachment)
            t_scan.append(time.perf_counter())
            scan_pub.put(scan, attachment=attachment)
            time.sleep(period)
        time.sleep(0.5)
        stop.set()
    cmd.undeclare()
    return added[args.warmup :]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=300)
    parser.add_argument("--warmup", type=int, default=20)
    parser.add_argument("--rtf", type=float, default=1.0)
    parser.add_argument("--target-ms", type=float, default=10.0)
    args = parser.parse_args()
    robot = f"tcp/127.0.0.1:{free_loopback_port()}"
    with (
        tempfile.TemporaryDirectory(prefix="voxshape-bench-ros2-") as logs,
        LoopbackSession(SESSION, logs=Path(logs)) as session,
    ):
        robot_bus = robot_session(robot)  # the robot's router, before the bridge joins it
        try:
            session.add(session.client("ros2", bridge_command(args, robot)))
            added = measure(args, robot_bus, session)
        finally:
            robot_bus.close()
    ms = sorted(a * 1000 for a in added)
    if not ms:
        print("no scan came back as a command: is the bridge running?")
        return 1
    p99 = percentile(ms, 99)
    print(f"samples {len(ms)} of {args.samples} scans, at {args.rtf:g}x real time")
    worst = "" if is_max(99, len(ms)) else f", max {ms[-1]:.1f} ms"
    print(
        f"bridge's added latency (scan in to cmd_vel out, less the learner's): {spread(ms)}"
        f"{worst} (target p99 <= {args.target_ms:g} ms)"
    )
    ok = p99 <= args.target_ms and len(ms) >= 0.95 * args.samples
    print("ok" if ok else "FAILED: above the target, or scans lost")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
