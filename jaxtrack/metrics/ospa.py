r"""OSPA and GOSPA distances between two finite sets of points at one frame, jittable.

Sets are fixed-capacity arrays with masks. Both distances need the minimum, over injective
assignments of the smaller set into the larger, of :math:`\sum \min(d, c)^p` over the pairs
(with :math:`\alpha \le 2` a GOSPA optimum pairs as many points as it can, like OSPA). It is
found by the Hungarian algorithm (`optax.assignment.hungarian_algorithm`) on a square cost
matrix padded with absent points: a present pair costs :math:`\min(d, c)^p`, a present point
paired with an absent one :math:`c^p`, two absent points 0. Batch frames (or episodes) with
`jax.vmap`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxtrack import _checks

Array = jax.Array

__all__ = ["OSPAResult", "GOSPAResult", "ospa", "gospa"]


class OSPAResult(NamedTuple):
    r"""OSPA and its two components, :math:`d^p = e_\mathrm{loc}^p + e_\mathrm{card}^p`.

    Attributes:
      distance: the OSPA distance (m), in [0, c].
      localisation: :math:`(\frac{1}{n} \sum_{\text{pairs}} \min(d, c)^p)^{1/p}`.
      cardinality: :math:`(\frac{1}{n} c^p |n - m|)^{1/p}`.
    """

    distance: Array
    localisation: Array
    cardinality: Array


class GOSPAResult(NamedTuple):
    r"""GOSPA and its decomposition, :math:`d^p = \mathrm{localisation} + \frac{c^p}{\alpha}
    (\mathrm{missed} + \mathrm{false})`.

    Attributes:
      distance: the GOSPA distance (m).
      localisation: sum of :math:`\min(d, c)^p` over the assigned pairs (m^p). With
        :math:`\alpha = 2` a pair at distance >= c is counted as one missed and one false point
        instead (the two are equivalent), so every assigned pair is closer than c.
      num_missed: present truths left unassigned.
      num_false: present estimates left unassigned.
      assignment: [N] index of the estimate assigned to each truth slot, -1 if none.
    """

    distance: Array
    localisation: Array
    num_missed: Array
    num_false: Array
    assignment: Array


def ospa(truths: Array, truth_mask: Array | None, estimates: Array,
         estimate_mask: Array | None, c: float | Array, p: float | Array = 1.0) -> OSPAResult:
    r"""Optimal sub-pattern assignment distance of order p with cut-off c at one frame.

    Schuhmacher, Vo & Vo, "A consistent metric for performance evaluation of multi-object
    filters", IEEE Trans. Signal Processing, 2008. For sets X (m points) and Y (n points),
    :math:`m \le n` (else swap),

    .. math::
        \bar d^{(c)}_p(X, Y) = \Big(\frac{1}{n} \Big(\min_{\pi \in \Pi_n} \sum_{i=1}^m
        \min(c, \lVert x_i - y_{\pi(i)} \rVert)^p + c^p (n - m)\Big)\Big)^{1/p},

    and 0 when both sets are empty.

    Args:
      truths: [N, d] points of the first set.
      truth_mask: optional [N] bools (False: empty slot).
      estimates: [M, d] points of the second set.
      estimate_mask: optional [M] bools.
      c: cut-off (m) > 0; may be traced.
      p: order >= 1; may be traced.

    Returns:
      `OSPAResult` of scalars.

    Example:
      >>> from jaxtrack import metrics
      >>> x, y = jnp.array([[0.0, 0.0], [5.0, 0.0]]), jnp.array([[0.0, 1.0]])
      >>> metrics.ospa(x, None, y, None, c=2.0).distance  # (1 + 2) / 2 = 1.5
    """
    truth_mask, estimate_mask = _check_sets(truths, truth_mask, estimates, estimate_mask)
    _check_params(c, p, 1.0)
    dtype = jnp.result_type(truths, estimates, float)
    c, p = jnp.asarray(c, dtype), jnp.asarray(p, dtype)
    return _ospa(_optimal_assignment(truths, truth_mask, estimates, estimate_mask, c, p),
                 truth_mask, estimate_mask, c, p)


@jax.jit
def _ospa(assignment, truth_mask, estimate_mask, c, p):
    pair_sum, _, _ = assignment
    m = jnp.sum(truth_mask)
    n = jnp.sum(estimate_mask)
    size = jnp.maximum(jnp.maximum(m, n), 1).astype(c.dtype)
    card = c**p * jnp.abs(m - n).astype(c.dtype)
    return OSPAResult(distance=_root((pair_sum + card) / size, p),
                      localisation=_root(pair_sum / size, p), cardinality=_root(card / size, p))


def gospa(truths: Array, truth_mask: Array | None, estimates: Array,
          estimate_mask: Array | None, c: float | Array, p: float | Array = 1.0,
          alpha: float | Array = 2.0) -> GOSPAResult:
    r"""Generalised OSPA distance at one frame, with its localisation / missed / false split.

    Rahmathullah, García-Fernández & Svensson, "Generalized optimal sub-pattern assignment
    metric", FUSION 2017. For :math:`|X| = m \le n = |Y|` (else swap),

    .. math::
        d^{(c, \alpha)}_p(X, Y) = \Big(\min_{\pi \in \Pi_n} \sum_{i=1}^m
        \min(c, \lVert x_i - y_{\pi(i)} \rVert)^p + \frac{c^p}{\alpha} (n - m)\Big)^{1/p};

    with :math:`\alpha = 2` (default) this equals
    :math:`\big(\min_\gamma \sum_{(i, j) \in \gamma} d(x_i, y_j)^p + \frac{c^p}{2}
    (|X| + |Y| - 2|\gamma|)\big)^{1/p}` over assignments :math:`\gamma` of pairs closer than c.
    Unlike OSPA it is not normalised by n, so it grows with the number of errors.

    Args:
      truths: [N, d] true points (unassigned ones are missed).
      truth_mask: optional [N] bools.
      estimates: [M, d] estimated points (unassigned ones are false).
      estimate_mask: optional [M] bools.
      c: cut-off (m) > 0; may be traced.
      p: order >= 1; may be traced.
      alpha: in (0, 2]; may be traced.

    Returns:
      `GOSPAResult` (scalars and the [N] assignment).

    Example:
      >>> x, y = jnp.array([[0.0, 0.0], [5.0, 0.0]]), jnp.array([[0.0, 1.0]])
      >>> r = metrics.gospa(x, None, y, None, c=2.0)
      >>> r.distance, r.num_missed  # 1 + 2 / 2 = 2.0, 1
    """
    truth_mask, estimate_mask = _check_sets(truths, truth_mask, estimates, estimate_mask)
    _check_params(c, p, alpha)
    dtype = jnp.result_type(truths, estimates, float)
    c, p, alpha = (jnp.asarray(a, dtype) for a in (c, p, alpha))
    return _gospa(_optimal_assignment(truths, truth_mask, estimates, estimate_mask, c, p),
                  truth_mask, estimate_mask, c, p, alpha)


@jax.jit
def _gospa(assignment, truth_mask, estimate_mask, c, p, alpha):
    pair_sum, pairs, dist = assignment
    unpaired = jnp.abs(jnp.sum(truth_mask) - jnp.sum(estimate_mask)).astype(c.dtype)
    # With alpha = 2 a pair at >= c costs exactly a miss plus a false point: report it so.
    pairs = pairs & jnp.where(alpha == 2.0, dist < c, True)
    localisation = jnp.sum(jnp.where(pairs, jnp.minimum(dist, c) ** p, 0.0))
    assigned_truth = jnp.any(pairs, 1)
    if pairs.shape[1]:
        assignment = jnp.where(assigned_truth, jnp.argmax(pairs, 1), -1)
    else:
        assignment = jnp.full(pairs.shape[:1], -1)
    return GOSPAResult(
        distance=_root(pair_sum + c**p / alpha * unpaired, p),
        localisation=localisation,
        num_missed=jnp.sum(truth_mask & ~assigned_truth).astype(jnp.int32),
        num_false=jnp.sum(estimate_mask & ~jnp.any(pairs, 0)).astype(jnp.int32),
        assignment=assignment.astype(jnp.int32),
    )


# ---------------------------------------------------------------------------------------------
# Internals


@jax.jit
def _optimal_assignment(x, x_mask, y, y_mask, c, p):
    """Minimum over injective assignments of the smaller set into the larger of the sum of
    min(d, c)^p over the pairs; shared by OSPA and GOSPA (for alpha <= 2 both optima pair as
    many points as possible, so they differ only in the constant cardinality term).

    Returns ``(pair_sum, pairs [N, M] bools of the assigned present pairs, distances [N, M])``.
    """
    N, M = x_mask.shape[0], y_mask.shape[0]
    dtype = c.dtype
    diff = x[:, None, :].astype(dtype) - y[None, :, :].astype(dtype)
    sq = jnp.sum(diff * diff, -1)
    positive = sq > 0
    dist = jnp.where(positive, jnp.sqrt(jnp.where(positive, sq, 1.0)), 0.0)
    both = x_mask[:, None] & y_mask[None, :]
    # Masked slots may hold anything (NaN): they never reach the arithmetic.
    dist = jnp.where(both, dist, 0.0)
    S = max(N, M)
    if S == 0:
        return jnp.zeros((), dtype), jnp.zeros((N, M), bool), dist
    # Padded square problem: a present point left with an absent partner pays c^p; two such
    # points (2 c^p) always cost more than pairing them (at most c^p), so the optimum pairs
    # min(m, n) points.
    penalty = c**p
    pair_cost = jnp.minimum(dist, c) ** p
    xs = jnp.zeros((S,), bool).at[:N].set(x_mask)
    ys = jnp.zeros((S,), bool).at[:M].set(y_mask)
    padded = jnp.zeros((S, S), dtype).at[:N, :M].set(pair_cost)
    one_present = xs[:, None] ^ ys[None, :]
    cost = jnp.where(xs[:, None] & ys[None, :], padded, jnp.where(one_present, penalty, 0.0))
    # The assignment is piecewise constant in the points; the distance's gradient is that of the
    # cost at the optimal assignment.
    rows, cols = optax.assignment.hungarian_algorithm(jax.lax.stop_gradient(cost))
    chosen = jnp.zeros((S, S), bool).at[rows, cols].set(True)[:N, :M] & both
    pair_sum = jnp.sum(jnp.where(chosen, pair_cost, 0.0))
    return pair_sum, chosen, dist


def _root(value, p):
    """value^(1/p) with a finite gradient at 0."""
    positive = value > 0
    return jnp.where(positive, jnp.where(positive, value, 1.0) ** (1.0 / p), 0.0)


def _check_sets(x, x_mask, y, y_mask):
    _checks.check_ndim("truths", x, 2, "[N, d] points")
    N, d = _checks.shape_of(x)
    _checks.check_ndim("estimates", y, 2, "[M, d] points")
    _checks.check_shape("estimates", y, (None, d), f"[M, d] points with d = {d}")
    M = _checks.shape_of(y)[0]
    if x_mask is not None:
        _checks.check_shape("truth_mask", x_mask, (N,), "[N] bools")
    if y_mask is not None:
        _checks.check_shape("estimate_mask", y_mask, (M,), "[M] bools")
    x_mask = jnp.ones((N,), bool) if x_mask is None else jnp.asarray(x_mask, bool)
    y_mask = jnp.ones((M,), bool) if y_mask is None else jnp.asarray(y_mask, bool)
    return x_mask, y_mask


def _check_params(c, p, alpha):
    for name, value, ok, what in (("c", c, lambda v: v > 0, "positive"),
                                  ("p", p, lambda v: v >= 1, ">= 1"),
                                  ("alpha", alpha, lambda v: 0 < v <= 2, "in (0, 2]")):
        if np.ndim(value) != 0:
            raise ValueError(f"{name} must be a scalar; got shape {list(np.shape(value))}")
        if _checks.is_concrete(value) and not ok(float(value)):
            raise ValueError(f"{name} must be {what}; got {value!r}")
