"""A :class:`~kalmix.streaming.TrackPredictor`'s state file: every track's state, clock and the settings, saved
and loaded (older format versions resume with the settings they were written with)."""

from __future__ import annotations

import math
import numbers
import os
from dataclasses import asdict
from typing import Self

import numpy as np

from ..archive import open_archive, write_archive
from ..bank import LENGTH_UNIT_RANGE
from ..core.engine import tree_leaves, tree_map
from .config import StreamConfig
from .gaps import GapTracker
from .ids import id_from_meta, id_to_meta
from .population import Prior, prior_width

#: Format version of the state files :meth:`TrackPredictor.save` writes. :meth:`TrackPredictor.load` reads
#: versions 3 to 18 and resumes each with the settings it was written with (CHANGELOG.md, "State file format
#: versions", says what each version adds).
STATE_FORMAT_VERSION = 18
_READABLE_VERSIONS = (3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18)
_MAGIC = "kalmix-track-predictor"
#: A population prior's calibration arrays, as the file names them (``population/<i>/calibration_<name>``).
_CALIBRATION_NAMES = ("variance", "count", "log_scale")


def _prior_calibration(archive, engine, i: int) -> tuple | None:
    """The calibration of the file's ``i``-th population prior (None when the predictor keeps none)."""
    params = engine.params
    if not engine.config.calibration_prior or params is None:
        return None
    k, p = params.n_experts, params.measurement_dim
    return tuple(archive.array(f"population/{i}/calibration_{name}", shape, np.float64,
                               label=f"population/{i}/calibration_{name}")
                 for name, shape in zip(_CALIBRATION_NAMES, ((k, p), (k,), (1,))))


class StateFile:
    """The part of :class:`~kalmix.streaming.TrackPredictor` that saves and loads it."""

    def save(self, path: str | os.PathLike) -> None:
        """Write settings, every track's state and gap bookkeeping to ``path`` (``.npz``).

        Atomic and durable (see :func:`kalmix.archive.write_archive`): a reader sees the old
        file or the new one, never a mixture.
        """
        tracks = list(self.gaps)
        with_state = [t for t in tracks if t in self.states]
        meta = {"magic": _MAGIC, "format_version": STATE_FORMAT_VERSION, "config": asdict(self.config),
                "measurement_dim": None if self.params is None else self.params.measurement_dim,
                "position_names": None if self.position_names is None else list(self.position_names),
                "tracks": [{"id": id_to_meta(t), "gaps": self.gaps[t].to_json(), "state": t in self.states,
                            "rows": self.track_rows.get(t, 0)} for t in tracks],
                "rows": self.rows, "skipped": self.skipped, "outliers": self.outliers,
                "output": self.output, "priors": [prior.tracks for prior in self.priors]}
        arrays = {}
        if with_state:
            arrays = dict(tree_leaves(self.states.gather(with_state, self._new_states)))
        for i, prior in enumerate(self.priors):
            arrays.update({f"population/{i}/{name}": getattr(prior, name) for name in ("regret", "variance", "bound")})
            if prior.calibration is not None:
                arrays.update({f"population/{i}/calibration_{name}": value
                               for name, value in zip(_CALIBRATION_NAMES, prior.calibration)})
        write_archive(path, meta, arrays)

    @classmethod
    def load(cls, path: str | os.PathLike, *, backend: str = "cpu") -> Self:
        """Read a file written by :meth:`save` (to run on ``backend``); ``ValueError`` with the reason on a bad
        file."""
        with open_archive(path, magic=_MAGIC, version=_READABLE_VERSIONS, what="kalmix state file",
                          written_by="kalmix predict --state") as archive:
            meta = archive.meta
            try:
                config = dict(meta["config"])
                config.setdefault("rule", "boa")   # the default rule before BOA-blend (files name their rule)
                if config.get("options"):   # older files may hold gate arguments (without effect): drop them
                    from ..bank import GATE_OPTIONS
                    config["options"] = {k: v for k, v in config["options"].items() if k not in GATE_OPTIONS}
                if meta["format_version"] < 8:
                    config.setdefault("reach", None)   # files before version 8 ran without a reach
                if meta["format_version"] < 9:
                    config.setdefault("lead_delay", 1.0)   # files before version 9 ran at the one-step rate
                if meta["format_version"] < 5 and config.get("rule") == "boa":
                    config["rule_options"] = {"bound_forgetting": 1.0, **(config.get("rule_options") or {})}
                if meta["format_version"] < 10 and config.get("rule") == "boa":
                    config["rule_options"] = {"clip": math.inf, **(config.get("rule_options") or {})}
                if meta["format_version"] < 11:
                    config.setdefault("geographic", False)   # files before version 11 took positions as flat
                if meta["format_version"] < 12:
                    config.setdefault("gap_reference", "median")   # files before version 12 took the median
                if meta["format_version"] < 15:   # versions 12 to 14: the upper quartile, without the spread
                    config.setdefault("gap_reference", "upper quartile")
                if meta["format_version"] < 16:   # files before version 16: no gap floor
                    config.setdefault("gap_floor", None)
                if meta["format_version"] < 17:   # files before version 17: the prior starts the one-step rule only
                    config.setdefault("lead_prior", False)
                if meta["format_version"] < 18:   # files before version 18: every error calibrates, from the unit
                    config.setdefault("calibration_prior", False)
                    config.setdefault("calibration_from_points", 0)
                if meta["format_version"] < 13:   # files before version 13: any step a gap, no population prior
                    config.setdefault("gap_min_steps", 1)
                    config.setdefault("population_prior", False)
                engine = cls(StreamConfig(**config), meta.get("position_names"))
                engine.rows, engine.skipped = int(meta["rows"]), int(meta["skipped"])
                engine.outliers = int(meta.get("outliers", 0))
                engine.output = meta.get("output")
                engine.loaded_version = meta["format_version"]
                if meta["measurement_dim"] is not None:
                    engine._ensure_params(int(meta["measurement_dim"]))
                entries = [(id_from_meta(entry["id"]), GapTracker(**entry["gaps"]), bool(entry["state"]))
                           for entry in meta["tracks"]]
                engine.track_rows = {track: int(entry.get("rows", 0))
                                     for (track, _, _), entry in zip(entries, meta["tracks"]) if entry.get("rows")}
                k = None if engine.params is None else prior_width(engine.params, engine.config.lead_prior)
                engine.priors = [Prior(*(archive.array(f"population/{i}/{name}", (k,), np.float64,
                                                       label=f"population/{i}/{name}")
                                         for name in ("regret", "variance", "bound")), int(tracks),
                                       _prior_calibration(archive, engine, i))
                                 for i, tracks in enumerate(meta.get("priors", []))]
            except (KeyError, TypeError, ValueError) as error:
                settings = meta.get("config") if isinstance(meta, dict) else None
                unit = settings.get("length_unit") if isinstance(settings, dict) else None
                low, high = LENGTH_UNIT_RANGE
                if isinstance(unit, numbers.Real) and not low <= unit <= high:   # older versions had a wider range
                    raise ValueError(f"{path}: the state file's length unit {unit!r} is outside this version's range "
                                     f"[{low:g}, {high:g}] (where the predictions are scale-equivariant); start "
                                     "a new state file with a unit in it") from error
                raise ValueError(f"{path}: the kalmix state file's settings are incomplete or corrupt: "
                                 f"{error!r}") from error
            count = sum(has_state for _, _, has_state in entries)
            stacked, template = None, None
            if count:
                template = engine._fresh()
                version = meta["format_version"]
                fresh = lambda name: ((version == 3 and name.startswith("state/calibration/"))  # noqa: E731
                                      or (version <= 5 and name == "state/lead/issued")
                                  or (version <= 6 and name in ("state/screen/low", "state/screen/high"))
                                  or (version <= 9
                                      and name.startswith(("state/rule/error_", "state/lead/rule/error_")))
                                  or (version <= 13
                                      and name.startswith(("state/lead/blend/", "state/lead/candidates"))))
                stacked = {name: (np.broadcast_to(expected, (count, *expected.shape[1:])) if fresh(name)
                                  else archive.array(name, (count, *expected.shape[1:]), expected.dtype, label=name))
                           for name, expected in tree_leaves(template)}
                if version <= 14:   # the screen counted a track's learned rows up to 2: taken as warmed up (3)
                    points = stacked["state/screen/points"]
                    stacked["state/screen/points"] = np.where(points == 2.0, 3.0, points)
        engine.use_backend(backend)   # outside the checks of the file: a backend that cannot run is not corruption
        for track, gaps, _ in entries:
            engine.gaps[track] = gaps
        if count:
            leaves = iter([np.asarray(value) for value in stacked.values()])
            engine.states.share_as_new(template)
            engine.states.put([track for track, _, has_state in entries if has_state],
                              tree_map(lambda _: next(leaves), template))
        return engine
