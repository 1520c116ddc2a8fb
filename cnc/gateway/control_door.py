"""The control programs at the operator's door: the list the tuning window shows, and the
selection of the machine's program (`cnc.control`; `waterjet control` does the same from a
shell).

A selection is checked as `waterjet control check` checks (built, then run on the simulated
plant along the circle within its budget) and written into the machine file's `[control]
program`. It takes effect at the controller's next start: the program's registrations size the
trace record, the parameter slots and the log variables every process agrees on at start.
"""

from __future__ import annotations

from ..bus.states import PlannerState
from ..bus.messages import ControlParameter, ControlProgramInfo, ControlProgramList, Reply
from ..config import ConfigError, MachineConfig, load_machine
from ..control.loader import SHIPPED, build
from ..control.program import ControlProgramError
from ..control.trial import run as run_trial
from ..params import check_literals, save_literals, toml_string


def program_list(config: MachineConfig) -> ControlProgramList:
    """Every program this machine can name: the one it runs, the one its file names now, the shipped ones."""
    selected = _selected(config)
    names = list(dict.fromkeys([config.control.program, selected, *SHIPPED]))
    return ControlProgramList([_info(config, name) for name in names], config.control.program, selected,
                              config.control.budget_share * config.timing.period_s * 1e6)


def _selected(config: MachineConfig) -> str:
    try:
        return load_machine(config.source).control.program
    except ConfigError:
        return config.control.program


def _info(config: MachineConfig, name: str) -> ControlProgramInfo:
    try:
        program = build(config, name)
    except ControlProgramError as exc:
        return ControlProgramInfo(name, "", "", [], [], str(exc))
    cls = type(program)
    params = []
    for p in program.parameters:
        value = getattr(program, p.name)
        params.append(ControlParameter(p.name, [float(v) for v in value] if p.per_axis else [float(value)], p.unit, p.lo,
                                       p.hi, p.doc, p.per_axis))
    logs = [n for spec in program.log_variables for n in spec.names(config.axis_names)]
    return ControlProgramInfo(name, cls.__name__, cls.description or (cls.__doc__ or "").strip().splitlines()[0], params,
                              logs)


def select(config: MachineConfig, name: str, planner_state: PlannerState) -> Reply:
    """Check `name`, then name it in the machine file; refused (with the reason, the file as it
    was) while anything runs, or when it does not build or fails on the simulated plant."""
    if planner_state != PlannerState.IDLE:
        return Reply(False, f"control program: not while the planner is {planner_state.name}: select one while nothing "
                            "runs")
    change = {(("control",), "program"): toml_string(name)}
    try:
        fresh = load_machine(config.source)
        program = build(fresh, name)
        check_literals(config.source, change)  # the file as it would be (its parameters), before the plant
    except (ConfigError, ControlProgramError) as exc:
        return Reply(False, f"control program: {exc}")
    budget_ns = fresh.control.budget_share * fresh.timing.period_s * 1e9
    result = run_trial(program, fresh, "circle", fresh.control.check_periods * fresh.timing.period_s, budget_ns=budget_ns)
    if result.failure:
        return Reply(False, f"control program: {name} ({type(program).__name__}) {result.failure} (period "
                            f"{result.failed_at} of a circle on the simulated plant)")
    try:
        save_literals(config.source, change)
    except ConfigError as exc:
        return Reply(False, f"control program: {exc}")
    s = result.summary()
    return Reply(True, f"control program {name} ({type(program).__name__}) selected in {config.source}: checked on the "
                       f"simulated plant (circle: max following error {s['max_following_error_mm'] * 1e3:.1f} um, CPU "
                       f"p99 {s['control_p99_us']:.1f} us of {budget_ns / 1000:.0f}); the controller runs it from its "
                       "next start")
