"""Small tools for people and scripts looking at a session: who is there, what is said.

`voxshape status`  lists the nodes present in a session (and checks required ones: compose
                   healthchecks use it), and notes their inputs nobody present publishes.
`voxshape listen`  prints every message of a session, decoded and validated (JSON lines with
                   --json), like zenoh's z_sub but knowing voxshape's types.
`voxshape vocabulary` checks a vocabulary file and lists its phrases.
`voxshape dataflow` prints who publishes and subscribes to what (voxshape/protocol/dataflow.py).
"""

from __future__ import annotations

import argparse
import base64
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

from voxshape.launcher.record import RECORD_FILE, SessionRecord
from voxshape.protocol import Key, dataflow, load_vocabulary, parse_key, to_wire
from voxshape.protocol.keys import presence_in_every_session
from voxshape.runtime import Input, Node, add_bus_arguments, bus_config
from voxshape.services.logger.run import RUNS


def add_status_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    parser.add_argument(
        "--require",
        nargs="*",
        default=[],
        metavar="NODE",
        help="exit 1 unless these node ids are present",
    )
    parser.add_argument("--json", action="store_true", help="print JSON")


def status(args: argparse.Namespace) -> int:
    config = bus_config("status", args, fail_fast=True)
    if args.mode is None and config.mode == "peer":
        config = replace(config, mode="client")  # a one-shot look needs no listener
    with Node("status", config, quiet=True) as node:
        present = []
        for key in _present_keys(node, node.presences):
            parsed: Key = parse_key(key)
            if parsed.name != node.id:
                present.append({"role": parsed.owner, "node": parsed.name})
        others = other_sessions(node)
    present.sort(key=lambda p: (p["role"], p["node"]))
    missing = sorted(set(args.require) - {p["node"] for p in present})
    unfed = unfed_inputs(present)
    if args.json:
        print(
            json.dumps(
                {
                    "session": config.session,
                    "present": present,
                    "missing": missing,
                    "unfed": unfed,
                    "other_sessions": others,
                }
            )
        )
    else:
        print(f"session {config.session!r}: {len(present)} node(s) present")
        for p in present:
            print(f"  {p['role']:<12} {p['node']}")
        for name in missing:
            print(f"  missing      {name}")
        for line in unfed:
            print(f"  note         {line}")
        for other in others:
            print(
                f"also on this router: session {other['session']!r}, "
                f"{len(other['nodes'])} node(s): {', '.join(other['nodes'])}"
            )
            pids = ", ".join(f"{name} {pid}" for name, pid in other["pids"].items())
            print(f"  its pids     {pids or '(its launcher record is not in runs/ here)'}")
            if other["end"]:
                print(f"  end it with  {other['end']}")
            print(f"  look at it   voxshape status --session {other['session']}")
    return 1 if missing else 0


def _present_keys(node: Node, key: str) -> list[str]:
    """The liveliness tokens present under `key`."""
    replies = node.zenoh.liveliness().get(key, timeout=2.0)
    return [str(reply.ok.key_expr) for reply in replies if reply.ok is not None]


def other_sessions(node: Node, runs: Path = RUNS) -> list[dict]:
    """The other sessions present on the router `node` is connected to, each with its nodes
    and, when its launcher's record is in `runs` here, its pids and the command that ends it."""
    nodes: dict[str, list[str]] = {}
    for key in map(parse_key, _present_keys(node, presence_in_every_session())):
        if key.session != node.session_id:
            nodes.setdefault(key.session, []).append(key.name)
    found = []
    for session, names in sorted(nodes.items()):
        record = SessionRecord.read(runs / session / RECORD_FILE)
        alive = record.alive() if record is not None else {}
        end = record.ending() if record is not None and alive else ""
        found.append({"session": session, "nodes": sorted(names), "pids": alive, "end": end})
    return found


def unfed_inputs(present: list[dict[str, str]]) -> list[str]:
    """The inputs of present nodes (their rows in voxshape/protocol/dataflow.py) that no present
    node's role publishes, e.g. "learner learner-1 subscribes to robot/*/feedback: no arbiter
    present"; a node's inputs missing the same publishers share a line."""
    roles = {p["role"] for p in present}
    notes = []
    for p in present:
        row = dataflow.DATAFLOW.get(p["role"])
        unfed: dict[str, list[str]] = {}  # the missing publisher roles -> the inputs
        for flow in row.subscribes if row else ():
            publishers = dataflow.publishers_of(flow.scope, flow.topic)
            if not roles & set(publishers):
                unfed.setdefault(" or ".join(publishers), []).append(f"{flow.scope}/*/{flow.topic}")
        for publishers, inputs in unfed.items():
            notes.append(
                f"{p['role']} {p['node']} subscribes to {', '.join(inputs)}: "
                f"no {publishers} present"
            )
    return notes


def add_dataflow_arguments(parser: argparse.ArgumentParser) -> None:
    shown = parser.add_mutually_exclusive_group()
    shown.add_argument("--markdown", action="store_true", help="as a markdown table")
    shown.add_argument(
        "--docstring",
        metavar="ROLE",
        choices=tuple(dataflow.DATAFLOW),
        help="one role's row as its node's module docstring shows it",
    )
    shown.add_argument(
        "--delivery",
        action="store_true",
        help="how each topic reaches a slow, stopped or restarting subscriber (markdown)",
    )


def show_dataflow(args: argparse.Namespace) -> int:
    if args.delivery:
        print(dataflow.delivery_markdown())
    elif args.docstring:
        print(dataflow.docstring(args.docstring))
    else:
        print(dataflow.markdown() if args.markdown else dataflow.text())
    return 0


def add_listen_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    parser.add_argument("--key", help="key expression (default: voxshape/<session>/**)")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument("--count", type=int, help="exit after this many messages")
    parser.add_argument("--duration", type=float, help="exit after this many seconds")


def jsonable(value: object) -> object:
    if isinstance(value, bytes):
        return {"base64": base64.b64encode(value).decode()}
    if isinstance(value, dict):
        return {k: jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    return value


def listen(args: argparse.Namespace) -> int:
    received = 0
    deadline = time.monotonic() + args.duration if args.duration else None
    with Node("listen", bus_config("listen", args, fail_fast=True)) as node:
        node.input("all", args.key or node.everything)
        node.log.info("listening", extra={"voxshape_fields": {"key": args.key or "session"}})
        for event in node.events(tick=0.2):
            if isinstance(event, Input):
                received += 1
                wire = to_wire(event.message)
                if args.json:
                    print(json.dumps({"key": event.key, "message": jsonable(wire)}), flush=True)
                else:
                    body = ", ".join(
                        f"{k}={_short(v)}"
                        for k, v in wire.items()
                        if k not in ("schema", "type", "id", "sent_at")
                    )
                    print(f"{event.key} {wire['type']}: {body}", flush=True)
            if (args.count and received >= args.count) or (
                deadline and time.monotonic() >= deadline
            ):
                break
    return 0


def _short(value: object) -> str:
    if isinstance(value, bytes):
        return f"<{len(value)} bytes>"
    if isinstance(value, list | tuple) and len(value) > 6:
        return f"[{len(value)} values]"
    return str(value)


def add_vocabulary_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", nargs="?", type=Path, help="vocabulary file (default: built in)")


def vocabulary(args: argparse.Namespace) -> int:
    vocab = load_vocabulary(args.file)
    for meaning in vocab.meanings.values():
        value = (
            f"reward {meaning.reward:+g}" if meaning.action is None else f"action {meaning.action}"
        )
        print(f"{meaning.name:<10} {meaning.kind:<9} {value}")
        for language, phrases in meaning.phrases.items():
            if phrases:
                print(f"    {language}: {' | '.join(phrases)}")
    print(f"ok: {len(vocab.meanings)} meanings", file=sys.stderr)
    return 0
