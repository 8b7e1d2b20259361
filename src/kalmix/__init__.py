"""kalmix: model-free online motion prediction with a mixture of adaptive Kalman filters.

Implements P. Wira, J.-P. Urban, J. Gresser, "A divide-and-conquer learning architecture
for predicting unknown motion" (2001): state-model adaptive Kalman filters (AKF) whose
system matrix is re-estimated online, combined by a gated mixture of experts.

Two front doors: :class:`TrackPredictor` (many tracks, the default bank of expert families:
what ``kalmix predict`` runs, the most accurate on real tracks) and :class:`MixturePredictor`
(the paper's mixture of AKFs, one stream or N streams of frames).
"""

from .bank import make_params
from .core.run import RunResult
from .predictor import MixturePredictor, run

__version__ = "0.1.0"
__all__ = ["MixturePredictor", "make_params", "run", "RunResult", "TrackPredictor", "StreamConfig", "RowPrediction",
           "SkippedRowWarning", "__version__"]

_STREAMING = ("TrackPredictor", "StreamConfig", "RowPrediction", "SkippedRowWarning")


def __getattr__(name):
    """The default bank's front door (:mod:`kalmix.streaming`), imported when first asked for."""
    if name in _STREAMING:
        from . import streaming

        return getattr(streaming, name)
    raise AttributeError(f"module 'kalmix' has no attribute {name!r}")


def __dir__():
    """The module's names, those imported when first asked for too (tab completion lists them)."""
    return sorted(set(globals()) | set(_STREAMING))
