"""What a parameter may be, declared once beside it, and the one function that checks a value against it.

A component declares the constraints of the parameters a caller sets next to its ``Params`` NamedTuple, as a
plain class attribute ``CONSTRAINTS = {field: constraint}`` (in the spirit of scikit-learn's
``_parameter_constraints``). A class attribute without a type annotation is not a field of a NamedTuple (nor of
a dataclass): it adds nothing to the tuple's values, repr, equality or pickles, nor to what the compiled kernels
see, which type a NamedTuple by its fields. So the knowledge of what a forgetting factor or a screen threshold
may be stays with the component that uses it, and the recipes (:mod:`kalmix.bank`) check what a caller gives
through :func:`validate` and :func:`validate_options`; the core itself checks nothing at run time.

Each constraint checks one value. A rule between parameters (``low <= high`` in a pair, a choice that depends
on another argument) is not a constraint: the recipe checks it explicitly.

Errors name the parameter (with its prefix: ``rule_options['share']``), say what was expected and what came:
``TypeError`` for a value of the wrong type (a bool is not a number), ``ValueError`` for one out of range or of
the wrong shape.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Mapping, Set

import numpy as np

__all__ = ["Real", "Integer", "Choice", "Boolean", "Pair", "Levels", "validate", "validate_options"]

#: The longest repr of a refused value an error message shows.
SHOWN_LENGTH = 200


def _shown(value) -> str:
    text = repr(value.item() if isinstance(value, np.generic) else value)
    return text if len(text) <= SHOWN_LENGTH else text[:SHOWN_LENGTH] + "..."


def _bound(value) -> str:
    """A bound as written in a message: ``1.0``, ``1e-60``; a 64-bit limit as ``2**63 - 1``."""
    if isinstance(value, int) and value > 2**32 and (value + 1) & value == 0:
        return f"2**{value.bit_length()} - 1"
    return repr(value)


def _range(ge, gt, le, lt) -> str:
    low = ("[", ge) if ge is not None else ("(", gt) if gt is not None else None
    high = ("]", le) if le is not None else (")", lt) if lt is not None else None
    if low and high:
        return f"in {low[0]}{_bound(low[1])}, {_bound(high[1])}{high[0]}"
    if low:
        return f"{'>=' if low[0] == '[' else '>'} {_bound(low[1])}"
    if high:
        return f"{'<=' if high[0] == ']' else '<'} {_bound(high[1])}"
    return ""


def _type_error(name, expected, value) -> TypeError:
    return TypeError(f"{name}: expected {expected}, got {type(value).__name__} {_shown(value)}")


def _value_error(name, expected, value) -> ValueError:
    return ValueError(f"{name}: expected {expected}, got {_shown(value)}")


def _within(x, ge, gt, le, lt) -> bool:
    return ((ge is None or x >= ge) and (gt is None or x > gt) and (le is None or x <= le)
            and (lt is None or x < lt))


@dataclasses.dataclass(frozen=True)
class Real:
    """A real number (not a bool) within the bounds given (``gt``, ``ge``, ``lt``, ``le``), returned as a float.

    NaN is refused; so is an infinity, unless ``inf_ok`` (``+inf`` meaning "off", e.g. a clip or a threshold):
    an integer past the float range counts as infinite. ``noun`` replaces "a finite number" ("a number" with
    ``inf_ok``) in the message, ``hint`` is added after the range in parentheses.
    """

    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    inf_ok: bool = False
    noun: str | None = None
    hint: str | None = None

    @property
    def range(self) -> str:
        return _range(self.ge, self.gt, self.le, self.lt)

    @property
    def expected(self) -> str:
        noun = self.noun or ("a number" if self.inf_ok else "a finite number")
        return " ".join(filter(None, (noun, self.range))) + (f" ({self.hint})" if self.hint else "")

    @property
    def plural(self) -> str:
        return " ".join(filter(None, ("numbers", self.range))) + (f" ({self.hint})" if self.hint else "")

    def check(self, name: str, value) -> float:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
            raise _type_error(name, self.expected, value)
        try:
            x = float(value)
        except OverflowError:   # an integer past float's range
            x = math.inf if value > 0 else -math.inf
        if math.isnan(x) or (math.isinf(x) and not (self.inf_ok and x > 0)) \
                or not _within(x, self.ge, self.gt, self.le, self.lt):
            raise _value_error(name, self.expected, value)
        return x


@dataclasses.dataclass(frozen=True)
class Integer:
    """An integer (not a bool) within ``ge`` .. ``le``, returned as an int; with ``integral_floats``, a float
    with a whole value (``2.0``) is taken too."""

    ge: int | None = None
    le: int | None = None
    integral_floats: bool = False

    @property
    def range(self) -> str:
        return _range(self.ge, None, self.le, None)

    @property
    def expected(self) -> str:
        return " ".join(filter(None, ("an integer", self.range)))

    @property
    def plural(self) -> str:
        return " ".join(filter(None, ("integers", self.range)))

    def check(self, name: str, value) -> int:
        if isinstance(value, (bool, np.bool_)):
            raise _type_error(name, self.expected, value)
        if self.integral_floats and isinstance(value, numbers.Real) and not isinstance(value, numbers.Integral):
            if not (math.isfinite(value) and float(value).is_integer()):
                raise _value_error(name, self.expected, value)
        elif not isinstance(value, numbers.Integral):
            raise _type_error(name, self.expected, value)
        if not _within(value, self.ge, None, self.le, None):
            raise _value_error(name, self.expected, value)
        return int(value)


@dataclasses.dataclass(frozen=True)
class Choice:
    """One of ``values`` (compared with ``==``, as ``in`` does)."""

    values: tuple

    @property
    def expected(self) -> str:
        return f"one of {', '.join(map(repr, self.values))}"

    def check(self, name: str, value):
        try:
            known = value in self.values
        except (TypeError, ValueError):   # an array: no single truth value
            known = False
        if not known:
            raise _value_error(name, self.expected, value)
        return value


@dataclasses.dataclass(frozen=True)
class Boolean:
    """``True`` or ``False`` (a numpy bool too, not an integer), returned as a bool."""

    expected = "a bool"

    def check(self, name: str, value) -> bool:
        if not isinstance(value, (bool, np.bool_)):
            raise _type_error(name, self.expected, value)
        return bool(value)


def _items(value):
    """The items of a flat sequence (a list, a tuple, a 1-D array), or None for anything else."""
    if isinstance(value, (str, bytes, Mapping, Set)):   # text, or no order
        return None
    try:
        items = list(value) if hasattr(value, "__len__") else None
    except TypeError:   # a 0-d array
        return None
    if items is None or any(_nested(v) for v in items):
        return None
    return items


def _nested(item) -> bool:
    """An item that is itself a sequence (a sequence of them is not flat)."""
    if isinstance(item, np.ndarray):
        return item.ndim > 0
    return hasattr(item, "__len__") and not isinstance(item, (str, bytes))


@dataclasses.dataclass(frozen=True)
class Pair:
    """A pair ``(low, high)`` of values of ``element``, returned as a tuple (the order of the two is the
    caller's rule to check)."""

    element: Real | Integer

    @property
    def expected(self) -> str:
        return f"a pair (low, high) of {self.element.plural}"

    def check(self, name: str, value) -> tuple:
        items = _items(value)
        if items is None or len(items) != 2:
            raise _value_error(name, self.expected, value)
        return tuple(self.element.check(f"{name}[{i}]", v) for i, v in enumerate(items))


@dataclasses.dataclass(frozen=True)
class Levels:
    """A non-empty flat sequence of values of ``element`` (a list, a tuple, a 1-D array), returned as a list."""

    element: Real | Integer

    @property
    def expected(self) -> str:
        return f"a sequence of {self.element.plural}"

    def check(self, name: str, value) -> list:
        items = _items(value)
        if items is None:
            raise _value_error(name, self.expected, value)
        if not items:
            raise ValueError(f"{name}: expected at least one value, got none")
        return [self.element.check(f"{name}[{i}]", v) for i, v in enumerate(items)]


def validate(name: str, value, constraint):
    """``value`` checked against ``constraint`` and converted (a float for :class:`Real`, ...); a ``TypeError``
    or ``ValueError`` naming ``name`` otherwise."""
    return constraint.check(name, value)


def validate_options(options, constraints: Mapping, prefix: str, owner: str) -> dict:
    """A dict of options checked against ``constraints`` (name -> constraint), converted; each value is named
    ``prefix[name]`` in an error, and an option without a constraint is refused, naming ``owner``."""
    if not isinstance(options, Mapping):
        raise _type_error(prefix, f"a dict of the options of {owner}", options)
    unknown = [key for key in options if key not in constraints]
    if unknown:
        raise ValueError(f"{prefix}: {sorted(unknown, key=str)} not options of {owner} (expected some of "
                         f"{list(constraints)})")
    return {key: validate(f"{prefix}[{key!r}]", value, constraints[key]) for key, value in options.items()}
