"""SimBoard: the simulated XY table (drives, mechanics, switches, encoders) behind `IOBoard`.

Plant model of one axis
-----------------------
The drive is a P velocity loop, modelled as a first-order lag towards the commanded velocity
and limited by the drive's current limit; friction has a viscous and a Coulomb (dry) part:

    v_cmd   = clamp(U, +-drive_full_scale_v) / volts_per_mm_s
    a_drive = clamp((v_cmd - v) / tau, +-a_max)          (0 when the power stage is off)
    dv/dt   = a_drive - f * (b * v + c * sign(v))        (f: injectable friction scale)

At rest (v = 0) static friction holds the axis while |a_drive| <= f * c; the axis breaks
loose in the direction of a_drive otherwise.

Between three kinds of events the right-hand side is linear, dv/dt = u - k v, with
    lag region   |v_cmd - v| <= a_max * tau:   k = 1/tau + f b,  u = v_cmd/tau - f c s
    current limit (sigma = +-1):               k = f b,          u = sigma a_max - f c s
    power stage off:                           k = f b,          u = -f c s
(s = sign(v)), whose exact solution over a time t is
    v(t) = E v + G u,   p(t) = p + G v + H u,
    E = exp(-k t),  G = (1 - E) / k,  H = (t - G) / k      (G -> t, H -> t^2/2 as k -> 0).
The events are: v reaching 0 (Coulomb friction changes sign, or static friction takes over,
so friction never reverses the motion) and v entering or leaving the lag region. Each
sub-step is split at its events, so the integration is exact up to rounding; without an
event a sub-step costs one precomputed (E, G, H) triple. The pieces between events are
monotonic in position, which is where the end stops and the encoder index are checked.

Switches and encoder
--------------------
End stops sit at travel_min/max -+ hard_stop_overtravel_mm; a piece that ends beyond one is
clamped to it with the velocity zeroed (the axis then rests there for the rest of the
sub-step). Limit switches are active at or beyond travel_min/max -+ limit_switch_overtravel_mm,
the home switch at or below home_switch_mm.

Encoder counts are round-to-nearest, halves rounding up:
    counts = floor((p - encoder_zero_mm) / encoder_resolution_mm + 0.5)
An index pulse fires at every multiple of index_pitch_mm (measured from machine zero) the
table crosses, in either direction; the board latches the count of the exact crossing
position, like the index latch of a real encoder interface. A position exactly on a mark
counts as above it (cells [n, n+1) pitches), so the pulse fires on leaving it downwards or
reaching it upwards. When several pulses fire within one piece, the sequence advances by
their number and the latch holds the last one.
"""

from __future__ import annotations

import math

from cnc.config import AxisConfig, ConfigError, MachineConfig, SimAxisConfig
from cnc.hw.board import AxisIn, BoardInputs, DigitalIn, DigitalOut, IOBoard

# Plain ints: IntFlag arithmetic goes through the enum machinery, too slow for the tick path.
_LIMIT_MIN = int(AxisIn.LIMIT_MIN)
_LIMIT_MAX = int(AxisIn.LIMIT_MAX)
_HOME = int(AxisIn.HOME)
_INDEX = int(AxisIn.INDEX)
_DRIVE_READY = int(AxisIn.DRIVE_READY)
_DRIVE_ENABLED = int(AxisIn.DRIVE_ENABLED)
_ESTOP_OK = int(DigitalIn.ESTOP_OK)
_DOORS_CLOSED = int(DigitalIn.DOORS_CLOSED)
_MAINS_ON = int(DigitalIn.MAINS_ON)
_ALL_OUTPUTS = sum(int(o) for o in DigitalOut)  # the board has these outputs and no others

# A sub-step has at most a zero crossing and a region change or two; more pieces only arise
# from rounding at an event boundary, and the last allowed piece ignores further events.
_MAX_PIECES = 8


def _lin_coeffs(k: float, t: float) -> tuple[float, float, float]:
    """(E, G, H) of the exact solution of dv/dt = u - k v over a time t (see module doc)."""
    kt = k * t
    if kt < 1.0e-4:
        # Series: exact for k = 0 and free of the cancellation in (t - G) / k.
        return math.exp(-kt), t * (1.0 - kt / 2.0 + kt * kt / 6.0), t * t * (0.5 - kt / 6.0 + kt * kt / 24.0)
    g = -math.expm1(-kt) / k
    return math.exp(-kt), g, (t - g) / k


def _time_to(v: float, v_target: float, k: float, u: float, t_max: float) -> float:
    """Time for dv/dt = u - k v to take v to v_target (which lies ahead), within [0, t_max]."""
    if k > 0.0:
        den = v_target - u / k
        ratio = (v - v_target) / den if den != 0.0 else -1.0
        if not ratio > 0.0:  # rounding put the target at or beyond the asymptote u / k
            return t_max
        t = math.log1p(ratio) / k
    else:
        t = (v_target - v) / u if u != 0.0 else t_max
    if not t >= 0.0:  # rounding at a boundary, or NaN
        return 0.0
    return t if t < t_max else t_max


class _AxisPlant:
    """Parameters and true state of one simulated axis; `advance` integrates it."""

    __slots__ = (
        "position_mm", "velocity_mm_s", "driving", "fault",
        "index_seen", "index_latch_counts", "index_latch_seq", "_index_cell",
        "_full_scale_v", "_volts_per_mm_s", "_v_cmd", "_v_lo", "_v_hi",
        "_inv_tau", "_a_max", "_band_mm_s", "_viscous_1_s", "_coulomb_mm_s2",
        "_b", "_c", "_k_lag",
        "_h", "_lag_egh", "_free_egh",
        "_stop_min_mm", "_stop_max_mm", "_limit_min_mm", "_limit_max_mm", "_home_mm",
        "_pitch_mm", "_encoder_zero_mm", "_resolution_mm",
    )

    def __init__(self, name: str, axis: AxisConfig, sim: SimAxisConfig, source: str) -> None:
        self._full_scale_v = axis.drive_full_scale_v
        self._volts_per_mm_s = axis.volts_per_mm_s
        self._inv_tau = 1.0 / sim.drive_time_constant_s
        self._a_max = sim.max_accel_mm_s2
        # Half-width of the velocity band around v_cmd where the lag does not hit the current limit.
        self._band_mm_s = sim.max_accel_mm_s2 * sim.drive_time_constant_s
        self._viscous_1_s = sim.viscous_friction_1_s
        self._coulomb_mm_s2 = sim.coulomb_friction_mm_s2
        self._stop_min_mm = axis.travel_min_mm - sim.hard_stop_overtravel_mm
        self._stop_max_mm = axis.travel_max_mm + sim.hard_stop_overtravel_mm
        self._limit_min_mm = axis.travel_min_mm - sim.limit_switch_overtravel_mm
        self._limit_max_mm = axis.travel_max_mm + sim.limit_switch_overtravel_mm
        self._home_mm = sim.home_switch_mm
        self._pitch_mm = sim.index_pitch_mm
        self._encoder_zero_mm = sim.encoder_zero_mm
        self._resolution_mm = axis.encoder_resolution_mm

        start = sim.start_position_mm
        if math.isnan(start):
            start = 0.5 * (axis.travel_min_mm + axis.travel_max_mm)
        elif not self._stop_min_mm <= start <= self._stop_max_mm:
            raise ConfigError(
                source, f"sim.axes.{name}", "start_position_mm",
                f"{start:g} mm lies beyond the end stops ({self._stop_min_mm:g} to {self._stop_max_mm:g} mm)",
            )
        self.position_mm = start
        self.velocity_mm_s = 0.0
        self.driving = False
        self.fault = False
        self.index_seen = False
        self.index_latch_counts = 0
        self.index_latch_seq = 0
        self._index_cell = math.floor(start / self._pitch_mm)
        self.set_command_v(0.0)
        self.set_friction_scale(1.0)

    def set_command_v(self, volts: float) -> None:
        volts = float(volts)  # keep the plant in Python floats even when fed numpy scalars
        fs = self._full_scale_v
        volts = fs if volts > fs else (-fs if volts < -fs else volts)
        v_cmd = volts / self._volts_per_mm_s
        self._v_cmd = v_cmd
        self._v_lo = v_cmd - self._band_mm_s
        self._v_hi = v_cmd + self._band_mm_s

    def set_friction_scale(self, scale: float) -> None:
        self._b = scale * self._viscous_1_s
        self._c = scale * self._coulomb_mm_s2
        self._k_lag = self._inv_tau + self._b
        self._h = -1.0  # invalidate the per-sub-step coefficients

    def encoder_counts(self, position_mm: float) -> int:
        return math.floor((position_mm - self._encoder_zero_mm) / self._resolution_mm + 0.5)

    def input_word(self, power_on: bool) -> int:
        p = self.position_mm
        word = 0 if self.fault else _DRIVE_READY
        if p <= self._limit_min_mm:
            word |= _LIMIT_MIN
        if p >= self._limit_max_mm:
            word |= _LIMIT_MAX
        if p <= self._home_mm:
            word |= _HOME
        if self.index_seen:
            word |= _INDEX
        if power_on:
            word |= _DRIVE_ENABLED
        return word

    def advance(self, dt_s: float, substeps: int) -> None:
        h = dt_s / substeps
        if h != self._h:
            self._h = h
            self._lag_egh = _lin_coeffs(self._k_lag, h)
            self._free_egh = _lin_coeffs(self._b, h)
        self.index_seen = False
        for _ in range(substeps):
            self._substep(h)

    def _substep(self, h: float) -> None:
        p = self.position_mm
        v = self.velocity_mm_s
        driving = self.driving
        v_lo = self._v_lo
        v_hi = self._v_hi
        # sigma: +1 / -1 while the current limit clamps the drive's acceleration, 0 in the lag
        # region (and always 0 with the power stage off)
        sigma = (1 if v < v_lo else (-1 if v > v_hi else 0)) if driving else 0
        left = h
        for piece in range(_MAX_PIECES):
            lag = driving and sigma == 0
            if lag:
                k = self._k_lag
                u = self._v_cmd * self._inv_tau
            else:
                k = self._b
                u = sigma * self._a_max
            # u is now the drive's acceleration at v = 0; add Coulomb friction
            c = self._c
            if v == 0.0:
                if -c <= u <= c:
                    break  # static friction holds the axis for the rest of the sub-step
                s = 1.0 if u > 0.0 else -1.0
            else:
                s = 1.0 if v > 0.0 else -1.0
            u -= c * s
            if left == h:
                e, g, hh = self._lag_egh if lag else self._free_egh
            else:
                e, g, hh = _lin_coeffs(k, left)
            v_end = e * v + g * u
            end_sigma = (1 if v_end < v_lo else (-1 if v_end > v_hi else 0)) if driving else 0
            if (v_end * s < 0.0 or end_sigma != sigma) and piece < _MAX_PIECES - 1:
                t, v_end, sigma = self._first_event(v, v_end, s, k, u, left, sigma)
                e, g, hh = _lin_coeffs(k, t)
                left -= t
            else:
                left = 0.0
            p += g * v + hh * u
            v = v_end

            at_stop = False
            if p < self._stop_min_mm:
                p, v, at_stop = self._stop_min_mm, 0.0, True
            elif p > self._stop_max_mm:
                p, v, at_stop = self._stop_max_mm, 0.0, True
            cell = math.floor(p / self._pitch_mm)
            if cell != self._index_cell:
                self._latch_index(cell)
            if at_stop or left <= 0.0:
                break
        self.position_mm = p
        self.velocity_mm_s = v

    def _first_event(
        self, v: float, v_end: float, s: float, k: float, u: float, left: float, sigma: int
    ) -> tuple[float, float, int]:
        """(time, velocity, sigma after it) of the first event between v and v_end."""
        zero_crossing = v_end * s < 0.0  # v reaches 0, where Coulomb friction changes direction
        t, v_event, new_sigma = left, v_end, sigma
        if zero_crossing:
            t, v_event = _time_to(v, 0.0, k, u, left), 0.0
        if not self.driving:
            return t, v_event, new_sigma
        v_lo, v_hi = self._v_lo, self._v_hi
        if sigma == 0:  # leaving the lag region into the current limit
            if v_end < v_lo:
                edge, to_sigma = v_lo, 1
            elif v_end > v_hi:
                edge, to_sigma = v_hi, -1
            else:
                return t, v_event, new_sigma
        elif (v_end > v_lo) if sigma > 0 else (v_end < v_hi):  # entering the lag region
            edge, to_sigma = (v_lo if sigma > 0 else v_hi), 0
        else:
            return t, v_event, new_sigma
        t_edge = _time_to(v, edge, k, u, left)
        if zero_crossing and t <= t_edge:
            return t, v_event, new_sigma
        return t_edge, edge, to_sigma

    def _latch_index(self, cell: int) -> None:
        """The position moved from index cell `_index_cell` to `cell` (cell n = [n, n+1) pitches)."""
        old = self._index_cell
        # The crossed multiple nearest the new position: the lower edge of the new cell when
        # moving up, its upper edge when moving down.
        edge = cell if cell > old else cell + 1
        self.index_latch_counts = self.encoder_counts(edge * self._pitch_mm)
        self.index_latch_seq += abs(cell - old)
        self.index_seen = True
        self._index_cell = cell


class SimBoard(IOBoard):
    """Simulated I/O board driving the plant models of `config.sim`, one per configured axis.

    Axis i is `config.axis_names[i]` and bit i of the drive-enable mask. Besides `IOBoard`
    it offers fault injection (`set_estop`, `set_doors`, `set_mains`, `set_drive_fault`,
    `set_friction_scale`, `force_limit_switch`) and read-only access to the true plant state
    (`position_mm`, `velocity_mm_s`) for tests that compare it with the encoder.

    A drive's power stage is on while its enable bit is set, it has no fault, the e-stop is not
    pressed and the mains are on; only then does it accelerate the axis. The e-stop circuit and
    a mains loss also cut the digital outputs. `safe_state()` zeroes commands, enables and
    outputs until the next `write_outputs()`. The output watchdog (`arm_output_watchdog`) counts
    the board's own time, which `advance()` moves: outputs not refreshed within its timeout are
    dropped, as a real board's watchdog drops them.
    """

    def __init__(self, config: MachineConfig) -> None:
        self.axis_names = config.axis_names
        self.n_axes = len(self.axis_names)
        self._substeps = config.sim.substeps
        self._plants = [
            _AxisPlant(name, config.axis[name], config.sim.axis(name), config.source) for name in self.axis_names
        ]
        self._enable_mask = 0
        self._digital_out = 0
        self._estop_pressed = False
        self._doors_open = False
        self._mains_on = True
        self._forced_limits = [0] * self.n_axes
        self._watchdog_s = 0.0  # 0: not armed
        self._since_write_s = 0.0
        self.watchdog_expired = False  # the outputs were dropped because nobody refreshed them

    # -- IOBoard -------------------------------------------------------------------------

    def write_outputs(self, speed_cmd_v: list[float], drive_enable_mask: int, digital_out: int) -> None:
        if len(speed_cmd_v) != self.n_axes:
            raise ValueError(f"speed_cmd_v has {len(speed_cmd_v)} values, the board has {self.n_axes} axes")
        for volts in speed_cmd_v:
            if volts != volts:
                raise ValueError(f"speed command is NaN: speed_cmd_v = {list(speed_cmd_v)!r}")
        plants = self._plants
        for i in range(self.n_axes):
            plants[i].set_command_v(speed_cmd_v[i])
        self._enable_mask = int(drive_enable_mask)
        self._digital_out = int(digital_out) & _ALL_OUTPUTS
        self._since_write_s = 0.0
        self.watchdog_expired = False

    def advance(self, dt_s: float) -> None:
        if not 0.0 < dt_s < math.inf:
            raise ValueError(f"dt_s must be a positive time, got {dt_s!r}")
        if self._watchdog_s > 0.0:
            self._since_write_s += dt_s
            if self._since_write_s > self._watchdog_s + 1e-12 and not self.watchdog_expired:
                self._drop_outputs()
                self.watchdog_expired = True
        substeps = self._substeps
        plants = self._plants
        for i in range(self.n_axes):
            plant = plants[i]
            plant.driving = self._power_on(i)
            plant.advance(dt_s, substeps)

    def read_inputs(self, into: BoardInputs) -> None:
        plants = self._plants
        for i in range(self.n_axes):
            plant = plants[i]
            into.encoder_counts[i] = plant.encoder_counts(plant.position_mm)
            into.axis_inputs[i] = plant.input_word(self._power_on(i)) | self._forced_limits[i]
            into.index_latch_counts[i] = plant.index_latch_counts
            into.index_latch_seq[i] = plant.index_latch_seq
        digital_in = 0
        if not self._estop_pressed:
            digital_in |= _ESTOP_OK
        if not self._doors_open:
            digital_in |= _DOORS_CLOSED
        if self._mains_on:
            digital_in |= _MAINS_ON
        into.digital_in = digital_in
        into.digital_out = 0 if self._estop_pressed or not self._mains_on else self._digital_out

    def safe_state(self) -> None:
        self._drop_outputs()
        self._since_write_s = 0.0

    def arm_output_watchdog(self, timeout_s: float) -> None:
        if not 0.0 < timeout_s < math.inf:
            raise ValueError(f"timeout_s must be a positive time, got {timeout_s!r}")
        self._watchdog_s = float(timeout_s)
        self._since_write_s = 0.0

    def _drop_outputs(self) -> None:
        for plant in self._plants:
            plant.set_command_v(0.0)
        self._enable_mask = 0
        self._digital_out = 0

    def _power_on(self, axis: int) -> bool:
        return ((self._enable_mask >> axis) & 1 == 1 and not self._plants[axis].fault and not self._estop_pressed
                and self._mains_on)

    # -- fault injection and true plant state ---------------------------------------------

    def set_estop(self, pressed: bool) -> None:
        """Press (True) or release (False) the e-stop: drives lose power, outputs are cut."""
        self._estop_pressed = bool(pressed)

    def set_doors(self, open_: bool) -> None:
        """Open (True) or close (False) the safety doors (DigitalIn.DOORS_CLOSED)."""
        self._doors_open = bool(open_)

    def set_mains(self, on: bool) -> None:
        """Switch the machine mains on (True) or off (False): off, the drives lose their power and the
        outputs are cut (DigitalIn.MAINS_ON reads back the contactor)."""
        self._mains_on = bool(on)

    def force_limit_switch(self, axis: int, at_min: bool, at_max: bool) -> None:
        """Hold axis `axis`'s limit switches active whatever the table's position (a tripped or
        stuck switch); False, False gives them back to the table."""
        self._forced_limits[self._check_axis(axis)] = (_LIMIT_MIN if at_min else 0) | (_LIMIT_MAX if at_max else 0)

    def set_drive_fault(self, axis: int, fault: bool) -> None:
        """Give axis `axis` a drive fault (True) or clear it: no DRIVE_READY, no power stage."""
        self._plants[self._check_axis(axis)].fault = bool(fault)

    def set_friction_scale(self, axis: int, scale: float) -> None:
        """Multiply axis `axis`'s viscous and Coulomb friction by `scale` (default 1.0)."""
        plant = self._plants[self._check_axis(axis)]
        if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not 0.0 <= scale < math.inf:
            raise ValueError(f"scale must be a finite number >= 0, got {scale!r}")
        plant.set_friction_scale(float(scale))

    def position_mm(self, axis: int) -> float:
        """True table position of axis `axis` (not quantised by the encoder)."""
        return self._plants[self._check_axis(axis)].position_mm

    def velocity_mm_s(self, axis: int) -> float:
        """True velocity of axis `axis`."""
        return self._plants[self._check_axis(axis)].velocity_mm_s

    def _check_axis(self, axis: int) -> int:
        if isinstance(axis, bool) or not isinstance(axis, int) or not 0 <= axis < self.n_axes:
            raise ValueError(f"axis must be an axis index 0 to {self.n_axes - 1}, got {axis!r}")
        return axis
