"""Tests for `jaxtrack.association.assignment` (linear_sum_assignment, gnn).

References: `scipy.optimize.linear_sum_assignment` on the equivalent finite problem (scipy
raises on infeasible +inf matrices, so the test builds the reduction itself: forbidden entries
become a cost larger than any allowed total), and `scipy.sparse.csgraph.maximum_bipartite_matching`
for the maximum cardinality, independently of costs. Costs agree to 1e-9.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment as scipy_lsa
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import maximum_bipartite_matching

from jaxtrack import association

N_PROBLEMS = 500
SHAPE = (7, 5)
_batched = jax.jit(jax.vmap(association.linear_sum_assignment))
_batched_unassigned = jax.jit(jax.vmap(
    lambda c, c0: association.linear_sum_assignment(c, unassigned_cost=c0)))


def padded(cost, shape=SHAPE):
    """A small [k, m] problem inside the shared [7, 5] shape (padding forbidden), so that the
    toy examples reuse the compiled solvers."""
    out = np.full(shape, np.inf)
    out[: cost.shape[0], : cost.shape[1]] = cost
    return out


def solve(cost, unassigned_cost=None):
    k = cost.shape[0]
    if unassigned_cost is None:
        return np.asarray(_batched(padded(cost)[None]))[0, :k]
    c0 = np.full((1, SHAPE[0]), float(unassigned_cost))
    return np.asarray(_batched_unassigned(padded(cost)[None], c0))[0, :k]


def _with_masks(cost, rows, cols):
    # eager call: reuses the solver that linear_sum_assignment compiles for this signature
    return association.linear_sum_assignment(cost, row_mask=rows, col_mask=cols)


def random_costs(seed, shape, n=N_PROBLEMS, forbidden=0.45):
    rng = np.random.default_rng(seed)
    cost = rng.uniform(-5.0, 10.0, (n,) + shape)
    cost[rng.uniform(size=cost.shape) < forbidden] = np.inf
    # a few integer-valued problems with ties
    cost[: n // 10] = np.where(np.isfinite(cost[: n // 10]), np.round(cost[: n // 10]), np.inf)
    return cost


def scipy_optimum(cost):
    """(max cardinality, min cost among max-cardinality matchings) via scipy."""
    allowed = np.isfinite(cost)
    cardinality = int(np.sum(maximum_bipartite_matching(csr_matrix(allowed.astype(int)),
                                                        perm_type="column") >= 0))
    finite = np.where(allowed, cost, 0.0)
    big = (min(cost.shape) + 1) * (np.ptp(finite[allowed]) + 1.0) + np.abs(finite).max() \
        if allowed.any() else 1.0
    rows, cols = scipy_lsa(np.where(allowed, cost, big))
    keep = allowed[rows, cols]
    assert keep.sum() == cardinality       # the reduction reaches the maximum cardinality
    return cardinality, float(cost[rows[keep], cols[keep]].sum())


def check_matching(cost, col):
    assigned = col >= 0
    used = col[assigned]
    assert len(set(used.tolist())) == len(used), "a column is used twice"
    assert np.all(np.isfinite(cost[np.nonzero(assigned)[0], used])), "forbidden pair used"
    return int(assigned.sum()), float(cost[np.nonzero(assigned)[0], used].sum())


@pytest.mark.parametrize("shape", [SHAPE, SHAPE[::-1]])
def test_reaches_scipy_optimum_on_500_rectangular_problems_with_forbidden_pairs(shape):
    costs = random_costs(0 if shape == SHAPE else 1, shape)
    cols = np.asarray(_batched(costs))
    assert cols.shape == (N_PROBLEMS, shape[0]) and cols.dtype == np.int32
    for cost, col in zip(costs, cols):
        n, total = check_matching(cost, col)
        ref_n, ref_total = scipy_optimum(cost)
        assert n == ref_n
        assert abs(total - ref_total) <= 1e-9 * max(1.0, abs(ref_total))


def test_unassigned_cost_matches_scipy_on_the_augmented_matrix():
    costs = random_costs(2, SHAPE, n=200)
    c0 = np.random.default_rng(3).uniform(0.0, 6.0, (200, SHAPE[0]))
    cols = np.asarray(_batched_unassigned(costs, c0))
    K, M = SHAPE
    for cost, c, col in zip(costs, c0, cols):
        n, total = check_matching(cost, col)
        total += c[col < 0].sum()
        big = 1e6
        aug = np.full((K, M + K), big)
        aug[:, :M] = np.where(np.isfinite(cost), cost, big)
        aug[np.arange(K), M + np.arange(K)] = c
        rows, cs = scipy_lsa(aug)
        assert abs(total - aug[rows, cs].sum()) <= 1e-9 * max(1.0, abs(total))


def test_rows_stay_unassigned_only_when_their_columns_are_taken():
    inf = np.inf
    cost = np.array([[1.0, inf], [2.0, inf], [inf, 3.0]])
    assert solve(cost).tolist() == [0, -1, 1]
    # cardinality first: the cheap pair (0, 0) would block row 1
    cost = np.array([[0.0, 1.0], [5.0, inf]])
    assert solve(cost).tolist() == [1, 0]
    # with an unassigned cost, leaving row 1 out is cheaper
    assert solve(cost, unassigned_cost=2.0).tolist() == [0, -1]
    assert solve(np.full((3, 2), inf)).tolist() == [-1] * 3
    # the docstring example, unpadded
    cost = np.array([[1.0, inf], [2.0, inf], [inf, 3.0]])
    assert np.asarray(association.linear_sum_assignment(cost)).tolist() == [0, -1, 1]


def test_masks_and_nan_forbid_rows_and_columns():
    rng = np.random.default_rng(4)
    cost = rng.uniform(size=SHAPE)
    rows = np.array([True, False, True, True, True, True, True])
    cols = np.array([True, True, False, True, True])
    col = np.asarray(_with_masks(cost, rows, cols))
    assert col[1] == -1 and 2 not in col.tolist() and (col >= 0).sum() == 4
    cost[0, :] = np.nan
    assert solve(cost)[0] == -1


def test_gnn_assigns_inside_the_gate_and_empty_shapes_work():
    d2 = padded(np.array([[0.5, 20.0, 3.0], [0.4, 1.0, 50.0]]))
    gated = d2 <= 9.21
    track_mask = np.arange(SHAPE[0]) < 2
    meas_mask = np.arange(SHAPE[1]) < 3
    col = np.asarray(association.gnn(d2, gated, track_mask=track_mask, meas_mask=meas_mask))
    assert col.tolist() == [0, 1] + [-1] * 5
    assert float(association.assignment_cost(d2, col)) == pytest.approx(1.5)
    assert np.asarray(association.linear_sum_assignment(np.zeros((3, 0)))).tolist() == [-1] * 3
    assert association.linear_sum_assignment(np.zeros((0, 3))).shape == (0,)


def test_float32_costs_and_vmap_equals_loop():
    costs = random_costs(5, SHAPE, n=4)
    everything = np.ones(SHAPE[0], bool), np.ones(SHAPE[1], bool)
    loop = np.stack([np.asarray(_with_masks(c, *everything)) for c in costs])
    np.testing.assert_array_equal(np.asarray(_batched(costs)), loop)
    col32 = np.asarray(_batched(jnp.asarray(costs, jnp.float32)))
    np.testing.assert_array_equal(col32, loop)


def test_bad_inputs_are_rejected_at_the_boundary():
    with pytest.raises(ValueError, match=r"cost must be a \[K, M\]"):
        association.linear_sum_assignment(np.zeros(3))
    with pytest.raises(ValueError, match="-inf"):
        association.linear_sum_assignment(np.array([[-np.inf, 1.0]]))
    with pytest.raises(ValueError, match="row_mask"):
        association.linear_sum_assignment(np.zeros((2, 2)), row_mask=np.ones(3, bool))
    with pytest.raises(ValueError, match="unassigned_cost"):
        association.linear_sum_assignment(np.zeros((2, 2)), unassigned_cost=np.ones(3))
    with pytest.raises(ValueError, match="NaN or inf"):
        association.linear_sum_assignment(np.zeros((2, 2)), unassigned_cost=np.inf)
    with pytest.raises(ValueError, match="gated"):
        association.gnn(np.zeros((2, 2)), np.ones((2, 3), bool))


@pytest.mark.parametrize("unassigned_cost", [None, 1.0])
def test_no_columns_or_no_rows_leave_everything_unassigned(unassigned_cost):
    out = association.linear_sum_assignment(jnp.zeros((3, 0)), unassigned_cost=unassigned_cost)
    np.testing.assert_array_equal(out, [-1, -1, -1])
    assert association.linear_sum_assignment(jnp.zeros((0, 3)),
                                             unassigned_cost=unassigned_cost).shape == (0,)
