"""Dependencies flow one way: gcode never imports cnc; only hmi imports Qt; hmi reaches cnc only through cnc.bus."""

from __future__ import annotations

import ast
import enum
from pathlib import Path

import pytest

from .conftest import REPO

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)


def _imports(package: str) -> list[tuple[Path, str]]:
    found = []
    for path in (REPO / package).rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                found += [(path, a.name) for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                found.append((path, node.module))
    return found


def test_gcode_is_a_pure_library_that_never_imports_the_controller():
    assert [(p.name, m) for p, m in _imports("gcode") if m.split(".")[0] in ("cnc", "hmi", "plc_link", "PySide6")] == []


def test_only_the_hmi_imports_qt():
    for package in ("cnc", "gcode", "plc_link"):
        assert [(p.name, m) for p, m in _imports(package) if m.startswith(("PySide6", "pyqtgraph"))] == []


def test_the_hmi_reaches_the_controller_only_through_the_bus_schemas():
    bad = [(p.name, m) for p, m in _imports("hmi") if m.startswith("cnc") and not m.startswith("cnc.bus")]
    assert bad == []


# -- the layering, transitively ------------------------------------------------------------------


def _module_graph() -> dict[str, set[str]]:
    """Every project module and the project modules it imports (relative imports resolved,
    imports inside functions included: a lazy import is still a dependency)."""
    packages = ("cnc", "hmi", "plc_link", "gcode")
    modules: dict[str, Path] = {}
    for package in packages:
        for path in (REPO / package).rglob("*.py"):
            parts = list(path.relative_to(REPO).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            modules[".".join(parts)] = path
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        is_package = path.name == "__init__.py"
        base = name.split(".") if is_package else name.split(".")[:-1]
        edges: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    anchor = base[: len(base) - (node.level - 1)]
                    module = ".".join(anchor + ([node.module] if node.module else []))
                else:
                    module = node.module or ""
                targets = [module] + [f"{module}.{a.name}" for a in node.names]
            for target in targets:
                while target and target not in modules:  # `a.b.C` (a class) is a use of module `a.b`
                    target = target.rpartition(".")[0]
                if target and target != name:
                    edges.add(target)
        graph[name] = edges
    return graph


def _reach(graph: dict[str, set[str]], start: str) -> set[str]:
    seen, todo = set(), [start]
    while todo:
        for nxt in graph[todo.pop()]:
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


# What assembles the controller and so may start the PLC link: the supervisor, its table of process entry points,
# the simulation aids and the command line. The PLC link builds on the rest (the machine file, the data plane,
# a child process's set-up), and nothing of that rest reaches back into it.
COMPOSITION = ("cnc.runtime.supervisor", "cnc.runtime.procs", "cnc.sim", "cnc.cli")


def test_plc_link_builds_on_the_controllers_core_and_no_module_import_runs_in_a_circle_between_them():
    graph = _module_graph()
    for name in graph:
        if name.startswith("plc_link"):
            reached = _reach(graph, name)
            assert not [m for m in reached if m.startswith(COMPOSITION)], f"{name} reaches the composition layer"
        elif name.startswith("cnc") and not name.startswith(COMPOSITION):
            reached = _reach(graph, name)
            assert not [m for m in reached if m.startswith("plc_link")], f"{name} reaches plc_link"
    for name in graph:  # and no module reaches itself again (an import cycle across modules)
        cycle = name in _reach(graph, name)
        crosses = cycle and any(m.startswith("plc_link") for m in _reach(graph, name)) and name.startswith("cnc")
        assert not crosses, f"{name} is in an import cycle through plc_link"


def test_the_hmi_reaches_no_part_of_the_running_controller_even_indirectly():
    """Through the bus it reaches the schemas, the sessions and the machine file's validation (with
    the enums that validation checks), never a process of the controller or the PLC link."""
    graph = _module_graph()
    reached = set().union(*(_reach(graph, m) for m in graph if m.startswith("hmi")))
    running = ("cnc.runtime", "cnc.gateway", "cnc.logger", "cnc.sim", "cnc.servo", "cnc.hw", "cnc.planner", "cnc.logic",
               "cnc.alarms", "cnc.cli", "plc_link")
    assert sorted(m for m in reached if m.startswith(running)) == []


def test_the_tick_path_reaches_neither_the_network_nor_the_disk_writers_nor_the_screen():
    graph = _module_graph()
    for tick in ("cnc.servo", "cnc.hw.server", "cnc.interlock", "cnc.brake"):
        reached = _reach(graph, tick)
        bad = sorted(m for m in reached if m.startswith(("cnc.gateway", "cnc.logger", "cnc.sim", "cnc.alarms", "hmi", "plc_link",
                                                          "cnc.runtime.supervisor")))
        assert bad == [], f"{tick} reaches {bad}"


def test_the_screen_and_the_gateway_compare_states_by_their_enums_never_by_spelled_out_names():
    """cnc.bus.states defines every state, fault and alarm level once, for the controller and the
    HMI; a comparison against a literal such as "RUNNING" would silently break on a rename."""
    from cnc.bus import states

    names = {m.name for e in vars(states).values() if isinstance(e, type) and issubclass(e, enum.Enum) for m in e}
    names |= {m.name.lower() for m in states.AlarmLevel}
    spelled = []
    for package in ("hmi", "cnc/gateway"):
        for path in (REPO / package).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Compare):
                    for side in [node.left, *node.comparators]:
                        elements = side.elts if isinstance(side, (ast.Tuple, ast.List, ast.Set)) else [side]
                        spelled += [(path.name, node.lineno, e.value) for e in elements
                                    if isinstance(e, ast.Constant) and isinstance(e.value, str) and e.value in names]
    assert spelled == []


def test_every_door_of_the_controller_serves_through_the_one_command_service_with_one_refusal_type():
    """Queryables are declared, and queries answered, only by cnc.bus.service (a station's answer to
    the gateway's ping aside: that is the station's, not a door of the controller); no module
    declares a refusal exception of its own."""
    allowed = {REPO / "cnc/bus/service.py", REPO / "cnc/bus/operator.py"}
    serving, refusals = [], []
    for package in ("cnc", "plc_link"):
        for path in (REPO / package).rglob("*.py"):
            tree = ast.parse(path.read_text(), str(path))
            for node in ast.walk(tree):
                if isinstance(node, ast.Attribute) and node.attr in ("declare_queryable", "reply_err") and path not in allowed:
                    serving.append((path.name, node.lineno, node.attr))
                if isinstance(node, ast.ClassDef) and "Refus" in node.name and node.name != "CommandRefused":
                    refusals.append((path.name, node.name))
    assert serving == [] and refusals == []
