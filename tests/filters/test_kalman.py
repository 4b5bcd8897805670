"""Reference tests for `jaxtrack.filters.kalman` (filter, step functions, RTS smoother).

References: filterpy 2.0.0's ``KalmanFilter`` (Joseph-form update, ``rts_smoother``), the exact
posterior of the joint Gaussian over states and measurements, central finite differences.
Errors are scale-relative (max |a - b| / max |b| per array; see ``assert_close``).

Tolerances (float64): 1e-9 against filterpy and the joint Gaussian; 1e-12 for vmap vs loop and
for NaN-masked vs placeholder-masked runs; 1e-6 for gradients vs finite differences; float32 vs
float64 1e-4.
"""

import filterpy.kalman
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import multivariate_normal

from jaxtrack.filters import kalman
from jaxtrack.filters.kalman import Gaussian
from jaxtrack.models import measurement, motion

T_RANDOM = 50  # the T of the shared CV problem, so compiled filters are reused
_rts = jax.jit(kalman.rts_smoother, static_argnames=("time_varying",))


def rts(*args, **kwargs):
    return jax.device_get(_rts(*args, **kwargs))


# ---------------------------------------------------------------------------------------------
# Random models and the filterpy reference


def random_model(seed, n, m, k=0):
    """Random F (spectral radius 0.98), SPD Q and R, H [m, n], prior, measurements [T, m]."""
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((n, n))
    F = 0.98 * a / np.max(np.abs(np.linalg.eigvals(a)))
    Q = _spd(rng, n, 0.1)
    H = rng.standard_normal((m, n))
    R = _spd(rng, m, 0.5)
    init = (rng.standard_normal(n), _spd(rng, n, 1.0))
    zs = 2.0 * rng.standard_normal((T_RANDOM, m))
    B = rng.standard_normal((n, k)) if k else None
    us = rng.standard_normal((T_RANDOM, k)) if k else None
    return dict(F=F, Q=Q, H=H, R=R, init=init, zs=zs, B=B, us=us, rng=rng)


def _spd(rng, n, scale):
    a = rng.standard_normal((n, n))
    return scale * (a @ a.T / n + 0.1 * np.eye(n))


def filterpy_filter(init, zs, F, Q, H, R, masks=None, B=None, us=None, Fs=None, Qs=None):
    """filterpy's KalmanFilter, predict then update per step; masks [T] or [T, m] bools.

    A component mask updates with the present rows of H, R (and columns of R) only; a fully
    missing step calls ``update(None)`` and contributes log-likelihood 0.
    """
    T, m = zs.shape
    n = len(init[0])
    kf = filterpy.kalman.KalmanFilter(dim_x=n, dim_z=m, dim_u=0 if B is None else B.shape[1])
    kf.x, kf.P, kf.F, kf.Q, kf.H, kf.R = init[0].copy(), init[1].copy(), F, Q, H, R
    if B is not None:
        kf.B = B
    if masks is None:
        masks = np.ones(T, bool)
    masks = np.broadcast_to(masks if masks.ndim == 2 else masks[:, None], (T, m))
    out = {k: [] for k in ("means", "covs", "predicted_means", "predicted_covs",
                           "log_likelihoods")}
    for t in range(T):
        kf.predict(u=None if us is None else us[t],
                   F=None if Fs is None else Fs[t], Q=None if Qs is None else Qs[t])
        out["predicted_means"].append(kf.x.copy())
        out["predicted_covs"].append(kf.P.copy())
        present = masks[t]
        if present.all():
            kf.update(zs[t])
            ll = kf.log_likelihood
        elif present.any():
            kf.update(zs[t][present], R=R[np.ix_(present, present)], H=H[present])
            ll = kf.log_likelihood
        else:
            kf.update(None)
            ll = 0.0
        out["means"].append(kf.x.copy())
        out["covs"].append(kf.P.copy())
        out["log_likelihoods"].append(ll)
    return {k: np.array(v) for k, v in out.items()}


def compare_to_reference(assert_close, res, ref, tol):
    for name in ("means", "covs", "predicted_means", "predicted_covs", "log_likelihoods"):
        assert_close(getattr(res, name), ref[name], tol, name)
    assert_close(res.log_likelihood, np.sum(ref["log_likelihoods"]), tol, "log_likelihood")


# ---------------------------------------------------------------------------------------------
# Against filterpy


@pytest.mark.parametrize("seed,n,m,k", [(0, 2, 1, 1), (1, 4, 2, 0), (2, 6, 3, 0)],
                         ids=["n2m1-control", "n4m2", "n6m3"])
def test_filter_matches_filterpy_with_missing_steps(kf_filter, assert_close, seed, n, m, k):
    p = random_model(seed, n, m, k)
    masks = p["rng"].random(T_RANDOM) > 0.25
    masks[0] = True
    assert not masks.all()
    res = kf_filter(Gaussian(*p["init"]), p["zs"], p["F"], p["Q"], p["H"], p["R"], masks,
                    B=p["B"], us=p["us"])
    ref = filterpy_filter(p["init"], p["zs"], p["F"], p["Q"], p["H"], p["R"], masks,
                          B=p["B"], us=p["us"])
    compare_to_reference(assert_close, res, ref, 1e-9)
    np.testing.assert_array_equal(np.asarray(res.log_likelihoods)[~masks], 0.0)
    assert int(res.num_invalid) == 0


@pytest.fixture(scope="module")
def component_masked(kf_filter):
    """A 5-state, 3-measurement model with per-component masks [T, 3], and its filter result."""
    p = random_model(3, 5, 3)
    masks = p["rng"].random((T_RANDOM, 3)) > 0.3
    masks[5] = False  # a step with nothing present
    masks[6] = [True, False, True]
    res = kf_filter(Gaussian(*p["init"]), p["zs"], p["F"], p["Q"], p["H"], p["R"], masks)
    return p, masks, res


def test_filter_component_masks_match_update_with_present_rows(component_masked, assert_close):
    p, masks, res = component_masked
    ref = filterpy_filter(p["init"], p["zs"], p["F"], p["Q"], p["H"], p["R"], masks)
    compare_to_reference(assert_close, res, ref, 1e-9)
    assert float(res.log_likelihoods[5]) == 0.0


def test_rts_smoother_matches_filterpy(component_masked, assert_close):
    p, _, res = component_masked
    sm = rts(res, p["F"], p["Q"])
    kf = filterpy.kalman.KalmanFilter(dim_x=5, dim_z=3)
    kf.F, kf.Q = p["F"], p["Q"]
    ref_means, ref_covs, _, _ = kf.rts_smoother(np.asarray(res.means), np.asarray(res.covs))
    assert_close(sm.means, ref_means, 1e-9, "smoothed means")
    assert_close(sm.covs, ref_covs, 1e-9, "smoothed covs")
    # the module-level filterpy smoother agrees for a time-invariant model
    ref2 = filterpy.kalman.rts_smoother(np.asarray(res.means), np.asarray(res.covs),
                                        [p["F"]] * T_RANDOM, [p["Q"]] * T_RANDOM)
    assert_close(sm.means, ref2[0], 1e-9, "smoothed means (rts_smoother function)")


def test_rts_smoother_time_varying_F_Q_matches_filterpy(kf_filter, assert_close):
    p = random_model(4, 4, 2)
    rng = p["rng"]
    Fs = np.stack([p["F"] + 0.05 * rng.standard_normal((4, 4)) for _ in range(T_RANDOM)])
    Qs = np.stack([_spd(rng, 4, 0.1) for _ in range(T_RANDOM)])
    init = Gaussian(*p["init"])
    masks = np.ones(T_RANDOM, bool)
    res = kf_filter(init, p["zs"], Fs, Qs, p["H"], p["R"], masks, time_varying=("F", "Q"))
    ref = filterpy_filter(p["init"], p["zs"], None, None, p["H"], p["R"], masks, Fs=Fs, Qs=Qs)
    compare_to_reference(assert_close, res, ref, 1e-9)
    sm = rts(res, Fs, Qs, time_varying=("F", "Q"))
    kf = filterpy.kalman.KalmanFilter(dim_x=4, dim_z=2)
    ref_means, ref_covs, _, _ = kf.rts_smoother(np.asarray(res.means), np.asarray(res.covs),
                                                Fs=Fs, Qs=Qs)
    assert_close(sm.means, ref_means, 1e-9, "smoothed means")
    assert_close(sm.covs, ref_covs, 1e-9, "smoothed covs")


# ---------------------------------------------------------------------------------------------
# Against the joint Gaussian over x_0..x_T, z_1..z_T


def joint_gaussian(init, F, Q, H, R, T):
    """Mean and covariance of [x_1..x_T, z_1..z_T] as a linear map of independent noises."""
    n, m = F.shape[0], H.shape[0]
    dim = n + T * n + T * m  # x_0, w_1..w_T, v_1..v_T
    mean_e = np.concatenate([init[0], np.zeros(T * (n + m))])
    cov_e = np.zeros((dim, dim))
    cov_e[:n, :n] = init[1]
    for t in range(T):
        w, v = n + t * n, n + T * n + t * m
        cov_e[w:w + n, w:w + n] = Q
        cov_e[v:v + m, v:v + m] = R
    x_maps, z_maps = [], []
    x_map = np.zeros((n, dim))
    x_map[:, :n] = np.eye(n)
    for t in range(T):
        x_map = F @ x_map
        x_map[:, n + t * n:n + (t + 1) * n] += np.eye(n)
        z_map = H @ x_map
        z_map[:, n + T * n + t * m:n + T * n + (t + 1) * m] += np.eye(m)
        x_maps.append(x_map.copy())
        z_maps.append(z_map)
    A = np.concatenate(x_maps + z_maps, 0)
    return A @ mean_e, A @ cov_e @ A.T


def condition(mean, cov, target, observed, values):
    """Moments of y[target] given y[observed] = values, and log N(values) of the marginal."""
    if len(observed) == 0:
        return mean[target], cov[np.ix_(target, target)], 0.0
    s_oo = cov[np.ix_(observed, observed)]
    s_to = cov[np.ix_(target, observed)]
    gain = np.linalg.solve(s_oo, s_to.T).T
    post_mean = mean[target] + gain @ (values - mean[observed])
    post_cov = cov[np.ix_(target, target)] - gain @ s_to.T
    ll = multivariate_normal(mean[observed], s_oo).logpdf(values)
    return post_mean, post_cov, ll


def test_filter_and_smoother_match_joint_gaussian_posterior(component_masked, assert_close):
    p, masks, res = component_masked
    n, m, T = 5, 3, 12  # the first 12 steps (filtering is causal), including the masked ones
    sm = rts(res, p["F"], p["Q"])
    mean, cov = joint_gaussian(p["init"], p["F"], p["Q"], p["H"], p["R"], T_RANDOM)
    z_index = (T_RANDOM * n + np.arange(T_RANDOM * m)).reshape(T_RANDOM, m)
    z_flat = p["zs"].reshape(-1)
    observed_all = z_index[masks]
    all_states = np.arange(T_RANDOM * n)
    s_means, s_covs, _ = condition(mean, cov, all_states, observed_all,
                                   z_flat[observed_all - T_RANDOM * n])
    for t in list(range(T)) + [T_RANDOM - 1]:
        x_index = np.arange(t * n, (t + 1) * n)
        observed = z_index[:t + 1][masks[:t + 1]]
        f_mean, f_cov, ll = condition(mean, cov, x_index, observed,
                                      z_flat[observed - T_RANDOM * n])
        assert_close(res.means[t], f_mean, 1e-9, "filtered means")
        assert_close(res.covs[t], f_cov, 1e-9, "filtered covs")
        # log p(z_{1:t}) of the marginal is the running sum of the per-step log-likelihoods
        assert_close(np.sum(res.log_likelihoods[:t + 1]), ll, 1e-9, "log p(z_1:t)")
        assert_close(sm.means[t], s_means[x_index], 1e-9, "smoothed means")
        assert_close(sm.covs[t], s_covs[np.ix_(x_index, x_index)], 1e-9, "smoothed covs")


# ---------------------------------------------------------------------------------------------
# Step functions


def test_update_with_mask_false_returns_state_unchanged_and_zero_log_likelihood():
    rng = np.random.default_rng(11)
    prior = Gaussian(rng.standard_normal(4), _spd(rng, 4, 1.0))
    H, R = rng.standard_normal((2, 4)), _spd(rng, 2, 0.3)
    z = rng.standard_normal(2)
    jitted = jax.jit(kalman.update)
    update = lambda *args: jax.device_get(jitted(*args))  # noqa: E731
    cases = [(z, np.array(False)), (z, np.array([False, False])),
             (np.array([np.nan, np.inf]), np.array(True))]  # flagged present, nothing finite
    for z_, mask in cases:
        post, ll = update(prior, z_, H, R, mask)
        np.testing.assert_array_equal(post.mean, prior.mean)
        np.testing.assert_array_equal(post.cov, prior.cov)
        assert float(ll) == 0.0
    # a present measurement does change the state (so the checks above can fail)
    post, ll = update(prior, z, H, R, np.array(True))
    assert np.max(np.abs(post.mean - prior.mean)) > 1e-3
    assert float(ll) != 0.0


def test_step_functions_run_per_track_inside_jit_and_vmap():
    """`predict` / `update` mapped over K tracks under jit (as `association.nn_update` and the
    tracker call them) equal the eager calls; inside the trace, values are not checked."""
    rng = np.random.default_rng(12)
    K = 5
    F, Q = (np.asarray(a) for a in motion.constant_velocity(0.1, 0.5))
    H, R = np.eye(2, 4), _spd(rng, 2, 0.1)
    means, covs = rng.standard_normal((K, 4)), np.stack([_spd(rng, 4, 1.0) for _ in range(K)])
    zs, present = rng.standard_normal((K, 2)), np.array([True, False, True, True, False])

    def step(m, P, z, mask):
        return kalman.update(kalman.predict(Gaussian(m, P), F, Q), z, H, R, mask)

    (post, ll) = jax.device_get(jax.jit(jax.vmap(step))(means, covs, zs, present))
    for k in range(K):
        ref, ref_ll = step(means[k], covs[k], zs[k], present[k])
        np.testing.assert_allclose(post.mean[k], ref.mean, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(post.cov[k], ref.cov, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(ll[k], ref_ll, rtol=1e-12)
    assert np.all(ll[~present] == 0) and np.all(ll[present] != 0)
    bad = means.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="state.mean contains NaN"):
        step(bad[0], covs[0], zs[0], True)
    out = jax.device_get(jax.jit(jax.vmap(step))(bad, covs, zs, present))[0]
    assert np.isnan(out.mean[0]).any() and np.isfinite(out.mean[1:]).all()


# ---------------------------------------------------------------------------------------------
# The constant-velocity benchmark: NaN handling, gradients, vmap, float32


@pytest.fixture(scope="module")
def cv_loss(kf_filter_jit, cv_matrices_fn, cv_problem):
    """Jitted (log-likelihood, d/d(log q, log r)) of the CV benchmark; masks [T]."""
    init = Gaussian(cv_problem["init_mean"], cv_problem["init_cov"])

    def loss(log_q, log_r, zs, masks):
        F, Q, H, R = cv_matrices_fn(log_q, log_r)
        return kf_filter_jit(init, zs, F, Q, H, R, masks).log_likelihood

    return jax.jit(loss), jax.jit(jax.value_and_grad(loss, argnums=(0, 1)))


def _cv_args(cv_problem):
    p = cv_problem
    return Gaussian(p["init_mean"], p["init_cov"]), p["zs"], p["F"], p["Q"], p["H"], p["R"]


def test_nan_in_masked_measurement_is_ignored(kf_filter, cv_problem, cv_loss, assert_close):
    init, zs, F, Q, H, R = _cv_args(cv_problem)
    masks = np.ones(len(zs), bool)
    masks[[7, 30]] = False
    with_nan, placeholder = zs.copy(), zs.copy()
    with_nan[[7, 30]] = np.nan
    placeholder[[7, 30]] = 0.0
    a = kf_filter(init, with_nan, F, Q, H, R, masks)
    b = kf_filter(init, placeholder, F, Q, H, R, masks)
    for name in ("means", "covs", "log_likelihoods"):
        assert_close(getattr(a, name), getattr(b, name), 1e-12, name)
    assert int(a.num_invalid) == 0
    # the gradient does not see the NaN either (NaN padding must not break tuning)
    _, value_and_grad = cv_loss
    log_q, log_r = np.log(0.3), np.log(0.1)
    ga = jax.device_get(value_and_grad(log_q, log_r, with_nan, masks))
    gb = jax.device_get(value_and_grad(log_q, log_r, placeholder, masks))
    assert_close(np.array(ga[1]), np.array(gb[1]), 1e-12, "gradient")


def test_nan_in_unmasked_measurement_is_missing_and_counted(kf_filter, component_masked,
                                                            assert_close):
    p, masks, ref = component_masked
    # every component flagged present, but the masked ones are NaN / inf in the data
    with_nan = np.where(masks, p["zs"], np.nan)
    with_nan[~masks & (np.arange(T_RANDOM)[:, None] % 2 == 0)] = np.inf
    res = kf_filter(Gaussian(*p["init"]), with_nan, p["F"], p["Q"], p["H"], p["R"],
                    np.ones_like(masks))
    assert int(res.num_invalid) == np.sum(~masks)
    assert int(ref.num_invalid) == 0
    for name in ("means", "covs", "log_likelihoods"):
        assert_close(getattr(res, name), getattr(ref, name), 1e-12, name)
    assert float(res.log_likelihoods[5]) == 0.0


def test_log_likelihood_gradient_matches_finite_differences(cv_problem, cv_loss, assert_close):
    loss, value_and_grad = cv_loss
    zs, masks = cv_problem["zs"], np.ones(len(cv_problem["zs"]), bool)
    theta = np.array([np.log(0.2), np.log(0.15)])  # away from the truth: gradient not ~0
    _, grad = value_and_grad(theta[0], theta[1], zs, masks)
    h = 1e-5
    fd = [(float(loss(*(theta + h * e), zs, masks)) - float(loss(*(theta - h * e), zs, masks)))
          / (2 * h) for e in np.eye(2)]
    assert np.linalg.norm(fd) > 1.0
    assert_close(np.array(grad), np.array(fd), 1e-6, "gradient vs central differences")


def test_vmap_over_episodes_equals_python_loop(kf_filter, kf_filter_jit, cv_problem,
                                               assert_close):
    init, _, F, Q, H, R = _cv_args(cv_problem)
    batch = cv_problem["batch_zs"]
    masks = np.ones(batch.shape[1], bool)
    batched = jax.device_get(
        jax.jit(jax.vmap(lambda zs: kf_filter_jit(init, zs, F, Q, H, R, masks)))(batch))
    for i, zs in enumerate(batch):
        single = kf_filter(init, zs, F, Q, H, R, masks)
        for name in ("means", "covs", "log_likelihoods"):
            assert_close(getattr(batched, name)[i], getattr(single, name), 1e-12,
                         f"{name}[{i}]")


def test_float32_matches_float64(kf_filter, cv_problem, assert_close):
    init, zs, F, Q, H, R = _cv_args(cv_problem)
    masks = np.ones(len(zs), bool)
    f32 = lambda a: np.asarray(a, np.float32)  # noqa: E731
    res32 = kf_filter(Gaussian(f32(init.mean), f32(init.cov)), f32(zs), f32(F), f32(Q), f32(H),
                      f32(R), masks)
    res64 = kf_filter(init, zs, F, Q, H, R, masks)
    assert res32.means.dtype == jnp.float32 and res32.covs.dtype == jnp.float32
    for name in ("means", "covs", "log_likelihoods"):
        assert_close(getattr(res32, name), getattr(res64, name), 1e-4, name)


# ---------------------------------------------------------------------------------------------
# Long run on a badly scaled model


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_long_badly_scaled_run_keeps_covariances_symmetric_positive_definite(
        kf_filter, badly_scaled_problem, assert_spd_sequence, dtype):
    init, zs, F, Q, H, R = jax.tree.map(lambda a: np.asarray(a, dtype), badly_scaled_problem)
    res = kf_filter(Gaussian(*init), zs, F, Q, H, R)
    assert res.covs.dtype == dtype and res.covs.shape == (10_000, 4, 4)
    assert_spd_sequence(res.covs)
    assert np.all(np.isfinite(np.asarray(res.log_likelihoods)))


# ---------------------------------------------------------------------------------------------
# Errors at the public boundary


def _bad_input_cases():
    rng = np.random.default_rng(12)
    s4 = Gaussian(np.zeros(4), np.eye(4))
    F, Q = np.eye(4), 0.1 * np.eye(4)
    H, R = np.eye(2, 4), np.eye(2)
    zs = np.zeros((10, 2))
    non_sym = np.array([[1.0, 0.5], [0.0, 1.0]])
    non_psd = np.array([[1.0, 2.0], [2.0, 1.0]])
    return [
        ("z vs H", lambda: kalman.update(s4, np.zeros(3), H, R), ValueError,
         r"H must have shape \[3, 4\]"),
        ("zs vs H", lambda: kalman.filter(s4, np.zeros((10, 3)), F, Q, H, R), ValueError,
         r"H must have shape \[3, 4\]"),
        ("F vs state", lambda: kalman.predict(s4, np.eye(3), Q), ValueError,
         r"F must have shape \[4, 4\]"),
        ("F vs init", lambda: kalman.filter(s4, zs, np.eye(5), Q, H, R), ValueError,
         r"F must have shape \[4, 4\]"),
        ("Q non-square", lambda: kalman.predict(s4, F, np.zeros((4, 3))), ValueError,
         r"Q must be \[4, 4\]"),
        ("cov non-square", lambda: kalman.predict(Gaussian(np.zeros(4), np.eye(4, 3)), F, Q),
         ValueError, r"state.cov must be \[4, 4\]"),
        ("R non-symmetric", lambda: kalman.update(s4, np.zeros(2), H, non_sym), ValueError,
         "R is not symmetric"),
        ("R not PSD", lambda: kalman.update(s4, np.zeros(2), H, non_psd), ValueError,
         "R is not positive semi-definite"),
        ("R not PSD in filter", lambda: kalman.filter(s4, zs, F, Q, H, non_psd), ValueError,
         "R is not positive semi-definite"),
        ("time-varying Q not PSD at one step",
         lambda: kalman.filter(s4, zs, F, np.stack([Q] * 9 + [-Q]), H, R,
                               time_varying=("Q",)),
         ValueError, "Q is not positive semi-definite"),
        ("unknown time_varying", lambda: kalman.filter(s4, zs, F, Q, H, R, time_varying=("G",)),
         ValueError, r"unknown time_varying \['G'\]"),
        ("time_varying as a bare unknown string",
         lambda: kalman.rts_smoother(kalman.SmootherResult(np.zeros((10, 4)),
                                                           np.stack([np.eye(4)] * 10)),
                                     F, Q, time_varying="H"),
         ValueError, "unknown time_varying"),
        ("time-varying F without time axis",
         lambda: kalman.filter(s4, zs, F, Q, H, R, time_varying=("F",)), ValueError,
         r"F must have shape \[10, 4, 4\]"),
        ("masks vs zs", lambda: kalman.filter(s4, zs, F, Q, H, R, np.ones(9, bool)), ValueError,
         r"masks must have shape \[10\]"),
        ("B without u", lambda: kalman.predict(s4, F, Q, B=np.ones((4, 1))), ValueError,
         "B and u must be given together"),
        ("state not a Gaussian", lambda: kalman.predict((np.zeros(4), np.eye(4)), F, Q),
         TypeError, "must be a kalman.Gaussian"),
        ("NaN in state mean",
         lambda: kalman.predict(Gaussian(np.full(4, np.nan), np.eye(4)), F, Q), ValueError,
         "state.mean contains NaN"),
        ("NaN in R", lambda: kalman.update(s4, np.zeros(2), H, np.full((2, 2), np.nan)),
         ValueError, "R contains NaN"),
        ("zs not 2-D", lambda: kalman.filter(s4, rng.standard_normal(10), F, Q, H, R),
         ValueError, r"zs must be a \[T, m\] sequence"),
    ]


@pytest.mark.parametrize("call,error,match", [c[1:] for c in _bad_input_cases()],
                         ids=[c[0] for c in _bad_input_cases()])
def test_bad_input_raises_clear_error(call, error, match):
    with pytest.raises(error, match=match):
        call()


def test_return_predicted_false_drops_only_the_predictions():
    F, Q = motion.constant_velocity(0.1, 0.5)
    H, R = measurement.position(4), 0.1 * np.eye(2)
    zs = np.random.default_rng(3).normal(size=(12, 2))
    init = Gaussian(np.zeros(4), np.eye(4))
    full = kalman.filter(init, zs, F, Q, H, R)
    lean = kalman.filter(init, zs, F, Q, H, R, return_predicted=False)
    assert lean.predicted_means is None and lean.predicted_covs is None
    np.testing.assert_array_equal(lean.means, full.means)
    np.testing.assert_array_equal(lean.covs, full.covs)
    np.testing.assert_array_equal(lean.log_likelihood, full.log_likelihood)


def test_zero_length_sequence_filters_and_smooths_to_empty_results():
    init = Gaussian(jnp.zeros(4), jnp.eye(4))
    F, Q, H, R = jnp.eye(4), 0.1 * jnp.eye(4), jnp.eye(2, 4), jnp.eye(2)
    res = kalman.filter(init, jnp.zeros((0, 2)), F, Q, H, R)
    assert res.means.shape == (0, 4) and float(res.log_likelihood) == 0.0
    sm = kalman.rts_smoother(res, F, Q)
    assert sm.means.shape == (0, 4) and sm.covs.shape == (0, 4, 4)


# ---------------------------------------------------------------------------------------------
# Dtype policy and value checks at the boundary of the drivers

_DTYPE_PROBLEM = dict(F=np.eye(4) + np.eye(4, k=2) * 0.1, Q=0.01 * np.eye(4), H=np.eye(2, 4),
                      R=0.1 * np.eye(2), zs=np.arange(10.0).reshape(5, 2) / 10)


@pytest.mark.parametrize("driver", ["kf", "ekf", "ukf"])
@pytest.mark.parametrize("state_dtype, matrix_dtype, expected", [
    (np.int64, np.float64, np.float64), (np.float32, np.float64, np.float64),
    (np.float32, np.float32, np.float32), (np.int32, np.float32, np.float32)])
def test_inputs_are_promoted_to_one_floating_dtype(driver, state_dtype, matrix_dtype, expected):
    from jaxtrack.filters import ekf, ukf

    p = {k: v.astype(matrix_dtype) for k, v in _DTYPE_PROBLEM.items()}
    init = Gaussian(np.zeros(4, state_dtype), np.eye(4, dtype=state_dtype))
    F, H = p["F"], p["H"]
    if driver == "kf":
        res = kalman.filter(init, p["zs"], F, p["Q"], H, p["R"])
    else:
        mod = ekf if driver == "ekf" else ukf
        res = mod.filter(init, p["zs"], lambda x: F @ x, p["Q"], lambda x: H @ x, p["R"])
    assert res.means.dtype == expected and res.covs.dtype == expected
    ref = kalman.filter(Gaussian(np.zeros(4), np.eye(4)),
                        *(_DTYPE_PROBLEM[k] for k in ("zs", "F", "Q", "H", "R")))
    tol = 1e-5 if expected == np.float32 else 1e-9
    np.testing.assert_allclose(res.means, ref.means, atol=tol)
    assert int(res.num_not_pd) == 0


@pytest.mark.parametrize("dtype", [np.float16, "bfloat16"])
def test_half_precision_is_refused_naming_the_argument(dtype):
    init = Gaussian(jnp.zeros(4, dtype), jnp.eye(4, dtype=dtype))
    p = _DTYPE_PROBLEM
    with pytest.raises(TypeError, match="init.mean has dtype .*half precision"):
        kalman.filter(init, p["zs"], p["F"], p["Q"], p["H"], p["R"])


@pytest.mark.parametrize("name", ["F", "H", "B", "us"])
def test_nan_in_a_model_array_is_refused(name):
    p = dict(_DTYPE_PROBLEM, B=np.ones((4, 1)), us=np.ones((5, 1)))
    p[name] = p[name].copy()
    p[name].flat[0] = np.nan
    with pytest.raises(ValueError, match=f"{name} contains NaN"):
        kalman.filter(Gaussian(np.zeros(4), np.eye(4)), p["zs"], p["F"], p["Q"], p["H"], p["R"],
                      B=p["B"], us=p["us"])


def test_singular_measurement_noise_and_negative_smoother_noise_are_refused():
    p = _DTYPE_PROBLEM
    with pytest.raises(ValueError, match="R must be positive definite"):
        kalman.filter(Gaussian(np.zeros(4), np.zeros((4, 4))), p["zs"], p["F"],
                      np.zeros((4, 4)), p["H"], np.zeros((2, 2)))
    res = kalman.filter(Gaussian(np.zeros(4), np.eye(4)), p["zs"], p["F"], p["Q"], p["H"], p["R"])
    with pytest.raises(ValueError, match="Q is not positive semi-definite"):
        kalman.rts_smoother(res, p["F"], -p["Q"])
