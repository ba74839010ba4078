"""`voxshape router`: the zenoh router of a session (a Python process in router mode).

Inputs: none. Outputs: none. It routes every other node's traffic: local services and remote
teachers and robots connect to it. It holds the presence token `presence/router/<node>`.
"""

from __future__ import annotations

import argparse

from services.runtime import Node, Presence, bus_config, fields


def run(args: argparse.Namespace) -> int:
    with Node("router", bus_config("router", args)) as node:
        node.watch_presence()
        for event in node.events():
            if isinstance(event, Presence) and event.node != node.id:
                verb = "joined" if event.alive else "left"
                node.log.info(f"node {verb}", extra=fields(role=event.role, node=event.node))
    return 0
