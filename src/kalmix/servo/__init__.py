"""Visual servoing: arm kinematics and the SOM that learns the inverse image Jacobian.

The paper's controller (Wira, Urban & Gresser 2001, section 2) moves a three-joint arm by
``dq = B e`` (eq. 3), with ``e = d - v`` the image error (eq. 1) and ``B`` the inverse image
Jacobian learned by a supervised self-organising map.
"""

from kalmix.servo.arm import (
    TARGET_REGION_HALF_WIDTHS,
    WORKSPACE_CENTRE,
    WORKSPACE_HALF_WIDTHS,
    Arm,
)
from kalmix.servo.loop import (
    MODES,
    ModeResult,
    ServoConfig,
    ServoResult,
    delay_stability_limit,
    run_servo,
    train_som,
)
from kalmix.servo.som import (
    InverseJacobianSOM,
    RelativeError,
    SOMConfig,
    TrainingHistory,
    plot_learning_curve,
)

__all__ = [
    "MODES",
    "ModeResult",
    "ServoConfig",
    "ServoResult",
    "delay_stability_limit",
    "run_servo",
    "train_som",
    "Arm",
    "InverseJacobianSOM",
    "RelativeError",
    "SOMConfig",
    "TARGET_REGION_HALF_WIDTHS",
    "TrainingHistory",
    "WORKSPACE_CENTRE",
    "WORKSPACE_HALF_WIDTHS",
    "plot_learning_curve",
]
