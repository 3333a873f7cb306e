"""Resampling schemes: valid indices for degenerate weights, unbiased counts, ESS."""

import numpy as np
import pytest

from mapfilter.filter.resample import (
    RESAMPLERS,
    effective_sample_size,
    get_resampler,
    needs_resampling,
)

SCHEMES = sorted(RESAMPLERS)


def _check_valid(idx, weights, n):
    assert idx.shape == (n,)
    assert idx.dtype.kind == "i"
    assert idx.min() >= 0 and idx.max() < len(weights)
    assert np.all(np.asarray(weights)[idx] > 0), "a zero-weight particle was chosen"


@pytest.mark.parametrize("name", SCHEMES)
@pytest.mark.parametrize("case", ["one_nonzero_first", "one_nonzero_last", "one_nonzero_middle", "all_equal",
                                  "tiny", "zeros_at_ends", "round_off"])
def test_degenerate_weights_give_valid_indices(name, case):
    rng = np.random.default_rng(3)
    n = 1000
    w = np.zeros(n)
    if case == "one_nonzero_first":
        w[0] = 1.0
    elif case == "one_nonzero_last":
        w[-1] = 1e-300
    elif case == "one_nonzero_middle":
        w[417] = 5.0
    elif case == "all_equal":
        w[:] = 1.0 / n
    elif case == "tiny":
        w[:] = rng.random(n) * 1e-310  # subnormal
    elif case == "zeros_at_ends":
        w[100:200] = rng.random(100)
    elif case == "round_off":
        w[:] = 1.0 / 3.0  # sums to slightly off 1 in floating point
    idx = get_resampler(name)(w, n, rng)
    _check_valid(idx, w, n)
    if case.startswith("one_nonzero"):
        assert np.all(idx == np.flatnonzero(w)[0])
    if case == "all_equal" and name in ("systematic", "residual"):
        assert np.array_equal(np.sort(idx), np.arange(n))  # exactly one copy each


@pytest.mark.parametrize("name", SCHEMES)
def test_counts_are_unbiased(name):
    rng = np.random.default_rng(4)
    w = rng.random(50) ** 3
    w /= w.sum()
    n = 2000
    counts = np.zeros(50)
    reps = 200
    for _ in range(reps):
        counts += np.bincount(get_resampler(name)(w, n, rng), minlength=50)
    mean = counts / reps
    # E[count_i] = n w_i; multinomial sd per rep sqrt(n w (1-w)) ~ <= 22 -> mean sd ~1.6
    assert np.allclose(mean, n * w, atol=6.0)


@pytest.mark.parametrize("name", ["systematic", "stratified"])
def test_low_variance_schemes_keep_counts_within_one(name):
    rng = np.random.default_rng(5)
    w = rng.random(300)
    w /= w.sum()
    counts = np.bincount(get_resampler(name)(w, 300, rng), minlength=300)
    if name == "systematic":
        assert np.all(np.abs(counts - 300 * w) < 1.0 + 1e-9)
    else:
        assert np.all(np.abs(counts - 300 * w) < 2.0 + 1e-9)


def test_same_seed_same_indices():
    w = np.random.default_rng(6).random(100)
    for name in SCHEMES:
        a = get_resampler(name)(w, 100, np.random.default_rng(7))
        b = get_resampler(name)(w, 100, np.random.default_rng(7))
        assert np.array_equal(a, b)


@pytest.mark.parametrize("bad", [np.zeros(5), np.array([1.0, np.nan]), np.array([1.0, -0.1]), np.zeros(0)])
def test_bad_weights_raise(bad):
    with pytest.raises(ValueError):
        get_resampler("systematic")(bad, 3, np.random.default_rng(0))


def test_unknown_scheme_raises():
    with pytest.raises(ValueError, match="unknown resampler"):
        get_resampler("bogus")


def test_effective_sample_size():
    assert effective_sample_size(np.full(10, 0.1)) == pytest.approx(10.0)
    assert effective_sample_size(np.array([0, 0, 1.0])) == pytest.approx(1.0)
    assert effective_sample_size(np.array([1.0, 1.0, 0, 0])) == pytest.approx(2.0)  # unnormalised ok
    assert needs_resampling(np.array([1.0, 0, 0, 0]), 0.5)
    assert not needs_resampling(np.full(4, 0.25), 0.5)
