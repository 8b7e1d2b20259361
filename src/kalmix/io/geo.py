"""Geographic coordinates: latitude and longitude (degrees, WGS84) to a local metric frame and back.

kalmix predicts latitude/longitude tracks in metres: each track gets its own local tangent
plane (east, north, up on the WGS84 ellipsoid, :mod:`pymap3d`'s ``geodetic2enu`` /
``enu2geodetic``) whose origin is the track's first valid fix. The experts run on east and
north metres (and up, when an altitude column is given); the forecasts go back to degrees.

- **Antimeridian**: the frame is local, so a track crossing ±180° moves a few metres east, not
  360° west; forecasts come back as longitudes in [-180°, 180°].
- **Poles**: the tangent plane has no singularity there (east and north are those of the
  origin).
- **Accuracy**: positions go to the frame and back exactly (to ~1e-9 m). Two-coordinate data
  lie on the ellipsoid: a forecast's point is found on it below its east/north (a few Newton
  steps), so the round trip is exact without an altitude. Distances in the frame (the
  intervals ``std_east_m`` / ``std_north_m``, :mod:`kalmix.experiments.evaluate`'s errors) are
  the tangent plane's: within 0.2 % of the ground distance within 300 km of the origin, 1.2 %
  at 1,000 km. A fix more than :data:`REANCHOR_M` (straight line) from its frame's origin
  starts a new segment there with its own frame (:func:`assign_frames`), so no frame is used
  far from where it is accurate.
- **Altitude**: a third column named ``alt`` / ``altitude`` (metres above the ellipsoid) is
  the frame's up coordinate: predicted, and given back in metres.

Names: a position column is a latitude when its name is ``lat`` / ``latitude`` (any case, with
the prefixes :func:`kalmix.io.detect_columns` knows, and an optional ``_deg`` suffix), a
longitude when ``lon`` / ``lng`` / ``long`` / ``longitude``, an altitude when ``alt`` /
``altitude``.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence

import numpy as np

__all__ = ["GeoAxes", "geographic_axes", "resolve_axes", "check_degrees", "beyond_degrees",
           "degrees_problem", "to_local", "from_local", "chord",
           "origin_of", "assign_frames", "std_names", "geographic_note", "NOT_AVAILABLE", "not_available",
           "without_not_available", "local_table", "REANCHOR_M", "LATITUDE_NAMES",
           "LONGITUDE_NAMES", "ALTITUDE_NAMES"]

LATITUDE_NAMES = ("lat", "latitude")
LONGITUDE_NAMES = ("lon", "lng", "long", "longitude")
ALTITUDE_NAMES = ("alt", "altitude")
_PREFIX = re.compile(r"^(?:position[_.]?|pos[_.]?|p(?=(?:lat|lon|lng|alt)))")
_SUFFIX = re.compile(r"(?:_?deg(?:rees)?|_m)$")

#: A fix farther than this (metres, straight line) from its frame's origin starts a new segment with its
#: own frame: the tangent plane's distances are within 1.2 % of the ground's up to there.
REANCHOR_M = 1_000_000.0
#: WGS84 semi-major and semi-minor axes (metres).
_A, _B = 6378137.0, 6356752.314245179


def _pymap3d():
    try:
        import pymap3d
    except ImportError:   # pragma: no cover - a core dependency
        raise ImportError("geographic coordinates need pymap3d (pip install 'pymap3d>=3'), or pass "
                          "geographic=False (--no-geographic) to take them as flat numbers") from None
    return pymap3d


class GeoAxes(tuple):
    """``(lat, lon, alt)``: the positions' indices of the latitude, the longitude and the altitude (None)."""

    @property
    def lat(self) -> int:
        return self[0]

    @property
    def lon(self) -> int:
        return self[1]

    @property
    def alt(self) -> int | None:
        return self[2]

    @property
    def dim(self) -> int:
        """Coordinates of the metric frame: 2 (east, north) or 3 (and up)."""
        return 2 if self[2] is None else 3


def _kind(name) -> str | None:
    text = str(name).strip().lower()
    text = _SUFFIX.sub("", _PREFIX.sub("", text))
    for kind, names in (("lat", LATITUDE_NAMES), ("lon", LONGITUDE_NAMES), ("alt", ALTITUDE_NAMES)):
        if text in names:
            return kind
    return None


def geographic_axes(names: Sequence[str]) -> GeoAxes | None:
    """The :class:`GeoAxes` of position columns named like latitude and longitude (and altitude); None
    when they are not (exactly one latitude, one longitude, at most one altitude, nothing else)."""
    kinds = [_kind(name) for name in names]
    if None in kinds or kinds.count("lat") != 1 or kinds.count("lon") != 1 or kinds.count("alt") > 1:
        return None
    return GeoAxes((kinds.index("lat"), kinds.index("lon"), kinds.index("alt") if "alt" in kinds else None))


def resolve_axes(names: Sequence[str] | None, geographic: bool | None, dim: int | None = None) -> GeoAxes | None:
    """Whether positions ``names`` are geographic: ``geographic`` None detects it from the names; True
    takes them (or, named otherwise, the positions in the order latitude, longitude[, altitude]);
    False: never. ``dim``: the number of positions when there are no names."""
    if geographic is False:
        return None
    found = geographic_axes(names) if names is not None else None
    if geographic is None or found is not None:
        return found
    count = len(names) if names is not None else dim
    if count is None:
        return None   # decided once the number of coordinates is known
    if count not in (2, 3):
        raise ValueError(f"geographic: expected 2 or 3 position columns (latitude, longitude[, altitude]), got "
                         f"{count}" + (f" ({list(names)})" if names is not None else ""))
    return GeoAxes((0, 1, 2 if count == 3 else None))


def geographic_note(names, axes, off: str) -> str:
    """What is said when positions ``names`` are taken as geographic (``axes``): which column is which, and the
    units of the outputs; ``off`` names the setting that turns it off."""
    lat, lon = names[axes.lat], names[axes.lon]
    spread = ", ".join(f"std_{name}" for name in std_names(axes))
    return (f"geographic coordinates ({lat!r} latitude, {lon!r} longitude"
            + (f", {names[axes.alt]!r} altitude in metres" if axes.alt is not None else "")
            + f"): predicted in metres in each track's local frame; pred_ columns in degrees, {spread} in metres "
            f"({off}: flat numbers)")


def std_names(axes: GeoAxes) -> tuple[str, ...]:
    """The names of a geographic prediction's standard deviations: metres east, north (and up)."""
    return ("east_m", "north_m", "up_m")[:axes.dim]


#: What AIS reports when it has no fix: a latitude of 91° or a longitude of 181° (ITU-R M.1371); such a row is a
#: missing position (NaN), as an empty cell.
NOT_AVAILABLE = (91.0, 181.0)


def not_available(values, axes: GeoAxes) -> np.ndarray:
    """``(n,)`` bool: the rows of ``values (n, p)`` (degrees) whose latitude is 91° or longitude 181°
    (:data:`NOT_AVAILABLE`)."""
    values = np.asarray(values, dtype=np.float64)
    if values.size == 0:
        return np.zeros(len(values), dtype=bool)
    return (values[:, axes.lat] == NOT_AVAILABLE[0]) | (values[:, axes.lon] == NOT_AVAILABLE[1])


def without_not_available(values, axes: GeoAxes) -> np.ndarray:
    """``values (n, p)`` (degrees) with the rows of :func:`not_available` missing (NaN); ``values`` itself when
    there is none."""
    values = np.asarray(values, dtype=np.float64)
    gone = not_available(values, axes)
    if not gone.any():
        return values
    values = values.copy()
    values[gone] = np.nan
    return values


def beyond_degrees(values, axes: GeoAxes) -> np.ndarray:
    """``(n,)`` bool: the rows of ``values (n, p)`` (degrees) whose latitude is beyond ±90° or longitude beyond
    ±180° (NaN is a missing fix, and so is AIS's "not available", :data:`NOT_AVAILABLE`: neither is beyond)."""
    values = without_not_available(values, axes)
    if values.size == 0:
        return np.zeros(len(values), dtype=bool)
    with np.errstate(invalid="ignore"):
        return (np.abs(values[:, axes.lat]) > 90.0) | (np.abs(values[:, axes.lon]) > 180.0)


def degrees_problem(row, axes: GeoAxes, names: Sequence[str] | None) -> str:
    """What is wrong with ``row (p,)``, one of :func:`beyond_degrees`' rows: which column must hold what, and its
    value (``names``: the position columns' names, None where they have none)."""
    lat, lon = float(row[axes.lat]), float(row[axes.lon])
    if abs(lat) > 90.0:
        column, what, value = axes.lat, "a latitude in degrees, -90 to 90", lat
    else:
        column, what, value = axes.lon, "a longitude in degrees, -180 to 180", lon
    which = "latitude" if column == axes.lat else "longitude"
    label = repr(names[column]) if names is not None else f"{column} (the {which})"
    return (f"position column {label} must hold {what}, got {value!r} (geographic coordinates; pass "
            "--no-geographic, geographic=False in Python, if they are not)")


def check_degrees(values, axes: GeoAxes, names: Sequence[str] | None, where: Callable[[int], str]) -> None:
    """``ValueError`` at the first row of ``values (n, p)`` whose latitude is beyond ±90° or longitude beyond
    ±180° (:func:`beyond_degrees`); ``where(i)`` names row ``i`` (``"row 17 (counted from 0)"``)."""
    bad = beyond_degrees(values, axes)
    if not bad.any():
        return
    i = int(np.flatnonzero(bad)[0])
    raise ValueError(f"{where(i)}: {degrees_problem(np.asarray(values, dtype=np.float64)[i], axes, names)}")


def _origins(origins, n):
    origins = np.asarray(origins, dtype=np.float64)
    return np.broadcast_to(origins.reshape(-1, 3) if origins.ndim == 1 else origins, (n, 3))


def to_local(values, origins, axes: GeoAxes) -> np.ndarray:
    """Positions ``values (n, p)`` (degrees, and the altitude in metres) as ``(n, axes.dim)`` metres east,
    north (and up) of their ``origins (n, 3)`` (latitude, longitude, height; one row for all). NaN where a
    fix or its origin is missing."""
    pymap3d = _pymap3d()

    values = np.asarray(values, dtype=np.float64)
    n = len(values)
    origin = _origins(origins, n)
    height = values[:, axes.alt] if axes.alt is not None else np.zeros(n)
    with np.errstate(invalid="ignore"):
        east, north, up = pymap3d.geodetic2enu(values[:, axes.lat], values[:, axes.lon], height,
                                               origin[:, 0], origin[:, 1], origin[:, 2])
    columns = (east, north, up)[:axes.dim]
    return np.column_stack([np.asarray(c, dtype=np.float64).reshape(n) for c in columns])


def chord(values, origins, axes: GeoAxes) -> np.ndarray:
    """Straight-line distance (metres) of each fix from its origin, on the ellipsoid (altitude ignored)."""
    pymap3d = _pymap3d()

    values = np.asarray(values, dtype=np.float64)
    n = len(values)
    origin = _origins(origins, n)
    with np.errstate(invalid="ignore"):
        east, north, up = pymap3d.geodetic2enu(values[:, axes.lat], values[:, axes.lon], np.zeros(n),
                                               origin[:, 0], origin[:, 1], np.zeros(n))
    return np.sqrt(np.asarray(east) ** 2 + np.asarray(north) ** 2 + np.asarray(up) ** 2).reshape(n)


def from_local(local, origins, axes: GeoAxes, p: int) -> np.ndarray:
    """The inverse of :func:`to_local`: ``local (n, axes.dim)`` metres to ``(n, p)`` positions in the columns'
    order (degrees; the altitude in metres). Without an altitude the point is the one on the ellipsoid below
    that east/north; a point whose east/north lies beyond the ellipsoid's edge seen from the origin (more
    than about a quarter of the globe away) has none: NaN."""
    pymap3d = _pymap3d()

    local = np.asarray(local, dtype=np.float64)
    n = len(local)
    origin = _origins(origins, n)
    out = np.full((n, p), np.nan)
    east, north = local[:, 0], local[:, 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        if axes.alt is not None:
            lat, lon, height = pymap3d.enu2geodetic(east, north, local[:, 2], origin[:, 0], origin[:, 1],
                                                    origin[:, 2])
            out[:, axes.alt] = height
        else:
            # the point of the ellipsoid below (east, north): start on the sphere of the local radius, then Newton
            # steps along the origin's up (the height changes by cos(angle) per metre of up)
            radius = _B + (_A - _B) * np.cos(np.radians(origin[:, 0]))
            d2 = east ** 2 + north ** 2
            inside = d2 < (0.95 * _B) ** 2
            d2 = np.where(inside, d2, np.nan)
            rest = np.sqrt(np.maximum(radius ** 2 - d2, 0.0))
            up = -d2 / (radius + rest)
            slope = np.maximum(rest / radius, 0.05)
            for _ in range(4):
                lat, lon, height = pymap3d.enu2geodetic(east, north, up, origin[:, 0], origin[:, 1], origin[:, 2])
                up = up - np.asarray(height) / slope
            lat, lon, height = pymap3d.enu2geodetic(east, north, up, origin[:, 0], origin[:, 1], origin[:, 2])
            off = ~(np.abs(np.asarray(height)) < 1e-3)
            lat, lon = np.where(off, np.nan, lat), np.where(off, np.nan, lon)
    out[:, axes.lat] = np.asarray(lat).reshape(n)
    out[:, axes.lon] = np.asarray(lon).reshape(n)
    return out


def origin_of(fix, axes: GeoAxes) -> tuple[float, float, float]:
    """A fix ``(p,)`` as a frame origin: (latitude, longitude, height)."""
    height = float(fix[axes.alt]) if axes.alt is not None else 0.0
    return float(fix[axes.lat]), float(fix[axes.lon]), height


def assign_frames(values, origin, axes: GeoAxes):
    """The frames of one track's rows, in order: each row's origin and which rows start a new frame.

    A track's frame starts at its first valid fix; a valid fix more than :data:`REANCHOR_M`
    (straight line) from its frame's origin starts a new frame there, and a new segment of the
    track (its experts start again: their states are in the old frame's metres).

    Parameters
    ----------
    values : ndarray (n, p)
        The track's rows (degrees), NaN where a fix is missing.
    origin : tuple or None
        The frame the track is in before these rows (None: none yet).

    Returns
    -------
    origins : ndarray (n, 3)
        Each row's frame origin (NaN for rows before the track's first valid fix).
    anchored : ndarray (n,) bool
        Rows that start a new frame (not the track's first).
    origin : tuple or None
        The frame after these rows.
    """
    values = np.asarray(values, dtype=np.float64)
    n = len(values)
    valid = np.isfinite(values).all(axis=1)
    anchored = np.zeros(n, dtype=bool)
    origins = np.full((n, 3), np.nan)
    current, start = origin, 0
    while start < n:
        if current is None:
            first = np.flatnonzero(valid[start:])
            if not len(first):
                break
            start += int(first[0])
            current = origin_of(values[start], axes)
        origins[start:] = current
        with np.errstate(invalid="ignore"):
            far = valid[start:] & (chord(values[start:], current, axes) > REANCHOR_M)
        if not far.any():
            break
        start += int(np.flatnonzero(far)[0])
        anchored[start] = True
        current = None
    return origins, anchored, current


def local_table(table, names: Sequence[str], axes: GeoAxes):
    """A track table (``track_id``, ``time``, positions ``names``) with its positions in metres: columns
    ``east_m``, ``north_m`` (and ``up_m``) in place of ``names``, each track in the frame of its first valid
    fix (one frame a track: what :func:`kalmix.experiments.evaluate.evaluate_table` and the length unit's
    estimate use). ``ValueError`` naming the first row (counted from 0) beyond ±90° / ±180°."""
    import pandas as pd

    names = list(names)
    values = without_not_available(table[names].to_numpy(np.float64), axes)
    check_degrees(values, axes, names, lambda i: f"row {i} (counted from 0)")
    codes = pd.factorize(table["track_id"], sort=False)[0]
    valid = np.isfinite(values).all(axis=1)
    origins = np.full((len(values), 3), np.nan)
    if valid.any():
        rows = np.flatnonzero(valid)
        tracks, first = np.unique(codes[rows], return_index=True)   # each track's first valid row
        fixes = values[rows[first]]
        per_track = np.full((codes.max() + 1, 3), np.nan)
        per_track[tracks, 0], per_track[tracks, 1] = fixes[:, axes.lat], fixes[:, axes.lon]
        per_track[tracks, 2] = fixes[:, axes.alt] if axes.alt is not None else 0.0
        origins = per_track[codes]
    local = to_local(values, origins, axes)
    out = table.drop(columns=names)
    for j, name in enumerate(std_names(axes)):
        out[name] = local[:, j]
    return out
