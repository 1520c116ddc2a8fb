"""Who reaches the controller (issue 18): the private plane, secure by default, accounts and
roles, command keys bound to who logged in; real routers and sessions on loopback and a Unix socket."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh

from cnc.bus.access import (
    access_control, dictionary_file, open_machine_router, plan_access, role_of, router_config, run_dir,
    write_local_login,
)
from cnc.bus.keys import Keys
from cnc.bus.session import local_login, open_client, zenoh_config
from cnc.bus.users import Account, read_users, write_users
from cnc.config import ConfigError, MachineConfig
from cnc.sim.demo import free_port

from .conftest import REPO, machine_config

PASSWORDS = {"operator1": "op-secret", "observer1": "obs-secret", "engineer1": "eng-secret"}
ROLES_OF = {"operator1": "operator", "observer1": "observer", "engineer1": "engineer"}
QUERY_TIMEOUT_S = 1.0


def accounts_file(tmp_path: Path) -> Path:
    path = tmp_path / "machine.users"
    write_users(path, {u: Account(u, ROLES_OF[u], p) for u, p in PASSWORDS.items()})
    return path


def machine(tmp_path: Path, accounts: bool = True, **overrides) -> MachineConfig:
    """The shipped machine listening on every interface at a free port; its users file in tmp_path."""
    users = accounts_file(tmp_path) if accounts else tmp_path / "none.users"
    return machine_config(**{"zenoh.listen": [f"tcp/0.0.0.0:{free_port()}"], "zenoh.access.users_file": str(users),
                             **overrides})


class Bus:
    """A controller's router (its private plane on a Unix socket) and a test's sessions, closed at the end."""

    def __init__(self, cfg: MachineConfig, tmp_path: Path) -> None:
        self.cfg = cfg
        self.keys = Keys(cfg.zenoh.key_prefix, cfg.machine.name)
        self.plan = plan_access(cfg, run_dir() / f"test-{os.getpid()}-{free_port()}.sock")
        self.router = open_machine_router(cfg, self.plan)
        self.login_file = write_local_login(self.plan)
        self.network = [ep.replace("0.0.0.0", "127.0.0.1") for ep in self.plan.network]
        self.sessions: list[zenoh.Session] = []

    def login(self, user: str | None, password: str | None = None, tls=None) -> zenoh.Session:
        """A station's session on the network endpoint as `user` (its own password unless one is given)."""
        credentials = None if user is None else (user, password if password is not None else PASSWORDS[user])
        return self._keep(zenoh.open(zenoh_config("client", connect=self.network, credentials=credentials, tls=tls)))

    def inside(self) -> zenoh.Session:
        """A controller process's session: on the private plane, with the controller's login of this run."""
        return self._keep(open_client([self.plan.private], self.plan.controller))

    def _keep(self, session: zenoh.Session) -> zenoh.Session:
        self.sessions.append(session)
        return session

    def close(self) -> None:
        for session in reversed(self.sessions):
            session.close()
        self.router.close()
        Path(self.plan.private.split("/", 1)[1]).unlink(missing_ok=True)
        if self.login_file is not None:
            self.login_file.unlink(missing_ok=True)


@pytest.fixture
def bus(tmp_path):
    b = Bus(machine(tmp_path), tmp_path)
    yield b
    b.close()


@pytest.fixture
def local_bus(tmp_path):
    b = Bus(machine(tmp_path, accounts=False), tmp_path)
    yield b
    b.close()


def put_until_received(put, received: threading.Event, timeout_s: float = 30.0) -> bool:
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


def reached(declarer: zenoh.Session, watcher: zenoh.Session, keys: Keys, as_user: str = "") -> None:
    """Wait until what `declarer` has declared so far is known where `watcher` is connected.
    Declarations travel a link in order, so a liveliness token declared after them arrives after
    them; `alive/**` is a key every role may watch, and a station (`as_user`) announces under its own
    `hmi/<user>/`."""
    arrived = threading.Event()
    key = keys.station("sync", as_user, "x") if as_user else keys.alive("sync")
    subscriber = watcher.liveliness().declare_subscriber(key, lambda s: arrived.set(), history=True)
    token = declarer.liveliness().declare_token(key)
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



# -- secure by default ----------------------------------------------------------------------------


def test_without_accounts_the_controller_serves_its_own_host_only_and_says_how_to_let_others_in(tmp_path):
    cfg = machine(tmp_path, accounts=False, **{"zenoh.connect": ["tcp/10.1.2.3:7448"]})
    plan = plan_access(cfg, tmp_path / "bus.sock")
    port = cfg.zenoh.listen[0].rsplit(":", 1)[1]
    assert plan.network == [f"tcp/127.0.0.1:{port}"] and plan.connect == [] and not plan.auth
    assert "serving this host only" in plan.notice and "waterjet users add NAME --role operator" in plan.notice
    assert "not connecting to tcp/10.1.2.3:7448" in plan.notice
    opened = plan_access(machine(tmp_path, accounts=False, **{"zenoh.access.open_network": True}), tmp_path / "b.sock")
    assert opened.network[0].startswith("tcp/0.0.0.0:") and "UNSAFE" in opened.notice
    assert plan_access(cfg).roles == {"local": "engineer"}


def test_a_local_process_on_the_network_endpoint_gets_the_public_keys_and_nothing_internal(local_bus):
    inside, station = local_bus.inside(), local_bus.login(None)
    seen: list[str] = []
    _cmd = command_queryable(inside, f"{local_bus.keys.root}/u/*/cmd/**", seen)
    _internal = command_queryable(inside, local_bus.keys.logic("drives"), seen)
    reached(inside, station, local_bus.keys)
    assert replies(station, local_bus.keys.logic("drives")) == []
    assert replies(station, local_bus.keys.cmd("stop")) == ["ok"]  # u/local/cmd: a station on this host commands
    assert replies(station, local_bus.keys.cmd("stop", "someone")) == []
    assert replies(inside, local_bus.keys.logic("drives")) == ["ok"]  # the private plane reaches everything
    assert seen == [local_bus.keys.cmd("stop"), local_bus.keys.logic("drives")]


def test_a_station_cannot_serve_or_forge_what_the_controller_serves(local_bus):
    inside, station = local_bus.inside(), local_bus.login(None)
    got: list[str] = []
    _sub = inside.declare_subscriber(local_bus.keys.status, lambda s: got.append(s.payload.to_string()))
    _fake = station.declare_queryable(local_bus.keys.logic("reset"), lambda q: q.reply(q.key_expr, "forged"))
    reached(station, inside, local_bus.keys, as_user="local")
    station.put(local_bus.keys.status, "forged")
    inside.put(local_bus.keys.status, "real")
    deadline = time.monotonic() + 30.0  # an event: the limit only says when to give up
    while "real" not in got and time.monotonic() < deadline:
        time.sleep(0.01)
    assert got == ["real"]
    assert replies(inside, local_bus.keys.logic("reset")) == []


# -- accounts ---------------------------------------------------------------------------------------


def test_with_accounts_a_session_without_credentials_or_with_a_wrong_one_is_refused(bus):
    for user, password in ((None, None), ("operator1", "not-the-password"), ("intruder", "op-secret")):
        with pytest.raises(zenoh.ZError):
            bus.login(user, password)
    for user in PASSWORDS:
        assert bus.login(user).info.routers_zid() == [bus.router.zid()]


def test_each_user_reaches_only_its_own_command_keys_and_observers_none(bus):
    inside = bus.inside()
    seen: list[str] = []
    _cmd = command_queryable(inside, f"{bus.keys.root}/u/*/**", seen)
    operator, observer, engineer = bus.login("operator1"), bus.login("observer1"), bus.login("engineer1")
    for s in (operator, observer, engineer):
        reached(inside, s, bus.keys)
    assert replies(observer, bus.keys.cmd("start", "observer1")) == []
    assert replies(observer, bus.keys.cmd("start", "operator1")) == []
    assert replies(operator, bus.keys.cmd("start", "engineer1")) == []
    assert replies(operator, bus.keys.cmd("hold", "operator1")) == ["ok"]
    assert replies(engineer, bus.keys.user_param("engineer1", "axis.x.kp_1_s")) == ["ok"]
    assert seen == [bus.keys.cmd("hold", "operator1"), bus.keys.user_param("engineer1", "axis.x.kp_1_s")]


def test_an_observer_reaches_its_stop_all_only_where_the_machine_file_lets_it(tmp_path):
    """Observers command nothing, unless `[zenoh.access] observers_may_stop_all`: then their own
    stop_all key, and still no other command."""
    for allowed in (False, True):
        bus = Bus(machine(tmp_path, **{"zenoh.access.observers_may_stop_all": allowed}), tmp_path)
        try:
            inside = bus.inside()
            seen: list[str] = []
            _cmd = command_queryable(inside, f"{bus.keys.root}/u/*/**", seen)
            observer = bus.login("observer1")
            reached(inside, observer, bus.keys)
            assert replies(observer, bus.keys.cmd("stop_all", "observer1")) == (["ok"] if allowed else [])
            assert replies(observer, bus.keys.cmd("stop", "observer1")) == []
            assert replies(observer, bus.keys.cmd("stop_all", "operator1")) == [], "only under its own name"
        finally:
            bus.close()


def test_the_controllers_own_login_opens_nothing_internal_from_the_network(bus):
    inside = bus.inside()
    seen: list[str] = []
    _internal = command_queryable(inside, f"{bus.keys.root}/internal/**", seen)
    stolen = bus.login(*bus.plan.controller)  # the right password, from a network endpoint: no rule matches it
    reached(inside, bus.login("operator1"), bus.keys)  # the queryable is known at the router by now
    assert replies(stolen, bus.keys.logic("drives")) == []
    assert replies(inside, bus.keys.logic("drives")) == ["ok"]


def test_a_station_on_the_controllers_host_logs_in_by_itself_as_local(bus):
    assert local_login(bus.network) == bus.plan.local
    assert stat.S_IMODE(bus.login_file.stat().st_mode) == 0o600
    inside, here = bus.inside(), bus._keep(open_client(bus.network))  # no credentials given: the local login
    seen: list[str] = []
    _cmd = command_queryable(inside, f"{bus.keys.root}/u/*/cmd/**", seen)
    reached(inside, here, bus.keys)
    assert replies(here, bus.keys.cmd("stop")) == ["ok"]
    assert role_of(bus.cfg, "local") == "engineer" and role_of(bus.cfg, "operator1") == "operator"
    assert role_of(bus.cfg, "nobody") is None


def test_observers_watch_status_events_and_histories_and_announce_only_their_own_station(bus):
    inside, observer = bus.inside(), bus.login("observer1")
    _q = inside.declare_queryable(bus.keys.alarms_history, lambda q: q.reply(q.key_expr, "page"))
    got = threading.Event()
    _sub = observer.declare_subscriber(bus.keys.status, lambda s: got.set())
    assert put_until_received(lambda: inside.put(bus.keys.status, "{}"), got)
    reached(inside, observer, bus.keys)
    assert replies(observer, bus.keys.alarms_history) == ["page"]
    tokens: list[str] = []
    _watch = inside.liveliness().declare_subscriber(f"{bus.keys.root}/hmi/**", lambda s: tokens.append(str(s.key_expr)),
                                                    history=True)
    _own = observer.liveliness().declare_token(bus.keys.station("screen", "observer1", "s1"))
    _other = observer.liveliness().declare_token(bus.keys.station("panel", "operator1", "s2"))
    reached(observer, inside, bus.keys, as_user="observer1")
    deadline = time.monotonic() + 30.0
    while not tokens and time.monotonic() < deadline:
        time.sleep(0.01)
    assert bus.keys.station("screen", "observer1", "s1") in tokens
    assert bus.keys.station("panel", "operator1", "s2") not in tokens, "an observer announced another user's station"


def test_rules_deny_by_default_and_bind_the_private_plane_to_the_unix_socket(bus):
    acl = access_control(bus.cfg, bus.plan)
    assert acl["default_permission"] == "deny"
    subjects = {s["id"]: s for s in acl["subjects"]}
    assert subjects["controller"] == {"id": "controller", "usernames": ["controller"], "link_protocols": ["unixsock-stream"]}
    assert subjects["station local"] == {"id": "station local", "usernames": ["local"], "interfaces": ["lo"]}
    rules = {r["id"]: r for r in acl["rules"]}
    assert "commands observer1" not in rules and rules["commands operator1"]["key_exprs"] == [f"{bus.keys.root}/u/operator1/**"]


def test_opening_the_router_leaves_no_dictionary_copy_behind(tmp_path):
    cfg = machine(tmp_path)
    plan = plan_access(cfg, tmp_path / "bus.sock")
    conf = router_config(cfg, plan)
    copy = dictionary_file(conf)
    assert copy is not None and copy.exists() and stat.S_IMODE(copy.stat().st_mode) == 0o600
    copy.unlink()
    router = open_machine_router(cfg, plan)
    try:
        assert not list(Path(copy.parent).glob("waterjet-usrpwd-*"))
    finally:
        router.close()
        (tmp_path / "bus.sock").unlink(missing_ok=True)


# -- the users file and `waterjet users` ----------------------------------------------------------------


@pytest.mark.parametrize("text, mode, where", [
    ("alice:operator:long-enough\n", 0o644, "readable by others (mode 0644)"),
    ("alice:operator\n", 0o600, ":2: expected name:role:password"),
    ("alice:admin:long-enough\n", 0o600, ":2: role 'admin' is not one of observer, operator, engineer"),
    ("controller:operator:long-enough\n", 0o600, "is the controller's own"),
    ("alice:operator:short\n", 0o600, "at least 8 characters"),
])
def test_a_broken_users_file_is_refused_naming_the_key_the_line_and_why(tmp_path, text, mode, where):
    users = tmp_path / "m.users"
    users.write_text("# accounts\n" + text)
    users.chmod(mode)
    with pytest.raises(ConfigError) as err:
        machine_config(**{"zenoh.access.users_file": str(users)})
    assert "[zenoh.access] users_file" in str(err.value) or "zenoh.access" in str(err.value)
    assert where in str(err.value)


def test_waterjet_users_adds_lists_changes_and_removes_accounts_never_printing_a_password(tmp_path):
    machine_file = tmp_path / "m.toml"
    machine_file.write_text((REPO / "machines" / "waterjet.toml").read_text())

    def users(*args: str, stdin: str = "") -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "cnc.cli", "users", *args, "--machine", str(machine_file)],
                              input=stdin, capture_output=True, text=True, cwd=REPO, timeout=60)

    listed = users("list")
    assert listed.returncode == 0 and "serves its own host only" in listed.stdout
    added = users("add", "alice", "--role", "operator", "--password-stdin", stdin="alice-secret\n")
    assert added.returncode == 0 and "added alice (operator)" in added.stdout and "next starts" in added.stdout
    assert users("add", "bob", "--role", "observer", "--password-stdin", stdin="bob-secret-1\n").returncode == 0
    changed = users("add", "alice", "--role", "engineer", "--password-stdin", stdin="alice-secret-2\n")
    assert changed.returncode == 0 and "changed alice (engineer)" in changed.stdout
    path = tmp_path / "m.users"
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert {n: a.role for n, a in read_users(path).items()} == {"alice": "engineer", "bob": "observer"}
    listed = users("list")
    assert listed.stdout.split() == ["alice", "engineer", "bob", "observer"]
    short = users("add", "carol", "--role", "operator", "--password-stdin", stdin="short\n")
    assert short.returncode == 2 and "at least 8 characters" in short.stderr
    no_tty = users("add", "carol", "--role", "operator")
    assert no_tty.returncode == 2 and "--password-stdin" in no_tty.stderr
    assert users("remove", "bob").returncode == 0 and list(read_users(path)) == ["alice"]
    missing = users("remove", "bob")
    assert missing.returncode == 2 and "no account 'bob'" in missing.stderr
    everything = "".join(r.stdout + r.stderr for r in (listed, added, changed, short, no_tty, missing))
    assert "secret" not in everything


# -- TLS ---------------------------------------------------------------------------------------------


def test_over_tls_a_station_needs_both_a_certificate_of_the_machines_ca_and_an_account(tmp_path):
    from cnc.bus.certs import TlsFiles, files_for, issue, make_ca

    tls = tmp_path / "machine.tls"
    make_ca(tls, "waterjet")
    issue(tls, "controller", ["127.0.0.1", "localhost"])
    issue(tls, "panel")
    stranger = tmp_path / "other.tls"  # a CA of some other machine, and a station certificate it signed
    make_ca(stranger, "other")
    issue(stranger, "panel")
    port = free_port()
    cfg = machine(tmp_path, **{"zenoh.listen": [f"tls/127.0.0.1:{port}"], "zenoh.access.tls_dir": str(tls)})
    b = Bus(cfg, tmp_path)
    try:
        inside = b.inside()
        seen: list[str] = []
        _cmd = command_queryable(inside, f"{b.keys.root}/u/*/cmd/**", seen)
        station = b.login("operator1", tls=files_for(tls, "panel"))
        reached(inside, station, b.keys)
        assert replies(station, b.keys.cmd("hold", "operator1")) == ["ok"]
        for why, files, user in (
            ("no certificate of its own", TlsFiles(tls / "ca.pem", tls / "ca.pem", tls / "ca.key"), "operator1"),
            ("a certificate of another CA", TlsFiles(tls / "ca.pem", stranger / "panel.pem", stranger / "panel.key"),
             "operator1"),
            ("a certificate but no account", files_for(tls, "panel"), None),
        ):
            with pytest.raises(zenoh.ZError):
                b.login(user, tls=files)
                pytest.fail(f"let in with {why}")
        with pytest.raises(zenoh.ZError):  # plain TCP to the TLS endpoint
            zenoh.open(zenoh_config("client", connect=[f"tcp/127.0.0.1:{port}"], credentials=("operator1", "op-secret")))
    finally:
        b.close()


def test_a_tls_endpoint_without_the_machines_tls_files_is_refused_naming_the_key(tmp_path):
    with pytest.raises(ConfigError, match=r"tls_dir.*needs the machine's TLS directory"):
        machine(tmp_path, **{"zenoh.listen": [f"tls/127.0.0.1:{free_port()}"]})
    cfg = machine(tmp_path, **{"zenoh.listen": [f"tls/127.0.0.1:{free_port()}"], "zenoh.access.tls_dir": str(tmp_path / "none")})
    with pytest.raises(ConfigError, match=r"tls_dir.*no CA certificate"):
        plan_access(cfg, tmp_path / "bus.sock")


def test_waterjet_certs_makes_a_ca_router_and_station_certificates_with_private_keys(tmp_path):
    machine_file = tmp_path / "m.toml"
    machine_file.write_text((REPO / "machines" / "waterjet.toml").read_text())

    def certs(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "cnc.cli", "certs", *args, "--machine", str(machine_file)],
                              capture_output=True, text=True, cwd=REPO, timeout=60)

    assert "no CA here" in certs("station", "panel").stderr
    made = certs("ca")
    assert made.returncode == 0 and 'tls_dir = "m.tls"' in made.stdout
    assert certs("ca").returncode == 2, "a second CA would invalidate every certificate"
    empty = certs("controller", "--host", "")
    assert empty.returncode == 2 and "is empty" in empty.stderr
    assert certs("controller", "--host", "cnc1.shop", "--host", "10.0.0.5").returncode == 0
    assert certs("station", "panel").returncode == 0
    listed = certs("list").stdout
    assert "controller.pem: controller (cnc1.shop, 10.0.0.5)" in listed and "panel.pem: panel" in listed
    for key in ("ca.key", "controller.key", "panel.key"):
        assert stat.S_IMODE((tmp_path / "m.tls" / key).stat().st_mode) == 0o600


def test_a_tool_on_the_controllers_host_reaches_it_on_loopback_tcp_beside_a_tls_endpoint(tmp_path):
    from cnc.bus.session import connect_endpoints

    listen = ["tls/0.0.0.0:7448", "tcp/0.0.0.0:7447"]
    assert connect_endpoints(listen) == ["tcp/127.0.0.1:7447"], "no station certificate needed on this host"
    assert connect_endpoints(["tls/0.0.0.0:7448"]) == ["tls/127.0.0.1:7448"]
