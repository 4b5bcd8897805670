"""Tests for `jaxtrack.metrics.errors`: RMSE, wrapped angle errors, NEES / NIS, chi-square
quantiles and bounds.

References: NumPy formulas written independently (angles wrapped with complex exponentials,
quadratic forms with `numpy.linalg.solve` on the present sub-block), ``scipy.stats.chi2.ppf``,
and a Monte-Carlo simulation of a consistent (and an inconsistent) Kalman filter.

Tolerances: 1e-12 (relative) in float64 for the formulas and 1e-12 for chi-square quantiles
against scipy (measured about 1e-13); float32 1e-5 relative (quantiles: 1e-5 for dof <= 1000).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from jaxtrack import metrics
from jaxtrack.filters import kalman
from jaxtrack.models import motion

RNG = np.random.default_rng(4242)


def reference_wrap(a):
    return np.angle(np.exp(1j * a))


def reference_quadratic(v, cov, present):
    idx = np.flatnonzero(present)
    if idx.size == 0:
        return 0.0
    sub = cov[np.ix_(idx, idx)]
    return float(v[idx] @ np.linalg.solve(sub, v[idx]))


def random_spd(n, batch):
    a = RNG.standard_normal((batch, n, n))
    return a @ np.swapaxes(a, -1, -2) / n + 0.2 * np.eye(n)


# ---------------------------------------------------------------------------------------------
# Position and angle errors


def test_rmse_matches_numpy_with_and_without_mask():
    est, true = RNG.standard_normal((30, 3)), RNG.standard_normal((30, 3))
    mask = RNG.random(30) < 0.6
    err = np.linalg.norm(est - true, axis=1)
    np.testing.assert_allclose(metrics.position_error(est, true), err, rtol=1e-13)
    np.testing.assert_allclose(metrics.rmse(est, true), np.sqrt(np.mean(err**2)), rtol=1e-13)
    np.testing.assert_allclose(metrics.rmse(est, true, mask), np.sqrt(np.mean(err[mask] ** 2)),
                               rtol=1e-13)


def test_rmse_ignores_nan_in_masked_steps_and_is_nan_when_nothing_is_present():
    est, true = RNG.standard_normal((5, 2)), RNG.standard_normal((5, 2))
    mask = np.array([True, False, True, False, True])
    poisoned = est.copy()
    poisoned[~mask] = np.nan
    np.testing.assert_allclose(metrics.rmse(poisoned, true, mask), metrics.rmse(est, true, mask),
                               rtol=0)
    assert np.isnan(metrics.rmse(est, true, np.zeros(5, bool)))
    grad = jax.grad(lambda e: metrics.rmse(e, true, mask))(jnp.asarray(poisoned))
    assert np.all(np.isfinite(grad)) and np.all(grad[~mask] == 0)


@pytest.mark.parametrize("shape", [(40,), (40, 3)])
def test_angle_rmse_and_mae_match_a_complex_exponential_reference(shape):
    est, true = RNG.uniform(-10, 10, shape), RNG.uniform(-10, 10, shape)
    mask = RNG.random(shape) < 0.7
    err = reference_wrap(est - true)
    np.testing.assert_allclose(metrics.angle_error(est, true), err, atol=1e-12)
    np.testing.assert_allclose(metrics.angle_rmse(est, true, mask),
                               np.sqrt(np.mean(err[mask] ** 2)), rtol=1e-12)
    np.testing.assert_allclose(metrics.angle_mae(est, true, mask), np.mean(np.abs(err[mask])),
                               rtol=1e-12)
    step_mask = mask.reshape(shape[0], -1)[:, 0]
    full = np.broadcast_to(step_mask.reshape((-1,) + (1,) * (len(shape) - 1)), shape)
    np.testing.assert_allclose(metrics.angle_mae(est, true, step_mask),
                               np.mean(np.abs(err[full])), rtol=1e-12)


def test_angle_errors_take_the_short_way_across_plus_minus_pi():
    pi = np.pi
    est = np.array([pi - 0.1, -pi + 0.1, pi, pi, 3 * pi, 0.0])
    true = np.array([-pi + 0.1, pi - 0.1, -pi, 0.0, -pi, 2 * pi])
    signed = np.asarray(metrics.angle_error(est, true))
    np.testing.assert_allclose(np.abs(signed), [0.2, 0.2, 0.0, pi, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(signed[:2], [-0.2, 0.2], atol=1e-12)
    np.testing.assert_allclose(metrics.angle_mae(est[:2], true[:2]), 0.2, rtol=1e-12)
    np.testing.assert_allclose(metrics.angle_rmse(est[3:4], true[3:4]), pi, rtol=1e-12)


# ---------------------------------------------------------------------------------------------
# NEES and NIS


@pytest.mark.parametrize("fn", [metrics.nees, metrics.nis])
@pytest.mark.parametrize("mask_kind", ["none", "steps", "components"])
def test_normalised_squares_match_a_sub_block_solve(fn, mask_kind):
    T, n = 25, 4
    v, cov = RNG.standard_normal((T, n)), random_spd(n, T)
    mask = {"none": None, "steps": RNG.random(T) < 0.7,
            "components": RNG.random((T, n)) < 0.7}[mask_kind]
    full = np.ones((T, n), bool) if mask is None else np.broadcast_to(
        mask[:, None] if mask.ndim == 1 else mask, (T, n))
    ref = [reference_quadratic(v[t], cov[t], full[t]) for t in range(T)]
    got = fn(v, cov, mask)
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12)


def test_nees_ignores_nan_in_masked_entries():
    T, n = 6, 3
    v, cov = RNG.standard_normal((T, n)), random_spd(n, T)
    mask = RNG.random((T, n)) < 0.6
    poisoned_v, poisoned_cov = v.copy(), cov.copy()
    poisoned_v[~mask] = np.nan
    for t in range(T):
        poisoned_cov[t][~mask[t], :] = np.nan
    np.testing.assert_allclose(metrics.nees(poisoned_v, poisoned_cov, mask),
                               metrics.nees(v, cov, mask), rtol=1e-13)


def simulate_cv(rng, F, Q, H, R, m0, P0, T):
    """State path [T, 4] and measurements [T, 2] of the linear-Gaussian model, x0 ~ N(m0, P0)."""
    lq, lr = np.linalg.cholesky(Q), np.linalg.cholesky(R)
    x = m0 + np.linalg.cholesky(P0) @ rng.standard_normal(4)
    xs, zs = [], []
    for _ in range(T):
        x = F @ x + lq @ rng.standard_normal(4)
        xs.append(x)
        zs.append(H @ x + lr @ rng.standard_normal(2))
    return np.array(xs), np.array(zs)


@pytest.fixture(scope="module")
def kf_runs():
    """50 Monte-Carlo runs (T = 20) of a CV model; NEES / NIS of a matched KF and of one that
    believes the measurement noise is 20 times smaller than it is."""
    runs, T = 50, 20
    F, Q = (np.asarray(a) for a in motion.constant_velocity(0.1, 0.5))
    H, R = np.eye(2, 4), 0.05 * np.eye(2)
    m0, P0 = np.array([0.0, 0.0, 1.0, 0.5]), np.diag([0.1, 0.1, 0.05, 0.05])
    rng = np.random.default_rng(7)
    xs, zs = (np.stack(a) for a in zip(*(simulate_cv(rng, F, Q, H, R, m0, P0, T)
                                          for _ in range(runs))))

    def episode(x, z, r_scale):
        res = kalman.filter(kalman.Gaussian(m0, P0), z, F, Q, H, r_scale * R)
        S = H @ res.predicted_covs @ H.T + r_scale * R
        return (metrics.nees(x - res.means, res.covs),
                metrics.nis(z - res.predicted_means @ H.T, S))

    run = jax.jit(jax.vmap(episode, in_axes=(0, 0, None)))
    matched = jax.device_get(run(xs, zs, 1.0))
    overconfident = jax.device_get(run(xs, zs, 0.05))
    return runs, T, matched, overconfident


def test_nees_and_nis_of_a_consistent_kalman_filter_lie_inside_the_chi2_bounds(kf_runs):
    runs, T, (nees, nis), _ = kf_runs
    lo4, hi4 = metrics.chi2_bounds(4, runs)
    lo2, hi2 = metrics.chi2_bounds(2, runs)
    avg_nees, avg_nis = nees.mean(0), nis.mean(0)
    # 95% bounds per step: expect about 1 of 20 steps outside; allow 3.
    assert np.sum((avg_nees < lo4) | (avg_nees > hi4)) <= 3, avg_nees
    assert np.sum((avg_nis < lo2) | (avg_nis > hi2)) <= 3, avg_nis
    # Steps of one run are correlated, so pooling them does not tighten the bounds: the average
    # over all runs and steps is checked against the bounds for `runs` samples only.
    assert lo4 <= nees.mean() <= hi4 and lo2 <= nis.mean() <= hi2


def test_nees_of_an_overconfident_kalman_filter_lies_above_the_chi2_bounds(kf_runs):
    runs, T, _, (nees, nis) = kf_runs
    _, hi4 = metrics.chi2_bounds(4, runs)
    _, hi2 = metrics.chi2_bounds(2, runs)
    assert np.mean(nees.mean(0) > hi4) > 0.9
    assert np.mean(nis.mean(0) > hi2) > 0.9


# ---------------------------------------------------------------------------------------------
# Chi-square quantiles and bounds

_chi2_ppf = jax.jit(metrics.chi2_ppf)


def test_chi2_ppf_matches_scipy_over_degrees_of_freedom_and_tails():
    q = np.array([1e-10, 1e-6, 1e-3, 0.025, 0.3, 0.5, 0.7, 0.975, 0.999, 1 - 1e-6, 1 - 1e-10])
    dof = np.array([0.5, 1, 2, 3, 4, 6, 10, 50, 200, 1000, 1e4])
    Q, K = np.meshgrid(q, dof)
    ref = stats.chi2.ppf(Q, K)
    got = np.asarray(_chi2_ppf(Q, K))
    assert np.max(np.abs(got - ref) / ref) < 1e-12


def test_chi2_ppf_in_float32_is_accurate_to_1e_5():
    q = np.array([1e-3, 0.025, 0.5, 0.975, 0.999], np.float32)
    dof = np.array([1, 2, 4, 10, 100, 1000], np.float32)
    Q, K = np.meshgrid(q, dof)
    got = _chi2_ppf(Q, K)
    assert got.dtype == jnp.float32
    ref = stats.chi2.ppf(Q.astype(np.float64), K.astype(np.float64))
    assert np.max(np.abs(np.asarray(got, np.float64) - ref) / ref) < 1e-5


def test_chi2_ppf_traced_inside_jit_skips_the_value_checks_and_matches_eager():
    # The gate quantile of `jaxtrack.association.chi2_ppf` calls it inside its own jit.
    q, dof = np.array([0.01, 0.5, 0.9999]), np.array([3.0, 5.0, 8.0])
    eager = np.asarray(metrics.chi2_ppf(q, dof))
    np.testing.assert_allclose(np.asarray(jax.jit(lambda q: metrics.chi2_ppf(q, dof))(q)), eager,
                               rtol=1e-14)
    np.testing.assert_allclose(eager, stats.chi2.ppf(q, dof), rtol=1e-12)
    # a traced q of 1.5 cannot be checked (it comes out NaN); a concrete one is rejected
    assert np.isnan(jax.jit(metrics.chi2_ppf)(1.5, 3.0))
    with pytest.raises(ValueError, match="q must lie"):
        metrics.chi2_ppf(1.5, 3.0)


@pytest.mark.parametrize("dof,num_samples,prob", [(2, 1, 0.95), (4, 50, 0.95), (6, 1000, 0.99),
                                                  (3, 20, 0.5)])
def test_chi2_bounds_match_scipy(dof, num_samples, prob):
    lo, hi = metrics.chi2_bounds(dof, num_samples, prob)
    k = dof * num_samples
    np.testing.assert_allclose(lo, stats.chi2.ppf((1 - prob) / 2, k) / num_samples, rtol=1e-12)
    np.testing.assert_allclose(hi, stats.chi2.ppf((1 + prob) / 2, k) / num_samples, rtol=1e-12)


# ---------------------------------------------------------------------------------------------
# Batching, float32, bad input


def _episode(e, x, m, P, a, b):
    return (metrics.rmse(e, x, m), metrics.nees(e - x, P, m), metrics.angle_rmse(a, b, m),
            metrics.angle_mae(a, b, m))


def test_vmap_over_episodes_equals_a_loop():
    B, T, n = 4, 12, 3
    est, true = RNG.standard_normal((B, T, n)), RNG.standard_normal((B, T, n))
    masks = RNG.random((B, T)) < 0.8
    covs = random_spd(n, B * T).reshape(B, T, n, n)
    angles, truth_angles = RNG.uniform(-4, 4, (B, T)), RNG.uniform(-4, 4, (B, T))
    args = (est, true, masks, covs, angles, truth_angles)
    batched = jax.jit(jax.vmap(_episode))(*args)
    single = jax.jit(_episode)
    for i in range(B):
        for got, want in zip(batched, single(*(a[i] for a in args))):
            np.testing.assert_allclose(got[i], want, rtol=1e-14, atol=1e-14)


def test_float32_inputs_give_float32_results_close_to_float64():
    T, n = 20, 4
    est, true = RNG.standard_normal((T, n)), RNG.standard_normal((T, n))
    covs = random_spd(n, T)
    angles = RNG.uniform(-4, 4, T)
    mask = np.ones(T, bool)
    got = jax.jit(_episode)(*(np.float32(a) for a in (est, true)), mask, np.float32(covs),
                            np.float32(angles), np.float32(true[:, 0]))
    err = reference_wrap(angles - true[:, 0])
    want = (np.sqrt(np.mean(np.sum((est - true) ** 2, 1))),
            [reference_quadratic(est[t] - true[t], covs[t], np.ones(n, bool)) for t in range(T)],
            np.sqrt(np.mean(err**2)), np.mean(np.abs(err)))
    for g, w in zip(got, want):
        assert g.dtype == jnp.float32
        np.testing.assert_allclose(np.asarray(g, np.float64), w, rtol=1e-5)


@pytest.mark.parametrize("call,match", [
    (lambda: metrics.rmse(np.zeros((5, 2)), np.zeros((5, 3))), "truths must have shape"),
    (lambda: metrics.rmse(np.zeros((5, 2)), np.zeros((5, 2)), np.ones(4, bool)), "mask"),
    (lambda: metrics.rmse(np.zeros(5), np.zeros(5)), "estimates must be"),
    (lambda: metrics.angle_rmse(np.zeros(5), np.zeros(6)), "same shape"),
    (lambda: metrics.angle_mae(np.zeros((5, 2)), np.zeros((5, 2)), np.ones(2, bool)), "mask"),
    (lambda: metrics.nees(np.zeros((5, 2)), np.zeros((5, 3, 3))), "covs must have shape"),
    (lambda: metrics.nis(np.zeros((5, 2)), np.zeros((5, 2, 2)), np.ones((5, 3))), "mask"),
    (lambda: metrics.chi2_ppf(1.5, 2), "q must lie"),
    (lambda: metrics.chi2_ppf(0.5, 0), "dof must be positive"),
    (lambda: metrics.chi2_bounds(4, 0), "num_samples must be positive"),
    (lambda: metrics.chi2_bounds(4, 10, prob=1.0), "prob must lie"),
])
def test_bad_input_raises_a_clear_value_error(call, match):
    with pytest.raises(ValueError, match=match):
        call()
