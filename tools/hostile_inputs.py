"""Throw issue 27's broken and hostile inputs at the CLI and print what each does.

Every case runs ``python -m mapfilter ...`` as a subprocess with its address space capped
(``RLIMIT_AS``, default 4 GB: a case that asks for more gets a MemoryError instead of taking
the machine) and a timeout (default 180 s; the case's process group is then killed). The
table gives each case's exit code, the first line of its stderr that says something (the
``mapfilter: error`` line, or the last line of a traceback), its peak memory (the child's
``ru_maxrss`` from ``wait4``, which covers the processes it waited for) and its wall time, and
a verdict: ``ok`` when there is no traceback, the exit code is the one expected, the peak is
under 2 GB and the time under 2 minutes (issue 27's bar).

The hostile files are made in a temporary directory (removed at the end unless ``--keep``),
never in the repository. Usage::

    .venv/bin/python tools/hostile_inputs.py [--only NAME ...] [--skip-slow] [--markdown OUT.md]
"""

from __future__ import annotations

import argparse
import dataclasses
import gzip
import os
import resource
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import zlib
from collections.abc import Callable
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MAPS = REPO / "maps"
WALK = MAPS / "office_walk.txt.gz"
MAP = MAPS / "office.yaml"
RADIOMAP = MAPS / "office_radiomap.npz"
APS = MAPS / "office_aps.csv"
DAY_MS = 86_400_000
BAR_MB, BAR_S = 2048, 120.0  # issue 27: no case above 2 GB or 2 minutes


@dataclasses.dataclass
class Case:
    name: str
    where: str  # the module (under mapfilter/) that handles it
    argv: Callable[[Path], list[str]] | None  # mapfilter arguments, given the work directory
    expect: tuple[int, ...] = (1,)  # exit codes that count as handled
    stdin_closed_stdout: bool = False  # run with a stdout whose reader has gone (| head -1)
    fsize_bytes: int | None = None  # RLIMIT_FSIZE: writes past it fail as on a full disk
    sigterm_when: str | None = None  # send SIGTERM once a file with this prefix appears in the work dir
    python: str | None = None  # run this Python code instead of the CLI
    slow: bool = False
    must_say: str = ""  # the first stderr line must hold this (a row skipped: the warning that says so)


@dataclasses.dataclass
class Outcome:
    case: Case
    code: int | None
    message: str
    peak_mb: float
    wall_s: float
    leftovers: list[str]

    @property
    def verdict(self) -> str:
        problems = []
        if self.code not in self.case.expect:
            problems.append(f"exit {self.code}")
        if self.case.must_say and self.case.must_say not in self.message:
            problems.append(f"no '{self.case.must_say}'")
        if "Traceback" in self.message or self.message.startswith("(traceback)"):
            problems.append("traceback")
        if self.peak_mb > BAR_MB:
            problems.append("memory")
        if self.wall_s > BAR_S:
            problems.append("time")
        if self.leftovers:
            problems.append("left " + ", ".join(self.leftovers))
        return "ok" if not problems else "FAILS: " + "; ".join(problems)


# ---- hostile files ------------------------------------------------------------------------------
def _walk_lines() -> list[str]:
    with gzip.open(WALK, "rt") as handle:
        return handle.readlines()


def _write_walk(path: Path, edit: Callable[[list[str]], list[str]]) -> Path:
    path.write_text("".join(edit(_walk_lines())))
    return path


def _fields(line: str) -> list[str]:
    return line.rstrip("\n").split("\t")


def _shift_after(lines: list[str], split_ms: int, shift_ms: int, only: str | None = None, first_only: bool = False):
    out, done = [], False
    for line in lines:
        f = _fields(line)
        if line.startswith("#") or int(f[0]) <= split_ms or (only and f[1] != only) or (first_only and done):
            out.append(line)
            continue
        f[0] = str(int(f[0]) + shift_ms)
        if f[1] == "TYPE_WIFI":
            f[6] = str(int(f[6]) + shift_ms)
        out.append("\t".join(f) + "\n")
        done = True
    return out


def _set_first(lines: list[str], kind: str, column: int, value: str) -> list[str]:
    out, done = [], False
    for line in lines:
        f = _fields(line)
        if not done and not line.startswith("#") and f[1] == kind:
            f[column] = value
            line, done = "\t".join(f) + "\n", True
        out.append(line)
    return out


def write_flat_png(path: Path, width: int, height: int, value: int = 254) -> Path:
    """A valid grey PNG of one colour, streamed row by row (20000 x 20000: 0.4 MB, seconds)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    packer = zlib.compressobj(9)
    row = b"\x00" + bytes([value]) * width
    data = b"".join(packer.compress(row) for _ in range(height)) + packer.flush()
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
                     + chunk(b"IDAT", data) + chunk(b"IEND", b""))
    return path


def write_long_line_gzip(path: Path, line_bytes: int) -> Path:
    """The bundled walk with one line of ``line_bytes`` bytes (no newline) in the middle, gzipped."""
    lines = _walk_lines()
    block = b"7" * (1 << 24)
    with gzip.open(path, "wb", compresslevel=6) as out:
        out.writelines(line.encode() for line in lines[:2000])
        out.write(b"1600000040000\tTYPE_WIFI\t")
        left = line_bytes
        while left > 0:
            out.write(block[:min(left, len(block))])
            left -= len(block)
        out.write(b"\n")
        out.writelines(line.encode() for line in lines[2000:])
    return path


def write_forged_npz(path: Path, declared_shape: tuple[int, int]) -> Path:
    """A radio map whose rssi_dbm header declares ``declared_shape`` float32 and holds 64 bytes."""
    import io
    import zipfile

    import numpy as np
    from numpy.lib import format as npy

    with zipfile.ZipFile(path, "w") as archive:
        for name, value in (("format", np.array("mapfilter-radiomap")), ("version", np.array(2))):
            buffer = io.BytesIO()
            npy.write_array(buffer, value)
            archive.writestr(f"{name}.npy", buffer.getvalue())
        buffer = io.BytesIO()
        npy.write_array_header_1_0(buffer, {"descr": "<f4", "fortran_order": False, "shape": declared_shape})
        archive.writestr("rssi_dbm.npy", buffer.getvalue() + b"\0" * 64)
    return path


def write_far_radiomap(path: Path, offset_m: float) -> Path:
    from mapfilter.sensors.radiomap import RadioMap

    radio_map = RadioMap.load(RADIOMAP)
    radio_map.xy_m = radio_map.xy_m + [offset_m, 0.0]
    radio_map.save(path)
    return path


def write_ap_table(path: Path, column: str, value: str, row: int = 3) -> Path:
    lines = APS.read_text().splitlines()
    header = lines[0].split(",")
    fields = lines[row - 1].split(",")
    fields[header.index(column)] = value
    lines[row - 1] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")
    return path


def make_files(work: Path, skip_slow: bool) -> None:
    """Every hostile input, in ``work``."""
    write_flat_png(work / "big.png", 20000, 20000)
    (work / "big.yaml").write_text("image: big.png\nresolution: 0.05\norigin: [0, 0, 0]\n")
    for name, key, value in (("tiny", "resolution", "1.0e-300"), ("negative", "resolution", "-0.05"),
                             ("nan", "resolution", ".nan"), ("far_origin", "origin", "[1.0e+300, 0, 0]")):
        meta = {"image": str(MAPS / "office.png"), "resolution": "0.05", "origin": "[0, 0, 0]", key: value}
        (work / f"{name}.yaml").write_text("".join(f"{k}: {v}\n" for k, v in meta.items()))
    write_forged_npz(work / "huge_header.npz", (100_000, 100_000))
    (work / "random.npz").write_bytes(os.urandom(100_000))
    write_far_radiomap(work / "far_radiomap.npz", 1e6)
    write_ap_table(work / "aps_n0.csv", "n", "0")
    write_ap_table(work / "aps_dmax.csv", "d_max", "-5")
    write_ap_table(work / "aps_c.csv", "C", "1e9")
    write_ap_table(work / "aps_far.csv", "x", "1000000")  # 1000 km east
    _write_walk(work / "gap30d.txt", lambda lines: _shift_after(lines, 1_600_000_060_000, 30 * DAY_MS))
    _write_walk(work / "wifi_3y.txt",
                lambda lines: _shift_after(lines, 1_600_000_060_000, 3 * 365 * DAY_MS, only="TYPE_WIFI",
                                           first_only=True))
    _write_walk(work / "rssi_1e300.txt", lambda lines: _set_first(lines, "TYPE_WIFI", 4, "1e300"))
    _write_walk(work / "acc_1e308.txt", lambda lines: _set_first(lines, "TYPE_ACCELEROMETER", 2, "1e308"))
    _write_walk(work / "negative_t.txt", lambda lines: _set_first(lines, "TYPE_ACCELEROMETER", 0, "-5000"))
    _write_walk(work / "duplicated.txt", lambda lines: [x for line in lines for x in ((line,) if line.startswith("#")
                                                                                        else (line, line))])
    _write_walk(work / "no_wifi.txt", lambda lines: [x for x in lines if "\tTYPE_WIFI\t" not in x])

    def far_waypoints(lines: list[str]) -> list[str]:
        out = []
        for line in lines:
            f = _fields(line)
            if not line.startswith("#") and f[1] == "TYPE_WAYPOINT":
                f[2] = f"{float(f[2]) + 1e6:.6f}"
                line = "\t".join(f) + "\n"
            out.append(line)
        return out

    _write_walk(work / "far_survey.txt", far_waypoints)
    if not skip_slow:
        write_long_line_gzip(work / "long_line.txt.gz", 3 << 30)
    (work / "a-file").write_text("x")
    (work / "outdir").mkdir()


# ---- the cases ----------------------------------------------------------------------------------
def _track(log: str | Path, *extra: str, map_path: str | Path = MAP) -> Callable[[Path], list[str]]:
    return lambda w: ["track", str(map_path).format(w=w), str(log).format(w=w), *[e.format(w=w) for e in extra]]


_FOREIGN_CLIENT = """
import logging
from distributed import Client
from distributed.security import Security
from mapfilter.engine import Engine, _DaskClient
with _DaskClient(Engine(jobs=2)) as client:
    client.wait_for_workers(2, timeout=120)
    address = client.scheduler_info()["address"]
    for attempt, security, label in ((address.replace("tls://", "tcp://"), None, "plain TCP"),
                                     (address, Security.temporary(), "TLS, other credentials")):
        try:
            Client(attempt, timeout="5s", security=security).close()
            print(f"FOREIGN CLIENT CONNECTED ({label}) to {address}")
            raise SystemExit(3)
        except OSError as exc:
            pass
    print(f"foreign clients refused by the --jobs cluster at {address} (plain TCP; TLS with other credentials)")
"""

CASES = [
    # inputs larger than memory
    Case("plan 20000x20000 PNG (0.4 MB)", "maps/floorplan.py", _track(WALK, "--radiomap", str(RADIOMAP), map_path="{w}/big.yaml")),
    Case("map prepare of that PNG", "maps/floorplan.py",
         lambda w: ["map", "prepare", f"{w}/big.png", "--resolution", "0.05", "--out", f"{w}/outdir/m.yaml"]),
    Case("map resolution: 1e-300", "maps/floorplan.py", _track(WALK, map_path="{w}/tiny.yaml")),
    Case("map resolution: -0.05", "maps/floorplan.py", _track(WALK, map_path="{w}/negative.yaml")),
    Case("map resolution: NaN", "maps/floorplan.py", _track(WALK, map_path="{w}/nan.yaml")),
    Case("map origin 1e300 m", "maps/floorplan.py", _track(WALK, map_path="{w}/far_origin.yaml")),
    Case(".npz declaring 100000x100000", "sensors/radiomap.py", _track(WALK, "--radiomap", "{w}/huge_header.npz")),
    Case("random bytes named .npz", "sensors/radiomap.py", _track(WALK, "--radiomap", "{w}/random.npz")),
    Case("simulate --survey-spacing 0.001", "cli/simulate_cmd.py",
         lambda w: ["simulate", str(MAP), "--survey", "--survey-spacing", "0.001", "--out", f"{w}/s.txt"], (2,)),
    Case("simulate --duration 1e9", "cli/simulate_cmd.py",
         lambda w: ["simulate", str(MAP), "--duration", "1e9", "--out", f"{w}/s.txt"], (2,)),
    Case("simulate --scans-per-point 1e6", "cli/simulate_cmd.py",
         lambda w: ["simulate", str(MAP), "--survey", "--scans-per-point", "1000000", "--out", f"{w}/s.txt"], (2,)),
    # a bad row is skipped and named in one warning, the walk tracked (exit 0); --strict refuses it
    Case("one 3 GB line in a gzip", "sensors/logread.py", _track("{w}/long_line.txt.gz", "--radiomap", str(RADIOMAP)),
         (0,), slow=True, must_say="skipped 1 unreadable line"),
    Case("one 3 GB line in a gzip, --strict", "sensors/logread.py",
         _track("{w}/long_line.txt.gz", "--radiomap", str(RADIOMAP), "--strict"), slow=True),
    # values that make no sense
    Case("AP table n = 0", "sensors/pathloss.py", _track(WALK, "--aps", "{w}/aps_n0.csv")),
    Case("AP table d_max < 0", "sensors/pathloss.py", _track(WALK, "--aps", "{w}/aps_dmax.csv")),
    Case("AP table C = 1e9 dBm", "sensors/pathloss.py", _track(WALK, "--aps", "{w}/aps_c.csv")),
    Case("AP 1000 km away", "sensors/pathloss.py", _track(WALK, "--aps", "{w}/aps_far.csv")),
    Case("radio map 1e6 m off the floor (track)", "sensors/radiomap.py",
         _track(WALK, "--radiomap", "{w}/far_radiomap.npz")),
    Case("survey 1e6 m off the floor (radiomap build)", "sensors/radiomap.py",
         lambda w: ["radiomap", "build", str(MAP), f"{w}/far_survey.txt", "--out", f"{w}/outdir/rm.npz"]),
    Case("AP fit, an RSSI of 1e300 dBm", "sensors/logread.py",
         lambda w: ["radiomap", "fit-aps", str(MAP), f"{w}/rssi_1e300.txt", "--out", f"{w}/outdir/aps.csv"], (0,)),
    Case("track, an RSSI of 1e300 dBm", "sensors/logread.py", _track("{w}/rssi_1e300.txt", "--radiomap", str(RADIOMAP)),
         (0,), must_say="RSSI out of range"),
    Case("track, an RSSI of 1e300 dBm, --strict", "sensors/logread.py",
         _track("{w}/rssi_1e300.txt", "--radiomap", str(RADIOMAP), "--strict")),
    Case("track, an acceleration of 1e308", "sensors/logread.py", _track("{w}/acc_1e308.txt", "--radiomap", str(RADIOMAP)),
         (0,), must_say="out of range"),
    Case("track, a negative timestamp", "sensors/logread.py", _track("{w}/negative_t.txt", "--radiomap", str(RADIOMAP)),
         (0,), must_say="time out of range"),
    Case("evaluate, every record twice", "sensors/logread.py",
         lambda w: ["evaluate", str(MAP), f"{w}/duplicated.txt", "--radiomap", str(RADIOMAP), "--methods", "kwnn",
                    "--out", f"{w}/outdir/dup"], (0,), must_say="exact duplicate rows"),
    # time gaps
    Case("a 30-day gap in the log", "sensors/pdr.py, filter/run.py",
         _track("{w}/gap30d.txt", "--radiomap", str(RADIOMAP)), (0, 1)),
    Case("a WiFi row stamped 3 years ahead", "sensors/logread.py, filter/run.py",
         _track("{w}/wifi_3y.txt", "--radiomap", str(RADIOMAP)), (0, 1)),
    Case("evaluate, one walk without WiFi", "evaluation/comparison.py",
         lambda w: ["evaluate", str(MAP), str(WALK), f"{w}/no_wifi.txt", "--radiomap", str(RADIOMAP), "--methods",
                    "kwnn", "--out", f"{w}/outdir/nowifi"]),
    # the cluster
    Case("--scheduler tcp://", "engine.py", _track(WALK, "--radiomap", str(RADIOMAP), "--scheduler", "tcp://",
                                                    "--out-dir", "{w}/outdir/s1")),
    Case("--scheduler foo://x:1", "engine.py", _track(WALK, "--radiomap", str(RADIOMAP), "--scheduler",
                                                       "foo://x:1", "--out-dir", "{w}/outdir/s2")),
    Case("--scheduler tcp://host:99999", "engine.py", _track(WALK, "--radiomap", str(RADIOMAP), "--scheduler",
                                                              "tcp://host:99999", "--out-dir", "{w}/outdir/s3")),
    Case("foreign client vs the --jobs cluster", "engine.py", None, (0,), python=_FOREIGN_CLIENT),
    # outputs
    Case("simulate --out in an unwritable dir", "cli/common.py",
         lambda w: ["simulate", str(MAP), "--out", "/sys/walk.txt"]),
    Case("simulate --out a directory", "cli/common.py", lambda w: ["simulate", str(MAP), "--out", f"{w}/outdir"]),
    Case("radiomap build --out under a file", "cli/common.py",
         lambda w: ["radiomap", "build", str(MAP), str(WALK), "--out", f"{w}/a-file/rm.npz"]),
    Case("track --out in an unwritable dir", "cli/common.py",
         _track(WALK, "--radiomap", str(RADIOMAP), "--out", "/sys/track.csv")),
    Case("track --out a directory", "cli/common.py",
         _track(WALK, "--radiomap", str(RADIOMAP), "--out", "{w}/outdir")),
    Case("evaluate --out under a file", "cli/common.py",
         lambda w: ["evaluate", str(MAP), str(WALK), "--radiomap", str(RADIOMAP), "--methods", "kwnn",
                    "--out", f"{w}/a-file/eval"]),
    Case("full disk: simulate", "atomic.py", lambda w: ["simulate", str(MAP), "--out", f"{w}/outdir/full.txt"],
         fsize_bytes=100_000),
    Case("full disk: radiomap build", "atomic.py",
         lambda w: ["radiomap", "build", str(MAP), str(WALK), "--out", f"{w}/outdir/full.npz"], fsize_bytes=2_000),
    Case("full disk: track --rerun", "viz/recorder.py",
         _track(WALK, "--radiomap", str(RADIOMAP), "--rerun", "{w}/outdir/full.rrd"), fsize_bytes=100_000),
    Case("full disk: track --out", "atomic.py",
         _track(WALK, "--radiomap", str(RADIOMAP), "--out", "{w}/outdir/full.csv"), fsize_bytes=1_000),
    Case("full disk: evaluate", "atomic.py, cli/__init__.py",
         lambda w: ["evaluate", str(MAP), str(WALK), "--radiomap", str(RADIOMAP), "--methods", "kwnn",
                    "--out", f"{w}/outdir/full_eval"], fsize_bytes=20_000),
    Case("check LOG... | head -1", "cli/__init__.py", lambda w: ["check", str(WALK), str(WALK), str(WALK)], (141,),
         stdin_closed_stdout=True),
    Case("simulate --seed -1", "cli/common.py", lambda w: ["simulate", str(MAP), "--seed", "-1", "--out", f"{w}/x.txt"],
         (2,)),
    Case("track --seed -1", "cli/common.py", _track(WALK, "--radiomap", str(RADIOMAP), "--seed", "-1"),
         (2,)),
    Case("SIGTERM during track --rerun", "cli/__init__.py",
         _track(WALK, "--radiomap", str(RADIOMAP), "--smooth", "--rerun", "{w}/outdir/run.rrd"), (143,),
         sigterm_when=".run."),
]


# ---- running ------------------------------------------------------------------------------------
def run_case(case: Case, work: Path, memory_bytes: int, timeout_s: float) -> Outcome:
    before = set(_tree(work))
    if case.python is not None:
        argv = [sys.executable, "-c", case.python]
    else:
        argv = [sys.executable, "-m", "mapfilter", *case.argv(work)]

    def limits() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
        if case.fsize_bytes is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (case.fsize_bytes, case.fsize_bytes))

    err_path = work / ".stderr"
    read_end = write_end = None
    if case.stdin_closed_stdout:
        read_end, write_end = os.pipe()
        os.close(read_end)  # the reader has gone, as after `| head -1`
    with err_path.open("w") as err:
        start = time.monotonic()
        process = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stderr=err, cwd=work, preexec_fn=limits,
                                   stdout=(write_end if write_end is not None else
                                           err if case.python is not None else subprocess.DEVNULL),
                                   start_new_session=True)
        if write_end is not None:
            os.close(write_end)
        status, usage, killed, signalled = None, None, False, False
        while status is None:
            pid, wait_status, rusage = os.wait4(process.pid, os.WNOHANG)
            if pid:
                status, usage = wait_status, rusage
                break
            if case.sigterm_when and not signalled and any(p.name.startswith(case.sigterm_when)
                                                           for p in (work / "outdir").iterdir()):
                time.sleep(0.5)  # let it write a few steps more
                os.kill(process.pid, signal.SIGTERM)
                signalled = True
            if time.monotonic() - start > timeout_s:
                os.killpg(process.pid, signal.SIGKILL)  # the case's own process group
                killed = True
            time.sleep(0.05)
        wall = time.monotonic() - start
        process.returncode = os.waitstatus_to_exitcode(status)  # keep Popen from waiting again
    text = err_path.read_text(errors="replace")
    err_path.unlink()
    leftovers = sorted(set(_tree(work)) - before)
    leftovers = [p for p in leftovers if Path(p).name.startswith(".")]  # temporaries (finished outputs may stay)
    message = _first_line(text)
    if killed:
        message = f"(killed after {timeout_s:g} s) " + message
    if case.sigterm_when and not signalled:
        message = "(finished before the signal) " + message
    return Outcome(case, process.returncode, message, usage.ru_maxrss / 1024.0, wall, leftovers)


def _tree(root: Path) -> list[str]:
    return [str(p.relative_to(root)) for p in root.rglob("*") if p.is_file()]


def _first_line(stderr: str) -> str:
    """The line that says what happened: the error line, the end of a traceback, or the first line."""
    lines = [line for line in stderr.splitlines() if line.strip()]
    if not lines:
        return ""
    if any(line.startswith("Traceback") for line in lines):
        return "(traceback) " + lines[-1].strip()
    for prefix in ("mapfilter: ", "mapfilter "):  # ours (and argparse's usage errors)
        for line in lines:
            if line.startswith(prefix):
                return line.strip()
    return lines[0].strip()


def table(outcomes: list[Outcome]) -> str:
    rows = ["| case | handled in | exit | first line of stderr | peak MB | wall s | verdict |",
            "| --- | --- | --- | --- | --- | --- | --- |"]
    for o in outcomes:
        message = o.message.replace("|", "\\|")
        if len(message) > 160:
            message = message[:157] + "..."
        rows.append(f"| {o.case.name.replace('|', chr(92) + '|')} | {o.case.where} | {o.code} | {message} | {o.peak_mb:.0f} | {o.wall_s:.1f} | "
                    f"{o.verdict} |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", nargs="+", metavar="TEXT", help="run the cases whose name contains any TEXT")
    parser.add_argument("--skip-slow", action="store_true", help="leave out the 3 GB line (its gzip takes a while)")
    parser.add_argument("--memory-gb", type=float, default=4.0, help="address-space cap per case (default 4)")
    parser.add_argument("--timeout", type=float, default=180.0, help="seconds per case (default 180)")
    parser.add_argument("--keep", action="store_true", help="keep the temporary directory of hostile files")
    parser.add_argument("--markdown", type=Path, help="also write the table here")
    args = parser.parse_args(argv)
    cases = [c for c in CASES if not (args.skip_slow and c.slow)
             and (not args.only or any(t.lower() in c.name.lower() for t in args.only))]
    work = Path(tempfile.mkdtemp(prefix="mapfilter-hostile-"))
    try:
        print(f"hostile files in {work}", file=sys.stderr)
        make_files(work, skip_slow=args.skip_slow or not any(c.slow for c in cases))
        outcomes = []
        for case in cases:
            outcome = run_case(case, work, int(args.memory_gb * (1 << 30)), args.timeout)
            print(f"{case.name}: exit {outcome.code}, {outcome.peak_mb:.0f} MB, {outcome.wall_s:.1f} s, "
                  f"{outcome.verdict}", file=sys.stderr)
            outcomes.append(outcome)
        text = table(outcomes)
        print(text)
        if args.markdown:
            args.markdown.write_text(text + "\n")
        return 0 if all(o.verdict == "ok" for o in outcomes) else 1
    finally:
        if args.keep:
            print(f"kept {work}", file=sys.stderr)
        else:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
