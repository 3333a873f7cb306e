"""What several commands share: warnings on stderr, the engine options, output-path checks,
argument types with limits, progress bars."""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

from mapfilter.engine import Engine
from mapfilter.errors import MapfilterError


def warn(message: str) -> None:
    """One warning line on stderr, in the form every command uses."""
    print(f"mapfilter: warning: {message}", file=sys.stderr)


def add_strict_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--strict", action="store_true",
                        help="refuse a log with a bad row in a record type the run needs, or a cut gzip stream "
                             "(default: skip such rows with a warning; bad rows of unused types are always skipped)")


def add_engine_arguments(parser: argparse.ArgumentParser) -> None:
    engine = parser.add_mutually_exclusive_group()
    engine.add_argument("--jobs", type=positive_int, default=1, metavar="N",
                        help="walks in N local Dask worker processes on 127.0.0.1, reachable only by this run "
                             "(TLS with temporary credentials; default: 1, serial, no Dask)")
    engine.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                        help="run the walks on an existing Dask cluster that you trust: whoever can use it runs "
                             "code as its workers, and its results are unpickled here (workers need mapfilter "
                             "and the logs; tls://HOST:PORT uses Dask's TLS configuration)")


def engine_from(args: argparse.Namespace) -> Engine:
    return Engine(jobs=args.jobs, scheduler=args.scheduler)


# ---- argument order ------------------------------------------------------------------------------
MAP_SUFFIXES = (".yaml", ".yml")


def check_map_first(usage: str, map_path: Path, log_paths: Sequence[Path] = ()) -> None:
    """Refuse arguments in the wrong order (``track LOG MAP``) in one line that says the map comes
    first: a MAP that is a phone log, or a LOG that is a map YAML. ``usage``: the command's
    synopsis, e.g. ``mapfilter track MAP LOG...``."""
    from mapfilter.sensors.logs import sniff_log_format  # not at import: --help loads no numerical library

    if Path(map_path).is_file() and Path(map_path).suffix.lower() not in MAP_SUFFIXES:
        log_format = sniff_log_format(map_path)
        if log_format is not None:
            raise MapfilterError(f"is a phone log ({log_format}), not a map: the map comes first ({usage})", map_path)
    for path in log_paths:
        if Path(path).suffix.lower() in MAP_SUFFIXES and Path(path).is_file():
            raise MapfilterError(f"is a map YAML, not a phone log: the map comes first ({usage})", path)


# ---- ground truth against the map --------------------------------------------------------------
def waypoints_in_walls(building, recording) -> str | None:
    """One line when waypoints of ``recording`` fall in the walls of ``building`` (or outside its
    maps), naming the log, how many and the first; a line saying why they cannot be checked
    (latitude/longitude waypoints and a map without a georeference, no floor named in a
    building); None when every waypoint is on free space or the log has none."""
    import numpy as np

    from mapfilter.sensors.logs import localise

    if not recording.has_ground_truth:
        return None
    where = recording.path
    try:
        if recording.needs_georeference:
            recording = localise(recording, building)
        n = recording.waypoint_t_s.size
        if building.is_single_floor:
            floors = [building.floors[0].name] * n
        else:
            header = building.floor_of_log(recording.floor_name, where)
            floors = list(recording.waypoint_floor) if recording.waypoint_floor else (
                [building.floor_names[header]] * n if header is not None else None)
            if floors is None:
                return f"{where}: names no floor (FloorName): its waypoints cannot be checked against a building"
    except MapfilterError as exc:
        return f"{where}: its waypoints cannot be checked: {exc.reason}"
    in_walls = np.zeros(n, dtype=bool)
    for name in dict.fromkeys(floors):
        on = np.array([f == name for f in floors])
        in_walls[on] = ~building.floor(name).plan.is_free(recording.waypoint_xy_m[on])
    if not in_walls.any():
        return None
    first = int(np.flatnonzero(in_walls)[0])
    x, y = recording.waypoint_xy_m[first]
    t = recording.waypoint_t_s[first] - recording.waypoint_t_s[0]
    return (f"{where}: {int(in_walls.sum())} of {n} waypoints fall in walls or outside the map (the first at "
            f"x {x:.1f} m, y {y:.1f} m, t {t:+.0f} s): a wrong scale or origin, closed outlines (--open-outlines), "
            "or a plan of another floor?")


# ---- output paths ------------------------------------------------------------------------------
def check_output_path(path: str | os.PathLike | None, option: str = "--out", directory: bool = False) -> None:
    """Refuse an output path that cannot be written, before any work is done.

    ``path`` is a file to write (``directory=False``) or a directory to write files into
    (``directory=True``). A missing parent (or a missing directory) is fine when it can be
    made: writing makes it, as ``mapfilter.atomic.atomic_paths`` does. ``MapfilterError``
    (one line naming the path and the option) when the path is a directory but a file is
    wanted (or the other way round), when a parent is a file, or when the nearest existing
    directory cannot be written to (permissions, a read-only file system). ``None`` passes
    (the option was not given).
    """
    if path is None:
        return
    path = Path(path)
    if str(path) in ("", "."):
        raise MapfilterError(f"{option} needs a {'directory' if directory else 'file'} name")
    if path.exists():
        if directory and not path.is_dir():
            raise MapfilterError(f"{option}: exists and is not a directory", path)
        if not directory and path.is_dir():
            raise MapfilterError(f"{option}: is a directory; give a file name", path)
    existing = path if directory and path.is_dir() else path.parent
    # the nearest directory that exists: the missing ones below it are made when writing
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise MapfilterError(f"{option}: cannot be made, {existing} is not a directory", path)
    _check_writable_directory(existing, path, option)


def _check_writable_directory(directory: Path, path: Path, option: str) -> None:
    # os.access says yes to root and knows nothing of read-only mounts or ACLs: try it
    try:
        fd, probe = tempfile.mkstemp(prefix=".mapfilter-probe.", dir=directory)
    except OSError as exc:
        raise MapfilterError(f"{option}: cannot write in {directory} ({exc.strerror or exc})", path) from None
    os.close(fd)
    with contextlib.suppress(OSError):
        os.unlink(probe)


# ---- argument types with limits ----------------------------------------------------------------
def non_negative_int(text: str) -> int:
    """argparse type: a whole number >= 0 (e.g. ``--seed``); argparse turns the error into its usage line."""
    return bounded_int(0)(text)


def positive_int(text: str) -> int:
    """argparse type: a whole number >= 1."""
    return bounded_int(1)(text)


def bounded_int(low: int | None = None, high: int | None = None):
    """argparse type: a whole number in [low, high] (either end may be open)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a whole number, got {text!r}") from None
        _check_range(value, text, low, high)
        return value

    parse.__name__ = "whole number"  # argparse names the type in some messages
    return parse


def bounded_float(low: float | None = None, high: float | None = None, low_open: bool = False):
    """argparse type: a finite number in [low, high] (``low_open``: strictly above ``low``)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
        if low_open and low is not None and value <= low:
            raise argparse.ArgumentTypeError(f"must be above {low:g}, got {text}")
        _check_range(value, text, low, high)
        return value

    parse.__name__ = "number"
    return parse


def _check_range(value: float, text: str, low: float | None, high: float | None) -> None:
    if low is not None and value < low:
        raise argparse.ArgumentTypeError(f"must be at least {low:g}, got {text}")
    if high is not None and value > high:
        raise argparse.ArgumentTypeError(f"must be at most {high:g}, got {text}")


class ProgressBar:
    """A tqdm bar on stderr, drawn only when stderr is a terminal (quiet in pipes, logs, CI).

    Call it as a ``progress(done, total, name)`` callback, or use ``update_to`` for a fraction.
    """

    def __init__(self, description: str, total: float, unit: str = "walk") -> None:
        from tqdm import tqdm

        self.bar = tqdm(total=total, desc=description, unit=unit, file=sys.stderr, leave=False,
                        disable=not sys.stderr.isatty(), dynamic_ncols=True)

    def __call__(self, done: int, total: int, name: str) -> None:
        self.bar.total = total
        self.bar.set_postfix_str(name[:40], refresh=False)
        self.bar.update(done - self.bar.n)

    def update_to(self, value: float) -> None:
        self.bar.update(value - self.bar.n)

    def close(self) -> None:
        self.bar.close()

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()
