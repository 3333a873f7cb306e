"""The readers' block parse (the common rows of many lines parsed together) against their parse
line by line: the same records, report and errors on real logs and on broken ones, whole and
streamed in pieces."""

import gzip

import numpy as np
import pytest

from mapfilter.errors import MapfilterError
from mapfilter.sensors import ilc, ipin
from mapfilter.sensors.logread import RecordStream, group_scans, handle_each
from mapfilter.sensors.recording import WifiScans, concatenate
from mapfilter.sensors.wifi import ap_key, band_of_frequency
from tests.sensors.test_logs_stream import _ilc_walk, assert_same, random_pieces

REPO_MAPS = __import__("pathlib").Path(__file__).resolve().parents[2] / "maps"


class LineByLineIlc(ilc.IlcParser):
    def handle_lines(self, first, lines, bad_row):
        handle_each(self.handle_line, first, lines, bad_row)


class LineByLineGsd(ipin.GsdParser):
    def handle_lines(self, first, lines, bad_row):
        handle_each(self.handle_line, first, lines, bad_row)


def read_with(parser, pieces, strict=False):
    """The recording the parser makes of ``pieces`` fed to a stream, or the error it raised."""
    stream = RecordStream("log", 5.0, strict, None, parser)
    try:
        chunks = [stream.feed_bytes(piece) for piece in pieces]
        chunks.append(stream.close())
    except MapfilterError as exc:
        return f"error: {exc}"
    return concatenate(chunks)


def assert_block_is_line_by_line(block, line, data: bytes, rng, strict=False):
    expected = read_with(line, [data], strict)
    if isinstance(expected, str):
        assert read_with(block, [data], strict) == expected
        return
    assert_same(read_with(block, [data], strict), expected)
    if not strict:
        assert_same(read_with(block, random_pieces(data, rng, fine_prefix=0)), expected)


def gsd_walk(seconds: int = 30) -> str:
    """A GetSensorData log: IMU and AHRS at 50 Hz read in bursts, the magnetometer from 5 s on
    (a late stream), the barometer at 5 Hz, a WiFi scan every 2 s (an SSID with ';' in it), BLE4,
    POSI every 10 s and GNSS rows (not read)."""
    lines = ["% LogFile created by the 'GetSensorData' App for Android.\n",
             "% Date of creation: Thu Jun 15 10:01:26 GMT+02:00 2023\n", "% Model:   \tSM-TEST\n"]
    for k in range(seconds * 50):
        app = 0.02 * k + 0.004 * (k % 3)
        sensor = 2558.6 + 0.02 * k
        lines.append(f"ACCE;{app:.4f};{sensor:.4f};{np.sin(k / 7):.5f};0.2;9.8;3\n")
        lines.append(f"GYRO;{app + 0.001:.4f};{sensor:.4f};0.01;{np.cos(k / 5):.5f};0.03;3\n")
        lines.append(f"AHRS;{app + 0.002:.4f};{sensor:.4f};1.0;2.0;3.0;0.1;0.2;{0.5 + 0.1 * np.sin(k / 50):.6f};3\n")
        if k >= 250:
            lines.append(f"MAGN;{app + 0.003:.4f};{sensor + 0.5:.4f};20.0;-3.0;{-40 + k % 5};3\n")
        if k % 10 == 0:
            lines.append(f"PRES;{app:.4f};{sensor:.4f};{980 + 0.001 * k:.4f};3\n")
        if k % 100 == 50:
            for ap in range(5):
                ssid = "semi;colon" if ap == 4 else f"net{ap}"
                lines.append(f"WIFI;{app:.4f};{sensor - 0.3:.4f};{ssid};20:23:00:00:00:{ap:02x};"
                             f"{2437 if ap % 2 else 5500};{-50 - 4 * ap - k % 7}\n")
        if k % 60 == 7:
            lines.append(f"BLE4;{app:.4f};iBeacon;be:ac:20:23:00:0{k % 6 + 1};{-70 - k % 9};0;1;6;11111111\n")
            lines.append(f"GNSS;{app:.4f};1686816087.2760;49.46;11.11;365.6;229.7;12.0;0.3;6;0\n")
        if k % 500 == 0:
            lines.append(f"POSI;{app:.4f};{k // 500};49.460948;11.110539;0;100\n")
    return "".join(lines)


JUNK = ["nan", "inf", "-inf", "", " ", "1_000", "\u0661\u0662", "\uff11", "1e400", "abc", " 5 ", "0x10", "+1",
        "Infinity", "-0", "1e-400", "2.5e3", "TYPE_WIFI", "9" * 30, "1.5\r", "WIFI", "%"]


def corrupt(text: str, rng: np.random.Generator, rate: float, sep: str, time_column: int, ms: float) -> bytes:
    """``text`` with a share ``rate`` of its lines broken: a field swapped for junk, two lines
    glued, a line repeated, dropped, cut, stamped back or far ahead, moved a few lines down (a
    WiFi row after records of a later time), given a field more or a carriage return inside, or
    a header, blank or unknown line put before it."""
    out: list[str] = []
    delayed: list[list] = []  # [lines still to pass, line]
    for line in text.split("\n"):
        for item in delayed:
            item[0] -= 1
        out += [held for wait, held in delayed if wait < 0]
        delayed = [item for item in delayed if item[0] >= 0]
        if rng.random() >= rate or not line:
            out.append(line)
            continue
        fields = line.split(sep)
        op = int(rng.integers(13))
        if op >= 11:
            delayed.append([int(rng.integers(1, 30)), line])
        elif op == 0:
            fields[int(rng.integers(len(fields)))] = str(rng.choice(JUNK))
            out.append(sep.join(fields))
        elif op == 1 and out:
            out[-1] += line  # a missing newline
        elif op == 2:
            out += [line, line]
        elif op == 3:
            out.append("")  # the line dropped (a blank line in its place)
        elif op == 4:
            out.append(line[:int(rng.integers(len(line)))])
        elif op in (5, 6) and len(fields) > time_column:
            try:
                t = float(fields[time_column])
            except ValueError:
                out.append(line)
                continue
            shift = -rng.uniform(0, 30) if op == 5 else rng.choice([70.0, 3e6])
            fields[time_column] = f"{t + shift * ms:.{0 if ms > 1 else 4}f}"
            out.append(sep.join(fields))
        elif op == 7:
            out.append(line + sep + "extra")
        elif op == 8:
            at = int(rng.integers(len(line)))
            out.append(line[:at] + "\r" + line[at:])
        elif op == 9:
            out += [str(rng.choice(["#\tFloorName:F2", "% Model: other", "", "  ", "123\tTYPE_LIGHT\t1",
                                    "LIGH;1.0;2.0;3", "TYPE_X", "ACCE;", "1574559495000\tTYPE_WIFI"])), line]
        else:
            out.append(line.replace(sep, sep + sep, 1))
    out += [held for _, held in delayed]
    return "\n".join(out).encode("utf-8", errors="surrogateescape")


@pytest.fixture(params=["default", "always"])
def block_share(request, monkeypatch):
    """The block parse where most lines are good (as on real logs), or on every block."""
    if request.param == "always":
        monkeypatch.setattr(ilc, "_BLOCK_SHARE", 0.0)
        monkeypatch.setattr(ipin, "_BLOCK_SHARE", 0.0)
    return request.param


def _office_walk(n_lines: int = 6000) -> str:
    return "\n".join(gzip.decompress((REPO_MAPS / "office_walk.txt.gz").read_bytes()).decode().split("\n")[:n_lines])


@pytest.mark.parametrize("rate", [0.0, 0.02, 0.2])
def test_a_broken_ilc_log_reads_the_same_in_blocks_and_line_by_line(block_share, rate):
    for seed, text in enumerate([_ilc_walk(30), _office_walk()]):
        rng = np.random.default_rng([seed, int(rate * 1000)])
        data = corrupt(text, rng, rate, "\t", 0, 1000.0)
        assert_block_is_line_by_line(ilc.IlcParser, LineByLineIlc, data, rng)
        assert_block_is_line_by_line(ilc.IlcParser, LineByLineIlc, data, rng, strict=True)


@pytest.mark.parametrize("rate", [0.0, 0.02, 0.2])
def test_a_broken_getsensordata_log_reads_the_same_in_blocks_and_line_by_line(block_share, rate):
    for seed in range(2):
        rng = np.random.default_rng([seed, int(rate * 1000)])
        data = corrupt(gsd_walk(), rng, rate, ";", 1, 1.0)
        assert_block_is_line_by_line(ipin.GsdParser, LineByLineGsd, data, rng)
        assert_block_is_line_by_line(ipin.GsdParser, LineByLineGsd, data, rng, strict=True)


def test_real_logs_read_the_same_in_blocks_and_line_by_line(ilc_site1, ipin2023):
    # every log: tools/check_readers.py; here a few of each format
    rng = np.random.default_rng(0)
    for path in sorted((ilc_site1 / "F1" / "path_data_files").glob("*.txt.gz"))[:1]:
        assert_block_is_line_by_line(ilc.IlcParser, LineByLineIlc, gzip.decompress(path.read_bytes()), rng)
    for path in sorted((ipin2023 / "logs").glob("*.txt.gz"))[:1]:
        assert_block_is_line_by_line(ipin.GsdParser, LineByLineGsd, gzip.decompress(path.read_bytes()), rng)


def _group_scans_by_row(rows, max_age_s):
    """WiFi rows grouped into scans one row at a time: the oracle of ``group_scans``."""
    keys, per_scan = {}, {}
    for t_s, bssid, rssi, freq, age_s in rows:
        if age_s > max_age_s:
            continue
        index = keys.setdefault(ap_key(bssid, band_of_frequency(freq)), len(keys))
        scan = per_scan.setdefault(t_s, {})
        if index not in scan or rssi > scan[index][0]:
            scan[index] = (rssi, freq, age_s)
    times = sorted(per_scan)
    flat = [(s, index, *values) for s, t in enumerate(times) for index, values in per_scan[t].items()]
    return WifiScans(t_s=np.array(times, dtype=np.float64), ap_keys=list(keys),
                     row_scan=np.array([r[0] for r in flat], dtype=np.int64),
                     row_ap=np.array([r[1] for r in flat], dtype=np.int64),
                     rssi_dbm=np.array([r[2] for r in flat], dtype=np.float32),
                     freq_mhz=np.array([r[3] for r in flat], dtype=np.float32),
                     age_s=np.array([r[4] for r in flat], dtype=np.float32))


@pytest.mark.parametrize("seed", range(20))
def test_wifi_rows_group_into_scans_as_row_by_row(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(0, 300))
    # few scan times and BSSIDs (upper and lower case, both bands): repeats, ties and stale rows
    rows = [(float(rng.integers(5)), str(rng.choice(["aa:bb", "AA:BB", "cc:dd", "ee:ff", "11:22"])),
             float(rng.integers(-90, -40, endpoint=True) // 5 * 5), float(rng.choice([2412.0, 2437.0, 5180.0])),
             float(rng.choice([0.0, 1.0, 6.0, np.nan]))) for _ in range(n)]
    for max_age_s in (5.0, np.inf):
        assert_same(group_scans(rows, max_age_s), _group_scans_by_row(rows, max_age_s))
