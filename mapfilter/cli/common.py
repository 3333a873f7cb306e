"""What several commands share: warnings on stderr, the engine options, progress bars."""

from __future__ import annotations

import argparse
import sys

from mapfilter.engine import Engine


def warn(message: str) -> None:
    """One warning line on stderr, in the form every command uses."""
    print(f"mapfilter: warning: {message}", file=sys.stderr)


def add_strict_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--strict", action="store_true",
                        help="refuse a log with a bad row in a record type the run needs, or a cut gzip stream "
                             "(default: skip such rows with a warning; bad rows of unused types are always skipped)")


def add_engine_arguments(parser: argparse.ArgumentParser) -> None:
    engine = parser.add_mutually_exclusive_group()
    engine.add_argument("--jobs", type=int, default=1, metavar="N",
                        help="walks in N local Dask worker processes (default: 1, serial, no Dask)")
    engine.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                        help="run the walks on an existing Dask cluster (workers need mapfilter and the logs)")


def engine_from(args: argparse.Namespace) -> Engine:
    return Engine(jobs=args.jobs, scheduler=args.scheduler)


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
