"""Many tracks from a file: read, predict every track at once, and score the forecasts.

300 simulated vessels report their position (metres east and north, ~3 m noise) every
second, with lost reports (empty cells) and a radio outage of 60 s on some tracks. The CSV
uses the names of an AIS export (``mmsi``, ``timestamp``), which kalmix detects.
"""
import numpy as np
import pandas as pd

from kalmix import StreamConfig, TrackPredictor
from kalmix.io import read_tracks, to_arrays
from kalmix.streaming import auto_length_unit

rng = np.random.default_rng(0)
parts = []
for i in range(300):
    n = int(rng.integers(100, 400))
    heading = rng.uniform(0, 2 * np.pi) + np.cumsum(rng.normal(0, 0.02, n))   # slowly turning
    speed = rng.uniform(2, 8)                                                   # m/s
    time = np.arange(n, dtype=float)
    if i % 10 == 0:
        time[n // 2:] += 60.0                                                   # a 60 s outage
    east = np.cumsum(speed * np.cos(heading)) + rng.normal(0, 3, n)
    north = np.cumsum(speed * np.sin(heading)) + rng.normal(0, 3, n)
    lost = rng.random(n) < 0.02
    east[lost] = north[lost] = np.nan                                           # empty cells in the file
    parts.append(pd.DataFrame({"mmsi": 200_000_000 + i, "timestamp": time, "east": east, "north": north}))
pd.concat(parts).to_csv("tracks.csv", index=False)

table = read_tracks("tracks.csv")                      # columns detected: mmsi, timestamp, east, north
unit = auto_length_unit(to_arrays(table).values)       # the noise size, from the second differences
predictor = TrackPredictor(StreamConfig(length_unit=unit, horizon=10))   # also 10 time units (10 s) ahead
out = predictor.process_table(table, ["east", "north"])

# score after each track's first 20 s: row k's pred_ forecasts the track's next row, pred10_ the position 10 s on
positions = table[["east", "north"]].to_numpy()
following = table.groupby("track_id")[["east", "north"]].shift(-1).to_numpy()
continues = (out.groupby("track_id")["segment"].shift(-1) == out["segment"]).to_numpy()   # not across a gap
rows = continues & (out.time >= 20.0).to_numpy()
error = (following - out[["pred_east", "pred_north"]].to_numpy())[rows]
hold = (following - positions)[rows]                   # no prediction: the last measured position
std = out[["std_east", "std_north"]].to_numpy()[rows]
now = out.assign(east_now=positions[:, 0], north_now=positions[:, 1])
later = table.assign(time=table.time - 10.0).merge(now[now.time >= 20.0], on=["track_id", "time"])
error10 = later[["east", "north"]].to_numpy() - later[["pred10_east", "pred10_north"]].to_numpy()
hold10 = later[["east", "north"]].to_numpy() - later[["east_now", "north_now"]].to_numpy()


def rms(e):
    return np.sqrt(np.nanmean(np.square(e)))


print(f"{table.track_id.nunique()} tracks, {len(out)} rows, {int(out.groupby('track_id').segment.max().sum())} "
      f"restarts at time gaps; length unit {unit:.3f} m")
print(f"one-step RMS {rms(error):.3f} m (holding the last position: {rms(hold):.3f} m)")
print(f"inside the 95 % intervals: {np.mean((np.abs(error) <= 1.96 * std)[~np.isnan(error)]):.1%}")
print(f"10 s ahead RMS {rms(error10):.3f} m (holding the last position: {rms(hold10):.3f} m)")
print(out[out.time >= 100.0].head(3).to_string())
