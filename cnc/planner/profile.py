"""Jerk-limited motion along one section of the path, between two stops.

A section is a stretch of path the head runs without stopping; each element of it has its
own velocity limit (`limits.py`), so the limit is a step function of the path length s.
The motion s(t) is made one servo period at a time, as an online trajectory generator:

- towards the limit of the zone it is in (ruckig's velocity interface: jerk-limited, the
  acceleration carried across element boundaries, so CAM polylines do not stop and go);
- braking for a slower zone ahead when it can wait no longer: when one more period of the
  hardest acceleration would leave less room than the braking distance from there;
- and the end counts as one more zone, of limit 0: once braking for it has begun and the
  speed is within every limit left, ruckig's position interface stops it exactly there.

The braking distance from (v0, a0) to v1 with the acceleration back at zero is taken from
the closed form of the symmetric jerk-limited ramp,

    dv = v0 - v1;  T = dv/A + A/J  if dv >= A^2/J,  else 2 sqrt(dv/J);   d = (v0 + v1) T / 2,

after first letting a positive a0 fall to zero (which raises v0 by a0^2 / 2J): a bound,
never short of the real distance, so braking starts early rather than late.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from ruckig import ControlInterface, InputParameter, OutputParameter, Result, Ruckig, RuckigError

ZONE_EPS_MM = 1e-9


@dataclass(frozen=True, slots=True)
class Zone:
    """Part of the section [start_mm, end_mm) where the path velocity may not exceed v_max_mm_s."""

    start_mm: float
    end_mm: float
    v_max_mm_s: float


def braking_distance(v0: float, a0: float, v1: float, a_max: float, j_max: float) -> float:
    """An upper bound of the distance a jerk-limited stop from (v0, a0) to v1 (a = 0 there) needs."""
    extra = 0.0
    if a0 > 0.0:  # the acceleration must first come down to zero: the speed still rises meanwhile
        t = a0 / j_max
        extra = v0 * t + a0 * t * t / 2.0
        v0 += a0 * a0 / (2.0 * j_max)
    dv = v0 - v1
    if dv <= 0.0:
        return extra
    t = dv / a_max + a_max / j_max if dv * j_max >= a_max * a_max else 2.0 * math.sqrt(dv / j_max)
    return extra + (v0 + v1) * t / 2.0


def _update(otg: Ruckig, inp: InputParameter, out: OutputParameter) -> Result:
    """One ruckig step; a state exactly at the acceleration limit can trip ruckig's numerics
    (e.g. v 312.5000000000002, a 5000 towards 250 fails where v 312.5 works): nudge it in by 1e-9."""
    try:
        return otg.update(inp, out)
    except RuckigError:
        inp.current_acceleration = [inp.current_acceleration[0] * (1.0 - 1e-9)]
        return otg.update(inp, out)


class SectionMotion:
    """s(t) over one section: `run()` returns (s, v, a) at every servo period until at rest at the end."""

    def __init__(self, zones: list[Zone], a_max: float, j_max: float, dt: float, v_start: float = 0.0) -> None:
        if not zones:
            raise ValueError("a section needs at least one zone")
        self.zones = zones
        self.length = zones[-1].end_mm
        self.a_max, self.j_max, self.dt = a_max, j_max, dt
        self.v_start = v_start
        # the end is one more zone, of limit 0: braking for it is braking for any slower zone
        self.starts = np.array([z.start_mm for z in zones] + [self.length])
        self.vmax = np.array([z.v_max_mm_s for z in zones] + [0.0])
        # the lowest limit from each zone to the end: the final approach may not exceed it
        self.v_rest = np.minimum.accumulate(self.vmax[:-1][::-1])[::-1]

    def run(self) -> np.ndarray:
        # a bound no real run reaches: the whole length at the slowest limit, twice, plus a minute
        slowest = max(float(self.vmax[:-1].min()), 1e-3)
        max_steps = int((2.0 * self.length / slowest + 60.0) / self.dt)
        otg = Ruckig(1, self.dt)
        inp, out = InputParameter(1), OutputParameter(1)
        inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0], [self.v_start], [0.0]
        inp.max_acceleration, inp.max_jerk = [self.a_max], [self.j_max]
        inp.control_interface = ControlInterface.Velocity
        inp.target_acceleration = [0.0]
        samples: list[tuple[float, float, float]] = []
        final = False
        for _ in range(max_steps):
            s, v, a = inp.current_position[0], inp.current_velocity[0], inp.current_acceleration[0]
            k = min(max(int(np.searchsorted(self.starts, s, side="right")) - 1, 0), len(self.zones) - 1)
            if not final:
                target = self._target(k, s, v, a)
                if target == 0.0 and v <= self.v_rest[k] + 1e-9:
                    # braking for the end, within every limit left: stop exactly there
                    final = True
                    inp.control_interface = ControlInterface.Position
                    inp.target_position, inp.target_velocity = [self.length], [0.0]
                else:
                    inp.max_velocity = [float(self.vmax[k])]
                    inp.target_velocity = [target]
            if final:
                inp.max_velocity = [max(float(self.v_rest[k]), v, 1e-9)]
            result = _update(otg, inp, out)
            if result not in (Result.Working, Result.Finished):
                raise RuntimeError(f"motion along the section failed at s={s:.3f} mm: {result}")
            samples.append((out.new_position[0], out.new_velocity[0], out.new_acceleration[0]))
            out.pass_to_input(inp)
            if final and result == Result.Finished:
                break
        else:
            raise RuntimeError(f"the section of {self.length:.3f} mm did not end within {max_steps} periods")
        return np.array(samples)

    def _target(self, k: int, s: float, v: float, a: float) -> float:
        """The zone's limit, or a slower zone's ahead when braking can wait no longer: if it does
        not start now, one more period of the hardest acceleration could leave too little room."""
        target = float(self.vmax[k])
        ds, v_next, a_next = self._worst_next(v, a)
        # Slowing to some v1 > 0 can take longer than stopping (faster on average for a similar
        # time): (v0 + v1) <= 2 v0 and T(v0 - v1) <= T(v0) bound every such distance by twice the stop.
        horizon = 2.0 * braking_distance(max(v_next, target), a_next, 0.0, self.a_max, self.j_max) + ds
        for z in range(k + 1, len(self.starts)):
            ahead = self.starts[z] - s
            if ahead > horizon:
                break  # beyond any braking distance: nothing further can matter yet
            vz = float(self.vmax[z])
            if vz < target and ahead - ds <= braking_distance(v_next, a_next, vz, self.a_max, self.j_max):
                target = vz
        return target

    def _worst_next(self, v: float, a: float) -> tuple[float, float, float]:
        """Distance, velocity and acceleration after one more period of pushing the acceleration up at full jerk."""
        dt, j = self.dt, self.j_max
        a_next = min(a + j * dt, self.a_max)
        v_next = v + (a + a_next) * dt / 2.0
        ds = v * dt + a * dt * dt / 2.0 + j * dt**3 / 6.0
        return ds, v_next, a_next
