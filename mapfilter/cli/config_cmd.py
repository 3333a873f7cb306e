"""``mapfilter config show [--config FILE]``: every tracking setting as YAML, one comment each."""

from __future__ import annotations

import argparse
from pathlib import Path

_EPILOG = """\
Every setting of a tracking run lives in this config. Save it, change what you need, and give
it to track or evaluate with --config FILE (their flags override the file; a file may hold only
the settings it changes). track --out-dir and evaluate write the config that ran beside their
results (config.yaml), so a run can be repeated from its outputs.

examples:
  mapfilter config show > my_settings.yaml
  mapfilter config show --config my_settings.yaml     # the file's settings, every other one at its default
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("config", help="show the tracking settings (YAML with a comment per setting)",
                                   description="The tracking settings.", epilog=_EPILOG,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="config_command", metavar="COMMAND", required=True)
    show = sub.add_parser("show", help="print every setting as YAML (the defaults, or a config file's)",
                          description="Print every tracking setting as YAML with a one-line comment each.",
                          epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    show.add_argument("--config", type=Path, metavar="FILE", help="show this file's settings (the rest at default)")
    show.set_defaults(func=run_show)


def run_show(args: argparse.Namespace) -> int:
    from mapfilter.config import TrackingConfig

    config = TrackingConfig.from_yaml(args.config) if args.config is not None else TrackingConfig()
    print(config.to_yaml(), end="")
    return 0
