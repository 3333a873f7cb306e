"""The barometer as floor evidence: a height from pressure, read against a reference floor.

A phone barometer measures height *changes* only (the weather moves its zero), so the filter
reads it against a reference: a floor it was sure of and the barometer's height then
(``BarometerReference``). ``barometric_height`` turns pressure into height.
"""

from __future__ import annotations

import dataclasses

import math

import numpy as np

from mapfilter.errors import MapfilterError


# When the reference moves (``BarometerReference.update``): only to a floor the filter is sure of
# (ANCHOR_SHARE of the weight) while the height is steady (less than STEADY_M of change over
# STEADY_WINDOW_S), and no faster than the weather moves a barometer
ANCHOR_SHARE = 0.95  # the reference moves to a floor only when this share of the weight is on it
STEADY_M = 0.5  # ... and the height changed less than this ...
STEADY_WINDOW_S = 3.0  # ... over this long
# 0.01 m/s is 36 m/h, about 4 hPa/h, above any weather front (1-3 hPa/h); a climber pausing on
# the stairs looks steady for a few seconds, and a faster reference would follow each pause
DRIFT_M_PER_S = 0.01
# pressure readings of the last this-many seconds make one height (a phone barometer's noise is
# about 0.25 m per sample)
SMOOTHING_WINDOW_S = 2.0
# a scan weighs the barometer's zero by its match to each floor's fingerprints (dB per AP, as
# the survey reach's): floor f gains -(d_f^2 - d_min^2) / (2 tau^2); the middle of the 2-8 dB over
# which a per-floor best-match vote was tried (docs/accuracy.md), set before any run
ZERO_MATCH_TAU_DB = 4.0


@dataclasses.dataclass(frozen=True)
class BarometerConfig:
    """How the barometer weighs floors (a phone barometer: about 0.25 m noise per sample)."""

    # a barometer's height is good to about 0.25 m per sample and drifts with the weather by
    # well under a metre in ten minutes; 1 m keeps a storey (4-5 m) four sigmas or more away
    sigma_m: float = 1.0  # spread of the height a floor is expected at

    def __post_init__(self) -> None:
        if not (self.sigma_m > 0 and np.isfinite(self.sigma_m)):
            raise MapfilterError(f"barometer setting sigma_m must be a positive number, got {self.sigma_m}")


class BarometerReference:
    """The barometer's zero for floor evidence: which floor the walker stood on at height zero.

    A phone barometer measures height *changes* only. Hypothesis j: the walker stood on floor j
    when the barometer read zero, so at height h stands at elevation e_j + h - drift (``drift_m``
    follows the weather). ``floor_log_likelihood`` gives floor f the mixture
    log sum_j P(j) exp(-(e_f - (e_j + h - drift))^2 / (2 sigma_m^2)).

    With WiFi, the scans weigh the hypotheses (``observe_scan``: each scan's match to each floor's
    fingerprints, at the floor each hypothesis puts the walker on), never the filter's own floor:
    a filter sure of a wrong floor early (a start that matches the floor below 1 dB better) would
    otherwise be held there by the barometer for good, however well a later stretch matches the
    right floor (IPIN trial 01, docs/accuracy.md). A known start settles it (``start_on``).
    Without WiFi (the barometer beside other measurement sources) the reference is the filter's:
    ``update`` sets it when the filter is sure of its floor (``ANCHOR_SHARE``) while the height
    is steady, and moves it to a floor the barometer agrees with. Either way, while the height is
    steady and one hypothesis holds ``ANCHOR_SHARE``, the zero follows the nearest floor no faster
    than the weather moves a barometer (``DRIFT_M_PER_S``).
    """

    def __init__(self, elevation_m: np.ndarray, config: BarometerConfig = BarometerConfig()) -> None:
        self.elevation_m = np.asarray(elevation_m, dtype=np.float64)
        self.config = config
        self.log_p: np.ndarray | None = None  # (F,) log P(floor j at height zero); None: no evidence yet
        self.drift_m = 0.0
        self._t_drift: float | None = None  # when the drift last moved (or the reference was set)
        self._from_scans = False  # the scans weigh the hypotheses (the filter's floor never does then)

    def start_on(self, floor: int, height_m: float) -> None:
        """The walker is known to be on ``floor`` at barometer height ``height_m`` (a known start)."""
        self._set(floor, height_m)
        self._from_scans = True  # the user's floor, not the filter's: the scans cannot move it

    def observe_scan(self, height_m: float, match_db: np.ndarray, in_survey: float = 1.0) -> None:
        """A scan at barometer height ``height_m``, its match distance (dB) to each floor's
        fingerprints (``radiomap.match_distance_by_floor_db``; inf: none shares enough APs) and
        the probability that it was taken inside the survey (``filter.models.survey_reach``): each
        hypothesis gains -w (d_f^2 - d_min^2) / (2 tau^2) at the floor f it puts the walker on
        (``ZERO_MATCH_TAU_DB``; a floor nobody surveyed as the scan's worst). A scan from where
        nobody surveyed matches every floor poorly, and best the floor surveyed above or below
        it: it says little (w small)."""
        match = np.asarray(match_db, dtype=np.float64)
        finite = np.isfinite(match)
        if not finite.any():
            return
        if not self._from_scans:  # every floor alike at first, whatever the filter took before
            self._from_scans = True
            self.log_p = np.full(self.elevation_m.size, -math.log(self.elevation_m.size))
            self.drift_m, self._t_drift = 0.0, None
        d = np.where(finite, match, match[finite].max())
        scan_ll = -in_survey * (d ** 2 - d.min() ** 2) / (2.0 * ZERO_MATCH_TAU_DB ** 2)
        # (J, F): hypothesis j puts the walker at floor f as well as the barometer allows, each row
        # scaled so that it sums to its best floor's fit: a height off every floor under j still
        # rules j out, but no hypothesis gains from its neighbours' tails (summed, a middle floor's
        # gained two at every scan, and a walk whose scans tell the floors apart no better than
        # chance drifted to the middle floor: IPIN trial 21, surveyed on one floor only)
        height_ll = self._height_log_likelihood(height_m)
        tails = _logsumexp(height_ll, axis=1) - height_ll.max(axis=1)
        ll = scan_ll[None, :] + height_ll - tails[:, None]
        self.log_p = _normalised_log(self.log_p + _logsumexp(ll, axis=1))

    def update(self, t_s: float, height_m: float, steady: bool, floor_shares: np.ndarray) -> None:
        """After a filter step at ``t_s``: the barometer's height, whether it was steady, and the
        filter's share of weight per floor (read only without WiFi)."""
        if not steady:
            return
        if self._from_scans:  # follow the floor nearest the most probable hypothesis
            target = self.sure_floor_at(height_m)
            if target is None:
                return
        else:  # follow the filter's floor
            if float(np.max(floor_shares)) < ANCHOR_SHARE:
                return
            target = int(np.argmax(floor_shares))
            if self.log_p is None:
                self._set(target, height_m, t_s)
                return
        residual = self._expected_m(height_m) - self.elevation_m[target]
        # never move to a floor the barometer disagrees with: a filter that missed a floor change
        # would otherwise silence the barometer for good (and on the stairs there is none to follow)
        if abs(residual) > 2.0 * self.config.sigma_m:
            return
        drift = DRIFT_M_PER_S * max(t_s - (t_s if self._t_drift is None else self._t_drift), 0.0)
        self.drift_m += float(np.clip(residual, -drift, drift))
        self._t_drift = t_s

    def floor_log_likelihood(self, height_m: float) -> np.ndarray | None:
        """(F,) log-likelihood of each floor at barometer height ``height_m``; None before any evidence."""
        if self.log_p is None:
            return None
        return _logsumexp(self.log_p[:, None] + self._height_log_likelihood(height_m), axis=0)

    def floor_at(self, height_m: float) -> int:
        """The floor nearest the walker's elevation at ``height_m`` under the most probable hypothesis."""
        return self._nearest_floor(self._expected_m(height_m))

    def sure_floor_at(self, height_m: float) -> int | None:
        """``floor_at`` when one hypothesis holds ``ANCHOR_SHARE`` or more, else None."""
        if self.log_p is None or float(np.exp(self.log_p.max())) < ANCHOR_SHARE:
            return None
        return self.floor_at(height_m)

    def _height_log_likelihood(self, height_m: float) -> np.ndarray:
        """(J, F): -(e_f - (e_j + h - drift))^2 / (2 sigma^2)."""
        expected = self.elevation_m + height_m - self.drift_m
        return -0.5 * ((self.elevation_m[None, :] - expected[:, None]) / self.config.sigma_m) ** 2

    def _expected_m(self, height_m: float) -> float:
        """The walker's elevation at ``height_m`` under the most probable hypothesis."""
        return float(self.elevation_m[int(np.argmax(self.log_p))] + height_m - self.drift_m)

    def _nearest_floor(self, elevation_m: float) -> int:
        return int(np.argmin(np.abs(self.elevation_m - elevation_m)))

    def _set(self, floor: int, height_m: float, t_s: float | None = None) -> None:
        """The walker on ``floor`` at ``height_m``: one hypothesis, the drift that puts it there."""
        zero = self._nearest_floor(self.elevation_m[floor] - height_m)
        self.log_p = np.where(np.arange(self.elevation_m.size) == zero, 0.0, -np.inf)
        self.drift_m = float(self.elevation_m[zero] + height_m - self.elevation_m[floor])
        self._t_drift = t_s


def _logsumexp(a: np.ndarray, axis: int) -> np.ndarray:
    m = np.max(a, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    return np.squeeze(m, axis=axis) + np.log(np.sum(np.exp(a - m), axis=axis))


def _normalised_log(log_p: np.ndarray) -> np.ndarray:
    return log_p - _logsumexp(log_p, axis=0)


def barometric_height(t_s: np.ndarray, pressure_hpa: np.ndarray, window_s: float = SMOOTHING_WINDOW_S,
                      centred: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(times, heights in metres relative to the first sample) from barometer readings: the
    international barometric formula h = 44330.8 (1 - (p / p_first)^(1 / 5.25588)) of the
    pressure smoothed causally, from the readings of the last ``window_s`` only (a phone
    barometer's noise is about 0.25 m per sample): the end of a straight line fitted to them,
    which, unlike their mean, does not lag a climb or a ride by half the window.

    ``centred`` (offline, the whole walk at hand): the same line read at its middle, i.e. the
    window's mean at the window's mean time, with half the noise of its end."""
    t = np.asarray(t_s, dtype=np.float64)
    p_hpa = np.asarray(pressure_hpa, dtype=np.float64)
    p = p_hpa - p_hpa[0]  # small numbers keep the windowed sums exact over long logs
    tr = t - t[0]
    lo = np.searchsorted(t, t - window_s, side="left")
    hi = np.arange(1, t.size + 1)  # reading i's window ends at reading i

    def window_sum(x: np.ndarray) -> np.ndarray:
        cum = np.concatenate([[0.0], np.cumsum(x)])
        return cum[hi] - cum[lo]

    # least squares p = mean_p + slope (t - mean_t) over each window, at the window's last reading
    n = (hi - lo).astype(np.float64)
    mean_t, mean_p = window_sum(tr) / n, window_sum(p) / n
    var_t = window_sum(tr * tr) / n - mean_t ** 2
    cov = window_sum(tr * p) / n - mean_t * mean_p
    slope = np.where(var_t > 1e-9, cov / np.maximum(var_t, 1e-9), 0.0)
    if centred:
        t, smooth = t[0] + mean_t, p_hpa[0] + mean_p
    else:
        smooth = p_hpa[0] + mean_p + slope * (tr - mean_t)
    return t, 44330.8 * (1.0 - (smooth / smooth[0]) ** (1.0 / 5.25588))


class BarometricHeights:
    """``barometric_height`` of readings that come in pieces (a live run), each reading's height
    made once: the same numbers, to the bit, as ``barometric_height`` of every reading so far (its
    windowed sums are differences of running sums, and a running sum carried on is the whole's),
    at a cost per piece that does not grow with the walk."""

    def __init__(self, window_s: float = SMOOTHING_WINDOW_S) -> None:
        self.window_s = window_s
        self._n = 0
        self._t = np.zeros(64)
        self._hpa = np.zeros(64)
        self._height = np.zeros(64)
        self._cum = np.zeros((65, 4))  # running sums of tr, p, tr^2, tr p (row 0: none yet)
        self._smooth_first = math.nan

    def __len__(self) -> int:
        return self._n

    @property
    def t_s(self) -> np.ndarray:
        return self._t[:self._n]

    @property
    def pressure_hpa(self) -> np.ndarray:
        return self._hpa[:self._n]

    @property
    def height_m(self) -> np.ndarray:
        return self._height[:self._n]

    def add(self, t_s: np.ndarray, pressure_hpa: np.ndarray) -> None:
        """The next readings (in time order, after those already added)."""
        t_new = np.asarray(t_s, dtype=np.float64).reshape(-1)
        hpa_new = np.asarray(pressure_hpa, dtype=np.float64).reshape(-1)
        if t_new.size == 0:
            return
        k0, k1 = self._n, self._n + t_new.size
        if k1 > self._t.size:  # twice the room
            size = max(2 * self._t.size, k1)
            self._t, self._hpa, self._height = (np.resize(a, size) for a in (self._t, self._hpa, self._height))
            self._cum = np.resize(self._cum, (size + 1, 4))
        self._t[k0:k1], self._hpa[k0:k1] = t_new, hpa_new
        self._n = k1
        t, hpa = self._t[:k1], self._hpa[:k1]
        p = hpa_new - hpa[0]  # small numbers keep the windowed sums exact over long logs
        tr = t_new - t[0]
        for j, x in enumerate((tr, p, tr * tr, tr * p)):
            self._cum[k0 + 1:k1 + 1, j] = np.cumsum(np.concatenate([[self._cum[k0, j]], x]))[1:]
        lo = np.searchsorted(t, t_new - self.window_s, side="left")
        hi = np.arange(k0 + 1, k1 + 1)  # reading i's window ends at reading i
        sums = self._cum[hi] - self._cum[lo]
        n = (hi - lo).astype(np.float64)
        mean_t, mean_p = sums[:, 0] / n, sums[:, 1] / n
        var_t = sums[:, 2] / n - mean_t ** 2
        cov = sums[:, 3] / n - mean_t * mean_p
        slope = np.where(var_t > 1e-9, cov / np.maximum(var_t, 1e-9), 0.0)
        smooth = hpa[0] + mean_p + slope * (tr - mean_t)
        if k0 == 0:
            self._smooth_first = float(smooth[0])
        self._height[k0:k1] = 44330.8 * (1.0 - (smooth / self._smooth_first) ** (1.0 / 5.25588))
