"""Tests for `jaxtrack.association.pda` (PDA / JPDA combined update, NN update).

References: Bar-Shalom, Daum and Huang (2009) combined-innovation update with the spread term,
written plainly in numpy (`references.pda_reference`); moment matching of per-detection Kalman
posteriors for heterogeneous sensors (`references.mixture_reference`); `kalman.update`. Stone
Soup's PDAUpdater is compared in test_jpda.py. Tolerances: 1e-10 relative (float64), 1e-4
(float32 vs float64).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack import association
from jaxtrack.filters import kalman
from jaxtrack.filters.kalman import Gaussian
from tests.association.references import mixture_reference, pda_reference, random_spd

H = np.eye(2, 4)
SENSOR_R = np.stack([0.1**2 * np.eye(2), 0.3**2 * np.eye(2), 0.2**2 * np.eye(2)])  # seed 003
_pda = jax.jit(association.pda_update)
_kf_update = jax.jit(kalman.update)


def track_and_frame(seed, M=5):
    rng = np.random.default_rng(seed)
    mean = rng.standard_normal(4)
    cov = random_spd(rng, 4, 0.5)
    zs = H @ mean + 0.6 * rng.standard_normal((M, 2))
    beta = rng.dirichlet(np.ones(M + 1))
    return mean, cov, zs, beta, random_spd(rng, 2, 0.05)


def test_pda_update_equals_bar_shalom_combined_innovation():
    for seed in range(5):
        mean, cov, zs, beta, R = track_and_frame(seed)
        post = _pda(Gaussian(mean, cov), zs, beta, H, R)
        ref_mean, ref_cov = pda_reference(mean, cov, zs, beta, H, R)
        np.testing.assert_allclose(np.asarray(post.mean), ref_mean, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(np.asarray(post.cov), ref_cov, rtol=1e-10, atol=1e-12)
        cov_out = np.asarray(post.cov)
        np.testing.assert_array_equal(cov_out, cov_out.T)
        assert np.linalg.eigvalsh(cov_out).min() > 0


def test_heterogeneous_sensors_are_fused_by_mixture_reduction():
    mean, cov, zs, beta, _ = track_and_frame(10)
    sensor = np.array([0, 1, 2, 1, 0])
    post = _pda(Gaussian(mean, cov), zs, beta, H, SENSOR_R, sensor=sensor)
    ref_mean, ref_cov = mixture_reference(mean, cov, zs, beta, H, SENSOR_R[sensor])
    np.testing.assert_allclose(np.asarray(post.mean), ref_mean, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(np.asarray(post.cov), ref_cov, rtol=1e-10, atol=1e-12)
    # one sensor listed three times = the single-R update
    same = _pda(Gaussian(mean, cov), zs, beta, H, np.stack([SENSOR_R[2]] * 3), sensor=sensor)
    single = _pda(Gaussian(mean, cov), zs, beta, H, SENSOR_R[2])
    np.testing.assert_allclose(np.asarray(same.cov), np.asarray(single.cov), rtol=1e-12)


def test_one_detection_inside_the_gate_gives_the_kalman_update():
    mean, cov, zs, _, R = track_and_frame(11)
    prior = Gaussian(mean, cov)
    zs = zs.copy()
    zs[0] = H @ mean + 0.1
    zs[1:] = H @ mean + 50.0 + np.arange(4)[:, None]      # far outside the gate
    inn = association.innovations(mean[None], cov[None], zs, H, R)
    gated = np.asarray(association.gate(inn.d2, 2, 0.99))
    assert gated.tolist() == [[True, False, False, False, False]]
    g = np.where(gated, np.exp(np.asarray(inn.log_likelihood)), 0.0)
    beta = association.jpda_marginals(g, 1.0, 1e-12)
    post = _pda(prior, zs, beta[0], H, R)
    ref, _ = _kf_update(prior, zs[0], H, R)
    np.testing.assert_allclose(np.asarray(post.mean), np.asarray(ref.mean), rtol=1e-10)
    np.testing.assert_allclose(np.asarray(post.cov), np.asarray(ref.cov), rtol=1e-10)
    col = association.nn_jpda(beta)
    nn_post, _ = association.nn_update(Gaussian(mean[None], cov[None]), zs, col, H, R)
    np.testing.assert_allclose(np.asarray(nn_post.mean[0]), np.asarray(ref.mean), rtol=1e-12)


def test_masked_nan_detections_are_ignored():
    mean, cov, zs, beta, R = track_and_frame(12, M=5)
    mask = np.array([True, False, True, True, False])
    bad = zs.copy()
    bad[~mask] = np.nan
    beta_masked = np.where(np.append(mask, True), beta, 0.0)
    beta_masked /= beta_masked.sum()
    post = _pda(Gaussian(mean, cov), bad, beta, H, R, meas_mask=mask)   # weights dropped
    keep = np.append(mask, True)
    ref_mean, ref_cov = pda_reference(mean, cov, zs[mask], beta[keep] / beta[keep].sum(), H, R)
    np.testing.assert_allclose(np.asarray(post.mean), ref_mean, rtol=1e-10)
    np.testing.assert_allclose(np.asarray(post.cov), ref_cov, rtol=1e-10)
    grad = jax.grad(lambda m: jnp.sum(association.pda_update(
        Gaussian(m, cov), bad, beta_masked, H, R, meas_mask=mask).mean))(jnp.asarray(mean))
    assert np.all(np.isfinite(np.asarray(grad)))
    empty = _pda(Gaussian(mean, cov), zs, np.zeros(6), H, R)
    np.testing.assert_allclose(np.asarray(empty.mean), mean)
    no_detections = _pda(Gaussian(mean, cov), bad, beta, H, R, meas_mask=np.zeros(5, bool))
    np.testing.assert_array_equal(np.asarray(no_detections.mean), mean)
    np.testing.assert_allclose(np.asarray(no_detections.cov), cov, rtol=1e-15)


def test_jpda_update_is_vmapped_pda_and_keeps_masked_tracks():
    frames = [track_and_frame(20 + i) for i in range(3)]
    means = np.stack([f[0] for f in frames])
    covs = np.stack([f[1] for f in frames])
    zs, R = frames[0][2], frames[0][4]
    beta = np.stack([f[3] for f in frames])
    track_mask = np.array([True, False, True])
    posts = association.jpda_update(Gaussian(means, covs), zs, beta, H, R,
                                    track_mask=track_mask)
    for k in range(3):
        ref = _pda(Gaussian(means[k], covs[k]), zs, beta[k], H, R)
        want = ref.mean if track_mask[k] else means[k]
        np.testing.assert_allclose(np.asarray(posts.mean[k]), np.asarray(want), rtol=1e-12)


def test_nn_update_uses_the_assigned_detection_and_its_sensor():
    frames = [track_and_frame(30 + i) for i in range(3)]
    means = np.stack([f[0] for f in frames])
    covs = np.stack([f[1] for f in frames])
    zs = frames[0][2]
    sensor = np.array([2, 0, 1, 1, 0])
    col = np.array([3, -1, 0])
    posts, ll = association.nn_update(Gaussian(means, covs), zs, col, H, SENSOR_R,
                                      sensor=sensor)
    for k in range(3):
        if col[k] < 0:
            np.testing.assert_array_equal(np.asarray(posts.mean[k]), means[k])
            assert float(ll[k]) == 0.0
            continue
        ref, ref_ll = _kf_update(Gaussian(means[k], covs[k]), zs[col[k]], H,
                                 SENSOR_R[sensor[col[k]]])
        np.testing.assert_allclose(np.asarray(posts.mean[k]), np.asarray(ref.mean), rtol=1e-12)
        np.testing.assert_allclose(float(ll[k]), float(ref_ll), rtol=1e-12)


def test_float32_pda_update():
    mean, cov, zs, beta, R = track_and_frame(40)
    ref = _pda(Gaussian(mean, cov), zs, beta, H, R)
    f32 = [jnp.asarray(a, jnp.float32) for a in (mean, cov, zs, beta, H, R)]
    out = association.pda_update(Gaussian(f32[0], f32[1]), *f32[2:])
    assert out.mean.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(out.mean), np.asarray(ref.mean), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(np.asarray(out.cov), np.asarray(ref.cov), rtol=1e-4, atol=1e-5)


def test_bad_inputs_are_rejected():
    mean, cov, zs, beta, R = track_and_frame(41)
    with pytest.raises(ValueError, match="beta_row must have shape"):
        association.pda_update(Gaussian(mean, cov), zs, beta[:-1], H, R)
    with pytest.raises(TypeError, match="kalman.Gaussian"):
        association.pda_update((mean, cov), zs, beta, H, R)
    with pytest.raises(ValueError, match="col_for_row entries"):
        association.nn_update(Gaussian(mean[None], cov[None]), zs, np.array([7]), H, R)
    with pytest.raises(ValueError, match="beta must have shape"):
        association.jpda_update(Gaussian(mean[None], cov[None]), zs, beta[None, :-1], H, R)


def test_zero_tracks_and_an_empty_scan_are_defined():
    H, R = jnp.eye(2, 4), jnp.eye(2)
    none = Gaussian(jnp.zeros((0, 4)), jnp.zeros((0, 4, 4)))
    out = association.jpda_update(none, jnp.zeros((3, 2)), jnp.zeros((0, 4)), H, R)
    assert out.mean.shape == (0, 4) and out.cov.shape == (0, 4, 4)
    tracks = Gaussian(jnp.arange(12.0).reshape(3, 4), jnp.tile(jnp.eye(4), (3, 1, 1)))
    beta = association.jpda_marginals(jnp.zeros((3, 0)), 0.9, 0.5)
    same = association.jpda_update(tracks, jnp.zeros((0, 2)), beta, H, R)
    np.testing.assert_array_equal(same.mean, tracks.mean)
    np.testing.assert_array_equal(same.cov, tracks.cov)
