"""Families of experts: homogeneous batches that meet the rest of a bank only as predictions.

- :mod:`.kinematic`: constant-velocity and constant-acceleration Kalman filters with
  the real time step between samples;
- :mod:`.akf`: the paper's state-model adaptive Kalman filters (frame-based).

The compiled versions are in :mod:`kalmix.core.compiled`.
"""

from . import akf, kinematic

__all__ = ["akf", "kinematic"]
