"""Command line: ``mapfilter <command> ...``. Thin: parse, load, call the library, write.

Each command lives in its own module here (listed in ``COMMAND_MODULES``) with
``register(subparsers)``; the module sets ``func=run`` on its parser, and ``run(args) -> int``
returns the exit code. A
``MapfilterError`` (an error the user caused) becomes one line on stderr and exit code 1, and
so does an ``OSError`` (a full disk, a file that cannot be written); anything else is a bug and
crashes loudly. SIGTERM is handled like Ctrl-C (context managers run, temporaries are removed:
exit code 143, Ctrl-C's is 130), and a closed pipe on stdout (``mapfilter ... | head -1``)
ends the command quietly. The cyclic garbage collector runs rarely while a command does
(``runtime/collector.py``).
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import importlib
import os
import re
import signal
import sys
import threading

from mapfilter import __version__
from mapfilter.errors import MapfilterError
from mapfilter.runtime.collector import rare_collections
from mapfilter.runtime.interrupts import Terminated, clear, deferring, interrupted_by, note_signal

# Command modules, in the order they appear in --help.
COMMAND_MODULES = ("map_cmd", "radiomap_cmd", "check_cmd", "track_cmd", "evaluate_cmd", "simulate_cmd", "view_cmd",
                   "config_cmd", "evaal_cmd", "score_cmd")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mapfilter", allow_abbrev=False,
        description="Track a walking person on an indoor floor plan with a map-aware particle filter.",
    )
    parser.add_argument("--version", action="version", version=f"mapfilter {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(f"mapfilter.cli.{name}").register(subparsers)
    from mapfilter.cli.tracking_options import attach_source_arguments

    attach_source_arguments(_all_parsers(parser))
    for sub in _all_parsers(parser):
        # no prefix matching: `--particle 500` must not quietly mean --particles
        sub.allow_abbrev = False
    return parser


def _all_parsers(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    """The parser and every subparser below it (``map prepare``, ``radiomap build``, ...)."""
    found = [parser]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in dict.fromkeys(action.choices.values()):
                found += _all_parsers(sub)
    return found


def main(argv: list[str] | None = None) -> int:
    clear()  # the signals of an earlier command in this process (tests run many)
    with _sigterm_as_interrupt(), rare_collections():
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
        except Exception as exc:
            # a signal whose handler ran while numba's dispatcher was in Python code (loading a
            # kernel from its cache): the dispatcher reports "returned a result with an exception
            # set", the interrupt in its contexts; the run ends as the signal
            signum = interrupted_by(exc)
            if signum == signal.SIGTERM:
                print("mapfilter: terminated", file=sys.stderr)
                return 128 + signal.SIGTERM
            if signum == signal.SIGINT:
                print("mapfilter: interrupted", file=sys.stderr)
                return 130
            raise


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    from mapfilter.filter.sources import refusals

    for line in refusals():  # a measurement source that could not be registered
        print(f"mapfilter: warning: {line}", file=sys.stderr)
    argv = list(sys.argv[1:] if argv is None else argv)
    command = _command_parser(parser, argv)
    argv = _join_negative_values(command, argv)
    args, unknown = parser.parse_known_args(argv)
    if unknown:
        # the command's own usage, not the top level's, and the nearest option by name
        options = [o for action in command._actions for o in action.option_strings]
        hints = [difflib.get_close_matches(u.split("=")[0], options, n=1) for u in unknown if u.startswith("-")]
        hint = "; ".join(f"did you mean {h[0]}?" for h in hints if h)
        command.error(f"unrecognized arguments: {' '.join(unknown)}" + (f" ({hint})" if hint else ""))
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


def _command_parser(parser: argparse.ArgumentParser, argv: list[str]) -> argparse.ArgumentParser:
    """The (sub)parser of the command ``argv`` names: ``mapfilter radiomap build ...`` -> ``build``'s."""
    current = parser
    for token in argv:
        if token.startswith("-"):
            continue
        choices = next((a.choices for a in current._actions if isinstance(a, argparse._SubParsersAction)), None)
        if not choices or token not in choices:
            break
        current = choices[token]
    return current


_NEGATIVE = re.compile(r"^-\d")


def _join_negative_values(command: argparse.ArgumentParser, argv: list[str]) -> list[str]:
    """``--kwnn-min-rssi -90dBm`` as ``--kwnn-min-rssi=-90dBm``: argparse takes a value that starts
    with '-' for an option unless it is a plain number; no option of ours starts with a digit."""
    takes_one = {o for action in command._actions if action.nargs is None and action.option_strings
                 and not isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction))
                 for o in action.option_strings}
    out: list[str] = []
    for token in argv:
        if out and out[-1] in takes_one and _NEGATIVE.match(token):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


def describe_os_error(exc: OSError) -> str:
    """One line for an OSError: the file it names (if any) and the system's reason."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    return f"{exc.filename}: {reason}" if exc.filename is not None else reason


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """While the command runs, SIGTERM raises ``Terminated`` in the main thread (as Ctrl-C raises
    KeyboardInterrupt): ``with`` blocks and ``finally`` clauses run, temporaries are removed. Both
    are noted for ``runtime.interrupts.raise_pending_signal`` (and only noted inside its ``deferred``)."""
    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be set from the main thread
        return

    def terminate(signum, frame):
        signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second SIGTERM must not cut the clean-up short
        note_signal(signum)
        if not deferring():
            raise Terminated()

    def interrupt(signum, frame):
        note_signal(signum)
        if not deferring():
            raise KeyboardInterrupt()

    previous = signal.signal(signal.SIGTERM, terminate)
    previous_int = signal.signal(signal.SIGINT, interrupt) if signal.getsignal(signal.SIGINT) is \
        signal.default_int_handler else None
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
        if previous_int is not None:
            signal.signal(signal.SIGINT, previous_int)


def _quiet_stdout() -> None:
    # the reader has gone: point stdout at /dev/null so that the interpreter's final flush
    # does not print "Exception ignored ... BrokenPipeError"
    with contextlib.suppress(OSError, ValueError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)


if __name__ == "__main__":
    sys.exit(main())
