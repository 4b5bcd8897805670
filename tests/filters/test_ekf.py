"""Reference tests for `jaxtrack.filters.ekf`.

References: the linear Kalman filter (itself checked against filterpy in test_kalman.py), a
numpy EKF with analytic range-bearing Jacobian and wrapped bearing innovation, central finite
differences. Errors are scale-relative (max |a - b| / max |b| per array).

Tolerances (float64): 1e-12 against the KF for linear models (same arithmetic up to rounding);
1e-9 against the numpy EKF; 1e-7 for the EKF predict against a finite-difference Jacobian (the
difference quotient's own error is ~1e-10); 1e-6 for gradients vs finite differences; float32
vs float64 1e-4.
"""

import jax
import numpy as np
import pytest
from scipy.stats import multivariate_normal

from jaxtrack.filters import ekf
from jaxtrack.filters.kalman import Gaussian
from jaxtrack.models import measurement, motion

RB = measurement.range_bearing
RB_RESIDUAL = measurement.range_bearing_residual


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


# ---------------------------------------------------------------------------------------------
# Linear models: the EKF is the KF


def test_filter_with_linear_models_equals_kalman_filter(kf_filter, cv_problem, assert_close):
    p = cv_problem
    F, H = p["F"], p["H"]
    init = Gaussian(p["init_mean"], p["init_cov"])
    masks = np.ones(len(p["zs"]), bool)
    masks[[3, 17]] = False
    run = jax.jit(lambda i, zs, m: ekf.filter(i, zs, lambda x: F @ x, p["Q"], lambda x: H @ x,
                                              p["R"], m))
    res = jax.device_get(run(init, p["zs"], masks))
    ref = kf_filter(init, p["zs"], F, p["Q"], H, p["R"], masks)
    for name in ("means", "covs", "predicted_means", "predicted_covs", "log_likelihoods"):
        assert_close(getattr(res, name), getattr(ref, name), 1e-12, name)


# ---------------------------------------------------------------------------------------------
# Predict: Jacobian of a nonlinear f


def test_predict_propagates_covariance_through_jacobian_of_f(assert_close, random_spd_fn):
    f, Q = motion.coordinated_turn(0.1, q_accel=0.5, q_turn=0.05)
    f_jit = jax.jit(f)
    predict = jax.jit(lambda s: ekf.predict(s, f, Q))
    rng = np.random.default_rng(21)
    for _ in range(3):
        mean = np.array([1.0, 2.0, 1.5, 3.0, 0.4]) + 0.3 * rng.standard_normal(5)
        cov = random_spd_fn(rng, 5, 0.1)
        h = 1e-6
        jac = np.stack([(np.asarray(f_jit(mean + h * e)) - np.asarray(f_jit(mean - h * e)))
                        / (2 * h) for e in np.eye(5)], axis=1)
        pred = jax.device_get(predict(Gaussian(mean, cov)))
        assert_close(pred.mean, np.asarray(f_jit(mean)), 1e-12, "mean")
        assert_close(pred.cov, jac @ cov @ jac.T + np.asarray(Q), 1e-7, "cov")


# ---------------------------------------------------------------------------------------------
# Range-bearing near the bearing cut at +-pi


def numpy_range_bearing_ekf(init, zs, F, Q, R):
    """Reference EKF: linear motion, range-bearing from the origin, wrapped bearing innovation.

    Returns means, covs, log-likelihoods and the *unwrapped* bearing innovations.
    """
    m, P = init[0].copy(), init[1].copy()
    means, covs, lls, raw = [], [], [], []
    for z in zs:
        m, P = F @ m, F @ P @ F.T + Q
        dx, dy = m[0], m[1]
        r2 = dx * dx + dy * dy
        r = np.sqrt(r2)
        H = np.zeros((2, len(m)))
        H[0, :2] = dx / r, dy / r
        H[1, :2] = -dy / r2, dx / r2
        y = z - np.array([r, np.arctan2(dy, dx)])
        raw.append(y[1])
        y[1] = _wrap(y[1])
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        m = m + K @ y
        I_KH = np.eye(len(m)) - K @ H
        P = I_KH @ P @ I_KH.T + K @ R @ K.T
        means.append(m)
        covs.append(P)
        lls.append(multivariate_normal(np.zeros(2), S).logpdf(y))
    return np.array(means), np.array(covs), np.array(lls), np.array(raw)


def test_range_bearing_filter_near_pi_wraps_innovation(cv_rb_ekf, assert_close):
    rng = np.random.default_rng(31)
    log_q, log_r = np.log(0.05), np.log(0.01)
    F, Q = (np.asarray(a) for a in motion.constant_velocity(0.1, np.exp(log_q)))
    R = np.exp(log_r) * np.diag([1.0, 0.04])  # range std 0.1 m, bearing std 0.02 rad
    # a target near the negative x axis, crossing it from bearing ~+pi to ~-pi
    x, xs, zs = np.array([-8.0, 1.0, 0.1, -0.5]), [], []
    for _ in range(50):
        x = F @ x + np.linalg.cholesky(Q) @ rng.standard_normal(4)
        z = np.array([np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])])
        z = z + np.sqrt(np.diag(R)) * rng.standard_normal(2)
        z[1] = _wrap(z[1])
        xs.append(x)
        zs.append(z)
    xs, zs = np.array(xs), np.array(zs)
    assert np.all(np.abs(zs[:, 1]) > 2.5) and zs[0, 1] > 0 > zs[-1, 1]  # crosses the cut
    init = (np.array([-8.0, 1.0, 0.0, -0.4]), np.diag([0.5, 0.5, 0.2, 0.2]))

    run, _ = cv_rb_ekf
    res = jax.device_get(run(Gaussian(*init), zs, np.ones(50, bool), log_q, log_r))
    means, covs, lls, raw = numpy_range_bearing_ekf(init, zs, F, Q, R)
    assert np.max(np.abs(raw)) > np.pi  # some unwrapped innovations are ~2 pi: wrapping matters
    assert_close(res.means, means, 1e-9, "means")
    assert_close(res.covs, covs, 1e-9, "covs")
    assert_close(res.log_likelihoods, lls, 1e-9, "log_likelihoods")
    # and the filter keeps tracking through the cut
    assert np.max(np.linalg.norm(res.means[:, :2] - xs[:, :2], axis=1)) < 0.5


def test_update_with_range_bearing_across_cut_moves_state_little():
    prior = Gaussian(np.array([-5.0, 0.05, 0.0, 0.0]), np.diag([0.1, 0.1, 1.0, 1.0]))
    R = np.diag([0.1**2, 0.05**2])
    z = np.array([5.0, -np.pi + 0.01])  # the same direction as the prior (bearing ~ pi - 0.01)
    post, ll = jax.device_get(jax.jit(
        lambda s, z: ekf.update(s, z, RB, R, residual=RB_RESIDUAL))(prior, z))
    # the wrapped bearing innovation is +0.02 rad (0.1 m sideways at 5 m), not 0.02 - 2 pi
    assert np.linalg.norm(post.mean - prior.mean) < 0.2
    assert ll > -5.0


# ---------------------------------------------------------------------------------------------
# Masks, gradients, float32 on the CV + range-bearing problem


def test_update_with_mask_false_returns_state_unchanged_and_zero_log_likelihood():
    prior = Gaussian(np.array([3.0, 4.0, 0.5, 0.1]), np.diag([0.2, 0.3, 0.5, 0.5]))
    R = np.diag([0.1, 0.01])
    z = np.array([5.5, 0.8])
    jitted = jax.jit(lambda s, z, m: ekf.update(s, z, RB, R, m, residual=RB_RESIDUAL))
    for mask in (np.array(False), np.array(True)):
        post, ll = jax.device_get(jitted(prior, z, mask))
        if mask:  # the present measurement does move the state (the check can fail)
            assert np.max(np.abs(post.mean - prior.mean)) > 1e-2 and ll != 0.0
        else:
            np.testing.assert_array_equal(post.mean, prior.mean)
            np.testing.assert_array_equal(post.cov, prior.cov)
            assert float(ll) == 0.0


@pytest.fixture(scope="module")
def cv_rb_ekf(cv_range_bearing_model_fn):
    """Jitted EKF on CV + range-bearing (residual wraps the bearing) as a function of the log
    noises, and its jitted value-and-gradient; the dtype follows the inputs."""

    def run(init, zs, masks, log_q, log_r):
        F, Q, R = cv_range_bearing_model_fn(log_q, log_r)
        return ekf.filter(init, zs, lambda x: F @ x, Q, RB, R, masks, residual=RB_RESIDUAL)

    def loss(log_q, log_r, init, zs, masks):
        return run(init, zs, masks, log_q, log_r).log_likelihood

    return jax.jit(run), jax.jit(jax.value_and_grad(loss, argnums=(0, 1)))


def test_log_likelihood_gradient_matches_finite_differences(cv_range_bearing_problem, cv_rb_ekf,
                                                            assert_close):
    run, value_and_grad = cv_rb_ekf
    p = cv_range_bearing_problem
    init = Gaussian(p["init_mean"], p["init_cov"])
    theta = np.array([p["log_q"] - 1.0, p["log_r"] + 0.7])  # away from the truth
    masks = np.ones(len(p["zs"]), bool)
    _, grad = value_and_grad(theta[0], theta[1], init, p["zs"], masks)
    h = 1e-5

    def loss(th):
        return float(run(init, p["zs"], masks, th[0], th[1]).log_likelihood)

    fd = [(loss(theta + h * e) - loss(theta - h * e)) / (2 * h) for e in np.eye(2)]
    assert np.linalg.norm(fd) > 1.0
    assert_close(np.array(grad), np.array(fd), 1e-6, "gradient vs central differences")


def test_nan_in_unmasked_measurement_is_missing_and_counted(cv_range_bearing_problem,
                                                            cv_rb_ekf, assert_close):
    run, _ = cv_rb_ekf
    p = cv_range_bearing_problem
    init = Gaussian(p["init_mean"], p["init_cov"])
    T = len(p["zs"])
    with_nan, placeholder, masks = p["zs"].copy(), p["zs"].copy(), np.ones(T, bool)
    with_nan[[4, 33]] = np.nan
    placeholder[[4, 33]] = 0.0
    masks[[4, 33]] = False
    res = jax.device_get(run(init, with_nan, np.ones(T, bool), p["log_q"], p["log_r"]))
    ref = jax.device_get(run(init, placeholder, masks, p["log_q"], p["log_r"]))
    assert int(res.num_invalid) == 4 and int(ref.num_invalid) == 0
    for name in ("means", "covs", "log_likelihoods"):
        assert_close(getattr(res, name), getattr(ref, name), 1e-12, name)


def test_float32_matches_float64(cv_range_bearing_problem, cv_rb_ekf, assert_close):
    run, _ = cv_rb_ekf
    p = cv_range_bearing_problem
    args64 = (Gaussian(p["init_mean"], p["init_cov"]), p["zs"], np.ones(len(p["zs"]), bool),
              p["log_q"], p["log_r"])
    args32 = jax.tree.map(lambda a: a if a.dtype == bool else np.asarray(a, np.float32),
                          args64)
    res64 = jax.device_get(run(*args64))
    res32 = jax.device_get(run(*args32))
    assert res32.means.dtype == np.float32 and res32.covs.dtype == np.float32
    for name in ("means", "covs", "log_likelihoods"):
        assert_close(getattr(res32, name), getattr(res64, name), 1e-4, name)


# ---------------------------------------------------------------------------------------------
# Errors at the public boundary


def _bad_input_cases():
    s4 = Gaussian(np.zeros(4) + 1.0, np.eye(4))
    F, Q = np.eye(4), 0.1 * np.eye(4)
    R = np.eye(2)
    zs = np.ones((10, 2))
    lin_f = lambda x: F @ x  # noqa: E731
    return [
        ("f not callable (a matrix)", lambda: ekf.predict(s4, F, Q), TypeError,
         "f must be callable"),
        ("f not callable in filter", lambda: ekf.filter(s4, zs, F, Q, RB, R), TypeError,
         "f must be callable"),
        ("h not callable", lambda: ekf.update(s4, np.ones(2), np.eye(2, 4), R), TypeError,
         "h must be callable"),
        ("f output shape", lambda: ekf.predict(s4, lambda x: x[:3], Q), ValueError,
         r"f\(x\) must have shape \[4\]"),
        ("h output vs z", lambda: ekf.update(s4, np.ones(3), RB, np.eye(3)), ValueError,
         r"h\(x\) must have shape \[3\]"),
        ("Q vs state", lambda: ekf.predict(s4, lin_f, np.eye(3)), ValueError,
         r"Q must be \[4, 4\]"),
        ("R not PSD", lambda: ekf.update(s4, np.ones(2), RB, -R), ValueError,
         "R is not positive semi-definite"),
        ("unknown time_varying",
         lambda: ekf.filter(s4, zs, lin_f, Q, RB, R, time_varying=("F",)), ValueError,
         r"unknown time_varying \['F'\]"),
        ("time-varying R without time axis",
         lambda: ekf.filter(s4, zs, lin_f, Q, RB, R, time_varying=("R",)), ValueError,
         r"R must be leading batch axes"),
    ]


@pytest.mark.parametrize("call,error,match", [c[1:] for c in _bad_input_cases()],
                         ids=[c[0] for c in _bad_input_cases()])
def test_bad_input_raises_clear_error(call, error, match):
    with pytest.raises(error, match=match):
        call()

