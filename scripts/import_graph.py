"""Draw the project's import graph (docs/import-graph.png) and report import circles.

    python scripts/import_graph.py [--out docs/import-graph.png]

Every `import` of a project module in seggrasp/, sim/ and hardware/ is an edge, module-level ones solid and the
ones inside functions (lazy) dashed; seggrasp.detect, seggrasp.grasp and hardware are drawn as one node each.
Columns: the harnesses (benchmark, gym env, CLIs), the episode, the method and its building blocks, and the
cells beside them. Exits 1 when two or more modules import each other in a circle (lazy imports included; checked module by
module, before collapsing), naming it.
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

import networkx as nx

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("seggrasp", "sim", "hardware")
COLLAPSED = ("seggrasp.detect", "seggrasp.grasp", "hardware")
#: Column of a node (first matching prefix wins): data flows left to right, the cells sit on the right.
COLUMNS = (
    ("harness", ("sim.evaluate", "sim.env", "sim.__init__", "seggrasp.__main__")),
    ("cell", ("seggrasp.cell", "sim.", "hardware")),
    ("episode", ("seggrasp.episode", "seggrasp.truth")),
    ("method", ("seggrasp.method", "seggrasp.segment", "seggrasp.fusion", "seggrasp.baselines", "seggrasp.detect",
                "seggrasp.grasp", "seggrasp.perception")),
    ("building blocks", ("seggrasp.",)),
)
COLOURS = {"harness": "#f4a261", "episode": "#e76f51", "method": "#2a9d8f", "building blocks": "#8ab17d",
           "cell": "#577590"}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__" and len(parts) > 1 and parts[0] != "sim":
        parts = parts[:-1]
    return ".".join(parts)


def node_of(module: str) -> str:
    for prefix in COLLAPSED:
        if module == prefix or module.startswith(prefix + "."):
            return prefix
    return module


def column_of(node: str) -> str:
    for column, prefixes in COLUMNS:
        if any(node == p or node.startswith(p) for p in prefixes):
            return column
    return "building blocks"


def imports_of(path: Path, modules: set[str]) -> list[tuple[str, bool]]:
    """(imported project module, lazy) for every import statement in `path`."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    top_level = {id(node) for node in tree.body}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module] + [f"{node.module}.{alias.name}" for alias in node.names]
        else:
            continue
        lazy = id(node) not in top_level and not _in_type_checking(tree, node)
        for name in names:
            while name and name not in modules:
                name = name.rpartition(".")[0]
            if name:
                found.append((name, lazy))
    return found


def _in_type_checking(tree: ast.Module, target: ast.AST) -> bool:
    for node in tree.body:
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            if any(child is target for child in ast.walk(node)):
                return True
    return False


def build_graph(collapse: bool = True) -> nx.DiGraph:
    """The import graph; with `collapse`, the COLLAPSED packages are one node each."""
    files = [p for package in PACKAGES for p in sorted((ROOT / package).rglob("*.py"))]
    modules = {module_name(p) for p in files} | set(PACKAGES)
    merge = node_of if collapse else (lambda name: name)
    graph = nx.DiGraph()
    for path in files:
        source = merge(module_name(path))
        graph.add_node(source)
        for target, lazy in imports_of(path, modules):
            target = merge(target)
            if target != source:
                eager = not lazy or graph.get_edge_data(source, target, {}).get("eager", False)
                graph.add_edge(source, target, eager=eager)
    graph.remove_nodes_from([n for n in list(graph) if n in ("sim.__main__",)])
    return graph


def draw(graph: nx.DiGraph, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    order = [c for c, _ in COLUMNS]
    x_of = {"harness": 0, "episode": 1, "method": 2, "building blocks": 3, "cell": 4.3}
    by_column: dict[str, list[str]] = {c: [] for c in order}
    for node in sorted(graph):
        by_column[column_of(node)].append(node)
    pos = {}
    for column, nodes in by_column.items():
        for i, node in enumerate(nodes):
            pos[node] = (x_of[column], -(i - (len(nodes) - 1) / 2))
    fig, ax = plt.subplots(figsize=(16, 10))
    eager = [(u, v) for u, v, d in graph.edges(data=True) if d["eager"]]
    lazy = [(u, v) for u, v, d in graph.edges(data=True) if not d["eager"]]
    nx.draw_networkx_edges(graph, pos, edgelist=eager, ax=ax, alpha=0.35, arrowsize=8, node_size=1800)
    nx.draw_networkx_edges(graph, pos, edgelist=lazy, ax=ax, alpha=0.35, arrowsize=8, style="dashed", node_size=1800)
    nx.draw_networkx_nodes(graph, pos, ax=ax, node_size=1800, node_shape="s",
                           node_color=[COLOURS[column_of(n)] for n in graph], alpha=0.85)
    nx.draw_networkx_labels(graph, pos, ax=ax, font_size=7)
    top = max(y for _, y in pos.values()) + 1.2
    for column in order:
        ax.text(x_of[column], top, column, ha="center", fontsize=12, weight="bold", color=COLOURS[column])
    ax.set_title("Imports (arrow: imports; dashed: inside a function). Data flows harness -> episode -> method; "
                 "the cells beside.", fontsize=11, pad=28)
    ax.axis("off")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "import-graph.png")
    args = parser.parse_args(argv)
    graph = build_graph()
    draw(graph, args.out)
    print(f"{graph.number_of_nodes()} modules, {graph.number_of_edges()} imports -> {args.out}")
    # circles between single modules, a package's __init__ importing its own modules aside
    full = build_graph(collapse=False)
    full.remove_edges_from([(u, v) for u, v in list(full.edges) if v.startswith(u + ".") or u.startswith(v + ".")])
    cycles = sorted(list(c) for c in nx.simple_cycles(full))
    for cycle in cycles:
        print("import circle: " + " -> ".join(cycle), file=sys.stderr)
    return 1 if cycles else 0


if __name__ == "__main__":
    sys.exit(main())
