"""Object API: persistence and validation at the boundary."""

import numpy as np
import pytest

from conftest import smooth_tracks
from kalmix import MixturePredictor, make_params


@pytest.mark.parametrize("options", [{}, {"gating": "paper"}, {"gating": "random"}, {"dynamics": "literal"}])
def test_save_and_resume_is_bit_for_bit(tmp_path, options):
    z = smooth_tracks(0, 150)[:, 0]
    z[40:45] = np.nan
    uninterrupted = MixturePredictor(12, seed=4, **options).run(z).predictions
    first = MixturePredictor(12, seed=4, **options)
    head = first.run(z[:77]).predictions
    first.save(tmp_path / "state.npz")
    resumed = MixturePredictor.load(tmp_path / "state.npz")
    tail = np.array([resumed.step(row) for row in z[77:]])
    np.testing.assert_array_equal(np.concatenate([head, tail]), uninterrupted)
    assert resumed.get_config() == first.get_config()


def test_batch_predictor_round_trips(tmp_path):
    z = smooth_tracks(1, 60, targets=5)
    predictor = MixturePredictor(4, seed=0)
    predictor.run(z[:30])
    predictor.save(tmp_path / "batch.npz")
    loaded = MixturePredictor.load(tmp_path / "batch.npz")
    np.testing.assert_array_equal(loaded.run(z[30:]).predictions, predictor.run(z[30:]).predictions)
    assert loaded.weights_.shape == (5, 4)


def test_loading_a_corrupt_foreign_or_mismatched_file_gives_a_clear_error(tmp_path):
    predictor = MixturePredictor(3)
    predictor.step([1.0, 2.0])
    good = tmp_path / "good.npz"
    predictor.save(good)
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(good.read_bytes()[:200])
    with pytest.raises(ValueError, match="not a kalmix predictor file"):
        MixturePredictor.load(corrupt)
    text = tmp_path / "text.npz"
    text.write_text("hello")
    with pytest.raises(ValueError, match="not a kalmix predictor file"):
        MixturePredictor.load(text)
    archive = dict(np.load(good))
    import json
    meta = json.loads(str(archive["meta"]))
    meta["format_version"] = 99
    np.savez(tmp_path / "future.npz", **{**archive, "meta": np.array(json.dumps(meta))})
    with pytest.raises(ValueError, match="expected format version 1, got 99"):
        MixturePredictor.load(tmp_path / "future.npz")
    archive["state/mean"] = archive["state/mean"][:, :2]
    np.savez(tmp_path / "shape.npz", **archive)
    with pytest.raises(ValueError, match="field 'mean' expected shape"):
        MixturePredictor.load(tmp_path / "shape.npz")
    with pytest.raises(FileNotFoundError):
        MixturePredictor.load(tmp_path / "absent.npz")


@pytest.mark.parametrize("kwargs,error,message", [
    ({"n_experts": 0}, ValueError, r"n_experts: expected an integer >= 1, got 0"),
    ({"n_experts": 2.5}, TypeError, r"n_experts: expected an integer >= 1, got float 2.5"),
    ({"temperature": 0.0}, ValueError, r"temperature: expected a finite number > 0, got 0.0"),
    ({"temperature": -1}, ValueError, r"temperature: expected a finite number > 0, got -1"),
    ({"process_noise_range": (-1.0, 1.0)}, ValueError,
     r"process_noise_range\[0\]: expected a finite number > 0, got -1.0"),
    ({"measurement_noise_range": (0.0, 1.0)}, ValueError,
     r"measurement_noise_range\[0\]: expected a finite number > 0, got 0.0"),
    ({"expert_scale": float("inf")}, ValueError, r"expert_scale: expected a finite number > 0, got inf"),
    ({"gating": "magic"}, ValueError, r"gating: expected one of 'fixed_share', 'paper', 'random', 'none', got 'magic'"),
    ({"dynamics": "kalman"}, ValueError, r"dynamics: expected one of 'rls', 'literal', 'fixed', got 'kalman'"),
    ({"gate_share": 1.5}, ValueError, r"gate_share: expected a finite number in \[0, 1.0\], got 1.5"),
    ({"temperature": "hot"}, TypeError, r"temperature: expected a finite number > 0, got str 'hot'"),
    ({"order": 0}, ValueError, r"order: expected an integer >= 1, got 0"),
])
def test_bad_parameters_are_named_with_expected_and_received(kwargs, error, message):
    with pytest.raises(error, match=message):
        MixturePredictor(**kwargs)
    with pytest.raises(error, match=message):
        make_params(3, **kwargs)


def test_bad_measurements_are_named_with_expected_and_received():
    predictor = MixturePredictor(3)
    predictor.step([1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match=r"z: expected shape \(3,\), got \(2,\)"):
        predictor.step([1.0, 2.0])
    with pytest.raises(ValueError, match=r"z: expected finite numbers or NaN \(missing\), got inf at index \(1,\)"):
        predictor.step([1.0, np.inf, 3.0])
    with pytest.raises(TypeError, match=r"z: expected numbers \(NaN for a missing measurement\)"):
        predictor.step(["a", "b", "c"])
    with pytest.raises(ValueError,
                       match=r"z: expected shape \(p,\) for one stream or \(N, p\) for N streams, got \(2, 2, 2\)"):
        MixturePredictor(3).step(np.zeros((2, 2, 2)))
    with pytest.raises(ValueError,
                       match=r"measurements: expected shape \(T, p\) or \(T, N, p\) with T >= 1, got \(5,\)"):
        MixturePredictor(3).run(np.zeros(5))
    with pytest.raises(ValueError, match=r"horizon: expected an integer in \[1, 10000\], got 0"):
        predictor.predict(0)
    with pytest.raises(RuntimeError, match="has seen no measurement yet"):
        MixturePredictor(3).predict()
    # NaN is a missing measurement, never an error
    assert np.isfinite(predictor.step([np.nan, np.nan, np.nan])).all()


def test_inputs_are_not_mutated():
    z = smooth_tracks(2, 40)[:, 0]
    z[5] = np.nan
    copy = z.copy()
    MixturePredictor(3).run(z)
    np.testing.assert_array_equal(z, copy)
