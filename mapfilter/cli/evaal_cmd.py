"""``mapfilter evaal SERVER_URL TRIAL MAP``: enter an IPIN competition trial on its EvaalAPI
server, online (batch by batch, within the server's slack) or offline (``--offline``)."""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from mapfilter.cli.common import (bounded_float, check_distinct_outputs, check_map_first, check_output_path, input_paths,
                                  warn)
from mapfilter.cli.tracking_options import (add_source_arguments, add_tracking_arguments, load_sources, source_paths,
                                            tracking_config_from)
from mapfilter.errors import MapfilterError

_EPILOG = """\
The server: SERVER_URL is the API's root (the competition's is https://evaal.aaloa.org/evaalapi/;
a local one http://127.0.0.1:54321/evaalapi/), TRIAL the trial's name. MAP must be
georeferenced (`mapfilter map import-ipin`), its floors named by their numbers (0, -1, ...):
positions go to the server as longitude,latitude,floor.

Online (the default): the trial's state first, then `nextdata?horizon=H&position=...` until the
server says the trial has finished (405): each batch of log lines is fed to the streaming
tracker, and the next request carries the latest causal estimate (before the first one, the
position the server holds). A scoring trial with V > 2 refuses requests faster than real time
(423): they are sent again H after the previous one. A dropped connection, or an answer not
whole within --timeout, is retried with the same request label (the server gives the same lines
again), for up to --retry seconds; a trial that another run of this command started is
continued from its trial time with a fresh tracker. A server that breaks the protocol is
refused in one line (docs/robustness.md): an answer over 1 MiB (a state), 16 MiB (a batch) or
256 MiB (an offline log), 8 refusals as too fast in a row, no line of the log for 10 s of trial
time, a trial past its slack. The slack left (as this client counts it) is printed every 30 s of trial time, and the
server's own figure at the end.

Offline (--offline): `nextdata?offline` (the whole log), the whole-walk (smoothed) track, and
its estimates posted in one go: every 0.5 s of the log's clock from its first line, and at every
POSI time the log gives; the server takes them for S seconds after it sent the log.

--out (default TRIAL_estimates.csv) gets the estimates the server keeps from this run, as
`pts,lon,lat,floor` lines (the log's clock, s): `mapfilter score LOG FILE` scores them, and
`mapfilter track MAP LOG --evaal-out FILE` makes the same from a log file, without a server.

examples:
  mapfilter evaal http://127.0.0.1:54321/evaalapi/ ipin23t3online venue.yaml --radiomap venue_rm.npz
  mapfilter evaal http://127.0.0.1:54321/evaalapi/ ipin23t3offline venue.yaml --radiomap venue_rm.npz --offline
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "evaal", help="enter an IPIN competition trial on its EvaalAPI server (online or offline)",
        description="Enter an IPIN competition trial: the trial's log from its EvaalAPI server, the streaming "
                    "tracker's estimates back to it.",
        epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("server", metavar="SERVER_URL", help="the EvaalAPI root, e.g. http://127.0.0.1:54321/evaalapi/")
    parser.add_argument("trial", metavar="TRIAL", help="the trial's name")
    parser.add_argument("map", type=Path, metavar="MAP", help="georeferenced building YAML (or map YAML)")
    wifi = parser.add_mutually_exclusive_group()
    wifi.add_argument("--radiomap", type=Path, metavar="RM", help="radio map (.npz) for fingerprinting")
    wifi.add_argument("--aps", type=Path, metavar="APS.csv", help="access-point table for trilateration")
    parser.add_argument("--floor", metavar="NAME", help="track on this floor only (default: find the floor)")
    parser.add_argument("--phone", metavar="MODEL",
                        help="the trial's phone model (the server sends no log header): a source's table applies "
                             "what it says of that phone (an RSSI offset: offset_db:MODEL)")
    parser.add_argument("--offline", action="store_true",
                        help="an offline trial: the whole log at once, the whole-walk track posted in one go")
    parser.add_argument("--reload", action="store_true",
                        help="put the trial back to its start first (test trials only; scoring trials refuse)")
    parser.add_argument("--horizon", type=bounded_float(0.0, 10.0, low_open=True), default=0.5, metavar="S",
                        help="online: seconds of log per request, one estimate each (default: 0.5, the "
                             "competition's)")
    parser.add_argument("--out", type=Path, metavar="FILE",
                        help="the estimates the server keeps (pts,lon,lat,floor lines; default: TRIAL_estimates.csv)")
    parser.add_argument("--timeout", type=bounded_float(0.0, 600.0, low_open=True), default=10.0, metavar="S",
                        help="seconds for each request, to the answer's last byte (default: 10)")
    parser.add_argument("--retry", type=bounded_float(0.0, 3600.0), default=30.0, metavar="S",
                        help="seconds to keep trying after a dropped connection (default: 30)")
    add_tracking_arguments(parser)
    add_source_arguments(parser)
    parser.set_defaults(func=run, adapted_aps=None)


def default_out(trial: str) -> Path:
    """``TRIAL_estimates.csv`` in the current directory (a trial name that is no plain file name:
    refused, give --out)."""
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", trial) or trial.startswith("."):
        raise MapfilterError(f"trial name {trial!r} does not make a file name: give --out FILE")
    return Path(f"{trial}_estimates.csv")


def run(args: argparse.Namespace) -> int:
    from mapfilter.settings import replace_setting

    check_map_first("mapfilter evaal SERVER_URL TRIAL MAP", args.map)
    config = tracking_config_from(args)
    if args.offline:
        config = replace_setting(config, "smooth", True)  # offline trials get the whole-walk track
    elif config.smooth:
        raise MapfilterError("--smooth needs the whole walk: an online trial gets the causal estimates (an offline "
                             "trial, --offline, gets the whole-walk track)")
    out = args.out if args.out is not None else default_out(args.trial)
    inputs = input_paths(args.map, args.radiomap, args.aps, *source_paths(args), args.config)
    check_output_path(out, inputs=inputs)
    check_distinct_outputs([("--out", out)])
    return _enter(args, config, out)


def _enter(args: argparse.Namespace, config, out: Path) -> int:
    from mapfilter.evaal.client import EvaalClient, run_offline, run_online
    from mapfilter.evaal.protocol import check_building
    from mapfilter.cli.track_cmd import _wifi_source
    from mapfilter.maps.building import Building
    from mapfilter.runtime.memory import building_extents_m, check_tracking_fits
    from mapfilter.pipeline.tracker import Tracker, TrackingInputs

    building = Building.load(args.map)
    check_building(building, args.map)
    if args.floor is not None:
        building.floor_index(args.floor, args.map)
    check_tracking_fits(config, building_extents_m(building), args.radiomap is not None)
    radio_map, ap_table = _wifi_source(args, building, config)
    sources = load_sources(args, building)
    client = EvaalClient(args.server, args.trial, timeout_s=args.timeout, retry_s=args.retry,
                               on_retry=lambda message: warn(f"trial {args.trial}: connection dropped: {message}"))
    if args.reload:
        client.reload()
        print(f"trial {args.trial}: reloaded", file=sys.stderr)
    floor = None if building.is_single_floor else args.floor
    tracker = Tracker(building, TrackingInputs(radio_map, ap_table, sources, phone_model=args.phone), config,
                      floor=floor, log_name=f"trial {args.trial}")

    def progress(message: str) -> None:
        print(f"trial {args.trial}: {message}", file=sys.stderr, flush=True)

    if args.offline:
        run = run_offline(client, tracker, progress=progress)
    else:
        run = run_online(client, tracker, args.horizon, progress=progress)
    run.estimates.write(out)
    print(_summary(run, out))
    if run.timed_out:
        raise MapfilterError(f"trial {args.trial} timed out: the server stopped taking estimates (the estimates it "
                             f"kept are in {out})")
    if run.offline and not run.reply.startswith(f"{len(run.estimates)} estimates accepted, none rejected"):
        raise MapfilterError(f"trial {args.trial}: the server did not take every estimate: {run.reply}")
    return 0


def _summary(run, out: Path) -> str:
    """What the run did, the server's last answer, the tracker's numbers, the file written."""
    import numpy as np

    kind = "offline" if run.offline else "online"
    final = run.final
    timing = f", V={final.slowdown:g}, S={final.slack_s:g} s" if final is not None and not run.offline else ""
    if final is not None and run.offline:
        timing = f", S={final.slack_s:g} s"
    times = run.estimates.t_s
    lines = [f"trial {run.trial} ({kind}{timing}): {run.requests} request{'s' if run.requests != 1 else ''} in "
             f"{run.wall_s:.1f} s, {len(run.estimates)} estimates kept from trial time {times[0]:.3f} s to "
             f"{times[-1]:.3f} s" + (f" (continued at {run.resumed_at_s:.3f} s)" if run.resumed_at_s is not None
                                     else "")]
    lines.append(f"  the server: {run.reply}")
    if run.offline:
        lines.append(f"  time left to post: {run.slack_left_s:.1f} s of {final.slack_s:g} s" if final is not None
                     else "")
    else:
        lines.append(f"  slack left at the end {run.slack_left_s:.2f} s (lowest {run.lowest_slack_s:.2f} s); "
                     f"{run.too_fast} request{'s' if run.too_fast != 1 else ''} refused as faster than real time, "
                     f"{run.dropped} sent again after a dropped connection")
        if run.busy_s is not None and run.busy_s.size and final is not None:
            lines.append(f"  the client's time per batch: median {1000 * np.median(run.busy_s):.0f} ms, max "
                         f"{1000 * run.busy_s.max():.0f} ms (the trial allows V h = "
                         f"{final.slowdown * final.horizon_s:g} s on average)")
    result = run.result
    if result is not None:
        from mapfilter.cli.track_cmd import _measured

        lines.append(f"  the tracker: {result.n_filter_steps} filter steps, {result.n_scans_used} WiFi scans used"
                     f"{_measured(result)}, "
                     f"{len(result.collapses)} collapses; causal {result.causal_runtime_s:.1f} s"
                     + (f", offline {result.offline_runtime_s:.1f} s" if result.offline is not None else ""))
    lines.append(f"  wrote {out} (the estimates the server keeps: pts,lon,lat,floor)")
    return "\n".join(line for line in lines if line)
