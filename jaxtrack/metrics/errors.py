r"""Estimation errors of one episode: position RMSE, wrapped angle errors, NEES / NIS and their
chi-square consistency bounds.

Every function takes one episode with a leading time axis ``T`` and an optional mask (False marks
a step, or a component, that is left out); batch episodes with `jax.vmap`. Everything is
jittable: the chi-square quantiles are computed with `jax.scipy.special.gammainc` (scipy is not
needed at run time).

Averages over no present entries are undefined and come back as NaN for that episode only, so a
silent 0 cannot pass for a perfect score; masked entries never reach the arithmetic, so NaN or
inf written into masked slots does not leak into the result.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.scipy.linalg import solve_triangular
from jax.scipy.special import gammainc, gammaincc, gammaln, ndtri

from jaxtrack import _checks
from jaxtrack.angles import wrap

Array = jax.Array

__all__ = ["position_error", "rmse", "angle_error", "angle_rmse", "angle_mae", "nees", "nis",
           "chi2_ppf", "chi2_bounds"]


# ---------------------------------------------------------------------------------------------
# Position and angle errors


def position_error(estimates: Array, truths: Array) -> Array:
    r"""Euclidean position error :math:`e_t = \lVert \hat p_t - p_t \rVert_2` at every step.

    Args:
      estimates: [T, d] estimated positions (m).
      truths: [T, d] true positions (m).

    Returns:
      [T] errors (m).

    Example:
      >>> from jaxtrack import metrics
      >>> metrics.position_error(jnp.array([[3.0, 4.0]]), jnp.zeros((1, 2)))  # [5.]
    """
    _check_pair("estimates", estimates, "truths", truths, ndim=2, what="[T, d] positions")
    return _position_error(estimates, truths)


def rmse(estimates: Array, truths: Array, mask: Array | None = None) -> Array:
    r"""Root-mean-square Euclidean position error over the present steps.

    .. math::
        \mathrm{RMSE} = \sqrt{\frac{1}{|\mathcal{T}|} \sum_{t \in \mathcal{T}}
        \lVert \hat p_t - p_t \rVert_2^2},\qquad \mathcal{T} = \{t : \mathrm{mask}_t\}.

    Args:
      estimates: [T, d] estimated positions (m).
      truths: [T, d] true positions (m).
      mask: optional [T] bools; False leaves the step out.

    Returns:
      Scalar RMSE (m); NaN when no step is present.

    Example:
      >>> est, true = jnp.array([[1.0, 0.0], [0.0, 0.0]]), jnp.zeros((2, 2))
      >>> metrics.rmse(est, true)  # sqrt(1/2)
      >>> metrics.rmse(est, true, mask=jnp.array([True, False]))  # 1.0
    """
    T, _ = _check_pair("estimates", estimates, "truths", truths, ndim=2, what="[T, d] positions")
    return _rmse(estimates, truths, _step_mask(mask, T))


def angle_error(estimates: Array, truths: Array) -> Array:
    r"""Signed wrapped angle error :math:`\operatorname{wrap}(\hat\theta - \theta) \in [-\pi, \pi)`.

    Args:
      estimates: [...] estimated angles (rad).
      truths: [...] true angles (rad), the same shape.

    Returns:
      [...] errors (rad), the shortest signed rotation from the truth to the estimate.

    Example:
      >>> metrics.angle_error(jnp.array([3.1]), jnp.array([-3.1]))  # about -0.083, not 6.2
    """
    if np.shape(estimates) != np.shape(truths):
        raise ValueError(f"estimates and truths must have the same shape; got "
                         f"{list(np.shape(estimates))} and {list(np.shape(truths))}")
    return _angle_error(estimates, truths)


def angle_rmse(estimates: Array, truths: Array, mask: Array | None = None) -> Array:
    r"""Root-mean-square wrapped angle error over the present entries.

    .. math::
        \sqrt{\frac{1}{|\mathcal{P}|} \sum_{\mathcal{P}} \operatorname{wrap}(\hat\theta -
        \theta)^2}

    Args:
      estimates: [T] or [T, k] estimated angles (rad).
      truths: true angles (rad), the same shape.
      mask: optional [T] bools (whole steps) or bools of the same shape as ``estimates``.

    Returns:
      Scalar RMSE (rad) in [0, pi]; NaN when nothing is present.

    Example:
      >>> metrics.angle_rmse(jnp.array([jnp.pi - 0.1]), jnp.array([-jnp.pi + 0.1]))  # 0.2
    """
    return _angle_stats(estimates, truths, _angle_mask(estimates, truths, mask))[0]


def angle_mae(estimates: Array, truths: Array, mask: Array | None = None) -> Array:
    r"""Mean absolute wrapped angle error :math:`\frac{1}{|\mathcal{P}|} \sum_{\mathcal{P}}
    |\operatorname{wrap}(\hat\theta - \theta)|` over the present entries.

    Args:
      estimates: [T] or [T, k] estimated angles (rad).
      truths: true angles (rad), the same shape.
      mask: optional [T] bools (whole steps) or bools of the same shape as ``estimates``.

    Returns:
      Scalar mean absolute error (rad) in [0, pi]; NaN when nothing is present.

    Example:
      >>> metrics.angle_mae(jnp.array([0.1, 6.2]), jnp.array([0.0, 0.0]))  # about 0.092
    """
    return _angle_stats(estimates, truths, _angle_mask(estimates, truths, mask))[1]


# ---------------------------------------------------------------------------------------------
# Consistency: NEES, NIS and chi-square bounds


def nees(errors: Array, covs: Array, mask: Array | None = None) -> Array:
    r"""Normalised estimation error squared at every step (Bar-Shalom, Li & Kirubarajan 2001,
    sec. 5.4).

    .. math::
        \epsilon_t = \tilde x_t^\top P_t^{-1} \tilde x_t,\qquad \tilde x_t = x_t - \hat x_t,

    which is :math:`\chi^2_n` distributed for a consistent filter. With a component mask, the
    quadratic form uses the present components only (the marginal covariance), so
    :math:`\epsilon_t \sim \chi^2_{n_t}` with :math:`n_t` = number of present components.

    Args:
      errors: [T, n] estimation errors (truth minus estimate; the sign does not matter).
      covs: [T, n, n] estimate covariances (symmetric positive definite on present components).
      mask: optional [T] bools (whole steps) or [T, n] bools (components).

    Returns:
      [T] NEES values; 0 at fully masked steps (use the mask when averaging).

    Example:
      >>> res = kalman.filter(init, zs, F, Q, H, R)
      >>> eps = metrics.nees(xs - res.means, res.covs)          # [T]
      >>> lo, hi = metrics.chi2_bounds(4, num_samples=eps.shape[0])  # time-average bounds
    """
    T, n = _check_quadratic_form("errors", errors, "covs", covs, mask)
    return _normalised_squares(errors, covs, _component_mask(mask, T, n))


def nis(innovations: Array, S: Array, mask: Array | None = None) -> Array:
    r"""Normalised innovation squared at every step (Bar-Shalom, Li & Kirubarajan 2001,
    sec. 5.4).

    .. math::
        \epsilon^\nu_t = \nu_t^\top S_t^{-1} \nu_t,\qquad \nu_t = z_t - \hat z_t,\;
        S_t = H P^-_t H^\top + R,

    which is :math:`\chi^2_m` distributed for a consistent filter (:math:`m_t` present components
    under a component mask).

    Args:
      innovations: [T, m] innovations.
      S: [T, m, m] innovation covariances.
      mask: optional [T] bools (whole steps) or [T, m] bools (components).

    Returns:
      [T] NIS values; 0 at fully masked steps.

    Example:
      >>> nu = zs - res.predicted_means @ H.T
      >>> S = H @ res.predicted_covs @ H.T + R                  # [T, m, m]
      >>> eps = metrics.nis(nu, S)
    """
    T, m = _check_quadratic_form("innovations", innovations, "S", S, mask)
    return _normalised_squares(innovations, S, _component_mask(mask, T, m))


def chi2_ppf(q: Array, dof: Array) -> Array:
    r"""Quantile of the chi-square distribution, :math:`F^{-1}_{\chi^2_k}(q)`, jittable.

    Solves :math:`P(k/2, x/2) = q` (regularised lower incomplete gamma, `gammainc`) by Newton's
    method from the Wilson-Hilferty approximation, safeguarded by bisection on a bracket, for a
    fixed number of iterations. Agrees with ``scipy.stats.chi2.ppf`` to about 1e-12 (relative) in
    float64 for ``dof`` in [1, 10^4] and ``q`` in [1e-10, 1 - 1e-10] (see the tests). Callable
    inside `jit` (``q`` and ``dof`` are checked only when concrete); the gate's quantile
    `jaxtrack.association.chi2_ppf` uses it for three or more degrees of freedom.

    Args:
      q: probability in (0, 1) (any shape, broadcast with ``dof``).
      dof: degrees of freedom k > 0 (need not be an integer).

    Returns:
      The quantile, in the floating dtype of the inputs.

    Example:
      >>> metrics.chi2_ppf(0.95, 2)  # 5.991...
    """
    if _checks.is_concrete(q) and np.any((np.asarray(q) <= 0) | (np.asarray(q) >= 1)):
        raise ValueError(f"q must lie in (0, 1); got {q}")
    if _checks.is_concrete(dof) and np.any(np.asarray(dof) <= 0):
        raise ValueError(f"dof must be positive; got {dof}")
    return _chi2_ppf(q, dof)


def chi2_bounds(dof: Array, num_samples: Array, prob: float = 0.95) -> tuple[Array, Array]:
    r"""Two-sided chi-square acceptance interval for an average of NEES (or NIS) values.

    If :math:`\epsilon_1, \dots, \epsilon_N` are independent :math:`\chi^2_n` values (one per
    Monte-Carlo run at a given time, or one per time step of a single run),
    :math:`N \bar\epsilon \sim \chi^2_{Nn}`, so with probability ``prob``

    .. math::
        \bar\epsilon \in \Big[\tfrac{1}{N} F^{-1}_{\chi^2_{Nn}}\big(\tfrac{1 - p}{2}\big),\;
        \tfrac{1}{N} F^{-1}_{\chi^2_{Nn}}\big(\tfrac{1 + p}{2}\big)\Big]

    (Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4.2).

    Args:
      dof: n, the state (NEES) or measurement (NIS) dimension.
      num_samples: N, the number of values averaged.
      prob: p, the probability mass inside the interval, in (0, 1).

    Returns:
      ``(lower, upper)`` bounds on the average.

    Example:
      >>> lo, hi = metrics.chi2_bounds(dof=4, num_samples=50)   # (3.25..., 4.82...)
      >>> eps = jax.vmap(metrics.nees)(errors, covs)            # [50, T] from 50 runs
      >>> inside = (eps.mean(0) >= lo) & (eps.mean(0) <= hi)    # about 95% of the steps
    """
    for name, value in (("dof", dof), ("num_samples", num_samples)):
        if _checks.is_concrete(value) and np.any(np.asarray(value) <= 0):
            raise ValueError(f"{name} must be positive; got {value}")
    if _checks.is_concrete(prob) and not np.all((np.asarray(prob) > 0) & (np.asarray(prob) < 1)):
        raise ValueError(f"prob must lie in (0, 1); got {prob}")
    dtype = jnp.result_type(float)
    dof, num_samples, prob = (jnp.asarray(a, dtype) for a in (dof, num_samples, prob))
    k = dof * num_samples
    lower = _chi2_ppf(0.5 * (1.0 - prob), k) / num_samples
    upper = _chi2_ppf(0.5 * (1.0 + prob), k) / num_samples
    return lower, upper


# ---------------------------------------------------------------------------------------------
# Internals


# The public functions check their inputs, then call these jitted kernels: one compile per
# shape and dtype, shared by every call (eager op-by-op dispatch would compile each op).


@jax.jit
def _position_error(estimates, truths):
    """Euclidean norm over the last axis with a finite gradient at 0."""
    v = estimates - truths
    sq = jnp.sum(v * v, -1)
    safe = jnp.where(sq > 0, sq, 1.0)
    return jnp.where(sq > 0, jnp.sqrt(safe), 0.0)


@jax.jit
def _angle_error(estimates, truths):
    return wrap(estimates - truths)


@jax.jit
def _rmse(estimates, truths, present):
    diff = jnp.where(present[:, None], estimates - truths, 0.0)
    return jnp.sqrt(_masked_mean(jnp.sum(diff * diff, -1), present))


@jax.jit
def _angle_stats(estimates, truths, present):
    """(RMSE, mean absolute error) of the wrapped differences over the present entries."""
    err = jnp.where(present, wrap(jnp.where(present, estimates - truths, 0.0)), 0.0)
    return jnp.sqrt(_masked_mean(err * err, present)), _masked_mean(jnp.abs(err), present)


def _masked_mean(values, present):
    count = jnp.sum(present)
    total = jnp.sum(jnp.where(present, values, 0.0))
    return jnp.where(count > 0, total / jnp.maximum(count, 1), jnp.nan)


def _angle_mask(estimates, truths, mask):
    if np.ndim(estimates) not in (1, 2):
        raise ValueError(f"estimates must be [T] or [T, k] angles; got shape "
                         f"{list(np.shape(estimates))}")
    if np.shape(estimates) != np.shape(truths):
        raise ValueError(f"estimates and truths must have the same shape; got "
                         f"{list(np.shape(estimates))} and {list(np.shape(truths))}")
    shape = np.shape(estimates)
    if mask is None:
        return jnp.ones(shape, bool)
    if np.shape(mask) == shape:
        return jnp.asarray(mask, bool)
    if np.shape(mask) == shape[:1]:
        lead = jnp.asarray(mask, bool).reshape(shape[:1] + (1,) * (len(shape) - 1))
        return jnp.broadcast_to(lead, shape)
    raise ValueError(f"mask must be [T] bools or of the shape of estimates {list(shape)}; "
                     f"got {list(np.shape(mask))}")


def _check_pair(name_a, a, name_b, b, *, ndim, what):
    _checks.check_ndim(name_a, a, ndim, what)
    _checks.check_shape(name_b, b, _checks.shape_of(a), f"the shape of {name_a}")
    return _checks.shape_of(a)


def _step_mask(mask, T):
    if mask is None:
        return jnp.ones((T,), bool)
    _checks.check_shape("mask", mask, (T,), "[T] bools")
    return jnp.asarray(mask, bool)


def _check_quadratic_form(name_v, v, name_c, c, mask):
    _checks.check_ndim(name_v, v, 2, f"a [T, n] sequence of {name_v}")
    T, n = _checks.shape_of(v)
    _checks.check_shape(name_c, c, (T, n, n), f"one [{n}, {n}] covariance per step")
    if mask is not None and np.shape(mask) not in ((T,), (T, n)):
        raise ValueError(f"mask must have shape [{T}] or [{T}, {n}]; got {list(np.shape(mask))}")
    return T, n


def _component_mask(mask, T, n):
    if mask is None:
        return jnp.ones((T, n), bool)
    mask = jnp.asarray(mask, bool)
    return jnp.broadcast_to(mask[:, None] if mask.ndim == 1 else mask, (T, n))


@jax.jit
def _normalised_squares(v, cov, present):
    """v^T C^{-1} v over the present components (missing ones decouple with unit variance)."""
    both = present[..., :, None] & present[..., None, :]
    eye = jnp.eye(v.shape[-1], dtype=cov.dtype)
    cov = jnp.where(both, cov, 0.0) + jnp.where(present[..., None], 0.0, eye)
    v = jnp.where(present, v, 0.0)
    # metrics sits below filters in the layering, so it uses LAPACK rather than the filters'
    # unrolled Cholesky; a NaN factor (covariance not positive definite) gives a NaN value.
    low = jnp.linalg.cholesky(0.5 * (cov + jnp.swapaxes(cov, -1, -2)))
    white = solve_triangular(low, v[..., None], lower=True)[..., 0]
    return jnp.sum(white * white, -1)


_PPF_ITERATIONS = 60


@jax.jit
def _chi2_ppf(q, dof):
    """Newton on y = log x, safeguarded by bisection, for a fixed number of iterations.

    Working in log x makes the lower tail (where the cdf behaves like x^{k/2}) nearly linear;
    below the median the equation is log P(k/2, x/2) = log q, above it
    log Q(k/2, x/2) = log(1 - q), so neither tail loses digits to 1 - q.
    """
    dtype = jnp.result_type(q, dof, float)
    q, dof = jnp.broadcast_arrays(jnp.asarray(q, dtype), jnp.asarray(dof, dtype))
    a = 0.5 * dof
    log_norm = gammaln(a) + a * jnp.log(jnp.asarray(2.0, dtype))
    upper = q > 0.5
    target = jnp.where(upper, jnp.log1p(-q), jnp.log(q))

    def residual_and_slope(y):
        x = jnp.exp(y)
        tail = jnp.where(upper, gammaincc(a, 0.5 * x), gammainc(a, 0.5 * x))
        log_tail = jnp.log(tail)
        log_x_pdf = a * y - 0.5 * x - log_norm  # log(x * chi2 pdf(x))
        slope = jnp.exp(log_x_pdf - log_tail)
        # Both forms increase with y: log P rises, -log Q rises.
        return jnp.where(upper, target - log_tail, log_tail - target), slope

    # Wilson-Hilferty start, inside a bracket that holds every quantile the dtype can express.
    h = 2.0 / (9.0 * dof)
    x0 = dof * jnp.maximum(1.0 - h + ndtri(q) * jnp.sqrt(h), 0.1) ** 3
    lo = jnp.full_like(q, np.log(np.finfo(dtype).tiny))
    hi = jnp.log(dof + 20.0 * jnp.sqrt(2.0 * dof) + 100.0)
    y0 = jnp.clip(jnp.log(x0), lo, hi)

    def body(_, state):
        y, lo, hi = state
        r, slope = residual_and_slope(y)
        lo = jnp.where(r < 0, y, lo)
        hi = jnp.where(r < 0, hi, y)
        newton = y - r / slope
        ok = jnp.isfinite(newton) & (newton > lo) & (newton < hi)
        return jnp.where(ok, newton, 0.5 * (lo + hi)), lo, hi

    y, _, _ = lax.fori_loop(0, _PPF_ITERATIONS, body, (y0, lo, hi))
    return jnp.exp(y)
