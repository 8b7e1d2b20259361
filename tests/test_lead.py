"""The lead head's forecasts against the one-step weights' forecasts on the same experts (docs' results, "What the
lead head brings"): the blend keeps the lead forecasts from doing worse than the one-step weights."""

import numpy as np
import pytest

from kalmix.bank import DEFAULT_BANK, make_bank
from kalmix.core.compiled import engine as compiled
from kalmix.streaming import auto_length_unit


def _accelerating(seed, t_count=600, n=4):
    """Tracks whose acceleration jumps every 50 rows (normal, 0.02 a row squared), noise 0.05: the one-step weights
    follow a change of motion H rows before weights learned on H-step errors can."""
    rng = np.random.default_rng(seed)
    acceleration = np.repeat(rng.normal(0.0, 0.02, (t_count // 50, n, 2)), 50, axis=0)
    velocity = np.cumsum(acceleration, axis=0) + rng.normal(0.0, 0.3, (1, n, 2))
    z = np.cumsum(velocity, axis=0) + rng.normal(0.0, 0.05, (t_count, n, 2))
    return z, np.arange(t_count, dtype=float)[:, None]


def _ratio(z, h, result):
    """H-step RMS of the lead forecasts over that of the one-step weights', after the first fifth of the rows."""
    def rms(forecasts):
        return float(np.sqrt(np.nanmean((z[h:] - forecasts[:-h])[len(z) // 5:] ** 2)))
    return rms(result.lead) / rms(result.ahead)


@pytest.mark.parametrize("h", [2, 5, 10])
def test_the_lead_forecasts_stay_near_the_one_step_weights_where_the_lead_weights_lose(h):
    """Where the lead weights alone do worse than the one-step weights (here by 0.4 %, 5.6 % and 14 % at H = 2,
    5, 10), the lead forecasts stay within 0.6 % of the one-step weights' (measured: -0.03 %, +0.50 %, +0.39 %),
    and at H = 5 and 10 the blend has moved to the one-step weights' forecast on every track."""
    z, t = _accelerating(seed=1)
    bank = make_bank(2, length_unit=0.05, time_unit=1.0, lead=float(h), **DEFAULT_BANK)
    result = compiled.run(bank, z, t)
    assert _ratio(z, h, result) <= 1.006
    weights = bank.rule_module.weights(bank.blend_rule_params, result.state.lead.blend,
                                       np.ones((z.shape[1], 2), dtype=bool))
    if h >= 5:
        assert np.all(weights[:, 1] > 0.8)   # the one-step weights' share (measured: 0.85 and more)


def test_the_lead_forecasts_keep_what_the_lead_weights_win():
    """The paper's simulated target (seeds 0 to 3), where the lead weights alone beat the one-step weights (by
    0.3 %, 2.6 % and 9.7 % at H = 2, 5, 10): the lead forecasts do too (measured: 0.9957, 0.9815, 0.9096)."""
    from kalmix.experiments.table1 import FRAME_RATE, paper_table

    table = paper_table(seeds=range(4))
    groups = [group for _, group in table.groupby("track_id")]
    z = np.stack([g[["f0", "f1", "f2"]].to_numpy() for g in groups], axis=1)
    t = np.stack([g["time"].to_numpy() for g in groups], axis=1)
    unit = 1.0 / FRAME_RATE
    for h, bound in ((2, 1.0), (5, 0.99), (10, 0.92)):
        bank = make_bank(3, length_unit=auto_length_unit(z[:len(z) // 5]), time_unit=unit, lead=h * unit,
                         **DEFAULT_BANK)
        assert _ratio(z, h, compiled.run(bank, z, t)) <= bound, h
