r"""Linear assignment and Global Nearest Neighbour (GNN) association.

GNN (seed 001 section IV, solved there with Munkres) picks the one joint assignment of
detections to tracks of least total cost, with gated-out pairs forbidden. The solver is optax's
jittable Hungarian algorithm (`optax.assignment.hungarian_algorithm`, exact for finite costs);
this module turns the tracking problem, which has forbidden pairs and rows that may stay
unassigned, into the finite rectangular problem that solver expects.

Hard assignment is piecewise constant in the costs, so it has no useful gradient; where a
gradient is needed use the soft marginals of `jaxtrack.association.jpda_marginals`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxtrack import _checks

Array = jax.Array

__all__ = ["linear_sum_assignment", "gnn", "assignment_cost"]


def linear_sum_assignment(cost: Array, *, unassigned_cost: Array | float | None = None,
                          row_mask: Array | None = None,
                          col_mask: Array | None = None) -> Array:
    r"""Optimal assignment of rows (tracks) to columns (detections) with forbidden pairs.

    Entries that are +inf or NaN (or in a masked row / column) are *forbidden*: that pair is
    never assigned. Two semantics, chosen by ``unassigned_cost``:

    * ``unassigned_cost=None`` (default): among all matchings that use allowed pairs only,
      take those of **maximum cardinality**, and among them one of **minimum total cost**. A
      row stays unassigned (-1) only when no maximum matching can give it an allowed column.
      This is what scipy's ``linear_sum_assignment`` does when the problem is feasible, and it
      is the classical GNN rule (assign as many gated pairs as possible).
    * ``unassigned_cost=c`` (scalar or [K]): every row may instead stay unassigned at cost
      :math:`c_i`; the result minimises :math:`\sum_{assigned} C_{ij} + \sum_{unassigned} c_i`
      (the auction / "non-assignment cost" formulation; e.g. ``c`` = the gate threshold).

    Reduction to a finite problem for the exact Hungarian solver: allowed costs are shifted to
    :math:`[0, \Delta]` and forbidden entries replaced by
    :math:`B = (\min(K, M) + 1)(\Delta + 1)`, larger than any difference between allowed
    totals, so a solution with fewer forbidden pairs always wins (first semantics). For the
    second, the matrix is augmented to [K, M + K] with dummy column :math:`M + i` of cost
    :math:`c_i` for row i only (others :math:`B`), so leaving a row unassigned is an ordinary
    column. Pairs that still land on a :math:`B` entry are reported as -1.

    Args:
      cost: [K, M] costs (+inf forbidden).
      unassigned_cost: None, or finite scalar / [K] cost of leaving each row unassigned.
      row_mask: optional [K] bools; masked rows are left unassigned.
      col_mask: optional [M] bools; masked columns are never used.

    Returns:
      col_for_row: [K] int32, the column of each row, -1 where the row is unassigned.

    Example:
      >>> cost = jnp.array([[1.0, jnp.inf], [2.0, jnp.inf], [jnp.inf, 3.0]])
      >>> linear_sum_assignment(cost)
      Array([ 0, -1,  1], dtype=int32)
    """
    _checks.check_ndim("cost", cost, 2, "a [K, M] cost matrix")
    K, M = _checks.shape_of(cost)
    if row_mask is not None:
        _checks.check_shape("row_mask", row_mask, (K,), "one flag per row")
    if col_mask is not None:
        _checks.check_shape("col_mask", col_mask, (M,), "one flag per column")
    if unassigned_cost is not None:
        if np.ndim(unassigned_cost) not in (0, 1):
            raise ValueError("unassigned_cost must be a scalar or [K]; got shape "
                             f"{_checks.shape_of(unassigned_cost)}")
        if np.ndim(unassigned_cost) == 1:
            _checks.check_shape("unassigned_cost", unassigned_cost, (K,))
        _checks.check_finite("unassigned_cost", unassigned_cost)
    if _checks.is_concrete(cost) and np.any(np.isneginf(np.asarray(cost))):
        raise ValueError("cost contains -inf; forbidden pairs are +inf")
    return _linear_sum_assignment(cost, unassigned_cost, row_mask, col_mask)


def gnn(cost: Array, gated: Array, *, unassigned_cost: Array | float | None = None,
        track_mask: Array | None = None, meas_mask: Array | None = None) -> Array:
    r"""Global Nearest Neighbour association: the optimal assignment inside the gates.

    :math:`\min \sum_{(k, j)} C_{kj}` over assignments that only use gated pairs (seed 001,
    section IV; Blackman and Popoli 1999, 6.2). ``cost`` is typically the squared Mahalanobis
    distance ``d2`` or ``d2 + log det S`` (the negative log-likelihood), optionally plus
    appearance terms (seed 001 eq. 2).

    Args:
      cost: [K, M] association costs.
      gated: [K, M] bools (e.g. from `gate`); False pairs are forbidden.
      unassigned_cost, track_mask, meas_mask: as in `linear_sum_assignment`.

    Returns:
      col_for_row: [K] int32 detection of each track, -1 if none.

    Example:
      >>> d2 = mahalanobis(means, covs, zs, H, R)
      >>> col = gnn(d2, gate(d2, 2, 0.99))
    """
    _checks.check_ndim("cost", cost, 2, "a [K, M] cost matrix")
    _checks.check_shape("gated", gated, _checks.shape_of(cost), "same shape as cost")
    cost = jnp.where(jnp.asarray(gated, bool), cost, jnp.inf)
    return linear_sum_assignment(cost, unassigned_cost=unassigned_cost, row_mask=track_mask,
                                 col_mask=meas_mask)


def assignment_cost(cost: Array, col_for_row: Array) -> Array:
    """Total cost of an assignment: :math:`\\sum_{i: c_i \\ge 0} C_{i, c_i}` (scalar).

    Args:
      cost: [K, M] costs.
      col_for_row: [K] int column of each row, -1 for unassigned rows (they add 0).

    Example:
      >>> assignment_cost(cost, linear_sum_assignment(cost))
    """
    cost = jnp.asarray(cost)
    col = jnp.asarray(col_for_row)
    picked = jnp.take_along_axis(cost, jnp.maximum(col, 0)[:, None], 1)[:, 0]
    return jnp.sum(jnp.where(col >= 0, picked, 0.0))


# ---------------------------------------------------------------------------------------------
# Internals


@jax.jit
def _linear_sum_assignment(cost, unassigned_cost, row_mask, col_mask):
    cost = jnp.asarray(cost)
    if not jnp.issubdtype(cost.dtype, jnp.floating):
        cost = cost.astype(jnp.result_type(float))
    K, M = cost.shape
    allowed = jnp.isfinite(cost)
    if row_mask is not None:
        allowed = allowed & jnp.asarray(row_mask, bool)[:, None]
    if col_mask is not None:
        allowed = allowed & jnp.asarray(col_mask, bool)[None, :]
    none = jnp.full((K,), -1, jnp.int32)
    if K == 0 or M == 0:  # nothing to assign: every row unassigned
        return none
    finite = jnp.where(allowed, cost, 0.0)
    any_allowed = jnp.any(allowed)
    lo = jnp.where(any_allowed, jnp.min(jnp.where(allowed, cost, jnp.inf)), 0.0)
    hi = jnp.where(any_allowed, jnp.max(jnp.where(allowed, cost, -jnp.inf)), 0.0)
    if unassigned_cost is None:
        span = hi - lo
        big = (min(K, M) + 1) * (span + 1.0)
        work = jnp.where(allowed, finite - lo, big)
        rows, cols = optax.assignment.hungarian_algorithm(work)
        ok = allowed[rows, cols]
        return none.at[rows].set(jnp.where(ok, cols, -1).astype(jnp.int32))
    c0 = jnp.broadcast_to(jnp.asarray(unassigned_cost, cost.dtype), (K,))
    lo = jnp.minimum(lo, jnp.min(c0))
    hi = jnp.maximum(hi, jnp.max(c0))
    span = hi - lo
    big = (K + 1) * (span + 1.0)
    real = jnp.where(allowed, finite - lo, big)
    dummy = jnp.where(jnp.eye(K, dtype=bool), (c0 - lo)[:, None], big)
    rows, cols = optax.assignment.hungarian_algorithm(jnp.concatenate([real, dummy], 1))
    ok = (cols < M) & allowed[rows, jnp.minimum(cols, M - 1)] if M else jnp.zeros_like(rows, bool)
    return none.at[rows].set(jnp.where(ok, cols, -1).astype(jnp.int32))
