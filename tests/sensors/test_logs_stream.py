"""Logs read as streams (sensors/logs.LogStream): fed in any pieces, the chunks are the log read
whole, array by array; each record depends on the records before it only."""

import dataclasses
import gzip
import tracemalloc

import numpy as np
import pytest

from mapfilter.errors import MapfilterError
from mapfilter.sensors.ilc import read_ilc
from mapfilter.sensors.ipin import read_ipin
from mapfilter.sensors.logread import MAX_LINE_BYTES
from mapfilter.sensors.logs import LogStream, log_format, read_log
from mapfilter.sensors.recording import Recording, concatenate

_STREAMS = ("waypoint", "acc", "gyro", "magnet", "rotvec", "pressure")


def assert_same(a, b, where: str = "recording") -> None:
    """Every field equal: arrays in dtype, shape and every value (NaN where NaN), lists, header
    fields and the read report (dataclasses field by field)."""
    if isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape, where
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), where
    elif dataclasses.is_dataclass(a) and not isinstance(a, type):
        assert type(a) is type(b), where
        for field in dataclasses.fields(a):
            assert_same(getattr(a, field.name), getattr(b, field.name), f"{where}.{field.name}")
    else:
        assert a == b, where




def _records(recording: Recording, imu: bool = True) -> Recording:
    """The records only (no path or read report; without the IMU and barometer unless ``imu``)."""
    cut = {} if imu else {name: None for name in ("acc_t_s", "acc_mps2", "gyro_t_s", "gyro_radps", "magnet_t_s",
                                                     "magnet_ut", "rotvec_t_s", "rotvec_xyz", "pressure_t_s",
                                                     "pressure_hpa")}
    return dataclasses.replace(recording, path=None, read_report=None, **cut)


def random_pieces(data, rng: np.random.Generator, fine_prefix: int = 600):
    """``data`` cut at random places: byte by byte (or character by character) at first, where
    a header's multibyte characters are, then pieces of 1 byte to 64 KiB (log-uniform)."""
    pieces, start = [], 0
    while start < len(data):
        size = 1 if start < fine_prefix else int(np.exp(rng.uniform(0.0, np.log(65536.0))))
        pieces.append(data[start:start + size])
        start += size
    return pieces


def stream_pieces(pieces, name, feed="bytes", **options) -> Recording:
    stream = LogStream(name, **options)
    feed_piece = stream.feed_bytes if feed == "bytes" else stream.feed_text
    chunks = [feed_piece(piece) for piece in pieces]
    assert all(isinstance(c, Recording) and c.acc_t_s is not None for c in chunks)
    chunks.append(stream.close())
    return concatenate(chunks)


def _raw_bytes(path) -> bytes:
    with gzip.open(path, "rb") as handle:
        return handle.read()


def _real_ilc_logs(site1):
    f1 = sorted((site1 / "F1" / "path_data_files").glob("*.txt.gz"))
    f2_full = (site1 / "F2" / "full_set.txt").read_text().split()[0]
    return [f1[0], f1[len(f1) // 2], f1[-1], site1 / "F2" / "path_data_files" / f"{f2_full}.txt.gz"]


def _real_ipin_logs(root):
    # one log per phone model (the header's Model): SM-A520F, and SM-G930F over two floors
    logs = root / "logs"
    return [logs / "IPIN2023_T3_TrainingTrial01_repetition01.txt.gz",
            logs / "IPIN2023_T3_TrainingTrial52_repetition01.txt.gz"]


@pytest.mark.parametrize("index", range(4))
def test_a_real_ilc_log_streamed_in_random_pieces_is_the_log_read_whole(ilc_site1, index):
    path = _real_ilc_logs(ilc_site1)[index]
    whole = read_log(path, warn=lambda m: None)
    assert whole.acc_t_s.size > 500 and len(whole.wifi) > 5 and whole.beacons.t_s.size > 10
    data = _raw_bytes(path)
    assert len(data) > len(data.decode("utf-8"))  # multibyte characters (the site's name) to cut into
    rng = np.random.default_rng([7, index])
    assert_same(stream_pieces(random_pieces(data, rng), path), whole)
    text = data.decode("utf-8")
    assert_same(stream_pieces(random_pieces(text, rng), path, feed="text"), whole)


@pytest.mark.parametrize("index", range(2))
def test_a_real_ipin_log_streamed_in_random_pieces_is_the_log_read_whole(ipin2023, index):
    path = _real_ipin_logs(ipin2023)[index]
    whole = read_log(path, warn=lambda m: None)
    assert whole.phone_model == ("SM-A520F", "SM-G930F")[index] and whole.beacons.t_s.size > 10
    data = _raw_bytes(path)
    rng = np.random.default_rng([8, index])
    assert_same(stream_pieces(random_pieces(data, rng), path), whole)
    assert_same(stream_pieces(random_pieces(data.decode("utf-8"), rng), path, feed="text"), whole)


def test_half_second_batches_of_lines_as_a_competition_server_sends_them(ipin2023):
    path = _real_ipin_logs(ipin2023)[0]
    whole = read_log(path, warn=lambda m: None)
    lines = _raw_bytes(path).decode("utf-8").splitlines(keepends=True)
    stream = LogStream(path)
    chunks, batch, batch_end_s = [], [], None
    for line in lines:
        if not line.startswith("%") and line.strip():
            app_s = float(line.split(";")[1])
            batch_end_s = app_s + 0.5 if batch_end_s is None else batch_end_s  # from the first record
            if app_s > batch_end_s:
                chunks.append(stream.feed_lines(batch))
                batch, batch_end_s = [], batch_end_s + 0.5
        batch.append(line)
    chunks.append(stream.feed_lines(batch))
    chunks.append(stream.close())
    assert_same(concatenate(chunks), whole)
    # the first half second is held (for the clock offsets) and comes out with the next one
    assert chunks[0].acc_t_s.size == 0 and len(chunks[0].wifi) == 0
    assert chunks[1].acc_t_s.size > 0 and chunks[1].acc_t_s[0] == whole.acc_t_s[0]
    # each chunk: only what it completed, in time order after the chunk before
    for before, after in zip(chunks, chunks[1:]):
        for name in ("acc", "gyro", "rotvec", "pressure"):
            t0, t1 = getattr(before, f"{name}_t_s"), getattr(after, f"{name}_t_s")
            if t0.size and t1.size:
                assert t1[0] >= t0[-1]


@pytest.mark.slow
def test_no_record_of_the_real_logs_goes_back_in_time(ilc_site1, ipin2023):
    # every record type of the 191 ILC site-1 logs and the 29 IPIN 2023 logs is in time order:
    # file order within each type drops nothing
    paths = sorted(ilc_site1.glob("*/path_data_files/*.txt.gz")) + sorted((ipin2023 / "logs").glob("*.txt.gz"))
    assert len(paths) == 191 + 29
    for path in paths:
        report = read_log(path, warn=lambda m: None).read_report
        assert report.went_back == {} and report.duplicates == {} and report.clock_strays == {}, path


# ---- cutting a log -----------------------------------------------------------------------------

def _record_times(line: str, fmt: str) -> float | None:
    if not line.strip() or line[0] in "#%":
        return None
    fields = line.split("\t" if fmt == "ILC 2.0" else ";")
    return float(fields[0]) / 1000.0 if fmt == "ILC 2.0" else float(fields[1])


def _leading_part(part: Recording, whole: Recording) -> None:
    """Every stream of ``part`` is the first records of the same stream of ``whole``."""
    for name in _STREAMS:
        t, w = getattr(part, f"{name}_t_s"), getattr(whole, f"{name}_t_s")
        assert np.array_equal(t, w[:t.size]), name
    n = len(part.wifi)
    assert np.array_equal(part.wifi.t_s, whole.wifi.t_s[:n])
    assert part.wifi.row_ap.size == np.count_nonzero(whole.wifi.row_scan < n)
    b = part.beacons.t_s.size
    assert np.array_equal(part.beacons.t_s, whole.beacons.t_s[:b]) and part.beacons.beacon_id == whole.beacons.beacon_id[:b]


def _first_time_not_read(part: Recording, whole: Recording) -> float:
    """The earliest time of a record of ``whole`` that ``part`` does not hold."""
    times = [getattr(whole, f"{name}_t_s")[getattr(part, f"{name}_t_s").size:] for name in _STREAMS]
    times += [whole.wifi.t_s[len(part.wifi):], whole.beacons.t_s[part.beacons.t_s.size:]]
    return min(float(t.min()) for t in times if t.size)


@pytest.mark.parametrize("which", ["ilc", "ipin"])
def test_the_log_cut_where_time_passes_t_reads_as_the_whole_logs_records_up_to_t(ilc_site1, ipin2023, which):
    path = _real_ilc_logs(ilc_site1)[0] if which == "ilc" else _real_ipin_logs(ipin2023)[0]
    whole = read_log(path, warn=lambda m: None)
    fmt = whole.read_report.format
    lines = _raw_bytes(path).decode("utf-8").splitlines(keepends=True)
    times = [_record_times(line, fmt) for line in lines]
    first, last = min(t for t in times if t is not None), max(t for t in times if t is not None)
    cut_s = first + 0.5 * (last - first)  # T, on the log's own clock
    cut = next(i for i, t in enumerate(times) if t is not None and t > cut_s)
    part = read_log_text("".join(lines[:cut]), path)
    _leading_part(part, whole)
    # every record up to the earliest time written after the cut is read, as in the whole log
    safe_s = _first_time_not_read(part, whole)
    assert_same(_records(part.until(safe_s - 1e-6)), _records(whole.until(safe_s - 1e-6)))
    base_s = whole.start_t_s if which == "ipin" else 0.0
    if which == "ipin":
        # the AppTimestamp clock is the log's: only the IMU, on the sensor clock, is a few ms short of T
        assert base_s + cut_s - safe_s < 0.05
        assert_same(_records(part.until(base_s + cut_s), imu=False), _records(whole.until(base_s + cut_s), imu=False))
    else:
        # the ILC logger writes IMU rows, beacons and waypoints seconds after rows of later time
        assert 0.0 < cut_s - safe_s < 13.0
    # the WiFi scans up to T are all there, each whole: a scan's rows never straddle the cut
    assert_same(part.wifi.until(base_s + cut_s), whole.wifi.until(base_s + cut_s))


def read_log_text(text: str, name) -> Recording:
    stream = LogStream(name)
    return concatenate([stream.feed_text(text), stream.close()])


# ---- hand-written logs -------------------------------------------------------------------------
T0 = 1574559495000


def _ilc_walk(seconds: int = 60, jump_back_at_s: float | None = None) -> str:
    """An ILC log: IMU at 50 Hz, a WiFi scan every 2 s, a waypoint every 10 s. With
    ``jump_back_at_s``, the IMU clock jumps back 20 s there (the WiFi and waypoints do not)."""
    lines = ["#\tstartTime:1574559495000\n", "#\tSiteID:x\tFloorName:F1\n", "#\tBrand:OPPO\tModel:PBCM10\n"]
    for k in range(seconds * 50):
        t_ms = T0 + 20 * k
        imu_ms = t_ms - 20000 if jump_back_at_s is not None and k >= jump_back_at_s * 50 else t_ms
        lines.append(f"{imu_ms}\tTYPE_ACCELEROMETER\t{np.sin(k / 7):.4f}\t0.25\t9.75\t3\n")
        lines.append(f"{imu_ms}\tTYPE_GYROSCOPE\t0.01\t{np.cos(k / 5):.4f}\t0.02\t3\n")
        lines.append(f"{imu_ms}\tTYPE_ROTATION_VECTOR\t0.01\t0.02\t{0.5 + 0.1 * np.sin(k / 50):.4f}\t3\n")
        if k % 100 == 50:
            for ap in range(4):
                lines.append(f"{t_ms}\tTYPE_WIFI\tnet\taa:bb:cc:dd:ee:{ap:02x}\t{-50 - 5 * ap - k % 7}\t2412\t{t_ms - 300}\n")
        if k % 500 == 0:
            lines.append(f"{t_ms}\tTYPE_WAYPOINT\t{k / 50:.2f}\t5.0\n")
    return "".join(lines)


def test_an_imu_clock_that_jumps_back_20_s_drops_what_went_back_with_a_warning(tmp_path):
    path = tmp_path / "jump.txt"
    path.write_text(_ilc_walk(60, jump_back_at_s=30.0))
    warnings = []
    rec = read_ilc(path, warn=warnings.append)
    # the samples after the jump first repeat times already read (behind their own stream), then
    # run 20 s behind the WiFi and the waypoints (behind the log's clock, logread.LogClock): a live
    # run would have moved on without them, so a whole read drops them too, and no sample is out
    # of order
    for t in (rec.acc_t_s, rec.gyro_t_s, rec.rotvec_t_s):
        assert np.all(np.diff(t) > 0) and t[-1] < T0 / 1000 + 30
    for t in (rec.wifi.t_s, rec.waypoint_t_s):
        assert np.all(np.diff(t) > 0)
    dropped = 30 * 50
    assert rec.read_report.went_back == {k: dropped for k in ("TYPE_ACCELEROMETER", "TYPE_GYROSCOPE",
                                                              "TYPE_ROTATION_VECTOR")}
    assert rec.read_report.duplicates == {} and len(rec.wifi) == 30 and rec.waypoint_t_s.size == 6
    assert rec.acc_t_s.size == 60 * 50 - dropped
    assert len(warnings) == 1 and f"skipped {3 * dropped} rows that went back in time" in warnings[0]


def test_a_getsensordata_sensor_clock_that_jumps_back_20_s_is_placed_at_the_app_clock(tmp_path):
    lines = ["% LogFile created by the 'GetSensorData' App for Android.\n"]
    for k in range(3000):
        app_s = 0.02 * k + 0.003 * (k % 3)  # read in bursts
        sensor_s = 1000.0 + 0.02 * k - (20.0 if k >= 1500 else 0.0)
        lines.append(f"ACCE;{app_s:.4f};{sensor_s:.4f};0.1;0.2;9.8;3\n")
        lines.append(f"GYRO;{app_s:.4f};{sensor_s:.4f};0.01;0.02;0.03;3\n")
        if k % 100 == 50:
            lines.append(f"WIFI;{app_s:.4f};{sensor_s - 0.2:.4f};net;20:23:00:00:00:90;2437;-70\n")
    path = tmp_path / "jump.txt"
    path.write_text("".join(lines))
    warnings = []
    rec = read_ipin(path, warn=warnings.append)
    assert rec.acc_t_s.size == 3000 and np.all(np.diff(rec.acc_t_s) > 0)
    assert np.all(np.diff(rec.wifi.t_s) > 0) and len(rec.wifi) == 30
    assert rec.read_report.clock_strays == {"ACCE": 1500, "GYRO": 1500}
    assert len(warnings) == 1 and "3000 samples off their sensor clock, placed at their AppTimestamp" in warnings[0]
    # the WiFi rows after the jump are 20 s off the accelerometer's clock: their scans' ages are unknown (0)
    assert np.all(rec.wifi.age_s[rec.wifi.row_scan >= 15] == 0.0)
    assert np.all(np.abs(rec.wifi.age_s[rec.wifi.row_scan < 15] - 0.2) < 0.01)


HOSTILE_ILC = (
    "#\tstartTime:1574559495255\n#\tSiteID:x\tSiteName:杭州西溪银泰城\tFloorName:F1\n#\tModel:PBCM10\r\n"
    "1574559495263\tTYPE_WAYPOINT\t81.3\t93.3\n"
    "1574559495401\tTYPE_ACCELEROMETER\t-0.85\t1.82\t9.83\t2\n"
    "1574559495401\tTYPE_ACCELEROMETER\t-0.85\t1.82\t9.83\t2\n"  # an exact duplicate
    "1574559495401\tTYPE_GYROSCOPE\t-0.39\t-0.08\t0.09\t31574559495421\tTYPE_GYROSCOPE\t-0.3\t-0.1\t0.1\t3\n"  # joined
    "1574559495430\tTYPE_ACCELEROMETER\tnan\t1.82\t9.83\t2\n"  # a bad row
    "1574559495441\tTYPE_ACCELEROMETER\t-0.8\t1.8\t9.8\t2\r\n"
    "1574559495300\tTYPE_ACCELEROMETER\t-0.7\t1.7\t9.7\t2\n"  # went back in time
    "1574559497191\tTYPE_WIFI\tcafé ☕\ta8:0c:ca:03:9d:d7\t-49\t2422\t1574559496450\n"
    "1574559497191\tTYPE_WIFI\tnet\ta8:0c:ca:03:9d:d7\t-60\t2437\t1574559496450\n"
    "1574559497191\tTYPE_WIFI\tnet\tb8:0c:ca:03:9d:d7\t-55\t2412\t1574559480000\n"  # stale
    "1574559497200\tTYPE_BEACON\tfda50693\t10073\t61418\t-65\t-79\t2.5\te0:78:a3:3d:a8:f0\t1574559497200\n"
    "1574559497250\tTYPE_BEACON\tfda50693\t10073\t61418\t-65\t-79\tInfinity\te0:78:a3:3d:a8:f0\t1574559497250\n"
    "1574559497300\tTYPE_BEACON\tfda50693\t10073\t61418\t-65\t-81\t3.0\n"  # no MAC
    "\udcff\udcfe broken UTF-8\n"  # two bytes that are not UTF-8 (written as such below)
    + "1574559497400\tTYPE_WIFI\tnet\t" + "7" * (MAX_LINE_BYTES + 10) + "\n"  # over-long
    + "1574559498191\tTYPE_WIFI\tnet\ta8:0c:ca:03:9d:d7\t-50\t2422\t1574559498000\n"
    "1574559497191\tTYPE_WIFI\tnet\tc8:0c:ca:03:9d:d7\t-50\t2422\t1574559497191\n"  # after its scan: went back
    "1574559499263\tTYPE_WAYPOINT\t85.3\t93.3\n"
    "1674559499263\tTYPE_WAYPOINT\t85.3\t93.3\n"  # three years ahead: a gap
    "1574559499500\tTYPE_ACCELEROMETER\t-0.8\t1.8\t9.8\t2"  # the last line, without newline
)


def test_a_hostile_ilc_log_streamed_in_any_pieces_is_the_log_read_whole(tmp_path):
    path = tmp_path / "hostile.txt"
    path.write_bytes(HOSTILE_ILC.encode("utf-8", errors="surrogateescape"))
    whole = read_log(path, warn=lambda m: None)
    report = whole.read_report
    assert report.duplicates == {"TYPE_ACCELEROMETER": 1}
    assert report.went_back == {"TYPE_ACCELEROMETER": 1, "TYPE_WIFI": 1}
    assert report.joined_lines == 1 and len(report.time_gaps_s) == 1
    assert report.bad_rows == {"TYPE_ACCELEROMETER": 1, "TYPE_BEACON": 1, "?": 2}
    assert whole.acc_t_s.tolist() == [1574559495.401, 1574559495.441, 1574559499.5]
    assert whole.gyro_t_s.size == 2 and whole.waypoint_t_s.size == 3
    assert whole.beacons.beacon_id == ["E0:78:A3:3D:A8:F0", "fda50693:10073:61418"]
    assert len(whole.wifi) == 2 and whole.wifi.ap_keys == ["a8:0c:ca:03:9d:d7@2.4"]
    assert whole.floor_name == "F1" and whole.phone_model == "PBCM10"
    data = path.read_bytes()
    for seed in range(5):
        assert_same(stream_pieces(random_pieces(data, np.random.default_rng(seed)), path), whole)
    # in one piece, line by line, and byte by byte but for the over-long line
    assert_same(stream_pieces([data], path), whole)
    lines = data.splitlines(keepends=True)
    assert_same(stream_pieces(lines, path), whole)
    assert_same(stream_pieces([b for line in lines for b in ([line] if len(line) > 1000 else
                                                             [line[i:i + 1] for i in range(len(line))])], path), whole)


_IMU = [f"ACCE;{0.02 * k + 0.001:.4f};{2558.6 + 0.02 * k:.4f};0.1;0.2;9.8;3\n"
        f"GYRO;{0.02 * k + 0.002:.4f};{2558.6 + 0.02 * k:.4f};0.01;0.02;0.03;3\n" for k in range(60)]
HOSTILE_IPIN = (
    "% LogFile created by the 'GetSensorData' App for Android.\n"
    "% Date of creation: Thu Jun 15 10:01:26 GMT+02:00 2023\n"
    "% Model:                   \tSM-TEST\n"
    + "".join(_IMU)
    + _IMU[-1].splitlines(keepends=True)[0]  # an exact duplicate of the last ACCE
    + "ACCE;1.1000;2559.7000;0.1;0.2;9.8;3\n"  # went back in time
    + "WIFI;1.2635;2559.8518;café;20:23:00:00:00:90;2437;-75\n"
    "WIFI;1.2635;2559.8518;semi;colon;20:23:00:00:00:91;5500;-80;\n"
    "WIFI;1.2635;2559.8518;café;20:23:00:00:00:90;2437;-75\n"  # a duplicate within the scan
    "WIFI;1.2635;2559.8518;net;20:23:00:00:00:92;2437;strong\n"  # a bad row
    "BLE4;1.3;iBeacon;be:ac:20:23:00:06;-98;0;1;6;11111111-1111-BEAC-2023-111111111111\n"
    "POSI;1.4;1;49.460948188642;11.110539036217;0;100\n"
    "garbage\n"
    "GNSS;1.5;1686816087.2760;49.460948;11.110714;365.620;229.743;12.0;0.3;6;0\n"
    "PRES;1.6;2560.0;980.0779;3\n"
    "WIFI;1.2635;2559.8518;late;20:23:00:00:00:93;2437;-70\n"  # after its scan was complete
    "POSI;3.0;2;49.461013377334;11.110529162966;-02;100"
)


def test_a_hostile_getsensordata_log_streamed_in_any_pieces_is_the_log_read_whole(tmp_path):
    path = tmp_path / "hostile.txt"
    path.write_text(HOSTILE_IPIN)
    whole = read_log(path, warn=lambda m: None)
    report = whole.read_report
    assert report.duplicates == {"ACCE": 1, "WIFI": 1}
    assert report.went_back == {"ACCE": 1, "WIFI": 1}
    assert report.bad_rows == {"WIFI": 1, "?": 1} and report.unknown_rows == 1
    assert whole.acc_t_s.size == 60 and len(whole.wifi) == 1 and whole.wifi.row_ap.size == 2
    assert whole.beacons.beacon_id == ["BE:AC:20:23:00:06"] and whole.waypoint_floor == ["0", "-2"]
    data = path.read_bytes()
    for seed in range(5):
        assert_same(stream_pieces(random_pieces(data, np.random.default_rng(seed)), path), whole)
    assert_same(stream_pieces(data.splitlines(keepends=True), path), whole)


def test_a_stream_holds_text_until_it_knows_the_format_and_scans_until_they_are_complete():
    stream = LogStream("phone")
    assert stream.format is None
    chunk = stream.feed_text("\n\n#\tstartTime:1574559495255\n#\tSiteID:x\tFloor")
    assert stream.format == "ILC 2.0" and chunk.floor_name is None  # the header line is not complete yet
    chunk = stream.feed_text("Name:F1\n1574559497191\tTYPE_WIFI\tnet\ta8:0c:ca:03:9d:d7\t-49\t2422\t1574559496450\n")
    assert chunk.floor_name == "F1" and len(chunk.wifi) == 0 and chunk.wifi.t_s.shape == (0,)
    assert chunk.acc_t_s.shape == (0,) and chunk.acc_mps2.shape == (0, 3)  # empty, never None
    # an IMU row of an earlier time does not complete the scan; one of a later time does
    chunk = stream.feed_text("1574559497000\tTYPE_ACCELEROMETER\t-0.85\t1.82\t9.83\t2\n")
    assert chunk.acc_t_s.tolist() == [1574559497.0] and len(chunk.wifi) == 0
    chunk = stream.feed_text("1574559497191\tTYPE_WIFI\tnet\tb8:0c:ca:03:9d:d7\t-60\t2412\t1574559496450\n"
                             "1574559497200\tTYPE_ACCELEROMETER\t-0.85\t1.82\t9.83\t2\n1574559497")
    assert len(chunk.wifi) == 1 and chunk.wifi.row_ap.size == 2 and chunk.acc_t_s.size == 1
    chunk = stream.close()  # the last line, without newline, is not a record: a bad row
    assert chunk.acc_t_s.size == 0 and stream.report.bad_rows == {"?": 1}
    assert chunk.read_report == stream.report and chunk.read_report is not stream.report
    with pytest.raises(ValueError, match="closed"):
        stream.feed_text("more")


def test_a_getsensordata_stream_holds_its_first_half_second_for_the_clock_offsets():
    stream = LogStream("-")
    held = stream.feed_text("% LogFile created by the 'GetSensorData' App for Android.\n"
                            + "".join(f"ACCE;{0.1 * k:.4f};{100.0 + 0.1 * k - 0.004 * (k % 2):.4f};0.1;0.2;9.8;3\n"
                                      for k in range(6)))
    assert stream.format == "GetSensorData" and held.acc_t_s.size == 0
    released = stream.feed_text("PRES;0.5001;100.5;980.0;3\n")  # the log's AppTimestamp passes 0.5 s
    assert released.acc_t_s.size == 6 and released.pressure_t_s.size == 0  # the barometer starts its own window
    # the median of (app - sensor) over the window: 0.002 s (six samples, three of each 0.0 and 0.004)
    np.testing.assert_allclose(released.acc_t_s, 0.1 * np.arange(6) - 0.004 * (np.arange(6) % 2) + 0.002,
                               rtol=0, atol=1e-9)
    rest = stream.close()
    assert rest.pressure_t_s == pytest.approx([0.5001], abs=1e-9)


def test_stream_errors_name_the_stream():
    with pytest.raises(MapfilterError, match="^-: empty log"):
        LogStream().close()
    stream = LogStream("stdin")
    stream.feed_text("t,x,y\n" * 199)
    with pytest.raises(MapfilterError, match=r"^stdin: unknown log format \(none of its first 200 lines shows one\): "
                                             "the known formats are ILC 2.0"):
        stream.feed_text("1,2,3\n")
    stream = LogStream("phone", strict=True)
    stream.feed_text("#\tFloorName:F1\n1574559495401\tTYPE_ACCELEROMETER\t0.1")
    with pytest.raises(MapfilterError, match="^phone:2: malformed TYPE_ACCELEROMETER line"):
        stream.feed_text("\t0.2\n")
    with pytest.raises(MapfilterError, match="^phone: no usable record"):
        stream = LogStream("phone")
        stream.feed_text("#\tFloorName:F1\n")
        stream.close()
    with pytest.raises(ValueError, match="unknown log format 'csv'"):
        LogStream(format="csv")


def test_an_over_long_line_fed_in_pieces_is_never_held_whole():
    stream = LogStream("phone")
    stream.feed_text("#\tFloorName:F1\n1574559495401\tTYPE_ACCELEROMETER\t0.1\t0.2\t9.8\t2\n1574559498000\tTYPE_WIFI\t")
    piece = b"7" * (1 << 20)
    tracemalloc.start()
    try:
        for _ in range(64):
            stream.feed_bytes(piece)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 8_000_000  # far below the 64 MB line
    rest = stream.feed_bytes(b"\n1574559499000\tTYPE_ACCELEROMETER\t0.1\t0.2\t9.8\t2\n")
    assert rest.acc_t_s.size == 1 and stream.report.bad_rows == {"?": 1}
    assert stream.report.first_bad["?"].startswith("line 3: line longer than")
    stream.close()
    assert stream.report.n_lines == 4


def test_utf8_cut_inside_a_character_decodes_as_the_line_whole():
    # a header with multibyte characters and one cut short by its line end (b"\xe2\x82")
    data = ("#\tFloorName:杭州\tModel:caf".encode("utf-8") + b"\xe2\x82\n"
            + "1574559497191\tTYPE_WIFI\tcafé ☕\ta8:0c:ca:03:9d:d7\t-49\t2422\t1574559496450\n"
              "1574559498000\tTYPE_ACCELEROMETER\t0.1\t0.2\t9.8\t2\n".encode("utf-8"))
    for cut in range(len(data)):
        stream = LogStream("phone")
        chunks = [stream.feed_bytes(data[:cut]), stream.feed_bytes(data[cut:]), stream.close()]
        rec = concatenate(chunks)
        assert rec.floor_name == "杭州" and rec.phone_model == "caf\ufffd"  # one replacement, wherever the cut
        assert len(rec.wifi) == 1 and rec.acc_t_s.size == 1 and stream.report.clean


def test_beacon_ids_are_the_mac_in_upper_case(tmp_path):
    path = tmp_path / "log.txt"
    path.write_text("#\tFloorName:F1\n"
                    "1574559497200\tTYPE_BEACON\tfda50693\t0\t0\t-56\t-79\t2.5\te0:78:a3:3d:a8:f0\t1574559497200\n"
                    "1574559497300\tTYPE_BEACON\tfda50693\t0\t0\t-56\t-81\t3.0\n"
                    "1574559497400\tTYPE_BEACON\tfda50693\t0\t0\t-56\t-71\t1.0\tnot-a-mac\t1574559497400\n")
    rec = read_log(path)
    assert rec.beacons.beacon_id == ["E0:78:A3:3D:A8:F0", "fda50693:0:0", "fda50693:0:0"]
    np.testing.assert_array_equal(rec.beacons.distance_m, np.array([2.5, 3.0, 1.0], dtype=np.float32))


def test_until_cuts_every_stream_and_keeps_whole_scans(tmp_path):
    path = tmp_path / "walk.txt"
    path.write_text(_ilc_walk(30))
    rec = read_log(path)
    cut_s = (T0 + 12_000) / 1000.0  # after the scans at 1 s, 3 s, ... 11 s; a waypoint at 10 s
    part = rec.until(cut_s)
    assert part.acc_t_s.size == 12 * 50 + 1 and part.acc_mps2.shape == (601, 3) and part.acc_t_s[-1] == cut_s
    assert len(part.wifi) == 6 and part.wifi.row_ap.size == 24 and part.wifi.t_s[-1] < cut_s
    assert part.wifi.ap_keys == rec.wifi.ap_keys and part.waypoint_t_s.size == 2
    np.testing.assert_array_equal(part.wifi.matrix(), rec.wifi.matrix()[:6])
    assert len(rec.until(T0 / 1000.0 - 1).wifi) == 0 and rec.until(T0 / 1000.0 - 1).acc_t_s.size == 0
    assert_same(rec.until(np.inf), rec)


def test_a_scan_cut_by_the_end_of_the_log_is_read_with_the_rows_so_far(tmp_path):
    text = _ilc_walk(10)
    lines = text.splitlines(keepends=True)
    last_scan_row = max(i for i, line in enumerate(lines) if "TYPE_WIFI" in line)
    part = read_log_text("".join(lines[:last_scan_row]), "cut")  # the last scan's last row cut off
    whole = read_log_text(text, "whole")
    assert len(part.wifi) == len(whole.wifi)
    assert part.wifi.row_ap.size == whole.wifi.row_ap.size - 1


_AHEAD_MS = int(3 * 365.25 * 86400 * 1000)


def _shifted(line: str, ms: int) -> str:
    """An ILC line stamped ``ms`` later (a WiFi row's last-seen time too)."""
    fields = line.rstrip("\n").split("\t")
    fields[0] = str(int(fields[0]) + ms)
    if fields[1] == "TYPE_WIFI":
        fields[6] = str(int(fields[6]) + ms)
    return "\t".join(fields) + "\n"


@pytest.mark.parametrize("kind, rows", [("TYPE_ACCELEROMETER", 1), ("TYPE_WIFI", 2), ("TYPE_WAYPOINT", 1)])
def test_one_record_stamped_years_ahead_is_dropped_not_the_rest_of_its_stream(tmp_path, kind, rows):
    lines = _ilc_walk(60).splitlines(keepends=True)
    middle = next(i for i, line in enumerate(lines) if i > len(lines) // 2 and kind in line)
    ahead = [_shifted(line, _AHEAD_MS) for line in lines[middle:] if kind in line][:rows]
    if kind == "TYPE_WIFI":  # a scan of two rows, each with its own BSSID
        ahead = [row.replace("ee:00", f"ee:{10 + i:02x}") for i, row in enumerate(ahead)]
    clean, hostile = tmp_path / "clean.txt", tmp_path / "hostile.txt"
    clean.write_text("".join(lines))
    hostile.write_text("".join(lines[:middle] + ahead + lines[middle:]))
    warnings = []
    rec = read_log(hostile, warn=warnings.append)
    # held until the next record of its stream, which went back: the lone record is dropped
    assert rec.read_report.went_back == {kind: rows} and rec.read_report.time_gaps_s == []
    assert_same(_records(rec), _records(read_log(clean)))
    assert len(warnings) == 1 and f"{rows} row{'s' if rows > 1 else ''} that went back in time" in warnings[0]
    data = hostile.read_bytes()
    assert_same(stream_pieces(random_pieces(data, np.random.default_rng(5)), hostile), rec)


def test_a_pause_of_thirty_days_drops_nothing_and_is_a_gap(tmp_path):
    lines = _ilc_walk(60).splitlines(keepends=True)
    middle = len(lines) // 2
    month_ms = 30 * 86400 * 1000
    later = [_shifted(line, month_ms) for line in lines[middle:]]
    path = tmp_path / "pause.txt"
    path.write_text("".join(lines[:middle] + later))
    rec = read_log(path, warn=lambda m: None)
    assert rec.read_report.went_back == {} and rec.read_report.duplicates == {}
    assert rec.acc_t_s.size == 60 * 50 and len(rec.wifi) == 30 and rec.waypoint_t_s.size == 6
    gaps = rec.read_report.time_gaps_s
    assert len(gaps) == 1 and 30 * 86400 <= gaps[0][1] - gaps[0][0] < 30 * 86400 + 1
    assert_same(stream_pieces(random_pieces(path.read_bytes(), np.random.default_rng(6)), path), rec)


def test_blank_lines_count_towards_the_lines_a_format_is_looked_for_in():
    """A stream of blank lines is refused at the sniff limit instead of being held without end
    (it grew by 40 MB/s), and a log after a few blank lines is read as usual."""
    stream = LogStream("-")
    stream.feed_bytes(b"\n" * 199)
    with pytest.raises(MapfilterError, match=r"^-: unknown log format \(its first 200 lines are blank\)"):
        stream.feed_bytes(b"\n" * 1_000_000)
    stream = LogStream("-")
    stream.feed_bytes(b"\n" * 150)
    chunk = stream.feed_bytes(b"#\tFloorName:F1\n1574559495401\tTYPE_ACCELEROMETER\t0.1\t0.2\t9.8\n")
    assert chunk.acc_t_s.size == 1 and stream.format == "ILC 2.0" and stream.report.n_lines == 152
    with pytest.raises(MapfilterError, match=r"^-: empty log \(3 blank lines\)"):
        stream = LogStream("-")
        stream.feed_bytes(b"\n\n\n")
        stream.close()


@pytest.mark.parametrize("newlines", [True, False])
def test_random_bytes_are_called_binary_data_not_an_empty_log(tmp_path, newlines):
    """Random bytes (with newlines, and one line of them without any) are refused at once as
    binary data, streamed or read from a file; no line of them is taken for a header."""
    data = np.random.default_rng(45).integers(0, 256, 4_000_000, dtype=np.uint8).tobytes()
    if not newlines:
        data = data.replace(b"\n", b"x")
    stream = LogStream("-")
    with pytest.raises(MapfilterError, match="binary data") as caught:
        for i in range(0, len(data), 65536):
            stream.feed_bytes(data[i:i + 65536])
    assert "empty log" not in str(caught.value) and i < 200_000  # refused within the first pieces
    path = tmp_path / "random.bin"
    path.write_bytes(data)
    for read in (read_log, log_format):
        with pytest.raises(MapfilterError, match=r"unknown log format \(line \d+ .*binary data"):
            read(path)
