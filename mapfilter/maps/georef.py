"""Georeference: WGS-84 latitude/longitude <-> a venue's metres, and raster plans placed by it.

- :class:`LocalFrame` is the east/north tangent plane at a venue origin: x east, y north, in
  metres, exact (the point's WGS-84 position projected onto the plane that touches the
  ellipsoid at the origin), with an exact inverse. Over a building (a few hundred metres) it
  differs from distances on the ellipsoid by well under a centimetre.
- :class:`ImagePlacement` puts a raster plan on the Earth the way the IPIN competitions'
  calibration files do: the latitude and longitude of the image centre, the rotation that
  aligns the image with geographic north, and the scale in metres per pixel.
- :func:`read_cal` reads such a calibration file (``.cal``, written by the organisers'
  MATLAB tool "GUI_mapas"): one column per floor of image file, floor number, building
  number, centre latitude, centre longitude, rotation (degrees) and scale (m/px).

The sign of the rotation was measured, not guessed: the floor -1 plan of IPIN 2023 marks its
nine surveyed reference points (plans/references.csv), and a similarity fitted from their pixel
positions to their east/north metres turns the image counter-clockwise by 20.65 deg, the
calibration's rotation being -20.736 deg: east/north = R(-rotation) (image right, image up).
Placed by the calibration, the nine points land within 0.6 m of their surveyed positions (the
fit's own scale is 0.3 % smaller than the calibration's).
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path

import numpy as np

from mapfilter.errors import MapfilterError, not_a_file

# WGS-84 ellipsoid
WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
_E2 = WGS84_F * (2.0 - WGS84_F)


def _ecef(lat_rad: np.ndarray, lon_rad: np.ndarray) -> np.ndarray:
    """Earth-centred, Earth-fixed coordinates (m) of points on the ellipsoid (height 0)."""
    n = WGS84_A_M / np.sqrt(1.0 - _E2 * np.sin(lat_rad) ** 2)
    return np.stack([n * np.cos(lat_rad) * np.cos(lon_rad), n * np.cos(lat_rad) * np.sin(lon_rad),
                     n * (1.0 - _E2) * np.sin(lat_rad)], axis=-1)


@dataclasses.dataclass(frozen=True)
class LocalFrame:
    """The east/north tangent plane at (``origin_lat_deg``, ``origin_lon_deg``): x east, y north, metres."""

    origin_lat_deg: float
    origin_lon_deg: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.origin_lat_deg) and -90.0 < self.origin_lat_deg < 90.0
                and math.isfinite(self.origin_lon_deg) and -180.0 <= self.origin_lon_deg <= 180.0):
            raise MapfilterError(f"a georeference origin must be a latitude in (-90, 90) and a longitude in "
                                 f"[-180, 180] degrees, got {self.origin_lat_deg}, {self.origin_lon_deg}")

    def _axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        lat, lon = math.radians(self.origin_lat_deg), math.radians(self.origin_lon_deg)
        east = np.array([-math.sin(lon), math.cos(lon), 0.0])
        north = np.array([-math.sin(lat) * math.cos(lon), -math.sin(lat) * math.sin(lon), math.cos(lat)])
        return _ecef(np.array(lat), np.array(lon)), east, north

    def to_xy_m(self, latlon_deg: np.ndarray) -> np.ndarray:
        """(..., 2) latitude, longitude in degrees -> (..., 2) east, north metres."""
        latlon = np.asarray(latlon_deg, dtype=np.float64)
        origin, east, north = self._axes()
        d = _ecef(np.radians(latlon[..., 0]), np.radians(latlon[..., 1])) - origin
        return np.stack([d @ east, d @ north], axis=-1)

    def to_latlon_deg(self, xy_m: np.ndarray) -> np.ndarray:
        """(..., 2) east, north metres -> (..., 2) latitude, longitude in degrees (inverse of ``to_xy_m``)."""
        xy = np.asarray(xy_m, dtype=np.float64)
        lat0 = math.radians(self.origin_lat_deg)
        # first guess with the local radii of curvature, then Newton steps on the exact forward map
        # (the Jacobian is nearly that of the first guess); three steps reach far below a millimetre
        meridian = WGS84_A_M * (1 - _E2) / (1 - _E2 * math.sin(lat0) ** 2) ** 1.5
        normal = WGS84_A_M / math.sqrt(1 - _E2 * math.sin(lat0) ** 2)
        scale = np.array([meridian, normal * math.cos(lat0)])  # metres per radian of lat, lon
        guess = np.stack([self.origin_lat_deg + np.degrees(xy[..., 1] / scale[0]),
                          self.origin_lon_deg + np.degrees(xy[..., 0] / scale[1])], axis=-1)
        for _ in range(4):
            error = self.to_xy_m(guess) - xy  # (east, north) error
            guess = guess - np.stack([np.degrees(error[..., 1] / scale[0]), np.degrees(error[..., 0] / scale[1])],
                                     axis=-1)
        return guess


@dataclasses.dataclass(frozen=True)
class ImagePlacement:
    """Where a raster plan lies on the Earth: its centre, rotation to north, and scale.

    ``rotation_deg`` is the calibration file's: east/north = R(-rotation_deg) applied to (image
    right, image up), i.e. a negative value turns the image's up axis west of north.
    """

    centre_lat_deg: float
    centre_lon_deg: float
    rotation_deg: float
    scale_m_per_px: float
    size_px: tuple[int, int]  # (width, height) of the image

    def pixel_to_xy_m(self, uv_px: np.ndarray, frame: LocalFrame) -> np.ndarray:
        """Continuous pixel coordinates (column, row from the top-left corner) -> ``frame`` metres."""
        uv = np.asarray(uv_px, dtype=np.float64)
        width, height = self.size_px
        right = (uv[..., 0] - 0.5 * width) * self.scale_m_per_px
        up = (0.5 * height - uv[..., 1]) * self.scale_m_per_px
        c, s = math.cos(math.radians(-self.rotation_deg)), math.sin(math.radians(-self.rotation_deg))
        centre = frame.to_xy_m(np.array([self.centre_lat_deg, self.centre_lon_deg]))
        return np.stack([centre[0] + c * right - s * up, centre[1] + s * right + c * up], axis=-1)

    def xy_m_to_pixel(self, xy_m: np.ndarray, frame: LocalFrame) -> np.ndarray:
        """``frame`` metres -> continuous pixel coordinates (inverse of ``pixel_to_xy_m``)."""
        xy = np.asarray(xy_m, dtype=np.float64)
        centre = frame.to_xy_m(np.array([self.centre_lat_deg, self.centre_lon_deg]))
        dx, dy = xy[..., 0] - centre[0], xy[..., 1] - centre[1]
        c, s = math.cos(math.radians(-self.rotation_deg)), math.sin(math.radians(-self.rotation_deg))
        right, up = c * dx + s * dy, -s * dx + c * dy
        width, height = self.size_px
        return np.stack([0.5 * width + right / self.scale_m_per_px, 0.5 * height - up / self.scale_m_per_px], axis=-1)

    def corners_xy_m(self, frame: LocalFrame) -> np.ndarray:
        """(4, 2) the image's corners (top-left, top-right, bottom-right, bottom-left) in ``frame``."""
        width, height = self.size_px
        return self.pixel_to_xy_m(np.array([[0, 0], [width, 0], [width, height], [0, height]], dtype=float), frame)


@dataclasses.dataclass(frozen=True)
class CalFloor:
    """One floor of a calibration file."""

    image: str  # the image file name, relative to the .cal
    floor: str  # the venue's floor id ("0", "-1", "-2")
    building: str
    centre_lat_deg: float
    centre_lon_deg: float
    rotation_deg: float
    scale_m_per_px: float

    def placement(self, size_px: tuple[int, int]) -> ImagePlacement:
        return ImagePlacement(self.centre_lat_deg, self.centre_lon_deg, self.rotation_deg, self.scale_m_per_px,
                              size_px)


_CAL_ROWS = ("image file names", "floor numbers", "building numbers", "latitudes", "longitudes", "rotations",
             "scales")


def read_cal(path: str | os.PathLike) -> list[CalFloor]:
    """The floors of an IPIN calibration file (``%`` comments; seven rows of one column per floor)."""
    path = Path(path)
    if not path.is_file():
        raise not_a_file(path)
    if path.stat().st_size > 1_000_000:
        raise MapfilterError("too large for a calibration file (over 1 MB)", path)
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except UnicodeDecodeError:
        raise MapfilterError("not a text calibration file", path) from None
    rows: list[tuple[int, list[str]]] = []
    for line_no, line in enumerate(text.splitlines(), start=1):
        content = line.split("%", 1)[0].strip()
        if content:
            rows.append((line_no, content.split()))
    if len(rows) != len(_CAL_ROWS):
        raise MapfilterError(f"a calibration file has {len(_CAL_ROWS)} rows ({', '.join(_CAL_ROWS)}), "
                             f"this one has {len(rows)}", path)
    n_floors = len(rows[0][1])
    for (line_no, values), what in zip(rows, _CAL_ROWS):
        if len(values) != n_floors:
            raise MapfilterError(f"{len(values)} {what} for {n_floors} floors", path, line_no)
    numbers = []
    for (line_no, values), what, (low, high) in zip(rows[3:], _CAL_ROWS[3:],
                                                     ((-90, 90), (-180, 180), (-360, 360), (1e-6, 1e3))):
        try:
            parsed = [float(v) for v in values]
        except ValueError:
            raise MapfilterError(f"the {what} must be numbers, got {values}", path, line_no) from None
        bad = [v for v in parsed if not (math.isfinite(v) and low <= v <= high)]
        if bad:
            raise MapfilterError(f"{what} out of range: {bad[0]} (expected {low} to {high})", path, line_no)
        numbers.append(parsed)
    floors = [CalFloor(rows[0][1][i], _floor_id(rows[1][1][i]), rows[2][1][i], numbers[0][i], numbers[1][i],
                       numbers[2][i], numbers[3][i]) for i in range(n_floors)]
    ids = [f.floor for f in floors]
    if len(set(ids)) != len(ids):
        raise MapfilterError(f"floor numbers repeat: {' '.join(ids)}", path, rows[1][0])
    return floors


def _floor_id(text: str) -> str:
    """A floor id as the venue writes it, integers normalised ("00" -> "0", "-01" -> "-1")."""
    try:
        return str(int(text))
    except ValueError:
        return text
