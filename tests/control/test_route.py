"""Routes on a static map: free cells, shortest routes, straight-segment shortcuts.

References: free cells are checked by a numpy distance computation; route lengths by a plain
heapq Dijkstra on the same 8-connected grid; segment clearances by dense sampling of the
segments in numpy.
"""

import heapq
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack import geometry
from jaxtrack.control import avoidance, follower, route

BOUNDS = ((-3.0, 3.0), (-2.0, 2.0))
CELL, CLEAR = 0.25, 0.45


def wall_points():
    """A wall from (0, -2) up to (0, 0.5), sampled every 0.05 m: the way from left to right is
    over its top."""
    y = np.arange(-2.0, 0.5 + 1e-9, 0.05)
    return np.stack([np.zeros_like(y), y], -1)


@pytest.fixture(scope="module")
def wall_route():
    return route.build(wall_points(), BOUNDS, cell=CELL, clearance=CLEAR, dtype=jnp.float64)


waypoint = jax.jit(route.waypoint, static_argnames=("lookahead",))


def dijkstra(free, nx, ny, cell, src):
    """Distances [C] from ``src`` on the 8-connected grid of free cells (no corner cutting)."""
    dist = np.full(nx * ny, np.inf)
    dist[src] = 0.0
    heap = [(0.0, src)]
    while heap:
        d, i = heapq.heappop(heap)
        if d > dist[i]:
            continue
        iy, ix = divmod(i, nx)
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                jx, jy = ix + dx, iy + dy
                if (dx, dy) == (0, 0) or not (0 <= jx < nx and 0 <= jy < ny):
                    continue
                j = jx + nx * jy
                if not free[j]:
                    continue
                if dx and dy and not (free[jx + nx * iy] and free[ix + nx * jy]):
                    continue
                nd = d + cell * math.hypot(dx, dy)
                if nd < dist[j] - 1e-12:
                    dist[j] = nd
                    heapq.heappush(heap, (nd, j))
    return dist


def sampled_clearance(a, b, obstacles, n=4001):
    t = np.linspace(0.0, 1.0, n)[:, None]
    pts = a + t * (b - a)
    return np.sqrt(((pts[:, None] - obstacles[None]) ** 2).sum(-1)).min()


def test_free_cells_keep_the_clearance_from_obstacles_and_bounds(wall_route):
    rt = wall_route
    centres = np.asarray(rt.centres)
    d = np.sqrt(((centres[:, None] - wall_points()[None]) ** 2).sum(-1)).min(1)
    (x0, x1), (y0, y1) = BOUNDS
    edge = np.minimum.reduce([centres[:, 0] - x0, x1 - centres[:, 0], centres[:, 1] - y0,
                              y1 - centres[:, 1]])
    np.testing.assert_array_equal(np.asarray(rt.free), (d >= CLEAR) & (edge >= CLEAR))
    # Snapping: free cells map to themselves, others to their nearest free cell.
    snap = np.asarray(rt.snap)
    free = np.asarray(rt.free)
    assert np.all(snap[free] == np.nonzero(free)[0])
    fc = np.nonzero(free)[0]
    for i in np.nonzero(~free)[0][:50]:
        dd = np.linalg.norm(centres[fc] - centres[i], axis=1)
        assert np.isclose(dd[fc == snap[i]][0], dd.min())


def test_following_next_hops_gives_shortest_routes(wall_route):
    rt = wall_route
    nx, ny = (int(v) for v in rt.shape)
    free = np.asarray(rt.free)
    nxt = np.asarray(rt.next_hop)
    rng = np.random.default_rng(0)
    fc = np.nonzero(free)[0]
    for src in rng.choice(fc, 6, replace=False):
        dist = dijkstra(free, nx, ny, CELL, src)
        assert np.all(np.isfinite(dist[fc]))  # one connected free space
        for dst in rng.choice(fc, 10, replace=False):
            # walk from dst to src along next_hop[., src]
            length, c = 0.0, dst
            for _ in range(nx * ny):
                if c == src:
                    break
                n = nxt[c, src]
                length += CELL * math.hypot(*np.subtract(divmod(n, nx), divmod(c, nx)))
                c = n
            assert c == src
            np.testing.assert_allclose(length, dist[dst], rtol=1e-9)


def test_waypoint_is_the_goal_when_the_way_is_clear(wall_route):
    obst = jnp.asarray(wall_points())
    start, goal = jnp.array([-2.0, 1.5]), jnp.array([2.0, 1.6])
    wp, direct = waypoint(wall_route, start, goal, obst)
    assert bool(direct)
    np.testing.assert_allclose(wp, goal)


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_waypoints_lead_around_the_wall_on_clear_segments(dtype):
    rt = route.build(wall_points(), BOUNDS, cell=CELL, clearance=CLEAR, dtype=dtype)
    obst = jnp.asarray(wall_points(), dtype)
    seg = 0.4
    start, goal = np.array([-1.5, -1.0]), np.array([1.5, -1.0])
    pos, steps, top = start, 0, -np.inf
    for steps in range(40):
        wp, direct = waypoint(rt, jnp.asarray(pos, dtype), jnp.asarray(goal, dtype), obst,
                              clearance=seg)
        wp = np.asarray(wp, float)
        if bool(direct):
            assert sampled_clearance(pos, goal, wall_points()) >= seg - 1e-3
            break
        assert sampled_clearance(pos, wp, wall_points()) >= seg - 1e-3
        pos = pos + 0.3 * (wp - pos) / max(np.linalg.norm(wp - pos), 0.3)  # 0.3 m steps
        top = max(top, pos[1])
    else:
        pytest.fail("the waypoints never led to a clear line to the goal")
    # over the top of the wall (0.5 m) with its clearance, then down (0.3 m steps)
    assert pos[0] > 0 and top > 0.5 + seg - 0.1 and steps >= 8


def test_segment_clear_matches_dense_sampling():
    rng = np.random.default_rng(3)
    obst = rng.uniform(-2, 2, (30, 2))
    start = np.array([0.1, -0.2])
    ends = rng.uniform(-3, 3, (200, 2))
    c = 0.35
    got = np.asarray(route.segment_clear(jnp.asarray(start), jnp.asarray(ends),
                                         jnp.asarray(obst), jnp.ones(30, bool), c))
    for e, g in zip(ends, got):
        pts = start + np.linspace(0, 1, 2001)[:, None] * (e - start)
        dmin = np.sqrt(((pts[:, None] - obst[None]) ** 2).sum(-1)).min(0)
        start_d = np.linalg.norm(obst - start, axis=1)
        need = np.minimum(c, start_d)
        margin = dmin - need
        if np.all(margin > 1e-3):
            assert g
        elif np.any(margin < -1e-3):
            assert not g
    # Masked obstacles are ignored; a start already near a point may move away from it.
    assert np.all(route.segment_clear(jnp.asarray(start), jnp.asarray(ends), jnp.asarray(obst),
                                      jnp.zeros(30, bool), c))
    away = route.segment_clear(jnp.zeros(2), jnp.array([[-1.0, 0.0], [1.0, 0.0]]),
                               jnp.array([[0.1, 0.0]]), jnp.ones(1, bool), 0.3)
    np.testing.assert_array_equal(away, [True, False])


def test_without_a_route_the_waypoint_is_the_goal():
    # A wall across the whole room: the two halves are not connected.
    y = np.arange(-2.0, 2.0 + 1e-9, 0.05)
    wall = np.stack([np.zeros_like(y), y], -1)
    rt = route.build(wall, BOUNDS, cell=CELL, clearance=CLEAR)
    goal = jnp.array([1.5, 0.0])
    wp, direct = waypoint(rt, jnp.array([-1.5, 0.0]), goal, jnp.asarray(wall))
    assert bool(direct)
    np.testing.assert_allclose(wp, goal)


def test_waypoint_vmaps_like_a_loop(wall_route):
    rng = np.random.default_rng(5)
    obst = jnp.asarray(wall_points())
    starts = jnp.asarray(rng.uniform([-2.5, -1.5], [-0.6, 1.5], (8, 2)))
    goals = jnp.asarray(rng.uniform([0.6, -1.5], [2.5, 1.5], (8, 2)))
    wps, ds = jax.vmap(lambda s, g: waypoint(wall_route, s, g, obst))(starts, goals)
    for i in range(8):
        wp, d = waypoint(wall_route, starts[i], goals[i], obst)
        np.testing.assert_allclose(wps[i], wp)
        assert bool(ds[i]) == bool(d)


def test_bad_input_raises_clear_errors(wall_route):
    with pytest.raises(ValueError, match="bounds"):
        route.build(wall_points(), ((1.0, -1.0), (-1.0, 1.0)))
    with pytest.raises(ValueError, match="no free cell"):
        route.build(wall_points(), BOUNDS, clearance=5.0)
    with pytest.raises(ValueError, match="finite"):
        route.build(np.array([[np.nan, 0.0]]), BOUNDS)
    with pytest.raises(ValueError, match="too large"):
        route.build(wall_points(), ((-50, 50), (-50, 50)), cell=0.1)
    with pytest.raises(ValueError, match=r"\[Q, 2\]"):
        route.waypoint(wall_route, jnp.zeros(2), jnp.ones(2), jnp.zeros(3))
    with pytest.raises(ValueError, match="lookahead"):
        route.waypoint(wall_route, jnp.zeros(2), jnp.ones(2), jnp.zeros((1, 2)), lookahead=0)
    with pytest.raises(ValueError, match="start"):
        route.waypoint(wall_route, jnp.zeros(3), jnp.ones(2), jnp.zeros((1, 2)))


def cup_points():
    """A cup open toward -x (the robot's side): back wall at x = 0.5, arms to x = -1."""
    ys = np.arange(-1.5, 1.5 + 1e-9, 0.1)
    xs = np.arange(-1.0, 0.5, 0.1)
    return np.concatenate([np.stack([np.full_like(ys, 0.5), ys], -1),
                           np.stack([xs, np.full_like(xs, 1.5)], -1),
                           np.stack([xs, np.full_like(xs, -1.5)], -1)])


def closed_loop(use_route, steps=400, dt=0.1):
    """Follower law + (route) + dynamic window on a unicycle; a person stands behind the cup."""
    obst = jnp.asarray(cup_points())
    rt = route.build(cup_points(), ((-4.0, 4.0), (-4.0, 4.0)), cell=0.25, clearance=0.65)
    fp = follower.Params.create(point="A", v_max=1.0, omega_max=1.5, a_max=1.5, alpha_max=3.0)
    ap = avoidance.AvoidanceParams(radius=0.3, margin=0.3, horizon=1.0, v_max=1.0,
                                   omega_max=1.5, a_max=1.5, alpha_max=3.0, dt=dt)
    person = jnp.array([2.5, 0.0])
    point = jnp.asarray(fp.point)

    def body(carry, _):
        pose, prev = carry
        goal = person
        if use_route:
            wp, direct = route.waypoint(rt, pose[:2], person, obst)
            away = wp - pose[:2]
            reach = wp + jnp.linalg.norm(point) * away / jnp.maximum(jnp.linalg.norm(away), 1e-3)
            goal = jnp.where(direct, person, reach)
        u = follower.control(fp, geometry.to_frame(pose, goal), jnp.zeros(2), prev, dt,
                             reverse=False)
        c, s = jnp.cos(pose[2]), jnp.sin(pose[2])
        d = obst - pose[:2]
        local = jnp.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], -1)
        u, _ = avoidance.select(ap, u, prev, local, jnp.ones(local.shape[0], bool))
        pose = follower.unicycle_step(pose, u, dt)
        return (pose, u), pose

    run = jax.jit(lambda: jax.lax.scan(body, (jnp.array([-2.5, 0.0, 0.0]), jnp.zeros(2)), None,
                                       length=steps)[1])
    return np.asarray(run()), np.asarray(person)


def test_route_leads_a_follower_out_of_the_cup_a_straight_law_is_trapped_in():
    for use_route in (True, False):
        poses, person = closed_loop(use_route)
        th = poses[:, 2]
        follow_pt = poses[:, :2] + 1.5 * np.stack([np.cos(th), np.sin(th)], -1)
        err = np.linalg.norm(follow_pt - person, axis=-1)
        clearance = np.sqrt(((poses[:, None, :2] - cup_points()[None]) ** 2).sum(-1)).min()
        assert clearance > 0.3  # the body never touches the cup
        if use_route:
            assert err[-50:].max() < 0.3, err[-50:].max()
        else:
            assert err[-50:].min() > 1.5, err[-50:].min()
