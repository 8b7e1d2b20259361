import numpy as np
import pandas as pd
from kalmix import StreamConfig, TrackPredictor

rng = np.random.default_rng(0)
t = np.arange(0.0, 30.0, 0.1)                                    # seconds, 10 Hz
table = pd.concat([pd.DataFrame({"track_id": name, "time": t,    # two targets circling, metres
                                 "x": r * np.cos(t / r) + rng.normal(0, 0.05, t.size),
                                 "y": r * np.sin(t / r) + rng.normal(0, 0.05, t.size)})
                   for name, r in [("boat", 20.0), ("drone", 5.0)]], ignore_index=True)

predictor = TrackPredictor(StreamConfig(length_unit=0.05))       # the noise, ~5 cm, in data units
predictions = predictor.process_table(table, ["x", "y"])         # pred_x: x at the track's next row
print(predictions.head())
