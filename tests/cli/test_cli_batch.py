"""`mapfilter track LOG... --out-dir` (many walks, failures reported) and `mapfilter check`."""

import csv
import gzip

import pytest
from conftest import REPO

from mapfilter.io.outputs import MANIFEST
from mapfilter.cli import main

MAPS = REPO / "maps"
OFFICE, WALK, RADIOMAP = MAPS / "office.yaml", MAPS / "office_walk.txt.gz", MAPS / "office_radiomap.npz"
INFINITY_BEACON = "1574559497300\tTYPE_BEACON\tuuid\t10073\t61418\t-65\t-79\tInfinity\t00:ab:cd:ef:01:02\t1574559497300\n"


def _walk_lines() -> list[str]:
    with gzip.open(WALK, "rt") as handle:
        return handle.readlines()


def _write(path, lines, gz=True):
    if gz:
        with gzip.open(path, "wt") as handle:
            handle.writelines(lines)
    else:
        path.write_text("".join(lines))
    return path


def _bad_wifi_row(lines):
    """The walk with one WiFi row's RSSI replaced by garbage, and that row's line number."""
    index = next(i for i, line in enumerate(lines) if "\tTYPE_WIFI\t" in line)
    fields = lines[index].split("\t")
    fields[4] = "strong"
    return lines[:index] + ["\t".join(fields)] + lines[index + 1:], index + 1


def test_batch_tracks_every_walk_reports_the_failed_one_and_matches_the_single_walk_track(tmp_path, capsys):
    lines = _walk_lines()
    logs = tmp_path / "logs"
    logs.mkdir()
    good = _write(logs / "good.txt.gz", lines)
    beacon = _write(logs / "beacon.txt.gz", lines[:3000] + [INFINITY_BEACON] + lines[3000:])
    no_wifi = _write(logs / "nowifi.txt", [line for line in lines if "TYPE_WIFI" not in line], gz=False)
    out = tmp_path / "tracks"
    common = ["--radiomap", str(RADIOMAP), "--particles", "300", "--seed", "3"]
    assert main(["track", str(OFFICE), str(good), str(no_wifi), str(beacon), "--out-dir", str(out)] + common) == 1
    captured = capsys.readouterr()
    assert "3 walks (serial): 2 tracked, 1 failed, 0 crashed" in captured.out
    assert "mapfilter: failed: " in captured.err and "nowifi.txt: the log has no usable WiFi" in captured.err
    assert "beacon.txt.gz: skipped 1 bad TYPE_BEACON row (not used" in captured.err
    # not a terminal: no progress bar, only the warning and failure lines
    assert all(line.startswith("mapfilter: ") for line in captured.err.splitlines())
    with (out / "summary.csv").open() as handle:
        rows = {row["trace"]: row for row in csv.DictReader(handle)}
    assert [rows[t]["status"] for t in ("good", "nowifi", "beacon")] == ["ok", "failed", "ok"]
    assert "no usable WiFi" in rows["nowifi"]["reason"] and rows["nowifi"]["track_file"] == ""
    assert "Infinity" in rows["beacon"]["skipped_rows"]
    assert float(rows["good"]["mean_m"]) < 4.0 and int(rows["good"]["waypoints"]) > 100
    assert sorted(p.name for p in out.iterdir() if p.name != MANIFEST) == ["beacon.csv", "config.yaml", "good.csv", "summary.csv",
                                                     "summary.json"]
    # a walk tracked in a batch is the walk tracked alone (same seed); the skipped beacon changes nothing
    single = tmp_path / "single.csv"
    assert main(["track", str(OFFICE), str(good), "--out", str(single)] + common) == 0
    assert (out / "good.csv").read_bytes() == single.read_bytes() == (out / "beacon.csv").read_bytes()


def test_batch_with_every_walk_tracked_exits_zero_and_tum_files(tmp_path, capsys):
    out = tmp_path / "tracks"
    assert main(["track", str(OFFICE), str(WALK), "--radiomap", str(RADIOMAP), "--particles", "200",
                 "--format", "tum", "--out-dir", str(out)]) == 0
    assert (out / "office_walk.tum").is_file() and (out / "summary.csv").is_file()


def test_batch_on_two_local_workers_writes_the_serial_tracks(tmp_path, capsys):
    lines = _walk_lines()
    logs = [_write(tmp_path / f"walk{i}.txt.gz", lines) for i in range(3)]
    common = ["track", str(OFFICE), *map(str, logs), "--radiomap", str(RADIOMAP), "--particles", "200"]
    assert main(common + ["--out-dir", str(tmp_path / "serial")]) == 0
    assert main(common + ["--jobs", "2", "--out-dir", str(tmp_path / "jobs2")]) == 0
    assert "3 walks (2 local worker processes): 3 tracked" in capsys.readouterr().out
    for i in range(3):
        assert (tmp_path / "serial" / f"walk{i}.csv").read_bytes() == (tmp_path / "jobs2" / f"walk{i}.csv").read_bytes()


def test_several_logs_need_out_dir_and_one_walk_options_are_refused_in_a_batch(tmp_path, capsys):
    base = ["track", str(OFFICE), str(WALK), str(WALK), "--radiomap", str(RADIOMAP)]
    assert main(base) == 1
    assert "needs --out-dir" in capsys.readouterr().err
    assert main(base + ["--out-dir", str(tmp_path / "o"), "--out", str(tmp_path / "t.csv")]) == 1
    assert "--out is for one walk" in capsys.readouterr().err
    assert main(base + ["--out-dir", str(tmp_path / "o")]) == 1  # the same trace twice: files would collide
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "share the trace name office_walk" in err
    assert not (tmp_path / "o").exists()


def test_bad_row_in_a_needed_type_warns_by_default_and_is_refused_with_strict(tmp_path, capsys):
    lines, bad_line_no = _bad_wifi_row(_walk_lines())
    log = _write(tmp_path / "badwifi.txt", lines, gz=False)
    args = ["track", str(OFFICE), str(log), "--radiomap", str(RADIOMAP), "--particles", "200"]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert f"skipped 1 bad TYPE_WIFI row (needed; first at line {bad_line_no}" in err
    assert main(args + ["--strict"]) == 1
    err = capsys.readouterr().err.strip()
    assert err == f"mapfilter: error: {log}:{bad_line_no}: malformed TYPE_WIFI line: column 5 is not a number: 'strong'"


def test_check_reports_each_oddity_and_refuses_only_what_cannot_be_read(tmp_path, capsys):
    lines = _walk_lines()
    logs = {
        "clean": _write(tmp_path / "clean.txt.gz", lines),
        "beacon": _write(tmp_path / "beacon.txt", lines[:50] + [INFINITY_BEACON.replace("Infinity", "NaN")] + lines[50:],
                         gz=False),
        "joined": _write(tmp_path / "joined.txt", lines[:40] + [lines[40].rstrip("\n")] + lines[41:], gz=False),
        "badwifi": _write(tmp_path / "badwifi.txt", _bad_wifi_row(lines)[0], gz=False),
        "empty": _write(tmp_path / "empty.txt", ["#\tstartTime:1\n", "1\tTYPE_WIFI\tonly-an-ssid\n"], gz=False),
    }
    cut = tmp_path / "cut.txt.gz"
    cut.write_bytes(logs["clean"].read_bytes()[:20000])
    assert main(["check", *map(str, logs.values()), str(cut)]) == 1
    out = capsys.readouterr().out.splitlines()
    line = {name: next(text for text in out if text.startswith(str(path))) for name, path in logs.items()}
    line["cut"] = next(text for text in out if text.startswith(str(cut)))
    assert "IMU" in line["clean"] and "WiFi scans" in line["clean"] and "skipped" not in line["clean"]
    assert "1 bad TYPE_BEACON row (not used" in line["beacon"] and "'NaN'" in line["beacon"]
    assert "1 line held two records (split)" in line["joined"] and "skipped" not in line["joined"]
    assert "1 bad TYPE_WIFI row (needed" in line["badwifi"]
    assert "gzip stream ends early" in line["cut"]
    assert "no usable record" in line["empty"] and line["empty"].endswith("[refused]")
    assert out[-1] == ("6 logs: 5 readable (5 with IMU for dead reckoning), 4 with rows skipped or split, "
                       "0 with time gaps, 1 refused")
    # --strict refuses the needed-type row and the cut stream, never the unused beacon
    assert main(["check", "--strict", str(logs["beacon"]), str(logs["badwifi"]), str(cut)]) == 1
    out = capsys.readouterr().out
    assert out.count("[refused]") == 2 and "truncated" in out and "'strong'" in out
