"""The dataflow declared once (voxshape/protocol/dataflow.py): the table is consistent, the router's
access control, `voxshape status` and the docs come from it, nodes refuse keys outside their
row, and the real services declare exactly their rows."""

from __future__ import annotations

import importlib
import json
import os
import re
import signal
import subprocess
import time

import pytest

from tests.conftest import ROOT, VOXSHAPE, bus_args, collect, free_port, wait_present
from voxshape.cli import main
from voxshape.deploy.access import ROLES, User, access_control
from voxshape.launcher.tools import unfed_inputs
from voxshape.protocol import (
    CreditedFeedback,
    HelpAnswer,
    HelpRequest,
    Observation,
    TeacherNotice,
    TeachingStats,
    robot_key,
    teacher_key,
)
from voxshape.protocol.dataflow import (
    ANY,
    DATAFLOW,
    DELIVERY,
    UNLISTED,
    DataflowError,
    check,
    delivery_markdown,
    delivery_of,
    docstring,
    flow_of,
    markdown,
    publishers_of,
)
from voxshape.protocol.keys import SCOPES
from voxshape.runtime import Input, Node

ARCHITECTURE = ROOT / "docs" / "architecture.md"
BEGIN = "<!-- dataflow:begin"
END = "<!-- dataflow:end -->"


def test_every_flow_names_a_topic_and_every_subscription_has_a_publisher():
    for role, row in DATAFLOW.items():
        flows = (*row.publishes, *row.subscribes)
        assert len(set(row.publishes)) == len(row.publishes), role
        assert len(set(row.subscribes)) == len(row.subscribes), role
        # an everything row lists only what it publishes for a subscriber (the demo's learnt)
        assert not (row.everything and row.subscribes), f"{role}: everything subscribes to all"
        for flow in flows:
            assert flow.topic in SCOPES[flow.scope], (role, flow)
            assert flow.owner in ("own", ANY), (role, flow)
        for flow in row.subscribes:
            assert publishers_of(flow.scope, flow.topic), (role, flow)


def test_the_drift_is_gone():
    """What the services really do (their node files), not what the old ROLES said."""
    assert ("robot", "robots", "episode") not in ROLES["learner"].subscribe
    assert ("robot", ANY, "episode") not in ROLES["arbiter"].subscribe
    assert ("robot", ANY, "teaching") not in ROLES["teacher"].subscribe


def test_the_access_roles_are_what_the_table_implies():
    own = {"robot": "robots", "teacher": "self"}
    assert list(ROLES) == list(
        dict.fromkeys(row.access for row in DATAFLOW.values() if row.access != ANY)
    )
    for access, role in ROLES.items():
        rows = {name: row for name, row in DATAFLOW.items() if row.access in (access, ANY)}

        def union(direction: str, rows=rows) -> set[tuple[str, str, str]]:
            flows = [f for row in rows.values() for f in row.flows(direction)]
            return {(f.scope, own[f.scope] if f.owner == "own" else ANY, f.topic) for f in flows}

        assert set(role.publish) == union("publishes"), access
        assert set(role.subscribe) == union("subscribes"), access
        assert set(role.announce) == set(rows), access
        assert role.everything == any(row.everything for row in rows.values()), access
        assert role.takes_robots == any(o == "robots" for _, o, _ in role.publish), access
    assert set(ROLES["teacher"].announce) == {"teacher", "simteacher", "status"}
    assert ROLES["admin"].everything and not ROLES["speech"].everything


def test_a_users_router_rules_are_its_rows_keys():
    users = {"learner": User("learner", "learner", ("r1",)), "ana": User("ana", "teacher")}
    rules = {r["id"]: r for r in access_control("s1", users)["rules"]}
    assert rules["learner:subscribe"]["key_exprs"] == sorted(
        robot_key("s1", "r1", t) for t in ("obs", "feedback", "limits")
    )
    assert rules["learner:publish"]["key_exprs"] == sorted(
        robot_key("s1", "r1", t) for t in ("action", "learning", "help")
    )
    assert set(rules["ana:publish"]["key_exprs"]) == {
        teacher_key("s1", "ana", t) for t in ("audio", "utterance", "said", "clock", "placed")
    }
    assert set(rules["ana:announce"]["key_exprs"]) == {
        f"voxshape/s1/presence/{r}/*" for r in ("teacher", "simteacher", "status")
    }


def test_check_follows_the_rows():
    check("learner", "subscribes", robot_key("s1", "r1", "obs"))
    check("arbiter", "subscribes", robot_key("s1", "*", "obs"))
    check("simteacher", "subscribes", robot_key("s1", "r7", "obs"))  # any robot's
    check("logger", "subscribes", "voxshape/s1/**")  # everything
    check("a-tool", "publishes", robot_key("s1", "r1", "feedback"))  # not in the table
    with pytest.raises(DataflowError, match=r"not declared in voxshape/protocol/dataflow\.py"):
        check("learner", "subscribes", robot_key("s1", "*", "obs"))  # its own robot's only
    with pytest.raises(DataflowError, match="router row publishes: nothing"):
        check("router", "publishes", robot_key("s1", "r1", "obs"))


def test_voxshape_dataflow_prints_the_table(capsys):
    assert main(["dataflow", "--markdown"]) == 0
    assert capsys.readouterr().out.strip() == markdown()
    assert main(["dataflow"]) == 0
    text = capsys.readouterr().out
    assert "learner (access role learner)" in text and "robot/<own>/feedback" in text


@pytest.mark.skipif(not ARCHITECTURE.exists(), reason="no docs/architecture.md")
def test_the_docs_show_the_table():
    text = ARCHITECTURE.read_text()
    begin, end = text.index(BEGIN), text.index(END)
    shown = text[text.index("\n", begin) + 1 : end].strip()
    assert shown == markdown(), "paste `voxshape dataflow --markdown` between the markers"
    text = (ROOT / "docs" / "reliability.md").read_text()
    begin, end = text.index("<!-- delivery:begin"), text.index("<!-- delivery:end -->")
    shown = text[text.index("\n", begin) + 1 : end].strip()
    assert shown == delivery_markdown(), "paste `voxshape dataflow --delivery` there"


def test_status_names_inputs_nobody_present_publishes():
    present = [
        {"role": "learner", "node": "learner-r1"},
        {"role": "sim", "node": "sim"},
        {"role": "logger", "node": "logger"},
        {"role": "status", "node": "health"},
    ]
    assert unfed_inputs(present) == [
        "learner learner-r1 subscribes to robot/*/feedback: no arbiter present"
    ]
    assert unfed_inputs([*present, {"role": "arbiter", "node": "arbiter"}]) == [
        "arbiter arbiter subscribes to teacher/*/utterance: no speech or teacher present",
        "arbiter arbiter subscribes to teacher/*/clock: no teacher or simteacher present",
    ]


def test_a_node_declaring_a_key_outside_its_row_is_refused(client_config, session_id):
    with Node("learner", client_config("learner-test")) as node:
        node.input("obs", robot_key(session_id, "r1", "obs"))
        with pytest.raises(DataflowError) as refused:
            node.input("episode", robot_key(session_id, "r1", "episode"))
        message = str(refused.value)
        assert "learner" in message and robot_key(session_id, "r1", "episode") in message
        assert "declared in voxshape/protocol/dataflow.py" in message
        with pytest.raises(DataflowError, match="learner row publishes"):
            node.output("feedback", robot_key(session_id, "r1", "feedback"))
        assert node.declared == {
            "publishes": set(),
            "subscribes": {robot_key(session_id, "r1", "obs")},
        }
    with Node("logger", client_config("logger-test")) as logger:  # everything: not checked
        logger.output("feedback", robot_key(session_id, "r1", "feedback"))
    with Node("a-tool", client_config("tool")) as tool:  # not in the table: not checked
        tool.input("episode", robot_key(session_id, "r1", "episode"))


def declared(stderr: str) -> dict[str, set[str]]:
    """The `scope/topic`s a service said it declared, in its "left the bus" log line (JSON
    logs: `publishes="robot/r1/obs robot/r1/episode"`)."""
    for line in stderr.splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        if record.get("message") == "left the bus":
            return {
                d: {f"{k.split('/')[0]}/{k.split('/')[2]}" for k in record[d].split()}
                for d in ("publishes", "subscribes")
            }
    raise AssertionError(f"no 'left the bus' line in:\n{stderr[-3000:]}")


# Flows a service declares only with other options than the ones run here.
WITH_OTHER_OPTIONS = {
    ("simteacher", "publishes"): {"teacher/audio"},  # --audio: speech, not text for the mock
    # --wav or --mic; placed: `voxshape placed` and a browser's teacher (the page's button)
    ("teacher", "publishes"): {"teacher/audio", "teacher/placed"},
}


def say(teacher: subprocess.Popen, text: str) -> None:
    """What a person types into `voxshape teach`."""
    teacher.stdin.write(f"{text}\n".encode())
    teacher.stdin.flush()


def answered(node: Node, within: float) -> bool:
    """Whether a HelpAnswer arrives within `within` seconds (other messages are skipped)."""
    deadline = time.monotonic() + within
    while time.monotonic() < deadline:
        event = node.poll(0.1)
        if isinstance(event, Input) and isinstance(event.message, HelpAnswer):
            return True
    return False


def test_the_real_services_declare_exactly_their_rows(
    spawn, router, session_id, tmp_path, client_config
):
    """Every service of a session a process, taught by a simulated teacher until the learner
    has credited feedback, a person's client (voxshape teach) and the web page's gateway beside
    it; then each says, as it leaves, what it declared: exactly its row."""
    env = {**os.environ, "VOXSHAPE_LOG_FORMAT": "json"}

    def start(role: str, *argv: str, **kwargs: object) -> subprocess.Popen:
        command, *rest = argv
        kwargs.setdefault("env", env)
        with (tmp_path / f"{role}.log").open("w") as log:  # a file: a full pipe would block
            return spawn(
                [VOXSHAPE, command, *bus_args(router, session_id, role), *rest],
                stdout=subprocess.DEVNULL,
                stderr=log,
                cwd=tmp_path,
                **kwargs,
            )

    services = {
        "arbiter": start("arbiter", "arbiter", "--robot-time", "ana"),
        "speech": start("speech", "speech", "--engine", "mock", "--seed", "1"),
        "learner": start("learner", "learner", "--robot", "r1", "--seed", "1"),
        "simteacher": start("simteacher", "sim-teacher", "--teacher", "ana", "--robot", "r1"),
        # a quiet node: its "left the bus" line shows at debug level; stdin open, typing nothing
        "teacher": start(
            "teacher",
            *("teach", "--teacher", "bob", "--robot", "r1", "--through-speech", "--json"),
            env={**env, "VOXSHAPE_LOG_LEVEL": "debug"},
            stdin=subprocess.PIPE,
        ),
        "web": start("web", "web", "--port", str(free_port())),
    }
    with Node("test", client_config("observer")) as node:
        node.watch_presence()
        node.input("feedback", robot_key(session_id, "r1", "feedback"))
        node.input("teaching", robot_key(session_id, "r1", "teaching"))
        node.input("notice", teacher_key(session_id, "ana", "notice"))
        node.input("rejected", teacher_key(session_id, "bob", "notice"))
        wait_present(node, set(services), timeout=60.0)
        services["sim"] = start("sim", "sim", "--rtf", "20", "--seed", "1")
        # The arbiter and speech declare their outputs as they first use them: speech its
        # notices when it rejects what bob says.
        collect(node, 1, CreditedFeedback, timeout=60.0)
        # The arbiter declares a robot's answers as it first gives one: ask as the learner
        # would (the learner asks by itself only when lost), until someone answers. bob answers
        # too: his window is wall seconds, ana's robot seconds (a few hundredths of a wall
        # second at 20x, which a loaded machine can miss).
        node.input("obs", robot_key(session_id, "r1", "obs"))
        node.input("answer", robot_key(session_id, "r1", "answer"))
        ask = node.output("help", robot_key(session_id, "r1", "help"))
        for _ in range(4):
            seen = collect(node, 1, Observation, timeout=10.0)[0]
            where = {"episode": seen.episode, "step": seen.step, "x": seen.x, "y": seen.y}
            ask.put(HelpRequest(robot="r1", reason="unsure", detail="asked by the test", **where))
            say(services["teacher"], "left")
            if answered(node, within=15.0):
                break
        else:
            pytest.fail("no teacher's answer to the robot's question reached the arbiter")
        say(services["teacher"], "cucumber")
        kinds: dict[str, str] = {}
        deadline = time.monotonic() + 20.0
        while not (kinds.get("bob") == "not_recognized" and "ana" in kinds):
            assert time.monotonic() < deadline, kinds
            (notice,) = collect(node, 1, TeacherNotice, timeout=10.0)
            kinds[notice.teacher] = notice.kind
        collect(node, 1, TeachingStats, timeout=10.0)
    for proc in services.values():
        proc.send_signal(signal.SIGINT)
    for role, proc in services.items():
        proc.wait(timeout=30)
        got = declared((tmp_path / f"{role}.log").read_text())
        for direction in ("publishes", "subscribes"):
            rows = DATAFLOW[role].flows(direction)  # type: ignore[arg-type]
            want = {f"{f.scope}/{f.topic}" for f in rows}
            want -= WITH_OTHER_OPTIONS.get((role, direction), set())
            assert got[direction] == want, (role, direction)


def test_the_flows_say_what_is_kept_and_recovered_and_nodes_follow(client_config, session_id):
    obs, said = robot_key(session_id, "r1", "obs"), teacher_key(session_id, "ana", "said")
    assert flow_of("sim", "publishes", obs).delivery.kept == 600 == delivery_of(obs).kept
    assert not any(d.waits for d in DELIVERY.values())  # no observer can stall a publisher
    assert delivery_of("voxshape/s/a/tool/key") == UNLISTED
    assert flow_of("arbiter", "subscribes", obs).recover_s == 30.0
    assert flow_of("learner", "subscribes", obs).recover_s == 0.0  # live steps only
    assert flow_of("speech", "subscribes", said).recover_s == 30.0
    assert flow_of("a-tool", "subscribes", obs) is None
    with Node("arbiter", client_config("arbiter-test")) as node:
        node.input("obs", robot_key(session_id, "*", "obs"))
        node.input("clock", teacher_key(session_id, "*", "clock"))
        assert set(node._recovering) == {"obs"}  # a recovering input, as its flow says
        feedback = node.output("feedback", robot_key(session_id, "r1", "feedback"))
        notice = node.output("notice", teacher_key(session_id, "ana", "notice"), keep=0)
        assert feedback.kept and not notice.kept  # as its topic says, or as told


# node role -> the module whose docstring names its row (the learner's:
# voxshape/services/learner/node.py)
NODE_MODULES = {
    "sim": "voxshape.services.sim.node",
    "ros2": "voxshape.services.ros2.node",
    "learner": "voxshape.services.learner.node",
    "arbiter": "voxshape.services.arbiter.node",
    "speech": "voxshape.services.speech.node",
    "teacher": "voxshape.services.teacher.node",
    "simteacher": "voxshape.services.simteacher.node",
    "web": "voxshape.services.web.node",
    "logger": "voxshape.services.logger.node",
    "router": "voxshape.deploy.router",
}


@pytest.mark.parametrize("role", NODE_MODULES)
def test_each_node_docstring_names_its_row_and_copies_none(role):
    """A node's inputs and outputs are written once, in its row: its docstring points there
    (`voxshape dataflow --docstring ROLE` renders it) rather than keep a copy that drifts."""
    text = importlib.import_module(NODE_MODULES[role]).__doc__ or ""
    assert f"`voxshape dataflow --docstring {role}`" in text
    assert not re.search(r"^(Inputs|Outputs):", text, re.M), f"{role}: a copy of its row"


def test_the_docstring_rendering_says_direction_owner_type_and_what_survives():
    assert docstring("sim").splitlines() == [
        "Inputs:  voxshape/<session>/robot/<robot>/action   Action",
        "Outputs: voxshape/<session>/robot/<robot>/obs      Observation (keeps 600)",
        "         voxshape/<session>/robot/<robot>/episode  EpisodeEvent (keeps 256)",
        "         voxshape/<session>/robot/<robot>/limits   RobotLimits (keeps 1)",
    ]
    assert "voxshape/<session>/teacher/*/utterance    Utterance (recovers 30 s)" in docstring(
        "arbiter"
    )
    assert docstring("router") == "Inputs:  nothing\nOutputs: nothing"
