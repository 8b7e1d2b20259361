"""One expert of a bank, by its index: its name in ``kalmix evaluate``'s output and a bank of it alone (the best
expert in hindsight, :func:`kalmix.experiments._evaluate_mixture.run_bank`). Each family names and slices its own
experts (:data:`kalmix.core.families.KINDS`)."""

from __future__ import annotations

from ..core.families import parts


def _locate(bank, expert):
    for family, columns in zip(bank.families, bank.slices()):
        if columns.start <= expert < columns.stop:
            return family, expert - columns.start
    raise IndexError(expert)


def expert_name(bank, expert):
    family, i = _locate(bank, expert)
    return parts(family.kind).spec.expert_name(family.params, i, family.kind)


def single_expert_bank(bank, expert):
    """A bank of the one expert ``expert`` (same parameters), under the same rule."""
    from dataclasses import replace

    from ..core.engine import Family

    family, i = _locate(bank, expert)
    single = parts(family.kind).spec.one_expert(family.params, i)
    return replace(bank, families=(Family(family.kind, single),), lead=None)
