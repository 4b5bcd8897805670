r"""One closed-loop episode of the service robot in the flat (seeds 002 and 003).

Each 10 Hz frame is five stages:

1. **world step** (`sims.service.people.step`, then MJX physics for the robot's last command);
2. **sense**: four ceiling cameras (`jaxtrack.perception.ceiling_camera`, seed 003's 0.1 m),
   and the robot's laser legs (0.2 m) and RGB-D people (0.3 m) from the person-following scene's
   sensors (`sims.following.world.observe`, `jaxtrack.perception.sensing.sense`);
3. **estimate**:
   - navigation experiments: a KF + NN-JPDA tracker with one update per sensor per scan
     (`TrackerConfig(sensor_update="sequential")`) over the sensors of ``config.perception``
     (map frame; the robot is localised in its map), then each track's status and heading
     (`jaxtrack.tracking.status`: walking above 0.1 m/s, seated in the couch area, hand-over in
     the hand-over area);
   - ``approach``: seed 002's 6-state laser + odometry Kalman filter of the person in the robot's
     odometry frame with the adaptive AR heading filter (`jaxtrack.tracking.user.robot_frame_kf`);
4. **behave**:
   - navigation: the person costmap (`jaxtrack.control.costmap.build`: standing, walking,
     seated, hand-over costs; seated people attend the TV, and the zone between them is lethal;
     people facing each other interact), inflated by the robot's radius, over the static layer
     of the flat; the cost-to-go to the goal, solved in full every ``replan_every`` frames
     (`jaxtrack.control.grid_planner.distance_field`) and refined by a few Bellman rounds from
     the last frame's at the frames between (`grid_planner.refine`), and the path down it,
     followed by pure pursuit. In ``handover`` the goal is the point 1 m in
     front of the tracked person in the hand-over area, and the robot turns to face them there;
   - ``approach``: gradient following of seed 002's person-interest potential field
     (`jaxtrack.control.potential_field.approach_velocity`) with PI fixed (``config.interest``)
     or estimated from the person's motion (`jaxtrack.control.person_interest`);
5. **record** (world frame): the `Frame`.

Metrics (`summarize`, per episode): success, time to goal, path length, the minimum distance to
each person and the time inside each of Hall's zones (intimate 0.45 m, personal 1.2 m; distances
from a person's centre to the robot's body, its 0.3 m disc), and the rule violations:
``right_pass`` (``overtake``: the robot passed the walking person on their right),
``tv_crossing`` (the robot's body touched the segment between a seated person and the TV),
``intimate`` (any frame inside anyone's intimate zone); for ``handover`` and ``approach`` the
final pose relative to the person and ``heading_error``, the mean absolute error of the
estimated heading of the task's person after the first ``settle`` seconds, and
``person_lost``, that person's position estimate was more than 1 m off at some frame after
those first seconds. The multi-target tracker's CLEAR MOT and position RMSE are
scored against every present person.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage

from jaxtrack import geometry
from jaxtrack import metrics as jmetrics
from jaxtrack.angles import wrap
from jaxtrack.control import costmap, grid_planner, pan_tilt, person_interest, potential_field
from jaxtrack.filters import heading as heading_filter
from jaxtrack.perception import ceiling_camera, sensing
from jaxtrack.tracking import status as status_mod
from jaxtrack.tracking import tracker, user
from sims.following import lidar
from sims.following import scene as scene_mod
from sims.following import world
from sims.service import experiments, flat
from sims.service import people as people_mod

Array = jax.Array

__all__ = ["ServiceConfig", "ServiceParams", "Frame", "PERCEPTION", "make_params",
           "make_rollout", "make_episode", "summarize", "static_cost", "cameras", "grid",
           "build_scene", "HEADING_FILTERS", "INTIMATE", "PERSONAL", "GOAL_TOLERANCE",
           "behind_the_scan", "corroborated", "CORROBORATION"]

PERCEPTION = ("all", "ceiling", "robot", "truth")
HEADING_FILTERS = ("ar", "windowed", "sustained")
HEADING_SEGMENTS = 3
"""Pieces of the sustained heading filter's window (`windowed_heading_step`'s segments)."""
INTIMATE, PERSONAL = costmap.INTIMATE, costmap.PERSONAL
GOAL_TOLERANCE = 0.25
MAP_FILTER_CELL = 0.1
"""Largest cell (m) of the static map that drops detections inside walls and furniture."""
COVERED_OCCLUSION = 0.25
"""Largest hidden fraction at which a ceiling camera is taken to see a robot detection's
place (the cameras' own detector misses people hidden by more than half)."""
MOT_THRESHOLD = 0.5
CORROBORATION = 0.9
"""Largest distance (m) of a laser detection that corroborates an RGB-D one
(``corroborated_births``): 0.95 of the difference of the two sensors' errors (0.3 and 0.2 m
per axis) falls within it."""
_SENSOR_GROUPS = {"all": (0, 1, 2), "ceiling": (0,), "robot": (1, 2)}
_CEILING, _RGBD, _LASER = 0, 1, 2
_CAMERA_SLOTS = 4
_LETHAL_PENALTY = 25.0
PATH_AHEAD = 2.5
"""Length (m) of the path extracted from the robot each frame: pure pursuit reads it only up to
the lookahead (0.6 m) beyond the point nearest the robot, so a longer path changes no command
while its descent costs a step per cell. A lookahead beyond about 2.3 m aims at its end."""
_STATURE, _BODY_RADIUS = 1.7, 0.25


def build_scene(num_people: int = experiments.NUM_PEOPLE):
    """The flat as a `sims.following.scene.Scene` (MJX robot, people as mocap bodies)."""
    return scene_mod.build(num_people=num_people, layout=flat.flat())


@dataclasses.dataclass(frozen=True, eq=False)
class ServiceConfig:
    """Static configuration of an episode.

    Attributes:
      scene: `build_scene()`.
      experiment: one of `sims.service.experiments.EXPERIMENTS`.
      perception: "all" (ceiling cameras, RGB-D and laser), "ceiling", "robot" (RGB-D and
        laser) or "truth" (the true people, for the floor of a metric): what the behaviour's
        tracker is fed.
      compare_sensors: also run trackers on the ceiling-only and robot-only detections (for the
        cooperative-perception comparison; the behaviour still uses ``perception``).
      interest: ``approach``: seed 002's person interest, fixed in [0, 1], or None to estimate it
        with the case base.
      duration: seconds; control_dt: frame period (s).
      cell: costmap cell (m; the detections' map filter keeps `MAP_FILTER_CELL` or finer,
        `free_space`). replan_every: frames between full solves of the distance field
        (`jaxtrack.control.grid_planner.distance_field`); sweeps: planner rounds at the frames
        between (`jaxtrack.control.grid_planner.refine`, from the last frame's field). Rounds
        lower stale values at once but raise them by about one cell's cost per round, so a
        field refined after people appeared across the way would lead the robot into them
        until the next full solve. The defaults (a full solve every 2 s, 5 rounds a frame)
        run 1.3x faster than every 0.5 s with 10 rounds, with the same success and rules
        (docs/service.md, "The planner's schedule"). solve_to_robot: a full solve stops once
        the robot's cell is exact (``distance_field``'s ``start_cell``), not when the whole
        flat is; False solves the whole flat (the same path, more rounds).
      settle: seconds the robot stands still at the start while its tracks confirm.
      still_at_end: seconds at the end of the episode in which nobody starts a step, so that
        a final pose is judged once the person has stood still that long (a step in the last
        second moves the person 0.3 m; no robot is back in place by the end).
      heading_slow: ``approach``: the AR heading filter's coefficient below 0.1 m/s (seed
        002's eq. 13 has 0.9, under which a still person's heading wanders with the noise of
        the estimated velocity; 1.0, the default here, holds it).
      heading_filter: ``approach`` and ``handover``: "ar", seed 002's eqs. 12-13 on the filter's
        velocity, or "windowed" (`jaxtrack.filters.heading.windowed_heading_step`): the same
        equations on the mean velocity over ``heading_window`` seconds, the heading held while the
        person has moved less than ``heading_min_distance`` (m) over it, so that a step backwards or
        sideways does not turn it; or "sustained": the windowed filter on the averages of
        `HEADING_SEGMENTS` pieces of the window, each move between them covering that share of the
        distance the same way, so that two steps in a row, a step after a walk, or a jump of the
        estimate do not turn it either; it turns towards the chord of the walk. ``handover``: "ar"
        takes the waiting person's heading from their track's velocity (the status's); "windowed"
        and "sustained" run that filter on every track's map positions and give its heading to the
        tracks with the hand-over status. None (the default): "sustained" for ``handover``,
        whose rule needs it (with "ar" it held in 95.7 % of 256 episodes), "ar" otherwise.
        ``heading_min_distance`` None: 0.5 m windowed, 0.8 m sustained.
      heading_frame: ``approach``, windowed or sustained filter: "odom", the person's positions
        in the odometry frame, as seed 002 (a held heading then drifts with the odometry's yaw
        as the robot turns), or "map": in the map frame the robot is localised in (as in
        the navigation experiments).
      pan: ``approach``: the RGB-D camera's pan unit (`jaxtrack.control.pan_tilt`), servoed to
        the estimated person, or None (the camera looks ahead).
      map_filter_estimator: ``approach``: the map filter (detections outside the flat or in
        walls and furniture dropped) also on the estimator's candidates.
      feed_forward: ``approach``: add the person's estimated velocity to the descent
        (`jaxtrack.control.potential_field.approach_velocity`'s ``person_vel``).
      reverse: ``approach``: the unicycle may drive backwards down the field, keeping its
        front (laser, RGB-D) towards the person (`approach_velocity`'s ``reverse``).
      settle_iterations: ``approach``: drive to where the field's gradient flow settles
        (`potential_field.settle_point`, this many iterations a frame; the approach gain then
        in 1/s) instead of along the gradient itself; 0: the gradient.
      park: ``approach``, with ``settle_iterations``: (arrive, leave) in m. Closer than
        arrive to the settled point the robot parks, standing and turning to face the person,
        until the point is more than leave away (the person moved); None: it never parks, and
        chases the point as the person estimate's noise moves it (turning to and fro, which
        drifts the odometry frame the person's heading is kept in).
      person_q: ``approach``: the person's acceleration variance in seed 002's filter
        (m^2/s^4; the following scene's 4 keeps up with a walking user's turns, but gives a
        still person a velocity estimate noisy enough to swing the heading filter).
      line_of_sight: drop the RGB-D detections more than 0.5 m beyond the laser's range on
        their bearing (behind a wall or a person, where the camera cannot see either).
      corroborated_births: with the ceiling cameras among a tracker's sensors, an RGB-D
        detection that no camera sees (`track`) starts a track only when a laser detection
        lies within `CORROBORATION` (`corroborated`). False: any robot detection there does;
        the RGB-D clutter in each room camera's blind corner then made false tracks that the
        cameras alone do not have.
      arc_check: seconds of the commanded arc checked against the people's inflated lethal
        cores each frame: if it enters one, the robot turns on the spot instead of driving
        (0: no check; navigation experiments).
      hold_radius: ``handover``: once the hand-over pose is reached, the robot stays there,
        turning to face the person, until the goal moves farther than this (m) away;
        ``GOAL_TOLERANCE`` or less: it chases the goal again whenever it leaves the tolerance.
      robot_radius: the body (m). safety_margin: people's costs are inflated by the body
        plus this (m): the grid's cells, the tracks' errors (about 0.08 m) and pure pursuit's
        cut corners would otherwise put the body a few centimetres inside a lethal core.
        v_max, omega_max: limits.
      sensors: the robot's `sims.following.world.SensorsConfig`.
      dtype: float dtype.
    """

    scene: scene_mod.Scene
    experiment: str = "avoid"
    perception: str = "all"
    compare_sensors: bool = False
    interest: float | None = 0.5
    duration: float = 60.0
    control_dt: float = 0.1
    cell: float = 0.1
    sweeps: int = 5
    replan_every: int = 20
    solve_to_robot: bool = True
    settle: float = 1.0
    still_at_end: float = 0.0
    heading_slow: float = 1.0
    heading_filter: str | None = None
    feed_forward: bool = False
    reverse: bool = False
    settle_iterations: int = 0
    park: tuple[float, float] | None = None
    map_filter_estimator: bool = False
    pan: pan_tilt.PanTiltConfig | None = None
    heading_window: float = 2.0
    heading_frame: str = "odom"
    heading_min_distance: float | None = None
    person_q: float = 0.5
    line_of_sight: bool = False
    corroborated_births: bool = True
    arc_check: float = 0.5
    hold_radius: float = 0.5
    robot_radius: float = 0.3
    safety_margin: float = 0.1
    v_max: float = 0.8
    omega_max: float = 1.2
    sensors: world.SensorsConfig = world.SensorsConfig()
    dtype: object = jnp.float32

    def __post_init__(self):
        if self.heading_filter is None:
            object.__setattr__(self, "heading_filter",
                               "sustained" if self.experiment == "handover" else "ar")
        if self.experiment not in experiments.EXPERIMENTS:
            raise ValueError(f"unknown experiment {self.experiment!r}; choose one of "
                             f"{experiments.EXPERIMENTS}")
        if self.perception not in PERCEPTION:
            raise ValueError(f"unknown perception {self.perception!r}; choose one of "
                             f"{PERCEPTION}")
        if self.interest is not None and not 0.0 <= float(self.interest) <= 1.0:
            raise ValueError(f"interest must be in [0, 1] or None; got {self.interest}")
        if not (math.isfinite(self.duration) and self.duration > 0):
            raise ValueError(f"duration must be > 0; got {self.duration}")
        if not 0.0 <= self.still_at_end <= self.duration:
            raise ValueError(f"still_at_end must be in [0, duration]; got {self.still_at_end}")
        if not 0.05 <= self.cell <= 0.5:
            raise ValueError(f"cell must be in [0.05, 0.5] m; got {self.cell}")
        if not (math.isfinite(self.arc_check) and 0 <= self.arc_check <= 5.0):
            raise ValueError(f"arc_check must be in [0, 5] s; got {self.arc_check}")
        if not (math.isfinite(self.hold_radius) and self.hold_radius >= 0):
            raise ValueError(f"hold_radius must be >= 0 m; got {self.hold_radius}")
        if self.replan_every < 1 or self.sweeps < 1:
            raise ValueError("replan_every and sweeps must be >= 1")
        if self.heading_filter not in HEADING_FILTERS:
            raise ValueError(f"unknown heading_filter {self.heading_filter!r}; choose one of "
                             f"{HEADING_FILTERS}")
        if self.heading_frame not in ("odom", "map"):
            raise ValueError(f"heading_frame must be 'odom' or 'map'; got "
                             f"{self.heading_frame!r}")
        if self.park is not None and not 0 < self.park[0] <= self.park[1]:
            raise ValueError(f"park must be (arrive, leave) with 0 < arrive <= leave; got "
                             f"{self.park}")
        if not (self.heading_window >= self.control_dt
                and (self.heading_min_distance is None or self.heading_min_distance >= 0)):
            raise ValueError("heading_window must be >= one frame and heading_min_distance "
                             ">= 0")

    @property
    def min_heading_distance(self) -> float:
        """``heading_min_distance``, or its default for ``heading_filter``."""
        if self.heading_min_distance is not None:
            return float(self.heading_min_distance)
        return 0.8 if self.heading_filter == "sustained" else 0.5

    @property
    def num_frames(self) -> int:
        return max(1, int(round(self.duration / self.control_dt)))


class ServiceParams(NamedTuple):
    """Tunable parameters: the costmap's (`costmap.CostParams`), the path follower's
    (`grid_planner.Params`), the tracker's, the potential field's and the approach gain."""

    cost: costmap.CostParams
    follow: grid_planner.Params
    tracker: tracker.TrackerParams
    field: potential_field.Params
    estimator: object
    lookahead: Array
    approach_gain: Array


_TRACKER = tracker.TrackerConfig(capacity=8, association="nn_jpda", sensor_update="sequential",
                                 merge_distance=0.4, max_misses=10,
                                 tentative_outside_confirmed=True, tentative_from_births=True)


def _kf_config(config: ServiceConfig) -> user.RobotFrameKFConfig:
    return user.RobotFrameKFConfig(
        sensors="both", heading=heading_filter.HeadingParams(slow=config.heading_slow))


def make_params(config: ServiceConfig) -> ServiceParams:
    """Default parameters: seed 003's sensor noise in the tracker (and in seed 002's filter of
    the approach: 0.2 m laser, 0.3 m RGB-D), whose acceleration density
    is 0.1 m^2/s^3 (people in a home walk smoothly): with 0.5, a still person's estimated
    velocity has a 0.18 m/s spread per axis and crosses the 0.1 m/s walking threshold most of
    the time, and a velocity test at the 0.9 level then calls walkers at 0.5 m/s still (the
    steady-state velocity std is 0.34 m/s; 0.19 with 0.1)."""
    dtype = config.dtype
    est = user.robot_frame_kf(_kf_config(config))
    return ServiceParams(
        costmap.CostParams.create(dtype=dtype),
        grid_planner.Params.create(k_speed=1.5, k_turn=1.5, v_max=config.v_max,
                                   omega_max=config.omega_max, dtype=dtype),
        tracker.TrackerParams.create(_TRACKER, dt=config.control_dt, q=0.1,
                                     r_std=(0.1, 0.3, 0.2), p_detect=0.8,
                                     clutter_density=0.02, birth_confidence=0.75,
                                     dtype=dtype),
        potential_field.Params.create(dtype=dtype),
        est.params(dt=config.control_dt, q=config.person_q, laser_std=0.2, rgbd_std=0.3),
        jnp.asarray(0.6, dtype), jnp.asarray(1.0, dtype))


# ---------------------------------------------------------------------------------------------
# Static geometry: the grid, the static cost layer, the ceiling cameras


def grid(config: ServiceConfig) -> costmap.Grid:
    """The costmap grid over the whole flat."""
    W, H = flat.SIZE
    shape = (int(round(H / config.cell)), int(round(W / config.cell)))
    return costmap.Grid(jnp.asarray([-0.5 * W, -0.5 * H], config.dtype),
                        jnp.asarray(config.cell, config.dtype), shape)


def static_cost(config: ServiceConfig) -> np.ndarray:
    """[H, W] the static layer: ``inf`` on walls, blocks and the table; `costmap.LETHAL` where
    the robot's body would touch them (closer than its radius + 2 cm); then a cost falling from
    0.3 with 0.15 m scale, to keep the robot off the walls when it can."""
    g = grid(config)
    Hc, Wc = g.shape
    c = config.cell
    xs = -0.5 * flat.SIZE[0] + (np.arange(Wc) + 0.5) * c
    ys = -0.5 * flat.SIZE[1] + (np.arange(Hc) + 0.5) * c
    X, Y = np.meshgrid(xs, ys)
    occ = np.zeros((Hc, Wc), bool)
    boxes = [(b["centre"], b["size"]) for b in config.scene.blocks]
    boxes += [(it["centre"], it["size"]) for it in config.scene.furniture]
    # a cell is occupied when its square overlaps a box: thin walls stay unbroken
    for (cx, cy), (sx, sy) in boxes:
        occ |= (np.abs(X - cx) < 0.5 * (sx + c)) & (np.abs(Y - cy) < 0.5 * (sy + c))
    border = np.zeros_like(occ)
    border[0, :] = border[-1, :] = border[:, 0] = border[:, -1] = True
    d = ndimage.distance_transform_edt(~occ) * c
    # distance to the outer walls (the flat's edge)
    d = np.minimum(d, np.minimum.reduce([X + 0.5 * flat.SIZE[0], 0.5 * flat.SIZE[0] - X,
                                          Y + 0.5 * flat.SIZE[1], 0.5 * flat.SIZE[1] - Y]))
    r = config.robot_radius + 0.02
    cost = np.where(d < r, costmap.LETHAL, 0.3 * np.exp(-(d - r) / 0.15))
    return np.where(occ | (d < 0.5 * c), np.inf, cost)


_CAMERA_POSES = (((-5.8, -2.0, 2.5), (-2.0, -2.7, 0.0)),
                 ((5.8, -2.0, 2.5), (2.0, -2.7, 0.0)),
                 ((-5.8, 3.8, 2.5), (-2.8, 1.0, 0.0)),
                 ((0.2, 3.8, 2.5), (3.6, 0.6, 0.0)))
# each camera reports people in its own room only (the walls hide the others)
_CAMERA_ROOMS = (flat.CORRIDOR, flat.CORRIDOR, flat.KITCHEN, flat.LIVING_ROOM)


def cameras(dtype=jnp.float32) -> ceiling_camera.CeilingCamera:
    """The four ceiling cameras stacked (two in the corridor, one per room)."""
    cams = [ceiling_camera.look_at(jnp.asarray(p, dtype), jnp.asarray(t, dtype), fx=300.0,
                                   width=640, height=480, max_range=9.0, dtype=dtype)
            for p, t in _CAMERA_POSES]
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *cams)


def _planner_grid(g: costmap.Grid) -> grid_planner.Grid:
    """The costmap grid as the planner indexes it (its origin is cell (0, 0)'s centre)."""
    return grid_planner.Grid(g.origin + 0.5 * g.resolution, g.resolution,
                             jnp.asarray(g.shape, jnp.int32))


def free_space(config: ServiceConfig, dtype=jnp.float32):
    """``in_free_space(zs [N, 2]) -> [N]`` bools: map-frame points inside the flat and off its
    walls and furniture (the static layer's finite cells), the map filter of the detections.

    Its grid has the costmap's cell or `MAP_FILTER_CELL`, whichever is finer: the static
    layer's obstacles grow by half a cell, and with 0.2 m cells the couch swallowed the
    detections of the people seated on it (the TV experiment's MOTA fell from 99.3 to 94.6 %).

    Example:
      >>> keep = free_space(config)(detections_xy)
    """
    free_config = dataclasses.replace(config, cell=min(config.cell, MAP_FILTER_CELL))
    pg = _planner_grid(grid(free_config))
    free = jnp.isfinite(jnp.asarray(static_cost(free_config), dtype))
    half = 0.5 * jnp.asarray(flat.SIZE, dtype)

    def in_free_space(zs):
        inside = jnp.all(jnp.abs(zs) < half, -1)
        cell = grid_planner.cell_of(pg, jnp.where(inside[:, None], zs, 0.0).astype(dtype))
        return inside & free[cell[:, 0], cell[:, 1]]

    return in_free_space


def _in_box(box, xy):
    x0, y0, x1, y1 = box
    return (xy[..., 0] >= x0) & (xy[..., 0] <= x1) & (xy[..., 1] >= y0) & (xy[..., 1] <= y1)


# ---------------------------------------------------------------------------------------------
# The episode


class State(NamedTuple):
    data: object
    people: people_mod.People
    robot: Array
    u: Array
    sensing: object
    odom: Array
    tracks: tracker.Tracks
    extra_tracks: tuple
    estimator: object
    interest: Array
    done: Array
    dist: Array
    t: Array
    heading: Array
    ids: Array
    person_heading: heading_filter.WindowedHeading
    pan: pan_tilt.PanState
    parked: Array
    track_heading: heading_filter.WindowedHeading


class Frame(NamedTuple):
    """One frame's record (world frame).

    Attributes:
      robot: [3] true pose. u: [2] the command. done: bool, the task was done by this frame.
      people: [P, 2]; people_heading: [P]; people_mask: [P]; people_role: [P].
      hyp_pos: [G, K, 2], hyp_ids: [G, K], hyp_mask: [G, K]: the confirmed tracks of each
        tracker (G = 1, or 3 with ``compare_sensors``: the behaviour's, ceiling-only,
        robot-only); for ``approach`` one row holding the person estimate.
      status: [K] the behaviour tracker's status codes; heading: [K] their headings (the
        costmap's inputs, with ``hyp_pos[0]``). goal: [2] the current goal.
      target_est: [3] the estimate of the task's person (x, y, heading), NaN if none.
      interest: the person interest used (``approach``).
    """

    robot: Array
    u: Array
    done: Array
    people: Array
    people_heading: Array
    people_mask: Array
    people_role: Array
    hyp_pos: Array
    hyp_ids: Array
    hyp_mask: Array
    status: Array
    heading: Array
    goal: Array
    target_est: Array
    interest: Array


def _inflate(cost: Array, cells: int) -> Array:
    """Cell-wise maximum over a disc of ``cells`` cells: the cost to the robot's *centre* of a
    person cost defined for its body (its configuration space).

    The disc is a stack of rows: row ``di`` spans the columns ``|dj| <= w(di)``, so the maximum
    is taken along the rows first (one running maximum per half-width), then across them:
    about 4 * cells shifted copies of the map instead of the disc's pi * cells^2. The shifts
    are slices of maps padded on one axis only (a running maximum along the rows pads the
    columns; the rows' maximum of one half-width pads the rows once): in isolation 1.5-1.7x
    faster than rolling copies of a map padded on both axes (64 maps of 80 x 120, 4 cells)."""
    H, W = cost.shape
    half = [math.isqrt(cells * cells - di * di) for di in range(cells + 1)]
    cols = jnp.pad(cost, ((0, 0), (cells, cells)))
    run = cost
    out = cost
    for w in range(max(half) + 1):
        if w:
            run = jnp.maximum(run, jnp.maximum(cols[:, cells + w:cells + w + W],
                                               cols[:, cells - w:cells - w + W]))
        offsets = [di for di in range(-cells, cells + 1) if half[abs(di)] == w]
        if offsets:
            rows = jnp.pad(run, ((cells, cells), (0, 0)))
            for di in offsets:
                out = jnp.maximum(out, rows[cells + di:cells + di + H])
    return out


def make_rollout(config: ServiceConfig):
    """Build ``rollout(key, params) -> Frame`` stacked over the frames.

    Example:
      >>> cfg = ServiceConfig(build_scene(), experiment="tv", duration=20.0)
      >>> frames = jax.jit(make_rollout(cfg))(jax.random.key(0), make_params(cfg))
    """
    sc = config.scene
    dtype = config.dtype
    dt = config.control_dt
    exp = config.experiment
    scfg = config.sensors
    laser = world.laser_world(sc, scfg.laser, dtype)
    static_map = world.static_map(sc, laser, scfg.map_filter)
    g = grid(config)
    pg = _planner_grid(g)
    static = jnp.asarray(static_cost(config), dtype)
    in_free_space = free_space(config, dtype)
    inflate_cells = int(round((config.robot_radius + config.safety_margin) / config.cell))
    path_cells = math.ceil(PATH_AHEAD / config.cell) + 1
    cams = cameras(dtype)
    rooms = np.asarray(_CAMERA_ROOMS)
    sitting = _areas(flat.SITTING_AREAS, dtype)
    handover = _areas(flat.HANDOVER_AREA[None], dtype)
    tv = jnp.asarray(flat.TV, dtype)[None]
    P = sc.num_people
    approach = exp == "approach"
    settle_frames = int(round(config.settle / dt))
    still_from = config.num_frames - int(round(config.still_at_end / dt))
    estimator = user.robot_frame_kf(_kf_config(config))
    groups = ([config.perception] if config.perception != "truth" else ["all"])
    if config.compare_sensors:
        groups = groups + [g_ for g_ in ("ceiling", "robot") if g_ != groups[0]]
    cases = person_interest.CaseBase.create(dtype=dtype)
    window = max(1, int(round(config.heading_window / dt)))
    heading_params = heading_filter.HeadingParams(slow=config.heading_slow)
    segments = HEADING_SEGMENTS if config.heading_filter == "sustained" else 1
    arc_frames = int(round(config.arc_check / dt))
    track_headings = (exp == "handover" and config.heading_filter != "ar"
                      and config.perception != "truth")

    def reset(key, params):
        k_setup, k_est = jax.random.split(key)
        setup = experiments.sample(k_setup, exp, dtype)
        ppl = setup.people
        pose = setup.robot
        data = scene_mod.reset(sc, pose, people_mod.as_pedestrians(ppl))
        tracks = tracker.init(_TRACKER, dtype)
        prior = user.Prior(ppl.pos[0], pose, jnp.zeros(3, dtype))
        est = estimator.init(k_est, params.estimator, prior)
        dist = jnp.zeros(g.shape, dtype)        # the first frame solves in full
        pi0 = jnp.asarray(0.5 if config.interest is None else config.interest, dtype)
        return setup, State(data, ppl, pose, jnp.zeros(2, dtype),
                            sensing.init(scfg.sensing, dtype), pose, tracks,
                            tuple(tracks for _ in groups[1:]), est, pi0, jnp.asarray(False),
                            dist, jnp.int32(0), jnp.zeros(_TRACKER.capacity, dtype),
                            jnp.full(_TRACKER.capacity, -1, jnp.int32),
                            heading_filter.windowed_heading_init(
                                jnp.arctan2(pose[1] - ppl.pos[0, 1], pose[0] - ppl.pos[0, 0]),
                                ppl.pos[0], window),
                            pan_tilt.init(dtype), jnp.asarray(False),
                            jax.vmap(lambda p: heading_filter.windowed_heading_init(
                                0.0, p, window))(jnp.zeros((_TRACKER.capacity, 2), dtype)))

    def world_step(key, s: State):
        ppl = s.people._replace(steps=s.people.steps & (s.t < still_from))
        ppl = people_mod.step(key, ppl, s.robot, dt)
        data = scene_mod.robot_step(sc, s.data, s.u, max(1, round(dt / sc.dt)))
        return ppl, data, scene_mod.robot_pose(data).astype(dtype)

    def sense(keys, s: State, ppl, pose):
        """Detections of every sensor in the map frame ([M, 2], mask, sensor) and the robot's
        sensing step (odometry frame, for the approach's estimator)."""
        k_obs, k_cam = keys[:3], keys[3]
        colours = jnp.zeros((P, 3), dtype)
        pan = None if config.pan is None else s.pan.angle
        obs = world.observe(k_obs, scfg, sc, laser, s.robot, pose,
                            people_mod.as_pedestrians(ppl), colours, pan)
        odom = geometry.compose(s.odom, obs.increment)
        sensing_state, sensed = sensing.sense(
            scfg.sensing, s.sensing, obs.ranges, laser.angles,
            sensing.Odometry(odom, obs.increment), obs.rgbd.xy, obs.rgbd.mask, obs.rgbd.colour,
            static_map, map_pose=pose, period=dt)
        sensed = sensed._replace(camera_pan=pan)
        heights = jnp.full(P, _STATURE, dtype)
        radii = jnp.full(P, _BODY_RADIUS, dtype)

        def one_camera(cam, key, room):
            z, ok = ceiling_camera.detect(cam, key, ppl.pos, heights, radii, ppl.mask,
                                          capacity=_CAMERA_SLOTS, sigma=0.1, p_detect=0.9,
                                          clutter_rate=0.05, feet_offset=_BODY_RADIUS,
                                          upright=True)
            return z, ok & _in_box(room, z)

        zc, okc = jax.vmap(one_camera)(cams, jax.random.split(k_cam, 4), jnp.asarray(rooms,
                                                                                       dtype))
        rgbd_xy = geometry.from_frame(pose, obs.rgbd.xy.astype(dtype))
        rgbd_ok = obs.rgbd.mask
        if config.line_of_sight:
            rgbd_ok = rgbd_ok & ~behind_the_scan(rgbd_xy, obs.ranges, laser.angles,
                                                 lidar.laser_pose(pose, scfg.laser))
        zs = jnp.concatenate([zc.reshape(-1, 2), rgbd_xy, sensed.laser_map_xy.astype(dtype)])
        ok = jnp.concatenate([okc.reshape(-1), rgbd_ok, sensed.laser_mask])
        # the map: a detection outside the flat or inside a wall or furniture is none (the
        # RGB-D detector's false positives fall anywhere in its field of view, through walls)
        ok = ok & in_free_space(zs) & jnp.all(jnp.isfinite(zs), -1)
        sensor = jnp.concatenate([jnp.full(okc.size, _CEILING), jnp.full(rgbd_xy.shape[0], _RGBD),
                                  jnp.full(sensed.laser_mask.shape[0], _LASER)]).astype(jnp.int32)
        return (zs, ok, sensor), sensing_state, sensed, odom

    def covered(zs, sensor, tracks):
        """[M] robot detections a ceiling camera would see: in its room and view, and not
        hidden behind the confirmed tracks (the cameras' occlusion model with the tracked
        people as occluders)."""
        others = tracks.mean[:, :2]
        others_on = tracks.status == tracker.CONFIRMED
        # the ceiling cameras' own slots come first; only the robot's are checked
        robot = zs[_CAMERA_SLOTS * len(_CAMERA_POSES):]
        M = robot.shape[0]
        # a track on the detection itself is the person, not an occluder
        near = jnp.sum((others[None] - robot[:, None]) ** 2, -1) < 0.5 ** 2
        may_occlude = others_on[None] & ~near

        def seen_by(cam, room):
            # with a margin: a point a camera sees half hidden, or at its image's edge, may be
            # a person it misses in every frame (the occlusion here is computed from the
            # tracks, and coarsely); the robot's detection there may start a track
            visible = ceiling_camera.visible_among(
                cam, robot, jnp.full(M, _STATURE, dtype), jnp.full(M, _BODY_RADIUS, dtype),
                others, jnp.full(others.shape[0], _STATURE, dtype),
                jnp.full(others.shape[0], _BODY_RADIUS, dtype), may_occlude, rim_points=8,
                occlusion_grid=4, max_occlusion=COVERED_OCCLUSION, min_in_image=0.75)
            return visible & _in_box(room, robot)

        seen = jnp.any(jax.vmap(seen_by)(cams, jnp.asarray(rooms, dtype)), 0)
        return jnp.concatenate([jnp.zeros(zs.shape[0] - M, bool), seen])

    def track(tracks, dets, in_group, with_ceiling, params):
        """One tracker step on the detections of the sensors ``in_group`` ([3] bool, by sensor
        code). With the ceiling cameras in the group (``with_ceiling``), a robot detection a
        camera would see (`covered`) gets confidence 1/2, under the tracker's birth
        threshold: it updates the tracks but starts none (were a person there, the camera
        would have started their track; the robot's noisier, clutter-prone detections there
        only made false tracks). Where the cameras cannot see, behind tracked people or out
        of their view, the robot's detections start tracks; with ``corroborated_births``, an
        RGB-D detection there only when the laser sees legs beside it (`corroborated`)."""
        zs, ok, sensor = dets
        keep = ok & in_group[sensor]
        confidence = jnp.ones(zs.shape[0], dtype)
        if any_ceiling:     # static: no group with the cameras computes no coverage
            unborn = covered(zs, sensor, tracks)
            if config.corroborated_births:
                unborn = unborn | ((sensor == _RGBD) & ~corroborated(zs, keep, sensor))
            confidence = jnp.where(with_ceiling & unborn, 0.5, 1.0)
        det = tracker.Detections(jnp.where(keep[:, None], zs, 0.0), keep, sensor,
                                 confidence.astype(dtype), jnp.zeros((zs.shape[0], 0), dtype))
        return tracker.step(tracks, det, params.tracker)

    # the behaviour's tracker and the comparison ones differ only in the detections they
    # keep: one tracker step, vmapped over the groups (one trace and compile, not one each)
    group_sensors = jnp.asarray([[k in _SENSOR_GROUPS[gr] for k in range(3)] for gr in groups])
    group_ceiling = jnp.asarray([_CEILING in _SENSOR_GROUPS[gr] for gr in groups])
    any_ceiling = any(_CEILING in _SENSOR_GROUPS[gr] for gr in groups)

    def track_groups(all_tracks, dets, params):
        if len(groups) == 1:
            return (track(all_tracks[0], dets, group_sensors[0], group_ceiling[0], params),)
        stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *all_tracks)
        new = jax.vmap(track, (0, None, 0, 0, None))(stacked, dets, group_sensors,
                                                     group_ceiling, params)
        return tuple(jax.tree_util.tree_map(lambda x: x[i], new) for i in range(len(groups)))

    def people_estimate(tracks, ppl):
        """(xy [K, 2], velocity [K, 2], previous heading [K], present [K]) of the behaviour's
        tracker, or of the true people for ``perception="truth"``."""
        if config.perception == "truth":
            K = tracks.mean.shape[0]
            pad = lambda x: jnp.zeros((K,) + x.shape[1:], x.dtype).at[:P].set(x)  # noqa: E731
            return (pad(ppl.pos), pad(ppl.vel), pad(ppl.heading),
                    jnp.zeros(K, bool).at[:P].set(ppl.mask))
        confirmed = tracks.status == tracker.CONFIRMED
        return tracks.mean[:, :2], tracks.mean[:, 2:], tracks.heading, confirmed

    def navigate(s: State, pose, tracks, ppl, setup, params, full):
        xy, vel, prev_heading, present = people_estimate(tracks, ppl)
        cov = None
        if config.perception != "truth":
            cov = tracks.cov[:, 2:, 2:]
            # the heading the status kept for this track last frame (a new track: the
            # tracker's); the tracker's own turns with any velocity above 0.1 m/s, noise too
            prev_heading = jnp.where(tracks.id == s.ids, s.heading, prev_heading)
        st = status_mod.classify(xy, vel, prev_heading, present, sitting=sitting,
                                 handover=handover, velocity_cov=cov, significance=0.9)
        track_heading = s.track_heading
        if track_headings:
            # a waiting person's heading from the windowed (or sustained) filter on their
            # track's positions, as the approach's, rather than from the velocity at which they
            # stopped: the tracker's velocity turns with the noise as it decays to zero
            fresh = tracks.id != s.ids
            init = jax.vmap(lambda h, p: heading_filter.windowed_heading_init(h, p, window))(
                st.heading, xy)
            track_heading = jax.tree_util.tree_map(
                lambda a, b: jnp.where(fresh.reshape((-1,) + (1,) * (a.ndim - 1)), a, b),
                init, s.track_heading)
            track_heading = jax.vmap(lambda h, p: heading_filter.windowed_heading_step(
                h, p, dt, heading_params, config.min_heading_distance,
                segments=segments))(track_heading, xy)
            st = st._replace(heading=jnp.where(st.status == status_mod.HANDOVER,
                                               track_heading.heading, st.heading))
        if config.perception == "truth":
            # the true roles: a seated person is seated, a waiting one waits
            role = jnp.zeros(xy.shape[0], jnp.int32).at[:P].set(ppl.role)
            code = jnp.where(role == people_mod.SEATED, status_mod.SEATED, st.status)
            st = st._replace(status=code, heading=prev_heading)
        attended = jnp.where(st.status == status_mod.SEATED, 0, -1).astype(jnp.int32)
        people_cost = costmap.build(g, params.cost, xy, st.heading, st.status, st.mask,
                                    objects_xy=tv, attended=attended)
        people_layer = _inflate(people_cost, inflate_cells)
        cost = jnp.maximum(people_layer, static)
        # the task's goal
        if exp == "handover":
            waiting = st.mask & (st.status == status_mod.HANDOVER)
            d_goal = jnp.where(waiting, jnp.sum((xy - setup.goal) ** 2, -1), jnp.inf)
            k = jnp.argmin(d_goal)
            found = jnp.isfinite(d_goal[k])
            h = st.heading[k]
            front = xy[k] + 1.0 * jnp.stack([jnp.cos(h), jnp.sin(h)])
            goal = jnp.where(found, front, setup.goal + jnp.asarray([0.0, -1.6], dtype))
            target = jnp.where(found, jnp.append(xy[k], h), jnp.full(3, jnp.nan, dtype))
            face = xy[k]
        else:
            goal, found = setup.goal, jnp.asarray(False)
            target = jnp.full(3, jnp.nan, dtype)
            face = goal
        plan_cost = jnp.where(cost >= costmap.LETHAL, _LETHAL_PENALTY, cost)
        goal_cell = grid_planner.cell_of(pg, goal)
        goal_cell = jnp.clip(goal_cell, 0, jnp.asarray(g.shape) - 1)
        # a full solve on the first frame of each replanning block, refined rounds on the
        # others; ``full`` is the same in every episode (it comes from the frame index, not
        # the episode), so under vmap this stays a branch and only one side runs
        start = jnp.clip(grid_planner.cell_of(pg, pose[:2]), 0, jnp.asarray(g.shape) - 1)
        dist = jax.lax.cond(
            full,
            lambda: grid_planner.distance_field(
                plan_cost, goal_cell, cell=config.cell,
                start_cell=start if config.solve_to_robot else None),
            lambda: grid_planner.refine(s.dist, plan_cost, goal_cell, config.sweeps,
                                        cell=config.cell))
        path = grid_planner.extract_path(dist, start, path_cells, cost=plan_cost,
                                         cell=config.cell)
        aim = grid_planner.lookahead_point(pg, path.cells, path.valid, pose[:2],
                                           params.lookahead)
        aim = jnp.where(geometry.safe_norm(goal - pose[:2]) < params.lookahead, goal, aim)
        u = grid_planner.track_path(pose, aim, params.follow)
        if arc_frames:
            # the arc's collision check against the people's lethal cores (inflated by the
            # body): pure pursuit's arc cut the corner round a person by up to 0.15 m
            u = grid_planner.clear_arc(u, pose, people_layer >= costmap.LETHAL, pg, dt,
                                       arc_frames)
        to_goal = geometry.safe_norm(goal - pose[:2])
        at_goal = to_goal < GOAL_TOLERANCE
        if exp == "handover":
            # once there, the robot holds the hand-over pose while the goal (which moves with
            # the person's estimate) stays within ``hold_radius``: chasing its jitter across
            # the tolerance turned the robot to and fro, away from the person
            at_goal = at_goal | (s.done & (to_goal < config.hold_radius))
        # at the goal: stop, turning toward the person (hand-over) or staying
        to_face = face - pose[:2]
        e = wrap(jnp.arctan2(to_face[1], to_face[0]) - pose[2])
        turn = jnp.clip(1.5 * e, -config.omega_max, config.omega_max)
        u_goal = jnp.stack([jnp.zeros((), dtype), jnp.where(exp == "handover", turn, 0.0)])
        u = jnp.where(at_goal, u_goal, u)
        if exp == "handover":
            done = at_goal & found & (jnp.abs(e) < math.radians(15.0))
        else:
            done = at_goal
        return u, done, st, goal, target, dist, track_heading

    def on_map(xy_odom, odom_pose, pose):
        """[N] odometry-frame points that lie in the flat's free space (the map filter of
        `sense`, for the estimator's candidates)."""
        return in_free_space(geometry.from_frame(pose, geometry.to_frame(odom_pose, xy_odom)))

    def approach_behaviour(s: State, key, sensed, ppl, params, pose):
        if config.map_filter_estimator:
            sensed = sensed._replace(
                laser_mask=sensed.laser_mask & on_map(sensed.laser_xy, sensed.odom_pose, pose),
                rgbd_mask=sensed.rgbd_mask & on_map(sensed.rgbd_xy, sensed.odom_pose, pose))
        est_state, e = estimator.update(key, s.estimator, sensed, params.estimator)
        if config.perception == "truth":
            # the true person, in the odometry frame: the controller's floor
            turn = sensed.odom_pose[2] - pose[2]
            xy = geometry.from_frame(sensed.odom_pose, geometry.to_frame(pose, ppl.pos[0]))
            e = e._replace(user=jnp.concatenate([xy, geometry.rotate(turn, ppl.vel[0])]),
                           user_heading=wrap(ppl.heading[0] + turn))
        p = e.user
        heading = e.user_heading
        person_heading = s.person_heading
        if config.heading_filter != "ar" and config.perception != "truth":
            # the person's heading from their displacement over the window (odometry frame;
            # at the start: facing the robot, as seed 002 assumes of a person it finds)
            turn = 0.0
            xy = p[:2]
            if config.heading_frame == "map":
                turn = pose[2] - sensed.odom_pose[2]
                xy = geometry.from_frame(pose, geometry.to_frame(sensed.odom_pose, xy))
            person_heading = heading_filter.windowed_heading_step(
                s.person_heading, xy, dt, heading_params, config.min_heading_distance,
                segments=segments)
            heading = wrap(person_heading.heading - turn)
        if config.interest is None:
            feats = person_interest.encounter_features(
                geometry.to_frame(sensed.odom_pose, p[:2]),
                wrap(heading - sensed.odom_pose[2]),
                geometry.rotate(-sensed.odom_pose[2], p[2:]))
            pi = person_interest.interest_step(cases, s.interest, feats)
        else:
            pi = s.interest
        person = jnp.append(p[:2], heading)
        target, parked = None, s.parked
        if config.settle_iterations and config.park is not None:
            here = sensed.odom_pose[:2]
            target = potential_field.settle_point(params.field, here, person, pi,
                                                  iterations=config.settle_iterations)
            away = jnp.sqrt(jnp.sum((target - here) ** 2))
            arrive, leave = config.park
            parked = (away < arrive) | (s.parked & (away < leave))
            target = jnp.where(parked, here, target)
        # the person's velocity is fed forward: the field moves with them, and a step
        # would otherwise leave the robot behind until the gradient caught up
        u = potential_field.approach_velocity(params.field, sensed.odom_pose, person, pi,
                                              p[2:] if config.feed_forward else None,
                                              gain=params.approach_gain, v_max=config.v_max,
                                              omega_max=config.omega_max,
                                              reverse=config.reverse,
                                              settle_iterations=config.settle_iterations,
                                              target=target)
        camera = s.pan
        if config.pan is not None:
            # the RGB-D camera on its pan unit keeps the person in view while the unicycle
            # goes round them (seed 002's omnidirectional Robotino could face them instead)
            rel = geometry.to_frame(sensed.odom_pose, p[:2])
            camera = pan_tilt.servo(config.pan, s.pan, jnp.arctan2(rel[1], rel[0]), dt)
        return (est_state, e._replace(user_heading=heading), pi, u,
                (person_heading, camera, parked))

    def frame(s: State, key, setup, params, full):
        ks = jax.random.split(key, 7)
        ppl, data, pose = world_step(ks[0], s)
        dets, sensing_state, sensed, odom = sense(ks[1:5], s, ppl, pose)
        K = _TRACKER.capacity
        if approach:
            tracks, extra = s.tracks, s.extra_tracks
            est_state, e, pi, u, (person_heading, camera, parked) = approach_behaviour(
                s, ks[5], sensed, ppl, params, pose)
            dist, track_heading = s.dist, s.track_heading
            est_world = geometry.from_frame(pose, geometry.to_frame(sensed.odom_pose,
                                                                     e.user[:2]))
            target = jnp.append(est_world, wrap(e.user_heading + pose[2]
                                                - sensed.odom_pose[2]))
            done = jnp.sqrt(jnp.sum(u ** 2)) < 0.02
            st = status_mod.PersonStatus(jnp.zeros(K, jnp.int32), jnp.zeros(K, dtype),
                                         jnp.zeros(K, dtype), jnp.zeros(K, bool))
            goal = setup.goal
            hyp_pos = jnp.zeros((1, K, 2), dtype).at[0, 0].set(est_world)
            hyp_ids = jnp.full((1, K), -1, jnp.int32).at[0, 0].set(0)
            hyp_mask = jnp.zeros((1, K), bool).at[0, 0].set(True)
        else:
            est_state, pi, person_heading = s.estimator, s.interest, s.person_heading
            camera, parked = s.pan, s.parked
            tracks, *extra = track_groups((s.tracks,) + s.extra_tracks, dets, params)
            extra = tuple(extra)
            u, done, st, goal, target, dist, track_heading = navigate(s, pose, tracks, ppl,
                                                                      setup, params, full)
            all_tracks = (tracks,) + extra
            hyp_pos = jnp.stack([t.mean[:, :2] for t in all_tracks])
            hyp_ids = jnp.stack([t.id for t in all_tracks])
            hyp_mask = jnp.stack([t.status == tracker.CONFIRMED for t in all_tracks])
        done = s.done | done
        u = jnp.where(done & (exp != "handover") & ~approach, 0.0, u)
        # the robot looks before it goes: its tracks confirm in the first frames
        u = jnp.where(s.t < settle_frames, 0.0, u)
        new = State(data, ppl, pose, u, sensing_state, odom, tracks, extra, est_state, pi, done,
                    dist, s.t + 1, jnp.where(st.mask, st.heading, 0.0).astype(dtype), tracks.id,
                    person_heading, camera, parked, track_heading)
        rec = Frame(pose, u, done, ppl.pos, ppl.heading, ppl.mask, ppl.role, hyp_pos, hyp_ids,
                    hyp_mask, jnp.where(st.mask, st.status, -1), st.heading, goal, target, pi)
        return new, rec

    def rollout(key, params: ServiceParams) -> Frame:
        k_reset, k_run = jax.random.split(key)
        setup, state = reset(k_reset, params)
        # blocks of `replan_every` frames: a full solve at the first frame of each, refined
        # rounds at the others; the frame is traced once, with the block's start as an input
        n = config.replan_every
        T = config.num_frames
        keys = jax.random.split(k_run, -(-T // n) * n)[:T]
        full = jnp.asarray(np.arange(T) % n == 0)

        def step(s, inputs):
            k, first = inputs
            return frame(s, k, setup, params, first)

        _, frames = jax.lax.scan(step, state, (keys, full))
        return frames

    return rollout


def corroborated(zs: Array, keep: Array, sensor: Array,
                 radius: float = CORROBORATION) -> Array:
    """[M] bool: the kept RGB-D detections (sensor code 1) with a kept laser detection (code 2)
    closer than ``radius`` (m); False for every other row.

    The RGB-D detector's and the laser's false positives fall independently, so two of them
    rarely coincide, while a person in view of both gives one of each; ``corroborated_births``
    lets an RGB-D detection that no ceiling camera sees start a track only when corroborated.

    Args:
      zs: [M, 2] detections (map frame). keep: [M] bool, the valid ones. sensor: [M] int
        sensor codes (0 ceiling, 1 RGB-D, 2 laser).

    Example:
      >>> corroborated(jnp.array([[0.0, 0.0], [0.5, 0.0], [3.0, 0.0]]),
      ...              jnp.array([True, True, True]), jnp.array([1, 2, 1]))
      Array([ True, False, False], dtype=bool)
    """
    laser = keep & (sensor == _LASER)
    d2 = jnp.sum((zs[:, None] - zs[None]) ** 2, -1)
    near = jnp.any(laser[None] & (d2 < radius ** 2), -1)
    return keep & (sensor == _RGBD) & near


def behind_the_scan(xy: Array, ranges: Array, angles: Array, laser_pose: Array,
                    margin=0.5) -> Array:
    """[N] bools: the world points ``xy`` [N, 2] lie more than ``margin`` (m) beyond the laser's
    range on their bearing, behind a wall or a person the RGB-D camera cannot see through
    either. Points outside the scan's angles are not behind it.

    Args:
      xy: [N, 2] world points. ranges: [B] the scan's ranges; angles: [B] its beam angles,
        evenly spaced, in the laser's frame. laser_pose: [3] the laser's world pose.

    Example:
      >>> behind_the_scan(jnp.array([[1.0, 0.0], [3.0, 0.0]]), jnp.full(5, 2.0),
      ...                 jnp.linspace(-0.2, 0.2, 5), jnp.zeros(3))     # [False, True]
    """
    rel = geometry.to_frame(laser_pose, xy)
    bearing = jnp.arctan2(rel[:, 1], rel[:, 0])
    off = jnp.abs(wrap(angles[None, :] - bearing[:, None]))                 # [N, B]
    beam = jnp.argmin(off, 1)
    in_scan = jnp.min(off, 1) <= jnp.abs(angles[1] - angles[0])
    return in_scan & (geometry.safe_norm(rel) > ranges[beam] + margin)


def _areas(boxes, dtype) -> status_mod.Areas:
    """`status.Areas` of axis-aligned boxes [A, 4] (x0, y0, x1, y1)."""
    boxes = np.asarray(boxes, float)
    return status_mod.Areas.create(0.5 * (boxes[:, :2] + boxes[:, 2:]),
                                   0.5 * (boxes[:, 2:] - boxes[:, :2]), dtype=dtype)


# ---------------------------------------------------------------------------------------------
# Metrics


def _segment_distance(p, a, b):
    """Distance [...] from points p [..., 2] to the segments a-b [..., 2]."""
    ab = b - a
    t = jnp.clip(jnp.sum((p - a) * ab, -1) / jnp.maximum(jnp.sum(ab * ab, -1), 1e-12), 0.0, 1.0)
    return geometry.safe_norm(p - (a + t[..., None] * ab))


def summarize(config: ServiceConfig, f: Frame) -> dict:
    """Episode metrics (module docstring) from a rollout's `Frame` record (one episode)."""
    dtype = f.robot.dtype
    dt = config.control_dt
    T = f.robot.shape[0]
    body = geometry.safe_norm(f.people - f.robot[:, None, :2]) - config.robot_radius  # [T, P]
    body = jnp.where(f.people_mask, body, jnp.inf)
    done_any = jnp.any(f.done)
    first = jnp.argmax(f.done)
    t_goal = jnp.where(done_any, (first + 1) * dt, jnp.nan)
    step = geometry.safe_norm(f.robot[1:, :2] - f.robot[:-1, :2])
    before = jnp.arange(1, T) <= first
    path_length = jnp.sum(jnp.where(before | ~done_any, step, 0.0))
    present = jnp.any(f.people_mask, 0)
    min_dist = jnp.where(present, jnp.min(body, 0), jnp.nan)
    intimate_time = jnp.sum((body < INTIMATE) & f.people_mask, 0) * dt
    personal_time = jnp.sum((body < PERSONAL) & f.people_mask, 0) * dt
    intimate = jnp.any((body < INTIMATE) & f.people_mask)
    # overtaking: where the robot passes the walker (person 0), which side is it on?
    rel = geometry.rotate(-f.people_heading[:, 0], f.robot[:, :2] - f.people[:, 0])  # [T, 2]
    ahead = rel[:, 0] > 0
    passes = ahead[1:] & ~ahead[:-1] & (jnp.abs(rel[1:, 1]) < 2.0)
    right_pass = jnp.any(passes & (rel[1:, 1] < 0))
    passed = jnp.any(passes)
    # TV interaction: the robot's body touching a seated person's segment to the TV
    seated = f.people_mask & (f.people_role == people_mod.SEATED)
    tv = jnp.asarray(flat.TV, dtype)
    d_tv = _segment_distance(f.robot[:, None, :2], f.people, jnp.broadcast_to(tv, f.people.shape))
    tv_crossing = jnp.any(seated & (d_tv < config.robot_radius))
    # final pose relative to the task's person (hand-over, approach)
    final = f.robot[-1]
    person = f.people[-1, 0]
    ph = f.people_heading[-1, 0]
    rel_final = geometry.rotate(-ph, final[:2] - person)
    final_distance = geometry.safe_norm(final[:2] - person)
    final_angle = jnp.arctan2(rel_final[1], rel_final[0])
    facing = wrap(jnp.arctan2(person[1] - final[1], person[0] - final[0]) - final[2])
    exp = config.experiment
    if exp == "avoid":
        rule = ~intimate
    elif exp == "overtake":
        rule = passed & ~right_pass
    elif exp == "tv":
        rule = ~tv_crossing
    elif exp == "handover":
        edge = final_distance - config.robot_radius
        rule = ((edge > INTIMATE) & (edge < PERSONAL) & (jnp.abs(final_angle) < math.radians(30))
                & (jnp.abs(facing) < math.radians(30)))
    else:
        rule = jnp.asarray(True)
    heading_error = jnp.abs(wrap(f.target_est[:, 2] - f.people_heading[:, 0]))
    settled = (jnp.arange(T) * dt >= config.settle) & jnp.isfinite(heading_error)
    heading_error = jnp.sum(jnp.where(settled, heading_error, 0.0)) / jnp.maximum(
        jnp.sum(settled), 1)
    # the task person's position estimate: lost when more than 1 m off after the settling time
    position_error = geometry.safe_norm(f.target_est[:, :2] - f.people[:, 0])
    seen = (jnp.arange(T) * dt >= config.settle) & jnp.isfinite(position_error)
    person_lost = jnp.any(seen & (position_error > 1.0))
    if exp == "approach":
        # seed 002's pose for the interest, reached (time to goal) and held at the end
        rel_t = geometry.rotate(-f.people_heading[:, 0], f.robot[:, :2] - f.people[:, 0])
        ok_t = _approach_ok(config.interest, geometry.safe_norm(rel_t),
                            jnp.arctan2(rel_t[:, 1], rel_t[:, 0]))
        ok_t = jnp.broadcast_to(ok_t, (T,))
        t_goal = jnp.where(jnp.any(ok_t), (jnp.argmax(ok_t) + 1) * dt, jnp.nan)
        path_length = jnp.sum(step)
        success = ok_t[-1]
        rule = success
    else:
        success = done_any & rule
    G = f.hyp_pos.shape[1]
    P = f.people.shape[1]
    gt_ids = jnp.broadcast_to(jnp.arange(P, dtype=jnp.int32), (T, P))
    mot = {}
    for gi in range(G):
        ids = jnp.where(f.hyp_mask[:, gi], f.hyp_ids[:, gi], -1)
        m = jmetrics.clear_mot(gt_ids, f.people, f.people_mask, ids, f.hyp_pos[:, gi],
                               f.hyp_mask[:, gi], MOT_THRESHOLD, num_ids=P)
        mot[gi] = m
    out = dict(success=success, rule=rule, time_to_goal=t_goal, path_length=path_length,
               min_distance=min_dist, intimate_time=intimate_time, personal_time=personal_time,
               intimate=intimate, right_pass=right_pass, passed=passed, tv_crossing=tv_crossing,
               final_distance=final_distance, final_angle=final_angle, facing=facing,
               mota=mot[0].mota, motp=mot[0].motp, interest=f.interest[-1],
               heading_error=jnp.where(exp in ("approach", "handover"), heading_error,
                                       jnp.nan),
               person_lost=jnp.where(exp in ("approach", "handover"), person_lost, False))
    if G > 1:
        out.update(mota_ceiling=mot[1].mota, mota_robot=mot[2].mota, motp_ceiling=mot[1].motp,
                   motp_robot=mot[2].motp)
    return out


APPROACH_TARGETS = {0.0: (2.0, 0.0), 0.5: (1.3, math.radians(45.0)), 1.0: (0.45, 0.0)}


def _approach_ok(interest, distance, angle):
    """Seed 002's final poses: PI = 0 about 2 m in front, 0.5 about 45 deg off the heading just
    outside 1.2 m, 1 about 0.45 m in front (tolerances: 0.35 m and 20 deg)."""
    if interest is None:
        return jnp.asarray(True)
    key = min(APPROACH_TARGETS, key=lambda k: abs(k - float(interest)))
    r, a = APPROACH_TARGETS[key]
    return (jnp.abs(distance - r) < 0.35) & (jnp.abs(jnp.abs(angle) - a) < math.radians(20))


def make_episode(config: ServiceConfig):
    """``episode(key, params) -> metrics`` for `jaxtrack.montecarlo.evaluate`."""
    rollout = make_rollout(config)

    def episode(key, params):
        return summarize(config, rollout(key, params))

    return episode
