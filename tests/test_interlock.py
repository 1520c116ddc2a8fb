"""The stop-cut interlocks the servo evaluates every tick (`cnc.interlock`), without processes."""

from __future__ import annotations

import os
import subprocess

from cnc.data.dataserver import BlockLayout
from cnc.hw.board import DigitalIn
from cnc.interlock import CATEGORY_0, Interlock, StopCause, fault_of, process_gone
from cnc.data.layout import LinkState, Proc, ServoFault, command_layout, plc_layout

from .conftest import machine_config

ALL_OK = int(DigitalIn.ESTOP_OK | DigitalIn.DOORS_CLOSED | DigitalIn.MAINS_ON)
MS = 1_000_000
MEMBERS = 1 << Proc.LOGIC | 1 << Proc.PLC_LINK


class Images:
    """The commander's and the PLC link's blocks as flat value lists, edited by name."""

    def __init__(self, config) -> None:
        self.cmd_layout, self.plc_layout = command_layout(2), plc_layout()
        self.cmd, self.plc = self.cmd_layout.defaults(), self.plc_layout.defaults()
        self.inputs = {v.id: k for k, v in enumerate(config.plc.inputs())}
        self.set_cmd(token=7, heartbeat=1)
        self.set_plc(state=int(LinkState.OK), input_seq=1)
        self.set_input(safety_circuit_ok=1, barrier_front_ok=1, barrier_rear_ok=1, pump_fault=0, pump_pressure=3800.0)

    def _set(self, layout: BlockLayout, values: list, fields: dict) -> None:
        for name, value in fields.items():
            values[layout.index[name]] = value

    def set_cmd(self, **fields) -> None:
        self._set(self.cmd_layout, self.cmd, fields)

    def set_plc(self, **fields) -> None:
        self._set(self.plc_layout, self.plc, fields)

    def set_input(self, **values) -> None:
        i = self.plc_layout.index["inputs"]
        for name, value in values.items():
            self.plc[i.start + self.inputs[name]] = value

    def evaluate(self, il: Interlock, tick: int, din: int = ALL_OK, jet: bool = False, wall_ns: int | None = None) -> int:
        """One tick's causes, the wall clock a millisecond a tick unless given."""
        return il.evaluate(tick, tick * MS if wall_ns is None else wall_ns, din, tuple(self.plc), self.plc_layout.index,
                           tuple(self.cmd), self.cmd_layout.index, jet)


def setup(members: int = MEMBERS):
    config = machine_config()
    return Interlock(config, members), Images(config)


def test_the_boards_inputs_are_always_watched_and_e_stop_and_mains_are_category_0():
    il, img = setup(members=0)
    assert img.evaluate(il, 1) == 0
    assert img.evaluate(il, 2, din=ALL_OK & ~DigitalIn.DOORS_CLOSED) == StopCause.DOORS
    causes = img.evaluate(il, 3, din=0)
    assert causes == StopCause.ESTOP | StopCause.MAINS | StopCause.DOORS
    assert causes & CATEGORY_0 and fault_of(causes) == ServoFault.ESTOP
    assert fault_of(StopCause.DOORS | StopCause.PLC_LINK) == ServoFault.DOORS


def test_a_commander_that_stops_beating_is_a_cause_after_its_timeout_and_a_new_commander_starts_afresh():
    il, img = setup()
    for tick in range(1, 101):  # 100 ms of silence: the limit, not yet past it
        assert not img.evaluate(il, tick) & StopCause.COMMANDER
    assert img.evaluate(il, 102) & StopCause.COMMANDER
    img.set_cmd(heartbeat=2)
    assert not img.evaluate(il, 103) & StopCause.COMMANDER, "a beat clears it"
    img.set_cmd(token=8, heartbeat=0)
    for tick in range(104, 200):
        assert not img.evaluate(il, tick) & StopCause.COMMANDER, "a new commander has its own grace"


def test_overdue_means_both_clocks_have_run_past_the_limit():
    """On the virtual clock ticks outrun the wall: a sign of life is overdue only when both agree."""
    il, img = setup()
    img.evaluate(il, 1)
    assert not img.evaluate(il, 5000, wall_ns=50 * MS) & StopCause.COMMANDER, "5000 ticks but 50 ms of wall time"
    assert img.evaluate(il, 5001, wall_ns=150 * MS) & StopCause.COMMANDER


def test_plc_inputs_count_only_while_the_link_delivers_them():
    il, img = setup()
    plc = machine_config().plc
    plc_limit = round((plc.lost_after_cycles + 1) * max(plc.cycle_ms, plc.timeout_ms))  # ticks of 1 ms
    assert img.evaluate(il, 1) == 0
    for tick in range(2, plc_limit + 1):
        img.set_cmd(heartbeat=tick)
        assert not img.evaluate(il, tick) & StopCause.PLC_LINK, "an OK image that stopped changing: not yet stale"
    img.set_cmd(heartbeat=plc_limit + 5)
    assert img.evaluate(il, plc_limit + 5) == StopCause.PLC_LINK, "a hung link process: stale, and nothing else trusted"
    img.set_plc(input_seq=2)
    img.set_input(safety_circuit_ok=0)
    assert img.evaluate(il, plc_limit + 6) == StopCause.SAFETY_CIRCUIT
    img.set_plc(state=int(LinkState.LOST))
    assert img.evaluate(il, plc_limit + 7) == StopCause.PLC_LINK


def test_barriers_matter_only_while_armed_and_the_pump_floor_only_with_the_jet_open():
    il, img = setup()
    img.set_input(barrier_rear_ok=0)
    assert img.evaluate(il, 1) == 0, "not armed: outside the automatic cycle"
    img.set_cmd(arm=int(StopCause.BARRIER))
    assert img.evaluate(il, 2) == StopCause.BARRIER
    img.set_input(barrier_rear_ok=1, pump_pressure=900.0)
    img.set_cmd(pressure_floor_bar=3200.0)
    assert img.evaluate(il, 3) == 0, "below the floor with the jet closed: nothing"
    assert img.evaluate(il, 4, jet=True) == StopCause.PUMP
    assert il.pressure_bar == 900.0, "the reading a PUMP trip reports"
    img.set_input(pump_pressure=3800.0, pump_fault=1)
    assert img.evaluate(il, 5) == StopCause.PUMP, "the pump's own fault counts whatever the jet"


def test_without_a_plc_link_or_a_control_logic_their_causes_are_not_watched():
    il, img = setup(members=0)
    img.set_plc(state=int(LinkState.DOWN))
    for tick in range(1, 2000, 50):
        assert img.evaluate(il, tick) == 0


def test_a_dead_writer_is_a_block_stuck_mid_write_longer_than_a_tick_whose_process_has_ended():
    il, _ = setup()
    gone = subprocess.Popen(["true"])
    gone.wait()
    assert process_gone(gone.pid) and not process_gone(os.getpid())
    assert il.dead_writer(1_000, 1_000 + 2 * MS, gone.pid)
    assert not il.dead_writer(1_000, 1_000 + 2 * MS, os.getpid()), "alive: preempted mid-write, not dead"
    assert not il.dead_writer(1_000, 1_000 + MS // 2, gone.pid), "within one period: not yet"
    assert not il.dead_writer(0, 10 * MS, gone.pid), "not stuck at all"
