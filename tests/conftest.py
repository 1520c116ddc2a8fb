"""Shared fixtures: the shipped machine file on a free loopback port, and running controllers."""

from __future__ import annotations

import socket
import time
from pathlib import Path

import numpy as np
import pytest

from cnc.config import MachineConfig, load_machine
from cnc.supervisor import Supervisor

REPO = Path(__file__).resolve().parent.parent
MACHINE_FILE = REPO / "machines" / "waterjet.toml"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def machine_config(**overrides) -> MachineConfig:
    """The shipped machine on its own loopback port, with optional dotted-key overrides."""
    return load_machine(MACHINE_FILE, {"zenoh.listen": [f"tcp/127.0.0.1:{free_port()}"], **overrides})


@pytest.fixture
def machine() -> MachineConfig:
    return machine_config()


@pytest.fixture
def virtual_controller(machine):
    with Supervisor(machine, clock="virtual") as sup:
        yield sup


@pytest.fixture
def realtime_controller(machine):
    with Supervisor(machine, clock="realtime") as sup:
        yield sup


def feed(sup: Supervisor, setpoints: np.ndarray, timeout_s: float = 60.0) -> None:
    """Push all setpoints into the FIFO as space frees up, supervising meanwhile."""
    pushed, deadline = 0, time.monotonic() + timeout_s
    while pushed < len(setpoints):
        pushed += sup.fifo.push(setpoints[pushed:])
        sup.poll()
        if time.monotonic() > deadline:
            raise TimeoutError(f"only {pushed} of {len(setpoints)} setpoints taken in {timeout_s} s")
        time.sleep(0.001)


def enable_and_hold(sup: Supervisor) -> list[float]:
    """Close the loop and wait until the servo holds; returns the held position."""
    from cnc.layout import ServoState

    sup.enable()
    sup.wait_until(lambda: sup.servo()["state"] == ServoState.HOLDING, 10.0, "the servo to hold position")
    return list(sup.servo()["commanded_mm"])
