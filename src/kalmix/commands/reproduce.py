"""``kalmix reproduce``: the paper's Table 1, Figure 2 and the ablations, from one command each.

::

    kalmix reproduce table1 --seeds 5 --json table1.json      # both AKF modes, a few seconds in all
    kalmix reproduce figure2 --out figure2.png
    kalmix reproduce ablations --seeds 3 --json ablations.json
"""

from __future__ import annotations

import click
import numpy as np

from ._common import SEED, figure_file, one_line_errors, output_file, progress_bar, write_json

_STATS = ("mean_abs", "std", "max", "rms")
#: The configuration tests/test_claims.py asserts our claims on.
_DEFAULT_RUN = {"n_experts": 40, "scenario": "paper", "gating": "fixed_share"}


def _cell(mean: float, spread: float | None, width: int = 13) -> str:
    digits = 1 if abs(mean) >= 100 else 2 if abs(mean) >= 10 else 3
    text = f"{mean:.{digits}f}"
    if spread is not None:
        text += f"±{spread:.{digits}f}"
    return f"{text:>{width}}"


def _seed_text(seeds: list[int]) -> str:
    return f"seeds {seeds[0]}..{seeds[-1]}" if len(seeds) > 1 else f"seed {seeds[0]}"


def heading(result: dict) -> str:
    """The run's first line: what is reproduced, on what."""
    gate = {"fixed_share": "fixed-share gate", "paper": "the paper's gate (eq. 8-10)"}.get(
        result.get("gating", "fixed_share"), f"gate {result.get('gating')}")
    scenario = "the short --quick scenario" if result.get("scenario") == "quick" else "the paper's simulated target"
    return (f"Wira, Urban & Gresser (2001), Table 1: {scenario}, {result['frames']} frames at 25 Hz, "
            f"{_seed_text(result['seeds'])}, {result.get('n_experts', 40)}-AKF mixtures, {gate}")


def format_table(result: dict, mode: str = "rls", rows: tuple[str, ...] | None = None) -> str:
    """The paper's Table 1 layout (mean |e|, std, max per X and Y) plus RMS, paper numbers beside ours.

    ``rows``: only these rows (default all), e.g. the AKF rows of a second mode whose peer rows were printed.
    """
    from ..experiments.table1 import PAPER_TABLE1, ROW_LABELS

    key = "rows" if mode == "rls" else f"rows_{mode}"
    table, spread = result[key], result[f"{key}_spread"]
    seeds = result["seeds"]
    with_spread = len(seeds) > 1
    width = 13 if with_spread else 9
    name_width = 25
    what = "ours, the default" if mode == "rls" else "eq. 6/7 as printed" if mode == "literal" else mode
    lines = [f"Table 1, AKF mode '{mode}' ({what}): absolute one-step prediction error in pixels"
             + (f", mean ± std over {len(seeds)} seeds" if with_spread else f", {_seed_text(seeds)}")]
    header_1 = (" " * name_width + f"{'X coordinate (u_left, u_right)':^{4 * width}}"
                + f"{'Y coordinate (v)':^{4 * width}}").rstrip()
    header_2 = f"{'':<{name_width}}" + "".join(f"{label:>{width}}" for label in ("mean", "std", "max", "RMS") * 2)
    lines += [header_1, header_2, "-" * len(header_2)]
    for row, values in table.items():
        if rows is not None and row not in rows:
            continue
        cells = "".join(_cell(values[axis][stat], spread[row][axis][stat] if with_spread else None, width)
                        for axis in ("X", "Y") for stat in _STATS)
        lines.append(f"{ROW_LABELS.get(row, row):<{name_width}}" + cells)
        if row in PAPER_TABLE1:
            paper = PAPER_TABLE1[row]
            cells = "".join((_cell(paper[axis][stat], None, width) if stat != "rms"
                             else f"{'(' + format(paper[axis][stat], '.3g') + ')':>{width}}")
                            for axis in ("X", "Y") for stat in _STATS)
            lines.append(f"{'  paper (2001)':<{name_width}}" + cells)
    if rows is None:
        lines.append("The paper's RMS (in parentheses) is derived: sqrt(mean² + std²). Rows without a paper line "
                     "are ours.")
    else:
        lines.append("Peer rows as above: they do not depend on the AKF mode.")
    return "\n".join(lines)


def _not_default(result: dict) -> list[str]:
    """What makes this run differ from the configuration our claims are asserted on."""
    differences = []
    if result.get("scenario", "paper") != "paper":
        differences.append("--quick")
    if result.get("gating", "fixed_share") != "fixed_share":
        differences.append(f"--gating {result['gating']}")
    if result.get("n_experts", 40) != _DEFAULT_RUN["n_experts"]:
        differences.append(f"--experts {result['n_experts']}")
    return differences


def format_claims(result: dict, mode: str = "rls") -> str:
    """The paper's claims as "reproduced" / "not reproduced", each with one line of why and the page that
    explains it; in mode ``rls``, ours as "holds" / "does not hold" (tests/test_claims.py asserts them)."""
    suffix = "" if mode == "rls" else f"_{mode}"
    per_seed = result["claims_per_seed"][mode]
    claims = result[f"claims{suffix}"]
    shown = [index for index, claim in enumerate(claims) if claim["source"] == "paper" or mode == "rls"]
    counts = [sum(seed_claims[index]["holds"] for seed_claims in per_seed) for index in range(len(claims))]
    unanimous = all(counts[index] in (0, len(per_seed)) for index in shown)
    if len(per_seed) == 1:
        basis = "on 1 seed"
    elif unanimous:
        basis = f"on the mean over {len(per_seed)} seeds, the same on each"
    else:
        basis = f"on the mean over {len(per_seed)} seeds; [k/{len(per_seed)}]: seeds on which it holds"
    indent = " " * 18

    def verdict_line(index: int, claim: dict, link: str | None) -> str:
        text = f"  {claim['verdict']:<16}{claim['statement']}"
        if not unanimous:
            text += f" [{counts[index]}/{len(per_seed)}]"
        return f"{text:<92}  see {link}" if link else text

    lines = [f"The paper's claims, AKF mode '{mode}' ({basis}; pairs are X / Y):"]
    for index, claim in enumerate(claims):
        if claim["source"] == "paper":
            lines += [verdict_line(index, claim, claim["link"]), indent + claim["why"]]
    ours = [(index, claim) for index, claim in enumerate(claims) if claim["source"] == "ours"]
    if mode == "rls" and ours:
        lines += ["", ("Our claims for the default configuration (tests/test_claims.py asserts them; see "
                       "docs/paper.md#our-claims):")]
        differences = _not_default(result)
        if differences:
            lines.append(f"  (this run uses {', '.join(differences)}; the tests assert them on the paper's scenario, "
                         "K = 40, fixed-share gate)")
        for index, claim in ours:
            lines += [verdict_line(index, claim, None), indent + claim["why"]]
    return "\n".join(lines)


@click.group()
def reproduce():
    """Reproduce the paper's Table 1, Figure 2 and the ablations (Wira, Urban & Gresser 2001)."""


@reproduce.command("table1")
@click.option("--seeds", "n_seeds", default=5, show_default=True, type=click.IntRange(1),
              help="Number of evaluation seeds (0 .. N-1); numbers are means over seeds.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, writable=True), default=None,
              callback=output_file, help="Write every number to this JSON file.")
@click.option("--mode", type=click.Choice(["rls", "literal", "both"]), default="both", show_default=True,
              help="AKF dynamics of the single AKF and the mixtures: rls (ours), literal (eq. 6/7 as printed).")
@click.option("--experts", "n_experts", default=40, show_default=True, type=click.IntRange(2),
              help="Number of experts K of the mixtures.")
@click.option("--gating", type=click.Choice(["fixed_share", "paper"]), default=None,
              help="Gate of the softmax-mixture row (default: the default mixture's, fixed_share; "
                   "paper = eq. 8-10).")
@click.option("--quick", is_flag=True, help="A short scenario (312 frames instead of 1000) for a smoke run.")
@one_line_errors
def table1_command(n_seeds: int, json_path: str | None, mode: str, n_experts: int, gating: str | None, quick: bool):
    """Table 1: single AKF, softmax and random mixtures, beside our peers and the paper's numbers; then each of
    the paper's claims, reproduced or not, with one line of why (docs/paper.md explains them)."""
    from ..experiments.table1 import AKF_ROWS, aggregate, quick_scenario, run_seed, runs_per_seed

    modes = ("rls", "literal") if mode == "both" else (mode,)
    seeds = list(range(n_seeds))
    per_seed = []
    with progress_bar(n_seeds * runs_per_seed(modes), "table1", "run") as tick:
        for seed in seeds:
            per_seed.append(run_seed(seed, modes=modes, n_experts=n_experts, progress=tick,
                                     scenario=quick_scenario() if quick else None,
                                     mixture_options=None if gating is None else {"gating": gating}))
    result = aggregate(per_seed, modes, gating=gating)
    result["n_experts"] = n_experts
    result["scenario"] = "quick" if quick else "paper"
    result["gating"] = gating or "fixed_share"
    if json_path:   # first: a closed or full stdout ends the echoes below, not the file
        write_json(json_path, result)
    click.echo(heading(result))
    for number, current in enumerate(modes):
        click.echo()
        click.echo(format_table(result, current, rows=AKF_ROWS if number else None))
        click.echo()
        click.echo(format_claims(result, current))
    if json_path:
        click.echo()
        click.echo(f"wrote {json_path}")


@reproduce.command("figure2")
@click.option("--out", "out_path", required=True, type=click.Path(dir_okay=False, writable=True),
              callback=figure_file, help="Figure file to write (PNG; .pdf or .svg write those).")
@click.option("--seed", default=0, show_default=True, type=SEED, help="Seed of the scenario and of the bank.")
@click.option("--experts", "n_experts", default=40, show_default=True, type=click.IntRange(1), help="K.")
@click.option("--gating", type=click.Choice(["fixed_share", "paper", "random"]), default=None,
              help="Gate (default: the default mixture's, fixed_share).")
@click.option("--quick", is_flag=True, help="A short scenario (312 frames instead of 1000).")
@one_line_errors
def figure2_command(out_path: str, seed: int, n_experts: int, gating: str | None, quick: bool):
    """Figure 2: gating weights, learning rate, Q diagonals and absolute error of one run."""
    from .. import plots
    from ..experiments.figure2 import figure2
    from ..experiments.table1 import quick_scenario

    options = {} if gating is None else {"gating": gating}
    data = figure2(seed, n_experts=n_experts, scenario=quick_scenario() if quick else None, **options)
    plots.figure2(data, out_path)
    one_hot = float(np.mean(data["weights"].max(axis=1) > 0.8))
    click.echo(f"mixture RMS X {data['rms']['X']:.3f} px, Y {data['rms']['Y']:.3f} px; "
               f"largest weight > 0.8 on {100 * one_hot:.1f}% of frames")
    click.echo(f"wrote {out_path}")


def format_ablations(result: dict) -> str:
    lines = [f"Ablations on the paper's scenario, seeds {result['seeds']} (mean over seeds; ratio = mixture RMS / "
             "best single expert of the same run in hindsight)"]
    header = (f"{'variant':<58}{'K':>4}{'RMS X':>9}{'RMS Y':>9}{'RMS':>9}{'max':>8}{'best exp':>10}{'ratio':>8}"
              f"{'g>0.8':>8}")
    group = None
    for row in result["rows"]:
        if row["group"] != group:
            group = row["group"]
            lines += ["", f"[{group}]", header]
        m = row["mean"]
        lines.append(f"{row['name']:<58}{row['n_experts']:>4}{m['rms_X']:>9.3f}{m['rms_Y']:>9.3f}{m['rms']:>9.3f}"
                     f"{m['max']:>8.2f}{m['best_expert_rms']:>10.3f}{m['ratio_to_best_expert']:>8.3f}"
                     f"{m['max_weight_above_0.8_fraction']:>8.3f}")
    return "\n".join(lines)


@reproduce.command("ablations")
@click.option("--seeds", "n_seeds", default=3, show_default=True, type=click.IntRange(1),
              help="Number of seeds (0 .. N-1).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, writable=True), default=None,
              callback=output_file, help="Write every number to this JSON file.")
@click.option("--group", "groups", multiple=True,
              type=click.Choice(["akf_mode", "gate", "gating_input", "noise", "n_experts", "gate_settings"]),
              help="Only these groups (repeatable; default all).")
@click.option("--quick", is_flag=True, help="A short scenario (312 frames instead of 1000).")
@one_line_errors
def ablations_command(n_seeds: int, json_path: str | None, groups: tuple[str, ...], quick: bool):
    """Ablations: AKF literal vs rls, gate and gating input, Q/R adaptation and floor, K."""
    from ..experiments.ablations import ablations, variants
    from ..experiments.table1 import quick_scenario

    selected = groups or None
    total = len(variants(selected)) * n_seeds
    with progress_bar(total, "ablations", "run") as tick:
        result = ablations(range(n_seeds), groups=selected, progress=tick,
                           scenario=quick_scenario() if quick else None)
    if json_path:   # first: a closed or full stdout ends the echoes below, not the file
        write_json(json_path, result)
    click.echo(format_ablations(result))
    if json_path:
        click.echo(f"wrote {json_path}")


__all__ = ["reproduce", "heading", "format_table", "format_claims", "format_ablations"]
