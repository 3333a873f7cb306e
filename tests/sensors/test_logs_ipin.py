"""The GetSensorData (IPIN) reader on the 29 real logs of IPIN 2023 and on hand-written logs."""

import gzip
from collections import Counter

import numpy as np
import pytest

from mapfilter.errors import MapfilterError
from mapfilter.maps.building import Building, Floor
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.georef import LocalFrame
from mapfilter.sensors import pdr
from mapfilter.sensors.ipin import read_ipin, read_ipin_header
from mapfilter.sensors.logs import localise, read_log


def _raw(path):
    """A plain second reading of a log: rows per type, POSI floors, distinct WIFI AppTimestamps, phone."""
    counts, floors, wifi_times, model = Counter(), [], set(), None
    with gzip.open(path, "rt") as handle:
        for line in handle:
            if line.startswith("%"):
                if "Model:" in line:
                    model = line.split(":", 1)[1].strip()
                continue
            fields = line.rstrip("\n").split(";")
            counts[fields[0]] += 1
            if fields[0] == "POSI":
                floors.append(fields[5])
            if fields[0] == "WIFI":
                wifi_times.add(fields[1])
    return counts, floors, wifi_times, model


def _logs(root):
    paths = sorted((root / "logs").glob("*.txt.gz"))
    assert len(paths) == 29
    return paths


@pytest.mark.slow
def test_every_real_log_reads_whole(ipin2023):
    for path in _logs(ipin2023):
        counts, floors, wifi_times, model = _raw(path)
        warnings = []
        rec = read_ipin(path, max_wifi_age_s=np.inf, warn=warnings.append)
        report = rec.read_report
        assert warnings == [] and report.clean and report.format == "GetSensorData", path
        for kind in ("ACCE", "GYRO", "MAGN", "AHRS", "PRES", "WIFI", "POSI", "BLE4"):
            assert report.rows.get(kind, 0) == counts[kind], (path, kind)
        assert report.unknown_rows == sum(counts[k] for k in ("GNSS", "LIGH", "SOUN", "PROX"))
        # ground truth: every POSI point, its floor, in time order, lat/lon in the venue
        assert rec.waypoint_t_s.size == counts["POSI"] and list(rec.waypoint_floor) == floors
        assert np.all(np.diff(rec.waypoint_t_s) > 0)
        assert np.all(np.abs(rec.waypoint_latlon_deg - [49.4612, 11.1112]) < 0.002)
        assert np.isnan(rec.waypoint_xy_m).all() and rec.needs_georeference
        assert rec.floor_name == (floors[0] if len(set(floors)) == 1 else None)
        # one scan per AppTimestamp; APs keyed by BSSID and band
        assert len(rec.wifi) == len(wifi_times)
        assert all(k.rsplit("@", 1)[1] in ("2.4", "5") for k in rec.wifi.ap_keys)
        assert rec.phone_model == model and rec.phone_model in ("SM-A520F", "SM-G930F")
        # one clock: IMU, barometer, WiFi and ground truth within the log's span from its start
        for t in (rec.acc_t_s, rec.gyro_t_s, rec.rotvec_t_s, rec.pressure_t_s, rec.wifi.t_s, rec.waypoint_t_s):
            assert np.all(np.diff(t) >= 0) and t[0] >= rec.start_t_s - 1.0 and t[-1] < rec.start_t_s + 400
        assert 970.0 < rec.pressure_hpa.min() and rec.pressure_hpa.max() < 990.0


def test_default_reading_drops_no_fresh_wifi_row(ipin2023):
    # the WiFi sensor times are on the IMU's boot clock: every row of these logs is under 1 s old
    path = _logs(ipin2023)[0]
    rec = read_ipin(path)
    assert rec.wifi.row_ap.size == rec.read_report.rows["WIFI"]
    assert 0.0 <= rec.wifi.age_s.min() and rec.wifi.age_s.max() < 1.0


def test_header_names_the_floor_of_one_floor_logs_only(ipin2023):
    paths = _logs(ipin2023)
    header = read_ipin_header(paths[0])
    assert header["FloorName"] == "0" and header["Model"] == "SM-A520F" and header["format"] == "GetSensorData"
    assert "FloorName" not in read_ipin_header(paths[-1])  # trial 52: floors 0 and -2


def test_barometer_of_the_multi_floor_walk_separates_its_floors(ipin2023):
    rec = read_ipin(ipin2023 / "logs" / "IPIN2023_T3_TrainingTrial52_repetition01.txt.gz")
    height = 44330.8 * (1.0 - (rec.pressure_hpa / rec.pressure_hpa[0]) ** (1.0 / 5.25588))
    at = np.array([height[np.abs(rec.pressure_t_s - t) < 1.0].mean() for t in rec.waypoint_t_s])
    floors = np.array([int(f) for f in rec.waypoint_floor])
    assert set(floors) == {0, -2}
    # every floor-0 point is higher than every floor-(-2) point, by two storeys of 2-4 m
    assert at[floors == 0].min() > at[floors == -2].max()
    drop = at[floors == 0].mean() - at[floors == -2].mean()
    assert 4.0 < drop < 8.0


def test_ahrs_quaternion_gives_the_heading_pdr_expects(ipin2023):
    """AHRS columns 7-9 are the rotation vector (device -> ENU): on turns its heading change
    follows the gyro's, and its heading follows the walking direction between POSI points."""
    frame = LocalFrame(49.46115181, 11.11114911)
    slopes, legs = [], []
    for path in _logs(ipin2023)[::4]:
        rec = read_ipin(path)
        trace = pdr.imu_trace(rec)
        known = np.isfinite(trace.abs_heading_rad)  # none before the rotation vector's first sample
        gyro = trace.heading_rad[known]
        absolute = np.unwrap(trace.abs_heading_rad[known])
        k = int(round(2.0 * pdr.SAMPLE_RATE_HZ))
        d_gyro, d_abs = gyro[k:] - gyro[:-k], absolute[k:] - absolute[:-k]
        turns = np.abs(d_gyro) > 0.5
        slopes.append(np.median(d_abs[turns] / d_gyro[turns]))
        steps = pdr.detect_steps(rec)
        xy = frame.to_xy_m(rec.waypoint_latlon_deg)
        for i in range(len(xy) - 1):
            leg = xy[i + 1] - xy[i]
            on_leg = (steps.t_s > rec.waypoint_t_s[i]) & (steps.t_s <= rec.waypoint_t_s[i + 1])
            if np.hypot(*leg) > 8.0 and on_leg.sum() >= 5:
                walked = np.angle(np.mean(np.exp(1j * steps.abs_heading_rad[on_leg])))
                legs.append(np.angle(np.exp(1j * (walked - np.arctan2(leg[1], leg[0])))))
    # one of the eight (Trial23 repetition01) tumbles the phone for its first 35 s: the causal
    # gravity estimate lags the turns and its gyro heading with it (slope 0.5)
    assert sum(0.7 < s < 1.3 for s in slopes) >= len(slopes) - 1 and 0.8 < np.median(slopes) < 1.2, slopes
    assert len(legs) >= 8 and abs(np.degrees(np.median(legs))) < 20.0


# ---- hand-written logs -----------------------------------------------------------------------
HEADER = ("% LogFile created by the 'GetSensorData' App for Android.\n"
          "% Date of creation: Thu Jun 15 10:01:26 GMT+02:00 2023\n"
          "% Model:                   \tSM-TEST\n")
GOOD = (
    "ACCE;0.0448;2558.6338;-1.13967;6.03836;6.58426;3\n"
    "GYRO;0.0442;2558.6338;-0.05815;-0.34633;0.13078;3\n"
    "AHRS;0.0456;2558.6338;38.4;6.9;-157.5;0.12037100;-0.31112301;-0.92053300;3\n"
    "PRES;0.0429;2558.6124;980.0779;3\n"
    "ACCE;0.0465;2558.6538;-1.35516;6.11737;5.78696;3\n"
    "GYRO;0.0477;2558.6538;-0.63297;-0.41597;0.31282;3\n"
    "WIFI;1.2635;2559.8518;net;20:23:00:00:00:90;2437;-75\n"
    "WIFI;1.2635;2559.8518;semi;colon;20:23:00:00:00:91;5500;-80;\n"  # an SSID with ';', a trailing ';'
    "WIFI;3.5000;2562.1000;net;20:23:00:00:00:90;2437;-70\n"
    "BLE4;2.0;iBeacon;BE:AC:20:23:00:06;-98;0;1;6;11111111-1111-BEAC-2023-111111111111\n"
    "BLE4;2.5;Eddystone;BE:AC:20:23:00:07;-90;abcdef\n"
    "GNSS;0.1668;1686816087.2760;49.460948;11.110714;365.620;229.743;12.0;0.3;6;0\n"
    "POSI;1.0;1;49.460948188642;11.110539036217;0;100\n"
    "POSI;3.0;2;49.461013377334;11.110529162966;-02;100\n"
)


def _write(tmp_path, text, name="log.txt", gz=False):
    path = tmp_path / name
    if gz:
        with gzip.open(path, "wt") as handle:
            handle.write(text)
    else:
        path.write_text(text)
    return path


def test_a_hand_written_log_reads_every_record(tmp_path):
    rec = read_log(_write(tmp_path, HEADER + GOOD))
    start = 1686816086.0  # 10:01:26 at GMT+2
    assert rec.start_t_s == start and rec.phone_model == "SM-TEST"
    assert rec.read_report.format == "GetSensorData" and rec.read_report.clean
    np.testing.assert_allclose(rec.waypoint_t_s, [start + 1.0, start + 3.0])
    assert rec.waypoint_floor == ["0", "-2"] and rec.floor_name is None
    np.testing.assert_allclose(rec.waypoint_latlon_deg[1], [49.461013377334, 11.110529162966])
    # IMU on the sensor clock moved to the app clock: 20 ms apart, as the sensor says
    assert np.diff(rec.acc_t_s)[0] == pytest.approx(0.02, abs=1e-6)  # float64 at Unix times: ~2e-7 s
    np.testing.assert_allclose(rec.rotvec_xyz, [[0.120371, -0.31112301, -0.920533]])
    assert rec.pressure_hpa.tolist() == [980.0779]
    assert len(rec.wifi) == 2
    keys, rssi = rec.wifi.scan(0)
    assert dict(zip(keys, rssi.tolist())) == {"20:23:00:00:00:90@2.4": -75.0, "20:23:00:00:00:91@5": -80.0}
    assert rec.beacons.beacon_id == ["BE:AC:20:23:00:06", "BE:AC:20:23:00:07"]  # the MAC, iBeacon or Eddystone
    assert np.isnan(rec.beacons.distance_m).all()
    assert rec.read_report.unknown_rows == 1  # GNSS


def test_gzip_is_told_by_content_not_by_name(tmp_path):
    plain = read_log(_write(tmp_path, HEADER + GOOD, "plain.txt.gz"))  # named .gz, plain text
    packed = read_log(_write(tmp_path, HEADER + GOOD, "packed.txt", gz=True))  # gzip, named .txt
    assert plain.wifi.ap_keys == packed.wifi.ap_keys and plain.waypoint_floor == packed.waypoint_floor


@pytest.mark.parametrize("bad_line, kind, message", [
    ("ACCE;5.0;2563.0;0.1;0.2\n", "ACCE", "fields"),
    ("GYRO;5.0;2563.0;nan;0.2;0.3;3\n", "GYRO", "not finite"),
    ("WIFI;5.0;2563.0;net;20:23:00:00:00:92;2437;strong\n", "WIFI", "not a number"),
    ("WIFI;5.0;2563.0;net;20:23:00:00:00:92;2437;1e300\n", "WIFI", "RSSI out of range"),
    ("ACCE;5.0;2563.0;1e308;0.2;9.8;3\n", "ACCE", "out of range"),
    ("PRES;5.0;2563.0;5000;3\n", "PRES", "out of range"),
    ("POSI;5.0;3;95.0;11.1;0;100\n", "POSI", "latitude out of range"),
    ("POSI;-5.0;3;49.46;11.11;0;100\n", "POSI", "AppTimestamp out of range"),
    ("AHRS;5.0;2563.0;1;2;3;0.9;0.9;0.9;3\n", "AHRS", "unit quaternion"),
])
def test_bad_rows_are_skipped_and_named_or_refused_with_strict(tmp_path, bad_line, kind, message):
    path = _write(tmp_path, HEADER + GOOD + bad_line)
    line_no = (HEADER + GOOD).count("\n") + 1
    with pytest.raises(MapfilterError, match=message) as caught:
        read_ipin(path, strict=True)
    assert str(caught.value).startswith(f"{path}:{line_no}: ")
    warnings = []
    rec = read_ipin(path, warn=warnings.append)
    assert rec.read_report.bad_rows == {kind: 1}
    assert len(warnings) == 1 and f"1 bad {kind} row (needed; first at line {line_no}" in warnings[0]
    assert rec.waypoint_t_s.size == 2 and len(rec.wifi) == 2 and rec.acc_t_s.size == 2


def test_a_line_of_no_known_type_is_a_bad_row(tmp_path):
    path = _write(tmp_path, HEADER + GOOD + "garbage without a type\n")
    assert read_ipin(path, warn=lambda m: None).read_report.bad_rows == {"?": 1}
    with pytest.raises(MapfilterError, match="record type"):
        read_ipin(path, strict=True)


def test_duplicated_records_count_once(tmp_path):
    lines = GOOD.splitlines(keepends=True)
    warnings = []
    # the last POSI again (a duplicate: same time), then the first POSI and the first ACCE again:
    # earlier than their stream's last record, they went back in time
    rec = read_ipin(_write(tmp_path, HEADER + GOOD + lines[-1] + lines[-2] + lines[0]), warn=warnings.append)
    assert rec.waypoint_t_s.size == 2 and rec.acc_t_s.size == 2
    assert rec.read_report.duplicates == {"POSI": 1}
    assert rec.read_report.went_back == {"ACCE": 1, "POSI": 1}
    assert len(warnings) == 1 and "1 exact duplicate row (1 POSI)" in warnings[0]
    assert "2 rows that went back in time (1 ACCE, 1 POSI)" in warnings[0]


def test_localise_places_the_ground_truth_in_a_georeferenced_building(tmp_path):
    rec = read_log(_write(tmp_path, HEADER + GOOD))
    frame = LocalFrame(49.46115181, 11.11114911)
    plan = FloorPlan(np.zeros((400, 400), bool), 0.5, (-100.0, -100.0))
    building = Building([Floor("-2", plan, -8.0), Floor("0", plan, 0.0, offset_m=(10.0, 0.0))],
                        georeference=frame)
    placed = localise(rec, building)
    assert placed is not rec and np.isnan(rec.waypoint_xy_m).all()  # the input is not changed
    expected = frame.to_xy_m(rec.waypoint_latlon_deg)
    np.testing.assert_allclose(placed.waypoint_xy_m[0], expected[0] - [10.0, 0.0])  # floor 0's own frame
    np.testing.assert_allclose(placed.waypoint_xy_m[1], expected[1])
    assert not placed.needs_georeference
    np.testing.assert_allclose(read_log(rec.path, building=building).waypoint_xy_m, placed.waypoint_xy_m)
    with pytest.raises(MapfilterError, match="no georeference"):
        localise(rec, Building([Floor("0", plan), Floor("-2", plan)]))
    with pytest.raises(MapfilterError, match="floor '-2' is not in the building"):
        localise(rec, Building([Floor("0", plan), Floor("-1", plan)], georeference=frame))
