"""The contract every bank (family x rule) passes: ``check_bank`` runs the generic checks.

In the spirit of river's estimator checks: one generator of checks, run on every family
and every rule by the test suite, each check a plain function raising AssertionError:

- weights valid: finite, >= 0, summing to 1 over the awake experts, 0 on sleeping ones;
- a NaN row is missing data: nothing learned (the time-based state is unchanged);
- a batch equals the same targets run one at a time;
- resume equals an uninterrupted run, bit for bit (and the block size does not matter);
- compiled equals reference, bit for bit (outputs, experts, weights and every state leaf), for
  every family and rule: both do the same operations in the same order (sums and matrix
  products in index order, the C library's exp, expm1, log, sin, cos, atan2). A looser
  tolerance would not do: an ulp of difference in an expert, summed by a rule's regrets over
  thousands of rows at a 1e8 offset, grows into a visible difference in the positions;
- every forecast is finite once the target has started, for finite input.
"""

from __future__ import annotations

import numpy as np

from .engine import Bank, run, tree_leaves
from .families import parts

__all__ = ["check_bank", "adversarial_tracks", "benign_tracks"]


def benign_tracks(seed: int, t_count: int = 120, n: int = 3, p: int = 2):
    rng = np.random.default_rng(seed)
    times = np.cumsum(rng.uniform(0.5, 1.5, (t_count, n)), axis=0)
    z = np.cumsum(np.cumsum(rng.normal(0, 0.05, (t_count, n, p)), axis=0), axis=0) + rng.normal(0, 0.3, (t_count, n, p))
    z[20:25, 1] = np.nan
    return z, times


def adversarial_tracks(seed: int, t_count: int = 400, p: int = 2):
    """Jumps of 1e8, a long NaN gap, constant input and values of 1e200, one target each."""
    rng = np.random.default_rng(seed)
    base = np.cumsum(rng.normal(0, 1.0, (t_count, 4, p)), axis=0)
    base[t_count // 2:, 0] += 1e8                 # a jump of 1e8
    base[50:50 + t_count // 2, 1] = np.nan        # a long gap
    base[:, 2] = 3.0                              # constant input
    base[:, 3] = 1e200 + base[:, 3] * 1e190       # huge values
    times = np.broadcast_to(np.arange(t_count, dtype=float)[:, None], (t_count, 4)).copy()
    return base, times


#: The outputs compared between runs (those the bank gives).
OUTPUTS = ("forecasts", "std", "lead", "lead_std")


def _outputs(result):
    return {name: getattr(result, name) for name in OUTPUTS if getattr(result, name) is not None}


def _same_arrays(got: dict, want: dict, what: str):
    """Equal, bit for bit, name by name: an array given on one side only (a dropped output, a missing or an
    extra state leaf) fails as well as a different one, and so does one of another type or shape."""
    assert list(got) == list(want), f"{what}: {sorted(set(got) ^ set(want))} on one side only"
    for name, a in got.items():
        assert np.asarray(a).dtype == np.asarray(want[name]).dtype, f"{what}: {name} of another type"
        assert np.array_equal(a, want[name], equal_nan=True), f"{what}: {name} differ"


def _same(a, b, what):
    _same_arrays(_outputs(a), _outputs(b), what)


def _same_state(a, b, what):
    _same_arrays(dict(tree_leaves(a)), dict(tree_leaves(b)), what)


def _joined(first, second):
    return type(first)(*[None if a is None or b is None or not hasattr(a, "ndim") or name == "state"
                         else np.concatenate([a, b]) for name, a, b in zip(first._fields, first, second)])


def check_bank(bank: Bank, measurements, times, *, compiled=True, restart=None):
    """Run every check of the module docstring on ``bank`` with ``measurements (T, N, p)``.

    ``restart (T, N)``: gap restarts to run with (:func:`kalmix.core.engine.run`). Every
    output is checked: forecasts, their calibrated standard deviations and, for a bank with
    a lead head, the lead forecasts and theirs (a standard deviation comes from differences
    of positions, so its rounding is compared relative to the positions' size).
    """
    z = np.asarray(measurements, dtype=float)
    t_count, n, _ = z.shape
    gaps = (lambda rows: None) if restart is None else (lambda rows: restart[rows])  # noqa: E731
    reference = run(bank, z, times, record_experts=True, restart=gaps(slice(None)))
    given = ("forecasts", "std") + (() if bank.lead is None else ("lead", "lead_std"))
    assert tuple(_outputs(reference)) == given, f"outputs {tuple(_outputs(reference))}, not {given}"
    # weights valid
    w, experts = reference.weights, reference.experts
    awake = np.isfinite(experts).all(axis=-1)
    assert np.all(np.isfinite(w)) and np.all(w >= 0)
    assert np.all(w[~awake] == 0)
    sums = w.sum(axis=-1)
    started = awake.any(axis=-1)
    assert np.allclose(sums[started], 1.0, atol=1e-9)
    # finite once started (finite input), standard deviations too
    assert np.all(np.isfinite(reference.forecasts[started])), "a forecast is not finite"
    assert np.all(np.isfinite(reference.std[started])) and np.all(reference.std[started] >= 0), "a bad std"
    # batch == singles
    for j in range(n):
        single = run(bank, z[:, j:j + 1], times[:, j:j + 1],
                     restart=None if restart is None else restart[:, j:j + 1])
        _same_arrays(_outputs(single), {name: a[:, j:j + 1] for name, a in _outputs(reference).items()},
                     "batch != single")
    # resume == uninterrupted, bit for bit
    cut = t_count // 3
    first = run(bank, z[:cut], times[:cut], restart=gaps(slice(None, cut)))
    second = run(bank, z[cut:], times[cut:], first.state, restart=gaps(slice(cut, None)))
    _same(_joined(first, second), reference, "resume")
    # a NaN row learns nothing: the rule's and the calibration's states are unchanged
    missing = np.full_like(z[:1], np.nan)
    after = run(bank, missing, times[cut:cut + 1], first.state).state
    for part in ("rule", "calibration"):
        _same_state(getattr(after, part), getattr(first.state, part),
                    f"a missing row changed the {part}'s state")
    for family, old, new in zip(bank.families, first.state.families, after.families):
        if parts(family.kind).clock == "time":   # (a frame-based family counts the missing row)
            for a, b in zip(old, new):
                assert np.array_equal(a, b, equal_nan=True), "a missing row changed a kinematic state"
    if compiled:
        from .compiled import engine as ce

        fast = ce.run(bank, z, times, restart=gaps(slice(None)), record_experts=True)
        _same(fast, reference, "compiled != reference, bit for bit")
        _same_arrays({name: getattr(fast, name) for name in ("experts", "weights")},
                     {name: getattr(reference, name) for name in ("experts", "weights")},
                     "compiled != reference, bit for bit")
        _same_state(fast.state, reference.state, "compiled != reference, bit for bit")
        head = ce.run(bank, z[:cut], times[:cut], restart=gaps(slice(None, cut)))
        resumed = ce.run(bank, z[cut:], times[cut:], head.state, restart=gaps(slice(cut, None)))
        _same(_joined(head, resumed), fast, "compiled resume")
        saved = ce.BUFFER_BYTES
        try:
            ce.BUFFER_BYTES = 1
            blocked = ce.run(bank, z, times, restart=gaps(slice(None)))
        finally:
            ce.BUFFER_BYTES = saved
        _same(blocked, fast, "block size")
    return reference
