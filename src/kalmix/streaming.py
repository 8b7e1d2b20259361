"""Many tracks, one mixture predictor each: the engine behind ``kalmix predict``.

Two ways in, the same numbers out:

- :meth:`TrackPredictor.step_row` takes one measurement of one track at a time (the
  stdin streaming mode: a prediction is returned as soon as its measurement arrives);
  :meth:`TrackPredictor.step_rows` takes the rows that have already arrived (of any tracks)
  with the same results bit for bit, through one run of the core;
- :meth:`TrackPredictor.process_table` takes a track table (or one chunk of a big
  file) and steps every track segment present in it at once through the batched core.

Each track segment is an independent stream: batching only changes how the arithmetic
is grouped, and the two paths agree to rounding.

Time gaps
---------
The CV/CA experts run in real time (they predict across any time step); the paper's
AKFs are frame-based (consecutive rows of a track are consecutive frames whatever their
time stamps; a missing frame should be a row with NaN positions). A time step larger
than the *gap threshold* starts a new **segment**: the track's experts start again from
the row after the gap (a halftime, a lost GPS fix, a camera cut: the motion before it
says little about the motion after it), while the aggregation rule and the calibration
keep what they learned on the track (a warm start, :func:`kalmix.core.engine.run`'s
``restart``). The threshold is ``max_gap`` (in the time column's units)
when given, else ``max_gap_factor`` (3) times the track's *reference interval*, taken from
the first (up to 16) positive time steps of the track (a gap among them too, so that one
short first step cannot make every later step a gap; once it has 16, a gap's step does not
change it): their upper quartile (the 13th in increasing order of 16) times their spread,
the upper quartile over the lower quartile (the 5th), to the power 1.5. On regular sampling
it is the step; where the sampling itself is spread (steps of 5 to 60 s, or of 10 s to 10
min drawn at random) it lies beyond the long steps, so the sampling is not taken for gaps
and the track stays one segment, while an outage many times the usual steps still starts a
new segment.
The rule is causal (it only looks at rows already seen), so a row-by-row stream and a
whole file give the same segments, and it survives a ``--state`` save and resume.

What is predicted
-----------------
After each row, ``pred_<pos>`` is the forecast for the time of the track's **next row**
and ``std_<pos>`` its calibrated standard deviation (:mod:`kalmix.core.calibration`):
in a table, the next row's time is known (:meth:`TrackPredictor.process_table` takes the
times of the rows that follow the table, ``next_times``); for a track's last row, and
always in :meth:`TrackPredictor.step_row` (which must answer before the next row exists),
it is the time one reference interval later. With a ``lead`` L, ``lead_<pos>`` /
``lead_std_<pos>`` forecast ``time + L`` with weights and intervals learned on lead-L
errors (:mod:`kalmix.core.lead`); a ``horizon`` H > 1 is the lead of H time units
(columns ``pred<H>_<pos>`` / ``std<H>_<pos>``).

A row whose time is not after its track's previous time (out of order or a repeated
timestamp) cannot be undone in a stream: it is skipped and counted in
:attr:`TrackPredictor.skipped`; the first one that :meth:`~TrackPredictor.step_row`,
:meth:`~TrackPredictor.step_rows` or :meth:`~TrackPredictor.process_table` skips gives a
:class:`SkippedRowWarning` (a sensor clock
that restarts would otherwise skip every later row of its track in silence). (File inputs
are sorted and de-duplicated when read, see :mod:`kalmix.io.tables`.)

One exception keeps a single wrong timestamp from costing the rest of a track: when a
track's previous row *jumped ahead* (a gap, or the track's first row) and the next row
comes back to a time between the time before the jump and the jump, the jump was a wrong
timestamp (a clock glitch, a typo in a feed). The track's first step has no reference
interval to be judged by, so it counts as such a jump only when it is more than
``max_gap_factor`` times the step the next row implies (``0, 1e9, 1``: yes, and its
interval is taken back out of the reference; ``0, 1, 0.5``: no, 0.5 is skipped). The track's
clock goes back to the new row, which continues the jump's segment (no row is skipped),
and the event is counted in :attr:`GapTracker.glitches` (:attr:`TrackPredictor.time_glitches`).
Without this, every later row of the track would be "before its previous time" and skipped.

Transactions
------------
:meth:`~TrackPredictor.step_row` and :meth:`~TrackPredictor.process_table` change the
predictor only when they return: an exception (``KeyboardInterrupt`` included) in the
middle leaves every track, counter and gap tracker as it was.
:meth:`~TrackPredictor.checkpoint` / :meth:`~TrackPredictor.rollback` extend that over
several calls (``kalmix predict`` rolls a whole chunk back when interrupted).
"""

from __future__ import annotations

from .stream.bank_runs import BACKENDS as BACKENDS
from .stream.bank_runs import check_backend as check_backend
from .stream.columns import ColumnNoteWarning, find_columns, guess_id
from .stream.config import GAP_REFERENCES, StreamConfig
from .stream.gaps import REFERENCE_INTERVALS as REFERENCE_INTERVALS
from .stream.gaps import GapTracker, SkippedRowWarning
from .stream.gaps import short_median as short_median
from .stream.ids import id_to_json
from .stream.predictor import Checkpoint, TrackPredictor, learned_sampling, learned_time_unit
from .stream.row_steps import RowPrediction
from .stream.state_file import STATE_FORMAT_VERSION
from .stream.table_steps import TRACK_BATCH as TRACK_BATCH
from .stream.table_steps import with_input_names
from .stream.times import next_row_times
from .stream.units import (IRREGULAR_REACH, LengthUnitWarning, auto_length_unit, auto_reach, auto_time_unit,
                           estimate_length_unit,
                           gap_floor_for_steps, length_unit_fallback, length_unit_rule, reach_for_steps)

__all__ = ["StreamConfig", "TrackPredictor", "RowPrediction", "GapTracker", "SkippedRowWarning", "Checkpoint",
           "LengthUnitWarning", "ColumnNoteWarning", "estimate_length_unit", "length_unit_fallback", "find_columns",
           "guess_id", "auto_length_unit", "length_unit_rule", "auto_time_unit", "learned_time_unit", "next_row_times",
           "learned_sampling", "auto_reach", "reach_for_steps", "IRREGULAR_REACH", "gap_floor_for_steps",
           "id_to_json", "with_input_names", "STATE_FORMAT_VERSION", "GAP_REFERENCES"]
