"""The servo's own controlled stop (IEC 60204-1 category 1): jerk-limited, along the path.

When the servo trips on anything but an e-stop or a mains loss, it does not switch the drives off
and let the table coast: it brings the axes to rest itself, then disables them. Two pieces:

`StopProfile` is the time-optimal stop of a path speed v0 > 0 that starts with acceleration a0,
within a deceleration limit A and a jerk limit J (the machine's axis limits). It has at most three
phases: jerk -J until the deceleration reaches a1 (-A, or less when v0 is small), constant a1,
then jerk +J back to 0 exactly when the speed reaches 0. With a0 = 0 and v0 >= A^2/J its length is

    S = v0^2 / (2 A) + v0 A / (2 J)                      (25 + 6.25 mm from 500 mm/s at 5 m/s^2, 200 m/s^3)

which is the braking term of the stop bound in the README. Closed form, so it costs a few float
operations per tick.

`PathBrake` runs the profile along the setpoints still queued in the FIFO: the planner's own path
(its records are 1 ms apart, so chords are within micrometres of the arcs they sample), at the
profile's speed instead of the planned one. The profile is the fastest possible way down from
the current state, so at every point of the path it is no faster than any speed the planner
could have planned there (a corner the planner slows for, the brake is already slower at); a
record at rest ends the path (an exact-stop corner, a pierce) and the brake ends there. Where the
queue runs out (the planner is gone or starved) the brake goes straight on along the last
direction: "along their current velocity". Nothing is re-planned and nothing waits for the
planner, so the stop starts in the tick that trips, with no FIFO lead run out at full speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

_EPS_MM = 1e-9


class StopProfile:
    """The time-optimal jerk-limited stop from (v0, a0) to rest: `at(t)` gives (s, v, a)."""

    def __init__(self, v0: float, a0: float, max_accel: float, max_jerk: float) -> None:
        if not (max_accel > 0.0 and max_jerk > 0.0):
            raise ValueError(f"a stop needs positive limits, got accel {max_accel!r}, jerk {max_jerk!r}")
        A, J = max_accel, max_jerk
        v0 = max(0.0, v0)
        a0 = min(A, max(-A, a0))
        self.v0, self.a0 = v0, a0
        # phases: (duration, jerk); the state at each phase start is integrated once here
        phases: list[tuple[float, float]] = []
        if v0 > 0.0:
            t2 = (v0 + (a0 * a0 - 2.0 * A * A) / (2.0 * J)) / A
            if t2 >= 0.0:  # reaches -A: jerk down, hold, jerk up
                phases = [((a0 + A) / J, -J), (t2, 0.0), (A / J, J)]
            else:
                a1 = -math.sqrt(J * v0 + 0.5 * a0 * a0)
                if a1 <= a0:  # a triangle: jerk down to a1, then straight back up to 0 at rest
                    phases = [((a0 - a1) / J, -J), (-a1 / J, J)]
                else:  # already braking harder than the rest needs: ease off, v reaches 0 before a does
                    disc = max(0.0, a0 * a0 - 2.0 * J * v0)
                    phases = [((-a0 - math.sqrt(disc)) / J, J)]
        self._starts: list[tuple[float, float, float, float, float]] = []  # (t, s, v, a, jerk)
        t, s, v, a = 0.0, 0.0, v0, a0
        for duration, jerk in phases:
            if duration <= 0.0:
                continue
            self._starts.append((t, s, v, a, jerk))
            s, v, a = _advance(s, v, a, jerk, duration)
            t += duration
        self.duration = t
        self.distance = s

    def at(self, t: float) -> tuple[float, float, float]:
        """(path done, speed, acceleration) at time t after the trip; at rest from `duration` on."""
        if t >= self.duration:
            return self.distance, 0.0, 0.0
        start = self._starts[0]
        for phase in self._starts:
            if phase[0] > t:
                break
            start = phase
        t0, s, v, a, jerk = start
        s, v, a = _advance(s, v, a, jerk, t - t0)
        return s, max(0.0, v), a


def _advance(s: float, v: float, a: float, jerk: float, dt: float) -> tuple[float, float, float]:
    return s + v * dt + a * dt * dt / 2.0 + jerk * dt ** 3 / 6.0, v + a * dt + jerk * dt * dt / 2.0, a + jerk * dt


def stop_distance_bound_mm(speed_mm_s: float, detect_s: float, max_accel: float, max_jerk: float) -> float:
    """The bound a servo-local stop keeps: v T_detect + v^2/(2a) + v a/(2j) + 1 mm."""
    v = abs(speed_mm_s)
    return v * detect_s + v * v / (2.0 * max_accel) + v * max_accel / (2.0 * max_jerk) + 1.0


@dataclass(frozen=True)
class PathPoint:
    """A queued setpoint as the brake sees it: where, and how fast the planner meant to pass it."""

    position: tuple[float, ...]
    speed_mm_s: float


class PathSource(Protocol):
    """The queued path: the next setpoint's position, consumed (None when the queue is empty)."""

    def next_point(self) -> PathPoint | None: ...


class PathBrake:
    """A `StopProfile` run along the queued path from `position`, straight on where it runs out."""

    def __init__(self, position: list[float], velocity: list[float], accel_along: float, max_accel: float,
                 max_jerk: float, dt: float, source: PathSource) -> None:
        speed = math.sqrt(sum(v * v for v in velocity))
        self.here = [float(p) for p in position]
        self.direction = [v / speed for v in velocity] if speed > 0.0 else [0.0] * len(velocity)
        self.profile = StopProfile(speed, accel_along, max_accel, max_jerk)
        self.dt, self.source = dt, source
        self.t = 0.0
        self.s = 0.0  # path run so far
        self.target: PathPoint | None = None
        self.straight = speed <= 0.0  # True once the queue ran out: the rest of the stop goes straight on
        self.at_rest_point = False  # the path came to rest (an exact stop): the brake ends there
        self.speed = speed
        self.done = self.profile.duration <= 0.0

    def step(self, ticks: int = 1) -> tuple[list[float], list[float]]:
        """Advance `ticks` periods; the new setpoint (position, velocity)."""
        if self.done:
            return list(self.here), [0.0] * len(self.here)
        self.t += ticks * self.dt
        s_goal, v, _ = self.profile.at(self.t)
        left = s_goal - self.s
        self.s = s_goal
        while left > _EPS_MM and not self.at_rest_point:
            if self.straight:
                self.here = [p + d * left for p, d in zip(self.here, self.direction)]
                break
            if self.target is None:
                self.target = self.source.next_point()
                if self.target is None:
                    self.straight = True
                continue
            left = self._towards(left)
        if self.at_rest_point:
            self.s -= max(left, 0.0)
            v = 0.0
        self.done = self.at_rest_point or self.t >= self.profile.duration
        self.speed = 0.0 if self.done else v
        return list(self.here), [d * self.speed for d in self.direction]

    def _towards(self, left: float) -> float:
        """Move up to `left` mm towards the target point; the path still to run."""
        target = self.target
        delta = [q - p for p, q in zip(self.here, target.position)]
        d = math.sqrt(sum(x * x for x in delta))
        if d <= _EPS_MM:  # already there: a point at rest ends the path, any other is passed
            self.target = None
            if target.speed_mm_s <= 0.0:
                self.at_rest_point = True
            return left
        self.direction = [x / d for x in delta]
        if d <= left:
            self.here = list(target.position)
            self.target = None
            if target.speed_mm_s <= 0.0:
                self.at_rest_point = True
            return left - d
        self.here = [p + x * (left / d) for p, x in zip(self.here, delta)]
        return 0.0
