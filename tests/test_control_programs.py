"""Control programs (QMotor's): the axis control law as a program with registered parameters and
log variables, chosen in the machine file, checked on the simulated plant, supervised by the servo.

The PI-P is a control program and computes today's law; registrations and the machine file's
choice are checked with errors naming the program, the member or the key; a program's own
parameters are control parameters the servo applies at a tick boundary; its log variables reach
the trace and the logger's columns; the two examples improve what they claim on the plant; a
program that fails is replaced by the fallback law in the same tick (the safety matrix and the
fault-injection runs show the stop; `waterjet control` checks and selects).
"""

from __future__ import annotations

import math
import shutil
import textwrap
import time

import numpy as np
import pytest

from cnc.cli import main
from cnc.config import ConfigError, load_machine
from cnc.control.loader import SHIPPED, build
from cnc.control.pip import PIP
from cnc.control.program import ControlInputs, ControlProgram, ControlProgramError
from cnc.control.trial import run as run_trial
from cnc.data.dataserver import unique_name
from cnc.data.layout import ServoFault, ServoState
from cnc.data.trace import TraceRing
from cnc.logger.logvars import log_variables, trace_columns
from cnc.params import registry, values_of

from .conftest import MACHINE_FILE, machine_config
from .tickrig import Rig

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)


def _inputs(n: int, error, velocity, accel, dt: float = 0.001) -> ControlInputs:
    inp = ControlInputs(n)
    inp.error_mm[:], inp.setpoint_velocity_mm_s[:], inp.setpoint_accel_mm_s2[:] = error, velocity, accel
    inp.dt_s = dt
    return inp


def test_the_pi_p_is_a_control_program_of_the_machine_file_s_gains_computing_the_paper_s_law():
    config = machine_config()
    program = build(config)
    assert type(program) is PIP and SHIPPED["pip"] == "cnc.control.pip:PIP"
    ax = config.axis["x"]
    assert program.kp_1_s == [a.kp_1_s for a in config.axes] and program.accel_ff_s == [a.accel_ff_s for a in config.axes]
    program._started()
    integral = 0.0
    for k in range(5):  # u = kv v + ka a + kp e + ki integral(e), the integral clamped to its limit's share
        e, v, a = 0.01 * (k + 1), 20.0 * k, 300.0
        u = program.control(_inputs(2, [e, -e], [v, 0.0], [a, 0.0]))
        integral = max(-ax.integral_limit_mm_s / ax.ki_1_s2, min(ax.integral_limit_mm_s / ax.ki_1_s2, integral + e * 0.001))
        assert u[0] == pytest.approx(ax.velocity_ff * v + ax.accel_ff_s * a + ax.kp_1_s * e + ax.ki_1_s2 * integral)
    program.position_referenced(0)
    assert program._integral[0] == 0.0 and program._integral[1] != 0.0, "homing resets only that axis' integral"
    names = [s.name for s in registry(config)]
    assert names[:6] == ["axis.x.kp_1_s", "axis.x.ki_1_s2", "axis.x.velocity_ff", "axis.x.accel_ff_s",
                         "axis.x.integral_limit_mm_s", "axis.x.following_error_limit_mm"], "the tuning names stay"


class _Empty(ControlProgram):
    def control(self, inputs):  # noqa: ANN001, ANN201
        return [0.0] * self.n_axes


@pytest.mark.parametrize(("register", "message"), [
    (lambda p: p.register_parameter("9lives", 1.0), "'9lives' is not a member name"),
    (lambda p: p.register_parameter("control", 1.0), "'control' is a method or property of the class"),
    (lambda p: (p.register_parameter("g", 1.0), p.register_log_variable("g")), "'g' is registered twice"),
    (lambda p: p.register_parameter("g", 5.0, range=(0.0, 1.0)), "parameter 'g': 5.0 is outside its range 0 to 1"),
    (lambda p: p.register_parameter("g", [1.0, 2.0, 3.0], per_axis=True), "parameter 'g': 3 values for 2 axes"),
    (lambda p: p.register_parameter("g", [1.0, 2.0]), "parameter 'g': a list needs per_axis=True"),
    (lambda p: p.register_parameter("g", 1.0, option="kp_1_s"), "parameter 'g': an [axis] option is per axis"),
    (lambda p: p.register_parameter("g", 1.0, per_axis=True, option="kp_gain"), "[axis] has no option 'kp_gain'"),
    (lambda p: p.register_parameter("g", 1.0, range=(2.0, 1.0)), "parameter 'g': range (2.0, 1.0) is empty"),
    (lambda p: p.register_log_variable("trace", size=40), "log variable 'trace': size 40 is not 1 to 16"),
])
def test_registrations_are_checked_and_a_bad_one_names_the_program_and_the_member(register, message):
    program = _Empty(machine_config())
    with pytest.raises(ControlProgramError, match=r"^_Empty: .*") as caught:
        register(program)
    assert message in str(caught.value)


LAW = '''
from cnc.control.pip import PIP

class Softer(PIP):
    """The PI-P with a scaled command."""

    def __init__(self, machine):
        super().__init__(machine)
        self.register_parameter("scale", 1.0, "", (0.0, 2.0), "command scale")
        self.register_parameter("bias_mm_s", 0.0, "mm/s", (-5.0, 5.0), "speed bias", per_axis=True)
        self.register_log_variable("u", "mm/s", "the command", per_axis=True)
        self.register_log_variable("calls", "", "periods computed")

    def control(self, inputs):
        out = super().control(inputs)
        for i in range(len(out)):
            out[i] = out[i] * self.scale + self.bias_mm_s[i]
        self.u = list(out)
        self.calls = float(self.ticks)
        return out
'''


def _machine_with(tmp_path, text: str, law: str | None = LAW):
    machine = tmp_path / "machine.toml"
    shutil.copy(MACHINE_FILE, machine)
    if law is not None:
        (tmp_path / "softer.py").write_text(law)
    machine.write_text(machine.read_text() + textwrap.dedent(text))
    return machine


def test_the_machine_file_names_its_program_and_its_parameters_and_errors_name_the_key(tmp_path):
    machine = _machine_with(tmp_path, """
        [control]
        program = "softer.py:Softer"

        [control.parameters]
        scale = 0.5

        [control.parameters.y]
        bias_mm_s = -1.5
        """)
    config = load_machine(machine)
    program = build(config)
    assert type(program).__name__ == "Softer" and program.scale == 0.5 and program.bias_mm_s == [0.0, -1.5]
    specs = {s.name: s for s in registry(config)}
    assert {"control.scale", "control.x.bias_mm_s", "control.y.bias_mm_s"} <= set(specs)
    values = dict(zip(specs, values_of(config, list(specs.values()))))
    assert values["control.scale"] == 0.5 and values["control.x.bias_mm_s"] == 0.0 and values["control.y.bias_mm_s"] == -1.5

    cases = [
        ('[control]\nprogram = "nothing"\n', r"\[control\] program: 'nothing' is neither a shipped program"),
        ('[control]\nprogram = "softer.py:Harder"\n', r"\[control\] program: 'softer.py:Harder': .* no ControlProgram subclass 'Harder'"),
        ('[control]\nprogram = "gone.py:Law"\n', r"'gone.py': no such file beside the machine file"),
        ('[control]\nprogram = "cnc.no_such_module:Law"\n', r"importing cnc.no_such_module failed: ModuleNotFoundError"),
        ('[control]\nprogram = "softer.py:Softer"\n[control.parameters]\nscale = 3.0\n',
         r"\[control.parameters\] scale: 3 is out of range: allowed 0 to 2"),
        ('[control]\nprogram = "softer.py:Softer"\n[control.parameters]\ngain = 3.0\n',
         r"\[control.parameters\] gain: Softer has no such parameter \(known: scale\)"),
        ('[control]\nprogram = "softer.py:Softer"\n[control.parameters]\nscale = "half"\n',
         r"\[control.parameters\] scale: expected a number, got 'half'"),
        ('[control]\nprogram = "softer.py:Softer"\n[control.parameters.w]\nbias_mm_s = 1.0\n',
         r"\[control.parameters\] w: a table here is an axis' parameters"),
        ('[control]\nprogram = "softer.py:Softer"\n[control.parameters.z]\nbias_mm_s = 1.0\n',
         r"\[control.parameters\] z: this machine has no axis 'z'"),
        ('[control]\nbudget_share = 1.5\n', r"\[control\] budget_share: 1.5 is out of range"),
    ]
    for k, (text, message) in enumerate(cases):
        where = tmp_path / f"case{k}"
        where.mkdir()
        bad = _machine_with(where, text)
        with pytest.raises(ConfigError, match=message):
            load_machine(bad)
    broken = tmp_path / "broken"
    broken.mkdir()
    bad = _machine_with(broken, '[control]\nprogram = "softer.py:Softer"\n', law="import numpy\n1 / 0\n")
    with pytest.raises(ConfigError, match=r"importing softer.py failed: ZeroDivisionError: division by zero"):
        load_machine(bad)


def test_a_program_s_parameters_apply_in_the_servo_at_a_tick_and_its_log_variables_reach_the_trace(tmp_path):
    machine = _machine_with(tmp_path, '[control]\nprogram = "softer.py:Softer"\n')
    config = load_machine(machine, {"sim.axes.x.start_position_mm": 100.0, "sim.axes.y.start_position_mm": 100.0})
    specs = registry(config)
    names = [v.name for v in log_variables(config).trace]
    assert names[-3:] == ["x.u", "y.u", "control.calls"], "the program's variables, after the servo's"
    ring = TraceRing.create(unique_name("test", "trace"), 4096, 2, 3)
    try:
        with Rig(config) as rig:
            servo = rig.servo
            assert type(servo.program).__name__ == "Softer" and len(servo.log_values) == 3
            servo.trace = ring
            sup = rig.area.writer("supervisor")
            sup.load_current()
            sup.set("trace_enable", 1)
            sup.publish()
            block = rig.area.writer("params")
            values = values_of(config, specs)
            scale = next(s for s in specs if s.name == "control.scale")
            values[scale.index] = 0.0  # no command at all: the axes cannot follow
            block.set("values", values + [0.0] * (len(block.get("values")) - len(values)))
            block.set("change", 1)
            block.publish()
            rig.step(1)
            assert servo.program.scale == 0.0 and rig.servo_block()["params_change"] == 1
            values[scale.index] = 1.0
            block.set("values", values + [0.0] * (len(block.get("values")) - len(values)))
            block.set("change", 2)
            block.publish()
            rig.run_program("G21 G90\nG1 X120 Y110 F3000\nM2\n")
            rig.run_until(lambda: rig.feeder.runner.finished and rig.fifo.fill() == 0, 5000, "the move")
            rig.step(10)
            assert servo.program.scale == 1.0 and rig.servo_block()["state"] == ServoState.HOLDING
            records = ring.drain()
        cols = trace_columns(records, config)
        assert (np.abs(cols["x.velocity"]) > 1.0).sum() > 100, "the move is in the trace"
        for axis in ("x", "y"):  # what the program logged is the command the drive got, tick by tick
            vpm = config.axis[axis].volts_per_mm_s
            assert np.allclose(cols[f"{axis}.u"] * vpm, cols[f"{axis}.speed_cmd"], rtol=1e-12, atol=1e-12)
        assert np.all(np.diff(cols["control.calls"][-50:]) == 1.0), "a scalar log variable, period by period"
        assert np.all(cols["control_time"] > 0.0), "the program's CPU time, every tick"
    finally:
        ring.close()


def test_a_failing_program_is_replaced_by_the_fallback_law_in_the_same_tick_and_back_after_a_reset():
    config = machine_config(**{"sim.axes.x.start_position_mm": 100.0, "sim.axes.y.start_position_mm": 100.0})
    with Rig(config) as rig:
        servo = rig.servo
        rig.run_program("G21 G90\nG1 X400 F6000\nM2\n")
        rig.run_until(lambda: rig.speed_mm_s() > 90.0, 3000, "cruising")
        servo.program.control = lambda inputs: [0.0, math.inf]
        rig.step(1)
        s = rig.servo_block()
        assert s["state"] == ServoState.STOPPING and ServoFault(s["fault"]) == ServoFault.CONTROL_PROGRAM
        assert s["control_failure"] == "control program pip (PIP) returned inf as the speed command of axis Y"
        assert servo.law is servo.fallback and s["control_failures"] == 1
        assert abs(s["speed_cmd_v"][0]) > 0.5, "the fallback commands the axes in that tick: a controlled stop"
        rig.run_until(lambda: rig.servo_block()["state"] == ServoState.FAULT, 3000, "the stop")
        del servo.program.control
        rig.reset()
        rig.step(5)
        assert servo.law is servo.program and rig.servo_block()["state"] == ServoState.HOLDING


def test_friction_feed_forward_lowers_the_following_error_at_velocity_reversals_on_the_plant():
    config = machine_config(**{"sim.axes.x.coulomb_friction_mm_s2": 2000.0, "sim.axes.y.coulomb_friction_mm_s2": 2000.0})
    pip = run_trial(PIP(config), config, "circle")
    program = build(config, "friction_ff")
    drive = config.sim.axis("x").drive_time_constant_s
    program.friction_mm_s = [drive * 2000.0] * 2  # the speed the friction takes away: tau * c
    ff = run_trial(program, config, "circle")
    assert not pip.failure and not ff.failure
    assert ff.summary()["max_following_error_mm"] < 0.6 * pip.summary()["max_following_error_mm"]
    assert ff.summary()["rms_following_error_mm"] < 0.6 * pip.summary()["rms_following_error_mm"]


def test_cross_coupled_contour_control_lowers_the_contour_error_on_the_paper_s_contour():
    config = machine_config()
    pip = run_trial(PIP(config), config, "fig10").summary()
    cc = run_trial(build(config, "cross_coupled"), config, "fig10").summary()
    assert cc["rms_contour_error_mm"] < 0.8 * pip["rms_contour_error_mm"]
    assert cc["max_following_error_mm"] <= pip["max_following_error_mm"] * 1.01, "along the path: no worse"


@pytest.mark.parametrize(("fault", "message"), [
    (1, "raised RuntimeError: fault injected (fault = 1)"),
    (2, "returned nan as the speed command of axis X"),
    (3, "over its budget of 500 us"),
])
def test_waterjet_control_check_refuses_a_program_that_fails_on_the_plant_and_select_names_a_good_one(
        tmp_path, capsys, fault, message):
    machine = _machine_with(tmp_path, f'[control]\nprogram = "fault_injection"\n[control.parameters]\nfault = {fault}\n',
                            law=None)
    assert main(["control", "--machine", str(machine), "check", "fault_injection"]) == 1
    assert message in capsys.readouterr().err
    assert main(["control", "--machine", str(machine), "select", "cross_coupled", "--trajectory", "step"]) == 1
    assert "[control.parameters] fault: CrossCoupled has no such parameter" in capsys.readouterr().err, \
        "the machine file's parameters are the old program's: refused, the file as it was"
    assert load_machine(machine).control.program == "fault_injection"
    machine.write_text(machine.read_text().replace(f"[control.parameters]\nfault = {fault}\n", ""))
    assert main(["control", "--machine", str(machine), "select", "cross_coupled", "--trajectory", "step"]) == 0
    out = capsys.readouterr().out
    assert "cross_coupled (CrossCoupled) on the simulated plant, step" in out and "computation p99 (us)" in out
    assert load_machine(machine).control.program == "cross_coupled"
    assert main(["control", "--machine", str(machine), "select", "nothing"]) == 1
    assert "'nothing' is neither a shipped program" in capsys.readouterr().err
    assert load_machine(machine).control.program == "cross_coupled", "a refused selection changes nothing"
    assert main(["control", "--machine", str(machine)]) == 0
    listed = capsys.readouterr().out
    assert "* cross_coupled  (CrossCoupled)" in listed and "log control.contour_error [mm]" in listed


def test_the_readme_s_example_program_loads_from_a_file_beside_the_machine_file_and_runs(tmp_path):
    from .conftest import REPO

    readme = (REPO / "README.md").read_text()
    section = readme[readme.index("## Writing a control program"):]
    code = section[section.index("```python") + len("```python"):]
    code = code[:code.index("```")]
    toml = section[section.index("```toml") + len("```toml"):]
    toml = toml[:toml.index("```")]
    (tmp_path / "my_law.py").write_text(code)
    machine = _machine_with(tmp_path, toml, law=None)
    config = load_machine(machine)
    program = build(config)
    assert type(program).__name__ == "Damped" and program.damping == 0.05 and program.bias_mm_s == [0.0, -0.2]
    result = run_trial(program, config, "circle")
    assert not result.failure and result.summary()["max_following_error_mm"] < 0.2
    assert [v.name for v in log_variables(config).trace][-2:] == ["x.damping_term", "y.damping_term"]


def test_the_screen_shows_the_program_s_cpu_time_over_the_last_second_beside_its_budget():
    from cnc.data.dataserver import SharedArea
    from cnc.data.layout import controller_layouts
    from cnc.gateway.control_timing import ControlTiming
    from hmi.tuning import law_text

    config = machine_config(**{"control.program": "cross_coupled"})
    area = SharedArea.create(unique_name("test", "ct"), controller_layouts(2))
    try:
        now = [100.0]
        timing = ControlTiming(config, area, clock=lambda: now[0])
        servo = {"control_failures": 0, "control_failure": ""}
        assert timing.law(servo).p50_us == -1.0, "nothing ran yet"
        hist = area.blocks["control_timing"].array[0]["hist"]
        hist[2] += 1000  # a second of 2-3 us periods, then one that took 40 us
        hist[40] += 1
        now[0] += 0.5
        law = timing.law(servo)
        assert (law.program, law.p50_us, law.p99_us, law.max_us, law.budget_us) == ("cross_coupled (CrossCoupled)", 3.0,
                                                                                     3.0, 41.0, 500.0)
        now[0] += 1.0  # a second later the slow one is out of the window
        hist[5] += 10
        law = timing.law(servo)
        assert (law.p50_us, law.max_us) == (6.0, 6.0)
        text = law_text(law)
        assert text.startswith("Control program cross_coupled (CrossCoupled): CPU per period p50 6 µs, p99 6 µs, max 6 µs "
                               "of a 500 µs budget")
        failed = timing.law({"control_failures": 2, "control_failure": "control program x (X) raised KeyError: 'k'"})
        assert law_text(failed).endswith("; stopped 2 times, last: control program x (X) raised KeyError: 'k'")
    finally:
        del timing, hist
        area.close()


class _SlowOnce(PIP):
    """The PI-P, spending two periods of CPU time in each of `slow` (a set of period numbers)."""

    slow: frozenset = frozenset()

    def control(self, inputs: ControlInputs) -> list[float]:
        self.period = getattr(self, "period", -1) + 1
        if self.period in self.slow:
            until = time.thread_time_ns() + int(2e9 * inputs.dt_s)
            while time.thread_time_ns() < until:
                pass
        return super().control(inputs)


@pytest.mark.parametrize("slow,overruns,fails", [
    ({5}, 3, False),  # one slow period: the servo would carry on (3 in a row stop a program)
    ({5, 6, 7}, 3, True),
    ({5}, 1, True),  # a machine that stops at the first
])
def test_the_plant_trial_stops_a_program_over_its_budget_by_the_servo_s_own_rule(slow, overruns, fails):
    """`waterjet control check` refused a good program for one slow period (a garbage collection
    pass, a busy host), where the servo stops one only after `[control] budget_overruns` in a row."""
    config = machine_config(**{"control.budget_overruns": overruns})
    program = _SlowOnce(config)
    program.slow = frozenset(slow)
    budget_ns = config.control.budget_share * config.timing.period_s * 1e9
    result = run_trial(program, config, "step", 0.05, budget_ns=budget_ns)
    assert bool(result.failure) == fails, result.failure
    if fails:
        assert "over its budget" in result.failure and result.failed_at == sorted(slow)[overruns - 1]
