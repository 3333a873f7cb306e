"""Throw broken and hostile inputs (issues 27, 36 and 45) at the CLI and print what each does.

Every case runs ``python -m mapfilter ...`` as a subprocess with its address space capped
(``RLIMIT_AS``, default 4 GB: a case that asks for more gets a MemoryError instead of taking
the machine) and a timeout (default 180 s; the case's process group is then killed). The
table gives each case's exit code, the first line of its stderr that says something (the
``mapfilter: error`` line, or the last line of a traceback), its peak memory (the child's
``ru_maxrss`` from ``wait4``, which covers the processes it waited for) and its wall time, and
a verdict: ``ok`` when there is no traceback, the exit code is the one expected, the peak is
under 2 GB and the time under 2 minutes (issue 27's bar), a case that used to hang ends within
10 s, and every file a case names as its user's (``keep``: its inputs, a file of theirs in the
output folder) is byte-identical afterwards (issue 36). Issue 45's cases (a bad EvaalAPI server,
``check --truth``, a full disk under a multi-file output, ``tools/get_data.py``, tables and
estimates files) must end within 15 s, their stderr printable, with one error line.

The hostile files are made in a temporary directory (removed at the end unless ``--keep``),
never in the repository. Usage::

    .venv/bin/python tools/hostile_inputs.py [--only NAME ...] [--skip-slow] [--markdown OUT.md]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import gzip
import os
import resource
import shutil
import signal
import stat
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
    cwd: str | None = None  # run in this folder of the work directory
    must_say: str = ""  # the first stderr line must hold this (a row skipped: the warning that says so)
    keep: tuple[str, ...] = ()  # files of the work directory that must be byte-identical afterwards
    max_s: float = BAR_S  # a case that used to hang must end within this
    one_line: bool = False  # stderr printable (no escape sequence, no raw byte), one error line at most
    stdin: str | None = None  # a file of the work directory fed on standard input (a live run: LOG -)


@dataclasses.dataclass
class Outcome:
    case: Case
    code: int | None
    message: str
    peak_mb: float
    wall_s: float
    leftovers: list[str]
    changed: list[str] = dataclasses.field(default_factory=list)  # kept files that were changed or removed
    stderr: str = ""  # all of it (must_say may be on any line)

    @property
    def verdict(self) -> str:
        problems = []
        if self.code not in self.case.expect:
            problems.append(f"exit {self.code}")
        if self.case.must_say and self.case.must_say not in self.stderr:
            problems.append(f"no '{self.case.must_say}'")
        if "Traceback" in self.message or self.message.startswith("(traceback)"):
            problems.append("traceback")
        if self.peak_mb > BAR_MB:
            problems.append("memory")
        if self.wall_s > min(BAR_S, self.case.max_s):
            problems.append("time")
        if self.leftovers:
            problems.append("left " + ", ".join(self.leftovers))
        if self.changed:
            problems.append("DESTROYED " + ", ".join(self.changed))
        if self.case.one_line:
            lines = self.stderr.splitlines()
            if not all(line.isprintable() for line in lines):
                problems.append("unprintable stderr")
            if sum(": error: " in line for line in lines) > 1:
                problems.append("more than one error line")
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
    make_files_36(work)
    make_files_45(work, skip_slow)
    make_files_53(work)


# ---- issue 36's files -------------------------------------------------------------------------
BOMB = ("a: &a [x, x, x, x, x, x, x, x, x]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]\n"
        "c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b]\nd: &d [*c, *c, *c, *c, *c, *c, *c, *c, *c]\n"
        "e: &e [*d, *d, *d, *d, *d, *d, *d, *d, *d]\nf: &f [*e, *e, *e, *e, *e, *e, *e, *e, *e]\n"
        "g: &g [*f, *f, *f, *f, *f, *f, *f, *f, *f]\nh: &h [*g, *g, *g, *g, *g, *g, *g, *g, *g]\n"
        "i: &i [*h, *h, *h, *h, *h, *h, *h, *h, *h]\n")  # 9^9 = 387 M strings from 400 bytes


def write_radio_map_arrays(path: Path, edit: Callable[[dict], None]) -> Path:
    """The bundled radio map with its arrays edited (``edit(arrays)``), saved as a plain npz."""
    import numpy as np

    with np.load(RADIOMAP, allow_pickle=False) as data:
        arrays = {key: data[key] for key in data.files}
    edit(arrays)
    np.savez_compressed(path, **arrays)
    return path


def write_huge_radio_map(path: Path, n_points: int, n_aps: int) -> Path:
    """A radio map of ``n_points`` x ``n_aps`` float32 RSSI (all unheard: NaN), which compresses
    to a few MB: each array streamed into the zip, never whole in memory."""
    import io
    import zipfile

    import numpy as np
    from numpy.lib import format as npy

    def put(archive, name, array):
        buffer = io.BytesIO()
        npy.write_array(buffer, array)
        archive.writestr(f"{name}.npy", buffer.getvalue())

    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        put(archive, "format", np.array("mapfilter-radiomap"))
        put(archive, "version", np.array(2))
        put(archive, "xy_m", np.zeros((n_points, 2)))
        put(archive, "t_s", np.zeros(n_points))
        put(archive, "trace", np.zeros(n_points, dtype=np.int64))
        put(archive, "ap_keys", np.array([f"02:00:00:00:{i // 256:02x}:{i % 256:02x}|2.4" for i in range(n_aps)]))
        put(archive, "source_traces", np.array(["survey"]))
        with archive.open("rssi_dbm.npy", "w", force_zip64=True) as member:
            npy.write_array_header_1_0(member, {"descr": "<f4", "fortran_order": False, "shape": (n_points, n_aps)})
            row = np.full(n_aps, np.nan, dtype=np.float32).tobytes()
            block = row * 1000
            for _ in range(n_points // 1000):
                member.write(block)
    return path


def make_files_36(work: Path) -> None:
    """Issue 36's inputs: copies of the bundled map, walk and radio map the cases must not harm."""
    import numpy as np

    user = work / "user"
    user.mkdir()
    for source in (MAP, MAPS / "office.png", RADIOMAP, APS):
        shutil.copy(source, user / source.name)
    shutil.copy(WALK, user / "office_walk.txt.gz")
    with gzip.open(WALK, "rt") as handle:
        (user / "walk.txt").write_text(handle.read())
    (work / "here" / "walks").mkdir(parents=True)  # evaluate --out . in a folder holding its logs
    shutil.copy(WALK, work / "here" / "walks" / "office_walk.txt.gz")
    (work / "res" / "tracks").mkdir(parents=True)
    (work / "res" / "tracks" / "my_track.csv").write_text("t_s,x_m,y_m\n0,1,2\n")
    with contextlib.suppress(OSError):  # a private copy of /dev/null (needs root)
        os.mknod(work / "devnull", 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    os.mkfifo(work / "fifo")
    os.symlink("/proc/self/fd/1", work / "stdout-link")
    meta = f"resolution: 0.1\norigin: [0.0, 0.0, 0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    (work / "bomb_image.yaml").write_text(BOMB + "image: *i\n" + meta)
    (work / "bomb_origin.yaml").write_text(BOMB + f"image: {MAPS / 'office.png'}\nresolution: 0.1\norigin: *i\n")
    (work / "bomb_building.yaml").write_text(BOMB + f"floors:\n  - name: *i\n    map: {MAP}\n    elevation_m: 0\n")
    (work / "bomb_config.yaml").write_text(BOMB + "seed: *i\n")
    with (work / "big_map.yaml").open("w") as handle:  # 50 MB
        handle.write(f"image: {MAPS / 'office.png'}\nresolution: 0.1\norigin: [0, 0, 0]\nnotes:\n")
        handle.writelines(f"  - note number {i} about this map, of no use to anyone\n" for i in range(1_000_000))
    (work / "init_samples.yaml").write_text("filter:\n  init_samples: 10000000000\n")
    (work / "likelihood_cell.yaml").write_text("wifi:\n  radio_map_likelihood:\n    cell_m: 0.000001\n")
    (work / "matching_cell.yaml").write_text("offline:\n  map_matching:\n    cell_m: 0.000001\n")
    (work / "heading_sigma.yaml").write_text("motion:\n  pdr:\n    heading_sigma_rad: -0.02\n")
    write_huge_radio_map(work / "huge_rssi.npz", 200_000, 1_000)  # 0.8 GB of float32 RSSI
    write_radio_map_arrays(work / "rm_keys0d.npz", lambda a: a.update(ap_keys=np.array("02:00:00:00:00:01|2.4")))
    write_radio_map_arrays(work / "rm_version22.npz", lambda a: a.update(version=np.array([2, 2])))
    write_radio_map_arrays(work / "rm_xy_text.npz", lambda a: a.update(xy_m=a["xy_m"].astype(str)))
    write_radio_map_arrays(work / "rm_cv_nan.npz",
                           lambda a: a.update(cv_fix_errors_params=np.array([3.0, np.nan, 1.0])))
    os.symlink("loop_b.png", work / "loop_a.png")
    os.symlink("loop_a.png", work / "loop_b.png")
    (work / "loop.yaml").write_text("image: loop_a.png\nresolution: 0.1\norigin: [0, 0, 0]\n")
    (work / "res400.yaml").write_text(f"image: {MAPS / 'office.png'}\nresolution: 1{'0' * 400}\n"
                                      "origin: [0, 0, 0]\n")
    lines = APS.read_text().splitlines()
    (work / "aps_latin1.csv").write_bytes(("\n".join(lines[:2]) + "\n").encode()
                                          + lines[2].replace(lines[2][:2], "c\xe9", 1).encode("latin-1") + b"\n"
                                          + ("\n".join(lines[3:]) + "\n").encode())
    (work / "aps_bom.csv").write_bytes(b"\xef\xbb\xbf" + APS.read_bytes())
    header, first = lines[0].split(","), lines[1].split(",")
    moved = list(first)
    moved[header.index("x")] = str(float(first[header.index("x")]) + 20.0)
    (work / "aps_twice.csv").write_text("\n".join(lines + [",".join(moved)]) + "\n")
    (work / "dup_key.yaml").write_text(f"image: {MAPS / 'office.png'}\nresolution: 0.1\nresolution: 0.05\n"
                                       "origin: [0, 0, 0]\n")
    office_yaml = MAP.read_text().replace("image: office.png", f"image: {MAPS / 'office.png'}")
    (work / "utf16.yaml").write_bytes(office_yaml.encode("utf-16"))
    (work / "latin1_comment.yaml").write_bytes("# plan du b\xe2timent\n".encode("latin-1") + office_yaml.encode())
    floor_dir = work / "ilc_huge" / "F1"
    floor_dir.mkdir(parents=True)
    (floor_dir / "floor_info.json").write_text('{"map_info": {"width": 1e12, "height": 1e12}}')
    (floor_dir / "geojson_map.json").write_text('{"type": "FeatureCollection", "features": []}')
    (work / "unordered.yaml").write_text(f"floors:\n  - {{name: up, map: {MAP}, elevation_m: 4}}\n"
                                         f"  - {{name: down, map: {MAP}, elevation_m: 0}}\n")
    (work / "same_elevation.yaml").write_text(f"floors:\n  - {{name: a, map: {MAP}, elevation_m: 0}}\n"
                                              f"  - {{name: b, map: {MAP}, elevation_m: 0}}\n")
    shutil.copy(WALK, work / "summary.txt.gz")
    _write_walk(work / "clock_back.txt", lambda lines: _shift_after(lines, 1_600_000_060_000, -20_000))


def make_files_53(work: Path) -> None:
    """Issue 53's inputs: the probe's log whose IMU clock (not the WiFi's) jumps back 20 s at 60 s,
    and a track to view."""
    def imu_back(lines: list[str]) -> list[str]:
        for kind in ("TYPE_ACCELEROMETER", "TYPE_GYROSCOPE", "TYPE_MAGNETIC_FIELD", "TYPE_ROTATION_VECTOR"):
            lines = _shift_after(lines, 1_600_000_060_000, -20_000, only=kind)
        return lines

    _write_walk(work / "clock_back_imu.txt", imu_back)
    (work / "view_track.csv").write_text("t_s,x_m,y_m,std_m,heading_rad\n1600000000,15,10,1,0\n1600000001,16,10,1,0\n")


# ---- issue 45's files ------------------------------------------------------------------------
TOOLS = REPO / "tools"
IPIN_ROW = "ipin2023/logs/IPIN2023_T3_TrainingTrial01_repetition01.txt.gz"  # a file of get_data's manifest
LONG_FIELD = "7" * 200_000  # over the csv module's field limit (131 072)


def write_getsensordata(path: Path, posi: bool = True, swapped: bool = False) -> Path:
    """A small GetSensorData log in the georeferenced office (12 s of IMU, six POSI points), and,
    with ``swapped``, its POSI points as estimates with latitude and longitude swapped."""
    lines = ["% LogFile created by the 'GetSensorData' App for Android.\n",
             "% Date of creation: Wed Jun 14 10:00:58 GMT+02:00 2023\n"]
    points = []
    for i in range(600):
        t = 0.02 * i
        lines += [f"ACCE;{t:.3f};{1000 + t:.3f};0.1;9.8;0.2;3\n", f"GYRO;{t + 0.001:.3f};{1000 + t:.3f};0.0;0.0;0.0;3\n"]
        if i % 100 == 50:
            points.append((t, 49.4601 + 1e-5 * i, 11.1101 + 1e-5 * i))
            if posi:
                lines.append(f"POSI;{t:.4f};{len(points)};{points[-1][1]:.9f};{points[-1][2]:.9f};0;100\n")
    path.write_text("".join(lines))
    if swapped:
        path.with_suffix(".swapped.csv").write_text("".join(f"{t:.3f},{lat:.9f},{lon:.9f},0\n" for t, lat, lon in points))
    return path


def make_files_45(work: Path, skip_slow: bool) -> None:
    """Issue 45's inputs: a georeferenced venue, a gzip bomb for the bad EvaalAPI server, tables and
    files over their bounds, a user's track beside its log, get_data's sources; for live runs 100 MB
    of blank lines, 100 MB of random bytes (and 20 MB of them without a newline)."""
    with (work / "blank_lines.txt").open("wb") as handle:
        for _ in range(100):
            handle.write(b"\n" * (1 << 20))
    with (work / "random.bin").open("wb") as handle:
        for _ in range(100):
            handle.write(os.urandom(1 << 20))
    (work / "random_one_line.bin").write_bytes(os.urandom(20 << 20).replace(b"\n", b"x"))
    sys.path.insert(0, str(TOOLS))
    from bad_evaal_server import gzip_of_zeros

    (work / "venue.yaml").write_text(f"floors:\n- name: '0'\n  map: {MAP}\n  elevation_m: 0.0\n"
                                     "georeference:\n  origin_lat_deg: 49.46\n  origin_lon_deg: 11.11\n")
    (work / "bomb.gz").write_bytes(gzip_of_zeros(3 << 30))  # 3 GB of zeros in 3 MB
    with (work / "big_beacons.csv").open("w") as handle:  # one row, then 600 MB of spaces
        handle.write("beacon_id,x,y\nbe:ac:20:23:00:01,1.0,2.0\n")
        block = " " * (1 << 20)
        for _ in range(600):
            handle.write(block)
    (work / "long_beacons.csv").write_text(f"beacon_id,x,y\nbe:ac:20:23:00:01,{LONG_FIELD},2.0\n")
    aps = APS.read_text().splitlines()
    header = aps[0].split(",")
    fields = aps[1].split(",")
    fields[header.index("x")] = LONG_FIELD
    (work / "long_aps.csv").write_text("\n".join([aps[0], ",".join(fields)] + aps[2:]) + "\n")
    with (work / "long_track.csv").open("w") as handle:  # a track of one line of 100 MB
        handle.write("t_s,x_m,y_m\n")
        block = "7" * (1 << 20)
        for _ in range(100):
            handle.write(block)
        handle.write(",1,2\n")
    with (work / "many_estimates.csv").open("w") as handle:  # 10 million estimates
        block = "0.500,11.110000000,49.460000000,0\n" * 1_000_000
        for _ in range(10):
            handle.write(block)
    write_getsensordata(work / "gsd.txt", swapped=True)
    write_getsensordata(work / "gsd_no_posi.txt", posi=False)
    with gzip.open(WALK, "rt") as handle:  # the user's own track of the walk (its waypoints' times)
        times = [line.split("\t")[0] for line in handle if "\tTYPE_WAYPOINT\t" in line]
    (work / "user" / "track.csv").write_text("t_s,x_m,y_m\n" + "".join(f"{int(t) / 1000:.3f},10.0,10.0\n"
                                                                      for t in times))
    gd = work / "gd"
    (gd / "src_bad").mkdir(parents=True)
    (gd / "src_link").mkdir()
    name = Path(IPIN_ROW).name.removesuffix(".gz")
    (gd / "src_bad" / name).write_text("% not the log the manifest names\n")
    os.symlink(work / "user" / "walk.txt", gd / "src_link" / name)
    (gd / "victim.txt").write_text("a file of the user's, outside the data folder\n")
    (gd / "abs_victim.txt").write_text("another file of the user's\n")


# a bad EvaalAPI server (tools/bad_evaal_server.py) in the case's process, entered by the command
_BAD_SERVER = """
import sys
sys.path.insert(0, {tools!r})
from bad_evaal_server import BadServer
bomb = open("bomb.gz", "rb").read() if {kind!r}.startswith("bomb") else None
with BadServer({kind!r}, bomb=bomb) as server:
    from mapfilter.cli import main
    code = main(["evaal", server.url, "t", "venue.yaml", "--radiomap", {rm!r}, "--timeout", "2", "--retry", "0",
                 "--out", "outdir/evaal_{kind}.csv"] + {extra!r})
sys.exit(code)
"""

# the same through the Python API
_BAD_SERVER_API = """
import sys
sys.path.insert(0, {tools!r})
from bad_evaal_server import BadServer
import mapfilter as mf
from mapfilter.errors import MapfilterError
bomb = open("bomb.gz", "rb").read() if {kind!r}.startswith("bomb") else None
with BadServer({kind!r}, bomb=bomb) as server:
    try:
        mf.enter_trial(server.url, "t", "venue.yaml", radio_map={rm!r}, offline={offline!r}, timeout_s=2.0,
                       retry_s=0.0)
    except MapfilterError as exc:
        print(f"mapfilter: error: {{exc}}", file=sys.stderr)
        sys.exit(1)
sys.exit(0)
"""

# a second run over an earlier one's files on a full disk (a file-size limit set after the first run):
# every file of the earlier run byte-identical afterwards
_FULL_DISK_AGAIN = """
import hashlib, pathlib, resource, sys
from mapfilter.cli import main
args = {args!r}
out = pathlib.Path({out!r})
assert main(args) == 0
def files():
    return {{str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(out.rglob("*")) if p.is_file()}}
before = files()
resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, {limit}))
code = main(args)
after = files()
if after != before:
    print(f"CHANGED: {{sorted(set(before.items()) ^ set(after.items()))[:3]}}", file=sys.stderr)
    sys.exit(3)
sys.exit(code)
"""

# track --smooth over t.csv and t.causal.csv, the second write failing as on a full disk
_SMOOTH_SECOND_FAILS = """
import errno, os, pathlib, sys
from mapfilter.cli import main
from mapfilter.io import tracks
args = ["track", {map!r}, {walk!r}, "--radiomap", {rm!r}, "--smooth", "--particles", "300", "--out", "outdir/t.csv"]
assert main(args) == 0
before = {{p: pathlib.Path(p).read_bytes() for p in ("outdir/t.csv", "outdir/t.causal.csv")}}
real, calls = tracks.write_track, []
def second_fails(track, path, *rest, **kw):
    calls.append(path)
    if len(calls) == 2:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    return real(track, path, *rest, **kw)
tracks.write_track = second_fails
code = main(args)
if any(pathlib.Path(p).read_bytes() != data for p, data in before.items()):
    print("CHANGED: t.csv or t.causal.csv", file=sys.stderr)
    sys.exit(3)
sys.exit(code)
"""

# tools/get_data.py against a Zenodo record on 127.0.0.1 (a listing and the files it names)
_GET_DATA = """
import http.server, io, json, sys, threading, zipfile
sys.path.insert(0, {tools!r})
import get_data
kind = {kind!r}
buffer = io.BytesIO()
with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
    archive.writestr("logs/walk.txt", open("user/walk.txt", "rb").read())
package = buffer.getvalue()
files = {{"/p.zip": (package, len(package))}}
entry = {{"key": "p.zip", "size": len(package)}}
if kind == "short":
    files["/p.zip"] = (package[:len(package) // 2], len(package))
elif kind == "half":
    files["/p.zip"] = (package[:len(package) // 2], len(package) // 2)
    entry = {{"key": "p.zip"}}
elif kind in ("victim", "absolute"):
    entry["key"] = "../../../victim.txt" if kind == "victim" else str(__import__("pathlib").Path("gd/abs_victim.txt").resolve())
class Handler(http.server.BaseHTTPRequestHandler):
    def do_GET(self):
        if self.path == "/record":
            body = json.dumps({{"files": [entry]}}).encode()
            length = len(body)
        else:
            body, length = files[self.path]
        self.send_response(200)
        self.send_header("Content-Length", str(length))
        self.end_headers()
        self.wfile.write(body)
    def log_message(self, *args):
        pass
server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
threading.Thread(target=server.serve_forever, daemon=True).start()
url = f"http://127.0.0.1:{{server.server_address[1]}}"
entry["links"] = {{"self": url + "/p.zip"}}
get_data.ZENODO_API_URL = url + "/record"
sys.exit(get_data.main(["--out", "gd/data", "--only", {row!r}]))
"""


# a scheduler that is not one: silent, an HTTP server, random bytes (run in the case's process)
_FAKE_SCHEDULER = """
import os, socket, sys, threading, time
kind = {kind!r}
server = socket.socket()
server.bind(("127.0.0.1", 0))
server.listen(8)
def serve():
    while True:
        conn, _ = server.accept()
        if kind == "http":
            conn.sendall(b"HTTP/1.1 400 Bad Request\\r\\nContent-Length: 0\\r\\n\\r\\n")
        elif kind == "random":
            conn.sendall(os.urandom(4096))
        threading.Thread(target=lambda c=conn: (time.sleep(300), c.close()), daemon=True).start()
threading.Thread(target=serve, daemon=True).start()
from mapfilter.cli import main
sys.exit(main(["track", {map!r}, {walk!r}, "--radiomap", {rm!r}, "--out-dir", "outdir/sched_{kind}",
               "--scheduler", f"tcp://127.0.0.1:{{server.getsockname()[1]}}"]))
"""

# evaluate --resume on a store edited after the run (its errors set to 0, or methods a number)
_EDITED_STORE = """
import json, pathlib, sys
from mapfilter.cli import main
args = ["evaluate", "user/office.yaml", "user/office_walk.txt.gz", "--radiomap", "user/office_radiomap.npz",
        "--methods", "kwnn", "--out", "outdir/store_{edit}"]
assert main(args) == 0
stored = pathlib.Path("outdir/store_{edit}/walks/office_walk.json")
data = json.loads(stored.read_text())
if "{edit}" == "zeros":
    for method in data["methods"]:
        method["errors_m"] = [0.0] * len(method["errors_m"])
else:
    data["methods"] = 3
stored.write_text(json.dumps(data))
sys.exit(main(args + ["--resume"]))
"""

# evaluate --resume after a log or the radio map was replaced at the same path: nothing resumed
_REPLACED_INPUT = """
import contextlib, io, pathlib, shutil, sys
from mapfilter.cli import main
shutil.copy("user/office_walk.txt.gz", "replaced_walk.txt.gz")
shutil.copy("user/office_radiomap.npz", "replaced_rm.npz")
args = ["evaluate", "user/office.yaml", "replaced_walk.txt.gz", "--radiomap", "replaced_rm.npz", "--methods", "kwnn",
        "--out", "outdir/replaced_{what}"]
assert main(args) == 0
if "{what}" == "log":
    shutil.copy("gap30d.txt", "replaced_walk.txt.gz")  # another walk, same name
else:
    import numpy as np
    with np.load("replaced_rm.npz") as data:
        arrays = {{k: data[k] for k in data.files}}
    arrays["rssi_dbm"] = arrays["rssi_dbm"] - 3.0  # another survey, same name
    np.savez_compressed("replaced_rm.npz", **arrays)
out = io.StringIO()
with contextlib.redirect_stdout(out):
    code = main(args + ["--resume"])
said = [line for line in out.getvalue().splitlines() if line.startswith("resuming")]
print(said[0] if said else "no resume line", file=sys.stderr)
sys.exit(code if said == ["resuming: 0 of 1 walks already done in outdir/replaced_{what}"] else 3)
"""

# track --out-dir with a log named summary.txt.gz: its track and the summary are two files
_SUMMARY_LOG = """
import pathlib, sys
from mapfilter.cli import main
code = main(["track", "user/office.yaml", "summary.txt.gz", "user/office_walk.txt.gz", "--radiomap",
             "user/office_radiomap.npz", "--out-dir", "outdir/summary_log"])
out = pathlib.Path("outdir/summary_log")
track = (out / "summary.track.csv").read_text().splitlines()[0] if (out / "summary.track.csv").exists() else ""
summary = (out / "summary.csv").read_text().splitlines()[0]
ok = track.startswith("t_s,") and summary.startswith("trace,")
print(f"track file summary.track.csv: {track[:20]!r}; summary.csv: {summary[:20]!r}", file=sys.stderr)
sys.exit(code if ok else 3)
"""

# the Python API called with the wrong types (issue 37): a one-line TypeError, not a traceback deep inside
_API_TYPES = """
import sys
import mapfilter as mf
building = mf.load_map({map!r})
walk = mf.read_log({walk!r})
radio_map = mf.load_radio_map({rm!r})
calls = {{"map path": lambda: mf.track({map!r}, walk, radio_map=radio_map),
          "dict config": lambda: mf.track(building, walk, radio_map=radio_map, config={{"seed": 1}}),
          "path radio map": lambda: mf.track(building, walk, radio_map={rm!r}),
          "None walk": lambda: mf.track(building, None, radio_map=radio_map)}}
from mapfilter.errors import MapfilterError
try:
    calls[{which!r}]()
except (TypeError, MapfilterError) as exc:
    print(f"{{type(exc).__name__}}: {{exc}}", file=sys.stderr)
    sys.exit(1)
sys.exit(0)
"""

# the README's first command from a copy of the package that its user cannot write (numba's cache)
_READ_ONLY_INSTALL = """
import ctypes, os, shutil, subprocess, sys, pathlib
repo = pathlib.Path({repo!r})
install = pathlib.Path("ro_install")
shutil.copytree(repo / "mapfilter", install / "mapfilter", ignore=shutil.ignore_patterns("__pycache__"))
shutil.copytree(repo / "maps", "ro_work/maps")  # the README's paths, away from the checkout
for root, dirs, files in os.walk(install):
    for name in dirs + files:
        os.chmod(os.path.join(root, name), 0o555 if name in dirs else 0o444)
home = pathlib.Path("ro_home")
home.mkdir()
os.chmod(home, 0o555)  # a HOME the user cannot write either: the temporary folder is left
def drop():
    if os.geteuid() == 0:  # root without the capabilities that ignore file modes
        libc = ctypes.CDLL(None, use_errno=True)
        for cap in (1, 2, 3):
            libc.prctl(24, cap, 0, 0, 0)
env = {{k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "XDG_"))}}
import sysconfig
# -S: the checkout's editable install (a .pth finder that wins over PYTHONPATH) is not loaded
env.update(PYTHONPATH=os.pathsep.join([str(install.resolve()), sysconfig.get_paths()["purelib"]]),
           HOME=str(home.resolve()))
run = subprocess.run([sys.executable, "-S", "-m", "mapfilter", "track", "maps/office.yaml", "maps/office_walk.txt.gz",
                      "--radiomap", "maps/office_radiomap.npz", "--smooth"], cwd=pathlib.Path("ro_work"), env=env,
                     preexec_fn=drop,
                     capture_output=True, text=True)
for root, dirs, files in os.walk(install):
    for name in dirs:
        os.chmod(os.path.join(root, name), 0o755)
os.chmod(install, 0o755)
os.chmod(home, 0o755)
shutil.rmtree(install)
shutil.rmtree(home)
shutil.rmtree("ro_work")
sys.stderr.write(run.stderr)
print(run.stdout.splitlines()[0] if run.returncode == 0 else "", file=sys.stderr)
sys.exit(run.returncode)
"""


def _fmt(code: str, **values: str) -> str:
    return code.format(**values)


# the same log fed to the tracker whole and in 64 KiB pieces gives the same rows
_CHUNKED_ROWS = """
import sys
from mapfilter.config import TrackingConfig
from mapfilter.maps.building import Building
from mapfilter.pipeline.tracker import Tracker, TrackingInputs
from mapfilter.sensors.logs import LogStream
from mapfilter.sensors.radiomap import RadioMap
data = open({log!r}, "rb").read()
building, radio_map = Building.load({map!r}), RadioMap.load({rm!r})
counts = []
for piece in (len(data), 65536):
    tracker, stream = Tracker(building, TrackingInputs(radio_map), TrackingConfig(seed=1).with_particles(1000)), LogStream("x")
    rows = sum(len(tracker.feed(stream.feed_bytes(data[i:i + piece]))) for i in range(0, len(data), piece))
    rows += len(tracker.feed(stream.close())) + len(tracker.close())
    counts.append(rows)
print(f"fed whole: {{counts[0]}} rows; in 64 KiB pieces: {{counts[1]}} rows", file=sys.stderr)
sys.exit(0 if counts[0] == counts[1] else 1)
"""

# track FILE and track - on the same bytes: the same rows (issue 53)
_LIVE_VS_FILE = """
import subprocess, sys
common = ["--radiomap", {rm!r}, "--particles", "1000", "--seed", "1"]
run = lambda log, out, **kw: subprocess.run([sys.executable, "-m", "mapfilter", "track", {map!r}, log, *common,
                                             "--out", out], capture_output=True, text=True, **kw)
run({log!r}, "outdir/from_file.csv")
with open({log!r}, "rb") as handle:
    run("-", "outdir/from_stdin.csv", stdin=handle)
rows = [open(f"outdir/from_{{how}}.csv").read().splitlines() for how in ("file", "stdin")]
print(f"track FILE: {{len(rows[0]) - 1}} rows; track -: {{len(rows[1]) - 1}} rows; "
      f"{{'the same' if rows[0] == rows[1] else 'not the same'}}", file=sys.stderr)
sys.exit(0 if rows[0] == rows[1] and len(rows[0]) > 50 else 1)
"""

_OFFICE = {"map": str(MAP), "walk": str(WALK), "rm": str(RADIOMAP)}
USER = ("user/office.yaml", "user/office.png", "user/office_radiomap.npz", "user/office_walk.txt.gz",
        "user/walk.txt", "user/office_aps.csv")

# ---- the cases ----------------------------------------------------------------------------------
def _track(log: str | Path, *extra: str, map_path: str | Path = MAP) -> Callable[[Path], list[str]]:
    return lambda w: ["track", str(map_path).format(w=w), str(log).format(w=w), *[e.format(w=w) for e in extra]]


_FOREIGN_CLIENT = """
import logging
from distributed import Client
from distributed.security import Security
from mapfilter.runtime.dispatch import Engine, _DaskClient
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
    Case("--scheduler tcp://", "runtime/dispatch.py", _track(WALK, "--radiomap", str(RADIOMAP), "--scheduler", "tcp://",
                                                    "--out-dir", "{w}/outdir/s1")),
    Case("--scheduler foo://x:1", "runtime/dispatch.py", _track(WALK, "--radiomap", str(RADIOMAP), "--scheduler",
                                                       "foo://x:1", "--out-dir", "{w}/outdir/s2")),
    Case("--scheduler tcp://host:99999", "runtime/dispatch.py", _track(WALK, "--radiomap", str(RADIOMAP), "--scheduler",
                                                              "tcp://host:99999", "--out-dir", "{w}/outdir/s3")),
    Case("foreign client vs the --jobs cluster", "runtime/dispatch.py", None, (0,), python=_FOREIGN_CLIENT),
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
    Case("full disk: simulate", "io/atomic.py", lambda w: ["simulate", str(MAP), "--out", f"{w}/outdir/full.txt"],
         fsize_bytes=100_000),
    Case("full disk: radiomap build", "io/atomic.py",
         lambda w: ["radiomap", "build", str(MAP), str(WALK), "--out", f"{w}/outdir/full.npz"], fsize_bytes=2_000),
    Case("full disk: track --rerun", "viz/recorder.py",
         _track(WALK, "--radiomap", str(RADIOMAP), "--rerun", "{w}/outdir/full.rrd"), fsize_bytes=100_000),
    Case("full disk: track --out", "io/atomic.py",
         _track(WALK, "--radiomap", str(RADIOMAP), "--out", "{w}/outdir/full.csv"), fsize_bytes=1_000),
    Case("full disk: evaluate", "io/atomic.py, cli/__init__.py",
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
] + [  # issue 36: data loss (every input byte-identical afterwards)
    Case("evaluate --out . in a folder holding its logs", "io/outputs.py",
         lambda w: ["evaluate", str(MAP), "walks/office_walk.txt.gz", "--radiomap", str(RADIOMAP), "--methods", "kwnn",
                    "--out", "."], keep=("here/walks/office_walk.txt.gz",), cwd="here"),
    Case("evaluate --out res holding the user's res/tracks/my_track.csv", "io/outputs.py",
         lambda w: ["evaluate", str(MAP), str(WALK), "--radiomap", str(RADIOMAP), "--methods", "kwnn", "--out", "res"],
         keep=("res/tracks/my_track.csv",)),
    Case("track MAP walk.txt --out walk.txt", "io/outputs.py",
         _track("user/walk.txt", "--radiomap", "user/office_radiomap.npz", "--out", "user/walk.txt",
                map_path="user/office.yaml"), keep=USER),
    Case("track MAP LOG --out office.yaml (the map)", "io/outputs.py",
         _track("user/office_walk.txt.gz", "--radiomap", "user/office_radiomap.npz", "--out", "user/office.yaml",
                map_path="user/office.yaml"), keep=USER),
    Case("radiomap fit-aps MAP walk.txt --out walk.txt", "io/outputs.py",
         lambda w: ["radiomap", "fit-aps", "user/office.yaml", "user/walk.txt", "--out", "user/walk.txt"], keep=USER),
    Case("simulate office.yaml --out office.yaml", "io/outputs.py",
         lambda w: ["simulate", "user/office.yaml", "--out", "user/office.yaml"], keep=USER),
    Case("track --out a device node (a copy of /dev/null)", "io/outputs.py, io/atomic.py",
         _track(WALK, "--radiomap", str(RADIOMAP), "--out", "devnull")),
    Case("track --out a FIFO", "io/outputs.py, io/atomic.py", _track(WALK, "--radiomap", str(RADIOMAP), "--out", "fifo")),
    Case("track --out a symlink to /proc/self/fd/1", "io/outputs.py, io/atomic.py",
         _track(WALK, "--radiomap", str(RADIOMAP), "--out", "stdout-link")),
    # hangs and memory (each over within 10 s)
    Case("map YAML: alias bomb in image", "io/yamlio.py", _track(WALK, map_path="{w}/bomb_image.yaml"), max_s=10),
    Case("map YAML: alias bomb in origin", "io/yamlio.py", _track(WALK, map_path="{w}/bomb_origin.yaml"), max_s=10),
    Case("building YAML: alias bomb as a floor name", "io/yamlio.py", _track(WALK, map_path="{w}/bomb_building.yaml"),
         max_s=10),
    Case("config: alias bomb as the seed", "io/yamlio.py, settings.py",
         _track(WALK, "--radiomap", str(RADIOMAP), "--config", "{w}/bomb_config.yaml"), max_s=10),
    Case("a 50 MB map YAML", "io/yamlio.py", _track(WALK, map_path="{w}/big_map.yaml"), max_s=10),
    Case("--jobs 10000", "runtime/dispatch.py", _track(WALK, "{w}/gap30d.txt", "--radiomap", str(RADIOMAP), "--out-dir", "{w}/outdir/j1",
                                             "--jobs", "10000"), max_s=10),
    Case("--jobs 32", "runtime/dispatch.py", _track(WALK, "{w}/gap30d.txt", "--radiomap", str(RADIOMAP), "--out-dir", "{w}/outdir/j2",
                                          "--jobs", "32"), max_s=10),
    Case("--scheduler that accepts and never answers", "runtime/dispatch.py", None,
         python=_fmt(_FAKE_SCHEDULER, kind="silent", **_OFFICE), max_s=10),
    Case("radio map: 0.8 GB of RSSI compressed to a few MB", "sensors/radiomap.py, runtime/memory.py",
         _track(WALK, "--radiomap", "{w}/huge_rssi.npz"), max_s=10),
    # tracebacks
    Case("README's first command, install and HOME not writable", "__init__.py (numba cache)", None, (0,),
         python=_fmt(_READ_ONLY_INSTALL, repo=str(REPO)), must_say="filter steps"),
    Case("--scheduler an HTTP server", "runtime/dispatch.py", None, python=_fmt(_FAKE_SCHEDULER, kind="http", **_OFFICE),
         max_s=10),
    Case("--scheduler sending random bytes", "runtime/dispatch.py", None,
         python=_fmt(_FAKE_SCHEDULER, kind="random", **_OFFICE), max_s=10),
    Case("track --particles 1000000000000", "runtime/memory.py", _track(WALK, "--radiomap", str(RADIOMAP), "--particles",
                                                                "1000000000000"), max_s=10),
    Case("track --particles 100000000", "runtime/memory.py", _track(WALK, "--radiomap", str(RADIOMAP), "--particles",
                                                            "100000000"), max_s=10),
    Case("config filter.init_samples 1e10", "runtime/memory.py",
         _track(WALK, "--radiomap", str(RADIOMAP), "--config", "{w}/init_samples.yaml"), max_s=10),
    Case("config likelihood cell_m 1e-6", "runtime/memory.py",
         _track(WALK, "--radiomap", str(RADIOMAP), "--config", "{w}/likelihood_cell.yaml"), max_s=10),
    Case("config map-matching cell_m 1e-6 (--smooth)", "runtime/memory.py",
         _track(WALK, "--radiomap", str(RADIOMAP), "--smooth", "--config", "{w}/matching_cell.yaml"), max_s=10),
    Case("radiomap grow --particles 1e12", "runtime/memory.py",
         lambda w: ["radiomap", "grow", str(MAP), str(WALK), "--radiomap", str(RADIOMAP), "--particles",
                    "1000000000000", "--out", f"{w}/outdir/grown.npz"], max_s=10),
    Case("map prepare --close-gaps 100000", "cli/map_cmd.py, maps/prepare.py",
         lambda w: ["map", "prepare", str(MAPS / "office_plan.png"), "--resolution", "0.05", "--close-gaps", "100000",
                    "--out", f"{w}/outdir/closed.yaml"], (2,), max_s=10),
    Case("radio map: ap_keys a 0-d array", "sensors/radiomap.py", _track(WALK, "--radiomap", "{w}/rm_keys0d.npz")),
    Case("radio map: version [2, 2]", "sensors/radiomap.py", _track(WALK, "--radiomap", "{w}/rm_version22.npz")),
    Case("radio map: xy_m as strings", "sensors/radiomap.py", _track(WALK, "--radiomap", "{w}/rm_xy_text.npz")),
    Case("radio map: cv_fix_errors_params NaN", "sensors/radiomap.py", _track(WALK, "--radiomap", "{w}/rm_cv_nan.npz")),
    Case("map image a symlink loop", "maps/floorplan.py", _track(WALK, map_path="{w}/loop.yaml")),
    Case("map resolution a 400-digit integer", "maps/floorplan.py", _track(WALK, map_path="{w}/res400.yaml")),
    Case("AP table: a Latin-1 byte in a BSSID", "sensors/pathloss.py, io/yamlio.py",
         _track(WALK, "--aps", "{w}/aps_latin1.csv"), must_say="not UTF-8"),
    Case("evaluate --resume, the store's methods a number", "evaluation/store.py", None,
         python=_fmt(_EDITED_STORE, edit="methods"), must_say="fails its checks"),
    # a path where an object is expected is read (every API function takes both); a wrong type is a TypeError
    *[Case(f"API: mf.track with {which}", "api.py (issue 37)", None, (0,) if "path" in which else (1,),
           python=_fmt(_API_TYPES, which=which, **_OFFICE))
      for which in ("map path", "dict config", "path radio map", "None walk")],
    # silently wrong
    Case("evaluate --resume, the store's errors edited to 0", "evaluation/store.py", None,
         python=_fmt(_EDITED_STORE, edit="zeros"), must_say="fails its checks"),
    Case("evaluate --resume, a log replaced at the same path", "evaluation/store.py", None, (0,),
         python=_fmt(_REPLACED_INPUT, what="log"), must_say="resuming: 0 of 1"),
    Case("evaluate --resume, the radio map replaced at the same path", "evaluation/store.py", None, (0,),
         python=_fmt(_REPLACED_INPUT, what="radiomap"), must_say="resuming: 0 of 1"),
    Case("track --out-dir, a log named summary.txt.gz", "cli/track_cmd.py", None, (0,), python=_SUMMARY_LOG,
         must_say="summary.track.csv: 't_s"),
    Case("every clock jumps back 20 s", "sensors/logread.py", _track("{w}/clock_back.txt", "--radiomap",
                                                                              str(RADIOMAP)), (0,), must_say="back"),
    Case("--kwnn-min-rssi nan", "cli/tracking_options.py", _track(WALK, "--radiomap", str(RADIOMAP),
                                                                  "--kwnn-min-rssi", "nan"), (2,)),
    Case("config: a negative heading sigma", "config.py (lead)",
         _track(WALK, "--radiomap", str(RADIOMAP), "--config", "{w}/heading_sigma.yaml")),
    Case("radiomap build --max-wifi-age nan", "cli/radiomap_cmd.py",
         lambda w: ["radiomap", "build", str(MAP), str(WALK), "--max-wifi-age", "nan", "--out",
                    f"{w}/outdir/age.npz"], (2,)),
    Case("AP table: one BSSID and band twice, 20 m apart", "sensors/pathloss.py",
         _track(WALK, "--aps", "{w}/aps_twice.csv"), must_say="listed twice"),
    Case("map YAML: resolution given twice", "io/yamlio.py", _track(WALK, map_path="{w}/dup_key.yaml"),
         must_say="given twice"),
    Case("map import-ilc: floor_info.json of 1e12 m", "maps/prepare.py",
         lambda w: ["map", "import-ilc", f"{w}/ilc_huge/F1", "--out", f"{w}/outdir/huge_ilc.yaml"]),
    Case("evaluate --leave-one-out, one walk without WiFi among good ones", "evaluation/comparison.py",
         lambda w: ["evaluate", str(MAP), "gap30d.txt", "wifi_3y.txt", "no_wifi.txt", "--leave-one-out",
                    "--methods", "kwnn", "--out", f"{w}/outdir/loo_nowifi"], must_say="no_wifi.txt"),
    # unclear or wrongly refused
    Case("AP table saved with a UTF-8 BOM (Excel)", "sensors/pathloss.py", _track(WALK, "--aps", "{w}/aps_bom.csv"),
         (0,)),
    Case("map YAML in UTF-16", "io/yamlio.py", _track(WALK, "--radiomap", str(RADIOMAP), map_path="{w}/utf16.yaml"),
         (0,)),
    Case("map YAML: a Latin-1 byte in a comment", "io/yamlio.py", _track(WALK, map_path="{w}/latin1_comment.yaml"),
         must_say="not UTF-8"),
    Case("building: floors out of elevation order", "maps/building.py",
         lambda w: ["simulate", f"{w}/unordered.yaml", "--aps", str(APS), "--floor-changes", "0", "--out",
                    f"{w}/outdir/unordered.txt"], (0,)),
    Case("building: two floors at one elevation", "maps/building.py",
         lambda w: ["simulate", f"{w}/same_elevation.yaml", "--aps", str(APS), "--floor-changes", "0", "--out",
                    f"{w}/outdir/same.txt"],
         must_say="own elevation"),
    Case("track --out a name of 250 characters", "io/atomic.py",
         _track(WALK, "--radiomap", str(RADIOMAP), "--out", "{w}/outdir/" + "t" * 246 + ".csv"), (0,)),
] + [  # issue 45: a bad EvaalAPI server, each refusal within 15 s in one printable line
    *[Case(f"evaal: {what}", "evaal/client.py", None, python=_fmt(_BAD_SERVER, tools=str(TOOLS), kind=kind,
                                                                   rm=str(RADIOMAP), extra=extra),
           max_s=15, one_line=True)
      for what, kind, extra in (
          ("an answer's body dripped a byte a second (--timeout 2 --retry 0)", "drip-body", []),
          ("the status line dripped a byte a second", "drip-status", []),
          ("a 3 GB answer to state", "huge-state", []),
          ("a 3 GB answer to nextdata", "huge-nextdata", []),
          ("a 3 GB log to nextdata?offline", "huge-offline", ["--offline"]),
          ("a gzip bomb (3 MB to 3 GB) on state", "bomb-state", []),
          ("a gzip bomb on nextdata", "bomb-nextdata", []),
          ("a gzip bomb on nextdata?offline", "bomb-offline", ["--offline"]),
          ("423 (faster than real time) forever", "too-fast", []),
          ("a trial that never ends: empty batches", "endless-empty", []),
          ("a trial that never ends: the first batch again and again", "endless-repeat", []),
          ("escape sequences and raw bytes in the server's text", "escape", []))],
    *[Case(f"mf.enter_trial: {what}", "evaal/client.py", None,
           python=_fmt(_BAD_SERVER_API, tools=str(TOOLS), kind=kind, rm=str(RADIOMAP), offline=offline),
           max_s=15, one_line=True)
      for what, kind, offline in (
          ("the status line dripped a byte a second", "drip-status", False),
          ("a gzip bomb on nextdata?offline", "bomb-offline", True),
          ("423 forever", "too-fast", False),
          ("a trial that never ends", "endless-repeat", False),
          ("escape sequences in the server's text", "escape", False))],
    # outputs
    Case("check --truth onto its --at track", "io/outputs.py",
         lambda w: ["check", "user/office_walk.txt.gz", "--truth", "user/track.csv", "--at", "user/track.csv"],
         keep=USER + ("user/track.csv",), max_s=15, one_line=True),
    Case("check --truth onto the map YAML", "io/outputs.py",
         lambda w: ["check", "user/office_walk.txt.gz", "--map", "user/office.yaml", "--truth", "user/office.yaml"],
         keep=USER, max_s=15, one_line=True),
    Case("check --truth onto the map's image", "io/outputs.py",
         lambda w: ["check", "user/office_walk.txt.gz", "--map", "user/office.yaml", "--truth", "user/office.png"],
         keep=USER, max_s=15, one_line=True),
    Case("full disk: evaluate over an earlier evaluation", "io/outputs.py, io/atomic.py", None,
         python=_fmt(_FULL_DISK_AGAIN, limit=20_000, out="outdir/again_eval", args=[
             "evaluate", str(MAP), str(WALK), "--radiomap", str(RADIOMAP), "--methods", "kwnn", "--out",
             "outdir/again_eval"]), one_line=True),
    Case("full disk: track --out-dir over an earlier batch", "io/outputs.py, io/atomic.py", None,
         python=_fmt(_FULL_DISK_AGAIN, limit=2_000, out="outdir/again_batch", args=[
             "track", str(MAP), str(WALK), "user/walk.txt", "--radiomap", str(RADIOMAP), "--particles", "300",
             "--out-dir", "outdir/again_batch"]), one_line=True),
    Case("full disk: track --smooth, t.causal.csv fails after t.csv", "io/atomic.py, cli/track_cmd.py", None,
         python=_fmt(_SMOOTH_SECOND_FAILS, **_OFFICE), one_line=True),
    # tools/get_data.py
    *[Case(f"get_data: {what}", "tools/get_data.py", None,
           python=_fmt(_GET_DATA, tools=str(TOOLS), kind=kind, row=IPIN_ROW), keep=keep, max_s=15, one_line=True)
      for what, kind, keep in (
          ("a record's file named ../../../victim.txt", "victim", ("gd/victim.txt",)),
          ("a record's file named by an absolute path", "absolute", ("gd/abs_victim.txt",)),
          ("a download shorter than its Content-Length", "short", ()),
          ("a half-downloaded package (no size, no MD5 in the record)", "half", ()))],
    Case("get_data: a corrupted source", "tools/get_data.py",
         None, python=f"import sys; sys.path.insert(0, {str(TOOLS)!r}); import get_data; "
                      f"sys.exit(get_data.main(['--out', 'gd/data_bad', '--from-dir', 'gd/src_bad', '--only', "
                      f"{IPIN_ROW!r}]))", max_s=15, one_line=True),
    Case("get_data: a source that is a link to another file", "tools/get_data.py",
         None, python=f"import sys; sys.path.insert(0, {str(TOOLS)!r}); import get_data; "
                      f"sys.exit(get_data.main(['--out', 'gd/data_link', '--from-dir', 'gd/src_link', '--only', "
                      f"{IPIN_ROW!r}]))", keep=USER, max_s=15, one_line=True),
    Case("get_data: a full disk while downloading", "tools/get_data.py", None,
         python=_fmt(_GET_DATA, tools=str(TOOLS), kind="full", row=IPIN_ROW), fsize_bytes=100_000, max_s=15,
         one_line=True),
    # memory and input checks
    Case("beacon table of 600 MB: one row, then spaces", "io/tables.py, sensors/beacons.py",
         _track(WALK, "--radiomap", str(RADIOMAP), "--beacons", "{w}/big_beacons.csv"), max_s=15, one_line=True),
    Case("beacon table: a field of 200 kB", "io/tables.py, sensors/beacons.py",
         _track(WALK, "--radiomap", str(RADIOMAP), "--beacons", "{w}/long_beacons.csv"), max_s=15, one_line=True,
         must_say="long_beacons.csv:2: "),
    Case("access-point table: a field of 200 kB", "io/tables.py, sensors/pathloss.py",
         _track(WALK, "--aps", "{w}/long_aps.csv"), max_s=15, one_line=True, must_say="long_aps.csv:2: "),
    Case("check --at a track of one 100 MB line", "io/tables.py, io/tracks.py",
         lambda w: ["check", str(WALK), "--truth", f"{w}/outdir/gt.csv", "--at", f"{w}/long_track.csv"],
         max_s=15, one_line=True, must_say="long_track.csv:2: "),
    Case("score of 10 million estimates", "evaal/protocol.py",
         lambda w: ["score", f"{w}/gsd.txt", f"{w}/many_estimates.csv"], max_s=15, one_line=True,
         must_say="more than 200000 estimates"),
    Case("score with latitude and longitude swapped", "evaal/protocol.py, cli/score_cmd.py",
         lambda w: ["score", f"{w}/gsd.txt", f"{w}/gsd.swapped.csv"], (0,), max_s=15, one_line=True,
         must_say="has them swapped"),
    Case("track --evaal-out, a log without POSI rows", "evaal/replay.py, cli/track_cmd.py",
         lambda w: ["track", f"{w}/venue.yaml", f"{w}/gsd_no_posi.txt", "--radiomap", str(RADIOMAP), "--evaal-out",
                    f"{w}/outdir/no_posi.csv"], max_s=15, one_line=True, must_say="--evaal-start LON,LAT,FLOOR"),
] + [  # issue 45: a live run (track MAP -)
    Case("live: 100 MB of blank lines on standard input", "sensors/logread.py",
         _track("-", "--radiomap", str(RADIOMAP)), max_s=15, one_line=True, stdin="blank_lines.txt",
         must_say="its first 200 lines are blank"),
    Case("live: 100 MB of random bytes on standard input", "sensors/logread.py",
         _track("-", "--radiomap", str(RADIOMAP)), max_s=15, one_line=True, stdin="random.bin",
         must_say="binary data"),
    Case("a log of 20 MB of random bytes without a newline", "sensors/logread.py",
         _track("{w}/random_one_line.bin", "--radiomap", str(RADIOMAP)), max_s=15, one_line=True,
         must_say="binary data"),
    Case("every clock 20 s back, fed whole and in 64 KiB pieces", "sensors/logread.py, filter/causal.py", None,
         (0,), python=_fmt(_CHUNKED_ROWS, log="clock_back.txt", **_OFFICE), must_say="fed whole"),
] + [  # issue 53: the probe's two cases
    Case("the IMU clock 20 s back, fed whole and in 64 KiB pieces", "sensors/logread.py, filter/causal.py", None,
         (0,), python=_fmt(_CHUNKED_ROWS, log="clock_back_imu.txt", **_OFFICE), must_say="fed whole"),
    Case("the IMU clock 20 s back: track - against track FILE", "sensors/logread.py, filter/causal.py", None, (0,),
         python=_fmt(_LIVE_VS_FILE, log="clock_back_imu.txt", **_OFFICE), must_say="the same"),
] + [Case(f"full disk: {command} --rerun, try {k} of 5", "viz/recorder.py",
          (lambda w, k=k: _track(WALK, "--radiomap", str(RADIOMAP), "--particles", "500", "--rerun",
                                 f"{w}/outdir/t{k}.rrd")(w)) if command == "track" else
          (lambda w, k=k: ["view", str(MAP), f"{w}/view_track.csv", "--log", str(WALK), "--rerun",
                           f"{w}/outdir/v{k}.rrd"]),
          fsize_bytes=4096, max_s=30, one_line=True, must_say="is the disk full?")
     for command in ("track", "view") for k in range(1, 6)]


# ---- running ------------------------------------------------------------------------------------
def run_case(case: Case, work: Path, memory_bytes: int, timeout_s: float) -> Outcome:
    before = set(_tree(work))
    kept = {name: _digest(work / name) for name in case.keep}
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
        stdin = (work / case.stdin).open("rb") if case.stdin else subprocess.DEVNULL
        process = subprocess.Popen(argv, stdin=stdin, stderr=err, cwd=work / (case.cwd or ""),
                                   preexec_fn=limits,
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
        if case.stdin:
            stdin.close()
        process.returncode = os.waitstatus_to_exitcode(status)  # keep Popen from waiting again
    text = err_path.read_text(errors="replace")
    err_path.unlink()
    leftovers = sorted(set(_tree(work)) - before)
    leftovers = [p for p in leftovers if Path(p).name.startswith(".")  # temporaries (finished outputs may stay)
                 and Path(p).name != ".mapfilter-manifest.json"]
    message = _first_line(text)
    if killed:
        message = f"(killed after {timeout_s:g} s) " + message
    if case.sigterm_when and not signalled:
        message = "(finished before the signal) " + message
    changed = [name for name, digest in kept.items() if _digest(work / name) != digest]
    return Outcome(case, process.returncode, message, usage.ru_maxrss / 1024.0, wall, leftovers, changed, text)


def _digest(path: Path) -> str | None:
    import hashlib

    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None


def _tree(root: Path) -> list[str]:
    return [str(p.relative_to(root)) for p in root.rglob("*") if p.is_file() and not p.is_symlink()]


def _first_line(stderr: str) -> str:
    """The line that says what happened: the error line, the end of a traceback, or the first line."""
    lines = [line for line in stderr.splitlines() if line.strip()]
    if not lines:
        return ""
    if any(line.startswith("Traceback") for line in lines):
        return "(traceback) " + lines[-1].strip()
    for line in lines:  # the refusal, after any progress line
        if ": error: " in line:
            return line.strip()
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
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
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
