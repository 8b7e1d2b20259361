"""The registry of families and the compiled rules: every kind has the same parts, so no engine branches on a kind."""

import inspect
import re
from pathlib import Path

import numpy as np
import pytest

from kalmix.bank import make_bank
from kalmix.core import aggregators
from kalmix.core.engine import Family
from kalmix.core.families import KINDS, parts

CORE = Path(__file__).resolve().parents[1] / "src" / "kalmix" / "core"


def test_every_family_kind_has_the_common_signature_and_a_driver_with_the_common_parts():
    from kalmix.core.compiled.drivers import driver

    for name, entry in KINDS.items():
        spec = entry.spec
        assert list(inspect.signature(spec.forecast).parameters) == ["params", "state", "time", "frames"], name
        assert list(inspect.signature(spec.update).parameters) == [
            "params", "state", "measurement", "time", "learn", "active", "restart"], name
        assert entry.clock in ("time", "frames"), name
        module = driver(name)
        for part in ("constants", "pack", "unpack", "scratch", "work_arrays", "kernel", "check_gpu",
                     "COST", "NAME", "COMPILE_APART"):
            assert hasattr(module, part), (name, part)


def test_a_family_state_packed_for_its_driver_unpacks_to_the_same_state():
    from kalmix.core.compiled.drivers import driver

    bank = make_bank(2, "mixed+ar+turn+ct", n_akf=4)
    assert {family.kind for family in bank.families} == set(KINDS)
    for family in bank.families:
        state = family.module.init_state(family.params, 3, 2)
        module = driver(family.kind)
        packed = module.pack(family.params, state)
        back = module.unpack(packed, state)
        assert type(back) is type(state)
        for a, b in zip(back, state):
            assert np.array_equal(a, b, equal_nan=True)
        module.check_gpu(family.params)   # the GPU runs each family of the default bank
        assert all(isinstance(a, np.ndarray) for a in module.work_arrays(4, 3, family.params, 2, True))


def test_an_unknown_kind_is_refused_by_name():
    with pytest.raises(ValueError, match="kind: expected one of 'cv', 'ca', 'ar', 'turn', 'ct', 'akf', got 'imm'"):
        parts("imm")
    with pytest.raises(ValueError, match="got 'imm'"):
        Family("imm", None)


def test_a_compiled_rule_has_the_specs_state_fields_and_reads_only_its_parameters():
    from kalmix.core.compiled.rules import COMPILED_RULES

    assert set(COMPILED_RULES) == set(aggregators.RULES)
    for name, module in aggregators.RULES.items():
        assert COMPILED_RULES[name].state._fields == module.State._fields, name
        assert set(COMPILED_RULES[name].params._fields) <= set(module.Params._fields), name


def test_no_engine_branches_on_a_family_kind():
    """The engines reach a family's parts through the registry (kalmix.core.families.KINDS)."""
    branch = re.compile(r"\.kind\s*(==|!=|in\b|not in\b)")
    for name in ("engine.py", "compiled/engine.py", "compiled/block.py", "compiled/gpu.py", "compiled/gpu_staged.py",
                 "compiled/_warm.py"):
        found = [line for line in (CORE / name).read_text().splitlines() if branch.search(line)]
        assert not found, (name, found)
