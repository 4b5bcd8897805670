r"""Extended Kalman filter with Jacobians from `jax.jacfwd`.

Model

.. math::
    x_t = f(x_{t-1}, u_t) + w_t,\; w_t \sim N(0, Q), \qquad z_t = h(x_t) + v_t,\; v_t \sim N(0, R).

``f(x, u)`` is called as ``f(x)`` when no control is given; ``h(x)`` maps [n] to [m]. Angle
components are handled by a ``residual(a, b)`` function (e.g. `jaxtrack.models.measurement.
range_bearing_residual`) used for the innovation, so a bearing near +-pi is differenced
correctly. The update uses the Joseph form of `jaxtrack.filters.kalman.update` with
:math:`H = \partial h / \partial x` at the predicted mean.
"""

from __future__ import annotations

from collections.abc import Callable, Collection

import jax
import jax.numpy as jnp

from jaxtrack import _checks
from jaxtrack.filters import _gaussian, _linalg, kalman
from jaxtrack.filters.kalman import FilterResult, Gaussian

Array = jax.Array

__all__ = ["predict", "update", "filter"]


def predict(state: Gaussian, f: Callable, Q: Array, u: Array | None = None) -> Gaussian:
    r"""EKF prediction :math:`m' = f(m, u)`, :math:`P' = J P J^T + Q`, :math:`J = \partial f/\partial x`.

    Args:
      state: Gaussian, mean [n], cov [n, n].
      f: transition ``f(x [n], u) -> [n]`` (``f(x)`` when ``u`` is None).
      Q: [n, n] process-noise covariance.
      u: optional control input.

    Returns:
      Predicted Gaussian.

    Example:
      >>> f = motion.coordinated_turn(dt=0.1)
      >>> prior = ekf.predict(kalman.Gaussian(x0, P0), f, Q)
    """
    n = _gaussian.check_state(state)
    _checks.check_callable("f", f)
    _checks.check_covariance("Q", Q, n)
    out = jax.eval_shape(lambda x: _call_f(f, x, u), state.mean)
    _checks.check_shape("f(x)", out, (n,), "the transition must map [n] to [n]")
    return _predict(state, f, Q, u)


def update(state: Gaussian, z: Array, h: Callable, R: Array, mask: Array | bool | None = None,
           residual: Callable | None = None) -> tuple[Gaussian, Array]:
    r"""EKF update: Joseph-form Kalman update with :math:`H = \partial h/\partial x` at the mean.

    Args:
      state: prior Gaussian, mean [n], cov [n, n].
      z: [m] measurement.
      h: measurement function ``h(x [n]) -> [m]``.
      R: [m, m] measurement-noise covariance.
      mask: None, scalar or [m] bools (see `kalman.update`).
      residual: optional ``residual(z, z_hat) -> [m]`` (default ``z - z_hat``).

    Returns:
      ``(posterior, log_likelihood)`` with log-likelihood :math:`\log N(y; 0, H P H^T + R)`.

    Example:
      >>> post, ll = ekf.update(prior, z, measurement.range_bearing, R,
      ...                       residual=measurement.range_bearing_residual)
    """
    _gaussian.check_state(state)
    m = _gaussian.check_measurement(z, mask)
    _checks.check_callable("h", h)
    out = jax.eval_shape(h, state.mean)
    _checks.check_shape("h(x)", out, (m,), "the measurement function must map [n] to [m]")
    _checks.check_covariance("R", R, m)
    return _update(state, z, h, R, mask, residual)


def filter(init: Gaussian, zs: Array, f: Callable, Q: Array, h: Callable, R: Array,
           masks: Array | None = None, *, us: Array | None = None,
           residual: Callable | None = None,
           time_varying: Collection[str] = (), return_predicted: bool = True) -> FilterResult:
    """EKF over a sequence under `lax.scan` (predict, then update, at every step).

    Args:
      init: prior before the first step; zs: [T, m]; f, h: as in `predict` / `update`.
      Q: [n, n] ([T, n, n] if "Q" in ``time_varying``); R: [m, m] ([T, m, m] likewise).
      masks: optional [T] or [T, m] bools. us: optional [T, ...] controls passed to ``f``.
      residual: optional innovation function for angle components.
      time_varying: subset of {"Q", "R"} carrying a leading time axis.
      return_predicted: also return the one-step predictions (see `kalman.filter`).

    Returns:
      `kalman.FilterResult`.

    Example:
      >>> res = ekf.filter(init, zs, motion.coordinated_turn(0.1), Q,
      ...                  measurement.range_bearing, R,
      ...                  residual=measurement.range_bearing_residual)
    """
    tv = _checks.check_options("time_varying", time_varying, ("Q", "R"))
    n = _gaussian.check_state(init, "init")
    T, m = _gaussian.check_sequence(zs, masks)
    _checks.check_callable("f", f)
    _checks.check_callable("h", h)
    _checks.check_covariance("Q", Q, n, batch_axes=int("Q" in tv))
    _checks.check_covariance("R", R, m, batch_axes=int("R" in tv), definite=True)
    dtype = _gaussian.working_dtype(**{"init.mean": init.mean, "init.cov": init.cov, "zs": zs,
                                       "Q": Q, "R": R})
    init, zs = _gaussian.as_dtype(init, dtype), jnp.asarray(zs, dtype)
    Q, R = jnp.asarray(Q, dtype), jnp.asarray(R, dtype)
    if "Q" in tv:
        _checks.check_shape("Q", Q, (T, n, n))
    if "R" in tv:
        _checks.check_shape("R", R, (T, m, m))
    if us is not None:
        _checks.check_shape("us", us, (T,) + tuple(jnp.shape(us)[1:]), "leading time axis")
    per_step = {k: v for k, v in (("Q", Q), ("R", R)) if k in tv}
    fixed = {k: v for k, v in (("Q", Q), ("R", R)) if k not in tv}
    if us is not None:
        per_step["u"] = us

    def step(state, z, mask, p):
        p = {**fixed, **p}
        pred = _predict(state, f, p["Q"], p.get("u"))
        post, ll = _update(pred, z, h, p["R"], mask, residual)
        return pred, post, ll

    return kalman.run_filter(init, zs, masks, step, per_step, return_predicted)


def _call_f(f, x, u):
    return f(x) if u is None else f(x, u)


def _predict(state, f, Q, u=None):
    mean, jac = _value_and_jacfwd(lambda x: _call_f(f, x, u), state.mean)
    cov = jac @ state.cov @ jac.T + Q
    return Gaussian(mean, _linalg.symmetrize(cov))


def _update(state, z, h, R, mask, residual):
    z_hat, H = _value_and_jacfwd(h, state.mean)
    return kalman.condition(state, z, z_hat, H, R, mask, residual)


def _value_and_jacfwd(fun, x):
    """(fun(x), d fun / dx) with one forward pass per input column."""
    y, pushforward = jax.linearize(fun, x)
    jac = jax.vmap(pushforward, out_axes=-1)(jnp.eye(x.shape[-1], dtype=x.dtype))
    return y, jac
