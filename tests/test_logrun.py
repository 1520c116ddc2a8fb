"""The logging modes on known signals: timed windows, continuous rings kept at the end, triggered spans."""

from __future__ import annotations

import numpy as np
import pytest

from cnc.bus.messages import LogSetting
from cnc.logger.logrun import LogRun, LogSettingError

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

DT = 0.001
KNOWN = ["ramp", "x.following_error", "jet"]


def feed(run: LogRun, first: int, last: int, chunk: int = 37) -> None:
    """Ticks first..last in uneven chunks: ramp = tick, jet on for ticks 300-399 and 700-749."""
    for lo in range(first, last + 1, chunk):
        ticks = np.arange(lo, min(lo + chunk, last + 1))
        jet = (((ticks >= 300) & (ticks < 400)) | ((ticks >= 700) & (ticks < 750))).astype(float)
        run.feed(ticks, {"ramp": ticks.astype(float), "x.following_error": np.where(jet > 0, 0.03, 0.001), "jet": jet})


def test_timed_logs_from_its_start_for_its_duration_at_its_divisor_and_the_run_ends_by_itself():
    run = LogRun([LogSetting("ramp", "timed", divisor=10, start_s=0.2, duration_s=0.1)], KNOWN, DT, tick0=100)
    feed(run, 100, 350)
    assert not run.complete
    feed(run, 351, 500)
    t, v = run.samples("ramp")
    assert np.allclose(t, np.arange(0.2, 0.3 - 1e-9, 0.01)) and list(v) == list(range(300, 400, 10))
    assert run.complete, "every variable timed and past its window"


def test_continuous_keeps_only_the_last_window_in_order_when_the_run_ends():
    run = LogRun([LogSetting("ramp", "continuous", divisor=2, window_s=0.05)], KNOWN, DT, tick0=0)
    feed(run, 0, 999)
    t, v = run.samples("ramp")
    assert len(v) == 25 and list(v) == list(range(950, 1000, 2)), "the last 50 ms, oldest first"
    assert np.allclose(t, v * DT)
    assert not run.complete, "a continuous variable runs until stopped"


def test_triggered_records_while_its_condition_holds_or_between_enable_and_disable():
    while_on = LogSetting("ramp", "triggered", enable_when="jet")
    latched = LogSetting("x.following_error", "triggered", divisor=5, enable_when="x.following_error > 0.02",
                         disable_when="ramp >= 720")
    run = LogRun([while_on, latched], KNOWN, DT, tick0=0)
    feed(run, 0, 999)
    _, v = run.samples("ramp")
    assert list(v) == [*range(300, 400), *range(700, 750)]
    t, fe = run.samples("x.following_error")
    ticks = [int(round(x / DT)) for x in t]
    # on at 300 (error high), held on after the error falls at 400, off at 720 (disable_when); while the
    # error is high again (700-749) each sample it is off re-enables it and the next one disables it
    assert ticks == [*range(300, 720, 5), 725, 735, 745]
    assert fe[0] == 0.03 and fe[-1] == 0.03


def test_the_sample_limit_truncates_and_says_so_and_a_tick_fed_twice_counts_once():
    run = LogRun([LogSetting("ramp", "timed", duration_s=10.0)], KNOWN, DT, tick0=0, max_samples=100)
    feed(run, 0, 80)
    feed(run, 50, 199)  # overlaps: ticks 50-80 again
    _, v = run.samples("ramp")
    assert list(v) == list(range(100)) and run.truncated == ["ramp"]
    assert run.complete, "a truncated timed variable is done"


@pytest.mark.parametrize("setting, message", [
    (LogSetting("nope"), "no log variable 'nope'"),
    (LogSetting("ramp", "sometimes"), "mode 'sometimes' is not one of: timed, continuous, triggered"),
    (LogSetting("ramp", divisor=0), "divisor 0 must be a whole number"),
    (LogSetting("ramp", duration_s=-1.0), "duration_s -1.0 must be 0 or more"),
    (LogSetting("ramp", "continuous", window_s=0.0), "needs window_s > 0"),
    (LogSetting("ramp", "triggered"), "needs enable_when"),
    (LogSetting("ramp", "triggered", enable_when="ramp >"), "enable_when"),
    (LogSetting("ramp", "triggered", enable_when="speed > 3"), "speed"),
])
def test_a_bad_setting_is_refused_naming_the_variable_and_the_field(setting, message):
    with pytest.raises(LogSettingError, match="variable 1 \\(") as err:
        LogRun([setting], KNOWN, DT, tick0=0)
    assert message in str(err.value)
