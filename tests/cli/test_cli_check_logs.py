"""``--check-logs`` on both map commands (issue 53, friction 4): ``map import-ilc`` takes it as
``map prepare`` does, and a clean check says so in one line."""

from __future__ import annotations

from pathlib import Path

import pytest

from mapfilter.cli import main as cli_main
from mapfilter.sensors.logs import read_log

REPO = Path(__file__).resolve().parents[2]
WALK = REPO / "maps" / "office_walk.txt.gz"


def _run(argv: list, capsys) -> tuple[int, str, str]:
    code = cli_main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _warnings(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("mapfilter: warning: ")]


def test_a_clean_check_on_prepare_says_so_in_one_line(tmp_path: Path, capsys):
    n = read_log(WALK).waypoint_t_s.size
    code, out, err = _run(["map", "prepare", REPO / "maps" / "office_plan.png", "--resolution", 0.05,
                           "--out", tmp_path / "office.yaml", "--check-logs", WALK], capsys)
    assert code == 0 and _warnings(err) == [], err
    (line,) = [line for line in out.splitlines() if "--check-logs" in line]
    assert f"{n} of {n} waypoints of 1 log on free space" in line


@pytest.mark.real_data
def test_import_ilc_checks_logs(ilc_site1: Path, tmp_path: Path, capsys):
    floor_logs = sorted((ilc_site1 / "F1" / "path_data_files").glob("*.txt.gz"))[:2]
    n = sum(read_log(p).waypoint_t_s.size for p in floor_logs)
    code, out, err = _run(["map", "import-ilc", ilc_site1 / "F1", "--out", tmp_path / "F1.yaml",
                           "--check-logs", *floor_logs], capsys)
    assert code == 0 and _warnings(err) == [], err
    (line,) = [line for line in out.splitlines() if "--check-logs" in line]
    assert f"{n} of {n} waypoints of 2 logs on free space" in line
    # another floor's walk on this floor's map: its waypoints in walls are named, and the count says so
    other = sorted((ilc_site1 / "F2" / "path_data_files").glob("*.txt.gz"))[0]
    code, out, err = _run(["map", "import-ilc", ilc_site1 / "F1", "--out", tmp_path / "F1b.yaml",
                           "--check-logs", other], capsys)
    (warning,) = _warnings(err)
    m = read_log(other).waypoint_t_s.size
    assert code == 0 and str(other) in warning and "waypoints fall in walls" in warning
    (line,) = [line for line in out.splitlines() if "--check-logs" in line]
    assert f"of {m} waypoints of 1 log on free space" in line and f"{m} of {m}" not in line


def test_import_ilc_refuses_a_missing_log_before_the_work(tmp_path: Path, capsys):
    code, out, err = _run(["map", "import-ilc", tmp_path / "nofloor", "--out", tmp_path / "F1.yaml",
                           "--check-logs", tmp_path / "missing.txt"], capsys)
    assert code == 1 and "missing.txt" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "F1.yaml").exists()
