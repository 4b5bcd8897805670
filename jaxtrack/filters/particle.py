r"""Particle filters: weighted particle sets, resampling, differentiable resampling, SIR.

A `ParticleSet` holds particles [N, n] and *log* weights [N]; weights never leave log space.
One step of the bootstrap (SIR) filter, `step`, is

1. resample the incoming set if its ESS is below ``ess_threshold * N`` (adaptive resampling:
   the threshold is an array, so changing it does not recompile);
2. propagate every particle with ``transition(key, x)``;
3. reweight with ``log_likelihood(z, x)``:
   :math:`\log w_t^i = \log \bar w_{t-1}^i + \log p(z_t | x_t^i) - \log \hat p(z_t | z_{1:t-1})`,
   with the marginal-likelihood increment
   :math:`\log \hat p(z_t | z_{1:t-1}) = \operatorname{logsumexp}_i(\log \bar w_{t-1}^i +
   \log p(z_t | x_t^i))` over normalised incoming weights :math:`\bar w`.

A masked step only propagates. A measurement array with a NaN or inf is treated as masked, as
the Kalman filters treat one, and `filter` counts it (``num_invalid``), so one corrupt reading
cannot turn an episode's log-likelihood (and a batch-mean loss's gradient) into NaN. A
measurement *pytree* (e.g. padded detections with their own mask, whose absent slots may hold
NaN) is handed to the likelihood as it is: the likelihood masks its own padding. If every particle gets zero likelihood (all log weights ``-inf``), the step is
*degenerate*: the increment is ``-inf``, the weights are reset to uniform over the propagated
particles (so nothing turns into NaN) and `filter` counts it. NaN and ``+inf``
log-likelihoods of single particles count as ``-inf`` (a particle whose density is not a
number gets no weight). Particles of zero weight do not enter the moments, so a NaN particle
of zero weight leaves the mean finite.

Resamplers map ``(key, log_weights [N], num=None) -> ancestors [num]``: `multinomial`,
`systematic`, `stratified`, `residual`. Differentiable resampling (`stop_gradient_resampling`,
`soft_resampling`, `optimal_transport_resampling`) changes what the gradient of the
log-likelihood estimate means; each documents it. The default stays the exact,
non-differentiable `systematic`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.scipy.special import logsumexp

from jaxtrack import _checks
from jaxtrack.angles import wrap
from jaxtrack.filters import _linalg

Array = jax.Array

__all__ = [
    "ParticleSet", "ParticleFilterResult", "Resampling", "normalize", "ess", "weighted_mean",
    "weighted_cov", "multinomial", "systematic", "stratified", "residual",
    "stop_gradient_resampling", "soft_resampling", "optimal_transport_resampling", "step",
    "filter", "init_from_gaussian",
]


class ParticleSet(NamedTuple):
    """Weighted particles: ``particles`` [N, n], ``log_weights`` [N] (normalised or not)."""

    particles: Array
    log_weights: Array


class ParticleFilterResult(NamedTuple):
    """Output of `filter`.

    Attributes:
      means: [T, n] weighted posterior means (circular for ``angle_dims``).
      covs: [T, n, n] weighted posterior covariances (None if ``return_covs=False``).
      ess: [T] effective sample size after each update.
      log_likelihoods: [T] increments :math:`\\log \\hat p(z_t | z_{1:t-1})`.
      log_likelihood: scalar sum of the increments.
      resampled: [T] bools, whether the step resampled before propagating.
      num_degenerate: number of steps where every particle had zero likelihood.
      final: the last `ParticleSet`.
      particles: [T, N, n] particles, only if ``return_particles=True`` (else None).
      num_invalid: number of steps whose measurement was flagged present but held NaN or inf,
        and was therefore treated as missing.
    """

    means: Array
    covs: Array | None
    ess: Array
    log_likelihoods: Array
    log_likelihood: Array
    resampled: Array
    num_degenerate: Array
    final: ParticleSet
    particles: Array | None = None
    num_invalid: Array | None = None


# ---------------------------------------------------------------------------------------------
# Weights and moments


def normalize(log_weights: Array) -> Array:
    """Log weights shifted so that they sum to one in linear space: ``lw - logsumexp(lw)``.

    If every weight is ``-inf`` the result is uniform (``-log N``) instead of NaN.
    """
    total = logsumexp(log_weights)
    n = log_weights.shape[-1]
    ok = jnp.isfinite(total)
    return jnp.where(ok, log_weights - jnp.where(ok, total, 0.0), -math.log(n))


def ess(log_weights: Array) -> Array:
    r"""Effective sample size :math:`1 / \sum_i \bar w_i^2`, computed in log space.

    Example:
      >>> ess(jnp.zeros(100))  # 100.0
    """
    lw = normalize(log_weights)
    return jnp.exp(-logsumexp(2.0 * lw))


def weighted_mean(ps: ParticleSet, angle_dims: Sequence[int] = ()) -> Array:
    """Weighted mean [n]; components in ``angle_dims`` use the circular mean."""
    return _mean(jnp.exp(normalize(ps.log_weights)), ps.particles, angle_dims)


def weighted_cov(ps: ParticleSet, angle_dims: Sequence[int] = (),
                 mean: Array | None = None) -> Array:
    """Weighted covariance [n, n] about the weighted mean (wrapped deviations for angles)."""
    w = jnp.exp(normalize(ps.log_weights))
    if mean is None:
        mean = _mean(w, ps.particles, angle_dims)
    return _cov(w, ps.particles, mean, angle_dims)


def _mean(w, particles, angle_dims):
    particles = jnp.where(w[:, None] > 0, particles, 0.0)
    mean = w @ particles
    for d in angle_dims:
        ang = particles[:, d]
        mean = mean.at[d].set(jnp.arctan2(w @ jnp.sin(ang), w @ jnp.cos(ang)))
    return mean


def _cov(w, particles, mean, angle_dims):
    dev = jnp.where(w[:, None] > 0, particles - mean, 0.0)
    for d in angle_dims:
        dev = dev.at[:, d].set(wrap(dev[:, d]))
    return _linalg.symmetrize((dev.T * w) @ dev)


# ---------------------------------------------------------------------------------------------
# Resamplers: (key, log_weights [N], num=None) -> ancestors [num]


def _weights(log_weights):
    return jnp.exp(normalize(log_weights))


def _cdf(w):
    """Normalised CDF [N] of linear weights ``w`` [N] (summing to about one).

    A pairwise (tree) prefix sum: on XLA:CPU it is faster than ``jnp.cumsum`` (measurements:
    docs/design_notes.md, "Particle filter: a pairwise prefix sum for the CDF") and its
    rounding error grows as log N instead of N. Rounding can leave ``cdf[-1]`` slightly
    off 1; the rescale lets every u in [0, 1) find an index.
    """
    cdf = lax.associative_scan(jnp.add, w)
    return cdf / cdf[-1]


def _invert(cdf, u):
    # (U + i) / num can round up to 1 (float32, large num), which would select the last particle
    # even at zero weight; below 1 the search stops at the last particle with positive weight.
    u = jnp.minimum(u, 1.0 - jnp.finfo(cdf.dtype).epsneg)
    idx = jnp.searchsorted(cdf, u, side="right", method="scan")
    return jnp.clip(idx, 0, cdf.shape[0] - 1).astype(jnp.int32)


def _ancestors_from_counts(w, below, num):
    r"""Ancestors [num] of sorted points in [0, 1) given ``below`` [N], the number of points
    strictly below each ``cdf[i]``.

    Particle i owns the slots ``[below[i-1], below[i])``: each particle with a non-empty range
    writes its index at the range's start and a running max over the slots fills the rest,
    O(N + num) instead of a binary search per point. The tree prefix sum of the CDF is not
    exactly flat across zero weights, so zero-weight particles write nothing: the slots a
    rounding error would give them go to the positive-weight particle before them.
    """
    n = w.shape[0]
    index = jnp.arange(n, dtype=jnp.int32)
    start = jnp.concatenate([jnp.zeros((1,), jnp.int32), below[:-1]])
    owns = (w > 0) & (below > start)
    first_alive = jnp.argmax(w > 0).astype(jnp.int32)
    slots = jnp.full((num,), first_alive).at[start].max(jnp.where(owns, index, 0), mode="drop")
    return lax.associative_scan(jnp.maximum, slots)


def _systematic_w(key, w, num):
    # Points (U + j) / num below c: j < num c - U, i.e. ceil(num c - U) of them. The same
    # ancestors as searching every point in the CDF, but for rounding at the boundaries.
    u = jax.random.uniform(key, (), dtype=w.dtype)
    below = jnp.clip(jnp.ceil(num * _cdf(w) - u), 0, num).astype(jnp.int32)
    return _ancestors_from_counts(w, below, num)


def _stratified_w(key, w, num):
    # Points (U_j + j) / num below c: all j < k = floor(num c), and j = k if U_k < num c - k.
    u = jax.random.uniform(key, (num,), dtype=w.dtype)
    scaled = num * _cdf(w)
    k = jnp.clip(jnp.floor(scaled), 0, num).astype(jnp.int32)
    extra = (k < num) & (u[jnp.minimum(k, num - 1)] < scaled - k)
    return _ancestors_from_counts(w, k + extra.astype(jnp.int32), num)


def _multinomial_w(key, w, num):
    u = jnp.sort(jax.random.uniform(key, (num,), dtype=w.dtype))
    return _invert(_cdf(w), u)


def _residual_w(key, w, num):
    n = w.shape[0]
    scaled = num * w
    counts = jnp.floor(scaled).astype(jnp.int32)
    cum = jnp.cumsum(counts)
    slots = jnp.arange(num)
    deterministic = jnp.clip(jnp.searchsorted(cum, slots, side="right", method="scan"), 0, n - 1)
    rest = scaled - counts
    # Unsorted uniforms: the last slots must hold i.i.d. draws, not the largest of num sorted
    # ones (which would favour high-index particles).
    total = jnp.sum(rest)
    rest_w = jnp.where(total > 0, rest / jnp.where(total > 0, total, 1.0), w)
    drawn = _invert(_cdf(rest_w), jax.random.uniform(key, (num,), dtype=w.dtype))
    return jnp.where(slots < cum[-1], deterministic, drawn).astype(jnp.int32)


def multinomial(key: Array, log_weights: Array, num: int | None = None) -> Array:
    """Multinomial resampling: ``num`` i.i.d. draws from the weights (sorted uniforms + one
    search, O(N log N)).

    Example:
      >>> ancestors = multinomial(key, log_weights)
    """
    num = log_weights.shape[-1] if num is None else num
    return _multinomial_w(key, _weights(log_weights), num)


def systematic(key: Array, log_weights: Array, num: int | None = None) -> Array:
    r"""Systematic resampling: one uniform :math:`U`, points :math:`(U + i) / num`.

    Particle i receives the points in :math:`[C_{i-1}, C_i)` of its CDF, whose number is
    :math:`\lceil num\,C_i - U \rceil - \lceil num\,C_{i-1} - U \rceil`: ancestors come from
    these offspring counts in O(N + num), no search.
    """
    num = log_weights.shape[-1] if num is None else num
    return _systematic_w(key, _weights(log_weights), num)


def stratified(key: Array, log_weights: Array, num: int | None = None) -> Array:
    r"""Stratified resampling: one uniform per stratum, points :math:`(U_i + i) / num`
    (ancestors from offspring counts, as `systematic`)."""
    num = log_weights.shape[-1] if num is None else num
    return _stratified_w(key, _weights(log_weights), num)


def residual(key: Array, log_weights: Array, num: int | None = None) -> Array:
    r"""Residual resampling: :math:`\lfloor num\,\bar w_i \rfloor` deterministic copies of each
    particle, the remaining slots drawn multinomially from the residual weights.

    Fixed shapes: the first ``sum(floor(num w))`` slots hold the deterministic copies in index
    order, the rest the multinomial draws.
    """
    num = log_weights.shape[-1] if num is None else num
    return _residual_w(key, _weights(log_weights), num)


RESAMPLERS = {"multinomial": multinomial, "systematic": systematic, "stratified": stratified,
              "residual": residual}
# The same resamplers on normalised linear weights: (key, w [N], num) -> ancestors [num].
_FROM_WEIGHTS = {multinomial: _multinomial_w, systematic: _systematic_w,
                 stratified: _stratified_w, residual: _residual_w}


# ---------------------------------------------------------------------------------------------
# Differentiable resampling: (key, particles, log_weights) -> (particles, log_weights)


@dataclasses.dataclass(frozen=True)
class Resampling:
    """A particle-level resampling scheme: ``apply(key, particles [N, n], log_weights [N]) ->
    (particles [N, n], log_weights [N])``. Build with `stop_gradient_resampling`,
    `soft_resampling` or `optimal_transport_resampling`; a plain ancestor resampler passed to
    `step` is wrapped in the standard (gather, uniform weights) scheme."""

    apply: Callable
    name: str
    # For the built-in ancestor resamplers: ``(key, particles, w [N]) -> (particles,
    # log_weights)`` on normalised linear weights, so `filter` computes them once per step.
    apply_weights: Callable | None = dataclasses.field(default=None, repr=False)


jax.tree_util.register_static(Resampling)


def _standard(resampler):
    def apply(key, particles, log_weights):
        n = log_weights.shape[-1]
        a = resampler(key, log_weights)
        return particles[a], jnp.full((n,), -math.log(n), log_weights.dtype)

    from_weights = _FROM_WEIGHTS.get(resampler)

    def apply_weights(key, particles, w):
        n = w.shape[-1]
        a = from_weights(key, w, n)
        return particles[a], jnp.full((n,), -math.log(n), w.dtype)

    return Resampling(apply, getattr(resampler, "__name__", "custom"),
                      None if from_weights is None else apply_weights)


def stop_gradient_resampling(resampler: Callable = systematic) -> Resampling:
    r"""Stop-gradient resampling (Scibior & Wood 2021).

    Forward pass identical to ``resampler`` (uniform weights after resampling); the new log
    weights are :math:`\log w_{a_i} - \perp(\log w_{a_i}) - \log N`, so their value is uniform
    but their gradient is that of the selected weights. With reparameterised transitions the
    gradient of the resulting log-marginal-likelihood estimate is a consistent estimate of the
    score :math:`\nabla_\theta \log p_\theta(z_{1:T})` (Fisher's identity), with no bias from
    ignoring the discrete resampling.

    Example:
      >>> res = particle.filter(key, init, zs, f, g, resampler=stop_gradient_resampling())
    """
    def apply(key, particles, log_weights):
        n = log_weights.shape[-1]
        lw = normalize(log_weights)
        a = resampler(key, lax.stop_gradient(lw))
        sel = lw[a]
        return particles[a], sel - lax.stop_gradient(sel) - math.log(n)

    return Resampling(apply, "stop_gradient")


def soft_resampling(alpha: float, resampler: Callable = systematic) -> Resampling:
    r"""Soft resampling (Karkus et al. 2018).

    Ancestors are drawn from :math:`q_i = \alpha \bar w_i + (1 - \alpha)/N` and get the
    importance weights :math:`\bar w_{a} / q_{a}`, through which gradients flow. The gradient is
    biased (the draw itself is not differentiated) with a bias that vanishes as
    :math:`\alpha \to 0` (no resampling) at the price of weight degeneracy; ``alpha = 1`` is
    standard resampling (uniform weights, zero gradient through the weights).

    Example:
      >>> scheme = soft_resampling(0.5)
    """
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"alpha must be in [0, 1]; got {alpha}")

    def apply(key, particles, log_weights):
        n = log_weights.shape[-1]
        lw = normalize(log_weights)
        log_q = jnp.logaddexp(math.log(alpha) + lw if alpha > 0 else jnp.full_like(lw, -jnp.inf),
                              jnp.full_like(lw, math.log(1.0 - alpha) - math.log(n))
                              if alpha < 1 else jnp.full_like(lw, -jnp.inf))
        a = resampler(key, lax.stop_gradient(log_q))
        return particles[a], normalize(lw[a] - log_q[a])

    return Resampling(apply, f"soft({alpha})")


def optimal_transport_resampling(epsilon: float = 0.1, num_iters: int = 50,
                                 scale: bool = True) -> Resampling:
    r"""Entropy-regularised optimal-transport resampling (Corenflos et al. 2021).

    Solves :math:`\min_P \langle P, C\rangle - \epsilon H(P)` with row marginals :math:`\bar w`
    and column marginals :math:`1/N`, :math:`C_{ij} = \|x_i - x_j\|^2`, by ``num_iters``
    log-domain Sinkhorn iterations, and returns :math:`\tilde x_j = N \sum_i P_{ij} x_i` with
    uniform weights. Deterministic and differentiable end to end; the transported set is a
    biased (the bias vanishes as :math:`\epsilon \to 0`) but smooth function of the weights and
    particles, so the gradient of the log-likelihood estimate is that of a smooth surrogate.
    O(N^2) memory and time: for small N (a few hundred). With ``scale=True`` the cost is
    divided by the mean squared particle spread, so ``epsilon`` is dimensionless.

    Example:
      >>> scheme = optimal_transport_resampling(epsilon=0.05, num_iters=100)
    """
    if epsilon <= 0 or num_iters < 1:
        raise ValueError("epsilon must be > 0 and num_iters >= 1")

    def apply(key, particles, log_weights):
        del key
        n = log_weights.shape[-1]
        lw = normalize(log_weights)
        diff = particles[:, None, :] - particles[None, :, :]
        cost = jnp.sum(diff**2, -1)
        if scale:
            w = jnp.exp(lw)
            centred = particles - w @ particles
            spread = jnp.maximum(jnp.sum(w @ centred**2), jnp.finfo(cost.dtype).tiny)
            cost = cost / lax.stop_gradient(spread)
        log_b = jnp.full((n,), -math.log(n), lw.dtype)
        f = jnp.zeros_like(lw)
        g = jnp.zeros_like(lw)

        def body(_, fg):
            f, g = fg
            f = -epsilon * logsumexp(log_b[None, :] + (g[None, :] - cost) / epsilon, axis=1)
            f = jnp.where(jnp.isfinite(lw), f, 0.0)
            g = -epsilon * logsumexp(lw[:, None] + (f[:, None] - cost) / epsilon, axis=0)
            return f, g

        f, g = lax.fori_loop(0, num_iters, body, (f, g))
        log_p = lw[:, None] + log_b[None, :] + (f[:, None] + g[None, :] - cost) / epsilon
        transport = jnp.exp(log_p)  # [N, N], columns sum to ~1/N
        col = jnp.sum(transport, 0)
        new = (transport / col).T @ particles
        return new, log_b

    return Resampling(apply, f"ot({epsilon}, {num_iters})")


def _as_resampling(resampler) -> Resampling:
    if isinstance(resampler, Resampling):
        return resampler
    if isinstance(resampler, str):
        if resampler not in RESAMPLERS:
            raise ValueError(f"unknown resampler {resampler!r}; expected one of "
                             f"{sorted(RESAMPLERS)} or a Resampling")
        return _standard(RESAMPLERS[resampler])
    _checks.check_callable("resampler", resampler)
    return _standard(resampler)


# ---------------------------------------------------------------------------------------------
# Regularisation after resampling

_REGULARISE = (None, "roughening", "kernel")


def _regularise(key, particles, log_weights, kind, scale):
    """Jitter particles after resampling to fight sample impoverishment.

    "roughening" (Gordon et al. 1993): per-dimension std ``scale * E_d * N^{-1/n}`` with E_d the
    particle range. "kernel" (regularised PF, Musso et al. 2001): Gaussian kernel with the
    weighted covariance and the optimal bandwidth ``h = (4 / (N (n + 2)))^{1/(n + 4)}``, times
    ``scale``.
    """
    n_p, n = particles.shape
    eps = jax.random.normal(key, particles.shape, particles.dtype)
    if kind == "roughening":
        spread = jnp.max(particles, 0) - jnp.min(particles, 0)
        return particles + scale * spread * n_p ** (-1.0 / n) * eps
    h = (4.0 / (n_p * (n + 2))) ** (1.0 / (n + 4))
    cov = weighted_cov(ParticleSet(particles, log_weights))
    low = _linalg.safe_cholesky(cov)
    return particles + scale * h * eps @ low.T


# ---------------------------------------------------------------------------------------------
# SIR step and driver


def step(key: Array, ps: ParticleSet, z: Array, transition: Callable, log_likelihood: Callable,
         resampler=systematic, ess_threshold=1.0, mask=None, *, vectorized: bool = False,
         regularise: str | None = None, regularise_scale: float = 1.0
         ) -> tuple[ParticleSet, Array]:
    r"""One SIR step: adaptive resample, propagate, reweight.

    Args:
      key: PRNG key.
      ps: incoming `ParticleSet` (particles [N, n], log_weights [N]).
      z: measurement (any pytree the likelihood accepts).
      transition: ``transition(key, x [n]) -> x' [n]`` (``[N, n] -> [N, n]`` if ``vectorized``).
      log_likelihood: ``log_likelihood(z, x [n]) -> scalar`` (``[N, n] -> [N]`` if vectorized).
      resampler: an ancestor resampler (`systematic` default, `multinomial`, `stratified`,
        `residual`, or its name) or a `Resampling` scheme (differentiable variants).
      ess_threshold: resample when ``ESS < ess_threshold * N`` (array-valued: no recompile).
        1.0 resamples at every step (unless the weights are exactly uniform); 0.0 never.
      mask: optional bool; False means no measurement: the step only propagates.
      vectorized: the user functions take all particles at once (one batched random draw per
        step instead of N split keys: faster).
      regularise: None, "roughening" or "kernel": jitter after resampling (see `_regularise`).
      regularise_scale: multiplier of the jitter.

    Returns:
      ``(ParticleSet with normalised log weights, log_marginal_increment)``; the increment is 0
      for a masked step and ``-inf`` for a degenerate one.

    Example:
      >>> ps, inc = particle.step(key, ps, z, transition, log_likelihood)
    """
    _check_set(ps)
    scheme = _as_resampling(resampler)
    _checks.check_options("regularise", () if regularise is None else (regularise,),
                          ("roughening", "kernel"))
    return _step(key, ps, z, transition, log_likelihood, scheme, ess_threshold, mask,
                 vectorized, regularise, regularise_scale)[:2]


def filter(key: Array, init: ParticleSet, zs, transition: Callable, log_likelihood: Callable,
           resampler=systematic, ess_threshold=1.0, masks: Array | None = None, *,
           vectorized: bool = False, regularise: str | None = None,
           regularise_scale: float = 1.0, angle_dims: Sequence[int] = (),
           return_covs: bool = True, return_particles: bool = False) -> ParticleFilterResult:
    """Particle filter over a sequence under `lax.scan` (see `step` for the arguments).

    Args:
      key: PRNG key. init: `ParticleSet` before the first step.
      zs: measurements with a leading time axis [T, ...] (a pytree is allowed).
      masks: optional [T] bools.
      angle_dims: state components reported with circular means and wrapped deviations.
      return_covs: also return the weighted covariances [T, n, n]; ``False`` skips their
        computation (a noticeable part of a step; measurements: docs/design_notes.md,
        "Particle filter: skipping the covariances") and sets ``covs`` to None.
      return_particles: also return all particles [T, N, n] (memory: T N n floats).

    The carried log weights are normalised once, before the scan; each step then computes the
    linear weights once and shares them between the ESS test, the resampler and the moments.

    Returns:
      `ParticleFilterResult`.

    Example:
      >>> init = particle.init_from_gaussian(key, jnp.zeros(4), jnp.eye(4), 1000)
      >>> res = particle.filter(key, init, zs, transition, log_likelihood)
      >>> res.means.shape, res.log_likelihood
    """
    _check_set(init, "init")
    scheme = _as_resampling(resampler)
    _checks.check_options("regularise", () if regularise is None else (regularise,),
                          ("roughening", "kernel"))
    leaves = jax.tree_util.tree_leaves(zs)
    if not leaves:
        raise ValueError("zs must contain at least one array with a leading time axis")
    T = jnp.shape(leaves[0])[0]
    for leaf in leaves:
        if jnp.ndim(leaf) == 0 or jnp.shape(leaf)[0] != T:
            raise ValueError("every leaf of zs must have the same leading time axis "
                             f"(T = {T}); got shape {jnp.shape(leaf)}")
    if masks is None:
        masks = jnp.ones((T,), bool)
    else:
        _checks.check_shape("masks", masks, (T,))
    keys = jax.random.split(key, T)
    init = ParticleSet(init.particles, normalize(init.log_weights))

    def body(ps, inp):
        k, z, m = inp
        ps, inc, did = _step(k, ps, z, transition, log_likelihood, scheme, ess_threshold, m,
                             vectorized, regularise, regularise_scale, normalized=True)
        w = jnp.exp(ps.log_weights)  # `_step` returns normalised log weights
        mean = _mean(w, ps.particles, angle_dims)
        out = {"mean": mean, "ess": 1.0 / jnp.sum(w * w), "inc": inc, "did": did,
               "invalid": m & ~_finite(z)}
        if return_covs:
            out["cov"] = _cov(w, ps.particles, mean, angle_dims)
        if return_particles:
            out["particles"] = ps.particles
        return ps, out

    final, outs = lax.scan(body, init, (keys, zs, jnp.asarray(masks, bool)))
    incs = outs["inc"]
    degenerate = jnp.isneginf(incs)
    return ParticleFilterResult(outs["mean"], outs.get("cov"), outs["ess"], incs, jnp.sum(incs),
                                outs["did"], jnp.sum(degenerate), final, outs.get("particles"),
                                jnp.sum(outs["invalid"]).astype(jnp.int32))


def init_from_gaussian(key: Array, mean: Array, cov: Array, num: int) -> ParticleSet:
    """``num`` equally weighted particles drawn from N(mean [n], cov [n, n]).

    Example:
      >>> ps = init_from_gaussian(key, jnp.zeros(4), jnp.eye(4), 1000)
    """
    if isinstance(num, bool) or not isinstance(num, (int, np.integer)) or num < 1:
        raise ValueError(f"num (the number of particles) must be a positive int; got {num!r}")
    _checks.check_ndim("mean", mean, 1, "a [n] vector")
    _checks.check_covariance("cov", cov, jnp.shape(mean)[0])
    low = _linalg.safe_cholesky(jnp.asarray(cov))
    eps = jax.random.normal(key, (num, jnp.shape(mean)[0]), jnp.result_type(mean, cov))
    return ParticleSet(mean + eps @ low.T, jnp.full((num,), -math.log(num), eps.dtype))


def _step(key, ps, z, transition, log_likelihood, scheme, ess_threshold, mask, vectorized,
          regularise, regularise_scale, normalized=False):
    n_p = ps.log_weights.shape[-1]
    k_res, k_prop, k_reg = jax.random.split(key, 3)
    present = jnp.asarray(True if mask is None else mask, bool) & _finite(z)
    # A masked or non-finite measurement may be NaN padding: its likelihood is discarded, but
    # the gradient of a discarded NaN is still NaN, so the likelihood sees zeros instead.
    z = jax.tree_util.tree_map(lambda a: jnp.where(present, a, jnp.zeros_like(a)), z)
    lw = ps.log_weights if normalized else normalize(ps.log_weights)
    w = jnp.exp(lw)
    do_resample = present & (1.0 / jnp.sum(w * w) < ess_threshold * n_p)
    if scheme.apply_weights is not None:
        res_x, res_lw = scheme.apply_weights(k_res, ps.particles, w)
    else:
        res_x, res_lw = scheme.apply(k_res, ps.particles, lw)
    if regularise is not None:
        res_x = _regularise(k_reg, res_x, res_lw, regularise, regularise_scale)
    x = jnp.where(do_resample, res_x, ps.particles)
    lw = jnp.where(do_resample, res_lw, lw)
    if vectorized:
        x = transition(k_prop, x)
        ll = log_likelihood(z, x)
    else:
        x = jax.vmap(transition)(jax.random.split(k_prop, n_p), x)
        ll = jax.vmap(log_likelihood, (None, 0))(z, x)
    ll = jnp.where(jnp.isnan(ll) | (ll == jnp.inf), -jnp.inf, ll)
    joint = lw + ll
    inc = logsumexp(joint)
    degenerate = present & jnp.isneginf(inc)
    new_lw = jnp.where(present & ~degenerate, joint - jnp.where(degenerate, 0.0, inc), lw)
    new_lw = jnp.where(degenerate, -math.log(n_p), new_lw)
    inc = jnp.where(present, inc, 0.0)
    return ParticleSet(x, new_lw), inc, do_resample


def _finite(z) -> Array:
    """Scalar bool: a floating measurement array is finite (pytrees mask their own padding,
    see the module doc)."""
    if isinstance(z, (jax.Array, np.ndarray, float)) and jnp.issubdtype(jnp.result_type(z),
                                                                         jnp.inexact):
        return jnp.all(jnp.isfinite(z))
    return jnp.asarray(True)


def _check_set(ps, name="ps"):
    if not isinstance(ps, ParticleSet):
        raise TypeError(f"{name} must be a particle.ParticleSet; got {type(ps).__name__}")
    _checks.check_ndim(f"{name}.particles", ps.particles, 2, "[N, n] particles")
    _checks.check_shape(f"{name}.log_weights", ps.log_weights, (jnp.shape(ps.particles)[0],))
