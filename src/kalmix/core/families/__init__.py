"""Families of experts: homogeneous batches that meet the rest of a bank only as predictions.

- :mod:`.kinematic`: constant-velocity and constant-acceleration Kalman filters with
  the real time step between samples;
- :mod:`.ar`: adaptive autoregressive models of the velocity in real time (weighted least
  squares with forgetting, a persistence prior and a jump test for relocations);
- :mod:`.turn`: coordinated-turn extrapolation (the last turn rate and speed carried
  forward) in real time, in any dimension;
- :mod:`.akf`: the paper's state-model adaptive Kalman filters (frame-based).

The compiled versions are in :mod:`kalmix.core.compiled`.
"""

from . import akf, ar, kinematic, turn

__all__ = ["akf", "ar", "kinematic", "turn"]
