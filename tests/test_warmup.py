"""The experts' warm-up: an expert's forecasts weigh once its track (since its (re)start) has given it its kind's
rows; until then the one-step weights leave it out, if an expert warmed up is awake."""

import numpy as np
import pytest

from kalmix.bank import DEFAULT_BANK, make_bank
from kalmix.core import engine
from kalmix.core.compiled import engine as ce
from kalmix.core.families import KINDS
from kalmix.core.screen import MAX_POINTS


def _tracks(seed=0, rows=30, targets=3):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.5, 2.0, (rows, targets)), axis=0)
    z = np.stack([3.0 * t + 0.1 * t ** 1.5, -2.0 * t], axis=-1) + rng.normal(0, 0.5, (rows, targets, 2))
    return z, t


def _warm(bank):
    return np.concatenate([np.full(f.n_experts, f.parts.warmup) for f in bank.families])


def test_every_kind_declares_rows_the_screen_counts_to():
    warmups = {name: kind.warmup for name, kind in KINDS.items()}
    assert warmups == {"cv": 2, "ca": 3, "ar": 3, "turn": 2, "ct": 2, "akf": 3}
    assert all(kind.warmup <= MAX_POINTS for kind in KINDS.values())
    assert all(kind.warmup == kind.order for kind in KINDS.values() if kind.order is not None)   # CV, CA


@pytest.mark.parametrize("run", [engine.run, ce.run], ids=["spec", "compiled"])
def test_the_experts_of_three_rows_sleep_on_a_segments_third_row(run):
    """Row 2 (one learned row): no expert has its rows, every one forecasts. Row 3: only CV and the turns weigh (the
    others' forecasts are still recorded). Row 4 on: every family. Again after a restart (row 10 of target 0)."""
    z, t = _tracks()
    restart = np.zeros(t.shape, dtype=bool)
    restart[10, 0] = True
    bank = make_bank(2, **DEFAULT_BANK, length_unit=0.5, time_unit=1.0, n_akf=4)
    result = run(bank, z, t, restart=restart, record_experts=True)
    late = _warm(bank) == 3
    assert late.any() and (~late).any()
    w = result.weights
    assert (w[1][:, late] > 0).any()                                     # the second row: everyone
    assert np.all(w[2][:, late] == 0) and np.allclose(w[2][:, ~late].sum(-1), 1.0)
    assert np.isfinite(result.experts[2][:, late]).all()                 # asleep, not silent
    assert (w[3][:, late] > 0).all(axis=-1).all()
    # target 0 restarts at row 10 (its segment's first): row 11 everyone, row 12 CV and turn, row 13 everyone
    assert (w[11, 0, late] > 0).any() and np.all(w[12, 0, late] == 0) and (w[13, 0, late] > 0).all()
    assert (w[12, 1:][:, late] > 0).all()   # the others go on


def test_a_bank_of_one_warm_up_has_nothing_to_mask():
    assert make_bank(2, "turn").warmup_rows() is None and make_bank(2, "akf", n_akf=4).warmup_rows() is None
    assert make_bank(2, "kinematic").warmup_rows() is not None


def test_without_a_warmed_up_expert_awake_every_expert_forecasts():
    """The one-step weights never drop to no expert: where the warmed-up ones have no forecast, the others
    weigh."""
    bank = make_bank(2, **DEFAULT_BANK, length_unit=0.5, time_unit=1.0, n_akf=4)
    late = _warm(bank) == 3
    experts = np.ones((2, bank.n_experts, 2))
    experts[1, ~late] = np.nan
    out = engine.warmed_up(bank, experts, np.array([2.0, 2.0]))
    assert np.isnan(out[0, late]).all() and np.isfinite(out[0, ~late]).all()
    assert np.array_equal(out[1], experts[1], equal_nan=True)
    assert engine.warmed_up(bank, experts, np.array([3.0, 3.0])) is experts


def test_compiled_equals_the_spec_on_short_segments():
    """Bit for bit on tracks of 2 to 6 rows, restarts every few rows, missing rows, ahead times and a lead head."""
    z, t = _tracks(seed=5, rows=40, targets=5)
    z[[3, 17], 1] = np.nan
    restart = np.zeros(t.shape, dtype=bool)
    restart[::4, 2] = True
    restart[[5, 7, 8, 20], 3] = True
    lengths = np.array([2, 40, 40, 40, 6])
    for lead in (None, 2.0):
        bank = make_bank(2, **DEFAULT_BANK, length_unit=0.5, time_unit=1.0, n_akf=4, lead=lead)
        ref = engine.run(bank, z, t, lengths=lengths, ahead_times=t + 1.0, restart=restart, record_experts=True)
        fast = ce.run(bank, z, t, lengths=lengths, ahead_times=t + 1.0, restart=restart, record_experts=True)
        names = ("forecasts", "std", "ahead", "ahead_std", "weights", "experts")
        names += ("lead", "lead_std") if lead else ()
        for name in names:
            assert np.array_equal(getattr(ref, name), getattr(fast, name), equal_nan=True), (lead, name)
        assert np.array_equal(ref.state.screen.points, fast.state.screen.points)
