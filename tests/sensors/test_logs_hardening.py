"""Broken and hostile logs (issue 27): bounded lines, physical ranges, duplicates, time gaps and
format detection, the same in both readers (sensors/logread.py)."""

import gzip
import tracemalloc

import numpy as np
import pytest

from mapfilter.cli import main
from mapfilter.errors import MapfilterError
from mapfilter.sensors.ilc import NEEDED_TYPES, read_ilc
from mapfilter.sensors.logs import log_format, read_log, read_log_header

ILC_HEADER = "#\tstartTime:1574559495255\n#\tSiteID:x\tFloorName:F1\n#\tBrand:OPPO\tModel:PBCM10\n"
ILC_GOOD = (
    "1574559495263\tTYPE_WAYPOINT\t81.3\t93.3\n"
    "1574559495401\tTYPE_ACCELEROMETER\t-0.85\t1.82\t9.83\t2\n"
    "1574559495401\tTYPE_GYROSCOPE\t-0.39\t-0.08\t0.09\t3\n"
    "1574559497191\tTYPE_WIFI\tnet\ta8:0c:ca:03:9d:d7\t-49\t2422\t1574559496450\n"
    "1574559499263\tTYPE_WAYPOINT\t85.3\t93.3\n"
)
IPIN_HEADER = "% LogFile created by the 'GetSensorData' App for Android.\n"
IPIN_GOOD = (
    "ACCE;0.0448;2558.6338;-1.13967;6.03836;6.58426;3\n"
    "GYRO;0.0442;2558.6338;-0.05815;-0.34633;0.13078;3\n"
    "WIFI;1.2635;2559.8518;net;20:23:00:00:00:90;2437;-75\n"
    "POSI;1.0;1;49.460948188642;11.110539036217;0;100\n"
)


def _write(path, text, gz=False):
    if gz:
        with gzip.open(path, "wt") as handle:
            handle.write(text)
    else:
        path.write_text(text)
    return path


def test_one_huge_line_in_a_small_gzip_is_skipped_without_being_held(tmp_path):
    # 64 MB of one line (the case is 3 GB in 13 MB of gzip; the reader's memory is the same)
    path = tmp_path / "huge.txt.gz"
    with gzip.open(path, "wb", compresslevel=1) as handle:
        handle.write((ILC_HEADER + ILC_GOOD).encode())
        chunk = b"7" * (1 << 20)
        handle.write(b"1574559498000\tTYPE_WIFI\tnet\t")
        for _ in range(64):
            handle.write(chunk)
        handle.write(b"\n" + ILC_GOOD.encode())
    assert path.stat().st_size < 1_000_000
    tracemalloc.start()
    try:
        warnings = []
        rec = read_ilc(path, warn=warnings.append)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 16_000_000  # far below the 64 MB line
    line_no = (ILC_HEADER + ILC_GOOD).count("\n") + 1
    assert rec.read_report.bad_rows == {"?": 1} and "line longer than" in rec.read_report.first_bad["?"]
    assert rec.read_report.first_bad["?"].startswith(f"line {line_no}:")
    assert rec.read_report.n_lines == line_no + ILC_GOOD.count("\n")  # the lines after it are read
    assert len(warnings) == 1 and f"1 unreadable line (first at line {line_no}: line longer than" in warnings[0]
    with pytest.raises(MapfilterError, match=f":{line_no}: line longer than"):
        read_ilc(path, strict=True)


@pytest.mark.parametrize("bad_line, kind", [
    ("1574559498000\tTYPE_WIFI\tnet\tb8:0c:ca:03:9d:d7\t1e300\t2412\t1574559498000\n", "TYPE_WIFI"),
    ("1574559498000\tTYPE_ACCELEROMETER\t1e308\t0\t9.8\t3\n", "TYPE_ACCELEROMETER"),
    ("1574559498000\tTYPE_GYROSCOPE\t0\t-900\t0\t3\n", "TYPE_GYROSCOPE"),
    ("1574559498000\tTYPE_MAGNETIC_FIELD\t0\t1e9\t0\t3\n", "TYPE_MAGNETIC_FIELD"),
    ("1574559498000\tTYPE_PRESSURE\t-3\t3\n", "TYPE_PRESSURE"),
    ("-1574559498000\tTYPE_WAYPOINT\t1.0\t2.0\n", "TYPE_WAYPOINT"),
    ("1574559498000\tTYPE_WAYPOINT\t1e12\t2.0\n", "TYPE_WAYPOINT"),
    ("9974559498000\tTYPE_GYROSCOPE\t0\t0\t0\t3\n", "TYPE_GYROSCOPE"),  # the year 2286
])
def test_values_outside_their_physical_range_are_bad_rows(tmp_path, bad_line, kind):
    path = _write(tmp_path / "log.txt", ILC_HEADER + ILC_GOOD + bad_line)
    warnings = []
    rec = read_ilc(path, warn=warnings.append)
    assert rec.read_report.bad_rows == {kind: 1} and "out of range" in warnings[0]
    assert rec.waypoint_t_s.size == 2 and rec.acc_t_s.size == 1 and rec.gyro_t_s.size == 1
    if kind in NEEDED_TYPES:  # the magnetometer is used by no stage: never refused
        with pytest.raises(MapfilterError, match="out of range"):
            read_ilc(path, strict=True)


def test_a_duplicated_waypoint_counts_once(tmp_path):
    lines = ILC_GOOD.splitlines(keepends=True)
    rec = read_ilc(_write(tmp_path / "log.txt", ILC_HEADER + ILC_GOOD + lines[0] + lines[4] + lines[1]),
                   warn=lambda m: None)
    assert rec.waypoint_t_s.size == 2 and rec.acc_t_s.size == 1
    # the last waypoint and the accelerometer row again, at their stream's last time: duplicates;
    # the first waypoint again, earlier than the last kept one: it went back in time
    assert rec.read_report.duplicates == {"TYPE_WAYPOINT": 1, "TYPE_ACCELEROMETER": 1}
    assert rec.read_report.went_back == {"TYPE_WAYPOINT": 1}
    # a log written twice over is the log once
    twice = read_ilc(_write(tmp_path / "twice.txt", ILC_HEADER + ILC_GOOD * 2), warn=lambda m: None)
    np.testing.assert_array_equal(twice.waypoint_xy_m, read_ilc(_write(tmp_path / "once.txt",
                                                                       ILC_HEADER + ILC_GOOD)).waypoint_xy_m)


def test_a_wifi_row_years_ahead_is_a_reported_gap_not_a_long_walk(tmp_path):
    three_years_ms = int(3 * 365.25 * 86400 * 1000)
    ahead = f"{1574559497191 + three_years_ms}\tTYPE_WIFI\tnet\tb8:0c:ca:03:9d:d7\t-60\t2412\t{1574559497191 + three_years_ms}\n"
    warnings = []
    rec = read_ilc(_write(tmp_path / "log.txt", ILC_HEADER + ILC_GOOD + ahead), warn=warnings.append)
    gaps = rec.read_report.time_gaps_s
    assert len(gaps) == 1 and gaps[0][1] - gaps[0][0] > 3 * 365 * 86400
    assert len(warnings) == 1 and "1 time gap with no record (1095.7 days, from 4.0 s into the log)" in warnings[0]
    # nothing is filled in: the recording holds the rows the file holds
    assert len(rec.wifi) == 2 and rec.acc_t_s.size == 1


def test_a_thirty_day_gap_in_a_getsensordata_log_is_reported(tmp_path):
    later = IPIN_GOOD.replace("ACCE;0.0448", f"ACCE;{30 * 86400 + 0.0448}")
    path = _write(tmp_path / "log.txt", IPIN_HEADER + IPIN_GOOD + later.splitlines(keepends=True)[0])
    warnings = []
    rec = read_log(path, warn=warnings.append)
    assert rec.acc_t_s.size == 2 and len(rec.read_report.time_gaps_s) == 1
    assert "1 time gap with no record (30.0 days" in warnings[0]


def test_check_reports_format_phone_and_gaps_in_one_line(tmp_path, capsys):
    three_years_ms = int(3 * 365.25 * 86400 * 1000)
    ahead = f"{1574559497191 + three_years_ms}\tTYPE_WIFI\tnet\tb8:0c:ca:03:9d:d7\t-60\t2412\t{1574559497191 + three_years_ms}\n"
    ilc = _write(tmp_path / "ilc.txt", ILC_HEADER + ILC_GOOD + ahead)
    ipin = _write(tmp_path / "ipin.txt.gz", IPIN_HEADER + IPIN_GOOD, gz=True)
    assert main(["check", str(ilc), str(ipin)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 3
    assert out[0].startswith(f"{ilc}: ILC 2.0, phone PBCM10, floor F1") and "1 time gap" in out[0]
    assert out[1].startswith(f"{ipin}: GetSensorData, phone ?, floor 0") and "(lat/lon)" in out[1]
    assert "1 with time gaps" in out[2]


def test_the_format_is_told_by_content(tmp_path):
    ilc = _write(tmp_path / "a.log", ILC_HEADER + ILC_GOOD)
    ipin = _write(tmp_path / "b.txt.gz", IPIN_HEADER + IPIN_GOOD, gz=True)
    headerless = _write(tmp_path / "c.txt", IPIN_GOOD)
    assert log_format(ilc) == "ILC 2.0" and log_format(ipin) == "GetSensorData" and log_format(headerless) == "GetSensorData"
    assert read_log(ilc).read_report.format == "ILC 2.0" and read_log(ipin).read_report.format == "GetSensorData"
    assert read_log_header(ilc)["FloorName"] == "F1" and read_log_header(ipin)["FloorName"] == "0"
    for text in ("t,x,y\n1,2,3\n", "\x00\x01binary\xff" * 100):
        other = _write(tmp_path / "other.txt", text)
        with pytest.raises(MapfilterError, match=r"unknown log format \(.*\): the known formats are ILC 2.0") as caught:
            read_log(other)
        assert str(caught.value).startswith(f"{other}: ") and "GetSensorData" in str(caught.value)
        assert "\n" not in str(caught.value)
    with pytest.raises(MapfilterError, match="empty log"):
        read_log(_write(tmp_path / "empty.txt", "\n\n"))
    with pytest.raises(MapfilterError, match="not found"):
        read_log(tmp_path / "missing.txt")
