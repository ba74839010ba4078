"""A second process on the bus for tests: publishes one example message of every type once
the test's node is present, and prints each message it sent as a JSON line."""

from __future__ import annotations

import argparse
import json
import sys
import time

from voxshape.launcher.tools import jsonable
from voxshape.protocol import to_wire
from voxshape.protocol.examples import example_messages
from voxshape.runtime import Node, Presence, add_bus_arguments, bus_config


def main() -> int:
    parser = argparse.ArgumentParser()
    add_bus_arguments(parser)
    parser.add_argument("--wait-for", required=True, help="node id to wait for")
    args = parser.parse_args()
    with Node("peer", bus_config("peer", args)) as node:
        node.watch_presence(node=args.wait_for)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            event = node.poll(0.5)
            if isinstance(event, Presence) and event.alive:
                break
        else:
            print("the test node never appeared", file=sys.stderr)
            return 1
        time.sleep(0.3)  # its subscriptions travel with its presence; give them a moment
        for key, message in example_messages(node.session_id):
            output = node.output(key.rsplit("/", 1)[-1], key)
            output.put(message)
            print(
                json.dumps({"key": key, "id": message.id, "message": jsonable(to_wire(message))}),
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
