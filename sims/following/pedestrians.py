r"""Pedestrians for the person-following scene: waypoints, social forces, stops, crossings, gait.

Pure ``jax.numpy`` (no MuJoCo): the state is a fixed-capacity array of ``P`` people plus a mask;
person 0 is the user the robot follows, persons ``1..distractors`` walk around them, the rest are
inactive (parked below the floor by `leg_capsules`).

Motion (per person :math:`i`, Helbing-Molnar social force model, one explicit step of ``dt``):

.. math::
    \dot v_i = \frac{s_i e_i - v_i}{\tau}
      + \sum_{j \ne i} w(\varphi_{ij}) A\, e^{(2r - d_{ij})/B}\, (n_{ij} + \kappa\, r_i)
      + \sum_{\text{walls}} A_w e^{(r - d_{iw})/B_w} n_{iw}
      + \sum_{\text{obstacles}} \ldots + \text{robot},

with :math:`e_i` the unit vector to the current waypoint, :math:`s_i` the preferred speed (drawn
in ``speed_range``, 0 while stopped), :math:`n_{ij}` the unit vector from :math:`j` to
:math:`i`, :math:`r_i` person :math:`i`'s right (everyone keeps right, which breaks head-on
deadlocks), :math:`w(\varphi) = \lambda + (1 - \lambda)(1 + \cos\varphi)/2` the anisotropy
(what is ahead matters more). Speeds are clipped to ``max_speed``; after the step, positions are
projected so that no two people are closer than ``min_separation``, nobody enters a furniture
footprint or the robot's disc, and everyone stays ``wall_margin`` inside the walls.

Scenario: each person walks to random waypoints in the free part of the room (the user's next
waypoint is at least ``user_min_leg`` away, so the user's path has long legs and turns); at a
waypoint a person stops with probability ``stop_prob`` (and anywhere at rate ``stop_rate``) for
a time in ``stop_duration``; a distractor picking a new waypoint crosses the user's path with
probability ``cross_prob`` (its waypoint is its own position mirrored through a point 1-3 m
ahead of the user). A waypoint that takes too long to reach is replaced.

Gait (`leg_capsules`, `torso_position`): the cadence (steps per second) grows with speed,
:math:`f = f_0 + f_1 |v|` (1.96 Hz at 1.2 m/s), the step length is :math:`L = |v| / f`
(0.61 m at 1.2 m/s, 0 standing). The gait phase advances by :math:`\pi f\,dt` (a full cycle of
:math:`2\pi` is one stride = two steps); the feet sit ``hip_width`` apart sideways and
:math:`\pm (L/2) \sin\phi` along the heading, so they pass each other (merge, for a laser) at every
step. Each leg is a capsule of fixed length from the foot to the hip (the hips drop a little when
the feet are apart). The torso sways sideways over the stance foot,
:math:`-a \cos\phi` (amplitude ``sway``, 2.5 cm at walking speed): one left-right sway per stride,
so the sway's fundamental frequency is the stride frequency :math:`f/2` and its period two steps.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import _checks
from jaxtrack.angles import wrap

Array = jax.Array

__all__ = ["GaitParams", "SocialForces", "Walks", "Shopping", "UserBehaviour", "PedestrianConfig",
           "PedestrianState", "init", "step", "rollout", "robot_start", "leg_capsules",
           "torso_position", "cadence", "PARK_DEPTH"]

PARK_DEPTH = -50.0
"""Height (m) at which inactive people are parked, far below the floor and any sensor."""


class GaitParams(NamedTuple):
    """Body and gait of a pedestrian (metres, seconds; float leaves).

    Attributes:
      cadence_offset, cadence_slope: cadence :math:`f = f_0 + f_1 |v|` in steps/s.
      stand_speed: below this speed (m/s) a person stands: the phase stops, the legs close.
      hip_width: lateral distance between the two legs (hips and feet).
      leg_radius: radius of the leg capsules.
      leg_length: distance between the two end points (foot and hip centres) of a leg capsule.
      sway: sideways torso sway amplitude at walking speed (m).
      sway_speed: speed (m/s) from which the sway has its full amplitude (linear below).
      torso_radius: radius of the torso capsule.
      torso_bottom, torso_top: heights of the torso capsule's end points.
    """

    cadence_offset: float = 1.0
    cadence_slope: float = 0.8
    stand_speed: float = 0.1
    hip_width: float = 0.2
    leg_radius: float = 0.06
    leg_length: float = 0.82
    sway: float = 0.025
    sway_speed: float = 0.5
    torso_radius: float = 0.17
    torso_bottom: float = 1.05
    torso_top: float = 1.5


class SocialForces(NamedTuple):
    """Social-force parameters (Helbing & Molnar): how people move.

    Attributes:
      relax_time: :math:`\\tau`, time to reach the preferred velocity (s).
      person_radius: body radius used by the forces and the projections (m).
      min_separation: no two people's centres come closer than this (m).
      social_strength, social_range: :math:`A` (m/s^2) and :math:`B` (m) between people.
      keep_right: :math:`\\kappa`, sideways share of the social force (steps to the right).
      anisotropy: :math:`\\lambda`, weight of what is behind a person.
      wall_strength, wall_range: wall force :math:`A_w`, :math:`B_w`.
      wall_margin: centres stay this far inside the walls (m).
      robot_strength, robot_range: robot force parameters.
      max_speed: hard speed limit (m/s).
      max_turn_rate: heading rate limit (rad/s).
    """

    relax_time: float = 0.5
    person_radius: float = 0.25
    min_separation: float = 0.6
    social_strength: float = 3.0
    social_range: float = 0.3
    keep_right: float = 0.5
    anisotropy: float = 0.3
    wall_strength: float = 3.0
    wall_range: float = 0.2
    wall_margin: float = 0.4
    robot_strength: float = 3.0
    robot_range: float = 0.3
    max_speed: float = 1.5
    max_turn_rate: float = 4.0


class Walks(NamedTuple):
    """Where people walk: random waypoints, stops.

    Attributes:
      speed_range: preferred walking speeds are drawn uniformly in this range (m/s).
      waypoint_tolerance: a waypoint is reached within this distance (m).
      user_min_leg: the user's next waypoint is at least this far (m).
      stop_prob: probability of stopping at a waypoint.
      stop_rate: rate (1/s) of stopping anywhere while walking.
      stop_duration: stop times are drawn uniformly in this range (s).
      cross_prob: probability that a distractor's next waypoint crosses the user's path.
    """

    speed_range: tuple = (0.5, 1.5)
    waypoint_tolerance: float = 0.4
    user_min_leg: float = 2.5
    stop_prob: float = 0.3
    stop_rate: float = 0.02
    stop_duration: tuple = (1.0, 4.0)
    cross_prob: float = 0.5


class Shopping(NamedTuple):
    """How people walk a shop's aisle graph (`sims.following.layout.AisleGraph`): from shelf
    spot to shelf spot along the shortest route, stopping at each.

    The user follows the shop's tour (`AisleGraph.tour`, aisle by aisle), skipping 0 to
    ``max_skip - 1`` spots at a time, and now and then (``turn_back_prob``) turns back to a spot
    up to ``max_skip`` behind; distractors go to random spots anywhere.

    Attributes:
      speed_range: walking speeds are drawn uniformly in this range at every new spot (m/s).
      stop_duration: the stop at a shelf, drawn uniformly in this range (s), facing it.
      side_step_prob: after a stop, the probability that the next spot is the neighbouring one
        along the same shelf (a side step).
      turn_back_prob: the probability that the user's next spot is behind them on the tour.
      max_skip: the user's next spot is 1 to ``max_skip`` places on along the tour.
      stop_rate: rate (1/s) of a short stop anywhere while walking (someone standing in the
        aisle); its duration is drawn from `Walks.stop_duration`.
      arrive_tolerance: a spot is reached within this distance (m); pass_tolerance: a route
        node on the way, within this distance (m).
    """

    speed_range: tuple = (0.6, 1.3)
    stop_duration: tuple = (2.0, 8.0)
    side_step_prob: float = 0.4
    turn_back_prob: float = 0.1
    max_skip: int = 4
    stop_rate: float = 0.01
    arrive_tolerance: float = 0.25
    pass_tolerance: float = 0.5


class UserBehaviour(NamedTuple):
    """How the user treats their robot.

    Attributes:
      wander: the user wanders (random waypoints; in a shop, random nodes of the aisle graph
        with `Walks` stops) instead of shopping (shelf spot to shelf spot, leading the robot).
      robot_start_distance: the robot starts this far behind the user (`robot_start`).
      wait: ``(near, far)`` distances (m) between the user and the robot: beyond ``near`` the
        user slows down linearly, and at ``far`` they stand and wait for their robot, as the
        user of a following robot does; ``None``: the user ignores the robot.
      return_distance: beyond this distance (m) from the robot (with ``wait`` set) the user
        walks back toward it, at their preferred speed from half a metre further on: a user
        whose robot has lost them comes back into its sensors' range instead of waiting out of
        it. ``None``: they only wait.
    """

    robot_start_distance: float = 1.2
    wait: tuple | None = (3.0, 4.0)
    return_distance: float | None = 4.0
    wander: bool = False


class PedestrianConfig(NamedTuple):
    """The pedestrians' room and scenario, by concern.

    Attributes:
      room: (width along x, depth along y) of the room, centred at the origin (m).
      obstacles: [K, 3] furniture footprints (centre x, centre y, radius) people walk around
        (`sims.following.scene.pedestrian_config` fills them from the scene).
      distractors: number of active people besides the user (person 0).
      robot_radius: radius of the robot's disc for avoidance (m).
      boxes: [B, 4] solid axis-aligned blocks (centre x, centre y, half size x, half size y):
        shelves and counters people walk around.
      aisles: the shop's `sims.following.layout.AisleGraph`, or None (a room: everyone walks to
        random waypoints, `Walks`). With aisles everyone walks the graph (`Shopping`).
      forces: `SocialForces`. walks: `Walks`. shopping: `Shopping`. user: `UserBehaviour`.
      gait: `GaitParams`.
    """

    room: tuple = (10.0, 8.0)
    obstacles: tuple | Array = ()
    distractors: int = 4
    robot_radius: float = 0.3
    forces: SocialForces = SocialForces()
    walks: Walks = Walks()
    user: UserBehaviour = UserBehaviour()
    gait: GaitParams = GaitParams()
    boxes: tuple | Array = ()
    aisles: object = None
    shopping: Shopping = Shopping()


class PedestrianState(NamedTuple):
    """State of ``P`` people (person 0 is the user).

    Attributes:
      pos: [P, 2] positions (m); vel: [P, 2] velocities (m/s).
      heading: [P] walking directions (rad); phase: [P] gait phases in [0, 2 pi).
      mask: [P] bool, active people.
      goal: [P, 2] current waypoints; speed: [P] preferred speeds (m/s).
      stop_timer: [P] remaining stop time (s, > 0 while stopped).
      goal_timer: [P] time left to reach the waypoint before it is replaced (s).
      crossing: [P] bool, the current waypoint crosses the user's path.
      node: [P] int32, the aisle-graph node walked to (shop); target: [P] int32, the spot
        walked to; face: [P] the heading a person stopped at a shelf turns to.
    """

    pos: Array
    vel: Array
    heading: Array
    phase: Array
    mask: Array
    goal: Array
    speed: Array
    stop_timer: Array
    goal_timer: Array
    crossing: Array
    node: Array | None = None
    target: Array | None = None
    face: Array | None = None


_CANDIDATES = 8  # waypoint candidates drawn per person and step (first free one is taken)
_CELL = 1.2  # grid cell (m) for the initial placement


def _obstacles(cfg, dtype):
    obs = jnp.asarray(cfg.obstacles, dtype)
    return obs.reshape(-1, 3)


def _unit(v, eps=1e-9):
    n = jnp.sqrt(jnp.sum(v * v, -1, keepdims=True) + eps)
    return v / n, n[..., 0]


def _boxes(cfg, dtype):
    return jnp.asarray(cfg.boxes, dtype).reshape(-1, 4)


def _free(points, cfg, clearance, dtype):
    """[..., 2] -> bool: outside every footprint and block by ``clearance`` and inside the
    walls."""
    obs = _obstacles(cfg, dtype)
    hw, hh = 0.5 * cfg.room[0] - cfg.forces.wall_margin, 0.5 * cfg.room[1] - cfg.forces.wall_margin
    inside = (jnp.abs(points[..., 0]) <= hw) & (jnp.abs(points[..., 1]) <= hh)
    if obs.shape[0]:
        d = jnp.linalg.norm(points[..., None, :] - obs[:, :2], axis=-1) - obs[:, 2]
        inside = inside & jnp.all(d > clearance, -1)
    boxes = _boxes(cfg, dtype)
    if boxes.shape[0]:
        off = jnp.abs(points[..., None, :] - boxes[:, :2]) - boxes[:, 2:] - clearance
        inside = inside & ~jnp.any(jnp.all(off < 0.0, -1), -1)
    return inside


def _nearest_on_boxes(pos, boxes):
    """[P, B, 2] the point of every block nearest to every position [P, 2]."""
    lo, hi = boxes[:, :2] - boxes[:, 2:], boxes[:, :2] + boxes[:, 2:]
    return jnp.clip(pos[:, None, :], lo, hi)


def _push_out_boxes(pos, boxes, reach):
    """Move positions [P, 2] out of the blocks grown by ``reach``: along the normal of the
    nearest face (through it when the position is inside the block)."""
    off = pos[:, None, :] - boxes[:, :2]                                     # [P, B, 2]
    depth = boxes[:, 2:] + reach - jnp.abs(off)                             # > 0 on both: inside
    inside = jnp.all(depth > 0.0, -1)
    q = _nearest_on_boxes(pos, boxes)
    n, d = _unit(pos[:, None, :] - q)
    corner = inside & (d > 0.0) & jnp.all(jnp.abs(off) > boxes[:, 2:], -1)
    # Near a corner, push radially from the corner; elsewhere through the nearest face.
    axis = jnp.argmin(depth, -1)
    face = jnp.where(jnp.arange(2) == axis[..., None], jnp.sign(off) * depth, 0.0)
    radial = n * jnp.maximum(reach - d, 0.0)[..., None]
    move = jnp.where(corner[..., None], radial, jnp.where(inside[..., None], face, 0.0))
    return pos + jnp.sum(move, 1)


def _sample_goals(u, cfg, pos, user_pos, user_dir, dtype):
    """New waypoint of every person from uniforms ``u`` [P, 2 C + 2]: ([P, 2], [P] crossing)."""
    P = pos.shape[0]
    hw, hh = 0.5 * cfg.room[0] - cfg.forces.wall_margin, 0.5 * cfg.room[1] - cfg.forces.wall_margin
    cand = (2.0 * u[:, :2 * _CANDIDATES] - 1.0).reshape(P, _CANDIDATES, 2)
    cand = cand * jnp.asarray([hw, hh], dtype)
    clearance = cfg.forces.person_radius + 0.3
    ok = _free(cand, cfg, clearance, dtype)
    far = jnp.linalg.norm(cand - pos[:, None], axis=-1) >= cfg.walks.user_min_leg
    ok = ok & jnp.where((jnp.arange(P) == 0)[:, None], far, True)
    first = jnp.argmax(ok, -1)
    goal = jnp.sum(jnp.where((jnp.arange(_CANDIDATES) == first[:, None])[..., None], cand, 0.0), 1)
    # Crossing: mirror the distractor's position through a point 1-3 m ahead of the user.
    ahead = user_pos + user_dir * (1.0 + 2.0 * u[:, -1:])
    mirror = 2.0 * ahead - pos
    cross = ((u[:, -2] < cfg.walks.cross_prob) & (jnp.arange(P) > 0)
             & _free(mirror, cfg, clearance, dtype))
    return jnp.where(cross[:, None], mirror, goal), cross


_GOAL_UNIFORMS = 2 * _CANDIDATES + 2


def cadence(speed: Array, params: GaitParams = GaitParams()) -> Array:
    """Steps per second at a walking speed: :math:`f = f_0 + f_1 |v|` (1.96 Hz at 1.2 m/s)."""
    return params.cadence_offset + params.cadence_slope * speed


def init(key: Array, cfg: PedestrianConfig, num_people: int,
         dtype=jnp.float32) -> PedestrianState:
    """Place the user and the distractors in free cells of the room, at rest.

    The user starts at least ``robot_start_distance + 1`` m from the walls, facing the room's
    centre, with free space behind for the robot (`robot_start`); the distractors start in
    distinct free grid cells (1.2 m) away from both. Inactive slots are masked out.

    Args:
      key: PRNG key.
      cfg: `PedestrianConfig` (``1 + cfg.distractors <= num_people`` is required).
      num_people: capacity ``P`` (static).
      dtype: float dtype of the state.

    Returns:
      `PedestrianState` with [P]-sized leaves.

    Example:
      >>> state = init(jax.random.PRNGKey(0), PedestrianConfig(), 8)
    """
    P = int(num_people)
    if P < 1:
        raise ValueError(f"num_people must be at least 1; got {P}")
    if _checks.is_concrete(cfg.distractors):
        active = 1 + int(cfg.distractors)
        if int(cfg.distractors) < 0 or active > P:
            raise ValueError(f"{active} people (the user + {int(cfg.distractors)} distractors) "
                             f"exceed the capacity of {P} people")
    obs = np.shape(cfg.obstacles)
    if obs not in ((0,),) and (len(obs) != 2 or obs[1] != 3):
        raise ValueError(f"cfg.obstacles must have shape [K, 3]; got {list(obs)}")
    _checks.check_finite("cfg.obstacles", cfg.obstacles)
    lo, hi = cfg.walks.speed_range
    if _checks.is_concrete(lo) and not 0.0 < float(lo) <= float(hi) <= float(cfg.forces.max_speed):
        raise ValueError(f"walks.speed_range must satisfy 0 < lo <= hi <= max_speed; got "
                         f"{tuple(cfg.walks.speed_range)} with forces.max_speed "
                         f"{cfg.forces.max_speed}")
    if cfg.user.wait is not None and all(_checks.is_concrete(x) for x in cfg.user.wait):
        near_w, far_w = (float(x) for x in cfg.user.wait)
        if not 0.0 <= near_w < far_w:
            raise ValueError(f"user.wait must be (near, far) with 0 <= near < far; got "
                             f"{tuple(cfg.user.wait)}")
        ret = cfg.user.return_distance
        if ret is not None and _checks.is_concrete(ret) and not float(ret) >= far_w:
            raise ValueError(f"user.return_distance ({ret}) must be at least user.wait's far "
                             f"distance ({far_w}): the user waits before walking back")
    if cfg.aisles is not None:
        return _init_shop(key, cfg, P, dtype)
    W, H = (float(x) for x in cfg.room)
    wall = cfg.forces.wall_margin
    nx, ny = int((W - 2 * wall) // _CELL), int((H - 2 * wall) // _CELL)
    if W <= 0 or H <= 0 or nx * ny < P + 3:
        raise ValueError(f"room {cfg.room} is too small for {P} people")
    gx = (jnp.arange(nx, dtype=dtype) - 0.5 * (nx - 1)) * _CELL
    gy = (jnp.arange(ny, dtype=dtype) - 0.5 * (ny - 1)) * _CELL
    cells = jnp.stack(jnp.meshgrid(gx, gy, indexing="ij"), -1).reshape(-1, 2)
    n = cells.shape[0]
    u = jax.random.uniform(key, (2 * n + P * (4 + _GOAL_UNIFORMS),), dtype)
    u_user, u_cells, u = u[:n], u[n:2 * n], u[2 * n:].reshape(P, 4 + _GOAL_UNIFORMS)
    free = _free(cells, cfg, cfg.forces.person_radius + 0.2, dtype)
    # The user: well inside the room, facing the centre, the robot's start free behind.
    margin = cfg.user.robot_start_distance + 1.0
    inner = ((jnp.abs(cells[:, 0]) <= 0.5 * W - margin) & (jnp.abs(cells[:, 1]) <= 0.5 * H - margin)
             & (jnp.linalg.norm(cells, axis=-1) > 0.5))
    facing = _unit(-cells)[0]
    behind = cells - cfg.user.robot_start_distance * facing
    user_ok = free & inner & _free(behind, cfg, cfg.robot_radius + 0.1, dtype)
    user_score = jnp.where(user_ok, u_user, -1.0)
    iu = jnp.argmax(user_score)
    user_pos, user_dir = cells[iu], facing[iu]
    robot = behind[iu]
    away = ((jnp.linalg.norm(cells - user_pos, axis=-1) > 1.5)
            & (jnp.linalg.norm(cells - robot, axis=-1) > 1.5))
    score = jnp.where(free & away, u_cells, -1.0)
    others = jax.lax.top_k(score, P - 1)[1] if P > 1 else jnp.zeros((0,), jnp.int32)
    jitter = 0.3 * (u[1:, :2] - 0.5)
    pos = jnp.concatenate([user_pos[None], cells[others] + jitter], 0)
    heading = jnp.concatenate([jnp.arctan2(user_dir[1], user_dir[0])[None],
                               jnp.pi * (2.0 * u[1:, 2] - 1.0)])
    mask = jnp.arange(P) <= cfg.distractors
    speed = lo + (hi - lo) * u[:, 3]
    goal, crossing = _sample_goals(u[:, 4:], cfg, pos, user_pos, user_dir, dtype)
    zeros = jnp.zeros((P,), dtype)
    state = PedestrianState(pos=pos, vel=jnp.zeros((P, 2), dtype), heading=heading.astype(dtype),
                            phase=zeros, mask=mask, goal=goal, speed=speed, stop_timer=zeros,
                            goal_timer=_goal_time(goal, pos, speed), crossing=crossing)
    return _park(state)


def _graph(cfg, dtype):
    g = cfg.aisles
    return (jnp.asarray(g.nodes, dtype), jnp.asarray(g.next_hop, jnp.int32),
            jnp.asarray(g.pair, jnp.int32), jnp.asarray(g.facing, dtype),
            np.flatnonzero(np.asarray(g.spot)))


def _init_shop(key, cfg, P, dtype):
    """Shoppers on the aisle graph, at rest: the user at a route node with the robot's start
    free behind them (facing the first hop toward their first spot), the distractors at other
    route nodes at least 1.5 m from both, each with a random first spot."""
    nodes, next_hop, _, _, spots = _graph(cfg, dtype)
    route = np.flatnonzero(~np.asarray(cfg.aisles.spot))
    N = nodes.shape[0]
    if route.size < P + 2:
        raise ValueError(f"the aisle graph has {route.size} route nodes for {P} people")
    k_user, k_other, k_target, k_speed, k_head = jax.random.split(key, 5)
    targets = jnp.asarray(spots)[jax.random.randint(k_target, (max(N, P),), 0, spots.size)]
    # The user: any route node whose first hop points away from the robot's start.
    cand = jnp.asarray(route)
    first = nodes[next_hop[cand, targets[cand]]] - nodes[cand]
    facing = _unit(first)[0]
    behind = nodes[cand] - cfg.user.robot_start_distance * facing
    ok = (_free(behind, cfg, cfg.robot_radius + 0.1, dtype)
          & (jnp.linalg.norm(first, axis=-1) > 0.1))
    iu = cand[jnp.argmax(jnp.where(ok, jax.random.uniform(k_user, (cand.size,), dtype), -1.0))]
    user_pos, user_dir, robot = nodes[iu], facing[jnp.argmax(cand == iu)], behind[
        jnp.argmax(cand == iu)]
    away = ((jnp.linalg.norm(nodes[cand] - user_pos, axis=-1) > 1.5)
            & (jnp.linalg.norm(nodes[cand] - robot, axis=-1) > 1.5))
    score = jnp.where(away, jax.random.uniform(k_other, (cand.size,), dtype), -1.0)
    others = cand[jax.lax.top_k(score, P - 1)[1]] if P > 1 else jnp.zeros((0,), jnp.int32)
    node = jnp.concatenate([iu[None], others]).astype(jnp.int32)
    pos = nodes[node]
    target = targets[node].astype(jnp.int32)
    heading = jnp.concatenate([jnp.arctan2(user_dir[1], user_dir[0])[None],
                               jax.random.uniform(k_head, (P - 1,), dtype, -jnp.pi, jnp.pi)])
    lo, hi = cfg.shopping.speed_range
    speed = lo + (hi - lo) * jax.random.uniform(k_speed, (P,), dtype)
    mask = jnp.arange(P) <= cfg.distractors
    zeros = jnp.zeros((P,), dtype)
    state = PedestrianState(pos=pos, vel=jnp.zeros((P, 2), dtype), heading=heading.astype(dtype),
                            phase=zeros, mask=mask, goal=pos, speed=speed, stop_timer=zeros,
                            goal_timer=jnp.full((P,), 5.0, dtype),
                            crossing=jnp.zeros((P,), bool), node=node, target=target,
                            face=heading.astype(dtype))
    return _park(state)


def _shop_plan(u, cfg, state, robot_xy, dt):
    """Waypoints and stops of shoppers on the aisle graph (`Shopping`): at an intermediate
    node, the next hop toward the target spot; at the target spot, a stop facing the shelf and
    a new target (the neighbouring spot with ``side_step_prob``, else a random spot; for a
    wandering user, any node). Returns ``(goal, node, target, face, speed, stop_timer,
    goal_timer)``."""
    dtype = state.pos.dtype
    P = state.pos.shape[0]
    sh, wk = cfg.shopping, cfg.walks
    nodes, next_hop, pair, facing, spots = _graph(cfg, dtype)
    pos, node, target = state.pos, state.node, state.target
    u_stop, u_rand, u_len, u_speed, u_spot, u_side = (u[:, i] for i in range(6))
    walking = state.stop_timer <= 0.0
    d = jnp.linalg.norm(nodes[node] - pos, axis=-1)
    at_target = node == target
    # A route node under the robot counts as passed (the walker goes round the robot instead).
    under_robot = (jnp.linalg.norm(nodes[node] - robot_xy, axis=-1)
                   < cfg.robot_radius + cfg.forces.person_radius + 0.1) & ~at_target
    reached = walking & state.mask & ((d < jnp.where(at_target, sh.arrive_tolerance,
                                                     sh.pass_tolerance)) | under_robot)
    arrived = reached & at_target
    user = jnp.arange(P) == 0
    wander = user & cfg.user.wander
    N, S = nodes.shape[0], spots.size
    any_node = jnp.minimum((u_spot * N).astype(jnp.int32), N - 1)
    random_spot = jnp.asarray(spots)[jnp.minimum((u_spot * S).astype(jnp.int32), S - 1)]
    # The user's next spot along the tour: 1..max_skip on, or back now and then.
    tour, rank = jnp.asarray(cfg.aisles.tour), jnp.asarray(cfg.aisles.rank)
    skip = 1 + jnp.minimum((u_spot * sh.max_skip).astype(jnp.int32), sh.max_skip - 1)
    skip = jnp.where(u_stop < sh.turn_back_prob, -skip, skip)
    on_tour = tour[jnp.mod(jnp.maximum(rank[target], 0) + skip, S)]
    new_target = jnp.where(wander, any_node,
                           jnp.where(u_side < sh.side_step_prob, pair[target],
                                     jnp.where(user, on_tour, random_spot)))
    target = jnp.where(arrived, new_target, target).astype(jnp.int32)
    # A stop at the shelf (a wandering user stops as `Walks` says), or a short one anywhere.
    s0, s1 = jnp.where(wander, wk.stop_duration[0], sh.stop_duration[0]), jnp.where(
        wander, wk.stop_duration[1], sh.stop_duration[1])
    shelf_stop = arrived & (~wander | (u_stop < wk.stop_prob))
    aisle_stop = walking & ~arrived & (u_rand < jnp.where(wander, wk.stop_rate, sh.stop_rate)
                                       * dt)
    a0, a1 = wk.stop_duration
    duration = jnp.where(shelf_stop, s0 + (s1 - s0) * u_len, a0 + (a1 - a0) * u_len)
    stop_timer = jnp.where(shelf_stop | aisle_stop, duration, state.stop_timer - dt)
    face = jnp.where(shelf_stop & ~wander, facing[node], state.face)
    lo, hi = sh.speed_range
    speed = jnp.where(arrived, lo + (hi - lo) * u_speed, state.speed)
    node = jnp.where(reached, next_hop[node, target], node)
    # A waypoint that takes too long is given up: re-route from the nearest node.
    stuck = state.mask & (state.goal_timer <= 0.0)
    nearest = jnp.argmin(jnp.linalg.norm(pos[:, None] - nodes[None], axis=-1), -1)
    node = jnp.where(stuck, nearest, node).astype(jnp.int32)
    goal = nodes[node]
    fresh = reached | stuck
    goal_timer = jnp.where(fresh, _goal_time(goal, pos, speed),
                           jnp.where(stop_timer > 0.0, state.goal_timer, state.goal_timer - dt))
    return goal, node, target, face, speed, stop_timer, goal_timer


def _pass_robot(cfg, pos, to_goal, dist, robot_xy, dtype):
    """Walking directions [P, 2] that pass beside the robot when it stands in the way (within
    2 m, less than 60 deg off the way to the waypoint, and nearer than it): toward a point
    beside the robot, on the walker's side of it if that is free, else on the other. Returns
    ``(directions, passing [P])``."""
    sf = cfg.forces
    n_r, d_r = _unit(robot_xy - pos)
    ahead = (jnp.sum(n_r * to_goal, -1) > 0.5) & (d_r < 2.0) & (d_r < dist + 0.5)
    right = jnp.stack([to_goal[:, 1], -to_goal[:, 0]], -1)
    # The side the walker is already on (right when straight behind), unless it is blocked.
    side = jnp.where(jnp.sum((pos - robot_xy) * right, -1) >= 0.0, 1.0, -1.0)[:, None]
    clear = cfg.robot_radius + sf.person_radius + 0.05
    via = robot_xy + clear * side * right
    via = jnp.where(_free(via, cfg, sf.person_radius, dtype)[:, None], via,
                    robot_xy - clear * side * right)
    passing = ahead | (d_r < clear + 0.1)
    return jnp.where(ahead[:, None], _unit(via - pos)[0], to_goal), passing


def _goal_time(goal, pos, speed):
    return 2.0 * jnp.linalg.norm(goal - pos, axis=-1) / speed + 5.0


def _park(state):
    """Inactive people: still, at their slot's position (their legs are parked by the gait)."""
    m = state.mask
    return state._replace(vel=jnp.where(m[:, None], state.vel, 0.0),
                          stop_timer=jnp.where(m, state.stop_timer, 0.0),
                          crossing=state.crossing & m)


def robot_start(cfg: PedestrianConfig, state: PedestrianState) -> Array:
    """Robot pose [3] (x, y, theta) ``robot_start_distance`` behind the user, facing them.

    Example:
      >>> pose = robot_start(cfg, init(key, cfg, 8))
    """
    h = state.heading[0]
    e = jnp.stack([jnp.cos(h), jnp.sin(h)])
    return jnp.concatenate([state.pos[0] - cfg.user.robot_start_distance * e, h[None]])


def _repulsion(pos, others, heading, strength, range_, reach, anisotropy, keep_right, weight):
    """Social force on every person [P, 2] from points ``others`` [..., Q, 2].

    ``reach`` [Q] or scalar is the contact distance; ``weight`` [P, Q] masks pairs.
    """
    n, d = _unit(pos[:, None, :] - others)
    e = jnp.stack([jnp.cos(heading), jnp.sin(heading)], -1)
    right = jnp.stack([e[:, 1], -e[:, 0]], -1)
    cos_phi = -jnp.sum(n * e[:, None, :], -1)
    w = anisotropy + (1.0 - anisotropy) * 0.5 * (1.0 + cos_phi)
    mag = strength * jnp.exp(jnp.minimum((reach - d) / range_, 10.0)) * w * weight
    side = keep_right * jnp.maximum(cos_phi, 0.0)
    return jnp.sum(mag[..., None] * (n + side[..., None] * right[:, None, :]), 1)


def _push_out(pos, centres, reach, active):
    """Move points out of discs (centres [Q, 2], reach [Q]) they entered; ``active`` [P, Q]."""
    n, d = _unit(pos[:, None, :] - centres)
    depth = jnp.where(active, jnp.maximum(reach - d, 0.0), 0.0)
    return pos + jnp.sum(depth[..., None] * n, 1)


def step(key: Array, cfg: PedestrianConfig, state: PedestrianState, robot_pose: Array,
         dt=0.1) -> PedestrianState:
    """Advance every active person by ``dt`` (social forces, waypoints, stops, gait phase).

    Args:
      key: PRNG key.
      cfg: `PedestrianConfig`.
      state: `PedestrianState` with ``P`` people.
      robot_pose: [3] robot (x, y, theta); people avoid its disc of ``cfg.robot_radius``.
      dt: time step (s), e.g. the 0.1 s control period.

    Returns:
      The new `PedestrianState`.

    Example:
      >>> state = step(jax.random.PRNGKey(1), cfg, state, jnp.zeros(3), 0.1)
    """
    _checks.check_shape("robot_pose", robot_pose, (3,), "x, y, theta")
    dtype = state.pos.dtype
    P = state.pos.shape[0]
    g, sf = cfg.gait, cfg.forces
    u = jax.random.uniform(key, (P, 4 + _GOAL_UNIFORMS), dtype)
    u_stop, u_rand, u_len, u_speed = u[:, 0], u[:, 1], u[:, 2], u[:, 3]
    robot_xy = jnp.asarray(robot_pose, dtype)[:2]
    pos, vel, mask = state.pos, state.vel, state.mask

    # --- waypoints and stops ---------------------------------------------------------------
    node, target, face = state.node, state.target, state.face
    if cfg.aisles is not None:
        goal, node, target, face, speed, stop_timer, goal_timer = _shop_plan(
            u[:, 4:], cfg, state, robot_xy, dt)
        crossing = state.crossing
    else:
        arrived = jnp.linalg.norm(state.goal - pos, axis=-1) < cfg.walks.waypoint_tolerance
        replan = (arrived | (state.goal_timer <= 0.0)) & mask
        user_dir = jnp.where(jnp.linalg.norm(vel[0]) > g.stand_speed, _unit(vel[0])[0],
                             jnp.stack([jnp.cos(state.heading[0]), jnp.sin(state.heading[0])]))
        new_goal, new_cross = _sample_goals(u[:, 4:], cfg, pos, pos[0], user_dir, dtype)
        goal = jnp.where(replan[:, None], new_goal, state.goal)
        crossing = jnp.where(replan, new_cross, state.crossing)
        lo, hi = cfg.walks.speed_range
        speed = jnp.where(replan, lo + (hi - lo) * u_speed,
                          state.speed)
        walking = state.stop_timer <= 0.0
        start_stop = walking & ((arrived & (u_stop < cfg.walks.stop_prob))
                                | (u_rand < cfg.walks.stop_rate * dt))
        d0, d1 = cfg.walks.stop_duration
        duration = d0 + (d1 - d0) * u_len
        stop_timer = jnp.where(start_stop, duration, state.stop_timer - dt)
        goal_timer = jnp.where(replan, _goal_time(goal, pos, speed),
                               jnp.where(stop_timer > 0.0, state.goal_timer,
                                         state.goal_timer - dt))

    # --- social forces ---------------------------------------------------------------------
    to_goal, dist = _unit(goal - pos)
    pace = speed
    near_robot = jnp.ones((P, 1), dtype)
    if cfg.aisles is not None:
        to_goal, passing = _pass_robot(cfg, pos, to_goal, dist, robot_xy, dtype)
        # Someone squeezing past the cart in an aisle keeps close to it.
        near_robot = jnp.where(passing, 0.3, 1.0)[:, None].astype(dtype)
        # Shoppers slow down over the last half metre to the spot they stop at.
        pace = speed * jnp.where(node == target, jnp.minimum(1.0, dist / 0.5), 1.0)
    preferred = jnp.where((stop_timer > 0.0)[:, None], 0.0, pace[:, None] * to_goal)
    if cfg.user.wait is not None:
        near_w, far_w = cfg.user.wait
        gap = jnp.linalg.norm(pos[0] - robot_xy)
        slow = jnp.clip((far_w - gap) / (far_w - near_w), 0.0, 1.0)
        preferred = preferred.at[0].multiply(slow)
        if cfg.user.return_distance is not None:
            back = jnp.clip((gap - cfg.user.return_distance) / 0.5, 0.0, 1.0)
            to_robot, _ = _unit(robot_xy - pos[0])
            preferred = preferred.at[0].add(back * speed[0] * to_robot)
    force = (preferred - vel) / sf.relax_time
    pair = mask[:, None] & mask[None, :] & ~jnp.eye(P, dtype=bool)
    force += _repulsion(pos, pos[None], state.heading, sf.social_strength, sf.social_range,
                        2.0 * sf.person_radius, sf.anisotropy, sf.keep_right, pair)
    force += _repulsion(pos, robot_xy[None, None], state.heading, sf.robot_strength,
                        sf.robot_range, sf.person_radius + cfg.robot_radius, sf.anisotropy,
                        sf.keep_right, near_robot)
    obs = _obstacles(cfg, dtype)
    if obs.shape[0]:
        force += _repulsion(pos, obs[None, :, :2], state.heading, sf.social_strength,
                            sf.social_range, obs[:, 2] + sf.person_radius, sf.anisotropy,
                            sf.keep_right, jnp.ones((P, obs.shape[0]), dtype))
    boxes = _boxes(cfg, dtype)
    if boxes.shape[0]:
        # Blocks push like walls, from their nearest points.
        force += _repulsion(pos, _nearest_on_boxes(pos, boxes), state.heading, sf.wall_strength,
                            sf.wall_range, sf.person_radius, 1.0, 0.0,
                            jnp.ones((P, boxes.shape[0]), dtype))
    half = jnp.asarray([0.5 * cfg.room[0], 0.5 * cfg.room[1]], dtype)
    near = jnp.exp(jnp.minimum((sf.person_radius - (half - pos)) / sf.wall_range, 10.0))
    far = jnp.exp(jnp.minimum((sf.person_radius - (half + pos)) / sf.wall_range, 10.0))
    force += sf.wall_strength * (far - near)

    new_vel = vel + dt * force
    _, v_norm = _unit(new_vel)
    new_vel = new_vel * jnp.minimum(1.0, sf.max_speed / v_norm)[:, None]
    new_pos = pos + dt * new_vel

    # --- hard constraints: separation, furniture, robot, walls -----------------------------
    for _ in range(2):
        n, d = _unit(new_pos[:, None, :] - new_pos[None])
        depth = jnp.where(pair, jnp.maximum(sf.min_separation - d, 0.0), 0.0)
        new_pos = new_pos + 0.5 * jnp.sum(depth[..., None] * n, 1)
        if obs.shape[0]:
            new_pos = _push_out(new_pos, obs[:, :2], obs[:, 2] + sf.person_radius,
                                jnp.ones((P, obs.shape[0]), bool))
        if boxes.shape[0]:
            new_pos = _push_out_boxes(new_pos, boxes, sf.person_radius)
        new_pos = _push_out(new_pos, robot_xy[None], sf.person_radius + cfg.robot_radius,
                            jnp.ones((P, 1), bool))
        new_pos = jnp.clip(new_pos, -half + sf.wall_margin, half - sf.wall_margin)
    new_pos = jnp.where(mask[:, None], new_pos, pos)
    new_vel = (new_pos - pos) / dt
    _, v_norm = _unit(new_vel)
    new_vel = new_vel * jnp.minimum(1.0, sf.max_speed / v_norm)[:, None]

    # --- heading and gait phase ------------------------------------------------------------
    moving = v_norm > g.stand_speed
    turn = wrap(jnp.arctan2(new_vel[:, 1], new_vel[:, 0]) - state.heading)
    max_turn = sf.max_turn_rate * dt
    turning = moving
    if cfg.aisles is not None:
        # Stopped at a shelf, a shopper turns to face it.
        turn = jnp.where(moving, turn, wrap(face - state.heading))
        turning = moving | (stop_timer > 0.0)
    heading = wrap(state.heading + jnp.where(turning, jnp.clip(turn, -max_turn, max_turn), 0.0))
    s = jnp.minimum(v_norm, sf.max_speed)
    phase = jnp.mod(state.phase + jnp.where(moving, jnp.pi * cadence(s, g) * dt, 0.0),
                    2.0 * jnp.pi)
    new = PedestrianState(pos=new_pos.astype(dtype), vel=new_vel.astype(dtype),
                          heading=heading.astype(dtype), phase=phase.astype(dtype), mask=mask,
                          goal=goal.astype(dtype), speed=speed.astype(dtype),
                          stop_timer=jnp.maximum(stop_timer, 0.0).astype(dtype),
                          goal_timer=goal_timer.astype(dtype), crossing=crossing & mask,
                          node=node, target=target,
                          face=None if face is None else face.astype(dtype))
    return _park(new)


def rollout(key: Array, cfg: PedestrianConfig, state: PedestrianState, robot_pose: Array,
            num_steps: int, dt=0.1) -> tuple[PedestrianState, PedestrianState]:
    """`step` under ``lax.scan`` with a still robot: ``(final, states [T, ...])``.

    Example:
      >>> final, traj = rollout(key, cfg, init(key, cfg, 8), jnp.array([0.0, 0.0, 0.0]), 100)
    """
    def body(st, k):
        st = step(k, cfg, st, robot_pose, dt)
        return st, st

    return jax.lax.scan(body, state, jax.random.split(key, num_steps))


def _speed_and_frame(state, params):
    speed = jnp.linalg.norm(state.vel, axis=-1)
    e = jnp.stack([jnp.cos(state.heading), jnp.sin(state.heading)], -1)
    left = jnp.stack([-e[..., 1], e[..., 0]], -1)
    return speed, e, left


def torso_position(state: PedestrianState, params: GaitParams = GaitParams()) -> Array:
    """Torso centre [P, 3] (x, y on the sway, z mid-torso); inactive people parked below.

    The sway is :math:`-a \\min(1, |v| / v_s) \\cos\\phi` along the person's left (toward the
    stance foot).
    """
    speed, _, left = _speed_and_frame(state, params)
    amp = params.sway * jnp.minimum(1.0, speed / params.sway_speed)
    amp = jnp.where(speed > params.stand_speed, amp, 0.0)
    xy = state.pos - (amp * jnp.cos(state.phase))[:, None] * left
    z = jnp.where(state.mask, 0.5 * (params.torso_bottom + params.torso_top), PARK_DEPTH)
    return jnp.concatenate([xy, z[:, None].astype(xy.dtype)], -1)


def leg_capsules(state: PedestrianState,
                 params: GaitParams = GaitParams()) -> tuple[Array, Array, Array]:
    """World-frame leg capsules of every person (leg 0 left, leg 1 right).

    The feet are :math:`\\pm` ``hip_width``/2 sideways and :math:`\\pm (L/2)\\sin\\phi` along the
    heading (step length :math:`L = |v|/f`); each capsule runs from the foot centre (``z`` =
    leg radius) to the hip, right above the foot's sideways offset on the body, at the height
    that keeps the capsule's length ``leg_length``. Inactive people get radius 0 and are parked
    at ``z`` = `PARK_DEPTH`.

    Args:
      state: `PedestrianState` with ``P`` people.
      params: `GaitParams`.

    Returns:
      ``(p0 [P, 2, 3] feet, p1 [P, 2, 3] hips, radius [P, 2])``.

    Example:
      >>> p0, p1, r = leg_capsules(state)
    """
    speed, e, left = _speed_and_frame(state, params)
    walking = speed > params.stand_speed
    step_len = jnp.where(walking, speed / cadence(speed, params), 0.0)
    fwd = 0.5 * step_len * jnp.sin(state.phase)
    side = jnp.asarray([0.5, -0.5], state.pos.dtype) * params.hip_width
    sign = jnp.asarray([1.0, -1.0], state.pos.dtype)
    hips = state.pos[:, None, :] + side[None, :, None] * left[:, None, :]
    feet = hips + (sign[None, :] * fwd[:, None])[..., None] * e[:, None, :]
    r = params.leg_radius
    rise = jnp.sqrt(jnp.maximum(params.leg_length ** 2 - fwd ** 2, 0.0))
    park = jnp.where(state.mask, 0.0, PARK_DEPTH)[:, None]
    z0 = jnp.broadcast_to(r + park, (state.pos.shape[0], 2))
    z1 = z0 + rise[:, None]
    p0 = jnp.concatenate([feet, z0[..., None]], -1)
    p1 = jnp.concatenate([hips, z1[..., None]], -1)
    radius = jnp.where(state.mask[:, None], jnp.asarray(r, state.pos.dtype), 0.0)
    return p0, p1, jnp.broadcast_to(radius, (state.pos.shape[0], 2))
