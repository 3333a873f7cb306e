"""mapfilter.runtime.memory: what a run would allocate is refused, in one line with the figure, before
it is allocated; --jobs is bounded by the cores; a scheduler that is not one fails in seconds."""

import socket
import threading

import numpy as np
import pytest

from mapfilter.runtime import memory
from mapfilter.cli import main
from mapfilter.runtime.dispatch import check_local_jobs, machine_cores, probe_scheduler
from mapfilter.errors import MapfilterError
from mapfilter.sensors.radiomap import RadioMap
from tests.io.test_output_policy import MAPS

TRACK = ["track", str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"), "--radiomap",
         str(MAPS / "office_radiomap.npz")]


def test_check_fits_names_the_figure():
    memory.check_fits(1 << 20, "a megabyte")
    with pytest.raises(MapfilterError, match=r"a lot needs about 1 EiB of memory, more than the .* free: less"):
        memory.check_fits(float(1 << 60), "a lot", "less")
    with pytest.raises(MapfilterError, match="unbounded"):
        memory.check_fits(memory.grid_bytes(10.0, 10.0, 0.0, 8), "a grid")


def test_the_estimates():
    assert memory.particle_filter_bytes(10_000) == 10_000 * memory.PARTICLE_BYTES
    assert memory.grid_bytes(100.0, 50.0, 0.5, 8) == 200 * 100 * 8


@pytest.mark.parametrize("extra, words", [
    (["--particles", "1000000000000"], "1000000000000 particles"),
    (["--particles", "1000000000"], "1000000000 particles"),
])
def test_huge_settings_are_refused_before_the_work(extra, words, capsys):
    assert main(TRACK + extra) == 1
    err = capsys.readouterr().err
    assert words in err and "of memory, more than the" in err and err.count("\n") == 1


@pytest.mark.parametrize("yaml_text, words", [
    ("filter:\n  init_samples: 10000000000\n", "filter.init_samples"),
    ("wifi:\n  radio_map_likelihood:\n    cell_m: 0.000001\n", "wifi.radio_map_likelihood.cell_m"),
    ("smooth: true\noffline:\n  map_matching:\n    cell_m: 0.000001\n", "offline.map_matching.cell_m"),
])
def test_huge_config_settings_are_refused(tmp_path, yaml_text, words, capsys):
    (tmp_path / "c.yaml").write_text(yaml_text)
    assert main(TRACK + ["--config", str(tmp_path / "c.yaml")]) == 1
    assert words in capsys.readouterr().err


def test_radiomap_grow_particles_refused_before_reading(capsys, tmp_path):
    assert main(["radiomap", "grow", str(MAPS / "office.yaml"), str(MAPS / "office_walk.txt.gz"), "--radiomap",
                 str(MAPS / "office_radiomap.npz"), "--particles", "1000000000000", "--out",
                 str(tmp_path / "g.npz")]) == 1
    assert "--particles 1000000000000 needs about" in capsys.readouterr().err


def test_close_gaps_is_bounded():
    with pytest.raises(SystemExit):
        main(["map", "prepare", str(MAPS / "office_plan.png"), "--resolution", "0.05", "--close-gaps", "100000",
              "--out", "x.yaml"])


def test_jobs_are_bounded_by_the_cores():
    check_local_jobs(1)
    with pytest.raises(MapfilterError, match=f"has {machine_cores()} core"):
        check_local_jobs(machine_cores() + 1)


@pytest.mark.parametrize("edit, words", [
    (lambda a: a.update(ap_keys=np.array("02:00:00:00:00:01|2.4")), "'ap_keys' is 0-d"),
    (lambda a: a.update(version=np.array([2, 2])), "'version' is 1-d"),
    (lambda a: a.update(xy_m=a["xy_m"].astype(str)), "'xy_m' is 2-d <U"),
    (lambda a: a.update(cv_fix_errors_params=np.array([3.0, np.nan, 1.0])), "cv_fix_errors"),
])
def test_malformed_radio_maps_are_one_line(tmp_path, edit, words):
    with np.load(MAPS / "office_radiomap.npz") as data:
        arrays = {k: data[k] for k in data.files}
    edit(arrays)
    np.savez(tmp_path / "rm.npz", **arrays)
    with pytest.raises(MapfilterError, match=words):
        RadioMap.load(tmp_path / "rm.npz")


@pytest.mark.parametrize("kind, words", [("silent", "sent nothing"), ("http", "HTTP"),
                                         ("random", "not a Dask scheduler")])
def test_a_scheduler_that_is_not_one_is_refused_in_seconds(kind, words):
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    held = []

    def serve():
        conn, _ = server.accept()
        held.append(conn)
        if kind == "http":
            conn.sendall(b"HTTP/1.1 400 Bad Request\r\n\r\n")
        elif kind == "random":
            conn.sendall(bytes(range(256)) * 4)  # its first 8 bytes read as a length of exabytes

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        with pytest.raises(MapfilterError, match=words):
            probe_scheduler(f"tcp://127.0.0.1:{server.getsockname()[1]}", timeout_s=1.0)
    finally:
        for conn in held:
            conn.close()
        server.close()
