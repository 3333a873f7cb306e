"""The package's stages import one way only (docs/architecture.md), imports for annotations
(``if TYPE_CHECKING:``) counted like any other: a type-only import upward is still a stage
that knows one above it."""

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
# inside filter/, its layers from the bottom up (docs/architecture.md, "filter/"): a module imports
# only from its own layer or those below. The kernels; the state and what is read off it; the
# models (likelihoods and moves); a source's adapter base; the registered sources; a walk's
# WiFi evidence; the step; the reference step in numpy; the causal loop.
FILTER_LAYERS = (
    ("mapfilter.filter.kernels",),
    ("mapfilter.filter.particles", "mapfilter.filter.estimate", "mapfilter.filter.events"),
    ("mapfilter.filter.models",),
    ("mapfilter.filter.measurement",),
    ("mapfilter.filter.sources",),
    ("mapfilter.filter.evidence",),
    ("mapfilter.filter.particle_filter",),
    ("mapfilter.filter.reference",),
    ("mapfilter.filter.causal",),
)


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


def _filter_layer(module: str) -> int | None:
    for depth, layer in enumerate(FILTER_LAYERS):
        if any(module == prefix or module.startswith(prefix + ".") for prefix in layer):
            return depth
    return None


def test_every_filter_module_has_a_layer():
    graph = _imports()
    modules = [m for m in graph if m.startswith("mapfilter.filter.")]
    assert "mapfilter.filter.causal" in modules and "mapfilter.filter.models.ble" in modules
    assert [m for m in modules if _filter_layer(m) is None] == []


def test_filter_layers_import_one_way():
    graph = _imports()
    upward = sorted((a, b) for a, targets in graph.items() if _filter_layer(a) is not None
                    for b in targets if _filter_layer(b) is not None and _filter_layer(b) > _filter_layer(a))
    assert upward == []


def test_the_checks_see_type_only_imports():
    """An upward import inside ``if TYPE_CHECKING:`` counts: the graph has it."""
    graph = _imports()
    # filter.measurement imports the models' interface for its annotations only
    assert "mapfilter.filter.models.interface" in graph["mapfilter.filter.measurement"]
