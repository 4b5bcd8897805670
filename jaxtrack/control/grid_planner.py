r"""Shortest paths on a costmap grid, planned on the device every frame, and a pure-pursuit
follower for the path (human-aware navigation, seed 003 section IV).

A service robot's costmap changes with every tracked person, so the plan is recomputed every
control period, inside the same jitted (and vmapped) step as the tracker. Everything here has
fixed shapes and no host round trip.

**The graph.** Cell :math:`(r, c)` of a costmap ``cost`` [H, W] is *passable* when
:math:`0 \le \mathrm{cost}_{rc} < \mathrm{lethal}` (so ``inf`` is never passable). Passable
cells are joined to their 4 or 8 neighbours; a diagonal step is allowed only when both cells it
passes between are passable too, so a path never cuts an obstacle's corner. The edge cost is the
trapezoid rule for the line integral of :math:`1 + \mathrm{cost}` along the step:

.. math::
    w(a, b) = \ell_{ab}\, h \left(1 + \tfrac{1}{2} (\mathrm{cost}_a + \mathrm{cost}_b)\right),
    \qquad \ell_{ab} \in \{1, \sqrt 2\},

with :math:`h` the cell size (m). A cost is a dimensionless surcharge: crossing cells of cost
:math:`c` takes :math:`1 + c` times their length, so a free map gives metric distances. The
weights are symmetric, so the distance *to* the goal equals the distance *from* it.

**The distance field** (`distance_field`) is the cost-to-go :math:`D` to the goal, the solution
of the Bellman equation :math:`D_g = 0`, :math:`D_a = \min_{b \sim a} w(a, b) + D_b`, with
:math:`D = \infty` where the goal cannot be reached. Dijkstra's algorithm (scipy's
``csgraph.dijkstra``) needs a priority queue: data-dependent control flow that neither traces
under ``jit`` nor runs on an accelerator, and that would force a host callback (which loses
batching) into every control step. Bellman-Ford needs only array operations: starting from
:math:`D = \infty` except :math:`D_g = 0`, relaxation rounds that never raise a value and only
produce lengths of real paths are repeated in a `lax.while_loop` until a round changes
nothing (tested every 4 edge rounds: the test reads the whole field, as a round does); then the
Bellman equation holds and :math:`D` is the shortest-path distance (at most H * W rounds,
Bellman-Ford's bound). "Nothing" is up to rounding: no value drops by more than
16 ulps (relative), so :math:`D` is within that of the exact distances. Two relaxations:

- ``method="edges"`` (default; plain Bellman-Ford / value iteration): every cell takes the
  minimum over its neighbours, read from shifted copies of the field, :math:`D_a \leftarrow
  \min(D_a, \min_b w(a, b) + D_b)`. The weights are factored as
  :math:`w(a, b) = \ell_{ab}(u_a + u_b)`, :math:`u = \tfrac{h}{2}(1 + \mathrm{cost})`, so a
  round reads the field and :math:`u` rather than eight weight arrays (equal to the weights
  above up to rounding). A round moves information one cell, so a path of :math:`n` steps
  needs :math:`n` rounds.
- ``method="lines"``: every grid line (rows, columns and, with 8-connectivity, both
  diagonal families) is relaxed *exactly* in one round, by a min-plus prefix scan
  in each direction: an element :math:`(w_i, D_i)` stands for the map
  :math:`x \mapsto \min(x + w_i, D_i)` and maps compose as :math:`(a_1, b_1) \circ (a_2, b_2) =
  (a_1 + a_2, \min(b_1 + a_2, b_2))`. A path made of :math:`k` straight runs then needs about
  :math:`k` rounds, whatever its length. On XLA:CPU this does not pay: on 64 x 64 and
  128 x 128 rooms it took 6-17 rounds where ``"edges"`` took 56-148, but each round cost
  100-300 times as much, so it was 17-31 times slower overall (``benchmarks/grid_planner.py``,
  which also compares both with scipy). It is kept for maps of long free runs, where the
  number of edge rounds grows with the map and the number of line rounds does not.

**The path** (`extract_path`) descends the field from the start: each step goes to the
neighbour minimising :math:`w(a, b) + D_b`, which on a converged field equals :math:`D_a` for a
successor on a shortest path, so the path's summed edge cost is :math:`D_{start}`. It is a
fixed-length [max_len, 2] array of cells with a ``valid`` mask (a `lax.scan`).

**Following** (`lookahead_point`, `track_path`): pure pursuit (Coulter 1992). The target is the
point ``distance`` metres further along the path than the point of the path closest to the
robot; a unicycle at :math:`(x, y, \theta)` with the target at range :math:`L` and bearing
:math:`\alpha` in its frame drives the arc through it, curvature :math:`\kappa = 2 \sin\alpha /
L`:

.. math::
    v = \min(v_{max}, k_v L) \max(\cos\alpha, 0), \qquad
    \omega = \kappa v + k_\omega\, \alpha\, (1 - \max(\cos\alpha, 0)),

slowing as the target (at the end, the goal) comes near, and turning on the spot toward a target
behind it. The command is then scaled as a whole into :math:`|v| \le v_{max}`,
:math:`|\omega| \le \omega_{max}`, which keeps the curvature it asked for.

Cells are ``(row, col)`` int32 pairs indexing ``cost[row, col]``; rows run along world
:math:`y` and columns along :math:`x` (`Grid`, `cell_of`, `centre_of`).

Public API: `Grid`, `cell_of`, `centre_of`, `distance_field`, `refine` (a few rounds from the
previous frame's field), `Path`, `extract_path`, `plan`, `Params`, `lookahead_point`,
`track_path`.

Example:
  >>> cost = jnp.zeros((32, 32)).at[10:20, 16].set(jnp.inf)     # a wall
  >>> path = plan(cost, jnp.array([15, 2]), jnp.array([15, 30]), max_len=64, cell=0.1)
  >>> grid = Grid.create(origin=(0.0, 0.0), cell=0.1, shape=(32, 32))
  >>> target = lookahead_point(grid, path.cells, path.valid, robot_xy, 0.4)
  >>> u = track_path(robot_pose, target, Params.create(v_max=0.5, omega_max=1.0))
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxtrack import _checks

Array = jax.Array

__all__ = ["Grid", "cell_of", "centre_of", "distance_field", "refine", "Path", "extract_path",
           "plan", "Params", "lookahead_point", "track_path", "clear_arc"]

_STRAIGHT = ((0, 1), (1, 0), (0, -1), (-1, 0))
_DIAGONAL = ((1, 1), (1, -1), (-1, 1), (-1, -1))
_METHODS = ("lines", "edges")
_CHECK_EVERY = 4
"""Edge relaxation rounds of `_field` between two convergence tests."""


# ---------------------------------------------------------------------------------------------
# Grid geometry


class Grid(NamedTuple):
    """Where a costmap's cells are in the world.

    Cell ``(row, col)`` is the square of side ``cell`` centred at
    ``origin + cell * (col, row)`` (x along columns, y along rows).

    Attributes:
      origin: [2] world (x, y) of the centre of cell (0, 0) (m).
      cell: scalar cell size (m).
      shape: [2] int32 (H, W), the costmap's shape (rows, columns).
    """

    origin: Array
    cell: Array
    shape: Array

    @classmethod
    def create(cls, origin=(0.0, 0.0), cell=0.1, shape=(32, 32), dtype=None) -> "Grid":
        """A grid from its cell-(0, 0) centre, cell size and (H, W).

        Example:
          >>> grid = Grid.create(origin=(-1.6, -1.6), cell=0.1, shape=(32, 32))
        """
        _checks.check_shape("origin", origin, (2,), "(x, y) of the centre of cell (0, 0)")
        _checks.check_finite("origin", origin)
        _check_positive("cell", cell)
        _checks.check_shape("shape", shape, (2,), "(H, W)")
        if _checks.is_concrete(shape) and not np.all(np.asarray(shape) >= 1):
            raise ValueError(f"shape must be (H, W) with H, W >= 1; got {shape}")
        dtype = dtype if dtype is not None else jnp.result_type(float)
        return cls(jnp.asarray(origin, dtype), jnp.asarray(cell, dtype),
                   jnp.asarray(shape, jnp.int32))


def cell_of(grid: Grid, xy: Array) -> Array:
    """The cell ``(row, col)`` [..., 2] int32 containing the world points ``xy`` [..., 2].

    Points outside the grid are clamped to its border cells (and NaN maps to cell (0, 0)): the
    result always indexes the costmap.

    Example:
      >>> cell_of(Grid.create(cell=0.5, shape=(4, 4)), jnp.array([1.1, 0.2]))  # (0, 2)
    """
    _check_grid(grid)
    _checks.check_shape("xy", xy, (*np.shape(xy)[:-1], 2), "[..., 2] world points")
    xy = jnp.asarray(xy, grid.origin.dtype)
    col_row = jnp.round((xy - grid.origin) / grid.cell)
    row_col = jnp.nan_to_num(col_row[..., ::-1])
    hi = (jnp.asarray(grid.shape) - 1).astype(row_col.dtype)
    return jnp.clip(row_col, 0, hi).astype(jnp.int32)


def centre_of(grid: Grid, cell: Array) -> Array:
    """The world (x, y) [..., 2] of the centres of the cells ``(row, col)`` [..., 2].

    Example:
      >>> centre_of(Grid.create(cell=0.5, shape=(4, 4)), jnp.array([0, 2]))  # (1.0, 0.0)
    """
    _check_grid(grid)
    _checks.check_shape("cell", cell, (*np.shape(cell)[:-1], 2), "[..., 2] (row, col)")
    col_row = jnp.asarray(cell)[..., ::-1].astype(grid.origin.dtype)
    return grid.origin + grid.cell * col_row


# ---------------------------------------------------------------------------------------------
# Planning


class Path(NamedTuple):
    """A path on the grid, fixed length with a mask.

    Attributes:
      cells: [max_len, 2] int32 cells ``(row, col)``; ``cells[0]`` is the start. After the last
        valid cell the entries repeat it.
      valid: [max_len] bool, true on the path's cells (a prefix: ``valid[0]`` is always true).
      reached: bool, whether the last valid cell is the goal. False when the goal cannot be
        reached from the start (then only the start is valid) and when ``max_len`` cells are too
        few (then ``valid`` is all true and the path is the beginning of a shortest path).
      cost: the start's cost-to-go, the path's summed edge cost when ``reached`` (``inf`` when
        the goal cannot be reached).
    """

    cells: Array
    valid: Array
    reached: Array
    cost: Array


def distance_field(cost: Array, goal_cell: Array, *, connectivity: int = 8, lethal=math.inf,
                   cell=1.0, method: str = "edges", start_cell: Array | None = None) -> Array:
    r"""The cost-to-go [H, W] to ``goal_cell`` over the costmap ``cost`` (module docstring).

    :math:`D_g = 0`, :math:`D_a = \min_{b \sim a} w(a, b) + D_b`,
    :math:`w(a, b) = \ell_{ab} h (1 + (\mathrm{cost}_a + \mathrm{cost}_b) / 2)`; equal to
    Dijkstra's distances on the same graph (tested against ``scipy.sparse.csgraph.dijkstra``).

    With ``start_cell`` (``method="edges"``), the rounds stop as soon as the start's value is
    exact, which a robot near its goal knows after a few rounds. Every edge weighs at least
    :math:`h` (costs are >= 0), so a path of cost :math:`D` has at most :math:`D / h` edges,
    and :math:`n` rounds make exact every cell whose shortest path has at most :math:`n`
    edges. Once :math:`D^{(n)}_s \le n h`, the start and every cell on its shortest paths
    (all of cost-to-go :math:`\le D_s`) are exact; the other cells hold upper bounds (or
    ``inf``), which `extract_path` from the start never prefers to an exact successor.

    Args:
      cost: [H, W] non-negative costs; ``inf`` or ``>= lethal`` is impassable. Under ``jit``,
        where values cannot be checked, NaN and negative cells are impassable.
      goal_cell: [2] integer ``(row, col)``. An impassable goal (or, under ``jit``, one outside
        the grid) reaches nothing: the field is all ``inf``.
      connectivity: 4 or 8 (static). lethal: cost threshold of impassable cells (default
        ``inf``: only ``inf`` cells). cell: cell size :math:`h` (m), > 0.
      method: ``"edges"`` (plain Bellman-Ford) or ``"lines"`` (exact line relaxations); the
        same result, ``"lines"`` in fewer but costlier rounds (static; module docstring).
      start_cell: optional [2] integer ``(row, col)`` the path will start from (clamped into
        the grid under ``jit``): stop once its value is exact (above). Not with ``"lines"``.

    Returns:
      [H, W] float (``cost``'s float dtype) distances; ``inf`` where the goal is unreachable
      (impassable cells included). With ``start_cell``: exact at the start and at every cell
      whose distance is at most the start's, upper bounds elsewhere.

    Example:
      >>> cost = jnp.zeros((8, 8)).at[2:6, 4].set(jnp.inf)
      >>> d = distance_field(cost, jnp.array([4, 7]), cell=0.25)
      >>> float(d[4, 7]), bool(jnp.isinf(d[3, 4]))  # (0.0, True)
    """
    cost = _check_cost("cost", cost)
    _check_cell_index("goal_cell", goal_cell, cost.shape)
    _check_options(connectivity, lethal, cell, method)
    if start_cell is None:
        return _field(cost, _as_cell(goal_cell), connectivity, lethal, cell, method)[0]
    if method != "edges":
        raise ValueError("start_cell stops the edge rounds early; it needs method='edges'")
    _check_cell_index("start_cell", start_cell, cost.shape)
    return _field(cost, _as_cell(goal_cell), connectivity, lethal, cell, method,
                  _as_cell(start_cell))[0]


def refine(dist: Array, cost: Array, goal_cell: Array, sweeps: int = 2, *,
           connectivity: int = 8, lethal=math.inf, cell=1.0) -> Array:
    r"""``sweeps`` rounds of the Bellman operator from a previous field ``dist``: the distance
    field of a costmap that changes a little every frame, at a few rounds per frame.

    .. math:: D_g \leftarrow 0, \qquad D_a \leftarrow \min_{b \sim a} w(a, b) + D_b
        \quad (a \ne g)

    Unlike `distance_field`'s rounds, the new value does not keep the old one when it is lower,
    so values rise where costs rose (a person stepped onto the path) as well as fall. From any
    non-negative start the rounds converge to the exact field: after :math:`n` rounds
    :math:`D_a` is the cheapest of the paths to the goal of at most :math:`n` steps and of
    :math:`n`-step walks ending at some :math:`b` plus the old :math:`D_b`, and the latter cost
    at least :math:`n` times the smallest edge weight. A stale value falls at once (one round
    per cell along the new shortcut) but rises by at least one edge weight per round. A closed
    loop that replans every frame calls `distance_field` once at its start and `refine` at
    every frame after, a few rounds each, instead of a full solve (about 100 rounds on a
    120 x 80 flat) per frame.

    Args:
      dist: [H, W] the previous field (``inf`` allowed).
      cost, goal_cell, connectivity, lethal, cell: the graph now (`distance_field`).
      sweeps: rounds (static, >= 1).

    Returns:
      [H, W] the refined field (``cost``'s float dtype).

    Example:
      >>> d = distance_field(cost0, goal, cell=0.1)           # once
      >>> d = refine(d, cost1, goal, 2, cell=0.1)             # every frame after
    """
    _checks.check_ndim("dist", dist, 2, "[H, W] distances")
    cost = _check_cost("cost", cost)
    _checks.check_shape("cost", cost, np.shape(dist), "the shape of dist")
    _check_cell_index("goal_cell", goal_cell, cost.shape)
    _check_options(connectivity, lethal, cell, "edges")
    if int(sweeps) != sweeps or sweeps < 1:
        raise ValueError(f"sweeps must be a positive integer; got {sweeps}")
    return _refine(jnp.asarray(dist, cost.dtype), cost, jnp.asarray(goal_cell), int(sweeps),
                   connectivity, lethal, cell)


@functools.partial(jax.jit, static_argnames=("sweeps", "connectivity"))
def _refine(dist, cost, goal, sweeps, connectivity, lethal, cell):
    H, W = cost.shape
    passable = _passable(cost, lethal)
    edges = _half_edges(cost, passable, connectivity, cell)
    goal = goal.astype(jnp.int32)
    inside = jnp.all((goal >= 0) & (goal < jnp.array([H, W])))
    g = jnp.clip(goal, 0, jnp.array([H - 1, W - 1]))
    at_goal = jnp.zeros((H, W), bool).at[g[0], g[1]].set(inside)

    def one(d, _):
        best = jnp.where(at_goal, 0.0, _bellman(d, edges))
        return jnp.where(passable, best, jnp.inf), None

    out, _ = lax.scan(one, jnp.where(passable, dist, jnp.inf), None, length=sweeps)
    return out


def extract_path(dist: Array, start_cell: Array, max_len: int, *, cost: Array,
                 connectivity: int = 8, lethal=math.inf, cell=1.0) -> Path:
    r"""The path from ``start_cell`` down the distance field ``dist`` to its goal (a `lax.scan`).

    Each step goes from :math:`a` to the neighbour :math:`b` minimising :math:`w(a, b) + D_b`
    (the steepest descent of the field measured in edge cost); on a field from
    `distance_field` this is a shortest path and its summed edge cost is :math:`D_{start}`. The
    descent stops at the goal (:math:`D = 0`).

    Args:
      dist: [H, W] the field from `distance_field`.
      start_cell: [2] integer ``(row, col)`` (clamped into the grid under ``jit``).
      max_len: number of cells of the result, >= 1 (static).
      cost, connectivity, lethal, cell: the graph ``dist`` was computed on (`distance_field`).

    Returns:
      `Path` (``cells`` [max_len, 2], ``valid`` [max_len], ``reached``, ``cost``).

    Example:
      >>> d = distance_field(cost, goal, cell=0.25)
      >>> path = extract_path(d, jnp.array([0, 0]), 32, cost=cost, cell=0.25)
      >>> path.cells[path.valid]  # start ... goal
    """
    _checks.check_ndim("dist", dist, 2, "[H, W] distances")
    cost = _check_cost("cost", cost)
    _checks.check_shape("cost", cost, np.shape(dist), "the costmap dist was computed on")
    _check_cell_index("start_cell", start_cell, np.shape(dist))
    max_len = _check_max_len(max_len)
    _check_options(connectivity, lethal, cell, "lines")
    dist = jnp.asarray(dist, cost.dtype)
    return _descend(dist, _as_cell(start_cell), max_len, cost, connectivity, lethal, cell)


def plan(cost: Array, start_cell: Array, goal_cell: Array, max_len: int, *,
         connectivity: int = 8, lethal=math.inf, cell=1.0, method: str = "edges") -> Path:
    """`distance_field` to ``goal_cell`` then `extract_path` from ``start_cell``.

    Example:
      >>> path = plan(cost, jnp.array([0, 0]), jnp.array([7, 7]), 32, cell=0.25)
    """
    cost = _check_cost("cost", cost)
    _check_cell_index("start_cell", start_cell, cost.shape)
    _check_cell_index("goal_cell", goal_cell, cost.shape)
    max_len = _check_max_len(max_len)
    _check_options(connectivity, lethal, cell, method)
    dist, _ = _field(cost, _as_cell(goal_cell), connectivity, lethal, cell, method)
    return _descend(dist, _as_cell(start_cell), max_len, cost, connectivity, lethal, cell)


# ---------------------------------------------------------------------------------------------
# Following


class Params(NamedTuple):
    r"""Pure-pursuit parameters (a pytree; optax steps the log gains and the limits).

    Attributes:
      log_k_speed: :math:`\log k_v` (1/s): the speed is :math:`k_v L` below the limit, so the
        robot slows down over the last :math:`v_{max} / k_v` metres to the target.
      log_k_turn: :math:`\log k_\omega` (1/s): turn rate per radian of bearing toward a target
        that is not ahead.
      v_max: speed limit (m/s), > 0. omega_max: turn-rate limit (rad/s), > 0.
    """

    log_k_speed: Array
    log_k_turn: Array
    v_max: Array
    omega_max: Array

    @classmethod
    def create(cls, k_speed=1.0, k_turn=1.5, v_max=0.5, omega_max=1.0, dtype=None) -> "Params":
        """Parameters from positive gains and limits.

        Example:
          >>> params = Params.create(k_speed=1.0, v_max=0.6, omega_max=1.2)
        """
        for name, value in (("k_speed", k_speed), ("k_turn", k_turn), ("v_max", v_max),
                            ("omega_max", omega_max)):
            _check_positive(name, value)
        dtype = dtype if dtype is not None else jnp.result_type(float)
        return cls(jnp.log(jnp.asarray(k_speed, dtype)), jnp.log(jnp.asarray(k_turn, dtype)),
                   jnp.asarray(v_max, dtype), jnp.asarray(omega_max, dtype))


def lookahead_point(grid: Grid, cells: Array, valid: Array, robot_xy: Array,
                    distance) -> Array:
    """The pure-pursuit target [2]: ``distance`` metres along the path beyond its point closest
    to ``robot_xy``, or the path's end when that is nearer.

    The path is the polyline through the centres of the valid cells. The closest point is the
    robot's projection on the nearest segment; on a path replanned from the robot's cell every
    frame it lies near the start, so a path passing close to itself does not make it jump.

    Args:
      grid: `Grid` of the cells. cells: [N, 2] ``(row, col)``; valid: [N] bool, a prefix (e.g. a
        `Path`'s fields). robot_xy: [2] world position. distance: lookahead (m), >= 0.

    Returns:
      [2] world (x, y).

    Example:
      >>> target = lookahead_point(grid, path.cells, path.valid, pose[:2], 0.5)
    """
    _check_grid(grid)
    _checks.check_shape("cells", cells, (None, 2), "[N, 2] (row, col)")
    n = np.shape(cells)[0]
    if n < 1:
        raise ValueError("cells must hold at least one cell")
    _checks.check_shape("valid", valid, (n,), "[N] bool")
    _check_bool("valid", valid)
    _checks.check_shape("robot_xy", robot_xy, (2,), "(x, y)")
    _checks.check_finite("robot_xy", robot_xy)
    if _checks.is_concrete(distance) and not float(distance) >= 0:
        raise ValueError(f"distance must be >= 0; got {distance}")
    dtype = grid.origin.dtype
    pts = centre_of(grid, cells)
    valid = jnp.asarray(valid, bool).at[0].set(True)
    r = jnp.asarray(robot_xy, dtype)
    seg_ok = valid[1:]
    seg = pts[1:] - pts[:-1]
    len2 = jnp.sum(seg * seg, -1)
    length = jnp.sqrt(len2)
    safe2 = jnp.where(len2 > 0, len2, 1.0)
    s = jnp.concatenate([jnp.zeros(1, dtype), jnp.cumsum(jnp.where(seg_ok, length, 0.0))])
    t = jnp.clip(jnp.sum((r - pts[:-1]) * seg, -1) / safe2, 0.0, 1.0)
    off = r - (pts[:-1] + t[:, None] * seg)
    d2 = jnp.where(seg_ok, jnp.sum(off * off, -1), jnp.inf)
    k = jnp.argmin(d2) if n > 1 else 0
    any_seg = jnp.any(seg_ok) if n > 1 else jnp.asarray(False)
    s_near = jnp.where(any_seg, s[k] + t[k] * length[k], 0.0) if n > 1 else jnp.zeros((), dtype)
    s_goal = jnp.minimum(s_near + jnp.asarray(distance, dtype), s[-1])
    if n == 1:
        return pts[0]
    n_seg = jnp.sum(seg_ok)
    j = jnp.clip(jnp.sum(seg_ok & (s[1:] < s_goal)), 0, jnp.maximum(n_seg - 1, 0))
    frac = jnp.clip((s_goal - s[j]) / jnp.where(length[j] > 0, length[j], 1.0), 0.0, 1.0)
    return jnp.where(any_seg, pts[j] + frac * seg[j], pts[0])


def track_path(pose: Array, target_xy: Array, params: Params) -> Array:
    r"""Pure-pursuit command u [2] ``(v, omega)`` steering the unicycle ``pose`` [3] through
    ``target_xy`` [2] (module docstring).

    Differentiable with respect to ``params``, ``pose`` and ``target_xy`` (a robot exactly at
    its target gets zero command and finite gradients).

    Args:
      pose: [3] (x, y, theta) in the world. target_xy: [2] world target (`lookahead_point`).
      params: `Params`.

    Returns:
      [2] (v, omega) with :math:`0 \le v \le v_{max}`, :math:`|\omega| \le \omega_{max}`.

    Example:
      >>> u = track_path(jnp.zeros(3), jnp.array([1.0, 0.5]), Params.create())
      >>> pose = follower.unicycle_step(jnp.zeros(3), u, 0.1)
    """
    if not isinstance(params, Params):
        raise TypeError(f"params must be a grid_planner.Params; got {type(params).__name__}")
    _checks.check_shape("pose", pose, (3,), "(x, y, theta)")
    _checks.check_shape("target_xy", target_xy, (2,), "(x, y)")
    _checks.check_finite("pose", pose)
    _checks.check_finite("target_xy", target_xy)
    for name in Params._fields:
        value = getattr(params, name)
        _checks.check_shape(f"params.{name}", value, (), "a scalar")
        _checks.check_finite(f"params.{name}", value)
    for name in ("v_max", "omega_max"):
        value = getattr(params, name)
        if _checks.is_concrete(value) and not float(value) > 0:
            raise ValueError(f"params.{name} must be > 0; got {value}")
    dtype = jnp.result_type(jnp.asarray(pose).dtype, jnp.asarray(target_xy).dtype, jnp.float32)
    pose = jnp.asarray(pose, dtype)
    d = jnp.asarray(target_xy, dtype) - pose[:2]
    c, s = jnp.cos(pose[2]), jnp.sin(pose[2])
    x, y = c * d[0] + s * d[1], -s * d[0] + c * d[1]
    len2 = x * x + y * y
    at_target = len2 <= 0
    safe2 = jnp.where(at_target, 1.0, len2)
    L = jnp.where(at_target, 0.0, jnp.sqrt(safe2))
    alpha = jnp.arctan2(jnp.where(at_target, 0.0, y), jnp.where(at_target, 1.0, x))
    ahead = jnp.maximum(jnp.cos(alpha), 0.0)
    v_max = jnp.asarray(params.v_max, dtype)
    omega_max = jnp.asarray(params.omega_max, dtype)
    k_speed = jnp.exp(jnp.asarray(params.log_k_speed, dtype))
    k_turn = jnp.exp(jnp.asarray(params.log_k_turn, dtype))
    v = jnp.minimum(v_max, k_speed * L) * ahead
    # kappa v = 2 sin(alpha) v / L, written with y / L^2 so that it stays bounded as L -> 0.
    omega = 2.0 * y / safe2 * v + k_turn * alpha * (1.0 - ahead)
    u = jnp.stack([v, omega])
    scale = jnp.minimum(_shrink(v, v_max), _shrink(omega, omega_max))
    return jnp.where(at_target, 0.0, u * scale).astype(dtype)


def clear_arc(u: Array, pose: Array, blocked: Array, grid: Grid, dt, steps: int) -> Array:
    r"""The command ``u`` [2] with no forward speed if the arc it drives from ``pose`` [3]
    enters a ``blocked`` cell from a free one within ``steps`` periods ``dt``: the robot then
    turns on the spot. The local planner's collision check (as a dynamic window's): pure
    pursuit's arc to its lookahead point cuts the corners of the path, into what the path went
    round.

    The arc's points are Euler steps of the unicycle,
    :math:`\theta_k = \theta + k\,\omega\,dt`,
    :math:`p_k = p_{k-1} + v\,dt\,(\cos\theta_k, \sin\theta_k)`, :math:`k = 1..n`; ``u``
    is kept when the robot's own cell is blocked already (it may drive out).

    Args:
      u: [2] (v, omega). pose: [3] (x, y, theta). blocked: [H, W] bool (``grid``'s shape).
      grid: `Grid`. dt: period (s), > 0. steps: n (static), >= 1.

    Returns:
      [2] ``u`` or ``(0, omega)``.

    Example:
      >>> g = Grid.create(origin=(0.0, 0.0), cell=0.1, shape=(20, 20))
      >>> wall = jnp.zeros((20, 20), bool).at[:, 12:].set(True)   # x >= 1.15 m
      >>> clear_arc(jnp.array([0.8, 0.0]), jnp.array([0.5, 1.0, 0.0]), wall, g, 0.1, 10)
      >>> # (0.0, 0.0): driving 0.8 m along +x would enter the wall
    """
    _check_grid(grid)
    if int(steps) != steps or steps < 1:
        raise ValueError(f"steps must be a positive number of periods; got {steps}")
    _checks.check_shape("u", u, (2,), "(v, omega)")
    _checks.check_shape("pose", pose, (3,), "(x, y, theta)")
    _checks.check_shape("blocked", blocked, (None, None), "[H, W]")
    _checks.check_finite("u", u)
    _checks.check_finite("pose", pose)
    if _checks.is_concrete(dt) and not float(dt) > 0:
        raise ValueError(f"dt must be > 0; got {dt}")
    dtype = jnp.result_type(jnp.asarray(u).dtype, jnp.asarray(pose).dtype, jnp.float32)
    u, pose = jnp.asarray(u, dtype), jnp.asarray(pose, dtype)
    theta = pose[2] + u[1] * dt * jnp.arange(1, int(steps) + 1, dtype=dtype)
    moves = u[0] * dt * jnp.stack([jnp.cos(theta), jnp.sin(theta)], -1)
    points = jnp.concatenate([pose[None, :2], pose[:2] + jnp.cumsum(moves, 0)])
    cells = cell_of(grid, points)
    hit = jnp.asarray(blocked, bool)[cells[:, 0], cells[:, 1]]
    return u.at[0].set(jnp.where(jnp.any(hit[1:]) & ~hit[0], 0.0, u[0]))


# ---------------------------------------------------------------------------------------------
# Relaxation


@functools.partial(jax.jit, static_argnames=("connectivity", "method"))
def _field(cost, goal, connectivity, lethal, cell, method, start_cell=None):
    """(distances [H, W], rounds) by Bellman-Ford (module docstring); with ``start_cell``, until
    the start's value is exact (`distance_field`)."""
    H, W = cost.shape
    dtype = cost.dtype
    passable = _passable(cost, lethal)
    goal = goal.astype(jnp.int32)
    inside = jnp.all((goal >= 0) & (goal < jnp.array([H, W])))
    g = jnp.clip(goal, 0, jnp.array([H - 1, W - 1]))
    start = jnp.full((H, W), jnp.inf, dtype)
    start = start.at[g[0], g[1]].set(jnp.where(inside & passable[g[0], g[1]], 0.0, jnp.inf))
    offsets = _offsets(connectivity)
    if method == "edges":
        edges = _half_edges(cost, passable, connectivity, cell)

        def relax(d):
            return jnp.minimum(d, _bellman(d, edges))
    else:
        weights = _edge_weights(cost, passable, connectivity, cell)
        lines = _line_families(H, W, connectivity, offsets, weights)

        def relax(d):
            for to_lines, from_lines, w in lines:
                d = from_lines(_relax_lines(to_lines(d), w))
            return d

    # Paths of equal length summed in different orders differ in their last bits, and a round
    # may keep finding such one-ulp "improvements"; a round counts as a change only when some
    # value drops by more than a few ulps (relative), so the result is within that of the
    # exact distances.
    tol = 16 * jnp.finfo(dtype).eps
    every = _CHECK_EVERY if method == "edges" else 1

    if start_cell is not None:
        s = jnp.clip(start_cell.astype(jnp.int32), 0, jnp.array([H - 1, W - 1]))
        h = jnp.asarray(cell, dtype)
        eps = jnp.finfo(dtype).eps

    def cond(state):
        d, changed, rounds = state
        go = changed & (rounds < H * W)
        if start_cell is not None:
            # n rounds are exact on paths of at most n edges, each weighing at least h; the
            # margin covers the rounding of D_s (a sum of at most n weights)
            n = rounds.astype(dtype)
            go = go & ~(d[s[0], s[1]] <= n * h * (1 - 4 * eps * n))
        return go

    def body(state):
        d, _, rounds = state
        # the test reads the whole field, as much as an edge round does: it runs every
        # `every` rounds (a converged field does not change in the extra rounds)
        new = lax.fori_loop(0, every, lambda _, x: relax(x), d)
        return new, jnp.any(new < d * (1 - tol)), rounds + every

    dist, _, rounds = lax.while_loop(cond, body, (start, jnp.asarray(True), jnp.asarray(0)))
    return dist, rounds


@functools.partial(jax.jit, static_argnames=("max_len", "connectivity"))
def _descend(dist, start, max_len, cost, connectivity, lethal, cell):
    H, W = dist.shape
    offsets = jnp.asarray(_offsets(connectivity), jnp.int32)
    hi = jnp.array([H - 1, W - 1], jnp.int32)
    start = jnp.clip(start.astype(jnp.int32), 0, hi)

    def step(cur, _):
        here = dist[cur[0], cur[1]]
        nb = jnp.clip(cur + offsets, 0, hi)
        # Off-grid and impassable neighbours have infinite edge weight.
        q = _weights_at(cost, cur, offsets, lethal, cell) + dist[nb[:, 0], nb[:, 1]]
        k = jnp.argmin(q)
        move = jnp.isfinite(here) & (here > 0) & jnp.isfinite(q[k])
        nxt = jnp.where(move, nb[k], cur)
        return nxt, (nxt, move)

    last, (cells, moved) = lax.scan(step, start, None, length=max_len - 1)
    cells = jnp.concatenate([start[None], cells])
    valid = jnp.concatenate([jnp.ones(1, bool), moved])
    return Path(cells, valid, dist[last[0], last[1]] == 0, dist[start[0], start[1]])


def _weights_at(cost, cur, offsets, lethal, cell):
    """[K] `_edge_weights` ``[:, cur[0], cur[1]]``, from the few cells the edges touch: a path
    reads a few dozen cells' edges, not the whole grid's (the same arithmetic, so the same
    bits)."""
    H, W = cost.shape
    dtype = cost.dtype

    def passable_at(rc):
        inside = (rc[..., 0] >= 0) & (rc[..., 0] < H) & (rc[..., 1] >= 0) & (rc[..., 1] < W)
        c = cost[jnp.clip(rc[..., 0], 0, H - 1), jnp.clip(rc[..., 1], 0, W - 1)]
        ok = inside & _passable(c, lethal)
        return ok, jnp.where(ok, c, 0.0)

    here_ok, here_c = passable_at(cur)
    nb_ok, nb_c = passable_at(cur + offsets)
    diagonal = (offsets[:, 0] != 0) & (offsets[:, 1] != 0)
    row_ok, _ = passable_at(cur + offsets * jnp.array([1, 0], jnp.int32))
    col_ok, _ = passable_at(cur + offsets * jnp.array([0, 1], jnp.int32))
    ok = here_ok & nb_ok & (~diagonal | (row_ok & col_ok))
    h = jnp.asarray(cell, dtype)
    step = jnp.where(diagonal, h * math.sqrt(2.0), h * 1.0)
    return jnp.where(ok, step * (1.0 + 0.5 * (here_c + nb_c)), jnp.inf)


def _passable(cost, lethal):
    # NaN fails both comparisons: impassable.
    return (cost >= 0) & (cost < jnp.asarray(lethal, cost.dtype))


def _offsets(connectivity):
    return _STRAIGHT + (_DIAGONAL if connectivity == 8 else ())


def _shift(a, di, dj, fill):
    """``out[i, j] = a[i + di, j + dj]``, ``fill`` outside the grid."""
    H, W = a.shape
    p = jnp.pad(a, 1, constant_values=fill)
    return p[1 + di:1 + di + H, 1 + dj:1 + dj + W]


def _half_edges(cost, passable, connectivity, cell):
    r"""(u [H, W], corners [4, H, W] or None): the edge weights of `_edge_weights` factored as
    :math:`w(a, b) = \ell_{ab} (u_a + u_b)`, :math:`u = \tfrac{h}{2} (1 + \mathrm{cost})`
    (``inf`` on impassable cells), and for each diagonal whether the two cells it passes
    between are passable.

    A Bellman round then reads two [H, W] arrays and four masks of bytes instead of eight
    [H, W] weight arrays: on a CPU the rounds are bound by memory traffic, and this halves
    their time. The weights are the same up to rounding (a few ulps)."""
    u = jnp.where(passable, 0.5 * jnp.asarray(cell, cost.dtype) * (1.0 + cost), jnp.inf)
    if connectivity == 4:
        return u, None
    corners = jnp.stack([_shift(passable, di, 0, False) & _shift(passable, 0, dj, False)
                         for di, dj in _DIAGONAL])
    return u, corners


def _bellman(d, edges):
    r""":math:`\min_{b \sim a} w(a, b) + D_b` for every cell :math:`a` ([H, W]; ``inf`` for no
    neighbour), with the weights of `_half_edges`: :math:`\min(u_a + \min_{b\,
    straight}(u_b + D_b),\ \sqrt 2 u_a + \min_{b\, diagonal}(\sqrt 2 u_b + D_b))`."""
    u, corners = edges
    e = u + d
    best = jnp.minimum(jnp.minimum(_shift(e, 0, 1, jnp.inf), _shift(e, 0, -1, jnp.inf)),
                       jnp.minimum(_shift(e, 1, 0, jnp.inf), _shift(e, -1, 0, jnp.inf)))
    best = u + best
    if corners is None:
        return best
    r2 = math.sqrt(2.0)
    e = r2 * u + d
    diagonal = jnp.full(d.shape, jnp.inf, d.dtype)
    for k, (di, dj) in enumerate(_DIAGONAL):
        diagonal = jnp.minimum(diagonal, jnp.where(corners[k], _shift(e, di, dj, jnp.inf),
                                                   jnp.inf))
    return jnp.minimum(best, r2 * u + diagonal)


def _edge_weights(cost, passable, connectivity, cell):
    """[K, H, W]: ``w[k, i, j]`` joins cell (i, j) to (i, j) + offset k (``inf``: no edge)."""
    dtype = cost.dtype
    c = jnp.where(passable, cost, 0.0)
    h = jnp.asarray(cell, dtype)
    out = []
    for di, dj in _offsets(connectivity):
        ok = passable & _shift(passable, di, dj, False)
        if di and dj:
            ok &= _shift(passable, di, 0, False) & _shift(passable, 0, dj, False)
        step = h * (math.sqrt(2.0) if di and dj else 1.0)
        w = step * (1.0 + 0.5 * (c + _shift(c, di, dj, 0.0)))
        out.append(jnp.where(ok, w, jnp.inf))
    return jnp.stack(out)


def _relax_lines(d, w):
    """Exact relaxation of every column of ``d`` [L, M] as a path graph, ``w[r]`` the weight
    between rows r - 1 and r (``w[0]`` unused): forward and backward min-plus scans."""
    inf_row = jnp.full((1,) + d.shape[1:], jnp.inf, d.dtype)
    fwd = _min_plus_scan(jnp.concatenate([inf_row, w[1:]]), d)
    bwd = _min_plus_scan(jnp.concatenate([w[1:], inf_row])[::-1], d[::-1])[::-1]
    return jnp.minimum(fwd, bwd)


def _min_plus_scan(a, b):
    """Inclusive scan along axis 0 of the maps ``x -> min(x + a_r, b_r)``, composed as
    ``(a1, b1) then (a2, b2) = (a1 + a2, min(b1 + a2, b2))``; returns the ``b`` part.

    Hillis-Steele doubling: ceil(log2 L) rounds of shifted combinations, padded with the
    identity (0, inf). It does more work than `lax.associative_scan`'s work-efficient form,
    but it is a handful of whole-array operations, which XLA compiles much faster (24 x 19
    grid, 8-connected: 1.7 s instead of 7.4 s on a loaded 2-core machine).
    """
    n = a.shape[0]
    shift = 1
    while shift < n:
        pad = ((shift, 0),) + ((0, 0),) * (a.ndim - 1)
        a_prev = jnp.pad(a, pad, constant_values=0.0)[:n]
        b_prev = jnp.pad(b, pad, constant_values=jnp.inf)[:n]
        a, b = a_prev + a, jnp.minimum(b_prev + a, b)
        shift *= 2
    return b


def _line_families(H, W, connectivity, offsets, weights):
    """For each family of grid lines: (to lines, from lines, weights laid out as lines), the
    lines being the columns of the layout. Diagonals are skewed into columns by static
    gathers, padded with ``inf`` (an infinite weight separates lines)."""
    index = {o: k for k, o in enumerate(offsets)}
    fams = [(lambda d: d, lambda d: d, weights[index[(-1, 0)]]),           # columns
            (lambda d: d.T, lambda d: d.T, weights[index[(0, -1)]].T)]       # rows
    if connectivity == 8:
        r = np.arange(H)[:, None]
        q = np.arange(H + W - 1)[None, :]
        for sign, prev in ((1, (-1, -1)), (-1, (-1, 1))):
            # Diagonal (sign 1): column q = j - i + H - 1; anti-diagonal: q = i + j.
            j = q - (H - 1) + r if sign == 1 else q - r
            ok = (j >= 0) & (j < W)
            gather = np.where(ok, r * W + j, H * W)
            i_all, j_all = np.mgrid[0:H, 0:W]
            q_back = j_all - i_all + H - 1 if sign == 1 else i_all + j_all
            scatter = i_all * (H + W - 1) + q_back

            def to_lines(a, gather=gather):
                flat = jnp.concatenate([a.ravel(), jnp.full(1, jnp.inf, a.dtype)])
                return flat[gather]

            def from_lines(a, scatter=scatter):
                return a.ravel()[scatter]

            fams.append((to_lines, from_lines, to_lines(weights[index[prev]])))
    return fams


def _shrink(x, limit):
    """Factor in (0, 1] bringing |x| within ``limit`` (1 when already inside)."""
    over = jnp.abs(x) > limit
    return jnp.where(over, limit / jnp.where(over, jnp.abs(x), 1.0), 1.0)


# ---------------------------------------------------------------------------------------------
# Input checks


def _as_cell(idx):
    # One index dtype, so that numpy int64 and jax int32 cells share compiled code.
    return jnp.asarray(idx).astype(jnp.int32)


def _dtype(x):
    return x.dtype if hasattr(x, "dtype") else np.asarray(x).dtype


def _check_cost(name, cost):
    if np.ndim(cost) != 2:
        raise ValueError(f"{name} must be a [H, W] costmap; got shape {list(np.shape(cost))}")
    if 0 in np.shape(cost):
        raise ValueError(f"{name} must have H, W >= 1; got shape {list(np.shape(cost))}")
    dt = _dtype(cost)
    if not (np.issubdtype(dt, np.floating) or np.issubdtype(dt, np.integer)) \
            or np.issubdtype(dt, np.bool_):
        raise TypeError(f"{name} must be a real (float or integer) array; got {dt}")
    if _checks.is_concrete(cost):
        a = np.asarray(cost, np.float64)
        if np.any(np.isnan(a)):
            raise ValueError(f"{name} contains NaN (use inf for impassable cells)")
        if np.any(a < 0):
            raise ValueError(f"{name} must be >= 0 (inf for impassable); got min {a.min():.3g}")
    dtype = dt if np.issubdtype(dt, np.floating) else jnp.result_type(float)
    return jnp.asarray(cost, dtype)


def _check_cell_index(name, idx, shape):
    _checks.check_shape(name, idx, (2,), "(row, col)")
    dt = _dtype(idx)
    if not np.issubdtype(dt, np.integer) or np.issubdtype(dt, np.bool_):
        raise TypeError(f"{name} must be an integer (row, col); got dtype {dt}")
    if _checks.is_concrete(idx):
        r, c = (int(v) for v in np.asarray(idx))
        if not (0 <= r < shape[0] and 0 <= c < shape[1]):
            raise ValueError(f"{name} ({r}, {c}) is outside the grid [{shape[0]}, {shape[1]}]")


def _check_max_len(max_len):
    if isinstance(max_len, bool) or not isinstance(max_len, (int, np.integer)):
        raise TypeError(f"max_len must be a Python int (static); got {type(max_len).__name__}")
    if max_len < 1:
        raise ValueError(f"max_len must be >= 1; got {max_len}")
    return int(max_len)


def _check_options(connectivity, lethal, cell, method):
    if connectivity not in (4, 8):
        raise ValueError(f"connectivity must be 4 or 8; got {connectivity!r}")
    if method not in _METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {list(_METHODS)}")
    _checks.check_shape("lethal", lethal, (), "a scalar threshold")
    if _checks.is_concrete(lethal) and not float(lethal) > 0:
        raise ValueError(f"lethal must be > 0; got {lethal}")
    _check_positive("cell", cell)


def _check_positive(name, value):
    _checks.check_shape(name, value, (), "a scalar")
    if _checks.is_concrete(value) and not (np.isfinite(float(value)) and float(value) > 0):
        raise ValueError(f"{name} must be finite and > 0; got {value}")


def _check_bool(name, x):
    dt = _dtype(x)
    if not np.issubdtype(dt, np.bool_):
        raise TypeError(f"{name} must be bool; got {dt}")


def _check_grid(grid):
    if not isinstance(grid, Grid):
        raise TypeError(f"grid must be a grid_planner.Grid; got {type(grid).__name__}")
