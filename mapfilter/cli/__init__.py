"""Command line: ``mapfilter <command> ...``. Thin: parse, load, call the library, write.

Each command lives in its own module here (listed in ``COMMAND_MODULES``) with
``register(subparsers)``; the module sets ``func=run`` on its parser, and ``run(args) -> int``
returns the exit code. A
``MapfilterError`` (an error the user caused) becomes one line on stderr and exit code 1, and
so does an ``OSError`` (a full disk, a file that cannot be written); anything else is a bug and
crashes loudly. SIGTERM is handled like Ctrl-C (context managers run, temporaries are removed:
exit code 143, Ctrl-C's is 130), and a closed pipe on stdout (``mapfilter ... | head -1``)
ends the command quietly.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import signal
import sys
import threading

from mapfilter import __version__
from mapfilter.errors import MapfilterError

# Command modules, in the order they appear in --help.
COMMAND_MODULES = ("map_cmd", "radiomap_cmd", "check_cmd", "track_cmd", "evaluate_cmd", "simulate_cmd", "view_cmd",
                   "config_cmd")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mapfilter",
        description="Track a walking person on an indoor floor plan with a map-aware particle filter.",
    )
    parser.add_argument("--version", action="version", version=f"mapfilter {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(f"mapfilter.cli.{name}").register(subparsers)
    return parser


class Terminated(KeyboardInterrupt):
    """Raised in the main thread on SIGTERM, so that a terminated run cleans up as Ctrl-C does."""


def main(argv: list[str] | None = None) -> int:
    with _sigterm_as_interrupt():
        try:
            return _main(argv)
        except BrokenPipeError:
            _quiet_stdout()
            return 128 + signal.SIGPIPE  # as a command killed by SIGPIPE: quiet, but not success
        except Terminated:
            print("mapfilter: terminated", file=sys.stderr)
            return 128 + signal.SIGTERM
        except KeyboardInterrupt:
            print("mapfilter: interrupted", file=sys.stderr)
            return 130


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return 2
    try:
        return int(args.func(args) or 0)
    except MapfilterError as exc:
        print(f"mapfilter: error: {exc}", file=sys.stderr)
        return 1
    except BrokenPipeError:
        raise
    except OSError as exc:
        # a full disk, a quota, a file that cannot be written: the environment, not a bug
        print(f"mapfilter: error: {describe_os_error(exc)}", file=sys.stderr)
        return 1


def describe_os_error(exc: OSError) -> str:
    """One line for an OSError: the file it names (if any) and the system's reason."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    return f"{exc.filename}: {reason}" if exc.filename is not None else reason


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """While the command runs, SIGTERM raises ``Terminated`` in the main thread (as Ctrl-C raises
    KeyboardInterrupt): ``with`` blocks and ``finally`` clauses run, temporaries are removed."""
    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be set from the main thread
        return

    def terminate(signum, frame):
        signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second SIGTERM must not cut the clean-up short
        raise Terminated()

    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _quiet_stdout() -> None:
    # the reader has gone: point stdout at /dev/null so that the interpreter's final flush
    # does not print "Exception ignored ... BrokenPipeError"
    with contextlib.suppress(OSError, ValueError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)


if __name__ == "__main__":
    sys.exit(main())
