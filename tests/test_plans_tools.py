"""The plan generator and the map-preparation benchmark (tools/plans/): the same seed gives the
same plans, the truth is consistent with the drawing, every style renders, and the scores are
what they claim on masks whose answer is known."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import shapely
from shapely.ops import unary_union

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools" / "plans"))
import benchmark  # noqa: E402
import plangen  # noqa: E402


def test_the_same_seed_gives_the_same_plan_and_another_seed_another():
    first = plangen.generate_plan(plangen.plan_seeds(5, 2)[1], "double")
    again = plangen.generate_plan(plangen.plan_seeds(5, 7)[1], "double")  # plan 1 whatever the count
    np.testing.assert_array_equal(first.image, again.image)
    np.testing.assert_array_equal(first.walls, again.walls)
    other = plangen.generate_plan(plangen.plan_seeds(6, 2)[1], "double")
    assert first.image.shape != other.image.shape or not np.array_equal(first.image, other.image)


@pytest.mark.parametrize("wall", plangen.WALL_STYLES)
def test_truth_is_consistent_and_the_drawing_shows_the_walls(wall, tmp_path: Path):
    plan = plangen.generate_plan(plangen.plan_seeds(11, 1)[0], wall, "white")
    assert plan.walls.shape == plan.free.shape == plan.rooms.shape == plan.image.shape[:2]
    assert not (plan.walls & plan.free).any()
    assert (plan.free[plan.rooms > 0]).all()  # rooms are free space
    # 0.2-9 megapixels for the sheet before its title block (which adds at most a third)
    assert 0.19e6 <= plan.image.shape[0] * plan.image.shape[1] <= 12e6
    gray = plan.image if plan.image.ndim == 2 else cv2.cvtColor(plan.image, cv2.COLOR_BGR2GRAY)
    inner = plan.walls & ~cv2.dilate((~plan.walls).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    # solid walls are dark inside; outlined walls are dark along their edges
    edges = plan.walls & ~inner
    assert np.median(gray[edges | inner]) < np.median(gray[plan.free])
    path = plangen.write_plan(plan, tmp_path, "p")
    meta = json.loads((tmp_path / "p.json").read_text())
    assert meta["resolution_m"] == pytest.approx(plan.resolution_m) and meta["style"]["wall"] == wall
    np.testing.assert_array_equal(cv2.imread(str(tmp_path / "p_walls.png"), cv2.IMREAD_GRAYSCALE) > 0, plan.walls)
    assert path.exists() and len(meta["rooms"]) == len(plan.room_info)


def test_the_layouts_hold_what_real_drawings_hold():
    """Every outline shape (round, angled and courtyard ones too), bays, window runs and terraces
    turn up in a set; a courtyard is outside; a terrace is outside and its rail no wall; windows are
    wall in the truth."""
    rng = np.random.default_rng(5)
    layouts = [plangen.make_layout(rng) for _ in range(60)]
    assert {layout.features["outline"] for layout in layouts} == set(plangen.OUTLINES)
    for feature in ("bay", "window_run", "terrace"):
        assert sum(layout.features[feature] for layout in layouts) >= 5, feature
    courtyard = next(layout for layout in layouts if layout.features["outline"] == "courtyard")
    assert len(courtyard.footprint.interiors) == 1
    hole = shapely.Polygon(courtyard.footprint.interiors[0])
    assert hole.area > 4.0 and not hole.buffer(-0.05).intersects(courtyard.solid)
    layout = next(layout for layout in layouts if layout.features["terrace"] and layout.windows)
    plan = plangen.draw_plan(np.random.default_rng(1), layout, "double", "white")
    terrace = plangen._raster(layout.terraces[0].buffer(-0.1), plan.walls.shape, 1 / plan.resolution_m, plan.origin_m)
    assert terrace.any() and not (plan.walls | plan.free)[terrace].any()
    windows = plangen._raster(unary_union([w.cut(0.0).buffer(-0.02) for w in layout.windows]), plan.walls.shape,
                              1 / plan.resolution_m, plan.origin_m)
    assert windows.any() and plan.walls[windows].all()


def test_scores_of_known_masks():
    truth_walls = np.zeros((40, 60), bool)
    truth_walls[:, :2] = truth_walls[:, -2:] = truth_walls[:2] = truth_walls[-2:] = True
    truth_walls[:, 29:31] = True
    truth_walls[18:24, 29:31] = False  # a door
    truth_free = ~truth_walls
    rooms = np.zeros((40, 60), np.uint16)
    rooms[2:38, 2:29] = 1
    rooms[2:38, 31:58] = 2
    perfect = benchmark.score(truth_walls, truth_walls, truth_free, rooms, [1, 2])
    assert perfect["wall_iou"] == 1.0 and perfect["rooms_reached"] == perfect["rooms_reachable"] == 2
    assert perfect["connectivity"] == perfect["truth_connectivity"] == 1.0
    shut = truth_walls.copy()
    shut[18:24, 29:31] = True  # the door closed: one room cut off, the walls still all found
    closed = benchmark.score(shut, truth_walls, truth_free, rooms, [1, 2])
    assert closed["rooms_reached"] == 1 and closed["connectivity"] == pytest.approx(0.5, abs=0.01)
    # the closed door's pixels more than 2 px from a true wall (its two middle rows) are spurious
    assert closed["wall_iou"] == pytest.approx(truth_walls.sum() / (truth_walls.sum() + 4))
    moved = np.roll(truth_walls, (3, 3), axis=(0, 1))  # walls 3 px off: beyond the 2 px tolerance
    assert benchmark.score(moved, truth_walls, truth_free, rooms, [1, 2])["wall_iou"] < 0.5


def test_the_benchmark_runs_the_command_and_summarises(tmp_path: Path):
    row = benchmark.run_plan((3, 0, str(tmp_path)))
    assert row["exit_code"] == 0 and 0.0 <= row["wall_iou"] <= 1.0 and row["runtime_s"] > 0
    assert list(tmp_path.iterdir()) == []  # the plan's files are removed once scored
    table = benchmark.summarise([row, dict(row, wall="double", wall_iou=0.5)], "wall")
    assert [t["group"] for t in table] == ["all", "solid", "double"] and table[0]["plans"] == 2
    assert "| all | 2 |" in benchmark.markdown(table, "wall style")


def test_the_plans_of_one_outline_are_the_first_of_the_set_with_it():
    seeds = plangen.plan_seeds(3, 100)
    for seed in seeds[:2]:  # the layout alone names the drawn plan's outline
        assert plangen.outline_of(seed) == plangen.generate_plan(seed).features["outline"]
    picked = benchmark.plan_indices(3, 2, "courtyard")
    shapes = [plangen.outline_of(seed) for seed in seeds[:picked[-1] + 1]]
    assert len(picked) == 2 and [i for i, shape in enumerate(shapes) if shape == "courtyard"] == picked
    assert benchmark.plan_indices(3, 4) == [0, 1, 2, 3]
