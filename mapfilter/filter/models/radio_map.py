"""The radio map as a per-particle likelihood (a ``MeasurementModel``): no point fix, every particle
weighed by the radio map's own probability of the scan at its position."""

from __future__ import annotations

import dataclasses
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
    """

    kind = "radio_map"

    def __init__(self, radio_map: RadioMap, floorplan: FloorPlan | None = None,
                 config: RadioMapLikelihoodConfig = RadioMapLikelihoodConfig(),
                 heard_keys: Collection[str] | None = None):
        """``heard_keys``: the APs the scans to be weighed can hear (e.g. every AP of one walk).
        Only their per-AP tables are built (a walk hears a tenth of a mall's APs: most of the
        build's time and memory); every AP still counts where it is *not* heard. An AP outside
        the set, heard by a scan anyway, is ignored like an AP the radio map does not know.
        None: all APs."""
        from scipy.spatial import cKDTree

        cfg = self.config = config
        heard = ~np.isnan(radio_map.rssi_dbm)
        use_aps = np.nonzero(heard.sum(axis=0) >= MIN_OBSERVATIONS)[0]
        if use_aps.size == 0 or len(radio_map) == 0:
            raise MapfilterError(f"the radio map has no AP heard in {MIN_OBSERVATIONS} reference points")
        self.ap_keys = [radio_map.ap_keys[j] for j in use_aps]
        tabled = np.ones(use_aps.size, dtype=bool) if heard_keys is None else np.isin(self.ap_keys, list(heard_keys))
        self.key_index = {key: j for j, key in enumerate(self.ap_keys) if tabled[j]}
        n_aps = use_aps.size
        # grid: the floor plan's extent, else the reference points' bounding box plus the kernel support
        reach = cfg.bandwidth_m * SUPPORT_SIGMAS
        if floorplan is not None:
            x0, x1, y0, y1 = floorplan.extent_m
        else:
            (x0, y0), (x1, y1) = radio_map.xy_m.min(axis=0) - reach, radio_map.xy_m.max(axis=0) + reach
        self.origin_m = (float(x0), float(y0))
        self.shape = (max(int(math.ceil((y1 - y0) / cfg.cell_m)), 1), max(int(math.ceil((x1 - x0) / cfg.cell_m)), 1))
        rows, cols = np.indices(self.shape)
        centres = np.column_stack([x0 + (cols.ravel() + 0.5) * cfg.cell_m, y0 + (rows.ravel() + 0.5) * cfg.cell_m])
        near = cKDTree(radio_map.xy_m).query(centres, distance_upper_bound=reach)[0] < np.inf
        if floorplan is not None:
            near &= floorplan.is_free(centres)
        active = np.nonzero(near)[0]
        n_cells = active.size
        self.cell_of = np.full(centres.shape[0], n_cells, dtype=np.int64)  # row n_cells = the prior cell
        self.cell_of[active] = np.arange(n_cells)
        self.cell_xy_m = centres[active]

        prior_var = PRIOR_SIGMA_DB ** 2 + SIGMA_FLOOR_DB ** 2
        # kernel weights cell x reference point, sparse: only points within the support count,
        # and a point hears a few per cent of the APs, so W @ H is a sparse product
        from scipy import sparse

        pairs = cKDTree(self.cell_xy_m).sparse_distance_matrix(cKDTree(radio_map.xy_m), reach,
                                                                 output_type="coo_matrix")
        kernel = np.exp(-0.5 * pairs.data ** 2 / cfg.bandwidth_m ** 2)
        if radio_map.is_grown:
            # a point whose position is uncertain (sigma) spreads its reading over the kernel
            # convolved with that uncertainty: variance b^2 + sigma^2, height b^2 / (b^2 + sigma^2)
            # (the 2-D Gaussian's peak), so it counts less and less sharply than a surveyed point
            variance = cfg.bandwidth_m ** 2 + radio_map.xy_sigma_m[pairs.col] ** 2
            kernel = cfg.bandwidth_m ** 2 / variance * np.exp(-0.5 * pairs.data ** 2 / variance)
        weight = sparse.csr_matrix((kernel.astype(np.float32), (pairs.row, pairs.col)),
                                   shape=(n_cells, len(radio_map)))
        w_all = np.zeros(n_cells + 1)
        w_all[:n_cells] = np.asarray(weight.sum(axis=1)).ravel()
        observed = heard[:, use_aps]
        ref, ap_col = np.nonzero(observed)
        values = radio_map.rssi_dbm[:, use_aps][ref, ap_col].astype(np.float32)
        # P(heard) of every AP (for the not-heard term) as a sparse product (the RSSI sums of an
        # AP come when its table is built)
        heard_sum = (weight @ sparse.csr_matrix((np.ones_like(values), (ref, ap_col)),
                                                shape=(len(radio_map), n_aps))).tocsr()
        heard_sum.sort_indices()
        heard_sum = heard_sum.tocoo()
        all_cell, all_ap = heard_sum.row.astype(np.int64), heard_sum.col.astype(np.int64)
        all_wh = heard_sum.data.astype(np.float64)
        # the per-AP tables are built when a scan first hears the AP (_build_tables): what they need
        self._weight, self._n_refs, self._n_aps = weight, len(radio_map), n_aps
        self._observed = (ref, ap_col, values)
        self._entries = (all_cell, all_ap, all_wh)
        self._w_all = w_all
        self._built = ~tabled  # an AP outside heard_keys never gets a table
        self._tables: list[tuple[np.ndarray, ...]] = []  # per batch: (ap, cell, mu, 1/var, offset)
        self._ap_ptr = np.zeros(n_aps + 1, dtype=np.int64)
        self._cell = np.zeros(0, dtype=np.int32)
        self._mu = self._inv_var = self._offset = np.zeros(0, dtype=np.float32)
        clip = HEARD_CLIP
        pw = PRIOR_WEIGHT
        # the prior per cell: an AP never heard near the cell
        p0 = np.clip(PRIOR_WEIGHT * PRIOR_HEARD / (w_all + PRIOR_WEIGHT), clip, 1 - clip)
        self._prior_mu_dbm = PRIOR_RSSI_DBM
        self._prior_inv_var = 1.0 / prior_var
        self._prior_offset = np.log(p0) - 0.5 * np.log(2 * np.pi * prior_var) - np.log1p(-p0)  # (cells + 1,)
        # every AP unheard: the prior everywhere, corrected where an AP has data (all APs)
        self.base = n_aps * np.log1p(-p0)
        data = all_wh > MIN_WEIGHT
        base_cell = all_cell[data]
        p_heard_all = np.clip((all_wh[data] + pw * PRIOR_HEARD) / (w_all[base_cell] + pw), clip, 1 - clip)
        np.add.at(self.base, base_cell, np.log1p(-p_heard_all) - np.log1p(-p0[base_cell]))

    def build_tables(self, keys: Collection[str]) -> None:
        """Build the per-AP tables of these APs now (else each is built when a scan first hears it)."""
        cols = [self.key_index[key] for key in keys if key in self.key_index]
        self._build_tables(np.array(cols, dtype=np.int64))

    def _build_tables(self, cols: np.ndarray) -> None:
        """The per-AP tables of the APs ``cols`` not built yet: each AP's RSSI mean, spread and
        P(heard) on the cells where it has data. An AP's table depends on its own readings only,
        so building some now and others later gives the same numbers as building all at once."""
        from scipy import sparse

        new = np.unique(cols[~self._built[cols]])
        if new.size == 0:
            return
        self._built[new] = True
        n_aps = self._n_aps
        ref, ap_col, values = self._observed
        all_cell, all_ap, all_wh = self._entries
        w_all = self._w_all
        tabled = np.zeros(n_aps, dtype=bool)
        tabled[new] = True
        # the RSSI sums of these APs, as a sparse product whose entries line up with the P(heard)
        # sums' (an entry's pattern is the same: sparse products drop exact zeros only, and r < 0)
        mine = tabled[ap_col]
        rssi_sums = (self._weight @ sparse.csr_matrix(
            (np.concatenate([values[mine], values[mine] ** 2]),
             (np.tile(ref[mine], 2), np.concatenate([ap_col[mine], ap_col[mine] + n_aps]))),
            shape=(self._n_refs, 2 * n_aps))).tocsr()
        rssi_sums.sort_indices()
        rssi_sums = rssi_sums.tocoo()
        block = rssi_sums.col // n_aps
        s1, s2 = (rssi_sums.data[block == b].astype(np.float64) for b in range(2))
        in_table = tabled[all_ap]
        cell, ap, wh = all_cell[in_table], all_ap[in_table], all_wh[in_table]
        # below the threshold the prior's pseudo-count dominates: keep the prior there
        keep = wh > MIN_WEIGHT
        cell, ap, wh, s1, s2 = cell[keep], ap[keep], wh[keep], s1[keep], s2[keep]
        pw = PRIOR_WEIGHT
        mu = (s1 + pw * PRIOR_RSSI_DBM) / (wh + pw)
        # weighted spread around mu, the prior's spread counting as pw pseudo-observations
        var = (s2 - 2 * mu * s1 + mu * mu * wh + pw * PRIOR_SIGMA_DB ** 2) / (wh + pw)
        var = np.maximum(var, 0.0) + SIGMA_FLOOR_DB ** 2
        p_heard = (wh + pw * PRIOR_HEARD) / (w_all[cell] + pw)
        ap, cell = ap.astype(np.int64), cell.astype(np.int64)
        p_heard = np.clip(p_heard, HEARD_CLIP, 1 - HEARD_CLIP)
        self._tables.append((ap, cell.astype(np.int32), mu.astype(np.float32), (1.0 / var).astype(np.float32),
                             (np.log(p_heard) - 0.5 * np.log(2 * np.pi * var) - np.log1p(-p_heard)).astype(np.float32)))
        # sparse per-AP tables (CSR by AP): log h + log N normaliser - log(1 - h), mean, 1/var;
        # each AP's entries come from one batch, in cell order
        ap, cell, mu, inv_var, offset = (np.concatenate(parts) for parts in zip(*self._tables))
        order = np.argsort(ap, kind="stable")
        self._ap_ptr = np.searchsorted(ap[order], np.arange(n_aps + 1))
        self._cell, self._mu, self._inv_var, self._offset = cell[order], mu[order], inv_var[order], offset[order]

    @property
    def n_cells(self) -> int:
        """Active grid cells (the prior cell not counted)."""
        return self.cell_xy_m.shape[0]

    def grid_log_likelihood(self, scan: WifiScan) -> np.ndarray:
        """Log-likelihood of the scan at every active cell plus the prior cell, shape (cells + 1,)."""
        cols, rssi = [], []
        for key, value in zip(scan.ap_keys, scan.rssi_dbm):
            j = self.key_index.get(key)
            if j is not None:
                cols.append(j)
                rssi.append(float(value))
        out = np.zeros(self.n_cells + 1)
        if not cols:
            return out  # nothing known heard: no information
        r = np.array(rssi)
        self._build_tables(np.array(cols, dtype=np.int64))
        # every heard AP at its prior, then the cells where it has data replace that term
        out += self.base + len(cols) * self._prior_offset
        out -= 0.5 * self._prior_inv_var * float(((r - self._prior_mu_dbm) ** 2).sum())
        _add_heard_corrections(out, np.array(cols, dtype=np.int64), r, self._ap_ptr, self._cell, self._mu,
                               self._inv_var, self._offset, self._prior_offset, self._prior_mu_dbm,
                               self._prior_inv_var)
        return self.config.exponent * out

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
        """Centre of the active cell with the highest likelihood: the radio-map likelihood used alone."""
        ll = self.grid_log_likelihood(scan)[:-1]
        if ll.size == 0:
            return np.full(2, np.nan)
        return self.cell_xy_m[int(np.argmax(ll))]


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
