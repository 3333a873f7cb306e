"""The ILC trace reader on a real walk and on hand-written good and malformed logs."""

import gzip

import numpy as np
import pytest

from mapfilter.errors import MapfilterError
from mapfilter.sensors.ilc import LogReadWarning, read_ilc
from mapfilter.sensors.wifi import scans_of


def test_reads_a_real_trace_with_stale_rows_dropped(ilc_site1):
    path = sorted((ilc_site1 / "F1" / "path_data_files").glob("*.txt.gz"))[0]
    everything = read_ilc(path, max_wifi_age_s=np.inf)
    fresh = read_ilc(path)
    assert fresh.floor_name == "F1"
    assert fresh.waypoint_xy_m.shape[0] >= 8
    assert fresh.acc_mps2.shape[1] == 3 and np.all(np.diff(fresh.acc_t_s) >= 0)
    assert 0 < fresh.wifi.row_ap.size < everything.wifi.row_ap.size
    assert np.all(fresh.wifi.age_s <= 5.0)

HEADER = "#\tstartTime:1574559495255\n#\tSiteID:x\tFloorName:F1\n"
GOOD = (
    "1574559495263\tTYPE_WAYPOINT\t81.3\t93.3\n"
    "1574559495401\tTYPE_ACCELEROMETER\t-0.85\t1.82\t9.83\t2\n"
    "1574559495401\tTYPE_GYROSCOPE\t-0.39\t-0.08\t0.09\t3\n"
    "1574559497191\tTYPE_WIFI\tnet\ta8:0c:ca:03:9d:d7\t-49\t2422\t1574559496450\n"
    "1574559497191\tTYPE_WIFI\tnet\ta8:0c:ca:03:9d:d7\t-60\t2437\t1574559496450\n"  # same BSSID, same band: weaker
    "1574559497191\tTYPE_WIFI\tnet\ta8:0c:ca:03:9d:d7\t-70\t5180\t1574559496450\n"  # same BSSID, 5 GHz: own key
    "1574559497191\tTYPE_WIFI\tnet\tb8:0c:ca:03:9d:d7\t-55\t2412\t1574559480000\n"  # 17 s old: stale
    "1574559498000\tTYPE_BLUETOOTH_LE\twhatever\n"  # unknown type: skipped
)


def _write(tmp_path, text, name="log.txt"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_reader_groups_scans_keys_bands_and_drops_stale_rows(tmp_path):
    rec = read_ilc(_write(tmp_path, HEADER + GOOD))
    assert rec.floor_name == "F1" and rec.start_t_s == pytest.approx(1574559495.255)
    np.testing.assert_allclose(rec.waypoint_xy_m, [[81.3, 93.3]])
    assert len(rec.wifi) == 1
    keys, rssi = rec.wifi.scan(0)
    assert dict(zip(keys, rssi.tolist())) == {"a8:0c:ca:03:9d:d7@2.4": -49.0, "a8:0c:ca:03:9d:d7@5": -70.0}


def test_gzip_reads_like_plain(tmp_path):
    path = tmp_path / "log.txt.gz"
    with gzip.open(path, "wt") as handle:
        handle.write(HEADER + GOOD)
    assert read_ilc(path).wifi.ap_keys == read_ilc(_write(tmp_path, HEADER + GOOD)).wifi.ap_keys


@pytest.mark.parametrize("bad_line, message", [
    ("1574559499000\tTYPE_ACCELEROMETER\t0.1\t0.2\n", "fields"),  # truncated
    ("1574559499000\tTYPE_GYROSCOPE\tnan\t0.2\t0.3\t3\n", "not finite"),
    ("1574559499000\tTYPE_WIFI\tnet\tc8:0c:ca:03:9d:d7\tstrong\t2412\t1574559499000\n", "not a number"),
    ("1574559499000\tTYPE_WAYPOINT\t1.0\n", "fields"),
])
def test_bad_row_in_a_needed_type_is_refused_with_strict_naming_file_and_line(tmp_path, bad_line, message):
    path = _write(tmp_path, HEADER + GOOD + bad_line)
    bad_line_no = (HEADER + GOOD).count("\n") + 1
    with pytest.raises(MapfilterError, match=message) as caught:
        read_ilc(path, strict=True)
    assert str(caught.value).startswith(f"{path}:{bad_line_no}: ")
    # without --strict the row is skipped, counted and named once; the good rows are kept
    warnings = []
    rec = read_ilc(path, warn=warnings.append)
    kind = bad_line.split("\t")[1]
    assert rec.read_report.bad_rows == {kind: 1}
    assert len(warnings) == 1 and kind in warnings[0] and f"line {bad_line_no}" in warnings[0]
    assert "needed" in warnings[0] and warnings[0].startswith(str(path))
    assert rec.waypoint_xy_m.shape == (1, 2) and len(rec.wifi) == 1 and rec.acc_mps2.shape == (1, 3)


def test_empty_file_and_missing_file(tmp_path):
    with pytest.raises(MapfilterError, match="empty log"):
        read_ilc(_write(tmp_path, ""))
    with pytest.raises(MapfilterError, match="not found"):
        read_ilc(tmp_path / "missing.txt")


def test_log_without_wifi_reads_but_has_no_scans(tmp_path):
    rec = read_ilc(_write(tmp_path, HEADER + "".join(l for l in GOOD.splitlines(True) if "WIFI" not in l)))
    assert len(rec.wifi) == 0 and rec.acc_mps2.shape == (1, 3)
    with pytest.raises(MapfilterError, match="no usable WiFi"):
        scans_of(rec)


def test_corrupted_gzip_is_one_error_naming_the_file(tmp_path):
    path = tmp_path / "log.txt.gz"
    with gzip.open(path, "wt") as handle:
        handle.write(HEADER + GOOD * 50)
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF  # flip bits in the middle of the deflate stream
    path.write_bytes(bytes(data))
    with pytest.raises(MapfilterError) as caught:
        read_ilc(path)
    assert str(path) in str(caught.value)


# A beacon row as Android writes it when it has no distance estimate (seen in real ILC logs).
INFINITY_BEACON = ("1574559497300\tTYPE_BEACON\tfda50693-a4e2-4fb1-afcf-c6eb07647825\t10073\t61418\t-65"
                   "\t-79\tInfinity\t00:ab:cd:ef:01:02\t1574559497300\n")


@pytest.mark.parametrize("bad_value", ["Infinity", "NaN", "-Infinity", "nan"])
def test_non_finite_row_in_an_unused_type_is_skipped_even_with_strict(tmp_path, bad_value):
    path = _write(tmp_path, HEADER + GOOD + INFINITY_BEACON.replace("Infinity", bad_value) * 3)
    for strict in (False, True):
        warnings = []
        rec = read_ilc(path, strict=strict, warn=warnings.append)
        assert rec.read_report.bad_rows == {"TYPE_BEACON": 3}
        assert rec.beacons.t_s.size == 0 and len(rec.wifi) == 1
        assert len(warnings) == 1 and "3 bad TYPE_BEACON rows (not used" in warnings[0]
        assert "not finite" in warnings[0]


def test_nan_in_a_needed_type_is_skipped_by_default_and_refused_with_strict(tmp_path):
    path = _write(tmp_path, HEADER + GOOD + "1574559499000\tTYPE_ACCELEROMETER\tNaN\t0.2\t9.8\t3\n")
    with pytest.warns(LogReadWarning, match="1 bad TYPE_ACCELEROMETER row .needed; first at line 11"):
        assert read_ilc(path).acc_mps2.shape == (1, 3)
    with pytest.raises(MapfilterError, match=r":11: malformed TYPE_ACCELEROMETER line: column 3 is not finite"):
        read_ilc(path, strict=True)


def test_joined_lines_are_split_back_into_their_records(tmp_path):
    lines = GOOD.splitlines(keepends=True)
    # a missing newline: the accelerometer's accuracy "2" runs into the gyroscope row's time
    joined = "".join(lines[:1]) + lines[1].rstrip("\n") + lines[2] + "".join(lines[3:])
    # and a WiFi row whose last-seen time runs into the next WiFi row's time (26 digits)
    joined = joined.replace("1574559496450\n1574559497191\tTYPE_WIFI\tnet\tb8", "15745594964501574559497191\tTYPE_WIFI\tnet\tb8")
    assert joined.count("\n") == GOOD.count("\n") - 2
    rec = read_ilc(_write(tmp_path, HEADER + joined, "joined.txt"), max_wifi_age_s=np.inf, strict=True)
    ref = read_ilc(_write(tmp_path, HEADER + GOOD), max_wifi_age_s=np.inf)
    assert rec.read_report.joined_lines == 2 and rec.read_report.clean
    assert rec.read_report.rows == ref.read_report.rows
    np.testing.assert_array_equal(rec.gyro_radps, ref.gyro_radps)
    np.testing.assert_array_equal(rec.gyro_t_s, ref.gyro_t_s)
    np.testing.assert_array_equal(rec.acc_mps2, ref.acc_mps2)
    assert rec.wifi.ap_keys == ref.wifi.ap_keys
    np.testing.assert_array_equal(rec.wifi.age_s, ref.wifi.age_s)


def _truncated_gzip(tmp_path, text, keep_fraction=0.6):
    path = tmp_path / "cut.txt.gz"
    with gzip.open(path, "wt") as handle:
        handle.write(text)
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep_fraction)])
    return path


def test_truncated_gzip_keeps_the_complete_lines_before_the_cut(tmp_path):
    # x counts the rows (within an accelerometer's range), so that every kept row can be checked
    body = "".join(f"{1574559495401 + 20 * i}\tTYPE_ACCELEROMETER\t{i % 150}.25\t1.5\t9.75\t3\n" for i in range(20000))
    path = _truncated_gzip(tmp_path, HEADER + GOOD + body)
    warnings = []
    rec = read_ilc(path, warn=warnings.append)
    kept = rec.acc_mps2.shape[0]
    assert 2 < kept < 20001
    # every row kept is exactly as written: no half line slipped through at the cut
    np.testing.assert_array_equal(rec.acc_mps2[1:, 0], np.arange(kept - 1) % 150 + 0.25)
    assert rec.read_report.truncated_after_line == kept + GOOD.count("\n") - 1 + HEADER.count("\n")
    assert len(warnings) == 1 and "gzip stream ends early" in warnings[0]
    with pytest.raises(MapfilterError, match="truncated") as caught:
        read_ilc(path, strict=True)
    assert str(path) in str(caught.value)


def test_nothing_usable_left_is_one_error_naming_the_file(tmp_path):
    path = _write(tmp_path, HEADER + INFINITY_BEACON + "1574559499000\tTYPE_WIFI\tnet\n")
    with pytest.raises(MapfilterError, match="no usable record") as caught:
        read_ilc(path)
    assert str(caught.value).startswith(f"{path}: ") and "\n" not in str(caught.value)
    with pytest.raises(MapfilterError, match="no usable record"):
        read_ilc(_truncated_gzip(tmp_path, HEADER * 5000 + GOOD, keep_fraction=0.3))
