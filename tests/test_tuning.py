"""Gradient tuning: noise identification through the KF, skipped NaN steps, parameter maps."""

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from jaxtrack import tuning
from jaxtrack.filters import _linalg, kalman
from jaxtrack.models import measurement, motion

Q_TRUE, R_TRUE, DT, T = 0.5, 0.04, 0.1, 60
H = measurement.position(4)


def simulate(key):
    F, Q = motion.constant_velocity(DT, Q_TRUE)
    k1, k2 = jax.random.split(key)
    w = jax.random.normal(k1, (T, 4)) @ _linalg.cholesky(Q).T

    def body(x, wt):
        x = F @ x + wt
        return x, x

    _, xs = jax.lax.scan(body, jnp.zeros(4), w)
    return xs, xs[:, :2] + jnp.sqrt(R_TRUE) * jax.random.normal(k2, (T, 2))


def run_kf(key, p):
    xs, zs = simulate(key)
    F, Q = motion.constant_velocity(DT, jnp.exp(p["log_q"]))
    R = jnp.exp(p["log_r"]) * jnp.eye(2)
    return kalman.filter(kalman.Gaussian(jnp.zeros(4), 0.01 * jnp.eye(4)), zs, F, Q, H, R), xs


def negative_log_likelihood(key, p):
    return -run_kf(key, p)[0].log_likelihood / T


def tracking_mse(key, p):
    res, xs = run_kf(key, p)
    return jnp.mean(jnp.sum((res.means[:, :2] - xs[:, :2]) ** 2, -1))


P0 = {"log_q": np.log(2.0), "log_r": np.log(0.01)}


def test_maximum_likelihood_recovers_process_and_measurement_noise():
    opt = optax.adam(optax.exponential_decay(0.1, 80, 0.05))
    p, hist = tuning.fit(negative_log_likelihood, P0, jax.random.PRNGKey(1), optimizer=opt,
                         steps=80, batch_size=16, validation=8, progress=False)
    q, r = float(jnp.exp(p["log_q"])), float(jnp.exp(p["log_r"]))
    assert abs(q / Q_TRUE - 1) < 0.10, q
    assert abs(r / R_TRUE - 1) < 0.10, r
    assert hist.loss.shape == (80,) and hist.params["log_q"].shape == (81,)
    assert hist.val_loss[-1] < hist.val_loss[0]
    assert not hist.skipped.any()


def test_minimising_tracking_error_recovers_the_noise_ratio():
    opt = optax.adam(optax.exponential_decay(0.1, 120, 0.05))
    p, _ = tuning.fit(tracking_mse, P0, jax.random.PRNGKey(2), optimizer=opt, steps=120,
                      batch_size=32, progress=False)
    ratio = float(jnp.exp(p["log_q"] - p["log_r"]))
    assert abs(ratio / (Q_TRUE / R_TRUE) - 1) < 0.10, ratio


def test_non_finite_steps_are_skipped_and_reported(capsys):
    def loss(key, p):
        # Finite at x = 0, NaN beyond x = 1: the first step (to 0 - 0.3 * 2 * (0 - 3) = 1.8)
        # is applied, every later one must be skipped.
        return jnp.where(p["x"] > 1.0, jnp.nan, (p["x"] - 3.0) ** 2 + 0.0 * jax.random.normal(key))

    p, hist = tuning.fit(loss, {"x": 0.0}, jax.random.PRNGKey(0),
                         optimizer=optax.sgd(0.3), steps=10, batch_size=2)
    assert not hist.skipped[0] and hist.skipped[1:].all()
    np.testing.assert_allclose(hist.params["x"][1:], 1.8, rtol=1e-12)
    np.testing.assert_allclose(float(p["x"]), 1.8, rtol=1e-12)
    assert "skipped" in capsys.readouterr().err


def test_gradient_clipping_bounds_the_first_step():
    p, hist = tuning.fit(lambda k, p: 1e6 * p["x"] ** 2, {"x": 1.0}, jax.random.PRNGKey(0),
                         optimizer=optax.sgd(1.0), steps=1, batch_size=1, clip_norm=0.5,
                         progress=False)
    np.testing.assert_allclose(float(p["x"]), 0.5, rtol=1e-6)
    np.testing.assert_allclose(hist.grad_norm[0], 2e6, rtol=1e-6)


def test_parameter_maps_round_trip_and_give_positive_definite_covariances():
    rng = np.random.default_rng(0)
    y = rng.uniform(0.01, 5.0, 10)
    np.testing.assert_allclose(tuning.positive(tuning.positive_inverse(y)), y, rtol=1e-10)
    v = jnp.asarray(rng.normal(size=6))
    low = tuning.cholesky_from_unconstrained(v, 3)
    assert np.all(np.triu(np.asarray(low), 1) == 0) and np.all(np.diag(low) > 0)
    np.testing.assert_allclose(tuning.unconstrained_from_cholesky(low), v, rtol=1e-10)
    cov = tuning.covariance_from_unconstrained(v, 3)
    assert np.min(np.linalg.eigvalsh(np.asarray(cov))) > 0
    np.testing.assert_allclose(np.linalg.cholesky(np.asarray(cov)), low, rtol=1e-10)
    with pytest.raises(ValueError, match="need 6 values"):
        tuning.cholesky_from_unconstrained(jnp.zeros(5), 3)


def test_bad_arguments_raise():
    with pytest.raises(TypeError, match="float"):
        tuning.fit(lambda k, p: p["n"], {"n": 1}, jax.random.PRNGKey(0), steps=1)
    with pytest.raises(ValueError, match="positive"):
        tuning.fit(lambda k, p: p["x"], {"x": 1.0}, jax.random.PRNGKey(0), steps=0)
