"""The coordinated-turn family: exact on circles (any plane, any sampling), a CV extrapolation without a turn."""

import numpy as np
import pytest

from kalmix.bank import DEFAULT_BANK, make_bank
from kalmix.core import engine
from kalmix.core.compiled import engine as ce
from kalmix.core.families import turn
from kalmix.core.testing import check_bank


def _run(z, t, gains=(0.0, 0.5, 1.0, 1.5), compiled=True):
    bank = make_bank(z.shape[-1], "turn", turn_gains=gains, length_unit=0.1)
    run = ce.run if compiled else engine.run
    return run(bank, z[:, None, :], t[:, None], record_experts=True).experts[:, 0]   # (T, K, p)


def _circle(times, radius=5.0, omega=0.3, plane=None):
    angle = omega * times
    xy = radius * np.column_stack([np.cos(angle), np.sin(angle)])
    if plane is None:
        return xy
    return xy @ plane   # (2, p) orthonormal rows: the circle in that plane


@pytest.mark.parametrize("compiled", [False, True])
def test_gain_one_forecasts_a_circle_exactly_whatever_the_sampling(compiled):
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.3, 1.7, size=60))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    for z in (_circle(t), _circle(t, plane=q[:2])):   # 2-D, and 3-D in a tilted plane
        experts = _run(z, t, compiled=compiled)
        np.testing.assert_allclose(experts[3:, 2], z[3:], atol=1e-9)   # gain 1, from the 4th row on
        errors = np.abs(experts[3:] - z[3:, None, :]).max(axis=(0, 2))
        assert errors[0] > 0.1 and errors[1] > 0.01 and errors[3] > 0.01   # the other gains do not


def test_no_turn_is_a_constant_velocity_extrapolation():
    t = np.array([0.0, 1.0, 2.5, 3.0, 4.5, 6.0])
    line = np.column_stack([2.0 * t - 1.0, -0.5 * t])                        # a straight line, uneven steps
    experts = _run(line, t)
    np.testing.assert_allclose(experts[2:], np.broadcast_to(line[2:, None, :], experts[2:].shape), atol=1e-12)
    z1 = np.array([[0.0], [1.0], [3.0], [2.0], [2.5]])                       # 1-D: no plane, no turn
    experts = _run(z1, np.arange(5.0))
    two_point = 2 * z1[1:-1] - z1[:-2]
    np.testing.assert_allclose(experts[2:], np.broadcast_to(two_point[:, None, :], experts[2:].shape))
    np.testing.assert_array_equal(experts[1], np.broadcast_to(z1[0], experts[1].shape))   # one row: hold it
    assert np.isnan(experts[0]).all()                                        # none yet: asleep


def test_gain_zero_goes_straight_on_at_the_arc_speed_and_gain_one_follows_the_circle():
    t = np.arange(8.0)
    z = _circle(t, omega=0.4)
    bank = make_bank(2, "turn", turn_gains=(0.0, 1.0), length_unit=0.1)
    state = engine.init_bank_state(bank, 1)
    for row in range(len(t)):
        state, _ = engine.step(bank, state, z[row][None], t[row])
    params, fstate = bank.families[0].params, state.families[0]
    means, variances = turn.forecast(params, fstate, np.array([t[-1] + 2.0]))
    arc_speed = 1.0 / np.sinc(0.2 / np.pi)   # omega * Delta_2 / 2 = 0.2: the chord is shorter than the arc
    np.testing.assert_allclose(means[0, 0], z[-1] + 2.0 * arc_speed * (z[-1] - z[-2]), atol=1e-12)
    np.testing.assert_allclose(means[0, 1], _circle(np.array([t[-1] + 2.0]), omega=0.4)[0], atol=1e-9)
    assert np.all(variances > 0) and variances.shape == (1, 2)


def test_the_default_bank_has_the_turn_families():
    bank = make_bank(2, **DEFAULT_BANK)
    kinds = [f.kind for f in bank.families]
    assert "turn" in kinds and "ct" in kinds and "ar" in kinds and "akf" in kinds and "cv" in kinds
    assert bank.n_experts == 125
    assert make_bank(1, **DEFAULT_BANK).n_experts == 119   # (one coordinate: no coordinated-turn filters)


def test_turn_gains_are_checked():
    with pytest.raises(ValueError, match=r"turn_gains\[1\]: expected a finite number >= 0, got -1.0"):
        make_bank(2, "turn", turn_gains=(1.0, -1.0))
    with pytest.raises(ValueError, match="turn_gains: expected at least one value"):
        make_bank(2, "mixed+ar+turn", turn_gains=())


def test_compiled_equals_reference_after_huge_jumps_values_and_a_5000_row_gap():
    """1e8 jumps, 1e200 values, a 5,000-row NaN gap and constant input on a turning track: the
    contract (compiled == spec to 1e-9, resume, batch == single streams) and finite forecasts after it."""
    rng = np.random.default_rng(3)
    t = np.arange(6000.0)
    z = np.column_stack([np.cos(t / 30) * 20, np.sin(t / 30) * 20]) + rng.normal(0, 0.1, (6000, 2))
    z[150] += 1e8                       # a glitch
    z[300:] += np.array([1e8, -1e8])    # a relocation
    z[400] = 1e200                      # an absurd value
    z[500:5500] = np.nan                # a 5,000-row gap
    z[5800:] = z[5799]                  # constant input
    z = np.stack([z, np.column_stack([t * 0.5, -t])], axis=1)   # and a straight track beside it
    times = np.broadcast_to(t[:, None], z.shape[:2]).copy()
    bank = make_bank(2, "turn", length_unit=0.3)
    check_bank(bank, z, times)
    result = ce.run(bank, z, times)
    assert np.isfinite(result.forecasts[5600:]).all()
