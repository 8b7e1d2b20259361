"""``kalmix demo``: a short run on built-in simulated data."""

from __future__ import annotations

import click
import numpy as np

from ._common import SEED, one_line_errors


@click.command()
@click.option("--seed", default=0, show_default=True, type=SEED, help="Seed of the scenario and of the bank.")
@click.option("--experts", "n_experts", default=40, show_default=True, type=click.IntRange(1),
              help="Number of experts K.")
@one_line_errors
def demo(seed: int, n_experts: int):
    """Predict the paper's simulated target one frame ahead; print the error of the mixture beside a single AKF."""
    from ..baselines import single_akf, softmax_mixture
    from ..scenarios import PaperScenario, paper_measurements

    _, observation = paper_measurements(PaperScenario(seed=seed))
    z = observation.measured
    click.echo(f"paper scenario, seed {seed}: {len(z)} frames of stereo features (u_left, u_right, v) in pixels")
    click.echo(f"{'predictor':<28}{'RMS X (px)':>12}{'RMS Y (px)':>12}{'max (px)':>10}")
    for name, predictor in (("mixture (K=%d)" % n_experts, softmax_mixture(n_experts, seed=seed)),
                            ("single AKF", single_akf(seed=seed))):
        predictions = predictor.run(z, diagnostics=False).predictions
        error = predictions[:-1] - z[1:]
        error = error[np.isfinite(error).all(axis=1)]
        rms_x = np.sqrt(np.mean(error[:, :2] ** 2))
        rms_y = np.sqrt(np.mean(error[:, 2] ** 2))
        click.echo(f"{name:<28}{rms_x:>12.3f}{rms_y:>12.3f}{np.abs(error).max():>10.2f}")
