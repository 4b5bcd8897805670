r"""Measurement updates after association: PDA / JPDA combined innovation and NN (hard) update.

PDA / JPDA (Bar-Shalom, Daum and Huang, IEEE CSM 2009, eqs. 11-18; seed 003 eq. 8). Given the
association probabilities :math:`\beta_j` of a track's detections and :math:`\beta_0` of "no
detection", the posterior is the moment-matched Gaussian of the mixture
:math:`\beta_0 N(m, P) + \sum_j \beta_j N(m_j, P_j)`, where :math:`(m_j, P_j)` is the Kalman
update (Joseph form, `jaxtrack.filters.kalman`) with detection :math:`j`:

.. math::
    m^+ = m + \sum_j \beta_j K_j \nu_j,\qquad
    P^+ = \beta_0 P + \sum_j \beta_j P_j
          + \beta_0 (m - m^+)(m - m^+)^T + \sum_j \beta_j (m_j - m^+)(m_j - m^+)^T.

When every detection has the same noise :math:`R` (one gain :math:`K`), this is exactly the
classical combined-innovation update :math:`m^+ = m + K \nu`, :math:`\nu = \sum_j \beta_j
\nu_j`, :math:`P^+ = \beta_0 P + (1 - \beta_0) P^c + K (\sum_j \beta_j \nu_j \nu_j^T - \nu
\nu^T) K^T`, with the last term the spread of the innovations. With several sensors
(heterogeneous :math:`R_s`, seed 003: 0.1 / 0.3 / 0.2 m) each detection keeps its sensor's
:math:`S_s = H P H^T + R_s` and gain :math:`K_s` in one fused step; this is the same mixture
reduction, not a sequential per-sensor approximation, so the result does not depend on the order
of the sensors. Since :math:`S`, :math:`K` and the component covariances depend on the sensor
only, a track costs one gain and one Joseph update per sensor plus innovation-weighted sums over
its detections, not a Kalman update per detection.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import _checks
from jaxtrack.association import detections as _detections
from jaxtrack.filters import _gaussian, _linalg, kalman
from jaxtrack.filters.kalman import Gaussian

Array = jax.Array

__all__ = ["pda_update", "jpda_update", "nn_update"]


def pda_update(state: Gaussian, zs: Array, beta_row: Array, H: Array, R: Array, *,
               sensor: Array | None = None, meas_mask: Array | None = None) -> Gaussian:
    r"""PDA / JPDA update of one track with all its detections (module docstring).

    Args:
      state: predicted Gaussian, mean [n], cov [n, n].
      zs: [M, m] detections (NaN allowed under a False ``meas_mask``).
      beta_row: [M + 1] association probabilities; the last entry is "no detection"
        (a row of `jpda_marginals`). Weights of masked or non-finite detections are dropped
        and the rest renormalised.
      H: [m, n] measurement matrix.
      R: [m, m], or [S, m, m] with ``sensor`` [M] (one noise covariance per sensor).
      sensor: [M] int sensor index of each detection.
      meas_mask: optional [M] bools, present detections.

    Returns:
      The posterior Gaussian (covariance symmetric, positive semi-definite by construction).

    Example:
      >>> beta = jpda_marginals(g, 0.9, 1e-2)                 # [K, M + 1]
      >>> post = pda_update(Gaussian(means[0], covs[0]), zs, beta[0], H, R)
    """
    n = _gaussian.check_state(state)
    M, m = _detections.check_frame(zs, H, n, meas_mask)
    _checks.check_shape("beta_row", beta_row, (M + 1,), "M + 1 probabilities")
    _detections.check_noise(R, sensor, M, m)
    return _pda_update(state, zs, beta_row, H, R, sensor, meas_mask)


def jpda_update(states: Gaussian, zs: Array, beta: Array, H: Array, R: Array, *,
                sensor: Array | None = None, meas_mask: Array | None = None,
                track_mask: Array | None = None) -> Gaussian:
    r"""`pda_update` of every track with its row of the JPDA marginals (the JPDA filter step).

    Args:
      states: Gaussian with mean [K, n] and cov [K, n, n] (predicted tracks).
      zs, H, R, sensor, meas_mask: as in `pda_update`.
      beta: [K, M + 1] marginals from `jpda_marginals`.
      track_mask: optional [K] bools; masked tracks are returned unchanged.

    Returns:
      Gaussian with mean [K, n], cov [K, n, n].

    Example:
      >>> beta = jpda_marginals(g, 0.9, 1e-2, meas_mask=mask)
      >>> posts = jpda_update(Gaussian(means, covs), zs, beta, H, R, meas_mask=mask)
    """
    K, n = _gaussian.check_states(states)
    M, m = _detections.check_frame(zs, H, n, meas_mask)
    _checks.check_shape("beta", beta, (K, M + 1), "[K, M + 1] marginals")
    _detections.check_noise(R, sensor, M, m)
    if track_mask is not None:
        _checks.check_shape("track_mask", track_mask, (K,), "one flag per track")
    return _jpda_update(states, zs, beta, H, R, sensor, meas_mask, track_mask)


def nn_update(states: Gaussian, zs: Array, col_for_row: Array, H: Array, R: Array, *,
              sensor: Array | None = None,
              track_mask: Array | None = None) -> tuple[Gaussian, Array]:
    r"""Standard Kalman update of each track with its one assigned detection (GNN / NN-JPDA).

    Seed 003 eqs. 2-4 after the NN-JPDA choice (`nn_jpda`), or after `gnn`: track k is
    updated by `jaxtrack.filters.kalman.update` (Joseph form) with ``zs[col_for_row[k]]`` and
    that detection's sensor noise; tracks with ``col_for_row[k] = -1`` keep their prediction.

    Args:
      states: Gaussian with mean [K, n], cov [K, n, n].
      zs: [M, m] detections.
      col_for_row: [K] int detection of each track, -1 for none.
      H: [m, n] measurement matrix.
      R: [m, m], or [S, m, m] with ``sensor`` [M].
      sensor: [M] int sensor index of each detection.
      track_mask: optional [K] bools; masked tracks are returned unchanged.

    Returns:
      ``(posteriors, log_likelihoods)``: Gaussian [K, n] / [K, n, n] and [K] log N(z; Hm, S)
      (0 for unassigned tracks).

    Example:
      >>> col = nn_jpda(jpda_marginals(g, 0.9, 1e-2))
      >>> posts, ll = nn_update(Gaussian(means, covs), zs, col, H, R)
    """
    K, n = _gaussian.check_states(states)
    M, m = _detections.check_frame(zs, H, n, None)
    _checks.check_shape("col_for_row", col_for_row, (K,), "one detection index per track")
    if not jnp.issubdtype(jnp.result_type(col_for_row), jnp.integer):
        raise ValueError("col_for_row must hold integers (-1 for no detection)")
    if _checks.is_concrete(col_for_row):
        c = np.asarray(col_for_row)
        if c.size and (c.min() < -1 or c.max() >= M):
            raise ValueError(f"col_for_row entries must lie in [-1, {M - 1}]")
    _detections.check_noise(R, sensor, M, m)
    if track_mask is not None:
        _checks.check_shape("track_mask", track_mask, (K,), "one flag per track")
    if M == 0:
        return states, jnp.zeros(K, jnp.result_type(states.mean))
    return _nn_update(states, zs, col_for_row, H, R, sensor, track_mask)


# ---------------------------------------------------------------------------------------------
# Internals


@jax.jit
def _pda_update(state, zs, beta_row, H, R, sensor, meas_mask):
    r"""Mixture reduction with one gain per sensor (module docstring).

    The component means are :math:`m_j = m + K_{s(j)} \nu_j` and the component covariances
    :math:`P_s` (Joseph form) depend only on the sensor, so the moments need S gains and
    Joseph updates per track plus [M, n] weighted sums, not M Kalman updates:
    :math:`P^+ = \beta_0 P + \sum_s B_s P_s + \sum_j \beta_j (d_j - \bar d)(d_j - \bar d)^T
    + \beta_0 \bar d \bar d^T` with :math:`d_j = K_{s(j)} \nu_j`, :math:`\bar d = \sum_j
    \beta_j d_j` and :math:`B_s` the weight of sensor s (every term positive semi-definite).
    """
    M = zs.shape[0]
    dtype = jnp.result_type(state.mean, state.cov, zs, H, R, beta_row)
    mean, cov = jnp.asarray(state.mean, dtype), jnp.asarray(state.cov, dtype)
    zs, H = jnp.asarray(zs, dtype), jnp.asarray(H, dtype)
    valid = jnp.all(jnp.isfinite(zs), -1)
    if meas_mask is not None:
        valid = valid & jnp.asarray(meas_mask, bool)
    beta_row = jnp.asarray(beta_row, dtype)
    w = jnp.where(valid, beta_row[:M], 0.0)
    w0 = beta_row[M]
    total = w0 + jnp.sum(w)
    empty = ~(total > 0)
    w = jnp.where(empty, 0.0, w / jnp.where(empty, 1.0, total))
    w0 = jnp.where(empty, 1.0, w0 / jnp.where(empty, 1.0, total))
    if M == 0:
        return Gaussian(mean, cov)
    R = jnp.asarray(R, dtype)
    Rs = R[None] if R.ndim == 2 else R                               # [S, m, m]
    num_sensors = Rs.shape[0]
    innovation = jnp.where(valid[:, None], zs - H @ mean, 0.0)        # masked NaN never enters
    PHt = cov @ H.T
    S = _linalg.symmetrize(H @ PHt + Rs)
    gain = jnp.swapaxes(_linalg.cho_solve(_linalg.cholesky(S), jnp.broadcast_to(
        PHt.T, S.shape[:1] + PHt.T.shape)), -1, -2)                    # [S, n, m]
    I_KH = jnp.eye(cov.shape[-1], dtype=dtype) - gain @ H
    cov_s = I_KH @ cov @ jnp.swapaxes(I_KH, -1, -2) + gain @ Rs @ jnp.swapaxes(gain, -1, -2)
    if num_sensors == 1:
        d = innovation @ gain[0].T                                    # [M, n]
        sensor_weight = jnp.sum(w)[None]
    else:
        onehot = (jnp.asarray(sensor)[:, None] == jnp.arange(num_sensors)).astype(dtype)
        d = jnp.einsum("js,snm,jm->jn", onehot, gain, innovation)
        sensor_weight = w @ onehot
    d_bar = w @ d
    dc = d - d_bar
    new_cov = (w0 * (cov + jnp.outer(d_bar, d_bar))
               + jnp.einsum("s,sab->ab", sensor_weight, cov_s)
               + jnp.einsum("j,ja,jb->ab", w, dc, dc))
    return Gaussian(mean + d_bar, _linalg.symmetrize(new_cov))


@jax.jit
def _jpda_update(states, zs, beta, H, R, sensor, meas_mask, track_mask):
    post = jax.vmap(lambda s, b: _pda_update(s, zs, b, H, R, sensor, meas_mask))(states, beta)
    return _keep_masked(states, post, track_mask)


@jax.jit
def _nn_update(states, zs, col_for_row, H, R, sensor, track_mask):
    M = zs.shape[0]
    dtype = jnp.result_type(states.mean, states.cov, zs, H, R)
    zs, H = jnp.asarray(zs, dtype), jnp.asarray(H, dtype)
    Rj = _detections.noise_per_detection(jnp.asarray(R, dtype), sensor, M)

    def one(state, col):
        j = jnp.clip(col, 0, M - 1)
        return kalman.update(state, zs[j], H, Rj[j], col >= 0)

    post, ll = jax.vmap(one)(states, jnp.asarray(col_for_row))
    if track_mask is not None:
        ll = jnp.where(jnp.asarray(track_mask, bool), ll, 0.0)
    return _keep_masked(states, post, track_mask), ll


def _keep_masked(states, post, track_mask):
    if track_mask is None:
        return post
    keep = jnp.asarray(track_mask, bool)
    return Gaussian(jnp.where(keep[:, None], post.mean, states.mean),
                    jnp.where(keep[:, None, None], post.cov, states.cov))
