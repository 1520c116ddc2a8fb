"""Servo ticks late are alarms: a warning per episode with its count and worst lateness, and an
error that stops the cut when they come faster than `[timing] max_overruns_per_s` allows."""

from __future__ import annotations

from cnc.alarms import AlarmHistory
from cnc.bus.messages import Reset
from cnc.data.layout import ServoState
from cnc.logic.overruns import EPISODE_GAP_S, OverrunWatch
from cnc.logic.states import MachineState

from .conftest import NEAR_HOME, full_controller, logic, machine_config
from .test_logic_process import Events, command, cutting_in_auto, jet_open

PERIOD_S = 0.001


def test_an_episode_raises_a_warning_at_once_and_clears_it_a_second_after_its_last_overrun():
    watch = OverrunWatch(seen=7, period_s=PERIOD_S, limit_per_s=20)
    assert watch.update(7, 0, 10.0) == [], "overruns counted before the watch began are not told"
    [(action, alarm, detail)] = watch.update(10, 3, 10.004)
    assert (action, alarm) == ("raise", "tick_overruns") and "3 ticks late, the worst 3 ms" in detail
    assert watch.update(11, 1, 10.5) == [], "the same episode: nothing new to raise"
    assert watch.update(11, 1, 10.5 + EPISODE_GAP_S - 0.01) == []
    actions = watch.update(11, 1, 10.5 + EPISODE_GAP_S)
    assert [a[:2] for a in actions] == [("clear", "tick_overruns"), ("latch", "tick_overruns")]
    assert "episode over: the servo ran 4 ticks late within 0.5 s, the worst 3 ms" in actions[1][2]
    [(action, _, detail)] = watch.update(12, 1, 20.0)
    assert action == "raise" and "1 tick late, the worst 1 ms" in detail, "a new episode"


def test_an_episode_that_did_not_grow_is_only_cleared():
    watch = OverrunWatch(seen=0, period_s=PERIOD_S, limit_per_s=20)
    watch.update(2, 2, 1.0)
    assert watch.update(2, 2, 1.0 + EPISODE_GAP_S) == [("clear", "tick_overruns", "")]


def test_more_overruns_within_a_second_than_allowed_stop_the_cut_once_per_episode():
    watch = OverrunWatch(seen=0, period_s=PERIOD_S, limit_per_s=5)
    watch.update(3, 3, 1.0)
    [(action, alarm, detail)] = watch.update(6, 3, 1.5)
    assert (action, alarm) == ("fault", "tick_overrun_rate")
    assert "6 ticks late within one second (at most 5, [timing] max_overruns_per_s), the worst 3 ms" in detail
    assert watch.update(9, 3, 1.6) == [], "told once per episode"


def test_overruns_spread_wider_than_a_second_stay_a_warning():
    watch = OverrunWatch(seen=0, period_s=PERIOD_S, limit_per_s=5)
    actions = [a for k in range(8) for a in watch.update(2 * (k + 1), 2, 1.0 + 0.6 * k)]
    assert [a[0] for a in actions] == ["raise"], "2 every 0.6 s: never more than 4 within a second, one episode"


def test_a_restarted_servo_counting_afresh_is_no_overrun():
    watch = OverrunWatch(seen=50, period_s=PERIOD_S, limit_per_s=5)
    assert watch.update(0, 0, 1.0) == [] and watch.update(0, 0, 2.0) == []


def test_a_servo_late_at_rest_is_a_warning_in_the_history_and_nothing_stops(plc_controller):
    sup = plc_controller
    events = Events(sup)
    before = sup.servo()["overruns"]
    sup.stall_servo(3)
    sup.wait_until(lambda: 1015 in events.codes(), 10.0, "the overrun warning")
    assert sup.servo()["overruns"] == before + 3 and not sup.hw()["watchdog_tripped"]
    sup.wait_until(lambda: 1015 in events.codes("cleared"), 10.0, "the episode to end")
    assert 1016 not in events.codes() and logic(sup)["state"] != MachineState.FAULT
    with AlarmHistory(sup.history_path, readonly=True) as history:
        [raised] = [e for e in history.after(0, 1000).entries if e.code == 1015 and e.action == "raised"]
    assert "the servo ran 3 ticks late, the worst 3 ms" in raised.detail and raised.level == "warning"
    events.close()


def test_overruns_faster_than_allowed_during_a_cut_close_the_jet_and_stop_then_reset_recovers(tmp_path):
    config = machine_config(**NEAR_HOME, **{"timing.max_overruns_per_s": 5})
    with full_controller(config, tmp_path / "history.sqlite") as sup:
        events = Events(sup)
        cutting_in_auto(sup, tmp_path)
        jet = lambda: jet_open(sup)  # noqa: E731
        before = sup.servo()["overruns"]
        sup.stall_servo(3)
        sup.wait_until(lambda: sup.servo()["overruns"] == before + 3, 10.0, "the first three ticks late")
        sup.stall_servo(3)
        sup.wait_until(lambda: 1016 in events.codes(), 10.0, "the overrun-rate error")
        assert 1015 in events.codes() and not sup.hw()["watchdog_tripped"], "late, but never 5 ticks in a row"
        sup.wait_until(lambda: not jet() and logic(sup)["state"] == MachineState.FAULT
                       and sup.motion()["state"] == 0, 30.0, "the jet closed and the cut stopped")
        sup.wait_until(lambda: 1015 in events.codes("cleared"), 10.0, "the episode to end")
        assert command(sup, Reset()) == ""
        sup.wait_until(lambda: logic(sup)["state"] in (MachineState.READY, MachineState.IDLE)
                       and sup.servo()["state"] == ServoState.HOLDING, 20.0, "recovered by the reset")
        events.close()
