"""Online colour classifier: learns to separate a track's colour from the frame's others."""

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack.tracking import appearance


def _hist(rng, centre, bins=8):
    h = np.exp(-0.5 * ((np.arange(bins) - centre) / 1.0) ** 2) + 0.05 * rng.random(bins)
    return h / h.sum()


def test_online_updates_separate_the_tracked_colour_from_the_other_detections():
    rng = np.random.default_rng(0)
    model = appearance.init(2, 8, jnp.float64)
    step = jax.jit(appearance.update)
    for _ in range(60):
        feats = jnp.asarray(np.stack([_hist(rng, 1.5), _hist(rng, 6.0), _hist(rng, 3.5)]))
        model = step(model, feats, jnp.array([0, 1]), jnp.array([True, True, True]),
                     jnp.array([True, True]), 2.0)
    test = jnp.asarray(np.stack([_hist(rng, 1.5), _hist(rng, 6.0), _hist(rng, 3.5)]))
    c = np.asarray(appearance.confidence(model, test))
    assert c[0, 0] > 0.8 and c[0, 1] < 0.2 and c[0, 2] < 0.5
    assert c[1, 1] > 0.8 and c[1, 0] < 0.2


def test_step_equals_a_hand_written_logistic_regression_gradient_step():
    rng = np.random.default_rng(1)
    feats = rng.random((3, 4))
    w0, b0 = rng.normal(size=4), 0.3
    model = appearance.Appearance(jnp.asarray(w0[None]), jnp.asarray([b0]))
    lr, l2 = 0.7, 0.01
    new = appearance.update(model, jnp.asarray(feats), jnp.array([1]),
                            jnp.array([True, True, False]), jnp.array([True]), lr, l2)
    sig = lambda x: 1 / (1 + np.exp(-x))  # noqa: E731
    p = sig(feats @ w0 + b0)
    # d/dlogit: -(1 - p) for the positive, p / |N| for each negative (only detection 0 here)
    gw = -(1 - p[1]) * feats[1] + p[0] * feats[0] + l2 * w0
    gb = -(1 - p[1]) + p[0]
    np.testing.assert_allclose(new.weights[0], w0 - lr * gw, rtol=1e-12)
    np.testing.assert_allclose(new.bias[0], b0 - lr * gb, rtol=1e-12)


def test_tracks_without_a_detection_or_dead_are_not_updated():
    model = appearance.Appearance(jnp.ones((3, 2)), jnp.zeros(3))
    new = appearance.update(model, jnp.eye(2), jnp.array([-1, 0, 1]), jnp.array([True, True]),
                            jnp.array([True, True, False]))
    np.testing.assert_array_equal(new.weights[0], model.weights[0])
    np.testing.assert_array_equal(new.weights[2], model.weights[2])
    assert not np.allclose(new.weights[1], model.weights[1])
