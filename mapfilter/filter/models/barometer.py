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
    """The barometer's zero for floor evidence: a floor the filter was sure of and the height then.

    ``update`` sets the reference when the filter is sure of its floor (``ANCHOR_SHARE``)
    while the height is steady, and afterwards moves it no faster than the weather moves a
    barometer (``DRIFT_M_PER_S``), never to a floor the barometer disagrees with;
    ``floor_log_likelihood`` gives a floor of elevation e the value
    -(e - (e_ref + h - h_ref))^2 / (2 sigma_m^2).
    """

    def __init__(self, elevation_m: np.ndarray, config: BarometerConfig = BarometerConfig()) -> None:
        self.elevation_m = np.asarray(elevation_m, dtype=np.float64)
        self.config = config
        self.anchor: tuple[int, float, float] | None = None  # (floor, barometer height, time)

    def update(self, t_s: float, height_m: float, steady: bool, floor_shares: np.ndarray) -> None:
        """After a filter step at ``t_s``: the barometer's height, whether it was steady, and the
        filter's share of weight per floor."""
        cfg = self.config
        floor = int(np.argmax(floor_shares))
        if not (steady and float(np.max(floor_shares)) >= ANCHOR_SHARE):
            return
        if self.anchor is None:
            self.anchor = (floor, height_m, t_s)
            return
        ref_floor, h_ref, t_ref = self.anchor
        h_floor = h_ref + self.elevation_m[floor] - self.elevation_m[ref_floor]  # the floor's height by the reference
        # never move the reference to a floor the barometer disagrees with: a filter that
        # missed a floor change would otherwise silence the barometer for good
        if abs(height_m - h_floor) > 2.0 * cfg.sigma_m:
            return
        drift = DRIFT_M_PER_S * max(t_s - t_ref, 0.0)
        self.anchor = (floor, h_floor + float(np.clip(height_m - h_floor, -drift, drift)), t_s)

    def floor_log_likelihood(self, height_m: float) -> np.ndarray | None:
        """(F,) log-likelihood of each floor at barometer height ``height_m``; None before a reference."""
        if self.anchor is None:
            return None
        floor, h_ref, _ = self.anchor
        expected = self.elevation_m[floor] + height_m - h_ref
        return -0.5 * ((self.elevation_m - expected) / self.config.sigma_m) ** 2


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
