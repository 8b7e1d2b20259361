"""Pure, batched array core: Kalman kernels, AKF dynamics, gating, the mixture step."""

from .kalman import kalman_predict, kalman_update
from .mixture import MixtureParams, MixtureState, StepOutput, init_state, predict, step
from .run import RunResult, run_core

__all__ = ["kalman_predict", "kalman_update", "MixtureParams", "MixtureState", "StepOutput",
           "init_state", "predict", "step", "RunResult", "run_core"]
