"""Bus configuration: variables and flags, and clear errors for settings that cannot work."""

from __future__ import annotations

import argparse

import pytest

from voxshape.runtime import ConfigError, add_bus_arguments, bus_config


def flags(*argv):
    parser = argparse.ArgumentParser()
    add_bus_arguments(parser)
    return parser.parse_args(list(argv))


def test_embedded_default_is_a_loopback_peer_of_the_local_router():
    config = bus_config("sim", env={})
    assert (config.mode, config.connect, config.listen) == (
        "peer",
        ("tcp/127.0.0.1:7447",),
        ("tcp/127.0.0.1:0",),
    )
    router = bus_config("router", env={})
    assert (router.mode, router.connect, router.listen) == ("router", (), ("tcp/127.0.0.1:7447",))


def test_flags_override_variables():
    env = {
        "VOXSHAPE_SESSION": "lab",
        "VOXSHAPE_CONNECT": "tcp/10.0.0.2:7447, tcp/h:7448",
        "VOXSHAPE_MODE": "client",
    }
    config = bus_config("teach", flags("--session", "demo"), env)
    assert config.session == "demo" and config.mode == "client"
    assert config.connect == ("tcp/10.0.0.2:7447", "tcp/h:7448")


def test_password_from_file(tmp_path):
    secret = tmp_path / "pw"
    secret.write_text("s3cret\n")
    env = {"VOXSHAPE_USER": "ana", "VOXSHAPE_PASSWORD_FILE": str(secret)}
    assert bus_config("teach", env=env).password == "s3cret"


def test_a_teacher_with_a_user_alone_is_asked_for_the_password_or_reads_a_file(tmp_path):
    asked = []
    config = bus_config(
        "teacher", flags("--user", "ana"), {}, ask=lambda p: asked.append(p) or "pw"
    )
    assert config.password == "pw" and asked == ["password for ana: "]
    credentials = tmp_path / "credentials"  # as `voxshape certs` writes it
    credentials.write_text("logger:x\nana:s3cret\n")
    given = flags("--user", "ana", "--password-file", str(credentials))
    assert bus_config("teacher", given, {}, ask=lambda p: "never").password == "s3cret"
    with pytest.raises(ConfigError, match=r"--password-file .* has no line bob:<password>"):
        bus_config("teacher", flags("--user", "bob", "--password-file", str(credentials)), {})


@pytest.mark.parametrize(
    ("env", "error"),
    [
        ({"VOXSHAPE_MODE": "server"}, "VOXSHAPE_MODE='server' is not one of peer, client, router"),
        ({"VOXSHAPE_CONNECT": "127.0.0.1:7447"}, "not PROTOCOL/HOST:PORT"),
        ({"VOXSHAPE_SESSION": "my/session"}, "session: 'my/session' contains '/'"),
        ({"VOXSHAPE_NODE": "a b"}, "node: 'a b' contains ' '"),
        ({"VOXSHAPE_CONNECT_TIMEOUT": "soon"}, "VOXSHAPE_CONNECT_TIMEOUT='soon'"),
        ({"VOXSHAPE_CONNECT_TIMEOUT": "-1"}, "must be > 0"),
        ({"VOXSHAPE_USER": "ana"}, "user 'ana' needs its password: set VOXSHAPE_PASSWORD"),
        ({"VOXSHAPE_PASSWORD": "pw"}, "a password without a user: give --user"),
        ({"VOXSHAPE_TLS_ROOT_CA": "/nonexistent/ca.pem"}, "tls-root-ca file '/nonexistent/ca.pem'"),
        ({"VOXSHAPE_CONNECT": "tls/h:7448"}, "needs the CA certificate"),
        ({"VOXSHAPE_MODE": "client", "VOXSHAPE_CONNECT": ","}, "client mode needs a router"),
        ({"VOXSHAPE_PASSWORD_FILE": "/nonexistent/pw"}, "VOXSHAPE_PASSWORD_FILE"),
    ],
)
def test_bad_settings_name_the_problem(env, error):
    with pytest.raises(ConfigError, match=error.replace("(", r"\(").replace(")", r"\)")):
        bus_config("sim", env=env)


def test_zenoh_accepts_every_setting_we_generate(tmp_path):
    """zenoh validates config keys: auth and TLS settings must be ones it knows."""
    for name in ("ca.pem", "cert.pem", "key.pem"):
        (tmp_path / name).write_text("placeholder")
    env = {
        "VOXSHAPE_USER": "ana",
        "VOXSHAPE_PASSWORD": "pw",
        "VOXSHAPE_MTLS": "true",
        "VOXSHAPE_CONNECT": "tls/127.0.0.1:7448",
        "VOXSHAPE_TLS_ROOT_CA": str(tmp_path / "ca.pem"),
        "VOXSHAPE_TLS_CERT": str(tmp_path / "cert.pem"),
        "VOXSHAPE_TLS_KEY": str(tmp_path / "key.pem"),
    }
    for role in ("teach", "router"):
        config = bus_config(role, env=env)
        assert config.zenoh_config() is not None
