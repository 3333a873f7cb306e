"""The half-floor split: the fixed rule on a synthetic floor, both directions, errors per half."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapfilter.errors import MapfilterError
from mapfilter.evaluation.area_split import HalfSplit, errors_by_half, half_split, split_directions
from mapfilter.io.tracks import Track


def test_the_cut_is_across_the_longer_side_at_the_median_waypoint():
    # a floor 100 m wide and 40 m deep: the cut is an x, at the median of the waypoints' x
    walks = [np.array([[5.0, 5.0], [20.0, 35.0], [30.0, 10.0]]),  # the left
             np.array([[70.0, 5.0], [95.0, 30.0]]),  # the right
             np.array([[10.0, 20.0], [90.0, 20.0]])]  # across
    split = half_split(walks)
    assert split.axis == 0 and split.cut_m == pytest.approx(30.0)  # x of 7 waypoints: median 30
    assert split.describe() == "x = 30.00 m" and split.describe(0) == "x < 30.00 m"
    np.testing.assert_array_equal(split.side(walks[0]), [0, 0, 1])  # on the cut: side 1
    tall = half_split([np.array([[0.0, 0.0], [10.0, 80.0]]), np.array([[5.0, 30.0]])])
    assert tall.axis == 1 and tall.cut_m == pytest.approx(30.0)
    with pytest.raises(MapfilterError):
        half_split([np.array([[1.0, 1.0]])])


def test_both_directions_survey_one_half_and_test_every_other_walk():
    split = HalfSplit(0, 50.0)
    walks = [np.array([[10.0, 0.0], [20.0, 0.0]]), np.array([[60.0, 0.0], [80.0, 0.0]]),
             np.array([[10.0, 0.0], [70.0, 0.0]]), np.array([[30.0, 0.0], [40.0, 0.0]])]
    left, right = split_directions(split, walks)
    assert (left.surveyed_side, left.survey, left.test) == (0, (0, 3), (1, 2))
    assert (right.surveyed_side, right.survey, right.test) == (1, (1,), (0, 2, 3))


@settings(max_examples=50, deadline=None)
@given(st.lists(st.lists(st.tuples(st.floats(0, 200), st.floats(0, 80)), min_size=1, max_size=8),
                min_size=2, max_size=12))
def test_every_waypoint_is_scored_once_where_nobody_surveyed(walks):
    """Any floor: the survey walks lie wholly in the surveyed half, no test walk is a survey walk,
    every walk is tested, and every waypoint is in the unsurveyed half of exactly one direction's
    test walks (so both directions together score the whole floor unsurveyed)."""
    walks = [np.array(w) for w in walks]
    split = half_split(walks)
    directions = split_directions(split, walks)
    unsurveyed = [np.zeros(len(w), dtype=int) for w in walks]
    for d in directions:
        assert not set(d.survey) & set(d.test)
        assert all(np.all(split.side(walks[i]) == d.surveyed_side) for i in d.survey)
        for i in d.test:
            unsurveyed[i] += split.side(walks[i]) != d.surveyed_side
    assert set().union(*(d.test for d in directions)) == set(range(len(walks)))
    assert all(np.all(u == 1) for u in unsurveyed)


def test_errors_are_split_by_the_waypoints_half():
    split = HalfSplit(0, 50.0)
    wp_t = np.array([0.0, 10.0, 20.0, 30.0])
    wp_xy = np.array([[10.0, 0.0], [40.0, 0.0], [60.0, 0.0], [90.0, 0.0]])
    # a causal track from t = 5 s, 1 m north of the truth until 25 s, then 3 m
    track = Track(np.array([5.0, 10.0, 20.0, 25.0, 30.0]),
                  np.array([[10.0, 1.0], [40.0, 1.0], [60.0, 1.0], [90.0, 3.0], [90.0, 3.0]]))
    surveyed, unsurveyed = errors_by_half(split, 0, track, wp_t, wp_xy)
    np.testing.assert_allclose(surveyed, [1.0])  # the first waypoint comes before the track: in neither
    np.testing.assert_allclose(unsurveyed, [1.0, 3.0])
    surveyed, unsurveyed = errors_by_half(split, 1, track, wp_t, wp_xy, causal=False)
    np.testing.assert_allclose(surveyed, [1.0, 3.0])
    np.testing.assert_allclose(unsurveyed, [1.0, 1.0])  # interpolated: clamped to the track's first row
