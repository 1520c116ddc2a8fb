"""Who reaches the controller, and what they may do: the two planes and the access rules.

**Two planes, one router.** The controller's router listens on a Unix socket in a directory only
the controller's account can enter (`run_dir`): the private plane, where its own processes talk
(every key, `internal/**` included). It also listens on the network endpoints of `[zenoh] listen`
for stations. Access control is always on, and everything is denied unless a rule allows it:
sessions on the Unix socket may do everything; a station, whatever it declares, reaches only
the public keys - status, position, events, procedure, lock, the queries (histories, program,
procedures, parameters, the logger), liveliness under `alive/**` and `hmi/**` - and, by role,
its own command keys `u/<user>/**`. So no outside host and no local process on the network
endpoints reaches `internal/**`, with or without accounts.

**Accounts.** With accounts in the users file (`cnc.bus.users`), every session logs in (Zenoh's
user/password extension, on every listener of the router: the Unix socket too, where the
controller's processes use a password made for this run only) and acts in its account's role;
a station on the controller's own host logs in as `local` with a password the controller
writes for this run into `run_dir` (0600), accepted on the loopback interface only: an HMI,
`waterjet watch` or a script on the controller's host works without set-up. Without accounts the
controller serves its own host only: its network endpoints are moved to the loopback interface
and `[zenoh] connect` (a shop router) is not used, so nothing on the network reaches it; every
station there is `local`. `[zenoh.access] open_network = true` (unsafe) keeps the endpoints as
written and lets anyone in, in `open_role`.

**The command keys name who sends.** A station's commands go to `u/<user>/cmd/<verb>` and its
parameter changes to `u/<user>/param/...`, and the router lets only `<user>` query under
`u/<user>/**`: the gateway learns who sent a command from the key, never from what the query
says about itself. Observers get no command keys at all.

**A shop router** (`waterjet router --machine M`) applies the same rules to the stations that
connect there; the controller's router logs in to it as `controller` with a password both derive
from the users file, and trusts it by an ID derived the same way (`shop_router_zid`: a Zenoh ID
is an identifier, not a proof). Without TLS the scheme keeps unauthorised stations out of an
honest network, not an eavesdropper.

Zenoh's rules name both directions as seen from the router: `ingress` is what a session sends in
(declarations, puts, queries), `egress` what the router sends out to it (samples, replies,
liveliness tokens).
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import re
import secrets
import stat
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from ..config import ConfigError, MachineConfig, beside, read_credentials, users_path
from .certs import CertError, TlsFiles, files_for
from .keys import Keys
from .session import LOCAL_USER, local_login_path, zenoh_config
from .users import Account, UsersError, read_users, role_at_least

TABLE = "zenoh.access"
CONTROLLER_USER = "controller"
PRIVATE_PROTOCOL = "unixsock-stream"

# Every message kind Zenoh 1.x access control knows about.
ALL_MESSAGES = (
    "put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
    "liveliness_token", "declare_liveliness_subscriber", "liveliness_query",
)

# Public key groups, relative to the machine root `<prefix>/<machine>`.
WATCH_KEYS = ("status", "position", "event/**", "procedure", "lock", "log/live")  # subscribed to
READ_KEYS = ("alarms/**", "jobs/**", "audit/**", "program", "programs", "programs/**", "materials", "control/programs", "lock", "procedures",
             "param/**", "params", "log/**", "sim")  # queried
# (reading a parameter is a query on param/**; changing one goes to the sender's own u/<user>/param/**, and
# starting or stopping a log run is a query that never moves the machine)
ALIVE_KEYS = ("alive/**", "hmi/**")  # liveliness of controller processes and stations

# The file Zenoh reads the user/password dictionary from is a private copy (Zenoh's format
# allows no comments or blank lines); `cnc.bus.session.open_router` removes it once read.
DICTIONARY_PREFIX = "waterjet-usrpwd-"


def run_dir() -> Path:
    """The controller account's private directory (mode 0700): the private plane's socket and the
    local station's login live here. `WATERJET_RUN_DIR` overrides the place."""
    path = Path(os.environ.get("WATERJET_RUN_DIR") or Path(tempfile.gettempdir()) / f"waterjet-{os.getuid()}")
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    st = path.stat()
    if st.st_uid != os.getuid() or st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise ConfigError("<environment>", "run directory", str(path),
                          f"must belong to this account and be private (mode 0700), is {stat.S_IMODE(st.st_mode):04o} "
                          f"owned by uid {st.st_uid}")
    return path


@dataclass(frozen=True)
class Plan:
    """What the router of one controller (or shop router) listens on, who logs in, who may do what."""

    accounts: dict[str, Account]
    network: list[str]  # endpoints stations reach
    connect: list[str]  # routers this one connects to
    private: str = ""  # the private plane's endpoint ("" for a shop router)
    controller: tuple[str, str] | None = None  # the controller processes' login (accounts on)
    local: tuple[str, str] | None = None  # a station on the controller's host (accounts on)
    notice: str = ""  # what `waterjet up` tells the person starting it
    open_network: bool = False
    roles: dict[str, str] = field(default_factory=dict)  # principal -> role
    tls: TlsFiles | None = None  # the router's TLS files, for tls/ endpoints

    @property
    def auth(self) -> bool:
        return bool(self.accounts)


def plan_access(cfg: MachineConfig, private_socket: Path | None = None, shop: bool = False) -> Plan:
    """The plan for `cfg`'s router: the controller's (with its private plane on `private_socket`),
    or with `shop` the machine's shop router. ConfigError names the key at fault."""
    a = cfg.zenoh.access
    path = users_path(cfg)
    try:
        accounts = read_users(path)
    except UsersError as exc:
        raise ConfigError(cfg.source, TABLE, "users_file", str(exc)) from None
    network, connect = list(cfg.zenoh.listen), list(cfg.zenoh.connect)
    tls = None
    if a.tls_dir:
        try:
            tls = files_for(beside(cfg, a.tls_dir), "router" if shop else "controller").check()
        except CertError as exc:
            raise ConfigError(cfg.source, TABLE, "tls_dir", str(exc)) from None
    private = f"{PRIVATE_PROTOCOL}/{private_socket}" if private_socket is not None else ""
    how = f"`waterjet users add NAME --role operator --machine {cfg.source}`"
    if accounts:
        roles = {name: acc.role for name, acc in accounts.items()}
        if not shop:
            roles[LOCAL_USER] = a.local_role
        notice = (f"{len(accounts)} account(s) in {path}: stations log in "
                  f"({', '.join(f'{n} {r}' for n, r in sorted(roles.items()))})")
        controller = (CONTROLLER_USER, secrets.token_urlsafe(24)) if not shop else None
        local = (LOCAL_USER, secrets.token_urlsafe(24)) if not shop else None
        return Plan(accounts, network, connect, private, controller, local, notice, False, roles, tls)
    if shop:
        raise ConfigError(cfg.source, TABLE, "users_file",
                          f"{path} has no accounts: a shop router lets stations in by account; create them with {how}")
    if a.open_network:
        notice = (f"UNSAFE: [zenoh.access] open_network: any host reaching {', '.join(network)} may "
                  f"command this machine as {a.open_role}, without logging in")
        return Plan({}, network, connect, private, notice=notice, open_network=True, roles={LOCAL_USER: a.open_role},
                    tls=tls)
    loopback = [_loopback(ep) for ep in network]
    notice = (f"no accounts in {path}: serving this host only ({', '.join(loopback)})"
              + (f", not connecting to {', '.join(connect)}" if connect else "")
              + f". To let stations on other hosts in, create accounts with {how} and start again")
    return Plan({}, loopback, [], private, notice=notice, roles={LOCAL_USER: a.local_role}, tls=tls)


@dataclass(frozen=True)
class Roles:
    """Who has which role, read from the users file once (the router's rules are fixed when it
    starts too): checking a command never touches the disk, a STOP least of all."""

    of: dict[str, str]

    @classmethod
    def load(cls, cfg: MachineConfig) -> "Roles":
        a = cfg.zenoh.access
        try:
            accounts = read_users(users_path(cfg))
        except (UsersError, OSError):
            accounts = {}  # the router refused to start on such a file; nobody but `local` here
        roles = {name: acc.role for name, acc in accounts.items()}
        roles[LOCAL_USER] = a.open_role if a.open_network and not accounts else a.local_role
        return cls(roles)

    def role(self, user: str) -> str | None:
        """The role of `user` on this machine; None: no such account."""
        return self.of.get(user)


def role_of(cfg: MachineConfig, user: str) -> str | None:
    """The role of `user` on this machine (None: no such account), from the users file now."""
    return Roles.load(cfg).role(user)


def router_config(cfg: MachineConfig, plan: Plan, *, shop: bool = False) -> zenoh.Config:
    """The config of the router `plan` describes. With accounts it names a private copy of the
    user/password dictionary that the caller must delete once Zenoh has read it (`open_router`
    does); see `dictionary_file`."""
    listen = ([plan.private] if plan.private else []) + plan.network
    conf = zenoh_config("router", listen=listen, connect=plan.connect, tls=plan.tls)
    if plan.auth:
        logins = {name: acc.password for name, acc in plan.accounts.items()}
        link = (CONTROLLER_USER, _derived(plan.accounts, "controller link"))
        if shop:
            logins[CONTROLLER_USER] = link[1]  # the controller's router logs in here
            conf.insert_json5("id", json.dumps(shop_router_zid(cfg, plan.accounts)))
        else:
            for user, password in (plan.controller, plan.local):
                logins[user] = password
        conf.insert_json5("transport/auth/usrpwd", json.dumps(
            {"user": link[0], "password": link[1], "dictionary_file": str(_write_dictionary(logins))}))
    upstream = shop_router_zid(cfg, plan.accounts) if plan.connect and plan.auth and not shop else None
    conf.insert_json5("access_control", json.dumps(access_control(cfg, plan, upstream_zid=upstream, shop=shop)))
    return conf


def shop_router_zid(cfg: MachineConfig, accounts: dict[str, Account]) -> str:
    """The Zenoh ID of the machine's shop router, derived from the accounts both routers read."""
    root = Keys(cfg.zenoh.key_prefix, cfg.machine.name).root
    return "a" + _derived(accounts, f"waterjet shop router {root}")[:31]  # 16 bytes; no leading zero


def access_control(cfg: MachineConfig, plan: Plan, upstream_zid: str | None = None, shop: bool = False) -> dict[str, Any]:
    """The `access_control` section (JSON-ready): default deny, the private plane everything,
    each principal the public keys and, by role, its own command keys."""
    root = Keys(cfg.zenoh.key_prefix, cfg.machine.name).root
    rules = [
        _rule("everything", ["ingress", "egress"], ALL_MESSAGES, ["**"]),
        _rule("watch in", ["ingress"], ["declare_subscriber"], _under(root, WATCH_KEYS)),
        _rule("watch out", ["egress"], ["put"], _under(root, WATCH_KEYS)),
        _rule("read in", ["ingress"], ["query"], _under(root, READ_KEYS)),
        _rule("read out", ["egress"], ["reply"], _under(root, READ_KEYS)),
        _rule("alive in", ["ingress"], ["declare_liveliness_subscriber", "liveliness_query"], _under(root, ALIVE_KEYS)),
        _rule("alive out", ["egress"], ["liveliness_token", "reply"], _under(root, ALIVE_KEYS)),
    ]
    observe = ["watch in", "watch out", "read in", "read out", "alive in", "alive out"]
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    if shop:
        subjects.append({"id": "controller", "usernames": [CONTROLLER_USER]})
    elif plan.auth:
        subjects.append({"id": "controller", "usernames": [CONTROLLER_USER], "link_protocols": [PRIVATE_PROTOCOL]})
    else:
        subjects.append({"id": "controller", "link_protocols": [PRIVATE_PROTOCOL]})
    policies.append({"id": "controller", "rules": ["everything"], "subjects": ["controller"]})
    every_station: list[str] = []
    for principal, role in sorted(plan.roles.items()):
        own = [f"token {principal}", f"pong {principal}", f"ping {principal}"]
        rules.append(_rule(own[0], ["ingress"], ["liveliness_token"], [f"{root}/hmi/{principal}/**"]))
        rules.append(_rule(own[1], ["ingress"], ["declare_queryable", "reply"], [f"{root}/ping/{principal}/**"]))
        rules.append(_rule(own[2], ["egress"], ["query"], [f"{root}/ping/{principal}/**"]))
        if role_at_least(role, "operator"):
            own += [f"commands {principal}", f"answers {principal}"]
            rules.append(_rule(own[-2], ["ingress"], ["query"], [f"{root}/u/{principal}/**"]))
            rules.append(_rule(own[-1], ["egress"], ["reply"], [f"{root}/u/{principal}/**"]))
        elif cfg.zenoh.access.observers_may_stop_all:  # its one command: stop everything
            own += [f"stop all {principal}", f"stopped {principal}"]
            rules.append(_rule(own[-2], ["ingress"], ["query"], [f"{root}/u/{principal}/cmd/stop_all"]))
            rules.append(_rule(own[-1], ["egress"], ["reply"], [f"{root}/u/{principal}/cmd/stop_all"]))
        every_station += own
        sid = f"station {principal}"
        if plan.auth and principal == LOCAL_USER:
            subjects.append({"id": sid, "usernames": [LOCAL_USER], "interfaces": ["lo"]})
        elif plan.auth:
            subjects.append({"id": sid, "usernames": [principal]})
        else:
            protocols = sorted({ep.split("/", 1)[0] for ep in plan.network} - {PRIVATE_PROTOCOL})
            subjects.append({"id": sid, "link_protocols": protocols})
        policies.append({"id": sid, "rules": observe + own, "subjects": [sid]})
    if upstream_zid is not None:
        rules.append(_rule("announce out", ["egress"], ALL_MESSAGES,
                           _under(root, WATCH_KEYS + READ_KEYS + ALIVE_KEYS + ("u/**", "ping/**"))))
        subjects.append({"id": "shop router", "zids": [upstream_zid]})
        policies.append({"id": "shop router", "rules": observe + every_station + ["announce out"],
                         "subjects": ["shop router"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def write_local_login(plan: Plan) -> Path | None:
    """Write the local station's login for this run (0600) where stations on this host find it
    (`cnc.bus.session.local_login`); its path, or None when no login is needed (then a stale one
    for the same port, left by a controller that died, is removed)."""
    port = next((_port(ep) for ep in plan.network if _port(ep)), None)
    if port is None:
        return None
    path = local_login_path(port)
    if plan.local is None:  # no login needed: one left by an earlier controller on this port would be refused
        path.unlink(missing_ok=True)
        return None
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(f"{plan.local[0]}:{plan.local[1]}\n")
    return path


def dictionary_file(conf: zenoh.Config) -> Path | None:
    """The private dictionary copy a `router_config` names, or None (no accounts, or not ours)."""
    raw = json.loads(conf.get_json("transport/auth/usrpwd/dictionary_file"))
    if raw is None or not Path(raw).name.startswith(DICTIONARY_PREFIX):
        return None
    return Path(raw)


def station_login(path: str | Path) -> tuple[str, str]:
    """The (user, password) a station logs in with: the first user:password line of its login
    file. ValueError names the file and what is wrong."""
    try:
        users = read_credentials(Path(path))  # its ValueError names the file and the line
    except OSError as exc:
        raise ValueError(f"{path}: {exc.strerror or exc}") from None
    if not users:
        raise ValueError(f"{path}: no user:password line")
    return next(iter(users.items()))


def _rule(rule_id: str, flows: list[str], messages: tuple[str, ...] | list[str], key_exprs: list[str]) -> dict[str, Any]:
    return {"id": rule_id, "permission": "allow", "flows": flows, "messages": list(messages), "key_exprs": key_exprs}


def _under(root: str, keys: tuple[str, ...]) -> list[str]:
    return [f"{root}/{k}" for k in keys]


def _derived(accounts: dict[str, Account], purpose: str) -> str:
    """A secret both routers of a machine derive from its accounts, for `purpose`."""
    key = hashlib.sha256("\n".join(f"{a.name}:{a.role}:{a.password}" for a in sorted(accounts.values(),
                                                                                     key=lambda a: a.name)).encode())
    return hmac.new(key.digest(), purpose.encode(), hashlib.sha256).hexdigest()


def _write_dictionary(logins: dict[str, str]) -> Path:
    """A private (0600) copy of the logins in Zenoh's strict `user:password` format."""
    fd, name = tempfile.mkstemp(prefix=DICTIONARY_PREFIX, suffix=".txt")
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.writelines(f"{user}:{password}\n" for user, password in logins.items())
    return Path(name)


_HOST_PORT = re.compile(r"^(?P<proto>[a-z-]+)/(?P<host>\[[^\]]*\]|[^:/]*):(?P<port>\d+)")


def _loopback(endpoint: str) -> str:
    """`endpoint` moved to the loopback interface (same protocol and port)."""
    m = _HOST_PORT.match(endpoint)
    if m is None or m["proto"] == PRIVATE_PROTOCOL:
        return endpoint
    host = "[::1]" if m["host"].startswith("[") else "127.0.0.1"
    return f"{m['proto']}/{host}:{m['port']}{endpoint[m.end():]}"


def _port(endpoint: str) -> int | None:
    m = _HOST_PORT.match(endpoint)
    return int(m["port"]) if m is not None and m["proto"] == "tcp" else None


def open_machine_router(cfg: MachineConfig, plan: Plan, *, shop: bool = False) -> zenoh.Session:
    """Open the router `plan` describes; the dictionary copy Zenoh read is removed at once."""
    conf = router_config(cfg, plan, shop=shop)
    dictionary = dictionary_file(conf)
    try:
        return zenoh.open(conf)
    finally:
        if dictionary is not None:
            dictionary.unlink(missing_ok=True)
