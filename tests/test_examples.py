"""Every script in examples/ runs, in a fresh process and an empty working directory, and prints what it should.

The documentation includes these scripts as they are (pymdownx.snippets), so a script that breaks or
whose output drifts from what the pages say fails here. Each script has its own check below; a new
script without one fails ``test_every_example_is_checked``.
"""

import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
SCRIPTS = sorted(p.name for p in EXAMPLES.glob("*.py"))


def run_example(name: str, cwd: Path) -> str:
    import kalmix

    env = dict(os.environ)
    # the kalmix this test imports, also in the child (an installed copy or the source tree)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(Path(kalmix.__file__).resolve().parents[1]),
                                                      env.get("PYTHONPATH")]))
    env.setdefault("MPLBACKEND", "Agg")
    done = subprocess.run([sys.executable, str(EXAMPLES / name)], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=900)   # a fresh install compiles the kernels first (tens of seconds)
    assert done.returncode == 0, f"{name} exited with {done.returncode}:\n{done.stdout}\n{done.stderr}"
    return done.stdout


def number(pattern: str, text: str) -> float:
    found = re.search(pattern, text)
    assert found, f"expected a line matching {pattern!r} in:\n{text}"
    value = float(found.group(1))
    assert math.isfinite(value), f"{pattern!r}: {value}"
    return value


def vector(pattern: str, text: str) -> np.ndarray:
    found = re.search(pattern, text)
    assert found, f"expected a line matching {pattern!r} in:\n{text}"
    values = np.array([float(v) for v in found.group(1).split()])
    assert np.isfinite(values).all(), values
    return values


def check_quickstart(out: str, cwd: Path) -> None:
    lines = out.strip().splitlines()
    assert lines[0].split() == ["track_id", "time", "segment", "pred_x", "pred_y", "std_x", "std_y"]
    rows = [line.split() for line in lines[1:]]
    assert len(rows) == 5
    for index, track, time, segment, *numbers in rows:
        assert track == "boat" and segment == "0"
        pred_x, pred_y, std_x, std_y = map(float, numbers)
        assert std_x > 0 and std_y > 0
        # the forecast for the next row (0.1 s later) lies near the boat's circle of radius 20 m
        t = float(time) + 0.1
        assert math.hypot(pred_x - 20 * math.cos(t / 20), pred_y - 20 * math.sin(t / 20)) < 1.0


def check_live_feed(out: str, cwd: Path) -> None:
    nxt = vector(r"boat at the next frame: \[([^\]]*)\]", out)
    true_next = vector(r"boat at the next frame: .*true: \[([^\]]*)\]", out)
    assert np.abs(nxt - true_next).max() < 0.3   # measured to 5 cm
    ahead = vector(r"boat 1 s ahead: \[([^\]]*)\]", out)
    true_ahead = vector(r"boat 1 s ahead: .*true: \[([^\]]*)\]", out)
    assert np.abs(ahead - true_ahead).max() < 2.0   # a boat at 6 m/s on a 30 m circle, 1 s on
    assert 0 < number(r"1 s forecasts, rows 50-149: ([\d.]+) m", out) < 1.0
    assert 85.0 <= number(r"inside their 95 % intervals: ([\d.]+)%", out) <= 100.0
    assert "tracks: ['boat', 'buoy'] rows: 301" in out


def check_save_resume(out: str, cwd: Path) -> None:
    assert "resumed predictions identical to an uninterrupted run: True" in out
    assert "rows after the resume: 600" in out
    assert "length unit 0.02 lead 0.5 time unit 0.1" in out
    vector(r"after a missing row at 40.0 s: \[([^\]]*)\]", out)
    assert (cwd / "tracks.npz").is_file()


def check_paper_mixture(out: str, cwd: Path) -> None:
    ahead = vector(r"3 frames ahead: \[([^\]]*)\]", out)
    truth = vector(r"3 frames ahead: .*true: \[([^\]]*)\]", out)
    assert np.abs(ahead - truth).max() < 2.0   # pixels, noise 0.5
    weights = vector(r"gating weights g_i \(eq. 8\): \[([^\]]*)\]", out)
    assert (weights >= 0).all() and weights.sum() <= 1.0 + 1e-9 and np.all(np.diff(weights) <= 0)
    assert 0.5 <= number(r"one-step RMS error \(px\): ([\d.]+)", out) < 1.0   # at least the noise, 0.5
    assert "predictions (300, 50, 2)" in out
    assert 0.5 <= number(r"50 streams: .* one-step RMS \(px\): ([\d.]+)", out) < 1.0
    assert (cwd / "predictor.npz").is_file()


def check_many_tracks(out: str, cwd: Path) -> None:
    assert re.search(r"^300 tracks, \d+ rows, 30 restarts at time gaps", out, re.M)
    assert 2.0 < number(r"length unit ([\d.]+) m", out) < 4.5   # the simulated noise: 3 m
    one_step = number(r"one-step RMS ([\d.]+) m", out)
    assert 3.0 <= one_step < 0.8 * number(r"one-step RMS [\d.]+ m \(holding the last position: ([\d.]+) m\)", out)
    assert 90.0 <= number(r"inside the 95 % intervals: ([\d.]+)%", out) <= 99.0
    ahead = number(r"10 s ahead RMS ([\d.]+) m", out)
    assert ahead < 0.5 * number(r"10 s ahead RMS [\d.]+ m \(holding the last position: ([\d.]+) m\)", out)
    header = out.strip().splitlines()[-4].split()
    assert header == ["track_id", "time", "segment", "pred_east", "pred_north", "std_east", "std_north",
                      "pred10_east", "pred10_north", "std10_east", "std10_north"]
    assert (cwd / "tracks.csv").is_file()


def check_functional_core(out: str, cwd: Path) -> None:
    assert "predictions: (97, 1000, 3) weights: (1000, 40)" in out
    assert 0.9 <= number(r"one-step RMS error over frames 51-99: ([\d.]+)", out) < 1.5   # noise 1 per coordinate


def check_dask_archive(out: str, cwd: Path) -> None:
    assert "parquet archive: 600 predictions" in out
    assert "'pred10_x', 'pred10_y', 'std10_x', 'std10_y']" in out
    assert "the same numbers as one machine: True" in out
    assert sorted(p.name for p in (cwd / "predictions").iterdir())   # the partitioned output dataset


CHECKS = {
    "quickstart.py": check_quickstart,
    "live_feed.py": check_live_feed,
    "save_resume.py": check_save_resume,
    "paper_mixture.py": check_paper_mixture,
    "many_tracks.py": check_many_tracks,
    "functional_core.py": check_functional_core,
    "dask_archive.py": check_dask_archive,
}
#: examples that need an optional extra: the module to find first
REQUIRES = {"dask_archive.py": "dask.dataframe"}


def test_every_example_is_checked():
    assert set(SCRIPTS) == set(CHECKS), "give every examples/*.py a check in CHECKS (and every check a script)"


def test_quickstart_is_short():
    """The README shows the quick start whole."""
    assert len((EXAMPLES / "quickstart.py").read_text().splitlines()) <= 15


@pytest.mark.parametrize("name", SCRIPTS)
def test_example_runs(name, tmp_path):
    if name in REQUIRES:
        pytest.importorskip(REQUIRES[name])
    before = sorted(p.name for p in EXAMPLES.iterdir())
    out = run_example(name, tmp_path)
    CHECKS[name](out, tmp_path)
    assert sorted(p.name for p in EXAMPLES.iterdir()) == before, "an example wrote into examples/"
