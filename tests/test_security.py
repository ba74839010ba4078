"""A secured router: passwords, access control (deny by default), TLS and mutual TLS.

One router for the module, on loopback: tcp/ with passwords, tls/ with mutual TLS. Access
control acts at the router and a session hears its own puts, so every denial is checked with
a separate receiving session (an admin, who may receive everything in the session), and
every test has a positive control through the same router.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import threading
import time
import uuid
from dataclasses import replace
from pathlib import Path

import pytest
import zenoh

from tests.conftest import VOXSHAPE, collect, free_port, read_until, seconds_to_start, wait_for_port
from voxshape.deploy.access import (
    ROLES,
    AccessError,
    access_control,
    find_access_file,
    load_access,
    load_credentials,
)
from voxshape.deploy.certs import make_all
from voxshape.launcher import router_command
from voxshape.protocol import CreditedFeedback, robot_key, session_keys, teacher_key
from voxshape.protocol.dataflow import ANY, DATAFLOW
from voxshape.protocol.examples import example_messages
from voxshape.runtime import BusConfig, BusError, ConfigError, Node, bus_config
from voxshape.runtime.node import open_zenoh

SESSION = "secured"
ACCESS = """
[users]
logger = { role = "admin" }
sim = { role = "simulator", robots = ["r1"] }
learner = { role = "learner", robots = ["r1"] }
arbiter = { role = "arbiter" }
speech = { role = "speech" }
ana = { role = "teacher" }
ben = { role = "teacher" }
"""


def write_access(folder: Path) -> Path:
    path = folder / "access.toml"
    path.write_text(ACCESS)
    return path


@pytest.fixture(scope="module")
def secrets(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("secrets")
    make_all(folder, load_access(write_access(folder)))
    return folder


@pytest.fixture(scope="module")
def router(secrets) -> dict[str, str]:
    """A secured router: tcp/ (passwords) and tls/ (mutual TLS); its endpoints."""
    tcp, tls = f"tcp/127.0.0.1:{free_port()}", f"tls/127.0.0.1:{free_port()}"
    proc = subprocess.Popen(
        router_command(
            *("--session", SESSION, "--node", "router"),
            *("--secrets", str(secrets), "--access", str(secrets / "access.toml")),
            *("--listen", f"{tcp},{tls}", "--mtls"),
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        wait_for_port(int(tcp.rsplit(":", 1)[1]))
        # It says so once it is up (it listens a moment before: a loaded machine stopping it
        # then would end it before it said anything).
        read_until(proc, "secured:")
        os.set_blocking(proc.stdout.fileno(), True)
        yield {"tcp": tcp, "tls": tls}
    finally:
        os.kill(proc.pid, signal.SIGTERM)
        proc.communicate(timeout=15)


def as_user(
    router: dict[str, str], secrets: Path, user: str, *, via: str = "tcp", **changes: object
) -> BusConfig:
    """A client of the secured router as `user` (password and certificate from `secrets`)."""
    config = bus_config(
        "test",
        env={
            "VOXSHAPE_SESSION": SESSION,
            "VOXSHAPE_MODE": "client",
            "VOXSHAPE_CONNECT": router[via],
            "VOXSHAPE_SECRETS": str(secrets),
            "VOXSHAPE_USER": user,
            "VOXSHAPE_MTLS": "true" if via == "tls" else "",
        },
    )
    return replace(config, connect_timeout=3.0, **changes)


class Receiver:
    """A raw zenoh session collecting the keys it receives."""

    def __init__(self, config: BusConfig, *keys: str) -> None:
        self.keys: list[str] = []
        self._lock = threading.Lock()
        self.session = open_zenoh(config)
        self._subscribers = [self.session.declare_subscriber(k, self._on) for k in keys]

    def _on(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.keys.append(str(sample.key_expr))

    def wait_for(self, key: str, timeout: float = 15.0) -> list[str]:
        deadline = time.monotonic() + timeout
        while key not in self.keys and time.monotonic() < deadline:
            time.sleep(0.02)
        assert key in self.keys, f"{key} never arrived; got {self.keys}"
        time.sleep(1.0)  # anything sent before it, on other keys, has had time to arrive too
        with self._lock:
            return list(self.keys)

    def close(self) -> None:
        self.session.close()


def put_until_received(publisher: zenoh.Session, key: str, receiver: Receiver) -> None:
    """Routes take a moment to exist after a subscription: repeat the control until it lands."""
    deadline = time.monotonic() + 15.0
    while key not in receiver.keys and time.monotonic() < deadline:
        publisher.put(key, b"control")
        time.sleep(0.2)


# -- authentication ---------------------------------------------------------------------------


def test_a_wrong_password_is_refused(router, secrets):
    with pytest.raises(BusError, match="refused user 'ana': a wrong password"):
        open_zenoh(as_user(router, secrets, "ana", password="not-her-password"))
    with pytest.raises(BusError, match="answers but refused this session"):  # no credentials
        open_zenoh(replace(as_user(router, secrets, "ana"), user=None, password=None))
    open_zenoh(as_user(router, secrets, "ana")).close()  # her own password opens


def test_a_teacher_with_a_wrong_password_is_told_so_at_once_in_one_line(router, secrets):
    python_start = seconds_to_start(dict(os.environ))
    started = time.monotonic()
    result = subprocess.run(
        [VOXSHAPE, "teach", "--session", SESSION, "--connect", router["tcp"], "--user", "ana"],
        input="good\n",
        env={**os.environ, "VOXSHAPE_PASSWORD": "not-her-password"},
        capture_output=True,
        text=True,
        timeout=30,
    )
    took = time.monotonic() - started
    assert result.returncode != 0
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "refused user 'ana'" in lines[0], result.stderr
    assert "ERROR" not in result.stderr and "zenoh_transport" not in result.stderr
    # refused at once (LOGIN_WAIT_S, 1.2 s, past the client's start on an idle machine), not
    # after a timeout's wait (30 s): the figure itself a loaded machine can miss
    assert took - python_start < 10.0, (took, python_start)


# -- access control ---------------------------------------------------------------------------


def test_a_teacher_publishes_only_its_own_utterances_audio_and_clock(router, secrets):
    admin = Receiver(as_user(router, secrets, "logger"), session_keys(SESSION), "voxshape/other/**")
    ana = open_zenoh(as_user(router, secrets, "ana"))
    try:
        own = teacher_key(SESSION, "ana", "utterance")
        put_until_received(ana, own, admin)
        forbidden = [
            robot_key(SESSION, "r1", "action"),  # steering the robot around the arbiter
            robot_key(SESSION, "r1", "feedback"),  # rewarding it directly
            teacher_key(SESSION, "ben", "utterance"),  # speaking as another teacher
            teacher_key(SESSION, "ana", "notice"),  # faking the arbiter
            teacher_key("other", "ana", "utterance"),  # another session
        ]
        allowed = [teacher_key(SESSION, "ana", t) for t in ("audio", "said", "clock")]
        for key in forbidden + allowed:
            ana.put(key, b"x")
        last = teacher_key(SESSION, "ana", "clock")
        got = admin.wait_for(last)
        assert not set(got) & set(forbidden), got
        assert set(allowed) <= set(got), got
    finally:
        ana.close()
        admin.close()


def test_a_teacher_cannot_listen_to_another_teachers_notices(router, secrets):
    ana = Receiver(as_user(router, secrets, "ana"), teacher_key(SESSION, "ana", "notice"))
    ben = Receiver(
        as_user(router, secrets, "ben"),
        teacher_key(SESSION, "ana", "notice"),
        teacher_key(SESSION, "*", "utterance"),
    )
    arbiter = open_zenoh(as_user(router, secrets, "arbiter"))
    try:
        notice = teacher_key(SESSION, "ana", "notice")
        put_until_received(arbiter, notice, ana)
        arbiter.put(teacher_key(SESSION, "ben", "notice"), b"x")  # the arbiter may send both
        time.sleep(1.0)
        assert ben.keys == [], ben.keys
    finally:
        for closing in (arbiter, ana, ben):
            closing.close()


def test_only_the_robots_learner_asks_only_the_arbiter_answers_and_teachers_hear_both(
    router, secrets
):
    """robot/<r>/help is its learner's (a teacher cannot make the robot ask, nor answer for
    the arbiter): the router drops a teacher's, and the admin sees nothing of it."""
    admin = Receiver(as_user(router, secrets, "logger"), session_keys(SESSION))
    ana_hears = Receiver(
        as_user(router, secrets, "ana"),
        robot_key(SESSION, "*", "help"),
        robot_key(SESSION, "*", "answer"),
    )
    ana = open_zenoh(as_user(router, secrets, "ana"))
    learner = open_zenoh(as_user(router, secrets, "learner"))
    arbiter = open_zenoh(as_user(router, secrets, "arbiter"))
    asks, answers = robot_key(SESSION, "r1", "help"), robot_key(SESSION, "r1", "answer")
    try:
        put_until_received(ana, teacher_key(SESSION, "ana", "utterance"), admin)
        forbidden = [asks, answers, robot_key(SESSION, "r2", "help")]
        for key in forbidden:
            ana.put(key, b"x")
        learner.put(robot_key(SESSION, "r2", "help"), b"x")  # not its robot
        ana.put(teacher_key(SESSION, "ana", "clock"), b"x")
        got = admin.wait_for(teacher_key(SESSION, "ana", "clock"))
        assert not set(got) & set(forbidden), got
        put_until_received(learner, asks, admin)  # the learner may
        assert asks in admin.keys and asks in ana_hears.wait_for(asks)  # teachers hear it...
        put_until_received(arbiter, answers, ana_hears)  # ... and who answered it
        assert answers in ana_hears.keys
        assert robot_key(SESSION, "r2", "help") not in admin.keys
    finally:
        for closing in (ana, learner, arbiter, ana_hears, admin):
            closing.close()


def test_a_robots_services_use_only_their_own_robots_topics(router, secrets):
    admin = Receiver(as_user(router, secrets, "logger"), session_keys(SESSION))
    sim = open_zenoh(as_user(router, secrets, "sim"))
    try:
        own = robot_key(SESSION, "r1", "obs")
        put_until_received(sim, own, admin)
        forbidden = [
            robot_key(SESSION, "r2", "obs"),
            robot_key(SESSION, "r1", "action"),
            robot_key(SESSION, "r1", "feedback"),
            teacher_key(SESSION, "ana", "utterance"),
        ]
        for key in forbidden:
            sim.put(key, b"x")
        sim.put(robot_key(SESSION, "r1", "episode"), b"x")
        got = admin.wait_for(robot_key(SESSION, "r1", "episode"))
        assert not set(got) & set(forbidden), got
    finally:
        sim.close()
        admin.close()


def test_kept_feedback_is_recovered_through_the_access_control(router, secrets):
    """Kept outputs and recovering inputs (zenoh's advanced publisher and subscriber) talk
    under <key>/@adv/...: feedback the arbiter sent before the learner joined still reaches
    it, and new feedback too."""
    feedback = next(m for _, m in example_messages(SESSION) if isinstance(m, CreditedFeedback))
    key = robot_key(SESSION, "r1", "feedback")
    with Node("arbiter", as_user(router, secrets, "arbiter")) as arbiter:
        out = arbiter.output("feedback", key, keep=8)
        out.put(replace(feedback, robot="r1"))  # nobody listens yet
        with Node("learner", as_user(router, secrets, "learner")) as learner:
            learner.input("feedback", key, recover=30.0)
            first = collect(learner, 1, CreditedFeedback)
            out.put(replace(feedback, robot="r1", id=uuid.uuid4().hex))
            second = collect(learner, 1, CreditedFeedback)
    assert first[0].id == feedback.id and second[0].id != feedback.id


# -- TLS --------------------------------------------------------------------------------------


def test_tls_with_a_certificate_works_and_plain_tcp_cannot_use_the_tls_endpoint(router, secrets):
    open_zenoh(as_user(router, secrets, "ana", via="tls")).close()  # CA + her certificate
    plain = replace(
        as_user(router, secrets, "ana"), connect=(router["tls"].replace("tls/", "tcp/"),)
    )
    with pytest.raises(BusError, match=r"refused user 'ana'.*TLS endpoint: connect with tls/"):
        open_zenoh(plain)


def test_a_client_without_a_certificate_is_refused_under_mutual_tls(router, secrets):
    no_certificate = replace(
        as_user(router, secrets, "ana", via="tls"), tls_cert=None, tls_key=None, mtls=False
    )
    with pytest.raises(BusError, match=r"refused user 'ana'.*a certificate it does not accept"):
        open_zenoh(no_certificate)


# -- the pieces, without a bus ----------------------------------------------------------------


def test_access_control_is_built_from_the_protocols_keys(tmp_path):
    users = load_access(write_access(tmp_path))
    acl = access_control(SESSION, users)
    assert acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["ana:publish"]["key_exprs"] == sorted(
        teacher_key(SESSION, "ana", t) for t in ("audio", "utterance", "said", "clock", "placed")
    )
    assert rules["sim:publish"]["key_exprs"] == sorted(
        robot_key(SESSION, "r1", t) for t in ("obs", "episode", "limits")
    )
    every = session_keys(SESSION)
    assert rules["logger:all-in"]["key_exprs"] == sorted([every, f"{every}/@adv/**"])
    assert {p["id"] for p in acl["policies"]} == set(users)
    # zenoh accepts it
    config = replace(bus_config("router", env={}), extra=(("access_control", json.dumps(acl)),))
    assert config.zenoh_config() is not None


@pytest.mark.parametrize(
    ("text", "error"),
    [
        ('[users]\nana = { role = "pilot" }', "role 'pilot' is not one of"),
        ('[users]\nsim = { role = "simulator" }', "needs its robots"),
        ('[users]\nana = { role = "teacher", robots = ["r1"] }', "has no robots of its own"),
        ('[users]\n"a b" = { role = "teacher" }', "contains ' '"),
        ("[groups]\nx = 1", "unknown section"),
        ("[users", "not valid TOML"),
    ],
)
def test_bad_access_files_name_the_problem(tmp_path, text, error):
    path = tmp_path / "access.toml"
    path.write_text(text)
    with pytest.raises(AccessError, match=error):
        load_access(path)


def test_credentials_and_secrets_folder(secrets, tmp_path):
    passwords = load_credentials(secrets / "credentials")
    assert set(passwords) == set(load_access(secrets / "access.toml"))
    config = bus_config("sim", env={"VOXSHAPE_SECRETS": str(secrets)})
    assert (config.user, config.password) == ("sim", passwords["sim"])
    assert config.tls_root_ca == secrets / "ca.pem" and config.tls_cert == secrets / "sim.pem"
    env = {"VOXSHAPE_USER": "ana", "VOXSHAPE_PASSWORD_FILE": str(secrets / "credentials")}
    assert bus_config("teach", env=env).password == passwords["ana"]
    with pytest.raises(ConfigError, match="has no line nobody:<password>"):
        bus_config("teach", env={**env, "VOXSHAPE_USER": "nobody"})
    with pytest.raises(ConfigError, match="make one with `voxshape certs"):
        bus_config("sim", env={"VOXSHAPE_SECRETS": str(tmp_path / "missing")})
    bad = tmp_path / "credentials"
    bad.write_text("ana\n")
    with pytest.raises(AccessError, match="line 1: expected user:password"):
        load_credentials(bad)


def test_every_role_comes_from_the_dataflow_table():
    """The access roles are those of voxshape/protocol/dataflow.py, and each service's user in
    deploy/access.toml has the access role its node role runs under there."""
    assert set(ROLES) == {row.access for row in DATAFLOW.values()} - {ANY}
    for role, row in DATAFLOW.items():
        access = list(ROLES) if row.access == ANY else [row.access]
        assert all(role in ROLES[a].announce for a in access), role
    users = load_access(find_access_file())
    services = {name: user for name, user in users.items() if name in DATAFLOW}
    assert {"sim", "learner", "logger", "launcher", "simteacher"} <= set(services)
    for name, user in services.items():
        assert user.role == DATAFLOW[name].access, name
