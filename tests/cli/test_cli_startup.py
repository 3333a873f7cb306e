"""Start-up: --help imports no numerical library, and the CLI's copies of defaults match the library's."""

import dataclasses
import subprocess
import sys

import pytest

from mapfilter.cli import evaluate_cmd, radiomap_cmd, simulate_cmd, tracking_options

HEAVY = ("numpy", "numba", "scipy", "cv2", "shapely", "rerun", "matplotlib")


@pytest.mark.parametrize("argv", [["--help"], ["track", "--help"], ["evaluate", "--help"], ["map", "prepare", "--help"],
                                  ["radiomap", "build", "--help"], ["simulate", "--help"], ["view", "--help"],
                                  ["config", "show", "--help"]])
def test_help_imports_no_numerical_library(argv):
    code = ("import sys\nfrom mapfilter.cli import main\ntry:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
            f"print('imported:', ','.join(m for m in {HEAVY!r} if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, check=True).stdout
    assert "usage: mapfilter" in out
    assert out.strip().splitlines()[-1] == "imported:"  # none of HEAVY


def test_cli_defaults_are_the_librarys():
    from mapfilter.config import TrackingConfig
    from mapfilter.evaluation.comparison import ALL_METHODS, BUILDING_METHODS
    from mapfilter.filter.evidence import FINGERPRINT_MODELS
    from mapfilter.filter.causal import MOTION_MODELS
    from mapfilter.sensors.pathloss import ApFitConfig
    from mapfilter.simulate.walk import SimConfig

    options, config = tracking_options, TrackingConfig()
    assert options.MOTION_MODELS == MOTION_MODELS and options.FINGERPRINT_MODELS == FINGERPRINT_MODELS
    assert options.DEFAULT_PARTICLES == config.filter.n_particles
    assert options.DEFAULT_FINGERPRINT_MODEL == config.wifi.fingerprint_model
    assert options.DEFAULT_KWNN_MIN_RSSI_DBM == config.wifi.kwnn_min_rssi_dbm
    assert evaluate_cmd.ALL_METHODS == ALL_METHODS and evaluate_cmd.BUILDING_METHODS == BUILDING_METHODS
    assert options.DEFAULT_ADAPT_RSSI_LIMIT_DBM == config.trilateration.adapt_rssi_limit_dbm
    assert radiomap_cmd._MIN_OBSERVATIONS == ApFitConfig.min_observations
    sim = dataclasses.asdict(SimConfig())
    assert {key: sim[key] for key in simulate_cmd._SIM_DEFAULTS} == simulate_cmd._SIM_DEFAULTS


def test_cli_simulate_limits_are_the_librarys():
    from mapfilter.simulate import walk

    assert {name: getattr(walk, name) for name in simulate_cmd._SIM_LIMITS} == simulate_cmd._SIM_LIMITS
    assert simulate_cmd._MIN_SURVEY_SPACING_M == walk.SimConfig.grid_m
