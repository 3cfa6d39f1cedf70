"""The layering of docs/design.md section 2, checked on every import statement (nested ones too)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Top-level modules each package must never import.
FORBIDDEN = {
    "seggrasp": {"pybullet", "pybullet_data", "pybullet_utils", "sim", "hardware", "rtde_control", "rtde_receive",
                 "rtde_io", "dashboard_client", "pyrealsense2"},
    "hardware": {"sim", "pybullet", "pybullet_data", "pybullet_utils"},
    "sim": {"hardware"},
}
#: The benchmark and the gym environment build a `hardware.RealCell` when asked for the real backend.
MAY_BUILD_THE_REAL_CELL = ("sim/env.py", "sim/evaluate/")


def imported_modules(path: Path) -> list[tuple[str, int]]:
    """(top-level module, line) for every import in the file, at any depth."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found += [(alias.name.split(".")[0], node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append((node.module.split(".")[0], node.lineno))
    return found


def violations(package: str) -> list[str]:
    out = []
    for path in sorted((ROOT / package).rglob("*.py")):
        relative = path.relative_to(ROOT).as_posix()
        if package == "sim" and relative.startswith(MAY_BUILD_THE_REAL_CELL):
            continue
        out += [f"{relative}:{line} imports {module}" for module, line in imported_modules(path)
                if module in FORBIDDEN[package]]
    return out


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_package_imports_respect_the_layering(package):
    assert violations(package) == []


def test_the_check_sees_a_nested_import(tmp_path):
    module = tmp_path / "m.py"
    module.write_text("def f():\n    import pyrealsense2 as rs\n    from sim.world import World\n")
    assert sorted(imported_modules(module)) == [("pyrealsense2", 2), ("sim", 3)]
