"""A file's time and position columns as float64: numbers, ISO 8601 date-times and durations as seconds (dates
since 1970 UTC), the same bits from a file and from stdin; and why a value that is none of these is bad."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd

MISSING_TEXT = frozenset({"", "nan", "na", "n/a", "nan.0", "null", "none", "<na>", "nat"})


def iso_seconds(text, errors: str = "raise") -> np.ndarray:
    """Seconds since 1970-01-01 UTC of a sequence of ISO 8601 date-time texts (no offset = UTC);
    ``ValueError`` naming the first value that is not such text or is outside 1677-2262 (the nanosecond
    clock's range); ``errors="coerce"``: NaN there. Counted in nanoseconds whatever the text's precision, element
    by element, and shared by the file and stdin paths, so both give the same bits for the same text. ``now``
    and ``today``, which pandas reads as the clock's time, are not dates of the data; nor is a minute or second of
    one digit (``08:5``, a cut ``08:50``, which pandas reads as 08:05)."""
    series = pd.Series(list(text), dtype=object)
    given = series.notna().to_numpy()
    texts = series.astype(str).str.strip()
    words = (texts.str.lower().isin(("now", "today")) | texts.str.contains(r":\d(?!\d)", regex=True)).to_numpy() & given
    when = pd.to_datetime(series.where(~words), format="ISO8601", utc=True, errors="coerce")
    low, high = pd.Timestamp.min.tz_localize("UTC"), pd.Timestamp.max.tz_localize("UTC")
    outside = ((when < low) | (when > high)).to_numpy()
    bad = given & (when.isna().to_numpy() | outside | words)
    if bad.any() and errors == "raise":
        raise ValueError(f"not an ISO 8601 date-time between 1677 and 2262: {series[int(np.argmax(bad))]!r}")
    when = when.where(~(outside | words)).dt.as_unit("ns")
    return _seconds_of(when - pd.Timestamp(0, tz="UTC"))


def _seconds_of(delta: pd.Series) -> np.ndarray:
    """Float seconds of a Series of durations (NaT: NaN): the whole seconds and their fraction (of the same
    sign), each exact from the column's integer ticks, added: the float nearest the duration, or its neighbour
    where the two roundings meet. Dividing the nanoseconds as one float, as pandas does, loses up to ~2.4e-7 s
    on dates of this century (2^61 ns), enough for a gap rule to split a track of regular date-times where the
    same times as numbers do not."""
    unit = delta.dt.unit   # the column's own unit: converting to ns would overflow beyond 292 years
    per_second = {"s": 1, "ms": 1_000, "us": 1_000_000, "ns": 1_000_000_000}[unit]
    missing = delta.isna().to_numpy()
    ticks = np.where(missing, 0, delta.to_numpy(f"timedelta64[{unit}]").view(np.int64))
    # whole seconds and fraction of the same sign (toward zero), so that they add without cancelling
    whole = np.sign(ticks) * (np.abs(ticks) // per_second)
    seconds = whole.astype(np.float64) + (ticks - whole * per_second).astype(np.float64) / per_second
    return np.where(missing, np.nan, seconds)


def read_floats(s: pd.Series, dates: bool = False, kind: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A column as float64 (NaN where missing or bad) and which of its rows hold a bad value: text that is
    not a number, an infinity; in a time column (``dates``), text that is neither a number nor an ISO 8601
    date-time (read as seconds since 1970 UTC, :func:`iso_seconds`), or a value of the other kind than the
    column's: numbers and date-times do not mix, and the column's first time decides which it holds (kept in
    ``kind["kind"]``, so that a file's later chunks, or a stream's later rows, follow its first)."""
    kind = {} if kind is None else kind
    if pd.api.types.is_datetime64_any_dtype(s):
        epoch = pd.Timestamp(0, tz=getattr(s.dt, "tz", None))
        return _seconds_of(s - epoch), np.zeros(len(s), dtype=bool)
    if pd.api.types.is_timedelta64_dtype(s):
        return _seconds_of(s), np.zeros(len(s), dtype=bool)
    if pd.api.types.is_numeric_dtype(s) and not pd.api.types.is_bool_dtype(s):
        out = s.to_numpy(np.float64, na_value=np.nan)
        bad = np.isinf(out)
        if dates and "kind" not in kind and (~np.isnan(out)).any():
            kind["kind"] = "number"
        if bad.any():
            out = np.where(bad, np.nan, out)
        return out, bad
    out = pd.to_numeric(s.astype(object), errors="coerce").to_numpy(np.float64, na_value=np.nan)
    bad = np.isinf(out)
    unread = np.isnan(out) & s.notna().to_numpy()
    if unread.any():   # (the text only then: most columns are numbers)
        text = s.astype(str).str.strip().str.lower()
        unread &= ~text.isin(MISSING_TEXT).to_numpy()
    if dates:
        numbers = ~np.isnan(out) & ~bad
        seconds = np.full(len(s), np.nan)
        if unread.any():
            seconds[unread] = iso_seconds(s[unread].astype(object), errors="coerce")
        dated = ~np.isnan(seconds)
        if "kind" not in kind and (numbers | dated).any():
            first = int(np.argmax(numbers | dated))
            kind["kind"] = "number" if numbers[first] else "date-time"
        if kind.get("kind") == "date-time":
            bad |= numbers | (unread & ~dated)
            out = seconds
        else:
            bad |= unread
    else:
        bad |= unread
    if bad.any():
        out = np.where(bad, np.nan, out)
    return out, bad


def bad_value(s: pd.Series, i: int, name: str, dates: bool = False, kind: dict | None = None) -> str:
    """Why row ``i`` of a column is bad (:func:`read_floats`), in a few words that name the column and the value."""
    value = s.iloc[i:i + 1].tolist()[0]
    try:
        number = float(str(value).strip())
    except ValueError:
        number = None
    if dates:
        column = (kind or {}).get("kind")
        if column == "date-time" and number is not None and np.isfinite(number):
            return (f"column {name!r} holds a number ({value!r}) where its first time is a date-time; expected one "
                    "or the other")
        if column == "number" and isinstance(value, str) and not np.isnan(iso_seconds([value], errors="coerce")[0]):
            return (f"column {name!r} holds a date-time ({value!r}) where its first time is a number; expected one "
                    "or the other")
        if number is None or column == "date-time":
            return (f"column {name!r} must hold a number or an ISO 8601 date-time (like 2024-05-01T12:00:00.5Z), "
                    f"got {value!r}")
    if number is not None:
        return f"column {name!r} must be finite, got {value!r}"
    return f"column {name!r} must hold a number, got {value!r}"


def to_float(s: pd.Series, name: str, offset: int, dates: bool = False) -> np.ndarray:
    """Column to float64; ValueError at the first value that is not a number. ``dates``: a text column of
    ISO 8601 date-times is read as seconds since 1970 UTC (:func:`iso_seconds`), as a datetime column is."""
    if pd.api.types.is_datetime64_any_dtype(s):
        epoch = pd.Timestamp(0, tz=getattr(s.dt, "tz", None))
        return _seconds_of(s - epoch)
    if pd.api.types.is_timedelta64_dtype(s):
        return _seconds_of(s)
    if pd.api.types.is_numeric_dtype(s) and not pd.api.types.is_bool_dtype(s):
        out = s.to_numpy(np.float64, na_value=np.nan)
        bad = np.isinf(out)
    else:
        out = pd.to_numeric(s.astype(object), errors="coerce").to_numpy(np.float64, na_value=np.nan)
        bad = np.isinf(out)
        unread = np.isnan(out) & s.notna().to_numpy()
        if unread.any():   # (the text only then: most columns are numbers)
            text = s.astype(str).str.strip().str.lower()
            bad |= unread & ~text.isin(MISSING_TEXT).to_numpy()
    if bad.any() and dates and np.isnan(out).all():
        missing = s.isna().to_numpy() | s.astype(str).str.strip().str.lower().isin(MISSING_TEXT).to_numpy()
        text = s.where(~missing).astype(object)
        try:
            return iso_seconds(text)
        except (ValueError, TypeError, OverflowError):   # name the first value that is not a date-time
            undated = np.isnan(iso_seconds(text, errors="coerce")) & ~missing
            bad = undated if undated.any() else bad
    elif bad.any() and dates and not np.isnan(out).all():
        dated = ~np.isnan(iso_seconds(s.where(bad).astype(object), errors="coerce"))
        if dated.any():   # numbers and date-times in one column
            i, j = int(np.argmax(~np.isnan(out))), int(np.argmax(dated))
            raise ValueError(f"Column {name!r} mixes numbers (row {offset + i}: {s.iloc[i]!r}) and ISO 8601 "
                             f"date-times (row {offset + j}: {s.iloc[j]!r}); expected one or the other")
    if bad.any():
        i = int(np.argmax(bad))
        what = "finite numbers (or, for a time column, ISO 8601 date-times like 2024-05-01T12:00:00.5Z)" \
            if dates else "finite numbers"
        raise ValueError(
            f"Column {name!r} must hold {what}; row {offset + i} (counted from 0 after the "
            f"header) holds {s.iloc[i:i + 1].tolist()[0]!r}. Empty cells and 'nan' are read as "
            "missing measurements.")
    return out


_LONE_SURROGATE = re.compile("[\ud800-\udfff]")
#: UTF-16's byte order marks (little, big endian).
UTF16_BOMS = (b"\xff\xfe", b"\xfe\xff")
#: The first bytes of gzip-compressed data.
GZIP_MAGIC = b"\x1f\x8b"


def utf16_without_bom(data: bytes) -> str | None:
    """``"utf-16le"`` or ``"utf-16be"`` (``iconv``'s names) when ``data``, the start of a text, looks like UTF-16
    without a byte order mark: a zero byte in at least 3 of 4 of the places of one parity (the high bytes of
    Latin text), none in the other; else None."""
    low, high = data[0::2], data[1::2]
    for zeros, letters, name in ((high, low, "utf-16le"), (low, high, "utf-16be")):
        if len(zeros) >= 2 and 4 * zeros.count(0) >= 3 * len(zeros) and 0 not in letters:
            return name
    return None


def not_unicode(text) -> bool:
    """Whether ``text`` holds a lone surrogate: bytes that were not UTF-8, decoded with ``surrogateescape`` (or
    a JSON ``\\udce9`` escape), which no UTF-8 output can write."""
    return isinstance(text, str) and not text.isascii() and _LONE_SURROGATE.search(text) is not None


def guess_encoding(data: bytes) -> tuple[str, str, str]:
    """What bytes that are not UTF-8 may be: the encoding's ``iconv`` name, its common name and ``data`` read in it.
    UTF-16 when they start with its byte order mark, else Windows-1252 (Windows exports), Latin-1 where that
    cannot read them."""
    if data.startswith(UTF16_BOMS):
        source, label = "utf-16", "UTF-16"
    else:
        try:
            data.decode("cp1252")
            source, label = "cp1252", "Windows-1252"
        except UnicodeDecodeError:
            source, label = "latin1", "Latin-1"
    return source, label, data.decode(source, "replace").replace("\ufeff", "")


def as_bytes(text: str) -> bytes:
    """The bytes a text with lone surrogates (:func:`not_unicode`) was decoded from (``surrogateescape``); a
    surrogate that stands for no byte (a JSON escape) as UTF-8 with ``backslashreplace``."""
    try:
        return text.encode("utf-8", "surrogateescape")
    except UnicodeEncodeError:
        return text.encode("utf-8", "backslashreplace")


def not_utf8(name, text: str, where: str | None = None) -> tuple[str, str]:
    """Why a value ``text`` of column ``name`` (or of ``where``: "the header") with lone surrogates
    (:func:`not_unicode`) is wrong, naming its bytes and what they read as in the encoding they are likely in
    (:func:`guess_encoding`); and that encoding's ``iconv`` name, to say how to convert the input."""
    data = as_bytes(text)
    source, label, shown = guess_encoding(data)
    where = f"column {name!r}" if where is None else where
    return f"{where} holds bytes that are not UTF-8, {data!r} ({shown!r} if they are {label})", source
