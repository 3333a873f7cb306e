import math

import numpy as np
import pytest

from mapfilter.evaluation.metrics import errors_at_waypoints, format_table, summarise_errors
from mapfilter.evaluation.plots import plot_error_cdf


def test_causal_errors_use_latest_estimate_and_count_missed_waypoints():
    track_t = np.array([10.0, 20.0, 30.0])
    track_xy = np.array([[0.0, 0.0], [3.0, 4.0], [10.0, 0.0]])
    wp_t = np.array([5.0, 10.0, 25.0, 40.0])
    wp_xy = np.array([[9.0, 9.0], [0.0, 1.0], [0.0, 0.0], [10.0, 2.0]])
    result = errors_at_waypoints(track_t, track_xy, wp_t, wp_xy)
    assert result.missed == 1
    np.testing.assert_array_equal(result.waypoint_index, [1, 2, 3])
    # waypoint at t=10 -> estimate at t=10 (0,0): 1 m; t=25 -> estimate at t=20 (3,4): 5 m; t=40 -> (10,0): 2 m
    np.testing.assert_allclose(result.errors_m, [1.0, 5.0, 2.0])


def test_smoothed_errors_interpolate():
    result = errors_at_waypoints(np.array([0.0, 10.0]), np.array([[0.0, 0.0], [10.0, 0.0]]),
                                 np.array([5.0]), np.array([[5.0, 1.0]]), causal=False)
    np.testing.assert_allclose(result.errors_m, [1.0])
    assert result.missed == 0


def test_summary_against_hand_computed_values():
    summary = summarise_errors([1.0, 2.0, 3.0, 4.0])
    assert summary["mean"] == pytest.approx(2.5)
    assert summary["median"] == pytest.approx(2.5)
    assert summary["p75"] == pytest.approx(3.25)  # numpy linear interpolation: 3 + 0.25 * (4 - 3)
    assert summary["p90"] == pytest.approx(3.7)
    assert summary["max"] == 4.0
    assert summary["rmse"] == pytest.approx(math.sqrt(30 / 4))
    assert summary["n"] == 4
    assert math.isnan(summarise_errors([])["mean"])


def test_table_and_cdf_plot(tmp_path):
    table = format_table([{"method": "pf", "mean": 1.234, "n": 3}], ["method", "mean", "n"])
    assert table.splitlines()[2] == "| pf | 1.23 | 3 |"
    plot_error_cdf({"a": np.array([1.0, 2.0]), "b": np.array([3.0])}, tmp_path / "cdf.png")
    assert (tmp_path / "cdf.png").read_bytes()[:4] == b"\x89PNG"
