"""Tick overruns as alarms: the servo late, counted by the servo itself, told to the operator.

The servo counts the ticks it skipped (`overruns` in its block: the tick counter ran ahead of it,
a host that did not run it in time) and how many it skipped at its latest overrun. An episode
is a run of overruns with less than `EPISODE_GAP_S` between them. It raises the warning
`tick_overruns` at once, with the count and the worst lateness found in that scan, and when it
ends (after `EPISODE_GAP_S` without a new overrun) the warning is cleared, and an episode that
grew after it was raised is latched a second time with its totals. More than `[timing]
max_overruns_per_s` overruns within one second raise the error `tick_overrun_rate`, which stops
the cut: a host that late cannot be trusted with the servo's period.

The worst lateness is read at each scan of the logic (every few ticks): two overruns within one
scan show as the later one's.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

EPISODE_GAP_S = 1.0  # an episode ends this long after its last overrun
RATE_WINDOW_S = 1.0


@dataclass
class Episode:
    start_s: float
    last_s: float
    count: int = 0
    worst_ticks: int = 0
    told_count: int = 0  # the count when the warning was raised
    stopped: bool = False  # the rate error was raised in this episode


class OverrunWatch:
    """Turns the servo's overrun counter into alarm actions (`update`)."""

    def __init__(self, seen: int, period_s: float, limit_per_s: int) -> None:
        self.seen = seen  # overruns counted before the watch began are not told
        self.period_s = period_s
        self.limit_per_s = limit_per_s
        self.episode: Episode | None = None
        self._recent: deque[tuple[float, int]] = deque()  # (when, how many) within the rate window

    def update(self, count: int, last_ticks: int, now_s: float) -> list[tuple[str, str, str]]:
        """The servo's counters at time `now_s`: what to do, as (action, alarm id, detail) with
        action "raise" (a condition, active until cleared), "clear", "latch" (an event, listed
        until reset) or "fault" (latched, and the cut stops)."""
        new = count - self.seen
        self.seen = count
        if new < 0:  # a restarted servo counts afresh
            return []
        out: list[tuple[str, str, str]] = []
        ep = self.episode
        if new > 0:
            if ep is None:
                ep = self.episode = Episode(now_s, now_s)
            ep.count += new
            ep.last_s = now_s
            ep.worst_ticks = max(ep.worst_ticks, last_ticks)
            self._recent.append((now_s, new))
            while self._recent and self._recent[0][0] <= now_s - RATE_WINDOW_S:
                self._recent.popleft()
            if not ep.told_count:
                ep.told_count = ep.count
                out.append(("raise", "tick_overruns", f"the servo ran {self._ticks(ep.count)} late, the worst "
                                                      f"{self._ms(ep.worst_ticks)}: the host did not run it in time"))
            in_window = sum(n for _, n in self._recent)
            if in_window > self.limit_per_s and not ep.stopped:
                ep.stopped = True
                out.append(("fault", "tick_overrun_rate",
                            f"the servo ran {self._ticks(in_window)} late within one second (at most {self.limit_per_s}, "
                            f"[timing] max_overruns_per_s), the worst {self._ms(ep.worst_ticks)}"))
        elif ep is not None and now_s - ep.last_s >= EPISODE_GAP_S:
            out.append(("clear", "tick_overruns", ""))
            if ep.count > ep.told_count:
                out.append(("latch", "tick_overruns", f"episode over: the servo ran {self._ticks(ep.count)} late within "
                                                      f"{ep.last_s - ep.start_s:.1f} s, the worst {self._ms(ep.worst_ticks)}"))
            self.episode = None
            self._recent.clear()
        return out

    @staticmethod
    def _ticks(n: int) -> str:
        return f"{n} tick" if n == 1 else f"{n} ticks"

    def _ms(self, ticks: int) -> str:
        return f"{ticks * self.period_s * 1000:g} ms"
