"""Aggregation rules: how a bank's expert predictions become one prediction.

Every rule is a module with the same functional signature (R's opera is the model):

- ``Params`` (NamedTuple) and ``State`` (NamedTuple of ``(N, K)`` / ``(N,)`` arrays);
- ``init(params, n_targets, n_experts) -> State``;
- ``weights(params, state, awake) -> (N, K)``: the convex weights of the current
  prediction, zero on sleeping experts (``awake`` is ``(N, K)`` bool: an expert that
  has not started or whose prediction is not finite sleeps);
- ``update(params, state, experts, measurement, awake, learn) -> State``: learn from
  the experts' predictions ``(N, K, p)`` of the measurement ``(N, p)``, only where
  ``learn (N,)``; sleeping experts are neither scored nor changed;
- optionally ``restart(params, state, rows) -> State``: what changes where the experts of the
  targets in ``rows (N,)`` start again (BOA's error scale); a rule without it keeps its state.

Rules see predictions and measurements only, never the experts' internals, so any
family can sit in a bank. The compiled versions are in :mod:`kalmix.core.compiled.rules`.
"""

from ._common import linearised_regret, normalise_awake
from . import boa, boa_blend, fixed_share, mlpoly  # noqa: E402

#: name -> module, in the order of the ablation table.
RULES = {"boa": boa, "boa_blend": boa_blend, "mlpoly": mlpoly, "fixed_share": fixed_share}

__all__ = ["RULES", "boa", "boa_blend", "mlpoly", "fixed_share", "normalise_awake", "linearised_regret"]
