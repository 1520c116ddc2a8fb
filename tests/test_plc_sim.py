"""The PLC simulator: its Modbus RTU server on a real pty, its plant model, its child process."""

from __future__ import annotations

import dataclasses
import os
import select
import termios
import time
import tty

import pytest

from cnc.config import load_machine
from plc_link import rtu
from plc_link.pty_pair import PtyPair
from plc_link.sim_model import ModelError, PlantTimes, PlcAlarm, PlcModel, TransportStep
from plc_link.sim_server import PlcSimServer, start_simulator_process
from tests.conftest import MACHINE_FILE

PLC = load_machine(MACHINE_FILE).plc
FAST = PlantTimes(feed_s=0.3, gripper_s=0.1, unload_s=0.3, pneumatic_s=0.05, button_s=0.2)


@pytest.fixture
def line():
    """A simulator serving on a pty, and a raw fd on the other end to talk frames to it."""
    with PtyPair() as pair:
        model = PlcModel(PLC, FAST)
        server = PlcSimServer(PLC, model, pair.server_fd)
        server.start()
        fd = os.open(pair.device, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(fd, termios.TCSANOW)
        try:
            yield fd, model, server
        finally:
            os.close(fd)
            server.stop()
            assert server.error is None


def transact(fd: int, pdu: bytes, unit: int = 1, expect: int | None = None, wait_s: float = 0.2) -> bytes:
    """Send one framed request; return the raw answer (b"" when none came within wait_s)."""
    os.write(fd, rtu.with_crc(bytes((unit,)) + pdu))
    got, deadline = b"", time.monotonic() + wait_s
    while time.monotonic() < deadline and (expect is None or len(got) < expect):
        if select.select([fd], [], [], 0.01)[0]:
            got += os.read(fd, 256)
        elif got and expect is None:
            break
    return got


def u16(*values: int) -> bytes:
    return b"".join(v.to_bytes(2, "big") for v in values)


def wait_for(cond, timeout_s: float = 30.0) -> bool:
    """Until `cond()`; the limit only says when to give up (a busy host never reaches it)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.005)
    return False


# -- the server --------------------------------------------------------------------------


def test_reads_discrete_inputs_as_the_model_publishes_them(line):
    fd, model, _ = line
    assert wait_for(lambda: model.input("pneumatic_ready") == 1.0)
    answer = transact(fd, bytes((2,)) + u16(0, 16), expect=7)
    assert rtu.crc_ok(answer) and answer[:3] == bytes((1, 2, 2))
    bits = int.from_bytes(answer[3:5], "little")
    ins = model.inputs()
    for address, var_id in enumerate(("plc_running", "mains_on", "safety_circuit_ok", "pneumatic_supply_on", "pneumatic_ready")):
        assert (bits >> address) & 1 == int(ins[var_id]), var_id
    assert bits & 1 << 11 == 0  # material_in_place: nothing fed yet


def test_writes_registers_and_coils_and_reads_them_back(line):
    fd, model, _ = line
    assert transact(fd, bytes((16,)) + u16(0, 2) + bytes((4,)) + u16(3000, 7), expect=8)[:6] == bytes((1, 16)) + u16(0, 2)
    assert model.outputs()["pump_pressure_set"] == pytest.approx(300.0)
    assert model.outputs()["cnc_heartbeat"] == 7
    assert transact(fd, bytes((3,)) + u16(0, 2), expect=9)[2:7] == bytes((4,)) + u16(3000, 7)
    assert transact(fd, bytes((15,)) + u16(0, 6) + bytes((1, 0b001000)), expect=8)[1] == 15
    assert model.outputs()["pump_on"] == 1.0 and model.outputs()["feed_material"] == 0.0
    assert transact(fd, bytes((5,)) + u16(3, 0x0000), expect=8)[1] == 5
    assert model.outputs()["pump_on"] == 0.0
    assert transact(fd, bytes((6,)) + u16(1, 8), expect=8)[1] == 6
    assert model.outputs()["cnc_heartbeat"] == 8
    assert transact(fd, bytes((1,)) + u16(0, 6), expect=6)[2:4] == bytes((1, 0))


def test_answers_input_registers_scaled_like_the_map(line):
    fd, model, _ = line
    model.set_output("pump_on", 1.0)
    model.set_output("pump_pressure_set", 120.0)
    assert wait_for(lambda: model.input("pump_pressure") == pytest.approx(120.0))
    answer = transact(fd, bytes((4,)) + u16(0, 4), expect=13)
    assert int.from_bytes(answer[3:5], "big") == 1200  # 0.1 bar per count


@pytest.mark.parametrize(
    "pdu, code",
    [
        (bytes((7,)), rtu.ILLEGAL_FUNCTION),  # read exception status: not served
        (bytes((2,)) + u16(10, 8), rtu.ILLEGAL_DATA_ADDRESS),  # 10..17: past the last discrete input
        (bytes((4,)) + u16(0, 200), rtu.ILLEGAL_DATA_VALUE),  # more than 125 registers
        (bytes((2,)) + u16(0, 0), rtu.ILLEGAL_DATA_VALUE),
        (bytes((5,)) + u16(0, 0x1234), rtu.ILLEGAL_DATA_VALUE),  # a coil is 0xFF00 or 0x0000
        (bytes((16,)) + u16(0, 2) + bytes((3,)) + bytes(3), rtu.ILLEGAL_DATA_VALUE),  # byte count
        (bytes((6,)) + u16(9, 1), rtu.ILLEGAL_DATA_ADDRESS),
    ],
)
def test_answers_bad_requests_with_exception_responses(line, pdu, code):
    fd, _, server = line
    answer = transact(fd, pdu, expect=5)
    assert rtu.crc_ok(answer) and answer[1] == pdu[0] | 0x80 and answer[2] == code
    assert server.stats.exceptions == 1


def test_ignores_other_units_and_drops_bad_crc(line):
    fd, _, server = line
    assert transact(fd, bytes((2,)) + u16(0, 16), unit=7, wait_s=0.1) == b""
    os.write(fd, bytes((1, 2)) + u16(0, 16) + b"\x00\x00")  # wrong CRC
    assert wait_for(lambda: server.stats.crc_errors == 1)
    assert server.stats.other_unit == 1 and server.stats.responses == 0
    assert len(transact(fd, bytes((2,)) + u16(0, 16), expect=7)) == 7  # and still serves


def test_answers_no_earlier_than_the_line_would_carry_it(line):
    fd, _, _ = line
    char_s = rtu.char_time_s(PLC.baud, PLC.parity, PLC.stop_bits)
    t0 = time.perf_counter()
    answer = transact(fd, bytes((4,)) + u16(0, 4), expect=13)
    elapsed = time.perf_counter() - t0
    assert len(answer) == 13
    assert elapsed >= (8 + rtu.SILENCE_CHARS + 13) * char_s  # request, silence, response: 14 ms


def test_link_dead_fault_stops_the_answers(line):
    fd, model, _ = line
    model.inject("link_dead", True)
    assert transact(fd, bytes((2,)) + u16(0, 16), wait_s=0.1) == b""
    model.inject("link_dead", False)
    assert len(transact(fd, bytes((2,)) + u16(0, 16), expect=7)) == 7


def test_a_server_held_off_its_loop_counts_and_says_the_stall(line, caplog):
    """A PLC has a CPU of its own; the simulator shares the host's. When the host holds it off
    (here: one model step that takes 0.25 s), the answers due meanwhile go late and a master
    may count them missing: the simulator says so, so that a lost link in a test log tells a
    host that did not run the simulator from a line or a master that failed."""
    fd, model, server = line
    slow = {"once": True}
    step = model.step

    def held_off(now_s: float) -> None:
        if slow.pop("once", False):
            time.sleep(0.25)
        step(now_s)
    model.step = held_off
    said = lambda: any("PLC simulator: its server ran" in r.getMessage() and "ms behind" in r.getMessage()  # noqa: E731
                       for r in caplog.records)
    # counted, then said, on the server's thread: wait for both (a busy host ran this between the two)
    assert wait_for(lambda: server.stats.stalls >= 1 and said())
    assert 0.2 <= server.stats.longest_stall_s < 5.0
    assert len(transact(fd, bytes((2,)) + u16(0, 16), expect=7)) == 7  # and it serves on


# -- the model ---------------------------------------------------------------------------


def run_model(model: PlcModel, t0: float, seconds: float, heartbeat: bool = True) -> float:
    """Scan every 10 ms for `seconds`, advancing cnc_heartbeat like a live CNC; returns the end time."""
    t = t0
    while t < t0 + seconds:
        t += 0.01
        if heartbeat:
            model.set_output("cnc_heartbeat", round(t * 10) % 65536)
        model.step(t)
    return t


def test_transport_sequence_feeds_grips_and_unloads_in_its_travel_times():
    model = PlcModel(PLC, FAST)
    t = run_model(model, 0.0, 0.1)
    assert model.input("transport_ready") == 1.0 and model.input("supply_ready") == 1.0
    model.set_output("feed_material", 1)
    t = run_model(model, t, 0.2)
    assert model.input("transport_step") == TransportStep.FEEDING and model.input("material_in_place") == 0.0
    t = run_model(model, t, 0.15)
    assert model.input("material_in_place") == 1.0 and model.input("transport_step") == TransportStep.MATERIAL_IN_PLACE
    model.set_output("feed_material", 0)
    model.set_output("gripper_close", 1)
    t = run_model(model, t, 0.15)
    assert model.input("gripper_closed") == 1.0
    model.set_output("unload", 1)
    t = run_model(model, t, 0.2)
    assert model.input("gripper_closed") == 0.0 and model.input("transport_step") == TransportStep.UNLOADING
    t = run_model(model, t, 0.3)
    assert model.input("unload_done") == 1.0 and model.input("material_in_place") == 0.0
    model.set_output("unload", 0)
    model.set_output("gripper_close", 0)
    run_model(model, t, 0.05)
    assert model.input("unload_done") == 0.0 and model.input("transport_step") == TransportStep.IDLE


def test_transport_waits_while_the_cnc_cuts():
    model = PlcModel(PLC, FAST)
    model.set_output("cnc_cutting", 1)
    model.set_output("feed_material", 1)
    t = run_model(model, 0.0, 0.5)
    assert model.input("material_in_place") == 0.0
    model.set_output("cnc_cutting", 0)
    run_model(model, t, 0.5)
    assert model.input("material_in_place") == 1.0


def test_stalled_cnc_heartbeat_stops_the_transport_with_an_alarm():
    model = PlcModel(PLC, dataclasses.replace(FAST, feed_s=3.0))
    model.set_output("feed_material", 1)
    t = run_model(model, 0.0, 0.5)
    assert model.input("transport_step") == TransportStep.FEEDING
    t = run_model(model, t, 1.1, heartbeat=False)
    assert model.input("plc_alarm") == PlcAlarm.CNC_WATCHDOG
    assert model.input("transport_step") == TransportStep.STOPPED and model.input("transport_ready") == 0.0
    model.set_output("plc_reset", 1)
    run_model(model, t, 0.05)
    assert model.input("plc_alarm") == PlcAlarm.NONE and model.input("transport_step") == TransportStep.FEEDING


def test_pump_pressure_ramps_at_its_rate_and_decays_when_off():
    model = PlcModel(PLC, dataclasses.replace(FAST, ramp_bar_s=1000.0))
    model.set_output("pump_on", 1)
    model.set_output("pump_pressure_set", 2000.0)
    t = run_model(model, 0.0, 1.0)
    assert model.input("pump_running") == 1.0
    assert model.input("pump_pressure") == pytest.approx(1000.0, abs=15.0)  # 1000 bar/s for 1 s
    t = run_model(model, t, 1.2)
    assert model.input("pump_pressure") == pytest.approx(2000.0)
    model.inject("pump_pressure_drop", True)
    t = run_model(model, t, 2.0)
    assert model.input("pump_pressure") == pytest.approx(FAST.drop_bar)
    model.inject("pump_pressure_drop", False)
    model.set_output("pump_on", 0)
    run_model(model, t, 2.0)
    assert model.input("pump_running") == 0.0 and model.input("pump_pressure") < 1.0


@pytest.mark.parametrize(
    "fault, var_id",
    [
        ("estop", "safety_circuit_ok"),
        ("doors", "safety_circuit_ok"),
        ("barrier_front", "barrier_front_ok"),
        ("barrier_rear", "barrier_rear_ok"),
        ("mains_off", "mains_on"),
        ("pneumatic_off", "pneumatic_ready"),
        ("transport_drives_fault", "transport_drives_ready"),
        ("plc_stop", "plc_running"),
    ],
)
def test_fault_drops_its_signal_and_transport_ready(fault, var_id):
    model = PlcModel(PLC, FAST)
    t = run_model(model, 0.0, 0.1)
    assert model.input(var_id) == 1.0 and model.input("transport_ready") == 1.0
    model.inject(fault, True)
    t = run_model(model, t, 0.02)
    assert model.input(var_id) == 0.0 and model.input("transport_ready") == 0.0
    model.inject(fault, False)
    run_model(model, t, 0.1)
    assert model.input(var_id) == 1.0 and model.input("transport_ready") == 1.0


def test_pump_fault_stops_the_pump_and_latches_an_alarm_until_reset():
    model = PlcModel(PLC, FAST)
    model.set_output("pump_on", 1)
    t = run_model(model, 0.0, 0.1)
    model.inject("pump_fault", True)
    t = run_model(model, t, 0.05)
    assert model.input("pump_running") == 0.0 and model.input("pump_fault") == 1.0
    assert model.input("plc_alarm") == PlcAlarm.PUMP_FAULT
    model.inject("pump_fault", False)
    t = run_model(model, t, 0.05)
    assert model.input("plc_alarm") == PlcAlarm.PUMP_FAULT
    model.set_output("plc_reset", 1)
    run_model(model, t, 0.05)
    assert model.input("plc_alarm") == PlcAlarm.NONE and model.input("pump_running") == 1.0


def test_button_press_is_held_briefly_and_heartbeat_counts_scans():
    model = PlcModel(PLC, FAST)
    t = run_model(model, 0.0, 0.1)
    beat = model.input("plc_heartbeat")
    model.press_button()
    t = run_model(model, t, 0.1)
    assert model.input("button_pressed") == 1.0
    assert model.input("plc_heartbeat") == beat + 10
    run_model(model, t, 0.2)
    assert model.input("button_pressed") == 0.0


def test_model_names_the_variable_the_map_lacks():
    plc = dataclasses.replace(PLC, var=[v for v in PLC.var if v.id != "gripper_closed"])
    with pytest.raises(ModelError, match="'gripper_closed' is missing"):
        PlcModel(plc)
    with pytest.raises(ValueError, match="unknown PLC simulator fault 'flood'"):
        PlcModel(PLC).inject("flood", True)


# -- the child process -------------------------------------------------------------------


def test_simulator_process_serves_a_pty_and_takes_faults_over_its_pipe():
    from plc_link.master import PlcMaster

    sim = start_simulator_process(MACHINE_FILE, times=FAST)
    master = PlcMaster(PLC, sim.device)
    try:
        image = master.image
        outputs = [0.0] * len(image.outputs)
        assert wait_for(lambda: master.cycle(outputs) and master.inputs[image.input_index["safety_circuit_ok"]] == 1.0)
        sim.inject("estop", True)
        assert wait_for(lambda: master.cycle(outputs) and master.inputs[image.input_index["safety_circuit_ok"]] == 0.0)
        assert sim.inputs()["safety_circuit_ok"] == 0.0
        with pytest.raises(ValueError, match="unknown PLC simulator fault"):
            sim.inject("flood", True)
        master.close()
        master = PlcMaster(dataclasses.replace(PLC, timeout_ms=500.0), sim.device)  # timely answers keep a margin
        assert wait_for(lambda: master.cycle(outputs))
        failed = master.status.failed
        sim.answer_late(2, 0.75)  # the next read of the inputs answers past the timeout
        assert [master.cycle(outputs) for _ in range(3)] == [False, True, True]
        assert master.status.missed == 0 and master.status.failed == failed + 1
        with pytest.raises(ValueError, match="answer_late: extra_s must be >= 0, got -1.0"):
            sim.answer_late(2, -1)
    finally:
        master.close()
        sim.stop()
    assert not sim.process.is_alive()
