"""Grid planning and path following: distance field, path descent, pure pursuit.

References: the distance field is compared with ``scipy.sparse.csgraph.dijkstra`` on the same
graph, built cell by cell in numpy here (passable cells, corner-free diagonals, trapezoid edge
costs); paths are checked step by step against the costmap; pure pursuit is run in closed loop
on the exact unicycle (`follower.unicycle_step`).
"""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra

from jaxtrack.control import follower
from jaxtrack.control import grid_planner as gp

CELL = 0.3
LETHAL = 5.0
SHAPE = (24, 19)   # not square: a swapped axis would show

# The public functions check their inputs, then call jitted cores that every eager call of
# the same shapes shares; one whole-function jit checks that they also trace.
field_jit = jax.jit(gp.distance_field, static_argnames=("connectivity", "method"))
MAX_LEN = 96


def offsets(connectivity):
    straight = [(0, 1), (1, 0), (0, -1), (-1, 0)]
    return straight + ([(1, 1), (1, -1), (-1, 1), (-1, -1)] if connectivity == 8 else [])


def edge_cost(cost, a, b, cell=CELL):
    step = math.hypot(b[0] - a[0], b[1] - a[1])
    return cell * step * (1.0 + 0.5 * (float(cost[a]) + float(cost[b])))


def reference_graph(cost, connectivity, lethal=LETHAL, cell=CELL):
    """The planner's graph as a scipy CSR matrix, built cell by cell."""
    cost = np.asarray(cost, np.float64)
    H, W = cost.shape
    ok = (cost >= 0) & (cost < lethal)
    rows, cols, w = [], [], []
    for i in range(H):
        for j in range(W):
            if not ok[i, j]:
                continue
            for di, dj in offsets(connectivity):
                a, b = i + di, j + dj
                if not (0 <= a < H and 0 <= b < W) or not ok[a, b]:
                    continue
                if di and dj and not (ok[i + di, j] and ok[i, j + dj]):
                    continue
                rows.append(i * W + j)
                cols.append(a * W + b)
                w.append(edge_cost(cost, (i, j), (a, b), cell))
    return coo_matrix((w, (rows, cols)), shape=(H * W, H * W)).tocsr(), ok


def reference_field(cost, goal, connectivity, lethal=LETHAL, cell=CELL):
    graph, ok = reference_graph(cost, connectivity, lethal, cell)
    H, W = np.shape(cost)
    if not ok[goal[0], goal[1]]:
        return np.full((H, W), np.inf)
    return dijkstra(graph, indices=int(goal[0]) * W + int(goal[1])).reshape(H, W)


def random_costmap(seed, dtype, shape=SHAPE):
    """Random costs in [0, 3), about 25 % ``inf`` cells and 5 % cells at or above ``LETHAL``;
    the goal is a passable cell."""
    rng = np.random.default_rng(seed)
    cost = rng.uniform(0.0, 3.0, shape)
    cost[rng.uniform(size=shape) < 0.25] = np.inf
    cost[rng.uniform(size=shape) < 0.05] = LETHAL + rng.uniform(0.0, 2.0)
    # The goal: a random cell of the largest 4-connected free region, so that most cells
    # are reachable and some are not.
    graph, _ = reference_graph(cost, 4)
    _, label = connected_components(graph, directed=False)
    free = (cost < LETHAL).ravel()
    biggest = np.bincount(label[free]).argmax()
    cells = np.flatnonzero(free & (label == biggest))
    goal = np.array(np.unravel_index(rng.choice(cells), shape))
    return cost.astype(dtype), goal


def run_field(cost, goal, connectivity=8, method="edges", lethal=LETHAL, cell=CELL):
    return np.asarray(gp.distance_field(cost, np.asarray(goal), connectivity=connectivity,
                                        lethal=lethal, cell=cell, method=method))


def path_of(dist, start, max_len=MAX_LEN, *, cost, connectivity=8):
    return gp.extract_path(dist, np.asarray(start), max_len, cost=cost,
                           connectivity=connectivity, lethal=LETHAL, cell=CELL)


def check_path(path, cost, dist, start, connectivity, lethal=LETHAL, cell=CELL):
    cells = np.asarray(path.cells)
    valid = np.asarray(path.valid)
    n = int(valid.sum())
    assert valid[:n].all() and not valid[n:].any(), "valid is a prefix"
    route = cells[:n]
    np.testing.assert_array_equal(route[0], start)
    assert bool(path.reached)
    assert dist[tuple(route[-1])] == 0.0
    total = 0.0
    for a, b in zip(route[:-1], route[1:]):
        step = tuple(int(v) for v in b - a)
        assert step in offsets(connectivity), f"{a} -> {b} is not a neighbour step"
        assert np.isfinite(cost[tuple(b)]) and cost[tuple(b)] < lethal, "entered a lethal cell"
        if step[0] and step[1]:
            assert cost[a[0] + step[0], a[1]] < lethal and cost[a[0], a[1] + step[1]] < lethal
        total += edge_cost(np.asarray(cost, np.float64), tuple(a), tuple(b), cell)
    np.testing.assert_allclose(total, dist[tuple(start)], rtol=1e-5 if cost.dtype == np.float32
                               else 1e-10)
    np.testing.assert_allclose(float(path.cost), dist[tuple(start)], rtol=1e-6)
    # After the goal the cells stay there.
    assert (cells[n:] == route[-1]).all()


# ---------------------------------------------------------------------------------------------
# Distance field


@pytest.mark.parametrize("connectivity", [4, 8])
@pytest.mark.parametrize("dtype,rtol", [(np.float32, 1e-5), (np.float64, 1e-12)])
def test_distance_field_equals_scipy_dijkstra(connectivity, dtype, rtol):
    for seed in range(4):
        cost, goal = random_costmap(seed, dtype)
        d = run_field(cost, goal, connectivity)
        ref = reference_field(cost, goal, connectivity)
        assert d.dtype == dtype
        np.testing.assert_array_equal(np.isinf(d), np.isinf(ref))
        assert np.isinf(ref).any() and np.isfinite(ref).sum() > 20
        np.testing.assert_allclose(d[np.isfinite(ref)], ref[np.isfinite(ref)], rtol=rtol)


@pytest.mark.parametrize("connectivity", [4, 8])
def test_line_relaxation_gives_the_same_field(connectivity):
    for seed in (10, 11):
        cost, goal = random_costmap(seed, np.float64)
        ref = reference_field(cost, goal, connectivity)
        d = run_field(cost, goal, connectivity, method="lines")
        np.testing.assert_array_equal(np.isinf(d), np.isinf(ref))
        np.testing.assert_allclose(d[np.isfinite(ref)], ref[np.isfinite(ref)], rtol=1e-12)


def test_open_grid_is_metric_and_lines_converge_in_few_rounds():
    cost = jnp.zeros(SHAPE)
    d, rounds = gp._field(cost, jnp.array([0, 0], jnp.int32), 8, LETHAL, CELL, "lines")
    i, j = np.mgrid[0:SHAPE[0], 0:SHAPE[1]]
    octile = CELL * (np.maximum(i, j) + (math.sqrt(2) - 1) * np.minimum(i, j))
    np.testing.assert_allclose(np.asarray(d), octile, rtol=1e-12)
    # Two straight runs (a diagonal, then a row or column) per path: a few rounds, not 23.
    assert int(rounds) <= 4


@pytest.mark.parametrize("dtype,rtol", [(np.float32, 1e-5), (np.float64, 1e-12)])
def test_start_cell_stops_once_the_start_and_its_paths_are_exact(dtype, rtol):
    """With ``start_cell`` the field equals Dijkstra's at the start and at every cell no
    farther from the goal, bounds it from above elsewhere, gives a shortest path from the
    start, and takes fewer rounds for a start nearer the goal."""
    for seed in range(3):
        cost, goal = random_costmap(seed, dtype)
        ref = reference_field(cost, goal, 8)
        reach = np.argwhere(np.isfinite(ref))
        rng = np.random.default_rng(seed)
        for start in reach[rng.choice(len(reach), 3, replace=False)]:
            d = np.asarray(field_jit(cost, goal, lethal=LETHAL, cell=CELL, start_cell=start))
            assert d.dtype == dtype
            near = ref <= ref[tuple(start)]
            np.testing.assert_allclose(d[near], ref[near], rtol=rtol)
            fin = np.isfinite(ref)
            assert np.all(d[fin] >= ref[fin] * (1 - rtol))
            assert np.all(np.isinf(d[~fin]))
            check_path(path_of(d, start, cost=cost), cost, d, start, 8)
    cost, goal = random_costmap(0, dtype)
    ref = reference_field(cost, goal, 8)
    _, full = gp._field(jnp.asarray(cost), jnp.asarray(goal), 8, LETHAL, CELL, "edges")
    finite = np.argwhere(np.isfinite(ref) & (ref > 0))
    near = finite[np.argmin(ref[tuple(finite.T)])]
    _, early = gp._field(jnp.asarray(cost), jnp.asarray(goal), 8, LETHAL, CELL, "edges",
                         jnp.asarray(near))
    assert int(early) < int(full)


def test_start_cell_needs_edges_and_a_cell():
    cost, goal = random_costmap(0, np.float64)
    with pytest.raises(ValueError, match="method='edges'"):
        gp.distance_field(cost, goal, method="lines", start_cell=goal)
    with pytest.raises(ValueError, match="start_cell"):
        gp.distance_field(cost, goal, start_cell=np.array([0, 0, 0]))


def test_impassable_goal_reaches_nothing():
    cost, goal = random_costmap(3, np.float64)
    cost[goal[0], goal[1]] = np.inf
    assert np.isinf(run_field(cost, goal)).all()
    cost[goal[0], goal[1]] = LETHAL
    assert np.isinf(run_field(cost, goal)).all()


def test_integer_costmap_and_default_lethal():
    cost = np.zeros(SHAPE, np.int32)
    cost[:, 3] = 2                  # finite: crossing it is dearer, not forbidden
    d = np.asarray(gp.distance_field(cost, np.array([0, 0]), connectivity=4, cell=CELL))
    assert d.dtype == jnp.result_type(float)
    # The steps into and out of column 3 cost 2 cells each.
    assert d[0, 6] == pytest.approx(CELL * (4.0 + 2 * 2.0))
    np.testing.assert_allclose(d, reference_field(cost, (0, 0), 4, lethal=math.inf))


# ---------------------------------------------------------------------------------------------
# Paths


@pytest.mark.parametrize("connectivity", [4, 8])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_extracted_path_is_a_shortest_path(connectivity, dtype):
    for seed in range(3):
        cost, goal = random_costmap(seed, dtype)
        d = run_field(cost, goal, connectivity)
        reach = np.argwhere(np.isfinite(d) & (d > 0))
        start = reach[np.argmax(d[tuple(reach.T)])]          # the farthest reachable cell
        path = path_of(d, start, cost=cost, connectivity=connectivity)
        check_path(path, cost, d, start, connectivity)


def test_unreachable_goal_flags_the_path():
    cost = np.zeros(SHAPE)
    cost[:, 9] = np.inf                                       # a wall with no gap
    d = run_field(cost, (2, 15))
    path = path_of(d, (2, 1), cost=cost)
    assert not bool(path.reached) and np.isinf(float(path.cost))
    np.testing.assert_array_equal(np.asarray(path.valid), [True] + [False] * (MAX_LEN - 1))
    assert (np.asarray(path.cells) == [2, 1]).all()


def test_start_at_goal_and_too_short_path():
    cost = np.zeros(SHAPE)
    d = run_field(cost, (4, 4))
    at_goal = path_of(d, (4, 4), cost=cost)
    assert bool(at_goal.reached) and int(at_goal.valid.sum()) == 1
    short = path_of(d, (0, 9), 3, cost=cost)
    assert not bool(short.reached) and bool(short.valid.all())
    # The beginning of a shortest path: two steps, then the rest of the way.
    cells = [tuple(int(v) for v in c) for c in np.asarray(short.cells)]
    steps = sum(edge_cost(cost, a, b) for a, b in zip(cells[:-1], cells[1:]))
    np.testing.assert_allclose(steps + d[cells[-1]], d[0, 9], rtol=1e-12)
    assert all(max(abs(b[0] - a[0]), abs(b[1] - a[1])) == 1 for a, b in zip(cells, cells[1:]))


def test_jit_equals_eager_and_vmap_over_goals():
    cost, start = random_costmap(5, np.float64)
    d = run_field(cost, start)
    reachable = np.argwhere(np.isfinite(d))
    cut_off = np.argwhere(np.isinf(d) & (cost < LETHAL))
    goals = np.stack([reachable[3], reachable[-1], start, cut_off[0]])
    np.testing.assert_array_equal(
        np.asarray(field_jit(jnp.asarray(cost), jnp.asarray(goals[1]), lethal=LETHAL,
                             cell=CELL)),
        run_field(cost, goals[1]))

    batched = jax.jit(jax.vmap(lambda g: gp.plan(jnp.asarray(cost), jnp.asarray(start), g,
                                                 MAX_LEN, lethal=LETHAL, cell=CELL)))(
        jnp.asarray(goals))
    for k, g in enumerate(goals):
        one = gp.plan(cost, start, g, MAX_LEN, lethal=LETHAL, cell=CELL)
        for a, b in zip(one, batched):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b)[k])
    np.testing.assert_array_equal(np.asarray(batched.reached), [True, True, True, False])
    np.testing.assert_array_equal(np.asarray(batched.valid.sum(1))[2:], [1, 1])


# ---------------------------------------------------------------------------------------------
# Grid geometry and following


def test_cell_of_and_centre_of_round_trip():
    grid = gp.Grid.create(origin=(-1.0, 2.0), cell=0.25, shape=(8, 12))
    cells = jnp.array([[0, 0], [3, 5], [7, 11]])
    xy = gp.centre_of(grid, cells)
    np.testing.assert_allclose(np.asarray(xy[1]), [-1.0 + 5 * 0.25, 2.0 + 3 * 0.25])
    np.testing.assert_array_equal(np.asarray(gp.cell_of(grid, xy + 0.1)), np.asarray(cells))
    # Outside the grid: clamped to the border.
    np.testing.assert_array_equal(np.asarray(gp.cell_of(grid, jnp.array([-9.0, 99.0]))), [7, 0])


def l_corridor():
    """A map lethal but for an L-shaped corridor three cells wide: along row 2 to column 15,
    then up column 15 to row 20; its centre line is free, its sides cost 1."""
    cost = np.full(SHAPE, np.inf)
    cost[1:4, 1:17] = 1.0
    cost[1:22, 14:17] = 1.0
    cost[2, 2:16] = 0.0
    cost[2:21, 15] = 0.0
    return cost


PURSUIT = gp.Params.create(k_speed=1.0, k_turn=1.5, v_max=0.5, omega_max=1.0)
CORRIDOR_GRID = gp.Grid.create(origin=(0.0, 0.0), cell=0.25, shape=SHAPE)
CORRIDOR_GOAL = (20, 15)
track_batch = jax.jit(jax.vmap(gp.track_path, (None, 0, None)))


@functools.partial(jax.jit, static_argnames="steps")
def pursue(params, cells, valid, pose0, steps):
    """Pure pursuit of a fixed path on the exact unicycle, 0.1 s steps, 0.5 m lookahead."""
    def step(pose, _):
        target = gp.lookahead_point(CORRIDOR_GRID, cells, valid, pose[:2], 0.5)
        u = gp.track_path(pose, target, params)
        return follower.unicycle_step(pose, u, 0.1), (pose, u)

    last, (poses, us) = jax.lax.scan(step, pose0, None, length=steps)
    return last, poses, us


@pytest.fixture(scope="module")
def corridor_path():
    cost = l_corridor()
    return cost, gp.plan(cost, np.array([2, 2]), np.array(CORRIDOR_GOAL), MAX_LEN, cell=0.25)


def test_pure_pursuit_follows_an_l_shaped_path_to_the_goal(corridor_path):
    cost, path = corridor_path
    assert bool(path.reached)
    pose0 = jnp.array([0.5, 0.5, 0.0])
    last, poses, us = pursue(PURSUIT, path.cells, path.valid, pose0, steps=250)
    goal = 0.25 * np.array(CORRIDOR_GOAL[::-1], float)
    assert np.linalg.norm(np.asarray(last[:2]) - goal) < 0.05
    us = np.asarray(us)
    assert (us[:, 0] >= 0).all() and (us[:, 0] <= 0.5 + 1e-12).all()
    assert (np.abs(us[:, 1]) <= 1.0 + 1e-12).all()
    assert us[:, 0].max() > 0.49                        # it drove at the speed limit
    # It stays in the corridor, near the centre line.
    cells = np.asarray(gp.cell_of(CORRIDOR_GRID, poses[:, :2]))
    assert np.isfinite(cost[cells[:, 0], cells[:, 1]]).all()
    line = np.asarray(gp.centre_of(CORRIDOR_GRID, path.cells))[np.asarray(path.valid)]
    a, b = line[:-1], line[1:]
    p = np.asarray(poses[:, :2])[:, None]
    t = np.clip(((p - a) * (b - a)).sum(-1) / ((b - a) ** 2).sum(-1), 0, 1)
    off = np.linalg.norm(p - (a + t[..., None] * (b - a)), axis=-1).min(1)
    assert off.max() < 0.2


def test_track_path_limits_and_gradient(corridor_path):
    targets = jnp.array([[1.0, 0.2], [-1.0, 0.3], [0.05, 3.0], [0.0, 0.0], [3.0, -0.1]])
    us = np.asarray(track_batch(jnp.zeros(3), targets, PURSUIT))
    assert (us[:, 0] >= 0).all() and (us[:, 0] <= 0.5 + 1e-12).all()
    assert (np.abs(us[:, 1]) <= 1.0 + 1e-12).all()
    assert us[1, 0] == 0.0 and us[1, 1] > 0.0         # a target behind: turn on the spot
    np.testing.assert_array_equal(us[3], [0.0, 0.0])  # at the target: stop
    assert us[4, 0] > 0.49 and us[4, 1] < 0.0         # far ahead, a little right
    np.testing.assert_array_equal(us[4], np.asarray(gp.track_path(jnp.zeros(3), targets[4],
                                                                  PURSUIT)))

    def finite(tree):
        return all(np.isfinite(np.asarray(x)).all() for x in jax.tree_util.tree_leaves(tree))

    g = jax.grad(lambda p: jnp.sum(gp.track_path(jnp.array([0.0, 0.0, 0.2]),
                                                 jnp.array([0.3, 0.1]), p)))(PURSUIT)
    assert finite(g) and float(g.log_k_speed) != 0.0
    # At the target: zero command, finite gradients.
    g_at = jax.grad(lambda p: jnp.sum(gp.track_path(jnp.zeros(3), jnp.zeros(2), p)))(PURSUIT)
    assert finite(g_at)
    # Through a closed loop (forward mode, which compiles faster here): how far the robot got
    # along the first leg in 3 s grows with the speed limit.
    _, path = corridor_path

    def progress(params):
        last = pursue(params, path.cells, path.valid, jnp.array([0.5, 0.5, 0.0]), steps=30)[0]
        return last[0]

    tangent = jax.tree_util.tree_map(jnp.zeros_like, PURSUIT)._replace(v_max=jnp.asarray(1.0))
    _, d_progress = jax.jvp(progress, (PURSUIT,), (tangent,))
    assert np.isfinite(float(d_progress)) and float(d_progress) > 0.0


def test_lookahead_point_walks_along_the_path():
    grid = gp.Grid.create(origin=(0.0, 0.0), cell=1.0, shape=(5, 5))
    cells = jnp.array([[0, 0], [0, 1], [0, 2], [1, 2], [2, 2], [2, 2]])
    valid = jnp.array([True] * 5 + [False])
    look = jax.jit(gp.lookahead_point)
    np.testing.assert_allclose(np.asarray(look(grid, cells, valid, jnp.array([0.5, -0.3]), 1.0)),
                               [1.5, 0.0])
    np.testing.assert_allclose(np.asarray(look(grid, cells, valid, jnp.array([1.5, 0.1]), 1.0)),
                               [2.0, 0.5])
    np.testing.assert_allclose(np.asarray(look(grid, cells, valid, jnp.array([2.0, 1.0]), 9.0)),
                               [2.0, 2.0])
    only_start = jnp.array([True] + [False] * 5)
    np.testing.assert_allclose(np.asarray(look(grid, cells, only_start, jnp.array([3.0, 3.0]),
                                               1.0)), [0.0, 0.0])


# ---------------------------------------------------------------------------------------------
# Bad input


def test_bad_input_raises_naming_the_argument():
    cost = np.zeros((6, 6))
    goal = np.array([1, 1])
    cases = [
        (ValueError, "cost", lambda: gp.distance_field(np.zeros(6), goal)),
        (ValueError, "cost", lambda: gp.distance_field(cost.copy() - 1.0, goal)),
        (ValueError, "cost", lambda: gp.distance_field(np.where(cost == 0, np.nan, 0), goal)),
        (TypeError, "cost", lambda: gp.distance_field(cost > 0, goal)),
        (ValueError, "goal_cell", lambda: gp.distance_field(cost, np.array([6, 0]))),
        (ValueError, "goal_cell", lambda: gp.distance_field(cost, np.array([1, 1, 1]))),
        (TypeError, "goal_cell", lambda: gp.distance_field(cost, np.array([1.0, 1.0]))),
        (ValueError, "connectivity", lambda: gp.distance_field(cost, goal, connectivity=6)),
        (ValueError, "lethal", lambda: gp.distance_field(cost, goal, lethal=0.0)),
        (ValueError, "cell", lambda: gp.distance_field(cost, goal, cell=-0.1)),
        (ValueError, "method", lambda: gp.distance_field(cost, goal, method="astar")),
        (ValueError, "start_cell", lambda: gp.extract_path(cost, np.array([-1, 0]), 8,
                                                           cost=cost)),
        (ValueError, "cost", lambda: gp.extract_path(cost, goal, 8, cost=np.zeros((5, 6)))),
        (ValueError, "max_len", lambda: gp.extract_path(cost, goal, 0, cost=cost)),
        (TypeError, "max_len", lambda: gp.extract_path(cost, goal, 8.0, cost=cost)),
        (TypeError, "params", lambda: gp.track_path(jnp.zeros(3), jnp.ones(2), (1.0, 1.0))),
        (ValueError, "params.v_max", lambda: gp.track_path(
            jnp.zeros(3), jnp.ones(2), PURSUIT._replace(v_max=jnp.asarray(-1.0)))),
        (ValueError, "params.log_k_turn", lambda: gp.track_path(
            jnp.zeros(3), jnp.ones(2), PURSUIT._replace(log_k_turn=jnp.asarray(np.nan)))),
        (ValueError, "pose", lambda: gp.track_path(jnp.zeros(2), jnp.ones(2), PURSUIT)),
        (ValueError, "omega_max", lambda: gp.Params.create(omega_max=0.0)),
        (ValueError, "cell", lambda: gp.Grid.create(cell=0.0)),
        (TypeError, "grid", lambda: gp.cell_of((0.0, 0.0), jnp.zeros(2))),
        (TypeError, "valid", lambda: gp.lookahead_point(
            gp.Grid.create(), jnp.zeros((3, 2), jnp.int32), jnp.ones(3), jnp.zeros(2), 1.0)),
        (ValueError, "distance", lambda: gp.lookahead_point(
            gp.Grid.create(), jnp.zeros((3, 2), jnp.int32), jnp.ones(3, bool), jnp.zeros(2),
            -1.0)),
        (ValueError, "steps", lambda: gp.clear_arc(jnp.ones(2), jnp.zeros(3), jnp.zeros(
            (4, 4), bool), gp.Grid.create(shape=(4, 4)), 0.1, 0)),
        (ValueError, "blocked", lambda: gp.clear_arc(jnp.ones(2), jnp.zeros(3), jnp.zeros(
            4, bool), gp.Grid.create(shape=(4, 4)), 0.1, 3)),
        (ValueError, "pose", lambda: gp.clear_arc(jnp.ones(2), jnp.full(3, jnp.nan), jnp.zeros(
            (4, 4), bool), gp.Grid.create(shape=(4, 4)), 0.1, 3)),
        (ValueError, "dt", lambda: gp.clear_arc(jnp.ones(2), jnp.zeros(3), jnp.zeros(
            (4, 4), bool), gp.Grid.create(shape=(4, 4)), 0.0, 3)),
    ]
    for error, name, call in cases:
        with pytest.raises(error, match=name):
            call()


def _clear_arc_reference(u, pose, blocked, origin, cell, dt, steps):
    """Plain-loop reference of `clear_arc`: Euler steps, the cell by rounding, clamped."""
    H, W = blocked.shape

    def hit(x, y):
        col = min(max(int(np.round((x - origin[0]) / cell)), 0), W - 1)
        row = min(max(int(np.round((y - origin[1]) / cell)), 0), H - 1)
        return bool(blocked[row, col])

    x, y, th = (float(v) for v in pose)
    start = hit(x, y)
    for k in range(1, steps + 1):
        th_k = th + k * u[1] * dt
        x, y = x + u[0] * dt * np.cos(th_k), y + u[0] * dt * np.sin(th_k)
        if hit(x, y) and not start:
            return np.array([0.0, u[1]])
    return np.asarray(u, float)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_clear_arc_stops_before_blocked_cells_like_a_plain_loop(dtype):
    rng = np.random.default_rng(4)
    grid = gp.Grid.create(origin=(-1.0, -1.0), cell=0.1, shape=(21, 21), dtype=dtype)
    fn = jax.jit(lambda u, p, b: gp.clear_arc(u, p, b, grid, 0.1, 5))
    yx = np.stack(np.meshgrid(np.arange(21), np.arange(21), indexing="ij"), -1) * 0.1 - 1.0
    stopped = kept = differ = 0
    for _ in range(200):
        u = np.array([rng.uniform(0.0, 0.8), rng.uniform(-1.2, 1.2)])
        pose = np.array([*rng.uniform(-0.5, 0.5, 2), rng.uniform(-np.pi, np.pi)])
        # a disc of blocked cells (a person's lethal core, inflated) about the robot's way
        ahead = pose[2] + rng.uniform(-1.0, 1.0)
        centre = pose[:2] + rng.uniform(0.2, 0.8) * np.array([np.cos(ahead), np.sin(ahead)])
        blocked = np.linalg.norm(yx[..., ::-1] - centre, axis=-1) < rng.uniform(0.1, 0.4)
        got = np.asarray(fn(jnp.asarray(u, dtype), jnp.asarray(pose, dtype), blocked))
        assert got.dtype == dtype
        want = _clear_arc_reference(u, pose, blocked, (-1.0, -1.0), 0.1, 0.1, 5)
        if not np.allclose(got, want, atol=1e-6):
            differ += 1          # a point within float rounding of a cell border
            continue
        stopped += bool(got[0] == 0.0)
        kept += bool(np.isclose(got[0], u[0]))
    assert differ <= 4 and stopped > 20 and kept > 20, (differ, stopped, kept)


def test_clear_arc_lets_a_robot_leave_a_blocked_cell_and_turn_away():
    grid = gp.Grid.create(origin=(0.0, 0.0), cell=0.1, shape=(20, 20))
    wall = jnp.zeros((20, 20), bool).at[:, 12:].set(True)                   # x >= 1.15 m
    u = jnp.array([0.8, 0.0])
    assert float(gp.clear_arc(u, jnp.array([0.5, 1.0, 0.0]), wall, grid, 0.1, 10)[0]) == 0.0
    # 0.4 m of driving does not reach it; facing away, or already inside, the robot may drive
    for pose in ([0.5, 1.0, 0.0, 5], [0.5, 1.0, np.pi, 10], [1.5, 1.0, 0.0, 10]):
        out = gp.clear_arc(u, jnp.asarray(pose[:3]), wall, grid, 0.1, pose[3])
        np.testing.assert_array_equal(out, u)
    # the turn is kept when the speed is not
    out = gp.clear_arc(jnp.array([0.8, 0.3]), jnp.array([0.5, 1.0, 0.0]), wall, grid, 0.1, 10)
    np.testing.assert_allclose(out, [0.0, 0.3])


def test_bad_cells_under_jit_are_impassable():
    cost = np.zeros(SHAPE)
    cost[5, :] = np.nan
    cost[6, :] = -1.0
    d = np.asarray(field_jit(jnp.asarray(cost), jnp.array([0, 0]), lethal=LETHAL, cell=CELL))
    assert np.isinf(d[5:]).all() and np.isfinite(d[:5]).all()
    # A goal outside the grid under jit reaches nothing.
    out = field_jit(jnp.zeros(SHAPE), jnp.array([99, 0]), lethal=LETHAL, cell=CELL)
    assert np.isinf(np.asarray(out)).all()


def test_refine_keeps_the_exact_field_and_converges_to_a_changed_costmap():
    """The exact field is a fixed point of `refine`; from the field of another costmap (a
    person moved: costs rose in one place and fell in another) enough rounds give the new
    field exactly, with values that rose as well as fell; from all-inf nothing is reachable
    but the goal's neighbourhood grows one cell per round."""
    cost0, goal = random_costmap(0, np.float64)
    d0 = reference_field(cost0, goal, 8)
    d0_jax = run_field(jnp.asarray(cost0), goal)
    kw = dict(cell=CELL, lethal=LETHAL)
    np.testing.assert_allclose(np.asarray(gp.refine(d0_jax, jnp.asarray(cost0), goal, 3, **kw)),
                               d0, rtol=1e-12)
    cost1 = cost0.copy()
    rng = np.random.default_rng(1)
    changed = rng.uniform(size=SHAPE) < 0.3
    cost1 = np.where(changed & (cost0 < LETHAL), rng.uniform(0.0, 3.0, SHAPE), cost0)
    d1 = reference_field(cost1, goal, 8)
    assert np.any(np.isfinite(d1) & (d1 > d0 + 1e-6)) and np.any(d1 < d0 - 1e-6)
    d = jnp.asarray(d0)
    for _ in range(40):
        d = gp.refine(d, jnp.asarray(cost1), goal, 5, **kw)
    np.testing.assert_allclose(np.asarray(d), d1, rtol=1e-10)
    assert np.array_equal(np.isinf(np.asarray(d)), np.isinf(d1))
    one = np.asarray(gp.refine(jnp.full(SHAPE, jnp.inf), jnp.asarray(cost1), goal, 1, **kw))
    assert one[tuple(goal)] == 0 and np.isfinite(one).sum() <= 9
    with pytest.raises(ValueError, match="sweeps"):
        gp.refine(d, jnp.asarray(cost1), goal, 0, **kw)
    with pytest.raises(ValueError, match="cost"):
        gp.refine(d, jnp.zeros((3, 3)), goal, 1, **kw)
