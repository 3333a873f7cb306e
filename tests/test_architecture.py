"""The package's stages import one way only (docs/architecture.md)."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "mapfilter"
# stage -> the stages it must never import (also not lazily, inside a function); a stage is the
# package under mapfilter/ (or a top-level module), except the modules STAGE_OF names
ALL = {"settings", "io", "runtime", "maps", "sensors", "filter", "offline", "config", "pipeline", "evaluation", "batch",
       "evaal", "simulate", "viz", "cli", "api", "warmup"}


def _above(*allowed: str) -> set[str]:
    """Every stage but ``allowed``."""
    return ALL - set(allowed)


FORBIDDEN = {
    # the bottom: files, and how work runs (dispatching walks knows nothing of what a walk is)
    "io": _above(),
    "runtime": _above(),
    "settings": _above("io"),
    "maps": _above("io", "runtime"),
    "sensors": _above("io", "runtime", "maps"),
    "filter": _above("io", "runtime", "maps", "sensors"),
    "offline": _above("io", "runtime", "maps", "sensors", "filter"),
    "config": _above("io", "runtime", "settings", "maps", "sensors", "filter", "offline"),
    # one walk through the filter, and radio maps grown by tracking walks
    "pipeline": _above("io", "runtime", "settings", "maps", "sensors", "filter", "offline", "config"),
    "evaluation": _above("io", "runtime", "settings", "maps", "sensors", "filter", "offline", "config", "pipeline"),
    "batch": _above("io", "runtime", "settings", "maps", "sensors", "filter", "offline", "config", "pipeline",
                    "evaluation"),
    # the IPIN competition's client: the tracker and the competition's score, not the batch machinery
    "evaal": _above("io", "runtime", "settings", "maps", "sensors", "filter", "offline", "config", "pipeline",
                    "evaluation"),
    "simulate": _above("io", "runtime", "maps", "sensors"),
    "viz": _above("io", "runtime", "maps", "sensors", "filter"),
}
# the warm-up tracks a simulated walk through every stage to fill numba's cache: it sits on top
STAGE_OF = {"mapfilter.runtime.warmup": "warmup"}


def _imports() -> dict[str, set[str]]:
    """Module name -> the mapfilter modules it imports (anywhere in the file)."""
    graph: dict[str, set[str]] = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        found = graph.setdefault(name, set())
        tree = ast.parse(path.read_text())
        # names imported for annotations only (``if TYPE_CHECKING:``) are no dependency at run time
        for node in ast.walk(tree):
            if isinstance(node, ast.If) and getattr(node.test, "id", None) == "TYPE_CHECKING":
                node.body = []
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("mapfilter."):
                found.add(node.module)
            elif isinstance(node, ast.Import):
                found.update(a.name for a in node.names if a.name.startswith("mapfilter."))
    return graph


def _stage(module: str) -> str:
    return STAGE_OF.get(module) or module.split(".")[1]


def test_stages_import_one_way():
    graph = _imports()
    assert "mapfilter.sensors.wifi" in graph and "mapfilter.filter.particle_filter" in graph  # the walk found the package
    stages = {_stage(m) for m in graph if m.count(".") >= 1}
    assert stages <= ALL | {"errors", "__main__"}, stages - ALL  # every package has its place above
    wrong = sorted((a, b) for a, targets in graph.items() if a.count(".") >= 1
                   for b in targets if _stage(b) != _stage(a) and _stage(b) in FORBIDDEN.get(_stage(a), ()))
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
