"""Real recorded motion shipped inside PyPI packages, as track tables.

Every loader reads files installed with a package (``pip install 'kalmix[data]'``
brings ``kloppy`` and ``bokeh-sampledata``); nothing is downloaded. Each returns
a long table ``track_id, time, x, y[, z]`` with time in seconds and positions in
metres, sorted by ``(track_id, time)``, in the form :func:`kalmix.io.read_tracks`
produces.

- ``hawkeye_ball``: Hawk-Eye optical tracking of the football, 50 Hz, 3-D.
  Two one-minute sample files (``hawkeye_1_1`` = first half, minute 1;
  ``hawkeye_2_46`` = second half, minute 46), one track each
  (``ball_period1_minute1``, ``ball_period2_minute46``). ``x``, ``y``, ``z`` are
  the file's ``pos`` in metres (pitch centre origin, ``z`` up); ``time`` is the
  file's ``time``, seconds from the start of that file. All samples are kept,
  including the ball out of play; the second file has one 1.66 s hole.
- ``skillcorner``: SkillCorner broadcast tracking of a Bundesliga match
  (Bayern-Dortmund), 10 fps, 2-D metres from the pitch centre. One track per
  object: ``ball`` and each player (``<team acronym>_<shirt number>_<last name>``);
  the referee and detections without an identity are left out, and so are frames
  outside a period. ``time = frame / 10`` seconds from the start of the
  recording (so the second half starts near 4000 s, after a halftime gap).
  Broadcast video shows only part of the pitch, so objects drop out: a dropout
  of at most 10 frames (1 s) within a period becomes NaN rows (missing
  measurements, bridged by prediction); a longer absence (out of shot, replay,
  halftime) leaves no rows, so it shows as a time gap that
  :func:`kalmix.io.split_on_gaps` turns into a new segment. The ball's
  sometimes-present height is dropped. Broadcast tracking has identity
  switches: a few frame-to-frame jumps are far faster than any player (the
  99th percentile of player speeds is under 9 m/s).
- ``cycling``: a Garmin bicycle GPS log (bokeh-sampledata ``cycling.csv.gz``),
  1 Hz, one track ``ride``. Positions come in semicircles,
  ``degrees = semicircles * 180 / 2**31``, then local metres east (``x``) and
  north (``y``) of the first fix by the equirectangular approximation
  (``x = R cos(lat0) (lon - lon0)``, ``y = R (lat - lat0)`` with the mean Earth
  radius ``R = 6 371 008.8 m``; error well below a metre for a
  37 km ride that stays within 3.5 km of its start).
  The file's clock is rounded to whole seconds (63 repeated and 64 skipped
  seconds, each row a distinct fix), so ``time`` is the row number in seconds,
  which stays within 1 s of the file's clock.
"""

from __future__ import annotations

import functools
import importlib
import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
import pandas as pd

__all__ = ["DatasetInfo", "DATASETS", "load_dataset", "dataset_path", "semicircles_to_degrees",
           "degrees_to_local_metres", "EARTH_RADIUS_M"]

EARTH_RADIUS_M = 6_371_008.8
_EXTRA = "pip install 'kalmix[data]'"
_SKILLCORNER_FILL = 10  # frames (1 s): longest dropout kept as NaN rows


@dataclass(frozen=True)
class DatasetInfo:
    """Description of a shipped data set.

    Attributes
    ----------
    name : str
        Key in :data:`DATASETS`.
    description : str
        What was recorded.
    units : str
        Units of ``time`` and positions.
    rate_hz : float
        Nominal sampling rate.
    dims : int
        Number of position columns.
    package : str
        Distribution (pip name) that ships the files.
    module : str
        Importable module whose folder holds the files.
    files : tuple of str
        Paths relative to the module's folder.
    """

    name: str
    description: str
    units: str
    rate_hz: float
    dims: int
    package: str
    module: str
    files: tuple[str, ...]


DATASETS: dict[str, DatasetInfo] = {
    d.name: d for d in (
        DatasetInfo("hawkeye_ball", "Football position from Hawk-Eye optical tracking, two one-minute "
                    "samples (first and second half), 3-D, pitch centre origin",
                    "time s; x, y, z m", 50.0, 3, "kloppy", "kloppy",
                    ("tests/files/hawkeye_1_1.football.samples.ball",
                     "tests/files/hawkeye_2_46.football.samples.ball")),
        DatasetInfo("skillcorner", "Ball and players of a football match from SkillCorner broadcast "
                    "tracking, 2-D, pitch centre origin, NaN rows for dropouts up to 1 s",
                    "time s; x, y m", 10.0, 2, "kloppy", "kloppy",
                    ("tests/files/skillcorner_structured_data.json",
                     "tests/files/skillcorner_match_data.json")),
        DatasetInfo("cycling", "Bicycle ride from a Garmin GPS, local east/north of the first fix",
                    "time s; x (east), y (north) m", 1.0, 2, "bokeh-sampledata", "bokeh_sampledata",
                    ("_data/cycling.csv.gz",)),
    )
}


def dataset_path(name: str, index: int = 0) -> Path:
    """Path of the `index`-th file of a data set inside its installed package.

    Raises
    ------
    ValueError
        Unknown name.
    ImportError
        The package is not installed (message says what to ``pip install``).
    FileNotFoundError
        The package is installed but does not hold the file.
    """
    info = _info(name)
    try:
        module = importlib.import_module(info.module)
    except ImportError as exc:
        raise ImportError(f"Data set {name!r} needs the {info.package!r} package: {_EXTRA} "
                          f"(or pip install {info.package})") from exc
    path = Path(str(resources.files(module))) / info.files[index]
    if not path.is_file():
        version = getattr(module, "__version__", "?")
        raise FileNotFoundError(f"Data set {name!r}: {info.package} {version} installed, but it has no "
                                f"{path}; {_EXTRA} to get a version that ships it")
    return path


def load_dataset(name: str) -> pd.DataFrame:
    """Load a shipped recording as a track table.

    Parameters
    ----------
    name : str
        One of :data:`DATASETS` (``'hawkeye_ball'``, ``'skillcorner'``,
        ``'cycling'``); units and conversions are described in the module
        docstring.

    Returns
    -------
    pandas.DataFrame
        Columns ``track_id`` (str), ``time`` (s), ``x``, ``y`` [, ``z``] (m),
        sorted by ``(track_id, time)``. A fresh copy on each call.
    """
    return _load(_info(name).name).copy()


def _info(name: str) -> DatasetInfo:
    if name not in DATASETS:
        raise ValueError(f"Unknown data set {name!r}; expected one of {sorted(DATASETS)}")
    return DATASETS[name]


@functools.lru_cache(maxsize=None)
def _load(name: str) -> pd.DataFrame:
    df = {"hawkeye_ball": _hawkeye, "skillcorner": _skillcorner, "cycling": _cycling}[name]()
    return df.sort_values(["track_id", "time"], kind="stable").reset_index(drop=True)


def semicircles_to_degrees(semicircles) -> np.ndarray:
    """Garmin semicircles to degrees: ``deg = semicircles * 180 / 2**31``."""
    return np.asarray(semicircles, dtype=np.float64) * (180.0 / 2**31)


def degrees_to_local_metres(lat_deg, lon_deg, lat0: float | None = None,
                            lon0: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Latitude/longitude (degrees) to metres east and north of a reference fix.

    Equirectangular approximation around ``(lat0, lon0)`` (default the first
    fix): ``east = R cos(lat0) (lon - lon0)``, ``north = R (lat - lat0)`` with
    angles in radians and ``R`` the mean Earth radius; fine for tracks of tens
    of kilometres away from the poles.
    """
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    lat0 = lat.flat[0] if lat0 is None else np.radians(lat0)
    lon0 = lon.flat[0] if lon0 is None else np.radians(lon0)
    dlon = (lon - lon0 + np.pi) % (2 * np.pi) - np.pi
    return EARTH_RADIUS_M * np.cos(lat0) * dlon, EARTH_RADIUS_M * (lat - lat0)


def _hawkeye() -> pd.DataFrame:
    parts = []
    for i in range(len(DATASETS["hawkeye_ball"].files)):
        raw = json.loads(dataset_path("hawkeye_ball", i).read_text())
        samples = raw["samples"]["ball"]
        pos = np.array([s["pos"] for s in samples], dtype=np.float64)
        seq = raw.get("sequences", {})
        parts.append(pd.DataFrame({
            "track_id": f"ball_period{seq.get('segment', i + 1)}_minute{seq.get('match-minute', '?')}",
            "time": np.array([s["time"] for s in samples], dtype=np.float64),
            "x": pos[:, 0], "y": pos[:, 1], "z": pos[:, 2]}))
    return pd.concat(parts, ignore_index=True)


def _skillcorner() -> pd.DataFrame:
    frames = json.loads(dataset_path("skillcorner", 0).read_text())
    match = json.loads(dataset_path("skillcorner", 1).read_text())
    teams = {match[k]["id"]: match[k]["acronym"] for k in ("home_team", "away_team")}
    names = {p["trackable_object"]: f"{teams.get(p['team_id'], p['team_id'])}_{p['number']}_{p['last_name']}"
             for p in match["players"]}
    names[match["ball"]["trackable_object"]] = "ball"
    rows = [(f["frame"], f["period"], o["trackable_object"], o["x"], o["y"])
            for f in frames if f["period"] is not None for o in f["data"]
            if o.get("trackable_object") in names]
    det = pd.DataFrame(rows, columns=["frame", "period", "object", "x", "y"])
    det = det.drop_duplicates(["object", "frame"], keep="last").sort_values(["object", "frame"])
    # a dropout of up to _SKILLCORNER_FILL frames becomes NaN rows; a longer absence leaves no rows
    step = det.groupby(["object", "period"])["frame"].diff().to_numpy()
    fill = (step >= 2) & (step <= _SKILLCORNER_FILL + 1)
    n = step[fill].astype(np.int64) - 1
    end = det["frame"].to_numpy()[fill]
    within = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)  # 0..n-1 inside each hole
    holes = pd.DataFrame({"object": np.repeat(det["object"].to_numpy()[fill], n),
                          "frame": np.repeat(end - n, n) + within})
    df = pd.concat([det[["object", "frame", "x", "y"]], holes], ignore_index=True)
    return pd.DataFrame({"track_id": df["object"].map(names).astype(str),
                         "time": df["frame"].to_numpy(np.float64) / DATASETS["skillcorner"].rate_hz,
                         "x": df["x"].astype(np.float64), "y": df["y"].astype(np.float64)})


def _cycling() -> pd.DataFrame:
    raw = pd.read_csv(dataset_path("cycling"), usecols=["position_lat", "position_long"])
    x, y = degrees_to_local_metres(semicircles_to_degrees(raw["position_lat"]),
                                   semicircles_to_degrees(raw["position_long"]))
    return pd.DataFrame({"track_id": "ride", "time": np.arange(len(raw), dtype=np.float64), "x": x, "y": y})
