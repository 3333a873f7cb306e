"""What several commands share: warnings on stderr, the engine options, the order of the
arguments, output-path checks, argument types with limits, progress (a bar on a terminal, a line
every few seconds in a pipe) and the rough time of a long run, said before it starts."""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from mapfilter.runtime.dispatch import Engine
from mapfilter.errors import MapfilterError
from mapfilter.io.outputs import OutputDirectory, check_output_file, input_paths, is_stdout  # noqa: F401 - for the commands


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
                        help="walks in N local worker processes, forked from this one with the map, the radio map "
                             "and the compiled kernels already loaded (default: 1, serial)")
    engine.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                        help="run the walks on an existing Dask cluster that you trust: whoever can use it runs "
                             "code as its workers, and its results are unpickled here (workers need mapfilter "
                             "and the logs; tls://HOST:PORT uses Dask's TLS configuration)")


def engine_from(args: argparse.Namespace) -> Engine:
    """The engine of ``--jobs`` / ``--scheduler``: at most one local worker per core, and only as
    many as fit in memory (``mapfilter.runtime.dispatch.check_local_jobs``)."""
    from mapfilter.runtime.dispatch import check_local_jobs

    if args.scheduler is None:
        check_local_jobs(args.jobs)
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
    return waypoint_check(building, recording)[2]


def waypoint_check(building, recording) -> tuple[int, int, str | None]:
    """(waypoints on free space, waypoints checked, the warning line of ``waypoints_in_walls`` or
    None); (0, 0, None) for a log without waypoints, (0, 0, why) when they cannot be checked."""
    import numpy as np

    from mapfilter.sensors.logs import localise

    if not recording.has_ground_truth:
        return 0, 0, None
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
                return 0, 0, f"{where}: names no floor (FloorName): its waypoints cannot be checked against a building"
    except MapfilterError as exc:
        return 0, 0, f"{where}: its waypoints cannot be checked: {exc.reason}"
    in_walls = np.zeros(n, dtype=bool)
    for name in dict.fromkeys(floors):
        on = np.array([f == name for f in floors])
        in_walls[on] = ~building.floor(name).plan.is_free(recording.waypoint_xy_m[on])
    free = int(n - in_walls.sum())
    if not in_walls.any():
        return free, n, None
    first = int(np.flatnonzero(in_walls)[0])
    x, y = recording.waypoint_xy_m[first]
    t = recording.waypoint_t_s[first] - recording.waypoint_t_s[0]
    return free, n, (f"{where}: {int(in_walls.sum())} of {n} waypoints fall in walls or outside the map (the first "
                     f"at x {x:.1f} m, y {y:.1f} m, t {t:+.0f} s): a wrong scale or origin, closed outlines "
                     "(--open-outlines), or a plan of another floor?")


def check_logs_on_map(building, log_paths: Sequence[Path]) -> tuple[list[str], str]:
    """``map prepare|import-ilc --check-logs``: (a warning line per log whose waypoints fall in
    walls or cannot be checked, the check's one summary line: how many of the checked waypoints
    lie on free space). A log without waypoints is named in the summary."""
    from mapfilter.sensors.logs import read_log

    found, free, checked, without = [], 0, 0, 0
    for path in log_paths:
        recording = read_log(path, warn=lambda message: None)
        on_free, n, message = waypoint_check(building, recording)
        free, checked = free + on_free, checked + n
        without += not recording.has_ground_truth
        if message is not None:
            found.append(message)
    logs = f"{len(log_paths)} log{'s' if len(log_paths) != 1 else ''}"
    line = f"--check-logs: {free} of {checked} waypoints of {logs} on free space"
    if without:
        line += f" ({without} without waypoints)"
    return found, line


# ---- output paths ------------------------------------------------------------------------------
def check_output_path(path: str | os.PathLike | None, option: str = "--out", directory: bool = False,
                      inputs: Sequence[Path] = (), allow_stdout: bool = False) -> OutputDirectory | None:
    """Refuse an output path before any work is done (``mapfilter.io.outputs``: one line naming the
    path and the option).

    ``path`` is a file to write (``directory=False``: never one of ``inputs``, a directory, a
    device, a FIFO or a link; ``-`` is standard output when ``allow_stdout``) or a directory to
    fill (``directory=True``: returns its ``OutputDirectory``, which holds no input and no file
    that mapfilter did not write). A missing parent (or a missing directory) is fine when it can
    be made. ``None`` passes (the option was not given).
    """
    if path is None:
        return None
    if directory:
        return OutputDirectory(path, option, inputs)
    check_output_file(path, option, inputs, allow_stdout=allow_stdout)
    return None


def check_distinct_outputs(outputs: Sequence[tuple[str, Path | None]]) -> None:
    """Refuse two options of one run that name the same output file."""
    given = [(option, Path(path)) for option, path in outputs if path is not None and not is_stdout(path)]
    for i, (option, path) in enumerate(given):
        for other_option, other in given[:i]:
            if os.path.abspath(path) == os.path.abspath(other):
                raise MapfilterError(f"{option} and {other_option} name the same file: give each its own", path)


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


# Progress where stderr is not a terminal (a pipe, a log file, CI): one plain line this often
PIPE_PROGRESS_INTERVAL_S = 5.0


class ProgressBar:
    """Progress on stderr: a tqdm bar on a terminal; elsewhere (a pipe, a log file, CI) one plain
    line every ``PIPE_PROGRESS_INTERVAL_S`` seconds (none for work shorter than that), with the
    time so far and a rough time left.

    Call it as a ``progress(done, total, name)`` callback, or use ``update_to`` for a fraction.
    """

    def __init__(self, description: str, total: float, unit: str = "walk") -> None:
        self.description, self.total, self.unit = description, total, unit
        self.done = 0.0
        self.name = ""
        self.bar = None
        self.started = self.last_line = time.monotonic()
        if sys.stderr.isatty():
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=description, unit=unit, file=sys.stderr, leave=False,
                            dynamic_ncols=True)

    def __call__(self, done: int, total: int, name: str) -> None:
        from mapfilter.runtime.interrupts import raise_pending_signal

        raise_pending_signal()  # between two tasks: an interrupt a callback swallowed stops the run here
        self.total, self.name = total, name
        if self.bar is not None:
            self.bar.total = total
            self.bar.set_postfix_str(name[:40], refresh=False)
            self.bar.update(done - self.bar.n)
        self._advance(done)

    def update_to(self, value: float) -> None:
        if self.bar is not None:
            self.bar.update(value - self.bar.n)
        self._advance(value)

    def _advance(self, done: float) -> None:
        self.done = done
        now = time.monotonic()
        if self.bar is not None or now - self.last_line < PIPE_PROGRESS_INTERVAL_S:
            return
        self.last_line = now
        print(f"mapfilter: {self.description}: {self._amount()}, {duration_text(now - self.started)}"
              + self._left(now), file=sys.stderr, flush=True)

    def _amount(self) -> str:
        if self.unit == "%":
            return f"{self.done:.0f} %"
        units = self.unit if self.total == 1 else f"{self.unit}s"
        return f"{self.done:g} of {self.total:g} {units}" + (f" ({self.name})" if self.name else "")

    def _left(self, now: float) -> str:
        if not 0 < self.done < self.total:
            return ""
        return f", about {duration_text((now - self.started) * (self.total - self.done) / self.done)} left"

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


def duration_text(seconds: float) -> str:
    """``42 s``, ``3 min 20 s``, ``1 h 05 min``."""
    seconds = max(0.0, seconds)
    if seconds < 60:
        return f"{seconds:.0f} s"
    if seconds < 3600:
        return f"{int(seconds // 60)} min {int(seconds % 60):02d} s"
    return f"{int(seconds // 3600)} h {int(seconds % 3600 // 60):02d} min"


# ---- how long a run will take, said before it starts ---------------------------------------------
# A rough model, from warm runs on the 2-core machine: the causal filter with its evidence moves
# 1.5-1.7 M particle-steps a second on one worker when the machine is quiet (the office walk:
# 214 steps x 10,000 particles in 1.3 s; an ILC F1 walk: 134 steps in 0.8 s), less than half
# that when it is shared, and a building's walks cost more: 1 M is taken. A walker makes about
# 1.8 filter steps a second; the offline track (--smooth) costs about one and a half causal runs more.
PARTICLE_STEPS_PER_S = 1.0e6
FILTER_STEPS_PER_WALK_S = 1.8
SMOOTH_EXTRA_RUNS = 1.5
LARGE_RUN_S = 60.0  # runs expected to take longer than this are announced
# a rerun recording holds about 13 bytes per drawn particle and step (office walk: 14 MB for 214
# steps of 5,000 drawn particles)
RRD_BYTES_PER_DRAWN_PARTICLE_STEP = 13.0
LARGE_RECORDING_BYTES = 100e6


# reading a log's span means reading the whole log: of many logs, this many spread over the list
# are read and the others scaled by their size (a rough time needs no more; 500 logs took 20 s)
SPAN_SAMPLE_LOGS = 8


def walk_spans_s(paths: Sequence[Path]) -> list[float]:
    """Each log's time span in seconds, for a rough run time (0 for a log whose span cannot be
    read: it fails later with its own message). Of more than ``SPAN_SAMPLE_LOGS`` logs, those
    read give the seconds per byte that the others' file sizes are scaled by."""
    from mapfilter.sensors.logs import log_time_span_s

    def span(path: Path) -> float:
        try:
            return log_time_span_s(path)
        except MapfilterError:
            return 0.0

    def size(path: Path) -> int:
        try:
            return Path(path).stat().st_size
        except OSError:
            return 0

    if len(paths) <= SPAN_SAMPLE_LOGS:
        return [span(p) for p in paths]
    sampled = {round(i * (len(paths) - 1) / (SPAN_SAMPLE_LOGS - 1)) for i in range(SPAN_SAMPLE_LOGS)}
    read = {i: span(paths[i]) for i in sampled}
    per_byte = sum(read.values()) / max(sum(size(paths[i]) for i in sampled), 1)
    return [read[i] if i in read else size(p) * per_byte for i, p in enumerate(paths)]


def estimate_tracking_s(spans_s: Sequence[float], particles: int, runs_per_walk: float, workers: int = 1) -> float:
    """Rough wall time of filter runs over walks of ``spans_s`` seconds (the model above)."""
    particle_steps = sum(spans_s) * FILTER_STEPS_PER_WALK_S * particles * runs_per_walk
    return particle_steps / PARTICLE_STEPS_PER_S / max(1, workers)


def announce_estimate(what: str, seconds: float, detail: str) -> None:
    """One line on stderr before a run expected to take more than ``LARGE_RUN_S``."""
    if seconds >= LARGE_RUN_S:
        print(f"mapfilter: {what}: about {duration_text(seconds)} by a rough estimate ({detail})", file=sys.stderr,
              flush=True)


def announce_recording_size(spans_s: float, drawn_particles: int, path: Path) -> None:
    """One line on stderr before a rerun recording expected to exceed ``LARGE_RECORDING_BYTES``."""
    size = spans_s * FILTER_STEPS_PER_WALK_S * drawn_particles * RRD_BYTES_PER_DRAWN_PARTICLE_STEP
    if size >= LARGE_RECORDING_BYTES:
        print(f"mapfilter: {path}: the recording will be about {size / 1e6:.0f} MB by a rough estimate "
              f"({drawn_particles} particles drawn per step; --max-drawn-particles draws fewer)", file=sys.stderr,
              flush=True)
