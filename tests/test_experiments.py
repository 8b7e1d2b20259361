"""kalmix.experiments (Table 1, Figure 2, ablations), kalmix.plots and `kalmix reproduce`, on tiny scenarios."""

import json

import numpy as np
import pytest

from kalmix.experiments import ablations as ablation_module
from kalmix.experiments import table1 as table1_module
from kalmix.experiments.figure2 import figure2
from kalmix.scenarios import PaperScenario

TINY = PaperScenario(curve_duration_s=3.0, deceleration_duration_s=0.4, wander_duration_s=1.6)  # 125 frames
AXIS_KEYS = {"mean_abs", "std", "max", "rms"}


@pytest.fixture(scope="module")
def tiny_table():
    pytest.importorskip("filterpy")
    return table1_module.table1(seeds=(0, 1), modes=("rls", "literal"), n_experts=5, scenario=TINY)


def test_table1_json_shape(tiny_table):
    result = json.loads(json.dumps(tiny_table))  # serialisable as is
    assert set(result["paper"]) == {"single_akf", "mixture_softmax", "mixture_random"}
    for key in ("rows", "rows_literal"):
        assert list(result[key]) == list(table1_module.ROWS)
        for row in result[key].values():
            assert set(row) == {"X", "Y"}
            assert set(row["X"]) == AXIS_KEYS and set(row["Y"]) == AXIS_KEYS
    assert result["seeds"] == [0, 1]
    assert 0.0 <= result["max_weight_above_0.8_fraction"] <= 1.0
    assert {claim["name"] for claim in result["claims"]} == {
        "ordering", "single_over_softmax_3x", "random_over_single_3x", "one_hot", "mixture_beats_peers",
        "within_5pct_of_best_expert", "default_beats_peers_by_3pct", "default_within_5pct_of_best_expert"}


def test_table1_numbers_are_means_over_seeds(tiny_table):
    per_seed = tiny_table["per_seed"]
    for row in ("single_akf", "mixture_softmax"):
        values = [item["modes"]["rls"]["rows"][row]["Y"]["max"] for item in per_seed]
        assert tiny_table["rows"][row]["Y"]["max"] == pytest.approx(np.mean(values))
        assert tiny_table["rows_spread"][row]["Y"]["max"] == pytest.approx(np.std(values))
    # the peers do not depend on the AKF mode
    assert tiny_table["rows"]["imm_filterpy"] == tiny_table["rows_literal"]["imm_filterpy"]


def test_table1_stats_are_consistent(tiny_table):
    item = tiny_table["per_seed"][0]
    for row in list(item["modes"]["rls"]["rows"].values()) + list(item["peers"].values()):
        for axis in ("X", "Y"):
            stats = row[axis]
            assert stats["rms"] == pytest.approx(np.hypot(stats["mean_abs"], stats["std"]))
            assert stats["mean_abs"] <= stats["rms"] <= stats["max"]


def test_paper_numbers():
    paper = table1_module.PAPER_TABLE1
    assert paper["single_akf"]["X"]["max"] == 178.481
    assert paper["mixture_softmax"]["Y"]["std"] == 2.632
    assert paper["mixture_random"]["Y"]["mean_abs"] == 23.35
    assert paper["single_akf"]["X"]["rms"] == pytest.approx(np.hypot(0.5162, 9.431))


def _rows(single, softmax, random, best=None, peer=None):
    def axis(rms, std, maximum):
        return {"mean_abs": 0.0, "std": std, "max": maximum, "rms": rms}

    rows = {"single_akf": {a: axis(*single) for a in "XY"}, "mixture_softmax": {a: axis(*softmax) for a in "XY"},
            "mixture_random": {a: axis(*random) for a in "XY"}}
    if best is not None:
        rows["best_expert_hindsight"] = {a: axis(*best) for a in "XY"}
    if peer is not None:
        rows["imm_filterpy"] = {a: axis(*peer) for a in "XY"}
    return rows


def test_check_claims_true_and_false():
    paper_like = table1_module.check_claims(_rows((9, 9, 170), (2.7, 2.7, 20), (70, 70, 190), best=(2.7, 2.7, 20),
                                                  peer=(3, 3, 30)), one_hot_fraction=0.9)
    assert all(claim["holds"] for claim in paper_like)
    ours_like = {c["name"]: c["holds"] for c in table1_module.check_claims(
        _rows((1.2, 0.8, 7), (1.0, 0.7, 5), (1.4, 1.0, 8), best=(0.9, 0.6, 5), peer=(0.99, 0.6, 9)), 0.01)}
    assert ours_like == {"ordering": True, "single_over_softmax_3x": False, "random_over_single_3x": False,
                         "one_hot": False, "mixture_beats_peers": False, "within_5pct_of_best_expert": False}


def test_figure2_data_and_png(tmp_path):
    pytest.importorskip("matplotlib")
    from kalmix import plots

    data = figure2(0, n_experts=6, scenario=TINY)
    t_count = len(data["times"])
    assert data["weights"].shape == (t_count, 6)
    np.testing.assert_allclose(data["weights"].sum(axis=1), 1.0)
    assert data["eta"].shape == (t_count,)
    assert data["process_noise"].shape == (t_count, 6)
    assert data["abs_error"].shape == (t_count, 3) and np.isnan(data["abs_error"][0]).all()
    assert [span[0] for span in data["phase_spans"]] == ["accelerating curve", "deceleration", "small random moves"]
    out = plots.figure2(data, tmp_path / "figure2.png")
    with open(out, "rb") as handle:
        assert handle.read(8) == b"\x89PNG\r\n\x1a\n"


def test_ablations_structure():
    result = ablation_module.ablations(seeds=(0,), groups=("akf_mode", "noise"), scenario=TINY)
    names = [row["name"] for row in result["rows"]]
    assert names[0] == "rls (default)" and "literal" in names
    assert {row["group"] for row in result["rows"]} == {"akf_mode", "noise"}
    for row in result["rows"]:
        assert row["mean"]["rms"] > 0 and row["mean"]["ratio_to_best_expert"] > 0
    # every group the issue asks for is present
    groups = {group for group, *_ in ablation_module.ABLATIONS}
    assert {"akf_mode", "gate", "gating_input", "noise", "n_experts"} <= groups
    assert sorted({k for group, _, k, _ in ablation_module.ABLATIONS if group == "n_experts"}) == [1, 5, 10, 40, 80]


def test_cli_reproduce_table1_json(tmp_path, monkeypatch):
    pytest.importorskip("filterpy")
    click_testing = pytest.importorskip("click.testing")
    from kalmix.cli import build

    monkeypatch.setattr(table1_module, "quick_scenario", lambda seed=0: TINY)
    path = tmp_path / "table1.json"
    result = click_testing.CliRunner().invoke(
        build(), ["reproduce", "table1", "--seeds", "1", "--mode", "rls", "--experts", "4", "--quick",
                  "--json", str(path)])
    assert result.exit_code == 0, result.output
    assert "paper (2001)" in result.output and "Claims" in result.output
    assert ("PASS" in result.output) or ("FAIL" in result.output)
    data = json.loads(path.read_text())
    assert set(table1_module.ROWS) == set(data["rows"]) and data["seeds"] == [0]
