"""Reference tests for `jaxtrack.filters.imm`.

References:
- filterpy 2.0.0's ``IMMEstimator`` over its ``KalmanFilter`` (Joseph-form updates): the same
  textbook IMM, with ``M[i, j]`` the probability of switching from mode i to mode j.
- Stone Soup 1.9.1. The released package has no IMM (``stonesoup.predictor.imm`` and
  ``stonesoup.updater.imm`` are not in it), so the reference is assembled from its released
  parts: ``KalmanPredictor`` / ``KalmanUpdater`` per mode on ``GaussianMixture`` states of
  ``WeightedGaussianState``, and ``gm_reduce_single`` for both the mixing (with weights
  mu_{i|j}) and the combined estimate; only c_j, mu_{i|j} and the mode-probability update are
  written out here. Its updater uses P - K S K^T (jaxtrack the Joseph form).
- `kalman.filter`, `ekf.filter`, `ukf.filter` for a single mode of probability 1; central finite
  differences for gradients.

Tolerances (float64): 1e-9 against filterpy and Stone Soup (measured at most 9e-15 absolute on
every output); 1e-12 for the single-mode reductions and masked vs NaN runs; 1e-6 for gradients
vs central differences; float32 vs float64 1e-4. Errors are scale-relative (``assert_close``).
"""

from datetime import datetime, timedelta

import filterpy.kalman
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import multivariate_normal
from stonesoup.functions import gm_reduce_single
from stonesoup.models.measurement.linear import LinearGaussian
from stonesoup.models.transition.linear import LinearGaussianTimeInvariantTransitionModel
from stonesoup.predictor.kalman import KalmanPredictor
from stonesoup.types.detection import Detection
from stonesoup.types.hypothesis import SingleHypothesis
from stonesoup.types.mixture import GaussianMixture
from stonesoup.types.state import GaussianState, StateVectors, WeightedGaussianState
from stonesoup.updater.kalman import KalmanUpdater

from jaxtrack.filters import ekf, imm, kalman, ukf
from jaxtrack.filters.kalman import Gaussian

from .conftest import _cv_numpy

DT = 0.1
T = 50
# Three modes on [p_x, p_y, v_x, v_y] with position measurements: constant velocity with low and
# high process noise, and near-constant position (the velocity is reset to zero every step).
_F_CV, _Q_LOW = _cv_numpy(DT, 0.05)
_, _Q_HIGH = _cv_numpy(DT, 5.0)
_F_CP = np.diag([1.0, 1.0, 0.0, 0.0])
_Q_CP = np.diag([0.02, 0.02, 1e-4, 1e-4])
_H = np.eye(2, 4)
_R = 0.05 * np.eye(2)
MODELS = imm.LinearModels(np.stack([_F_CV, _F_CV, _F_CP]), np.stack([_Q_LOW, _Q_HIGH, _Q_CP]),
                          np.stack([_H, _H, _H]), np.stack([_R, _R, 2.0 * _R]))
TRANSITION = np.array([[0.90, 0.05, 0.05], [0.10, 0.85, 0.05], [0.05, 0.15, 0.80]])
INIT_MEANS = np.array([[0.0, 0.0, 0.5, 0.1], [0.1, 0.1, 0.6, 0.2], [0.2, 0.2, 0.0, 0.0]])
INIT_COVS = np.stack([np.eye(4), 1.3 * np.eye(4), np.diag([1.6, 1.6, 0.1, 0.1])])
INIT_PROBS = np.array([0.5, 0.3, 0.2])


def simulate(seed, steps):
    """Measurements [steps, 2] of a target switching among the three modes (numpy)."""
    rng = np.random.default_rng(seed)
    x, mode, zs = np.array([0.0, 0.0, 1.0, 0.5]), 0, np.empty((steps, 2))
    for t in range(steps):
        mode = rng.choice(3, p=TRANSITION[mode])
        q = np.linalg.cholesky(MODELS.Q[mode])
        x = MODELS.F[mode] @ x + q @ rng.standard_normal(4)
        zs[t] = _H @ x + np.sqrt(MODELS.R[mode][0, 0]) * rng.standard_normal(2)
    return zs


ZS = simulate(5, T)
INIT = imm.init(INIT_MEANS, INIT_COVS, INIT_PROBS)

_filter = jax.jit(imm.filter)


def run(init, zs, models=MODELS, transition=TRANSITION, masks=None):
    return jax.device_get(_filter(init, zs, models, transition, masks))


@pytest.fixture(scope="module")
def result():
    return run(INIT, ZS)


def _as(dtype, tree):
    return jax.tree.map(lambda a: np.asarray(a, dtype), tree)


# ---------------------------------------------------------------------------------------------
# References


def filterpy_imm(zs):
    filters = []
    for i in range(3):
        kf = filterpy.kalman.KalmanFilter(dim_x=4, dim_z=2)
        kf.x, kf.P = INIT_MEANS[i].copy(), INIT_COVS[i].copy()
        kf.F, kf.Q, kf.H, kf.R = MODELS.F[i], MODELS.Q[i], MODELS.H[i], MODELS.R[i]
        filters.append(kf)
    estimator = filterpy.kalman.IMMEstimator(filters, INIT_PROBS, TRANSITION)
    out = {k: [] for k in ("means", "covs", "mode_means", "mode_covs", "mode_probs")}
    for z in zs:
        estimator.predict()
        estimator.update(z)
        for name, value in (("means", estimator.x), ("covs", estimator.P),
                            ("mode_means", [f.x for f in filters]),
                            ("mode_covs", [f.P for f in filters]),
                            ("mode_probs", estimator.mu)):
            out[name].append(np.array(value))
    return {k: np.array(v) for k, v in out.items()}


def stone_soup_imm(zs):
    t0 = datetime(2026, 1, 1)
    predictors = [KalmanPredictor(LinearGaussianTimeInvariantTransitionModel(
        transition_matrix=MODELS.F[i], covariance_matrix=MODELS.Q[i])) for i in range(3)]
    sensors = [LinearGaussian(ndim_state=4, mapping=(0, 1), noise_covar=MODELS.R[i])
               for i in range(3)]
    updaters = [KalmanUpdater(sensor) for sensor in sensors]
    state = GaussianMixture([WeightedGaussianState(INIT_MEANS[i][:, None], INIT_COVS[i],
                                                   weight=INIT_PROBS[i], timestamp=t0)
                             for i in range(3)])
    out = {k: [] for k in ("means", "covs", "mode_means", "mode_covs", "mode_probs",
                           "log_likelihoods")}
    for t, z in enumerate(zs):
        time = t0 + timedelta(seconds=DT * (t + 1))
        mu = np.array([float(c.weight) for c in state])
        c = TRANSITION.T @ mu
        mixing = TRANSITION * mu[:, None] / c[None, :]  # mu_{i|j}
        means = StateVectors([comp.state_vector for comp in state])
        covs = np.stack([comp.covar for comp in state], axis=2)
        posteriors, likelihoods = [], []
        for j in range(3):
            mean, cov = gm_reduce_single(means, covs, mixing[:, j])
            prior = GaussianState(mean, cov, timestamp=state[0].timestamp)
            pred = predictors[j].predict(prior, timestamp=time)
            z_pred = updaters[j].predict_measurement(pred)
            detection = Detection(z[:, None], timestamp=time, measurement_model=sensors[j])
            posteriors.append(updaters[j].update(SingleHypothesis(pred, detection, z_pred)))
            likelihoods.append(multivariate_normal.pdf(z, np.ravel(z_pred.state_vector),
                                                       z_pred.covar))
        joint = c * np.array(likelihoods)
        mu = joint / np.sum(joint)
        state = GaussianMixture([WeightedGaussianState(p.state_vector, p.covar, weight=mu[j],
                                                       timestamp=time)
                                 for j, p in enumerate(posteriors)])
        mean, cov = gm_reduce_single(StateVectors([p.state_vector for p in posteriors]),
                                     np.stack([p.covar for p in posteriors], axis=2), mu)
        for name, value in (("means", np.ravel(mean)), ("covs", cov),
                            ("mode_means", [np.ravel(p.state_vector) for p in posteriors]),
                            ("mode_covs", [p.covar for p in posteriors]), ("mode_probs", mu),
                            ("log_likelihoods", np.log(np.sum(joint)))):
            out[name].append(np.array(value, np.float64))
    return {k: np.array(v) for k, v in out.items()}


@pytest.mark.parametrize("reference", [filterpy_imm, stone_soup_imm],
                         ids=["filterpy", "stonesoup"])
def test_filter_matches_reference_imm(result, reference, assert_close):
    ref = reference(ZS)
    for name, value in ref.items():
        actual = np.asarray(getattr(result, name))
        assert_close(actual, value, 1e-9, name)
        assert np.max(np.abs(actual - value)) <= 1e-9, name
    # the modes disagree, so mixing matters: every mode is likely at some step
    assert np.all(np.max(result.mode_probs, axis=0) > 0.3)
    assert int(result.num_not_pd) == 0 and int(result.num_invalid) == 0


def test_step_functions_compose_to_the_filter(result, assert_close):
    step = jax.jit(lambda s, z: imm.update(imm.predict(imm.mix(s, TRANSITION), MODELS), z,
                                           MODELS))
    state = INIT
    for t in range(3):
        state, ll = step(state, ZS[t])
        est = jax.device_get(imm.estimate(state))
        assert_close(state.means, result.mode_means[t], 1e-12, "mode means")
        assert_close(state.covs, result.mode_covs[t], 1e-12, "mode covs")
        assert_close(state.log_mode_probs, result.log_mode_probs[t], 1e-12, "log mode probs")
        assert_close(ll, result.log_likelihoods[t], 1e-12, "log-likelihood")
        assert_close(est.mean, result.means[t], 1e-12, "combined mean")
        assert_close(est.cov, result.covs[t], 1e-12, "combined cov")


def test_float32_matches_float64(result, assert_close):
    res32 = run(_as(np.float32, INIT), ZS.astype(np.float32), _as(np.float32, MODELS),
                TRANSITION.astype(np.float32))
    assert res32.means.dtype == np.float32 and res32.mode_covs.dtype == np.float32
    for name in ("means", "covs", "mode_means", "mode_covs", "mode_probs", "log_likelihoods"):
        assert_close(np.asarray(getattr(res32, name)), np.asarray(getattr(result, name)), 1e-4,
                     name)


# ---------------------------------------------------------------------------------------------
# Nonlinear modes: one mode of probability 1 under the identity transition is that mode's filter

_DRAG = 0.3


def drag(x):
    """Constant velocity with quadratic drag (nonlinear in the velocity)."""
    v = x[2:] * (1.0 - _DRAG * DT * jnp.linalg.norm(x[2:]))
    return jnp.concatenate([x[:2] + DT * v, v])


def position(x):
    return x[:2]


NONLINEAR_MODES = (imm.ExtendedMode(drag, _Q_LOW, position, _R),
                   imm.UnscentedMode(drag, _Q_HIGH, position, _R),
                   imm.LinearMode(_F_CV, _Q_LOW, _H, _R))


def test_single_certain_mode_reduces_to_its_own_filter(kf_filter, assert_close):
    run_modes = jax.jit(lambda init, zs, transition: imm.filter(init, zs, NONLINEAR_MODES,
                                                                transition))
    prior = Gaussian(INIT_MEANS[0], INIT_COVS[0])
    references = [
        jax.jit(lambda i, zs: ekf.filter(i, zs, drag, _Q_LOW, position, _R)),
        jax.jit(lambda i, zs: ukf.filter(i, zs, drag, _Q_HIGH, position, _R)),
        lambda i, zs: kf_filter(i, zs, _F_CV, _Q_LOW, _H, _R)]
    for k, reference in enumerate(references):
        certain = imm.init(np.stack([INIT_MEANS[0]] * 3), np.stack([INIT_COVS[0]] * 3),
                           np.eye(3)[k])
        res = jax.device_get(run_modes(certain, ZS, np.eye(3)))
        ref = jax.device_get(reference(prior, ZS))
        assert_close(res.mode_means[:, k], ref.means, 1e-12, f"mode {k} means")
        assert_close(res.mode_covs[:, k], ref.covs, 1e-12, f"mode {k} covs")
        assert_close(res.means, ref.means, 1e-12, f"mode {k} combined means")
        assert_close(res.covs, ref.covs, 1e-12, f"mode {k} combined covs")
        assert_close(res.log_likelihoods, ref.log_likelihoods, 1e-12, f"mode {k} lls")
        np.testing.assert_array_equal(res.mode_probs, np.broadcast_to(np.eye(3)[k], (T, 3)))
    # the three filters differ, so each comparison above could fail
    assert not np.allclose(res.mode_means[:, 0], res.mode_means[:, 2], atol=1e-3)
    # mixed: every mode contributes
    mixed = jax.device_get(run_modes(INIT, ZS, TRANSITION))
    assert np.all(np.isfinite(mixed.covs)) and int(mixed.num_not_pd) == 0
    assert np.all(np.max(mixed.mode_probs, axis=0) > 0.05)
    np.testing.assert_allclose(np.sum(mixed.mode_probs, axis=1), 1.0, rtol=1e-12)


# ---------------------------------------------------------------------------------------------
# Long run


@pytest.mark.parametrize("dtype", [np.float64, np.float32], ids=["f64", "f32"])
def test_long_badly_scaled_run_keeps_every_mode_covariance_positive_definite(
        badly_scaled_problem, assert_spd_sequence, dtype):
    """10,000 steps of the badly scaled CV problem (state scales 1e4 apart, covariances over ~15
    orders of magnitude) with two modes, process noise q and 100 q."""
    init, zs, F, Q, H, R = badly_scaled_problem
    models = imm.LinearModels(np.stack([F, F]), np.stack([Q, 100.0 * Q]), np.stack([H, H]),
                              np.stack([R, R]))
    state = imm.IMMState(np.stack([init.mean] * 2), np.stack([init.cov] * 2),
                         np.log(np.array([0.5, 0.5])))
    transition = np.array([[0.95, 0.05], [0.05, 0.95]])
    res = run(_as(dtype, state), zs.astype(dtype), _as(dtype, models), transition.astype(dtype))
    assert res.mode_covs.dtype == dtype and res.mode_covs.shape == (10_000, 2, 4, 4)
    assert_spd_sequence(res.mode_covs.reshape(-1, 4, 4))
    assert_spd_sequence(res.covs)
    assert int(res.num_not_pd) == 0
    assert np.all(np.isfinite(res.log_likelihoods)) and np.all(np.isfinite(res.log_mode_probs))


# ---------------------------------------------------------------------------------------------
# Masks and NaN


def test_fully_masked_step_only_mixes_and_predicts(result, assert_close):
    masks = np.ones(T, bool)
    masks[[0, 20]] = False
    res = run(INIT, ZS, masks=masks)
    before = imm.IMMState(res.mode_means[19], res.mode_covs[19], res.log_mode_probs[19])
    mix_predict = jax.jit(lambda s: imm.predict(imm.mix(s, TRANSITION), MODELS))
    prior, first = (jax.device_get(mix_predict(s)) for s in (before, INIT))
    for t, expected in ((0, first), (20, prior)):
        assert_close(res.mode_means[t], expected.means, 1e-12, "mode means")
        assert_close(res.mode_covs[t], expected.covs, 1e-12, "mode covs")
        assert_close(res.log_mode_probs[t], expected.log_mode_probs, 1e-12, "mode probs = c")
        assert res.log_likelihoods[t] == 0.0
    # the step function: a masked update returns its input and log-likelihood 0
    update = jax.jit(lambda s, z, m: imm.update(s, z, MODELS, m))
    for mask in (False, np.array([False, False])):
        post, ll = jax.device_get(update(prior, ZS[20], mask))
        for a, b in zip(post, prior):
            np.testing.assert_array_equal(a, b)
        assert float(ll) == 0.0
    post, ll = jax.device_get(update(prior, ZS[20], True))
    assert not np.allclose(post.means, prior.means) and float(ll) != 0.0
    # the measurement would have moved the state and the mode probabilities
    assert not np.allclose(res.mode_means[0], result.mode_means[0])
    assert not np.allclose(res.mode_probs[0], result.mode_probs[0])


def test_nan_measurements_are_masked_and_counted(assert_close):
    with_nan, placeholder = ZS.copy(), ZS.copy()
    step_masks = np.ones(T, bool)
    component_masks = np.ones((T, 2), bool)
    with_nan[[4, 33]] = np.nan
    with_nan[20, 1] = np.inf
    placeholder[[4, 33]] = 0.0
    placeholder[20, 1] = 123.0
    component_masks[[4, 33]] = False
    component_masks[20, 1] = False
    step_masks[[4, 33]] = False
    res = run(INIT, with_nan)
    ref = run(INIT, placeholder, masks=component_masks)
    assert int(res.num_invalid) == 5 and int(ref.num_invalid) == 0
    for name in ("means", "covs", "mode_means", "mode_covs", "log_mode_probs",
                 "log_likelihoods"):
        assert_close(getattr(res, name), getattr(ref, name), 1e-12, name)
    assert res.log_likelihoods[4] == 0.0 and res.log_likelihoods[20] != 0.0
    # a scalar mask per step is the same as masking every component of that step
    placeholder[20, 1] = ZS[20, 1]
    by_step = run(INIT, placeholder, masks=step_masks)
    assert_close(by_step.mode_means[:20], res.mode_means[:20], 1e-12, "step mask")
    # and a flagged-missing NaN is not counted as invalid
    assert int(run(INIT, with_nan, masks=component_masks).num_invalid) == 0


# ---------------------------------------------------------------------------------------------
# Gradients


_Q_SHAPE, _R_SHAPE = MODELS.Q / np.array([0.05, 5.0, 1.0])[:, None, None], _R / 0.05


def _log_likelihood(logits, log_q, log_r, zs):
    Q = jnp.exp(log_q)[:, None, None] * _Q_SHAPE
    R = jnp.exp(log_r)[:, None, None] * _R_SHAPE
    models = imm.LinearModels(MODELS.F, Q, MODELS.H, R)
    return imm.filter(INIT, zs, models, imm.transition_from_logits(logits)).log_likelihood


def test_transition_from_logits_is_row_stochastic_and_inverts_log():
    P = np.asarray(imm.transition_from_logits(np.log(TRANSITION) + 3.0))
    np.testing.assert_allclose(P, TRANSITION, rtol=1e-14)
    P = np.asarray(imm.transition_from_logits(np.random.default_rng(0).normal(size=(3, 3))))
    np.testing.assert_allclose(np.sum(P, axis=1), 1.0, rtol=1e-14)
    assert np.all(P > 0)


def test_log_likelihood_gradient_matches_finite_differences(assert_close):
    theta = (np.log(TRANSITION) + np.array([[0.0, 0.5, -0.3], [0.2, 0.0, 0.1], [-0.4, 0.3, 0.0]]),
             np.log(np.array([0.2, 2.0, 0.5])), np.log(np.array([0.1, 0.1, 0.2])))
    loss = jax.jit(_log_likelihood)
    grads = jax.device_get(jax.jit(jax.grad(_log_likelihood, argnums=(0, 1, 2)))(*theta, ZS))
    flat = np.concatenate([np.ravel(g) for g in grads])
    assert np.all(np.isfinite(flat))
    h = 1e-5
    fd = []
    for k, arg in enumerate(theta):
        for idx in np.ndindex(arg.shape):
            step = [np.array(a, copy=True) for a in theta]
            step[k][idx] += h
            up = float(loss(*step, ZS))
            step[k][idx] -= 2 * h
            fd.append((up - float(loss(*step, ZS))) / (2 * h))
    fd = np.array(fd)
    assert np.min(np.abs(fd[9:])) > 1e-2  # every noise matters
    assert np.max(np.abs(fd[:9])) > 1e-1  # and so does the transition matrix
    assert_close(flat, fd, 1e-6, "gradient vs central differences")


def test_gradient_with_a_certain_mode_is_finite_and_that_of_its_kalman_filter(assert_close):
    """Modes of probability exactly 0 (log -inf) under the identity transition do not poison
    the gradient: it is the gradient of the one Kalman filter left."""
    certain = imm.init(INIT_MEANS, INIT_COVS, np.array([1.0, 0.0, 0.0]))

    def imm_loss(log_q):
        models = MODELS._replace(Q=MODELS.Q * jnp.exp(log_q))
        return imm.filter(certain, ZS, models, np.eye(3)).log_likelihood

    def kf_loss(log_q):
        prior = Gaussian(INIT_MEANS[0], INIT_COVS[0])
        return kalman.filter(prior, ZS, _F_CV, _Q_LOW * jnp.exp(log_q), _H, _R).log_likelihood

    grad = float(jax.jit(jax.grad(imm_loss))(0.3))
    ref = float(jax.jit(jax.grad(kf_loss))(0.3))
    assert np.isfinite(grad) and abs(ref) > 1.0
    assert_close(grad, ref, 1e-12, "gradient")


# ---------------------------------------------------------------------------------------------
# T = 0 and errors at the boundary


def test_empty_sequence_returns_empty_results_and_zero_log_likelihood():
    res = run(INIT, np.zeros((0, 2)))
    shapes = {"means": (0, 4), "covs": (0, 4, 4), "mode_means": (0, 3, 4),
              "mode_covs": (0, 3, 4, 4), "log_mode_probs": (0, 3), "log_likelihoods": (0,)}
    for name, shape in shapes.items():
        assert np.shape(getattr(res, name)) == shape, name
    assert float(res.log_likelihood) == 0.0
    assert int(res.num_invalid) == 0 and int(res.num_not_pd) == 0


def _bad_input_cases():
    rows = np.array([[0.9, 0.05, 0.0], [0.1, 0.85, 0.05], [0.05, 0.15, 0.8]])
    negative = np.array([[1.1, -0.1, 0.0], [0.1, 0.85, 0.05], [0.05, 0.15, 0.8]])
    two_modes = imm.LinearModels(*(a[:2] for a in MODELS))
    bad_init = INIT._replace(log_mode_probs=np.log(np.array([0.5, 0.3, 0.3])))
    return [
        ("rows do not sum to 1", lambda: imm.filter(INIT, ZS, MODELS, rows), ValueError,
         r"each row of transition must sum to 1"),
        ("negative transition", lambda: imm.filter(INIT, ZS, MODELS, negative), ValueError,
         "transition must be non-negative"),
        ("transition shape", lambda: imm.filter(INIT, ZS, MODELS, np.eye(2)), ValueError,
         r"transition must have shape \[3, 3\]"),
        ("transition NaN", lambda: imm.mix(INIT, np.full((3, 3), np.nan)), ValueError,
         "transition contains NaN"),
        ("negative mode_probs", lambda: imm.init(INIT_MEANS, INIT_COVS,
                                                 np.array([1.2, -0.1, -0.1])), ValueError,
         "mode_probs must be non-negative"),
        ("mode_probs sum", lambda: imm.init(INIT_MEANS, INIT_COVS, np.array([0.5, 0.3, 0.3])),
         ValueError, "mode_probs must sum to 1"),
        ("mode_probs shape", lambda: imm.init(INIT_MEANS, INIT_COVS, np.array([0.5, 0.5])),
         ValueError, r"mode_probs must have shape \[3\]"),
        ("log_mode_probs sum", lambda: imm.filter(bad_init, ZS, MODELS, TRANSITION), ValueError,
         "init.log_mode_probs must be log probabilities summing to 1"),
        ("number of modes", lambda: imm.filter(INIT, ZS, two_modes, TRANSITION), ValueError,
         "models has 2 modes but the state has M = 3"),
        ("stacked Q", lambda: imm.filter(INIT, ZS, MODELS._replace(Q=MODELS.Q[:2]), TRANSITION),
         ValueError, r"models.Q must have shape \[3, \?, \?\]"),
        ("H vs measurements", lambda: imm.filter(INIT, np.ones((5, 3)), MODELS, TRANSITION),
         ValueError, r"models\[0\].H must have shape \[3, 4\]"),
        ("covs shape", lambda: imm.init(INIT_MEANS, INIT_COVS[:2], INIT_PROBS), ValueError,
         r"init.covs must have shape \[3, 4, 4\]"),
        ("R not symmetric", lambda: imm.update(INIT, ZS[0], MODELS._replace(
            R=np.stack([np.array([[1.0, 0.5], [0.0, 1.0]])] * 3))), ValueError,
         r"models\[0\].R is not symmetric"),
        ("h output", lambda: imm.filter(INIT, ZS, (NONLINEAR_MODES[0]._replace(h=lambda x: x),)
                                        + NONLINEAR_MODES[1:], TRANSITION), ValueError,
         r"models\[0\].h\(x\) must have shape \[2\]"),
        ("models type", lambda: imm.predict(INIT, NONLINEAR_MODES[2]), TypeError,
         "models must be an imm.LinearModels or a sequence"),
        ("state type", lambda: imm.estimate(Gaussian(INIT_MEANS[0], INIT_COVS[0])), TypeError,
         "state must be an imm.IMMState"),
    ]


@pytest.mark.parametrize("call,error,match", [c[1:] for c in _bad_input_cases()],
                         ids=[c[0] for c in _bad_input_cases()])
def test_bad_input_raises_clear_error(call, error, match):
    with pytest.raises(error, match=match):
        call()
