"""The radio-map likelihood built once per radio map: per-AP tables built as scans hear the APs
give the numbers of a likelihood built for one walk's APs up front."""

import numpy as np

from mapfilter.filter.models.radio_map import RadioMapLikelihood, radio_map_likelihood
from mapfilter.maps.prepare import import_ilc
from mapfilter.sensors.ilc import read_ilc
from mapfilter.sensors.radiomap import build_radio_map
from mapfilter.sensors.wifi import iter_scans


def test_tables_built_on_first_hearing_give_the_walks_own_numbers(ilc_site1):
    floor = ilc_site1 / "F1"
    plan = import_ilc(floor, route="geojson")
    logs = sorted((floor / "path_data_files").glob("*.txt.gz"))
    walks = [list(iter_scans(read_ilc(path))) for path in logs[:2]]
    radio_map = build_radio_map([read_ilc(path) for path in logs[2:14]], plan)
    shared = radio_map_likelihood(radio_map, plan)
    assert radio_map_likelihood(radio_map, plan) is shared  # built once per radio map
    assert radio_map_likelihood(radio_map, None) is not shared
    tabled = []
    for k, scans in enumerate(walks):  # two walks in turn: the second adds the tables of its own APs
        heard = {key for scan in scans for key in scan.ap_keys}
        own = RadioMapLikelihood(radio_map, plan, heard_keys=heard)
        if k == 1:  # its tables in one go (the first walk's were built scan by scan)
            assert radio_map_likelihood(radio_map, plan, heard_keys=heard) is shared
        for scan in scans:
            assert np.array_equal(shared.grid_log_likelihood(scan), own.grid_log_likelihood(scan))
        tabled.append(int(shared._built.sum()))  # noqa: SLF001
    assert 0 < tabled[0] < tabled[1] < len(shared.ap_keys)
