"""`voxshape bench WHAT`: performance figures, each measured by its own module."""

from __future__ import annotations

import argparse

from services.arbiter import bench as arbiter_bench
from services.experiment import bench as experiment_bench
from services.sim import bench as sim_bench

BENCHES = {"sim": sim_bench, "arbiter": arbiter_bench, "experiment": experiment_bench}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("what", choices=list(BENCHES), help="what to measure")
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    for bench in BENCHES.values():
        bench.add_arguments(parser)


def run(args: argparse.Namespace) -> int:
    return BENCHES[args.what].bench_command(args)
