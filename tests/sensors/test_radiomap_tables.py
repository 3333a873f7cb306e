"""The radio-map likelihood built once per radio map: per-AP tables built as scans hear the APs
give the numbers of a likelihood built for one walk's APs up front; the grid kept in the radio
map's file gives the numbers of one built for the run, and is used only when it fits."""

import numpy as np
import pytest

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


# ---- the likelihood's grid kept in the radio map's file (radiomap build) ---------------------------
OFFICE = __import__("pathlib").Path(__file__).resolve().parents[2] / "maps"


def _office():
    from mapfilter.maps.floorplan import FloorPlan
    from mapfilter.sensors.logs import read_log
    from mapfilter.sensors.radiomap import RadioMap

    return (FloorPlan.load(OFFICE / "office.yaml"), RadioMap.load(OFFICE / "office_radiomap.npz"),
            list(iter_scans(read_log(OFFICE / "office_walk.txt.gz"))))


def _same_likelihood(a, b, scans) -> None:
    assert np.array_equal(a.base, b.base) and np.array_equal(a.cell_of, b.cell_of)
    assert np.array_equal(a.cell_xy_m, b.cell_xy_m)
    for scan in scans:
        assert np.array_equal(a.grid_log_likelihood(scan), b.grid_log_likelihood(scan))


def test_the_tables_sums_are_scipys_sparse_product_to_the_bit():
    from scipy import sparse

    plan, radio_map, _ = _office()
    model = RadioMapLikelihood(radio_map, plan)
    ap_ptr, ref, rssi = model._readings  # noqa: SLF001
    w_ptr, w_ref, w_val = model._weight  # noqa: SLF001
    n = model._n_aps  # noqa: SLF001
    ap = np.repeat(np.arange(n), np.diff(ap_ptr))
    weight = sparse.csr_matrix((w_val, w_ref, w_ptr), shape=(w_ptr.size - 1, len(radio_map)))
    readings = sparse.csr_matrix((np.concatenate([np.ones_like(rssi), rssi, rssi ** 2]),
                                  (np.tile(ref, 3), np.concatenate([ap, ap + n, ap + 2 * n]))),
                                 shape=(len(radio_map), 3 * n))
    product = (weight @ readings).tocsr()
    product.sort_indices()
    product = product.tocoo()
    block = product.col // n
    cell, ap_of, wh, s1, s2 = model._sums(np.ones(n, dtype=bool))  # noqa: SLF001
    by_cell = np.lexsort((ap_of, cell))  # the product's (cell, AP) order
    assert np.array_equal(cell[by_cell], product.row[block == 0]) and np.array_equal(ap_of[by_cell], product.col[block == 0])
    for b, sums in enumerate((wh, s1, s2)):
        assert np.array_equal(sums[by_cell], product.data[block == b].astype(np.float64))


def test_a_saved_radio_map_keeps_the_likelihoods_grid_and_gives_its_numbers(tmp_path):
    import dataclasses

    from mapfilter.filter.models.radio_map import keep_tables
    from mapfilter.sensors.radiomap import RadioMap

    plan, bundled, scans = _office()
    assert RadioMapLikelihood(bundled, plan).from_stored_tables  # tools/make_example.sh: radiomap build
    dataclasses.replace(bundled, likelihood_tables={}).save(tmp_path / "older.npz")
    radio_map = RadioMap.load(tmp_path / "older.npz")
    assert radio_map.likelihood_tables == {}  # an older file: built as before
    built = RadioMapLikelihood(radio_map, plan)
    assert not built.from_stored_tables
    keep_tables(radio_map, plan).save(tmp_path / "rm.npz")
    loaded = RadioMap.load(tmp_path / "rm.npz")
    assert int(loaded.likelihood_tables["version"]) == 1
    stored = RadioMapLikelihood(loaded, plan)
    assert stored.from_stored_tables
    _same_likelihood(stored, built, scans)
    # every array of the map itself is the file's before
    for name in ("xy_m", "rssi_dbm", "t_s", "trace", "xy_sigma_m"):
        assert np.array_equal(getattr(loaded, name), getattr(radio_map, name), equal_nan=True)


def test_tables_of_another_plan_configuration_or_radio_map_are_not_used(tmp_path):
    import dataclasses

    from mapfilter.filter.models.radio_map import RadioMapLikelihoodConfig, keep_tables
    from mapfilter.maps.floorplan import FloorPlan

    plan, radio_map, scans = _office()
    keep_tables(radio_map, plan)
    mask = plan.wall_mask.copy()
    mask[np.nonzero(~mask)[0][0], np.nonzero(~mask)[1][0]] = True
    other_plan = FloorPlan(mask, plan.resolution_m, plan.origin_m)
    other_config = RadioMapLikelihoodConfig(bandwidth_m=2.5)
    changed = dataclasses.replace(radio_map, rssi_dbm=radio_map.rssi_dbm + 1.0, likelihood_tables=radio_map.likelihood_tables)
    for rm, fp, config in ((radio_map, other_plan, RadioMapLikelihoodConfig()), (radio_map, plan, other_config),
                           (changed, plan, RadioMapLikelihoodConfig()), (radio_map, None, RadioMapLikelihoodConfig())):
        model = RadioMapLikelihood(rm, fp, config)
        assert not model.from_stored_tables
        _same_likelihood(model, RadioMapLikelihood(dataclasses.replace(rm, likelihood_tables={}), fp, config),
                         scans[:5])


@pytest.mark.parametrize("damage", ["ref out of range", "pointer backwards", "cell out of range", "base NaN",
                                    "short weights", "version 2", "missing array"])
def test_broken_tables_are_not_used(damage):
    from mapfilter.filter.models.radio_map import keep_tables

    plan, radio_map, scans = _office()
    tables = dict(keep_tables(radio_map, plan).likelihood_tables)
    if damage == "ref out of range":
        tables["weight_ref"] = tables["weight_ref"].copy()
        tables["weight_ref"][7] = len(radio_map)
    elif damage == "pointer backwards":
        tables["weight_ptr"] = tables["weight_ptr"].copy()
        tables["weight_ptr"][3] = tables["weight_ptr"][5] + 1
    elif damage == "cell out of range":
        tables["cells"] = tables["cells"].copy()
        tables["cells"][-1] = 10 ** 9
    elif damage == "base NaN":
        tables["base"] = np.full_like(tables["base"], np.nan)
    elif damage == "short weights":
        tables["weight"] = tables["weight"][:-1]
    elif damage == "version 2":
        tables["version"] = np.array(2)
    else:
        del tables["w_all"]
    radio_map.likelihood_tables = tables
    model = RadioMapLikelihood(radio_map, plan)
    assert not model.from_stored_tables
    radio_map.likelihood_tables = {}
    _same_likelihood(model, RadioMapLikelihood(radio_map, plan), scans[:5])


def test_radiomap_build_keeps_the_grid_and_track_starts_from_it(tmp_path, ilc_site1):
    from mapfilter.cli import main
    from mapfilter.sensors.radiomap import RadioMap

    floor = ilc_site1 / "F1"
    logs = sorted((floor / "path_data_files").glob("*.txt.gz"))
    assert main(["map", "import-ilc", str(floor), "--route", "geojson", "--out", str(tmp_path / "F1.yaml")]) == 0
    assert main(["radiomap", "build", str(tmp_path / "F1.yaml"), *map(str, logs[1:6]), "--out",
                 str(tmp_path / "rm.npz")]) == 0
    radio_map = RadioMap.load(tmp_path / "rm.npz")
    plan = import_ilc(floor, route="geojson")
    assert RadioMapLikelihood(radio_map, plan).from_stored_tables
    # the walk's track is the same from the stored grid as from one built for the run
    assert main(["track", str(tmp_path / "F1.yaml"), str(logs[0]), "--radiomap", str(tmp_path / "rm.npz"),
                 "--out", str(tmp_path / "stored.csv")]) == 0
    radio_map.likelihood_tables = {}
    radio_map.save(tmp_path / "plain.npz")
    assert main(["track", str(tmp_path / "F1.yaml"), str(logs[0]), "--radiomap", str(tmp_path / "plain.npz"),
                 "--out", str(tmp_path / "plain.csv")]) == 0
    assert (tmp_path / "stored.csv").read_bytes() == (tmp_path / "plain.csv").read_bytes()


def test_the_per_ap_table_kernel_gives_the_numpy_tables_to_the_bit():
    """Oracle: ``_ap_table`` and ``_offset`` (one loop over the weighted sums, the logarithms in
    numpy) against the numpy formulas they replaced, on the office map's every AP: the same float32
    entries; entries at or below MIN_WEIGHT dropped."""
    from mapfilter.filter.models import radio_map as rml

    plan, radio_map, _ = _office()
    model = RadioMapLikelihood(radio_map, plan)
    cell, ap, wh, s1, s2 = model._sums(np.ones(model._n_aps, dtype=bool))  # noqa: SLF001
    keep = wh > rml.MIN_WEIGHT
    assert 0 < keep.sum() < keep.size  # some entries are dropped, most kept
    cell, ap, wh, s1, s2 = cell[keep], ap[keep], wh[keep], s1[keep], s2[keep]
    pw = rml.PRIOR_WEIGHT
    mu = (s1 + pw * rml.PRIOR_RSSI_DBM) / (wh + pw)
    var = (s2 - 2 * mu * s1 + mu * mu * wh + pw * rml.PRIOR_SIGMA_DB ** 2) / (wh + pw)
    var = np.maximum(var, 0.0) + rml.SIGMA_FLOOR_DB ** 2
    p_heard = np.clip((wh + pw * rml.PRIOR_HEARD) / (model._w_all[cell] + pw), rml.HEARD_CLIP,  # noqa: SLF001
                      1 - rml.HEARD_CLIP)
    offset = (np.log(p_heard) - 0.5 * np.log(2 * np.pi * var) - np.log1p(-p_heard)).astype(np.float32)
    got = rml._ap_table(*model._sums(np.ones(model._n_aps, dtype=bool)), model._w_all)  # noqa: SLF001
    got_ap, got_cell, got_mu, got_inv_var, got_p, got_two_pi_var = got
    np.testing.assert_array_equal(got_ap, ap)
    np.testing.assert_array_equal(got_cell, cell.astype(np.int32))
    np.testing.assert_array_equal(got_mu, mu.astype(np.float32))
    np.testing.assert_array_equal(got_inv_var, (1.0 / var).astype(np.float32))
    np.testing.assert_array_equal(got_p, p_heard)
    np.testing.assert_array_equal(rml._offset(np.log(got_p), np.log(got_two_pi_var), np.log1p(-got_p)), offset)


def test_the_not_heard_base_is_the_numpy_formulas_to_the_bit():
    """Oracle: the not-heard base (``_not_heard_entries``: the pairs whose P(heard) is not the
    prior's, one pass) against the numpy it replaced (every pair with data, ``np.add.at``), on the
    office map's every AP: the same float64 per cell."""
    from mapfilter.filter.models import radio_map as rml

    plan, radio_map, _ = _office()
    radio_map.likelihood_tables = {}  # the base built here, not the file's
    model = RadioMapLikelihood(radio_map, plan)
    assert not model.from_stored_tables
    clip, pw, w_all = rml.HEARD_CLIP, rml.PRIOR_WEIGHT, model._w_all  # noqa: SLF001
    p0 = np.clip(pw * rml.PRIOR_HEARD / (w_all + pw), clip, 1 - clip)
    cell, _, wh, _, _ = model._sums(np.ones(model._n_aps, dtype=bool))  # noqa: SLF001
    data = wh > rml.MIN_WEIGHT
    p_heard = np.clip((wh[data] + pw * rml.PRIOR_HEARD) / (w_all[cell[data]] + pw), clip, 1 - clip)
    assert 0 < np.sum(p_heard == p0[cell[data]]) < p_heard.size  # some pairs' terms are zero, not all
    expected = model._n_aps * np.log1p(-p0)  # noqa: SLF001
    np.add.at(expected, cell[data], np.log1p(-p_heard) - np.log1p(-p0[cell[data]]))
    np.testing.assert_array_equal(model.base, expected)
    assert not np.array_equal(model.base, model._n_aps * np.log1p(-p0))  # noqa: SLF001  the data count


def _numpy_grid(model, scan) -> np.ndarray:
    """``grid_log_likelihood`` as numpy made it before the kernel (``_grid_values``)."""
    from mapfilter.filter.models.radio_map import _add_heard_corrections

    cols, r = model._heard(scan)
    out = np.zeros(model.n_cells + 1)
    if not cols.size:
        return out
    out += model.base + len(cols) * model._prior_offset
    out -= 0.5 * model._prior_inv_var * float(((r - model._prior_mu_dbm) ** 2).sum())
    _add_heard_corrections(out, cols, r, model._ap_ptr, model._cell, model._mu, model._inv_var, model._offset,
                           model._prior_offset, model._prior_mu_dbm, model._prior_inv_var)
    return model.config.exponent * out


@pytest.mark.parametrize("exponent", [1.0, 0.4, 0.0])
def test_the_best_cell_is_numpys_argmax_of_the_grid(exponent):
    """Oracle: the grid (``_grid_values``) against the numpy it replaced, to the bit, and
    ``best_position`` (``_best_cell``) against the centre of ``np.argmax`` of that grid on the
    office walk's scans: the same cell every time; a flat grid (exponent 0, or no AP of the map
    heard) gives the first cell, as numpy's argmax does, and so does a NaN."""
    from mapfilter.filter.models.radio_map import RadioMapLikelihoodConfig
    from mapfilter.sensors.wifi import WifiScan

    plan, radio_map, scans = _office()
    model = RadioMapLikelihood(radio_map, plan, RadioMapLikelihoodConfig(exponent=exponent))
    cells = set()
    for scan in scans:
        grid = _numpy_grid(model, scan)
        assert np.array_equal(model.grid_log_likelihood(scan), grid)
        expected = model.cell_xy_m[int(np.argmax(grid[:-1]))]
        assert np.array_equal(model.best_position(scan), expected)
        cells.add(tuple(expected))
    assert (len(cells) > 5) == (exponent > 0)  # the walk's scans peak in many places
    unknown = WifiScan(0.0, ("02:00:00:00:ff:ff",), np.array([-50.0], dtype=np.float32))
    assert np.array_equal(model.best_position(unknown), model.cell_xy_m[0])
    model.base = model.base.copy()
    model.base[[7, 9]] = np.nan  # the first NaN wins, as in np.argmax
    assert np.array_equal(model.best_position(scans[0]), model.cell_xy_m[7])
    assert int(np.argmax(model.grid_log_likelihood(scans[0])[:-1])) == 7
