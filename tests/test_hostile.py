"""A hostile pass over the new options and the engine API: each fix of what was not handled well.

Every case here was found by feeding kalmix a bad input, option, or call: before the fix it gave
a traceback-like message, a wrong silent result, or an error after all the work.
"""

import numpy as np
import pytest

from kalmix.bank import make_bank
from kalmix.core import engine
from kalmix.core.compiled import engine as ce
from kalmix.streaming import StreamConfig, TrackPredictor

ENGINES = {"reference": engine.run, "compiled": ce.run}


# ---------------------------------------------------------------------------------------- engine API
def _data(n=2, p=2, t_count=30):
    z = np.cumsum(np.random.default_rng(1).normal(size=(t_count, n, p)), axis=0)
    return z, np.broadcast_to(np.arange(t_count, dtype=float)[:, None], (t_count, n)).copy()


@pytest.mark.parametrize("run", ENGINES.values(), ids=ENGINES.keys())
@pytest.mark.parametrize("call, message", [
    (lambda run, bank, z, t: run(bank, z[:, :, 0], t), r"measurements: expected shape \(T, N, p\).*got \(30, 2\)"),
    (lambda run, bank, z, t: run(bank, z[..., :1], t), "measurements: expected 2 coordinates per row"),
    (lambda run, bank, z, t: run(bank, z, np.arange(31.0)), r"times: expected shape \(T, N\) = \(30, 2\)"),
    (lambda run, bank, z, t: run(bank, z, t, lengths=np.array([3])), r"lengths: expected shape \(N,\) = \(2,\)"),
    (lambda run, bank, z, t: run(bank, z, t, engine.init_bank_state(make_bank(2, "kinematic"), 2)),
     "state: expected a BankState of this bank .* with 2 families"),
    (lambda run, bank, z, t: run(bank, z, t, engine.init_bank_state(bank, 3)),
     r"state: state.families\[0\].mean has shape \(3, "),
])
def test_engine_arguments_are_checked_by_name(run, call, message):
    """Before: 'not enough values to unpack', a numpy broadcast error, a state of another bank
    used silently by the reference (zip cut it short), data of the wrong dimension run silently."""
    z, t = _data()
    with pytest.raises(ValueError, match=message):
        call(run, make_bank(2, "mixed", n_akf=2), z, t)


@pytest.mark.parametrize("args, error, message", [
    (("a", 0.0, ["1", "x"]), ValueError, r"z: expected numbers .*got \['1', 'x'\]"),
    ((["a"], 0.0, [1.0, 2.0]), TypeError, r"track_id: expected a hashable id .*got list \['a'\]"),
    (("a", "noon", [1.0, 2.0]), ValueError, "time: expected a number, got 'noon'"),
])
def test_step_row_names_a_bad_argument(args, error, message):
    predictor = TrackPredictor(StreamConfig(bank="kinematic", length_unit=1.0))
    with pytest.raises(error, match=message):
        predictor.step_row(*args)
    assert predictor.rows == 0 and not predictor.track_ids
