"""The offline track's second forward pass weighs the particles' headings against the rotation
vector only where the causal track is out of the walls' reach (an open floor: nothing else holds
the heading there); near walls it leaves them to the walls (docs/accuracy.md)."""

from __future__ import annotations

import mapfilter as mf
import mapfilter.pipeline.offline as offline
from tests.conftest import REPO


def test_the_second_pass_keeps_the_heading_term_only_out_of_the_walls_reach(monkeypatch):
    building = mf.load_map(REPO / "maps" / "office.yaml")
    walk = mf.read_log(REPO / "maps" / "office_walk.txt.gz")
    radio_map = mf.load_radio_map(REPO / "maps" / "office_radiomap.npz")
    config = mf.TrackingConfig(smooth=True, seed=0).with_particles(500)
    assert config.motion.rotation_vector_sigma_deg > 0
    seen: list[float] = []
    first_pass = offline.run_over_scans

    def recording(plan, evidence, settings, *args, **kwargs):
        seen.append(settings.motion.rotation_vector_sigma_deg)
        return first_pass(plan, evidence, settings, *args, **kwargs)

    monkeypatch.setattr(offline, "run_over_scans", recording)
    # the office's corridors: every track within a few metres of a wall
    mf.track(building, walk, radio_map, config=config)
    # the same walk with the walls' reach taken as nothing: every floor counts as open
    monkeypatch.setattr(offline, "WALL_REACH_SIGMAS", 0.0)
    mf.track(building, walk, radio_map, config=config)
    assert seen == [0.0, config.motion.rotation_vector_sigma_deg]
