"""Reading track files and shipped recordings into long track tables."""

from .datasets import DATASETS, DatasetInfo, load_dataset
from .tables import (
    TrackArrays,
    TrackColumns,
    detect_columns,
    from_arrays,
    in_file_order,
    iter_track_chunks,
    read_tracks,
    split_on_gaps,
    to_arrays,
)

__all__ = [
    "DATASETS",
    "DatasetInfo",
    "TrackArrays",
    "TrackColumns",
    "detect_columns",
    "from_arrays",
    "in_file_order",
    "iter_track_chunks",
    "load_dataset",
    "read_tracks",
    "split_on_gaps",
    "to_arrays",
]
