r"""Linear Kalman filter and Rauch-Tung-Striebel smoother.

Model (time-invariant unless named in ``time_varying``)

.. math::
    x_t = F x_{t-1} + B u_t + w_t, \quad w_t \sim N(0, Q), \qquad
    z_t = H x_t + v_t, \quad v_t \sim N(0, R).

Every function works on one episode with pure arrays; batch with `jax.vmap`. The step functions
(`predict`, `update`) are public so that closed loops (tracker + controller) and other modules
(`jaxtrack.association.nn_update`) can call them one step at a time, inside `jit` and `vmap`:
their checks read shapes always and values only of concrete arrays. `filter` is the `lax.scan`
driver, following filterpy's ``batch_filter`` convention: each step predicts, then updates with
``zs[t]``.

Missing data is a mask, never a branch: ``mask`` may be a scalar (whole measurement present or
not) or one flag per measurement component. Components that are not finite are treated as
missing, so NaN padding in recorded data cannot poison a batch (and `filter` counts them).

Dtypes: the ``filter`` drivers (here, in `ekf` and `ukf`) run in one floating dtype, the widest
among their floating inputs; integer inputs are promoted to it and half precision is refused
(`jaxtrack.filters._gaussian.working_dtype`). A float32 state with float64 matrices therefore
runs in float64. The model matrices are checked for NaN / inf when concrete.
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxtrack import _checks
from jaxtrack.filters import _gaussian, _linalg
from jaxtrack.filters._gaussian import Gaussian

Array = jax.Array

__all__ = ["Gaussian", "FilterResult", "SmootherResult", "predict", "update", "filter",
           "rts_smoother"]


class FilterResult(NamedTuple):
    """Output of the ``filter`` drivers.

    Attributes:
      means: [T, n] filtered means E[x_t | z_{1:t}].
      covs: [T, n, n] filtered covariances.
      predicted_means: [T, n] one-step predictions E[x_t | z_{1:t-1}] (None when the filter
        was called with ``return_predicted=False``).
      predicted_covs: [T, n, n] prediction covariances (likewise).
      log_likelihoods: [T] log p(z_t | z_{1:t-1}) (0 for a fully masked step).
      log_likelihood: scalar, the sum of ``log_likelihoods``.
      num_invalid: number of measurement components that were flagged present but were not
        finite, and were therefore treated as missing.
      num_not_pd: number of steps whose filtered covariance is not positive definite (its
        Cholesky factorisation fails): a loss of definiteness made visible, jit-safe. 0 in a
        healthy run.
    """

    means: Array
    covs: Array
    predicted_means: Array
    predicted_covs: Array
    log_likelihoods: Array
    log_likelihood: Array
    num_invalid: Array
    num_not_pd: Array | None = None


class SmootherResult(NamedTuple):
    """Smoothed moments: ``means`` [T, n], ``covs`` [T, n, n]."""

    means: Array
    covs: Array


# ---------------------------------------------------------------------------------------------
# Step functions


def predict(state: Gaussian, F: Array, Q: Array, B: Array | None = None,
            u: Array | None = None) -> Gaussian:
    r"""Kalman prediction :math:`m' = F m + B u`, :math:`P' = F P F^T + Q`.

    Args:
      state: Gaussian with mean [n], cov [n, n].
      F: [n, n] transition matrix.
      Q: [n, n] process-noise covariance.
      B: optional [n, k] control matrix (requires ``u``).
      u: optional [k] control input.

    Returns:
      The predicted Gaussian (covariance symmetrised).

    Example:
      >>> from jaxtrack.filters import kalman
      >>> from jaxtrack.models import motion
      >>> F, Q = motion.constant_velocity(dt=0.1, q=1.0)
      >>> prior = kalman.predict(kalman.Gaussian(jnp.zeros(4), jnp.eye(4)), F, Q)
    """
    n = _gaussian.check_state(state)
    _checks.check_shape("F", F, (n, n), "state transition")
    _checks.check_covariance("Q", Q, n)
    if (B is None) != (u is None):
        raise ValueError("B and u must be given together")
    if B is not None:
        _checks.check_ndim("B", B, 2, "a [n, k] control matrix")
        _checks.check_shape("B", B, (n, None))
        _checks.check_shape("u", u, (jnp.shape(B)[1],))
    return _predict(state, F, Q, B, u)


def update(state: Gaussian, z: Array, H: Array, R: Array,
           mask: Array | bool | None = None) -> tuple[Gaussian, Array]:
    r"""Kalman measurement update in Joseph form.

    .. math::
        y = z - H m,\; S = H P H^T + R,\; K = P H^T S^{-1},\;
        m^+ = m + K y,\; P^+ = (I - K H) P (I - K H)^T + K R K^T,

    with :math:`P^+` symmetrised; the log-likelihood is :math:`\log N(y; 0, S)`.

    Args:
      state: prior Gaussian, mean [n], cov [n, n].
      z: [m] measurement.
      H: [m, n] measurement matrix.
      R: [m, m] measurement-noise covariance.
      mask: None (present), a scalar bool, or [m] bools. Masked components carry no
        information; a fully masked update returns ``state`` unchanged and log-likelihood 0.
        Non-finite components of ``z`` are treated as masked.

    Returns:
      ``(posterior, log_likelihood)``; the log-likelihood covers the present components only.

    Example:
      >>> post, ll = kalman.update(prior, jnp.array([1.0, 2.0]), H, R)
    """
    n = _gaussian.check_state(state)
    m = _gaussian.check_measurement(z, mask)
    _checks.check_shape("H", H, (m, n), "measurement matrix")
    _checks.check_covariance("R", R, m)
    return _update(state, z, H, R, mask)


# ---------------------------------------------------------------------------------------------
# Drivers

_TIME_VARYING = ("F", "Q", "H", "R", "B")


def filter(init: Gaussian, zs: Array, F: Array, Q: Array, H: Array, R: Array,
           masks: Array | None = None, *, B: Array | None = None, us: Array | None = None,
           time_varying: Collection[str] = (), return_predicted: bool = True) -> FilterResult:
    r"""Kalman filter over a sequence under `lax.scan` (predict, then update, at every step).

    Args:
      init: Gaussian prior on the state *before* the first step: mean [n], cov [n, n].
      zs: [T, m] measurements.
      F, Q: [n, n] transition and process-noise covariance ([T, n, n] if time-varying).
      H: [m, n] measurement matrix ([T, m, n] if time-varying).
      R: [m, m] measurement-noise covariance ([T, m, m] if time-varying).
      masks: optional [T] or [T, m] bools; False marks missing measurements.
      B: optional [n, k] control matrix ([T, n, k] if time-varying), with ``us`` [T, k].
      time_varying: names among {"F", "Q", "H", "R", "B"} whose argument carries a leading
        time axis. Nothing is inferred from array rank.
      return_predicted: also return the one-step predictions (needed for NIS; skipping them
        saves about a fifth of the time of a batched run).

    Returns:
      A `FilterResult`.

    Example:
      >>> F, Q = motion.constant_velocity(dt=0.1, q=1.0)
      >>> H, R = measurement.position(4), 0.1 * jnp.eye(2)
      >>> res = kalman.filter(kalman.Gaussian(jnp.zeros(4), jnp.eye(4)), zs, F, Q, H, R)
      >>> res.means.shape, res.log_likelihood
    """
    tv = _checks.check_options("time_varying", time_varying, _TIME_VARYING)
    n = _gaussian.check_state(init, "init")
    T, m = _gaussian.check_sequence(zs, masks)
    dtype = _gaussian.working_dtype(**{"init.mean": init.mean, "init.cov": init.cov, "zs": zs,
                                       "F": F, "Q": Q, "H": H, "R": R, "B": B, "us": us})
    for name, x in (("F", F), ("H", H), ("B", B), ("us", us)):
        if x is not None:
            _checks.check_finite(name, x)
    init, zs = _gaussian.as_dtype(init, dtype), jnp.asarray(zs, dtype)
    F, Q, H, R = (jnp.asarray(x, dtype) for x in (F, Q, H, R))
    if B is not None and us is not None:
        B, us = jnp.asarray(B, dtype), jnp.asarray(us, dtype)
    mats = {"F": F, "Q": Q, "H": H, "R": R}
    if (B is None) != (us is None):
        raise ValueError("B and us must be given together")
    if B is not None:
        mats["B"] = B
        _checks.check_ndim("us", us, 2, "[T, k] control inputs")
        k = jnp.shape(us)[1]
        _checks.check_shape("us", us, (T, k))
    elif "B" in tv:
        raise ValueError("time_varying names 'B' but no B was given")
    expected = {"F": (n, n), "Q": (n, n), "H": (m, n), "R": (m, m)}
    if B is not None:
        expected["B"] = (n, k)
    for name, shape in expected.items():
        lead = (T,) if name in tv else ()
        if name in ("Q", "R"):
            _checks.check_covariance(name, mats[name], shape[0], batch_axes=len(lead),
                                     definite=name == "R")
            _checks.check_shape(name, mats[name], lead + shape)
        else:
            _checks.check_shape(name, mats[name], lead + shape)
    per_step = {k_: v for k_, v in mats.items() if k_ in tv}
    fixed = {k_: v for k_, v in mats.items() if k_ not in tv}
    if us is not None:
        per_step["u"] = us

    def step(state, z, mask, p):
        p = {**fixed, **p}
        pred = _predict(state, p["F"], p["Q"], p.get("B"), p.get("u"))
        post, ll = _update(pred, z, p["H"], p["R"], mask)
        return pred, post, ll

    return run_filter(init, zs, masks, step, per_step, return_predicted)


def rts_smoother(result: FilterResult, F: Array, Q: Array, *, B: Array | None = None,
                 us: Array | None = None,
                 time_varying: Collection[str] = ()) -> SmootherResult:
    r"""Rauch-Tung-Striebel smoother for the output of `filter`.

    .. math::
        P^p_{t+1} = F P_t F^T + Q,\; G_t = P_t F^T (P^p_{t+1})^{-1},\;
        m^s_t = m_t + G_t (m^s_{t+1} - F m_t - B u_{t+1}),\;
        P^s_t = P_t + G_t (P^s_{t+1} - P^p_{t+1}) G_t^T.

    Time-varying ``F`` / ``Q`` / ``B`` use the matrices of step ``t + 1`` for the transition from
    ``t`` to ``t + 1`` (the same indexing as `filter` and filterpy's ``rts_smoother``).

    Args:
      result: a `FilterResult` with means [T, n], covs [T, n, n].
      F, Q, B, us, time_varying: as given to `filter`.

    Returns:
      `SmootherResult` (means [T, n], covs [T, n, n]); unpacks as ``(means, covs)``.
    """
    tv = _checks.check_options("time_varying", time_varying, ("F", "Q", "B"))
    T, n = jnp.shape(result.means)
    for name, x in (("F", F), ("Q", Q)):
        _checks.check_shape(name, x, ((T,) if name in tv else ()) + (n, n))
    _checks.check_covariance("Q", Q, n, batch_axes=int("Q" in tv))
    for name, x in (("F", F), ("B", B), ("us", us)):
        if x is not None:
            _checks.check_finite(name, x)
    if (B is None) != (us is None):
        raise ValueError("B and us must be given together")
    if T == 0:  # a zero-length sequence smooths to itself
        return SmootherResult(result.means, result.covs)
    per_step = {k_: v[1:] for k_, v in (("F", F), ("Q", Q), ("B", B)) if k_ in tv}
    fixed = {k_: v for k_, v in (("F", F), ("Q", Q), ("B", B)) if k_ not in tv}
    if us is not None:
        per_step["u"] = us[1:]

    def step(smoothed, inp):
        mean, cov, p = inp
        p = {**fixed, **p}
        pred = _predict(Gaussian(mean, cov), p["F"], p["Q"], p.get("B"), p.get("u"))
        low = _linalg.cholesky(pred.cov)
        # G^T = P_pred^{-1} F P (P_pred and P symmetric)
        gain = jnp.swapaxes(_linalg.cho_solve(low, p["F"] @ cov), -1, -2)
        s_mean = mean + gain @ (smoothed.mean - pred.mean)
        s_cov = cov + gain @ (smoothed.cov - pred.cov) @ gain.T
        s = Gaussian(s_mean, _linalg.symmetrize(s_cov))
        return s, s

    last = Gaussian(result.means[-1], result.covs[-1])
    _, sm = lax.scan(step, last, (result.means[:-1], result.covs[:-1], per_step), reverse=True)
    means = jnp.concatenate([sm.mean, last.mean[None]], 0)
    covs = jnp.concatenate([sm.cov, last.cov[None]], 0)
    return SmootherResult(means, covs)


# ---------------------------------------------------------------------------------------------
# Unchecked cores of `predict` / `update` (for the drivers), and pieces shared with ekf and ukf


def _predict(state, F, Q, B=None, u=None):
    mean = F @ state.mean
    if B is not None:
        mean = mean + B @ u
    cov = F @ state.cov @ F.T + Q
    return Gaussian(mean, _linalg.symmetrize(cov))


def _update(state, z, H, R, mask):
    z_hat = H @ state.mean
    return condition(state, z, z_hat, H, R, mask)


def effective_mask(z, mask):
    """[m] bools: requested present and finite."""
    finite = jnp.isfinite(z)
    if mask is None:
        return finite
    return jnp.broadcast_to(jnp.asarray(mask, bool), z.shape) & finite


def masked_noise(R, present):
    """R restricted to present components, identity on missing ones (they decouple)."""
    both = present[:, None] & present[None, :]
    return jnp.where(both, R, 0.0) + jnp.diag(jnp.where(present, 0.0, 1.0).astype(R.dtype))


def masked_log_likelihood(low_s, innovation, present):
    """log N(y; 0, S) over present components (missing ones were decoupled with unit noise)."""
    ll, _ = _linalg.gaussian_log_density(low_s, innovation)
    num_missing = jnp.sum(~present)
    return ll + 0.5 * jnp.log(2.0 * jnp.pi) * num_missing


def condition(state, z, z_hat, H, R, mask, residual: Callable | None = None):
    """Joseph-form update with innovation ``residual(z, z_hat)`` and (linearised) H [m, n]."""
    present = effective_mask(z, mask)
    z = jnp.where(present, z, z_hat)
    y = z - z_hat if residual is None else residual(z, z_hat)
    y = jnp.where(present, y, 0.0)
    H = jnp.where(present[:, None], H, 0.0)
    R = masked_noise(R, present)
    P = state.cov
    PHt = P @ H.T
    S = _linalg.symmetrize(H @ PHt + R)
    low = _linalg.cholesky(S)
    K = jnp.swapaxes(_linalg.cho_solve(low, PHt.T), -1, -2)
    I_KH = jnp.eye(P.shape[-1], dtype=P.dtype) - K @ H
    cov = I_KH @ P @ I_KH.T + K @ R @ K.T
    mean = state.mean + K @ y
    ll = masked_log_likelihood(low, y, present)
    any_present = jnp.any(present)
    post = Gaussian(jnp.where(any_present, mean, state.mean),
                    jnp.where(any_present, _linalg.symmetrize(cov), state.cov))
    return post, jnp.where(any_present, ll, 0.0)


def run_filter(init, zs, masks, step, per_step, return_predicted=True) -> FilterResult:
    """`lax.scan` driver shared by the Gaussian filters.

    ``step(state, z, mask, params) -> (predicted, posterior, log_likelihood)``.
    """
    T, m = zs.shape
    if masks is None:
        masks = jnp.ones((T,), bool)
    masks = jnp.asarray(masks, bool)
    full = jnp.broadcast_to(masks if masks.ndim == 2 else masks[:, None], (T, m))
    num_invalid = jnp.sum(full & ~jnp.isfinite(zs))

    dtype = jnp.result_type(init.mean)

    def body(state, inp):
        z, mask, p = inp
        pred, post, ll = step(state, z, mask, p)
        # User functions (EKF / UKF) may compute in a wider dtype: the carry keeps the run's.
        pred, post = _gaussian.as_dtype(pred, dtype), _gaussian.as_dtype(post, dtype)
        ll = jnp.asarray(ll, dtype)
        not_pd = ~jnp.all(jnp.isfinite(_linalg.cholesky(post.cov)))
        return post, (post, pred if return_predicted else None, ll, not_pd)

    _, (post, pred, lls, not_pd) = lax.scan(body, init, (zs, masks, per_step))
    pm, pc = (pred.mean, pred.cov) if return_predicted else (None, None)
    return FilterResult(post.mean, post.cov, pm, pc, lls, jnp.sum(lls), num_invalid,
                        jnp.sum(not_pd).astype(jnp.int32))
