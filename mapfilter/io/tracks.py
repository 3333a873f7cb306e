"""Track files: our CSV (``t_s,x_m,y_m[,floor][,floor_p][,latitude_deg,longitude_deg][,std_m][,heading_rad]``)
and TUM (``t x y z qx qy qz qw``).

TUM is what evo and most trajectory tools read: z = 0, the orientation a yaw rotation about z
(identity when no heading is known). In a georeferenced building (maps/georef.py) the CSV also
carries each row's WGS-84 latitude and longitude: the output the IPIN competitions ask for.
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path
from typing import Protocol

import numpy as np

from mapfilter.io.atomic import atomic_paths, write_csv_atomically
from mapfilter.io.tables import finite_number, table_dict_reader
from mapfilter.errors import MapfilterError, not_a_file



class Georeferenced(Protocol):
    """What a track's writer asks of a building (``maps.building.Building``, a stage above this
    one): whether it has a georeference, and the latitude and longitude of points on its floors."""

    georeference: object | None

    def floor_xy_to_latlon(self, xy_m: np.ndarray, floor_names: list[str] | str | None) -> np.ndarray:
        """(T, 2) latitude, longitude of each point on its floor's frame (floors by name)."""
        ...


@dataclasses.dataclass
class Track:
    """An estimated trajectory in the map frame."""

    t_s: np.ndarray  # (T,)
    xy_m: np.ndarray  # (T, 2)
    std_m: np.ndarray | None = None  # (T,) position spread
    heading_rad: np.ndarray | None = None  # (T,)
    floor: list[str] | None = None
    name: str = "track"
    latlon_deg: np.ndarray | None = None  # (T, 2) WGS-84 latitude, longitude (a georeferenced building)
    # (T,) the track's belief in its row's floor, 0-1 (a building with several floors): causal,
    # the share of the particles' weight on that floor; offline, the whole-walk floor posterior
    floor_p: np.ndarray | None = None

    def __len__(self) -> int:
        return self.t_s.shape[0]

    def rows(self, index: slice | np.ndarray) -> Track:
        """The track's rows ``index`` (a new track)."""
        def pick(values):
            if values is None:
                return None
            return [values[i] for i in np.arange(len(self))[index]] if isinstance(values, list) else values[index]
        return dataclasses.replace(self, t_s=self.t_s[index], xy_m=self.xy_m[index], std_m=pick(self.std_m),
                                   heading_rad=pick(self.heading_rad), floor=pick(self.floor),
                                   latlon_deg=pick(self.latlon_deg), floor_p=pick(self.floor_p))


def with_latlon(track: Track, building: Georeferenced) -> Track:
    """A new track with each row's latitude and longitude from a georeferenced ``building`` (rows
    on their own floor's frame; a track without floors is on the building's first floor)."""
    latlon = building.floor_xy_to_latlon(track.xy_m, track.floor)
    return dataclasses.replace(track, latlon_deg=latlon)


def csv_header(track: Track) -> list[str]:
    """The CSV columns of a track: ``t_s,x_m,y_m[,floor][,floor_p][,latitude_deg,longitude_deg][,std_m][,heading_rad]``."""
    header = ["t_s", "x_m", "y_m"]
    if track.floor is not None:
        header.append("floor")
    if track.floor_p is not None:
        header.append("floor_p")
    if track.latlon_deg is not None:
        header += ["latitude_deg", "longitude_deg"]
    if track.std_m is not None:
        header.append("std_m")
    if track.heading_rad is not None:
        header.append("heading_rad")
    return header


def csv_rows(track: Track) -> list[list[str]]:
    """The CSV rows of a track, in ``csv_header``'s columns."""
    rows = []
    for i in range(len(track)):
        row = [f"{track.t_s[i]:.3f}", f"{track.xy_m[i, 0]:.3f}", f"{track.xy_m[i, 1]:.3f}"]
        if track.floor is not None:
            row.append(track.floor[i])
        if track.floor_p is not None:
            row.append(f"{track.floor_p[i]:.4f}")
        if track.latlon_deg is not None:
            # 1e-8 degrees is about a millimetre
            row += [f"{track.latlon_deg[i, 0]:.8f}", f"{track.latlon_deg[i, 1]:.8f}"]
        if track.std_m is not None:
            row.append(f"{track.std_m[i]:.3f}")
        if track.heading_rad is not None:
            row.append(f"{track.heading_rad[i]:.4f}")
        rows.append(row)
    return rows


def write_track_csv(track: Track, path: str | os.PathLike, building: Georeferenced | None = None) -> None:
    """Write ``t_s,x_m,y_m[,floor][,floor_p][,latitude_deg,longitude_deg][,std_m][,heading_rad]`` atomically.

    Latitude and longitude are written when the track has them (``with_latlon``) or when
    ``building`` is given and has a georeference; otherwise the file is as it always was.
    """
    if track.latlon_deg is None and building is not None and building.georeference is not None:
        track = with_latlon(track, building)
    write_csv_atomically(path, csv_header(track), csv_rows(track))


def track_csv_bytes(track: Track, building: Georeferenced | None = None) -> bytes:
    """The bytes ``write_track_csv`` writes (made in memory: a worker's files for its parent)."""
    import csv
    import io

    if track.latlon_deg is None and building is not None and building.georeference is not None:
        track = with_latlon(track, building)
    text = io.StringIO(newline="")
    writer = csv.writer(text)
    writer.writerow(csv_header(track))
    writer.writerows(csv_rows(track))
    return text.getvalue().encode()


def tum_lines(track: Track) -> list[str]:
    """The TUM lines of a track: ``t x y z qx qy qz qw`` (z = 0; yaw-only quaternion; identity
    without a heading), each with its newline."""
    heading = track.heading_rad if track.heading_rad is not None else np.zeros(len(track))
    lines = []
    for t, (x, y), yaw in zip(track.t_s, track.xy_m, heading):
        qz, qw = math.sin(yaw / 2.0), math.cos(yaw / 2.0)
        lines.append(f"{t:.6f} {x:.4f} {y:.4f} 0.0 0.0 0.0 {qz:.6f} {qw:.6f}\n")
    return lines


def write_track_tum(track: Track, path: str | os.PathLike) -> None:
    """Write TUM ``t x y z qx qy qz qw`` lines (``tum_lines``), atomically."""
    with atomic_paths(path) as (tmp,):
        with tmp.open("w") as handle:
            handle.writelines(tum_lines(track))


def write_track(track: Track, path: str | os.PathLike, track_format: str = "csv",
                building: Georeferenced | None = None) -> None:
    """Write a track as ``csv`` (``write_track_csv``; with latitude and longitude in a
    georeferenced ``building``) or ``tum`` (``write_track_tum``), atomically."""
    if track_format == "tum":
        write_track_tum(track, path)
    elif track_format == "csv":
        write_track_csv(track, path, building)
    else:
        raise MapfilterError(f"unknown track format {track_format!r}: csv or tum", path)


def read_track(path: str | os.PathLike) -> Track:
    """Read a track written by ``write_track_csv`` or ``write_track_tum`` (told apart by content)."""
    path = Path(path)
    if not path.is_file():
        raise not_a_file(path)
    with path.open("rb") as handle:
        head = handle.read(1 << 20).decode("utf-8", errors="replace")  # the first line is what tells
    first = next((line for line in head.splitlines() if line.strip() and not line.startswith("#")), "")
    if first.startswith("t_s"):
        return _read_csv(path)
    return _read_tum(path)


def _read_csv(path: Path) -> Track:
    with path.open(newline="") as handle:
        reader = table_dict_reader(handle, path)  # a field over the csv module's limit: one line
        fields = reader.fieldnames or []
        if not {"t_s", "x_m", "y_m"} <= set(fields):
            raise MapfilterError("a track CSV needs the columns t_s,x_m,y_m", path, 1)
        columns: dict[str, list] = {name: [] for name in fields}
        for line_no, row in enumerate(reader, start=2):
            for name in fields:
                value = row.get(name)
                if name == "floor":
                    columns[name].append(value or "")
                    continue
                columns[name].append(finite_number(value, name, path, line_no))
    if not columns["t_s"]:
        raise MapfilterError("the track has no rows", path)
    return Track(
        t_s=np.array(columns["t_s"]),
        xy_m=np.column_stack([columns["x_m"], columns["y_m"]]),
        std_m=np.array(columns["std_m"]) if "std_m" in columns else None,
        heading_rad=np.array(columns["heading_rad"]) if "heading_rad" in columns else None,
        floor=columns.get("floor"),
        floor_p=_probabilities(columns["floor_p"], path) if "floor_p" in columns else None,
        name=path.stem,
        latlon_deg=np.column_stack([columns["latitude_deg"], columns["longitude_deg"]])
        if {"latitude_deg", "longitude_deg"} <= set(columns) else None,
    )


def _probabilities(values: list[float], path: Path) -> np.ndarray:
    out = np.array(values, dtype=np.float64)
    bad = np.flatnonzero((out < 0.0) | (out > 1.0))
    if bad.size:
        # line numbers: the header is line 1
        raise MapfilterError(f"column floor_p is a probability (0-1), not {out[bad[0]]:g}", path, int(bad[0]) + 2)
    return out


def _read_tum(path: Path) -> Track:
    rows = []
    for line_no, line in enumerate(path.read_text(errors="replace").splitlines(), start=1):
        if not line.strip() or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) != 8:
            raise MapfilterError(f"a TUM line has 8 numbers, this one has {len(parts)}", path, line_no)
        try:
            values = [float(p) for p in parts]
        except ValueError:
            raise MapfilterError("a TUM line holds a value that is not a number", path, line_no) from None
        if not all(math.isfinite(v) for v in values):
            raise MapfilterError("a TUM line holds a value that is not finite", path, line_no)
        rows.append(values)
    if not rows:
        raise MapfilterError("the track has no rows", path)
    data = np.array(rows)
    # yaw of a (yaw-only) quaternion, wrapped to [-pi, pi): other tools may write qw < 0
    yaw = np.mod(2.0 * np.arctan2(data[:, 6], data[:, 7]) + np.pi, 2.0 * np.pi) - np.pi
    return Track(t_s=data[:, 0], xy_m=data[:, 1:3].copy(), heading_rad=yaw, name=path.stem)
