"""Opening Zenoh sessions the controller way: explicit endpoints, no multicast scouting."""

from __future__ import annotations

import json

import zenoh


def zenoh_config(mode: str, listen: list[str] | None = None, connect: list[str] | None = None) -> zenoh.Config:
    """A session config: `router` listens, `client`/`peer` connect; scouting off (explicit topology)."""
    cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    if listen is not None:
        cfg.insert_json5("listen/endpoints", json.dumps(listen))
    if connect is not None:
        cfg.insert_json5("connect/endpoints", json.dumps(connect))
    return cfg


def connect_endpoints(listen: list[str]) -> list[str]:
    """Where local clients connect to reach a router listening on `listen` (wildcards -> loopback)."""
    out = []
    for ep in listen:
        out.append(ep.replace("0.0.0.0", "127.0.0.1").replace("[::]", "[::1]"))
    return out


def open_client(endpoints: list[str]) -> zenoh.Session:
    return zenoh.open(zenoh_config("client", connect=endpoints))


def open_router(listen: list[str]) -> zenoh.Session:
    return zenoh.open(zenoh_config("router", listen=listen))
