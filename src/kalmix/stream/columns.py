"""Which columns of a table are the track id, the time and the positions (re-exported by :mod:`kalmix.streaming`)."""

from __future__ import annotations


class ColumnNoteWarning(UserWarning):
    """What :meth:`TrackPredictor.process_table` found, or did not find, among a table's columns (the notes
    ``kalmix predict`` prints: no track id column, no time column, an id taken from a column's name)."""


def find_columns(header, *, time: str | None = None, positions=None, track_id: str | None = None,
                 sample=None):
    """The id, time and position columns of a table with the column names ``header``: how ``kalmix predict``
    finds them, and :meth:`TrackPredictor.process_table` when a table does not name them ``track_id`` and
    ``time``.

    :func:`kalmix.io.detect_columns` (names given win); ``track_id="none"`` (not a column):
    one track; with no id column named or detected, :func:`guess_id`; then
    :func:`kalmix.io.tables.check_output_names`.

    Parameters
    ----------
    sample : callable, optional
        ``sample(names, rows)``: the first ``rows`` rows of those columns (a DataFrame), to tell
        whether an unused column holds track ids; None: by names only.

    Returns
    -------
    (TrackColumns, list of str)
        The columns and the notes a user should hear (``kalmix predict`` prints them on stderr,
        ``process_table`` warns them as :class:`ColumnNoteWarning`).
    """
    import dataclasses

    from ..io.columns import check_output_names, column_notes, detect_columns

    header = [str(c) for c in header]
    single = track_id is not None and track_id.strip().lower() == "none" and track_id not in header
    columns = detect_columns(header, time=time, positions=positions, track_id=None if single else track_id)
    notes = []
    if single:
        columns = dataclasses.replace(columns, track_id=None)
    elif columns.track_id is None:
        columns, notes = guess_id(columns, header, sample)
    check_output_names(columns)
    return columns, notes + column_notes(columns, header, single_track=single)


def guess_id(columns, header, sample=None):
    """``columns`` with the unused column taken as the track id when exactly one is named like one (vessel,
    player_id, ...; a note says so); a ``ValueError`` naming them when unused columns look like ids otherwise
    (repeated words, whole numbers that tell apart rows of one time or change where the positions jump) or when
    several are named so: without an id every row would be one track, the tracks' rows mixed, and never
    silently. Returns the columns and the notes."""
    from ..io.columns import ID_SAMPLE_ROWS, detect_columns, id_candidates

    unused = [name for name in header if name not in {columns.time, *columns.positions}]
    if not unused:
        return columns, []
    wanted = [*unused, *([columns.time] if columns.time else []), *columns.positions]
    rows = sample(wanted, ID_SAMPLE_ROWS) if sample else None
    found = id_candidates(columns, header, rows)
    named = [name for name, why in found if why == "its name"]
    if len(named) == 1:
        note = (f"note: no track id column named or detected: taking {named[0]!r} as the track id, from its name "
                "(--id COLUMN to choose another, --id none for one track)")
        return detect_columns(header, time=columns.time, positions=columns.positions, track_id=named[0]), [note]
    if found:
        which = "; ".join(f"{name!r} ({why})" for name, why in found[:4]) + ("; ..." if len(found) > 4 else "")
        looks = "these columns look" if len(found) > 1 else "a column looks"
        raise ValueError(f"no track id column named or detected, and {looks} like one: {which}. Without an id "
                         f"every row is one track, the tracks' rows mixed: pass --id {found[0][0]}, or --id none "
                         "if the input holds a single track")
    return columns, []


def names_argument(names, where: str = "position_names") -> tuple | None:
    """A ``position_names`` argument as a tuple (one text: one name; None as it is); ``TypeError`` for what is not
    a sequence of names (a number, say, which ``tuple()`` would call not iterable)."""
    if names is None:
        return None
    if isinstance(names, str):
        return (names,)
    try:
        return tuple(names)
    except TypeError:
        raise TypeError(f"{where}: expected a sequence of column names, got {type(names).__name__} "
                        f"{names!r:.80}") from None
