"""Markdown tables of the saved benchmark results (``benchmarks/results/*.json``) for the docs' Results page.

Run: python -m benchmarks.results_tables              # docs/results.md with its tables filled in
     python -m benchmarks.results_tables --headline   # kalmix against the best tuned peer (one step, a lead)
     python -m benchmarks.results_tables --table NAME # the tables of one marker (``--list``: the names)

``docs/results.md`` holds marker lines ``<!-- results:table NAME -->``; :func:`fill` replaces each with the
tables of :data:`SECTIONS` ``[NAME]``, built from the JSON files alone (the docs' hook,
``docs/hooks/results.py``, calls it at every build). Every table names the files it read and the command
that wrote them. Each JSON file of ``benchmarks/results/`` is read by some table or listed in
:data:`NOT_SHOWN` with the reason (``tests/test_results_tables.py`` checks both). Standard library only.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS_DIR = ROOT / "benchmarks" / "results"
PAGE = ROOT / "docs" / "results.md"

#: A marker line of the page: ``<!-- results:table NAME -->``.
MARKER = re.compile(r"^(?P<indent>[ \t]*)<!--\s*results:table\s+(?P<name>[A-Za-z0-9_-]+)\s*-->[ \t]*$",
                    re.MULTILINE)

#: JSON files of ``benchmarks/results/`` that no table shows, and why.
NOT_SHOWN: dict[str, str] = {}

#: The shipped recordings (``kalmix evaluate --dataset NAME``) and the paper's simulated target, in table order.
RECORDINGS = ("hawkeye_ball", "cycling", "skillcorner")
DATASETS = ("paper",) + RECORDINGS
#: What each data set is, and the unit of its errors.
ABOUT = {
    "hawkeye_ball": ("hawkeye_ball", "m", "Hawk-Eye optical tracking of a football, 3-D, 50 Hz, two one-minute tracks"),
    "cycling": ("cycling", "m", "a bicycle's GPS log, 2-D, 1 Hz, one 73-minute ride"),
    "skillcorner": ("skillcorner", "m", "broadcast tracking of a whole football match, 2-D, 10 Hz, ball and players"),
    "paper": ("paper scenario", "px", "the paper's simulated stereo target (`kalmix reproduce`), 25 Hz"),
}

#: Rows of ``kalmix evaluate`` that are not peers: the mixture, its parts and the references (name prefixes;
#: the same as ``benchmarks.lead_vs_peers.NOT_PEERS``, which the tests check).
NOT_PEERS = ("mixture", "AKF mixture", "best expert", "no prediction", "single AKF")


# -- formatting ---------------------------------------------------------------------------------------------

def num(value, digits: int = 4) -> str:
    """``value`` to ``digits`` significant digits, plainly written (no exponent between 1e-4 and 1e6); thousands
    get separators; a missing or non-finite value is an em dash."""
    if value is None or isinstance(value, bool):
        return "—"
    value = float(value)
    if not math.isfinite(value):
        return "—"
    if value == 0:
        return "0"
    magnitude = math.floor(math.log10(abs(value)))
    if magnitude >= 6 or magnitude < -4:
        mantissa, exponent = f"{value:.{digits - 1}e}".split("e")
        return f"{mantissa}e{int(exponent)}"
    decimals = max(digits - 1 - magnitude, 0)
    return f"{value:,.{decimals}f}"


def ratio(value, digits: int = 3) -> str:
    """A ratio as ``0.951×``."""
    if value is None or not math.isfinite(float(value)):
        return "—"
    return f"{float(value):.{digits}f}×"


def percent(value, digits: int = 1) -> str:
    if value is None or not math.isfinite(float(value)):
        return "—"
    return f"{100 * float(value):.{digits}f} %"


def change(fraction: float) -> str:
    """A relative change as ``-1.9 %`` (two decimals where one would read 0.0)."""
    text = f"{100 * fraction:+.1f}"
    if float(text) == 0 and fraction != 0:
        text = f"{100 * fraction:+.2f}"
    return text.replace("-", "−") + " %"


def cell(text) -> str:
    """Table-safe text (a ``|`` would split the cell)."""
    return str(text).replace("|", "\\|").replace("\n", " ")


_NUMBER = re.compile(r"^(\*\*)?[-+−]?(\d|—|≥|≤|\.\d)")


def _numeric(rows, column: int) -> bool:
    """Whether ``column`` holds figures (right-aligned) rather than text: most of its non-empty cells start with one."""
    cells = [str(row[column]) for row in rows if str(row[column]) not in ("", "—")]
    return bool(cells) and sum(bool(_NUMBER.match(c)) for c in cells) * 2 >= len(cells)


# -- the files ----------------------------------------------------------------------------------------------

class Results:
    """The JSON files of a results directory, read once each; ``read`` holds the names read so far."""

    def __init__(self, directory: Path | str | None = None):
        self.directory = Path(RESULTS_DIR if directory is None else directory)
        self.read: set[str] = set()
        self._cache: dict[str, object] = {}

    def names(self) -> list[str]:
        return sorted(p.name for p in self.directory.glob("*.json"))

    def has(self, name: str) -> bool:
        return (self.directory / name).is_file()

    def __call__(self, name: str):
        if name not in self._cache:
            path = self.directory / name
            if not path.is_file():
                raise FileNotFoundError(f"{path}: no such results file (the tables read benchmarks/results/*.json; "
                                        f"re-run the benchmark that writes it, or change the table)")
            try:
                self._cache[name] = json.loads(path.read_text())
            except json.JSONDecodeError as error:
                raise ValueError(f"{path}: not valid JSON ({error})") from None
        self.read.add(name)
        return self._cache[name]


@dataclass
class Table:
    """A markdown table with its provenance: the files it was built from and the command that wrote them."""

    header: list
    rows: list
    sources: tuple
    command: str | tuple   # the command, or commands, that wrote the sources
    title: str | None = None
    notes: list = field(default_factory=list)
    bold_rows: set = field(default_factory=set)   # indexes of rows to set in bold

    def markdown(self) -> str:
        if not self.rows:
            raise ValueError(f"table {self.title or self.sources}: no rows")
        width = len(self.header)
        lines = []
        if self.title:
            lines += [f"**{self.title}**", ""]
        lines.append("| " + " | ".join(cell(h) for h in self.header) + " |")
        lines.append("|" + "|".join("--:" if i and _numeric(self.rows, i) else "---" for i in range(width)) + "|")
        for i, row in enumerate(self.rows):
            if len(row) != width:
                raise ValueError(f"table {self.title or self.sources}: row {row} has {len(row)} cells, not {width}")
            cells = [cell(c) for c in row]
            if i in self.bold_rows:
                cells = [f"**{c}**" if c not in ("", "—") and not c.startswith("**") else c for c in cells]
            lines.append("| " + " | ".join(cells) + " |")
        files = ", ".join(f"`benchmarks/results/{s}`" for s in self.sources)
        commands = (self.command,) if isinstance(self.command, str) else self.command
        lines += ["", f"<small>From {files}, written by {' and '.join(f'`{c}`' for c in commands)}."
                  + "".join(f" {n}" for n in self.notes) + "</small>"]
        return "\n".join(lines)


# -- kalmix evaluate on the shipped recordings ---------------------------------------------------------------

def evaluate_file(dataset: str) -> str:
    return f"evaluate_{dataset}.json"


EVALUATE_COMMAND = "kalmix evaluate --dataset NAME --per-coordinate --json benchmarks/results/evaluate_NAME.json"


def _is_peer(name: str) -> bool:
    return not name.startswith(NOT_PEERS)


def one_step_peers(evaluation: dict):
    """The peers' one-step RMS on the mixture's scored values ``{name: rms}``, and the peers left out because
    they ran on fewer values (a subsample) or gave no finite figure."""
    overall = evaluation["overall"]
    count = overall["mixture"]["one_step"]["count"]
    peers, left_out = {}, []
    for name in evaluation["predictors"]:
        if not _is_peer(name) or name not in overall:
            continue
        summary = overall[name]["one_step"]
        rms = summary.get("rms")
        if summary.get("count") != count or rms is None or not math.isfinite(rms):
            left_out.append(name)
        else:
            peers[name] = rms
    return peers, left_out


def best_one_step_peer(evaluation: dict):
    """``(name, rms)`` of the best tuned peer, one step ahead, on the mixture's scored values."""
    peers, _ = one_step_peers(evaluation)
    name = min(peers, key=peers.get)
    return name, peers[name]


def _peer_name(name: str, short: bool = False) -> str:
    """A peer's name as the tables write it; ``short``: without its package."""
    return re.sub(r" \([^)]*\)$", "", name) if short else name.replace(" (statsmodels ML)", " (statsmodels)")


def headline(results: Results, horizon: int = 10) -> list:
    """kalmix against the best tuned peer on each shipped recording: one row ahead, and ``horizon`` rows ahead."""
    lead = results("lead_vs_peers.json")
    rows = []
    for dataset in RECORDINGS:
        evaluation = results(evaluate_file(dataset))
        mixture = evaluation["overall"]["mixture"]["one_step"]["rms"]
        peer, peer_rms = best_one_step_peer(evaluation)
        if f"H={horizon}" not in lead[dataset]:
            raise ValueError(f"lead_vs_peers.json has no H={horizon} for {dataset}: it has "
                             f"{', '.join(k for k, _ in _horizons(lead[dataset]))}")
        ahead = lead[dataset][f"H={horizon}"]
        time_unit = evaluation["tuned"]["mixture"]["bank"]["time_unit"]
        label = ABOUT[dataset][0]
        rows.append([label, f"1 ({time_unit:.2g} s)", num(mixture), _peer_name(peer), num(peer_rms),
                     ratio(mixture / peer_rms)])
        rows.append([label, f"{horizon} ({horizon * time_unit:.2g} s)", num(ahead["mixture_rms"]),
                     _peer_name(ahead["best_peer"]), num(ahead["best_peer_rms"]), ratio(ahead["ratio"])])
    _blank_repeats(rows)
    unit = "/".join(sorted({ABOUT[d][1] for d in RECORDINGS}))
    return [Table(
        header=["recording", "rows ahead", f"kalmix ({unit})", "best tuned peer", f"its RMS ({unit})", "ratio"],
        rows=rows, sources=tuple(evaluate_file(d) for d in RECORDINGS) + ("lead_vs_peers.json",),
        command=(EVALUATE_COMMAND, "python -m benchmarks.lead_vs_peers --json benchmarks/results/lead_vs_peers.json"),
        notes=[("RMS per coordinate over the last 80 % of each track; every peer tuned on the first 20 %, kalmix "
                "untuned (its default bank). A ratio under 1 means kalmix is better.")])]


def _kind(predictor: str) -> str:
    if predictor.startswith(("mixture", "AKF mixture", "single AKF")):
        return "kalmix"
    return "reference" if predictor.startswith(("best expert", "no prediction")) else "tuned peer"


def one_step(results: Results) -> list:
    """Every row of ``kalmix evaluate`` on each shipped recording: one-step RMS and its ratio to the best peer's."""
    evaluations = {dataset: results(evaluate_file(dataset)) for dataset in RECORDINGS}
    predictors = []
    for evaluation in evaluations.values():
        predictors += [p for p in evaluation["predictors"] if p not in predictors]
    best = {dataset: best_one_step_peer(e) for dataset, e in evaluations.items()}
    left_out = {dataset: one_step_peers(e)[1] for dataset, e in evaluations.items()}
    rows, bold = [], set()
    for predictor in predictors:
        row = [predictor, _kind(predictor)]
        for dataset, evaluation in evaluations.items():
            summary = evaluation["overall"].get(predictor, {}).get("one_step", {})
            rms = summary.get("rms")
            if rms is None or not math.isfinite(rms):
                row.append("—")
            elif predictor in left_out[dataset]:
                row.append(f"{num(rms)} (subsample)")
            else:
                text = f"{num(rms)} ({ratio(rms / best[dataset][1])})"
                row.append(f"**{text}**" if predictor == best[dataset][0] else text)
        if predictor == "mixture":
            bold.add(len(rows))
        rows.append(row)
    notes = [("One-step RMS per coordinate (metres) over the last 80 % of each track and, in brackets, its ratio to "
             "the best tuned peer's (in bold). \"mixture\" is kalmix's default bank; \"AKF mixture\" and \"single "
             "AKF\" are the paper's; \"best expert (hindsight)\" is an oracle that picks the bank's best expert after "
             "the fact. The files also hold each row's mean absolute and largest error, per track as well.")]
    for dataset, names in left_out.items():
        if names:
            count = evaluations[dataset]["overall"][names[0]]["one_step"].get("count")
            notes.append(f"On {dataset}, {' and '.join(names)} ran on a subsample ({count:,} of "
                         f"{evaluations[dataset]['overall']['mixture']['one_step']['count']:,} values: Python loops), "
                         "so they are left out of the comparison.")
    for dataset, evaluation in evaluations.items():
        tracks = evaluation.get("tracks", {})
        label, _unit, about = ABOUT[dataset]
        notes.append(f"{label}: {about}; {len(tracks)} track(s), {sum(tracks.values()):,} rows.")
    return [Table(header=["predictor", "kind"] + [f"{ABOUT[d][0]} ({ABOUT[d][1]})" for d in RECORDINGS], rows=rows,
                  sources=tuple(evaluate_file(d) for d in RECORDINGS), command=EVALUATE_COMMAND, notes=notes,
                  bold_rows=bold)]


def lead(results: Results) -> list:
    """H-step RMS of the mixture (the lead head's forecasts) against every tuned peer's."""
    data = results("lead_vs_peers.json")
    rows = []
    for dataset in DATASETS:
        if dataset not in data:
            continue
        label, _unit, _ = ABOUT[dataset]
        for key, entry in _horizons(data[dataset]):
            rows.append([label, key[2:], num(entry["mixture_rms"]), _peer_name(entry["best_peer"]),
                         num(entry["best_peer_rms"]),
                         ratio(entry["ratio"])])
    _blank_repeats(rows)
    return [Table(header=["recording", "H", "kalmix (lead head)", "best tuned peer", "its RMS", "ratio"],
                  rows=rows, sources=("lead_vs_peers.json",),
                  command="python -m benchmarks.lead_vs_peers --json benchmarks/results/lead_vs_peers.json",
                  notes=[("What `kalmix evaluate -H H` prints: RMS per coordinate of the forecasts H rows ahead "
                         "(metres; pixels for the paper scenario), every peer tuned on the first 20 % of each track "
                         "for its one-step RMS. On the paper scenario the peers are tuned on the slow start of each "
                         "run, so they are far off there; the paper's Table 1 (peers tuned on a separate seed) is its "
                         "fair comparison.")])]


def _blank_repeats(rows, column: int = 0):
    """Leave a repeated value of ``column`` blank after its first row (a grouped table)."""
    last = None
    for row in rows:
        value = row[column]
        if value == "":
            continue
        if value == last:
            row[column] = ""
        else:
            last = value


def _horizons(entry: dict):
    """``(key, value)`` of the ``H=n`` entries in increasing n."""
    keys = sorted((k for k in entry if k.startswith("H=")), key=lambda k: int(k[2:]))
    return [(k, entry[k]) for k in keys]


def _lead_and_intervals(results: Results):
    """``lead_and_intervals.json`` with the entries re-run into ``lead_and_intervals_*.json`` put in their place;
    ``{dataset: {key: (value, file)}}``."""
    merged = {}
    for name in ["lead_and_intervals.json"] + sorted(
            n for n in results.names() if n.startswith("lead_and_intervals_")):
        for dataset, entries in results(name).items():
            for key, value in entries.items():
                merged.setdefault(dataset, {})[key] = (value, name)
    return merged


def _lead_and_intervals_rows(results: Results, build):
    """``build(dataset label, H, entry)`` for every ``H=`` entry of the lead-and-intervals files, and the files used."""
    merged = _lead_and_intervals(results)
    rows, used = [], set()
    for dataset in DATASETS:
        for key in sorted((k for k in merged.get(dataset, {}) if k.startswith("H=")), key=lambda k: int(k[2:])):
            entry, source = merged[dataset][key]
            used.add(source)
            rows.append(build(ABOUT[dataset][0], key[2:], entry))
    _blank_repeats(rows)
    later = sorted(used - {"lead_and_intervals.json"})
    notes = []
    if later:
        notes.append("Rows found in " + ", ".join(f"`{n}`" for n in later) + " (a re-run of part of the benchmark) "
                     "are taken from there.")
    return rows, tuple(["lead_and_intervals.json"] + later), notes


LEAD_AND_INTERVALS_COMMAND = ("python -m benchmarks.lead_and_intervals --json "
                              "benchmarks/results/lead_and_intervals.json")


def intervals(results: Results) -> list:
    """Coverage of the 95 % intervals and the NEES, one step and H rows ahead."""
    def build(label, h, entry):
        one, ahead = entry["calibration"]["one_step"], entry["calibration"]["horizon"]
        return [label, h, f"{percent(one['coverage_95'])} / {percent(ahead['coverage_95'])}",
                f"{num(one['mean_nees'], 3)} / {num(ahead['mean_nees'], 3)}",
                f"{num(one['median_nees'], 2)} / {num(ahead['median_nees'], 2)}", f"{ahead['count']:,}"]

    rows, sources, notes = _lead_and_intervals_rows(results, build)
    notes.insert(0, "Default bank, no peers; one row ahead and H rows ahead. The coverage aims at 95 %. The NEES "
                    "(squared error over the predicted "
                    "variance) of a Gaussian forecast averages the number of coordinates (3 on hawkeye_ball and the "
                    "paper scenario, 2 elsewhere): heavy tails (a kick, a relocation) make its mean large while its "
                    "median stays below.")
    return [Table(header=["recording", "H", "coverage, 1 / H ahead", "mean NEES, 1 / H", "median NEES, 1 / H",
                          "scored rows"],
                  rows=rows, sources=sources, command=LEAD_AND_INTERVALS_COMMAND, notes=notes)]


def lead_weights(results: Results) -> list:
    """H-step RMS of the lead head's forecasts and of the one-step weights'."""
    def build(label, h, entry):
        lead_rms, one_rms = entry["lead_weights_rms"], entry["one_step_weights_rms"]
        return [label, h, num(lead_rms), num(one_rms), change(lead_rms / one_rms - 1)]

    rows, sources, notes = _lead_and_intervals_rows(results, build)
    notes.insert(0, "The same H-step forecasts of the default bank's experts, weighted by the lead head (its weights "
                    "learned on H-step errors, blended with the one-step weights' forecast by the same rule on the "
                    "same delayed errors) or by the one-step rule.")
    return [Table(header=["recording", "H", "lead head", "one-step weights", "change"], rows=rows,
                  sources=sources, command=LEAD_AND_INTERVALS_COMMAND, notes=notes)]


def warm_start(results: Results) -> list:
    """One-step RMS and coverage with a warm, a cold or no restart at a time gap."""
    merged = _lead_and_intervals(results)
    rows, used = [], set()
    what = {"warm": "warm start (the default)", "cold": "cold start", "bridged": "bridged"}
    for dataset in DATASETS:
        if "warm_start" not in merged.get(dataset, {}):
            continue
        entry, source = merged[dataset]["warm_start"]
        used.add(source)
        for key, text in what.items():
            if key in entry:
                rows.append([ABOUT[dataset][0], text, num(entry[key]["rms"]), percent(entry[key]["coverage_95"]),
                             num(entry[key]["mean_nees"], 3)])
    _blank_repeats(rows)
    sources = tuple(sorted(used))
    return [Table(header=["recording", "at a time gap", "one-step RMS", "coverage", "mean NEES"], rows=rows,
                  sources=sources,
                  command="python -m benchmarks.lead_and_intervals [--datasets NAME ...] --json FILE",
                  notes=[("Warm start: at a gap the experts start again, the rule and the calibration keep what "
                          "the track taught them. Cold start: everything starts again. Bridged: nothing restarts, the "
                          "experts predict across the gap. The rows after a gap are scored in none of the three; "
                          "cycling has no gap, so its three rows agree.")])]


def lead_rate(results: Results) -> list:
    """The lead rule's delayed learning rate against the one-step rate, and the bounds in hindsight."""
    data = results("lead_rate.json")
    rows = []
    for dataset in DATASETS:
        if dataset not in data:
            continue
        for key, entry in _horizons(data[dataset]):
            hindsight = entry.get("hindsight", {})
            rows.append([ABOUT[dataset][0], key[2:],
                         (f"{num(entry['lead_rms_delay_1'])} → {num(entry['lead_rms_delay_H'])} "
                         f"({change(entry['change'])})"),
                         num(hindsight.get("best_expert")), num(hindsight.get("best_convex"))])
    _blank_repeats(rows)
    return [Table(header=["recording", "H", "one-step rate → rate / √H (the default)", "best expert*",
                          "best convex mix*"],
                  rows=rows, sources=("lead_rate.json",),
                  command="python -m benchmarks.lead_rate --hindsight --json benchmarks/results/lead_rate.json",
                  notes=[("H-step RMS of the default bank with lead weights, the lead rule learning at the one-step "
                          "rate or at the rate divided by √H. *In hindsight: the best single expert and the best fixed "
                          "convex combination of the experts, fitted on the very rows they score (where every expert "
                          "has a forecast); no online rule on this bank does better.")])]


# -- the ablation ----------------------------------------------------------------------------------------------

#: The ablation's files, in page order: (file, title). The rows are the JSON's, as ``benchmarks.ablation`` names them.
ABLATIONS = {
    "ablation": (("ablation_clip.json", "BOA on clipped errors (the default rule) and its neighbours"),
                 ("ablation_turn.json", "The turn family"),
                 ("ablation_default.json", "Banks × rules")),
    "ablation-more": (("ablation_ar.json", "The AR recipe"),
                      ("ablation_two_level.json", "A second level of aggregation (BOA over BOA mixtures)"),
                      ("ablation_iterated_ar.json", "Two rows with the AR experts' iterated forecasts"),
                      ("ablation_warmup_audit.json", ("The 119-expert bank without the clip, with the glitch screen's "
                                                     "warm-up audit"))),
    "ablation-hawkeye": (("ablation_reanchor_hawkeye.json", ("hawkeye_ball: every configuration, with the AKF "
                                                            "re-anchor")),),
}
ABLATION_PROTOCOL = ("One-step RMS over the last 80 % of every track, on the segments `kalmix predict` makes, length "
                     "and time units from the first 20 %; every segment starts afresh. In brackets, the ratio to the "
                     "best tuned peer of `kalmix evaluate` on the recording (a different protocol: it warm-starts a "
                     "track's segments). \"boa\" is the original rule; \"bound forgetting .99\" and \"clip 3\" are "
                     "the default's options; the numbers count experts (akf40: the paper's 40 AKFs, kinematic28: CV "
                     "and CA Kalman filters, ar48: AR models of the velocity, turn3: coordinated turns, mixed68: akf40 "
                     "+ kinematic28).")


def _ablation_command(name: str, data: dict) -> str:
    datasets = " ".join(data)
    two_level = " --two-level" if any(k.startswith("2-level") for v in data.values() for k in v["rows"]) else ""
    return (f"python -m benchmarks.ablation --datasets {datasets} --configs ROW ...{two_level} "
            f"--json benchmarks/results/{name}")


def _peer_rms(results: Results, dataset: str):
    if dataset in RECORDINGS and results.has(evaluate_file(dataset)):
        return best_one_step_peer(results(evaluate_file(dataset)))[1]
    return None


def ablation_table(results: Results, name: str, title: str) -> Table:
    data = results(name)
    datasets = [d for d in DATASETS if d in data] + [d for d in data if d not in DATASETS]
    configs = []
    for dataset in datasets:
        for config in data[dataset]["rows"]:
            if config not in configs:
                configs.append(config)
    peers = {d: _peer_rms(results, d) for d in datasets}
    rows, bold = [], set()
    for config in configs:
        row = [config]
        for dataset in datasets:
            entry = data[dataset]["rows"].get(config)
            if entry is None:
                row.append("—")
                continue
            text = num(entry["rms"], 5)
            if peers[dataset]:
                text += f" ({ratio(entry['rms'] / peers[dataset])})"
            row.append(text)
        if "(the default)" in config:
            bold.add(len(rows))
        rows.append(row)
    sources = (name,) + tuple(evaluate_file(d) for d in datasets if peers[d])
    header = ["bank and rule"] + [f"{ABOUT[d][0]} ({ABOUT[d][1]})" if d in ABOUT else d for d in datasets]
    return Table(header=header, rows=rows, sources=sources, title=title, bold_rows=bold,
                 command=(_ablation_command(name, data),) + ((EVALUATE_COMMAND,) if len(sources) > 1 else ()))


def _ablations(group: str, protocol: bool):
    def build(results: Results) -> list:
        tables = [ablation_table(results, name, title) for name, title in ABLATIONS[group]]
        if protocol:
            tables[0].notes.append(ABLATION_PROTOCOL)
        return tables

    build.__doc__ = f"The ablation's tables of {', '.join(name for name, _ in ABLATIONS[group])}."
    return build


def best_experts(results: Results) -> list:
    """The best single expert in hindsight of each bank of the main ablation (the same under every rule)."""
    data = results("ablation_default.json")
    datasets = [d for d in DATASETS if d in data]
    banks = {}
    for dataset in datasets:
        for config, entry in data[dataset]["rows"].items():
            bank = config.split(" ")[0]
            banks.setdefault(bank, {}).setdefault(dataset, set()).add(entry["best_expert"])

    def best(values):   # one figure per bank (the experts do not depend on the rule); a range if a file disagrees
        if not values:
            return "—"
        low, high = min(values), max(values)
        return num(low, 5) if num(low, 5) == num(high, 5) else f"{num(low, 5)}-{num(high, 5)}"

    rows = [[bank] + [best(values.get(d)) for d in datasets] for bank, values in banks.items()]
    return [Table(header=["bank"] + [f"{ABOUT[d][0]} ({ABOUT[d][1]})" for d in datasets], rows=rows,
                  sources=("ablation_default.json",), title="The best single expert of each bank, in hindsight",
                  command=_ablation_command("ablation_default.json", data),
                  notes=["An oracle: the bank's expert with the lowest RMS on the scored rows, chosen afterwards."])]


def clip_variants(results: Results) -> list:
    data = results("clip_variants.json")
    columns = [d for d in DATASETS if d in data] + [d for d in data if d not in DATASETS]
    variants = [k for k in next(iter(data.values())) if k != "engine"]
    labels = {"clip off": "clip off", "shipped": "shipped: regrets clipped, range bound whole, scale of whole errors",
              "bound shrunk too": "the range bound clipped too", "scale of shrunk errors": "the scale from the clipped "
              "errors (a Huber scale)"}
    rows = [[labels.get(v, v)] + [num(data[c].get(v), 5) for c in columns] for v in variants]
    rows.append(["the engine itself, clip off / shipped"]
                + [f"{num(data[c]['engine']['clip off'], 5)} / {num(data[c]['engine']['shipped'], 5)}"
                   for c in columns])
    header = ["BOA variant (bound forgetting .99, clip 3)"] + [ABOUT[c][0] if c in ABOUT else c for c in columns]
    return [Table(header=header, rows=rows, sources=("clip_variants.json",), bold_rows={1},
                  title="Which errors to clip: offline replays of the rule on the default bank's forecasts",
                  command="python -m benchmarks.clip_variants --json benchmarks/results/clip_variants.json",
                  notes=[("One-step RMS, the ablation's protocol. \"regime change\" is a noise-free target kicked from "
                         "0.5 mm to 3 m a row (RMS from the third row after the kick): how fast each variant follows "
                         "a lasting change of motion.")])]


# -- hawkeye_ball's bounds ---------------------------------------------------------------------------------------

def hawkeye_bounds(results: Results) -> list:
    data = results("hawkeye_bounds.json")
    peer = data["best_peer"]

    def row(what, rms):
        return [what, num(rms, 4), ratio(rms / peer, 4)]

    rows = [row("the best tuned peer (Holt-Winters)", peer), row("two-point extrapolation 2z[t-1] - z[t-2]",
                                                                  data["two_point"])]
    for key, entry in data["linear_oracle"].items():
        rows.append(row(f"best linear predictor of the velocity, {_singular(key)}", entry["rms"]))
    for key, rms in data["kinematic_features_oracle"].items():
        rows.append(row(f"the same plus gravity, drag and squared-velocity terms, {_singular(key)}", rms))
    bounce = data["bounce_oracle"]
    rows.append(row(f"two-point with a ground-bounce rule (restitution {bounce['restitution']}, offset "
                    f"{bounce['offset']} m)", bounce["rms"]))
    rows.append(row("the bounce rule plus the linear correction", data["bounce_and_linear_oracle"]))
    rows.append(row("kalmix's default mixture (the ablation's rows)", data["default_mixture"]))
    mixture_bounce = data["default_mixture_bounce_oracle"]
    rows.append(row("the default mixture with the bounce rule", mixture_bounce["rms"]))
    command = "python -m benchmarks.hawkeye_bounds --json benchmarks/results/hawkeye_bounds.json"
    first = Table(header=["predictor (every one but the mixture fitted in hindsight on the rows it scores)", "RMS (m)",
                          "/ best peer"], rows=rows, sources=("hawkeye_bounds.json",), command=command,
                  bold_rows={len(rows) - 2},
                  title="How low can a one-step forecast of hawkeye_ball go?",
                  notes=[(f"{data['scored_rows']:,} scored rows (the ablation's). Each oracle is fitted on the rows it "
                         "scores, so no online predictor of its kind does better.")])
    split = data["default_mixture_squared_error_by_rows"]
    rows = [[k, f"{v['rows']:,}", num(v["two-point"], 4), num(v["mixture"], 4)] for k, v in split.items()]
    shares = data["squared_error_shares"]
    second = Table(header=["rows", "count", "two-point: squared error", "default mixture: squared error"], rows=rows,
                   sources=("hawkeye_bounds.json",), command=command,
                   title="Where the squared error lies (kick rows: the two-point extrapolation's worst)",
                   notes=["Share of the two-point extrapolation's squared error in its worst rows: "
                          + ", ".join(f"{k} {percent(v, 0)}" for k, v in shares.items()) + "."])
    return [first, second]


def _singular(text: str) -> str:
    return re.sub(r"\b1 velocities\b", "1 velocity", text)


# -- irregular sampling -----------------------------------------------------------------------------------------

#: The irregular-sampling runs, as the table names them.
IRREGULAR_RUNS = {"gap restarts (default)": "default", "bridged (--max-gap none)": "bridged",
                  "gap restarts, --reach none": "default, `--reach none`", "bridged, --reach none":
                  "bridged, `--reach none`", "bridged, --reach 8": "bridged, `--reach 8`"}


def irregular(results: Results) -> list:
    data = results("irregular_sampling.json")
    command = "python -m benchmarks.irregular_sampling --json benchmarks/results/irregular_sampling.json"
    runs = {k: v for k, v in data.items() if isinstance(v, dict) and "mixture" in v and "segments" in v}
    rows = []
    peers = {entry["best_peer"] for entry in runs.values()}
    for key, entry in runs.items():
        peer = num(entry["best_peer_rms"])
        if len(peers) > 1:
            peer = f"{entry['best_peer']}: {peer}"
        rows.append([IRREGULAR_RUNS.get(key, key), f"{entry['segments']:,}", num(entry["mixture"]),
                     num(entry["best_expert"]), peer, ratio(entry["mixture"] / entry["best_peer_rms"]),
                     percent(entry["coverage_95"])])
    peer_note = f" The best tuned peer is {next(iter(peers))} in every run." if len(peers) == 1 else ""
    first = Table(header=["run", "segments", "kalmix (m)", "best expert* (m)", "best peer (m)", "ratio",
                          "coverage"], rows=rows, sources=("irregular_sampling.json",), command=command,
                  title="Six simulated vessels reporting every 2-180 s (AIS-like), one-step RMS",
                  notes=[("`kalmix evaluate` with its peers. Bridged: `--max-gap none`, no step restarts the experts; "
                          "with the default gap rule a step beyond the spread of a track's first steps does. "
                          "The default reach here: across a step over 1.5 time units only the CV experts forecast "
                          "(the steps are heavy-tailed); `--reach none`: every expert at every step. *The bank's "
                          "best expert, chosen in hindsight. Coverage of the 95 % intervals." + peer_note)])
    tables = [first]
    grid = data.get("bridged, by time unit and reach")
    if grid:
        parsed = {}
        for key, value in grid.items():
            match = re.match(r"time unit (?P<unit>[^,]+), reach (?P<reach>.+)$", key)
            parsed.setdefault(match["unit"], {})[match["reach"]] = value
        reaches = list(next(iter(parsed.values())))
        rows = [[f"{unit} s"] + [num(v.get(r)) for r in reaches] for unit, v in parsed.items()]
        tables.append(Table(header=["time unit"] + ["no reach" if r == "None" else f"reach {r}" for r in reaches],
                            rows=rows,
                            sources=("irregular_sampling.json",), command=command,
                            title="Bridged: one-step RMS (m) by time unit and reach",
                            notes=[("The engine on the bridged tracks with the time unit forced (`kalmix evaluate` "
                                   "takes the median step). With a reach, across a step over that many time units "
                                   "only the CV experts forecast.")]))
    for key, entry in data.items():
        if key.endswith("by step"):
            rows = [[family, num(v["best_rms"]), num(v["best_long"]), percent(v["weight_long"])]
                    for family, v in entry["families"].items()]
            run = IRREGULAR_RUNS.get(key.replace(", by step", ""), key.replace(", by step", ""))
            tables.append(Table(header=["family", "best expert, all steps (m)", "best expert, long steps (m)",
                                        "weight on long steps"], rows=rows, sources=("irregular_sampling.json",),
                                command=command, title=f"{run}: the families on the {entry['rows_long']:,} steps "
                                                       f"over 60 s",
                                notes=[(f"The mixture: {num(entry['mixture_long'])} m on those steps, "
                                       f"{num(entry['mixture_other'])} m on the {entry['rows_other']:,} others.")]))
    return tables


# -- models with a known optimum ---------------------------------------------------------------------------------

def _times(value) -> str:
    """A ratio as ``1.016×``, or ``16,899×`` when it is large."""
    return ratio(value) if value is None or not float(value) >= 10 else f"{num(value, 3)}×"


def _zoo_notes(entry: dict) -> list:
    """What the default gap rule did to a scenario: the track it split most, and the glitches a run reported."""
    notes = []
    scored = entry["scores"]["scored"]["predictors"]
    split = entry["kalmix_runs"]["kalmix"].get("segments_per_track", [])
    optimum, kalmix = scored["optimum"].get("per_track_rms_euclidean"), scored["kalmix"].get("per_track_rms_euclidean")
    if split and optimum and kalmix and max(split) > 2:
        worst = max(range(len(split)), key=split.__getitem__)
        rest = [k for k in range(len(split)) if k != worst]
        others = math.sqrt(sum(kalmix[k] ** 2 for k in rest) / sum(optimum[k] ** 2 for k in rest))
        notes.append(f"{entry['label']}: the default gap rule split one track into {split[worst]} segments (its "
                     f"reference interval came out short), and kalmix's RMS on it is "
                     f"{_times(kalmix[worst] / optimum[worst])} the reference's; on the other tracks together "
                     f"{_times(others)}.")
    for run, text in entry["kalmix_runs"].items():
        found = re.search(r"kalmix: (\d+) outlier", text.get("stderr", ""))
        if found and "silence" in entry["label"]:
            notes.append(f"{entry['label']}, `{run.replace('kalmix', 'kalmix predict')}`: it reported "
                         f"{found[1]} outliers, the first rows after the silence, which its glitch screen does not "
                         "learn from, so their forecasts stay where the track was expected, far off.")
    return notes


def model_zoo(results: Results) -> list:
    """kalmix against the optimal one-step predictor on tracks drawn from known models."""
    data = results("model_zoo.json")
    command = data.get("command", "python -m benchmarks.model_zoo") + " --json benchmarks/results/model_zoo.json"
    groups = {"scored": "", "after the silence": ": rows after it",
              "first row after the silence": ": first row after it"}
    rows, about, notes = [], [], []
    for entry in data["scenarios"].values():
        unit = entry.get("unit", "m")
        for group, suffix in groups.items():
            if group not in entry["scores"]:
                continue
            scored = entry["scores"][group]
            p = scored["predictors"]
            rows.append([entry["label"] + suffix, "IMM*" if "IMM" in entry["reference"] else "Kalman filter",
                         f"{scored['rows']:,}", f"{num(p['optimum']['rms_per_coordinate'])} {unit}",
                         f"{num(p['kalmix']['rms_per_coordinate'])} {unit}", _times(p["kalmix"]["ratio_to_optimum"]),
                         _times(p["kalmix --max-gap none"]["ratio_to_optimum"]),
                         _times(p["kalmix --no-population-prior"]["ratio_to_optimum"])
                         if "kalmix --no-population-prior" in p else "",
                         _times(p["kalmix --rule boa"]["ratio_to_optimum"]) if "kalmix --rule boa" in p else "",
                         _times(p["no prediction"]["ratio_to_optimum"]), percent(p["kalmix"]["coverage_95"])])
        segments = entry["kalmix_runs"]["kalmix"]["segments"]
        notes += _zoo_notes(entry)
        about.append([entry["label"], entry["about"], f"{entry['tracks']} × {entry['rows_per_track']}",
                      str(entry["seed"]), f"{segments:,}"])
    kalmix = data.get("kalmix", {})
    at = f" kalmix at commit {kalmix['commit'][:10]}." if kalmix.get("commit") and not kalmix.get(
        "working_tree_changes") else ""
    first = Table(
        header=["scenario", "reference", "scored rows", "reference RMS", "kalmix RMS", "kalmix / reference",
                "--max-gap none / reference", "--no-population-prior / reference", "--rule boa / reference",
                "no prediction / reference", "kalmix coverage"],
        rows=rows, sources=("model_zoo.json",), command=command,
        title="One-step RMS against the optimal predictor",
        notes=[("RMS per coordinate over every row after the first 20 % of each track (the same rows for every "
                "predictor); the ratios are the same for the Euclidean RMS. The reference is the Kalman filter with "
                "the true model, noises, time steps and prior: the optimal one-step predictor, so a ratio under 1 "
                "could only be chance. *For the Markov switching scenario it is an IMM with the true models and "
                "switching matrix, near-optimal, not optimal. kalmix: `kalmix predict` with its defaults on a CSV "
                "of the tracks (automatic units, the default gap rule, the population prior: a new track starts "
                "from what the tracks before it learned), with `--max-gap none`, with `--no-population-prior` "
                "(every track starts empty), and with `--rule boa` (BOA alone: the default, BOA-blend, runs it on "
                "the linearised and on the exact regrets and blends the two). No prediction: "
                "the last measurement. Coverage: share of the measurements inside kalmix's forecast ± 1.96 std, "
                "per coordinate (95 % is right). With a 3-day silence the first row after it is "
                "scored on its own, not in the scenario's main row." + at)] + notes)
    second = Table(header=["scenario", "true model", "tracks × rows", "seed", "kalmix segments"], rows=about,
                   sources=("model_zoo.json",), command=command, title="The scenarios",
                   notes=[("2-D tracks; each track's initial state drawn from the prior the reference starts from "
                           "(in the file with every parameter). kalmix segments: the tracks' pieces after "
                           "`kalmix predict`'s default gap rule (once a track has 4 steps, a step over 3 times its "
                           "reference interval, the upper quartile of its first 16 steps times their spread, "
                           "restarts the experts), one per track when nothing splits.")])
    return [first, second]


def zoo_lead(results: Results) -> list:
    """kalmix's lead forecasts (H rows ahead) against the optimal H-step predictor, the one-step weights on the same
    experts and the best tuned peer, on the zoo's regularly sampled scenarios."""
    data = results("model_zoo_lead.json")
    command = data.get("command", "python -m benchmarks.zoo_lead") + " --json benchmarks/results/model_zoo_lead.json"
    predict, cold = "kalmix predict --horizon H", "kalmix predict --horizon H --no-population-prior"
    rows = []
    for entry in data["scenarios"].values():
        unit = entry.get("unit", "m")
        for key, h in _horizons(entry["horizons"]):
            r = h["ratio_to_optimum"]
            worse = h["lead_over_one_step_weights_per_track"]
            rows.append([entry["label"], key[2:], f"{num(h['rms_per_coordinate']['optimum'])} {unit}",
                         _times(r[predict]), _times(r[cold]), _times(r["mixture (lead head)"]),
                         _times(r["mixture, one-step weights"]),
                         f"{ratio(h['lead_over_one_step_weights'], 4)} ({h['tracks_lead_worse']} of {len(worse)})",
                         _peer_name(h["best_peer"]), _times(h["best_peer_ratio_to_optimum"]),
                         _times(r["no prediction"]), percent(h["coverage_95"][predict])])
    _blank_repeats(rows)
    left_out = "; ".join(f"`{name}`: {why}" for name, why in data.get("left_out", {}).items())
    return [Table(
        header=["scenario", "H", "optimum RMS", "kalmix predict / optimum", "--no-population-prior / optimum",
                "lead head / optimum", "one-step weights / optimum", "lead / one-step weights (tracks worse)",
                "best tuned peer", "peer / optimum", "no prediction / optimum", "kalmix coverage"],
        rows=rows, sources=("model_zoo_lead.json",), command=command,
        title="Forecasts H rows ahead against the optimal H-step predictor",
        notes=[("RMS per coordinate of the forecast of each row made H rows before it, over every row after the "
                "first 20 % of each track (the same rows for every predictor and as the one-step table), on the "
                "same seeded tracks. The optimum is the Kalman filter with the true model, its state H rows back "
                "propagated H steps: the conditional mean. kalmix predict: its `pred<H>_` columns with the "
                "defaults, and with `--no-population-prior`. Lead head, one-step weights and peers: what `kalmix "
                "evaluate -H H` measures on the same table (every track's weights start empty there): the default "
                "mixture's forecasts (the lead head's weights blended with the one-step weights' forecast), the "
                "same experts' one-step mixture extrapolated H steps, and the best of the tuned peers at H (each "
                "tuned on the first 20 % of every track). Tracks worse: tracks where the lead head's RMS is above "
                "the one-step weights'. Coverage: of `kalmix predict`'s forecast ± 1.96 std, per coordinate. Left "
                f"out: {left_out}.")])]


# -- speed --------------------------------------------------------------------------------------------------------

SPEED_FILES = (("engine_speed.json", "source checkout"),
               ("engine_speed_user_install.json", "`pip install` of the same code"))


def _machine(data: dict) -> str:
    machine = data.get("machine", {})
    if not machine:
        return "machine not recorded"
    before = machine.get("load_average_before") or [math.nan]
    after = machine.get("load_average_after") or [math.nan]
    return (f"{machine.get('cpus', '?')} CPUs ({machine.get('processor', '?')}), 1-minute load average "
            f"{before[0]:.2f} before and {after[0]:.2f} after")


#: The speed table's rows: (label, section, key, target key or None, "at least" / "at most"); a label's
#: ``{name}`` is the section's size of that name in the first file.
SPEED_ROWS = (
    ("one stream, {steps} rows: steps/s", "one_stream", "steps_per_s", "target_steps_per_s", "≥"),
    ("peer: filterpy's IMM (CV + CA), same data: steps/s", "one_stream", "imm_steps_per_s", None, ""),
    ("{targets} targets × {steps} rows: expert-steps/s", "many_targets", "expert_steps_per_s",
     "target_expert_steps_per_s", "≥"),
    ("the same in target-steps/s", "many_targets", "target_steps_per_s", None, ""),
    ("peer: simdkalman, one CV filter per coordinate: target-steps/s", "many_targets",
     "simdkalman_cv_target_steps_per_s", None, ""),
    ("`kalmix predict`, {tracks}-track {rows}-row CSV, warm cache: rows/s", "cli", "rows_per_s", "target_rows_per_s",
     "≥"),
    ("the same: seconds, whole process", "cli", "seconds", None, ""),
    ("the same CSV piped into `kalmix predict -`: rows/s", "cli", "stdin_rows_per_s", None, ""),
    ("peer: filterpy CV filter per track, Python loop over the CSV: rows/s", "cli", "filterpy_cv_rows_per_s", None, ""),
    ("a live row, `TrackPredictor.step_row`: median ms", "live_row", "median_ms", None, ""),
    ("the same: 90th percentile, ms", "live_row", "p90_ms", None, ""),
    ("peer: filterpy's IMM, predict + update: ms a row", "live_row", "imm_ms_per_row", None, ""),
    ("cold start: `kalmix predict` of {rows} rows, empty compiled cache: s", "cold_start", "cold_seconds",
     "target_cold_seconds", "≤"),
    ("the same, warm cache: s", "cold_start", "warm_seconds", None, ""),
)


def speed(results: Results) -> list:
    present = [(name, label) for name, label in SPEED_FILES if results.has(name)]
    data = {name: results(name) for name, _ in present}
    first = data[present[0][0]]
    rows = []
    for text, section, key, target, sense in SPEED_ROWS:
        if not any(key in d.get(section, {}) for d in data.values()):
            continue
        sizes = {k: (f"{v:,}" if isinstance(v, int) else v) for k, v in first.get(section, {}).items()}
        goal = first.get(section, {}).get(target) if target else None
        rows.append([text.format(**sizes)] + [num(data[name].get(section, {}).get(key), 3) for name, _ in present]
                    + [f"{sense} {num(goal, 3)}" if goal is not None else ""])
    notes = [f"{label}: {_machine(data[name])}." for name, label in present]
    experts = first.get("one_stream", {}).get("experts")
    bank = f"default bank ({experts} experts, " if experts else "default bank ("
    notes.append("Medians of the timed runs after an untimed warm-up, the peers in the same run. kalmix runs its "
                 f"{bank}the glitch screen, calibrated intervals); each peer runs one model without intervals.")
    return [Table(header=["figure"] + [label for _, label in present] + ["goal"], rows=rows,
                  sources=tuple(name for name, _ in present),
                  command="python -m benchmarks.engine_speed --cold --json benchmarks/results/engine_speed.json",
                  notes=notes)]


def akf_kernels(results: Results) -> list:
    """The compiled AKF kernels of one or more source trees: seconds by bank size and workload, compile times."""
    name = "akf_kernels.json"
    data = results(name)
    columns = [(label, kernel) for label, tree in data["trees"].items() for kernel in tree["kernels"]]
    header = ["workload", "experts"] + [f"{label}: {kernel.replace('_', '-')} kernel, s" for label, kernel in columns]
    cells, hashes = {}, {}
    for label, tree in data["trees"].items():
        for row in tree["speed"]:
            cells[(row["workload"], row["targets"], row["rows"], row["experts"], label, row["kernel"])] = row["seconds"]
            hashes.setdefault((row["workload"], row["experts"]), set()).add(row.get("predictions_sha256"))
    rows = []
    for workload, targets, steps, k in dict.fromkeys(key[:4] for key in cells):
        size = f"{targets:,} target{'s' if targets > 1 else ''} × {steps:,} rows"
        rows.append([size, str(k)] + [num(cells.get((workload, targets, steps, k, label, kernel)), 3)
                                      for label, kernel in columns])
    compiled = {(label, c["kernel"]): c for label, tree in data["trees"].items() for c in tree.get("compile", [])}
    for key, label in (("compile_seconds", "compile from an empty cache: s"),
                       ("compile_cpu_seconds", "compile from an empty cache: CPU s")):
        if any(key in c for c in compiled.values()):
            rows.append([label, ""] + [num(compiled.get(column, {}).get(key), 3) for column in columns])
    loads = [c["load_1min_before"] for c in compiled.values()]
    notes = [f"{_machine(data)}" + (f"; the compiles ran at a 1-minute load of {min(loads):.1f} to "
                                    f"{max(loads):.1f}." if loads else "."),
             "The paper mixture's AKF step (`make_params(3, K)`: RLS dynamics, the fixed-share gate, noise "
             "feedback), one thread, CPU seconds, the best of 3 warm calls, the trees in turn."
             + (" Every kernel's predictions are the same bits." if hashes and all(
                 len(h) == 1 and None not in h for h in hashes.values()) else "")]
    trees = ", ".join(f"{label} = {tree.get('commit') or 'a source tree'}" for label, tree in data["trees"].items())
    notes.append(f"Trees: {trees}.")
    command = data.get("command") or "python -m benchmarks.akf_kernels --json benchmarks/results/" + name
    if data.get("compile_command"):
        command = (command, data["compile_command"])
    if data.get("note"):
        notes.append(data["note"])
    tables = [Table(header=header, rows=rows, sources=(name,), notes=notes, command=command)]
    cold = [(label, tree["cold_start"]) for label, tree in data["trees"].items() if "cold_start" in tree]
    if cold:
        rows = [[label, num(c["cold"]["seconds"], 3), num(c["cold"]["cpu_seconds"], 3),
                 f"{c['cold']['load_1min_before']:.1f}", num(c["warm"]["seconds"], 3)] for label, c in cold]
        same = len({c["output_sha256"] for _, c in cold}) == 1 and all(c["same_output"] for _, c in cold)
        tables.append(Table(
            header=["tree", "cold start, s", "its CPU s", "1-minute load", "warm, s"], rows=rows, sources=(name,),
            command=command, title=f"`kalmix predict {cold[0][1]['file']}` from an empty compiled cache",
            notes=["CPU seconds: the command's and its compile process's, what a machine of its own would wait on "
                   "one core; the wall seconds grow with the load of a shared machine."
                   + (" Every tree wrote the same bytes." if same else "")]))
    return tables


def dask(results: Results) -> list:
    tables = []
    for name in sorted(n for n in results.names() if n.startswith("dask_scaling")):
        data = results(name)
        rows, differences = [], []
        for run in data["best"]:
            workers = run.get("workers")
            label = "one process" if workers is None else f"Dask, {workers} worker{'s' if workers > 1 else ''}"
            rows.append([label, f"{num(run['seconds'], 3)} ({ratio(run['ratio_to_single'], 2)})",
                         f"{run['rows_per_s']:,.0f}",
                         f"{num(run['cpu_seconds'], 3)} ({ratio(run['cpu_ratio_to_single'], 2)})",
                         num(run.get("cluster_seconds"), 3)])
            if workers is not None and run.get("max_difference") is not None:
                differences.append(run["max_difference"])
        tracks, count = data["tracks"], data["rows"]
        same = (f" The largest difference between a Dask run's predictions and the single process's: "
                f"{num(max(differences))}." if differences else "")
        tables.append(Table(
            header=["run", "wall s (speed-up)", "rows/s", "CPU s (ratio)", "cluster's work, s"],
            rows=rows, sources=(name,),
            title=f"{count:,} rows in {tracks:,} tracks ({count // tracks:,} rows each), {data['files']} files",
            command=(f"python -m benchmarks.dask_scaling --rows {count} --tracks {tracks} --files {data['files']} "
                     f"--anatomy --json benchmarks/results/{name}"),
            notes=[(f"On {data['cores']} shared cores; the best of the repeats, each a fresh `kalmix` process "
                    "(interpreter, cluster start and compiled-engine load included); the cluster's work is its time "
                    "after the cluster's start and the first chunk." + same)]))
    return tables


def gpu(results: Results) -> list:
    tables = []
    for name in sorted(n for n in results.names() if n.startswith("gpu_")):
        data = results(name)
        device = data.get("device") or "an NVIDIA H100 (the file's name; its device field is empty)"
        rows = []
        for entry in data["rows"]:
            rows.append([f"{entry['targets']:,}",
                         f"{num(entry['gpu_expert_steps_per_s'], 3)} ({ratio(entry.get('speedup_kernel'), 1)})",
                         (f"{num(entry['gpu_expert_steps_per_s_with_transfers'], 3)} "
                         f"({ratio(entry.get('speedup_with_transfers'), 1)})"),
                         num(entry.get("cpu_expert_steps_per_s"), 3), num(entry.get("max_relative_difference"), 2)])
        threads = {e.get("cpu_threads") for e in data["rows"]} - {None}
        bank = data.get("bank", "?")
        engine = data.get("engine", "fused")
        notes = [(f"Expert-steps per second (targets × rows × experts / s). Measured on a lent GPU: {device}, "
                  "against the compiled CPU engine on the same machine's "
                 f"{', '.join(map(str, sorted(threads))) or '?'} cores, in the same run; random walks, "
                 f"{data['rows'][0]['steps']} rows per target, fp64. State: "
                 f"{num(data.get('state_bytes_per_target'), 3)} "
                 "bytes per target. The last column: the largest relative difference between the GPU's and the "
                 "CPU's forecasts.")]
        if "compile_gpu_s" in data:
            notes.append(f"Compiling the kernels took {num(data['compile_gpu_s'], 3)} s for the GPU and "
                         f"{num(data['compile_cpu_s'], 3)} s for the CPU in that run.")
        flag = "default" if "default" in name else "kinematic"
        tables.append(Table(
            header=["targets", "GPU kernels (× CPU)", "GPU with transfers (× CPU)", "CPU engine",
                    "max rel. diff."], rows=rows, sources=(name,),
            title=f"{bank}, {engine} engine, on a lent H100", notes=notes,
            command=f"python -m benchmarks.gpu --bank {flag} --json benchmarks/results/{name}"))
    return tables


#: Marker name -> the function that builds its tables.
SECTIONS = {
    "headline": headline,
    "evaluate": one_step,
    "lead": lead,
    "intervals": intervals,
    "lead-weights": lead_weights,
    "warm-start": warm_start,
    "lead-rate": lead_rate,
    "ablation": _ablations("ablation", protocol=True),
    "ablation-more": _ablations("ablation-more", protocol=False),
    "ablation-hawkeye": _ablations("ablation-hawkeye", protocol=False),
    "best-experts": best_experts,
    "clip-variants": clip_variants,
    "hawkeye-bounds": hawkeye_bounds,
    "irregular": irregular,
    "model-zoo": model_zoo,
    "model-zoo-lead": zoo_lead,
    "speed": speed,
    "akf-kernels": akf_kernels,
    "dask": dask,
    "gpu": gpu,
}


def render(name: str, results: Results | None = None) -> str:
    """The markdown of marker ``name``'s tables."""
    if name not in SECTIONS:
        raise ValueError(f"unknown results table {name!r}; expected one of {', '.join(SECTIONS)}")
    results = Results() if results is None else results
    return "\n\n".join(table.markdown() for table in SECTIONS[name](results))


def fill(markdown: str, results: Results | None = None) -> str:
    """``markdown`` with every marker line replaced by its tables."""
    results = Results() if results is None else results
    def replace(match):   # indented like the marker, so that a marker can sit in an admonition or a tab
        lines = render(match["name"], results).split("\n")
        return "\n".join(match["indent"] + line if line else line for line in lines)

    return MARKER.sub(replace, markdown)


def page(results: Results | None = None) -> str:
    """docs/results.md with its tables filled in."""
    return fill(PAGE.read_text(), results)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--headline", action="store_true", help="the one-step + lead table only")
    group.add_argument("--table", metavar="NAME", help="one marker's tables")
    group.add_argument("--list", action="store_true", help="the marker names")
    parser.add_argument("--horizon", type=int, default=10, help="rows ahead in --headline (default 10)")
    args = parser.parse_args(argv)
    try:
        if args.list:
            text = "\n".join(SECTIONS)
        elif args.headline:
            text = "\n\n".join(t.markdown() for t in headline(Results(), args.horizon))
        elif args.table:
            text = render(args.table)
        else:
            text = page()
    except (FileNotFoundError, ValueError, KeyError) as error:
        sys.exit(f"results_tables: {error}")
    try:
        print(text)
    except BrokenPipeError:   # | head
        sys.stderr.close()


if __name__ == "__main__":
    main()
