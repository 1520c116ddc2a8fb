"""The command lock's state: tokens Zenoh shows, stations that stopped answering, who holds it."""

from __future__ import annotations

import threading

import pytest

from cnc.bus.service import CommandRefused
from cnc.gateway.lock import OperatorLock, Token

PANEL = Token("local", "panel", "s1")
DESK = Token("ops", "desk", "s2")


def test_a_holder_that_stops_answering_loses_the_lock_and_counts_again_once_it_answers():
    lock = OperatorLock()
    lock.token_alive(PANEL)
    lock.take("local", "panel")
    assert lock.token_silent(PANEL), "it held the lock"
    assert lock.holder is None and lock.state().stations == [] and not lock.announced("local", "panel")
    assert lock.silent_tokens() == [PANEL]
    with pytest.raises(CommandRefused, match="does not answer the controller's ping"):
        lock.take("local", "panel", "s1")
    lock.token_alive(PANEL)  # Zenoh showing the token again (a duplicate put) does not bring it back
    assert not lock.announced("local", "panel")
    assert lock.token_answers(PANEL) and not lock.token_answers(PANEL), "it was silent once"
    assert lock.announced("local", "panel") and lock.state().stations == ["panel"]
    lock.take("local", "panel", "s1")
    assert lock.holds("local", "panel")


def test_a_silent_station_whose_token_goes_is_forgotten_and_a_new_session_of_it_counts():
    lock = OperatorLock()
    lock.token_alive(PANEL)
    lock.token_silent(PANEL)
    assert not lock.token_lost(PANEL), "it held nothing"
    assert lock.silent_token("local", "panel") is None and lock.tokens == set()
    fresh = Token("local", "panel", "s9")
    lock.token_alive(fresh)
    lock.take("local", "panel")
    assert lock.holder == fresh


def test_a_station_going_silent_leaves_another_holder_and_the_other_stations_alone():
    lock = OperatorLock()
    lock.token_alive(PANEL)
    lock.token_alive(DESK)
    lock.take("ops", "desk")
    seq = lock.seq
    assert not lock.token_silent(PANEL)
    assert lock.holds("ops", "desk") and lock.state().stations == ["desk"] and lock.seq > seq
    assert lock.silent_token("local", "panel", "s1") == PANEL and lock.silent_token("local", "panel", "other") is None


def test_waiting_for_a_token_ends_when_it_arrives_or_when_the_time_is_up():
    lock = OperatorLock()
    assert not lock.wait_announced("local", "panel", 0.0)
    arrived = threading.Event()

    def announce() -> None:
        arrived.wait()
        lock.token_alive(PANEL)

    thread = threading.Thread(target=announce)
    thread.start()
    arrived.set()
    assert lock.wait_announced("local", "panel", 60.0), "the token's arrival ends the wait"
    thread.join()
    lock.token_silent(PANEL)
    assert not lock.wait_announced("local", "panel", 0.0), "a silent token is not announced"
