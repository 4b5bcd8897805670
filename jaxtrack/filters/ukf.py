r"""Unscented Kalman filter (Julier & Uhlmann 1997; scaled points of van der Merwe 2004).

Sigma points :math:`\mathcal{X}_0 = m`, :math:`\mathcal{X}_{i} = m + \sqrt{c}\,L_{:,i}`,
:math:`\mathcal{X}_{n+i} = m - \sqrt{c}\,L_{:,i}` with :math:`L L^T = P`, propagated through the
model and recombined by the unscented transform

.. math::
    \bar y = \sum_i W^m_i \mathcal{Y}_i, \qquad
    P_y = \sum_i W^c_i (\mathcal{Y}_i - \bar y)(\mathcal{Y}_i - \bar y)^T + \text{noise}.

Numerics. With the common ``alpha = 1e-3`` the central mean weight is about
:math:`1 - 1/\alpha^2 \approx -10^6`. We compute the mean as :math:`\mathcal{Y}_0 +
\sum_{i>0} W^m_i(\mathcal{Y}_i - \mathcal{Y}_0)` (the weights sum to one), which is exact in
exact arithmetic and avoids the cancellation of the textbook sum; but the points then sit
:math:`\alpha\sqrt{n}` standard deviations from the mean, so rounding in ``f`` and ``h`` is still
amplified by about :math:`1/\alpha^2`: in float32 ``alpha = 1e-3`` loses about two digits per
step and long runs lose positive definiteness (measured in the tests). The default scheme of
`predict` / `update` / `filter` is therefore ``merwe_points(alpha=1.0, beta=2.0, kappa=0.0)``,
whose weights are all non-negative (:math:`W_0^m = 0`, :math:`W_0^c = 2`), so every unscented
covariance is a sum of positive semi-definite terms; pass ``points=merwe_points(alpha=1e-3)`` for filterpy's
usual small-alpha scheme (``merwe_points(alpha=1e-3)``, which warns) in float64. Covariances are symmetrised after every step, and sigma points are drawn with
`jaxtrack.filters._linalg.safe_cholesky`: if the Cholesky factor of a drifted covariance is not
finite, it is retried with a relative diagonal jitter (1e-9 in float64, 1e-5 in float32), and
failing that the square root of the clipped diagonal is used. The jitter only acts where the
plain factorisation failed.

Angles: ``x_mean_fn(sigmas [2n+1, n], weights [2n+1]) -> [n]`` and ``residual_x(a, b)`` (and the
``z`` counterparts) replace the weighted mean and the difference, as in filterpy.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable, Collection

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import _checks
from jaxtrack.filters import _gaussian, _linalg, kalman
from jaxtrack.filters.kalman import FilterResult, Gaussian

Array = jax.Array

__all__ = ["SigmaPoints", "merwe_points", "julier_points", "sigma_points", "unscented_transform",
           "predict", "update", "filter"]


@dataclasses.dataclass(frozen=True)
class SigmaPoints:
    """A sigma-point scheme (static configuration: hashable, not traced).

    Build with `merwe_points` or `julier_points`. ``weights(n)`` gives the mean and covariance
    weights [2n+1] and ``scale(n)`` the factor :math:`\\sqrt{c}` applied to the Cholesky columns.
    """

    kind: str
    alpha: float = 1.0
    beta: float = 0.0
    kappa: float = 0.0

    def __post_init__(self):
        if self.kind not in ("merwe", "julier"):
            raise ValueError(f"unknown sigma-point scheme {self.kind!r}; use 'merwe' or 'julier'")

    def _c(self, n: int) -> float:
        if self.kind == "merwe":
            c = self.alpha**2 * (n + self.kappa)
        else:
            c = n + self.kappa
        if c <= 0:
            raise ValueError(f"{self} gives n + lambda = {c} <= 0 for n = {n}")
        return c

    def scale(self, n: int) -> float:
        return float(np.sqrt(self._c(n)))

    def weights(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        c = self._c(n)
        lam = c - n
        wm = np.full(2 * n + 1, 0.5 / c)
        wc = wm.copy()
        wm[0] = lam / c
        wc[0] = lam / c + (1.0 - self.alpha**2 + self.beta if self.kind == "merwe" else 0.0)
        return wm, wc


jax.tree_util.register_static(SigmaPoints)


def merwe_points(alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0) -> SigmaPoints:
    r"""Scaled sigma points (van der Merwe 2004): :math:`\lambda = \alpha^2 (n+\kappa) - n`,
    :math:`W^m_0 = \lambda/(n+\lambda)`, :math:`W^c_0 = W^m_0 + 1 - \alpha^2 + \beta`,
    :math:`W_i = 1/(2(n+\lambda))`. Same points and order as filterpy's MerweScaledSigmaPoints.

    The default ``alpha = 1`` (with ``kappa = 0``: :math:`W^m_0 = 0`) keeps every weight
    non-negative. The literature's common ``alpha = 1e-3`` puts a weight of about
    :math:`1 - 1/\alpha^2 = -10^6` on the centre: in float32, long runs then lose positive
    definiteness (91-163 steps on a badly scaled model), so an ``alpha`` below `SMALL_ALPHA`
    warns.

    Example:
      >>> pts = ukf.merwe_points(alpha=0.5)
    """
    if not alpha > 0:
        raise ValueError(f"alpha must be > 0; got {alpha}")
    if alpha < SMALL_ALPHA:
        warnings.warn(f"merwe_points(alpha={alpha:g}) puts a weight of about "
                      f"{1 - 1 / alpha**2:.3g} on the centre point (kappa = 0): rounding is "
                      f"amplified ~1/alpha^2 and float32 runs lose positive definiteness; "
                      f"prefer alpha >= {SMALL_ALPHA} (the default is 1)", stacklevel=2)
    return SigmaPoints("merwe", float(alpha), float(beta), float(kappa))


#: Below this ``alpha``, `merwe_points` warns (centre weight below about -99).
SMALL_ALPHA = 0.1


def julier_points(kappa: float = 0.0) -> SigmaPoints:
    r"""Julier's symmetric sigma points: :math:`W_0 = \kappa/(n+\kappa)`,
    :math:`W_i = 1/(2(n+\kappa))`, spread :math:`\sqrt{n+\kappa}`.

    Example:
      >>> pts = ukf.julier_points(kappa=1.0)
    """
    return SigmaPoints("julier", 1.0, 0.0, float(kappa))


# Non-negative weights: robust in float32 and over long runs (see the module docstring).
DEFAULT_POINTS = merwe_points(alpha=1.0, beta=2.0, kappa=0.0)


def sigma_points(state: Gaussian, points: SigmaPoints = DEFAULT_POINTS) -> Array:
    """Sigma points [2n+1, n] of ``state`` (centre, then + columns, then - columns)."""
    n = state.mean.shape[-1]
    low = _linalg.safe_cholesky(state.cov) * jnp.asarray(points.scale(n), state.cov.dtype)
    cols = low.T
    return jnp.concatenate([state.mean[None], state.mean + cols, state.mean - cols], 0)


def unscented_transform(sigmas: Array, wm: Array, wc: Array, noise: Array | None = None,
                        mean_fn: Callable | None = None,
                        residual: Callable | None = None) -> tuple[Array, Array, Array]:
    r"""Weighted mean and covariance of transformed sigma points.

    Args:
      sigmas: [2n+1, d] transformed sigma points.
      wm, wc: [2n+1] mean and covariance weights.
      noise: optional [d, d] additive noise covariance.
      mean_fn: optional ``mean_fn(sigmas, wm) -> [d]`` (e.g. circular mean for angles).
      residual: optional ``residual(a, b) -> [d]`` (default ``a - b``).

    Returns:
      ``(mean [d], cov [d, d], deviations [2n+1, d])``.
    """
    if mean_fn is None:
        centre = sigmas[0]
        mean = centre + wm[1:] @ (sigmas[1:] - centre)
    else:
        mean = mean_fn(sigmas, wm)
    dev = sigmas - mean if residual is None else jax.vmap(residual, (0, None))(sigmas, mean)
    cov = (dev.T * wc) @ dev
    if noise is not None:
        cov = cov + noise
    return mean, _linalg.symmetrize(cov), dev


def predict(state: Gaussian, f: Callable, Q: Array, u: Array | None = None,
            points: SigmaPoints = DEFAULT_POINTS, x_mean_fn: Callable | None = None,
            residual_x: Callable | None = None) -> Gaussian:
    """UKF prediction: propagate sigma points through ``f`` and recombine, plus ``Q``.

    A step function for closed loops: callable inside `jit` and `vmap` (its checks read shapes,
    and values only of concrete arrays), e.g. mapped over the track slots of
    `jaxtrack.tracking.tracker.predict`.

    Args:
      state: Gaussian, mean [n], cov [n, n].
      f: transition ``f(x [n], u) -> [n]`` (``f(x)`` when ``u`` is None).
      Q: [n, n] process-noise covariance.
      u: optional control input.
      points: sigma-point scheme (default ``merwe_points(alpha=1.0)``, see the module notes).
      x_mean_fn, residual_x: optional mean / difference functions for angle states.

    Returns:
      Predicted Gaussian.

    Example:
      >>> prior = ukf.predict(kalman.Gaussian(x0, P0), motion.coordinated_turn(0.1), Q)
    """
    n = _gaussian.check_state(state)
    _check_points(points)
    _checks.check_callable("f", f)
    _checks.check_covariance("Q", Q, n)
    return _predict(state, f, Q, u, points, x_mean_fn, residual_x)


def update(state: Gaussian, z: Array, h: Callable, R: Array,
           points: SigmaPoints = DEFAULT_POINTS, mask: Array | bool | None = None,
           z_mean_fn: Callable | None = None, residual_z: Callable | None = None,
           residual_x: Callable | None = None) -> tuple[Gaussian, Array]:
    r"""UKF update with sigma points re-drawn from ``state``.

    .. math::
        S = \sum W^c_i \Delta z_i \Delta z_i^T + R,\; P_{xz} = \sum W^c_i \Delta x_i \Delta z_i^T,
        \; K = P_{xz} S^{-1},\; m^+ = m + K y,\; P^+ = P - K S K^T.

    Args:
      state: predicted Gaussian, mean [n], cov [n, n].
      z: [m] measurement; h: ``h(x [n]) -> [m]``; R: [m, m].
      points: sigma-point scheme.
      mask: None, scalar or [m] bools (see `kalman.update`).
      z_mean_fn, residual_z, residual_x: optional angle-aware mean / differences.

    Returns:
      ``(posterior, log_likelihood)`` with log-likelihood :math:`\log N(y; 0, S)`.

    Example:
      >>> post, ll = ukf.update(prior, z, measurement.range_bearing, R,
      ...                       residual_z=measurement.range_bearing_residual)
    """
    _gaussian.check_state(state)
    m = _gaussian.check_measurement(z, mask)
    _check_points(points)
    _checks.check_callable("h", h)
    _checks.check_covariance("R", R, m)
    out = jax.eval_shape(h, state.mean)
    _checks.check_shape("h(x)", out, (m,), "the measurement function must map [n] to [m]")
    return _update(state, z, h, R, points, mask, z_mean_fn, residual_z, residual_x)


def filter(init: Gaussian, zs: Array, f: Callable, Q: Array, h: Callable, R: Array,
           masks: Array | None = None, *, us: Array | None = None,
           points: SigmaPoints = DEFAULT_POINTS, x_mean_fn: Callable | None = None,
           residual_x: Callable | None = None, z_mean_fn: Callable | None = None,
           residual_z: Callable | None = None,
           time_varying: Collection[str] = (), return_predicted: bool = True) -> FilterResult:
    """UKF over a sequence under `lax.scan` (predict, then update, at every step).

    Arguments as in `predict` / `update` and `kalman.filter`; ``time_varying`` is a subset of
    {"Q", "R"}; ``us`` [T, ...] optional controls; ``return_predicted`` as in `kalman.filter`.

    Returns:
      `kalman.FilterResult`.

    Example:
      >>> res = ukf.filter(init, zs, motion.coordinated_turn(0.1), Q,
      ...                  measurement.range_bearing, R,
      ...                  residual_z=measurement.range_bearing_residual)
    """
    tv = _checks.check_options("time_varying", time_varying, ("Q", "R"))
    n = _gaussian.check_state(init, "init")
    T, m = _gaussian.check_sequence(zs, masks)
    _check_points(points)
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
    per_step = {k: v for k, v in (("Q", Q), ("R", R)) if k in tv}
    fixed = {k: v for k, v in (("Q", Q), ("R", R)) if k not in tv}
    if us is not None:
        _checks.check_shape("us", us, (T,) + tuple(jnp.shape(us)[1:]), "leading time axis")
        per_step["u"] = us

    def step(state, z, mask, p):
        p = {**fixed, **p}
        pred = _predict(state, f, p["Q"], p.get("u"), points, x_mean_fn, residual_x)
        post, ll = _update(pred, z, h, p["R"], points, mask, z_mean_fn, residual_z, residual_x)
        return pred, post, ll

    return kalman.run_filter(init, zs, masks, step, per_step, return_predicted)


def _check_points(points):
    if not isinstance(points, SigmaPoints):
        raise TypeError("points must be a ukf.SigmaPoints (use ukf.merwe_points() or "
                        f"ukf.julier_points()); got {type(points).__name__}")


def _weights(points, n, dtype):
    wm, wc = points.weights(n)
    return jnp.asarray(wm, dtype), jnp.asarray(wc, dtype)


def _predict(state, f, Q, u, points, x_mean_fn, residual_x):
    n = state.mean.shape[-1]
    wm, wc = _weights(points, n, state.cov.dtype)
    sig = sigma_points(state, points)
    fx = jax.vmap(f) if u is None else jax.vmap(f, (0, None))
    prop = fx(sig) if u is None else fx(sig, u)
    mean, cov, _ = unscented_transform(prop, wm, wc, Q, x_mean_fn, residual_x)
    return Gaussian(mean, cov)


def _update(state, z, h, R, points, mask, z_mean_fn, residual_z, residual_x):
    n = state.mean.shape[-1]
    wm, wc = _weights(points, n, state.cov.dtype)
    sig = sigma_points(state, points)
    zs = jax.vmap(h)(sig)
    present = kalman.effective_mask(z, mask)
    z_hat, _, dz = unscented_transform(zs, wm, wc, None, z_mean_fn, residual_z)
    dz = jnp.where(present, dz, 0.0)
    S = _linalg.symmetrize((dz.T * wc) @ dz + kalman.masked_noise(R, present))
    dx = sig - state.mean if residual_x is None else jax.vmap(residual_x, (0, None))(
        sig, state.mean)
    Pxz = (dx.T * wc) @ dz
    z = jnp.where(present, z, z_hat)
    y = z - z_hat if residual_z is None else residual_z(z, z_hat)
    y = jnp.where(present, y, 0.0)
    low = _linalg.cholesky(S)
    K = jnp.swapaxes(_linalg.cho_solve(low, Pxz.T), -1, -2)
    mean = state.mean + K @ y
    cov = _linalg.symmetrize(state.cov - K @ Pxz.T)
    ll = kalman.masked_log_likelihood(low, y, present)
    any_present = jnp.any(present)
    post = Gaussian(jnp.where(any_present, mean, state.mean),
                    jnp.where(any_present, cov, state.cov))
    return post, jnp.where(any_present, ll, 0.0)
