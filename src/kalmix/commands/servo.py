"""``kalmix servo``: the closed visual-servoing loop, with and without prediction.

::

    kalmix servo                                   # paper scenario, delay 2, gain 0.5 for every mode
    kalmix servo --prediction-gain 1.0             # the predicting loops at the gain they can stand
    kalmix servo --scenario circle --delay 1 --json servo.json --out-dir servo_out
"""

from __future__ import annotations

import os
import warnings

import click
import numpy as np

from ..archive import save_figure
from ._common import SEED, Finite, check_output_file, one_line_errors, output_directory, progress_bar, write_json

_LABELS = {
    "no_prediction": "no prediction (delayed e)",
    "single_akf": "single AKF",
    "mixture_softmax": "mixture, softmax gate",
    "oracle": "oracle (J^-1, true future)",
}
_COLOURS = {"no_prediction": "tab:red", "single_akf": "tab:orange", "mixture_softmax": "tab:blue",
            "oracle": "tab:green"}


def format_table(result) -> str:
    """Tracking error per mode: mean, RMS, max in pixels and in millimetres."""
    config = result.config
    lines = [
        f"tracking error ||d_k - v_k|| against the true, undelayed positions, {len(result.times)} frames, "
        f"delay {config.delay_frames} frames, noise {config.noise_px:g} px, seed {config.seed}",
        f"{'mode':<28}{'gain':>6}{'mean px':>9}{'RMS px':>9}{'max px':>9}"
        f"{'mean mm':>9}{'RMS mm':>9}{'max mm':>9}{'limit viol.':>12}{'diverged':>10}",
    ]
    for name, mode in result.modes.items():
        s = mode.summary()
        lines.append(
            f"{_LABELS[name]:<28}{_cell(s['gain'], 6, 2)}{_cell(s['mean_px'], 9, 2)}{_cell(s['rms_px'], 9, 2)}"
            f"{_cell(s['max_px'], 9, 1)}{_cell(s['mean_mm'], 9, 1)}{_cell(s['rms_mm'], 9, 1)}{_cell(s['max_mm'], 9, 1)}"
            f"{s['joint_limit_violations']:>12d}{'yes' if s['diverged'] else 'no':>10}"
        )
    return "\n".join(lines)


def _cell(value, width, decimals):
    """``value`` right-aligned in ``width`` with ``decimals``, or in 3 significant digits where that would not fit
    (a gain of 1e6 as 1000000.00 would shift the row's other columns) or would read 0 (a gain of 0.004 as
    0.00)."""
    text = f"{value:.{decimals}f}"
    if len(text) >= width or (value != 0 and float(text) == 0):
        text = f"{value:.3g}"
    return text.rjust(width)


def _ratios(result) -> dict:
    rms = {name: mode.summary()["rms_px"] for name, mode in result.modes.items()}
    out = {}
    if "no_prediction" in rms and "mixture_softmax" in rms:
        out["no_prediction_over_mixture_rms"] = rms["no_prediction"] / rms["mixture_softmax"]
    if "single_akf" in rms and "mixture_softmax" in rms:
        out["single_akf_over_mixture_rms"] = rms["single_akf"] / rms["mixture_softmax"]
    return out


def _fastest_window(result, seconds: float = 2.0) -> slice:
    """The ``seconds`` around the target's fastest image motion."""
    speed = np.linalg.norm(np.diff(result.target_features, axis=0), axis=-1)
    centre = int(np.argmax(speed))
    rate = 1.0 / float(np.median(np.diff(result.times)))
    half = int(round(seconds * rate / 2))
    start = max(0, min(centre - half, len(result.times) - 2 * half))
    return slice(start, min(len(result.times), start + 2 * half))


def plot_paths(result, path) -> None:
    """Target and end-effector paths in the left image (u_left, v) and u_left over time, fastest 2 s."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    window = _fastest_window(result)
    times = result.times[window]
    fig, (ax_image, ax_time) = plt.subplots(1, 2, figsize=(12.0, 5.0), dpi=110)
    target = result.target_features[window]
    ax_image.plot(target[:, 0], target[:, 2], color="black", lw=2.5, label="target d_k")
    ax_time.plot(times, target[:, 0], color="black", lw=2.5, label="target d_k")
    for name, mode in result.modes.items():
        v = mode.effector_features[window]
        style = dict(color=_COLOURS[name], lw=1.3, label=f"{_LABELS[name]} (RMS {mode.summary()['rms_px']:.1f} px)")
        ax_image.plot(v[:, 0], v[:, 2], **style)
        ax_time.plot(times, v[:, 0], **style)
    ax_image.set_xlabel("u_left (px)")
    ax_image.set_ylabel("v (px, image rows: down is +)")
    ax_image.invert_yaxis()
    ax_image.set_aspect("equal", adjustable="datalim")
    ax_image.set_title("left image, fastest 2 s of the run")
    ax_image.grid(alpha=0.3)
    ax_time.set_xlabel("time (s)")
    ax_time.set_ylabel("u_left (px)")
    ax_time.set_title("horizontal feature over the same 2 s")
    ax_time.grid(alpha=0.3)
    ax_time.legend(fontsize=8, loc="best")
    config = result.config
    gains = f"gain {config.gain:g}" + ("" if config.prediction_gain is None
                                      else f" (predicting modes {config.prediction_gain:g})")
    fig.suptitle(f"visual servoing: end effector v_k chasing the target d_k, delay {config.delay_frames} "
                 f"frames, {gains}")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def plot_errors(result, path, speeds=None) -> None:
    """Tracking error per mode over the whole run (log scale), target speed underneath."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = 2 if speeds is not None else 1
    fig, axes = plt.subplots(rows, 1, figsize=(11.0, 7.0 if rows == 2 else 5.0), dpi=110, sharex=True,
                             gridspec_kw={"height_ratios": [3, 1]} if rows == 2 else None)
    axes = np.atleast_1d(axes)
    ax = axes[0]
    low = []
    for name, mode in result.modes.items():
        summary = mode.summary()
        ax.plot(result.times, np.maximum(mode.error_px, 1e-2), color=_COLOURS[name], lw=0.9,
                label=f"{_LABELS[name]}, gain {summary['gain']:g}: RMS {summary['rms_px']:.1f} px, "
                      f"{summary['rms_mm']:.1f} mm")
        finite = mode.error_px[np.isfinite(mode.error_px)]
        if finite.size:
            low.append(np.percentile(finite, 5))
    ax.axhline(result.config.divergence_px, color="grey", ls=":", lw=0.8, label="divergence threshold")
    ax.set_yscale("log")
    # the floor under the smallest errors (a fixed 0.05 would cut off most of the oracle's)
    ax.set_ylim(bottom=max(1e-2, 0.5 * min(low)) if low else 0.05)
    ax.set_ylabel("||d_k - v_k|| (px, log)")
    fig.suptitle(f"tracking error against the true target, delay {result.config.delay_frames} frames")
    ax.grid(alpha=0.3, which="both")
    # above the axes: inside, any corner would hide a stretch of some run's errors
    ax.legend(fontsize=8, loc="lower left", bbox_to_anchor=(0.0, 1.01, 1.0, 0.1), ncol=2, mode="expand",
              borderaxespad=0.0, frameon=False)
    if speeds is not None:
        axes[1].plot(result.times, speeds, color="black", lw=1.0)
        axes[1].set_ylabel("target speed (m/s)")
        axes[1].grid(alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


#: Past these the run says nothing more (it diverges, or the features leave the image) and its arithmetic
#: overflows (a failure that names no option, or a flood of overflow warnings).
MAX_NOISE_PX = 1e4
MAX_GAIN = 1e6


def _check_json(json_path, out_dir) -> None:
    """``--json``, checked before the work as any output file, but it may lie directly in an ``--out-dir`` that
    the command makes (that directory need not exist yet)."""
    if os.path.abspath(json_path) == os.path.abspath(out_dir):
        raise click.BadParameter(f"{json_path!r} is the --out-dir; give a file name", param_hint="'--json'")
    try:
        check_output_file(json_path, made_directory=out_dir)
    except click.BadParameter as error:
        error.param_hint = "'--json'"
        raise


@click.command()
@click.option("--scenario", type=click.Choice(["paper", "circle", "random_walk"]), default="paper",
              show_default=True, help="Target trajectory.")
@click.option("--delay", "delay_frames", type=click.IntRange(min=0), default=2, show_default=True,
              help="Image-acquisition delay D (frames at 25 Hz).")
@click.option("--noise", "noise_px", type=Finite(0.0, maximum=MAX_NOISE_PX), default=0.5, show_default=True,
              help=f"Pixel noise on the delivered features (px, at most {MAX_NOISE_PX:g}).")
@click.option("--gain", type=Finite(0.0, open=True, maximum=MAX_GAIN), default=0.5, show_default=True,
              help=f"Loop gain lambda in dq = lambda B e, for every mode (at most {MAX_GAIN:g}).")
@click.option("--prediction-gain", type=Finite(0.0, open=True, maximum=MAX_GAIN), default=None,
              help="Gain of the predicting modes and the oracle (default: --gain).")
@click.option("--seed", default=0, show_default=True, type=SEED,
              help="Seed of the scenario, camera noise, SOM and predictors.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None,
              help="Write the summary as JSON (it may lie in --out-dir, made with it).")
@click.option("--out-dir", type=click.Path(file_okay=False), default="servo_out", show_default=True,
              callback=output_directory, help="Directory for the PNGs.")
@one_line_errors
def servo(scenario, delay_frames, noise_px, gain, prediction_gain, seed, json_path, out_dir):
    """Track a 3-D target with the 3-joint arm through delayed stereo cameras; compare predictors."""
    if json_path is not None:
        _check_json(json_path, out_dir)
    from ..scenarios import SCENARIOS
    from ..servo import Arm, ServoConfig, SOMConfig, plot_learning_curve, run_servo, train_som
    from ..vision import StereoCamera

    config = ServoConfig(delay_frames=delay_frames, noise_px=noise_px, gain=gain,
                         prediction_gain=prediction_gain, seed=seed)
    trajectory = SCENARIOS[scenario](seed).generate()
    n_frames = len(trajectory.times)
    if delay_frames >= n_frames:   # no image would ever arrive: every mode the same frozen arm, said "diverged"
        raise click.BadParameter(f"expected fewer frames than the run's {n_frames}, got {delay_frames}: no image "
                                 "would arrive before the run ends", param_hint="'--delay'")
    arm, camera = Arm(), StereoCamera()

    som_config = SOMConfig(seed=seed)
    with progress_bar(som_config.n_training_moves, "SOM babbling", "move") as update:
        last = {"done": 0}

        def som_progress(done, total, median):
            update(done - last["done"], postfix=f"median error {median:.3f}")
            last["done"] = done

        som, history = train_som(arm, camera, seed=seed, config=som_config, progress=som_progress)

    with progress_bar(n_frames * len(config.modes), "servo loop", "frame") as update:
        def progress(mode, frame, total):
            update(1, postfix=mode if frame == 1 else None)

        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = run_servo(trajectory, arm=arm, camera=camera, config=config, som=som, progress=progress)
    result = result._replace(som_history=history)
    said: dict = {}
    for warning in caught:   # each message once, with its count
        said[str(warning.message)] = said.get(str(warning.message), 0) + 1
    for message, count in said.items():
        click.echo(f"warning: {message}" + (f" ({count} times)" if count > 1 else ""), err=True)

    data = result.to_dict()
    data["scenario"] = scenario
    data.update(_ratios(result))
    # the files first: a closed stdout (| head) or a full one ends the echoes below, not the run's files
    os.makedirs(out_dir, exist_ok=True)
    figures = {
        "paths": os.path.join(out_dir, "servo_paths.png"),
        "errors": os.path.join(out_dir, "servo_error.png"),
        "som_learning_curve": os.path.join(out_dir, "servo_som_learning.png"),
    }
    plot_paths(result, figures["paths"])
    plot_errors(result, figures["errors"], speeds=trajectory.speeds)
    plot_learning_curve(history, figures["som_learning_curve"])
    data["figures"] = figures
    if json_path:
        write_json(json_path, data)

    click.echo(f"scenario '{scenario}', seed {seed}")
    click.echo(format_table(result))
    click.echo(
        f"SOM inverse Jacobian, median relative error over the target's path: "
        f"{data['som_relative_error_untrained']:.3f} untrained -> {data['som_relative_error']:.3f} after "
        f"{history.moves[-1]} babbling moves ({history.training_seconds:.1f} s; 90th percentile "
        f"{data['som_relative_error_p90']:.3f})"
    )
    after = {name: m.som_relative_error for name, m in result.modes.items() if m.som_relative_error is not None}
    if after:
        click.echo("  after the run (online learning): "
                   + ", ".join(f"{name} {value:.3f}" for name, value in after.items()))
    click.echo(f"joint-limit violations (commands outside the limits before clipping): "
               f"{data['joint_limit_violations']}; stability limit of the delayed loop: gain < "
               f"{data['stability_limit_no_prediction']:.3f}")
    if "no_prediction_over_mixture_rms" in data:
        click.echo(f"RMS ratio no prediction / mixture: {data['no_prediction_over_mixture_rms']:.2f}"
                   + (f"; single AKF / mixture: {data['single_akf_over_mixture_rms']:.3f}"
                      if "single_akf_over_mixture_rms" in data else ""))

    click.echo("figures: " + ", ".join(figures.values()))
    if json_path:
        click.echo(f"wrote {json_path}")
