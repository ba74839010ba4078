"""Who may open the page's socket and log in, the pure parts (docs/web.md#security): the names
the page is served under, the waiting room, the login throttle's keys and waits, the device
tokens that keep a teacher's own browser out of strangers' reach, and the connection budget."""

from __future__ import annotations

import pytest

from voxshape.services.web.admission import (
    FREE_FAILURES,
    Admission,
    AdmissionError,
    LoginThrottle,
    Origins,
    address_key,
    login_keys,
    public_origin,
)
from voxshape.services.web.connections import Budget
from voxshape.services.web.devices import DeviceTokens, cookie_name, device_secret


def test_only_the_pages_own_names_and_origin_are_let_in_whatever_the_address():
    """DNS rebinding: a name an attacker controls made to resolve here is refused, on any
    address; IP literals, loopback and this machine's names cannot be rebound."""
    mine = Origins(own_names=frozenset({"lab-pc"}))
    assert mine.origin_allowed("http://127.0.0.1:8080", "127.0.0.1:8080", "http")
    assert not mine.origin_allowed("http://evil.example", "127.0.0.1:8080", "http")
    assert not mine.origin_allowed("http://127.0.0.1:8080", "127.0.0.1:8080", "https")
    assert not mine.origin_allowed(None, "127.0.0.1:8080", "http")
    for host in ("localhost:8080", "[::1]:80", "10.0.0.7:8080", "lab-pc:8080"):
        assert mine.host_allowed(host), host
    assert not mine.host_allowed("evil.example:8080")
    assert not mine.origin_allowed("http://evil.example:8080", "evil.example:8080", "http")
    public = Origins(public_origin("HTTPS://Lab.Example:8443/"))
    assert public.public == "https://lab.example:8443"
    assert public.host_allowed("lab.example:8443") and not public.host_allowed("lab.example:80")
    # behind a TLS proxy the gateway serves http, the browser's origin is the public one
    assert public.origin_allowed("https://lab.example:8443", "lab.example:8443", "http")
    for bad in ("lab.example", "ftp://lab.example", "https://lab.example/teach"):
        with pytest.raises(AdmissionError, match=r"is not like https://lab\.example:8443"):
            public_origin(bad)


def test_sockets_waiting_to_log_in_never_take_a_teachers_place():
    a = Admission(max_clients=2, per_user=1, max_waiting=3, waiting_per_address=2)
    assert a.open("s1", "6.6.6.6") == (None, None) and a.open("s2", "6.6.6.6") == (None, None)
    refusal, gone = a.open("s3", "6.6.6.6")
    assert "of this address" in refusal and gone is None
    assert a.open("t1", "10.0.0.1") == (None, None)
    # The room is full: the socket that waited longest gives way to the newcomer.
    assert a.open("t2", "10.0.0.2") == (None, "s1")
    assert list(a.waiting) == ["s2", "t1", "t2"] and a.by_address["6.6.6.6"] == 1
    a.leave("t1")  # its login came: out of the room...
    assert a.login("ana") is None  # ...and a place once the router let it in
    assert "ana has 1 pages open already" in a.login("ana")
    assert a.login("ben") is None and "2 pages are open" in a.login("cleo")
    a.logout("ana")
    assert a.login("cleo") is None
    for s in ("s1", "s2", "t1", "t2", "t2"):  # leaving twice (or after giving way): harmless
        a.leave(s)
    assert dict(a.waiting) == {} and dict(a.by_address) == {}
    assert dict(a.teachers) == {"ben": 1, "cleo": 1}


def test_limits_count_an_ipv6_network_as_one_address():
    assert address_key("10.1.2.3") == "10.1.2.3"
    assert address_key("::ffff:10.1.2.3") == "10.1.2.3"
    assert address_key("2001:db8:1:2:aaaa::1") == address_key("2001:db8:1:2:bbbb::9")
    assert address_key("2001:db8:1:2::1") == "2001:db8:1:2::/64"
    assert address_key("2001:db8:1:3::1") != address_key("2001:db8:1:2::1")
    assert address_key("-") == "-"


def test_guesses_wait_longer_and_longer_and_are_counted_before_the_router_answers():
    t = LoginThrottle(longest=8.0, forget_s=100.0)
    keys = login_keys("ben", "6.6.6.6", teacher=True, device=None)
    assert keys == ("user-address:ben@6.6.6.6", "address:6.6.6.6", "user:ben")
    # 30 guesses at once: counted as they are let through, before any answer.
    let_through = [t.attempt(keys, 10.0) == 0.0 for _ in range(30)]
    assert sum(let_through) == FREE_FAILURES["user-address"] == 3
    t.failed(keys, 11.2)  # the router's refusals: the wait runs from them
    assert t.wait(keys, 11.2) == pytest.approx(1.0)
    assert t.attempt(keys, 12.2) == 0.0  # the fourth, a second later
    assert t.wait(keys, 12.2) == pytest.approx(2.0)
    for k in range(10):
        t.attempt(keys, 20.0 + 8.0 * k)
    assert t.wait(keys, 92.0) == pytest.approx(8.0)  # at most `longest`
    assert t.wait(keys, 192.0) == 0.0  # forgotten
    # A name that is no teacher counts under its address only: no key per made-up name.
    assert login_keys("ghost", "6.6.6.6", teacher=False, device=None) == ("address:6.6.6.6",)


def test_a_stranger_failing_as_a_teacher_never_locks_her_out():
    """Six failures as cy from another address, then cy's own login from hers (no cookie) goes
    through; strangers failing from everywhere hold up only browsers without her cookie, and
    one success clears exactly the keys it was counted under."""
    t = LoginThrottle()
    now = 100.0
    for _ in range(6):  # the stranger waits as told between tries
        stranger = login_keys("cy", "6.6.6.6", teacher=True, device=None)
        now += t.wait(stranger, now)
        assert t.attempt(stranger, now) == 0.0
        t.failed(stranger, now + 1.2)
        now += 1.2
    hers = login_keys("cy", "10.0.0.7", teacher=True, device=None)
    assert t.attempt(hers, now) == 0.0
    t.succeeded(hers)
    assert t.wait(stranger, now) > 0  # the stranger's own key still waits
    for k in range(FREE_FAILURES["user"]):  # from as many addresses: the per-user key fills
        t.attempt(login_keys("cy", f"6.6.7.{k}", teacher=True, device=None), now)
    assert t.wait(login_keys("cy", "10.0.0.8", teacher=True, device=None), now) > 0
    with_cookie = login_keys("cy", "10.0.0.8", teacher=True, device="ab" * 16)
    assert with_cookie == (f"device:cy:{'ab' * 16}",)
    assert t.attempt(with_cookie, now) == 0.0  # her own browser is not held up
    t.succeeded(with_cookie)
    assert t.wait(login_keys("cy", "10.0.0.9", teacher=True, device=None), now) > 0
    # A device's own failures (a stolen cookie guessing) wait like one user at one address.
    assert [t.attempt(with_cookie, now + 1) == 0.0 for _ in range(5)].count(True) == 3


def test_device_tokens_are_signed_for_one_user_and_expire():
    tokens = DeviceTokens(device_secret("the web's password"), ttl_s=1000)
    token = tokens.issue("cy", 5000.0)
    device = tokens.verify(token, 5500.0)
    assert device is not None and device.user == "cy" and len(device.nonce) == 32
    assert tokens.age_left(device, 5500.0) == 500
    assert tokens.verify(token, 6001.0) is None  # expired
    assert tokens.verify(token, 4000.0) is None  # issued in the future
    user, nonce, issued, mac = token.split(":")
    for forged in (
        f"ana:{nonce}:{issued}:{mac}",  # another user's name on cy's token
        f"{user}:{nonce}:{int(issued) + 1}:{mac}",  # renewed by hand
        f"{user}:{nonce}:{issued}:{mac[:-1]}A" if mac[-1] != "A" else token[:-1] + "B",
        token + "x",
        "x" * 5000,
        None,
        17,
    ):
        assert tokens.verify(forged, 5500.0) is None, forged
    # The key comes from the gateway's password: a restart keeps its tokens; another
    # gateway's (or a random key's) are not this one's.
    assert DeviceTokens(device_secret("the web's password"), ttl_s=1000).verify(token, 5500.0)
    assert DeviceTokens(device_secret("another"), ttl_s=1000).verify(token, 5500.0) is None
    assert DeviceTokens(device_secret(None)).verify(token, 5500.0) is None
    assert cookie_name("cy") == "voxshape-device-cy"


class Conn:
    """A connection as the budget sees it: its address and transport; gives way when told."""

    def __init__(self, address: str) -> None:
        self.address, self.transport, self.gone = address, object(), False

    def give_way(self) -> None:
        self.gone = True


def test_the_connection_budget_keeps_teachers_and_one_address_to_its_share():
    budget = Budget(16)
    assert budget.per_address == 8  # a quarter (at least 8)
    flood = [Conn("6.6.6.6") for _ in range(10)]
    assert [budget.take(c) for c in flood] == [True] * 8 + [False] * 2  # one address's share
    teacher = Conn("10.0.0.1")
    assert budget.take(teacher)
    budget.prove(teacher.transport)  # logged in: never gives way
    others = [Conn(f"7.7.7.{k // 4}") for k in range(12)]
    assert all(budget.take(c) for c in others)  # past the budget: the oldest unproven go
    assert [c.gone for c in flood[:8]] == [True] * 5 + [False] * 3 and not teacher.gone
    assert len(budget.open) == 16 and budget.gave_way == 5 and budget.refused == 2
    for c in flood[:5]:
        budget.release(c)  # their connection_lost, after giving way: nothing more
    assert len(budget.open) == 16 and budget.by_address["6.6.6.6"] == 3
    only_teachers = Budget(16)
    teachers = [Conn(f"10.0.1.{k}") for k in range(16)]
    for c in teachers:
        assert only_teachers.take(c)
        only_teachers.prove(c.transport)
    assert not only_teachers.take(Conn("6.6.6.7"))  # nobody to give way: refused
    assert not any(c.gone for c in teachers)
    assert Budget(100_000).per_address == 256
