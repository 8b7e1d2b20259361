"""A track's clock that restarts in a file (times 0 .. 49, then 0 .. 49 again), found as a chunk is read."""

from __future__ import annotations

import numpy as np
import pandas as pd


class ClockResets:
    """A track's clock that restarts (times 0 .. 49, then 0 .. 49 again), found in file order: sorting its rows
    by time would interleave the two runs (half of them then repeated timestamps), so the rows from the restart
    on are moved past the ones before it instead, by a step of ``step(usual)`` (``usual``: the track's
    median step in the chunk) after the last time before it: a gap that starts a new segment. The output
    keeps the times as given (:class:`AsGiven`); the table's times are the moved ones.

    A restart is a step back by more than :attr:`FACTOR` usual steps, to a time inside the range of the run
    before it (not a block of earlier rows that comes late: those are sorted into place), followed by steps
    forward of at most :attr:`FACTOR` usual steps (at least two, or as many as the chunk holds when a chunk
    follows it: a later chunk cannot move the rows of this one). State across a file's chunks: each track's
    shift, last time and the first time of its current clock (:meth:`resume` takes them from an earlier run).
    ``found``: the chunk's restarts, ``(place, track, time before, time after)``.
    """

    FACTOR = 3.0

    def __init__(self, step):
        self.step = step
        self.tracks: dict = {}   # track -> [shift, last time as given, first time of its current clock]
        self.found: list = []
        self.resumed: set = set()   # tracks of a resumed run's state not yet seen in this one
        self.more = False   # a chunk of the file comes after this one

    def resume(self, track, clock) -> None:
        """Go on with ``track``'s clock ``[shift, last time as given, first time of its current clock]`` saved by
        an earlier run: its rows that go on after that last time are moved by that shift. Its first row in this
        run at or before that time (the file read again from its start) drops it: the restarts are found again."""
        self.tracks[track] = [float(v) for v in clock]
        self.resumed.add(track)

    def apply(self, out: pd.DataFrame, named) -> pd.DataFrame:
        """``out`` (rows in file order, ``out.index`` their rows in the chunk) with each restarted clock's rows
        moved; ``named(row)``: where a row is, for :attr:`found`."""
        self.found = []
        if out.empty:
            return out
        raw = out["time"].to_numpy(np.float64)
        codes, uniques = pd.factorize(out["track_id"], sort=False)
        firsts = np.full(len(uniques), -1, dtype=np.int64)
        firsts[codes[::-1]] = np.arange(len(codes))[::-1]
        steps = pd.Series(raw).groupby(codes, sort=False).diff().to_numpy()
        look = np.zeros(len(uniques), dtype=bool)
        look[codes[steps < 0]] = True
        shift = np.zeros(len(uniques))
        for c, track in enumerate(uniques.tolist()):
            if track in self.resumed:
                self.resumed.discard(track)
                if raw[firsts[c]] <= self.tracks[track][1]:
                    del self.tracks[track]
            known = self.tracks.get(track)
            if known is not None:
                shift[c] = known[0]
                look[c] |= raw[firsts[c]] < known[1]
        moved = raw + shift[codes]
        values = out.drop(columns=["track_id", "time"]).to_numpy(np.float64)
        for c in np.flatnonzero(look):
            rows = np.flatnonzero(codes == c)
            moved[rows] = self._track(uniques[c], raw[rows], values[rows], out.index.to_numpy()[rows], named)
        highest = pd.Series(raw).groupby(codes, sort=False).agg(["min", "max"]).to_numpy()
        for c, track in enumerate(uniques.tolist()):   # each track's last time and current clock, for later chunks
            if look[c]:
                continue
            known = self.tracks.get(track)
            if known is None:
                self.tracks[track] = [0.0, highest[c, 1], highest[c, 0]]
            else:
                known[1], known[2] = max(known[1], highest[c, 1]), min(known[2], highest[c, 0])
        if not self.found and not shift.any():
            return out
        out = out.copy()
        out["time"] = moved
        return out

    def _track(self, track, times, values, places, named) -> np.ndarray:
        """One track's times in a chunk (file order) with its restarts moved; updates its state. Not a restart:
        a track whose rows go back at more than one step in ten (rows in no order, sorted as they are), or a run
        that repeats rows before it (the same time and positions: a block given twice)."""
        shift, last, start = self.tracks.get(track, [0.0, None, None])
        steps = np.diff(times)
        forward = steps[steps > 0]
        usual = float(np.median(forward)) if forward.size and 10 * int((steps < 0).sum()) <= len(times) else None
        out = np.empty(len(times))
        judged = 0   # rows before this are judged (a run of rows that came late is one block, sorted into place)
        for j, time in enumerate(times):
            if j >= judged and last is not None and usual is not None and last - time > self.FACTOR * usual:
                run = j + 1
                while run < len(times) and times[run - 1] < times[run] <= times[run - 1] + self.FACTOR * usual:
                    run += 1
                judged = run
                again = np.flatnonzero(times[:j] == time)
                again = again.size and all(np.array_equal(values[k], values[j], equal_nan=True) for k in again)
                # goes on (two steps forward, or forward up to the chunk's last row of the track when a chunk
                # follows, which cannot move rows already read), inside the earlier clock's range
                if (run > j + 2 or (self.more and run == len(times))) and times[run - 1] >= start and not again:
                    self.found.append((named(int(places[j])), track, float(last), float(time)))
                    shift = last + shift + float(self.step(usual)) - time
                    last = start = time
            out[j] = time + shift
            last = time if last is None else max(last, time)
            start = time if start is None else min(start, time)
        self.tracks[track] = [shift, last, start]
        return out
