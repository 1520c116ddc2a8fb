"""A large program's cycle time, planned in a process of its own.

Timing a program means making all of its sections (about 1 ms each: seconds to minutes for a
large program). Done on a thread of the planner it would share the interpreter lock with the
refills: on the real-time clock, the refills of a cut waited behind it and the FIFO ran dry.
So the planner hands the interpreted program to a child process (`python -m
cnc.planner.timing_process DIR`): the segments as a numpy file, the messages, the machine
configuration in force (with its tuned parameters) and the cutting job's plan pickled beside them. The child makes the
same steps with the same code (`sections.iter_steps`), times them (`ProgramTiming`) and writes
the result into the same directory; the planner polls it at its ticks without waiting. The
child runs under the normal scheduler, dies with the planner, and is stopped when the program
is replaced. It runs under SCHED_IDLE: it takes only CPU time nothing else wants. On a host with
more than one CPU it times the program in pieces cut at pierces, one forked process a CPU
(`ProgramTiming.of`), each under SCHED_IDLE too and ending with it.
"""

from __future__ import annotations

import os
import pickle
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from gcode.program import Program

from ..config import MachineConfig
from ..runtime.child import die_with
from .steps import ProgramTiming, timing_workers

_RESULT = "result.pickle"
DIR_PREFIX = "wjcnc-timing-"  # then the planner's pid: `remove_stale` finds the ones a dead planner left


def remove_stale() -> None:
    """Remove the timing directories of planners that are gone (killed before they could clean up)."""
    for d in Path(tempfile.gettempdir()).glob(f"{DIR_PREFIX}*"):
        pid = d.name[len(DIR_PREFIX):].split("-", 1)[0]
        if pid.isdigit() and not Path(f"/proc/{pid}").exists():
            shutil.rmtree(d, ignore_errors=True)


class TimingProcess:
    """One program's timing under way in a child process; `poll` fills `timing` when it is done."""

    def __init__(self, program: Program, config: MachineConfig, timing: ProgramTiming, cut=None) -> None:  # noqa: ANN001
        self.timing = timing
        self.dir = Path(tempfile.mkdtemp(prefix=f"{DIR_PREFIX}{os.getpid()}-"))
        np.save(self.dir / "segments.npy", program.segments)
        with open(self.dir / "job.pickle", "wb") as f:
            pickle.dump({"config": config, "messages": program.messages, "name": program.name, "cut": cut}, f)
        # started from a thread under the normal scheduler (the planner's helper): the child
        # inherits that policy, never the refills' real-time one
        with open(self.dir / "stderr.txt", "wb") as err:  # a file, not a pipe: a long traceback cannot block it
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "cnc.planner.timing_process", str(self.dir)],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err, close_fds=True,
            )

    def poll(self) -> bool:
        """Whether the child has finished (the timing then filled in, or its failure set); never waits."""
        if self.proc.poll() is None:
            return False
        try:
            with open(self.dir / _RESULT, "rb") as f:
                result = pickle.load(f)
        except (OSError, EOFError, pickle.UnpicklingError):
            err = (self.dir / "stderr.txt").read_text(errors="replace").strip().splitlines()
            self.timing.failure = RuntimeError(f"the timing process ended (exit {self.proc.returncode}) without a result"
                                               + (f": {err[-1]}" if err else ""))
        else:
            if result["failure"]:
                self.timing.failure = RuntimeError(result["failure"])
            else:
                self.timing.adopt(result["step_ticks"], result["total_mm"])
        self.close()
        return True

    def cancel(self) -> None:
        """Stop the child (the program was replaced) and remove its files."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self.close()

    def close(self) -> None:
        shutil.rmtree(self.dir, ignore_errors=True)


def main(argv: list[str]) -> int:
    die_with(os.getppid())  # ends with the planner that started it
    from ..runtime.rt import leave_realtime

    try:  # only the time no other process wants: the controller's own processes, the HMI's host tools
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except (OSError, AttributeError):
        leave_realtime()
        os.nice(19)
    workdir = Path(argv[0])
    with open(workdir / "job.pickle", "rb") as f:
        job = pickle.load(f)
    segments = np.load(workdir / "segments.npy")
    program = Program(job["name"], segments, job["messages"], None)
    config: MachineConfig = job["config"]
    timing = ProgramTiming.of(program, config, job.get("cut"), workers=timing_workers())
    result = {
        "failure": f"{type(timing.failure).__name__}: {timing.failure}" if timing.failure is not None else "",
        "step_ticks": np.array(timing.step_ticks, dtype=np.int64), "total_mm": timing.total_mm,
    }
    tmp = workdir / (_RESULT + ".part")
    with open(tmp, "wb") as f:
        pickle.dump(result, f)
    os.replace(tmp, workdir / _RESULT)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
