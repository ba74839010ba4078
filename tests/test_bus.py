"""Real zenoh sessions on loopback, in separate processes, through a real router."""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time

import pytest
import zenoh

from tests.conftest import VOXSHAPE, bus_args, free_port, read_until
from voxshape.launcher import router_command
from voxshape.launcher.tools import jsonable
from voxshape.protocol import MESSAGE_TYPES, session_keys, to_wire
from voxshape.protocol.examples import example_messages
from voxshape.runtime import BusError, Input, Node, Presence

ENVELOPE = ("sender", "sent_at")


def without_envelope(wire: dict) -> dict:
    return {k: v for k, v in wire.items() if k not in ENVELOPE}


def wait_presence(node: Node, who: str, alive: bool, timeout: float = 10.0) -> float:
    """Seconds until `who` appears (alive) or leaves; fails the test after `timeout`."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        event = node.poll(0.2)
        if isinstance(event, Presence) and event.node == who and event.alive == alive:
            return time.monotonic() - t0
    pytest.fail(f"{who} {'never appeared' if alive else 'never left'} within {timeout} s")


def test_every_message_type_reaches_another_process(router, session_id, client_config, spawn):
    listener = spawn(
        [
            VOXSHAPE,
            "listen",
            "--json",
            "--count",
            str(len(MESSAGE_TYPES)),
            *bus_args(router, session_id, "listener"),
        ],
        text=True,
    )
    examples = example_messages(session_id)
    read_until(listener, r"listening", stream="stderr")  # its subscription is declared
    with Node("test", client_config("sender")) as node:
        time.sleep(0.3)  # the declaration reaches the router, a loopback hop
        for key, message in examples:
            node.output(key.rsplit("/", 1)[-1], key).put(message)
    try:
        out, err = listener.communicate(timeout=20)
    except subprocess.TimeoutExpired as e:  # name what did not arrive (its output is bytes)
        out, err = (x.decode(errors="replace") if x else "" for x in (e.output, e.stderr))
    # One line per message, in any order across keys (zenoh orders per key and publisher).
    lines = [json.loads(line) for line in out.splitlines() if line.endswith("}")]
    by_id = {line["message"]["id"]: line for line in lines}
    missed = [type(m).__name__ for _, m in examples if m.id not in by_id]
    assert not missed and listener.returncode == 0, (missed, err)
    for key, message in examples:
        line = by_id[message.id]
        assert line["key"] == key and line["message"]["sender"] == "sender"
        assert without_envelope(line["message"]) == without_envelope(jsonable(to_wire(message)))


def test_every_message_type_arrives_from_another_process(router, session_id, client_config, spawn):
    with Node("test", client_config("receiver")) as node:
        node.input("all", session_keys(session_id))
        peer = spawn(
            [
                sys.executable,
                "-m",
                "tests.bus_peer",
                "--wait-for",
                "receiver",
                *bus_args(router, session_id, "peer"),
            ],
            text=True,
        )
        received = []
        deadline = time.monotonic() + 20
        while len(received) < len(MESSAGE_TYPES) and time.monotonic() < deadline:
            event = node.poll(0.2)
            if isinstance(event, Input):
                received.append(event)
        out, err = peer.communicate(timeout=10)
    assert peer.returncode == 0, err
    sent = {json.loads(line)["id"]: json.loads(line) for line in out.splitlines()}
    assert len(received) == len(sent) == len(MESSAGE_TYPES)
    for event in received:  # in any order across keys
        line = sent[event.message.id]
        assert event.key == line["key"] and event.message.sender == "peer"
        assert without_envelope(jsonable(to_wire(event.message))) == without_envelope(
            line["message"]
        )


def test_malformed_messages_are_counted_and_never_stop_a_node(
    router, session_id, client_config, caplog
):
    examples = example_messages(session_id)
    garbage = [b"", b"\xc1", b"\x93\x01\x02\x03", b"\x81\xa6schema\x02", b"\x00" * 70_000]
    raw = zenoh.open(
        zenoh.Config.from_json5(
            json.dumps(
                {
                    "mode": "client",
                    "connect": {"endpoints": [router]},
                    "scouting": {"multicast": {"enabled": False}},
                }
            )
        )
    )
    caplog.set_level(logging.WARNING)
    try:
        with Node("test", client_config("victim")) as node:
            for key, _ in examples:
                node.input(key.rsplit("/", 1)[-1], key)
            time.sleep(0.5)
            for key, message in examples:
                for payload in garbage:
                    raw.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)
                wrong_type = examples[0][1] if key != examples[0][0] else examples[1][1]
                node.output("x", key).put(wrong_type)  # a valid message on the wrong topic
                node.output("y", key).put(message)
            # Order holds per key and publisher only: the raw session's garbage and the
            # node's messages may interleave in any order, so wait for all of them.
            expected = {
                f"rejected.{key.rsplit('/', 1)[-1]}": len(garbage) + 1 for key, _ in examples
            }
            delivered = set()
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline and (
                len(delivered) < len(examples)
                or any(node.counters[k] < n for k, n in expected.items())
            ):
                event = node.poll(0.1)
                if isinstance(event, Input):
                    delivered.add(event.message.id)
            assert delivered == {m.id for _, m in examples}
            assert {k: node.counters[k] for k in expected} == expected
    finally:
        raw.close()
    warnings = [r for r in caplog.records if r.getMessage() == "rejected a message"]
    assert len(warnings) == len(examples) * (len(garbage) + 1)
    fields_named = {r.voxshape_fields["field"] for r in warnings}
    assert {"payload", "schema", "type"} <= fields_named


def test_presence_token_disappears_when_its_process_is_killed(
    router, session_id, client_config, spawn
):
    victim = spawn([VOXSHAPE, "listen", *bus_args(router, session_id, "victim")])
    with Node("test", client_config("watcher")) as node:
        node.watch_presence()
        wait_presence(node, "victim", alive=True)
        t0 = time.monotonic()
        os.kill(victim.pid, signal.SIGKILL)
        victim.wait(5)
        gone_after = wait_presence(node, "victim", alive=False, timeout=10)
    print(
        f"presence of a kill -9'd process vanished after {gone_after * 1000:.0f} ms "
        f"(kill at {t0:.3f})"
    )
    assert gone_after < 5.0


def test_unreachable_router_is_a_clear_error(session_id):
    port = free_port()
    result = subprocess.run(
        [
            VOXSHAPE,
            "listen",
            "--session",
            session_id,
            "--mode",
            "client",
            "--connect",
            f"tcp/127.0.0.1:{port}",
            "--connect-timeout",
            "0.5",
        ],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert result.returncode == 2
    assert f"cannot reach tcp/127.0.0.1:{port} within 0.5 s" in result.stderr
    assert "voxshape up" in result.stderr and "Traceback" not in result.stderr


def test_second_router_on_a_busy_port_is_a_clear_error(router, session_id):
    result = subprocess.run(
        router_command("--session", session_id, "--listen", router),
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert result.returncode == 2, result.stderr
    assert f"cannot listen on {router}" in result.stderr and "Traceback" not in result.stderr


def test_node_refuses_to_start_without_router():
    from voxshape.runtime import BusConfig

    config = BusConfig(
        mode="client", connect=(f"tcp/127.0.0.1:{free_port()}",), connect_timeout=0.3
    )
    with pytest.raises(BusError, match="Is the session's router running"):
        Node("test", config)


def test_a_timed_wait_ends_on_time_after_messages(client_config, session_id, spawn):
    """A paced simulator froze in CI: CPython 3.11's SimpleQueue.get(timeout=t) waited for the
    next message instead of t when the deadline passed inside it, which takes the thread being
    preempted there, and a simulator waiting 5 ms for its next tick gets no message until it
    steps. Busy processes preempt this one; each round, a message arrives and is taken (as an
    action is), then a 1 ns wait must come back empty; should it hang, a timer sends a message
    after 0.2 s to end the round. With the old queue, 13-36 of 1500 rounds hung (4 runs)."""
    busy = "import time\nend = time.time() + 60\nwhile time.time() < end: pass"
    for _ in range(3):  # more than CI's cores
        spawn([sys.executable, "-c", busy])
    key, message = example_messages(session_id)[0]
    rounds, hung = 1000, 0
    with Node("test", client_config("self")) as node:
        node.input("in", key)
        out = node.output("out", key)
        for _ in range(rounds):
            out.put(message)
            time.sleep(0.001)  # it is in before the node looks: taken without waiting
            assert isinstance(node.poll(5.0), Input)
            wake = threading.Timer(0.2, out.put, (message,))
            wake.start()
            if node.poll(1e-9) is not None:
                hung += 1
            wake.cancel()
            wake.join()
            node.poll(0)  # a message the timer sent just as the wait ended
    assert hung == 0, f"{hung} of {rounds} waits of 1 ns lasted until the next message"
