"""The log readers give the same recordings as another revision's, to the byte.

Reads every log given (default: the 76 ILC site1/F1 walks and the 29 IPIN 2023 logs in
../shared/data) with this checkout's reader, whole and fed to a ``LogStream`` in random pieces,
and compares every array (dtype, shape and bytes), every list and the ``ReadReport`` field by field:

- with ``--baseline REV``, against the reader of git revision REV, run in a child process from a
  temporary worktree (e.g. the revision before a change to the readers);
- always, the whole file against the same file streamed in random pieces (``--seed``).

    .venv/bin/python tools/check_readers.py --baseline main        # about a minute for 105 logs

Prints one line per log that differs (what differs) and a summary; exit code 1 when any differs.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"
DEFAULT_LOGS = [*sorted((DATA / "ilc20" / "site1" / "F1" / "path_data_files").glob("*.txt.gz")),
                *sorted((DATA / "ipin2023" / "logs").glob("*.txt.gz"))]

# Run in the child (the baseline's checkout first on sys.path): one JSON line per log, its digest.
_CHILD = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
sys.path.insert(0, sys.argv[2])
from check_readers import digest_of_file
import mapfilter
assert mapfilter.__file__.startswith(sys.argv[1]), mapfilter.__file__
for path in sys.stdin.read().split("\n"):
    if path:
        print(json.dumps(digest_of_file(path)), flush=True)
"""


def _value_digest(value) -> object:
    """A JSON-able digest of one field: arrays by dtype, shape and a hash of their bytes."""
    import numpy as np

    if isinstance(value, np.ndarray):
        return {"dtype": str(value.dtype), "shape": list(value.shape),
                "sha1": hashlib.sha1(np.ascontiguousarray(value).tobytes()).hexdigest()}
    if isinstance(value, (list, tuple)):
        return [_value_digest(v) for v in value]
    if isinstance(value, dict):  # in its order: a report's counts print in it
        return [[str(k), _value_digest(v)] for k, v in value.items()]
    if isinstance(value, (frozenset, set)):
        return sorted(map(str, value))
    if isinstance(value, float):
        return repr(value)  # exact
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, Path):
        return str(value)
    if hasattr(value, "__dataclass_fields__"):
        return {name: _value_digest(getattr(value, name)) for name in value.__dataclass_fields__}
    if isinstance(value, (np.floating, np.integer)):
        return repr(value.item())
    return repr(value)


def digest(recording) -> dict:
    """Every field of a ``Recording`` (its WiFi scans, beacons and read report included), digested."""
    return _value_digest(recording)


def digest_of_file(path: str) -> dict:
    """The digest of a log read whole by this checkout's reader (or the error it raised)."""
    from mapfilter.errors import MapfilterError
    from mapfilter.sensors.logs import read_log

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return digest(read_log(path))
        except MapfilterError as exc:
            return {"error": str(exc)}


def digest_streamed(path: str, seed: int) -> dict:
    """The digest of the log fed to a ``LogStream`` in random pieces (1 byte to 256 KiB)."""
    import gzip

    import numpy as np

    from mapfilter.errors import MapfilterError
    from mapfilter.sensors.logs import LogStream
    from mapfilter.sensors.recording import concatenate

    data = Path(path).read_bytes()
    if data[:2] == b"\x1f\x8b":
        data = gzip.decompress(data)
    rng = np.random.default_rng(seed)
    stream = LogStream(path)
    chunks, at = [], 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            while at < len(data):
                size = int(rng.choice([1, 7, 100, 4096, 65536, 262144]) * rng.uniform(0.5, 1.5)) + 1
                chunks.append(stream.feed_bytes(data[at:at + size]))
                at += size
            chunks.append(stream.close())
        except MapfilterError as exc:
            return {"error": str(exc)}
    return digest(concatenate(chunks))


def differences(a: object, b: object, where: str = "") -> list[str]:
    """The paths at which two digests differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b)):
            out += differences(a.get(key, "<absent>"), b.get(key, "<absent>"), f"{where}.{key}" if where else key)
        return out
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in differences(x, y, f"{where}[{i}]")]
    return [] if a == b else [where or "<root>"]


def _baseline_digests(revision: str, paths: list[Path]) -> list[dict]:
    with contextlib.ExitStack() as stack:
        checkout = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="check_readers_"))) / "repo"
        subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", str(checkout), revision],
                       check=True, capture_output=True)
        stack.callback(subprocess.run, ["git", "-C", str(REPO), "worktree", "remove", "--force", str(checkout)],
                       capture_output=True)
        done = subprocess.run([sys.executable, "-c", _CHILD, str(checkout), str(REPO / "tools")],
                              input="\n".join(map(str, paths)), capture_output=True, text=True, cwd=checkout)
        if done.returncode != 0:
            raise SystemExit(f"the baseline's reader failed: {done.stderr.strip()[-2000:]}")
        return [json.loads(line) for line in done.stdout.splitlines()]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.splitlines()[0])
    parser.add_argument("logs", nargs="*", type=Path, help="logs to read (default: ILC site1/F1 and IPIN 2023)")
    parser.add_argument("--baseline", metavar="REV", help="also compare with the reader of this git revision")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random pieces a stream is fed")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(REPO))
    paths = args.logs or DEFAULT_LOGS
    if not paths:
        raise SystemExit(f"no logs given and none found under {DATA}")
    baseline = _baseline_digests(args.baseline, paths) if args.baseline else None
    n_bad = 0
    for i, path in enumerate(paths):
        whole = digest_of_file(str(path))
        found = []
        streamed = digest_streamed(str(path), args.seed + i)
        if differences(whole, streamed):
            found.append("streamed in pieces: " + ", ".join(differences(whole, streamed)[:8]))
        if baseline is not None and differences(baseline[i], whole):
            found.append(f"against {args.baseline}: " + ", ".join(differences(baseline[i], whole)[:8]))
        if found:
            n_bad += 1
            print(f"{path.name}: " + "; ".join(found), flush=True)
    compared = f" and with {args.baseline}'s reader" if args.baseline else ""
    print(f"{len(paths) - n_bad} of {len(paths)} logs the same whole and streamed{compared}")
    return 1 if n_bad else 0


if __name__ == "__main__":
    sys.exit(main())
