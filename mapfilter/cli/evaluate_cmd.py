"""``mapfilter evaluate MAP LOG...``: every method on the same walks, one table, one CDF plot."""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import sys
from pathlib import Path

from mapfilter.cli.common import (SMOOTH_EXTRA_RUNS, ProgressBar, add_engine_arguments, add_strict_argument,
                                  announce_estimate, check_map_first, check_output_path, duration_text, engine_from,
                                  estimate_tracking_s, input_paths, walk_spans_s, warn)
from mapfilter.cli.tracking_options import (add_source_arguments, add_start_argument, add_tracking_arguments,
                                            load_sources, source_files, source_paths, start_from,
                                            tracking_config_from)
from mapfilter.errors import MapfilterError
from mapfilter.filter.sources import evaluation_methods, registered
from mapfilter.runtime.memory import building_extents_m, check_tracking_fits

# mapfilter.evaluation.comparison's methods, written out so that --help imports no numerical
# library (tests/cli/test_cli_startup.py holds them equal); the sources' from their registry
ALL_METHODS = ("pf", "pf-nomap", "pf-nopdr", "kwnn", "pdr-kwnn", "kf", "pdr", "ls", *evaluation_methods(True),
               "pdr-start")
BUILDING_METHODS = ("pf", "pf-floor", "kwnn", "kf", "pdr", *evaluation_methods(False), "pdr-start")


def _sources_epilog() -> str:
    """What each measurement source adds (``filter.sources``)."""
    lines = ["with a measurement source's files, also (NAME: the source's name):",
             "  pf+NAME   pf with the source's measurements too   pf-NAME   pf on the source alone (no WiFi)",
             "  pf-floor+NAME  pf-floor with the source too (a building); with --smooth, pf-smooth+NAME",
             "  With --survey or --leave-one-out a source may fit its input again on the labelled walks",
             "  (never the walk itself); with --radiomap, the inputs as given. The sources:"]
    for entry in registered():
        files = " ".join(f"{o.flag} {o.metavar}" for o in entry.options)
        lines.append(f"  {entry.name:8s}  {entry.title} ({files})")
    return "\n".join(lines)


_EPILOG = f"""\
methods on one floor: {', '.join(ALL_METHODS)} (default: all that the WiFi source allows)
  pf        particle filter: map + WiFi + PDR       kwnn      KWNN fixes (Chang et al.)
  pf-nomap  the same, walls ignored                 pdr-kwnn  KWNN with PDR (Chang et al.)
  pf-nopdr  the same, constant velocity, no PDR     kf        Kalman filter on fixes + PDR
  pdr       dead reckoning from the first fix       ls        least-squares trilateration
  pdr-start dead reckoning from the walk's true start (its first waypoint: ground truth no other
            method sees): what the steps alone give, to show what the WiFi adds or costs
methods in a building with several floors: {', '.join(BUILDING_METHODS)}
  pf        the floor in the filter's state         pf-floor  the same filter on the walker's floor
  kwnn      each scan on the WiFi floor HMM's floor
  kf, pdr   the Kalman filter and dead reckoning on those KWNN fixes, each row on their floor
  pdr-start from the true start, on the floor of the walk's first waypoint
--start X,Y[,FLOOR]: every walk started there (an entrance they all walked in from): the pf
methods start within 2 m of it at each walk's first step, and the offline track passes there;
--start truth: each walk at its own first waypoint (pdr-start always starts at the truth).

{{sources}}

the table (docs/results.md): errors at the waypoints, mean, median, p75 (the EvAAL/IPIN
percentile), p90, ce95 (the 95th percentile, ISO/IEC 18305's CE95), max, rmse; n waypoints
scored, missed (before the method's first estimate); availability: the share of waypoints with
an estimate; in a building also floor_accuracy (the share of the scored waypoints on the
walker's floor: its header's, or each waypoint's own), floor_detection (ISO/IEC 18305's floor
detection probability: right floor at all waypoints) and ipin_score (the IPIN competitions'
score, the 75th percentile of the horizontal error plus 15 m per storey off). Logs that name
their phone (GetSensorData) also get the table per phone model.

The radio map: --radiomap (one file for all walks), --survey LOGS (built from these walks,
which are never scored), or --leave-one-out (each walk's radio map from the other evaluated
walks, plus any --survey logs). Leave a group out instead of one walk (docs/ipin.md): each walk's
radio map (and fitted access points, the sources' fits, fix calibration, grown points) without every walk
of its group: --leave-out route (every repetition of an IPIN trial: the trial number of
..._TrainingTrialNN_repetitionR; other names are refused), --leave-out-group REGEX (the regex's
first group, or its whole match, in the log's file name), or --groups FILE.csv (rows log,group;
a header line 'log,group'); the printout, summary.json, walks.csv and config.yaml name the
protocol, and the table per group (per route) follows the summary.
Self-training (docs/self-training.md): --unlabelled LOGS grow that radio map from walks without
labels (tracked offline, their scans added where the offline track puts them; left out by walk
or group, grown once per fold of the labelled walks, a group's walks in one fold, so that no
walk is scored with points its own or its group's labels placed); --transductive lets the
evaluated walks grow it too, each scored with the other walks' grown points (left out by walk
or group: each fold's walks grow that fold's points, over the survey of the other folds).
Errors are taken at the ground-truth waypoint times from each method's latest estimate at or
before that time (causal); waypoints before a method's first estimate are counted as missed.
Every method of a walk is scored at the same waypoints: those after every method's first
estimate (the summary says how many; a method with no estimate at some of them is named, and
not_scored in summary.csv counts them); --waypoints own scores each method at every waypoint from
its own first estimate on. --smooth adds pf-smooth, the offline whole-walk track (not causal).
runtime_s is each method's own time.

writes into OUT, each walk's files as the walk finishes: walks/<trace>.json (its numbers),
tracks/<trace>/<method>.csv and tracks/<trace>.png (tracks on the plan, zoomed on the walk);
at the end: summary.csv, summary.json (with the config, per-trace and per-walk rows, and the
walks that failed), traces.csv, walks.csv (why each walk went wrong), cdf.png, config.yaml
(`--config OUT/config.yaml` repeats the run). OUT must be new, empty, or an earlier run's:
mapfilter lists every file it writes there (OUT/.mapfilter-manifest.json) and removes only
those first, never a file of yours;
--resume keeps the walks an interrupted run of the same settings finished and runs the rest.
A walk that cannot be tracked is named in the summary and the others go on (exit code 1).

examples (an ILC floor):
  mapfilter evaluate F1.yaml walks/*.txt.gz --leave-one-out --out results/F1 --jobs 2
  mapfilter evaluate F1.yaml test/*.txt.gz --survey survey/*.txt.gz --out results/F1-test --smooth
  mapfilter evaluate site1.yaml walks/*/*.txt.gz --leave-one-out --out results/site1

--jobs N runs the walks on N local worker processes; --scheduler tcp://HOST:PORT on a
Dask cluster you trust (pip install 'mapfilter[distributed]'; `dask scheduler` and
`dask worker tcp://HOST:PORT --nworkers N --nthreads 1`; the workers need the logs at the
same paths). Every walk seeds its own generator: serial, --jobs and a cluster give the same
numbers.
"""

# docs/results.md describes every column (ISO/IEC 18305 and EvAAL figures among them)
SUMMARY_COLUMNS = ("method", "mean", "median", "p75", "p90", "ce95", "max", "rmse", "n", "missed", "availability",
                   "wall_crossings", "collapses", "runtime_s")
BUILDING_COLUMNS = ("floor_accuracy", "floor_detection", "ipin_score")
# the files' columns: the printed ones and, after missed, the common waypoints a method has no estimate at
FILE_COLUMNS = SUMMARY_COLUMNS[:SUMMARY_COLUMNS.index("missed") + 1] + ("not_scored",) + SUMMARY_COLUMNS[
    SUMMARY_COLUMNS.index("missed") + 1:]


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "evaluate", help="compare every method on the same walks (errors, CDF plot, tracks)",
        description="Run every method on the same walks and compare their errors against ground truth.",
        epilog=_EPILOG.replace("{sources}", _sources_epilog()),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("map", type=Path, metavar="MAP", help="map YAML or building YAML")
    parser.add_argument("logs", type=Path, nargs="+", metavar="LOG", help="walks with waypoints (scored)")
    parser.add_argument("--methods", default=None, metavar="M1,M2",
                        help="comma-separated methods (default: all that the map and WiFi source allow)")
    parser.add_argument("--radiomap", type=Path, metavar="RM", help="one radio map for all walks")
    parser.add_argument("--aps", type=Path, metavar="APS.csv", help="access-point table (ls; pf if no radio map)")
    parser.add_argument("--survey", type=Path, nargs="+", default=[], metavar="LOG",
                        help="walks with waypoints that make the radio map (and fitted APs); never scored")
    leave_out = parser.add_mutually_exclusive_group()
    leave_out.add_argument("--leave-one-out", action="store_true",
                           help="each walk's radio map (and fitted APs for ls) from the other walks too")
    leave_out.add_argument("--leave-out", choices=("walk", "route"), default=None,
                           help="walk: as --leave-one-out; route: each walk's radio map without every repetition of "
                                "its IPIN trial (the trial number in ..._TrainingTrialNN_repetitionR)")
    leave_out.add_argument("--leave-out-group", default=None, metavar="REGEX",
                           help="each walk's radio map without its group: the regex's first group (or whole match) "
                                "in the log's file name")
    leave_out.add_argument("--groups", type=Path, default=None, metavar="FILE.csv",
                           help="each walk's radio map without its group: a CSV with the header log,group")
    parser.add_argument("--unlabelled", type=Path, nargs="+", default=[], metavar="LOG",
                        help="walks that grow the radio map (self-training; their waypoints never read); never scored")
    parser.add_argument("--transductive", action="store_true",
                        help="the evaluated walks grow the radio map too, without their labels; each walk is scored "
                             "with the others' grown points")
    add_start_argument(parser, every_walk=True)
    parser.add_argument("--waypoints", choices=("common", "own"), default="common",
                        help="common: every method of a walk scored at the waypoints every method has an estimate "
                             "for (default); own: each method at every waypoint from its own first estimate on")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    parser.add_argument("--resume", action="store_true",
                        help="keep the walks an interrupted run with the same settings finished in OUT")
    add_tracking_arguments(parser)
    add_source_arguments(parser)
    add_engine_arguments(parser)
    add_strict_argument(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mapfilter.evaluation.comparison import evaluate, methods_for
    from mapfilter.evaluation.plots import load_plotting

    check_map_first("mapfilter evaluate MAP LOG...", args.map, [*args.logs, *args.survey, *args.unlabelled])
    if args.leave_out == "walk":
        args.leave_one_out = True
    grouping = _grouping(args)
    config = tracking_config_from(args)
    methods = None if args.methods is None else tuple(m.strip() for m in args.methods.split(",") if m.strip())
    engine = engine_from(args)
    inputs = input_paths(args.map, args.logs, args.radiomap, args.aps, args.survey, args.unlabelled, args.config,
                         *source_paths(args), args.groups)
    out = check_output_path(args.out, directory=True, inputs=inputs)  # holds only our files, no input
    building = _checked_building(args, config)
    setup = _validated_setup(args, building, config, methods, grouping)  # before anything is written
    key = _run_key(args, config, methods, grouping, inputs)
    resumed = _resumed_walks(args, out, key)
    args.out.mkdir(parents=True, exist_ok=True)
    _announce(args, building, methods, config, len(resumed))
    finished = _WalkWriter(out, key, resumed)
    load_plotting()  # before the walks: an interrupt in its import would leave it half loaded for the pictures
    # every file of the run is staged and committed together at the end: a run that fails (a full
    # disk) leaves an earlier evaluation whole; an interrupted one commits the walks done so far
    evaluation = None
    try:
        with ProgressBar("evaluate", len(args.logs)) as progress, ProgressBar("growing the radio map", 1) as growing:
            try:
                evaluation = evaluate(building, args.logs, setup, engine, progress=progress, on_walk=finished,
                                      resumed=resumed, grow_progress=growing if setup.grows else None,
                                      walk_files=walk_files)
            except KeyboardInterrupt:
                _write_partial_summary(args, out, finished.done, setup, config,
                                       methods_for(building, source_files(args)))
                raise
        for message in evaluation.read_warnings:
            warn(message)
        _write_summary(args, out, evaluation, config, methods_for(building, source_files(args)), complete=True)
        out.commit()
    finally:
        out.discard()
    return 1 if evaluation.failed else 0


def _checked_building(args, config):
    """The map or building, its problems for tracking warned, refused when the tracking settings
    do not fit it."""
    from mapfilter.maps.building import Building
    from mapfilter.maps.walkable import check_before_tracking

    building = Building.load(args.map)
    for message in check_before_tracking(building, args.map):
        warn(message)
    check_tracking_fits(config, building_extents_m(building))
    return building


def _validated_setup(args, building, config, methods, grouping):
    """The evaluation's setup, checked against the building and the logs."""
    from mapfilter.evaluation.comparison import EvaluationSetup, validate_setup

    setup = EvaluationSetup(methods=methods, radio_map_path=args.radiomap, ap_table_path=args.aps,
                            survey_paths=tuple(args.survey), leave_one_out=args.leave_one_out, strict=args.strict,
                            tracking=config, unlabelled_paths=tuple(args.unlabelled),
                            transductive=args.transductive, sources=load_sources(args, building), groups=grouping,
                            common_waypoints=args.waypoints == "common", start=start_from(args, building))
    validate_setup(building, args.logs, setup)
    return setup


def _run_key(args, config, methods, grouping, inputs) -> str:
    """What makes two runs the same run (``--resume`` keeps only the walks of the same one)."""
    from mapfilter.evaluation.store import file_digest, run_key

    return run_key({"map": str(args.map.resolve()), "logs": [str(p.resolve()) for p in args.logs],
                    "survey": [str(p.resolve()) for p in args.survey], "radiomap": str(args.radiomap),
                    "aps": str(args.aps), "leave_one_out": args.leave_one_out, "methods": methods,
                    "unlabelled": [str(p.resolve()) for p in args.unlabelled], "transductive": args.transductive,
                    "strict": args.strict, "config": config.to_dict(),
                    **({"start": args.start} if args.start is not None else {}),
                    **({"sources": _source_files(args)} if source_files(args) else {}),
                    **({"groups": dict(grouping.group_of)} if grouping is not None else {}),
                    # by content: a log, map or model replaced at the same path is another run
                    "content": [file_digest(p) for p in inputs if p.is_file()]})


def _resumed_walks(args, out, key: str) -> list:
    """With --resume, the outcomes of the walks of this run an interrupted one finished in OUT;
    else none, and what an earlier run wrote there goes with the commit."""
    from mapfilter.evaluation.store import read_outcome
    from mapfilter.sensors.recording import trace_name

    walks_dir = args.out / "walks"
    resumed = []
    if args.resume:
        names = {trace_name(p) for p in args.logs}
        for path in sorted(walks_dir.glob("*.json")) if walks_dir.is_dir() else []:
            outcome = read_outcome(path, key)
            if outcome is not None and outcome.trace in names:
                resumed.append(outcome)
        print(f"resuming: {len(resumed)} of {len(args.logs)} walks already done in {args.out}")
    else:
        out.replace_earlier_run()  # what an earlier run wrote there (its manifest) goes with the commit
    return resumed


class _WalkWriter:
    """``on_walk`` of the evaluation: each walk's numbers and the files its task made (its tracks
    and picture: ``walk_files``) staged as it finishes (an interrupted run commits them); ``done``:
    the walks with an outcome, for a partial summary."""

    def __init__(self, out, key: str, resumed: list) -> None:
        self.out, self.key = out, key
        self.done: list = list(resumed)

    def __call__(self, outcome) -> None:
        from mapfilter.evaluation.store import write_outcome
        from mapfilter.runtime.interrupts import deferred

        # a walk computed is kept whole: a Ctrl-C while its files are written comes after them
        with deferred():
            with self.out.writing(f"walks/{outcome.trace}.json") as (tmp,):
                write_outcome(outcome, tmp, self.key)
            for name, content in outcome.files.items():
                with self.out.writing(name) as (tmp,):
                    tmp.write_bytes(content)
            self.done.append(outcome)
        if outcome.status != "ok":
            print(f"mapfilter: {outcome.status}: {outcome.reason}", file=sys.stderr)


def _write_partial_summary(args, out, done: list, setup, config, methods) -> None:
    """An interrupted run: the summary of the walks finished so far (a consistent partial
    result), committed with them."""
    from mapfilter.evaluation.comparison import Evaluation
    from mapfilter.sensors.recording import trace_name as name_of

    index = {name_of(p): i for i, p in enumerate(args.logs)}
    partial = Evaluation.from_outcomes([dataclasses.replace(o, index=index[o.trace]) for o in done
                                        if o.trace in index], len(args.logs), 0.0)
    partial.protocol, partial.grouping = setup.protocol, setup.groups
    partial.radio_map_source = setup.radio_map_source(len(args.logs))
    partial.common_waypoints = setup.common_waypoints
    _write_summary(args, out, partial, config, methods, complete=False)
    out.commit()
    print(f"interrupted: {len(done)} of {len(args.logs)} walks done; wrote a partial summary to "
          f"{args.out} (mapfilter evaluate ... --resume runs the rest)")


def _grouping(args):
    """The grouping of a leave-a-group-out run (None: by walk, or no leave-out), over the
    evaluated and the survey logs; one line and exit 1 for names it cannot group."""
    from mapfilter.evaluation import groups

    walks = [*args.survey, *args.logs]
    if args.leave_out == "route":
        grouping = groups.by_ipin_trial(walks)
    elif args.leave_out_group is not None:
        grouping = groups.by_regex(walks, args.leave_out_group)
    elif args.groups is not None:
        grouping = groups.from_csv(args.groups, walks)
    else:
        return None
    print(grouping.describe())
    return grouping


def _source_files(args) -> dict[str, dict[str, str]]:
    return {name: {key: str(path) for key, path in files.items()} for name, files in source_files(args).items()}


def _announce(args, building, methods, config, n_resumed: int) -> None:
    """The run's rough time, before it starts, when it is long: the particle filter runs of every
    walk (the baselines cost little beside them) and of the walks that grow the radio map."""
    from mapfilter.evaluation.comparison import methods_for

    pf_runs = [m for m in (methods or methods_for(building, source_files(args))) if m.startswith("pf")]
    runs = len(pf_runs) + (SMOOTH_EXTRA_RUNS if config.smooth and "pf" in pf_runs else 0)
    spans = walk_spans_s(args.logs)
    growing = walk_spans_s(args.unlabelled) + (spans if args.transductive else [])
    workers = args.jobs if args.scheduler is None else 1
    seconds = estimate_tracking_s(spans, config.filter.n_particles, runs, workers)
    seconds *= 1 - n_resumed / max(1, len(args.logs))
    # growing: each walk tracked offline, up to 3 rounds (selftrain.GrowConfig.max_iterations)
    seconds += estimate_tracking_s(growing, config.filter.n_particles, 3 * (1 + SMOOTH_EXTRA_RUNS), workers)
    announce_estimate(f"evaluating {len(args.logs)} walk{'s' if len(args.logs) != 1 else ''}", seconds,
                      f"{duration_text(sum(spans))} of walks, {len(pf_runs)} particle filter methods of "
                      f"{config.filter.n_particles} particles, {workers} worker{'s' if workers != 1 else ''}")



def walk_files(outcome, recording, building) -> dict[str, bytes]:
    """A walk's files, made in memory in its own task (``evaluate``'s ``walk_files``): every
    method's track (tracks/WALK/METHOD.csv) and the tracks on the walk's floor plan
    (tracks/WALK.png); the parent writes them."""
    import io

    from mapfilter.evaluation.plots import plot_tracks_on_map
    from mapfilter.io.tracks import track_csv_bytes

    index = 0  # the picture's plan: in a building, the floor the log's header names
    if not building.is_single_floor:
        try:
            index = building.floor_of_log(recording.floor_name or None, outcome.log_path) or 0
        except MapfilterError:
            index = 0
    files = {f"tracks/{outcome.trace}/{r.method}.csv": track_csv_bytes(dataclasses.replace(r.track, name=r.method),
                                                                        building) for r in outcome.results}
    shown = {r.method: r.track.xy_m for r in outcome.results if r.method in ("pf", "pf-smooth", "kwnn", "kf", "pdr")}
    picture = io.BytesIO()
    plot_tracks_on_map(building.floors[index].plan, shown, picture, recording.waypoint_xy_m, title=outcome.trace)
    files[f"tracks/{outcome.trace}.png"] = picture.getvalue()
    return files


def _write_summary(args, out_dir, evaluation, config, methods, complete: bool) -> None:
    from mapfilter.evaluation.plots import plot_error_cdf

    columns = SUMMARY_COLUMNS + (BUILDING_COLUMNS if evaluation.has_floors else ())
    file_columns = FILE_COLUMNS + (BUILDING_COLUMNS if evaluation.has_floors else ())
    summary = evaluation.summary_rows()
    by_phone = evaluation.summary_rows(by_phone=True)
    grouping = evaluation.grouping
    by_group = evaluation.summary_rows(by_group=True) if grouping is not None else []
    n_done = len({r.trace for r in evaluation.results}) + len(evaluation.failed)
    _print_tables(args, evaluation, columns, summary, by_phone, by_group, n_done)
    out: Path = args.out
    trace_rows = evaluation.trace_rows()
    # every walk's row names the protocol it was scored with, so walks.csv stands on its own
    walk_rows = [{"trace": row["trace"], "protocol": evaluation.protocol, **row} for row in evaluation.walk_rows()]
    failed = [{"trace": o.trace, "log": str(o.log_path), "status": o.status, "reason": o.reason}
              for o in evaluation.failed]
    names = ("summary.csv", "traces.csv", "walks.csv", "summary.json", "config.yaml") + (
        ("groups.csv",) if grouping is not None else ())
    with out_dir.writing(*names) as (s_csv, t_csv, w_csv, s_json, c_yaml, *g_csv):
        _write_csv(s_csv, summary, file_columns)
        _write_csv(t_csv, trace_rows, ("trace",) + (("group",) if grouping is not None else ()) + file_columns
                   + (("phone",) if by_phone else ()))
        _write_csv(w_csv, walk_rows, list(dict.fromkeys(k for row in walk_rows for k in row)) or ["trace"])
        if g_csv:
            _write_csv(g_csv[0], by_group, ("group",) + file_columns + ("traces",))
        s_json.write_text(json.dumps(_summary_json(args, evaluation, config, methods, complete, n_done, failed, {
            "summary": summary, "summary_by_phone": by_phone, "summary_by_group": by_group, "traces": trace_rows,
            "per_walk": walk_rows}), indent=1))
        # the protocol as a comment: the file still loads with --config
        c_yaml.write_text(f"# scored against {evaluation.protocol} (mapfilter evaluate; summary.json has the rest)\n"
                          + config.to_yaml())
    if evaluation.results:
        with out_dir.writing("cdf.png") as (tmp,):
            plot_error_cdf(evaluation.errors_by_method(), tmp,
                           title=f"{n_done} walks on {args.map.name}, {evaluation.protocol}"
                           + ("" if complete else " (partial)"))
    if failed:
        print(f"{len(failed)} walk{'s' if len(failed) != 1 else ''} without results (summary.json lists why): "
              + ", ".join(item["trace"] for item in failed))
    print(f"wrote {out}/summary.csv, summary.json, traces.csv, walks.csv (why each walk went wrong), cdf.png, "
          f"config.yaml, " + ("groups.csv (per group), " if grouping is not None else "") + "walks/, tracks/")


def _print_tables(args, evaluation, columns, summary: list[dict], by_phone: list[dict], by_group: list[dict],
                  n_done: int) -> None:
    """The summary line (walks, waypoints, time, where the radio map came from, the start), how the
    methods were scored, the summary table with the methods not scored at some waypoints, per phone
    model when there are several, per group in a leave-a-group-out run."""
    from mapfilter.evaluation.metrics import format_table
    from mapfilter.pipeline.tracker import TRUE_START

    waypoints = evaluation.common_count()[1]
    grown = f", plus {evaluation.grown}" if evaluation.grown else ""
    start = ("" if args.start is None else "; the pf methods started at each walk's first waypoint (--start truth)"
             if args.start == TRUE_START else f"; the pf methods started at {args.start} (--start)")
    print(f"{n_done} of {evaluation.n_traces} walks, {waypoints} waypoints, {evaluation.wall_time_s:.1f} s; "
          f"{evaluation.radio_map_source}{grown}{start}")
    if evaluation.results:
        print(evaluation.scoring_text())
    print(format_table(summary, columns))
    for line in evaluation.not_scored_text():
        print(f"  {line}")
    if len(evaluation.phones()) > 1:
        print(f"\nper phone model:\n{format_table(by_phone, ('phone',) + columns)}")
    if evaluation.grouping is not None:
        print(f"\nper {evaluation.grouping.unit} ({evaluation.protocol}):\n"
              f"{format_table(by_group, ('group',) + columns)}")


def _summary_json(args, evaluation, config, methods, complete: bool, n_done: int, failed: list[dict],
                  tables: dict[str, list[dict]]) -> dict:
    """summary.json: the run's inputs, protocol, settings and outcome, then ``tables`` (name: rows,
    NaN as null)."""
    from mapfilter.evaluation.comparison import nan_to_none

    grouping = evaluation.grouping
    return {
        "map": str(args.map), "logs": [str(p) for p in args.logs], "survey": [str(p) for p in args.survey],
        "radiomap": None if args.radiomap is None else str(args.radiomap), "leave_one_out": args.leave_one_out,
        "protocol": evaluation.protocol, "radio_map_source": evaluation.radio_map_source,
        "waypoints": args.waypoints, "scoring": evaluation.scoring_text(), "start": args.start,
        "groups": None if grouping is None else dict(grouping.group_of),
        "sources": _source_files(args),
        "unlabelled": [str(p) for p in args.unlabelled], "transductive": args.transductive,
        "grown": evaluation.grown,
        "methods": list(methods), "complete": complete, "walks": evaluation.n_traces, "walks_done": n_done,
        "wall_time_s": evaluation.wall_time_s, "config": config.to_dict(), "failed": failed,
        **{name: [{k: nan_to_none(v) for k, v in row.items()} for row in rows] for name, rows in tables.items()},
    }


def _write_csv(path: Path, rows: list[dict], columns) -> None:
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(columns)
        for row in rows:
            writer.writerow([_cell(row.get(c)) for c in columns])


def _cell(value) -> str:
    if isinstance(value, float):
        return "" if value != value else f"{value:.4f}"
    return "" if value is None else str(value)
