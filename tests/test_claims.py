"""The paper's claims and ours, as tests on the paper's scenario (1000 frames, seed 0).

The claims are made for the default scenario, so they are tested on it (one seed; the
reproduction report gives five). The short ``quick_scenario`` (312 frames, the same speed
range reached 3.5x faster) is used only to document where our own claim stops holding.

Our own claims (the default configuration must meet them) are asserted as stated. The
paper's claims that do not hold with a faithful implementation are written so that the
test documents the relation we actually measure (and fails if it changes), never a
loosened version of the claim; docs/paper.md (section "The paper's claims") explains why they do not hold.
``kalmix reproduce table1`` prints the same verdicts ("reproduced" / "not reproduced", "holds" / "does not
hold") as a report: a claim of ours that stops holding fails here, not in that command's output.
"""

import pytest

from kalmix.experiments.table1 import aggregate, quick_scenario, run_seed

pytest.importorskip("filterpy")

AXES = ("X", "Y")


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


@pytest.mark.parametrize("axis", AXES)
def test_ours_mixture_within_5_percent_of_best_expert_in_hindsight(rows, axis):
    assert rows["mixture_softmax"][axis]["rms"] <= 1.05 * rows["best_expert_hindsight"][axis]["rms"]


@pytest.mark.parametrize("axis", AXES)
def test_ours_default_bank_beats_the_best_peer_by_3_percent(rows, axis):
    """The bank ``kalmix predict`` uses by default, on the paper's scenario (issue target: <= 0.97 x the
    best tuned peer; every peer here was tuned on a separate seed)."""
    best_peer = min(rows[peer][axis]["rms"] for peer in ("imm_filterpy", "cv_kalman", "ca_kalman", "single_akf"))
    assert rows["default_bank"][axis]["rms"] <= 0.97 * best_peer


@pytest.mark.parametrize("axis", AXES)
def test_ours_default_bank_within_5_percent_of_its_best_expert(rows, axis):
    assert rows["default_bank"][axis]["rms"] <= 1.05 * rows["default_best_expert"][axis]["rms"]


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
    for peer in ("cv_kalman", "ca_kalman", "single_akf", "no_prediction"):
        for axis in AXES:
            assert quick_rows["mixture_softmax"][axis]["rms"] <= quick_rows[peer][axis]["rms"]


# -- the paper's claims (rls experts) -----------------------------------------------------------------


@pytest.mark.parametrize("axis", AXES)
@pytest.mark.parametrize("stat", ["std", "max"])
def test_paper_ordering_softmax_below_single(rows, axis, stat):
    """Reproduced: the softmax mixture is below the single AKF on std and max, X and Y."""
    assert rows["mixture_softmax"][axis][stat] < rows["single_akf"][axis][stat]


@pytest.mark.parametrize("axis", AXES)
@pytest.mark.parametrize("stat", ["std", "max"])
def test_paper_ordering_single_below_random(rows, axis, stat):
    """Reproduced (on every seed of the report)."""
    assert rows["single_akf"][axis][stat] < rows["mixture_random"][axis][stat]


@pytest.mark.parametrize("axis", AXES)
def test_paper_single_over_softmax_ratio_not_reproduced(rows, axis):
    """Paper: single-AKF RMS >= 3x the mixture's. Measured: the mixture is better, but by
    about 1.14x, because our single AKF (an RLS-learned model) is already a good predictor."""
    ratio = rows["single_akf"][axis]["rms"] / rows["mixture_softmax"][axis]["rms"]
    assert 1.0 < ratio < 3.0


@pytest.mark.parametrize("axis", AXES)
def test_paper_random_over_single_ratio_not_reproduced(rows, axis):
    """Paper: random-mixture RMS >= 3x the single AKF's. Measured: worse, but < 3x: every
    expert of the bank is a reasonable predictor, so a random convex mix of them is too."""
    ratio = rows["mixture_random"][axis]["rms"] / rows["single_akf"][axis]["rms"]
    assert 1.0 < ratio < 3.0


def test_paper_one_hot_weights_not_reproduced(table):
    """Paper (Figure 2a): often a single expert carries the prediction. Measured: many
    experts of the bank are near-equivalent, so the weight is shared; the largest weight
    exceeds 0.8 on only a few percent of the frames."""
    assert table["max_weight_above_0.8_fraction"] < 0.5


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
    little diversity and the mixture does not improve on one literal AKF (within 10 %)."""
    literal = table["rows_literal"]
    ratio = literal["single_akf"][axis]["rms"] / literal["mixture_softmax"][axis]["rms"]
    assert 0.9 < ratio < 1.1


@pytest.mark.parametrize("axis", AXES)
def test_literal_mode_is_much_weaker_than_rls(table, axis):
    """The literal AKF is >= 1.4x worse than the RLS one (it predicts a rescaled copy of the
    last measurement); in Y it is worse than repeating the last measurement."""
    assert table["rows_literal"]["single_akf"][axis]["rms"] >= 1.4 * table["rows"]["single_akf"][axis]["rms"]
    assert table["rows_literal"]["single_akf"]["Y"]["rms"] > table["rows"]["no_prediction"]["Y"]["rms"]
