"""kalmix: model-free online motion prediction with a mixture of adaptive Kalman filters.

Implements P. Wira, J.-P. Urban, J. Gresser, "A divide-and-conquer learning architecture
for predicting unknown motion" (2001): state-model adaptive Kalman filters (AKF) whose
system matrix is re-estimated online, combined by a gated mixture of experts.
"""

from .bank import make_params
from .core.run import RunResult
from .predictor import MixturePredictor, run

__version__ = "0.1.0"
__all__ = ["MixturePredictor", "make_params", "run", "RunResult", "__version__"]
