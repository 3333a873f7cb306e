"""mapfilter's build backend: setuptools', plus the numba kernels compiled at an editable install.

A first command would otherwise spend about 15 s of CPU compiling the kernels (``cache=True``
keeps them for the next). ``pip install -e .`` builds through ``build_editable`` below: it asks
for the kernels' own dependencies in the build environment, then runs ``mapfilter.runtime.warmup`` on
the sources, which stay where they are, so numba's cache beside them is the one every command
loads. Any failure there only costs the first command its compile: the install goes on.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from setuptools import build_meta as _setuptools
from setuptools.build_meta import *  # noqa: F401,F403 - every other hook is setuptools'

# what ``mapfilter.runtime.warmup`` imports (the same lower bounds as the project's dependencies)
KERNEL_REQUIREMENTS = ["numpy>=1.26", "scipy>=1.11", "numba>=0.60", "pyyaml>=6.0", "opencv-python-headless>=4.8"]
SOURCE = Path(__file__).resolve().parents[1]


def get_requires_for_build_editable(config_settings=None):
    return _setuptools.get_requires_for_build_editable(config_settings) + KERNEL_REQUIREMENTS


def build_editable(wheel_directory, config_settings=None, metadata_directory=None):
    wheel = _setuptools.build_editable(wheel_directory, config_settings, metadata_directory)
    _compile_kernels()
    return wheel


def _compile_kernels() -> None:
    if os.environ.get("MAPFILTER_SKIP_WARMUP"):
        return
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(SOURCE), env.get("PYTHONPATH", "")) if p)
    try:
        done = subprocess.run([sys.executable, "-m", "mapfilter.runtime.warmup"], cwd=SOURCE, env=env, timeout=1800,
                              capture_output=True, text=True)
    except (OSError, subprocess.SubprocessError) as error:
        print(f"mapfilter: the numba kernels were not compiled at install ({error}); the first command will",
              file=sys.stderr)
        return
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no message"])[-1]
        print(f"mapfilter: the numba kernels were not compiled at install ({last}); the first command will",
              file=sys.stderr)
    else:
        print(done.stdout.strip(), file=sys.stderr)
