"""The suite's own parallel safety (tests/conftest.py): every xdist worker takes its ports from
a share of its own, below the kernel's ephemeral ports, and never the same port twice."""

from __future__ import annotations

from itertools import pairwise

import pytest

from tests import conftest


@pytest.fixture
def as_worker(monkeypatch):
    """Runs the port choice as worker `index` of `count`, with a fresh memory of ports given."""

    def become(index: int, count: int) -> None:
        monkeypatch.setenv("PYTEST_XDIST_WORKER", f"gw{index}")
        monkeypatch.setenv("PYTEST_XDIST_WORKER_COUNT", str(count))
        monkeypatch.setattr(conftest, "_given", set())

    return become


def test_the_workers_shares_are_apart_and_below_the_ephemeral_ports(as_worker):
    ephemeral = conftest._ephemeral_range()[0]
    shares = []
    for index in range(6):
        as_worker(index, 6)
        shares.append(conftest._worker_ports())
    for share, after in pairwise(shares):
        assert share.stop <= after.start
    assert shares[0].start == conftest.LOWEST_PORT and shares[-1].stop <= ephemeral


def test_a_worker_is_given_its_own_ports_never_twice(as_worker):
    as_worker(2, 4)
    share = conftest._worker_ports()
    ports = [conftest.free_port() for _ in range(300)]
    assert len(set(ports)) == len(ports)
    assert all(port in share for port in ports)
