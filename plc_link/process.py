"""The PLC-link process: the cyclic Modbus exchange between the data area and the external PLC.

Every `cycle_ms` (absolute deadlines on the wall clock, not the controller's tick: the serial
line runs in real time whatever the controller's clock does) the loop takes the latest
output image from `plc_out`, does one supervised exchange, and publishes the input image,
the link state and its counters into `plc`, then bumps its heartbeat.

The output `cnc_heartbeat` (when the map has it) is advanced by the control logic every
scan; the link forwards its current value only every HEARTBEAT_PERIOD_S. A changed register
costs a write request (13 ms at 19200 baud), so sending it every cycle would not fit the
cycle; four changes a second are plenty for the PLC's usual 1 s watchdog, and a stalled
control logic still stops the PLC's transport because the forwarded value stops changing.
"""

from __future__ import annotations

import logging
import os
import time

from cnc.config import MachineConfig
from cnc.data.dataserver import SharedArea
from cnc.data.layout import MAX_PLC_VARS, LinkState, Proc, controller_layouts
from cnc.runtime.rt import enter_realtime, step_up_for_wall_time
from cnc.runtime.table import realtime_priority
from cnc.runtime.child import Runtime, child_setup, set_ready

from .master import NO_PORT, PlcMaster

log = logging.getLogger(__name__)

HEARTBEAT_PERIOD_S = 0.25
LATE_S = 0.1  # a cycle that wakes this much after its deadline is said (`PlcLink.run`)


class PlcLink:
    """The cyclic loop of the PLC-link process over a shared data area."""

    def __init__(self, config: MachineConfig, area: SharedArea, port: str) -> None:
        self.config = config
        self.master = PlcMaster(config.plc, port)
        self.period_s = config.plc.cycle_ms / 1000.0
        self._out_reader = area.reader("plc_out")
        self._writer = area.writer("plc")
        self._writer.load_current()  # a restarted link continues its counters
        self._shutdown = area.blocks["supervisor"].array["shutdown"]
        hb = area.blocks["heartbeat"].array[0]
        self._beat = hb["beat"]
        hb["pid"][Proc.PLC_LINK] = os.getpid()
        n_out = len(self.master.image.outputs)
        self._n_out = n_out
        self._heartbeat_slot = self.master.image.output_index.get("cnc_heartbeat")
        self._heartbeat = 0.0  # the value forwarded to the PLC
        self._heartbeat_due = 0.0
        self._out_idx = self._out_reader.layout.index
        self.late_wakes = 0  # cycles that woke LATE_S or more after their deadline
        self.longest_late_s = 0.0

    def step(self, now_s: float) -> bool:
        """One cycle: exchange the latest output image, publish the result; True when the
        inputs were refreshed."""
        values, _ = self._out_reader.read()
        seq = values[self._out_idx["image_seq"]]
        outputs = list(values[self._out_idx["outputs"]][: self._n_out])
        if self._heartbeat_slot is not None:
            if now_s >= self._heartbeat_due:
                self._heartbeat = outputs[self._heartbeat_slot]
                self._heartbeat_due = now_s + HEARTBEAT_PERIOD_S
            outputs[self._heartbeat_slot] = self._heartbeat
        ok = self.master.cycle(outputs, now_s)
        self._publish(ok, seq)
        return ok

    def _publish(self, ok: bool, seq: int) -> None:
        w, s = self._writer, self.master.status
        w.set("state", int(s.state))
        w.set("exchanges", s.exchanges)
        w.set("failed", s.failed)
        w.set("missed", s.missed)
        w.set("losses", s.losses)
        w.set("dropped", s.dropped)
        w.set("noise", s.noise)
        w.set("cycle_us", int(s.cycle_s * 1e6))
        w.set("error", s.error)
        if ok:
            w.set("input_seq", w.get("input_seq") + 1)
            inputs = self.master.inputs
            w.set("inputs", inputs + [0.0] * (MAX_PLC_VARS - len(inputs)))
            if self.master.writes_pending == 0:
                w.set("output_seq_sent", seq)
        w.publish()

    def run(self) -> None:
        """Cycle until the supervisor sets this process's shutdown bit."""
        my_bit = 1 << Proc.PLC_LINK
        deadline = time.monotonic()
        while not self._shutdown[0] & my_bit:
            self.step(time.monotonic())
            self._beat[Proc.PLC_LINK] += 1
            deadline += self.period_s
            now = time.monotonic()
            if deadline < now:  # an exchange overran: start the next cycle now, do not catch up
                deadline = now
            time.sleep(deadline - now)
            self._note_late(time.monotonic() - deadline)

    def _note_late(self, late_s: float) -> None:
        """Count and say a cycle that woke `late_s` after its deadline, when that is `LATE_S` or
        more: the host did not run the link (its exchanges' own overruns start the next cycle at
        once and are not counted), so a stale input image then is the host's, not the PLC's."""
        if late_s < LATE_S:
            return
        self.late_wakes += 1
        self.longest_late_s = max(self.longest_late_s, late_s)
        log.warning("PLC link: a cycle woke %.0f ms after its deadline (the host did not run the link)", late_s * 1000.0)

    def announce(self) -> None:
        """Before the first exchange: the link is connecting (its port about to open), not down, so
        that the control logic, which may start within milliseconds, waits for it instead of raising
        "PLC link lost: not started". Without a port it stays down: that is what it is."""
        if self.master.port:
            self._writer.set("state", int(LinkState.CONNECTING))
            self._writer.publish()

    def close(self) -> None:
        """Close the port and publish the link as down."""
        self.master.close()
        self._writer.set("state", int(LinkState.DOWN))
        self._writer.publish()
        self._beat = self._shutdown = None


def run_plc_link(rt: Runtime, ready) -> None:
    """Entry point of the PLC-link process (started by the supervisor)."""
    child_setup(rt, "plc-link")
    area = SharedArea.attach(rt.data_name, controller_layouts(len(rt.config.axis_names)))
    port = getattr(rt, "plc_port", "") or rt.config.plc.port
    link = PlcLink(rt.config, area, port)
    if not port:
        log.warning("PLC link: %s", NO_PORT)
    link.announce()
    if rt.clock == "realtime":
        # below the logic: the PLC's safety and plant signals must not wait behind a busy host
        # (a program being planned, fifty observers): three exchanges late is a lost link
        enter_realtime(realtime_priority(rt.config, "plc_link"), "plc link")
    else:
        step_up_for_wall_time(rt.clock)
    set_ready(ready)
    try:
        link.run()
    finally:
        link.close()
        del link
        area.close()
