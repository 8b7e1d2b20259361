"""One expert of a bank, by its index: its name in ``kalmix evaluate``'s output and a bank of it alone (the best
expert in hindsight, :func:`kalmix.experiments._evaluate_mixture.run_bank`)."""

from __future__ import annotations


def _locate(bank, expert):
    for family, columns in zip(bank.families, bank.slices()):
        if columns.start <= expert < columns.stop:
            return family, expert - columns.start
    raise IndexError(expert)


def expert_name(bank, expert):
    family, i = _locate(bank, expert)
    if family.kind == "akf":
        return f"akf[{i}]"
    if family.kind == "ar":
        fp = family.params
        return f"ar{fp.order}(forgetting={fp.forgetting[i]:.4g}, ridge={fp.ridge[i]:.3g})"
    if family.kind == "turn":
        return f"turn(gain={family.params.gain[i]:.3g})"
    return (f"{family.kind}(q={family.params.process_noise[i]:.3g}, r={family.params.measurement_noise[i]:.3g})")


def single_expert_bank(bank, expert):
    """A bank of the one expert ``expert`` (same parameters), under the same rule."""
    from dataclasses import replace

    from ..core.engine import Family

    family, i = _locate(bank, expert)
    if family.kind == "akf":
        params = family.params
        per_expert = {name: getattr(params, name)[i:i + 1] for name in (
            "forgetting", "ridge", "process_noise", "measurement_noise", "initial_variance", "initial_velocity",
            "expert_scale")}
        single = replace(params, **per_expert)
    elif family.kind == "ar":
        single = family.params._replace(forgetting=family.params.forgetting[i:i + 1],
                                        ridge=family.params.ridge[i:i + 1])
    elif family.kind == "turn":
        single = family.params._replace(gain=family.params.gain[i:i + 1])
    else:
        single = family.params._replace(process_noise=family.params.process_noise[i:i + 1],
                                        measurement_noise=family.params.measurement_noise[i:i + 1],
                                        initial_variance=family.params.initial_variance[i:i + 1])
    return replace(bank, families=(Family(family.kind, single),), lead=None)
