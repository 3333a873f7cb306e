"""evaluation.store: resume keyed by content, and a stored outcome that fails its own checks is
refused, not trusted."""

import json

import numpy as np
import pytest

from mapfilter.errors import MapfilterError
from mapfilter.evaluation.comparison import MethodResult, WalkOutcome
from mapfilter.evaluation.store import file_digest, read_outcome, write_outcome
from mapfilter.io.tracks import Track


def _outcome(tmp_path):
    result = MethodResult("kwnn", "walk", Track(np.zeros(0), np.zeros((0, 2))), np.array([1.5, 2.25]), 1, 3, 0,
                          0.1, True, {"spread_m": 2.0}, None, None)
    outcome = WalkOutcome(0, "walk", tmp_path / "walk.txt", "ok", "", [result], [], 0.5)
    path = tmp_path / "walk.json"
    write_outcome(outcome, path, "key1")
    return path


def test_a_stored_outcome_reads_back(tmp_path):
    read = read_outcome(_outcome(tmp_path), "key1")
    assert read.trace == "walk" and list(read.results[0].errors_m) == [1.5, 2.25]
    assert read_outcome(_outcome(tmp_path), "another run") is None


@pytest.mark.parametrize("edit", [
    lambda d: d["methods"][0].update(errors_m=[0.0, 0.0]),  # all-zero errors: a summary of 0.00 m
    lambda d: d.update(methods=3),
    lambda d: d.pop("checksum"),
])
def test_an_edited_store_is_refused(tmp_path, edit):
    path = _outcome(tmp_path)
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))
    with pytest.raises(MapfilterError, match="fails its checks"):
        read_outcome(path, "key1")


def test_a_store_with_a_matching_checksum_but_wrong_types_is_refused(tmp_path):
    from mapfilter.evaluation import store

    path = _outcome(tmp_path)
    data = json.loads(path.read_text())
    data["methods"] = 3
    data["checksum"] = store._checksum(data)  # forged consistently: the field checks still hold
    path.write_text(json.dumps(data))
    with pytest.raises(MapfilterError, match="fails its checks"):
        read_outcome(path, "key1")


def test_the_key_follows_the_content(tmp_path):
    log = tmp_path / "walk.txt"
    log.write_text("a")
    first = file_digest(log)
    log.write_text("b")  # replaced at the same path
    assert file_digest(log) != first


def test_evaluate_resume_after_a_log_is_replaced_runs_it_again(tmp_path, capsys):
    import shutil

    from mapfilter.cli import main
    from tests.io.test_output_policy import MAPS

    log = tmp_path / "walk.txt.gz"
    shutil.copy(MAPS / "office_walk.txt.gz", log)
    args = ["evaluate", str(MAPS / "office.yaml"), str(log), "--radiomap", str(MAPS / "office_radiomap.npz"),
            "--methods", "kwnn", "--out", str(tmp_path / "out")]
    assert main(args) == 0
    assert main(args + ["--resume"]) == 0
    assert "resuming: 1 of 1" in capsys.readouterr().out
    assert main(["simulate", str(MAPS / "office.yaml"), "--duration", "40", "--out", str(log)]) == 0
    assert main(args + ["--resume"]) == 0
    assert "resuming: 0 of 1" in capsys.readouterr().out
