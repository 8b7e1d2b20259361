"""The paper's experiments as functions returning data (no printing, no plotting).

- :mod:`kalmix.experiments.table1`: Table 1 (single AKF, softmax and random mixtures) with our
  peers, over seeds: ``from kalmix.experiments.table1 import table1``.
- :mod:`kalmix.experiments.figure2`: the four panels of Figure 2 from one run.
- :mod:`kalmix.experiments.ablations`: the questions the paper leaves open (AKF mode, gate,
  Q/R adaptation, K).

The submodules are not imported here (their main functions share their names).
"""

__all__ = ["table1", "figure2", "ablations"]
