import warnings

import numpy as np
import pandas as pd
import pytest

from kalmix.io import DATASETS, load_dataset, read_tracks, split_on_gaps, to_arrays
from kalmix.io.datasets import dataset_path, degrees_to_local_metres, semicircles_to_degrees

# name -> (position columns, tracks, (min rows, max rows), min finite fraction)
EXPECTED = {
    "hawkeye_ball": (["x", "y", "z"], 2, (5000, 7000), 1.0),
    "skillcorner": (["x", "y"], 29, (400_000, 600_000), 0.95),
    "cycling": (["x", "y"], 1, (4000, 5000), 1.0),
}


def available(name):
    try:
        for i in range(len(DATASETS[name].files)):
            dataset_path(name, i)
    except (ImportError, FileNotFoundError) as exc:
        return pytest.param(name, marks=pytest.mark.skip(reason=str(exc)))
    return name


ALL = [available(name) for name in DATASETS]


def speeds(df):
    """Frame-to-frame speeds between consecutive finite samples one period apart, per track."""
    pos = [c for c in df.columns if c not in ("track_id", "time")]
    groups = df.groupby("track_id", sort=False)
    step = np.sqrt((groups[pos].diff() ** 2).sum(axis=1, min_count=len(pos)))
    dt = groups["time"].diff()
    period = dt.median()
    ok = np.isfinite(step) & (dt < 1.5 * period)
    return (step / dt)[ok], df["track_id"][ok]


def test_registry_describes_each_dataset():
    assert set(DATASETS) == set(EXPECTED)
    for name, info in DATASETS.items():
        assert info.name == name and info.rate_hz > 0 and info.dims == len(EXPECTED[name][0])
        assert "m" in info.units and info.package and info.files


@pytest.mark.parametrize("name", ALL)
def test_shape_and_finite_fraction(name):
    pos, n_tracks, (lo, hi), finite = EXPECTED[name]
    df = load_dataset(name)
    assert list(df.columns) == ["track_id", "time", *pos]
    assert df["track_id"].nunique() == n_tracks and lo <= len(df) <= hi
    assert np.isfinite(df[pos].to_numpy()).all(axis=1).mean() >= finite
    assert np.isfinite(df["time"]).all()
    # sorted, no repeated time within a track, sampled at the stated rate
    assert not df.duplicated(["track_id", "time"]).any()
    dt = df.groupby("track_id")["time"].diff().dropna()
    assert (dt > 0).all()
    assert dt.median() == pytest.approx(1 / DATASETS[name].rate_hz, rel=1e-3)


@pytest.mark.parametrize("name", ALL)
def test_speeds_plausible(name):
    v, ids = speeds(load_dataset(name))
    if name == "hawkeye_ball":
        assert v.max() < 50
    elif name == "cycling":
        assert v.max() < 25 and v.median() > 3  # a ride, not a walk
    else:  # broadcast tracking has rare identity switches: bound the 99th percentile
        ball = ids == "ball"
        assert np.percentile(v[ball], 99) < 50
        assert np.percentile(v[~ball], 99) < 12
        assert (v[~ball] > 12).mean() < 0.01


@pytest.mark.parametrize("name", ALL)
@pytest.mark.parametrize("ext", ["csv", "parquet"])
def test_roundtrip_through_read_tracks(tmp_path, name, ext):
    df = load_dataset(name)
    path = tmp_path / f"{name}.{ext}"
    df.to_csv(path, index=False) if ext == "csv" else df.to_parquet(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # already canonical: nothing to sort or drop
        back = read_tracks(path)
    pd.testing.assert_frame_equal(back, df, check_dtype=False, check_exact=False, rtol=1e-12)


def need(name):
    if not isinstance(available(name), str):
        pytest.skip(f"{DATASETS[name].package} not installed")


def test_load_returns_fresh_copy():
    need("cycling")
    a = load_dataset("cycling")
    a["x"] = 0.0
    assert load_dataset("cycling")["x"].abs().max() > 0


def test_unknown_name():
    with pytest.raises(ValueError, match=r"Unknown data set 'nope'; expected one of \['cycling', 'hawkeye"):
        load_dataset("nope")


def test_missing_package_says_what_to_install(monkeypatch):
    import importlib

    real = importlib.import_module

    def fake(name, *args, **kwargs):
        if name == "kloppy":
            raise ModuleNotFoundError("No module named 'kloppy'")
        return real(name, *args, **kwargs)

    monkeypatch.setattr(importlib, "import_module", fake)
    with pytest.raises(ImportError, match=r"needs the 'kloppy' package: pip install 'kalmix\[data\]'"):
        dataset_path("skillcorner")


def test_missing_file_is_file_not_found(monkeypatch):
    from kalmix.io import datasets

    info = datasets.DATASETS["cycling"]
    monkeypatch.setitem(datasets.DATASETS, "cycling",
                        datasets.DatasetInfo(**{**info.__dict__, "module": "json", "files": ("nope.csv",)}))
    with pytest.raises(FileNotFoundError, match=r"has no .*nope.csv; pip install 'kalmix\[data\]'"):
        dataset_path("cycling")


def test_unit_conversions():
    assert semicircles_to_degrees(2**31) == pytest.approx(180.0)
    assert semicircles_to_degrees(-(2**30)) == pytest.approx(-90.0)
    east, north = degrees_to_local_metres([45.0, 45.0, 45.001], [7.0, 7.001, 7.0])
    assert north[2] == pytest.approx(111.195, rel=1e-4) and east[2] == 0
    assert east[1] == pytest.approx(111.195 * np.cos(np.radians(45)), rel=1e-4) and north[1] == 0


def test_skillcorner_gaps_become_segments():
    need("skillcorner")
    df = load_dataset("skillcorner")
    seg = split_on_gaps(df["time"], track_ids=df["track_id"])
    # halftime and long out-of-shot spells start segments; short dropouts are NaN rows
    assert seg[df["track_id"].to_numpy() == "ball"].max() > 1
    arrays = to_arrays(df[df["track_id"].isin(["ball", "BMU_25_Müller"])])
    assert arrays.values.shape[1:] == (2, 2)
    assert arrays.lengths.sum() == np.isfinite(arrays.times).sum()
