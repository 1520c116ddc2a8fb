"""Zenoh authentication and access control from `[zenoh.access]`: who may do what on the router.

When `[zenoh.access] enabled`, every session authenticates with user/password (Zenoh's `usrpwd`
extension: a session that offers no credentials, or wrong ones, is refused while the link is
being established) and the router applies access-control rules per message kind, direction and
key expression. Everything is denied unless a rule allows it:

- the controller user may do everything;
- observers may subscribe to status, position, events, the procedure and the lock, query the
  alarms, the job history, the loaded program, the lock, the procedure catalogue and the control
  parameters (changing one needs the command lock, which only an operator can take), and declare liveliness tokens and liveliness subscribers
  under `alive/**` and `hmi/**`;
- operators may do what observers may, plus query `cmd/**` and put/query `program/**`.

Zenoh's rules name both directions of a message as seen from the router: `ingress` is what a
session sends in (its declarations, puts, queries), `egress` is what the router sends out to it
(samples, replies, liveliness tokens). Observers therefore get `declare_subscriber` in and `put`
out on the keys they may watch, and `query` in and `reply` out on the keys they may ask.

Router-to-router links. Zenoh's user/password handshake authenticates the side that *opens* a
link to the side that accepts it, not the other way round: a router that `connect`s to a shop
router (`waterjet router --machine M`) knows the shop router only by its Zenoh ID. So the shop
router of a machine runs under an ID derived from the controller user's password
(`shop_router_zid`), and the controller's router grants that ID what any operator station may
do, plus announcing the controller's own declarations (the shop router filters its stations
with the same rules). A Zenoh ID is an identifier, not a proof; without TLS the whole scheme
protects against unauthorised stations on an honest network, not against someone who can read
the traffic.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import tempfile
from pathlib import Path
from typing import Any

import zenoh

from ..config import ConfigError, MachineConfig, credentials_path, read_credentials
from .keys import Keys
from .session import zenoh_config

TABLE = "zenoh.access"

# Every message kind Zenoh 1.x access control knows about.
ALL_MESSAGES = (
    "put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
    "liveliness_token", "declare_liveliness_subscriber", "liveliness_query",
)

# Key groups, relative to the machine root `<prefix>/<machine>`.
WATCH_KEYS = ("status", "position", "event/**", "procedure", "lock", "log/live")  # subscribed to
READ_KEYS = ("alarms/**", "jobs/**", "program", "lock", "procedures", "param/**", "params", "log/**")  # queried
# (changing a parameter is a query too: the gateway requires the command lock for it, which observers cannot
# take; starting and stopping a log run are queries that never move the machine)
ALIVE_KEYS = ("alive/**", "hmi/**")  # liveliness of controller processes and stations
COMMAND_KEYS = ("cmd/**",)  # operators only
UPLOAD_KEYS = ("program/**",)  # operators only

# The file Zenoh reads the user/password dictionary from is a private copy (Zenoh's format
# allows no comments or blank lines); `cnc.bus.session.open_router` removes it once read.
DICTIONARY_PREFIX = "waterjet-usrpwd-"


def router_config(cfg: MachineConfig, *, shop: bool = False) -> zenoh.Config:
    """The config of a router for machine `cfg`: router mode on `[zenoh] listen` and `connect`,
    no multicast scouting, and when `[zenoh.access] enabled` authentication and the rules above.

    `shop=True` builds the shop router of the machine (`waterjet router --machine`): it runs
    under `shop_router_zid(cfg)`, the ID the controller's router trusts on its `connect` links.
    With access enabled the config names a private copy of the dictionary that the caller must
    delete once Zenoh has read it (`open_router` does); see `dictionary_file`."""
    z = cfg.zenoh
    conf = zenoh_config("router", listen=list(z.listen), connect=list(z.connect))
    if not z.access.enabled:
        return conf
    users = _users(cfg)
    controller = z.access.controller_user
    conf.insert_json5(
        "transport/auth/usrpwd",
        json.dumps({"user": controller, "password": users[controller], "dictionary_file": str(_write_dictionary(cfg, users))}),
    )
    if shop:
        conf.insert_json5("id", json.dumps(shop_router_zid(cfg)))
    upstream = shop_router_zid(cfg) if z.connect and not shop else None
    conf.insert_json5("access_control", json.dumps(access_control(cfg, upstream_zid=upstream)))
    return conf


def client_config(endpoints: list[str], credentials: tuple[str, str] | None) -> zenoh.Config:
    """A client session connecting to `endpoints`, authenticating as (user, password) if given."""
    return zenoh_config("client", connect=endpoints, credentials=credentials)


def controller_credentials(cfg: MachineConfig) -> tuple[str, str] | None:
    """(user, password) the controller's own sessions authenticate with; None when access is off."""
    if not cfg.zenoh.access.enabled:
        return None
    user = cfg.zenoh.access.controller_user
    return user, _users(cfg)[user]


def shop_router_zid(cfg: MachineConfig) -> str:
    """The Zenoh ID of the machine's shop router: an HMAC of the machine root under the
    controller user's password, so that both routers derive it and stations cannot guess it."""
    users = _users(cfg)
    root = Keys(cfg.zenoh.key_prefix, cfg.machine.name).root
    digest = hmac.new(users[cfg.zenoh.access.controller_user].encode(), f"waterjet shop router {root}".encode(), hashlib.sha256)
    return "a" + digest.hexdigest()[:31]  # 16 bytes; Zenoh refuses IDs with a leading zero


def access_control(cfg: MachineConfig, upstream_zid: str | None = None) -> dict[str, Any]:
    """The `access_control` section for `cfg` (JSON-ready): default deny, one policy per role.
    `upstream_zid` names a shop router this router connects to (see the module docstring)."""
    a = cfg.zenoh.access
    root = Keys(cfg.zenoh.key_prefix, cfg.machine.name).root
    hmi_keys = WATCH_KEYS + READ_KEYS + ALIVE_KEYS + COMMAND_KEYS + UPLOAD_KEYS
    rules = [
        _rule("everything", ["ingress", "egress"], ALL_MESSAGES, ["**"]),
        _rule("watch in", ["ingress"], ["declare_subscriber"], _under(root, WATCH_KEYS)),
        _rule("watch out", ["egress"], ["put"], _under(root, WATCH_KEYS)),
        _rule("read in", ["ingress"], ["query"], _under(root, READ_KEYS)),
        _rule("read out", ["egress"], ["reply"], _under(root, READ_KEYS)),
        _rule(
            "alive in", ["ingress"], ["liveliness_token", "declare_liveliness_subscriber", "liveliness_query"],
            _under(root, ALIVE_KEYS),
        ),
        _rule("alive out", ["egress"], ["liveliness_token", "reply"], _under(root, ALIVE_KEYS)),
        _rule("command in", ["ingress"], ["query"], _under(root, COMMAND_KEYS)),
        _rule("command out", ["egress"], ["reply"], _under(root, COMMAND_KEYS)),
        _rule("upload in", ["ingress"], ["put", "query"], _under(root, UPLOAD_KEYS)),
        _rule("upload out", ["egress"], ["reply"], _under(root, UPLOAD_KEYS)),
    ]
    observe = ["watch in", "watch out", "read in", "read out", "alive in", "alive out"]
    operate = ["command in", "command out", "upload in", "upload out"]
    subjects = [{"id": "controller", "usernames": [a.controller_user]}, {"id": "operators", "usernames": list(a.operators)}]
    policies = [
        {"id": "controller", "rules": ["everything"], "subjects": ["controller"]},
        {"id": "operators", "rules": observe + operate, "subjects": ["operators"]},
    ]
    if a.observers:  # a subject with no usernames is a Cartesian product with nothing in it
        subjects.append({"id": "observers", "usernames": list(a.observers)})
        policies.append({"id": "observers", "rules": observe, "subjects": ["observers"]})
    if upstream_zid is not None:
        rules.append(_rule("announce out", ["egress"], ALL_MESSAGES, _under(root, hmi_keys)))
        subjects.append({"id": "shop router", "zids": [upstream_zid]})
        policies.append({"id": "shop router", "rules": observe + operate + ["announce out"], "subjects": ["shop router"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def dictionary_file(conf: zenoh.Config) -> Path | None:
    """The private dictionary copy a `router_config` names, or None (access off, or not ours)."""
    raw = json.loads(conf.get_json("transport/auth/usrpwd/dictionary_file"))
    if raw is None or not Path(raw).name.startswith(DICTIONARY_PREFIX):
        return None
    return Path(raw)


def _rule(rule_id: str, flows: list[str], messages: tuple[str, ...] | list[str], key_exprs: list[str]) -> dict[str, Any]:
    return {"id": rule_id, "permission": "allow", "flows": flows, "messages": list(messages), "key_exprs": key_exprs}


def _under(root: str, keys: tuple[str, ...]) -> list[str]:
    return [f"{root}/{k}" for k in keys]


def _users(cfg: MachineConfig) -> dict[str, str]:
    """The credentials file's users; errors name `[zenoh.access]` and the key at fault."""
    a = cfg.zenoh.access
    if not a.credentials_file:
        raise ConfigError(cfg.source, TABLE, "credentials_file", "access control needs a credentials file (user:password lines)")
    path = credentials_path(cfg)
    try:
        users = read_credentials(path)
    except OSError as exc:
        raise ConfigError(cfg.source, TABLE, "credentials_file", f"{path}: {exc.strerror}") from None
    except ValueError as exc:
        raise ConfigError(cfg.source, TABLE, "credentials_file", str(exc)) from None
    for key, names in (("controller_user", [a.controller_user]), ("operators", a.operators), ("observers", a.observers)):
        missing = [u for u in names if u not in users]
        if missing:
            raise ConfigError(cfg.source, TABLE, key, f"{', '.join(missing)}: not in {path}")
    return users


def _write_dictionary(cfg: MachineConfig, users: dict[str, str]) -> Path:
    """A private (0600) copy of the users the rules name, in Zenoh's strict `user:password` format."""
    a = cfg.zenoh.access
    named = dict.fromkeys([a.controller_user, *a.operators, *a.observers])
    fd, name = tempfile.mkstemp(prefix=DICTIONARY_PREFIX, suffix=".txt")
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.writelines(f"{user}:{users[user]}\n" for user in named)
    return Path(name)


def station_login(path: str | Path) -> tuple[str, str]:
    """The (user, password) an observer or operator station logs in with: the first user:password
    line of its credentials file. ValueError names the file and what is wrong."""
    try:
        users = read_credentials(Path(path))  # its ValueError names the file and the line
    except OSError as exc:
        raise ValueError(f"{path}: {exc.strerror or exc}") from None
    if not users:
        raise ValueError(f"{path}: no user:password line")
    return next(iter(users.items()))
