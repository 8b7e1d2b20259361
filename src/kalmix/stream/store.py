"""Every track's engine state, kept by rows of shared blocks (re-exported by :mod:`kalmix.streaming`)."""

from __future__ import annotations

import mmap
from collections.abc import Mapping

import numpy as np

from ..core.engine import BankState, tree_leaves, tree_map


def _same_rows(array: np.ndarray) -> bool:
    """Whether every row (first axis) of ``array`` holds the bits of its first row (NaN payloads and the sign of
    zero included)."""
    if len(array) <= 1:
        return True
    flat = np.ascontiguousarray(array).reshape(len(array), -1)
    if flat.dtype.kind == "f":
        flat = flat.view(np.int64 if flat.dtype.itemsize == 8 else np.uint8)
    return bool((flat == flat[:1]).all())


#: A block whose own rows (the leaves not shared) hold at least this many bytes keeps them in a memory map of its
#: own: the engine's arrays of a run live only until the next, and the allocator would keep the holes they leave
#: among the blocks' (which live as long as their tracks) as memory of the process.
OWN_MEMORY_BYTES = 1 << 20


def _own_memory(arrays: list) -> list:
    """Read-only copies of ``arrays`` in one anonymous memory map (unmapped when the last of them is freed)."""
    offsets, total = [], 0
    for array in arrays:
        offsets.append(total)
        total += -(-array.nbytes // 64) * 64
    memory = np.frombuffer(mmap.mmap(-1, max(total, 1)), dtype=np.uint8)
    copies = []
    for array, at in zip(arrays, offsets):
        copy = memory[at:at + array.nbytes].view(array.dtype).reshape(array.shape)
        copy[...] = array
        copy.flags.writeable = False
        copies.append(copy)
    return copies


def _bits(array: np.ndarray) -> np.ndarray | None:
    """``array`` viewed as unsigned integers of its item size (floats compared bit for bit: NaN payloads and the
    sign of zero included); None for an item size that has none."""
    if array.dtype.kind not in "fc":
        return array
    if array.dtype.itemsize not in (1, 2, 4, 8):
        return None
    return array.view(f"u{array.dtype.itemsize}")


def _alike_along(array: np.ndarray) -> np.ndarray:
    """``array`` (rows of tracks) with each axis after the first along which every row holds one value (bit for bit)
    cut to its first entry, keeping the axis (length 1): what broadcasts back to ``array``. Young tracks' experts
    of one family are alike (the autoregressive ones, before their histories fill)."""
    bits = _bits(array)
    if bits is None:
        return array
    cut = [slice(None)] * array.ndim
    for axis in range(1, array.ndim):
        if array.shape[axis] > 1 and bool((bits == bits.take([0], axis=axis)).all()):
            cut[axis] = slice(0, 1)
    return array[tuple(cut)]


class _Block:
    """Rows of many tracks' states, read only: per leaf (in :func:`tree_leaves` order) an ``(n, ...)`` array, or a
    ``(1, ...)`` one that every row shares (a leaf whose rows are all alike, e.g. as new: the AKF family's
    regression statistics before it learns); an axis along which every row holds one value is kept at length 1
    (it broadcasts to ``shapes``, each leaf's shape after the first axis)."""

    __slots__ = ("leaves", "shapes", "rows", "__weakref__")

    def __init__(self, state: BankState, template=None):
        leaves = [array for _, array in tree_leaves(state)]
        self.rows = len(leaves[0]) if leaves else 0
        self.shapes = [array.shape[1:] for array in leaves]
        shared = template or {}
        self.leaves = []
        for i, array in enumerate(leaves):
            if _same_rows(array):
                first = array[:1]
                known = shared.get(i)
                if (known is not None and known.dtype == first.dtype and known.shape == first.shape
                        and known.tobytes() == first.tobytes()):   # (the same bits, as _same_rows compares)
                    self.leaves.append(known)   # (one array for every track whose leaf is as new)
                else:
                    self.leaves.append(first.copy())
            else:
                cut = _alike_along(array)
                self.leaves.append(cut if cut.shape == array.shape else cut.copy())
        own = [i for i, array in enumerate(self.leaves) if len(array) > 1]
        if sum(self.leaves[i].nbytes for i in own) >= OWN_MEMORY_BYTES:
            for i, copy in zip(own, _own_memory([self.leaves[i] for i in own])):
                self.leaves[i] = copy


class TrackStates(Mapping):
    """Every track's engine state, kept by rows of shared blocks (:class:`_Block`): track id -> (block, row).

    A mapping of track id -> :class:`~kalmix.core.engine.BankState` of one target (each look-up a copy). A
    step reads its tracks' rows in one batch (:meth:`gather`) and stores the result's rows as one new block
    (:meth:`put`): no per-track arrays, and a leaf alike in every row of a block (as new, or a
    regularly sampled track's covariances) is kept once. Blocks are never changed, so a reference
    (:meth:`ref`) stays valid for :meth:`TrackPredictor.rollback`; once the blocks hold twice as many rows
    as there are tracks (plus :data:`COMPACT_SLACK`), the tracks' rows are copied into new blocks of
    :data:`COMPACT_BATCH` tracks, block by block (so that each old block is freed as soon as its tracks have
    moved, and no more than a batch of states is ever unpacked at once).
    """

    #: rows a store may hold beyond twice its tracks' before it compacts
    COMPACT_SLACK = 1024
    #: tracks a compaction copies at a time
    COMPACT_BATCH = 1024

    def __init__(self):
        self._where: dict = {}    # track -> (block, row), or None (a track known to have no state)
        self._live: dict = {}     # id(block) -> [block, tracks on it]
        self._rows = 0            # rows of the blocks in _live
        self._template = None     # (structure, {leaf index: (1, ...) array as new})

    # -- mapping ------------------------------------------------------------------------
    def __len__(self):
        return len(self._where)

    def __iter__(self):
        return iter(self._where)

    def __contains__(self, track):
        return track in self._where

    def __getitem__(self, track):
        ref = self._where[track]
        return None if ref is None else self._rebuild([ref], 1)

    def __setitem__(self, track, state):
        if state is None:
            self._set(track, None)
        else:
            self.put([track], state)

    def pop(self, track, default=None):
        if track not in self._where:
            return default
        value = self[track]
        self._set(track, None)
        del self._where[track]
        return value

    # -- references (checkpoints) ---------------------------------------------------------
    def ref(self, track):
        """What :meth:`restore` takes to return ``track`` to its present state (None: no state)."""
        return self._where.get(track)

    def restore(self, track, ref) -> None:
        if ref is None:
            if track in self._where:
                self._set(track, None)
                del self._where[track]
        else:
            self._set(track, ref)

    def _set(self, track, ref) -> None:
        old = self._where.get(track)
        if old is not None:
            entry = self._live[id(old[0])]
            entry[1] -= 1
            if not entry[1]:
                del self._live[id(old[0])]
                self._rows -= old[0].rows
        if ref is not None:
            entry = self._live.get(id(ref[0]))
            if entry is None:
                entry = self._live[id(ref[0])] = [ref[0], 0]
                self._rows += ref[0].rows
            entry[1] += 1
        self._where[track] = ref

    # -- batches ------------------------------------------------------------------------
    def gather(self, tracks, fresh) -> BankState:
        """The states of ``tracks`` stacked (a copy), new ones' from ``fresh(n)`` (:func:`init_bank_state`)."""
        refs = [self._where.get(t) for t in tracks]
        new = [c for c, ref in enumerate(refs) if ref is None]
        if len(new) == len(tracks):
            return fresh(len(tracks))
        if new:
            block = _Block(fresh(len(new)))
            for k, c in enumerate(new):
                refs[c] = (block, k)
        return self._rebuild(refs, len(tracks))

    def _rebuild(self, refs, n) -> BankState:
        structure = self._template[0]
        out = []
        blocks: dict = {}
        for c, (block, row) in enumerate(refs):
            entry = blocks.get(id(block))
            if entry is None:
                entry = blocks[id(block)] = (block, [], [])
            entry[1].append(c)
            entry[2].append(row)
        groups = [(block, np.array(columns), np.array(rows)) for block, columns, rows in blocks.values()]
        for i in range(len(groups[0][0].leaves)):
            parts = [block.leaves[i] for block, _, _ in groups]
            array = np.empty((n,) + groups[0][0].shapes[i], dtype=np.result_type(*parts))   # (as np.concatenate)
            for (block, columns, rows), part in zip(groups, parts):
                array[columns] = part if len(part) == 1 else part[rows]
            out.append(array)
        leaves = iter(out)
        return tree_map(lambda _: next(leaves), structure)

    def put(self, tracks, state: BankState, columns=None) -> None:
        """Store row ``columns[c]`` of ``state`` (default: row c) as the state of ``tracks[c]``."""
        if not len(tracks):
            return
        if self._template is None:
            self._template = (tree_map(lambda a: None if a is None else 0, state), {})
        if columns is not None and list(columns) != list(range(len(state.screen.time))):
            state = tree_map(lambda a: a[np.asarray(columns)], state)
        self._store(tracks, state)
        if self._rows > 2 * len(self._where) + self.COMPACT_SLACK:
            self._compact()

    def _store(self, tracks, state: BankState) -> None:
        block = _Block(state, self._template[1])
        for c, track in enumerate(tracks):
            self._set(track, (block, c))

    def shares_as_new(self) -> bool:
        return self._template is not None and bool(self._template[1])

    def share_as_new(self, state: BankState) -> None:
        """Keep the leaves of ``state`` (one new target's) to be shared by every track whose leaf is as new."""
        if self._template is None:
            self._template = (tree_map(lambda a: 0, state), {})
        self._template[1].clear()
        self._template[1].update({i: array[:1].copy() for i, (_, array) in enumerate(tree_leaves(state))})

    def _compact(self) -> None:
        order = {key: k for k, key in enumerate(self._live)}   # the tracks block by block, each block's in row order
        tracks = sorted((t for t, ref in self._where.items() if ref is not None),
                        key=lambda t: (order[id(self._where[t][0])], self._where[t][1]))
        for begin in range(0, len(tracks), self.COMPACT_BATCH):
            batch = tracks[begin:begin + self.COMPACT_BATCH]
            self._store(batch, self._rebuild([self._where[t] for t in batch], len(batch)))
