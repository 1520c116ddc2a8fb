"""The pump pressure the control logic asked the PLC for, followed: reached yet, and the floor the
tick holds the pump to while the jet cuts.

Pure: the logic hands it the set point in force, the output image that carries it and what the
PLC link last published. A set point counts as reached only on a reading the PLC took after it
had that set point. The link reads the inputs before it writes the changed outputs in each
exchange, and a pierce changes the set point faster than the pressure follows (cut pressure,
low for the next pierce, cut pressure again within a second): judged on an earlier reading,
still at the old pressure, a set point the pump is only now turning towards would count as
reached, and the floor would rise above a pressure that is still falling.
"""

from __future__ import annotations

from dataclasses import dataclass

from cnc.config import PumpConfig


@dataclass(frozen=True)
class PlcView:
    """What the PLC link last published, as far as the pressure goes."""

    link_ok: bool
    output_seq_sent: int  # the output image (plc_out.image_seq) the PLC has been sent in full
    input_seq: int  # +1 at every input image read
    pressure_bar: float


class PressureWatch:
    """Follows one pump: the set point in force, whether the pressure reached it, the last set
    point it reached (a drop below that while cutting is a fault, even while ramping to a new one)."""

    def __init__(self, pump: PumpConfig) -> None:
        self.pump = pump
        self.set_bar: float | None = None
        self.reached = False  # the pressure reached the set point in force
        self.reached_bar = 0.0  # the last set point the pressure reached (0: none since the pump started)
        self.changed_at = 0.0  # when the set point in force was asked for (the logic's clock)
        self._image = 0  # the output image that carries the set point in force
        self._written_input: int | None = None  # the input image published with that write (read before it)

    def follow(self, set_bar: float, pump_on: bool, carrying_image: int, plc: PlcView, now: float) -> None:
        """One scan: the set point in force (`carrying_image`: the output image that carries it)."""
        if not pump_on:
            self.reached_bar = 0.0
        if set_bar != self.set_bar:
            self.set_bar, self.reached, self.changed_at = set_bar, False, now
            self._image, self._written_input = carrying_image, None
            # lowered on purpose (low pressure for the next pierce), the pressure may fall as far as the
            # new set point, and rise from there when the cutting pressure follows before it got there
            self.reached_bar = min(self.reached_bar, set_bar)
        elif not self.reached and pump_on and self._read_after_set(plc):
            self.reached = abs(plc.pressure_bar - set_bar) <= self.pump.tolerance_bar
            if self.reached:
                self.reached_bar = set_bar

    def _read_after_set(self, plc: PlcView) -> bool:
        if not plc.link_ok:
            return False
        if self._written_input is None:
            if plc.output_seq_sent < self._image:
                return False
            self._written_input = plc.input_seq  # its inputs were read just before the write
        return plc.input_seq > self._written_input

    def reached_at(self, bar: float) -> bool:
        """The pump holds `bar`: the set point in force, confirmed by a reading taken after the PLC had it."""
        return self.reached and self.set_bar == bar

    def holding_bar(self) -> float:
        """The pressure the pump must hold now: the set point once reached, else the last one reached."""
        return (self.set_bar or 0.0) if self.reached else self.reached_bar

    def floor_bar(self) -> float:
        """The tick's floor while the jet cuts: what the pump must hold less `[pump] drop_bar` (0: none)."""
        holding = self.holding_bar()
        return max(0.0, holding - self.pump.drop_bar) if holding else 0.0

    def fault(self, pressure_bar: float, now: float) -> str | None:
        """While cutting with the jet open: the pressure fell below the floor, or never got to the set point."""
        holding = self.holding_bar()
        if holding and pressure_bar < holding - self.pump.drop_bar:
            return f"pressure fell to {pressure_bar:.0f} bar while cutting at {holding:.0f} bar"
        if not self.reached and now - self.changed_at > self.pump.ramp_timeout_s:
            return f"the pump did not reach {self.set_bar or 0.0:.0f} bar within {self.pump.ramp_timeout_s:g} s while cutting"
        return None
