r"""The behaviour of a person-following robot: one step from the user estimate to the wheels.

`following` builds a `Behaviour` whose ``step`` runs, in the robot frame, the layers between
the estimate and the wheel command:

1. **follower law** (`jaxtrack.control.follower`, seed 004 eq. 9): the follower point ``P_fm``
   on the estimated user, with velocity and acceleration limits; a user unseen for longer than
   ``lost_timeout`` is assumed to stand still;
2. **route** (`jaxtrack.control.route`): when the straight line to the user passes within
   ``route_clearance`` of a table or chair of the robot's map, the robot itself (not its follower
   point) steers to a waypoint of the shortest route to them instead;
3. **avoidance** (`jaxtrack.control.avoidance`, a dynamic window): the law's command when its arc
   over ``avoidance_horizon`` is clear of the laser returns and of the outlines of the map's
   tables and chairs (the laser sees only their legs, and the gaps between legs are not free
   space), else the closest clear command; returns within ``user_clearance`` of the user's
   estimate are left out (the user walks ahead and is no obstacle to plan around);
4. **safety stop**: no forward motion while a laser return lies in the robot's path (ahead, within
   the robot's half-width plus ``corridor_margin``) within ``stop_distance`` of its centre
   (backing away stays possible);
5. **camera**: with a pan unit (``pan``), the RGB-D camera is servoed to keep the user's
   estimate centred (`jaxtrack.control.pan_tilt`), or the person to look at while looking;
6. **lost / search / look**: a user unseen for longer than ``lost_timeout`` stops the robot's
   driving; after ``search_after`` it turns on the spot at ``search_rate`` toward the side where
   the user was last estimated, keeping that direction (a stale estimate must not make it swing
   back and forth); with an estimate of whom to look at (`jaxtrack.tracking.user.UserEstimate`'s
   ``look``: a person the colours have not told apart from the user), from ``lost_timeout`` it
   first turns toward them, at most at ``search_rate``.

Frames: every input is in the robot frame, except ``map_pose``, the robot's pose in the map of
its known obstacles (routes and outlines are precomputed in that frame).

Example:
  >>> beh = following(FollowingConfig(), robot_radius=0.25, dt=0.1,
  ...                 known=KnownMap(outline, bounds))
  >>> state = beh.init(jnp.float32)
  >>> state, cmd = beh.step(state, inputs, follower.Params.create())
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import geometry
from jaxtrack.control import avoidance, follower, pan_tilt, route

Array = jax.Array

__all__ = ["FollowingConfig", "KnownMap", "FollowingInputs", "FollowingState", "Command",
           "Behaviour", "following"]


@dataclasses.dataclass(frozen=True)
class FollowingConfig:
    """Static settings of the following behaviour (module docstring).

    The robot's radius and the control period are arguments of `following` (they belong to the
    robot and the loop).

    Attributes:
      safety_margin: clearance kept between the robot's body and obstacles (m), by the
        avoidance layer and the routes.
      corridor_margin: half-width margin of the safety stop's corridor beyond the body (m).
      lost_timeout, search_after (s); search_rate (rad/s); look_gain: turn rate per radian of
        bearing toward the person to look at (clipped to ``search_rate``).
      avoidance: put the dynamic window between the law and the wheels; avoidance_stride: every
        how many laser returns it checks; avoidance_horizon: its rollout (s); user_clearance:
        returns this close to the user's estimate are not obstacles to it (m).
      reverse: allow driving backwards (the laser sees 240 deg to the front, nothing behind: by
        default the robot never reverses, and turns instead); reverse_speed: the backward speed
        limit (m/s) when it may (the avoidance layer checks backward arcs against the known
        map's outlines; people behind are not seen).
      route: steer along routes of the known map when the straight line is blocked (blocked
        straight lines made most of the following error; measurements: docs/design_notes.md,
        "Person following: routes around the furniture");
        route_cell: the route grid (m); route_clearance: distance (m) from furniture below
        which the straight line counts as blocked; the route's cells keep
        ``robot_radius + safety_margin + route_margin`` from furniture and walls.
      pan: `pan_tilt.PanTiltConfig` of the camera's pan unit, or None (a fixed camera).
      outline_reach: the avoidance layer checks only the known outline points within this
        distance (m) of the robot (looked up in a table over ``outline_cell`` cells built once
        from the map; inf checks them all). Farther points cannot change its choice while
        ``outline_reach`` exceeds the longest rollout plus the body, margin and clearance
        scale (1.5 m/s x 1 s + 0.25 + 0.1 + 0.5 m = 2.35 m for the defaults); in the shop they
        are 804 points, and checking all of them every frame was most of the frame's cost.
    """

    safety_margin: float = 0.3
    corridor_margin: float = 0.05
    lost_timeout: float = 1.0
    search_after: float = 1.5
    search_rate: float = 0.6
    look_gain: float = 2.0
    avoidance: bool = True
    avoidance_stride: int = 2
    avoidance_horizon: float = 1.0
    user_clearance: float = 0.45
    reverse: bool = False
    reverse_speed: float = 0.5
    route: bool = True
    route_cell: float = 0.25
    route_clearance: float = 0.3
    route_margin: float = 0.05
    pan: pan_tilt.PanTiltConfig | None = None
    outline_reach: float = 3.0
    outline_cell: float = 0.5

    def __post_init__(self):
        if not self.safety_margin >= 0:
            raise ValueError(f"safety_margin must be >= 0; got {self.safety_margin}")
        if not (self.route_cell > 0 and self.route_clearance >= 0):
            raise ValueError(f"route_cell must be > 0 and route_clearance >= 0; got "
                             f"{self.route_cell}, {self.route_clearance}")
        if not (self.outline_reach > 0 and self.outline_cell > 0):
            raise ValueError(f"outline_reach and outline_cell must be > 0; got "
                             f"{self.outline_reach}, {self.outline_cell}")
        if self.avoidance_stride < 1:
            raise ValueError(f"avoidance_stride must be >= 1; got {self.avoidance_stride}")
        if not (self.lost_timeout >= 0 and self.search_after >= 0 and self.search_rate >= 0):
            raise ValueError("lost_timeout, search_after and search_rate must be >= 0")


class KnownMap(NamedTuple):
    """The robot's map of static obstacles (map frame; numpy, built once).

    Attributes:
      outline: [N, 2] points along the outlines of tables and chairs (every 0.1 m, say).
      bounds: ``((x_min, x_max), (y_min, y_max))`` of the walls.
    """

    outline: np.ndarray
    bounds: tuple


class FollowingInputs(NamedTuple):
    """One frame's inputs of the behaviour (robot frame unless stated).

    Attributes:
      user: [2] the user's estimated position; user_vel: [2] their velocity in robot axes.
      user_found: bool, the estimator measured the user this frame.
      obstacles: [B, 2] laser returns; obstacle_mask: [B].
      map_pose: [3] the robot's pose in the map frame.
      look: [2] whom to look at while the user is lost, or None; look_ok: bool or None.
    """

    user: Array
    user_vel: Array
    user_found: Array
    obstacles: Array
    obstacle_mask: Array
    map_pose: Array
    look: Array | None = None
    look_ok: Array | None = None


class FollowingState(NamedTuple):
    """u: [2] the last command (v, omega); unseen: seconds since the user was last measured;
    search_side: +1 / -1, the direction of the search turn; pan: the camera's
    `pan_tilt.PanState` (None without a pan unit)."""

    u: Array
    unseen: Array
    search_side: Array
    pan: pan_tilt.PanState | None = None


class Command(NamedTuple):
    """What the behaviour decided, and why.

    Attributes:
      u: [2] the wheel command (v, omega); stopped: bool, the safety stop held the robot.
      pan: the camera's pan angle for the next frame (rad; None without a pan unit).
      direct: bool, the robot steered straight at the user (False: along a route around the
        known obstacles; True without a map).
      avoidance: int32 `avoidance.AvoidanceInfo.case` (0: the law's command, 1: replaced,
        2: blocked; -1 without the avoidance layer).
    """

    u: Array
    stopped: Array
    pan: Array | None = None
    direct: Array | None = None
    avoidance: Array | None = None


class Behaviour(NamedTuple):
    """``init(dtype) -> FollowingState`` and ``step(state, inputs, params) -> (state,
    Command)``, ``params`` a `follower.Params`."""

    init: Callable
    step: Callable


def following(config: FollowingConfig, *, robot_radius: float, dt: float,
              known: KnownMap | None = None, dtype=jnp.float32) -> Behaviour:
    """The following behaviour (module docstring) of a robot of radius ``robot_radius`` (m)
    controlled every ``dt`` (s), with the map ``known`` (None: no routes, no known outlines).

    Example:
      >>> beh = following(FollowingConfig(), robot_radius=0.25, dt=0.1,
      ...                 known=KnownMap(outline, ((-5, 5), (-4, 4))))
    """
    cfg = config
    if not (robot_radius > 0 and dt > 0):
        raise ValueError(f"robot_radius and dt must be > 0; got {robot_radius}, {dt}")
    body = _Body(robot_radius, dt)
    outline = jnp.zeros((0, 2), dtype) if known is None else jnp.asarray(known.outline, dtype)
    nearby = None
    if cfg.avoidance and outline.shape[0] and cfg.outline_reach < float("inf"):
        nearby = _outline_table(np.asarray(known.outline), known.bounds, cfg.outline_reach,
                                cfg.outline_cell)
    routes = None
    if cfg.route and outline.shape[0]:
        routes = route.build(np.asarray(outline), known.bounds, cell=cfg.route_cell,
                             clearance=robot_radius + cfg.safety_margin + cfg.route_margin,
                             dtype=dtype)

    def init(dtype=dtype) -> FollowingState:
        pan = None if cfg.pan is None else pan_tilt.init(dtype)
        return FollowingState(jnp.zeros(2, dtype), jnp.zeros((), dtype), jnp.ones((), dtype),
                              pan)

    def step(state: FollowingState, x: FollowingInputs, fol: follower.Params):
        dtype = state.u.dtype
        unseen = jnp.where(x.user_found, 0.0, state.unseen + dt)
        lost_now = unseen > cfg.lost_timeout
        rel = x.user
        vel = x.user_vel * (unseen <= cfg.lost_timeout)
        goal, goal_vel, direct = rel, vel, jnp.asarray(True)
        if routes is not None:
            goal, goal_vel, direct = _route_goal(cfg, body, routes, outline, x.map_pose, rel,
                                                 vel, fol.point)
        ahead = (x.obstacles[:, 0] > 0) & (jnp.abs(x.obstacles[:, 1])
                                          < robot_radius + cfg.corridor_margin)
        blocked = follower.safety_stop(x.obstacles, x.obstacle_mask & ahead, fol.stop_distance)
        u = follower.control(fol, goal, goal_vel, state.u, dt, reverse=cfg.reverse)
        case = jnp.int32(-1)
        if cfg.avoidance:
            near, near_ok = outline, jnp.ones(outline.shape[0], bool)
            if nearby is not None:
                near, near_ok = _nearby_outline(nearby, outline, x.map_pose)
            u, case = _avoid(cfg, body, fol, u, state.u, x,
                             geometry.to_frame(x.map_pose, near), near_ok)
        v = jnp.where(blocked | lost_now, jnp.minimum(u[0], 0.0), u[0])
        w, side = _search(cfg, body, fol, state, x, unseen, lost_now, u[1])
        u = jnp.stack([jnp.maximum(v, -cfg.reverse_speed) if cfg.reverse
                       else jnp.maximum(v, 0.0), w])
        pan = None if cfg.pan is None else _camera(cfg, body, state, x, lost_now)
        return (FollowingState(u, unseen, side.astype(dtype), pan),
                Command(u, blocked, None if pan is None else pan.angle, direct, case))

    return Behaviour(init, step)


class _Body(NamedTuple):
    robot_radius: float
    dt: float


def _route_goal(cfg, body, routes, outline, map_pose, rel, vel, point):
    """Off a clear straight line, the robot itself (not its follower point) drives to the
    route's waypoint: the goal moves out by the follower point's length along the waypoint's
    direction, with no velocity feed-forward."""
    wp, direct = route.waypoint(routes, map_pose[:2], geometry.from_frame(map_pose, rel), outline,
                                clearance=body.robot_radius + cfg.safety_margin,
                                direct_clearance=cfg.route_clearance)
    wp = geometry.to_frame(map_pose, wp)
    reach = wp + geometry.safe_norm(point) * wp / jnp.maximum(geometry.safe_norm(wp), 1e-3)
    return jnp.where(direct, rel, reach), jnp.where(direct, vel, 0.0), direct


class _OutlineTable(NamedTuple):
    """The outline points near each cell of a grid over the map: ``index`` [C, K] into the
    outline (``ok`` [C, K] marks the real entries), cell ``origin`` [2], ``cell`` size and
    ``shape`` (nx, ny)."""

    index: np.ndarray
    ok: np.ndarray
    origin: np.ndarray
    cell: float
    shape: tuple


def _outline_table(outline: np.ndarray, bounds, reach: float, cell: float) -> _OutlineTable:
    """For every ``cell`` of the map's bounds, the outline points within ``reach`` of some
    point of the cell (of its centre, plus half the cell's diagonal): a robot anywhere in the
    cell finds every point within ``reach`` of it there. Built once with numpy."""
    (x0, x1), (y0, y1) = bounds
    nx, ny = int(np.ceil((x1 - x0) / cell)), int(np.ceil((y1 - y0) / cell))
    cx = x0 + cell * (np.arange(nx) + 0.5)
    cy = y0 + cell * (np.arange(ny) + 0.5)
    centres = np.stack(np.meshgrid(cx, cy, indexing="ij"), -1).reshape(-1, 2)
    d = np.linalg.norm(centres[:, None] - outline[None], axis=-1)
    near = d <= reach + cell * np.sqrt(0.5)
    K = max(int(near.sum(1).max()), 1)
    order = np.argsort(~near, axis=1, kind="stable")[:, :K]
    ok = np.take_along_axis(near, order, 1)
    return _OutlineTable(np.where(ok, order, 0).astype(np.int32), ok,
                         np.array([x0, y0]), float(cell), (nx, ny))


def _nearby_outline(table: _OutlineTable, outline, map_pose):
    """The outline points [K, 2] (map frame) near the robot's cell, and their mask [K]."""
    ij = jnp.floor((map_pose[:2] - table.origin) / table.cell).astype(jnp.int32)
    ij = jnp.clip(ij, 0, jnp.array(table.shape) - 1)
    c = ij[0] * table.shape[1] + ij[1]
    return outline[jnp.asarray(table.index)[c]], jnp.asarray(table.ok)[c]


def _avoid(cfg, body, fol, u, u_prev, x, known, known_ok):
    """The dynamic window over the laser returns (every ``avoidance_stride``-th, those near the
    user left out) and the known outline points ``known`` [N, 2] (robot frame; ``known_ok``
    [N])."""
    ap = avoidance.AvoidanceParams(
        radius=body.robot_radius, margin=cfg.safety_margin, horizon=cfg.avoidance_horizon,
        v_max=fol.v_max, omega_max=fol.omega_max, a_max=fol.a_max, alpha_max=fol.alpha_max,
        dt=body.dt, allow_reverse=cfg.reverse)
    stride = cfg.avoidance_stride
    seen = x.obstacles[::stride]
    seen_ok = x.obstacle_mask[::stride] & ~(geometry.safe_norm(seen - x.user)
                                            < cfg.user_clearance)
    u, info = avoidance.select(ap, u, u_prev, jnp.concatenate([seen, known]),
                               jnp.concatenate([seen_ok, known_ok]))
    return u, info.case


def _camera(cfg, body, state, x, lost_now):
    """The pan unit turned toward the user's estimate, or toward the person to look at while
    looking for a lost user."""
    bearing = jnp.arctan2(x.user[1], x.user[0])
    if x.look is not None:
        bearing = jnp.where(x.look_ok & lost_now, jnp.arctan2(x.look[1], x.look[0]), bearing)
    return pan_tilt.servo(cfg.pan, state.pan, bearing, body.dt)


def _search(cfg, body, fol, state, x, unseen, lost_now, omega):
    """The turn rate while searching or looking (else ``omega``), with the search side."""
    searching = unseen > cfg.search_after
    side = jnp.where(searching, state.search_side, jnp.where(x.user[1] >= 0.0, 1.0, -1.0))
    target = side * cfg.search_rate
    if x.look is not None:
        looking = x.look_ok & lost_now
        target = jnp.where(looking, jnp.clip(cfg.look_gain * jnp.arctan2(x.look[1], x.look[0]),
                                             -cfg.search_rate, cfg.search_rate), target)
        searching = searching | looking
    dt = body.dt
    sweep = state.u[1] + jnp.clip(target - state.u[1], -fol.alpha_max * dt, fol.alpha_max * dt)
    return jnp.where(searching, sweep, omega), side
