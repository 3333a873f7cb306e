"""An evaluation's per-walk results as files: written as each walk finishes, read back to resume.

``OUT/walks/<trace>.json`` holds one walk's outcome (every method's errors at the waypoints,
totals, floor scores, diagnostics, or why the walk failed) and the run's key: a digest of what
decides the numbers (the map, the walks, the WiFi source, the methods, every tracking setting).
``--resume`` reuses only files whose key matches the run being resumed; floats are written
exactly (JSON keeps a float's shortest repr), so a resumed evaluation gives the numbers of an
uninterrupted one.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path

import numpy as np

from mapfilter.atomic import atomic_paths
from mapfilter.evaluation.comparison import MethodResult, WalkOutcome
from mapfilter.evaluation.metrics import FloorScore
from mapfilter.trackio import Track

__all__ = ["read_outcome", "run_key", "write_outcome"]


def run_key(description: dict) -> str:
    """A digest of everything that decides an evaluation's numbers (plain data)."""
    return hashlib.sha256(json.dumps(description, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _number(value: float) -> float | None:
    return None if value is None or (isinstance(value, float) and math.isnan(value)) else value


def write_outcome(outcome: WalkOutcome, path: str | os.PathLike, key: str) -> None:
    """One walk's outcome as JSON, atomically."""
    data = {
        "key": key, "index": outcome.index, "trace": outcome.trace, "log": str(outcome.log_path),
        "status": outcome.status, "reason": outcome.reason, "runtime_s": outcome.runtime_s,
        "read_warnings": outcome.read_warnings,
        "methods": [{
            "method": r.method, "errors_m": [float(e) for e in r.errors_m], "missed": r.missed,
            "wall_crossings": r.wall_crossings, "collapses": r.collapses, "runtime_s": r.runtime_s,
            "causal": r.causal, "diagnostics": {k: _number(v) for k, v in r.diagnostics.items()},
            "floor_score": None if r.floor_score is None else
            [r.floor_score.n_right, r.floor_score.n_judged, r.floor_score.missed],
        } for r in outcome.results],
    }
    with atomic_paths(path) as (tmp,):
        tmp.write_text(json.dumps(data))


def read_outcome(path: str | os.PathLike, key: str) -> WalkOutcome | None:
    """The outcome in ``path`` if it belongs to the run ``key`` (None: another run's, or unreadable).
    The tracks are not stored: results read back carry empty tracks."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("key") != key:
        return None
    results = []
    for m in data["methods"]:
        score = m.get("floor_score")
        results.append(MethodResult(
            m["method"], data["trace"], Track(np.zeros(0), np.zeros((0, 2)), name=m["method"]),
            np.array(m["errors_m"], dtype=np.float64), m["missed"], m["wall_crossings"], m["collapses"],
            m["runtime_s"], m["causal"], {k: (math.nan if v is None else v) for k, v in m["diagnostics"].items()},
            None if score is None else FloorScore(*score)))
    return WalkOutcome(data["index"], data["trace"], Path(data["log"]), data["status"], data["reason"], results,
                       list(data.get("read_warnings", [])), data.get("runtime_s", 0.0))
