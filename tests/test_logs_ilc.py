
import numpy as np

from mapfilter.logs import read_ilc

from conftest import ILC_SITE1 as ILC


def test_reads_a_real_trace_with_stale_rows_dropped():
    path = sorted((ILC / "F1" / "path_data_files").glob("*.txt.gz"))[0]
    everything = read_ilc(path, max_wifi_age_s=np.inf)
    fresh = read_ilc(path)
    assert fresh.floor_name == "F1"
    assert fresh.waypoint_xy_m.shape[0] >= 8
    assert fresh.acc_mps2.shape[1] == 3 and np.all(np.diff(fresh.acc_t_s) >= 0)
    assert 0 < fresh.wifi.row_ap.size < everything.wifi.row_ap.size
    assert np.all(fresh.wifi.age_s <= 5.0)
