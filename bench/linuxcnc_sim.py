#!/usr/bin/env python3
"""LinuxCNC's own trajectory planner, run headless, as a reference for our planner.

`run_linuxcnc()` runs a G-code program through a complete LinuxCNC 2.9 (Debian package
`linuxcnc-uspace`) configured as a simulated two-axis XY machine with the given axis limits,
and returns the commanded XY position at every servo period from motion start to motion
end, plus the program's cycle time. The benchmarks compare our planner's cycle time and
corner deviation against it for the same programs and limits.

How LinuxCNC is run (all in a fresh temporary directory, removed afterwards):
- `sim.ini`: trivkins with coordinates XY, 2 joints, SERVO_PERIOD = period_s, per-axis
  and per-joint MAX_VELOCITY / MAX_ACCELERATION / MIN_LIMIT / MAX_LIMIT from the
  arguments, [TRAJ] MAX_LINEAR_VELOCITY / MAX_LINEAR_ACCELERATION = hypot of the XY axis
  limits (so that, as in our planner, only the per-axis limits bind: a diagonal line may go
  faster than either axis), ARC_BLEND_ENABLE = 1 and planner defaults otherwise. Jerk is
  not limited (LinuxCNC 2.9 has no jerk limit). Homing is immediate (HOME_SEARCH_VEL =
  HOME_LATCH_VEL = 0): the joints are declared homed where they stand, at `home_mm`.
- `sim.hal`: motmod's joint.N.motor-pos-cmd looped back to joint.N.motor-pos-fb (a perfect
  servo, so there is never a following error), iocontrol's e-stop and tool-change loops,
  and `sampler` (cfg "ffbs", added to the servo thread after motion-controller) recording
  axis.x.pos-cmd, axis.y.pos-cmd, motion.in-position and motion.program-line every servo
  period. axis.L.pos-cmd is the planner's output in machine coordinates, before any
  motor offset, backlash or screw compensation, i.e. exactly "the commanded XY".
- [DISPLAY] DISPLAY is a small script (`DISPLAY_SCRIPT` below), run by LinuxCNC's launcher
  under the system /usr/bin/python3 (which has the `linuxcnc` module): it turns the machine
  on, homes, switches to AUTO, opens and runs the program, waits for it to finish, streams
  the sampler FIFO to a file with `halsampler -t` meanwhile, writes a status file and exits;
  the launcher (`linuxcnc -r sim.ini`) then shuts everything down as it does after any GUI.

The servo thread: on a kernel without PREEMPT_RT (as on our machines) rtapi_app says "Note:
Using POSIX non-realtime" and runs the thread as an ordinary thread. That only affects wall-clock
timing: the motion controller always advances by exactly one nominal period per call and
the sampler runs in the same thread, so the sampled trajectory is exact in servo periods
(a lost sample would show as a gap in the sample numbers and is reported as an error).
As root, rtapi_app refuses to run unless told which user to drop to: RTAPI_UID is set to
SUDO_UID or `nobody`, with its socket (RTAPI_FIFO_PATH) in a directory that user owns.

Cycle time: (last servo period in which the commanded position changed) - (first one) + 1,
times the period. So time spent at rest before the first move (start-up, a leading dwell)
and after the last move (M2, trailing dwells) is not counted; rests between moves are.
motion.in-position (false while the planner has motion queued) gives the same window to
within one period on every program tried (it may stay false for one more period after a
last step below the 1e-6 mm resolution of halsampler's "%f" output); its span is returned
too as a cross-check.

LinuxCNC uses fixed global names (HAL and NML shared memory keys, /tmp/linuxcnc.lock), so
only one instance can run per machine: runs are serialised with a lock file, and a run
refuses to start (LinuxCNCUnavailable) if another LinuxCNC session is live.

    python bench/linuxcnc_sim.py PROGRAM.ngc [--vel 500] [--acc 5000] [--home X Y] [--json OUT]
"""

from __future__ import annotations

import argparse
import fcntl
import json
import math
import os
import pwd
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

AXES = ("x", "y")
SYSTEM_PYTHON = "/usr/bin/python3"
RUN_LOCK = Path(tempfile.gettempdir()) / "linuxcnc_sim.lock"  # serialises our own runs
LINUXCNC_LOCK = Path("/tmp/linuxcnc.lock")  # LinuxCNC's launcher's own (fixed path)
NML_FILE = Path("/usr/share/linuxcnc/linuxcnc.nml")
HAL_SHM_KEYS = ("0x48414c32", "0x90280A48", "0x48484c34")  # HAL, RTAPI, UUID (scripts/realtime)
LINUXCNC_PROCESSES = ("linuxcncsvr", "milltask", "rtapi_app")
STARTUP_ALLOWANCE_S = 90.0  # on top of timeout_s: launcher start-up and shutdown
SAMPLER_CFG = "ffbs"  # axis.x.pos-cmd, axis.y.pos-cmd, motion.in-position, motion.program-line
SAMPLER_DEPTH = 20000  # FIFO rows between halsampler reads: 20 s at 1 kHz


class LinuxCNCUnavailable(RuntimeError):
    """LinuxCNC is not installed, or cannot start here; the message says why (callers skip)."""


class LinuxCNCRunError(RuntimeError):
    """LinuxCNC started but the program did not run to completion (G-code error, soft limit,
    timeout, lost samples); the message holds LinuxCNC's own error text."""


# --------------------------------------------------------------------------------------
# The DISPLAY program: runs under /usr/bin/python3, started by LinuxCNC's launcher.
# --------------------------------------------------------------------------------------

DISPLAY_SCRIPT = r'''#!/usr/bin/python3
"""Headless DISPLAY for bench/linuxcnc_sim.py: machine on, home, run one program, exit."""
import json
import os
import signal
import subprocess
import sys
import time

import linuxcnc

JOB = json.load(open(os.environ["LCSIM_JOB"]))
STATUS = {"ok": False, "phase": "connect", "errors": [], "messages": [],
          "version": linuxcnc.version, "pid": os.getpid(), "clock": []}


class Fail(Exception):
    pass


def save_status():
    tmp = JOB["status"] + ".tmp"
    with open(tmp, "w") as f:
        json.dump(STATUS, f)
    os.replace(tmp, JOB["status"])


def halcmd(*args):
    return subprocess.run(["halcmd", *args], check=True, capture_output=True, text=True).stdout.strip()


def drain(err):
    """Move queued error-channel messages into STATUS."""
    while True:
        msg = err.poll()
        if not msg:
            return
        kind, text = msg
        bad = kind in (linuxcnc.NML_ERROR, linuxcnc.OPERATOR_ERROR)
        STATUS["errors" if bad else "messages"].append(text)


def wait_for(stat, err, cond, timeout, what):
    deadline = time.monotonic() + timeout
    while True:
        stat.poll()
        drain(err)
        if cond(stat):
            return True
        if time.monotonic() > deadline:
            raise Fail("timed out after %.0f s waiting for %s" % (timeout, what))
        time.sleep(0.005)


def phase(name):
    STATUS["phase"] = name
    STATUS["clock"].append([name, time.time()])
    save_status()


def machine_on_and_home(stat, cmd, err):
    phase("machine on")
    cmd.state(linuxcnc.STATE_ESTOP_RESET)
    cmd.wait_complete()
    cmd.state(linuxcnc.STATE_ON)
    wait_for(stat, err, lambda s: s.task_state == linuxcnc.STATE_ON, 10, "machine on")
    phase("homing")
    cmd.mode(linuxcnc.MODE_MANUAL)
    cmd.wait_complete()
    cmd.home(-1)  # all joints, immediate homing (HOME_SEARCH_VEL = 0)
    cmd.wait_complete()
    wait_for(stat, err, lambda s: all(s.homed[:JOB["joints"]]), 10, "homing")


def open_program(stat, cmd, err):
    phase("open program")
    cmd.mode(linuxcnc.MODE_AUTO)
    cmd.wait_complete()
    wait_for(stat, err, lambda s: s.task_mode == linuxcnc.MODE_AUTO, 10, "AUTO mode")
    cmd.program_open(JOB["program"])
    cmd.wait_complete()
    stat.poll()
    drain(err)
    if STATUS["errors"]:
        raise Fail("program open failed")


def idle(s):
    return s.interp_state == linuxcnc.INTERP_IDLE and s.queue == 0 and s.inpos


def run_program(stat, cmd, err):
    phase("run")
    cmd.auto(linuxcnc.AUTO_RUN, 0)
    # not wait_complete(): for AUTO_RUN it returns only at the program's end or after 5 s.
    # Once task echoes the command's serial number it has started the program, so from
    # then on "interpreter idle, nothing queued, in position" means the program is over.
    serial = cmd.serial
    wait_for(stat, err, lambda s: s.echo_serial_number >= serial, 10, "task to take AUTO_RUN")
    wait_for(stat, err, idle, JOB["timeout_s"], "the program to finish")
    phase("program done")
    time.sleep(0.05)  # a few periods at rest after the end
    stat.poll()
    drain(err)
    if stat.task_state != linuxcnc.STATE_ON:
        raise Fail("machine left the ON state during the run")


def stop_sampler(sampler):
    halcmd("setp", "sampler.0.enable", "0")
    deadline = time.monotonic() + 10
    while int(halcmd("getp", "sampler.0.curr-depth")) > 0 and time.monotonic() < deadline:
        time.sleep(0.02)  # let halsampler empty the FIFO
    sampler.send_signal(signal.SIGTERM)  # halsampler flushes and exits on SIGTERM
    sampler.wait(10)


def main():
    signal.signal(signal.SIGTERM, lambda *_: sys.exit("terminated"))
    stat, cmd, err = linuxcnc.stat(), linuxcnc.command(), linuxcnc.error_channel()
    sampler = None
    try:
        machine_on_and_home(stat, cmd, err)
        open_program(stat, cmd, err)
        sampler = subprocess.Popen(["halsampler", "-t", JOB["samples"]])
        halcmd("setp", "sampler.0.enable", "1")
        run_program(stat, cmd, err)
        phase("stop sampler")
        stop_sampler(sampler)
        sampler = None
        STATUS["ok"] = not STATUS["errors"]
        phase("done")
    except BaseException as exc:  # report, then let the launcher shut LinuxCNC down
        STATUS["errors"].append("%s: %s" % (type(exc).__name__, exc))
    finally:
        if sampler is not None:
            sampler.kill()
        save_status()


main()
'''


# --------------------------------------------------------------------------------------
# Configuration files
# --------------------------------------------------------------------------------------


def _ini_text(vel: dict[str, float], acc: dict[str, float], travel: dict[str, tuple[float, float]],
              home: dict[str, float], period_ns: int, display: Path) -> str:
    """The machine: trivkins XY, per-axis limits, immediate homing, default planner."""
    lines = [
        "[EMC]", "VERSION = 1.1", "MACHINE = linuxcnc_sim-xy", "DEBUG = 0",
        "[DISPLAY]", f"DISPLAY = {display}",
        "[TASK]", "TASK = milltask", "CYCLE_TIME = 0.001",
        "[RS274NGC]", "PARAMETER_FILE = sim.var",
        "[EMCMOT]", "EMCMOT = motmod", "COMM_TIMEOUT = 1.0", f"SERVO_PERIOD = {period_ns}",
        "[EMCIO]", "EMCIO = io", "CYCLE_TIME = 0.100", "TOOL_TABLE = sim.tbl",
        "[HAL]", "HALFILE = sim.hal",
        "[TRAJ]", "COORDINATES = X Y", "LINEAR_UNITS = mm", "ANGULAR_UNITS = degree",
        f"DEFAULT_LINEAR_VELOCITY = {min(vel[a] for a in AXES):.10g}",
        f"MAX_LINEAR_VELOCITY = {math.hypot(*(vel[a] for a in AXES)):.10g}",
        f"DEFAULT_LINEAR_ACCELERATION = {min(acc[a] for a in AXES):.10g}",
        f"MAX_LINEAR_ACCELERATION = {math.hypot(*(acc[a] for a in AXES)):.10g}",
        "ARC_BLEND_ENABLE = 1",
        "[KINS]", "KINEMATICS = trivkins coordinates=XY", f"JOINTS = {len(AXES)}",
    ]
    for j, ax in enumerate(AXES):
        lo, hi = travel[ax]
        limits = [f"MAX_VELOCITY = {vel[ax]:.10g}", f"MAX_ACCELERATION = {acc[ax]:.10g}",
                  f"MIN_LIMIT = {lo:.10g}", f"MAX_LIMIT = {hi:.10g}"]
        lines += [f"[AXIS_{ax.upper()}]", *limits]
        lines += [f"[JOINT_{j}]", "TYPE = LINEAR", *limits,
                  f"HOME = {home[ax]:.10g}", f"HOME_OFFSET = {home[ax]:.10g}",
                  "HOME_SEARCH_VEL = 0", "HOME_LATCH_VEL = 0", "HOME_SEQUENCE = 0",
                  "FERROR = 1e9", "MIN_FERROR = 1e9"]
    return "\n".join(lines) + "\n"


def _hal_text(period_ns: int) -> str:
    """Motion with looped-back (perfect) servos, and a sampler on the servo thread."""
    return f"""\
loadrt trivkins coordinates=XY
loadrt motmod servo_period_nsec={period_ns} num_joints={len(AXES)}
loadrt sampler depth={SAMPLER_DEPTH} cfg={SAMPLER_CFG}
addf motion-command-handler servo-thread
addf motion-controller servo-thread
addf sampler.0 servo-thread
net j0-pos joint.0.motor-pos-cmd => joint.0.motor-pos-fb
net j1-pos joint.1.motor-pos-cmd => joint.1.motor-pos-fb
net estop-loop iocontrol.0.user-enable-out => iocontrol.0.emc-enable-in
net tool-prep-loop iocontrol.0.tool-prepare => iocontrol.0.tool-prepared
net tool-change-loop iocontrol.0.tool-change => iocontrol.0.tool-changed
net smp-x axis.x.pos-cmd => sampler.0.pin.0
net smp-y axis.y.pos-cmd => sampler.0.pin.1
net smp-inpos motion.in-position => sampler.0.pin.2
net smp-line motion.program-line => sampler.0.pin.3
setp sampler.0.enable 0
"""


def _write_config(work: Path, program: Path, vel: dict[str, float], acc: dict[str, float],
                  travel: dict[str, tuple[float, float]], home: dict[str, float],
                  period_ns: int, timeout_s: float, tools: dict[int, float]) -> None:
    display = work / "display.py"
    display.write_text(DISPLAY_SCRIPT)
    display.chmod(0o755)
    (work / "sim.ini").write_text(_ini_text(vel, acc, travel, home, period_ns, display))
    (work / "sim.hal").write_text(_hal_text(period_ns))
    (work / "sim.var").write_text("")
    (work / "sim.tbl").write_text("".join(f"T{n} P{n} D{d:.10g}\n" for n, d in sorted(tools.items())))
    job = {"program": str(program), "samples": str(work / "samples.txt"),
           "status": str(work / "status.json"), "timeout_s": timeout_s, "joints": len(AXES)}
    (work / "job.json").write_text(json.dumps(job))


# --------------------------------------------------------------------------------------
# Availability, processes, clean-up
# --------------------------------------------------------------------------------------


def _version() -> str:
    try:
        out = subprocess.run(["linuxcnc_var", "LINUXCNCVERSION"], capture_output=True,
                             text=True, timeout=10)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.TimeoutExpired):
        return "unknown"


def _live_processes(names: tuple[str, ...], run_id: str | None = None) -> list[int]:
    """PIDs (not zombies) whose command name is in `names`, or, with run_id, that carry our
    LCSIM_RUN_ID in their environment (any name: the processes of one of our runs)."""
    pids = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            comm, state = stat[stat.index("(") + 1:stat.rindex(")")], stat[stat.rindex(")") + 2]
            if state == "Z":
                continue
            if run_id is None:
                if comm in names:
                    pids.append(int(d.name))
            elif f"LCSIM_RUN_ID={run_id}".encode() in (d / "environ").read_bytes().split(b"\0"):
                pids.append(int(d.name))
        except (OSError, ValueError, IndexError):
            continue
    return pids


def _installed() -> tuple[bool, str]:
    """Whether LinuxCNC and its python module are installed; the reason or the version."""
    for tool in ("linuxcnc", "halcmd", "halsampler", "halrun", "rtapi_app", "linuxcnc_var"):
        if shutil.which(tool) is None:
            return False, f"`{tool}` not found: install LinuxCNC (apt-get install linuxcnc-uspace)"
    if not Path(SYSTEM_PYTHON).exists():
        return False, f"{SYSTEM_PYTHON} not found (LinuxCNC's python modules belong to it)"
    probe = subprocess.run([SYSTEM_PYTHON, "-c", "import linuxcnc, hal"], capture_output=True,
                           text=True, env=_clean_env({}))
    if probe.returncode != 0:
        return False, f"{SYSTEM_PYTHON} cannot import linuxcnc: {probe.stderr.strip()[-200:]}"
    return True, f"LinuxCNC {_version()}"


def _other_session() -> str | None:
    """Why we must not start: a live LinuxCNC session (ours would kill it), or None."""
    others = _live_processes(LINUXCNC_PROCESSES)
    return f"another LinuxCNC session is running (pids {others}); not touching it" if others else None


def available() -> tuple[bool, str]:
    """Whether run_linuxcnc() can be tried here: (True, "LinuxCNC <version>") or (False, why)."""
    ok, reason = _installed()
    busy = _other_session() if ok else None
    return (False, busy) if busy else (ok, reason)


def _rtapi_user() -> int | None:
    """The uid rtapi_app drops to when we are root (it refuses to run as root without one)."""
    if os.geteuid() != 0:
        return None
    if os.environ.get("SUDO_UID", "").isdigit() and int(os.environ["SUDO_UID"]) != 0:
        return int(os.environ["SUDO_UID"])
    try:
        return pwd.getpwnam("nobody").pw_uid
    except KeyError:
        return 65534


def _clean_env(extra: dict[str, str]) -> dict[str, str]:
    """The caller's environment without X display or venv/python overrides, system bins first."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("DISPLAY", "WAYLAND_DISPLAY", "PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env["PATH"] = "/usr/bin:/bin:/usr/sbin:/sbin:" + env.get("PATH", "")
    env.update(extra)
    return env


def _run_env(work: Path, run_id: str) -> dict[str, str]:
    extra = {"HOME": str(work), "LCSIM_JOB": str(work / "job.json"), "LCSIM_RUN_ID": run_id}
    uid = _rtapi_user()
    if uid is not None:
        rt = work / "rtapi"
        rt.mkdir()
        os.chown(rt, uid, -1)
        extra |= {"RTAPI_UID": str(uid), "RTAPI_FIFO_PATH": str(rt / "rtapi_fifo")}
    return _clean_env(extra)


def _signal_all(pids: list[int], sig: int) -> None:
    for pid in pids:
        try:
            os.kill(pid, sig)
        except ProcessLookupError:
            pass


def _kill_run_processes(run_id: str, grace_s: float = 3.0) -> None:
    """TERM, then KILL, every live process of this run (found by LCSIM_RUN_ID)."""
    pids = [p for p in _live_processes((), run_id) if p != os.getpid()]
    _signal_all(pids, signal.SIGTERM)
    deadline = time.monotonic() + grace_s
    while pids and time.monotonic() < deadline:
        time.sleep(0.1)
        pids = [p for p in _live_processes((), run_id) if p != os.getpid()]
    _signal_all(pids, signal.SIGKILL)


def _nml_shm_keys() -> list[str]:
    """Shared memory keys of LinuxCNC's NML buffers (the 'B ... SHMEM' lines of the NML file)."""
    keys = []
    for line in NML_FILE.read_text().splitlines() if NML_FILE.exists() else []:
        f = line.split()
        if len(f) > 9 and f[0] == "B" and f[2] == "SHMEM":
            keys.append(f[9])
    return keys


def _force_cleanup(env: dict[str, str], run_id: str, since: float) -> None:
    """What the launcher's own Cleanup does, for when it did not get to run: stop the
    realtime side, kill what is left of this run, free the shared memory, drop the lock
    and the launcher's log files. Safe only because we hold the run lock and no other
    LinuxCNC was live when the run started (_other_session())."""
    try:
        subprocess.run(["halrun", "-U"], env=env, capture_output=True, timeout=60, check=False)
    except subprocess.TimeoutExpired:
        pass  # what it left running is killed next
    _kill_run_processes(run_id)
    for key in (*HAL_SHM_KEYS, *_nml_shm_keys()):
        subprocess.run(["ipcrm", "-M", key], capture_output=True, check=False)
    LINUXCNC_LOCK.unlink(missing_ok=True)
    for pattern in ("linuxcnc.debug.*", "linuxcnc.print.*"):  # the launcher's mktemp files
        for f in Path("/tmp").glob(pattern):
            try:
                if f.stat().st_mtime >= since:
                    f.unlink()
            except OSError:
                pass


@contextmanager
def _run_lock(timeout_s: float) -> Iterator[None]:
    """One run at a time on this machine (LinuxCNC's names and shared memory are global)."""
    with open(RUN_LOCK, "a") as f:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise LinuxCNCUnavailable(f"another run holds {RUN_LOCK}") from None
                time.sleep(0.2)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _launch(work: Path, env: dict[str, str], timeout_s: float) -> tuple[int | None, str]:
    """Run `linuxcnc -r sim.ini` to its end: (the launcher's exit code, or None if it had to
    be stopped; its output). On a timeout the DISPLAY script is stopped first, so that the
    launcher's own shutdown runs; if that hangs too, its process group is killed."""
    log = work / "linuxcnc.log"
    with open(log, "w") as out:
        proc = subprocess.Popen(["linuxcnc", "-r", str(work / "sim.ini")], cwd=work, env=env,
                                stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                                start_new_session=True)
        try:
            code: int | None = proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            code = None
            _stop_display(work)
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                _signal_group(proc.pid, signal.SIGKILL)
                proc.wait()
    return code, log.read_text(errors="replace")


def _stop_display(work: Path) -> None:
    try:
        pid = json.loads((work / "status.json").read_text())["pid"]
        os.kill(pid, signal.SIGTERM)
    except (OSError, ValueError, KeyError):
        pass


def _signal_group(pgid: int, sig: int) -> None:
    try:
        os.killpg(pgid, sig)
    except ProcessLookupError:
        pass


# --------------------------------------------------------------------------------------
# Samples
# --------------------------------------------------------------------------------------


def _read_samples(path: Path) -> np.ndarray:
    """halsampler -t output as rows (sample number, x, y, in-position, program line)."""
    if not path.exists():
        raise LinuxCNCRunError("no samples were recorded")
    text = path.read_text()
    if "overrun" in text:
        raise LinuxCNCRunError("sampler FIFO overran: samples were lost")
    data = np.array(text.split(), dtype=float)
    ncol = 1 + len(SAMPLER_CFG)
    if data.size == 0 or data.size % ncol:
        raise LinuxCNCRunError(f"malformed sampler output in {path.name}")
    data = data.reshape(-1, ncol)
    if np.any(np.diff(data[:, 0]) != 1):
        raise LinuxCNCRunError("gap in the sample numbers: samples were lost")
    return data


def _motion_window(xy: np.ndarray) -> tuple[int, int]:
    """(k0, k1): xy[k0] is the last sample at rest before the first move, xy[k1] the last
    sample whose position differs from its predecessor. k0 == k1 when nothing moved."""
    moved = np.nonzero(np.any(np.diff(xy, axis=0) != 0.0, axis=1))[0]
    if moved.size == 0:
        return 0, 0
    return int(moved[0]), int(moved[-1]) + 1


def _in_position_span(inpos: np.ndarray) -> int:
    """Number of periods with motion.in-position false (first to last)."""
    busy = np.nonzero(inpos == 0)[0]
    return int(busy[-1] - busy[0] + 1) if busy.size else 0


def _result(data: np.ndarray, period_s: float, version: str, log: str) -> dict[str, Any]:
    xy_all = data[:, 1:3]
    k0, k1 = _motion_window(xy_all)
    rt = "POSIX non-realtime thread" if "POSIX non-realtime" in log else "realtime thread"
    how = (f"LinuxCNC {version} headless (linuxcnc -r, trivkins XY sim, motor-pos-cmd looped "
           f"to motor-pos-fb, {rt} at {period_s * 1e3:g} ms); axis.x/y.pos-cmd sampled every "
           "servo period by sampler + halsampler; cycle time = servo periods from the first to "
           "the last change of commanded position")
    return {
        "cycle_time_s": (k1 - k0) * period_s,
        "t_s": np.arange(k1 - k0 + 1) * period_s,
        "xy_mm": xy_all[k0:k1 + 1].copy(),
        "version": version,
        "how": how,
        "line": data[k0:k1 + 1, 4].astype(int),
        "in_position_time_s": _in_position_span(data[:, 3]) * period_s,
        "samples_total": int(len(data)),
    }


# --------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------


def _check_args(max_velocity_mm_s: dict[str, float], max_accel_mm_s2: dict[str, float],
                travel_mm: dict[str, tuple[float, float]], home: dict[str, float], period_ns: int) -> None:
    if period_ns < 1000:
        raise ValueError("period_s must be at least 1 us")
    for ax in AXES:
        for name, table in (("max_velocity_mm_s", max_velocity_mm_s), ("max_accel_mm_s2", max_accel_mm_s2)):
            if not table.get(ax, 0) > 0:
                raise ValueError(f"{name}[{ax!r}] must be given and > 0")
        lo, hi = travel_mm[ax]
        if not lo < hi or not lo <= home[ax] <= hi:
            raise ValueError(f"travel_mm[{ax!r}] = {travel_mm[ax]} must hold home {home[ax]}")


def run_linuxcnc(program: str | Path, *, max_velocity_mm_s: dict[str, float],
                 max_accel_mm_s2: dict[str, float], travel_mm: dict[str, tuple[float, float]],
                 period_s: float = 0.001, timeout_s: float = 600,
                 home_mm: dict[str, float] | None = None, tools_mm: dict[int, float] | None = None) -> dict[str, Any]:
    """Run `program` on LinuxCNC's planner with these XY limits and sample the commanded path.

    Keys of the limit dicts are "x" and "y"; units mm, mm/s, mm/s^2. The machine starts at
    `home_mm` (default: 0 clamped into the travel). `tools_mm`: the tool table, tool number to
    diameter (G41/G42 D<number> compensates half of it; ours: the nozzles' kerf widths).
    `timeout_s` bounds the program's run; start-up and shutdown get STARTUP_ALLOWANCE_S on top.

    Returns cycle_time_s (float), t_s (n,), xy_mm (n, 2) from the last sample at rest before
    the first move to the last sample of motion (t_s[-1] == cycle_time_s), version and how
    (str); also line (n,) program line per sample, in_position_time_s (span of
    motion.in-position false, a cross-check) and samples_total.

    Raises LinuxCNCUnavailable when LinuxCNC is missing or cannot start here, and
    LinuxCNCRunError when the program fails (G-code error, soft limit, timeout).
    """
    program = Path(program).resolve()
    if not program.is_file():
        raise FileNotFoundError(program)
    home = home_mm or {ax: min(max(0.0, travel_mm[ax][0]), travel_mm[ax][1]) for ax in AXES}
    period_ns = round(period_s * 1e9)  # SERVO_PERIOD is whole nanoseconds
    _check_args(max_velocity_mm_s, max_accel_mm_s2, travel_mm, home, period_ns)
    ok, reason = _installed()
    if not ok:
        raise LinuxCNCUnavailable(reason)
    version = reason.removeprefix("LinuxCNC ")
    with _run_lock(timeout_s), tempfile.TemporaryDirectory(prefix="linuxcnc_sim-") as tmp:
        busy = _other_session()  # checked under our lock: our own runs wait for each other
        if busy:
            raise LinuxCNCUnavailable(busy)
        work = Path(tmp)
        work.chmod(0o755)
        run_id = uuid.uuid4().hex
        _write_config(work, program, max_velocity_mm_s, max_accel_mm_s2, travel_mm, home,
                      period_ns, timeout_s, tools_mm or {})
        env = _run_env(work, run_id)
        limit_s = timeout_s + STARTUP_ALLOWANCE_S
        started, code, log = time.time(), None, ""
        try:
            code, log = _launch(work, env, limit_s)
        finally:  # the launcher cleans up after itself; this is for when it could not
            if code != 0 or _live_processes((), run_id) or LINUXCNC_LOCK.exists():
                _force_cleanup(env, run_id, started)
        _raise_for_status(_read_status(work), code, log, limit_s)
        return _result(_read_samples(work / "samples.txt"), period_ns * 1e-9, version, log)


def _read_status(work: Path) -> dict[str, Any]:
    """What the DISPLAY script reported (nothing if LinuxCNC never got as far as starting it)."""
    try:
        return json.loads((work / "status.json").read_text())
    except (OSError, ValueError):
        return {"ok": False, "phase": "startup", "errors": []}


def _log_tail(log: str, lines: int = 8) -> str:
    interesting = [ln for ln in log.splitlines() if ln.strip() and "fallback_uid" not in ln]
    return "launcher output: " + " | ".join(interesting[-lines:])


def _raise_for_status(status: dict[str, Any], code: int | None, log: str, limit_s: float) -> None:
    """Start-up failures mean LinuxCNC cannot run here; failures after that are the program's."""
    phase = status.get("phase")
    if code is None:
        raise LinuxCNCRunError(f"LinuxCNC did not finish within {limit_s:.0f} s (phase {phase}); "
                               + _log_tail(log))
    if status.get("ok"):
        return
    errors = "; ".join(status.get("errors", []))
    if phase in ("startup", "connect", "machine on", "homing"):
        raise LinuxCNCUnavailable(f"LinuxCNC did not start (phase {phase}, launcher exit code {code}): "
                                  f"{errors or 'no error message'}; {_log_tail(log)}")
    if phase == "done":  # ran to the end, but task or the interpreter reported errors
        raise LinuxCNCRunError(f"program failed: {errors}")
    raise LinuxCNCRunError(f"program failed (phase {phase}, launcher exit code {code}): "
                           f"{errors or _log_tail(log)}")


# --------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------


def _summary(res: dict[str, Any]) -> dict[str, float]:
    xy, dt = res["xy_mm"], float(res["t_s"][1] - res["t_s"][0]) if len(res["t_s"]) > 1 else 0.0
    vel = np.diff(xy, axis=0) / dt if dt else np.zeros((0, 2))
    acc = np.diff(vel, axis=0) / dt if dt else np.zeros((0, 2))
    peak = (lambda a: float(np.abs(a).max()) if a.size else 0.0)
    return {"max_path_speed_mm_s": float(np.linalg.norm(vel, axis=1).max()) if len(vel) else 0.0,
            "max_speed_x_mm_s": peak(vel[:, 0]), "max_speed_y_mm_s": peak(vel[:, 1]),
            "max_accel_x_mm_s2": peak(acc[:, 0]), "max_accel_y_mm_s2": peak(acc[:, 1])}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("program", type=Path)
    ap.add_argument("--vel", type=float, default=500.0, help="max velocity of X and Y, mm/s")
    ap.add_argument("--acc", type=float, default=5000.0, help="max acceleration of X and Y, mm/s^2")
    ap.add_argument("--travel", type=float, nargs=2, default=(-5000.0, 5000.0), metavar=("MIN", "MAX"),
                    help="soft limits of X and Y, mm")
    ap.add_argument("--home", type=float, nargs=2, metavar=("X", "Y"),
                    help="machine position when the program starts, mm (default 0 0, clamped into travel)")
    ap.add_argument("--period", type=float, default=0.001, help="servo period, s")
    ap.add_argument("--timeout", type=float, default=600.0, help="limit on the program's run, s")
    ap.add_argument("--json", type=Path, help="write the result (with the trajectory) here")
    args = ap.parse_args(argv)
    both = (lambda v: {ax: v for ax in AXES})
    t0 = time.monotonic()
    try:
        res = run_linuxcnc(args.program, max_velocity_mm_s=both(args.vel), max_accel_mm_s2=both(args.acc),
                           travel_mm=both(tuple(args.travel)), period_s=args.period, timeout_s=args.timeout,
                           home_mm=dict(zip(AXES, args.home)) if args.home else None)
    except LinuxCNCUnavailable as exc:
        print(f"LinuxCNC unavailable, skipped: {exc}", file=sys.stderr)
        return 2
    except LinuxCNCRunError as exc:
        print(f"LinuxCNC run failed: {exc}", file=sys.stderr)
        return 1
    wall = time.monotonic() - t0
    summary = _summary(res)
    print(f"{args.program}: cycle time {res['cycle_time_s']:.3f} s, {len(res['t_s'])} samples "
          f"(in-position span {res['in_position_time_s']:.3f} s), run took {wall:.1f} s")
    print(f"start {res['xy_mm'][0].round(4).tolist()}, end {res['xy_mm'][-1].round(4).tolist()}; "
          + ", ".join(f"{k} {v:.1f}" for k, v in summary.items()))
    print(res["how"])
    if args.json:
        out = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in res.items()}
        out |= {"program": str(args.program), "wall_time_s": wall, **summary}
        args.json.write_text(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
