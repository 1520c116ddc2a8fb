"""Opening Zenoh sessions the controller way: explicit endpoints, no multicast scouting."""

from __future__ import annotations

import json

import zenoh

from ..config import MachineConfig


# How long a silent link lasts before the other end declares this session gone (Zenoh's lease,
# with a keep-alive every quarter of it). Zenoh's default is 10 s: a cut cable left the operator's
# station "alive", and the cut running without it, that long. Every session of ours announces this.
LEASE_S = 3.0


def zenoh_config(
    mode: str,
    listen: list[str] | None = None,
    connect: list[str] | None = None,
    credentials: tuple[str, str] | None = None,
    lease_s: float = LEASE_S,
) -> zenoh.Config:
    """A session config: `router` listens, `client`/`peer` connect; scouting off (explicit
    topology). `credentials` (user, password) authenticate it to a router with access control.
    `lease_s`: how soon the other end notices that this session went silent."""
    cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("transport/link/tx/lease", json.dumps(round(lease_s * 1000)))
    cfg.insert_json5("transport/link/tx/keep_alive", "4")
    if listen is not None:
        cfg.insert_json5("listen/endpoints", json.dumps(listen))
    if connect is not None:
        cfg.insert_json5("connect/endpoints", json.dumps(connect))
    if credentials is not None:
        user, password = credentials
        cfg.insert_json5("transport/auth/usrpwd", json.dumps({"user": user, "password": password}))
    return cfg


def connect_endpoints(listen: list[str]) -> list[str]:
    """Where local clients connect to reach a router listening on `listen` (wildcards -> loopback)."""
    out = []
    for ep in listen:
        out.append(ep.replace("0.0.0.0", "127.0.0.1").replace("[::]", "[::1]"))
    return out


def open_client(endpoints: list[str], credentials: tuple[str, str] | None = None) -> zenoh.Session:
    """A client session on `endpoints`; with access control on, pass (user, password)
    (`cnc.bus.access.controller_credentials` for the controller's own processes)."""
    return zenoh.open(zenoh_config("client", connect=endpoints, credentials=credentials))


def open_router(
    listen: list[str] | MachineConfig, connect: list[str] | None = None, *, shop: bool = False
) -> zenoh.Session:
    """A router session. Given endpoints, a plain router listening there (and connecting to
    `connect`). Given a machine config, the router its `[zenoh]` table describes, with
    authentication and access control when `[zenoh.access] enabled` (`shop`: the machine's
    shop router, see `cnc.bus.access.router_config`)."""
    if not isinstance(listen, MachineConfig):
        return zenoh.open(zenoh_config("router", listen=listen, connect=connect))
    from .access import dictionary_file, router_config  # access builds on zenoh_config above

    conf = router_config(listen, shop=shop)
    dictionary = dictionary_file(conf)
    try:
        return zenoh.open(conf)
    finally:
        # Zenoh has read the user/password dictionary while opening; the copy is not left behind.
        if dictionary is not None:
            dictionary.unlink(missing_ok=True)
