"""Save every track's state, stop, and resume in another process with the same numbers.

A feed of three tracks is stepped up to t = 20 s and saved; a new predictor loaded from the
file steps the rest. Its predictions are the same bits as those of a run that never stopped.
"""
import numpy as np
import pandas as pd

from kalmix import StreamConfig, TrackPredictor

rng = np.random.default_rng(0)
t = np.arange(0.0, 40.0, 0.1)
table = pd.concat([pd.DataFrame({"track_id": f"target-{i}", "time": t,
                                 "x": 10 * np.sin(t / (3 + i)) + rng.normal(0, 0.02, t.size),
                                 "y": 0.5 * (i + 1) * t + rng.normal(0, 0.02, t.size)})
                   for i in range(3)]).sort_values("time", kind="stable", ignore_index=True)   # rows as they arrive
before, after = table[table.time < 20.0], table[table.time >= 20.0]
config = StreamConfig(length_unit=0.02, lead=0.5)

first = TrackPredictor(config)
first.process_table(before, ["x", "y"])
first.save("tracks.npz")                       # settings, every track's state and its gap bookkeeping

resumed = TrackPredictor.load("tracks.npz")    # e.g. in a new process, after a restart
resumed_predictions = resumed.process_table(after, ["x", "y"])
live = resumed.step_row("target-0", 40.0, [np.nan, np.nan])   # and go on row by row (here a missing row)

whole = TrackPredictor(config).process_table(table, ["x", "y"])   # the same rows, never stopped
columns = ["pred_x", "pred_y", "std_x", "std_y", "lead_x", "lead_y"]
same = np.array_equal(whole[whole.time >= 20.0][columns].to_numpy(), resumed_predictions[columns].to_numpy())
print("settings kept in the file: length unit", resumed.config.length_unit, "lead", resumed.config.lead,
      "time unit", round(resumed.config.time_unit, 6))
print("rows after the resume:", len(resumed_predictions), "tracks:", resumed.track_ids)
print("resumed predictions identical to an uninterrupted run:", same)
print("target-0 forecast for t = 40.1 s, after a missing row at 40.0 s:", live.next.round(3))
