r"""Routes around the known obstacles of a static map: where to steer when a person is out of
straight reach.

A follower law that steers straight at the person (`jaxtrack.control.follower`) gets stuck in
front of a table the person walked around: the local obstacle layer
(`jaxtrack.control.avoidance`) stops it, and nothing turns it away. With a map of the static
obstacles (tables, chairs, walls), the shortest routes can be computed once, and each control
step only looks them up:

- `build` (numpy, once per map): a grid of ``cell`` metres over the free space; a cell is free
  when its centre keeps ``clearance`` from every obstacle point and from the bounds (for a
  robot of radius :math:`r` and safety margin :math:`m`, :math:`r + m` and a little more, so
  that a route never passes where the safety layers would stop the robot). Shortest paths on
  the 8-connected grid of free cells (Dijkstra, `scipy.sparse.csgraph.shortest_path`) give
  ``next_hop[i, j]``, the next cell from ``i`` toward ``j``; a cell that is not free is
  snapped to the nearest free cell.
- `waypoint` (jittable): the goal itself when the straight segment to it is clear; otherwise
  the farthest of the next ``lookahead`` cells of the route whose straight segment from the
  start is clear (a shortcut along the route, so the robot does not zigzag on the grid).

A segment from :math:`s` to :math:`p` is clear when
:math:`\min_{t \in [0, 1]} |o_j - (s + t (p - s))| \ge \min(c, |o_j - s|)` for every obstacle
point :math:`o_j`: it keeps the clearance :math:`c`, and a robot already nearer than :math:`c`
to a point may leave it but not approach it.

Example:
  >>> rt = route.build(outline_xy, ((-5, 5), (-4, 4)), cell=0.25, clearance=0.65)
  >>> wp, direct = route.waypoint(rt, robot_xy, person_xy, outline_xy, clearance=0.6,
  ...                             direct_clearance=0.3)
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import _checks

Array = jax.Array

__all__ = ["Route", "build", "waypoint", "segment_clear", "cell_of"]


class Route(NamedTuple):
    """Precomputed routes of a grid over a static map.

    Attributes:
      origin: [2] centre of cell (0, 0); cell: scalar cell size (m).
      shape: [2] int32 (nx, ny); cells are numbered ``ix + nx * iy``.
      centres: [C, 2] cell centres; free: [C] bool.
      snap: [C] int32, the nearest free cell of every cell (itself when free).
      next_hop: [C, C] int32, the next cell from ``i`` toward ``j`` (``i`` when ``i == j`` or
        ``j`` is unreachable).
    """

    origin: Array
    cell: Array
    shape: Array
    centres: Array
    free: Array
    snap: Array
    next_hop: Array


def build(obstacles, bounds, cell: float = 0.25, clearance: float = 0.65,
          dtype=jnp.float32) -> Route:
    """Routes over the rectangle ``bounds = ((x_min, x_max), (y_min, y_max))`` around the
    obstacle points ``obstacles`` [Q, 2] (numpy, once per map).

    Args:
      obstacles: [Q, 2] static obstacle points (e.g. furniture outlines every 0.1 m).
      bounds: the walls' rectangle (m); cells keep ``clearance`` from it too.
      cell: grid spacing (m). clearance: free-cell distance from obstacles and bounds (m).

    Returns:
      `Route`.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import shortest_path

    obstacles = np.asarray(obstacles, float).reshape(-1, 2)
    if not np.all(np.isfinite(obstacles)):
        raise ValueError("obstacles must be finite")
    (x0, x1), (y0, y1) = ((float(a), float(b)) for a, b in bounds)
    if not (x1 > x0 and y1 > y0):
        raise ValueError(f"bounds must be ((x_min, x_max), (y_min, y_max)); got {bounds}")
    if not cell > 0 or not clearance >= 0:
        raise ValueError(f"cell must be > 0 and clearance >= 0; got {cell}, {clearance}")
    nx, ny = int(np.ceil((x1 - x0) / cell)), int(np.ceil((y1 - y0) / cell))
    if nx * ny > 4096:
        raise ValueError(f"{nx} x {ny} cells: the [C, C] route table would be too large; "
                         f"use a larger cell")
    origin = np.array([x0 + 0.5 * cell, y0 + 0.5 * cell])
    iy, ix = np.divmod(np.arange(nx * ny), nx)
    centres = origin + cell * np.stack([ix, iy], -1)
    inside = ((centres[:, 0] - x0 >= clearance) & (x1 - centres[:, 0] >= clearance)
              & (centres[:, 1] - y0 >= clearance) & (y1 - centres[:, 1] >= clearance))
    if len(obstacles):
        d = np.sqrt(((centres[:, None] - obstacles[None]) ** 2).sum(-1)).min(1)
        inside &= d >= clearance
    free = inside
    if not free.any():
        raise ValueError("no free cell: reduce clearance or cell")
    # 8-connected edges between free cells (diagonals only when both side cells are free, so
    # a route never cuts an obstacle's corner).
    rows, cols, w = [], [], []
    grid = free.reshape(ny, nx)
    for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
        a = np.zeros_like(grid)
        ys, ye = max(0, -dy), ny - max(0, dy)
        a[ys:ye, :nx - dx] = (grid[ys:ye, :nx - dx] & grid[ys + dy:ye + dy, dx:])
        if dx and dy:
            a[ys:ye, :nx - dx] &= grid[ys:ye, dx:] & grid[ys + dy:ye + dy, :nx - dx]
        yy, xx = np.nonzero(a)
        i = xx + nx * yy
        j = (xx + dx) + nx * (yy + dy)
        rows += [i, j]
        cols += [j, i]
        w += [np.full(len(i) * 2, cell * np.hypot(dx, dy))]
    C = nx * ny
    graph = coo_matrix((np.concatenate(w), (np.concatenate(rows), np.concatenate(cols))),
                       shape=(C, C)).tocsr()
    _, pred = shortest_path(graph, method="D", directed=False, return_predecessors=True)
    # pred[j, i] is the cell before i on the path from j: the next hop from i toward j.
    nxt = pred.T.copy()
    bad = nxt < 0
    nxt[bad] = np.broadcast_to(np.arange(C)[:, None], (C, C))[bad]
    fc = np.nonzero(free)[0]
    d2 = ((centres[:, None] - centres[fc][None]) ** 2).sum(-1)
    snap = fc[np.argmin(d2, 1)]
    return Route(jnp.asarray(origin, dtype), jnp.asarray(cell, dtype),
                 jnp.asarray([nx, ny], jnp.int32), jnp.asarray(centres, dtype),
                 jnp.asarray(free), jnp.asarray(snap, jnp.int32),
                 jnp.asarray(nxt, jnp.int32))


def cell_of(route: Route, xy: Array) -> Array:
    """The free cell (int32) nearest to the cell containing ``xy`` [2] (clamped to the grid)."""
    idx = jnp.round((jnp.asarray(xy, route.origin.dtype) - route.origin) / route.cell)
    idx = jnp.clip(jnp.nan_to_num(idx), 0, route.shape - 1).astype(jnp.int32)
    return route.snap[idx[0] + route.shape[0] * idx[1]]


def segment_clear(start: Array, ends: Array, obstacles: Array, obstacle_mask: Array,
                  clearance) -> Array:
    """[M] bool: whether each segment ``start`` [2] -> ``ends`` [M, 2] is clear of the masked
    obstacle points [Q, 2] (module docstring)."""
    # Coordinates as separate [M, Q] planes, not a trailing axis of 2: XLA's CPU backend
    # vectorises over the minor axis; a minor axis of 2 made this about 27x slower (804
    # outline points of the shop: docs/design_notes.md, "Routes and avoidance").
    abx, aby = (ends - start)[:, 0:1], (ends - start)[:, 1:2]            # [M, 1]
    aox, aoy = obstacles[None, :, 0] - start[0], obstacles[None, :, 1] - start[1]  # [1, Q]
    den = abx * abx + aby * aby
    t = jnp.clip((aox * abx + aoy * aby) / jnp.where(den > 0, den, 1.0), 0.0, 1.0)
    dx, dy = aox - t * abx, aoy - t * aby
    d2 = dx * dx + dy * dy
    limit = jnp.minimum(jnp.asarray(clearance, d2.dtype) ** 2, aox * aox + aoy * aoy)
    return jnp.all(~obstacle_mask[None, :] | (d2 >= limit * (1.0 - 1e-4)), -1)


def waypoint(route: Route, start: Array, goal: Array, obstacles: Array,
             obstacle_mask: Array | None = None, clearance=0.6, direct_clearance=None,
             lookahead: int = 12):
    """Where to steer from ``start`` [2] toward ``goal`` [2] (module docstring).

    Args:
      route: `Route` (from `build`, in the frame of ``start`` and ``goal``).
      obstacles: [Q, 2] points the straight segments must clear; obstacle_mask: [Q] bool.
      clearance: clearance (m) of the segments to route cells (what the robot's obstacle
        layer needs to drive them). direct_clearance: clearance of the straight segment to
        the goal (default ``clearance``; smaller lets a follower that stops short of the goal
        keep steering straight at it past a table corner).
      lookahead: route cells looked ahead (static).

    Returns:
      ``(waypoint [2], direct)``: ``direct`` is True when the waypoint is the goal itself (a
      clear straight line, or no route: start and goal in one cell, or in unconnected free
      space).
    """
    _checks.check_shape("start", start, (2,), "(x, y)")
    _checks.check_shape("goal", goal, (2,), "(x, y)")
    obstacles = jnp.asarray(obstacles, route.origin.dtype)
    if obstacles.ndim != 2 or obstacles.shape[-1] != 2:
        raise ValueError(f"obstacles must have shape [Q, 2]; got {list(obstacles.shape)}")
    if int(lookahead) < 1:
        raise ValueError(f"lookahead must be >= 1; got {lookahead}")
    if obstacle_mask is None:
        obstacle_mask = jnp.ones(obstacles.shape[0], bool)
    dtype = route.origin.dtype
    start = jnp.asarray(start, dtype)
    goal = jnp.asarray(goal, dtype)
    s, g = cell_of(route, start), cell_of(route, goal)

    def hop(c, _):
        n = route.next_hop[c, g]
        return n, n

    _, path = jax.lax.scan(hop, s, None, length=int(lookahead))
    direct = segment_clear(start, goal[None], obstacles, obstacle_mask,
                           clearance if direct_clearance is None else direct_clearance)[0]
    reachable = segment_clear(start, route.centres[path], obstacles, obstacle_mask, clearance)
    far = jnp.argmax(jnp.where(reachable, jnp.arange(int(lookahead)), -1))
    wp = jnp.where(jnp.any(reachable), route.centres[path[far]], route.centres[path[0]])
    # Same cell, or no route (the goal's free space is cut off): steer at the goal itself.
    no_route = (s == g) | (path[0] == s)
    direct = direct | no_route
    return jnp.where(direct, goal, wp), direct
