"""The figure of a :class:`~kalmix.servo.som_config.TrainingHistory`: the SOM's learning curve."""

from __future__ import annotations

import numpy as np

from kalmix.servo.som_config import TrainingHistory

__all__ = ["plot_learning_curve"]


def plot_learning_curve(history: TrainingHistory, path) -> None:
    """Write a PNG of the learning curve: relative error vs training moves (log x).

    Parameters
    ----------
    history : TrainingHistory
        From :meth:`~kalmix.servo.som.InverseJacobianSOM.fit`.
    path : str or os.PathLike
        Output file.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    moves = np.asarray(history.moves)
    shown = moves > 0  # log axis: the untrained point (0 moves) is drawn as a horizontal reference
    fig, ax = plt.subplots(figsize=(6.0, 4.0), dpi=120)
    ax.plot(moves[shown], np.asarray(history.median_relative_error)[shown], "o-", label="median")
    ax.plot(moves[shown], np.asarray(history.mean_relative_error)[shown], "s--", label="mean")
    if np.any(~shown):
        ax.axhline(np.asarray(history.median_relative_error)[~shown][0], color="grey", lw=0.8,
                   ls=":", label="untrained")
    ax.set_xscale("log")
    ax.set_xlabel("training moves (babbling)")
    ax.set_ylabel(r"relative error $\|B - J^{-1}\|_F / \|J^{-1}\|_F$")
    ax.set_title(f"SOM inverse-Jacobian learning curve ({history.training_seconds:.1f} s)\n"
                 "on random configurations across its joint box (not the target's path)", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    from ..archive import save_figure

    save_figure(fig, path)
    plt.close(fig)
