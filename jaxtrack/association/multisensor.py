r"""One scan of several sensors: sequential per-sensor JPDA / NN-JPDA updates.

Seed 003 fuses ceiling cameras (0.1 m), RGB-D cameras (0.3 m) and a laser leg detector
(0.2 m) in one KF + NN-JPDA tracker. When sensors overlap, one person yields up to one detection
*per sensor* in the same scan, which breaks the JPDA assumption "each track at most one
detection": a single JPDA over all detections would treat the extra detections of a person as
clutter or as other people. The standard remedy (sequential multi-sensor JPDA, Pao and Frei,
IEEE ACC 1995; also what the ROS ``bayes_people_tracker`` used in seed 003 does, one detector
callback at a time) is to associate and update **sensor by sensor** within the scan: for
sensor s = 0, ..., S - 1, compute the gate, the JPDA marginals over that sensor's detections
(each sensor sees each track at most once) with the current state, and update; the next sensor
starts from that posterior. The loop is a `lax.scan` over the S sensors with the detection mask
``meas_mask & (sensor == s)``, so shapes stay fixed and the whole scan jits and vmaps.

Within one sensor, `pda_update` handles any noise; across sensors the update order matters only
through the (approximate) per-sensor association, not through the Kalman algebra.

Gate convention (Bar-Shalom, Daum and Huang 2009, eq. 38; Stone Soup's PDAHypothesiser): with a
gate of probability :math:`P_G`, missed-detection weight :math:`1 - P_D P_G` and detection
weight :math:`P_D g / \lambda` for gated pairs. This is the JPDA model of `jpda_marginals`
with the detection-in-gate probability :math:`P_D P_G` and the gate-truncated density
:math:`g / P_G`, which is how it is evaluated here.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxtrack import _checks
from jaxtrack.association import detections as _detections
from jaxtrack.association import gating, jpda, pda
from jaxtrack.filters import _gaussian
from jaxtrack.filters.kalman import Gaussian

Array = jax.Array

__all__ = ["SensorScanResult", "sequential_jpda_update"]


class SensorScanResult(NamedTuple):
    """Output of `sequential_jpda_update`.

    Attributes:
      posterior: Gaussian with mean [K, n], cov [K, n, n] after all sensors.
      beta: [S, K, M + 1] JPDA marginals of each sensor's pass (columns of other sensors' and of
        masked detections are 0; column M is "no detection from this sensor").
      col_for_row: [S, K] int32 NN-JPDA choice of each pass (-1 none), filled for
        ``hard=True`` and all -1 otherwise.
      approximate: [S, K] bools, marginals that came from LBP (see `JPDAInfo`).
    """

    posterior: Gaussian
    beta: Array
    col_for_row: Array
    approximate: Array


def sequential_jpda_update(states: Gaussian, zs: Array, H: Array, R: Array, sensor: Array, *,
                           p_detect: Array | float, clutter_density: Array | float,
                           gate_prob: float = 0.99, meas_mask: Array | None = None,
                           track_mask: Array | None = None, hard: bool = False,
                           method: str = "exact", max_cluster_tracks: int = 8,
                           pair_mask: Array | None = None) -> SensorScanResult:
    r"""JPDA (``hard=False``) or NN-JPDA (``hard=True``) update with the detections of S sensors.

    For each sensor in turn (module docstring): :math:`d^2`, log-likelihoods with that sensor's
    :math:`R_s`, the chi-square gate of probability ``gate_prob``, `jpda_marginals` over that
    sensor's detections, then `pda_update` (combined innovation, JPDA) or `nn_jpda` +
    `nn_update` (the MAP detection and a standard Kalman update, seed 003 eq. 9).

    Args:
      states: predicted tracks, Gaussian with mean [K, n] and cov [K, n, n].
      zs: [M, m] detections of all sensors in the scan.
      H: [m, n] measurement matrix (shared).
      R: [S, m, m] measurement noise of each sensor.
      sensor: [M] int sensor index of each detection.
      p_detect: scalar or [S] detection probability of each sensor.
      clutter_density: scalar or [S] clutter intensity of each sensor (per unit measurement
        volume, > 0).
      gate_prob: gate probability :math:`P_G` in (0, 1]; 1 disables gating.
      meas_mask: optional [M] bools, present detections.
      track_mask: optional [K] bools; masked tracks are returned unchanged.
      hard: NN-JPDA instead of JPDA.
      method: ``"exact"`` or ``"lbp"`` (see `jpda_marginals`).
      max_cluster_tracks: exact-evaluation cap per cluster (see `jpda_marginals`).
      pair_mask: optional [K, M] bools; a False pair is outside the gate in every pass (e.g.
        `jaxtrack.tracking.tracker`'s ``tentative_outside_confirmed``).

    Returns:
      A `SensorScanResult`.

    Example:
      >>> R = jnp.stack([0.1**2 * jnp.eye(2), 0.3**2 * jnp.eye(2), 0.2**2 * jnp.eye(2)])
      >>> out = sequential_jpda_update(pred, zs, H, R, sensor, p_detect=0.9,
      ...                              clutter_density=0.05, meas_mask=mask, hard=True)
      >>> out.posterior.mean.shape    # [K, n]
    """
    K, n = _gaussian.check_states(states)
    M, m = _detections.check_frame(zs, H, n, meas_mask)
    if np.ndim(R) != 3:
        raise ValueError(f"R must be [S, m, m], one covariance per sensor; got shape "
                         f"{_checks.shape_of(R)}")
    S = _checks.shape_of(R)[0]
    _detections.check_noise(R, sensor, M, m)
    for name, value in (("p_detect", p_detect), ("clutter_density", clutter_density)):
        if np.ndim(value) != 0:
            _checks.check_shape(name, value, (S,), "a scalar or one value per sensor")
    if track_mask is not None:
        _checks.check_shape("track_mask", track_mask, (K,), "one flag per track")
    if pair_mask is not None:
        _checks.check_shape("pair_mask", pair_mask, (K, M), "one flag per track and detection")
    _checks.check_probability("gate_prob", gate_prob)
    if _checks.is_concrete(gate_prob) and float(gate_prob) <= 0:
        raise ValueError(f"gate_prob must be in (0, 1]; got {gate_prob!r}")
    if method not in jpda.METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {jpda.METHODS}")
    for name, value, ok in (("p_detect", p_detect, lambda a: (a >= 0) & (a <= 1)),
                            ("clutter_density", clutter_density,
                             lambda a: np.isfinite(a) & (a > 0))):
        if _checks.is_concrete(value) and not np.all(ok(np.asarray(value, np.float64))):
            raise ValueError(f"{name} has invalid values: {value!r}")
    return _sequential(states, zs, H, R, sensor, p_detect, clutter_density, gate_prob,
                       meas_mask, track_mask, hard, method, max_cluster_tracks, pair_mask)


@functools.partial(jax.jit, static_argnames=("hard", "method", "max_cluster_tracks"))
def _sequential(states, zs, H, R, sensor, p_detect, clutter_density, gate_prob, meas_mask,
                track_mask, hard, method, max_cluster_tracks, pair_mask=None):
    K = states.mean.shape[0]
    M, m = zs.shape
    S = R.shape[0]
    dtype = jnp.result_type(states.mean, states.cov, zs, H, R)
    zs, H, R = jnp.asarray(zs, dtype), jnp.asarray(H, dtype), jnp.asarray(R, dtype)
    sensor = jnp.asarray(sensor)
    present = jnp.ones(M, bool) if meas_mask is None else jnp.asarray(meas_mask, bool)
    pd_s = jnp.broadcast_to(jnp.asarray(p_detect, dtype), (S,))
    lam_s = jnp.broadcast_to(jnp.asarray(clutter_density, dtype), (S,))
    p_gate = jnp.asarray(gate_prob, dtype)
    threshold = gating.chi2_ppf(p_gate, m)

    def one_sensor(state, s):
        mask_s = present & (sensor == s)
        inn = gating.innovations(state.mean, state.cov, zs, H, R, sensor=sensor,
                                 track_mask=track_mask, meas_mask=mask_s)
        gated = inn.valid & (inn.d2 <= threshold)
        if pair_mask is not None:
            gated = gated & jnp.asarray(pair_mask, bool)
        log_g = jnp.where(gated, inn.log_likelihood - jnp.log(p_gate), -jnp.inf)
        beta, info = jpda.jpda_marginals(log_g, pd_s[s] * p_gate, lam_s[s], track_mask, mask_s,
                                         method, log=True, max_cluster_tracks=max_cluster_tracks,
                                         lbp_tol=1e-9, lbp_max_iter=200, return_info=True)
        if hard:
            col = jpda.nn_jpda(beta)
            post, _ = pda.nn_update(state, zs, col, H, R, sensor=sensor, track_mask=track_mask)
        else:
            col = jnp.full((K,), -1, jnp.int32)
            post = pda.jpda_update(state, zs, beta, H, R, sensor=sensor, meas_mask=mask_s,
                                   track_mask=track_mask)
        return post, (beta, col, info.approximate)

    states = Gaussian(jnp.asarray(states.mean, dtype), jnp.asarray(states.cov, dtype))
    post, (beta, col, approx) = lax.scan(one_sensor, states, jnp.arange(S))
    return SensorScanResult(post, beta, col, approx)
