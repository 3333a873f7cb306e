"""mapfilter's build backend: setuptools', plus the numba kernels compiled at an editable install.

A first command would otherwise spend about 15 s of CPU compiling the kernels (``cache=True``
keeps them for the next). ``pip install -e .`` builds through ``build_editable`` below: it asks
for the kernels' own dependencies in the build environment, then runs ``mapfilter.runtime.warmup`` on
the sources, which stay where they are, so numba's cache beside them is the one every command
loads. Any failure there only costs the first command its compile: the install goes on.

The editable wheel also gets ``FIRST_PTH``: setuptools' editable install finds the package
through an import hook it appends after Python's own path search, so Python started in the
folder that holds a clone named ``mapfilter`` took that folder for a namespace package
(``module 'mapfilter' has no attribute 'load_map'``); the line puts the hook first.
"""

from __future__ import annotations

import base64
import hashlib
import os
import subprocess
import sys
import zipfile
from pathlib import Path

from setuptools import build_meta as _setuptools
from setuptools.build_meta import *  # noqa: F401,F403 - every other hook is setuptools'

# what ``mapfilter.runtime.warmup`` imports (the same bounds as the project's dependencies: numba's cache
# holds for the numba release that wrote it)
KERNEL_REQUIREMENTS = ["numpy>=1.26", "scipy>=1.11", "numba>=0.61,<0.69", "pyyaml>=6.0", "opencv-python-headless>=4.8"]
SOURCE = Path(__file__).resolve().parents[1]


def get_requires_for_build_editable(config_settings=None):
    return _setuptools.get_requires_for_build_editable(config_settings) + KERNEL_REQUIREMENTS


# a .pth file's line runs at every start of Python: setuptools' editable finder for mapfilter
# ahead of the path search (its __editable__ .pth, which sorts first, has appended it)
FIRST_PTH = ("mapfilter_finder_first.pth",
             "import sys; sys.meta_path[:] = sorted(sys.meta_path, key=lambda finder: not getattr(finder, "
             "'__module__', '').startswith('__editable___mapfilter'))\n")


def build_editable(wheel_directory, config_settings=None, metadata_directory=None):
    wheel = _setuptools.build_editable(wheel_directory, config_settings, metadata_directory)
    _add_to_wheel(Path(wheel_directory) / wheel, *FIRST_PTH)
    _compile_kernels()
    return wheel


def _add_to_wheel(wheel: Path, name: str, text: str) -> None:
    """The wheel with one more top-level file, listed in its RECORD (the wheel is rewritten)."""
    data = text.encode()
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    rewritten = wheel.with_name(wheel.name + ".tmp")
    with zipfile.ZipFile(wheel) as source, zipfile.ZipFile(rewritten, "w", zipfile.ZIP_DEFLATED) as target:
        for item in source.infolist():
            content = source.read(item)
            if item.filename.endswith(".dist-info/RECORD"):
                content += f"{name},sha256={digest},{len(data)}\n".encode()
            target.writestr(item, content)
        target.writestr(name, data)
    os.replace(rewritten, wheel)


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
