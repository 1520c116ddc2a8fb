"""Opening Zenoh sessions the controller way: explicit endpoints, no multicast scouting."""

from __future__ import annotations

import json
import os
import re
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import zenoh

if TYPE_CHECKING:
    from .certs import TlsFiles



# How long a silent link lasts before the other end declares this session gone (Zenoh's lease,
# with a keep-alive every quarter of it). Zenoh's default is 10 s: a cut cable left the operator's
# station "alive", and the cut running without it, that long. Every session of ours announces this.
LEASE_S = 3.0

# A station on the controller's own host: its account needs no set-up (`cnc.bus.access`).
LOCAL_USER = "local"
_LOOPBACK = re.compile(r"^tcp/(127\.0\.0\.1|localhost|\[::1\]):(\d+)$")


def zenoh_config(
    mode: str,
    listen: list[str] | None = None,
    connect: list[str] | None = None,
    credentials: tuple[str, str] | None = None,
    lease_s: float = LEASE_S,
    tls: "TlsFiles | None" = None,
) -> zenoh.Config:
    """A session config: `router` listens, `client`/`peer` connect; scouting off (explicit
    topology). `credentials` (user, password) authenticate it to a router with access control.
    `lease_s`: how soon the other end notices that this session went silent."""
    cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    if mode in ("router", "peer"):
        # Zenoh sleeps this long at open "to scout for peers first" (500 ms by default), though with
        # multicast off there is nothing to scout: its `connect` endpoints are dialled in the
        # background either way. Every controller start (and restart) paid the half second.
        cfg.insert_json5("scouting/delay", "0")
    cfg.insert_json5("transport/link/tx/lease", json.dumps(round(lease_s * 1000)))
    cfg.insert_json5("transport/link/tx/keep_alive", "4")
    # Zenoh's shared-memory transport leaves a file per process in /dev/shm; ours is on its own
    cfg.insert_json5("transport/shared_memory/enabled", "false")
    if listen is not None:
        cfg.insert_json5("listen/endpoints", json.dumps(listen))
    if connect is not None:
        cfg.insert_json5("connect/endpoints", json.dumps(connect))
    if credentials is not None:
        user, password = credentials
        cfg.insert_json5("transport/auth/usrpwd", json.dumps({"user": user, "password": password}))
    if tls is not None:  # tls/ endpoints: check the other side against the machine's CA, show our own pair
        link = {"root_ca_certificate": str(tls.ca), "connect_certificate": str(tls.certificate),
                "connect_private_key": str(tls.key), "enable_mtls": True}  # mutual: both sides show a certificate
        if mode == "router":  # and a router asks every station for one the CA signed
            link.update(listen_certificate=str(tls.certificate), listen_private_key=str(tls.key))
        cfg.insert_json5("transport/link/tls", json.dumps(link))
    return cfg


def connect_endpoints(listen: list[str]) -> list[str]:
    """Where a client on this host connects to reach a router listening on `listen` (wildcards ->
    loopback). Where it listens on plain TCP as well as TLS, the TCP endpoints only: on this
    host's loopback they need no station certificate, and the local station's login applies there."""
    local = [ep.replace("0.0.0.0", "127.0.0.1").replace("[::]", "[::1]") for ep in listen]
    tcp = [ep for ep in local if ep.startswith("tcp/")]
    return tcp or local


def local_login_path(port: int) -> Path:
    """Where the controller listening on loopback port `port` writes the login of a station on its
    own host (`cnc.bus.access.write_local_login`), in its account's private run directory."""
    base = Path(os.environ.get("WATERJET_RUN_DIR") or Path(tempfile.gettempdir()) / f"waterjet-{os.getuid()}")
    return base / f"local-{port}.login"


def local_login(endpoints: list[str]) -> tuple[str, str] | None:
    """The login of a station on the controller's own host, when every endpoint is on this host's
    loopback and that controller wrote one (it has accounts); None otherwise."""
    ports = {m.group(2) for m in (_LOOPBACK.match(ep) for ep in endpoints) if m is not None}
    if len(ports) != 1 or len(endpoints) != sum(1 for ep in endpoints if _LOOPBACK.match(ep)):
        return None
    try:
        user, _, password = local_login_path(int(ports.pop())).read_text(encoding="utf-8").strip().partition(":")
    except OSError:
        return None
    return (user, password) if user and password else None


def open_client(endpoints: list[str], credentials: tuple[str, str] | None = None,
                tls: "TlsFiles | None" = None) -> zenoh.Session:
    """A client session on `endpoints`; with accounts on, pass (user, password), and for `tls/`
    endpoints the station's TLS files (`cnc.bus.certs`). Without credentials, a session to a
    controller on this host logs in with the local station's login when there is one."""
    if credentials is None:
        credentials = local_login(endpoints)
    return zenoh.open(zenoh_config("client", connect=endpoints, credentials=credentials, tls=tls))


def open_router(listen: list[str], connect: list[str] | None = None) -> zenoh.Session:
    """A plain router listening on `listen` (and connecting to `connect`): no accounts, no rules.
    The controller's and a machine's shop router: `cnc.bus.access.open_machine_router`."""
    return zenoh.open(zenoh_config("router", listen=listen, connect=connect))
