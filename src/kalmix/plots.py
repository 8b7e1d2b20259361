"""Matplotlib figures from experiment data (the ``cli`` extra; imported lazily, Agg backend)."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from .archive import save_figure

__all__ = ["figure2", "evaluate_errors", "readable_time"]

_PHASE_COLOURS = ("#dbe9f6", "#fde2c8", "#e3f1dc")


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _shade_phases(ax, spans, label: bool = False):
    for index, (name, start, end) in enumerate(spans):
        ax.axvspan(start, end, color=_PHASE_COLOURS[index % len(_PHASE_COLOURS)], alpha=0.6, lw=0, zorder=0)
        if index:
            ax.axvline(start, color="0.2", lw=0.9, ls=":", zorder=5)
        if label:
            ax.text((start + end) / 2, 1.02, name, transform=ax.get_xaxis_transform(), ha="center", va="bottom",
                    fontsize=9, color="0.25")


def figure2(data: dict[str, Any], out: str | os.PathLike, *, top: int = 5, dpi: int = 130) -> str:
    """Write the paper's Figure 2 (four panels) from :func:`kalmix.experiments.figure2.figure2` data.

    (a) gating weights of the experts (stacked, so the dominant expert is visible;
    the ``top`` experts by mean weight are named in the legend), (b) the adaptive
    learning rate :math:`\\eta_k` with the target speed, (c) the diagonal of every
    expert's :math:`Q_{i,k}` (log scale), (d) the absolute one-step prediction error in
    pixels. The trajectory's phases are shaded in every panel.

    Returns the path written.
    """
    plt = _pyplot()
    times = np.asarray(data["times"])
    weights = np.asarray(data["weights"])
    process_noise = np.asarray(data["process_noise"])
    abs_error = np.asarray(data["abs_error"])
    spans = data["phase_spans"]
    k = weights.shape[1]
    cmap = plt.get_cmap("hsv")
    # golden-ratio hues, alternating lightness: neighbouring experts get distinct colours
    colours = [tuple(0.55 * c + 0.45 * (i % 2) * 0.6 for c in cmap((i * 0.6180339887) % 1.0)[:3]) + (1.0,)
               for i in range(k)]
    order = np.argsort(-weights.mean(axis=0))
    leaders = set(order[: min(top, k)].tolist())

    fig, axes = plt.subplots(4, 1, figsize=(11, 11), sharex=True, constrained_layout=True)
    gate_name = data.get("options", {}).get("gating", "fixed_share")
    fig.suptitle(f"Figure 2 reproduced: mixture of {k} adaptive Kalman filters ({gate_name} gate), "
                 f"paper scenario seed {data['seed']}  —  RMS X {data['rms']['X']:.2f} px, "
                 f"Y {data['rms']['Y']:.2f} px", fontsize=11)

    ax = axes[0]
    _shade_phases(ax, spans, label=True)
    stacks = ax.stackplot(times, weights.T, colors=colours, linewidth=0)
    handles = [stacks[i] for i in order[: min(top, k)]]
    ax.legend(handles, [f"expert {i}" for i in order[: min(top, k)]], loc="center left", bbox_to_anchor=(1.0, 0.5),
              fontsize=8, title=f"top {len(handles)} by\nmean weight", title_fontsize=8)
    ax.set_ylim(0, 1)
    ax.set_ylabel("gating weight $g_{i,k}$\n(stacked)")
    ax.set_title("(a) gating weights of the experts", loc="left", fontsize=10, pad=16)

    ax = axes[1]
    _shade_phases(ax, spans)
    (eta_line,) = ax.plot(times, data["eta"], color="tab:blue", lw=0.9, label=r"$\eta_k$")
    ax.set_ylabel(r"learning rate $\eta_k$")
    ax.set_yscale("log")
    twin = ax.twinx()
    (speed_line,) = twin.plot(times, data["speed"], color="0.35", lw=1.0, ls="--", label="target speed")
    twin.set_ylabel("target speed (m/s)", color="0.35")
    lines = [eta_line, speed_line]
    ax.legend(lines, [line.get_label() for line in lines], loc="upper left", fontsize=8, framealpha=0.9)
    ax.set_title(r"(b) adaptive learning rate $\eta_k = \eta(t)(1 - e^{-\alpha\varepsilon})$", loc="left",
                 fontsize=10)

    ax = axes[2]
    _shade_phases(ax, spans)
    for i in range(k):
        lead = i in leaders
        ax.plot(times, process_noise[:, i], color=colours[i], lw=1.4 if lead else 0.6, alpha=1.0 if lead else 0.45,
                label=f"expert {i}" if lead else None)
    ax.set_yscale("log")
    ax.set_ylabel(r"diag $Q_{i,k}$ (px$^2$)")
    change = np.nanmax(1.0 - process_noise[-1] / process_noise[0])
    levels = len(np.unique(np.round(process_noise[0], 12)))
    ax.text(0.01, 0.04, f"{levels} initial level{'s' * (levels != 1)} shared by {k} expert{'s' * (k != 1)}; "
            "largest relative decrease of any "
            f"$Q_i$ over the run: {100 * change:.2g} %",
            transform=ax.transAxes, fontsize=8, color="0.2", bbox=dict(facecolor="white", alpha=0.8, lw=0))
    ax.legend(loc="center left", bbox_to_anchor=(1.0, 0.5), fontsize=8, title="thick: top experts",
              title_fontsize=8)
    ax.set_title(r"(c) process-noise diagonal of every expert (eq. 11)", loc="left", fontsize=10)

    ax = axes[3]
    _shade_phases(ax, spans)
    x_error = np.fmax(abs_error[:, 0], abs_error[:, 1])
    ax.plot(times, x_error, color="tab:red", lw=0.7, alpha=0.85, label="X: max(|e| u_left, |e| u_right)")
    ax.plot(times, abs_error[:, 2], color="tab:green", lw=0.7, alpha=0.85, label="Y: |e| v")
    ax.set_ylabel("|prediction error| (px)")
    ax.set_xlabel("time (s)")
    ax.set_ylim(bottom=0)
    ax.legend(loc="center left", bbox_to_anchor=(1.0, 0.5), fontsize=8)
    ax.set_title("(d) absolute one-step prediction error of the mixture", loc="left", fontsize=10)
    ax.set_xlim(times[0], times[-1])

    for ax in axes:
        ax.grid(True, which="major", alpha=0.3)
    path = os.fspath(out)
    save_figure(fig, path, dpi=dpi)
    plt.close(fig)
    return path


def readable_time(span: float) -> tuple[float, str]:
    """``(divisor, unit)`` to show ``span`` seconds in: s, min, h or days, whichever keeps the numbers short."""
    for divisor, unit in ((86400.0, "days"), (3600.0, "h"), (60.0, "min")):
        if span >= 3 * divisor:
            return divisor, unit
    return 1.0, "s"


#: Line styles of the error figure's references (kalmix's row is black, the best tuned peer's orange).
_EVALUATE_STYLES = {"CV Kalman": dict(color="tab:blue", lw=1.1, alpha=0.9),
                    "no prediction": dict(color="0.55", lw=1.1, ls="--")}


def evaluate_errors(result, out: str | os.PathLike, *, track: str, columns, rows, kalmix: str = "mixture",
                    dpi: int = 110) -> str:
    """The figure of ``kalmix evaluate --plot``: each row's one-step error over time on one track.

    ``result`` is a :class:`kalmix.experiments.evaluate.EvaluationResult`; ``track`` the
    track and ``columns`` its segments' columns
    (:func:`kalmix.experiments.evaluate.track_columns`); ``rows`` the rows to draw
    (:func:`kalmix.experiments.evaluate.plot_rows`: by default kalmix's, the best tuned
    peer's, CV Kalman's and no prediction's); ``kalmix`` kalmix's row, drawn on top in
    black; the track's best tuned peer (the result's verdict) is drawn in orange. Each line is the rolling median of the
    error's length ``|e|`` over about 2 % of the track's rows, on the scored rows, against
    the time since the track's first row (the time column read as seconds; a time gap
    breaks the lines). The legend gives each row's RMS on the track (the verdict's
    measure). Returns the path written.
    """
    import pandas as pd

    plt = _pyplot()
    streams = result.streams
    track, names, columns = str(track), list(rows), np.asarray(columns)
    entry = (result.verdict or {}).get("per_track", {}).get(track, {}).get("one_step", {})
    best = entry.get("best_peer")
    start = float(np.nanmin(streams.times[:, columns]))
    span = float(np.nanmax(streams.times[:, columns])) - start
    divisor, unit = readable_time(span)
    window = max(1, int(streams.lengths[columns].sum()) // 50)
    fig, ax = plt.subplots(figsize=(11, 4.8))
    palette = [c for c in plt.get_cmap("tab10").colors if c != plt.get_cmap("tab10").colors[0]]
    others = 0
    summaries = result.per_track.get(track, {})
    for name in names:
        errors = result.errors[name]
        times, norms = [], []
        for j in columns:   # a segment at a time, a gap (NaN) between them: no line across a time gap
            n = streams.lengths[j]
            e = np.sqrt(np.sum(errors[:n, j] ** 2, axis=-1))
            scored = np.isfinite(e)   # the scored rows only: a missing measurement joins its neighbours
            e, t = e[scored], streams.times[:n, j][scored]
            if window > 1:
                e = pd.Series(e).rolling(window, min_periods=1, center=True).median().to_numpy()
            times += [(t - start) / divisor, [np.nan]]
            norms += [e, [np.nan]]
        t, e = np.concatenate(times), np.concatenate(norms)
        if name == kalmix:
            style = dict(color="black", lw=2.0, zorder=4)
        elif name in _EVALUATE_STYLES:
            style = dict(_EVALUATE_STYLES[name])
        elif name == best:
            style = dict(color="tab:orange", lw=1.6, zorder=3)
        else:
            style = dict(color=palette[(others + 1) % len(palette)], lw=0.9, alpha=0.8)
            others += 1
        if np.isfinite(e).sum() < 50:   # a few errors: their points, which a line would not show alone
            style["marker"] = "o"
        rms = ((summaries.get(name) or {}).get("one_step") or {}).get("rms")
        label = name + (" (kalmix)" if name == kalmix else " (best tuned peer)" if name == best else "")
        if rms is not None and np.isfinite(rms):
            label += f": RMS {rms:.3g}" + (" per coordinate" if result.metric == "per-coordinate" else "")
        ax.plot(t, e, label=label, **style)
    scored = np.isfinite(result.errors[kalmix][:, columns]).all(axis=-1)
    first_scored = float(np.min(streams.times[:, columns][scored])) if scored.any() else start
    if first_scored > start:   # the tuning part: not scored, so no line there
        ax.axvspan(0.0, (first_scored - start) / divisor, color="0.93", lw=0, zorder=0)
        ax.text(0.5 * (first_scored - start) / divisor, 0.97, "tuning part\n(not scored)", ha="center", va="top",
                transform=ax.get_xaxis_transform(), fontsize=8, color="0.4")
    ax.set_xlim(left=0.0)
    ax.set_yscale("log")
    ax.set_xlabel(f"time since the track's first row ({unit})")
    ax.set_ylabel("one-step error |e| (data units)" + (f"\nrolling median of {window} rows" if window > 1 else ""))
    title = f"{result.dataset}: track {track}"
    if entry.get("text"):
        title += f"\none step ahead: {entry['text']}"
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="major", alpha=0.3)
    # beside the axes: inside, it hides the errors of some row wherever it sits
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    fig.tight_layout()
    path = os.fspath(out)
    save_figure(fig, path, dpi=dpi)
    plt.close(fig)
    return path
