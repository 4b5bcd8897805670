r"""Gradient tuning of parameter pytrees with optax, over batches of episodes.

`fit` minimises :math:`L(\theta) = \frac{1}{B}\sum_{b=1}^{B} \ell(k_b, \theta)` where
``loss_fn(key, params) -> scalar`` is the loss of one episode and the ``B`` keys are fresh at
every step (stochastic optimisation over the episode distribution). A step whose loss or
gradient is not finite is *skipped* (parameters and optimiser state unchanged) and reported in
the history, never applied.

Two gradients are available. ``gradient="pathwise"`` (default) differentiates the loss with
`jax.value_and_grad`. ``gradient="smoothed"`` estimates the gradient of the Gaussian-smoothed
loss :math:`L_\sigma(\theta) = E_{\epsilon \sim N(0, I)}[L(\theta + \sigma \epsilon)]` by
antithetic perturbations (`smoothed_value_and_grad`), from loss values only. Use it for closed
loops whose loss jumps with the parameters (a detection gained or lost, a gate or a stop
switching): the pathwise derivative does not see the jumps, and through a long chaotic loop its
tangent can grow without bound, while :math:`\nabla L_\sigma` accounts for both.

Parameters are unconstrained float leaves; map them to the constrained values a model needs
with `positive` (softplus), `exp`-style log parameters, or `cholesky_from_unconstrained` for
covariances. The inverse maps give initial values.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.flatten_util import ravel_pytree

GRADIENTS = ("pathwise", "smoothed")

__all__ = ["History", "fit", "smoothed_value_and_grad", "GRADIENTS", "positive",
           "positive_inverse", "cholesky_from_unconstrained", "unconstrained_from_cholesky",
           "covariance_from_unconstrained"]


class History(NamedTuple):
    """Optimisation trace returned by `fit` (numpy arrays).

    Attributes:
      loss: [steps] mean training loss of each step's batch (before the update).
      grad_norm: [steps] global gradient norm (before clipping).
      skipped: [steps] bools, steps whose loss or gradient was not finite.
      params: parameter pytree with leaves stacked to [steps + 1, ...] (initial first).
      val_steps: [V] steps at which the validation loss was computed.
      val_loss: [V] validation loss (mean over the fixed validation keys).
    """

    loss: np.ndarray
    grad_norm: np.ndarray
    skipped: np.ndarray
    params: Any
    val_steps: np.ndarray
    val_loss: np.ndarray


def smoothed_value_and_grad(loss_fn: Callable, params, keys: jax.Array, key: jax.Array,
                            smoothing: float = 0.1, directions: int = 8):
    r"""Antithetic Gaussian-smoothing estimate of the batch-mean loss and its gradient.

    With the parameters flattened to :math:`\theta \in R^D`, ``K = directions`` draws
    :math:`\epsilon_k \sim N(0, I_D)` and the ``B`` episode keys :math:`k_b` (common random
    numbers: the same episodes at :math:`\theta \pm \sigma \epsilon_k`),

    .. math::
        \hat g = \frac{1}{K B} \sum_{k, b} \epsilon_k
            \frac{\ell(k_b, \theta + \sigma \epsilon_k) - \ell(k_b, \theta - \sigma \epsilon_k)}
                 {2 \sigma},

    an unbiased estimate of :math:`\nabla L_\sigma(\theta)`, the gradient of the smoothed loss
    :math:`L_\sigma(\theta) = E_\epsilon[L(\theta + \sigma \epsilon)]` (exactly
    :math:`\nabla L` for a quadratic :math:`L`). It needs loss values only (``2 K B`` episodes,
    all in one `vmap`), so it works where `jax.grad` cannot (loops, argmax, jumps). The value
    returned is the mean of the ``2 K B`` losses, an estimate of :math:`L_\sigma(\theta)`.

    Args:
      loss_fn: ``loss_fn(key, params) -> scalar`` for one episode.
      params: parameter pytree (float leaves; the smoothing is the same ``smoothing`` in every
        unconstrained coordinate, so log-parameters are perturbed by a relative amount).
      keys: [B] episode keys.
      key: PRNG key of the directions.
      smoothing: :math:`\sigma > 0`.
      directions: :math:`K \ge 1` antithetic pairs.

    Returns:
      ``(value, grads)``: scalar and a pytree like ``params``.

    Example:
      >>> loss = lambda k, p: jnp.floor(10.0 * (p["x"] - 1.0) ** 2) / 10.0  # a staircase
      >>> keys = jax.random.split(jax.random.PRNGKey(0), 4)
      >>> value, g = smoothed_value_and_grad(loss, {"x": 0.0}, keys, jax.random.PRNGKey(1),
      ...                                    smoothing=0.2, directions=256)
    """
    _check_smoothing(smoothing, directions)
    flat, unravel = ravel_pytree(params)
    if not jnp.issubdtype(flat.dtype, jnp.floating):
        raise TypeError("params must be a pytree of float arrays")
    eps = jax.random.normal(key, (directions, flat.size), flat.dtype)
    thetas = jnp.concatenate([flat + smoothing * eps, flat - smoothing * eps])   # [2K, D]
    per_theta = lambda th: jax.vmap(loss_fn, (0, None))(keys, unravel(th))  # noqa: E731
    losses = jax.vmap(per_theta)(thetas)                                       # [2K, B]
    diff = (losses[:directions] - losses[directions:]) / (2.0 * smoothing)     # [K, B]
    grad = jnp.einsum("kb,kd->d", diff, eps) / (directions * losses.shape[1])
    return jnp.mean(losses), unravel(grad.astype(flat.dtype))


def _check_smoothing(smoothing, directions):
    if not (isinstance(directions, int) and directions >= 1):
        raise ValueError(f"directions must be a positive int; got {directions!r}")
    if not (np.isfinite(smoothing) and smoothing > 0):
        raise ValueError(f"smoothing must be a finite positive number; got {smoothing!r}")


def fit(loss_fn: Callable, params, key, optimizer: optax.GradientTransformation | None = None,
        steps: int = 200, batch_size: int = 32, validation=None, validate_every: int = 10,
        clip_norm: float | None = 10.0, progress: bool = True, gradient: str = "pathwise",
        smoothing: float = 0.1, directions: int = 8) -> tuple[Any, History]:
    """Minimise the batch-mean of ``loss_fn`` with an optax optimiser.

    Args:
      loss_fn: ``loss_fn(key, params) -> scalar`` for one episode (vmapped over the batch).
      params: initial parameter pytree (unconstrained float leaves).
      key: PRNG key, split into a training key (step ``i`` uses
        ``split(fold_in(train_key, i), batch_size)``) and a validation key.
      optimizer: an optax ``GradientTransformation`` (default ``optax.adam(0.05)``).
      steps: number of optimisation steps.
      batch_size: episodes per step.
      validation: None, an int (that many fixed held-out keys derived from ``key``), or an array
        of keys [V]; its mean loss is recorded every ``validate_every`` steps and at the end.
      clip_norm: clip the gradient to this global norm before the optimiser (None: no clip).
      progress: print a progress line (loss, gradient norm, steps/s) to stderr.
      gradient: ``"pathwise"`` (`jax.value_and_grad` of the batch mean) or ``"smoothed"``
        (`smoothed_value_and_grad` with ``smoothing`` and ``directions``: ``2 * directions *
        batch_size`` episodes per step, loss values only; the recorded loss is then the mean
        over the perturbed episodes).

    Returns:
      ``(params, history)``: the final parameters and a `History`.

    Example:
      >>> def loss(key, p):
      ...     return (jax.random.normal(key) + 3.0 - p["mu"]) ** 2
      >>> params, hist = fit(loss, {"mu": 0.0}, jax.random.PRNGKey(0), steps=100)
    """
    if not callable(loss_fn):
        raise TypeError("loss_fn must be callable as loss_fn(key, params)")
    if steps < 1 or batch_size < 1:
        raise ValueError("steps and batch_size must be positive")
    if gradient not in GRADIENTS:
        raise ValueError(f"unknown gradient {gradient!r}; expected one of {GRADIENTS}")
    if gradient == "smoothed":
        _check_smoothing(smoothing, directions)
    leaves = jax.tree_util.tree_leaves(params)
    if not leaves or not all(jnp.issubdtype(jnp.asarray(x).dtype, jnp.floating) for x in leaves):
        raise TypeError("params must be a non-empty pytree of float arrays")
    # Strong dtypes from the start: weak-typed leaves (Python floats) would change type after
    # the first update and compile the step twice.
    params = jax.tree_util.tree_map(lambda x: jnp.array(x, dtype=jnp.asarray(x).dtype), params)
    if optimizer is None:
        optimizer = optax.adam(0.05)
    if clip_norm is not None:
        optimizer = optax.chain(optax.clip_by_global_norm(clip_norm), optimizer)
    opt_state = optimizer.init(params)

    train_key, val_key = jax.random.split(key)

    def batch_loss(p, keys):
        return jnp.mean(jax.vmap(loss_fn, in_axes=(0, None))(keys, p))

    @jax.jit
    def update(p, state, i):
        step_key = jax.random.fold_in(train_key, i)
        keys = jax.random.split(step_key, batch_size)
        if gradient == "smoothed":
            loss, grads = smoothed_value_and_grad(loss_fn, p, keys,
                                                  jax.random.fold_in(step_key, 1),
                                                  smoothing, directions)
        else:
            loss, grads = jax.value_and_grad(batch_loss)(p, keys)
        gnorm = optax.tree.norm(grads)
        ok = jnp.isfinite(loss) & jnp.isfinite(gnorm)
        updates, new_state = optimizer.update(grads, state, p)
        new_p = optax.apply_updates(p, updates)
        keep = lambda new, old: jax.tree_util.tree_map(  # noqa: E731
            lambda a, b: jnp.where(ok, a, b), new, old)
        return keep(new_p, p), keep(new_state, state), loss, gnorm, ~ok

    val_keys = None
    if validation is not None:
        if isinstance(validation, int):
            val_keys = jax.random.split(val_key, validation)
        else:
            val_keys = jnp.asarray(validation)
        val_fn = jax.jit(batch_loss)

    trace = [params]
    losses, gnorms, skipped, val_steps, val_losses = [], [], [], [], []
    t0 = time.perf_counter()
    for i in range(steps):
        if val_keys is not None and i % validate_every == 0:
            val_steps.append(i)
            val_losses.append(float(val_fn(params, val_keys)))
        params, opt_state, loss, gnorm, skip = update(params, opt_state, i)
        losses.append(float(loss))
        gnorms.append(float(gnorm))
        skipped.append(bool(skip))
        trace.append(params)
        if progress and (i % max(1, steps // 20) == 0 or i == steps - 1):
            rate = (i + 1) / (time.perf_counter() - t0)
            end = "\n" if i == steps - 1 or not sys.stderr.isatty() else "\r"
            print(f"step {i + 1}/{steps}  loss {losses[-1]:.5g}  |grad| {gnorms[-1]:.3g}  "
                  f"skipped {sum(skipped)}  {rate:.1f} steps/s", end=end, file=sys.stderr,
                  flush=True)
    if val_keys is not None:
        val_steps.append(steps)
        val_losses.append(float(val_fn(params, val_keys)))
    stacked = jax.tree_util.tree_map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *trace)
    history = History(np.asarray(losses), np.asarray(gnorms), np.asarray(skipped), stacked,
                      np.asarray(val_steps, int), np.asarray(val_losses))
    return params, history


def positive(x, minimum: float = 0.0):
    """Softplus map from an unconstrained value to ``(minimum, inf)``."""
    return minimum + jax.nn.softplus(x)


def positive_inverse(y, minimum: float = 0.0):
    """Inverse of `positive`: the unconstrained value that maps to ``y`` (> minimum)."""
    z = jnp.asarray(y) - minimum
    return z + jnp.log(-jnp.expm1(-z))


def cholesky_from_unconstrained(v, n: int):
    """Lower-triangular factor with positive diagonal from ``n (n + 1) / 2`` free values.

    The first ``n`` entries of ``v`` pass through softplus to the diagonal; the rest fill the
    strictly lower triangle row by row.
    """
    v = jnp.asarray(v)
    if v.shape[-1] != n * (n + 1) // 2:
        raise ValueError(f"need {n * (n + 1) // 2} values for n = {n}; got {v.shape[-1]}")
    rows, cols = np.tril_indices(n, -1)
    low = jnp.zeros(v.shape[:-1] + (n, n), v.dtype)
    low = low.at[..., rows, cols].set(v[..., n:])
    diag = jax.nn.softplus(v[..., :n])
    return low.at[..., np.arange(n), np.arange(n)].set(diag)


def unconstrained_from_cholesky(low):
    """Inverse of `cholesky_from_unconstrained` ([..., n, n] -> [..., n (n + 1) / 2])."""
    low = jnp.asarray(low)
    n = low.shape[-1]
    rows, cols = np.tril_indices(n, -1)
    diag = positive_inverse(jnp.diagonal(low, axis1=-2, axis2=-1))
    return jnp.concatenate([diag, low[..., rows, cols]], -1)


def covariance_from_unconstrained(v, n: int):
    """Symmetric positive-definite ``L L^T`` from free values (see
    `cholesky_from_unconstrained`)."""
    low = cholesky_from_unconstrained(v, n)
    return low @ jnp.swapaxes(low, -1, -2)

