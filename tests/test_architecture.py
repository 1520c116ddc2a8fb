"""Dependencies flow one way: gcode never imports cnc; only hmi imports Qt; hmi reaches cnc only through cnc.bus."""

from __future__ import annotations

import ast
from pathlib import Path

from .conftest import REPO


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
