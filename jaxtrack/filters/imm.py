r"""Interacting multiple model (IMM) filter (Blom & Bar-Shalom 1988).

The target follows one of M modes (motion + measurement models sharing the state dimension n
and the measurement dimension m), switching as a Markov chain with transition matrix
:math:`p_{ij} = P(\text{mode } j \text{ at } t \mid \text{mode } i \text{ at } t-1)` (rows sum to
one). The belief is one Gaussian per mode plus the mode probabilities :math:`\mu_i`, kept in log
space (`IMMState`). One step is `mix`, then `predict`, then `update`:

.. math::
    c_j = \sum_i p_{ij}\mu_i, \qquad \mu_{i|j} = p_{ij}\mu_i / c_j
    \quad\text{(mixing probabilities)},

    \bar m_j = \sum_i \mu_{i|j} m_i, \qquad
    \bar P_j = \sum_i \mu_{i|j}\big(P_i + (m_i - \bar m_j)(m_i - \bar m_j)^T\big)
    \quad\text{(mixed initial conditions)},

    (m_j, P_j, L_j) = \text{mode-}j\text{ predict + update of } N(\bar m_j, \bar P_j),
    \quad L_j = N(z; \hat z_j, S_j),

    \mu_j^+ = c_j L_j / \textstyle\sum_k c_k L_k, \qquad
    \log p(z_t \mid z_{1:t-1}) = \log \textstyle\sum_j c_j L_j,

and the reported (combined) estimate is the moment-matched single Gaussian of the mixture,
:math:`m = \sum_j \mu_j m_j`, :math:`P = \sum_j \mu_j (P_j + (m_j - m)(m_j - m)^T)` (`estimate`).
It is an output only: the filter carries the M mode-matched Gaussians.

Modes are values: `LinearMode` (Kalman), `ExtendedMode` (EKF, Jacobians by `jax.linearize`),
`UnscentedMode` (UKF), or `LinearModels` for M linear modes given as stacked matrices. The
per-mode predict and update are those of `kalman`, `ekf` and `ukf` (Joseph form for the linear
and extended updates), and mixed covariances are sums of positive semi-definite terms,
symmetrised. Mixing treats states as vectors: angle components are averaged without wrapping.

Log space. :math:`\log c_j = \operatorname{logsumexp}_i(\log\mu_i + \log p_{ij})` is computed
with the :math:`p_{ij}` as weights (no :math:`\log 0`), so a transition matrix with zeros and a
mode of probability :math:`10^{-300}` both stay exact; a mode that cannot be reached
(:math:`c_j = 0`) keeps its own Gaussian instead of a 0/0 mix, and keeps probability 0.
Gradients stay finite there, but treat such a mode as absent (the derivative with respect to a
zero :math:`p_{ij}` that would make it reachable is 0): tune through `transition_from_logits`,
whose probabilities are never exactly 0.

Missing data follow `kalman.update`: a mask per step (scalar) or per measurement component, and
non-finite components are treated as missing (and counted by `filter`). A fully masked step only
mixes and predicts: :math:`L_j = 1`, so :math:`\mu^+ = c`.

References: H. A. P. Blom and Y. Bar-Shalom, "The interacting multiple model algorithm for
systems with Markovian switching coefficients", IEEE TAC 33(8), 1988; Bar-Shalom, Li and
Kirubarajan, *Estimation with Applications to Tracking and Navigation*, 2001, sec. 11.6.6.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple, Union

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxtrack import _checks
from jaxtrack.filters import _gaussian, _linalg, ekf, kalman, ukf
from jaxtrack.filters._gaussian import Gaussian

Array = jax.Array

__all__ = ["IMMState", "IMMResult", "LinearMode", "ExtendedMode", "UnscentedMode",
           "LinearModels", "init", "transition_from_logits", "mix", "predict", "update",
           "estimate", "filter"]


# ---------------------------------------------------------------------------------------------
# Types


class IMMState(NamedTuple):
    """The IMM belief: ``means`` [M, n], ``covs`` [M, n, n], ``log_mode_probs`` [M]
    (log mode probabilities, logsumexp 0; -inf for a mode of probability 0)."""

    means: Array
    covs: Array
    log_mode_probs: Array


class IMMResult(NamedTuple):
    """Output of `filter`.

    Attributes:
      means: [T, n] combined (moment-matched) filtered means.
      covs: [T, n, n] combined filtered covariances.
      mode_means: [T, M, n] mode-matched filtered means.
      mode_covs: [T, M, n, n] mode-matched filtered covariances.
      log_mode_probs: [T, M] filtered log mode probabilities (``mode_probs`` is their exp).
      log_likelihoods: [T] log p(z_t | z_{1:t-1}) = log sum_j c_j L_j (0 for a masked step).
      log_likelihood: scalar, the sum of ``log_likelihoods`` (0 for T = 0).
      num_invalid: measurement components flagged present that were not finite (treated as
        missing).
      num_not_pd: mode-matched covariances (over steps and modes) whose Cholesky factorisation
        failed, i.e. that were not numerically positive definite; 0 on a healthy run.
    """

    means: Array
    covs: Array
    mode_means: Array
    mode_covs: Array
    log_mode_probs: Array
    log_likelihoods: Array
    log_likelihood: Array
    num_invalid: Array
    num_not_pd: Array

    @property
    def mode_probs(self) -> Array:
        """[T, M] filtered mode probabilities."""
        return jnp.exp(self.log_mode_probs)


class LinearMode(NamedTuple):
    """A linear-Gaussian mode (Kalman filter): ``F`` [n, n], ``Q`` [n, n], ``H`` [m, n],
    ``R`` [m, m]."""

    F: Array
    Q: Array
    H: Array
    R: Array


class ExtendedMode(NamedTuple):
    """A nonlinear mode filtered by the EKF (see `ekf`): ``f(x [n]) -> [n]``, ``Q`` [n, n],
    ``h(x [n]) -> [m]``, ``R`` [m, m], optional innovation ``residual(z, z_hat) -> [m]``."""

    f: Callable
    Q: Array
    h: Callable
    R: Array
    residual: Callable | None = None


class UnscentedMode(NamedTuple):
    """A nonlinear mode filtered by the UKF (see `ukf`): ``f``, ``Q``, ``h``, ``R`` as in
    `ExtendedMode`, a sigma-point scheme and an optional measurement ``residual_z``."""

    f: Callable
    Q: Array
    h: Callable
    R: Array
    points: ukf.SigmaPoints = ukf.DEFAULT_POINTS
    residual_z: Callable | None = None


class LinearModels(NamedTuple):
    """M linear modes as stacked matrices: ``F`` [M, n, n], ``Q`` [M, n, n], ``H`` [M, m, n],
    ``R`` [M, m, m]. Equivalent to the tuple of `LinearMode`s ``modes(i)`` for i < M."""

    F: Array
    Q: Array
    H: Array
    R: Array


Mode = Union[LinearMode, ExtendedMode, UnscentedMode]
Models = Union[LinearModels, Sequence[Mode]]


# ---------------------------------------------------------------------------------------------
# Construction


def init(means: Array, covs: Array, mode_probs: Array) -> IMMState:
    """The initial `IMMState` from mode probabilities (checked: non-negative, summing to one).

    Args:
      means: [M, n] per-mode means (often M copies of one mean).
      covs: [M, n, n] per-mode covariances.
      mode_probs: [M] mode probabilities.

    Returns:
      `IMMState` with ``log_mode_probs = log(mode_probs)``.

    Example:
      >>> state = imm.init(jnp.zeros((2, 4)), jnp.stack([jnp.eye(4)] * 2),
      ...                  jnp.array([0.9, 0.1]))
    """
    _checks.check_ndim("means", means, 2, "[M, n] per-mode means")
    M, n = _checks.shape_of(means)
    _checks.check_shape("mode_probs", mode_probs, (M,), "one probability per mode")
    _check_probability_rows("mode_probs", mode_probs)
    mode_probs = jnp.asarray(mode_probs, jnp.result_type(means))
    state = IMMState(jnp.asarray(means), jnp.asarray(covs), jnp.log(mode_probs))
    _check_state(state, "init")
    return state


def transition_from_logits(logits: Array) -> Array:
    r"""Mode transition matrix from unconstrained logits: :math:`p_{ij} = \exp(l_{ij}) /
    \sum_k \exp(l_{ik})` (row-wise softmax), the parameterisation to tune with optax.

    Args:
      logits: [M, M] unconstrained.

    Returns:
      [M, M] row-stochastic transition matrix.

    Example:
      >>> logits = jnp.log(jnp.array([[0.95, 0.05], [0.1, 0.9]]))
      >>> P = imm.transition_from_logits(logits)  # equals the matrix above
    """
    _checks.check_ndim("logits", logits, 2, "[M, M] transition logits")
    _checks.check_square("logits", logits)
    return jax.nn.softmax(logits, axis=-1)


# ---------------------------------------------------------------------------------------------
# Step functions


def mix(state: IMMState, transition: Array) -> IMMState:
    r"""IMM interaction: mixed initial conditions and predicted mode probabilities.

    .. math::
        c_j = \sum_i p_{ij}\mu_i,\; \mu_{i|j} = p_{ij}\mu_i/c_j,\;
        \bar m_j = \sum_i \mu_{i|j} m_i,\;
        \bar P_j = \sum_i \mu_{i|j}(P_i + (m_i - \bar m_j)(m_i - \bar m_j)^T).

    Args:
      state: `IMMState`, means [M, n], covs [M, n, n], log_mode_probs [M].
      transition: [M, M] mode transition matrix, rows summing to one.

    Returns:
      `IMMState` with the mixed means and covariances and ``log_mode_probs = log c``.

    Example:
      >>> mixed = imm.mix(state, jnp.array([[0.95, 0.05], [0.1, 0.9]]))
    """
    M, _ = _check_state(state)
    _check_transition(transition, M)
    return _mix(state, transition)


def predict(state: IMMState, models: Models) -> IMMState:
    """Mode-matched prediction of every mode's (mixed) Gaussian; mode probabilities unchanged.

    Args:
      state: `IMMState` (normally the output of `mix`), means [M, n], covs [M, n, n].
      models: `LinearModels` or a sequence of M modes (`LinearMode`, `ExtendedMode`,
        `UnscentedMode`).

    Returns:
      The predicted `IMMState`.

    Example:
      >>> prior = imm.predict(imm.mix(state, P), models)
    """
    M, n = _check_state(state)
    modes = _modes(models)
    _check_modes(modes, M, n, None, jnp.result_type(state.means))
    return _predict(state, modes)


def update(state: IMMState, z: Array, models: Models,
           mask: Array | bool | None = None) -> tuple[IMMState, Array]:
    r"""Mode-matched updates and the mode-probability update.

    .. math::
        \mu_j^+ = c_j L_j / \textstyle\sum_k c_k L_k, \qquad
        \log p(z \mid \cdot) = \log \textstyle\sum_j c_j L_j,

    with :math:`c_j` the mode probabilities of ``state`` (after `mix`) and :math:`L_j` the
    mode-matched measurement likelihoods.

    Args:
      state: predicted `IMMState`, means [M, n], covs [M, n, n], log_mode_probs [M].
      z: [m] measurement.
      models: as in `predict`.
      mask: None, a scalar bool or [m] bools (see `kalman.update`); non-finite components are
        missing. A fully masked update returns ``state`` and log-likelihood 0.

    Returns:
      ``(posterior IMMState, log_likelihood)``.

    Example:
      >>> post, ll = imm.update(imm.predict(imm.mix(state, P), models), z, models)
      >>> imm.estimate(post).mean
    """
    M, n = _check_state(state)
    m = _gaussian.check_measurement(z, mask)
    modes = _modes(models)
    _check_modes(modes, M, n, m, jnp.result_type(state.means))
    return _update(state, z, modes, mask)


def estimate(state: IMMState) -> Gaussian:
    r"""Combined estimate, the moment-matched Gaussian of the mode mixture:
    :math:`m = \sum_j \mu_j m_j`, :math:`P = \sum_j \mu_j (P_j + (m_j - m)(m_j - m)^T)`.

    Args:
      state: `IMMState`, means [M, n], covs [M, n, n], log_mode_probs [M].

    Returns:
      `kalman.Gaussian` with mean [n], cov [n, n].

    Example:
      >>> est = imm.estimate(post)
    """
    _check_state(state)
    return _estimate(state)


# ---------------------------------------------------------------------------------------------
# Driver


def filter(init: IMMState, zs: Array, models: Models, transition: Array,
           masks: Array | None = None) -> IMMResult:
    r"""IMM filter over a sequence under `lax.scan`: `mix`, `predict`, `update` at every step.

    Args:
      init: `IMMState` before the first step (see `init`): means [M, n], covs [M, n, n],
        log_mode_probs [M].
      zs: [T, m] measurements (T may be 0).
      models: `LinearModels` or a sequence of M modes (`LinearMode`, `ExtendedMode`,
        `UnscentedMode`); close over the callables of nonlinear modes when jitting.
      transition: [M, M] mode transition matrix, :math:`p_{ij}` = P(j at t | i at t-1), rows
        summing to one (`transition_from_logits` for an unconstrained parameterisation). Cast
        to the dtype of ``init.means``.
      masks: optional [T] or [T, m] bools; False marks missing measurements.

    Returns:
      `IMMResult`.

    Example:
      >>> models = imm.LinearModels(F, Q, H, R)  # [2, 4, 4], [2, 4, 4], [2, 2, 4], [2, 2, 2]
      >>> res = imm.filter(imm.init(means, covs, jnp.array([0.5, 0.5])), zs, models,
      ...                  jnp.array([[0.95, 0.05], [0.05, 0.95]]))
      >>> res.means.shape, res.mode_probs.shape, res.log_likelihood
    """
    M, n = _check_state(init, "init")
    T, m = _gaussian.check_sequence(zs, masks)
    modes = _modes(models)
    dtype = jnp.result_type(init.means)
    _check_modes(modes, M, n, m, dtype)
    _check_transition(transition, M)
    transition = jnp.asarray(transition, dtype)
    if masks is None:
        masks = jnp.ones((T,), bool)
    masks = jnp.asarray(masks, bool)
    full = jnp.broadcast_to(masks if masks.ndim == 2 else masks[:, None], (T, m))
    num_invalid = jnp.sum(full & ~jnp.isfinite(zs))

    def body(state, inp):
        z, mask = inp
        post, ll = _update(_predict(_mix(state, transition), modes), z, modes, mask)
        est = _estimate(post)
        not_pd = jnp.sum(~_is_pd(post.covs))
        return post, (est.mean, est.cov, post, ll, not_pd)

    _, (means, covs, post, lls, not_pd) = lax.scan(body, init, (jnp.asarray(zs), masks))
    return IMMResult(means, covs, post.means, post.covs, post.log_mode_probs, lls,
                     jnp.sum(lls), num_invalid, jnp.sum(not_pd))


# ---------------------------------------------------------------------------------------------
# Unchecked cores


def _mix(state, transition):
    log_mu = state.log_mode_probs
    num_modes = log_mu.shape[0]
    # logsumexp with the p_ij as weights: no log 0 for forbidden transitions. An unreachable
    # mode (c_j = 0) gets log c_j = -inf through a where, so that gradients stay finite.
    reachable = jnp.any((transition > 0) & (log_mu > -jnp.inf)[:, None], axis=0)
    safe_log_mu = jnp.where(reachable[None, :], log_mu[:, None], 0.0)
    safe_transition = jnp.where(reachable[None, :], transition, 1.0)
    safe_log_c = jax.nn.logsumexp(safe_log_mu, axis=0, b=safe_transition)
    log_c = jnp.where(reachable, safe_log_c, -jnp.inf)
    weights = transition * jnp.exp(log_mu[:, None] - safe_log_c[None, :])  # mu_{i|j} [i, j]
    # c_j = 0: mode j has probability 0 whatever its Gaussian; keep its own (no 0/0)
    weights = jnp.where(reachable[None, :], weights, jnp.eye(num_modes, dtype=weights.dtype))
    means = weights.T @ state.means  # [j, n]
    dev = state.means[None, :, :] - means[:, None, :]  # [j, i, n]
    spread = state.covs[None] + dev[..., :, None] * dev[..., None, :]  # [j, i, n, n]
    covs = jnp.einsum("ij,jikl->jkl", weights, spread)
    return IMMState(means, _linalg.symmetrize(covs), log_c)


def _predict(state, modes):
    preds = [_predict_mode(mode, Gaussian(state.means[i], state.covs[i]))
             for i, mode in enumerate(modes)]
    return IMMState(jnp.stack([p.mean for p in preds]), jnp.stack([p.cov for p in preds]),
                    state.log_mode_probs)


def _update(state, z, modes, mask):
    posts, lls = zip(*[_update_mode(mode, Gaussian(state.means[i], state.covs[i]), z, mask)
                       for i, mode in enumerate(modes)])
    joint = state.log_mode_probs + jnp.stack(lls)  # log c_j L_j
    ll = jax.nn.logsumexp(joint)
    # without a measurement L_j = 1: keep log c exactly (not renormalised up to rounding)
    any_present = jnp.any(kalman.effective_mask(z, mask))
    log_mode_probs = jnp.where(any_present, joint - ll, state.log_mode_probs)
    ll = jnp.where(any_present, ll, 0.0)
    post = IMMState(jnp.stack([p.mean for p in posts]), jnp.stack([p.cov for p in posts]),
                    log_mode_probs)
    return post, ll


def _estimate(state):
    mu = jnp.exp(state.log_mode_probs)
    mean = mu @ state.means
    dev = state.means - mean
    cov = jnp.einsum("j,jkl->kl", mu, state.covs + dev[:, :, None] * dev[:, None, :])
    return Gaussian(mean, _linalg.symmetrize(cov))


# The public step functions of kalman / ekf / ukf: traced here, their checks read shapes only.


def _predict_mode(mode, g):
    if isinstance(mode, LinearMode):
        return kalman.predict(g, mode.F, mode.Q)
    if isinstance(mode, ExtendedMode):
        return ekf.predict(g, mode.f, mode.Q)
    return ukf.predict(g, mode.f, mode.Q, points=mode.points)


def _update_mode(mode, g, z, mask):
    if isinstance(mode, LinearMode):
        return kalman.update(g, z, mode.H, mode.R, mask)
    if isinstance(mode, ExtendedMode):
        return ekf.update(g, z, mode.h, mode.R, mask, mode.residual)
    return ukf.update(g, z, mode.h, mode.R, points=mode.points, mask=mask,
                      residual_z=mode.residual_z)


def _is_pd(covs):
    """[M] bools: the Cholesky factor of each covariance [M, n, n] is finite and positive."""
    low = _linalg.cholesky(covs)
    diag = jnp.diagonal(low, axis1=-2, axis2=-1)
    return jnp.all(jnp.isfinite(low), axis=(-2, -1)) & jnp.all(diag > 0, axis=-1)


def _modes(models):
    if isinstance(models, LinearModels):
        M = _checks.shape_of(models.F)[0] if np.ndim(models.F) == 3 else None
        for name, x in zip(LinearModels._fields, models):
            _checks.check_ndim(f"models.{name}", x, 3, f"[M, ., .] stacked {name} (one per mode)")
            _checks.check_shape(f"models.{name}", x, (M, None, None), "same M for F, Q, H, R")
        return tuple(LinearMode(*(a[i] for a in models)) for i in range(M))
    if isinstance(models, (LinearMode, ExtendedMode, UnscentedMode)) or not isinstance(
            models, Sequence):
        raise TypeError("models must be an imm.LinearModels or a sequence of imm.LinearMode / "
                        f"ExtendedMode / UnscentedMode; got {type(models).__name__}")
    return tuple(models)


# ---------------------------------------------------------------------------------------------
# Boundary checks (shapes always; values of concrete arrays only, see jaxtrack._checks)


def _tolerance(x):
    return 1e-5 if jnp.result_type(x) in (jnp.float32, jnp.float16, jnp.bfloat16) else 1e-9


def _check_probability_rows(name, p):
    """If concrete: finite, non-negative, and each row (or the vector) summing to one."""
    if not _checks.is_concrete(p):
        return
    a = np.asarray(p, np.float64)
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains NaN or inf")
    if np.any(a < 0):
        raise ValueError(f"{name} must be non-negative; smallest entry {a.min():.3g}")
    sums = np.sum(a, axis=-1)
    err = np.max(np.abs(sums - 1.0))
    if err > _tolerance(p) * a.shape[-1]:
        what = "each row of " + name if a.ndim == 2 else name
        raise ValueError(f"{what} must sum to 1; got sums {np.round(sums, 12).tolist()}")


def _check_transition(transition, M):
    _checks.check_shape("transition", transition, (M, M),
                        "[M, M] mode transition matrix, one row and column per mode")
    _check_probability_rows("transition", transition)


def _check_state(state, name="state"):
    if not isinstance(state, IMMState):
        raise TypeError(f"{name} must be an imm.IMMState; got {type(state).__name__}")
    _checks.check_ndim(f"{name}.means", state.means, 2, "[M, n] per-mode means")
    M, n = _checks.shape_of(state.means)
    if M < 1:
        raise ValueError(f"{name} must have at least one mode; got means of shape [0, {n}]")
    _checks.check_covariance(f"{name}.covs", state.covs, n, batch_axes=1)
    _checks.check_shape(f"{name}.covs", state.covs, (M, n, n))
    _checks.check_finite(f"{name}.means", state.means)
    _checks.check_shape(f"{name}.log_mode_probs", state.log_mode_probs, (M,),
                        "one log probability per mode")
    if _checks.is_concrete(state.log_mode_probs):
        logs = np.asarray(state.log_mode_probs, np.float64)
        if np.any(np.isnan(logs)) or np.any(logs == np.inf):
            raise ValueError(f"{name}.log_mode_probs contains NaN or +inf")
        total = float(np.sum(np.exp(logs)))
        if abs(total - 1.0) > _tolerance(state.log_mode_probs) * M:
            raise ValueError(f"{name}.log_mode_probs must be log probabilities summing to 1; "
                             f"exp sums to {total:.12g}")
    return M, n


def _check_modes(modes, M, n, m, dtype):
    if len(modes) != M:
        raise ValueError(f"models has {len(modes)} modes but the state has M = {M}")
    for i, mode in enumerate(modes):
        name = f"models[{i}]"
        if isinstance(mode, LinearMode):
            _checks.check_shape(f"{name}.F", mode.F, (n, n), "state transition")
            _checks.check_covariance(f"{name}.Q", mode.Q, n)
            _checks.check_ndim(f"{name}.H", mode.H, 2, "an [m, n] measurement matrix")
            _checks.check_shape(f"{name}.H", mode.H, (m, n), "measurement matrix")
            _checks.check_covariance(f"{name}.R", mode.R, jnp.shape(mode.H)[0])
        elif isinstance(mode, (ExtendedMode, UnscentedMode)):
            _checks.check_callable(f"{name}.f", mode.f)
            _checks.check_callable(f"{name}.h", mode.h)
            _checks.check_covariance(f"{name}.Q", mode.Q, n)
            x = jax.ShapeDtypeStruct((n,), dtype)
            _checks.check_shape(f"{name}.f(x)", jax.eval_shape(mode.f, x), (n,),
                                "the transition must map [n] to [n]")
            out = jax.eval_shape(mode.h, x)
            _checks.check_ndim(f"{name}.h(x)", out, 1, "an [m] vector")
            _checks.check_shape(f"{name}.h(x)", out, (m,), "the measurement function must map "
                                "[n] to [m]")
            _checks.check_covariance(f"{name}.R", mode.R, out.shape[0])
            if isinstance(mode, UnscentedMode) and not isinstance(mode.points, ukf.SigmaPoints):
                raise TypeError(f"{name}.points must be a ukf.SigmaPoints (ukf.merwe_points() "
                                f"or ukf.julier_points()); got {type(mode.points).__name__}")
        else:
            raise TypeError(f"{name} must be an imm.LinearMode, ExtendedMode or UnscentedMode; "
                            f"got {type(mode).__name__}")
