"""An evaluation's per-walk results as files: written as each walk finishes, read back to resume.

``OUT/walks/<trace>.json`` holds one walk's outcome (every method's errors at the waypoints,
totals, floor scores, diagnostics, or why the walk failed) and the run's key: a digest of what
decides the numbers, by content (``file_digest`` of every log, of the map and the files it
names, of every radio map and access-point table, and the methods and every tracking setting),
so that a file replaced at the same path is a new run. ``--resume`` reuses only files whose key
matches the run being resumed; floats are written exactly (JSON keeps a float's shortest repr),
so a resumed evaluation gives the numbers of an uninterrupted one. Each file carries a checksum
of its own content and is checked field by field when read: a file of this run that fails (an
edit, a number where a list belongs) is refused, never trusted.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path

import numpy as np

from mapfilter.io.atomic import atomic_paths
from mapfilter.errors import MapfilterError
from mapfilter.evaluation.comparison import MethodResult, WalkOutcome
from mapfilter.evaluation.metrics import FloorScore
from mapfilter.io.tracks import Track

__all__ = ["file_digest", "read_outcome", "run_key", "write_outcome"]

STATUSES = ("ok", "failed", "crashed")


def run_key(description: dict) -> str:
    """A digest of everything that decides an evaluation's numbers (plain data)."""
    return hashlib.sha256(json.dumps(description, sort_keys=True, default=str).encode()).hexdigest()[:16]


def file_digest(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes (a missing or unreadable file: the reason, so the key changes)."""
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    except OSError as exc:
        return f"unreadable: {exc.strerror or exc}"
    return digest.hexdigest()


def _checksum(data: dict) -> str:
    body = {k: v for k, v in data.items() if k != "checksum"}
    return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()


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
            [r.floor_score.n_right, r.floor_score.n_judged, r.floor_score.missed,
             None if r.floor_score.storeys_off is None else [_number(float(v)) for v in r.floor_score.storeys_off]],
            "phone": r.phone,
        } for r in outcome.results],
    }
    data["checksum"] = _checksum(data)
    with atomic_paths(path) as (tmp,):
        tmp.write_text(json.dumps(data))


def read_outcome(path: str | os.PathLike, key: str) -> WalkOutcome | None:
    """The outcome in ``path`` if it belongs to the run ``key``; None: another run's.
    ``MapfilterError`` for a file that is not one of ours or fails its checks (its checksum, a
    field of the wrong type, an error that is not a finite distance): refused, not trusted.
    The tracks are not stored: results read back carry empty tracks."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError, RecursionError) as exc:
        raise MapfilterError(f"not a walk's stored outcome ({exc.__class__.__name__}): remove it, or run without "
                             "--resume", path) from None
    if not isinstance(data, dict) or data.get("key") != key:
        return None
    try:
        if data.get("checksum") != _checksum(data):
            raise ValueError("its checksum does not match its content (edited?)")
        return _outcome(data)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise MapfilterError(f"the stored outcome fails its checks ({exc}): remove it, or run without --resume",
                             path) from None


def _outcome(data: dict) -> WalkOutcome:
    """A ``WalkOutcome`` from stored data, every field checked (TypeError / ValueError)."""
    _expect(data, {"index": int, "trace": str, "log": str, "status": str, "reason": str, "methods": list})
    if data["status"] not in STATUSES:
        raise ValueError(f"status {data['status']!r}")
    results = []
    for m in data["methods"]:
        if not isinstance(m, dict):
            raise TypeError("a method that is not a mapping")
        _expect(m, {"method": str, "errors_m": list, "missed": int, "wall_crossings": int, "collapses": int,
                    "runtime_s": (int, float), "causal": bool, "diagnostics": dict})
        errors = np.array([_finite(e, "errors_m") for e in m["errors_m"]], dtype=np.float64)
        if (errors < 0).any():
            raise ValueError("a negative error")
        score = m.get("floor_score")
        if score is not None and not (isinstance(score, list) and len(score) >= 3
                                      and all(isinstance(v, int) for v in score[:3])):
            raise TypeError("floor_score")
        diagnostics = {}
        for k, v in m["diagnostics"].items():
            diagnostics[str(k)] = math.nan if v is None else _finite(v, "diagnostics")
        results.append(MethodResult(
            m["method"], data["trace"], Track(np.zeros(0), np.zeros((0, 2)), name=m["method"]),
            errors, m["missed"], m["wall_crossings"], m["collapses"], float(m["runtime_s"]), m["causal"],
            diagnostics, None if score is None else _floor_score(score), m.get("phone")))
    warnings = data.get("read_warnings", [])
    if not isinstance(warnings, list):
        raise TypeError("read_warnings")
    return WalkOutcome(data["index"], data["trace"], Path(data["log"]), data["status"], data["reason"], results,
                       [str(w) for w in warnings], float(_finite(data.get("runtime_s", 0.0), "runtime_s")))


def _expect(data: dict, types: dict) -> None:
    for name, kind in types.items():
        value = data[name]
        if isinstance(value, bool) and kind is not bool or not isinstance(value, kind):
            raise TypeError(f"{name} is {type(value).__name__}")


def _finite(value, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{name} holds {value!r}")
    return float(value)


def _floor_score(stored: list) -> FloorScore:
    storeys = stored[3] if len(stored) > 3 else None
    return FloorScore(*stored[:3], None if storeys is None else
                      np.array([math.nan if v is None else v for v in storeys], dtype=np.float64))
