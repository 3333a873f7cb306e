"""The README's first command run by a user who cannot write the installed package (a
system-wide or container install): numba's cache goes to a per-user folder instead."""

import ctypes
import os
import shutil
import stat
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
README_FIRST = ["track", "maps/office.yaml", "maps/office_walk.txt.gz", "--radiomap", "maps/office_radiomap.npz",
                "--smooth"]
_PR_CAPBSET_DROP = 24
_CAP_DAC_OVERRIDE, _CAP_DAC_READ_SEARCH, _CAP_FOWNER = 1, 2, 3


def _as_a_user_without_write_access() -> None:
    """In the child: root keeps its uid but loses the capabilities that let it write anywhere
    (file modes then apply to it as to anyone); another user is one already."""
    if os.geteuid() != 0:
        return
    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (_CAP_DAC_OVERRIDE, _CAP_DAC_READ_SEARCH, _CAP_FOWNER):
        if libc.prctl(_PR_CAPBSET_DROP, cap, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP)")


def _read_only(path: Path) -> None:
    for root, dirs, files in os.walk(path):
        for name in dirs + files:
            p = Path(root, name)
            p.chmod(p.stat().st_mode & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))
    path.chmod(path.stat().st_mode & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))


def _writable_again(path: Path) -> None:
    for root, dirs, _ in os.walk(path):
        for name in dirs:
            Path(root, name).chmod(0o755)
    path.chmod(0o755)


@pytest.mark.slow
@pytest.mark.parametrize("home", ["writable", "read-only"])
def test_the_readme_first_command_runs_from_an_install_the_user_cannot_write(tmp_path, home):
    install = tmp_path / "install"
    shutil.copytree(REPO / "mapfilter", install / "mapfilter",
                    ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    home_dir = tmp_path / "home"
    home_dir.mkdir()
    # the README's relative paths, from a folder that is not the checkout (which would come first on sys.path)
    work = tmp_path / "work"
    shutil.copytree(REPO / "maps", work / "maps")
    _read_only(install)
    if home == "read-only":  # a container user whose HOME is not theirs: the temporary folder is left
        _read_only(home_dir)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "XDG_"))}
    # -S: without site's start-up files the development checkout's editable install (a .pth
    # finder that would win over PYTHONPATH) is not loaded; the dependencies come from PYTHONPATH
    env.update(PYTHONPATH=os.pathsep.join([str(install), sysconfig.get_paths()["purelib"]]), HOME=str(home_dir),
               TMPDIR=str(tmp_path))
    try:
        probe = subprocess.run([sys.executable, "-S", "-c", "import mapfilter; print(mapfilter.__file__)"], env=env,
                               cwd=work, capture_output=True, text=True, preexec_fn=_as_a_user_without_write_access)
        assert probe.stdout.strip() == str(install / "mapfilter" / "__init__.py"), probe.stderr
        run = subprocess.run([sys.executable, "-S", "-m", "mapfilter", *README_FIRST], env=env, cwd=work,
                             capture_output=True, text=True, timeout=600,
                             preexec_fn=_as_a_user_without_write_access)
    finally:
        _writable_again(install)
        _writable_again(home_dir)
    assert run.returncode == 0, run.stderr
    assert "Traceback" not in run.stderr
    assert "filter steps" in run.stdout and "offline" in run.stdout
    assert not list(install.rglob("*.nbi")), "numba wrote into the install"
    cache = home_dir / ".cache" / "mapfilter" / "numba" if home == "writable" else tmp_path / f"mapfilter-numba-{os.getuid()}"
    assert list(cache.rglob("*.nbi")), f"no numba cache in {cache}"
