"""Write output files so that a failure leaves nothing half-written."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def atomic_paths(*final_paths: str | os.PathLike) -> Iterator[list[Path]]:
    """Yield temporary paths beside ``final_paths``; move them into place only on success.

    All files appear together at the end of the ``with`` block; if the block raises,
    the temporaries are removed and no final path is touched.
    """
    finals = [Path(p) for p in final_paths]
    temps: list[Path] = []
    try:
        for final in finals:
            final.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{final.stem}.", suffix=final.suffix, dir=final.parent)
            os.close(fd)
            temps.append(Path(tmp))
        yield temps
        # mkstemp makes files private (0600); give them the usual mode (0666 minus the umask)
        umask = os.umask(0)
        os.umask(umask)
        for tmp, final in zip(temps, finals):
            if tmp.exists():
                os.chmod(tmp, 0o666 & ~umask)
            os.replace(tmp, final)
        temps = []
    finally:
        for tmp in temps:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
