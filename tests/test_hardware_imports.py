"""The hardware package's modules import one another one way: no circles, and no import hidden inside a function."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "hardware"


def hardware_imports(path: Path) -> tuple[set[str], list[int]]:
    """(hardware modules imported at the top level, line numbers of hardware imports inside functions)."""
    tree = ast.parse(path.read_text())
    top = {node.module.split(".")[1] for node in tree.body
           if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("hardware.")}
    functions = [node for node in ast.walk(tree) if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))]
    nested = [node.lineno for function in functions for node in ast.walk(function)
              if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("hardware")]
    return top, nested


def test_hardware_modules_import_one_way():
    graph = {}
    for path in sorted(PACKAGE.glob("*.py")):
        top, nested = hardware_imports(path)
        assert not nested, f"{path.name} imports hardware modules inside functions (lines {nested})"
        graph[path.stem] = top - {path.stem}
    order: list[str] = []

    def visit(module: str, stack: tuple[str, ...]) -> None:
        if module in stack:
            pytest.fail(f"import circle: {' -> '.join(stack[stack.index(module):] + (module,))}")
        if module not in order:
            for dependency in sorted(graph.get(module, ())):
                visit(dependency, stack + (module,))
            order.append(module)

    for module in graph:
        visit(module, ())
    assert order.index("fields") < order.index("calibration") < order.index("config")
