"""The compiled kernels' arithmetic for the reference engine: sums and matrix products in index order,
and the C library's ``exp``, ``log``, ``sin``, ``cos`` and ``atan2`` element by element.

The compiled kernels call the C library's functions (numba lowers ``math.exp`` and the others
to them); numpy's own vectorised ``np.exp``, ``np.sin``, ... may differ from them in the last
bit. The reference families and rules use these instead, so that both engines compute the
same bits wherever they also add in the same order: an ulp of difference in a weight, summed
over thousands of rows by a rule's regret, becomes a visible one. They are slower than
numpy's; the reference engine runs small inputs.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["ordered_sum", "ordered_matmul", "first_max", "exp", "expm1", "log", "sin", "cos", "atan2"]


def ordered_sum(a, axis: int = -1, keepdims: bool = False, from_zero: bool = True):
    """Sum over ``axis`` term by term in index order from 0.0, ``((0 + a_0) + a_1) + ...``: the compiled kernels'
    ``acc = 0.0; acc += ...`` (``a.sum`` adds in pairs and blocks, which rounds differently). ``from_zero=False``
    starts from the first term, ``(a_0 + a_1) + ...``, for the kernels that do; the two differ only in the sign
    of a sum of -0.0 terms."""
    total = np.take(np.add.accumulate(a, axis=axis), -1, axis=axis)
    if from_zero:
        total = 0.0 + total
    return np.expand_dims(total, axis) if keepdims else total


def first_max(a, axis: int = -1):
    """Index of the largest entry along ``axis`` as the kernels scan for it: from entry 0, moving on only to a
    strictly larger one (so the first of equal ones; a NaN is never larger, and a NaN entry 0 stays)."""
    a = np.moveaxis(np.asarray(a, dtype=np.float64), axis, -1)
    index = np.argmax(np.where(np.isnan(a), -np.inf, a), axis=-1)
    return np.where(np.isnan(a[..., 0]), 0, index)


def ordered_matmul(a, b):
    """``a @ b`` on the last two axes, each entry summed over the inner index in order from 0 (the compiled
    kernels' loops, ``acc = 0; acc += a[i, l] * b[l, j]``, which ``@`` need not follow)."""
    out = np.zeros(np.broadcast_shapes(a.shape[:-2], b.shape[:-2]) + (a.shape[-2], b.shape[-1]))
    for l in range(a.shape[-1]):
        out = out + a[..., :, l:l + 1] * b[..., l:l + 1, :]
    return out


def _or_inf(function):
    """``function`` giving inf where Python raises OverflowError (the C function gives inf)."""
    def apply(x):
        try:
            return function(x)
        except OverflowError:
            return math.inf
    apply.__name__ = function.__name__
    return apply


def _log_or_nan(x):
    if x > 0:
        return math.log(x)
    return -math.inf if x == 0 else math.nan


def _elementwise(function, arity=1):
    ufunc = np.frompyfunc(function, arity, 1)

    def apply(*arrays):
        with np.errstate(all="ignore"):   # inf and NaN results are the C functions' answers, not accidents
            out = ufunc(*(np.asarray(a, dtype=np.float64) for a in arrays))
        return np.asarray(out, dtype=np.float64)

    apply.__name__ = getattr(function, "__name__", "libm")
    apply.__doc__ = f"``{apply.__name__}`` of the C library, element by element."
    return apply


_exp_any, _log_any = _elementwise(_or_inf(math.exp)), _elementwise(_log_or_nan)
_exp_plain, _log_plain = _elementwise(math.exp), _elementwise(math.log)


def exp(a):
    """``exp`` of the C library, element by element (inf where it overflows)."""
    a = np.asarray(a, dtype=np.float64)
    return _exp_plain(a) if a.size and np.max(a, initial=-np.inf, where=~np.isnan(a)) < 709.0 else _exp_any(a)


def log(a):
    """``log`` of the C library, element by element (-inf at 0, NaN below)."""
    a = np.asarray(a, dtype=np.float64)
    return _log_plain(a) if a.size and np.min(a, initial=np.inf, where=~np.isnan(a)) > 0 else _log_any(a)


expm1 = _elementwise(_or_inf(math.expm1))


def _periodic(function):
    def apply(x):
        return function(x) if math.isfinite(x) else math.nan   # the C function's NaN (Python raises)
    apply.__name__ = function.__name__
    return apply


sin = _elementwise(_periodic(math.sin))
cos = _elementwise(_periodic(math.cos))
atan2 = _elementwise(math.atan2, 2)
