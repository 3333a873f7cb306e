"""Smoke tests of the paper-reproduction scripts (tools/experiments/papers/*.py) on tiny configurations,
and oracle/property tests of their shared helpers."""

from __future__ import annotations

import importlib
import re
import sys
from pathlib import Path

import numpy as np
import pytest

PAPERS = Path(__file__).resolve().parents[1] / "tools" / "experiments" / "papers"


@pytest.fixture(scope="module")
def papers():
    sys.path.insert(0, str(PAPERS))
    try:
        yield {name: importlib.import_module(name) for name in ("common", "chang", "evennou_marx", "lund_thesis")}
    finally:
        sys.path.remove(str(PAPERS))


def _table_rows(text: str, first_cell: str) -> list[list[str]]:
    rows = []
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and cells[0].startswith(first_cell):
            rows.append(cells)
    return rows


def _without_timing(text: str) -> str:
    return re.sub(r"Regenerate: .*", "", re.sub(r"Wall-clock .*", "", text))


def test_office_reference_points_follow_evennou_marx(papers):
    common = papers["common"]
    floorplan, _ = common.load_office()
    xy, n_rooms = common.office_reference_points(2.0)
    assert n_rooms == 24  # 20 offices (4 of them corner rooms) + 4 labs
    assert floorplan.is_free(xy).all()
    corridor = xy[n_rooms:]
    gaps = np.linalg.norm(np.diff(np.vstack([corridor, corridor[:1]]), axis=0), axis=1)
    np.testing.assert_allclose(gaps, 2.1, atol=0.05)  # 84 m loop in 40 equal pieces
    assert floorplan.distance_to_wall_m(corridor).min() > 0.8  # on the centre line of a 2 m corridor


def test_noise_free_survey_is_the_simulator_model(papers):
    common = papers["common"]
    from mapfilter.simulate.walk import model_rssi_dbm

    floorplan, aps = common.load_office()
    xy = np.array([[5.0, 5.0], [19.0, 8.5], [30.0, 30.0]])
    config = common.SimConfig(shadowing_sigma_db=0.0)
    radio_map = common.survey_radio_map(floorplan, aps, xy, 3, np.random.default_rng(0), config)
    expected, _ = model_rssi_dbm(floorplan, aps, np.tile(np.arange(len(aps)), 3), np.repeat(xy, len(aps), axis=0),
                                 config)
    expected = np.round(expected.reshape(3, len(aps)))
    heard = expected >= config.sensitivity_dbm
    np.testing.assert_array_equal(np.isnan(radio_map.rssi_dbm), ~heard)
    np.testing.assert_allclose(radio_map.rssi_dbm[heard], expected[heard])
    assert radio_map.ap_keys == aps.keys


def test_chang_lattice_and_their_pdr(papers):
    common, chang = papers["common"], papers["chang"]
    floorplan, aps = common.load_office()
    ref = chang.lattice_reference_points(floorplan, 300, np.random.default_rng(1))
    assert ref.shape == (300, 2) and floorplan.is_free(ref).all()
    assert np.unique(ref, axis=0).shape[0] == 300
    walk, _ = common.simulate_recording(floorplan, aps, common.SimConfig(duration_s=20.0, step_length_m=1.0), 3)
    steps = chang.their_pdr(walk, np.random.default_rng(2))
    assert len(steps) == walk.n_steps
    # length noise 0.1 m, heading noise 1 degree around the truth (plus the gyro's zero)
    assert np.abs(steps.step_length_m - walk.step_length_m).max() < 0.5
    chord = walk.position_at(walk.step_end_t_s) - walk.position_at(walk.step_start_t_s)
    true_heading = np.arctan2(chord[:, 1], chord[:, 0])
    diff = np.angle(np.exp(1j * (steps.abs_heading_rad - true_heading)))
    assert np.abs(diff).max() < np.deg2rad(5.0)


def test_chang_quick_run_is_deterministic(papers, tmp_path):
    chang = papers["chang"]
    assert chang.main(["--quick", "--out", str(tmp_path / "a.md")]) == 0
    assert chang.main(["--quick", "--out", str(tmp_path / "b.md")]) == 0
    a, b = (tmp_path / "a.md").read_text(), (tmp_path / "b.md").read_text()
    assert _without_timing(a) == _without_timing(b)
    rows = _table_rows(a, "KWNN") + _table_rows(a, "PDR-KWNN")
    assert len(rows) == 3
    assert rows[0][1] == "1.91"
    assert all(np.isfinite(float(r[2])) and float(r[2]) > 0 for r in rows)


def test_evennou_marx_quick_run(papers, tmp_path):
    em = papers["evennou_marx"]
    out = tmp_path / "em.md"
    assert em.main(["--quick", "--jobs", "1", "--out", str(out)]) == 0
    text = out.read_text()
    assert (tmp_path / "em_particles.png").stat().st_size > 1000
    main_rows = [r for r in _table_rows(text, "") if r[0].startswith(("Database", "Kalman", "EKF", "PF,"))]
    assert len(main_rows) == 8 + 4  # the main table, then the PF rows of "where the errors come from"
    main_rows = main_rows[:8]
    assert [r[1] for r in main_rows[:5]] == ["3.50", "", "2.29", "", "1.99"]
    assert all(float(r[2]) > 0 for r in main_rows)
    study = [r for r in _table_rows(text, "") if r[0].isdigit()]
    # the particle study, then the study with collapse detection on (N <= the largest quick N)
    assert [int(r[0]) for r in study] == list(em.QUICK_PARTICLES) + [1000]
    assert all(int(r[1]) == 2 for r in study)  # 2 walks x 1 seed
    assert all(int(r[-2]) >= 0 for r in study)  # runs lost
    assert "Checks (mean error over all walks)" in text


def test_lund_thesis_quick_run(papers, tmp_path):
    lund = papers["lund_thesis"]
    out = tmp_path / "lund.md"
    assert lund.main(["--quick", "--jobs", "1", "--out", str(out)]) == 0
    text = out.read_text()
    rows = {r[0]: r for r in _table_rows(text, "")}
    assert rows["LS trilateration"][1] == "4.80" and rows["PF, WiFi + PDR, map"][1] == "1.80"
    assert all(np.isfinite(float(rows[k][2])) for k in ("LS trilateration", "PF, WiFi + PDR, map"))
    step_rows = [r for r in _table_rows(text, "") if r[0].isdigit()]
    assert step_rows and float(step_rows[0][1]) == pytest.approx(lund.WRONG_START_M, abs=0.05)
    assert (tmp_path / "lund_step_length.png").stat().st_size > 1000
    # chapter 7: adaptation from a wrong table, the parameter table, blocking with and without compensation
    assert "## Chapter 7" in text and "adaptation closes" in text
    ch7 = {r[0]: r for r in _table_rows(text.split("## Chapter 7")[1], "")}
    assert np.isfinite(float(ch7["PF, WiFi only (random walk): wrong table, adapted (-42 dBm)"][1]))
    assert np.isfinite(float(ch7["PF, WiFi + PDR: blocked repeatedly, no compensation"][1]))


def test_run_parallel_spawns_workers_and_keeps_order(papers):
    import math

    common = papers["common"]
    assert common.run_parallel(math.sqrt, [9.0, 1.0, 4.0, 16.0], jobs=2) == [3.0, 1.0, 2.0, 4.0]
    assert common.run_parallel(math.sqrt, [9.0], jobs=2) == [3.0]  # one item: no pool
