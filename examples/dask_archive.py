"""A partitioned archive through Dask: the rows of a track spread over many files, the same numbers as one machine.

Needs the ``dask`` extra. Without a ``dask.distributed.Client`` the work runs on Dask's local
scheduler; open a Client first to run it on a cluster.
"""
import os

import numpy as np
import pandas as pd

from kalmix import StreamConfig, TrackPredictor
from kalmix.dask_predict import predict_dask, read_archive

rng = np.random.default_rng(0)
t = np.repeat(np.arange(300.0), 2)   # two tracks, reported every second, rows spread over 3 files
rows = pd.DataFrame({"track_id": np.tile(["a", "b"], 300), "time": t,
                     "x": 20 * np.sin(t / 20) * np.tile([1.0, 2.0], 300) + rng.normal(0, 0.1, 600),
                     "y": t / 10 + rng.normal(0, 0.1, 600)})
os.makedirs("reports", exist_ok=True)
for i in range(3):
    rows.iloc[200 * i:200 * (i + 1)].to_parquet(f"reports/part-{i}.parquet")

frame, columns, fmt = read_archive("reports/")            # a directory, a glob or a file; columns detected
predictions = predict_dask(frame, columns, prepared=True, length_unit=0.1, horizon=10)   # lazy
predictions.to_parquet("predictions/", write_index=False)   # computed here, one file per partition
result = pd.read_parquet("predictions/").sort_values(["track_id", "time"], ignore_index=True)

# Dask runs without the population prior (a partition does not see the other partitions' tracks)
one_machine = TrackPredictor(StreamConfig(length_unit=0.1, horizon=10, population_prior=False)).process_table(
    rows.sort_values(["track_id", "time"], kind="stable"), ["x", "y"])
print(f"{fmt} archive: {len(result)} predictions, columns {list(result.columns)}")
forecasts = ["pred_x", "pred_y", "std_x", "std_y", "pred10_x", "pred10_y", "std10_x", "std10_y"]
print("the same numbers as one machine:",
      np.array_equal(result[forecasts].to_numpy(), one_machine[forecasts].to_numpy(), equal_nan=True))
print(result.tail(3).to_string())
