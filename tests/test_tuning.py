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
    with pytest.raises(ValueError, match="unknown gradient"):
        tuning.fit(lambda k, p: p["x"], {"x": 1.0}, jax.random.PRNGKey(0), steps=1,
                   gradient="spsa")
    with pytest.raises(ValueError, match="smoothing"):
        tuning.fit(lambda k, p: p["x"], {"x": 1.0}, jax.random.PRNGKey(0), steps=1,
                   gradient="smoothed", smoothing=0.0)
    with pytest.raises(ValueError, match="directions"):
        tuning.smoothed_value_and_grad(lambda k, p: p["x"], {"x": 1.0},
                                       jax.random.split(jax.random.PRNGKey(0), 2),
                                       jax.random.PRNGKey(1), directions=0)


# --- smoothed (Gaussian-smoothing, antithetic) gradients -------------------------------------

A_QUAD = np.array([[2.0, 0.5], [0.5, 1.0]])
B_QUAD = np.array([1.0, -2.0])


def quadratic(key, p):
    x = jnp.concatenate([p["a"], p["b"][None]])
    return 0.5 * x @ jnp.asarray(A_QUAD) @ x + jnp.asarray(B_QUAD) @ x


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_smoothed_gradient_of_a_quadratic_is_its_gradient(dtype):
    # For a quadratic the antithetic difference is exactly eps . grad, so the estimate is
    # (1/K) sum_k eps_k eps_k^T grad: compare with that closed form, and with grad in the mean.
    p = {"a": jnp.array([0.3], dtype), "b": jnp.array(-0.7, dtype)}
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    dkey = jax.random.PRNGKey(5)
    K = 4096
    value, g = tuning.smoothed_value_and_grad(quadratic, p, keys, dkey, smoothing=0.3,
                                              directions=K)
    assert g["a"].dtype == dtype and g["b"].dtype == dtype
    x = np.array([0.3, -0.7])
    exact = A_QUAD @ x + B_QUAD
    eps = np.asarray(jax.random.normal(dkey, (K, 2), dtype), float)
    closed = (eps.T @ eps / K) @ exact
    est = np.array([float(g["a"][0]), float(g["b"])])
    tol = 1e-4 if dtype == jnp.float32 else 1e-10
    np.testing.assert_allclose(est, closed, rtol=tol * 10, atol=tol)
    # E[eps eps^T] = I: within 4 standard errors of the exact gradient.
    se = np.sqrt(np.mean((eps * (eps @ exact)[:, None] - exact) ** 2, 0) / K)
    assert np.all(np.abs(est - exact) < 4 * se)
    # The value is the smoothed loss: L(x) + sigma^2 tr(A) / 2, in the mean.
    smoothed_value = 0.5 * x @ A_QUAD @ x + B_QUAD @ x + 0.5 * 0.3**2 * np.trace(A_QUAD)
    assert abs(float(value) - smoothed_value) < 0.05


def test_smoothed_gradient_sees_a_jump_that_the_pathwise_gradient_misses():
    # A step at 0: the pathwise derivative is 0; the smoothed loss Phi(x / sigma) has
    # derivative phi(x / sigma) / sigma.
    from scipy.stats import norm
    loss = lambda k, p: (p["x"] > 0.0).astype(p["x"].dtype)  # noqa: E731
    p = {"x": jnp.asarray(0.05)}
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    assert float(jax.grad(lambda q: loss(None, q))(p)["x"]) == 0.0
    sigma, K = 0.1, 20000
    _, g = tuning.smoothed_value_and_grad(loss, p, keys, jax.random.PRNGKey(3), sigma, K)
    expected = norm.pdf(0.05 / sigma) / sigma
    # per-direction estimate |eps| 1[|eps| > 0.5] / 2: its sd bounds the error
    eps = np.random.default_rng(0).standard_normal(10**6)
    sd = np.std(np.abs(eps) * (np.abs(eps) > 0.05 / sigma) / (2 * sigma)) / np.sqrt(K)
    assert abs(float(g["x"]) - expected) < 4 * sd


def test_fit_with_smoothed_gradient_descends_a_staircase_the_pathwise_gradient_cannot():
    # A noisy staircase around (x - 2)^2: pathwise gradients are zero almost everywhere.
    def loss(key, p):
        return jnp.floor(4.0 * (p["x"] - 2.0) ** 2) / 4.0 + 0.01 * jax.random.normal(key)

    start = {"x": jnp.asarray(0.0)}
    _, hist_path = tuning.fit(loss, start, jax.random.PRNGKey(0), optax.adam(0.1), steps=20,
                              batch_size=4, progress=False)
    np.testing.assert_allclose(hist_path.params["x"], 0.0)   # never moved
    params, hist = tuning.fit(loss, start, jax.random.PRNGKey(0), optax.adam(0.1), steps=60,
                              batch_size=4, progress=False, gradient="smoothed",
                              smoothing=0.3, directions=16)
    assert abs(float(params["x"]) - 2.0) < 0.3
    assert hist.loss[-5:].mean() < 0.5 * hist.loss[:5].mean()
    assert not hist.skipped.any()
