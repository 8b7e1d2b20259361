"""The paper's claims and ours, as tests on the paper's scenario (1000 frames, seed 0).

The claims are made for the default scenario, so they are tested on it (one seed; the
reproduction report gives five). The short ``quick_scenario`` (312 frames, the same speed
range reached 3.5x faster) is used only to document where our own claim stops holding.

Our own claims (the default configuration must meet them) are asserted as stated. The
paper's claims that do not hold with a faithful implementation are written so that the
test documents the relation we actually measure (and fails if it changes), never a
loosened version of the claim; docs/paper.md (section "The paper's claims") explains why they do not hold.
Each ratio is also held near the value it measures on seed 0 (``NEAR``), so that a drift fails here long
before a claim or a relation breaks.
``kalmix reproduce table1`` prints the same verdicts ("reproduced" / "not reproduced", "holds" / "does not
hold") as a report: a claim of ours that stops holding fails here, not in that command's output.
"""

import pytest

from kalmix.experiments.table1 import aggregate, quick_scenario, run_seed

pytest.importorskip("filterpy")

AXES = ("X", "Y")

#: Bounds near what seed 0 measures, per axis: the seed-0 ratio moved by two standard deviations of its spread
#: over seeds 0-4 (the five seeds of ``kalmix reproduce table1``; what another draw of the same scenario moves it
#: by), rounded outward to 3 decimals, and never looser than the claim or relation the test states. ``(low,
#: high)`` where the test bounds both sides. In the comments: seed 0's value, then the standard deviation.
NEAR = {
    # mixture RMS / peer RMS
    "mixture/imm_filterpy": {"X": 0.836, "Y": 0.844},     # 0.828 / 0.826, std 0.004 / 0.009
    "mixture/cv_kalman": {"X": 0.589, "Y": 0.650},        # 0.578 / 0.625, std 0.005 / 0.012
    "mixture/ca_kalman": {"X": 0.666, "Y": 0.722},        # 0.658 / 0.704, std 0.004 / 0.009
    "mixture/single_akf": {"X": 0.885, "Y": 0.902},       # 0.876 / 0.887, std 0.005 / 0.007
    "mixture/no_prediction": {"X": 0.148, "Y": 0.155},    # 0.141 / 0.150, std 0.003 / 0.002
    "mixture/best_expert": {"X": 0.963, "Y": 0.933},      # 0.917 / 0.898, std 0.023 / 0.017 (claim: 1.05)
    "default/best_peer": {"X": 0.915, "Y": 0.909},        # 0.886 / 0.882, std 0.014 / 0.014 (claim: 0.97)
    "default/its_best_expert": {"X": 1.025, "Y": 0.937},  # 0.977 / 0.913, std 0.024 / 0.012 (claim: 1.05)
    # on the quick scenario: mixture RMS / peer RMS (the IMM's Y: the mixture is worse, > 1)
    "quick/imm_filterpy": {"X": 1.0, "Y": (1.0, 1.097)},  # 0.995 / 1.036, std 0.017 / 0.030
    "quick/cv_kalman": {"X": 0.800, "Y": 0.861},          # 0.760 / 0.829, std 0.019 / 0.016
    "quick/ca_kalman": {"X": 0.841, "Y": 0.920},          # 0.795 / 0.877, std 0.022 / 0.021
    "quick/single_akf": {"X": 0.778, "Y": 0.789},         # 0.732 / 0.747, std 0.023 / 0.021
    "quick/no_prediction": {"X": 0.206, "Y": 0.218},      # 0.195 / 0.208, std 0.006 / 0.005
    # the paper's ordering: softmax mixture / single AKF, single AKF / random mixture (relation: < 1)
    "softmax/single std": {"X": 0.895, "Y": 0.919},       # 0.880 / 0.898, std 0.007 / 0.010
    "softmax/single max": {"X": 0.781, "Y": 1.0},         # 0.672 / 0.877, std 0.054 / 0.090
    "single/random std": {"X": 0.850, "Y": 0.868},        # 0.801 / 0.818, std 0.024 / 0.025
    "single/random max": {"X": 1.0, "Y": 0.848},          # 0.885 / 0.521, std 0.125 / 0.163
    # RMS ratios the paper puts at >= 3 (relation: between 1 and 3)
    "single/softmax": {"X": (1.130, 1.154), "Y": (1.108, 1.146)},   # 1.142 / 1.127, std 0.006 / 0.009
    "random/single": {"X": (1.139, 1.213), "Y": (1.104, 1.172)},    # 1.176 / 1.138, std 0.018 / 0.017
    # the paper's gate: RMS / the single AKF's (relation: > 1), |RMS / the random gate's - 1| (relation: < 0.05)
    "paper_gate/single": {"X": (1.114, None), "Y": (1.094, None)},  # 1.155 / 1.116, std 0.021 / 0.011
    "paper_gate/random": {"X": 0.033, "Y": 0.042},                  # -0.018 / -0.019, std 0.007 / 0.011
    # literal mode: single AKF / softmax mixture (relation: within 10 %), literal / rls single AKF (>= 1.4),
    # literal single AKF / no prediction in Y (> 1)
    "literal/softmax": {"X": (0.994, 1.043), "Y": (0.965, 1.1)},    # 1.018 / 1.033, std 0.012 / 0.034
    "literal/rls": {"X": (2.572, None), "Y": (6.518, None)},        # 2.673 / 6.952, std 0.050 / 0.217
    "literal/no_prediction": {"Y": (1.095, None)},                  # 1.173, std 0.039
}

#: The fraction of frames whose largest weight is over 0.8 (relation: < 0.5): 0.006 on seed 0, std 0.013.
NEAR_ONE_HOT = 0.033


def _near(ratio, name, axis):
    """``ratio`` within ``NEAR[name][axis]``: below the bound, or inside ``(low, high)`` (None: no bound)."""
    bound = NEAR[name][axis]
    low, high = bound if isinstance(bound, tuple) else (None, bound)
    assert low is None or ratio > low, f"{name} {axis}: {ratio:.4f}, not above {low}"
    assert high is None or ratio < high, f"{name} {axis}: {ratio:.4f}, not below {high}"


@pytest.fixture(scope="module")
def table():
    return aggregate([run_seed(0, modes=("rls", "literal"))], ("rls", "literal"))


@pytest.fixture(scope="module")
def quick_rows():
    return aggregate([run_seed(0, scenario=quick_scenario(), modes=("rls",))], ("rls",))["rows"]


@pytest.fixture(scope="module")
def rows(table):
    return table["rows"]


# -- our claims (default configuration: rls experts, fixed-share gate, K = 40) ------------------------


@pytest.mark.parametrize("peer", ["imm_filterpy", "cv_kalman", "ca_kalman", "single_akf", "no_prediction"])
@pytest.mark.parametrize("axis", AXES)
def test_ours_mixture_no_worse_than_every_peer(rows, peer, axis):
    assert rows["mixture_softmax"][axis]["rms"] <= rows[peer][axis]["rms"]
    _near(rows["mixture_softmax"][axis]["rms"] / rows[peer][axis]["rms"], f"mixture/{peer}", axis)


@pytest.mark.parametrize("axis", AXES)
def test_ours_mixture_within_5_percent_of_best_expert_in_hindsight(rows, axis):
    assert rows["mixture_softmax"][axis]["rms"] <= 1.05 * rows["best_expert_hindsight"][axis]["rms"]
    _near(rows["mixture_softmax"][axis]["rms"] / rows["best_expert_hindsight"][axis]["rms"], "mixture/best_expert",
          axis)


@pytest.mark.parametrize("axis", AXES)
def test_ours_default_bank_beats_the_best_peer_by_3_percent(rows, axis):
    """The bank ``kalmix predict`` uses by default, on the paper's scenario (issue target: <= 0.97 x the
    best tuned peer; every peer here was tuned on a separate seed)."""
    best_peer = min(rows[peer][axis]["rms"] for peer in ("imm_filterpy", "cv_kalman", "ca_kalman", "single_akf"))
    assert rows["default_bank"][axis]["rms"] <= 0.97 * best_peer
    _near(rows["default_bank"][axis]["rms"] / best_peer, "default/best_peer", axis)


@pytest.mark.parametrize("axis", AXES)
def test_ours_default_bank_within_5_percent_of_its_best_expert(rows, axis):
    assert rows["default_bank"][axis]["rms"] <= 1.05 * rows["default_best_expert"][axis]["rms"]
    _near(rows["default_bank"][axis]["rms"] / rows["default_best_expert"][axis]["rms"], "default/its_best_expert", axis)


def test_ours_claims_summary(table):
    verdicts = {claim["name"]: claim["holds"] for claim in table["claims"] if claim["source"] == "ours"}
    assert verdicts == {"mixture_beats_peers": True, "within_5pct_of_best_expert": True,
                        "default_beats_peers_by_3pct": True, "default_within_5pct_of_best_expert": True}
    assert {claim["verdict"] for claim in table["claims"] if claim["source"] == "ours"} == {"holds"}


def test_ours_not_on_the_compressed_quick_scenario(quick_rows):
    """Where our claim stops holding: when the acceleration phase is squeezed from 28 s into
    8 s, the tuned filterpy IMM (CV+CA) predicts v (Y) slightly better than the mixture
    (1.48 vs 1.54 px on seed 0); the mixture still wins on X and beats the other peers."""
    assert quick_rows["imm_filterpy"]["Y"]["rms"] < quick_rows["mixture_softmax"]["Y"]["rms"]
    assert quick_rows["mixture_softmax"]["X"]["rms"] <= quick_rows["imm_filterpy"]["X"]["rms"]
    for peer in ("imm_filterpy", "cv_kalman", "ca_kalman", "single_akf", "no_prediction"):
        for axis in AXES:
            if peer != "imm_filterpy":
                assert quick_rows["mixture_softmax"][axis]["rms"] <= quick_rows[peer][axis]["rms"]
            _near(quick_rows["mixture_softmax"][axis]["rms"] / quick_rows[peer][axis]["rms"], f"quick/{peer}", axis)


# -- the paper's claims (rls experts) -----------------------------------------------------------------


@pytest.mark.parametrize("axis", AXES)
@pytest.mark.parametrize("stat", ["std", "max"])
def test_paper_ordering_softmax_below_single(rows, axis, stat):
    """Reproduced: the softmax mixture is below the single AKF on std and max, X and Y."""
    assert rows["mixture_softmax"][axis][stat] < rows["single_akf"][axis][stat]
    _near(rows["mixture_softmax"][axis][stat] / rows["single_akf"][axis][stat], f"softmax/single {stat}", axis)


@pytest.mark.parametrize("axis", AXES)
@pytest.mark.parametrize("stat", ["std", "max"])
def test_paper_ordering_single_below_random(rows, axis, stat):
    """Reproduced (on every seed of the report)."""
    assert rows["single_akf"][axis][stat] < rows["mixture_random"][axis][stat]
    _near(rows["single_akf"][axis][stat] / rows["mixture_random"][axis][stat], f"single/random {stat}", axis)


@pytest.mark.parametrize("axis", AXES)
def test_paper_single_over_softmax_ratio_not_reproduced(rows, axis):
    """Paper: single-AKF RMS >= 3x the mixture's. Measured: the mixture is better, but by
    about 1.14x, because our single AKF (an RLS-learned model) is already a good predictor."""
    ratio = rows["single_akf"][axis]["rms"] / rows["mixture_softmax"][axis]["rms"]
    assert 1.0 < ratio < 3.0
    _near(ratio, "single/softmax", axis)


@pytest.mark.parametrize("axis", AXES)
def test_paper_random_over_single_ratio_not_reproduced(rows, axis):
    """Paper: random-mixture RMS >= 3x the single AKF's. Measured: worse, but < 3x: every
    expert of the bank is a reasonable predictor, so a random convex mix of them is too."""
    ratio = rows["mixture_random"][axis]["rms"] / rows["single_akf"][axis]["rms"]
    assert 1.0 < ratio < 3.0
    _near(ratio, "random/single", axis)


def test_paper_one_hot_weights_not_reproduced(table):
    """Paper (Figure 2a): often a single expert carries the prediction. Measured: many
    experts of the bank are near-equivalent, so the weight is shared; the largest weight
    exceeds 0.8 on 0.6 % of the frames (seed 0; 0.2 to 3.4 % over seeds 0-4)."""
    assert table["max_weight_above_0.8_fraction"] < NEAR_ONE_HOT


@pytest.fixture(scope="module")
def paper_gate_rows():
    from kalmix.baselines import softmax_mixture
    from kalmix.experiments.table1 import _summary, scenario_measurements

    _, z = scenario_measurements(0)
    return _summary(softmax_mixture(40, seed=0, gating="paper").run(z, diagnostics=False).predictions, z)


@pytest.mark.parametrize("axis", AXES)
def test_paper_gate_is_not_better_than_the_single_akf(rows, paper_gate_rows, axis):
    """With the paper's own gate (eq. 8-10, NOTES.md starting values) on the same bank, claim 1
    fails: the gate learns too slowly (eta_k ~ 2e-3), its weights stay near uniform, and the
    mixture is worse than the single AKF, within 5 % of the random gate."""
    paper = paper_gate_rows
    assert paper[axis]["rms"] > rows["single_akf"][axis]["rms"]
    assert abs(paper[axis]["rms"] / rows["mixture_random"][axis]["rms"] - 1.0) < 0.05
    _near(paper[axis]["rms"] / rows["single_akf"][axis]["rms"], "paper_gate/single", axis)
    _near(abs(paper[axis]["rms"] / rows["mixture_random"][axis]["rms"] - 1.0), "paper_gate/random", axis)


def test_paper_verdicts_as_reported(table):
    """What ``kalmix reproduce table1`` reports for the paper's claims (rls experts, fixed-share gate): the
    ordering reproduced, the three others not, each with the cause docs/paper.md explains."""
    claims = {claim["name"]: claim for claim in table["claims"] if claim["source"] == "paper"}
    assert {name: claim["verdict"] for name, claim in claims.items()} == {
        "ordering": "reproduced", "single_over_softmax_3x": "not reproduced",
        "random_over_single_3x": "not reproduced", "one_hot": "not reproduced"}
    assert "fixed-share gate" in claims["ordering"]["why"]
    assert "our single AKF is already within" in claims["single_over_softmax_3x"]["why"]
    assert "a random mix of them does too" in claims["random_over_single_3x"]["why"]
    assert "the fixed-share gate spreads it" in claims["one_hot"]["why"]


def test_literal_mode_verdicts_as_reported(table):
    """In literal mode (eq. 6/7) none of the paper's claims is reproduced; the cause named is eq. 6."""
    claims = [claim for claim in table["claims_literal"] if claim["source"] == "paper"]
    assert len(claims) == 4 and {claim["verdict"] for claim in claims} == {"not reproduced"}
    for claim in claims:
        if claim["name"] != "random_over_single_3x":
            assert "eq. 6 gives all experts the same dynamics" in claim["why"]


# -- the paper's AKF taken literally (eq. 6/7) ---------------------------------------------------------


@pytest.mark.parametrize("axis", AXES)
def test_literal_mode_mixture_cannot_beat_its_single_akf(table, axis):
    """With eq. (6) as printed every expert has the same system matrix, so the bank has
    little diversity and the mixture does not improve on one literal AKF (within 10 %; 1.02 / 1.03 on seed 0)."""
    literal = table["rows_literal"]
    ratio = literal["single_akf"][axis]["rms"] / literal["mixture_softmax"][axis]["rms"]
    assert 0.9 < ratio < 1.1
    _near(ratio, "literal/softmax", axis)


@pytest.mark.parametrize("axis", AXES)
def test_literal_mode_is_much_weaker_than_rls(table, axis):
    """The literal AKF is >= 1.4x worse than the RLS one (it predicts a rescaled copy of the
    last measurement; 2.7x / 7.0x on seed 0); in Y it is worse than repeating the last measurement."""
    assert table["rows_literal"]["single_akf"][axis]["rms"] >= 1.4 * table["rows"]["single_akf"][axis]["rms"]
    assert table["rows_literal"]["single_akf"]["Y"]["rms"] > table["rows"]["no_prediction"]["Y"]["rms"]
    literal, rls = table["rows_literal"]["single_akf"], table["rows"]["single_akf"]
    _near(literal[axis]["rms"] / rls[axis]["rms"], "literal/rls", axis)
    _near(table["rows_literal"]["single_akf"]["Y"]["rms"] / table["rows"]["no_prediction"]["Y"]["rms"],
          "literal/no_prediction", "Y")
