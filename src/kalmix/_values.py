"""Measurements as the predictors take them (one place for :class:`kalmix.TrackPredictor` and
:class:`kalmix.MixturePredictor`)."""

from __future__ import annotations

import numpy as np

__all__ = ["measurements"]


def measurements(values, width: int | None = None) -> np.ndarray:
    """Positions as float64, with pandas' NA and None as NaN (a missing measurement) as in a table, and a masked
    array's masked values too (``np.asarray`` would keep the value under the mask, to be learned).
    ``TypeError`` for booleans (rather than taking them as 1 and 0), ``ValueError``/``TypeError`` for what is not
    numbers."""
    if _has_booleans(values):
        raise TypeError(f"expected numbers, got booleans {values!r:.80}")
    values = _missing_rows(values, width)
    if isinstance(values, np.ma.MaskedArray) or (isinstance(values, (list, tuple)) and any(
            isinstance(row, np.ma.MaskedArray) for row in values)):   # a list of masked rows keeps their masks
        return np.ma.asarray(values, dtype=np.float64).filled(np.nan)
    try:
        return np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        import pandas as pd

        given = np.asarray(values, dtype=object)
        missing = np.asarray(pd.isna(given), dtype=bool)
        if not missing.any():
            raise
        return np.where(missing, np.nan, given).astype(np.float64)


def _missing_rows(values, width: int | None = None):
    """A list of rows in which some rows are None (a missing row, as ``step(None)``): those rows as NaN, as wide as
    the others (which must agree), or ``width`` wide (the caller's number of coordinates) when every row is None;
    anything else as given."""
    if not isinstance(values, (list, tuple)) or not any(row is None for row in values):
        return values
    rows = [row for row in values if row is not None]
    widths = {np.shape(row) for row in rows}
    if rows and len(widths) == 1 and len(next(iter(widths))) == 1:
        width = next(iter(widths))[0]
    elif rows or width is None:   # scalars (a row's missing coordinates), ragged rows, or no width known
        return values
    return [[np.nan] * width if row is None else row for row in values]


def _has_booleans(values, depth: int = 0) -> bool:
    """Whether ``values`` (a scalar, an array, a pandas object, nested lists of rows) holds a boolean."""
    if isinstance(values, (bool, np.bool_)):
        return True
    dtype = getattr(values, "dtype", None)
    if dtype is not None and getattr(dtype, "kind", None) == "b":   # numpy bool, pandas' "boolean"
        return True
    if dtype is not None and getattr(dtype, "kind", None) == "O":
        return any(isinstance(v, (bool, np.bool_)) for v in np.asarray(values, dtype=object).flat)
    if isinstance(values, (list, tuple)) and depth < 2:
        return any(_has_booleans(v, depth + 1) for v in values)
    return False
