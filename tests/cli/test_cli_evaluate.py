"""`mapfilter evaluate`: every method on the same walks, outputs, and bad inputs."""

import csv
import json

import numpy as np
import pytest
from conftest import REPO, ctrl_c_as_a_terminal_gives_it

from mapfilter.cli import main
from mapfilter.io.tracks import read_track

MAPS = REPO / "maps"


def test_every_method_on_the_bundled_walk(tmp_path, capsys):
    out = tmp_path / "eval"
    args = ["evaluate", str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"), "--radiomap",
            str(MAPS / "office_radiomap.npz"), "--aps", str(MAPS / "office_fitted_aps.csv"),
            "--particles", "2000", "--smooth", "--out", str(out)]
    assert main(args) == 0
    printed = capsys.readouterr().out
    with (out / "summary.csv").open() as handle:
        rows = {row["method"]: row for row in csv.DictReader(handle)}
    assert set(rows) == {"pf", "pf-smooth", "pf-nomap", "pf-nopdr", "kwnn", "pdr-kwnn", "kf", "pdr", "ls", "pdr-start"}
    for method in rows:
        assert f"| {method} |" in printed
    # with a dense survey the map-aware filter beats the raw fixes; the smoothed track crosses no wall
    assert float(rows["pf"]["mean"]) < float(rows["kwnn"]["mean"])
    assert int(rows["pf-smooth"]["wall_crossings"]) == 0
    assert int(rows["pf-nomap"]["wall_crossings"]) > 0
    summary = json.loads((out / "summary.json").read_text())
    assert {r["method"] for r in summary["summary"]} == set(rows)
    assert (out / "cdf.png").read_bytes()[:4] == b"\x89PNG"
    assert (out / "tracks" / "office_walk.png").is_file()
    track = read_track(out / "tracks" / "office_walk" / "pf.csv")
    assert len(track) > 100 and np.all(np.diff(track.t_s) >= 0)


def test_same_seed_same_table(tmp_path):
    tables = []
    for name in ("a", "b"):
        out = tmp_path / name
        assert main(["evaluate", str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"), "--radiomap",
                     str(MAPS / "office_radiomap.npz"), "--methods", "pf,kwnn", "--particles", "1000",
                     "--seed", "4", "--out", str(out)]) == 0
        tables.append([row[:8] for row in csv.reader((out / "summary.csv").open())])
    assert tables[0] == tables[1]


def test_unknown_method_and_missing_log_are_one_line(tmp_path, capsys):
    out = tmp_path / "eval"
    base = ["evaluate", str(MAPS / "office.yaml")]
    assert main(base + [str(MAPS / "office_walk.txt.gz"), "--radiomap", str(MAPS / "office_radiomap.npz"),
                        "--methods", "pf,magic", "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "magic" in err
    assert main(base + [str(tmp_path / "missing.txt"), "--radiomap", str(MAPS / "office_radiomap.npz"),
                        "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "missing.txt" in err
    assert not out.exists()


def test_logs_without_imu_still_get_the_wifi_methods(tmp_path):
    import gzip

    log = tmp_path / "wifi_only.txt"
    with gzip.open(MAPS / "office_walk.txt.gz", "rt") as handle:
        log.write_text("".join(line for line in handle if "TYPE_ACCELEROMETER" not in line))
    out = tmp_path / "eval"
    assert main(["evaluate", str(MAPS / "office.yaml"), str(log), "--radiomap", str(MAPS / "office_radiomap.npz"),
                 "--methods", "pf,pf-nopdr,kwnn,kf,pdr", "--particles", "500", "--out", str(out)]) == 0
    with (out / "summary.csv").open() as handle:
        methods = {row["method"] for row in csv.DictReader(handle)}
    assert methods == {"pf-nopdr", "kwnn", "kf"}  # pf and pdr need steps


def test_two_logs_with_one_trace_name_are_refused(tmp_path, capsys):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "office_walk.txt.gz").write_bytes((MAPS / "office_walk.txt.gz").read_bytes())
    out = tmp_path / "eval"
    assert main(["evaluate", str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"),
                 str(tmp_path / "a" / "office_walk.txt.gz"), "--radiomap", str(MAPS / "office_radiomap.npz"),
                 "--out", str(out)]) == 1
    assert "office_walk" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.slow
def test_whole_walk_track_on_real_walks_beats_kwnn_and_crosses_no_wall(ilc_site1):
    """F1, the first 12 walks of the sparse set, leave-one-out among them: the whole-walk track
    (pf-smooth) against the KWNN fixes of the same walks (all 36: 0.52x; here fewer walks
    survey each other, so a looser bound), and per-walk diagnostics for every walk."""
    from conftest import tracking_config

    from mapfilter.evaluation.comparison import EvaluationSetup, evaluate
    from mapfilter.maps.building import Building
    from mapfilter.maps.prepare import import_ilc

    floor = ilc_site1 / "F1"
    names = (floor / "sparse_set.txt").read_text().split()[:12]
    paths = [floor / "path_data_files" / f"{name}.txt.gz" for name in names]
    setup = EvaluationSetup(methods=("pf", "kwnn"), leave_one_out=True,
                            tracking=tracking_config(n_particles=2000, smooth=True))
    evaluation = evaluate(Building.from_plan(import_ilc(floor, route="geojson")), paths, setup)
    rows = {row["method"]: row for row in evaluation.summary_rows()}
    assert rows["pf-smooth"]["wall_crossings"] == 0 and rows["pf-smooth"]["missed"] == 0
    assert rows["pf-smooth"]["mean"] < 0.85 * rows["kwnn"]["mean"]
    assert rows["pf-smooth"]["p75"] < 0.85 * rows["kwnn"]["p75"]
    walks = evaluation.walk_rows()
    assert len(walks) == 12 and all(w["coverage_m"] >= 0 and w["fix_error_m"] > 0 for w in walks)
    # dB per AP to the nearest reference point: phones and days differ by several dB, never by 40
    assert all(1.0 < w["signal_distance_db"] < 40.0 for w in walks)


def _office_walks(tmp_path, n):
    walks = []
    for seed in range(n):
        path = tmp_path / f"walk{seed}.txt.gz"
        assert main(["simulate", str(MAPS / "office.yaml"), "--aps", str(MAPS / "office_aps.csv"), "--out", str(path),
                     "--duration", "40", "--seed", str(seed)]) == 0
        walks.append(path)
    return walks


@pytest.mark.slow
@pytest.mark.parametrize("jobs", ["1", "2"])
def test_an_interrupted_evaluate_resumes_to_the_uninterrupted_summary(tmp_path, jobs):
    """SIGINT after the first walk, serial or on forked workers: the walks done are kept (their
    files, a partial summary, no temporaries); --resume runs the rest and the summary equals an
    uninterrupted run's."""
    import signal
    import subprocess
    import sys
    import time

    # six walks of about a second each: the signal, sent as the first walk's file appears, comes
    # seconds before the last walk could end, however fast or loaded the machine
    walks = _office_walks(tmp_path, 6)
    args = ["evaluate", str(MAPS / "office.yaml"), *map(str, walks), "--radiomap", str(MAPS / "office_radiomap.npz"),
            "--methods", "pf,kwnn", "--particles", "8000"]
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    assert main(args + ["--out", str(whole)]) == 0
    process = subprocess.Popen([sys.executable, "-m", "mapfilter", *args, "--jobs", jobs, "--out", str(cut)], cwd=REPO,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               preexec_fn=ctrl_c_as_a_terminal_gives_it)
    # the first walk's file appears staged (a hidden temporary, which the glob matches) as its
    # writing starts: from there the walk is kept, whenever the signal comes
    deadline = time.monotonic() + 120
    while not list((cut / "walks").glob("*.json")) and time.monotonic() < deadline:
        time.sleep(0.05)
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=120)
    assert process.returncode == 130, err
    done = sorted(p.name for p in (cut / "walks").glob("*.json"))
    assert 1 <= len(done) < 6 and "interrupted" in out
    partial = json.loads((cut / "summary.json").read_text())
    assert partial["complete"] is False and partial["walks_done"] == len(done)
    assert not [p for p in cut.rglob(".*") if p.is_file() and p.name != ".mapfilter-manifest.json"]  # no temporaries
    assert main(args + ["--out", str(cut), "--resume"]) == 0

    def numbers(out):  # every column but the run time
        rows = list(csv.DictReader((out / "summary.csv").open()))
        return [{k: v for k, v in row.items() if k != "runtime_s"} for row in rows]

    assert numbers(cut) == numbers(whole)
    assert json.loads((cut / "summary.json").read_text())["complete"] is True
    # a file that mapfilter did not write makes a new run refuse the folder, before touching anything
    (cut / "walks" / "mine.json").write_text("{}")
    fresh = args[:3] + ["--radiomap", str(MAPS / "office_radiomap.npz"), "--methods", "kwnn", "--out", str(cut)]
    assert main(fresh) == 1
    assert (cut / "walks" / "mine.json").read_text() == "{}" and len(list((cut / "walks").glob("*.json"))) == len(walks) + 1
    # without it, a fresh run (no --resume) removes what the earlier run left
    (cut / "walks" / "mine.json").unlink()
    assert main(fresh) == 0
    assert sorted(p.name for p in (cut / "walks").glob("*.json")) == [walks[0].name.replace(".txt.gz", ".json")]


def test_evaluate_against_survey_logs_scores_only_the_walks_given(tmp_path):
    walks = _office_walks(tmp_path, 3)
    out = tmp_path / "out"
    assert main(["evaluate", str(MAPS / "office.yaml"), str(walks[0]), "--survey", str(walks[1]), str(walks[2]),
                 "--methods", "kwnn,pf", "--particles", "500", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert {row["trace"] for row in summary["traces"]} == {"walk0"}
    assert main(["evaluate", str(MAPS / "office.yaml"), str(walks[0]), "--survey", str(walks[0]),
                 "--out", str(tmp_path / "o2")]) == 1


def test_the_summary_line_says_where_the_radio_map_came_from(tmp_path, capsys):
    """Issue 53, frictions 5 and 6: the summary line names the radio map in words (the file given,
    the survey walks it was built from, or each walk's from the others), not a protocol's label."""
    walks = _office_walks(tmp_path, 3)

    def first_line(args, out, logs=walks[:1]) -> str:
        assert main(["evaluate", str(MAPS / "office.yaml"), *map(str, logs), "--methods", "kwnn", *args,
                     "--out", str(tmp_path / out)]) == 0
        printed = capsys.readouterr().out
        return next(line for line in printed.splitlines() if " walks, " in line)

    line = first_line(["--survey", str(walks[1]), str(walks[2])], "survey")
    assert line.endswith("; the radio map built from the 2 survey walks (--survey, not scored)"), line
    assert "scored against" not in line and "(never scored)" not in line
    line = first_line(["--radiomap", str(MAPS / "office_radiomap.npz")], "given")
    assert line.endswith(f"; the radio map {MAPS / 'office_radiomap.npz'}"), line
    line = first_line(["--leave-one-out"], "loo", walks[:2])
    assert line.endswith("; each walk's radio map built from the other 1 walk (leave-one-walk-out)"), line
    summary = json.loads((tmp_path / "loo" / "summary.json").read_text())
    assert summary["radio_map_source"] == line.split("; ", 1)[1] and summary["protocol"] == "leave-one-walk-out"


@pytest.mark.slow
def test_unlabelled_and_transductive_walks_grow_the_radio_map_and_are_named(tmp_path, capsys):
    """--unlabelled walks grow the survey's radio map and are never scored; --transductive lets the
    scored walks grow it too; both are named in the printout and summary.json."""
    walks = _office_walks(tmp_path, 4)
    common = ["evaluate", str(MAPS / "office.yaml"), str(walks[0]), "--survey", str(walks[1]),
              "--methods", "kwnn,pf", "--particles", "500"]
    assert main(common + ["--unlabelled", str(walks[2]), str(walks[3]), "--out", str(tmp_path / "u")]) == 0
    summary = json.loads((tmp_path / "u" / "summary.json").read_text())
    assert {row["trace"] for row in summary["traces"]} == {"walk0"}
    assert "grown points from 2 walks" in summary["grown"] and ", plus 2" in capsys.readouterr().out
    assert main(common + ["--transductive", "--out", str(tmp_path / "t")]) == 0
    summary = json.loads((tmp_path / "t" / "summary.json").read_text())
    assert "(transductive)" in summary["grown"] and summary["transductive"] is True
    # left out by walk: each fold's scored walks grow its points over the other folds' labels
    assert main(["evaluate", str(MAPS / "office.yaml"), *map(str, walks[:2]), "--leave-one-out", "--transductive",
                 "--methods", "kwnn", "--particles", "500", "--out", str(tmp_path / "x")]) == 0
    summary = json.loads((tmp_path / "x" / "summary.json").read_text())
    assert "per fold of the labelled walks (2 folds)" in summary["grown"] and "(transductive)" in summary["grown"]
    assert main(common + ["--unlabelled", str(walks[0]), "--out", str(tmp_path / "y")]) == 1
    assert "both unlabelled and labelled or scored" in capsys.readouterr().err


@pytest.mark.slow
def test_leave_out_route_names_its_protocol_and_groups_as_a_regex_or_csv_does(tmp_path, capsys):
    """--leave-out route on logs with IPIN trial names: the protocol in the printout, summary.json,
    walks.csv and config.yaml (which still loads), a row per route; --leave-out-group and --groups
    with the same groups give the same table; a name it cannot place is refused in one line."""
    walks = []
    for i, path in enumerate(_office_walks(tmp_path, 4)):
        named = tmp_path / f"IPIN2023_T3_TrainingTrial0{1 + i // 2}_repetition0{1 + i % 2}.txt.gz"
        path.rename(named)
        walks.append(named)
    common = ["evaluate", str(MAPS / "office.yaml"), *map(str, walks), "--methods", "kwnn,pf", "--particles", "500"]
    assert main(common + ["--leave-out", "route", "--out", str(tmp_path / "route")]) == 0
    printed = capsys.readouterr().out
    assert "leave-one-route-out (IPIN trials): 2 routes of 2 walks" in printed
    assert ("each walk's radio map built from the walks of the other routes (leave-one-route-out (IPIN trials))"
            in printed and "per route" in printed)
    summary = json.loads((tmp_path / "route" / "summary.json").read_text())
    assert summary["protocol"] == "leave-one-route-out (IPIN trials)"
    assert summary["groups"]["IPIN2023_T3_TrainingTrial02_repetition01"] == "T02"
    assert [(r["group"], r["method"], r["traces"]) for r in summary["summary_by_group"]] == [
        ("T01", "kwnn", 2), ("T01", "pf", 2), ("T02", "kwnn", 2), ("T02", "pf", 2)]
    walk_rows = list(csv.DictReader((tmp_path / "route" / "walks.csv").open()))
    assert {(r["protocol"], r["group"]) for r in walk_rows} == {("leave-one-route-out (IPIN trials)", "T01"),
                                                                ("leave-one-route-out (IPIN trials)", "T02")}
    groups = list(csv.DictReader((tmp_path / "route" / "groups.csv").open()))
    assert [(r["group"], r["method"]) for r in groups] == [("T01", "kwnn"), ("T01", "pf"), ("T02", "kwnn"),
                                                             ("T02", "pf")]
    config = (tmp_path / "route" / "config.yaml").read_text()
    assert config.startswith("# scored against leave-one-route-out")
    # the same groups by a regex and by a CSV: the same numbers
    table = tmp_path / "groups.csv"
    table.write_text("log,group\n" + "".join(f"{w.name},{'ab'[i // 2]}\n" for i, w in enumerate(walks)))
    assert main(common + ["--leave-out-group", r"Trial(\d+)", "--out", str(tmp_path / "regex")]) == 0
    assert main(common + ["--groups", str(table), "--config", str(tmp_path / "route" / "config.yaml"),
                          "--out", str(tmp_path / "csv")]) == 0

    def numbers(out):
        return [{k: v for k, v in row.items() if k != "runtime_s"}
                for row in csv.DictReader((out / "summary.csv").open())]

    assert numbers(tmp_path / "regex") == numbers(tmp_path / "route") == numbers(tmp_path / "csv")
    # leave-one-walk-out keeps the other repetition of the route: another radio map, another table
    assert main(common + ["--leave-out", "walk", "--out", str(tmp_path / "walk")]) == 0
    assert json.loads((tmp_path / "walk" / "summary.json").read_text())["protocol"] == "leave-one-walk-out"
    assert numbers(tmp_path / "walk") != numbers(tmp_path / "route")
    capsys.readouterr()
    # a walk whose route it cannot tell: one line, nothing written
    other = tmp_path / "walk9.txt.gz"
    other.write_bytes(walks[0].read_bytes())
    assert main(common[:2] + [str(other)] + common[2:] + ["--leave-out", "route", "--out", str(tmp_path / "x")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "walk9.txt.gz" in err and not (tmp_path / "x").exists()
    # one group only: no walk would have a survey
    assert main(common + ["--leave-out-group", "IPIN", "--out", str(tmp_path / "y")]) == 1
    assert "at least two groups" in capsys.readouterr().err and not (tmp_path / "y").exists()


def test_the_causal_and_offline_rows_are_scored_at_the_same_waypoints(tmp_path, capsys):
    """Issue 53, friction 2: pf-smooth was scored at every waypoint and pf only from its first
    estimate on; by default both are scored at the same ones, and the printout says which."""
    common = ["evaluate", str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"), "--radiomap",
              str(MAPS / "office_radiomap.npz"), "--methods", "pf,kwnn", "--particles", "500", "--smooth"]
    assert main(common + ["--out", str(tmp_path / "same")]) == 0
    printed = capsys.readouterr().out
    rows = {row["method"]: row for row in csv.DictReader((tmp_path / "same" / "summary.csv").open())}
    assert rows["pf"]["n"] == rows["pf-smooth"]["n"] == rows["kwnn"]["n"]
    n, missed = int(rows["pf"]["n"]), int(rows["pf"]["missed"])
    assert missed > 0 and int(rows["pf-smooth"]["missed"]) == 0 and rows["pf-smooth"]["availability"] == "1.0000"
    assert f"every method scored at the same {n} of the {n + missed} waypoints" in printed
    assert main(common + ["--waypoints", "own", "--out", str(tmp_path / "own")]) == 0
    rows = {row["method"]: row for row in csv.DictReader((tmp_path / "own" / "summary.csv").open())}
    assert int(rows["pf-smooth"]["n"]) == n + missed and int(rows["pf"]["n"]) == n
    assert "each method scored at its own waypoints" in capsys.readouterr().out
