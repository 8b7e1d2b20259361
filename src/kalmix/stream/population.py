"""The population prior: a new track's rule starts from what the tracks before it learned.

A track of a dozen rows spends them learning which experts to trust; the tracks before it, from the same
sensor and of the same kind of target, already showed it. So a new track's BOA state is not empty: it is
the population's mean state per learned row, times :data:`POPULATION_ROWS` — as if the track had already
learned that many rows like the average of the tracks before it. Its own rows then count as much as those
pseudo-rows after :data:`POPULATION_ROWS` of them, and more and more after that. Its calibration (the experts'
error variances, their counts and the intervals' scale) starts as the population's mean calibration state
(``StreamConfig.calibration_prior``): a dozen-row track's intervals are then as wide as the tracks before it
found they should be, not set by the length unit and learned over the track's few rows.

**Which tracks, when.** The population is summarised at fixed points of the stream: after its first
:data:`FIRST_SNAPSHOT` rows, then after twice as many, and so on up to every :data:`SNAPSHOT_EVERY` rows
(the rows stepped, in the order they came, counted from the first row the predictor ever saw, across
chunks, calls and resumed state files; a row skipped for its time does not count). A track whose first row
comes after a point starts from the summary made there; before the first point, from an empty state (the
rule's own start). The summary takes every track with at least :data:`MIN_ROWS` learned rows. Defined by
rows, not by calls, it gives the same numbers whether a file is read in one table, in chunks, or row by row.
A table (a file's chunk) makes only the summaries a track could start from (:meth:`PopulationPrior.plan_summaries`):
the same numbers, fewer pieces to step.

On by default (``StreamConfig(population_prior=False)``, ``kalmix predict --no-population-prior`` start every
track empty); not with Dask, whose partitions do not see each other's tracks. ``kalmix predict`` steps a file
chunk by chunk, each chunk's tracks one after another: it cuts a chunk in file order where a summary falls
(:meth:`PopulationPrior.summary_cuts`), so that a file, any of its chunkings and the same rows on stdin learn the
same bits. BOA (the default rule) and BOA-blend have a prior (:data:`PRIOR_FIELDS`); a bank with another rule
starts every track empty.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .ids import factorize_ids, id_to_json

__all__ = ["POPULATION_ROWS", "MIN_ROWS", "FIRST_SNAPSHOT", "SNAPSHOT_EVERY", "PRIOR_FIELDS", "Prior", "prior_paths",
           "prior_width", "prior_parts", "snapshot_points", "summarise", "start_rule", "start_calibration",
           "start_state", "PopulationPrior"]

#: Pseudo-rows of the population a new track starts with (the weight of the prior, in rows of the track's own).
POPULATION_ROWS = 100
#: A track takes part in the population once it has learned this many rows.
MIN_ROWS = 3
#: The first summary is made after this many rows of the stream; the next after twice as many, and so on ...
FIRST_SNAPSHOT = 32
#: ... up to one every this many rows.
SNAPSHOT_EVERY = 65536
#: Tracks whose states are read at once for a summary.
SUMMARY_BATCH = 4096
#: The most errors a new track's calibration counts the population's mean variances as (its own errors weigh as
#: much after as many of them). A track started from the prior carries its count into the next summary, so the
#: mean count would climb towards the calibration's window, and a track noisier than the population's would keep
#: too narrow intervals for most of its rows.
CALIBRATION_ERRORS = 10


#: The rules a population prior starts, and the fields of their states it starts: groups of (regret, variance,
#: bound), each ``(N, width)``; a prior holds the groups side by side (BOA-blend: its two rules' and its blend's).
PRIOR_FIELDS = {"boa": (("regret", "variance", "bound"),),
                "boa_blend": (("regret", "variance", "bound"), ("exact_regret", "exact_variance", "exact_bound"),
                              ("blend_regret", "blend_variance", "blend_bound"))}


def prior_paths(bank, lead: bool = True) -> tuple:
    """The rule states a prior starts, as paths in a :class:`~kalmix.core.engine.BankState`: the one-step rule's
    and, with a lead head and ``lead`` (``StreamConfig.lead_prior``), the lead weights' and their blend's
    (:mod:`kalmix.core.lead`), which learn a track's H-step errors H rows late, and would start each track even,
    however the tracks before it went."""
    return (("rule",),) + ((("lead", "rule"), ("lead", "blend")) if bank.lead is not None and lead else ())


def _at(state, path):
    for name in path:
        state = getattr(state, name)
    return state


def _with(state, path, value):
    if not path:
        return value
    return state._replace(**{path[0]: _with(getattr(state, path[0]), path[1:], value)})


def _widths(rule_name: str, rule_state) -> list[int]:
    return [getattr(rule_state, group[0]).shape[-1] for group in PRIOR_FIELDS[rule_name]]


def prior_width(bank, lead: bool = True) -> int:
    """The length of the arrays of a prior of ``bank`` (its rule's groups of every path of :func:`prior_paths`);
    0 for a rule without one."""
    if bank.rule not in PRIOR_FIELDS:
        return 0
    from ..core.engine import init_bank_state

    state = init_bank_state(bank, 1)
    return sum(sum(_widths(bank.rule, _at(state, path))) for path in prior_paths(bank, lead))


def prior_parts(bank, state, lead: bool = True) -> tuple:
    """``(regret, variance, bound)`` of a :class:`~kalmix.core.engine.BankState` as a prior takes them: the groups
    of each of its rule states (:func:`prior_paths`) side by side, ``(N, width)``."""
    groups = PRIOR_FIELDS[bank.rule]
    states = [_at(state, path) for path in prior_paths(bank, lead)]
    return tuple(np.concatenate([getattr(rule, group[i]) for rule in states for group in groups], axis=-1)
                 for i in range(3))


class Prior(NamedTuple):
    """What a new track's BOA state starts from: :data:`POPULATION_ROWS` times the population's mean per row; and
    its calibration: the population's mean calibration state."""

    regret: np.ndarray     # (K,)
    variance: np.ndarray   # (K,)
    bound: np.ndarray      # (K,) the population's median range bound
    tracks: int            # tracks summarised
    calibration: tuple | None = None   # (variance (K, p), count (K,), log_scale (1,)), or None (not kept)


def _canonical(track) -> tuple:
    """A key that orders every track id (text, numbers, dates) the same way, whatever its type."""
    return type(track).__name__, repr(track)


def snapshot_points(done: int, upto: int) -> list[int]:
    """The summary points ``P`` with ``done < P <= upto`` (rows of the stream, see the module)."""
    points = []
    p = FIRST_SNAPSHOT
    while p < SNAPSHOT_EVERY and p <= upto:
        if p > done:
            points.append(p)
        p *= 2
    k = max(1, done // SNAPSHOT_EVERY + 1)
    while k * SNAPSHOT_EVERY <= upto:
        points.append(k * SNAPSHOT_EVERY)
        k += 1
    return points


def summarise(parts) -> Prior | None:
    """The prior from ``parts``, an iterable of ``(regret (n, K), variance (n, K), bound (n, K), rows (n,))``:
    BOA states of tracks and the rows each learned (the sums' bits depend on the order of the tracks), each with a
    fifth item, the tracks' calibration states ``(variance (n, K, p), count (n, K), log_scale (n,))``, to keep
    their mean too. None when no track has :data:`MIN_ROWS` rows."""
    regret = variance = calibration = None
    bounds = []
    count = 0
    for part in parts:
        r, v, b, rows = part[:4]
        rows = np.asarray(rows, dtype=np.float64)
        use = rows >= MIN_ROWS
        if not use.any():
            continue
        scale = 1.0 / rows[use, None]
        r_sum = (np.asarray(r)[use] * scale).sum(axis=0)
        v_sum = (np.asarray(v)[use] * scale).sum(axis=0)
        regret = r_sum if regret is None else regret + r_sum
        variance = v_sum if variance is None else variance + v_sum
        bounds.append(np.asarray(b)[use])
        count += int(use.sum())
        if len(part) > 4:
            sums = tuple(np.asarray(a)[use].sum(axis=0) for a in part[4])
            calibration = sums if calibration is None else tuple(a + s for a, s in zip(calibration, sums))
    if not count:
        return None
    if calibration is not None:
        calibration = tuple(np.atleast_1d(a / count) for a in calibration)
    return Prior(regret / count * POPULATION_ROWS, variance / count * POPULATION_ROWS,
                 np.median(np.concatenate(bounds), axis=0), count, calibration)


def start_calibration(calibration, prior: Prior | None):
    """``calibration`` (a fresh :class:`~kalmix.core.calibration.CalibrationState`, n targets) as the population's
    mean calibration state of ``prior`` (unchanged without one): a new track's intervals start as wide as the
    tracks before it learned they should be, counted as their mean number of errors, at most
    :data:`CALIBRATION_ERRORS`."""
    if prior is None or prior.calibration is None:
        return calibration
    n = calibration.log_scale.shape[0]
    variance, count, log_scale = prior.calibration
    count = np.minimum(count, float(CALIBRATION_ERRORS))
    return type(calibration)(np.broadcast_to(variance, (n, *variance.shape)).copy(),
                             np.broadcast_to(count, (n, *count.shape)).copy(), np.broadcast_to(log_scale, (n,)).copy())


def start_rule(rule_state, prior: Prior | None, rule_name: str = "boa", offset: int = 0):
    """``rule_state`` (a fresh state of rule ``rule_name``, n targets) starting from ``prior`` (unchanged without
    one), its part from ``offset`` on."""
    if prior is None:
        return rule_state
    n = rule_state.regret.shape[0]
    values, start = {}, offset
    for group, width in zip(PRIOR_FIELDS[rule_name], _widths(rule_name, rule_state)):
        for name, value in zip(group, (prior.regret, prior.variance, prior.bound)):
            values[name] = np.broadcast_to(value[start:start + width], (n, width)).copy()
        start += width
    return rule_state._replace(**values)


def start_state(bank, state, prior: Prior | None, lead: bool = True):
    """``state`` (a fresh :class:`~kalmix.core.engine.BankState`) with each rule state of :func:`prior_paths`
    started from its part of ``prior``, and its one-step calibration from the prior's, if it keeps one."""
    if prior is None:
        return state
    offset = 0
    for path in prior_paths(bank, lead):
        rule = _at(state, path)
        state = _with(state, path, start_rule(rule, prior, bank.rule, offset))
        offset += sum(_widths(bank.rule, rule))
    return state._replace(calibration=start_calibration(state.calibration, prior))


class PopulationPrior:
    """The part of :class:`~kalmix.streaming.TrackPredictor` that keeps its population prior: every track's learned
    rows (:attr:`track_rows`), the summaries made so far (:attr:`priors`), new tracks started from the last."""

    @property
    def prior(self) -> Prior | None:
        """The population prior a new track starts from now (None: the rule's own start)."""
        if not self.priors or self.params is None or self.params.rule not in PRIOR_FIELDS:
            return None
        return self.priors[-1]

    def with_prior(self, state):
        """``state`` (new tracks' :class:`~kalmix.core.engine.BankState`) with its rule started from :attr:`prior`."""
        return start_state(self.params, state, self.prior, self.config.lead_prior)

    @property
    def stepped(self) -> int:
        """Rows stepped so far (given and not skipped): the clock of the summaries."""
        return self.rows - self.skipped

    def summary_within(self, n_rows: int) -> bool:
        """Whether a summary may fall within the next ``n_rows`` rows (if all are stepped)."""
        return bool(self.config.population_prior and self.config.rule in PRIOR_FIELDS and n_rows > 0
                    and snapshot_points(self.stepped, self.stepped + n_rows))

    def summary_cuts(self, ids, times) -> list[int]:
        """Of these rows, in arrival order (continuing the tracks seen), the counts after which a summary is
        made before the next row: the places to cut them, where the rows before a cut must all be stepped before
        any after it (the last row, after which the summary comes anyway, is not a cut). Skipped rows do not
        count: a resumed run given again the rows it did skips them. Points whose summary no track would start
        from are not summaries (:meth:`plan_summaries`)."""
        if not self.summary_within(len(times) - 1):   # (a point at the last row is not a cut)
            return []
        stepped = self.stepped_rows(ids, times)
        ends = np.flatnonzero(stepped) + 1   # rows given up to each stepped row
        points = snapshot_points(self.stepped, self.stepped + len(ends))
        at = {p: int(ends[p - self.stepped - 1]) for p in points}   # (a point at the last row: len(times))
        self.plan_summaries(ids, stepped, at)
        return [cut for p, cut in at.items() if self.summary_plan[p] and cut < len(times)]

    def plan_summaries(self, ids, stepped, at: dict) -> None:
        """Decide, for each summary point ``p`` of these rows (``at``: point -> the rows before it), whether its
        summary is made (:attr:`summary_plan`; a point an outer call decided keeps its decision): the last one
        (a new track after these rows may start from it), and each after which a new track starts before the next
        point, once a track may have taken part (:data:`MIN_ROWS` rows; before, the summary is empty anyway).
        A summary no track starts from changes no number, and each summary cuts the rows there: a file's
        100 tracks of 1,000 rows, all started in its first rows, were stepped in 13 pieces for 12 summaries no
        track used. So the forecasts are the same bits as a stream's of the same rows, which makes every
        summary; :attr:`priors` holds fewer."""
        todo = [p for p in at if p not in self.summary_plan]
        if not todo:
            return
        index, uniques = factorize_ids(np.asarray(ids, dtype=object) if not isinstance(ids, np.ndarray) else ids)
        rows = np.flatnonzero(stepped)
        keys = [id_to_json(u) for u in uniques]
        first = np.full(len(uniques), len(stepped))
        np.minimum.at(first, index[rows], rows)
        starts = np.sort(first[[u for u, key in enumerate(keys) if key not in self.states and first[u] < len(stepped)]])
        if self.priors or max(self.track_rows.values(), default=0) >= MIN_ROWS:
            ready = 0   # (one takes part already; a new track starts with the prior's pseudo-rows)
        else:   # the rows after which a track may have MIN_ROWS rows (each stepped row is learned at most)
            order = np.argsort(index[rows], kind="stable")
            grouped = index[rows][order]
            rank = np.arange(len(order)) - np.searchsorted(grouped, grouped)   # each row's place in its track
            seen = np.array([self.track_rows.get(key, 0) for key in keys])
            there = rank + 1 + seen[grouped] >= MIN_ROWS
            ready = int(rows[order][there].min()) + 1 if there.any() else len(stepped) + 1
        points = sorted(at)
        for i, p in enumerate(points):
            if p in todo:
                nxt = at[points[i + 1]] if i + 1 < len(points) else len(stepped)
                new = np.searchsorted(starts, at[p]) < np.searchsorted(starts, nxt)
                self.summary_plan[p] = bool(i == len(points) - 1 or (at[p] >= ready and new))

    def count_rows(self, tracks, lengths) -> None:
        """Count the rows ``tracks`` learned; a new track that started from the prior counts its pseudo-rows too
        (its state holds them)."""
        if not self.config.population_prior:
            return
        start = POPULATION_ROWS if self.prior is not None else 0
        for track, n in zip(tracks, lengths):
            self.track_rows[track] = self.track_rows.get(track, start) + int(n)

    def summarise_if_due(self, before: int) -> None:
        """After stepping rows (:attr:`stepped` was ``before``): a summary if a point was reached that
        :attr:`summary_plan` does not leave out."""
        reached = snapshot_points(before, self.stepped)
        made = [p for p in reached if self.summary_plan.pop(p, True)]
        for p in [p for p in self.summary_plan if p <= self.stepped]:   # (points passed: decided for nothing now)
            del self.summary_plan[p]
        if not self.config.population_prior or not made:
            return
        if self.params is None or self.params.rule not in PRIOR_FIELDS:
            return
        # in one order whatever order the tracks were stored in (a Parquet chunk sorted by id, a new track cut by a
        # gap, a resumed state file): a floating-point sum depends on the order of its terms
        tracks = sorted((t for t in self.states if self.track_rows.get(t, 0) >= MIN_ROWS), key=_canonical)

        def parts():   # a batch of tracks at a time: their rule and calibration states only are kept
            for begin in range(0, len(tracks), SUMMARY_BATCH):
                these = tracks[begin:begin + SUMMARY_BATCH]
                state = self.states.gather(these, self._new_states)
                yield (*prior_parts(self.params, state, self.config.lead_prior), [self.track_rows[t] for t in these],
                       *((tuple(state.calibration),) if self.config.calibration_prior else ()))

        prior = summarise(parts())
        if prior is not None:
            self.priors.append(prior)
            self.states.share_as_new(self._fresh())
