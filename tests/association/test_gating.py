"""Tests for `jaxtrack.association.gating` and `detections` (chi-square gate, innovations).

References: `scipy.stats.chi2.ppf`, `scipy.stats.multivariate_normal.logpdf` and explicit
inverses in numpy. Tolerances: chi2 quantile 1e-11 relative in float64 (1e-5 in float32);
distances and log-likelihoods 1e-10 (float64), 1e-4 relative (float32).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import chi2, multivariate_normal

from jaxtrack import association, metrics
from jaxtrack.association import detections
from tests.association.references import random_spd

K, M, N_STATE, M_DIM = 4, 6, 4, 2
H = np.eye(2, 4)


def problem(seed, num_sensors=0):
    rng = np.random.default_rng(seed)
    means = rng.standard_normal((K, N_STATE))
    covs = np.stack([random_spd(rng, N_STATE, 0.5) for _ in range(K)])
    zs = means[rng.integers(0, K, M)] @ H.T + 0.7 * rng.standard_normal((M, M_DIM))
    if num_sensors:
        R = np.stack([random_spd(rng, M_DIM, s) for s in (0.01, 0.09, 0.04)[:num_sensors]])
        sensor = rng.integers(0, num_sensors, M)
        return means, covs, zs, R, sensor
    return means, covs, zs, random_spd(rng, M_DIM, 0.05), None


def reference_innovations(means, covs, zs, Rs):
    d2 = np.zeros((len(means), len(zs)))
    ll = np.zeros_like(d2)
    for k, (m, P) in enumerate(zip(means, covs)):
        for j, (z, R) in enumerate(zip(zs, Rs)):
            S = H @ P @ H.T + R
            y = z - H @ m
            d2[k, j] = y @ np.linalg.solve(S, y)
            ll[k, j] = multivariate_normal(H @ m, S).logpdf(z)
    return d2, ll


_innovations = jax.jit(association.innovations)


# ---------------------------------------------------------------------------------------------
# chi-square quantile


@pytest.mark.parametrize("dim", [1, 2, 3, 5])
def test_chi2_ppf_matches_scipy_over_the_whole_range(dim):
    p = np.concatenate([np.geomspace(1e-6, 0.5, 40), 1.0 - np.geomspace(1e-9, 0.5, 40)])
    ours = np.asarray(association.chi2_ppf(p, dim))
    ref = chi2.ppf(p, dim)
    assert np.max(np.abs(ours - ref) / ref) < 1e-11


@pytest.mark.parametrize("dim", [1, 3])
def test_chi2_ppf_float32_keeps_single_precision(dim):
    p = np.concatenate([np.geomspace(1e-5, 0.5, 20), 1.0 - np.geomspace(1e-5, 0.5, 20)])
    p32 = p.astype(np.float32)
    ours = association.chi2_ppf(jnp.asarray(p32), dim)
    assert ours.dtype == jnp.float32
    ref = chi2.ppf(p32.astype(np.float64), dim)
    assert np.max(np.abs(np.asarray(ours) - ref) / ref) < 1e-5


def test_chi2_ppf_edges_and_usual_gates():
    out = np.asarray(association.chi2_ppf(np.array([0.0, 1.0, 1.5, 0.95]), 3))
    assert out[0] == 0.0 and np.isinf(out[1]) and np.isnan(out[2])
    np.testing.assert_allclose(float(association.chi2_ppf(0.99, 2)), 9.2103403719761836,
                               rtol=1e-13)
    traced = jax.jit(association.chi2_ppf, static_argnums=1)(jnp.array([0.95]), 3)
    np.testing.assert_allclose(np.asarray(traced), chi2.ppf([0.95], 3), rtol=1e-12)


def test_chi2_ppf_above_two_dimensions_is_the_metrics_quantile():
    p = np.array([1e-6, 0.05, 0.5, 0.99, 0.9999])
    for dim in (3, 4, 6):
        np.testing.assert_allclose(np.asarray(association.chi2_ppf(p, dim)),
                                   np.asarray(metrics.chi2_ppf(p, float(dim))), rtol=1e-12)


def test_chi2_ppf_rejects_a_bad_dim():
    with pytest.raises(ValueError, match="dim"):
        association.chi2_ppf(0.9, 0)
    with pytest.raises(ValueError, match="dim"):
        association.chi2_ppf(0.9, 2.0)


# ---------------------------------------------------------------------------------------------
# Innovations and the gate


def test_innovations_match_explicit_inverse_and_scipy_logpdf():
    means, covs, zs, R, _ = problem(0)
    inn = _innovations(means, covs, zs, H, R)
    d2, ll = reference_innovations(means, covs, zs, [R] * M)
    np.testing.assert_allclose(np.asarray(inn.d2), d2, rtol=1e-10)
    np.testing.assert_allclose(np.asarray(inn.log_likelihood), ll, rtol=1e-10)
    assert np.all(np.asarray(inn.valid))
    np.testing.assert_allclose(np.asarray(association.mahalanobis(means, covs, zs, H, R)), d2,
                               rtol=1e-10)


def test_each_detection_uses_its_own_sensor_noise():
    means, covs, zs, R, sensor = problem(1, num_sensors=3)
    inn = _innovations(means, covs, zs, H, R, sensor=sensor)
    d2, ll = reference_innovations(means, covs, zs, R[sensor])
    np.testing.assert_allclose(np.asarray(inn.d2), d2, rtol=1e-10)
    np.testing.assert_allclose(np.asarray(inn.log_likelihood), ll, rtol=1e-10)


def test_masked_nan_detections_and_tracks_are_ignored_and_keep_gradients_finite():
    means, covs, zs, R, _ = problem(2)
    meas_mask = np.array([True, False, True, True, False, True])
    track_mask = np.array([True, True, False, True])
    bad_zs = zs.copy()
    bad_zs[~meas_mask] = np.nan
    bad_means = means.copy()
    bad_means[~track_mask] = np.nan
    inn = _innovations(bad_means, covs, bad_zs, H, R, track_mask=track_mask,
                       meas_mask=meas_mask)
    clean = _innovations(means, covs, zs, H, R)
    pair = track_mask[:, None] & meas_mask[None, :]
    np.testing.assert_array_equal(np.asarray(inn.valid), pair)
    np.testing.assert_allclose(np.asarray(inn.d2)[pair], np.asarray(clean.d2)[pair], rtol=1e-12)
    assert np.all(np.isinf(np.asarray(inn.d2)[~pair]))
    assert np.all(np.isneginf(np.asarray(inn.log_likelihood)[~pair]))

    def loss(m):
        out = association.innovations(m, covs, bad_zs, H, R, track_mask=track_mask,
                                      meas_mask=meas_mask)
        return jnp.sum(jnp.where(out.valid, out.log_likelihood, 0.0))

    grad = np.asarray(jax.grad(loss)(jnp.asarray(means)))
    assert np.all(np.isfinite(grad))


def test_non_finite_detection_under_a_true_mask_is_dropped():
    means, covs, zs, R, _ = problem(3)
    zs = zs.copy()
    zs[2] = [np.inf, 0.0]
    inn = _innovations(means, covs, zs, H, R)
    assert not np.any(np.asarray(inn.valid)[:, 2])
    assert np.all(np.isfinite(np.asarray(inn.d2)[:, [0, 1, 3, 4, 5]]))


def test_gate_matches_scipy_threshold_and_masks():
    means, covs, zs, R, _ = problem(4)
    d2 = np.asarray(association.mahalanobis(means, covs, zs, H, R))
    for prob in (0.5, 0.9, 0.99):
        np.testing.assert_array_equal(np.asarray(association.gate(d2, 2, prob)),
                                      d2 <= chi2.ppf(prob, 2))
    meas_mask = np.array([True, True, False, True, True, True])
    gated = np.asarray(association.gate(d2, 2, 0.999999, meas_mask=meas_mask))
    assert not gated[:, 2].any()
    d2_nan = d2.copy()
    d2_nan[0, 0] = np.nan
    assert not bool(association.gate(d2_nan, 2, 0.99)[0, 0])


def test_innovations_float32_and_vmap_equals_loop():
    batch = [problem(10 + i) for i in range(3)]
    means, covs, zs = (np.stack([b[i] for b in batch]) for i in range(3))
    R = batch[0][3]
    vm = jax.vmap(lambda m, c, z: association.innovations(m, c, z, H, R).d2)(means, covs, zs)
    loop = np.stack([np.asarray(_innovations(m, c, z, H, R).d2)
                     for m, c, z in zip(means, covs, zs)])
    np.testing.assert_allclose(np.asarray(vm), loop, rtol=1e-12)
    f32 = association.innovations(*(jnp.asarray(a, jnp.float32) for a in
                                    (means[0], covs[0], zs[0], H, R)))
    assert f32.d2.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(f32.d2), loop[0], rtol=1e-4)


def test_innovations_reject_bad_shapes_and_sensor_indices():
    means, covs, zs, R, _ = problem(5)
    with pytest.raises(ValueError, match="H must have shape"):
        association.innovations(means, covs, zs, np.eye(2, 3), R)
    with pytest.raises(ValueError, match="covs"):
        association.innovations(means, covs[:2], zs, H, R)
    with pytest.raises(ValueError, match="meas_mask"):
        association.innovations(means, covs, zs, H, R, meas_mask=np.ones(M + 1, bool))
    Rs = np.stack([R, 2 * R])
    with pytest.raises(ValueError, match="pass sensor"):
        association.innovations(means, covs, zs, H, Rs)
    with pytest.raises(ValueError, match=r"sensor indices must lie in \[0, 1\]"):
        association.innovations(means, covs, zs, H, Rs, sensor=np.full(M, 2))
    with pytest.raises(ValueError, match="sensor was given"):
        association.innovations(means, covs, zs, H, R, sensor=np.zeros(M, int))


# ---------------------------------------------------------------------------------------------
# Detection frames


def test_pad_detections_fills_the_capacity_and_masks_the_padding():
    zs, mask, sensor = association.pad_detections([[1.0, 2.0], [3.0, 4.0]], 4, sensor=[2, 0])
    assert zs.shape == (4, 2) and np.asarray(mask).tolist() == [True, True, False, False]
    assert np.all(np.isnan(np.asarray(zs)[2:]))
    assert np.asarray(sensor).tolist() == [2, 0, 0, 0]
    empty, empty_mask = association.pad_detections(np.zeros((0, 2)), 3)
    assert empty.shape == (3, 2) and not np.asarray(empty_mask).any()


def test_more_detections_than_capacity_is_a_clear_error():
    with pytest.raises(ValueError, match="3 detections do not fit in the capacity of 2"):
        association.pad_detections(np.zeros((3, 2)), 2)
    with pytest.raises(ValueError, match="sensor"):
        association.pad_detections(np.zeros((2, 2)), 4, sensor=[0])


def test_noise_per_detection_indexes_the_sensor_stack():
    R = np.stack([0.1**2 * np.eye(2), 0.3**2 * np.eye(2), 0.2**2 * np.eye(2)])
    out = np.asarray(detections.noise_per_detection(R, np.array([0, 2, 1, 2]), 4))
    np.testing.assert_array_equal(out, R[[0, 2, 1, 2]])
    shared = np.asarray(detections.noise_per_detection(R[0], None, 3))
    assert shared.shape == (3, 2, 2)
