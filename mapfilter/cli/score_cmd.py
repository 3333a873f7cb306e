"""``mapfilter score LOG ESTIMATES...``: IPIN competition estimates scored against a log's POSI points."""

from __future__ import annotations

import argparse
from pathlib import Path

from mapfilter.cli.common import add_strict_argument, warn

_EPILOG = """\
ESTIMATES are the competition's estimate files: pts,lon,lat,floor lines on the log's own clock
(AppTimestamp seconds), as `mapfilter evaal --out` and `mapfilter track --evaal-out` write them
and the server takes them, or the server's own list (GET TRIAL/estimates, with its header
pts,c,h,s,pos). LOG is the GetSensorData log with the POSI points (the trial's log).

At each POSI point the latest estimate at or before its time is taken (what a live system showed
when the walker passed the point; offline estimates include the POSI times themselves). The IPIN
score is the 75th percentile of the horizontal error plus 15 m for each floor the estimate is
off by; POSI points before a file's first estimate are counted as missed, not scored.

examples:
  mapfilter score IPIN2023_T3_TrainingTrial01_repetition01.txt.gz trial01_estimates.csv
  mapfilter score walk.txt.gz online.csv offline.csv server_estimates.csv
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "score", help="score IPIN competition estimates against a log's POSI points",
        description="Score IPIN competition estimate files against a log's ground truth (POSI points), as the "
                    "competition does.",
        epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("log", type=Path, metavar="LOG",
                        help="the GetSensorData log with POSI points (.txt or .txt.gz)")
    parser.add_argument("estimates", type=Path, nargs="+", metavar="ESTIMATES",
                        help="estimate files (pts,lon,lat,floor lines, or the server's pts,c,h,s,pos list)")
    add_strict_argument(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from mapfilter.evaal.protocol import far_from_the_points, read_estimates, score_against_log
    from mapfilter.sensors.logs import read_log

    recording = read_log(args.log, strict=args.strict, warn=warn)
    scores = []
    for path in args.estimates:
        estimates = read_estimates(path)
        scores.append((path, score_against_log(estimates, recording)))
        far = far_from_the_points(estimates, recording, scores[-1][1])
        if far is not None:
            warn(f"{path}: {far}")
    n = recording.waypoint_t_s.size
    print(f"{recording.name}: {n} POSI point{'s' if n != 1 else ''}; IPIN score = 75th percentile of the "
          "horizontal error + 15 m per floor off")
    for path, score in scores:
        errors = score.errors_m
        line = f"  {path}: "
        if errors.size == 0:
            line += "no estimate at or before any POSI point"
        else:
            right = int(np.count_nonzero(score.floors_off == 0))
            line += (f"IPIN score {score.score_m:.2f} m; error mean {errors.mean():.2f} m, median "
                     f"{np.median(errors):.2f} m, p75 {np.percentile(errors, 75):.2f} m, max {errors.max():.2f} m; "
                     f"floor right at {right} of {errors.size} points")
        if score.missed:
            line += f" ({score.missed} point{'s' if score.missed != 1 else ''} before the first estimate, not scored)"
        print(line)
    return 0
