"""The declared parameter constraints (kalmix.core.constraints): each type takes what it should, refuses the rest
with a TypeError (wrong type) or a ValueError (out of range, wrong shape) naming the parameter, what was expected
and what came; and the components' declarations are the ones make_bank and make_params apply."""

import dataclasses
import math
import re
from fractions import Fraction

import numpy as np
import pytest

from kalmix.bank import make_bank, make_params
from kalmix.core.aggregators import RULES
from kalmix.core.calibration import CalibrationParams
from kalmix.core.constraints import Boolean, Choice, Integer, Levels, Pair, Real, validate, validate_options
from kalmix.core.families.ar import ARParams
from kalmix.core.families.kinematic import KinematicParams
from kalmix.core.families.turn import TurnParams
from kalmix.core.lead import LeadParams
from kalmix.core.mixture import MAX_SEED, MixtureParams
from kalmix.core.screen import ScreenParams


@pytest.mark.parametrize("constraint, value, expected", [
    (Real(gt=0), 2, 2.0),
    (Real(gt=0), np.float32(0.5), 0.5),
    (Real(gt=0), Fraction(1, 4), 0.25),
    (Real(ge=0), 0, 0.0),
    (Real(gt=0, le=1.0), 1.0, 1.0),
    (Real(ge=0, lt=1), 0.0, 0.0),
    (Real(gt=1, inf_ok=True), math.inf, math.inf),
    (Real(gt=1, inf_ok=True), 10**400, math.inf),   # an integer past float's range is infinite
    (Real(ge=1e-60, le=1e60), 1e60, 1e60),
])
def test_real_takes_numbers_in_range_as_floats(constraint, value, expected):
    got = validate("x", value, constraint)
    assert got == expected and type(got) is float


@pytest.mark.parametrize("constraint, value, error, message", [
    (Real(gt=0), 0, ValueError, r"x: expected a finite number > 0, got 0$"),
    (Real(gt=0), -1.5, ValueError, r"x: expected a finite number > 0, got -1.5$"),
    (Real(gt=0), math.inf, ValueError, r"x: expected a finite number > 0, got inf$"),
    (Real(gt=0), math.nan, ValueError, r"x: expected a finite number > 0, got nan$"),
    (Real(gt=0), 10**400, ValueError, r"x: expected a finite number > 0, got 1000"),
    (Real(ge=0), -0.1, ValueError, r"x: expected a finite number >= 0, got -0.1$"),
    (Real(gt=0, le=1.0), 1.5, ValueError, r"x: expected a finite number in \(0, 1.0\], got 1.5$"),
    (Real(ge=0, lt=1), 1, ValueError, r"x: expected a finite number in \[0, 1\), got 1$"),
    (Real(ge=0, le=1.0), np.float64(2.0), ValueError, r"x: expected a finite number in \[0, 1.0\], got 2.0$"),
    (Real(gt=1, inf_ok=True, hint="inf: off"), 1, ValueError, r"x: expected a number > 1 \(inf: off\), got 1$"),
    (Real(gt=1, inf_ok=True), -math.inf, ValueError, r"x: expected a number > 1, got -inf$"),
    (Real(gt=1, inf_ok=True), math.nan, ValueError, r"x: expected a number > 1, got nan$"),
    (Real(gt=0, lt=1, noun="a probability"), 0.0, ValueError, r"x: expected a probability in \(0, 1\), got 0.0$"),
    (Real(ge=1e-60, le=1e60, noun="a number"), 1e61, ValueError, r"x: expected a number in \[1e-60, 1e\+60\]"),
    (Real(gt=0), "3", TypeError, r"x: expected a finite number > 0, got str '3'$"),
    (Real(gt=0), True, TypeError, r"x: expected a finite number > 0, got bool True$"),
    (Real(gt=0), np.bool_(True), TypeError, r"x: expected a finite number > 0, got (numpy\.)?bool_? True$"),
    (Real(gt=0), None, TypeError, r"x: expected a finite number > 0, got NoneType None$"),
    (Real(gt=0), [1.0], TypeError, r"x: expected a finite number > 0, got list \[1.0\]$"),
])
def test_real_refuses_by_name(constraint, value, error, message):
    with pytest.raises(error, match=message):
        validate("x", value, constraint)


def test_integer():
    assert validate("n", np.int64(3), Integer(ge=1)) == 3 and type(validate("n", np.int64(3), Integer(ge=1))) is int
    assert validate("seed", MAX_SEED, Integer(ge=0, le=MAX_SEED)) == MAX_SEED
    assert validate("order", 2.0, Integer(ge=1, integral_floats=True)) == 2
    for value, error, message in (
            (0, ValueError, r"n: expected an integer >= 1, got 0$"),
            (2.5, TypeError, r"n: expected an integer >= 1, got float 2.5$"),
            (2.0, TypeError, r"n: expected an integer >= 1, got float 2.0$"),   # a float is not an integer here
            (True, TypeError, r"n: expected an integer >= 1, got bool True$"),
            ("3", TypeError, r"n: expected an integer >= 1, got str '3'$")):
        with pytest.raises(error, match=message):
            validate("n", value, Integer(ge=1))
    with pytest.raises(ValueError, match=r"seed: expected an integer in \[0, 2\*\*63 - 1\], got 9223372036854775808"):
        validate("seed", MAX_SEED + 1, Integer(ge=0, le=MAX_SEED))
    for value in (1.5, math.inf, math.nan, 0.0):
        with pytest.raises(ValueError, match="order: expected an integer >= 1, got"):
            validate("order", value, Integer(ge=1, integral_floats=True))


def test_choice_and_boolean():
    assert validate("rule", "boa", Choice(("boa", "mlpoly"))) == "boa"
    with pytest.raises(ValueError, match=r"rule: expected one of 'boa', 'mlpoly', got 'x'$"):
        validate("rule", "x", Choice(("boa", "mlpoly")))
    with pytest.raises(ValueError, match=r"rule: expected one of 'boa', got array\(\[1, 2\]\)"):
        validate("rule", np.array([1, 2]), Choice(("boa",)))   # no single truth value: refused, not an error of ==
    assert validate("bias", np.bool_(True), Boolean()) is True
    for value in (1, "yes", None):
        with pytest.raises(TypeError, match=rf"bias: expected a bool, got {type(value).__name__}"):
            validate("bias", value, Boolean())


def test_pair_and_levels():
    assert validate("r", (1, 2.5), Pair(Real(gt=0))) == (1.0, 2.5)
    assert validate("r", np.array([3.0, 1.0]), Pair(Real(gt=0))) == (3.0, 1.0)   # the order is the caller's rule
    assert validate("q", np.array([0.5, 2.0]), Levels(Real(gt=0))) == [0.5, 2.0]
    assert validate("orders", (1, 2.0), Levels(Integer(ge=1, integral_floats=True))) == [1, 2]
    for value in (5, "ab", (1, 2, 3), [[1, 2], [3, 4]], {1: 2, 3: 4}):
        with pytest.raises(ValueError, match=r"r: expected a pair \(low, high\) of numbers > 0, got"):
            validate("r", value, Pair(Real(gt=0)))
    with pytest.raises(ValueError, match=r"r\[1\]: expected a finite number > 0, got -1$"):
        validate("r", (1, -1), Pair(Real(gt=0)))
    with pytest.raises(TypeError, match=r"r\[0\]: expected a finite number > 0, got bool True$"):
        validate("r", (True, 1), Pair(Real(gt=0)))
    for value in (0.1, "abc", [[1.0, 2.0]], {0.5, 1.0}, (x for x in (1.0,)), np.array(1.0)):
        with pytest.raises(ValueError, match=r"q: expected a sequence of numbers in \(0, 1.0\], got"):
            validate("q", value, Levels(Real(gt=0, le=1.0)))
    with pytest.raises(ValueError, match="q: expected at least one value, got none"):
        validate("q", [], Levels(Real(gt=0)))
    with pytest.raises(ValueError, match=r"q\[2\]: expected a finite number > 0, got nan$"):
        validate("q", [1.0, 2.0, math.nan], Levels(Real(gt=0)))
    with pytest.raises(ValueError, match=r"orders: expected a sequence of integers >= 1, got 3$"):
        validate("orders", 3, Levels(Integer(ge=1)))


def test_validate_options_names_the_option_with_its_prefix():
    constraints = {"share": Real(ge=0, lt=1), "bias": Boolean()}
    assert validate_options({"share": 0, "bias": True}, constraints, "opts", "the thing") == {"share": 0.0,
                                                                                                "bias": True}
    assert validate_options({}, constraints, "opts", "the thing") == {}
    with pytest.raises(ValueError, match=r"opts\['share'\]: expected a finite number in \[0, 1\), got 1$"):
        validate_options({"share": 1}, constraints, "opts", "the thing")
    with pytest.raises(TypeError, match=r"opts\['bias'\]: expected a bool, got int 1$"):
        validate_options({"bias": 1}, constraints, "opts", "the thing")
    with pytest.raises(ValueError, match=r"opts: \['lag', 'x'\] not options of the thing "
                                         r"\(expected some of \['share', 'bias'\]\)"):
        validate_options({"x": 1, "lag": 2, "share": 0.5}, constraints, "opts", "the thing")
    with pytest.raises(TypeError, match=r"opts: expected a dict of the options of the thing, got list"):
        validate_options([("share", 0.5)], constraints, "opts", "the thing")


def test_constraints_are_class_attributes_not_fields():
    """A declaration adds nothing to the values: not a field, not in the repr, equal tuples stay equal."""
    for params in (*(module.Params for module in RULES.values()), ARParams, TurnParams, KinematicParams,
                   ScreenParams, CalibrationParams, LeadParams):
        assert "CONSTRAINTS" not in params._fields
        assert set(params.CONSTRAINTS) <= set(params._fields), params
    assert "CONSTRAINTS" not in {f.name for f in dataclasses.fields(MixtureParams)}
    assert set(MixtureParams.CONSTRAINTS) <= {f.name for f in dataclasses.fields(MixtureParams)}
    assert all(set(module.Params.CONSTRAINTS) == set(module.Params._fields) for module in RULES.values())
    assert "CONSTRAINTS" not in repr(ScreenParams()) and ScreenParams() == (1000.0, 3, 5, 50)


@pytest.mark.parametrize("rule", list(RULES))
def test_make_bank_checks_rule_options_against_the_rules_declaration(rule):
    """Every option of every rule is refused out of its declared range, under its prefixed name; the default
    value of each is taken."""
    params = RULES[rule].Params
    bank = make_bank(2, "kinematic", rule=rule, rule_options=params()._asdict())
    assert bank.rule_params == params()
    for name, constraint in params.CONSTRAINTS.items():
        bad = constraint.ge - 0.5 if constraint.ge is not None else constraint.gt
        with pytest.raises(ValueError, match=rf"rule_options\['{name}'\]: expected .*, got {bad}"):
            make_bank(2, "kinematic", rule=rule, rule_options={name: bad})
        with pytest.raises(TypeError, match=rf"rule_options\['{name}'\]: expected .*, got str 'x'"):
            make_bank(2, "kinematic", rule=rule, rule_options={name: "x"})


def test_make_bank_checks_ar_options_against_the_ar_declaration():
    """ar_options are ARParams' fields with a default, each checked by its declaration."""
    names = [name for name in ARParams._field_defaults]
    with pytest.raises(ValueError, match=re.escape(f"ar_options: ['order'] not options of the AR family (expected "
                                                   f"some of {names!r})")):
        make_bank(2, "ar", ar_options={"order": 2})
    for name in names:
        with pytest.raises(TypeError, match=rf"ar_options\['{name}'\]: expected"):
            make_bank(2, "ar", ar_options={name: "x"})
    for name, bad in (("persistence", -1), ("initial_error", 0), ("jump_threshold", -math.inf), ("window", 0.5),
                      ("max_step", math.inf), ("max_velocity", math.nan)):
        with pytest.raises(ValueError, match=rf"ar_options\['{name}'\]: expected a (finite )?number"):
            make_bank(2, "ar", ar_options={name: bad})


def test_the_heads_declarations_name_the_arguments_of_make_bank():
    for kwargs, error, message in (
            (dict(outlier_threshold=0.5), ValueError, r"outlier_threshold: expected a number > 1 \(inf: no screen\)"),
            (dict(outlier_rejects=0), ValueError, "outlier_rejects: expected an integer >= 1, got 0"),
            (dict(outlier_rejects="x"), TypeError, "outlier_rejects: expected an integer >= 1, got str 'x'"),
            (dict(level=1), ValueError, r"level: expected a probability in \(0, 1\), got 1$"),
            (dict(lead=-2.0), ValueError, r"lead: expected a finite number > 0 \(time-column units\), got -2.0"),
            (dict(lead=3.0, lead_delay=0), ValueError,
             r"lead_delay: expected a finite number >= 1 \(rows between a forecast and its score\), got 0"),
            (dict(kind="kinematic", process_levels=[1.0, 0.0]), ValueError,
             r"process_levels\[1\]: expected a finite number > 0, got 0.0"),
            (dict(kind="turn", turn_gains=[math.nan]), ValueError, r"turn_gains\[0\]: expected a finite number >= 0")):
        with pytest.raises(error, match=message):
            make_bank(2, **kwargs)
    assert make_bank(2, outlier_threshold=10**400).screen_params.threshold == math.inf   # off, as inf


def test_make_params_checks_its_arguments_against_the_mixture_declaration():
    with pytest.raises(ValueError, match=r"noise_reinflation: expected a finite number in \[0, 1.0\], got 1.5"):
        make_params(2, noise_reinflation=1.5)
    with pytest.raises(ValueError, match=r"initial_variance_range: expected low <= high, got \(3.0, 2.0\)"):
        make_params(2, initial_variance_range=(3.0, 2.0))
    with pytest.raises(ValueError, match="prior_degree: expected one of 0, 1, got 2"):
        make_params(2, order=2, prior_degree=2)   # a rule between order and prior_degree
    assert make_params(2, order=3, prior_degree=2).order == 3
