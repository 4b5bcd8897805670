r"""Person costmaps for human-aware navigation (seed 003, sections III-A and IV).

The seed's navigation plans on costmaps (ROS ``move_base``): grid maps whose cell values say
where the robot may go. People enter them as cost functions around their position, one shape
per status -- standing, walking, seated, hand-over (`jaxtrack.tracking.status`) -- and
interactions enter as a circle between the two parties, which the robot never crosses. The
rules the shapes encode are the seed's constraints: respect personal spaces (3), avoid
navigating behind sitting humans (4), do not interfere with human-object interactions (5),
overtake people by the left (6).

Costs are in :math:`[0, 1]`: 0 free, `LETHAL` = 1 never entered (ROS's 254 scaled to 1).

**What the seed gives and what is ours.** The seed prints no equations: its Fig. 1 shows the
four shapes ("reprinted from [1]") and the text gives Hall's zones -- intimate up to 0.45 m,
personal up to 1.2 m, social up to 3.6 m -- the rules above, and a "circular shape between the
person and the object". The functional form and every number except Hall's radii are ours,
chosen so that each shape does what the seed's experiments need:

*Person cost.* In the person's frame, :math:`q = R(\phi)^T (x - p)` (:math:`q_x` ahead,
:math:`q_y` to the left), with four extents -- the personal-zone edge ahead :math:`e_f`, behind
:math:`e_b`, to the left :math:`e_l` and to the right :math:`e_r` -- the normalised distance

.. math::
    \rho^2 = \Big(\frac{q_x}{q_x \ge 0\ ?\ e_f : e_b}\Big)^2
           + \Big(\frac{q_y}{q_y \ge 0\ ?\ e_l : e_r}\Big)^2

is 1 on the personal-zone edge (an ellipse quadrant per side: continuous with a continuous
gradient, Kirby's asymmetric Gaussian made four-sided), and the cost is a Gaussian in
:math:`\rho`, clipped at lethal:

.. math::
    c(x) = \min\Big(1,\ \varepsilon^{(\rho^2 - \kappa^2) / (1 - \kappa^2)}\Big),

so :math:`c = 1` (lethal) inside the core :math:`\rho \le \kappa` and :math:`c = \varepsilon`
on the personal-zone edge :math:`\rho = 1`. :math:`\kappa = 0.45 / 1.2 = 0.375` (Hall's
intimate / personal radii, seed) makes the standing core the intimate zone; the edge cost
:math:`\varepsilon = 0.1` is ours (a planner still crosses the personal zone's edge, at a
price; the cost falls to 0.4 % at 1.5 times the edge and is nil in the social zone).

Extents :math:`(e_f, e_b, e_l, e_r)` in m, by status:

- standing (1.2, 1.2, 1.2, 1.2): Hall's personal zone, a circle (seed);
- walking (2.4, 1.2, 1.2, 1.8), ours: longer ahead (the 2 s a person walks at 1.2 m/s), and
  wider on the person's right than the left, so the cheapest way past is by the person's left
  (the seed overtakes by the left "by changing the person's costmap from standing to walking");
- seated (1.2, 1.8, 1.2, 1.2), ours: longer behind (constraint 4; the seed's robot passes
  behind the seated person "but not very close");
- hand-over (0.6, 1.2, 1.2, 1.2), ours: shortened ahead, so the robot may enter the personal
  zone in front, to within arm's reach, to hand the object over (lethal core 0.225 m ahead).

*Interaction zone.* Between a person at :math:`a` and what they attend at :math:`b` (a TV, or
another person), a disc centred at :math:`m = (a + b)/2` of radius
:math:`R = \gamma \|b - a\| / 2` -- the seed's circle between them, :math:`\gamma = 1` so the
disc's diameter is the segment -- lethal inside, with a Gaussian fall-off of width
:math:`\sigma = 0.1` m (ours) outside, so that the zone is differentiable in the positions:

.. math:: c(x) = \exp\big(-\tfrac12 \max(\|x - m\| - R,\ 0)^2 / \sigma^2\big).

Two people interact if both are still (not walking), closer than ``pair_distance`` (2 m, ours:
inside the social zone, where the seed says conversations happen) and each faces the other
within ``pair_angle`` (60 deg, ours). In the map each person gets one zone, with the nearest
person it interacts with: a conversation pairs people, and N zones instead of N^2 keep the
map's cost linear in the people (a group of three facing each other gets the zones of each
one's nearest partner). This gate is a hard decision: gradients flow through the
zones' geometry, not through whether a zone exists.

*Combination.* `build` takes the cell-wise **maximum** of the static layer, every person's
cost and every interaction zone -- as ROS's layered costmaps combine layers. A sum would make
two neighbours' overlapping personal spaces costlier than either person asks (the corridor
between the seed's slalom people would close) and would push costs past `LETHAL`, whose
meaning is "never". The maximum's gradient goes to the layer that attains it.

All parameters are positive floats in `CostParams` (`CostParams.create` checks them);
`to_unconstrained` / `from_unconstrained` map them to free values (log, and logit for the two
fractions) for optax.

Example:
  >>> grid = Grid(origin=jnp.array([-2.0, -2.0]), resolution=0.1, shape=(40, 40))
  >>> cost = build(grid, CostParams.create(), people_xy=jnp.array([[0.0, 0.0]]),
  ...              heading=jnp.zeros(1), status=jnp.array([WALKING]))        # [40, 40]
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import _checks, geometry
from jaxtrack.tracking.status import HANDOVER, NUM_STATUSES, SEATED, STANDING, WALKING

Array = jax.Array

__all__ = ["WALKING", "STANDING", "SEATED", "HANDOVER", "NUM_STATUSES", "LETHAL", "INTIMATE",
           "PERSONAL", "EXTENTS", "Grid", "CostParams", "UnconstrainedCostParams",
           "cell_centers", "person_cost", "standing_cost", "walking_cost", "seated_cost",
           "handover_cost", "interaction_cost", "interacting_pairs", "build",
           "to_unconstrained", "from_unconstrained"]

LETHAL = 1.0
"""Cost of a cell the robot never enters."""
INTIMATE = 0.45
"""Hall's intimate-zone radius (m), seed 003 III-A."""
PERSONAL = 1.2
"""Hall's personal-zone radius (m), seed 003 III-A."""

EXTENTS = (
    (2.4, 1.2, 1.2, 1.8),   # WALKING (ours)
    (1.2, 1.2, 1.2, 1.2),   # STANDING (seed: Hall's personal zone)
    (1.2, 1.8, 1.2, 1.2),   # SEATED (ours)
    (0.6, 1.2, 1.2, 1.2),   # HANDOVER (ours)
)
"""Default personal-zone extents (front, rear, left, right) in m, rows by status code."""


@dataclasses.dataclass(frozen=True)
class Grid:
    r"""A regular grid in the map frame, ROS ``OccupancyGrid`` layout.

    Cell ``[i, j]`` (row i along y, column j along x) has its centre at
    :math:`o + ((j + \tfrac12) r,\ (i + \tfrac12) r)`; ``origin`` :math:`o` is the outer corner
    of cell ``[0, 0]``. ``shape`` is static (it sets array shapes; changing it recompiles);
    ``origin`` and ``resolution`` are pytree leaves, so grids with one shape batch under
    ``vmap``.

    Attributes:
      origin: [2] map position of the grid's corner (m).
      resolution: cell size :math:`r` (m), > 0.
      shape: (H, W) cells, Python ints.
    """

    origin: Array
    resolution: Array
    shape: tuple[int, int]


jax.tree_util.register_dataclass(Grid, data_fields=["origin", "resolution"],
                                 meta_fields=["shape"])


class CostParams(NamedTuple):
    r"""Positive cost parameters (module docstring). Build with `CostParams.create`.

    Attributes:
      extents: [4, 4] personal-zone extents (front, rear, left, right) in m, rows by status
        code (`EXTENTS`).
      core: :math:`\kappa \in (0, 1)`, the lethal core as a fraction of the extents
        (seed: 0.45 / 1.2).
      edge_cost: :math:`\varepsilon \in (0, 1)`, the cost on the personal-zone edge (ours: 0.1).
      interaction_scale: :math:`\gamma` > 0, the interaction disc's diameter over the
        distance between the parties (seed's circle between them: 1).
      interaction_margin: :math:`\sigma` > 0 (m), the zone's fall-off width (ours: 0.1).
    """

    extents: Array
    core: Array
    edge_cost: Array
    interaction_scale: Array
    interaction_margin: Array

    @classmethod
    def create(cls, extents=EXTENTS, core=INTIMATE / PERSONAL, edge_cost=0.1,
               interaction_scale=1.0, interaction_margin=0.1, dtype=None) -> "CostParams":
        """Checked parameters (defaults: the module docstring's).

        Example:
          >>> params = CostParams.create(edge_cost=0.2)
        """
        params = cls(extents, core, edge_cost, interaction_scale, interaction_margin)
        _check_params(params)
        dtype = dtype if dtype is not None else jnp.result_type(float)
        return _cast(params, dtype)


class UnconstrainedCostParams(NamedTuple):
    """`CostParams` as free values for optax (`to_unconstrained`, `from_unconstrained`).

    Attributes:
      log_extents: [4, 4]. logit_core, logit_edge_cost: scalars.
      log_interaction_scale, log_interaction_margin: scalars.
    """

    log_extents: Array
    logit_core: Array
    logit_edge_cost: Array
    log_interaction_scale: Array
    log_interaction_margin: Array


def to_unconstrained(params: CostParams) -> UnconstrainedCostParams:
    """Free values of ``params``: log of the positive ones, logit of the two fractions.

    Example:
      >>> u = to_unconstrained(CostParams.create())
      >>> params = from_unconstrained(u)                  # the same values again
    """
    _check_params(params)
    p = CostParams(*(jnp.asarray(x) for x in params))
    logit = lambda x: jnp.log(x) - jnp.log1p(-x)  # noqa: E731
    return UnconstrainedCostParams(jnp.log(p.extents), logit(p.core), logit(p.edge_cost),
                                   jnp.log(p.interaction_scale), jnp.log(p.interaction_margin))


def from_unconstrained(u: UnconstrainedCostParams) -> CostParams:
    """`CostParams` from free values (exp and sigmoid), differentiable.

    Example:
      >>> params = from_unconstrained(to_unconstrained(CostParams.create()))
    """
    if not isinstance(u, UnconstrainedCostParams):
        raise TypeError(f"u must be a costmap.UnconstrainedCostParams; got {type(u).__name__}")
    _checks.check_shape("log_extents", u.log_extents, (NUM_STATUSES, 4),
                        "[status, (front, rear, left, right)]")
    return CostParams(jnp.exp(u.log_extents), jax.nn.sigmoid(u.logit_core),
                      jax.nn.sigmoid(u.logit_edge_cost), jnp.exp(u.log_interaction_scale),
                      jnp.exp(u.log_interaction_margin))


def cell_centers(grid: Grid) -> Array:
    r"""Map positions of the cell centres, [H, W, 2] (x, y): :math:`o + ((j + \tfrac12) r,
    (i + \tfrac12) r)` at ``[i, j]``.

    Example:
      >>> xy = cell_centers(Grid(jnp.zeros(2), 0.5, (2, 3)))   # xy[1, 2] == (1.25, 0.75)
    """
    _check_grid(grid)
    return _cell_centers(grid, _grid_dtype(grid))


def person_cost(params: CostParams, xy: Array, position: Array, heading, status) -> Array:
    r"""One person's cost :math:`c(x)` at points ``xy`` (module docstring), by status code.

    Args:
      params: `CostParams`.
      xy: [..., 2] points in the map frame (m).
      position: [2] the person's position :math:`p`.
      heading: the person's heading :math:`\phi` (rad), scalar.
      status: scalar int status code (`WALKING`, `STANDING`, `SEATED`, `HANDOVER`).

    Returns:
      [...] costs in [0, 1].

    Example:
      >>> c = person_cost(CostParams.create(), jnp.array([1.0, 0.0]), jnp.zeros(2), 0.0, SEATED)
    """
    _check_params(params)
    _check_xy("xy", xy)
    _check_person(position, heading)
    _checks.check_shape("status", status, (), "scalar int")
    _check_status_values(status, True)
    dtype = _dtype(xy, position, heading)
    return _person_cost(_cast(params, dtype), jnp.asarray(xy, dtype),
                        jnp.asarray(position, dtype), jnp.asarray(heading, dtype),
                        jnp.asarray(status, jnp.int32))


def standing_cost(params: CostParams, xy: Array, position: Array, heading) -> Array:
    """`person_cost` of a standing person: Hall's personal zone, lethal inside 0.45 m.

    Example:
      >>> c = standing_cost(CostParams.create(), jnp.array([0.3, 0.0]), jnp.zeros(2), 0.0)  # 1
    """
    return person_cost(params, xy, position, heading, STANDING)


def walking_cost(params: CostParams, xy: Array, position: Array, heading) -> Array:
    """`person_cost` of a walking person: long ahead, wider on the right (overtake by the left).

    Example:
      >>> c = walking_cost(CostParams.create(), jnp.array([2.0, 0.0]), jnp.zeros(2), 0.0)
    """
    return person_cost(params, xy, position, heading, WALKING)


def seated_cost(params: CostParams, xy: Array, position: Array, heading) -> Array:
    """`person_cost` of a seated person: longer behind (do not pass close behind them).

    Example:
      >>> c = seated_cost(CostParams.create(), jnp.array([-1.5, 0.0]), jnp.zeros(2), 0.0)
    """
    return person_cost(params, xy, position, heading, SEATED)


def handover_cost(params: CostParams, xy: Array, position: Array, heading) -> Array:
    """`person_cost` of a person being handed something: short ahead, so the robot can reach.

    Example:
      >>> c = handover_cost(CostParams.create(), jnp.array([0.5, 0.0]), jnp.zeros(2), 0.0)
    """
    return person_cost(params, xy, position, heading, HANDOVER)


def interaction_cost(params: CostParams, xy: Array, a: Array, b: Array) -> Array:
    r"""The interaction zone between parties at ``a`` and ``b`` (module docstring):
    :math:`\exp(-\tfrac12 \max(\|x - m\| - R, 0)^2 / \sigma^2)`, :math:`m = (a + b)/2`,
    :math:`R = \gamma \|b - a\| / 2`.

    Args:
      params: `CostParams`. xy: [..., 2] points. a, b: [2] the two parties' positions.

    Returns:
      [...] costs in [0, 1] (`LETHAL` inside the disc).

    Example:
      >>> c = interaction_cost(CostParams.create(), jnp.array([1.0, 0.0]), jnp.zeros(2),
      ...                      jnp.array([2.0, 0.0]))      # 1: between a person and a TV
    """
    _check_params(params)
    _check_xy("xy", xy)
    for name, v in (("a", a), ("b", b)):
        _checks.check_shape(name, v, (2,), "(x, y)")
        _checks.check_finite(name, v)
    dtype = _dtype(xy, a, b)
    return _interaction_cost(_cast(params, dtype), jnp.asarray(xy, dtype), jnp.asarray(a, dtype),
                             jnp.asarray(b, dtype))


def interacting_pairs(people_xy: Array, heading: Array, status: Array, mask: Array | None = None,
                      *, pair_distance=2.0, pair_angle=math.radians(60.0)) -> Array:
    """Which pairs of people interact (module docstring): [N, N] bools, symmetric, False on the
    diagonal.

    Both present and not walking, closer than ``pair_distance`` (m), and each one's heading
    within ``pair_angle`` (rad) of the direction to the other.

    Example:
      >>> pairs = interacting_pairs(jnp.array([[0.0, 0.0], [1.5, 0.0]]),
      ...                           jnp.array([0.0, jnp.pi]), jnp.array([STANDING, STANDING]))
    """
    n = _check_people(people_xy, heading, status, mask)
    _check_pair_gate(pair_distance, pair_angle)
    dtype = _dtype(people_xy, heading)
    xy, head, status, present = _people(people_xy, heading, status, mask, n, dtype)
    return _pairs(xy, head, status, present, jnp.asarray(pair_distance, dtype),
                  jnp.asarray(pair_angle, dtype))


def build(grid: Grid, params: CostParams, people_xy: Array, heading: Array, status: Array,
          mask: Array | None = None, *, objects_xy: Array | None = None,
          attended: Array | None = None, object_mask: Array | None = None,
          static_cost: Array | None = None, pair_distance=2.0,
          pair_angle=math.radians(60.0)) -> Array:
    r"""The costmap: the cell-wise maximum of the static layer, every person's cost and every
    interaction zone (module docstring).

    .. math:: C[i, j] = \max\big(S[i, j],\ \max_n c_n(x_{ij}),\
              \max_{(n, k)} z_{n,k}(x_{ij}),\ \max_{(n, n')} z_{n,n'}(x_{ij})\big)

    over present people n, person-object pairs (n attends object k) and interacting pairs of
    people. Masked people, people with non-finite position or heading, and objects that are
    masked contribute nothing; zero people (N = 0) gives the static layer. Inside ``jit`` an
    unknown status code is costed as standing (outside it raises).

    Args:
      grid: `Grid` with shape (H, W).
      params: `CostParams`.
      people_xy: [N, 2] positions (m). heading: [N] (rad). status: [N] int status codes.
      mask: optional [N] bools, the people present (default all).
      objects_xy: optional [M, 2] positions of objects people may attend (a TV).
      attended: optional [N] int, the object each person attends (index into ``objects_xy``),
        -1 for none. Requires ``objects_xy``.
      object_mask: optional [M] bools, the objects in use (default all).
      static_cost: optional [H, W] static layer in [0, 1] (walls, furniture).
      pair_distance, pair_angle: the person-person gate (`interacting_pairs`).

    Returns:
      [H, W] costs in [0, 1].

    Example:
      >>> grid = Grid(jnp.array([-2.0, -2.0]), 0.1, (40, 40))
      >>> cost = build(grid, CostParams.create(), jnp.array([[0.0, 0.0]]), jnp.zeros(1),
      ...              jnp.array([SEATED]), objects_xy=jnp.array([[1.5, 0.0]]),
      ...              attended=jnp.array([0]))
    """
    _check_grid(grid)
    _check_params(params)
    n = _check_people(people_xy, heading, status, mask)
    _check_pair_gate(pair_distance, pair_angle)
    if attended is not None and objects_xy is None:
        raise ValueError("attended needs objects_xy (the objects it indexes)")
    m = 0
    if objects_xy is not None:
        _checks.check_shape("objects_xy", objects_xy, (None, 2), "[M, 2]")
        _checks.check_finite("objects_xy", objects_xy)
        m = _checks.shape_of(objects_xy)[0]
        if object_mask is not None:
            _checks.check_shape("object_mask", object_mask, (m,), "[M]")
        if attended is not None:
            _checks.check_shape("attended", attended, (n,), "[N] object index or -1")
            if _checks.is_concrete(attended):
                att = np.asarray(attended)
                if not np.issubdtype(att.dtype, np.integer):
                    raise TypeError(f"attended must be integer; got dtype {att.dtype}")
                if np.any((att < -1) | (att >= m)):
                    raise ValueError(f"attended must be -1 or an index in [0, {m}); got {att}")
    elif object_mask is not None:
        raise ValueError("object_mask needs objects_xy")
    h, w = grid.shape
    if static_cost is not None:
        _checks.check_shape("static_cost", static_cost, (h, w), "[H, W] of the grid")
        if _checks.is_concrete(static_cost):
            s = np.asarray(static_cost, np.float64)
            if not (np.all(np.isfinite(s)) and np.all(s >= 0) and np.all(s <= LETHAL)):
                raise ValueError("static_cost must be finite and in [0, 1]")
    dtype = _dtype(people_xy, heading, grid.origin)
    grid = Grid(jnp.asarray(grid.origin, dtype), jnp.asarray(grid.resolution, dtype),
                (int(h), int(w)))
    mask = jnp.ones(n, bool) if mask is None else jnp.asarray(mask, bool)
    if objects_xy is None or attended is None:
        objects_xy, attended, object_mask = (jnp.zeros((0, 2), dtype),
                                             jnp.full(n, -1, jnp.int32), jnp.zeros(0, bool))
    object_mask = jnp.ones(m, bool) if object_mask is None else jnp.asarray(object_mask, bool)
    static_cost = (jnp.zeros((h, w), dtype) if static_cost is None
                   else jnp.asarray(static_cost, dtype))
    return _build(grid, _cast(params, dtype), jnp.asarray(people_xy, dtype),
                  jnp.asarray(heading, dtype), jnp.asarray(status, jnp.int32), mask,
                  jnp.asarray(objects_xy, dtype), jnp.asarray(attended, jnp.int32), object_mask,
                  static_cost, jnp.asarray(pair_distance, dtype), jnp.asarray(pair_angle, dtype))


# ---------------------------------------------------------------------------------------------
# Private


@jax.jit
def _build(grid, p, people_xy, heading, status, mask, objects, attended, object_mask, cost,
           pair_distance, pair_angle):
    # compiled once per shape and dtype, so that eager callers do not dispatch op by op.
    # Every person's cost is one decreasing function of their rho^2 (the core and edge cost
    # are shared by all statuses; the status only sets the extents inside rho^2), and every
    # zone's one decreasing function of its gap, so the maximum over people is that function of
    # the smallest rho^2, and over zones of the smallest gap: two exponentials per cell
    # instead of one per layer and cell, and no [layers, H, W] stack. The values are the
    # layer-wise maximum's (up to rounding); the gradient goes to the person (zone) attaining
    # it, as the maximum's does.
    n, m = people_xy.shape[0], objects.shape[0]
    xy, head, status, present = _people(people_xy, heading, status, mask, n, cost.dtype)
    x, y = _cell_axes(grid, cost.dtype)
    # an absent person (zone) is this far away: its cost underflows to exactly 0, and, unlike
    # inf, its gradient stays 0 rather than NaN
    far = jnp.asarray(_FAR, cost.dtype)
    out = cost
    if n:
        rho2 = _running_min([jnp.where(present[i], _rho2(p, x, y, xy[i], head[i], status[i]),
                                       far) for i in range(n)])
        out = jnp.maximum(out, _cost_of_rho2(p, rho2))
        # one zone per person, with the nearest person it interacts with: N zones, not N^2
        pairs = _pairs(xy, head, status, present, pair_distance, pair_angle)
        d2 = jnp.where(pairs, jnp.sum((xy[:, None] - xy[None]) ** 2, -1), jnp.inf)
        ends, on = [xy[jnp.argmin(d2, 1)]], [jnp.any(pairs, 1)]
        if m:
            k = jnp.clip(attended, 0, m - 1)
            ends.append(objects[k])
            on.append(present & (attended >= 0) & (attended < m) & object_mask[k])
        starts = jnp.concatenate([xy] * len(ends))
        ends, on = jnp.concatenate(ends), jnp.concatenate(on)
        gap = _running_min([jnp.where(on[i], _zone_gap(p, x, y, starts[i], ends[i]), far)
                            for i in range(starts.shape[0])])
        out = jnp.maximum(out, _cost_of_gap(p, gap))
    return out


def _running_min(layers):
    """The cell-wise minimum of a list of [H, W] layers, as a chain of ``minimum``: XLA fuses
    the chain and the layers' arithmetic into one pass over the cells, where a minimum over a
    stacked [N, H, W] array (a ``vmap`` over the people, then ``min``) wrote and read the
    whole stack (64 maps of 8 people and 16 zones on 80 x 120 cells: 7x faster in
    isolation). Where layers tie (a set of measure zero but for absent people, whose layers
    are constant), the chain halves the gradient at each tie where ``min`` shares it
    equally."""
    out = layers[0]
    for layer in layers[1:]:
        out = jnp.minimum(out, layer)
    return out


def _cell_axes(grid, dtype):
    """x [1, W] and y [H, 1] of the cell centres."""
    h, w = grid.shape
    r = jnp.asarray(grid.resolution, dtype)
    o = jnp.asarray(grid.origin, dtype)
    x = o[0] + (jnp.arange(w, dtype=dtype) + 0.5) * r
    y = o[1] + (jnp.arange(h, dtype=dtype) + 0.5) * r
    return x[None, :], y[:, None]


def _cell_centers(grid, dtype):
    x, y = _cell_axes(grid, dtype)
    return jnp.stack(jnp.broadcast_arrays(x, y), -1)


_FAR = 1e6
"""rho^2 and gap (m) of an absent person or zone in `_build`."""


def _rho2(p, x, y, position, heading, status):
    # x and y apart, not stacked in a minor axis of 2: XLA's CPU loops do not vectorise over
    # a last axis of length 2, and this runs for every person and cell of every frame
    valid = (status >= 0) & (status < NUM_STATUSES)
    e = p.extents[jnp.where(valid, status, STANDING)]
    c, s = jnp.cos(heading), jnp.sin(heading)
    dx, dy = x - position[0], y - position[1]
    qx, qy = c * dx + s * dy, c * dy - s * dx            # R(heading)^T (x - p)
    sx = jnp.where(qx >= 0, e[0], e[1])
    sy = jnp.where(qy >= 0, e[2], e[3])
    return (qx / sx) ** 2 + (qy / sy) ** 2


def _cost_of_rho2(p, rho2):
    k2 = p.core ** 2
    return jnp.minimum(LETHAL, jnp.exp(jnp.log(p.edge_cost) * (rho2 - k2) / (1.0 - k2)))


def _person_cost(p, xy, position, heading, status):
    return _cost_of_rho2(p, _rho2(p, xy[..., 0], xy[..., 1], position, heading, status))


def _zone_gap(p, x, y, a, b):
    centre = 0.5 * (a + b)
    radius = 0.5 * p.interaction_scale * geometry.safe_norm(b - a)
    d2 = (x - centre[0]) ** 2 + (y - centre[1]) ** 2
    # the norm's gradient at 0 (a cell centre on the zone's centre) is 0, as `safe_norm`'s
    d = jnp.sqrt(jnp.where(d2 > 0, d2, 1.0))
    return jnp.maximum(jnp.where(d2 > 0, d, 0.0) - radius, 0.0)


def _cost_of_gap(p, gap):
    return jnp.exp(-0.5 * (gap / p.interaction_margin) ** 2)


def _interaction_cost(p, xy, a, b):
    return _cost_of_gap(p, _zone_gap(p, xy[..., 0], xy[..., 1], a, b))


def _pairs(xy, heading, status, present, pair_distance, pair_angle):
    d = xy[None, :, :] - xy[:, None, :]                  # [i, j]: from i to j
    dist = geometry.safe_norm(d)
    facing = jnp.stack([jnp.cos(heading), jnp.sin(heading)], -1)
    # cos of the angle between i's heading and the direction from i to j
    cos_ij = jnp.sum(facing[:, None, :] * d, -1) / jnp.where(dist > 0, dist, 1.0)
    looks = cos_ij >= jnp.cos(pair_angle)
    still = present & (status != WALKING)
    n = xy.shape[0]
    return ((still[:, None] & still[None, :]) & (dist < pair_distance) & looks & looks.T
            & ~jnp.eye(n, dtype=bool))


def _people(people_xy, heading, status, mask, n, dtype):
    xy = jnp.asarray(people_xy, dtype)
    head = jnp.asarray(heading, dtype)
    present = jnp.ones(n, bool) if mask is None else jnp.asarray(mask, bool)
    present = present & jnp.all(jnp.isfinite(xy), -1) & jnp.isfinite(head)
    # absent rows are zeroed, so their NaNs reach neither the cost nor its gradient
    xy = jnp.where(present[:, None], xy, 0.0)
    head = jnp.where(present, head, 0.0)
    return xy, head, jnp.asarray(status, jnp.int32), present


def _dtype(*xs):
    return jnp.result_type(*(jnp.asarray(x).dtype for x in xs), jnp.float32)


def _grid_dtype(grid):
    return _dtype(grid.origin, grid.resolution)


def _cast(params, dtype):
    return CostParams(*(jnp.asarray(x, dtype) for x in params))


def _check_grid(grid):
    if not isinstance(grid, Grid):
        raise TypeError(f"grid must be a costmap.Grid; got {type(grid).__name__}")
    shape = grid.shape
    if (not isinstance(shape, tuple) or len(shape) != 2
            or not all(isinstance(s, (int, np.integer)) and s > 0 for s in shape)):
        raise ValueError(f"grid.shape must be (H, W), two positive ints; got {shape!r}")
    _checks.check_shape("grid.origin", grid.origin, (2,), "(x, y)")
    _checks.check_finite("grid.origin", grid.origin)
    _checks.check_shape("grid.resolution", grid.resolution, (), "scalar")
    if _checks.is_concrete(grid.resolution) and not float(grid.resolution) > 0:
        raise ValueError(f"grid.resolution must be > 0; got {grid.resolution}")


def _check_params(params):
    if not isinstance(params, CostParams):
        raise TypeError(f"params must be a costmap.CostParams; got {type(params).__name__}")
    _checks.check_shape("extents", params.extents, (NUM_STATUSES, 4),
                        "[status, (front, rear, left, right)]")
    for name in CostParams._fields:
        value = getattr(params, name)
        if name != "extents":
            _checks.check_shape(name, value, (), "scalar")
        _checks.check_finite(name, value)
        if _checks.is_concrete(value) and not np.all(np.asarray(value) > 0):
            raise ValueError(f"{name} must be > 0; got {value}")
    for name in ("core", "edge_cost"):
        value = getattr(params, name)
        if _checks.is_concrete(value) and not float(value) < 1:
            raise ValueError(f"{name} must be in (0, 1); got {value}")


def _check_xy(name, xy):
    _checks.check_shape(name, xy, (*_checks.shape_of(xy)[:-1], 2), "[..., 2]")
    _checks.check_finite(name, xy)


def _check_person(position, heading):
    _checks.check_shape("position", position, (2,), "(x, y)")
    _checks.check_finite("position", position)
    _checks.check_shape("heading", heading, (), "scalar (rad)")
    _checks.check_finite("heading", heading)


def _check_status_values(status, present):
    if not (_checks.is_concrete(status) and _checks.is_concrete(present)):
        return
    s = np.asarray(status)
    if not np.issubdtype(s.dtype, np.integer):
        raise TypeError(f"status must be integer status codes; got dtype {s.dtype}")
    bad = np.broadcast_to(np.asarray(present, bool), s.shape) & ((s < 0) | (s >= NUM_STATUSES))
    if np.any(bad):
        raise ValueError(f"status has unknown codes {sorted(set(s[bad].tolist()))}; expected "
                         f"WALKING={WALKING}, STANDING={STANDING}, SEATED={SEATED} or "
                         f"HANDOVER={HANDOVER}")


def _check_people(people_xy, heading, status, mask):
    _checks.check_shape("people_xy", people_xy, (None, 2), "[N, 2]")
    n = _checks.shape_of(people_xy)[0]
    _checks.check_shape("heading", heading, (n,), "[N]")
    _checks.check_shape("status", status, (n,), "[N] int status codes")
    if mask is not None:
        _checks.check_shape("mask", mask, (n,), "[N]")
    present = True if mask is None else mask
    _check_status_values(status, present)
    if all(_checks.is_concrete(x) for x in (people_xy, heading, present)):
        on = np.broadcast_to(np.asarray(present, bool), (n,))
        finite = np.all(np.isfinite(np.asarray(people_xy)), -1) & np.isfinite(np.asarray(heading))
        if np.any(on & ~finite):
            raise ValueError("people_xy or heading contains NaN or inf for a present person "
                             "(mask it out)")
    return n


def _check_pair_gate(pair_distance, pair_angle):
    for name, value in (("pair_distance", pair_distance), ("pair_angle", pair_angle)):
        _checks.check_shape(name, value, (), "scalar")
        if _checks.is_concrete(value) and not float(value) > 0:
            raise ValueError(f"{name} must be > 0; got {value}")
