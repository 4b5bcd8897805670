r"""Gating: innovation statistics of every track-detection pair and the chi-square gate.

For a predicted track :math:`k` (mean :math:`m_k`, covariance :math:`P_k`) and a detection
:math:`z_j` from a sensor with noise :math:`R_j`,

.. math::
    y_{kj} = z_j - H m_k,\quad S_{kj} = H P_k H^T + R_j,\quad
    d^2_{kj} = y_{kj}^T S_{kj}^{-1} y_{kj},\quad
    \log g_{kj} = \log N(y_{kj}; 0, S_{kj}).

Under the model, :math:`d^2_{kj}` of the true detection is :math:`\chi^2_m`-distributed, so the
gate :math:`d^2_{kj} \le \chi^2_m{}^{-1}(P_G)` keeps the true detection with probability
:math:`P_G` (seed 001 section IV; Bar-Shalom, Daum and Huang, IEEE CSM 2009, section III).

Masked or non-finite detections and masked tracks give :math:`d^2 = +\infty` and
:math:`\log g = -\infty`: they are never gated in, and their NaN never reaches a gradient.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.scipy import special

from jaxtrack import _checks
from jaxtrack.association import detections as _detections
from jaxtrack.filters import _linalg
from jaxtrack.metrics import errors as _metric_errors

Array = jax.Array

__all__ = ["Innovations", "innovations", "mahalanobis", "chi2_ppf", "gate"]


class Innovations(NamedTuple):
    """Innovation statistics of every track-detection pair.

    Attributes:
      d2: [K, M] squared Mahalanobis distances (+inf for masked / non-finite pairs).
      log_likelihood: [K, M] :math:`\\log N(z_j; H m_k, S_{kj})` (-inf where ``d2`` is inf).
      valid: [K, M] bools, the pairs with a present track and a present, finite detection.
    """

    d2: Array
    log_likelihood: Array
    valid: Array


def innovations(means: Array, covs: Array, zs: Array, H: Array, R: Array, *,
                sensor: Array | None = None, track_mask: Array | None = None,
                meas_mask: Array | None = None) -> Innovations:
    r"""Squared Mahalanobis distances and Gaussian log-likelihoods of all pairs, [K, M].

    .. math:: S_{kj} = H P_k H^T + R_{s(j)},\quad d^2_{kj} = y_{kj}^T S_{kj}^{-1} y_{kj}.

    With several sensors, each detection uses its own sensor's noise ``R[sensor[j]]``.

    Args:
      means: [K, n] predicted track means.
      covs: [K, n, n] predicted track covariances.
      zs: [M, m] detections (rows under a False ``meas_mask`` may hold NaN).
      H: [m, n] measurement matrix (shared by all sensors).
      R: [m, m] measurement noise, or [S, m, m] one per sensor (then ``sensor`` is required).
      sensor: [M] int sensor index of every detection.
      track_mask: [K] bools, present tracks (default all).
      meas_mask: [M] bools, present detections (default all; non-finite rows are dropped).

    Returns:
      `Innovations` (d2, log_likelihood, valid), each [K, M].

    Example:
      >>> inn = innovations(means, covs, zs, H, 0.2**2 * jnp.eye(2))
      >>> gated = gate(inn.d2, 2, 0.99)
    """
    K, n, M, m = _check_tracks_and_detections(means, covs, zs, H, track_mask, meas_mask)
    _detections.check_noise(R, sensor, M, m)
    return _innovations(means, covs, zs, H, R, sensor, track_mask, meas_mask)


def mahalanobis(means: Array, covs: Array, zs: Array, H: Array, R: Array, *,
                sensor: Array | None = None, track_mask: Array | None = None,
                meas_mask: Array | None = None) -> Array:
    r"""Squared Mahalanobis distances :math:`d^2_{kj} = y_{kj}^T S_{kj}^{-1} y_{kj}`, [K, M].

    The ``d2`` field of `innovations` (same arguments); +inf for masked or non-finite pairs.

    Example:
      >>> d2 = mahalanobis(means, covs, zs, H, R)          # [K, M]
      >>> d2_multi = mahalanobis(means, covs, zs, H, R_per_sensor, sensor=sensor)
    """
    return innovations(means, covs, zs, H, R, sensor=sensor, track_mask=track_mask,
                       meas_mask=meas_mask).d2


def chi2_ppf(prob: Array | float, dim: int) -> Array:
    r"""Quantile of the chi-square distribution with ``dim`` degrees of freedom.

    The gate's view of `jaxtrack.metrics.chi2_ppf` (which solves :math:`P(\mathrm{dim}/2, x/2)
    = p` with the upper tail used above the median, so gates like 0.9999 keep full precision),
    with closed forms for ``dim`` 1 (:math:`2\,\mathrm{erf}^{-1}(p)^2`) and 2
    (:math:`-2 \log(1 - p)`), and the edge values a gate needs: ``p = 0`` gives 0 and ``p = 1``
    gives +inf. Matches `scipy.stats.chi2.ppf` to 1e-11 relative in float64 for p in
    [1e-6, 1 - 1e-9] and to 1e-5 in float32; jit/vmap-able in ``prob``; ``dim`` is static.

    Args:
      prob: scalar or array of probabilities in (0, 1); 0 gives 0 and 1 gives +inf.
      dim: degrees of freedom, a positive Python int (the measurement dimension).

    Returns:
      The quantile, same shape as ``prob``.

    Example:
      >>> chi2_ppf(0.99, 2)   # 9.2103...
    """
    dim = _check_dim(dim)
    p = jnp.asarray(prob)
    if not jnp.issubdtype(p.dtype, jnp.floating):
        p = p.astype(jnp.result_type(float))
    return _chi2_ppf(p, dim)


def gate(d2: Array, dim: int, prob: Array | float, track_mask: Array | None = None,
         meas_mask: Array | None = None) -> Array:
    r"""Chi-square gate :math:`d^2_{kj} \le \chi^2_{\mathrm{dim}}{}^{-1}(P_G)`, [K, M] bools.

    Args:
      d2: [K, M] squared Mahalanobis distances (e.g. from `mahalanobis`); NaN is gated out.
      dim: the measurement dimension m (degrees of freedom).
      prob: gate probability :math:`P_G`, the probability that the gate holds the true
        detection (e.g. 0.99).
      track_mask: optional [K] bools; masked tracks gate nothing.
      meas_mask: optional [M] bools; masked detections are gated out.

    Returns:
      [K, M] bools, True where the pair is inside the gate.

    Example:
      >>> gated = gate(mahalanobis(means, covs, zs, H, R), 2, 0.99, meas_mask=mask)
    """
    _checks.check_ndim("d2", d2, 2, "a [K, M] matrix of squared distances")
    K, M = _checks.shape_of(d2)
    if track_mask is not None:
        _checks.check_shape("track_mask", track_mask, (K,))
    if meas_mask is not None:
        _checks.check_shape("meas_mask", meas_mask, (M,))
    _checks.check_probability("prob", prob)
    d2 = jnp.asarray(d2)
    inside = d2 <= chi2_ppf(jnp.asarray(prob, d2.dtype if jnp.issubdtype(d2.dtype, jnp.floating)
                                        else jnp.result_type(float)), dim)
    return inside & _pair_mask(track_mask, meas_mask, K, M)


# ---------------------------------------------------------------------------------------------
# Internals


@jax.jit
def _innovations(means, covs, zs, H, R, sensor, track_mask, meas_mask) -> Innovations:
    K, M = means.shape[0], zs.shape[0]
    dtype = jnp.result_type(means, covs, zs, H, R)
    means, covs, zs = (jnp.asarray(a, dtype) for a in (means, covs, zs))
    H, R = jnp.asarray(H, dtype), jnp.asarray(R, dtype)
    track_ok = jnp.ones(K, bool) if track_mask is None else jnp.asarray(track_mask, bool)
    track_ok = track_ok & jnp.all(jnp.isfinite(means), -1) \
        & jnp.all(jnp.isfinite(covs), (-2, -1))
    meas_ok = jnp.all(jnp.isfinite(zs), -1)
    if meas_mask is not None:
        meas_ok = meas_ok & jnp.asarray(meas_mask, bool)
    n = means.shape[-1]
    # Sanitise before any arithmetic so that masked NaN never reaches values or gradients.
    means = jnp.where(track_ok[:, None], means, 0.0)
    covs = jnp.where(track_ok[:, None, None], covs, jnp.eye(n, dtype=dtype))
    zs = jnp.where(meas_ok[:, None], zs, 0.0)
    HPHt = H @ covs @ H.T                                            # [K, m, m]
    y = zs[None, :, :] - (means @ H.T)[:, None, :]                   # [K, M, m]
    if jnp.ndim(R) == 2:
        low = _linalg.cholesky(_linalg.symmetrize(HPHt + R))[:, None]  # [K, 1, m, m]
    else:
        Rj = _detections.noise_per_detection(R, sensor, M)            # [M, m, m]
        low = _linalg.cholesky(_linalg.symmetrize(HPHt[:, None] + Rj[None]))  # [K, M, m, m]
    ll, w = _linalg.gaussian_log_density(low, y)
    d2 = jnp.sum(w * w, -1)
    valid = track_ok[:, None] & meas_ok[None, :] & jnp.isfinite(d2)
    return Innovations(jnp.where(valid, d2, jnp.inf), jnp.where(valid, ll, -jnp.inf), valid)


def _pair_mask(track_mask, meas_mask, K, M):
    rows = jnp.ones(K, bool) if track_mask is None else jnp.asarray(track_mask, bool)
    cols = jnp.ones(M, bool) if meas_mask is None else jnp.asarray(meas_mask, bool)
    return rows[:, None] & cols[None, :]


@functools.partial(jax.jit, static_argnums=1)
def _chi2_ppf(p, dim):
    if dim == 1:
        # P(1/2, x/2) = erf(sqrt(x/2)); the upper-tail form keeps precision when p is near 1
        x = jnp.where(p > 0.5, special.ndtri(0.5 * (1.0 - p)) ** 2,
                      2.0 * lax.erf_inv(jnp.minimum(p, 0.5)) ** 2)
    elif dim == 2:
        x = -2.0 * jnp.log1p(-p)
    else:
        interior = jnp.clip(p, jnp.finfo(p.dtype).tiny, 1.0 - jnp.finfo(p.dtype).epsneg)
        x = _metric_errors.chi2_ppf(interior, jnp.asarray(dim, p.dtype))
    x = jnp.where(p <= 0, 0.0, jnp.where(p >= 1, jnp.inf, x))
    return jnp.where(jnp.isnan(p) | (p < 0) | (p > 1), jnp.nan, x)


def _check_dim(dim) -> int:
    if isinstance(dim, bool) or not isinstance(dim, (int, np.integer)) or dim < 1:
        raise ValueError(f"dim must be a positive Python int (degrees of freedom); got {dim!r}")
    return int(dim)


def _check_tracks_and_detections(means, covs, zs, H, track_mask, meas_mask):
    _checks.check_ndim("means", means, 2, "[K, n] predicted track means")
    K, n = _checks.shape_of(means)
    _checks.check_shape("covs", covs, (K, n, n), "predicted track covariances")
    _checks.check_covariance("covs", covs, n, batch_axes=1)
    _checks.check_ndim("zs", zs, 2, "[M, m] detections")
    M, m = _checks.shape_of(zs)
    _checks.check_shape("H", H, (m, n), "measurement matrix")
    if track_mask is not None:
        _checks.check_shape("track_mask", track_mask, (K,), "one flag per track")
    if meas_mask is not None:
        _checks.check_shape("meas_mask", meas_mask, (M,), "one flag per detection slot")
    return K, n, M, m
