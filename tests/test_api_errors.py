"""The Python API under a robotics user's mistakes: each case a wrong argument or an input the docs take, that
gave a raw pandas or Python error deep inside, or dropped rows in silence."""

import warnings

import numpy as np
import pandas as pd
import pytest

from kalmix import MixturePredictor
from kalmix.streaming import SkippedRowWarning, StreamConfig, TrackPredictor


def _predictor():
    return TrackPredictor(StreamConfig(length_unit=1.0, n_experts=2))


def _table(n=12):
    t = np.arange(float(n))
    return pd.DataFrame({"track_id": "a", "time": t, "east": t, "north": 2.0 * t})


def test_a_track_id_and_time_table_takes_iso_text_times_as_dates():
    """step_row, step_rows, files and a detected time column take ISO 8601 text; a column named ``time`` gave
    pandas' 'could not convert string to float'."""
    table = _table()
    dates = pd.Timestamp("2024-05-01T12:00:00Z") + pd.to_timedelta(table["time"], unit="s")
    as_text = _predictor().process_table(table.assign(time=dates.dt.strftime("%Y-%m-%dT%H:%M:%SZ")))
    as_dates = _predictor().process_table(table.assign(time=dates))
    pd.testing.assert_frame_equal(as_text, as_dates)
    bad = table.assign(time=table["time"].astype(str).where(table.index != 3, "soon"))
    with pytest.raises(ValueError, match=r"Column 'time' must hold .*row 3 .*'soon'"):
        _predictor().process_table(bad)


@pytest.mark.parametrize("load", [TrackPredictor.load, MixturePredictor.load])
@pytest.mark.parametrize("path", [3, None, 2.5])
def test_a_state_file_path_that_is_not_a_path_is_a_type_error(load, path):
    """``load(3)`` gave "'int' object has no attribute 'seek'" (an AttributeError from zipfile)."""
    with pytest.raises(TypeError, match=r"path: expected the path of a kalmix .* file .*, got "):
        load(path)


def test_position_names_that_are_not_names_are_refused_by_name():
    with pytest.raises(TypeError, match=r"position_names: expected a sequence of column names, got int 5"):
        TrackPredictor(StreamConfig(length_unit=1.0), 5)
    with pytest.raises(ValueError, match=r"position_names: expected one name per coordinate, got none"):
        TrackPredictor(StreamConfig(length_unit=1.0), [])   # (it failed at the first row: 'expected 0 coordinates')
    with pytest.raises(TypeError, match=r"position_names: expected a sequence of column names, got int 5"):
        _predictor().process_table(_table(), 5)
    one = _predictor().process_table(_table(), "east")   # one name, not its letters e, a, s, t
    assert list(one.columns) == ["track_id", "time", "segment", "pred_east", "std_east"]


def test_text_coordinates_and_a_foreign_checkpoint_are_type_errors():
    """``step_row(0, 0.0, "12")`` was a one-coordinate row of 12; ``rollback(5)`` an AttributeError."""
    predictor = _predictor()
    with pytest.raises(TypeError, match=r"z: expected the coordinates .* got the text '12'"):
        predictor.step_row(0, 0.0, "12")
    with pytest.raises(TypeError, match=r"values: expected a \(n, p\) array of coordinates, got the text"):
        predictor.step_rows([0], [0.0], "1,2")
    with pytest.raises(TypeError, match=r"checkpoint: expected what TrackPredictor.checkpoint\(\) returned"):
        predictor.rollback(5)
    assert predictor.rows == 0 and predictor.position_names is None


def test_process_table_warns_once_of_the_rows_it_skips():
    """A track whose clock restarts (the same table fed again) came back as an empty frame, and a shuffled table
    as a few rows, with only ``skipped`` to show for it; step_row warns of the same rows."""
    predictor = _predictor()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(predictor.process_table(_table())) == 12
    with pytest.warns(SkippedRowWarning, match=r"table: 12 row\(s\) skipped, the first in row 0 \(counted from 0; "
                                               r"track 'a', time 0.0\)"):
        assert len(predictor.process_table(_table())) == 0
    assert predictor.skipped == 12 and predictor.warn_skipped is False
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # said once
        predictor.process_table(_table().assign(time=lambda t: t["time"] + 5.0))
    missing = _table().assign(time=lambda t: t["time"].where(t.index != 4))
    with pytest.warns(SkippedRowWarning, match=r"1 row\(s\) skipped, the first in row 4 .*time nan\)"):
        assert len(_predictor().process_table(missing)) == 11
