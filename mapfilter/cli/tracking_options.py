"""The tracking settings on the command line: ``--config FILE`` and the flags people change.

Every setting lives in the ``TrackingConfig`` (``mapfilter config show`` prints them all); a
flag given on the command line overrides the file's value, a flag not given leaves it alone.
The defaults are written out here so that ``--help`` imports no numerical library;
``tests/cli/test_cli_startup.py`` holds them equal to the library's.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mapfilter.cli.common import bounded_float, non_negative_int, positive_int

MOTION_MODELS = ("pdr", "cv", "rw")  # filter.causal.MOTION_MODELS
FINGERPRINT_MODELS = ("fix", "blend", "likelihood")  # filter.evidence.FINGERPRINT_MODELS
DEFAULT_PARTICLES = 10_000  # FilterConfig.n_particles
DEFAULT_FINGERPRINT_MODEL = "blend"  # WifiConfig.fingerprint_model
DEFAULT_KWNN_MIN_RSSI_DBM = -85.0  # WifiConfig.kwnn_min_rssi_dbm
DEFAULT_ADAPT_RSSI_LIMIT_DBM = -36.0  # TrilaterationConfig.adapt_rssi_limit_dbm (the thesis' limit)


def kwnn_min_rssi(text: str) -> float | None:
    """``--kwnn-min-rssi``: a dBm value (``-90`` or ``-90dBm``), or ``none`` for plain KWNN."""
    value = text.strip().lower()
    if value == "none":
        return None
    try:
        number = float(value.removesuffix("dbm").strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a dBm value such as -90, or none; got {text!r}") from None
    if not -150.0 <= number <= 30.0:  # also NaN and inf
        raise argparse.ArgumentTypeError(f"expected a dBm value between -150 and 30 (e.g. -90), or none; got {text!r}")
    return number


def add_tracking_arguments(parser: argparse.ArgumentParser) -> None:
    """``--config`` and the tracking flags of ``track`` and ``evaluate`` (each overrides the file)."""
    group = parser.add_argument_group("tracking settings (each overrides --config; every other setting lives "
                                      "in the config file: `mapfilter config show`)")
    group.add_argument("--config", type=Path, metavar="FILE",
                       help="tracking settings from this YAML file (write one with `mapfilter config show > FILE`)")
    group.add_argument("--motion", choices=MOTION_MODELS, default=None,
                       help="motion model: pdr (steps + gyro), cv (constant velocity), rw (random walk) "
                            "(default: pdr)")
    group.add_argument("--particles", type=positive_int, default=None, metavar="N",
                       help=f"number of particles (default: {DEFAULT_PARTICLES})")
    group.add_argument("--seed", type=non_negative_int, default=None, metavar="S", help="random seed (default: 0)")
    group.add_argument("--smooth", action="store_true", default=None,
                       help="also make the offline track from the whole walk: the dead-reckoned shape placed by "
                            "every scan, kept to free space (never crosses a wall)")
    group.add_argument("--no-map", action="store_true", default=None,
                       help="ignore the walls (to see what the map buys)")
    group.add_argument("--fingerprint-model", choices=FINGERPRINT_MODELS, default=None,
                       help="fix: KWNN fix weighed by a Gaussian; blend: that fix averaged with the radio-map "
                            "likelihood's best cell; likelihood: per-particle radio-map likelihood "
                            f"(default: {DEFAULT_FINGERPRINT_MODEL})")
    group.add_argument("--kwnn-min-rssi", type=kwnn_min_rssi, default=argparse.SUPPRESS, metavar="DBM",
                       help="the filter's KWNN fixes use readings at or above this only (phones disagree most "
                            f"on weak APs); none: every reading (default: {DEFAULT_KWNN_MIN_RSSI_DBM:g}); "
                            "negative values as --kwnn-min-rssi=-90")
    group.add_argument("--adapt", action="store_true", default=None,
                       help="trilateration: adapt the path-loss parameters during the run (C of the AP the phone "
                            "is below when a scan's strongest RSSI is above the limit, alpha per band; "
                            "Lund thesis 7.1-7.2)")
    group.add_argument("--adapt-rssi-limit", type=bounded_float(-150.0, 30.0), default=None, metavar="DBM",
                       help=f"with --adapt: a scan whose strongest RSSI is above this adapts (default: "
                            f"{DEFAULT_ADAPT_RSSI_LIMIT_DBM:g}, the thesis' value)")
    group.add_argument("--no-blocking-compensation", action="store_true", default=None,
                       help="trilateration: do not compensate signal blocking (by default a term H is taken off "
                            "every AP while the six strongest drop together by more than 6 dB; Lund thesis 7.3)")


def add_start_argument(parser: argparse.ArgumentParser, every_walk: bool = False) -> None:
    """``--start X,Y[,FLOOR]``: where the walk started, if the user knows (a walk's input, not a
    setting of the config); for every walk of an evaluation also ``truth``: each walk's own first
    waypoint."""
    parser.add_argument("--start", metavar="X,Y[,FLOOR]" + ("|truth" if every_walk else ""),
                        help=("where every walk started" if every_walk else "where the walk started") +
                             ", if you know it (metres in the map's frame; FLOOR: the floor's name, needed in a "
                             "building): the particles start within 2 m of it at the first step, instead of "
                             "over the map from the first WiFi scan, and the offline track passes there" +
                             ("; truth: each walk at its own first waypoint (as a competition gives a trial's "
                              "initial position)" if every_walk else ""))


def start_from(args: argparse.Namespace, building, floor: str | None = None):
    """The ``WalkStart`` of ``--start`` (None without it), checked on ``building``: on a floor it
    has and on free space (``MapfilterError`` in one line)."""
    if args.start is None:
        return None
    from mapfilter.pipeline.tracker import TRUE_START, WalkStart

    if args.start == TRUE_START and getattr(args, "command", None) == "evaluate":
        return TRUE_START

    start = WalkStart.parse(args.start)
    start.place(building, floor)
    return start


def tracking_config_from(args: argparse.Namespace):
    """The ``TrackingConfig`` of a command: the ``--config`` file's (or the defaults), with every
    flag that was given applied on top."""
    import dataclasses

    from mapfilter.config import TrackingConfig
    from mapfilter.settings import replace_setting

    config = TrackingConfig.from_yaml(args.config) if args.config is not None else TrackingConfig()
    flags = {
        "motion.model": args.motion,
        "filter.n_particles": args.particles,
        "seed": args.seed,
        "smooth": True if args.smooth else None,
        "use_map": False if args.no_map else None,
        "wifi.fingerprint_model": args.fingerprint_model,
        "trilateration.adapt_path_loss": True if args.adapt else None,
        "trilateration.adapt_rssi_limit_dbm": args.adapt_rssi_limit,
        "trilateration.blocking_compensation": False if args.no_blocking_compensation else None,
    }
    for dotted, value in flags.items():
        if value is not None:
            config = replace_setting(config, dotted, value)
    if hasattr(args, "kwnn_min_rssi"):  # given (None is a value here: plain KWNN)
        config = dataclasses.replace(config, wifi=dataclasses.replace(config.wifi, kwnn_min_rssi_dbm=args.kwnn_min_rssi))
    return config


def add_source_arguments(parser: argparse.ArgumentParser) -> None:
    """A place for the files of every registered measurement source (``filter.sources``); they are
    added once every command's own options are known (``attach_source_arguments``)."""
    parser._source_group = parser.add_argument_group(  # noqa: SLF001 - read by attach_source_arguments
        "measurement sources besides WiFi (each weighed when its files are given; config section sources)")


def attach_source_arguments(parsers: list[argparse.ArgumentParser]) -> None:
    """Every registered source's files on each parser that asked for them; a source whose option
    one of these commands takes itself is left out (one warning line, ``filter.sources.refusals``),
    never a traceback that stops every command."""
    from mapfilter.filter.sources import refuse, registered

    wanting = [p for p in parsers if getattr(p, "_source_group", None) is not None]
    own: dict[str, str] = {}  # flag -> the first command that takes it
    for p in wanting:
        for action in p._actions:
            for flag in action.option_strings:
                own.setdefault(flag, p.prog)
    for entry in registered():
        clash = next((o.flag for o in entry.options if o.flag in own), None)
        if clash:
            refuse(entry, f"its option {clash} is `{own[clash]}`'s own")
    for p in wanting:
        for entry in registered():
            for option in entry.options:
                p._source_group.add_argument(option.flag, type=Path, metavar=option.metavar,
                                             dest=f"source_{option.key}", help=option.help)


def source_files(args: argparse.Namespace) -> dict[str, dict[str, Path]]:
    """{source name: {option key: path}} of the sources whose files were given; a source given
    only some of its files is a ``MapfilterError`` naming the missing option."""
    from mapfilter.errors import MapfilterError
    from mapfilter.filter.sources import registered

    files = {}
    for entry in registered():
        given = {o.key: getattr(args, f"source_{o.key}", None) for o in entry.options}
        if all(path is None for path in given.values()):
            continue
        missing = [o.flag for o in entry.options if given[o.key] is None]
        if missing:
            named = next(o.flag for o in entry.options if given[o.key] is not None)
            raise MapfilterError(f"{named} needs {' and '.join(missing)} too ({entry.title})")
        files[entry.name] = given
    return files


def source_paths(args: argparse.Namespace) -> list[Path]:
    """Every source file given (the inputs no output may overwrite)."""
    return [path for files in source_files(args).values() for path in files.values()]


def load_sources(args: argparse.Namespace, building) -> dict:
    """{source name: its input} of the sources whose files were given, loaded and checked against
    ``building``."""
    from mapfilter.filter.sources import plugin

    return {name: plugin(name).load(files, building) for name, files in source_files(args).items()}
