"""The learned leg classifier: its JAX evaluation against scikit-learn's own predictions, the
model files, the shipped model, and the detector with it."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.perception import leg_classifier, leg_features, legs

sklearn_ensemble = pytest.importorskip("sklearn.ensemble")
F = leg_features.NUM_FEATURES
_proba = jax.jit(leg_classifier.predict_proba)


def _data(rng, n=3000):
    """Features with a nonlinear class boundary, some columns of few distinct values (ties at
    the split thresholds)."""
    X = rng.normal(size=(n, F))
    X[:, 0] = rng.integers(1, 30, n)                       # point counts: many ties
    X[:, 5] = np.round(X[:, 5], 1)
    y = ((X[:, 1] ** 2 + X[:, 2] > 0.5) ^ (X[:, 0] < 6)).astype(int)
    return X, y


@pytest.fixture(scope="module")
def forest():
    rng = np.random.default_rng(0)
    X, y = _data(rng)
    model, fitted = leg_classifier.fit(X, y, n_estimators=12, max_depth=8, seed=1)
    return model, fitted


def test_jax_probabilities_equal_the_forest_predictions(forest):
    model, fitted = forest
    X, _ = _data(np.random.default_rng(1), 2000)
    # Values exactly at split thresholds: the float32-floored thresholds must decide as
    # scikit-learn does (``x <= t`` with float32 x and float64 t).
    t = fitted.estimators_[0].tree_
    internal = np.flatnonzero(t.children_left >= 0)[:20]
    X[: len(internal), t.feature[internal]] = t.threshold[internal].astype(np.float32)
    X[20:40, t.feature[internal]] = np.nextafter(t.threshold[internal].astype(np.float32),
                                                 np.float32(np.inf))
    expected = fitted.predict_proba(X)[:, 1]
    got = np.asarray(_proba(model, jnp.asarray(X)))
    # Same leaves in every tree; the mean of T float32 leaf values vs float64.
    np.testing.assert_allclose(got, expected, atol=1e-6)
    for k, est in enumerate(fitted.estimators_[:3]):
        one = model._replace(**{f: getattr(model, f)[k:k + 1] for f in
                                ("feature", "threshold", "left", "right", "value")})
        leaf_value = est.predict_proba(X)[:, 1]
        np.testing.assert_allclose(np.asarray(_proba(one, jnp.asarray(X))), leaf_value,
                                   atol=1e-7)


def test_batch_axes_and_vmap(forest):
    model, fitted = forest
    X, _ = _data(np.random.default_rng(2), 60)
    X3 = jnp.asarray(X.reshape(3, 20, F))
    flat = np.asarray(_proba(model, jnp.asarray(X)))
    np.testing.assert_array_equal(np.asarray(_proba(model, X3)).reshape(-1), flat)
    np.testing.assert_array_equal(
        np.asarray(jax.vmap(lambda x: leg_classifier.predict_proba(model, x))(X3)).reshape(-1),
        flat)
    with pytest.raises(ValueError, match="14 features"):
        leg_classifier.predict_proba(model, jnp.zeros((3, 5)))


def test_save_and_load_round_trip_and_bad_files(forest, tmp_path):
    model, _ = forest
    path = leg_classifier.save(tmp_path / "m.npz", model, bags="a.bag b.bag", scans=12)
    back = leg_classifier.load(path)
    for a, b in zip(model, back):
        np.testing.assert_array_equal(a, b)
    assert leg_classifier.metadata(path) == {"bags": "a.bag b.bag", "scans": 12}
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(ValueError, match="not a jaxtrack leg classifier"):
        leg_classifier.load(tmp_path / "other.npz")
    with pytest.raises(FileNotFoundError):
        leg_classifier.load(tmp_path / "missing.npz")
    arrays = dict(np.load(path))
    arrays["feature_names"] = np.asarray(["a", "b"])
    np.savez(tmp_path / "renamed.npz", **arrays)
    with pytest.raises(ValueError, match="trained on features"):
        leg_classifier.load(tmp_path / "renamed.npz")


def test_fit_refuses_bad_training_sets():
    X = np.zeros((10, F))
    with pytest.raises(ValueError, match="both labels"):
        leg_classifier.fit(X, np.zeros(10, int))
    with pytest.raises(ValueError, match=r"\[M, 14\]"):
        leg_classifier.fit(np.zeros((10, 3)), np.arange(10) % 2)
    X[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        leg_classifier.fit(X, np.arange(10) % 2)
    fitted = sklearn_ensemble.RandomForestClassifier(2).fit(np.zeros((4, 3)), [0, 1, 0, 1])
    with pytest.raises(ValueError, match="fitted on 3 features"):
        leg_classifier.from_sklearn(fitted)


def test_the_shipped_model_ranks_legs_above_walls_and_decides_at_its_threshold():
    from sims.following import lidar

    model = leg_classifier.default()
    assert model.feature.shape == model.threshold.shape and model.levels.shape[0] >= 1
    assert 0.0 < float(model.decision) < 1.0
    # At the training scanner's resolution (0.35 deg): two people's legs before a wall, with
    # 5 mm range noise. Simulated arcs are not the trousers the model was trained on, so only
    # the order of the scores is asserted here (the accuracy on real scans is measured in
    # benchmarks/leg_detector.py).
    angles = jnp.arange(-2.356, 2.35, 0.006136)
    centres = jnp.asarray([[1.5, 0.3], [1.5, 0.6], [2.5, -1.0], [2.5, -1.3]])
    circles = lidar.Circles(centres, jnp.full(4, 0.055), jnp.ones(4, bool))
    walls = lidar.Walls(jnp.asarray([[[4.0, -3.0], [4.0, 3.0]]]), jnp.ones(1, bool))
    ranges = lidar.cast(jnp.zeros(3), angles, circles, walls, 11.0)
    noise = 0.005 * jax.random.normal(jax.random.PRNGKey(0), ranges.shape)
    ranges = jnp.where(ranges < 11.0, ranges + noise, jnp.inf)     # no return: inf
    detect = jax.jit(functools.partial(legs.detect, max_segments=32, max_people=4))
    det = detect(ranges, angles, legs.LegParams(max_range=11.0), classifier=model)
    mask = np.asarray(det.segments.mask)
    mean = np.asarray(det.features.mean)[mask]
    scores = np.asarray(det.scores)[mask]
    is_leg = np.linalg.norm(mean[:, None] - np.asarray(centres)[None], axis=-1).min(1) < 0.1
    assert is_leg.sum() == 4 and (~is_leg).sum() >= 4
    assert scores[is_leg].min() > scores[~is_leg].max()
    np.testing.assert_array_equal(np.asarray(det.legs_mask)[mask],
                                  scores >= float(model.decision))
