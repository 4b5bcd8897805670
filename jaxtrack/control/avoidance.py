r"""Obstacle-aware velocity selection for a unicycle: a dynamic window (Fox, Burgard, Thrun 1997).

A layer between a velocity law (e.g. `jaxtrack.control.follower`) and the wheels. Given the
desired command :math:`u_d = (v_d, \omega_d)`, the previous command :math:`u_p` and obstacle
points in the robot frame (laser returns; robot at the origin facing +x), `select` returns
:math:`u_d` itself when it is admissible and otherwise the admissible command of a grid closest
to it.

- Dynamic window. The commands reachable in one period ``dt``:
  :math:`v \in [v_p - a_{max} dt, v_p + a_{max} dt] \cap [v_{min}, v_{max}]`,
  :math:`\omega \in [\omega_p - \alpha_{max} dt, \omega_p + \alpha_{max} dt] \cap
  [-\omega_{max}, \omega_{max}]`, :math:`v_{min} = 0` (the robot has no sensor behind it) or
  :math:`-v_{max}` with ``allow_reverse``. A previous command outside the limits is first
  brought inside them. The grid is ``num_v`` x ``num_omega`` evenly spaced commands spanning the
  window, edges included.
- Rollout. Each candidate is held for ``horizon`` seconds :math:`T` on its exact unicycle arc
  :math:`x(t) = v t\,\mathrm{sinc}(\omega t)`, :math:`y(t) = v t \sin(\omega t / 2)\,
  \mathrm{sinc}(\omega t / 2)` (:math:`\mathrm{sinc}\,a = \sin a / a`), a circle of signed
  curvature :math:`\kappa = \omega / v` centred at :math:`(0, 1/\kappa)`. The distance from a
  point :math:`p` to the arc is computed exactly, not by sampling: inside the arc's wedge
  (between the normals at its two ends) it is the distance to the circle,
  :math:`\big|\kappa |p|^2 - 2 p_y\big| / \big(1 + \sqrt{(\kappa p_x)^2 + (1 - \kappa p_y)^2}\big)`
  (free of cancellation as :math:`\kappa \to 0`, where it becomes the distance :math:`|p_y|` to
  the straight path), and outside it the distance to the nearer end.
- Admissible (DWA's :math:`V_r = V_s \cap V_a \cap V_d`): the command is in the window, and the
  robot's disc of radius ``radius + margin`` stays clear of every valid point along the arc over
  the horizon, and the clear arc covers the stopping distance, :math:`v^2 \le 2 a_{max} d` with
  :math:`d = |v| T` (DWA's admissible velocities; true for every candidate when
  ``horizon >= v_max / (2 a_max)``, which `select` requires). A point already inside the
  enlarged disc (a person stepping close) may not be approached: its distance to the arc may
  not drop below its present distance. Turning on the spot (:math:`v = 0`) does not move the
  disc, so it is always admissible.
- Selection. If :math:`u_d` is admissible it is returned unchanged (bit-identical). Otherwise
  the admissible grid command minimising

  .. math::
      J(v, \omega) = w_v \Big(\frac{v - v_d}{v_{max}}\Big)^2
        + w_\omega \Big(\frac{\omega - \omega_d}{\omega_{max}}\Big)^2
        + w_c \frac{\max(c_{ref} - c, 0)}{c_{ref}}

  (:math:`c_{ref}` = ``clearance_scale``) replaces it, the first one in grid order on ties.
  :math:`c = \sqrt{\min_j (d_j^2 - l_j^2) + (r + \text{margin})^2} - r`, with :math:`d_j` the
  distance from point :math:`j` to the arc and :math:`l_j` its limit (``radius + margin``, or
  its present distance for a point already inside), is the arc's clearance from the robot's
  body when no point is inside the enlarged disc (one reduction over the points gives both
  :math:`c` and admissibility, :math:`\min_j (d_j^2 - l_j^2) \ge 0`). Turning on the spot
  leaves the disc where it is, so when :math:`v_d > 0` such a command takes the :math:`c` of
  the straight path of length :math:`v_{max} T` along the heading :math:`\omega T` it reaches,
  and one more unit of the clearance term (:math:`w_c`) if that path is not clear: a robot
  that has to stop turns toward open space rather than keep facing what blocks it.
- Blocked. If no grid command is admissible (possible only when the window excludes
  :math:`v = 0`), the robot stops: :math:`v = 0` at once (an emergency stop beyond
  :math:`a_{max}`) and turns at :math:`\omega_d` brought into the window (``blocked="rotate"``)
  or not at all (``"halt"``).
- Obstacles are static over the horizon. The person being followed is an obstacle too: unless
  the caller masks its returns, a user straight ahead at distance :math:`D` caps the speed near
  :math:`(D - r - \text{margin}) / T`.

Gradient: through :math:`u_d` (identity) when it is returned; zero when a grid command replaces
it (the choice is piecewise constant in :math:`u_d`, and the window is built from
``stop_gradient(u_prev)``), so the gains of the law upstream receive nothing from such a step;
in the blocked case, the turn rate's clip of :math:`\omega_d`. No gradient flows through the
obstacle points except into ``info.clearance``.

Cost: ``(num_v * num_omega + 1) * B`` point-to-arc distances per call (a square root and a
division each) and one reduction over them, plus ``num_omega * B`` point-to-segment distances
for the turns on the spot; ``stride`` keeps every ``stride``-th point (beams of a dense scan).

Public API: `AvoidanceParams`, `AvoidanceInfo`, `select`, `DESIRED`, `REPLACED`, `BLOCKED`.
"""

from __future__ import annotations

import operator
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxtrack import _checks

Array = jax.Array

__all__ = ["AvoidanceParams", "AvoidanceInfo", "select", "DESIRED", "REPLACED", "BLOCKED"]

DESIRED = 0
"""`AvoidanceInfo.case`: the desired command was admissible and is returned unchanged."""
REPLACED = 1
"""`AvoidanceInfo.case`: an admissible grid command replaced the desired one."""
BLOCKED = 2
"""`AvoidanceInfo.case`: nothing in the window was admissible; the robot stops (and turns)."""

_BLOCKED_MODES = ("rotate", "halt")
_STATIC = ("num_v", "num_omega", "allow_reverse")


class AvoidanceParams(NamedTuple):
    """Parameters of the dynamic window (a pytree; the float fields are its leaves).

    ``num_v``, ``num_omega`` and ``allow_reverse`` fix shapes and branches: they are
    static (kept in the pytree's structure, not leaves), so the parameters can be passed through
    `jax.jit` as an ordinary argument.

    Attributes:
      radius: robot radius (m). margin: clearance kept between the robot's body and any point (m).
      horizon: time each candidate is held in the rollout (s).
      num_v, num_omega: grid sizes over the window (static ints >= 2; an odd ``num_omega``
        keeps the previous turn rate on the grid).
      v_max (m/s), omega_max (rad/s), a_max (m/s^2), alpha_max (rad/s^2): limits.
      dt: control period (s): the window is what is reachable from the previous command in ``dt``.
      allow_reverse: whether v < 0 is allowed (static bool; default False, no sensor behind).
      weight_v, weight_omega: weights of the scaled distance to the desired command. Keeping
        the speed weighs more than keeping the turn rate by default: a robot that swerves
        keeps up with its user, while with equal weights a robot driving straight at a post
        slows down to a stop in front of it (the closed-loop test measures both).
      weight_clearance: weight of the clearance preference. clearance_scale: clearance (m) beyond
        which an arc is not preferred any more.

    Example:
      >>> params = AvoidanceParams(v_max=1.5, alpha_max=4.0)
    """

    radius: float = 0.3
    margin: float = 0.1
    horizon: float = 1.0
    num_v: int = 5
    num_omega: int = 11
    v_max: float = 2.0
    omega_max: float = 2.0
    a_max: float = 1.5
    alpha_max: float = 3.0
    dt: float = 0.1
    allow_reverse: bool = False
    weight_v: float = 1.0
    weight_omega: float = 0.1
    weight_clearance: float = 0.1
    clearance_scale: float = 0.5


def _flatten(p):
    leaves = tuple(getattr(p, f) for f in AvoidanceParams._fields if f not in _STATIC)
    return leaves, tuple(getattr(p, f) for f in _STATIC)


def _unflatten(static, leaves):
    it = iter(leaves)
    values = dict(zip(_STATIC, static))
    return AvoidanceParams(*[values[f] if f in values else next(it)
                             for f in AvoidanceParams._fields])


jax.tree_util.register_pytree_node(AvoidanceParams, _flatten, _unflatten)


class AvoidanceInfo(NamedTuple):
    """What `select` did.

    Attributes:
      case: int32, `DESIRED` (0), `REPLACED` (1) or `BLOCKED` (2).
      clearance: smallest distance between the robot's body (``radius``) and a valid point
        along the returned command's arc over the horizon (m; inf without valid points).
      num_admissible: int32, admissible grid commands.
    """

    case: Array
    clearance: Array
    num_admissible: Array


# ---------------------------------------------------------------------------------------------
# Public functions


def select(params: AvoidanceParams, u_desired: Array, u_prev: Array, points: Array,
           mask: Array, *, stride: int = 1, blocked: str = "rotate"
           ) -> tuple[Array, AvoidanceInfo]:
    r"""The desired command if admissible, else the closest admissible one in the dynamic window.

    See the module docstring for the window, the rollout, admissibility and the cost
    (Fox, Burgard, Thrun 1997, sections 3-4, with the distance to the desired command as the
    objective).

    Args:
      params: `AvoidanceParams`.
      u_desired: [2] desired (v, omega), e.g. from `follower.control`.
      u_prev: [2] previous command (v, omega): the centre of the dynamic window.
      points: [B, 2] obstacle points in the robot frame (m); rows with ``mask`` False may hold
        anything (NaN included).
      mask: [B] bool, valid points. Inside traced code, non-finite valid points are ignored.
      stride: keep every ``stride``-th point (static int >= 1); an obstacle thinner than the
        gap between kept beams may be missed until the robot is close to it.
      blocked: what to do when nothing is admissible: ``"rotate"`` (v = 0, turn toward the
        desired heading change) or ``"halt"`` (v = omega = 0).

    Returns:
      u: [2] (v, omega) in ``u_desired``'s float dtype; `AvoidanceInfo`.

    Gradient: the identity w.r.t. ``u_desired`` when it is returned (``case == DESIRED``), so
    the gradients of the follower's gains pass through untouched; zero when a grid command
    replaces it; in the blocked case only the turn rate's clip of ``u_desired[1]`` carries one.

    Example:
      >>> wall = jnp.stack([jnp.full(41, 0.5), jnp.linspace(-1, 1, 41)], -1)
      >>> u, info = select(AvoidanceParams(), jnp.array([0.5, 0.0]), jnp.array([0.5, 0.0]),
      ...                  wall, jnp.ones(41, bool))
      >>> int(info.case)  # 2: the window cannot brake below 0.35 m/s, so it stops
      >>> u  # (0, 0)
    """
    _check_params(params)
    if blocked not in _BLOCKED_MODES:
        raise ValueError(f"unknown blocked mode {blocked!r}; expected one of "
                         f"{list(_BLOCKED_MODES)}")
    if isinstance(stride, bool) or not isinstance(stride, (int, np.integer)) or stride < 1:
        raise ValueError(f"stride must be an int >= 1; got {stride!r}")
    _checks.check_shape("u_desired", u_desired, (2,), "(v, omega)")
    _checks.check_shape("u_prev", u_prev, (2,), "(v, omega)")
    _checks.check_shape("points", points, (None, 2), "[B, 2] robot-frame points")
    b = np.shape(points)[0]
    _checks.check_shape("mask", mask, (b,), "[B] bool")
    if _checks.is_concrete(mask) and not np.issubdtype(np.asarray(mask).dtype, np.bool_):
        raise TypeError(f"mask must be bool; got {np.asarray(mask).dtype}")
    _checks.check_finite("u_desired", u_desired)
    _checks.check_finite("u_prev", u_prev)
    if _checks.is_concrete(points) and _checks.is_concrete(mask):
        valid = np.asarray(points)[np.asarray(mask)]
        if not np.all(np.isfinite(valid)):
            raise ValueError("points contains NaN or inf in rows where mask is True")

    u_desired = jnp.asarray(u_desired)
    dtype = jnp.result_type(u_desired.dtype, jnp.float32)
    u_desired = u_desired.astype(dtype)
    points = jnp.asarray(points, dtype)[::stride]
    mask = jnp.asarray(mask, bool)[::stride]
    return _select_jit(params, u_desired, jnp.asarray(u_prev, dtype), points, mask, blocked)


# ---------------------------------------------------------------------------------------------
# Private helpers


def _select(params, u_des, u_prev, points, mask, blocked):
    dtype = u_des.dtype

    def f(x):
        return jnp.asarray(x, dtype)

    des_finite = jnp.all(jnp.isfinite(u_des))
    des = jnp.where(des_finite, u_des, 0.0)
    prev = lax.stop_gradient(jnp.where(jnp.all(jnp.isfinite(u_prev)), u_prev, 0.0))
    mask = mask & jnp.all(jnp.isfinite(points), -1)
    points = jnp.where(mask[:, None], points, 0.0)

    v_max, w_max = f(params.v_max), f(params.omega_max)
    v_min = -v_max if params.allow_reverse else f(0.0)
    dv, dw = f(params.a_max) * f(params.dt), f(params.alpha_max) * f(params.dt)
    v_lo, v_hi = jnp.clip(prev[0] - dv, v_min, v_max), jnp.clip(prev[0] + dv, v_min, v_max)
    w_lo, w_hi = jnp.clip(prev[1] - dw, -w_max, w_max), jnp.clip(prev[1] + dw, -w_max, w_max)
    vs = v_lo + (v_hi - v_lo) * jnp.linspace(0.0, 1.0, params.num_v, dtype=dtype)
    ws = w_lo + (w_hi - w_lo) * jnp.linspace(0.0, 1.0, params.num_omega, dtype=dtype)
    grid = jnp.stack(jnp.meshgrid(vs, ws, indexing="ij"), -1).reshape(-1, 2)
    turn = jnp.clip(des[1], w_lo, w_hi) if blocked == "rotate" else f(0.0)
    fallback = jnp.stack([f(0.0), turn])

    cand = jnp.concatenate([des[None], grid])
    free, clearance = _sweep(params, cand, points, mask)
    # Turning on the spot leaves the disc where it is. A robot that wants to drive on should
    # then turn toward open space rather than keep facing what blocks it: such commands are
    # judged by the straight path (v_max T long) along the heading they reach, with one more
    # unit of the clearance term when that path is not clear.
    g, nw = grid.shape[0], params.num_omega
    spot = (grid[:, 0] == 0) & (des[0] > 0)
    heading_clearance, heading_blocked = _heading_clearance(params, ws, points, mask)
    grid_clearance = jnp.where(spot, jnp.tile(heading_clearance, g // nw), clearance[1:])
    spot_blocked = spot & jnp.tile(heading_blocked, g // nw)

    # The follower's own acceleration limit lands on the window's edge up to rounding.
    eps = jnp.finfo(dtype).eps
    tol_v = 16 * eps * (1.0 + jnp.abs(prev[0]) + dv)
    tol_w = 16 * eps * (1.0 + jnp.abs(prev[1]) + dw)
    in_window = ((des[0] >= v_lo - tol_v) & (des[0] <= v_hi + tol_v)
                 & (des[1] >= w_lo - tol_w) & (des[1] <= w_hi + tol_w))
    desired_ok = des_finite & in_window & free[0]

    ok = free[1:]
    c_ref = f(params.clearance_scale)
    cost = (f(params.weight_v) * ((grid[:, 0] - des[0]) / v_max) ** 2
            + f(params.weight_omega) * ((grid[:, 1] - des[1]) / w_max) ** 2
            + f(params.weight_clearance) * (jnp.maximum(c_ref - grid_clearance, 0.0) / c_ref
                                            + spot_blocked))
    best = jnp.argmin(jnp.where(ok, cost, jnp.inf))
    any_ok = jnp.any(ok)

    case = jnp.where(desired_ok, DESIRED, jnp.where(any_ok, REPLACED, BLOCKED)).astype(jnp.int32)
    u = jnp.where(desired_ok, u_des, jnp.where(any_ok, grid[best], fallback))
    closest = jnp.min(jnp.where(mask, _arc_distance2(params, lax.stop_gradient(u)[None], points)[0],
                                jnp.inf))
    info = AvoidanceInfo(case, jnp.sqrt(closest) - f(params.radius),
                         jnp.sum(ok).astype(jnp.int32))
    return u, info


_select_jit = jax.jit(_select, static_argnums=5)


def _sweep(params, cand, points, mask):
    r"""(admissible [C], clearance used by the cost [C]) of candidates [C, 2] given points [B, 2].

    One reduction over the points: :math:`m = \min_j (d_j^2 - l_j^2)` with :math:`d_j` the
    distance from point :math:`j` to the arc and :math:`l_j` its limit (``radius + margin``, or
    its present distance for a point already inside). The arc collides iff :math:`m < 0`; the
    cost's clearance is :math:`\sqrt{m + (r + \text{margin})^2} - r`, the arc's clearance when
    no point is inside the enlarged disc (a point inside counts as on its edge, plus what the
    arc gains on it).
    """
    dtype = cand.dtype
    d2 = _arc_distance2(params, cand, points)                       # [C, B]
    radius = jnp.asarray(params.radius, dtype)
    reach = radius + jnp.asarray(params.margin, dtype)
    limit = _limit(points, reach)                                   # [B]
    m = jnp.min(jnp.where(mask, d2 - limit * limit, jnp.inf), axis=1)
    v = cand[:, 0]
    horizon = jnp.asarray(params.horizon, dtype)
    stoppable = v * v <= 2.0 * jnp.asarray(params.a_max, dtype) * jnp.abs(v) * horizon
    return (m >= 0) & stoppable, jnp.sqrt(jnp.maximum(m + reach * reach, 0.0)) - radius


def _heading_clearance(params, omegas, points, mask):
    """(cost clearance [W] as in `_sweep`, collides [W]) of straight paths v_max T long along
    the headings omega T."""
    dtype = points.dtype
    horizon = jnp.asarray(params.horizon, dtype)
    length = jnp.asarray(params.v_max, dtype) * horizon
    heading = omegas[:, None] * horizon
    c, s = jnp.cos(heading), jnp.sin(heading)
    px, py = points[:, 0], points[:, 1]
    along = c * px + s * py                                         # [W, B]
    across = c * py - s * px
    beyond = along - jnp.clip(along, 0.0, length)
    d2 = beyond * beyond + across * across
    radius = jnp.asarray(params.radius, dtype)
    reach = radius + jnp.asarray(params.margin, dtype)
    limit = _limit(points, reach)
    m = jnp.min(jnp.where(mask, d2 - limit * limit, jnp.inf), axis=1)
    return jnp.sqrt(jnp.maximum(m + reach * reach, 0.0)) - radius, m < 0


def _limit(points, reach):
    """[B] the distance each point must keep from the arcs: ``reach``, or less if already inside."""
    d0 = jnp.sqrt(jnp.sum(points * points, -1))
    near = jnp.maximum(d0 - 16 * jnp.finfo(points.dtype).eps * (1.0 + d0), 0.0)
    return jnp.minimum(reach, near)


def _arc_distance2(params, cand, points):
    """Squared distances [C, B] from points [B, 2] to the arcs of candidates [C, 2], exactly.

    Inside the arc's wedge (between the normals at its two ends) the distance is the distance
    to the circle, otherwise to the nearer end.
    """
    dtype = cand.dtype
    horizon = jnp.asarray(params.horizon, dtype)
    v, w = cand[:, :1], cand[:, 1:]                                 # [C, 1]
    moving = v != 0
    # Signed curvature; beyond 1/um the arc is a turn on the spot (and kappa^2 stays finite).
    kappa = jnp.clip(jnp.where(moving, w / jnp.where(moving, v, 1.0), 0.0), -1e6, 1e6)
    turn = w * horizon
    end_x = v * horizon * jnp.sinc(turn / jnp.pi)
    end_y = v * horizon * jnp.sin(turn / 2) * jnp.sinc(turn / (2 * jnp.pi))
    sign = jnp.sign(v)
    tan_x, tan_y = sign * jnp.cos(turn), sign * jnp.sin(turn)       # direction of travel at the end
    sweep = jnp.abs(turn)

    px, py = points[:, 0], points[:, 1]                             # [B]
    r2 = px * px + py * py
    # | |p - c| - 1/|kappa| | with c = (0, 1/kappa), free of cancellation for small kappa.
    root = jnp.sqrt((kappa * px) ** 2 + (1.0 - kappa * py) ** 2)
    to_circle = jnp.abs(kappa * r2 - 2.0 * py) / (1.0 + root)
    ahead = sign * px >= 0
    before_end = (end_x - px) * tan_x + (end_y - py) * tan_y >= 0
    inside = jnp.where(sweep >= 2 * jnp.pi, True,
                       jnp.where(sweep <= jnp.pi, ahead & before_end, ahead | before_end))
    to_end2 = (px - end_x) ** 2 + (py - end_y) ** 2
    return jnp.where(inside & moving, to_circle * to_circle, jnp.minimum(r2, to_end2))


def _check_params(params):
    if not isinstance(params, AvoidanceParams):
        raise TypeError(f"params must be an AvoidanceParams; got {type(params).__name__}")
    for name in ("num_v", "num_omega"):
        value = getattr(params, name)
        try:
            value = operator.index(value)
        except TypeError:
            raise TypeError(f"params.{name} must be a Python int (static); got "
                            f"{type(value).__name__}") from None
        if value < 2:
            raise ValueError(f"params.{name} must be >= 2; got {value}")
    if not isinstance(params.allow_reverse, (bool, np.bool_)):
        raise TypeError(f"params.allow_reverse must be a bool; got "
                        f"{type(params.allow_reverse).__name__}")
    rules = {"radius": "> 0", "margin": ">= 0", "horizon": "> 0", "v_max": "> 0",
             "omega_max": "> 0", "a_max": "> 0", "alpha_max": "> 0", "dt": "> 0",
             "weight_v": ">= 0", "weight_omega": ">= 0", "weight_clearance": ">= 0",
             "clearance_scale": "> 0"}
    for name, rule in rules.items():
        value = getattr(params, name)
        _checks.check_shape(f"params.{name}", value, (), "a scalar")
        if not _checks.is_concrete(value):
            continue
        x = float(np.asarray(value))
        good = np.isfinite(x) and (x > 0 if rule == "> 0" else x >= 0)
        if not good:
            raise ValueError(f"params.{name} must be finite and {rule}; got {x}")
    if all(_checks.is_concrete(getattr(params, n)) for n in ("horizon", "v_max", "a_max")):
        need = float(np.asarray(params.v_max)) / (2 * float(np.asarray(params.a_max)))
        if float(np.asarray(params.horizon)) < need:
            raise ValueError(f"params.horizon ({float(np.asarray(params.horizon))} s) must be >= "
                             f"v_max / (2 a_max) = {need:.3g} s, so that an arc clear over the "
                             f"horizon also covers the stopping distance")
