"""Resampling schemes as pure functions ``scheme(weights, n, rng) -> ancestor indices``.

Picked by name with :func:`get_resampler` (as in nchopin/particles). Weights need not be
normalised; they must be finite, non-negative and not all zero. Every scheme guards against
round-off (the last cumulative weight is set to exactly 1) so that an index never runs past
the end, and returns sorted int64 indices in ``[0, len(weights))`` with ``weights[i] > 0``.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from numba import njit

__all__ = [
    "RESAMPLERS",
    "effective_sample_size",
    "get_resampler",
    "multinomial",
    "needs_resampling",
    "residual",
    "stratified",
    "systematic",
]


def _normalised(weights: np.ndarray) -> np.ndarray:
    w = np.asarray(weights, dtype=np.float64).ravel()
    if w.size == 0:
        raise ValueError("cannot resample from zero particles")
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite and non-negative")
    total = w.sum()
    if not total > 0:
        raise ValueError("weights are all zero: nothing to resample from")
    return w / total


@njit(cache=True)
def _sorted_positions_to_indices(weights, positions):
    """One linear pass: ancestor index of each sorted position in [0, 1) under the cumsum.

    The running sum is kept in float64 and the last bin is closed at exactly 1 (round-off
    guard: ``cumsum[-1] = 1``), so a position can never fall past the last particle. A
    zero-weight particle is never chosen (its bin is empty).
    """
    n_w = weights.shape[0]
    n = positions.shape[0]
    out = np.empty(n, dtype=np.int64)
    # index of the last positive weight: the bin that is closed at 1
    last = n_w - 1
    while last > 0 and weights[last] <= 0.0:
        last -= 1
    i = 0
    cum = weights[0]
    for j in range(n):
        p = positions[j]
        while (p >= cum or weights[i] <= 0.0) and i < last:
            i += 1
            cum += weights[i]
        out[j] = i
    return out


def systematic(weights: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Systematic resampling: positions ``(j + U) / n`` with one ``U ~ U[0, 1)``.

    Lowest variance of the four in practice, O(n) numba linear pass.
    """
    w = _normalised(weights)
    positions = (np.arange(n, dtype=np.float64) + rng.random()) / n
    return _sorted_positions_to_indices(w, positions)


def stratified(weights: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Stratified resampling: positions ``(j + U_j) / n`` with independent ``U_j``."""
    w = _normalised(weights)
    positions = (np.arange(n, dtype=np.float64) + rng.random(n)) / n
    return _sorted_positions_to_indices(w, positions)


def multinomial(weights: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Multinomial resampling: ``n`` independent draws (sorted uniforms, one pass)."""
    w = _normalised(weights)
    positions = np.sort(rng.random(n))
    return _sorted_positions_to_indices(w, positions)


def residual(weights: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Residual resampling: ``floor(n w_i)`` copies of each, the rest multinomial on the residues."""
    w = _normalised(weights)
    # the tiny offset keeps an exact n w_i = k (equal weights) from rounding down to k - 1
    counts = np.floor(n * w + 1e-9).astype(np.int64)
    deterministic = np.repeat(np.arange(w.size, dtype=np.int64), counts)
    n_rest = n - deterministic.size
    if n_rest <= 0:
        return deterministic[:n]
    residues = np.maximum(n * w - counts, 0.0)
    if not residues.sum() > 0:  # every weight was an exact multiple of 1/n
        residues = w
    rest = multinomial(residues, n_rest, rng)
    return np.sort(np.concatenate([deterministic, rest]))


RESAMPLERS: dict[str, Callable[[np.ndarray, int, np.random.Generator], np.ndarray]] = {
    "systematic": systematic,
    "stratified": stratified,
    "residual": residual,
    "multinomial": multinomial,
}


def get_resampler(name: str) -> Callable[[np.ndarray, int, np.random.Generator], np.ndarray]:
    """The resampling function called ``name`` (one of :data:`RESAMPLERS`)."""
    try:
        return RESAMPLERS[name]
    except KeyError:
        raise ValueError(f"unknown resampler {name!r}; choose one of {sorted(RESAMPLERS)}") from None


def effective_sample_size(weights: np.ndarray) -> float:
    """ESS = 1 / sum(w^2) of the normalised weights (N for equal weights, 1 for one particle)."""
    w = np.asarray(weights, dtype=np.float64)
    total = w.sum()
    if not total > 0 or not np.isfinite(total):
        return 0.0
    w = w / total
    return float(1.0 / np.dot(w, w))


def needs_resampling(weights: np.ndarray, ess_fraction: float = 0.5) -> bool:
    """True when ESS < ``ess_fraction`` * N (Evennou & Marx: resample when 1/sum(w^2) < threshold)."""
    return effective_sample_size(weights) < ess_fraction * np.asarray(weights).size
