"""The PLC link: RTU arithmetic, the image's requests, the master's line (answers matched to
their requests), the master against the simulator on a real pty (exchange, timing, late
answers, loss and reconnection), a standard Modbus client against the simulator, and the
process loop over shared memory."""

from __future__ import annotations

import dataclasses
import logging
import os
import select
import threading
import time

import pytest

from cnc.config import PlcVarConfig, load_machine
from cnc.data.dataserver import SharedArea, unique_name
from cnc.data.layout import LinkState, Proc, controller_layouts
from plc_link import rtu
from plc_link.image import ImageError, PlcImage
from plc_link.line import ExceptionAnswer, NoAnswer, RtuLine
from plc_link.master import PlcExceptionResponse, PlcMaster, PlcTimeout
from plc_link.process import PlcLink
from plc_link.pty_pair import PtyPair
from plc_link.sim_model import PlantTimes, PlcModel
from plc_link.sim_server import PlcSimServer
from tests.conftest import MACHINE_FILE

MACHINE = load_machine(MACHINE_FILE)
PLC = MACHINE.plc
PLC_ADDRESS = {v.id: v.address for v in PLC.var}
FAST = PlantTimes(feed_s=0.3, gripper_s=0.1, unload_s=0.3, pneumatic_s=0.05)


class Sim:
    """A simulator serving on a fresh pty pair (the far end of the cable)."""

    def __init__(self, times: PlantTimes = FAST) -> None:
        self.pair = PtyPair()
        self.model = PlcModel(PLC, times)
        self.server = PlcSimServer(PLC, self.model, self.pair.server_fd)
        self.server.start()
        self.device = self.pair.device

    def cut(self) -> None:
        """Pull the cable: stop serving and close the simulator's end."""
        self.server.stop()
        self.pair.close()


@pytest.fixture
def sim():
    s = Sim()
    yield s
    s.cut()
    assert s.server.error is None


def wait_for(cond, timeout_s: float = 30.0) -> bool:
    """Until `cond()`; the limit only says when to give up (a busy host never reaches it)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.002)
    return False


def var(id_: str, kind: str, address: int, type_: str = "", scale: float = 1.0) -> PlcVarConfig:
    bits = kind in ("discrete_input", "coil")
    return PlcVarConfig(id=id_, kind=kind, address=address, type=type_ or ("bool" if bits else "uint16"), scale=scale)


# -- RTU arithmetic and the image --------------------------------------------------------


def test_crc16_matches_known_vectors():
    assert rtu.crc16(b"123456789") == 0x4B37  # CRC-16/MODBUS check value
    assert rtu.with_crc(bytes.fromhex("01030000000A")) == bytes.fromhex("01030000000AC5CD")
    assert rtu.crc_ok(bytes.fromhex("010402FFFFB880"))
    assert not rtu.crc_ok(bytes.fromhex("010402FFFFB881"))


def test_character_time_counts_start_parity_and_stop_bits():
    assert rtu.char_time_s(19200, "E", 1) == pytest.approx(11 / 19200)
    assert rtu.char_time_s(19200, "N", 2) == pytest.approx(11 / 19200)
    assert rtu.char_time_s(9600, "N", 1) == pytest.approx(10 / 9600)


def test_shipped_map_is_read_with_one_request_per_table():
    image = PlcImage(PLC)
    reads = [(r.function, r.address, r.count) for r in image.read_requests]
    assert reads == [(rtu.READ_DISCRETE_INPUTS, 0, 16), (rtu.READ_INPUT_REGISTERS, 0, 4)]
    groups = [(g.bits, g.address, len(g.indices)) for g in image.write_groups]
    assert groups == [(True, 0, 6), (False, 0, 2)]


def test_reads_split_at_wide_gaps_and_protocol_limits_and_writes_at_any_gap():
    regs = [var(f"r{a}", "input_register", a) for a in (0, 5, 60, *range(100, 230))]
    bits = [var(f"b{a}", "discrete_input", a) for a in (0, 1, 100, 400)]
    outs = [var("c0", "coil", 0), var("c1", "coil", 1), var("c3", "coil", 3), var("h7", "holding_register", 7)]
    image = PlcImage(dataclasses.replace(PLC, var=bits + regs + outs))
    reads = [(r.function, r.address, r.count) for r in image.read_requests]
    assert reads == [
        (rtu.READ_DISCRETE_INPUTS, 0, 101),  # a 98-bit gap costs 12 characters: read through it
        (rtu.READ_DISCRETE_INPUTS, 400, 1),  # a 299-bit gap costs more than a request
        (rtu.READ_INPUT_REGISTERS, 0, 6),
        (rtu.READ_INPUT_REGISTERS, 60, 1),
        (rtu.READ_INPUT_REGISTERS, 100, 125),  # the protocol's limit
        (rtu.READ_INPUT_REGISTERS, 225, 5),
    ]
    assert [(g.address, len(g.indices)) for g in image.write_groups] == [(0, 2), (3, 1), (7, 1)]


def test_values_decode_with_sign_and_scale_and_encode_with_rounding():
    plc = dataclasses.replace(PLC, var=[
        var("t", "input_register", 0, "int16", 0.5), var("b", "discrete_input", 0),
        var("set", "holding_register", 0, "uint16", 0.1), var("off", "holding_register", 1, "int16"),
    ])
    image = PlcImage(plc)
    inputs = [0.0, 0.0]
    image.decode_inputs([[1], [0xFFFE]], inputs)  # bits first, then registers
    assert inputs == [-1.0, 1.0]
    assert image.encode_outputs([300.04, -2]) == [3000, -2]
    assert image.write_span(0, [3000, -2], 0, 1).values == (3000, 0xFFFE)
    with pytest.raises(ImageError, match=r"PLC output set: 7000 is out of range 0\.\.6553\.5"):
        image.encode_outputs([7000.0, 0])
    raw, errors = image.clamp_outputs([7000.0, 40000])
    assert raw == [65535, 32767] and "off" in errors[1]


def test_theoretical_exchange_time_of_the_shipped_map():
    image = PlcImage(PLC)
    char_s = 11 / 19200
    # read bits 8+7, read registers 8+13 bytes, each frame followed by 3.5 characters
    assert image.read_time_s() == pytest.approx((8 + 7 + 8 + 13 + 4 * 3.5) * char_s)
    # plus write coils 10+8 and write registers 13+8: 59 ms, more than the 50 ms cycle
    assert image.full_exchange_time_s() == pytest.approx((75 + 8 * 3.5) * char_s)
    assert image.full_exchange_time_s() > PLC.cycle_ms / 1000


# -- the master against the simulator ----------------------------------------------------


def test_exchange_reads_the_model_and_the_model_sees_the_writes(sim):
    master = PlcMaster(PLC, sim.device)
    try:
        image = master.image
        outputs = [0.0] * len(image.outputs)
        outputs[image.output_index["pump_on"]] = 1.0
        outputs[image.output_index["pump_pressure_set"]] = 250.0
        master.exchange(outputs)
        master.exchange(outputs)  # one write request per cycle at 19200 baud: coils, then registers
        assert master.writes_pending == 0
        assert sim.model.outputs()["pump_on"] == 1.0
        assert sim.model.outputs()["pump_pressure_set"] == pytest.approx(250.0)
        pressure = image.input_index["pump_pressure"]
        seen = []
        assert wait_for(lambda: seen.append(master.exchange(outputs)[pressure]) or seen[-1] == pytest.approx(250.0))
        assert any(0.0 < p < 250.0 for p in seen)  # it ramped, and we saw it on the way
        assert master.inputs[image.input_index["pump_running"]] == 1.0
    finally:
        master.close()


def test_measured_exchange_is_no_faster_than_the_line_and_the_line_fits_the_cycle(sim):
    """The simulator paces its answers like the serial line, so no exchange beats the line time
    of its frames; that line time (a read, and a write with the read) fits the link's cycle. How
    long exchanges take on a host is a figure for `bench/plc_exchange.py`, not a test: on a busy
    2-core host the median write exchange once took 50.4 ms against the 50 ms cycle."""
    master = PlcMaster(PLC, sim.device)
    try:
        image = master.image
        outputs = [0.0] * len(image.outputs)
        master.exchange(outputs)
        master.exchange(outputs)  # every output confirmed: only reads from here
        reads, writes = [], []
        for k in range(12):
            outputs[image.output_index["cnc_heartbeat"]] = 1 + k // 2  # a write every other cycle
            t0 = time.perf_counter()
            master.exchange(outputs)
            (writes if k % 2 == 0 else reads).append(time.perf_counter() - t0)
        write_s = image.write_time_s(image.write_span(1, [0] * 8, 1, 1))
        assert min(reads) >= image.read_time_s()
        assert min(writes) >= image.read_time_s() + write_s
        assert image.read_time_s() + write_s < PLC.cycle_ms / 1000
    finally:
        master.close()


def test_transport_sequence_over_the_link(sim):
    master = PlcMaster(PLC, sim.device)
    image = master.image
    outputs = [0.0] * len(image.outputs)
    beat = [0]

    def until(var_id: str, value: float) -> bool:
        def check() -> bool:
            beat[0] += 1
            outputs[image.output_index["cnc_heartbeat"]] = beat[0]
            return master.cycle(outputs) and master.inputs[image.input_index[var_id]] == value
        return wait_for(check)

    try:
        assert until("transport_ready", 1.0)
        outputs[image.output_index["feed_material"]] = 1.0
        assert until("material_in_place", 1.0)
        outputs[image.output_index["feed_material"]] = 0.0
        outputs[image.output_index["gripper_close"]] = 1.0
        assert until("gripper_closed", 1.0)
        outputs[image.output_index["unload"]] = 1.0
        assert until("unload_done", 1.0)
        assert master.inputs[image.input_index["material_in_place"]] == 0.0
        assert master.inputs[image.input_index["gripper_closed"]] == 0.0
    finally:
        master.close()


def test_silent_plc_is_a_timeout_naming_the_request(sim):
    master = PlcMaster(PLC, sim.device)
    try:
        master.exchange([0.0] * 8)
        sim.model.inject("link_dead", True)
        with pytest.raises(PlcTimeout, match=r"read discrete inputs 0\.\.15 \(function 2\): no valid response within 100 ms "
                                             r"\(nothing came in 0\.\d{3} s\)"):
            master.exchange([0.0] * 8)
    finally:
        master.close()


def test_exception_response_names_the_request_and_code(sim):
    plc = dataclasses.replace(PLC, var=[*PLC.var, var("extra", "discrete_input", 20)])
    master = PlcMaster(plc, sim.device)
    try:
        with pytest.raises(PlcExceptionResponse, match=r"read discrete inputs 0\.\.20 .*exception 02 \(illegal data address\)"):
            master.exchange([0.0] * 8)
    finally:
        master.close()


@pytest.mark.parametrize("late", ["read discrete inputs", "read input registers", "write coil", "write register"])
def test_an_answer_later_than_the_timeout_costs_one_exchange_not_the_link(sim, late):
    """A PLC (or host) busy past the master's timeout answers late, while the master already waits
    for its next request's answer. The master drops the late answer where it does not fit and
    takes it where it cannot be told from the current one (a read of the same table): one
    exchange fails, the next ones succeed, nothing is lost and the PLC ends up with every output."""
    plc = dataclasses.replace(PLC, timeout_ms=500.0)  # a margin no busy host misses for the timely answers
    master = PlcMaster(plc, sim.device)
    image = master.image
    outputs = [0.0] * 8
    try:
        assert wait_for(lambda: master.cycle(outputs) and master.writes_pending == 0)
        failed = master.status.failed
        function = {
            "read discrete inputs": rtu.READ_DISCRETE_INPUTS, "read input registers": rtu.READ_INPUT_REGISTERS,
            "write coil": rtu.WRITE_SINGLE_COIL, "write register": rtu.WRITE_SINGLE_REGISTER,
        }[late]
        sim.server.answer_late(function, 1.5 * plc.timeout_ms / 1000)
        if late == "write coil":
            outputs[image.output_index["pump_on"]] = 1.0
        elif late == "write register":
            outputs[image.output_index["cnc_heartbeat"]] = 7.0
        results = [master.cycle(outputs) for _ in range(6)]
        assert results == [False, True, True, True, True, True], master.status.error
        assert master.status.state == LinkState.OK and master.status.losses == 0 and master.status.failed == failed + 1
        assert master.writes_pending == 0
        assert master.status.dropped == 1 and master.status.noise == 0, "the late answer (or the one it displaced) dropped"
        assert sim.model.outputs()["pump_on"] == outputs[image.output_index["pump_on"]]
        assert sim.model.outputs()["cnc_heartbeat"] == outputs[image.output_index["cnc_heartbeat"]]
        assert sim.server.stats.responses == sim.server.stats.requests  # the late answer was sent, and dropped
    finally:
        master.close()


class HandSlave:
    """The far end of a pty played by hand: reads one request, writes back the given bytes."""

    def __init__(self, local_echo: bool = False) -> None:
        self.pair = PtyPair()
        self.line = RtuLine(self.pair.device, 19200, "N", 1, timeout_s=2.0, silence_s=0.002, local_echo=local_echo)
        self.line.open()

    def answer(self, *frames: bytes, echo: bool = False) -> threading.Thread:
        """Answer the next request with `frames`; `echo`: hand the request back first."""
        def serve() -> None:
            got = b""
            while len(got) < 8:  # every request of these tests is 8 bytes
                select.select([self.pair.server_fd], [], [], 5.0)
                got += os.read(self.pair.server_fd, 64)
            os.write(self.pair.server_fd, (got if echo else b"") + b"".join(frames))
        thread = threading.Thread(target=serve, daemon=True)
        thread.start()
        return thread

    def close(self) -> None:
        self.line.close()
        self.pair.close()


def frame(*pdu: int) -> bytes:
    return rtu.with_crc(bytes((PLC.unit_id, *pdu)))


def test_the_line_drops_noise_and_misfit_answers_and_takes_the_one_that_fits_the_request():
    slave = HandSlave()
    try:
        read = rtu.read_pdu(rtu.READ_DISCRETE_INPUTS, 0, 16)
        thread = slave.answer(
            b"\x00\xff\x13",  # noise
            frame(rtu.WRITE_SINGLE_COIL, 0, 3, 0xFF, 0),  # a late write echo
            frame(rtu.READ_DISCRETE_INPUTS, 1, 0x05),  # a late read of another size
            rtu.with_crc(bytes((PLC.unit_id + 1, rtu.READ_DISCRETE_INPUTS, 2, 0, 0))),  # another unit
            frame(rtu.READ_DISCRETE_INPUTS, 2, 0xA5, 0x01),  # the answer
        )
        answer = slave.line.transact(PLC.unit_id, read, rtu.response_size(rtu.READ_DISCRETE_INPUTS, 16))
        thread.join()
        assert rtu.unpack_bits(answer[2:], 16) == [1, 0, 1, 0, 0, 1, 0, 1, 1, 0, 0, 0, 0, 0, 0, 0]
        assert slave.line.misfits == 3 and slave.line.noise == 3
    finally:
        slave.close()


def test_a_timeout_says_whether_the_line_stayed_silent_or_brought_only_misfits():
    """A dead line and a line full of other answers are different repairs (cable or PLC against
    a master out of step): the timeout says which, and how long the master really waited."""
    slave = HandSlave()
    try:
        slave.line.timeout_s = 0.2
        read = rtu.read_pdu(rtu.READ_DISCRETE_INPUTS, 0, 16)
        size = rtu.response_size(rtu.READ_DISCRETE_INPUTS, 16)
        thread = slave.answer()
        with pytest.raises(NoAnswer) as silent:
            slave.line.transact(PLC.unit_id, read, size)
        thread.join()
        assert silent.value.received == 0 and silent.value.waited_s >= 0.2
        assert silent.value.describe().startswith("nothing came in 0.2")
        late_write = frame(rtu.WRITE_SINGLE_COIL, 0, 3, 0xFF, 0)
        thread = slave.answer(b"\x00\xff", late_write)
        with pytest.raises(NoAnswer) as misfits:
            slave.line.transact(PLC.unit_id, read, size)
        thread.join()
        assert misfits.value.received == 2 + len(late_write)
        assert misfits.value.describe().startswith(f"{2 + len(late_write)} bytes came, none the answer, in 0.2")
    finally:
        slave.close()


def test_the_tail_of_a_frame_cut_short_does_not_hide_the_answer_behind_it():
    """A frame's tail left on the line (its first bytes went with a flushed buffer) can read as the
    head of a long frame: `01 03 40` promises 64 register bytes that never come. The answer after
    it is still found, by its size and CRC, before the timeout."""
    slave = HandSlave()
    try:
        read = rtu.read_pdu(rtu.READ_INPUT_REGISTERS, 0, 2)
        thread = slave.answer(bytes((PLC.unit_id, rtu.READ_HOLDING_REGISTERS, 0x40)), frame(rtu.READ_INPUT_REGISTERS, 4, 0, 7, 1, 2))
        # read only from the front, the line would wait for the 64 bytes until it times out (NoAnswer)
        answer = slave.line.transact(PLC.unit_id, read, rtu.response_size(rtu.READ_INPUT_REGISTERS, 2))
        thread.join()
        assert answer == bytes((rtu.READ_INPUT_REGISTERS, 4, 0, 7, 1, 2)) and slave.line.noise == 3
    finally:
        slave.close()


def test_with_local_echo_a_write_is_confirmed_by_the_plc_s_answer_not_by_its_own_echo():
    """A half-duplex adapter hears each request; a single write's answer repeats the request, so
    without `local_echo` the echo would confirm a write no PLC answered."""
    write = rtu.write_pdu(rtu.WRITE_SINGLE_COIL, 3, [1])
    size = rtu.response_size(rtu.WRITE_SINGLE_COIL, 1)
    deaf = HandSlave()
    try:
        thread = deaf.answer(echo=True)  # the adapter's echo, and no PLC behind it
        assert deaf.line.transact(PLC.unit_id, write, size) == write, "taken for the answer: the hazard"
        thread.join()
    finally:
        deaf.close()
    slave = HandSlave(local_echo=True)
    try:
        slave.line.timeout_s = 0.3
        thread = slave.answer(echo=True)
        with pytest.raises(NoAnswer):
            slave.line.transact(PLC.unit_id, write, size)
        thread.join()
        slave.line.timeout_s = 2.0
        read = rtu.read_pdu(rtu.READ_DISCRETE_INPUTS, 0, 8)
        thread = slave.answer(frame(rtu.READ_DISCRETE_INPUTS, 1, 0x81), echo=True)
        assert slave.line.transact(PLC.unit_id, read, rtu.response_size(rtu.READ_DISCRETE_INPUTS, 8)) == bytes((2, 1, 0x81))
        thread.join()
        thread = slave.answer(frame(rtu.WRITE_SINGLE_COIL, 0, 3, 0xFF, 0), echo=True)
        assert slave.line.transact(PLC.unit_id, write, size) == write
        thread.join()
        assert slave.line.noise == 0 and slave.line.misfits == 0
    finally:
        slave.close()


def test_the_master_with_local_echo_runs_the_link_over_an_echoing_adapter():
    plc = dataclasses.replace(PLC, local_echo=True, timeout_ms=500.0)  # timely answers keep a margin
    pair = PtyPair()
    model = PlcModel(plc, FAST)
    server = PlcSimServer(plc, model, pair.server_fd, echo=True)
    server.start()
    master = PlcMaster(plc, pair.device)
    try:
        outputs = [0.0] * 8
        outputs[master.image.output_index["pump_on"]] = 1.0
        assert wait_for(lambda: master.cycle(outputs) and master.writes_pending == 0)
        assert model.outputs()["pump_on"] == 1.0 and master.status.failed == 0
        assert master.status.dropped == 0 and master.status.noise == 0
    finally:
        master.close()
        server.stop()
        pair.close()
    assert server.error is None


def test_a_write_echo_of_another_address_or_value_is_not_the_write_s_answer():
    slave = HandSlave()
    try:
        write = rtu.write_pdu(rtu.WRITE_SINGLE_REGISTER, 4, [300])
        size = rtu.response_size(rtu.WRITE_SINGLE_REGISTER, 1)
        thread = slave.answer(frame(rtu.WRITE_SINGLE_REGISTER, 0, 3, 1, 44), frame(rtu.WRITE_SINGLE_REGISTER, 0, 4, 0, 7))
        with pytest.raises(NoAnswer):
            slave.line.timeout_s = 0.3  # neither echo is this write's: no answer came
            slave.line.transact(PLC.unit_id, write, size)
        thread.join()
        assert slave.line.misfits == 2
        thread = slave.answer(frame(rtu.WRITE_SINGLE_REGISTER, 0, 4, 1, 44))
        assert slave.line.transact(PLC.unit_id, write, size) == bytes((rtu.WRITE_SINGLE_REGISTER, 0, 4, 1, 44))
        thread.join()
    finally:
        slave.close()


def test_an_exception_answer_to_the_request_s_function_is_raised_with_its_code():
    slave = HandSlave()
    try:
        thread = slave.answer(frame(rtu.READ_INPUT_REGISTERS | 0x80, rtu.ILLEGAL_DATA_ADDRESS))
        with pytest.raises(ExceptionAnswer) as info:
            slave.line.transact(PLC.unit_id, rtu.read_pdu(rtu.READ_INPUT_REGISTERS, 0, 4), rtu.response_size(4, 4))
        thread.join()
        assert info.value.code == rtu.ILLEGAL_DATA_ADDRESS
    finally:
        slave.close()


def test_the_simulator_serves_a_standard_modbus_client(sim):
    """The master and the simulator share `rtu`; pymodbus, an independent implementation of the
    protocol, reads and writes the simulator as well, so both speak Modbus, not only each other."""
    from pymodbus.client import ModbusSerialClient
    from pymodbus.framer import FramerType

    client = ModbusSerialClient(sim.device, framer=FramerType.RTU, baudrate=19200, parity="N", timeout=2.0, retries=1)
    assert client.connect()
    try:
        unit = PLC.unit_id
        assert not client.write_coil(PLC_ADDRESS["pump_on"], True, device_id=unit).isError()
        assert not client.write_register(PLC_ADDRESS["pump_pressure_set"], 2000, device_id=unit).isError()
        assert sim.model.outputs()["pump_on"] == 1.0
        inputs = sim.model.inputs()
        bits = client.read_discrete_inputs(0, count=16, device_id=unit).bits[:16]
        for v in PLC.var:
            if v.kind == "discrete_input":
                assert bits[v.address] == bool(inputs[v.id]), v.id
        bad = client.read_discrete_inputs(0, count=200, device_id=unit)
        assert bad.isError() and bad.exception_code == rtu.ILLEGAL_DATA_ADDRESS
    finally:
        client.close()


def test_out_of_range_output_is_clamped_and_reported_without_failing_the_cycle(sim):
    master = PlcMaster(PLC, sim.device)
    try:
        outputs = [0.0] * 8
        outputs[master.image.output_index["pump_pressure_set"]] = 9000.0
        assert master.cycle(outputs) and master.cycle(outputs)
        assert master.status.state == LinkState.OK
        assert "pump_pressure_set: 9000 bar is out of range" in master.status.error
        assert sim.model.outputs()["pump_pressure_set"] == pytest.approx(6553.5)
    finally:
        master.close()


def test_cut_cable_is_lost_within_lost_after_cycles_then_reconnects_to_a_new_simulator(sim, caplog):
    """Each failed exchange on the way to a loss is said (a stale input image then tells answers
    missing from a link the host did not run), the loss once."""
    plc = dataclasses.replace(PLC, reconnect_s=0.2)
    master = PlcMaster(plc, sim.device)
    outputs = [0.0] * 8
    second = None
    try:
        assert master.cycle(outputs) and master.status.state == LinkState.OK
        sim.cut()
        cycles = 0
        with caplog.at_level(logging.WARNING, logger="plc_link.master"):
            while master.status.state != LinkState.LOST and cycles < 10:
                master.cycle(outputs)
                cycles += 1
        assert master.status.state == LinkState.LOST and cycles == plc.lost_after_cycles
        said = [r.getMessage() for r in caplog.records if r.name == "plc_link.master"]
        expected = [*[f"PLC link: exchange failed ({k} of {plc.lost_after_cycles} before the link counts as lost): "
                      for k in range(1, plc.lost_after_cycles)],
                    f"PLC link lost after {plc.lost_after_cycles} failed exchanges: "]
        assert len(said) == len(expected) and all(m.startswith(e) for m, e in zip(said, expected)), said
        assert master.status.losses == 1 and master.status.error
        second = Sim()
        master.retarget(second.device)
        assert wait_for(lambda: master.cycle(outputs) and master.status.state == LinkState.OK)
        assert master.status.missed == 0
        assert wait_for(lambda: master.cycle(outputs) and master.writes_pending == 0)
        assert second.model.outputs()["pump_on"] == 0.0 and second.server.stats.responses >= 3
    finally:
        master.close()
        if second is not None:
            second.cut()


def test_no_port_keeps_the_link_down_and_says_why():
    master = PlcMaster(dataclasses.replace(PLC, port=""))
    assert not master.cycle([0.0] * 8)
    assert master.status.state == LinkState.DOWN
    assert master.status.error == "no serial port: [plc] port is empty and no simulator was started"


def test_a_port_that_cannot_be_opened_fails_the_cycle_naming_the_device():
    master = PlcMaster(PLC, "/dev/no-such-plc-port")
    assert not master.cycle([0.0] * 8)
    assert master.status.state == LinkState.CONNECTING and master.status.missed == 1
    assert master.status.error.startswith("cannot open serial port '/dev/no-such-plc-port' (")
    assert master.status.error.endswith(") for the PLC link")
    master.close()


# -- the process loop over shared memory -------------------------------------------------


@pytest.fixture
def area():
    a = SharedArea.create(unique_name("test", "plc"), controller_layouts(2))
    yield a
    a.close()


def test_link_loop_publishes_inputs_state_and_counters_into_shared_memory(sim, area):
    plc_out = area.writer("plc_out")
    image = PlcImage(PLC)
    outputs = [0.0] * 64
    outputs[image.output_index["pump_on"]] = 1.0
    outputs[image.output_index["pump_pressure_set"]] = 100.0
    plc_out.set("image_seq", 5)
    plc_out.set("outputs", outputs)
    plc_out.publish()
    link = PlcLink(MACHINE, area, sim.device)
    thread = threading.Thread(target=link.run)
    thread.start()
    reader = area.reader("plc")
    beat = area.blocks["heartbeat"].array[0]["beat"]
    try:
        pressure = image.input_index["pump_pressure"]
        assert wait_for(lambda: reader.read_dict()["inputs"][pressure] == pytest.approx(100.0))
        plc = reader.read_dict()
        assert plc["state"] == LinkState.OK and plc["error"] == ""
        assert plc["output_seq_sent"] == 5 and plc["input_seq"] >= 2 and plc["exchanges"] >= 2
        assert 0 < plc["cycle_us"] < PLC.cycle_ms * 1000
        assert plc["inputs"][image.input_index["plc_running"]] == 1.0
        assert beat[Proc.PLC_LINK] >= 2
        outputs[image.output_index["cnc_heartbeat"]] = 77.0  # the control logic advances it
        plc_out.set("image_seq", 6)
        plc_out.set("outputs", outputs)
        plc_out.publish()
        assert wait_for(lambda: sim.model.outputs()["cnc_heartbeat"] == 77.0)  # written every HEARTBEAT_PERIOD_S
        assert wait_for(lambda: reader.read_dict()["output_seq_sent"] == 6)
        noise = reader.read_dict()["noise"]
        sim.server.noise_before_next_answer(b"\x00\xff\x00")
        assert wait_for(lambda: reader.read_dict()["noise"] >= noise + 3), "the line's dropped bytes are published"
        assert reader.read_dict()["state"] == LinkState.OK
        sim.model.inject("link_dead", True)
        assert wait_for(lambda: reader.read_dict()["state"] == LinkState.LOST)
        assert reader.read_dict()["losses"] == 1 and "no valid response" in reader.read_dict()["error"]
    finally:
        area.blocks["supervisor"].array["shutdown"][0] |= 1 << Proc.PLC_LINK
        thread.join(2.0)
        link.close()
    assert not thread.is_alive()
    assert reader.read_dict()["state"] == LinkState.DOWN


def test_the_link_loop_says_a_cycle_the_host_woke_late_but_not_its_own_overrun(area, monkeypatch, caplog):
    """A stale input image is a safe stop; whether the PLC or the host made it stale, the link's
    log tells: a cycle that wakes 100 ms or more after its deadline is counted and said, while an
    exchange that overruns its cycle (an answer waited for up to its timeout) starts the next
    one at once and is not. On a clock of the test's own: the first exchange takes three cycles,
    the third cycle's sleep oversleeps by 150 ms, the fifth by 50 ms."""
    import plc_link.process as process

    clock = {"now": 100.0, "sleeps": 0}
    link = PlcLink(dataclasses.replace(MACHINE, plc=dataclasses.replace(PLC, port="")), area, "")
    period = link.period_s

    def step(now_s: float) -> bool:
        clock["now"] += 3.0 * period if clock["sleeps"] == 0 else 0.001
        return True

    def sleep(s: float) -> None:
        clock["sleeps"] += 1
        clock["now"] += s + {3: 0.150, 5: 0.050}.get(clock["sleeps"], 0.0)
        if clock["sleeps"] == 8:
            area.blocks["supervisor"].array["shutdown"][0] |= 1 << Proc.PLC_LINK

    monkeypatch.setattr(link, "step", step)
    monkeypatch.setattr(process.time, "monotonic", lambda: clock["now"])
    monkeypatch.setattr(process.time, "sleep", sleep)
    with caplog.at_level(logging.WARNING, logger="plc_link.process"):
        link.run()
    link.close()
    assert link.late_wakes == 1 and link.longest_late_s == pytest.approx(0.150)
    assert [r.getMessage() for r in caplog.records] == [
        "PLC link: a cycle woke 150 ms after its deadline (the host did not run the link)"]


def test_link_loop_without_a_port_stays_down_and_beats(area):
    link = PlcLink(dataclasses.replace(MACHINE, plc=dataclasses.replace(PLC, port="")), area, "")
    link.step(time.monotonic())
    plc = area.reader("plc").read_dict()
    assert plc["state"] == LinkState.DOWN
    assert plc["error"] == "no serial port: [plc] port is empty and no simulator was started"
    link.close()
