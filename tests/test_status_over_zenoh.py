"""The gateway publishes the status on Zenoh; a separate process receives it; every process is alive on the bus."""

from __future__ import annotations

import multiprocessing
import threading

import pytest

from cnc.bus.keys import Keys
from cnc.bus.messages import SchemaVersionError, Status, decode, encode
from cnc.bus.session import open_client

from .conftest import enable_and_hold


def _subscribe(endpoint: str, key: str, n: int, out) -> None:
    """Runs in its own process: collect n status messages and send them back as dicts."""
    got, done = [], threading.Event()

    def on_sample(sample):
        got.append((str(sample.encoding), sample.payload.to_bytes()))
        if len(got) >= n:
            done.set()

    session = open_client([endpoint])
    sub = session.declare_subscriber(key, on_sample)
    done.wait(30.0)
    sub.undeclare()
    session.close()
    out.put(got[:n])


def test_a_separate_process_receives_the_status_over_zenoh(virtual_controller):
    sup = virtual_controller
    held = enable_and_hold(sup)
    ctx = multiprocessing.get_context("spawn")
    out = ctx.Queue()
    p = ctx.Process(target=_subscribe, args=(sup.runtime.zenoh_connect[0], sup.keys.status, 3, out))
    p.start()
    samples = out.get(timeout=60)
    p.join(10)
    assert p.exitcode == 0 and len(samples) == 3
    statuses = [decode(payload, Status) for _, payload in samples]
    assert all(enc.startswith("application/json") for enc, _ in samples)
    assert [s.seq for s in statuses] == sorted({s.seq for s in statuses})
    assert statuses[-1].tick > statuses[0].tick, "the tick counter advances between messages"
    last = statuses[-1]
    assert last.machine == "waterjet" and last.clock == "virtual" and last.version == 1
    assert [a.name for a in last.axes] == ["x", "y"]
    assert last.servo_state == "HOLDING" and last.fault == "NONE" and not last.watchdog_tripped
    assert all(abs(a.position_mm - h) < 0.01 for a, h in zip(last.axes, held))
    assert last.estop_ok and all(a.drive_enabled for a in last.axes)


def test_every_controller_process_declares_a_liveliness_token(virtual_controller):
    sup = virtual_controller
    session = open_client(sup.runtime.zenoh_connect)
    try:
        alive = {str(r.ok.key_expr).rsplit("/", 1)[-1] for r in session.liveliness().get(sup.keys.alive_all) if r.ok}
    finally:
        session.close()
    assert {"supervisor", "hardware", "servo", "gateway"} <= alive


def test_a_status_of_an_unknown_schema_version_is_refused_clearly():
    good = encode(_example_status())
    assert decode(good, Status).version == 1
    with pytest.raises(SchemaVersionError, match="version 2 is not the supported version 1"):
        decode(good.replace(b'"version":1', b'"version":2'), Status)
    with pytest.raises(SchemaVersionError, match="version None"):
        decode(b'{"machine": "m"}', Status)


def _example_status() -> Status:
    return Status(
        machine="m", seq=1, stamp_ns=0, tick=0, clock="virtual", servo_state="HOLDING", fault="NONE", fault_axis="",
        watchdog_tripped=False, safe_state=False, estop_ok=True, doors_closed=True, jet_on=False, axes=[],
        overruns=0, underruns=0, late_ticks=0, servo_missed_ticks=0, fifo_fill=0,
    )


def test_keys_live_under_prefix_and_machine():
    k = Keys("wj", "cell3")
    assert (k.status, k.position, k.alive("servo"), k.alive_all) == (
        "wj/cell3/status", "wj/cell3/position", "wj/cell3/alive/servo", "wj/cell3/alive/**",
    )
