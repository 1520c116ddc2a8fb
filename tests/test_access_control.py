"""Zenoh authentication and access control from `[zenoh.access]`, on real sessions on loopback."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest
import zenoh

from cnc.bus.access import (
    access_control, client_config, controller_credentials, dictionary_file, router_config, shop_router_zid,
)
from cnc.bus.keys import Keys
from cnc.bus.session import connect_endpoints, open_client, open_router
from cnc.config import ConfigError, MachineConfig

from .conftest import machine_config

CREDENTIALS = """\
# users of the test machine
controller:ctl-secret

operator1:op-secret
observer1:obs-secret
"""
PASSWORDS = {"controller": "ctl-secret", "operator1": "op-secret", "observer1": "obs-secret"}
QUERY_TIMEOUT_S = 1.0


def access_machine(tmp_path: Path, **overrides) -> MachineConfig:
    """The shipped machine on a free port with access control on and the users above."""
    creds = tmp_path / "credentials.txt"
    creds.write_text(CREDENTIALS, encoding="utf-8")
    return machine_config(**{
        "zenoh.access.enabled": True,
        "zenoh.access.credentials_file": str(creds),
        "zenoh.access.operators": ["operator1"],
        "zenoh.access.observers": ["observer1"],
        **overrides,
    })


class Bus:
    """A router for one machine and the client sessions of a test, all closed at the end."""

    def __init__(self, cfg: MachineConfig) -> None:
        self.cfg = cfg
        self.keys = Keys(cfg.zenoh.key_prefix, cfg.machine.name)
        self.endpoints = connect_endpoints(cfg.zenoh.listen)
        self.router = open_router(cfg)
        self.sessions: list[zenoh.Session] = []

    def login(self, user: str | None, password: str | None = None) -> zenoh.Session:
        """A client session as `user` (its own password unless one is given)."""
        credentials = None if user is None else (user, password if password is not None else PASSWORDS[user])
        session = open_client(self.endpoints, credentials)
        self.sessions.append(session)
        return session

    def close(self) -> None:
        for session in reversed(self.sessions):
            session.close()
        self.router.close()


@pytest.fixture
def bus(tmp_path):
    b = Bus(access_machine(tmp_path))
    yield b
    b.close()


@pytest.fixture
def open_bus():
    b = Bus(machine_config())
    yield b
    b.close()


def put_until_received(put, received: threading.Event, timeout_s: float = 5.0) -> bool:
    """Put again until the subscriber has it: a new subscription takes a moment to reach the router."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        put()
        if received.wait(0.05):
            return True
    return False


def replies(session: zenoh.Session, key: str, payload: bytes | None = None) -> list[str]:
    """The payloads of the ok replies to a query (the get returns at its final reply or timeout)."""
    return [r.ok.payload.to_string() for r in session.get(key, payload=payload, timeout=QUERY_TIMEOUT_S) if r.ok is not None]


def reached(declarer: zenoh.Session, watcher: zenoh.Session, keys: Keys) -> None:
    """Wait until what `declarer` has declared so far is known where `watcher` is connected.
    Declarations travel a link in order, so a liveliness token declared after them arrives after
    them; `alive/**` is a key every role may watch."""
    arrived = threading.Event()
    subscriber = watcher.liveliness().declare_subscriber(keys.alive("sync"), lambda s: arrived.set(), history=True)
    token = declarer.liveliness().declare_token(keys.alive("sync"))
    try:
        assert arrived.wait(5.0), "declarations did not reach the other session's router"
    finally:
        token.undeclare()
        subscriber.undeclare()


def command_queryable(session: zenoh.Session, key: str, seen: list[str]) -> zenoh.Queryable:
    """A stand-in for the gateway's `cmd/**`: records what reached it and answers ok."""

    def on_query(query: zenoh.Query) -> None:
        seen.append(str(query.key_expr))
        query.reply(query.key_expr, "ok")

    return session.declare_queryable(key, on_query)


# -- authentication -----------------------------------------------------------------------------


def test_session_without_credentials_is_refused_at_connection(bus):
    with pytest.raises(zenoh.ZError):
        bus.login(None)


def test_session_with_a_wrong_password_is_refused(bus):
    with pytest.raises(zenoh.ZError):
        bus.login("operator1", "not-the-password")


def test_user_missing_from_the_credentials_file_is_refused(bus):
    with pytest.raises(zenoh.ZError):
        bus.login("intruder", "op-secret")


def test_every_named_user_logs_in_with_its_password(bus):
    for user in PASSWORDS:
        assert bus.login(user).info.routers_zid() == [bus.router.zid()]


# -- rules --------------------------------------------------------------------------------------


def test_observer_receives_status_but_its_command_query_never_reaches_the_queryable(bus):
    controller, observer = bus.login("controller"), bus.login("observer1")
    seen: list[str] = []
    _q = command_queryable(controller, f"{bus.keys.root}/cmd/**", seen)
    status = controller.declare_publisher(bus.keys.status)
    got = threading.Event()
    _sub = observer.declare_subscriber(bus.keys.status, lambda sample: got.set())
    assert put_until_received(lambda: status.put("{}"), got)
    reached(controller, observer, bus.keys)

    assert replies(observer, f"{bus.keys.root}/cmd/start") == []
    operator = bus.login("operator1")
    assert replies(operator, f"{bus.keys.root}/cmd/hold") == ["ok"]
    assert seen == [f"{bus.keys.root}/cmd/hold"]  # the observer's cmd/start, sent first, never arrived


def test_operator_command_query_reaches_the_queryable_and_gets_its_reply(bus):
    controller, operator = bus.login("controller"), bus.login("operator1")
    seen: list[str] = []
    _q = command_queryable(controller, f"{bus.keys.root}/cmd/**", seen)
    reached(controller, operator, bus.keys)
    assert replies(operator, f"{bus.keys.root}/cmd/start") == ["ok"]
    assert seen == [f"{bus.keys.root}/cmd/start"]


def test_operator_uploads_a_program_and_an_observer_cannot(bus):
    controller, operator, observer = bus.login("controller"), bus.login("operator1"), bus.login("observer1")
    uploads: list[str] = []
    got = threading.Event()
    _sub = controller.declare_subscriber(
        f"{bus.keys.root}/program/**", lambda s: (uploads.append(s.payload.to_string()), got.set())
    )
    observer.put(f"{bus.keys.root}/program/upload", "from observer")
    assert put_until_received(lambda: operator.put(f"{bus.keys.root}/program/upload", "from operator"), got)
    assert set(uploads) == {"from operator"}


def test_observer_queries_alarms_jobs_and_the_loaded_program_but_not_uploads(bus):
    controller, observer = bus.login("controller"), bus.login("observer1")
    _qs = [
        controller.declare_queryable(key, lambda q: q.reply(q.key_expr, str(q.key_expr)))
        for key in (f"{bus.keys.root}/alarms/**", f"{bus.keys.root}/jobs/**", f"{bus.keys.root}/program/**")
    ]
    reached(controller, observer, bus.keys)
    for key in (bus.keys.alarms_active, f"{bus.keys.root}/jobs/history", f"{bus.keys.root}/program"):
        assert replies(observer, key) == [key]
    assert replies(observer, f"{bus.keys.root}/program/upload") == []


def test_observer_neither_sees_internal_keys_nor_forges_status(bus):
    controller, observer = bus.login("controller"), bus.login("observer1")
    internal = threading.Event()
    seen_by_observer: list[str] = []
    seen_by_controller: list[str] = []
    observer_got = threading.Event()
    _internal = observer.declare_subscriber(f"{bus.keys.root}/internal/**", lambda s: internal.set())
    _obs = observer.declare_subscriber(
        bus.keys.status, lambda s: (seen_by_observer.append(s.payload.to_string()), observer_got.set())
    )
    _ctl = controller.declare_subscriber(bus.keys.status, lambda s: seen_by_controller.append(s.payload.to_string()))
    _alarms = controller.declare_queryable(bus.keys.alarms_active, lambda q: q.reply(q.key_expr, "[]"))
    reached(controller, observer, bus.keys)
    assert put_until_received(lambda: controller.put(bus.keys.status, "sync"), observer_got)

    # Each link keeps its order: the marker behind a message proves the message had its chance.
    observer_got.clear()
    controller.put(f"{bus.keys.root}/internal/logic/x", "{}")
    controller.put(bus.keys.status, "marker")
    assert observer_got.wait(5.0) and seen_by_observer[-1] == "marker"
    assert not internal.is_set()

    observer.put(bus.keys.status, "forged")
    assert replies(observer, bus.keys.alarms_active) == ["[]"]
    assert "forged" not in seen_by_controller and "marker" in seen_by_controller


def test_observer_sees_controller_liveliness_and_announces_its_station(bus):
    controller, observer = bus.login("controller"), bus.login("observer1")
    _token = controller.liveliness().declare_token(bus.keys.alive("logic"))
    alive = threading.Event()
    _live = observer.liveliness().declare_subscriber(bus.keys.alive_all, lambda s: alive.set(), history=True)
    assert alive.wait(5.0)

    stations: list[str] = []
    station_seen = threading.Event()
    station = f"{bus.keys.root}/hmi/station1"

    def on_token(sample: zenoh.Sample) -> None:
        stations.append(str(sample.key_expr))
        if str(sample.key_expr) == station:
            station_seen.set()

    _watch = controller.liveliness().declare_subscriber(f"{bus.keys.root}/**", on_token, history=True)
    _forged = observer.liveliness().declare_token(f"{bus.keys.root}/cmd/forged")
    _station = observer.liveliness().declare_token(station)
    assert station_seen.wait(5.0)
    assert f"{bus.keys.root}/cmd/forged" not in stations  # declared first on the same link: it had its chance


def test_controller_user_declares_queryables_and_publishes_anywhere(bus):
    logic, planner = bus.login("controller"), bus.login("controller")
    _q = logic.declare_queryable(bus.keys.logic("state"), lambda q: q.reply(q.key_expr, "idle"))
    reached(logic, planner, bus.keys)
    assert replies(planner, bus.keys.logic("state")) == ["idle"]
    assert replies(bus.router, bus.keys.logic("state")) == ["idle"]  # the supervisor asks from the router
    got = threading.Event()
    _sub = logic.declare_subscriber(f"{bus.keys.root}/internal/**", lambda s: got.set())
    assert put_until_received(lambda: planner.put(f"{bus.keys.root}/internal/planner/x", "{}"), got)


def test_router_session_queryable_answers_operators(bus):
    operator = bus.login("operator1")
    _q = bus.router.declare_queryable(f"{bus.keys.root}/cmd/**", lambda q: q.reply(q.key_expr, "ok"))
    reached(bus.router, operator, bus.keys)
    assert replies(operator, f"{bus.keys.root}/cmd/reset") == ["ok"]


def test_access_disabled_lets_any_session_do_anything(open_bus):
    assert controller_credentials(open_bus.cfg) is None
    anyone, other = open_bus.login(None), open_bus.login(None)
    seen: list[str] = []
    _q = command_queryable(anyone, f"{open_bus.keys.root}/cmd/**", seen)
    reached(anyone, other, open_bus.keys)
    assert replies(other, f"{open_bus.keys.root}/cmd/start") == ["ok"]
    got = threading.Event()
    _sub = anyone.declare_subscriber(f"{open_bus.keys.root}/program/**", lambda s: got.set())
    assert put_until_received(lambda: other.put(f"{open_bus.keys.root}/program/upload", "G0 X0"), got)


# -- configuration ------------------------------------------------------------------------------


def test_controller_credentials_come_from_the_credentials_file(tmp_path):
    assert controller_credentials(access_machine(tmp_path)) == ("controller", "ctl-secret")


def test_client_config_carries_the_credentials():
    conf = client_config(["tcp/127.0.0.1:7447"], ("operator1", "op-secret"))
    assert json.loads(conf.get_json("transport/auth/usrpwd/user")) == "operator1"
    assert json.loads(conf.get_json("mode")) == "client"
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False


def test_router_config_without_access_has_no_authentication():
    cfg = machine_config()
    conf = router_config(cfg)
    assert json.loads(conf.get_json("listen/endpoints")) == cfg.zenoh.listen
    assert json.loads(conf.get_json("transport/auth/usrpwd/dictionary_file")) is None
    assert json.loads(conf.get_json("access_control/enabled")) is False


def test_opening_the_router_leaves_no_dictionary_copy_behind(tmp_path, monkeypatch):
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr("tempfile.tempdir", str(scratch))
    Bus(access_machine(tmp_path)).close()
    assert list(scratch.iterdir()) == []


def test_missing_credentials_file_names_the_key(tmp_path):
    cfg = access_machine(tmp_path)
    (tmp_path / "credentials.txt").unlink()
    with pytest.raises(ConfigError, match=r"\[zenoh\.access\] credentials_file: .*credentials\.txt"):
        router_config(cfg)


def test_controller_user_missing_from_the_file_names_the_key(tmp_path):
    cfg = access_machine(tmp_path)
    (tmp_path / "credentials.txt").write_text("operator1:op-secret\nobserver1:obs-secret\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"\[zenoh\.access\] controller_user: controller: not in"):
        controller_credentials(cfg)


def test_rules_deny_by_default_and_give_each_role_its_keys(tmp_path):
    cfg = access_machine(tmp_path)
    acl = access_control(cfg)
    root = Keys(cfg.zenoh.key_prefix, cfg.machine.name).root
    rules = {r["id"]: r for r in acl["rules"]}
    policies = {p["id"]: p for p in acl["policies"]}
    assert acl["default_permission"] == "deny"
    assert rules["command in"]["key_exprs"] == [f"{root}/cmd/**"]
    assert "command in" in policies["operators"]["rules"]
    assert not any(r.startswith(("command", "upload")) for r in policies["observers"]["rules"])
    assert "shop router" not in policies  # no `connect`: no upstream router to trust


def test_a_router_that_connects_trusts_only_the_machines_shop_router_id(tmp_path):
    cfg = access_machine(tmp_path, **{"zenoh.connect": ["tcp/127.0.0.1:7448"]})
    conf = router_config(cfg)
    dictionary_file(conf).unlink()
    acl = json.loads(conf.get_json("access_control"))
    subjects = {s["id"]: s for s in acl["subjects"]}
    assert subjects["shop router"]["zids"] == [shop_router_zid(cfg)]
    assert "everything" not in {p["id"]: p for p in acl["policies"]}["shop router"]["rules"]
