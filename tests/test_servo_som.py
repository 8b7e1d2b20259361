"""Tests for kalmix.servo.som: the supervised SOM learning the inverse image Jacobian."""

from __future__ import annotations

import numpy as np
import pytest

from kalmix.servo import (
    TARGET_REGION_HALF_WIDTHS,
    WORKSPACE_CENTRE,
    InverseJacobianSOM,
    SOMConfig,
    plot_learning_curve,
)

SMALL = dict(lattice_shape=(3, 3, 3), n_training_moves=600, evaluation_every=200, n_validation=100)


@pytest.fixture(scope="module")
def target_joints(arm) -> np.ndarray:
    """Joint configurations of 500 points of the region the target visits."""
    rng = np.random.default_rng(123)
    points = np.array(WORKSPACE_CENTRE) + rng.uniform(-1, 1, (500, 3)) * np.array(TARGET_REGION_HALF_WIDTHS)
    return arm.inverse(points)


@pytest.fixture(scope="module")
def trained(arm, camera):
    """The default configuration, trained once (about 1-3 s)."""
    som = InverseJacobianSOM(SOMConfig(), *arm.joint_box())
    history = som.fit(arm, camera)
    return som, history


# ---------------------------------------------------------------- configuration
@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"map_rate_initial": -0.1}, "map_rate_initial"),
        ({"map_rate_final": 0.0}, "map_rate_final"),
        ({"reference_rate_initial": -1.0}, "reference_rate_initial"),
        ({"reference_rate_final": float("nan")}, "reference_rate_final"),
        ({"neighbourhood_final": -0.5}, "neighbourhood_final"),
        ({"lattice_shape": (6, 0, 6)}, "lattice_shape"),
        ({"lattice_shape": (6, 6)}, "lattice_shape"),
        ({"babbling_step_rad": 0.0}, "babbling_step_rad"),
        ({"feature_noise_px": -1.0}, "feature_noise_px"),
        ({"n_training_moves": -5}, "n_training_moves"),
        ({"evaluation_every": 0}, "evaluation_every"),
        ({"seed": -1}, "seed"),
        ({"map_update": "hebbian"}, "map_update"),
        ({"lookup": "nearest"}, "lookup"),
    ],
)
def test_bad_config_values_raise_naming_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        SOMConfig(**kwargs)


def test_init_only_stores_and_bad_box_raises_at_use(arm, camera):
    som = InverseJacobianSOM(SOMConfig(**SMALL), [0.0, 0.0, 0.0], [1.0, -1.0, 1.0])
    with pytest.raises(ValueError, match="joint_low"):
        som.fit(arm, camera)


# ---------------------------------------------------------------- determinism
def test_same_seed_gives_same_maps(arm, camera):
    box = arm.joint_box()
    a = InverseJacobianSOM(SOMConfig(seed=7, **SMALL), *box)
    b = InverseJacobianSOM(SOMConfig(seed=7, **SMALL), *box)
    c = InverseJacobianSOM(SOMConfig(seed=8, **SMALL), *box)
    history_a, history_b = a.fit(arm, camera), b.fit(arm, camera)
    c.fit(arm, camera)
    np.testing.assert_array_equal(a.maps_, b.maps_)
    np.testing.assert_array_equal(a.reference_vectors_, b.reference_vectors_)
    np.testing.assert_array_equal(history_a.median_relative_error, history_b.median_relative_error)
    assert not np.array_equal(a.maps_, c.maps_)


def test_fit_leaves_global_random_state_alone(arm, camera):
    before = np.random.get_state()[1].copy()
    InverseJacobianSOM(SOMConfig(**SMALL), *arm.joint_box()).fit(arm, camera)
    np.testing.assert_array_equal(np.random.get_state()[1], before)


def test_fit_restarts_from_scratch(arm, camera):
    som = InverseJacobianSOM(SOMConfig(**SMALL), *arm.joint_box())
    som.fit(arm, camera)
    first = som.maps_
    som.fit(arm, camera)
    np.testing.assert_array_equal(som.maps_, first)


# ---------------------------------------------------------------- learning
def test_untrained_maps_are_zero(arm, camera, target_joints):
    som = InverseJacobianSOM(SOMConfig(), *arm.joint_box())
    np.testing.assert_array_equal(som.inverse_jacobian(target_joints[:5]), 0.0)
    error = som.relative_error(arm, camera, target_joints)
    assert error.median == pytest.approx(1.0)


def test_short_training_reduces_relative_error(arm, camera, target_joints):
    som = InverseJacobianSOM(SOMConfig(**SMALL), *arm.joint_box())
    history = som.fit(arm, camera)
    assert history.moves[0] == 0 and history.moves[-1] == SMALL["n_training_moves"]
    assert np.all(np.diff(history.moves) > 0)
    assert history.median_relative_error[0] == pytest.approx(1.0)
    assert history.median_relative_error[-1] < 0.5
    assert som.relative_error(arm, camera, target_joints).median < 0.5


def test_default_training_reaches_15_percent_on_target_region(trained, arm, camera, target_joints):
    som, history = trained
    error = som.relative_error(arm, camera, target_joints)
    assert error.median <= 0.15, f"median relative error {error.median:.3f}"
    assert error.mean <= 0.15, f"mean relative error {error.mean:.3f}"
    assert history.median_relative_error[-1] < 0.2 * history.median_relative_error[0]
    assert som.moves_seen_ == SOMConfig().n_training_moves


def test_paper_neighbourhood_rule_with_winner_lookup_also_learns(arm, camera, target_joints):
    """The literal rule of ref. [2] (own-error Widrow-Hoff, winner lookup) is the ablation row."""
    som = InverseJacobianSOM(SOMConfig(map_update="neighbourhood", lookup="winner"), *arm.joint_box())
    som.fit(arm, camera)
    assert som.relative_error(arm, camera, target_joints).median <= 0.15


def test_learn_moves_maps_toward_the_truth(arm, camera):
    som = InverseJacobianSOM(SOMConfig(**SMALL), *arm.joint_box())
    som.fit(arm, camera)
    q = arm.inverse([0.1, -0.05, 1.25])
    before = som.relative_error(arm, camera, q[None]).median
    rng = np.random.default_rng(11)
    for _ in range(60):
        q_start = q + 0.02 * rng.standard_normal(3)
        dq = 0.05 * rng.standard_normal(3)
        dv = arm.image_features(q_start + dq, camera) - arm.image_features(q_start, camera)
        som.learn(q_start, dq, dv, rate=0.3)
    after = som.relative_error(arm, camera, q[None]).median
    assert after < 0.5 * before, (before, after)
    assert som.moves_seen_ == SMALL["n_training_moves"] + 60


def test_learn_skips_missing_measurements_and_batches(arm, camera):
    som = InverseJacobianSOM(SOMConfig(**SMALL), *arm.joint_box())
    som.fit(arm, camera)
    maps = som.maps_
    q = arm.inverse([0.0, 0.0, 1.2])
    som.learn(q, [0.01, 0.0, 0.0], [np.nan, 1.0, 1.0])
    np.testing.assert_array_equal(som.maps_, maps)
    # a batch of pairs is learned in order, the same as one call per pair
    rng = np.random.default_rng(3)
    qs = q + 0.02 * rng.standard_normal((5, 3))
    dqs = 0.05 * rng.standard_normal((5, 3))
    dvs = arm.image_features(qs + dqs, camera) - arm.image_features(qs, camera)
    twin = InverseJacobianSOM.from_state_dict(som.state_dict())
    som.learn(qs, dqs, dvs)
    for args in zip(qs, dqs, dvs):
        twin.learn(*args)
    np.testing.assert_allclose(som.maps_, twin.maps_, rtol=0, atol=1e-15)


def test_learn_before_fit_works(arm, camera):
    som = InverseJacobianSOM(SOMConfig(**SMALL), *arm.joint_box())
    q = arm.inverse([0.0, 0.0, 1.2])
    dq = np.array([0.05, -0.03, 0.04])
    dv = arm.image_features(q + dq, camera) - arm.image_features(q, camera)
    som.learn(q, dq, dv, rate=1.0)
    np.testing.assert_allclose(som.inverse_jacobian(q + dq / 2) @ dv, dq, rtol=1e-3, atol=1e-6)


# ---------------------------------------------------------------- lookup
def test_inverse_jacobian_is_batched(trained, target_joints):
    som, _ = trained
    q = target_joints[:12].reshape(3, 4, 3)
    batched = som.inverse_jacobian(q)
    assert batched.shape == (3, 4, 3, 3)
    looped = np.array([[som.inverse_jacobian(q[i, j]) for j in range(4)] for i in range(3)])
    np.testing.assert_allclose(batched, looped, atol=1e-15)


def test_winner_lookup_returns_one_neurons_map(trained, target_joints):
    som, _ = trained
    state = som.state_dict()
    state["config"]["lookup"] = "winner"
    winner_som = InverseJacobianSOM.from_state_dict(state)
    maps = winner_som.maps_
    for q in target_joints[:10]:
        b = winner_som.inverse_jacobian(q)
        assert np.min(np.linalg.norm(maps - b, axis=(1, 2))) == 0.0


# ---------------------------------------------------------------- saving and plotting
def test_state_dict_round_trip(trained, target_joints):
    som, _ = trained
    state = som.state_dict()
    clone = InverseJacobianSOM.from_state_dict(state)
    np.testing.assert_array_equal(clone.inverse_jacobian(target_joints), som.inverse_jacobian(target_joints))
    assert clone.config == som.config
    state["whitened_maps"][:] = 0.0  # a copy: the original is untouched
    assert np.any(som.maps_ != 0)


def test_from_state_dict_checks_shapes(trained):
    som, _ = trained
    state = som.state_dict()
    state["whitened_maps"] = state["whitened_maps"][:-1]
    with pytest.raises(ValueError, match="whitened_maps"):
        InverseJacobianSOM.from_state_dict(state)


def test_plot_learning_curve_writes_png(trained, tmp_path):
    pytest.importorskip("matplotlib")
    _, history = trained
    path = tmp_path / "som_learning_curve.png"
    plot_learning_curve(history, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
