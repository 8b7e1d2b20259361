"""A model zoo: kalmix against the optimal one-step predictor on tracks drawn from known models.

Run: python -m benchmarks.model_zoo [--json FILE] [--quick] [--scenario NAME ...]

Every scenario draws seeded 2-D tracks from a known linear-Gaussian model (the true parameters are in the JSON)
and scores, on the same rows, the one-step forecast of

- the **optimum**: the Kalman filter with the true model, noises, time steps and prior (the tracks' initial
  state is drawn from that prior), so its forecast is the conditional mean: no predictor does better in mean
  square. For the switching scenario (Markov switching between constant velocity and coordinated turns) the
  reference is an IMM with the true models and switching probabilities, which is **near-optimal, not optimal**
  (the exact filter needs a Gaussian per mode history);
- **kalmix** as a user runs it: ``kalmix predict`` on a CSV of the tracks written to a temporary directory, with
  its defaults (automatic length and time units, the gap rule, the default bank, the population prior), in a
  subprocess; and the same with ``--max-gap none``, and with ``--no-population-prior`` (every track starts empty);
- **no prediction**: the last measurement, a floor every predictor should beat.

One-step RMS: of the Euclidean per-row distance between forecast and measurement, and per coordinate (the
former over sqrt(2)); the first 20 % of each track's rows are burn-in and not scored (the same rows for every
predictor). Also the coverage of kalmix's 95 % intervals (forecast +- 1.96 std, per coordinate) and of the
optimum's (from its innovation covariance: it should be 95 %). ``--quick``: fewer, shorter tracks.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.linalg import expm

#: Share of each track's rows not scored (burn-in).
BURN_IN = 0.2
Z95 = 1.959963984540054
ROOT = Path(__file__).resolve().parent.parent


# -- the models ---------------------------------------------------------------------------------------------------

def _axes(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One axis' continuous model (``a``, noise input ``b`` of unit spectral density) for x and y, independent."""
    return np.kron(np.eye(2), a), np.kron(np.eye(2), b @ b.T)


def kinematic(order: int, q: float, tau: float | None = None):
    """Continuous-time per-axis model, x and y stacked: ``order`` 0 random walk, 1 constant velocity (white
    acceleration of spectral density ``q``), 2 constant acceleration (white jerk), or with ``tau`` the Singer
    model (acceleration a first-order Gauss-Markov process of time constant ``tau``; ``q = 2 sigma_a^2 / tau``)."""
    n = order + 1
    a = np.eye(n, k=1)
    if tau is not None:
        a[-1, -1] = -1.0 / tau
    b = np.zeros((n, 1))
    b[-1, 0] = math.sqrt(q)
    A, Qc = _axes(a, b)
    H = np.zeros((2, 2 * n))
    H[0, 0] = H[1, n] = 1.0
    return A, Qc, H


def turn(omega: float, q: float):
    """Coordinated turn at the known rate ``omega`` (rad/s; 0: constant velocity), state ``[x, vx, y, vy]``,
    white acceleration of spectral density ``q`` on each axis."""
    A = np.zeros((4, 4))
    A[0, 1] = A[2, 3] = 1.0
    A[1, 3], A[3, 1] = -omega, omega
    Qc = np.diag([0.0, q, 0.0, q])
    H = np.zeros((2, 4))
    H[0, 0] = H[1, 2] = 1.0
    return A, Qc, H


def discretize(A: np.ndarray, Qc: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``F = exp(A dt)`` and ``Q = int_0^dt exp(A s) Qc exp(A s)' ds`` (Van Loan). Exact for the nilpotent models
    at any step; for the Singer and turn models accurate while ``exp(dt / tau)`` stays far from overflow (their
    scenarios step 1 s)."""
    n = len(A)
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n], M[:n, n:], M[n:, n:] = -A, Qc, A.T
    E = _exp(M * dt)
    F = E[n:, n:].T
    Q = F @ E[:n, n:]
    return F, (Q + Q.T) / 2


def _exp(M: np.ndarray) -> np.ndarray:
    """``exp(M)``: the finite series where ``M`` is nilpotent (the random walk, CV and CA models: exact, and
    much quicker than :func:`scipy.linalg.expm` for the thousands of distinct steps of irregular sampling)."""
    term, total = np.eye(len(M)), np.eye(len(M))
    for k in range(1, len(M) + 1):
        term = term @ M / k
        if not term.any():
            return total
        total = total + term
    return expm(M)


class Transitions:
    """``discretize`` with a cache per step (regular sampling repeats it)."""

    def __init__(self, A, Qc):
        self.A, self.Qc, self.cache = A, Qc, {}

    def __call__(self, dt: float):
        key = float(dt)
        if key not in self.cache:
            if len(self.cache) > 100_000:
                self.cache.clear()
            self.cache[key] = discretize(self.A, self.Qc, key)
        return self.cache[key]


# -- the scenarios ------------------------------------------------------------------------------------------------

@dataclass
class Scenario:
    """Seeded tracks of one known model: ``steps(rng, rows)`` gives a track's time steps; one model, or several
    with a Markov switching matrix (``switch``, rows: from, columns: to)."""

    name: str
    label: str
    about: str
    models: list                  # (A, Qc, H) per mode
    r: float                      # measurement noise std per coordinate
    prior_mean: np.ndarray
    prior_std: np.ndarray
    steps: object                 # (rng, rows) -> time steps, shape (rows - 1,)
    parameters: dict
    switch: np.ndarray | None = None
    outage: float | None = None   # a silence of this many seconds after the middle row
    integer_times: bool = False
    unit: str = "m"
    tracks: int = 20
    rows: int = 400
    seed: int = 0
    modes: list = field(default_factory=list)

    @property
    def reference(self) -> str:
        return "IMM with the true parameters (near-optimal)" if self.switch is not None else \
            "Kalman filter with the true model (optimal)"


def _regular(dt):
    return lambda rng, rows: np.full(rows - 1, dt)


def _uniform(low, high):
    return lambda rng, rows: rng.uniform(low, high, rows - 1)


def _log_uniform(low, high):
    return lambda rng, rows: np.exp(rng.uniform(math.log(low), math.log(high), rows - 1))


def _dropped(frame, kept):
    """Frames of ``frame`` s each kept with probability ``kept``: steps of a geometric number of frames."""
    return lambda rng, rows: frame * rng.geometric(kept, rows - 1).astype(float)


def scenarios() -> dict[str, Scenario]:
    out = {}

    def add(s):
        out[s.name] = s

    # constant velocity, 10 Hz: a pedestrian or a slow vehicle seen by a tracker
    q, r = 0.5, 0.2
    add(Scenario("cv_10hz", "constant velocity, 10 Hz",
                 f"constant velocity (white acceleration, q = {q} m²/s³), 0.1 s steps, {r} m noise",
                 [kinematic(1, q)], r, np.zeros(4), np.array([10.0, 2.0, 10.0, 2.0]), _regular(0.1),
                 {"model": "constant velocity", "q_m2_per_s3": q, "measurement_std_m": r, "dt_s": 0.1}, seed=1))
    # constant acceleration, 10 Hz
    q, r = 2.0, 0.2
    add(Scenario("ca_10hz", "constant acceleration, 10 Hz",
                 f"constant acceleration (white jerk, q = {q} m²/s⁵), 0.1 s steps, {r} m noise",
                 [kinematic(2, q)], r, np.zeros(6), np.array([10.0, 2.0, 1.0, 10.0, 2.0, 1.0]), _regular(0.1),
                 {"model": "constant acceleration", "q_m2_per_s5": q, "measurement_std_m": r, "dt_s": 0.1}, seed=2))
    # Singer manoeuvres, 1 Hz
    tau, sigma_a, r = 10.0, 1.0, 3.0
    add(Scenario("singer_1hz", "Singer manoeuvres, 1 Hz",
                 f"Singer acceleration (time constant {tau:g} s, {sigma_a:g} m/s² rms), 1 s steps, {r:g} m noise",
                 [kinematic(2, 2 * sigma_a ** 2 / tau, tau=tau)], r, np.zeros(6),
                 np.array([100.0, 10.0, sigma_a, 100.0, 10.0, sigma_a]), _regular(1.0),
                 {"model": "Singer", "tau_s": tau, "sigma_a_m_per_s2": sigma_a, "q_m2_per_s5": 2 * sigma_a ** 2 / tau,
                  "measurement_std_m": r, "dt_s": 1.0}, seed=3))
    # random walk on integer frames (pixels)
    q, r = 4.0, 2.0
    add(Scenario("random_walk_frames", "random walk, integer frames",
                 f"random walk ({q:g} px² per frame), integer frame numbers as time, {r:g} px noise",
                 [kinematic(0, q)], r, np.zeros(2), np.array([100.0, 100.0]), _regular(1.0),
                 {"model": "random walk", "q_px2_per_frame": q, "measurement_std_px": r, "dt_frames": 1},
                 integer_times=True, unit="px", seed=4))
    # constant velocity sampled at irregular intervals (a vessel's AIS); 100 tracks: the default gap rule's reference
    # interval is each track's median of its first 16 steps, so a few tracks in a hundred split often
    q, r = 1e-4, 10.0
    add(Scenario("cv_irregular", "constant velocity, steps 5-60 s",
                 f"constant velocity (q = {q:g} m²/s³), steps uniform in 5-60 s, {r:g} m noise",
                 [kinematic(1, q)], r, np.zeros(4), np.array([100.0, 5.0, 100.0, 5.0]), _uniform(5.0, 60.0),
                 {"model": "constant velocity", "q_m2_per_s3": q, "measurement_std_m": r,
                  "dt_s": "uniform in [5, 60]"}, tracks=100, seed=5))
    # the same vessel model reporting at random intervals spread over a factor of 60 (log-uniform 10 s to 10 min):
    # the long steps are the sampling, not gaps
    add(Scenario("cv_log_uniform", "constant velocity, steps 10 s-10 min",
                 f"constant velocity (q = {q:g} m²/s³), steps log-uniform in 10 s-10 min, {r:g} m noise",
                 [kinematic(1, q)], r, np.zeros(4), np.array([100.0, 5.0, 100.0, 5.0]), _log_uniform(10.0, 600.0),
                 {"model": "constant velocity", "q_m2_per_s3": q, "measurement_std_m": r,
                  "dt_s": "log-uniform in [10, 600]"}, tracks=40, seed=11))
    # the same vessel model, regular 10 s reports, silent for 3 days in the middle of each track
    outage = 3 * 86400.0
    add(Scenario("cv_outage", "constant velocity, a 3-day silence",
                 f"constant velocity (q = {q:g} m²/s³), 10 s steps, {r:g} m noise, no report for 3 days after "
                 "the middle row", [kinematic(1, q)], r, np.zeros(4), np.array([100.0, 5.0, 100.0, 5.0]),
                 _regular(10.0),
                 {"model": "constant velocity", "q_m2_per_s3": q, "measurement_std_m": r, "dt_s": 10.0,
                  "outage_s": outage}, outage=outage, seed=6))
    # many short tracks: vessels seen for a dozen reports each, 10-60 min apart (a day of a coastal AIS feed); the
    # optimum knows the population's speeds (its prior), which a track of 12 rows cannot learn alone
    q, r = 1e-6, 10.0
    add(Scenario("short_tracks", "400 tracks of 12 rows, steps 10-60 min",
                 f"constant velocity (q = {q:g} m²/s³), steps uniform in 10-60 min, {r:g} m noise, 12 rows per "
                 "track", [kinematic(1, q)], r, np.zeros(4), np.array([1000.0, 5.0, 1000.0, 5.0]),
                 _uniform(600.0, 3600.0),
                 {"model": "constant velocity", "q_m2_per_s3": q, "measurement_std_m": r,
                  "dt_s": "uniform in [600, 3600]", "rows_per_track": 12}, tracks=400, rows=12, seed=8))
    # Markov switching between constant velocity and coordinated turns left and right, 1 Hz
    omega, q, r, stay = 0.1, 0.05, 3.0, 0.95
    switch = np.array([[stay, (1 - stay) / 2, (1 - stay) / 2], [1 - stay, stay, 0.0], [1 - stay, 0.0, stay]])
    add(Scenario("switching_turn", "switching CV / coordinated turn, 1 Hz",
                 f"Markov switching between constant velocity and turns at ±{omega:g} rad/s (each held "
                 f"{1 / (1 - stay):g} s on average), q = {q:g} m²/s³, 1 s steps, {r:g} m noise",
                 [turn(0.0, q), turn(omega, q), turn(-omega, q)], r, np.zeros(4),
                 np.array([100.0, 10.0, 100.0, 10.0]), _regular(1.0),
                 {"model": "Markov switching: constant velocity, coordinated turn +omega, -omega",
                  "omega_rad_per_s": omega, "q_m2_per_s3": q, "measurement_std_m": r, "dt_s": 1.0,
                  "switch_matrix": switch.tolist(), "mode_order": ["CV", "turn +omega", "turn -omega"]},
                 switch=switch, seed=7))
    # constant acceleration at 10 Hz with 60 % of the frames dropped at random (a detector that misses): the long
    # steps are a few frames, where the acceleration experts still extrapolate well
    q_ca, r_ca = 2.0, 0.2   # (ca_10hz's)
    add(Scenario("ca_dropped_frames", "constant acceleration, 60 % of frames dropped",
                 f"constant acceleration (white jerk, q = {q_ca} m²/s⁵), 0.1 s frames each kept with probability 0.4, "
                 f"{r_ca} m noise", [kinematic(2, q_ca)], r_ca, np.zeros(6), np.array([10.0, 2.0, 1.0, 10.0, 2.0, 1.0]),
                 _dropped(0.1, 0.4),
                 {"model": "constant acceleration", "q_m2_per_s5": q_ca, "measurement_std_m": r_ca, "frame_s": 0.1,
                  "frame_kept": 0.4}, seed=12))
    # the same constant acceleration reported at heavy-tailed intervals (log-uniform 0.02-2 s): the automatic reach
    # (only the constant-velocity experts across a step over 1.5 time units) suits vessels, not this
    add(Scenario("ca_log_uniform", "constant acceleration, steps 0.02-2 s",
                 f"constant acceleration (white jerk, q = {q_ca} m²/s⁵), steps log-uniform in 0.02-2 s, {r_ca} m "
                 "noise", [kinematic(2, q_ca)], r_ca, np.zeros(6), np.array([10.0, 2.0, 1.0, 10.0, 2.0, 1.0]),
                 _log_uniform(0.02, 2.0),
                 {"model": "constant acceleration", "q_m2_per_s5": q_ca, "measurement_std_m": r_ca,
                  "dt_s": "log-uniform in [0.02, 2]"}, seed=13))
    return out


def simulate(s: Scenario, transitions=None):
    """The scenario's tracks: a table (``track_id, time, x, y``), and per track its times and measurements.
    ``transitions``: a :class:`Transitions` per mode (made here if not given)."""
    rng = np.random.default_rng(s.seed)
    transitions = transitions or [Transitions(A, Qc) for A, Qc, _ in s.models]
    H = s.models[0][2]
    frames, tracks = [], []
    for k in range(s.tracks):
        dt = np.asarray(s.steps(rng, s.rows), dtype=np.float64)
        if s.outage is not None:
            dt[s.rows // 2 - 1] = s.outage
        t = np.concatenate([[0.0], np.cumsum(dt)]) + (rng.integers(0, 1000) if s.integer_times else
                                                       rng.uniform(0, 100))
        x = s.prior_mean + s.prior_std * rng.standard_normal(len(s.prior_mean))
        mode = 0
        z = np.empty((s.rows, 2))
        for i in range(s.rows):
            if i:
                if s.switch is not None:
                    mode = rng.choice(len(s.models), p=s.switch[mode])
                F, Q = transitions[mode](dt[i - 1])
                x = F @ x + rng.multivariate_normal(np.zeros(len(x)), Q, method="cholesky")
            z[i] = H @ x + s.r * rng.standard_normal(2)
        tracks.append((t, z))
        frames.append(pd.DataFrame({"track_id": f"t{k:03d}", "time": t.astype(np.int64) if s.integer_times else t,
                                    "x": z[:, 0], "y": z[:, 1]}))
    return pd.concat(frames, ignore_index=True), tracks


# -- the reference filters --------------------------------------------------------------------------------------

def kalman_one_step(t, z, model, r, prior_mean, prior_std, transitions=None):
    """One-step forecasts of the Kalman filter with the true model: ``pred[i]`` (and its innovation covariance
    ``S[i]``) forecasts ``z[i]`` from ``z[:i]``; NaN for the first row."""
    return kalman_forecasts(t, z, model, r, prior_mean, prior_std, transitions)[1]


def kalman_forecasts(t, z, model, r, prior_mean, prior_std, transitions=None, horizons=(1,)):
    """The Kalman filter with the true model, ``h`` rows ahead for each ``h`` of ``horizons``: ``{h: (pred, S)}``,
    ``pred[i]`` (and the covariance ``S[i]`` of ``z[i] - pred[i]``) forecasting ``z[i]`` from ``z[:i - h + 1]``:
    the filtered state after row ``i - h`` propagated to ``t[i]``, the conditional mean of ``z[i]`` for these
    linear-Gaussian models; NaN for the first ``h`` rows."""
    A, Qc, H = model
    transitions = transitions or Transitions(A, Qc)
    R = r ** 2 * np.eye(2)
    x, P = prior_mean.astype(np.float64), np.diag(prior_std ** 2)
    pred, S_all = np.full(z.shape, np.nan), np.full((len(z), 2, 2), np.nan)
    later = {h: (np.full(z.shape, np.nan), np.full((len(z), 2, 2), np.nan)) for h in horizons if h > 1}
    I = np.eye(len(x))
    for i in range(len(z)):
        if i:
            F, Q = transitions(t[i] - t[i - 1])
            x, P = F @ x, F @ P @ F.T + Q
            pred[i] = H @ x
        S = H @ P @ H.T + R
        if i:
            S_all[i] = S
        K = np.linalg.solve(S, H @ P).T
        x = x + K @ (z[i] - H @ x)
        IKH = I - K @ H
        P = IKH @ P @ IKH.T + K @ R @ K.T   # Joseph form: stays symmetric and positive after a long silence
        for h, (pred_h, S_h) in later.items():
            if i + h < len(z):
                F, Q = transitions(t[i + h] - t[i])
                pred_h[i + h] = H @ F @ x
                S_h[i + h] = H @ (F @ P @ F.T + Q) @ H.T + R
    return {h: (pred, S_all) if h == 1 else later[h] for h in horizons}


def imm_one_step(t, z, models, switch, r, prior_mean, prior_std, transitions=None):
    """One-step forecasts of an interacting-multiple-model filter with the true models and switching matrix
    (Blom and Bar-Shalom): the mixture of the modes' forecasts under the predicted mode probabilities."""
    transitions = transitions or [Transitions(A, Qc) for A, Qc, _ in models]
    H = models[0][2]
    R = r ** 2 * np.eye(2)
    m = len(models)
    mu = np.full(m, 1.0 / m)
    xs = [prior_mean.astype(np.float64).copy() for _ in range(m)]
    Ps = [np.diag(prior_std ** 2) for _ in range(m)]
    pred, S_all = np.full(z.shape, np.nan), np.full((len(z), 2, 2), np.nan)
    for i in range(len(z)):
        if i:
            c = switch.T @ mu                                   # predicted mode probabilities
            w = switch * mu[:, None] / np.maximum(c, 1e-300)    # w[a, b] = P(mode a before | mode b now)
            mixed = []
            for b in range(m):
                x0 = sum(w[a, b] * xs[a] for a in range(m))
                P0 = sum(w[a, b] * (Ps[a] + np.outer(xs[a] - x0, xs[a] - x0)) for a in range(m))
                mixed.append((x0, P0))
            xs, Ps = [], []
            for b, (x0, P0) in enumerate(mixed):
                F, Q = transitions[b](t[i] - t[i - 1])
                xs.append(F @ x0)
                Ps.append(F @ P0 @ F.T + Q)
            zs = [H @ x for x in xs]
            pred[i] = sum(c[b] * zs[b] for b in range(m))
            S_all[i] = sum(c[b] * (H @ Ps[b] @ H.T + R + np.outer(zs[b] - pred[i], zs[b] - pred[i]))
                           for b in range(m))
            mu = c
        likelihood = np.empty(m)
        for b in range(m):
            S = H @ Ps[b] @ H.T + R
            nu = z[i] - H @ xs[b]
            K = np.linalg.solve(S, H @ Ps[b]).T
            xs[b] = xs[b] + K @ nu
            IKH = np.eye(len(xs[b])) - K @ H
            Ps[b] = IKH @ Ps[b] @ IKH.T + K @ R @ K.T
            likelihood[b] = math.exp(-0.5 * nu @ np.linalg.solve(S, nu)) / math.sqrt(np.linalg.det(2 * math.pi * S))
        mu = mu * likelihood
        mu = mu / mu.sum() if mu.sum() > 0 else np.full(m, 1.0 / m)
    return pred, S_all


def reference(s: Scenario, tracks, transitions=None):
    """The reference's one-step forecasts and innovation covariances, per track: the Kalman filter with the true
    model, or for a switching scenario the IMM with the true models."""
    transitions = transitions or [Transitions(A, Qc) for A, Qc, _ in s.models]
    if s.switch is not None:
        return [imm_one_step(t, z, s.models, s.switch, s.r, s.prior_mean, s.prior_std, transitions)
                for t, z in tracks]
    return [kalman_one_step(t, z, s.models[0], s.r, s.prior_mean, s.prior_std, transitions[0]) for t, z in tracks]


# -- kalmix, as `kalmix predict` runs ------------------------------------------------------------------------------

def kalmix_predict(table: pd.DataFrame, directory: Path, options=(), source: Path | None = None
                   ) -> tuple[pd.DataFrame, float, str]:
    """``kalmix predict`` (of the package under ``source``, default this checkout's ``src``) on ``table`` written
    as CSV, in a subprocess: its output, the seconds the process took, and what it said on stderr."""
    tracks = directory / "tracks.csv"
    if not tracks.exists():
        table.to_csv(tracks, index=False)
    target = directory / f"out{len(list(directory.glob('out*.csv')))}.csv"
    command = [sys.executable, "-m", "kalmix.cli", "predict", str(tracks), "-o", str(target), "--no-progress",
               *options]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(source or ROOT / "src")] + [p for p in [env.get("PYTHONPATH")] if p])
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, env=env)
    seconds = time.perf_counter() - start
    if done.returncode:
        raise RuntimeError(f"{' '.join(command)} failed ({done.returncode}): {done.stderr.strip()[-2000:]}")
    return pd.read_csv(target), seconds, done.stderr.strip()


def kalmix_one_step(out: pd.DataFrame, table: pd.DataFrame, tracks, horizon: int = 1):
    """Per track the forecasts of each row (the output row before it holds the forecast for its time) and their
    std, aligned with ``tracks``; NaN where kalmix gave none. ``horizon`` H > 1: the forecasts of ``--horizon H``
    (columns ``pred<H>_``, ``std<H>_`` of the output row H rows before, made for its time plus H time units: the
    row H steps later on a track sampled every time unit)."""
    if len(out) != len(table):
        raise RuntimeError(f"kalmix predict wrote {len(out)} rows for {len(table)} input rows")
    keys = table["track_id"].to_numpy()
    if not (out["track_id"].astype(str).to_numpy() == keys).all():
        raise RuntimeError("kalmix predict's output rows are not in the input's order")
    per, start = [], 0
    for t, z in tracks:
        part = out.iloc[start:start + len(z)]
        start += len(z)
        pred, std = np.full(z.shape, np.nan), np.full(z.shape, np.nan)
        name, h = ("", 1) if horizon == 1 else (str(horizon), horizon)
        pred[h:] = part[[f"pred{name}_x", f"pred{name}_y"]].to_numpy()[:-h]
        std[h:] = part[[f"std{name}_x", f"std{name}_y"]].to_numpy()[:-h]
        per.append((pred, std))
    return per


# -- scoring ----------------------------------------------------------------------------------------------------------

def _rms(errors: np.ndarray) -> dict:
    squared = np.sum(errors ** 2, axis=-1)
    euclid = float(np.sqrt(np.mean(squared))) if len(squared) else math.nan
    return {"rms_euclidean": euclid, "rms_per_coordinate": euclid / math.sqrt(2),
            "rms_x": float(np.sqrt(np.mean(errors[:, 0] ** 2))) if len(errors) else math.nan,
            "rms_y": float(np.sqrt(np.mean(errors[:, 1] ** 2))) if len(errors) else math.nan}


#: The groups of rows scored.
GROUPS = {"scored": f"every row after the first {100 * BURN_IN:g} % of its track; with a silence, all but the first "
                    "row after it",
          "after the silence": "the rows after the first row after the silence",
          "first row after the silence": "the first row after the silence, one per track"}


def score(s: Scenario, tracks, predictors: dict, stds: dict):
    """Every predictor's one-step RMS over the rows that all of them forecast, after the burn-in; for a scenario
    with a silence, also over parts of it. ``predictors``: name -> per track forecasts; ``stds``: name -> per
    track std per coordinate (for coverage)."""
    rows = []
    for k, (t, z) in enumerate(tracks):
        n = len(z)
        index = np.arange(n)
        part = np.full(n, "", dtype=object)
        part[index >= math.ceil(BURN_IN * n)] = "scored"
        if s.outage is not None:
            first = s.rows // 2
            part[first] = "first after the silence"
            part[(index > first) & (part == "scored")] = "after"
        rows.append(part)
    finite = [np.ones(len(z), bool) for _, z in tracks]
    for per in predictors.values():
        for k, pred in enumerate(per):
            finite[k] &= np.isfinite(pred).all(axis=1)
    counted = {name: sum(int((~np.isfinite(pred).all(axis=1) & (rows[k] != "")).sum()) for k, pred in enumerate(per))
               for name, per in predictors.items()}
    groups = {"scored": ("scored", "after")}   # with a silence: every row after the burn-in but the first after it
    if s.outage is not None:
        groups = {"scored": ("scored", "after"), "after the silence": ("after",),
                  "first row after the silence": ("first after the silence",)}
    out = {}
    for group, parts in groups.items():
        masks = [np.isin(rows[k], parts) & finite[k] for k in range(len(tracks))]
        entry = {"rows": int(sum(m.sum() for m in masks)), "predictors": {}}
        for name, per in predictors.items():
            errors = np.concatenate([z[m] - pred[m] for (t, z), pred, m in zip(tracks, per, masks)])
            summary = _rms(errors)
            if group == "scored":   # how it spreads over the tracks
                summary["per_track_rms_euclidean"] = [
                    float(np.sqrt(np.mean(np.sum((z[m] - pred[m]) ** 2, axis=-1)))) if m.any() else None
                    for (t, z), pred, m in zip(tracks, per, masks)]
            if name in stds:
                std = np.concatenate([sd[m] for sd, m in zip(stds[name], masks)])
                summary["coverage_95"] = float(np.mean(np.abs(errors) <= Z95 * std)) if len(std) else math.nan
            entry["predictors"][name] = summary
        out[group] = entry
    return out, counted


#: The ``kalmix predict`` runs of every scenario: the defaults, without the gap rule, without the population
#: prior, with BOA alone (the rule before BOA-blend).
RUNS = (("kalmix", ()), ("kalmix --max-gap none", ("--max-gap", "none")),
        ("kalmix --no-population-prior", ("--no-population-prior",)),
        ("kalmix --rule boa", ("--rule", "boa")))
#: ``--quick``'s runs (the test suite's): not the other rule's, a cold compile of its own in a subprocess.
QUICK_RUNS = tuple(run for run in RUNS if "--rule" not in run[1])


def run_scenario(s: Scenario, directory: Path, source: Path | None = None, log=print, predicts=RUNS) -> dict:
    """One scenario: its tracks, the reference's forecasts and ``kalmix predict``'s with each of ``predicts``
    (:data:`RUNS`, or :data:`QUICK_RUNS`), scored on the same rows."""
    start = time.perf_counter()
    transitions = [Transitions(A, Qc) for A, Qc, _ in s.models]
    table, tracks = simulate(s, transitions)
    simulated = time.perf_counter() - start
    ref = reference(s, tracks, transitions)
    reference_s = time.perf_counter() - start - simulated
    predictors = {"optimum": [p for p, _ in ref],
                  "no prediction": [np.vstack([np.full((1, 2), np.nan), z[:-1]]) for _, z in tracks]}
    stds = {"optimum": [np.sqrt(np.diagonal(S, axis1=1, axis2=2)) for _, S in ref]}
    runs = {}
    for name, options in predicts:
        out, seconds, said = kalmix_predict(table, directory, options, source)
        per = kalmix_one_step(out, table, tracks)
        predictors[name] = [p for p, _ in per]
        stds[name] = [sd for _, sd in per]
        segments = out.groupby("track_id", sort=False)["segment"].nunique()
        runs[name] = {"seconds": seconds, "stderr": said, "segments": int(segments.sum()),
                      "segments_per_track": [int(v) for v in segments]}
    scores, missing = score(s, tracks, predictors, stds)
    for group in scores.values():
        optimum = group["predictors"]["optimum"]["rms_euclidean"]
        for entry in group["predictors"].values():
            entry["ratio_to_optimum"] = entry["rms_euclidean"] / optimum if optimum > 0 else math.nan
    result = {"label": s.label, "about": s.about, "reference": s.reference, "unit": s.unit,
              "parameters": s.parameters,
              "tracks": s.tracks, "rows_per_track": s.rows, "seed": s.seed, "burn_in": BURN_IN,
              "time": "integer frame numbers" if s.integer_times else "seconds",
              "prior": {"mean": s.prior_mean.tolist(), "std": s.prior_std.tolist()},
              "unforecast_rows": missing, "kalmix_runs": runs, "groups": GROUPS if s.outage is not None else
              {"scored": GROUPS["scored"].split(";")[0]}, "scores": scores,
              "seconds": {"simulate": simulated, "reference": reference_s,
                          "total": time.perf_counter() - start}}
    for group, entry in scores.items():
        p = entry["predictors"]
        log(f"{s.name} [{group}, {entry['rows']} rows]: optimum {p['optimum']['rms_per_coordinate']:.4g}, "
            f"kalmix {p['kalmix']['rms_per_coordinate']:.4g} ({p['kalmix']['ratio_to_optimum']:.3f}x), "
            f"--max-gap none {p['kalmix --max-gap none']['ratio_to_optimum']:.3f}x, --no-population-prior "
            f"{p['kalmix --no-population-prior']['ratio_to_optimum']:.3f}x, no prediction "
            f"{p['no prediction']['ratio_to_optimum']:.3f}x; coverage kalmix "
            f"{100 * p['kalmix']['coverage_95']:.1f} %, optimum {100 * p['optimum']['coverage_95']:.1f} %")
    return result


def git(*args) -> str:
    """The output of ``git ARGS`` in this checkout; a ``RuntimeError`` when it fails."""
    done = subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"git {' '.join(args)}: {done.stderr.strip()}")
    return done.stdout


def export(revision: str, directory: Path) -> tuple[Path, str]:
    """kalmix's ``src`` at ``revision`` of this repository, written under ``directory``: its path and the commit."""
    commit = git("rev-parse", "--verify", f"{revision}^{{commit}}").strip()
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", commit, "src"], capture_output=True)
    if archive.returncode:
        raise RuntimeError(f"git archive {commit} src: {archive.stderr.decode().strip()}")
    subprocess.run(["tar", "-x", "-C", str(directory)], input=archive.stdout, check=True)
    return directory / "src", commit


def machine() -> dict:
    """The machine a report was measured on."""
    return {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine(),
            "python": platform.python_version()}


def checkout() -> dict:
    """The kalmix a report measured: this checkout's commit and the files of ``src`` changed in its working tree."""
    changed = git("status", "--porcelain", "--", "src").splitlines()
    return {"commit": git("rev-parse", "HEAD").strip(), "working_tree_changes": [line[3:] for line in changed]}


def run_all(report: dict, zoo: dict, chosen, quick: bool, directory: Path, run, start: float, json_path=None) -> dict:
    """``run(scenario, its own directory under directory)`` for each chosen scenario (``quick``: 5 tracks of 200
    rows) into ``report["scenarios"]``; then the seconds since ``start``, said and written to ``json_path``."""
    for name in chosen:
        s = zoo[name]
        if quick:
            s.tracks, s.rows = 5, 200
        scenario_directory = directory / name
        scenario_directory.mkdir()
        report["scenarios"][name] = run(s, scenario_directory)
    report["seconds"] = time.perf_counter() - start
    print(f"{len(chosen)} scenario(s) in {report['seconds']:.1f} s")
    if json_path:
        Path(json_path).write_text(json.dumps(report, indent=2) + "\n")
    return report


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=None, help="write the results here")
    parser.add_argument("--quick", action="store_true", help="5 tracks of 200 rows per scenario")
    zoo = scenarios()
    parser.add_argument("--scenario", action="append", choices=list(zoo), help="only this scenario (repeatable)")
    parser.add_argument("--at", metavar="REVISION", default=None,
                        help="run the kalmix of this commit (git archive of its src/) instead of the working tree's")
    args = parser.parse_args(argv)
    chosen = args.scenario or list(zoo)
    report = {"command": "python -m benchmarks.model_zoo" + (" --quick" if args.quick else "")
              + (f" --at {args.at}" if args.at else ""),
              "machine": machine(), "burn_in": BURN_IN, "scenarios": {}}
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="kalmix-zoo-") as temporary:
        source = None
        try:
            if args.at:
                source, commit = export(args.at, Path(temporary))
                report["kalmix"] = {"commit": commit, "working_tree_changes": []}
            else:
                report["kalmix"] = checkout()
        except (RuntimeError, FileNotFoundError) as error:
            if args.at:
                sys.exit(f"model_zoo: --at {args.at}: {error}")
            report["kalmix"] = {"commit": None, "note": f"not a git checkout ({error})"}
        return run_all(report, zoo, chosen, args.quick, Path(temporary),
                       lambda s, directory: run_scenario(s, directory, source,
                                                         predicts=QUICK_RUNS if args.quick else RUNS), start, args.json)


if __name__ == "__main__":
    main()
