"""The package's stages import one way only (docs/architecture.md)."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "mapfilter"
# stage -> the stages it must never import (also not lazily, inside a function)
FORBIDDEN = {
    # the bottom: what every stage may use, itself using no stage
    "settings": {"maps", "sensors", "filter", "offline", "config", "tracking", "selftrain", "evaluation", "batch",
                 "simulate", "viz", "cli"},
    "maps": {"sensors", "filter", "offline", "config", "tracking", "selftrain", "evaluation", "batch", "simulate", "viz",
             "cli"},
    "sensors": {"filter", "offline", "config", "tracking", "selftrain", "evaluation", "batch", "simulate", "viz", "cli"},
    "filter": {"offline", "config", "tracking", "selftrain", "evaluation", "batch", "simulate", "viz", "cli"},
    "offline": {"config", "tracking", "selftrain", "evaluation", "batch", "simulate", "viz", "cli"},
    "config": {"tracking", "selftrain", "evaluation", "batch", "simulate", "viz", "cli"},
    "tracking": {"selftrain", "evaluation", "batch", "simulate", "viz", "cli"},
    # growing a radio map tracks walks (tracking); evaluation may grow maps
    "selftrain": {"evaluation", "batch", "simulate", "viz", "cli"},
    "evaluation": {"batch", "simulate", "viz", "cli"},
    "batch": {"simulate", "viz", "cli"},
    # the IPIN competition's client: the tracker and the competition's score, not the batch machinery
    "evaal": {"selftrain", "batch", "simulate", "viz", "cli"},
    # how walks are dispatched knows nothing of what a walk is
    "engine": {"maps", "sensors", "filter", "offline", "config", "tracking", "selftrain", "evaluation", "batch",
               "simulate", "viz", "cli"},
    "simulate": {"filter", "offline", "config", "tracking", "selftrain", "evaluation", "batch", "viz", "cli"},
    "viz": {"offline", "config", "tracking", "selftrain", "evaluation", "batch", "simulate", "cli"},
}


def _imports() -> dict[str, set[str]]:
    """Module name -> the mapfilter modules it imports (anywhere in the file)."""
    graph: dict[str, set[str]] = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        found = graph.setdefault(name, set())
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("mapfilter."):
                found.add(node.module)
            elif isinstance(node, ast.Import):
                found.update(a.name for a in node.names if a.name.startswith("mapfilter."))
    return graph


def _stage(module: str) -> str:
    return module.split(".")[1]


def test_stages_import_one_way():
    graph = _imports()
    assert "mapfilter.sensors.wifi" in graph and "mapfilter.filter.particle_filter" in graph  # the walk found the package
    wrong = sorted((a, b) for a, targets in graph.items() if a.count(".") >= 1
                   for b in targets if _stage(b) in FORBIDDEN.get(_stage(a), ()))
    assert wrong == []


def test_no_module_imports_itself_back():
    graph = _imports()

    def reachable(start: str) -> set[str]:
        seen, todo = set(), [start]
        while todo:
            for nxt in graph.get(todo.pop(), ()):
                if nxt not in seen:
                    seen.add(nxt)
                    todo.append(nxt)
        return seen

    assert sorted(m for m in graph if m in reachable(m)) == []
