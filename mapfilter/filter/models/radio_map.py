"""The radio map as a per-particle likelihood (a ``MeasurementModel``): no point fix, every particle
weighed by the radio map's own probability of the scan at its position."""

from __future__ import annotations

import dataclasses
import hashlib
import math
import weakref
from collections.abc import Collection

import numpy as np
from numba import njit

from mapfilter.errors import MapfilterError
from mapfilter.filter.kernels.passes import LIKELIHOOD_SIGNATURE, X, Y
from mapfilter.filter.models.interface import LikelihoodKernel, MeasurementModel
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.sensors.radiomap import RadioMap
from mapfilter.sensors.wifi import WifiScan


# The spread of the radio map over space, past the kernel's width: a weak prior where data are
# thin, so that a cell without data neither wins nor kills a particle
SUPPORT_SIGMAS = 3.0  # cells farther than this many kernel sigmas from every point have no data
SIGMA_FLOOR_DB = 4.0  # added in quadrature: the kernel average underestimates the spread
PRIOR_SIGMA_DB = 6.0  # RSSI spread where an AP has few observations (pseudo-count below)
PRIOR_WEIGHT = 0.5  # pseudo-count of the prior, in kernel-weight units
PRIOR_HEARD = 0.05  # P(heard) where there is no data
PRIOR_RSSI_DBM = -95.0  # mean RSSI assumed where an AP is heard without data there
HEARD_CLIP = 0.02  # P(heard) kept in [clip, 1 - clip]: APs drop out and pop up at random
MIN_OBSERVATIONS = 2  # APs heard in fewer reference points are ignored (no spread from one reading)
MIN_WEIGHT = 0.02  # an AP's kernel weight below which a cell keeps the prior (keeps the tables sparse)


@dataclasses.dataclass(frozen=True)
class RadioMapLikelihoodConfig:
    """How the radio map is spread over space."""

    cell_m: float = 1.0  # grid cell; particles read their nearest cell
    bandwidth_m: float = 3.0  # Gaussian kernel sigma for averaging reference points
    exponent: float = 1.0  # tempering: APs are not independent; < 1 flattens the likelihood


class RadioMapLikelihood(MeasurementModel):
    """Per-particle likelihood of a WiFi scan from the radio map itself (a ``MeasurementModel``).

    On a grid over the floor, each AP's RSSI mean mu_k, spread sigma_k and probability of
    being heard h_k are Gaussian-kernel averages of the reference points, shrunk toward a
    weak prior (pseudo-count ``PRIOR_WEIGHT``) where data are thin. A grown point with position
    uncertainty s (``RadioMap.xy_sigma_m``) enters with its kernel convolved by it (variance
    bandwidth^2 + s^2, height bandwidth^2 / (bandwidth^2 + s^2)). A scan's log-likelihood
    at a cell is

        sum_{k heard} [log h_k + log N(r_k; mu_k, sigma_k^2)] + sum_{k not heard} log(1 - h_k)

    over the map's APs. Storage is sparse: an AP's statistics are kept only on the cells
    near reference points that heard it; elsewhere they equal the prior, which depends on
    the cell's total kernel weight alone. A scan then costs O(cells + stored cells of the
    heard APs): a per-cell constant sum_k log(1 - h_k), a vectorised prior term for the
    heard APs, and sparse corrections. Particles read the value of their cell (nearest
    lookup); off the grid, on walls or far from all data they get the prior cell's value.

    The grid, the kernel weights of every cell's reference points and the not-heard constant
    depend on the radio map, the floor plan and the configuration only: ``radiomap build``
    stores them in the radio map's file (:func:`keep_tables`), and a likelihood of that
    map on that plan with that configuration starts from them (no KD-tree, no scipy).
    """

    def __init__(self, radio_map: RadioMap, floorplan: FloorPlan | None = None,
                 config: RadioMapLikelihoodConfig = RadioMapLikelihoodConfig(),
                 heard_keys: Collection[str] | None = None):
        """``heard_keys``: the APs the scans to be weighed can hear (e.g. every AP of one walk).
        Only their per-AP tables are built (a walk hears a tenth of a mall's APs: most of the
        build's time and memory); every AP still counts where it is *not* heard. An AP outside
        the set, heard by a scan anyway, is ignored like an AP the radio map does not know.
        None: all APs."""
        cfg = self.config = config
        use_aps, tabled = self._index_readings(radio_map, heard_keys)
        grid = _stored_grid(radio_map, floorplan, cfg, use_aps)
        self.from_stored_tables = grid is not None
        if grid is None:
            grid = _built_grid(radio_map, floorplan, cfg)
        (x0, y0), self.shape, active, self._weight, w_all, stored_base = grid
        self._take_grid(x0, y0, active, len(radio_map))
        self._w_all = w_all
        self._built = ~tabled  # an AP outside heard_keys never gets a table
        self._tables: list[tuple[np.ndarray, ...]] = []  # per batch: (ap, cell, mu, 1/var, offset)
        self._ap_ptr = np.zeros(self._n_aps + 1, dtype=np.int64)
        self._cell = np.zeros(0, dtype=np.int32)
        self._mu = self._inv_var = self._offset = np.zeros(0, dtype=np.float32)
        p0 = self._set_prior(w_all)
        self.base = stored_base if stored_base is not None else self._not_heard_base(p0, w_all)
        self._use_aps = use_aps

    def _index_readings(self, radio_map: RadioMap,
                        heard_keys: Collection[str] | None) -> tuple[np.ndarray, np.ndarray]:
        """The APs in use (heard in ``MIN_OBSERVATIONS`` reference points), their keys, and every
        reading of them by AP (CSR by AP, each AP's in reference-point order); (the APs in use,
        which of them get tables)."""
        heard = ~np.isnan(radio_map.rssi_dbm.T)  # AP by point: the readings come out by AP, in point order
        use_aps = np.nonzero(heard.sum(axis=1) >= MIN_OBSERVATIONS)[0]
        if use_aps.size == 0 or len(radio_map) == 0:
            raise MapfilterError(f"the radio map has no AP heard in {MIN_OBSERVATIONS} reference points")
        self.ap_keys = [radio_map.ap_keys[j] for j in use_aps]
        tabled = np.ones(use_aps.size, dtype=bool) if heard_keys is None else np.isin(self.ap_keys, list(heard_keys))
        self.key_index = {key: j for j, key in enumerate(self.ap_keys) if tabled[j]}
        n_aps = use_aps.size
        ap_col, ref = np.nonzero(heard[use_aps])
        values = radio_map.rssi_dbm[ref, use_aps[ap_col]].astype(np.float32)
        self._readings = (np.searchsorted(ap_col, np.arange(n_aps + 1)).astype(np.int64), ref.astype(np.int64), values)
        self._n_refs, self._n_aps = len(radio_map), n_aps
        return use_aps, tabled

    def _take_grid(self, x0: float, y0: float, active: np.ndarray, n_refs: int) -> None:
        """The grid's cells (``active``: the grid indices of the cells kept), where particles find
        them, and the kernel weights by reference point (CSC, each point's cells in cell order)."""
        cfg = self.config
        w_ptr, w_ref, w_val = self._weight
        by_ref = np.argsort(w_ref, kind="stable")
        self._weight_by_ref = (np.searchsorted(w_ref[by_ref], np.arange(n_refs + 1)).astype(np.int64),
                               np.repeat(np.arange(w_ptr.size - 1), np.diff(w_ptr))[by_ref], w_val[by_ref])
        self.origin_m = (float(x0), float(y0))
        n_cells = active.size
        self.cell_of = np.full(self.shape[0] * self.shape[1], n_cells, dtype=np.int64)  # row n_cells = the prior cell
        self.cell_of[active] = np.arange(n_cells)
        rows, cols = np.divmod(active, self.shape[1])
        self.cell_xy_m = np.column_stack([x0 + (cols + 0.5) * cfg.cell_m, y0 + (rows + 0.5) * cfg.cell_m])

    def _set_prior(self, w_all: np.ndarray) -> np.ndarray:
        """The prior per cell (an AP never heard near it): its mean, inverse variance and offset;
        returns the probability of hearing such an AP at each cell (and the prior cell)."""
        clip = HEARD_CLIP
        prior_var = PRIOR_SIGMA_DB ** 2 + SIGMA_FLOOR_DB ** 2
        p0 = np.clip(PRIOR_WEIGHT * PRIOR_HEARD / (w_all + PRIOR_WEIGHT), clip, 1 - clip)
        self._prior_mu_dbm = PRIOR_RSSI_DBM
        self._prior_inv_var = 1.0 / prior_var
        self._prior_offset = np.log(p0) - 0.5 * np.log(2 * np.pi * prior_var) - np.log1p(-p0)  # (cells + 1,)
        return p0

    def _not_heard_base(self, p0: np.ndarray, w_all: np.ndarray) -> np.ndarray:
        """Each cell's log-likelihood of every AP unheard: the prior everywhere, corrected where an
        AP has data (all APs), each cell's terms added in AP order."""
        ap_ptr, reading_ref, _ = self._readings
        c_ptr, c_cell, c_val = self._weight_by_ref
        # only the (AP, cell) pairs whose P(heard) differs from the prior's: the others' terms are
        # exactly zero (most of a building's pairs are neither: millions of them)
        cell, p_heard = _not_heard_entries(c_ptr, c_cell, c_val, ap_ptr, reading_ref, self.n_cells, w_all, p0)
        not_p0 = np.log1p(-p0)
        grid_base = self._n_aps * not_p0
        # the logarithms in numpy, as the base always had them (each cell's prior one once); the
        # sums in AP order (np.add.at's)
        _add_in_order(grid_base, cell, np.log1p(-p_heard) - not_p0[cell])
        return grid_base

    def _sums(self, aps: np.ndarray) -> tuple[np.ndarray, ...]:
        """(cell, ap, weight, weighted RSSI sum, weighted RSSI^2 sum) of every cell and AP of
        ``aps`` (a mask over the APs in use) that a reference point within the kernel's reach of
        the cell heard, in (AP, cell) order; the sums are float32 (``_weighted_sums``), returned
        as float64."""
        ap_ptr, reading_ref, reading_rssi = self._readings
        c_ptr, c_cell, c_val = self._weight_by_ref
        cell, ap, wh, s1, s2 = _weighted_sums(c_ptr, c_cell, c_val, ap_ptr, reading_ref, reading_rssi,
                                              np.flatnonzero(aps).astype(np.int64), self.n_cells)
        return cell, ap, wh.astype(np.float64), s1.astype(np.float64), s2.astype(np.float64)

    def build_tables(self, keys: Collection[str]) -> None:
        """Build the per-AP tables of these APs now (else each is built when a scan first hears it)."""
        cols = [self.key_index[key] for key in keys if key in self.key_index]
        self._build_tables(np.array(cols, dtype=np.int64))

    def _build_tables(self, cols: np.ndarray) -> None:
        """The per-AP tables of the APs ``cols`` not built yet: each AP's RSSI mean, spread and
        P(heard) on the cells where it has data. An AP's table depends on its own readings only,
        so building some now and others later gives the same numbers as building all at once."""
        new = np.unique(cols[~self._built[cols]])
        if new.size == 0:
            return
        self._built[new] = True
        tabled = np.zeros(self._n_aps, dtype=bool)
        tabled[new] = True
        cell, ap, wh, s1, s2 = self._sums(tabled)
        # each entry's mean, spread and P(heard) in one loop (_ap_table); the logarithms in numpy,
        # whose vectorised log rounds as the tables always were
        ap, cell, mu, inv_var, p_heard, two_pi_var = _ap_table(cell, ap, wh, s1, s2, self._w_all)
        offset = _offset(np.log(p_heard), np.log(two_pi_var), np.log1p(-p_heard))
        self._tables.append((ap, cell, mu, inv_var, offset))
        # sparse per-AP tables (CSR by AP): log h + log N normaliser - log(1 - h), mean, 1/var;
        # each AP's entries come from one batch, in cell order
        ap, cell, mu, inv_var, offset = (np.concatenate(parts) if len(parts) > 1 else parts[0]
                                         for parts in zip(*self._tables))
        if np.any(ap[1:] < ap[:-1]):  # a batch after the first: its APs go between the others'
            order = np.argsort(ap, kind="stable")
            ap, cell, mu, inv_var, offset = ap[order], cell[order], mu[order], inv_var[order], offset[order]
        self._ap_ptr = np.searchsorted(ap, np.arange(self._n_aps + 1))
        self._cell, self._mu, self._inv_var, self._offset = cell, mu, inv_var, offset

    def stored_tables(self, radio_map: RadioMap, floorplan: FloorPlan) -> dict[str, np.ndarray]:
        """What a radio map file keeps of this likelihood (``RadioMap.likelihood_tables``): the
        grid, the kernel weights, the not-heard constant, and what they were made of."""
        w_ptr, w_ref, w_val = self._weight
        rows, cols = self.shape
        return {"version": np.array(TABLES_VERSION, dtype=np.int64),
                "parameters": _parameters(self.config), "plan": _plan_digest(floorplan),
                "radio_map": _radio_map_digest(radio_map), "aps": self._use_aps.astype(np.int64),
                "origin_m": np.array(self.origin_m, dtype=np.float64), "shape": np.array([rows, cols], dtype=np.int64),
                "cells": np.flatnonzero(self.cell_of < self.n_cells).astype(np.int64),
                "weight_ptr": w_ptr.astype(np.int64), "weight_ref": w_ref.astype(np.int32),
                "weight": w_val.astype(np.float32), "w_all": self._w_all.astype(np.float64),
                "base": self.base.astype(np.float64)}

    @property
    def n_cells(self) -> int:
        """Active grid cells (the prior cell not counted)."""
        return self.cell_xy_m.shape[0]

    def _heard(self, scan: WifiScan) -> tuple[np.ndarray, np.ndarray]:
        """(the scan's APs of the map with tables to be, as columns; their RSSI), tables built."""
        heard = [(j, value) for j, value in zip(map(self.key_index.get, scan.ap_keys),
                                                np.asarray(scan.rssi_dbm).tolist()) if j is not None]
        cols = np.array([j for j, _ in heard], dtype=np.int64)
        if cols.size and not self._built[cols].all():
            self._build_tables(cols)
        return cols, np.array([value for _, value in heard], dtype=np.float64)

    def grid_log_likelihood(self, scan: WifiScan) -> np.ndarray:
        """Log-likelihood of the scan at every active cell plus the prior cell, shape (cells + 1,)."""
        cols, r = self._heard(scan)
        if not cols.size:
            return np.zeros(self.n_cells + 1)  # nothing known heard: no information
        return self.config.exponent * self._grid_values(cols, r)

    def _grid_values(self, cols: np.ndarray, rssi_dbm: np.ndarray) -> np.ndarray:
        """``grid_log_likelihood`` before its exponent, of the heard APs ``cols`` (tables built)."""
        quad = 0.5 * self._prior_inv_var * float(((rssi_dbm - self._prior_mu_dbm) ** 2).sum())
        return _grid_values(self.base, self._prior_offset, float(cols.size), quad, cols, rssi_dbm, self._ap_ptr,
                            self._cell, self._mu, self._inv_var, self._offset, self._prior_mu_dbm,
                            self._prior_inv_var)

    def cell_index(self, xy_m: np.ndarray) -> np.ndarray:
        """Row of the grid tables for each point (the prior cell off the grid or without data)."""
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        col = np.floor((xy[:, 0] - self.origin_m[0]) / self.config.cell_m).astype(np.int64)
        row = np.floor((xy[:, 1] - self.origin_m[1]) / self.config.cell_m).astype(np.int64)
        inside = (row >= 0) & (row < self.shape[0]) & (col >= 0) & (col < self.shape[1])
        flat = np.where(inside, row * self.shape[1] + col, 0)
        return np.where(inside, self.cell_of[flat], self.n_cells)

    def kernel(self, measurement: WifiScan) -> LikelihoodKernel:
        """Each particle reads the value of its grid cell (the prior cell off the grid)."""
        values = self.grid_log_likelihood(measurement)
        rows, cols = self.shape
        head = [self.origin_m[0], self.origin_m[1], 1.0 / self.config.cell_m, rows, cols, values[-1]]
        return LikelihoodKernel(_grid_lookup, np.concatenate([head, values[self.cell_of]]))

    def best_position(self, scan: WifiScan) -> np.ndarray:
        """Centre of the active cell with the highest likelihood: the radio-map likelihood used
        alone (the first such cell, as ``np.argmax`` of ``grid_log_likelihood`` takes it: its
        numbers made in one kernel, without the grid's temporaries)."""
        if self.n_cells == 0:
            return np.full(2, np.nan)
        cols, r = self._heard(scan)
        if not cols.size:
            return self.cell_xy_m[0]  # nothing known heard: every cell alike
        return self.cell_xy_m[_best_cell(self._grid_values(cols, r), float(self.config.exponent))]


# ---- the tables a radio map file keeps (RadioMap.likelihood_tables) ------------------------------
TABLES_VERSION = 1  # the layout of the stored tables; another version is not used (built as if absent)


def keep_tables(radio_map: RadioMap, floorplan: FloorPlan,
                config: RadioMapLikelihoodConfig = RadioMapLikelihoodConfig()) -> RadioMap:
    """Keep the likelihood's grid on ``floorplan`` in the radio map (``RadioMap.likelihood_tables``,
    derived data like its cross-validated errors, written to its file by ``RadioMap.save``) and
    return the map: a walk tracked with the saved map on that plan and ``config`` starts from
    them instead of building them."""
    model = radio_map_likelihood(radio_map, floorplan, config)
    radio_map.likelihood_tables = model.stored_tables(radio_map, floorplan)
    return radio_map


def _parameters(config: RadioMapLikelihoodConfig) -> np.ndarray:
    """Every number the stored grid depends on besides the radio map and the floor plan."""
    return np.array([config.cell_m, config.bandwidth_m, SUPPORT_SIGMAS, SIGMA_FLOOR_DB, PRIOR_SIGMA_DB,
                     PRIOR_WEIGHT, PRIOR_HEARD, PRIOR_RSSI_DBM, HEARD_CLIP, MIN_OBSERVATIONS, MIN_WEIGHT],
                    dtype=np.float64)


def _plan_digest(floorplan: FloorPlan) -> np.ndarray:
    """(32,) uint8: SHA-256 of the floor plan's wall mask, shape, resolution and origin."""
    digest = hashlib.sha256(np.packbits(floorplan.wall_mask).tobytes())
    digest.update(np.array([*floorplan.wall_mask.shape, floorplan.resolution_m, *floorplan.origin_m],
                           dtype=np.float64).tobytes())
    return np.frombuffer(digest.digest(), dtype=np.uint8).copy()


def _radio_map_digest(radio_map: RadioMap) -> np.ndarray:
    """(32,) uint8: SHA-256 of what the likelihood reads of a radio map (positions, their
    uncertainty, RSSI), so that tables of another map, or of this one changed, are never used."""
    digest = hashlib.sha256()
    for array in (radio_map.xy_m, radio_map.xy_sigma_m, radio_map.rssi_dbm):
        digest.update(np.ascontiguousarray(array).tobytes())
    return np.frombuffer(digest.digest(), dtype=np.uint8).copy()


def _stored_grid(radio_map: RadioMap, floorplan: FloorPlan | None, config: RadioMapLikelihoodConfig,
                 use_aps: np.ndarray) -> tuple | None:
    """The grid kept in the radio map's file, if it was made of this map on this plan with this
    configuration, and is whole (every index in range: the numba kernels index with them);
    None otherwise (the likelihood is then built as without it)."""
    tables = radio_map.likelihood_tables
    if floorplan is None or not tables or int(tables.get("version", -1)) != TABLES_VERSION:
        return None
    try:
        if not (np.array_equal(tables["parameters"], _parameters(config))
                and np.array_equal(tables["plan"], _plan_digest(floorplan))
                and np.array_equal(tables["aps"], use_aps)
                and np.array_equal(tables["radio_map"], _radio_map_digest(radio_map))):
            return None
        origin, shape, cells = tables["origin_m"], tables["shape"], tables["cells"]
        w_ptr, w_ref, w_val = tables["weight_ptr"], tables["weight_ref"], tables["weight"]
        w_all, base = tables["w_all"], tables["base"]
    except KeyError:
        return None
    x0, x1, y0, y1 = floorplan.extent_m
    expected_shape = (max(int(math.ceil((y1 - y0) / config.cell_m)), 1),
                      max(int(math.ceil((x1 - x0) / config.cell_m)), 1))
    n = cells.size
    whole = (origin.shape == (2,) and tuple(origin.tolist()) == (float(x0), float(y0))
             and shape.shape == (2,) and tuple(shape.tolist()) == expected_shape
             and cells.ndim == 1 and (n == 0 or (cells[0] >= 0 and cells[-1] < expected_shape[0] * expected_shape[1]
                                                and np.all(np.diff(cells) > 0)))
             and w_ptr.shape == (n + 1,) and w_ptr[0] == 0 and np.all(np.diff(w_ptr) >= 0)
             and w_ref.shape == w_val.shape == (int(w_ptr[-1]),)
             and (w_ref.size == 0 or (w_ref.min() >= 0 and w_ref.max() < len(radio_map)))
             and w_val.dtype == np.float32 and np.all(np.isfinite(w_val))
             and w_all.shape == base.shape == (n + 1,) and np.all(np.isfinite(w_all)) and np.all(np.isfinite(base)))
    if not whole:
        return None
    return ((float(x0), float(y0)), expected_shape, cells.astype(np.int64),
            (w_ptr.astype(np.int64), w_ref.astype(np.int64), w_val), w_all.astype(np.float64), base.astype(np.float64))


def _built_grid(radio_map: RadioMap, floorplan: FloorPlan | None, config: RadioMapLikelihoodConfig) -> tuple:
    """(origin, shape, active cells, kernel weights (CSR: cells x reference points), each cell's
    total weight, None): the grid over the floor plan's extent (else the reference points'
    bounding box plus the kernel's support), its cells near a reference point and free."""
    from scipy import sparse
    from scipy.spatial import cKDTree

    reach = config.bandwidth_m * SUPPORT_SIGMAS
    if floorplan is not None:
        x0, x1, y0, y1 = floorplan.extent_m
    else:
        (x0, y0), (x1, y1) = radio_map.xy_m.min(axis=0) - reach, radio_map.xy_m.max(axis=0) + reach
    shape = (max(int(math.ceil((y1 - y0) / config.cell_m)), 1), max(int(math.ceil((x1 - x0) / config.cell_m)), 1))
    rows, cols = np.indices(shape)
    centres = np.column_stack([x0 + (cols.ravel() + 0.5) * config.cell_m, y0 + (rows.ravel() + 0.5) * config.cell_m])
    near = cKDTree(radio_map.xy_m).query(centres, distance_upper_bound=reach)[0] < np.inf
    if floorplan is not None:
        near &= floorplan.is_free(centres)
    active = np.nonzero(near)[0]
    n_cells = active.size
    # kernel weights cell x reference point, sparse: only points within the support count
    pairs = cKDTree(centres[active]).sparse_distance_matrix(cKDTree(radio_map.xy_m), reach, output_type="coo_matrix")
    kernel = np.exp(-0.5 * pairs.data ** 2 / config.bandwidth_m ** 2)
    if radio_map.is_grown:
        # a point whose position is uncertain (sigma) spreads its reading over the kernel
        # convolved with that uncertainty: variance b^2 + sigma^2, height b^2 / (b^2 + sigma^2)
        # (the 2-D Gaussian's peak), so it counts less and less sharply than a surveyed point
        variance = config.bandwidth_m ** 2 + radio_map.xy_sigma_m[pairs.col] ** 2
        kernel = config.bandwidth_m ** 2 / variance * np.exp(-0.5 * pairs.data ** 2 / variance)
    weight = sparse.csr_matrix((kernel.astype(np.float32), (pairs.row, pairs.col)), shape=(n_cells, len(radio_map)))
    w_all = np.zeros(n_cells + 1)
    w_all[:n_cells] = np.asarray(weight.sum(axis=1)).ravel()
    return ((float(x0), float(y0)), shape, active.astype(np.int64),
            (weight.indptr.astype(np.int64), weight.indices.astype(np.int64), weight.data), w_all, None)


@njit(cache=True, nogil=True)
def _ap_table(cell, ap, wh, s1, s2, w_all):
    """The per-AP table's entries (``RadioMapLikelihood._build_tables``) from the weighted sums:
    those with kernel weight above ``MIN_WEIGHT`` (below it the prior's pseudo-count dominates:
    the prior stays); their AP, cell (int32), RSSI mean and inverse variance (float32), P(heard)
    and 2 pi variance (float64, for the logarithms). The arithmetic of the numpy it replaced, term
    by term, so the same numbers (tests/sensors/test_radiomap_tables.py)."""
    pw = PRIOR_WEIGHT
    mu_prior = pw * PRIOR_RSSI_DBM
    var_prior = pw * PRIOR_SIGMA_DB ** 2
    var_floor = SIGMA_FLOOR_DB ** 2
    heard_prior = pw * PRIOR_HEARD
    low = HEARD_CLIP
    high = 1 - HEARD_CLIP
    two_pi = 2 * np.pi
    n = 0
    for i in range(wh.shape[0]):
        if wh[i] > MIN_WEIGHT:
            n += 1
    ap_out = np.empty(n, dtype=np.int64)
    cell_out = np.empty(n, dtype=np.int32)
    mu_out = np.empty(n, dtype=np.float32)
    inv_var_out = np.empty(n, dtype=np.float32)
    p_out = np.empty(n)
    two_pi_var = np.empty(n)
    k = 0
    for i in range(wh.shape[0]):
        w = wh[i]
        if not w > MIN_WEIGHT:
            continue
        mu = (s1[i] + mu_prior) / (w + pw)
        # weighted spread around mu, the prior's spread counting as pw pseudo-observations
        var = (s2[i] - 2 * mu * s1[i] + mu * mu * w + var_prior) / (w + pw)
        var = (var if var >= 0.0 or var != var else 0.0) + var_floor  # np.maximum(var, 0): NaN stays
        p = (w + heard_prior) / (w_all[cell[i]] + pw)
        if p < low:  # np.clip
            p = low
        elif p > high:
            p = high
        ap_out[k] = ap[i]
        cell_out[k] = cell[i]
        mu_out[k] = mu
        inv_var_out[k] = 1.0 / var
        p_out[k] = p
        two_pi_var[k] = two_pi * var
        k += 1
    return ap_out, cell_out, mu_out, inv_var_out, p_out, two_pi_var


@njit(cache=True, nogil=True)
def _offset(log_p, log_two_pi_var, log_not_p):
    """log h + the Gaussian's log normaliser - log(1 - h), float32 (``_ap_table``'s entries)."""
    out = np.empty(log_p.shape[0], dtype=np.float32)
    for i in range(log_p.shape[0]):
        out[i] = log_p[i] - 0.5 * log_two_pi_var[i] - log_not_p[i]
    return out


@njit(cache=True, nogil=True)
def _weighted_sums(c_ptr, c_cell, c_val, ap_ptr, reading_ref, reading_rssi, aps, n_cells):
    """Per AP of ``aps`` (ascending) and per cell near a reference point that heard it: sum w,
    sum w r and sum w r^2 in float32 over those points in ascending order, w the cell's kernel
    weight of the point (``c_*``: the weights by point, CSC) and r the point's reading (``ap_ptr``,
    ``reading_*``: the readings by AP, CSR): the order of scipy's sparse product (csr_matmat) of
    the weights (each cell's row in point order) by the readings, whose numbers the likelihood
    has always had. Entries in (AP, cell) order."""
    # plain loops, no numpy function that numba implements in numba.np.arraymath: loading a kernel
    # that calls one imports it, and with it scipy.linalg (runtime/numba_cache.py)
    seen = np.empty(n_cells, dtype=np.int64)
    seen[:] = -1
    total = 0
    for t in range(aps.shape[0]):
        a = aps[t]
        for kk in range(ap_ptr[a], ap_ptr[a + 1]):
            r = reading_ref[kk]
            for jj in range(c_ptr[r], c_ptr[r + 1]):
                c = c_cell[jj]
                if seen[c] != a:
                    seen[c] = a
                    total += 1
    cell = np.empty(total, dtype=np.int64)
    ap = np.empty(total, dtype=np.int64)
    wh = np.empty(total, dtype=np.float32)
    s1 = np.empty(total, dtype=np.float32)
    s2 = np.empty(total, dtype=np.float32)
    acc_w = np.zeros(n_cells, dtype=np.float32)
    acc_1 = np.zeros(n_cells, dtype=np.float32)
    acc_2 = np.zeros(n_cells, dtype=np.float32)
    touched = np.zeros(n_cells, dtype=np.bool_)
    e = 0
    for t in range(aps.shape[0]):
        a = aps[t]
        for kk in range(ap_ptr[a], ap_ptr[a + 1]):
            r = reading_ref[kk]
            x = reading_rssi[kk]
            for jj in range(c_ptr[r], c_ptr[r + 1]):
                c = c_cell[jj]
                v = c_val[jj]
                acc_w[c] += v
                acc_1[c] += v * x
                acc_2[c] += v * (x * x)
                touched[c] = True
        for c in range(n_cells):  # the AP's cells in cell order
            if touched[c]:
                cell[e] = c
                ap[e] = a
                wh[e] = acc_w[c]
                s1[e] = acc_1[c]
                s2[e] = acc_2[c]
                e += 1
                acc_w[c] = 0.0
                acc_1[c] = 0.0
                acc_2[c] = 0.0
                touched[c] = False
    return cell, ap, wh, s1, s2


@njit(cache=True, nogil=True)
def _not_heard_entries(c_ptr, c_cell, c_val, ap_ptr, reading_ref, n_cells, w_all, p0):
    """The not-heard base's corrections (``RadioMapLikelihood._not_heard_base``): per AP in order,
    its cells' kernel weight summed in float32 over the reference points that heard it in order
    (``_weighted_sums``' sums), and where that weight is above ``MIN_WEIGHT`` the cell's P(heard),
    clipped as numpy clips it; (cell, P(heard)) of the pairs whose P(heard) is not the prior's
    ``p0`` (their term is exactly zero), in (AP, cell first reached) order. One pass, no sweep of
    every cell per AP."""
    heard_prior = PRIOR_WEIGHT * PRIOR_HEARD
    low = HEARD_CLIP
    high = 1 - HEARD_CLIP
    acc = np.zeros(n_cells, dtype=np.float32)
    touched = np.zeros(n_cells, dtype=np.bool_)
    reached = np.empty(n_cells, dtype=np.int64)
    cell_out = np.empty(max(n_cells, 16), dtype=np.int64)
    p_out = np.empty(cell_out.shape[0])
    e = 0
    for a in range(ap_ptr.shape[0] - 1):
        n = 0
        for kk in range(ap_ptr[a], ap_ptr[a + 1]):
            r = reading_ref[kk]
            for jj in range(c_ptr[r], c_ptr[r + 1]):
                c = c_cell[jj]
                if not touched[c]:
                    touched[c] = True
                    reached[n] = c
                    n += 1
                acc[c] += c_val[jj]
        if e + n > cell_out.shape[0]:  # room for every cell this AP reached
            grown = max(2 * cell_out.shape[0], e + n)
            cell_new = np.empty(grown, dtype=np.int64)
            p_new = np.empty(grown)
            cell_new[:e] = cell_out[:e]
            p_new[:e] = p_out[:e]
            cell_out, p_out = cell_new, p_new
        for t in range(n):
            c = reached[t]
            w = np.float64(acc[c])
            acc[c] = 0.0
            touched[c] = False
            if w > MIN_WEIGHT:
                p = (w + heard_prior) / (w_all[c] + PRIOR_WEIGHT)
                if p < low:  # np.clip
                    p = low
                elif p > high:
                    p = high
                if p != p0[c]:
                    cell_out[e] = c
                    p_out[e] = p
                    e += 1
    return cell_out[:e].copy(), p_out[:e].copy()


@njit(cache=True, nogil=True)
def _add_in_order(out, index, values):
    """``np.add.at(out, index, values)``: each value added in order."""
    for i in range(index.shape[0]):
        out[index[i]] += values[i]


# id(radio map) -> (weak reference to it, its arrays when the entry was made, {(id(floor plan),
# config): (floor plan, likelihood)})
_MEMO: dict[int, tuple] = {}


def radio_map_likelihood(radio_map: RadioMap, floorplan: FloorPlan | None = None,
                         config: RadioMapLikelihoodConfig = RadioMapLikelihoodConfig(),
                         heard_keys: Collection[str] | None = None) -> RadioMapLikelihood:
    """The radio map's likelihood on ``floorplan``, built once per radio map and reused by every
    walk tracked with it in this process (its per-AP tables grow as walks hear more APs; the
    numbers are the same as a likelihood built for one walk). Forgotten with the radio map, or
    when its arrays are replaced. ``heard_keys``: the APs a walk hears, whose tables are built
    now in one go (one sparse product instead of one per scan that hears a new AP)."""
    arrays = (radio_map.xy_m, radio_map.rssi_dbm)
    entry = _MEMO.get(id(radio_map))
    if entry is None or entry[0]() is not radio_map or any(a is not b for a, b in zip(entry[1], arrays)):
        entry = (weakref.ref(radio_map, lambda _, key=id(radio_map): _MEMO.pop(key, None)), arrays, {})
        _MEMO[id(radio_map)] = entry
    models = entry[2]
    hit = models.get((id(floorplan), config))
    if hit is None or hit[0] is not floorplan:
        hit = (floorplan, RadioMapLikelihood(radio_map, floorplan, config))
        models[(id(floorplan), config)] = hit
    if heard_keys is not None:
        hit[1].build_tables(heard_keys)
    return hit[1]


@njit(LIKELIHOOD_SIGNATURE, cache=True, nogil=True, error_model="numpy")
def _grid_lookup(params, state, lo, m, out):
    # params: x0, y0, 1 / cell, rows, columns, the value off the grid, then the value of every cell row by row
    x0 = params[0]
    y0 = params[1]
    inv_cell = params[2]
    rows = int(params[3])
    cols = int(params[4])
    for j in range(m):
        u = (state[X, lo + j] - x0) * inv_cell
        v = (state[Y, lo + j] - y0) * inv_cell
        if 0.0 <= u < cols and 0.0 <= v < rows:
            out[j] = params[6 + int(v) * cols + int(u)]
        else:
            out[j] = params[5]


@njit(cache=True)
def _add_heard_corrections(out, cols, rssi, ap_ptr, cell, mu, inv_var, offset, prior_offset, prior_mu, prior_inv_var):
    """Swap the prior term of each heard AP for its own on the cells where it has data."""
    for i in range(cols.shape[0]):
        r = rssi[i]
        prior_quad = 0.5 * prior_inv_var * (r - prior_mu) ** 2
        for e in range(ap_ptr[cols[i]], ap_ptr[cols[i] + 1]):
            c = cell[e]
            d = r - mu[e]
            out[c] += (offset[e] - 0.5 * inv_var[e] * d * d) - (prior_offset[c] - prior_quad)


@njit(cache=True, nogil=True)
def _grid_values(base, prior_offset, n_heard, quad, cols, rssi, ap_ptr, cell, mu, inv_var, offset, prior_mu,
                 prior_inv_var):
    """``RadioMapLikelihood.grid_log_likelihood`` before its exponent, every cell and the prior
    one, without the grid's temporaries: every heard AP at its prior (``quad``: their quadratic
    terms' sum), then the cells where it has data replace that term."""
    out = np.empty(base.shape[0])
    for c in range(base.shape[0]):
        out[c] = base[c] + n_heard * prior_offset[c]
        out[c] -= quad
    _add_heard_corrections(out, cols, rssi, ap_ptr, cell, mu, inv_var, offset, prior_offset, prior_mu,
                           prior_inv_var)
    return out


@njit(cache=True, nogil=True)
def _best_cell(values, exponent):
    """``np.argmax(exponent * values[:-1])`` (``RadioMapLikelihood.best_position``): the first
    maximum (or first NaN, as numpy's) of the active cells (the last value is the prior cell's)."""
    best = 0
    top = exponent * values[0]
    if top != top:
        return 0
    for c in range(1, values.shape[0] - 1):
        v = exponent * values[c]
        if v != v:
            return c
        if v > top:
            best = c
            top = v
    return best
