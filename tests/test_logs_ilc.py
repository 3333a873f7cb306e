"""The ILC trace reader on a real walk and on hand-written good and malformed logs."""

import gzip

import numpy as np
import pytest
from conftest import ILC_SITE1 as ILC

from mapfilter.errors import MapfilterError
from mapfilter.sensors.ilc import read_ilc
from mapfilter.sensors.wifi import scans_of


def test_reads_a_real_trace_with_stale_rows_dropped():
    path = sorted((ILC / "F1" / "path_data_files").glob("*.txt.gz"))[0]
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
def test_malformed_line_names_file_and_line(tmp_path, bad_line, message):
    path = _write(tmp_path, HEADER + GOOD + bad_line)
    bad_line_no = (HEADER + GOOD).count("\n") + 1
    with pytest.raises(MapfilterError, match=message) as caught:
        read_ilc(path)
    assert str(caught.value).startswith(f"{path}:{bad_line_no}: ")


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
