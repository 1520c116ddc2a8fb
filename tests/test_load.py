"""Load: 50 observer sessions subscribed while the machine cuts, and a 1M-line program sent to the
controller and shown by the operator screen's preview model. Behaviour, not timing (the figures
come from bench/load.py): every observer gets the whole status stream and every event of the
cycle, and a million lines are accepted, checked and held whole. The planner's load of a million
lines takes minutes (about 340 s here): bench/load.py loads and previews it, and fails when it
cannot."""

from __future__ import annotations

from typing import Any

import pytest

from cnc.bus.keys import Keys
from cnc.bus.messages import AlarmEvent, CycleStart, Position, ProgramInfo, SetMode, Status, decode, encode
from cnc.bus.operator import OperatorStation
from cnc.bus.session import open_client
from cnc.gateway.door import program_path
from cnc.data.layout import PlannerState
from cnc.logic.states import CyclePhase, MachineState
from cnc.machine_dialect import dialect_for
from gcode.interp import Interpreter
from hmi.model import MachineModel

from .conftest import NEAR_HOME, full_controller, logic, machine_config, press_button_when_asked, reset_and_home

OBSERVERS = 50
MILLION = 1_000_000
MOVES = MILLION - 5  # the other lines: units and feed, the rapid to the start, M3, M5, M2

NEST = """(two parts and a strap)
G21 G90 G17 G64 P0.05 F6000
G0 X100 Y100
M3
G1 X160
G3 X170 Y110 I0 J10
G1 Y160
G1 X100
G1 Y100
M5
G0 X200 Y100
M3
G2 X200 Y100 I20 J0
M5
G0 X250 Y100
M3
""" + "\n".join(f"G1 X{250 + k:.1f} Y{100 + (k % 2) * 0.5:.1f}" for k in range(1, 81)) + """
M5
G0 X60 Y60
M2
"""


def raster(k: int) -> tuple[float, float]:
    """The k-th point of a raster of 0.5 mm steps, 1000 to a row."""
    return 100 + (k % 1000) * 0.5, 100 + (k // 1000) * 0.5


def million_lines() -> str:
    """A program of 1M lines (21 MB): plain G1 moves along the raster, one jet contour."""
    moves = (f"G1 X{x:.1f} Y{y:.1f}" for x, y in map(raster, range(1, MOVES + 1)))
    return "\n".join(["G21 G90 G17 F6000", "G0 X100 Y100", "M3", *moves, "M5", "M2"]) + "\n"


class Observer:
    """One observer: its own client session subscribed, as an operator screen is, to the status,
    the position stream and the alarm and message events; keeps what it received."""

    def __init__(self, endpoint: str, keys: Keys) -> None:
        self.session = open_client([endpoint])
        self.status_seqs: list[int] = []
        self.alarm_seqs: list[int] = []
        self.positions = 0
        self.subs = [
            self.session.declare_subscriber(keys.status, self._on_status),
            self.session.declare_subscriber(keys.position, self._on_position),
            self.session.declare_subscriber(keys.event_alarm, self._on_alarm),
        ]

    def _on_status(self, sample: Any) -> None:
        self.status_seqs.append(_decode(sample, Status).seq)

    def _on_position(self, sample: Any) -> None:
        _decode(sample, Position)
        self.positions += 1

    def _on_alarm(self, sample: Any) -> None:
        self.alarm_seqs.append(_decode(sample, AlarmEvent).seq)

    def close(self) -> None:
        for sub in self.subs:
            sub.undeclare()
        self.session.close()


def _decode(sample: Any, kind: type) -> Any:
    return decode(sample.payload.to_bytes(), kind)


def program_info(session: Any, keys: Keys) -> ProgramInfo:
    replies = list(session.get(f"{keys.program}?path=1", timeout=30.0))
    assert replies and replies[0].ok is not None, "the gateway did not answer the program query"
    return decode(replies[0].ok.payload.to_bytes(), ProgramInfo)


@pytest.fixture
def controller(tmp_path):
    with full_controller(machine_config(**NEAR_HOME), tmp_path / "history.sqlite") as sup:
        yield sup


def test_fifty_observers_get_every_status_and_event_of_a_cycle_while_a_million_line_upload_is_checked(controller):
    sup = controller
    endpoint = sup.config.zenoh.listen[0]
    observers = [Observer(endpoint, sup.keys) for _ in range(OBSERVERS)]
    sup.wait_until(lambda: all(o.status_seqs for o in observers), 30.0, "every observer's first status")
    first_event = logic(sup)["alarm_seq"]
    session = open_client([endpoint])
    op = OperatorStation(session, sup.keys, "op", timeout_s=120.0)
    try:
        assert op.take_lock().ok
        reset_and_home(sup, op.request)
        sup.wait_until(lambda: logic(sup)["state"] == MachineState.READY and sup.motion()["state"] == PlannerState.IDLE,
                       60.0, "homing")
        assert op.upload("nest.ngc", NEST).ok
        running = program_info(session, sup.keys)
        assert op.request(SetMode("AUTO")).ok and op.request(CycleStart(cycles=1)).ok
        press_button_when_asked(sup, lambda: logic(sup)["phase"] == CyclePhase.CUTTING, 60.0, "the cut")
        sup.pause_virtual_clock()  # the cut stands still in mid-program while the upload is checked
        big = op.upload("million.ngc", million_lines())
        assert not big.ok and "cannot load a program while cutting" in big.reason, big.reason
        assert program_info(session, sup.keys).path == running.path, "the running program's preview is still served"
        sup.poll()  # the supervisor sees the pause before the clock runs again: a beat stopped this long is no hang
        sup.resume_virtual_clock()
        press_button_when_asked(sup, lambda: logic(sup)["phase"] == CyclePhase.NONE and logic(sup)["cycles_done"] == 1,
                                60.0, "the end of the cycle")
        last_event = logic(sup)["alarm_seq"]
        sup.wait_until(lambda: all(max(o.alarm_seqs, default=0) >= last_event for o in observers), 10.0,
                       "the cycle's last event at every observer")
    finally:
        op.close()
        session.close()
        for o in observers:
            o.close()
    events = set(range(first_event + 1, last_event + 1))
    assert len(events) >= 3, "the cycle raised its prompts and messages"
    for k, o in enumerate(observers):
        assert events <= set(o.alarm_seqs), f"observer {k} missed events {sorted(events - set(o.alarm_seqs))}"
        seqs = o.status_seqs
        assert len(seqs) >= 20 and seqs == list(range(seqs[0], seqs[0] + len(seqs))), f"observer {k}: status gaps"
        assert o.positions > 0


@pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)
def test_the_preview_model_holds_every_segment_of_a_million_line_program(machine):
    """The path the gateway serves for a 1M-line program (its interpreter's result, as `program?path=1`
    sends it), encoded and decoded as on the bus, is held whole by the operator screen's model."""
    text = million_lines()
    program = Interpreter(dialect_for(machine), "million.ngc").run(text.encode())
    info = ProgramInfo("million.ngc", "h", len(text), text.count("\n"), 0.0, text=text, path=program_path(program))
    model = MachineModel("screen")
    model.apply_program(decode(encode(info), ProgramInfo))
    assert text.count("\n") == MILLION
    assert model.program.segments == MOVES + 1  # every G1 and the rapid
    assert (model.program.path.end_x[-1], model.program.path.end_y[-1]) == pytest.approx(raster(MOVES))
