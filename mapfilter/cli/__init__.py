"""Command line: ``mapfilter <command> ...``. Thin: parse, load, call the library, write.

Each command lives in its own module here (listed in ``COMMAND_MODULES``) with
``register(subparsers)``; the module sets ``func=run`` on its parser, and ``run(args) -> int``
returns the exit code. A
``MapfilterError`` (an error the user caused) becomes one line on stderr and exit code 1;
anything else is a bug and crashes loudly.
"""

from __future__ import annotations

import argparse
import importlib
import sys

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


def main(argv: list[str] | None = None) -> int:
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
    except KeyboardInterrupt:
        print("mapfilter: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
