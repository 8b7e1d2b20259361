"""A live feed: rows arrive frame by frame, and each row gets its forecast at once.

Two targets seen at 10 Hz. Every frame's rows go through ``step_rows`` together (the same
numbers as one row at a time); a single row goes through ``step_row``. With ``lead=1.0``
each row also gets a forecast one second ahead (``ahead``), learned on one-second errors.
"""
import numpy as np

from kalmix import StreamConfig, TrackPredictor

rng = np.random.default_rng(0)
t = np.arange(0.0, 20.0, 0.1)                                      # seconds, 10 Hz
boat = np.stack([30 * np.cos(0.2 * t), 30 * np.sin(0.2 * t)], 1)   # metres: a boat turning
buoy = np.stack([5 + 0.1 * t, 2 + 0.02 * t], 1)                    # a drifting buoy
boat_seen = boat + rng.normal(0, 0.05, boat.shape)                 # measured to ~5 cm
buoy_seen = buoy + rng.normal(0, 0.05, buoy.shape)
boat_seen[60] = np.nan                                             # a lost measurement: NaN (or None)

# length_unit: the measurement noise in data units; lead: also forecast 1 s (10 rows) ahead
predictor = TrackPredictor(StreamConfig(length_unit=0.05, lead=1.0), position_names=["x", "y"])
predictor.warm_up()   # load the compiled kernels now: the first row is then answered as fast as the rest

ahead_errors, inside = [], []
for k in range(150):
    boat_row, buoy_row = predictor.step_rows(["boat", "buoy"], [t[k], t[k]], [boat_seen[k], buoy_seen[k]])
    if k >= 50:   # after 5 s of learning, score the boat's 1 s forecasts and its next-row intervals
        ahead_errors.append(boat_row.ahead - boat[k + 10])
        if not np.isnan(boat_seen[k + 1]).any():
            inside.append(np.abs(boat_seen[k + 1] - boat_row.next) <= 1.96 * boat_row.next_std)

row = predictor.step_row("boat", t[150], {"x": boat_seen[150, 0], "y": boat_seen[150, 1]})   # by name

print("boat at the next frame:", row.next.round(2), "+-", (1.96 * row.next_std).round(2), "true:", boat[151].round(2))
print("boat 1 s ahead:", row.ahead.round(2), "+-", (1.96 * row.ahead_std).round(2), "true:", boat[160].round(2))
print(f"RMS of the boat's 1 s forecasts, rows 50-149: {np.sqrt(np.mean(np.square(ahead_errors))):.3f} m")
print(f"next measurements inside their 95 % intervals: {np.mean(inside):.1%}")
print("tracks:", predictor.track_ids, "rows:", predictor.rows)
