"""What several commands share: warnings on stderr, the engine options, output-path checks,
argument types with limits, progress bars."""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from mapfilter.engine import Engine
from mapfilter.errors import MapfilterError
from mapfilter.outputs import OutputDirectory, check_output_file, input_paths, is_stdout  # noqa: F401 - for the commands


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
    """The engine of ``--jobs`` / ``--scheduler``: at most one local worker per core, and only as
    many as fit in memory (``mapfilter.engine.check_local_jobs``)."""
    from mapfilter.engine import check_local_jobs

    if args.scheduler is None:
        check_local_jobs(args.jobs)
    return Engine(jobs=args.jobs, scheduler=args.scheduler)


# ---- output paths ------------------------------------------------------------------------------
def check_output_path(path: str | os.PathLike | None, option: str = "--out", directory: bool = False,
                      inputs: Sequence[Path] = (), allow_stdout: bool = False) -> OutputDirectory | None:
    """Refuse an output path before any work is done (``mapfilter.outputs``: one line naming the
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
