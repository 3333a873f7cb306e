"""A live run's cost per chunk does not grow with the run: each chunk makes only its own rows.

Timing would be noisy here; the test counts what a chunk makes instead: the rows of the tracks
it builds, the steps it copies, the rotation-vector samples it keeps for a later start."""

from __future__ import annotations

import gzip

import numpy as np

import mapfilter.filter.causal as causal
from mapfilter.config import TrackingConfig
from mapfilter.maps.floorplan import FloorPlan
from mapfilter.pipeline.tracker import Tracker, TrackingInputs
from mapfilter.sensors.logs import LogStream
from mapfilter.sensors.radiomap import RadioMap
from tests.conftest import REPO

PIECE_BYTES = 16384


def _repeated_walk(times: int) -> bytes:
    """The office walk played ``times`` times, each 120 s after the one before (one ILC log: the
    first column is the time in ms, and a WiFi row's last the time its AP was last seen)."""
    lines = gzip.open(REPO / "maps" / "office_walk.txt.gz", "rt").read().splitlines()
    out = [line for line in lines if line.startswith("#")]
    body = [line.split("\t") for line in lines if line.strip() and not line.startswith("#")]
    for k in range(times):
        for fields in body:
            shifted = [str(int(fields[0]) + k * 120_000), *fields[1:]]
            if fields[1] == "TYPE_WIFI":
                shifted[6] = str(int(fields[6]) + k * 120_000)
            out.append("\t".join(shifted))
    return ("\n".join(out) + "\n").encode()


def test_a_chunk_late_in_a_long_run_makes_only_its_own_rows(monkeypatch):
    built = []  # the rows of every track the causal filter builds
    steps_copied = []

    class CountedTrack(causal.Track):
        def __init__(self, t_s, *args, **kwargs):
            built.append(len(t_s))
            super().__init__(t_s, *args, **kwargs)

    def counted_merge(a, b):
        steps_copied.append((0 if a is None else len(a)) + len(b))
        return merge(a, b)

    merge = causal.merge_steps
    monkeypatch.setattr(causal, "Track", CountedTrack)
    monkeypatch.setattr(causal, "merge_steps", counted_merge)
    data = _repeated_walk(2)
    tracker = Tracker(FloorPlan.load(REPO / "maps" / "office.yaml"),
                      TrackingInputs(RadioMap.load(REPO / "maps" / "office_radiomap.npz")),
                      config=TrackingConfig(seed=0).override({"filter.n_particles": 200}))
    stream = LogStream("the repeated walk")
    kept_rotvec = []
    for i in range(0, len(data), PIECE_BYTES):
        built.clear()
        new = tracker.feed(stream.feed_bytes(data[i:i + PIECE_BYTES]))
        assert sum(built) == len(new)  # the chunk's rows only, never the track so far
        kept_rotvec.append(sum(t.size for t, _ in tracker.stream._rotvec))
    assert steps_copied == []  # steps are joined only when the whole walk's are asked for
    tracker.feed(stream.close())
    tracker.close()
    assert len(tracker.stream.rows) > 350 and tracker.stream.n_scans_used > 60  # two walks, both with WiFi
    # a later start needs the latest rotation-vector sample only: a chunk or two of them are kept
    # (a 16 KiB piece holds about 80), not the 11,836 of the two walks
    assert 0 < max(kept_rotvec) < 1000
    steps = tracker.stream.steps
    assert len(steps) > 300 and np.all(np.diff(steps.t_s) > 0)  # joined once, in order, when asked for


def test_barometer_heights_made_piece_by_piece_are_the_whole_walks_to_the_bit():
    """A building's barometer heights were made again from every reading at every chunk; now each
    reading's once, with the same numbers as ``barometric_height`` of all readings so far."""
    from mapfilter.filter.models.barometer import BarometricHeights, barometric_height

    rng = np.random.default_rng(45)
    t_s = 1.6e9 + np.cumsum(rng.uniform(0.02, 0.3, 5000))
    hpa = 1013.25 - np.cumsum(rng.normal(0.0, 0.01, 5000)) + rng.normal(0.0, 0.03, 5000)
    heights = BarometricHeights()
    cuts = np.sort(rng.choice(np.arange(1, 5000), 60, replace=False))
    for a, b in zip([0, *cuts], [*cuts, 5000]):
        heights.add(t_s[a:b], hpa[a:b])
        whole_t, whole_h = barometric_height(t_s[:b], hpa[:b])
        np.testing.assert_array_equal(heights.t_s, whole_t)
        np.testing.assert_array_equal(heights.height_m, whole_h)  # to the bit
