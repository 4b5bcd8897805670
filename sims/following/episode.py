"""One closed-loop person-following episode: people walk, the robot senses, estimates, follows.

Each 10 Hz frame (``control_dt``):

1. the world moves: the pedestrians step (`sims.following.pedestrians`, avoiding each other and
   the robot), and the robot applies the last command through MJX physics
   (`sims.following.scene.robot_step`);
2. sensing: noisy odometry integrates the robot's believed pose (the odometry frame, which
   drifts); the laser scans the legs, furniture legs and walls (`sims.following.lidar`); the
   leg detector finds people in the scan (`jaxtrack.perception.legs`); the RGB-D detector reports
   noisy people with a colour feature (`sims.following.rgbd`);
3. estimation (`sims.following.estimators`): the user's position and velocity in the odometry
   frame (and everyone, for the multi-target estimators);
4. control (`jaxtrack.control.follower`, seed 004 eq. 9): the follower point ``P_fm`` on the
   estimated user, with velocity and acceleration limits, then a dynamic window
   (`jaxtrack.control.avoidance`) that replaces a command whose arc would hit a laser return or
   a table or chair of the map, and a safety stop when a laser return lies in the robot's path
   within ``safety_margin`` of its body.

Metrics (per episode; the frames are ``T = duration / control_dt``):

- ``following_rms``: RMS distance between the true follower point and the true user (m);
- ``lost_fraction``: fraction of frames the user estimate is farther than 0.5 m from the user;
- ``user_switches``: times the person the estimate sits on (the true person within 0.5 m of
  it, if any) changes from one person to another;
- ``mota``, ``motp``, ``mot_switches`` (multi-target estimators; NaN otherwise): CLEAR MOT of
  the confirmed tracks, with as ground truth the people inside the laser's field of view and range
  and not fully occluded (some beam's return is one of their legs), threshold 0.5 m;
- ``near_fraction``: fraction of frames any person's centre is within 0.45 m (Hall's intimate
  zone) of the robot's body (its collision disc);
- ``stop_fraction``: fraction of frames the safety stop held the robot.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import metrics as jmetrics
from jaxtrack.control import avoidance, follower
from jaxtrack.control import route as route_mod
from jaxtrack.perception import legs
from sims.following import estimators, lidar, pedestrians
from sims.following import rgbd as rgbd_mod
from sims.following import scene as scene_mod

Array = jax.Array

__all__ = ["EpisodeConfig", "EpisodeParams", "make_params", "make_episode", "make_rollout",
           "summarize", "Frame", "LOST_DISTANCE", "INTIMATE"]

LOST_DISTANCE = 0.5
INTIMATE = 0.45
MOT_THRESHOLD = 0.5


@dataclasses.dataclass(frozen=True, eq=False)
class EpisodeConfig:
    """Static episode configuration (closed over by `make_episode`).

    Attributes:
      scene: `sims.following.scene.Scene`.
      estimator: `estimators.EstimatorConfig`.
      distractors: people besides the user (``1 + distractors <= scene.num_people``).
      duration: simulated seconds; control_dt: control / sensing period (s).
      laser: `lidar.LaserConfig`; leg_params: `legs.LegParams`. By default an unpaired leg
        is a person too (``single_legs=1``, with segments up to 0.4 m wide: a standing
        person's legs, 0.2 m apart, often merge into one segment, and a walking person seen
        along their path hides one leg behind the other); the map filter removes the
        furniture legs and wall pieces that would otherwise become people. Measured on 8
        episodes with JPDA and colour: MOTA 82 % with single legs vs 77 % without.
      rgbd: `rgbd.RGBDConfig`; odometry: `rgbd.OdometryConfig`.
      max_segments, max_laser_people: leg-detector capacities.
      safety_margin: safety stop distance from the robot's body (m).
      map_filter: drop laser people within ``map_filter_radius`` of a furniture leg, or within
        ``wall_filter_distance`` of a wall, of the robot's map (the robot is localised in its
        map for this filter; the estimators still work in the drifting odometry frame).
      lost_timeout: after this long (s) without a measurement of the user, the controller
        assumes the user stands still and the robot stops driving (it may still turn).
      search_after, search_rate: after this long (s) without a measurement of the user, the
        robot turns on the spot at ``search_rate`` (rad/s) to look for them, in one direction
        (toward the side of the last estimate) until it finds them. With an estimator that
        re-identifies by colour (``appearance``), from ``lost_timeout`` on it first turns
        toward the person the colours have not told apart from the user nearest to the last
        estimate (`estimators.Estimate.look`), at most at ``search_rate``.
      avoidance: put the dynamic-window layer (`jaxtrack.control.avoidance`) between the
        follower law and the wheels: the law's command when its arc over the next second is
        clear of the laser returns and of the outlines of the tables and chairs of the robot's
        map (the laser sees only their legs, and the gaps between them are not free space),
        else the closest clear command (the safety stop stays as the last guard);
        ``avoidance_stride``: every how many beams it checks.
      reverse: allow the robot to drive backwards (its laser sees 240 deg to the front, nothing
        behind: by default it never reverses, and turns instead).
      route: when the straight line to the user's estimate passes within
        ``route_clearance`` of a table or chair of the map, steer to a waypoint of the
        shortest route to them instead (`jaxtrack.control.route`, a grid of ``route_cell`` m
        whose cells keep ``robot_radius + safety_margin + 0.05`` from furniture and walls,
        precomputed once per map); the follower law then brings the robot itself, not its
        follower point, to the waypoint. Measured with the true user as the estimate (64
        episodes, no distractors), blocked straight lines were 86 % of the squared following
        error.
      dtype: float dtype of the estimators and metrics.
    """

    scene: scene_mod.Scene
    estimator: estimators.EstimatorConfig = estimators.EstimatorConfig()
    distractors: int = 4
    duration: float = 60.0
    control_dt: float = 0.1
    laser: lidar.LaserConfig = lidar.LaserConfig()
    leg_params: legs.LegParams = legs.LegParams(single_legs=1.0, max_width=0.4)
    rgbd: rgbd_mod.RGBDConfig = rgbd_mod.RGBDConfig()
    odometry: rgbd_mod.OdometryConfig = rgbd_mod.OdometryConfig()
    max_segments: int = 48
    max_laser_people: int = 8
    safety_margin: float = 0.3
    map_filter: bool = True
    map_filter_radius: float = 0.3
    wall_filter_distance: float = 0.25
    lost_timeout: float = 1.0
    search_after: float = 1.5
    search_rate: float = 0.6
    avoidance: bool = True
    avoidance_stride: int = 2
    reverse: bool = False
    route: bool = True
    route_cell: float = 0.25
    route_clearance: float = 0.3
    dtype: object = jnp.float32

    @property
    def num_frames(self) -> int:
        return int(round(self.duration / self.control_dt))

    def __post_init__(self):
        if 1 + self.distractors > self.scene.num_people:
            raise ValueError(f"{1 + self.distractors} people (user + {self.distractors} "
                             f"distractors) exceed the scene's capacity of "
                             f"{self.scene.num_people}")
        if self.distractors < 0 or self.duration <= 0 or self.control_dt <= 0:
            raise ValueError("distractors must be >= 0, duration and control_dt > 0")
        if not (self.route_cell > 0 and self.route_clearance >= 0):
            raise ValueError(f"route_cell must be > 0 and route_clearance >= 0; got "
                             f"{self.route_cell}, {self.route_clearance}")


class EpisodeParams(NamedTuple):
    """Tunable parameters: the follower's (`follower.Params`) and the estimator's."""

    follower: follower.Params
    estimator: estimators.EstimatorParams


def make_params(config: EpisodeConfig, point="A", k1=1.0, k2=1.0, **estimator_kw
                ) -> EpisodeParams:
    """Default parameters: follower point ``"A"`` (1.5, 0) or ``"B"`` (1, 1), gains k1, k2.

    Example:
      >>> params = make_params(config, point="B", k1=0.8)
    """
    dt = config.dtype
    fp = follower.Params.create(k1=k1, k2=k2, point=point, v_max=1.5, omega_max=2.0,
                                a_max=1.5, alpha_max=4.0,
                                stop_distance=config.scene.robot_radius + config.safety_margin,
                                dtype=dt)
    ep = estimators.EstimatorParams.create(config.estimator, dt=config.control_dt, dtype=dt,
                                           **estimator_kw)
    return EpisodeParams(fp, ep)


class _Carry(NamedTuple):
    data: object
    people: pedestrians.PedestrianState
    true_pose: Array
    odom: Array
    est: object
    u: Array
    prev_legs: Array
    prev_legs_mask: Array
    unseen: Array
    last_id: Array
    switches: Array
    search_side: Array


class Frame(NamedTuple):
    """Per-frame record of a rollout (world frame)."""

    robot: Array        # [3] true robot pose
    people: Array       # [P, 2]
    people_mask: Array  # [P]
    user_estimate: Array  # [2] in the world frame
    follow_error: Array
    lost: Array
    visible: Array      # [P] ground truth for MOT
    hyp_pos: Array      # [H, 2]
    hyp_ids: Array      # [H]
    hyp_mask: Array     # [H]
    near: Array
    stopped: Array
    u: Array            # [2]
    laser_user: Array   # distance from the user to the nearest laser person (m; inf: none)
    rgbd_user: Array    # distance from the user to the nearest RGB-D detection (m; inf: none)


def _norm(v):
    """Euclidean norm over the last axis with a finite gradient at 0 (scan outputs that a loss
    does not use still get zero cotangents, and 0 * inf would turn them into NaN)."""
    sq = jnp.sum(v**2, -1)
    pos = sq > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, sq, 1.0)), 0.0)


def _safe_sqrt(x):
    ok = (x > 0) & jnp.isfinite(x)
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, x, 1.0)), jnp.where(x > 0, jnp.inf, 0.0))


def _outline_points(furniture, spacing=0.1):
    """[N, 2] points every ``spacing`` m along the rectangle of each table and chair."""
    out = []
    for it in furniture:
        hx, hy = 0.5 * it["size"][0], 0.5 * it["size"][1]
        corners = np.asarray(it["centre"]) + np.array([[hx, hy], [-hx, hy], [-hx, -hy],
                                                       [hx, -hy], [hx, hy]])
        for a, b in zip(corners[:-1], corners[1:]):
            n = max(int(np.ceil(np.linalg.norm(b - a) / spacing)), 1)
            out.append(a + (b - a) * (np.arange(n) / n)[:, None])
    return np.concatenate(out, 0) if out else np.zeros((0, 2))


def _wall_distance(xy, segments):
    """[N] distance from points [N, 2] to the nearest of the segments [S, 2, 2]."""
    a, b = segments[None, :, 0], segments[None, :, 1]
    ab = b - a
    t = jnp.clip(jnp.sum((xy[:, None] - a) * ab, -1) / jnp.sum(ab * ab, -1), 0.0, 1.0)
    return jnp.min(_norm(xy[:, None] - (a + t[..., None] * ab)), 1)


def _visible(ranges, laser_pose, leg_xy, leg_r, cfg, window=12):
    """[P] a person is visible (not fully occluded) when some beam's return is one of their
    legs: the beam crosses the leg's cross-section within range, and reads no shorter than
    where it enters it (less 5 cm for the range noise). Only the ``2 window + 1`` beams around
    the one nearest to each leg are tested (every beam that can touch a 6 cm leg 0.8 m away
    or farther; the people the laser sees nearer are in plain view)."""
    P = leg_xy.shape[0]
    xy, r = leg_xy.reshape(-1, 2), leg_r.reshape(-1)
    rel = estimators.to_frame(laser_pose, xy)                                # [2P, 2]
    step = math.radians(cfg.step_deg)
    half = 0.5 * (cfg.num_beams - 1)
    centre = jnp.round(jnp.arctan2(rel[:, 1], rel[:, 0]) / step + half).astype(jnp.int32)
    idx = centre[:, None] + jnp.arange(-window, window + 1)                  # [2P, W]
    ok = (idx >= 0) & (idx < cfg.num_beams) & (r[:, None] > 0)
    idx = jnp.clip(idx, 0, cfg.num_beams - 1)
    ang = (idx - half) * step
    dx, dy = jnp.cos(ang), jnp.sin(ang)
    # Ray from the sensor origin along (dx, dy) into the circle of centre rel, radius r.
    b = dx * rel[:, :1] + dy * rel[:, 1:]
    cross = rel[:, :1] * dy - rel[:, 1:] * dx
    disc = r[:, None] ** 2 - cross * cross
    t = b - jnp.sqrt(jnp.where(disc > 0, disc, 0.0))
    hit = ok & (disc > 0) & (t >= 0) & (t < cfg.max_range)
    seen = hit & (ranges[idx] >= t - 0.05)
    return jnp.any(seen.reshape(P, -1), -1)


def laser_geometry(sc: scene_mod.Scene, lcfg: lidar.LaserConfig, dtype):
    """What the laser sees in the scene ``sc``: ``(walls, furniture_legs, circles_of)`` with
    ``circles_of(people) -> (Circles, leg_sections)``, the people's leg cross-sections at the
    laser's height followed by the furniture legs."""
    fc, fr = sc.furniture_circles()
    walls = lidar.Walls(jnp.asarray(sc.wall_segments(), dtype), jnp.ones(4, bool))
    furn = lidar.Circles(jnp.asarray(fc, dtype).reshape(-1, 2), jnp.asarray(fr, dtype),
                         jnp.ones(len(fr), bool))

    def circles_of(people):
        p0, p1, r = pedestrians.leg_capsules(people, sc.gait)
        sec = lidar.capsule_sections(p0.reshape(-1, 3), p1.reshape(-1, 3), r.reshape(-1),
                                     lcfg.height)
        return lidar.Circles(jnp.concatenate([sec.centers.astype(dtype), furn.centers]),
                             jnp.concatenate([sec.radii.astype(dtype), furn.radii]),
                             jnp.concatenate([sec.mask, furn.mask])), sec

    return walls, furn, circles_of


def make_rollout(config: EpisodeConfig):
    """Build ``rollout(key, params) -> Frame`` stacked over the T frames (for plots and tests).

    Example:
      >>> frames = jax.jit(make_rollout(config))(key, make_params(config))
    """
    sc = config.scene
    P = sc.num_people
    dtype = config.dtype
    dt = config.control_dt
    pcfg = scene_mod.pedestrian_config(sc, distractors=config.distractors)
    lcfg = config.laser
    angles = lidar.beam_angles(lcfg, dtype)
    walls, furn, circles_of = laser_geometry(sc, lcfg, dtype)
    ecfg = config.estimator
    substeps = max(1, round(dt / sc.dt))
    map_outline = jnp.asarray(_outline_points(sc.furniture), dtype)
    robot_radius = sc.robot_radius
    multi = ecfg.kind in ("gnn", "jpda", "nnjpda")
    routes = None
    if config.route and map_outline.shape[0]:
        W, H = sc.room
        routes = route_mod.build(np.asarray(map_outline), ((-W / 2, W / 2), (-H / 2, H / 2)),
                                 cell=config.route_cell,
                                 clearance=robot_radius + config.safety_margin + 0.05,
                                 dtype=dtype)

    def rollout(key, params: EpisodeParams):
        k_init, k_est, k_col, k_run = jax.random.split(key, 4)
        people = pedestrians.init(k_init, pcfg, P, dtype)
        pose0 = pedestrians.robot_start(pcfg, people).astype(dtype)
        data = scene_mod.reset(sc, pose0)
        k_col, k_shown = jax.random.split(k_col)
        colours = jax.random.uniform(k_col, (P, 3), dtype)
        # The robot is shown its user: one look at them gives their colour feature.
        shown = jnp.clip(colours[0] + config.rgbd.colour_std
                         * jax.random.normal(k_shown, (3,), dtype), 0.0, 1.0)
        est = estimators.init(k_est, params.estimator, people.pos[0], pose0, shown)
        S = config.max_segments
        carry = _Carry(data, people, pose0, pose0, est, jnp.zeros(2, dtype),
                       jnp.zeros((S, 2), dtype), jnp.zeros(S, bool), jnp.zeros((), dtype),
                       jnp.int32(0), jnp.int32(0), jnp.ones((), dtype))

        def frame(c: _Carry, k):
            ks = jax.random.split(k, 6)
            people = pedestrians.step(ks[0], pcfg, c.people, c.true_pose, dt)
            data = scene_mod.robot_step(sc, c.data, c.u, substeps)
            pose = scene_mod.robot_pose(data).astype(dtype)
            # Odometry: the believed motion in the previous (believed) robot frame.
            delta = rgbd_mod.odometry(ks[1], config.odometry, c.true_pose, pose)
            odom = rgbd_mod.integrate(c.odom, delta)
            # Laser and leg detection (sensor frame), into the odometry frame.
            circles, sec = circles_of(people)
            lpose = lidar.laser_pose(pose, lcfg)
            ranges = lidar.scan(ks[2], lpose, circles, walls, lcfg)
            prev = estimators.to_frame(lidar.laser_pose(odom, lcfg), c.prev_legs)
            det = legs.detect(ranges, angles, config.leg_params, max_segments=S,
                              max_people=config.max_laser_people,
                              prev_legs=(prev, c.prev_legs_mask))
            lodom = lidar.laser_pose(odom, lcfg)
            laser_xy = estimators.from_frame(lodom, det.people.xy.astype(dtype))
            laser_mask = det.people.mask
            world = estimators.from_frame(lpose, det.people.xy.astype(dtype))
            if config.map_filter and furn.centers.shape[0]:
                # The robot knows its map: leg pairs at known furniture legs are not people ...
                d2 = jnp.sum((world[:, None] - furn.centers[None]) ** 2, -1)
                laser_mask = laser_mask & ~jnp.any(d2 < config.map_filter_radius**2, 1)
            if config.map_filter:
                # ... nor are pieces of wall (at grazing incidence the range jumps between
                # beams cut a wall into leg-sized segments).
                laser_mask = laser_mask & (_wall_distance(world, walls.endpoints)
                                           > config.wall_filter_distance)
            # RGB-D detections (robot frame) into the odometry frame.
            rd = rgbd_mod.detect(ks[3], config.rgbd, pose, people.pos, people.mask, colours)
            rgbd_xy = estimators.from_frame(odom, rd.xy.astype(dtype))
            detected = estimators.Detected(laser_xy, laser_mask, rgbd_xy, rd.mask,
                                           rd.colour.astype(dtype))
            truth = None
            if ecfg.kind == "truth":
                truth = jnp.concatenate([
                    estimators.from_frame(odom, estimators.to_frame(pose, people.pos[0])),
                    estimators.rotate(odom[2] - pose[2], people.vel[0])]).astype(dtype)
            est, e = estimators.update(ks[4], c.est, detected, odom, delta[2] / dt,
                                       delta[0] / dt, params.estimator, truth=truth)
            # Control in the robot frame.
            unseen = jnp.where(e.user_found, 0.0, c.unseen + dt)
            rel = estimators.to_frame(odom, e.user[:2])
            vel = estimators.rotate(-odom[2], e.user[2:]) * (unseen <= config.lost_timeout)
            pts, valid = lidar.scan_points(ranges, angles, lcfg)
            corridor = (pts[:, 0] > 0) & (jnp.abs(pts[:, 1]) < robot_radius + 0.05)
            obstacles = pts + jnp.asarray(lcfg.mount, dtype)
            fol = params.follower
            goal, goal_vel = rel, vel
            if routes is not None:
                wp, direct = route_mod.waypoint(
                    routes, pose[:2], estimators.from_frame(pose, rel), map_outline,
                    clearance=robot_radius + config.safety_margin,
                    direct_clearance=config.route_clearance)
                wp = estimators.to_frame(pose, wp)
                # Off the straight line the robot itself (not its follower point) drives to
                # the waypoint.
                reach = wp + _norm(fol.point) * wp / jnp.maximum(_norm(wp), 1e-3)
                goal = jnp.where(direct, rel, reach)
                goal_vel = jnp.where(direct, vel, 0.0)
            blocked = follower.safety_stop(jnp.zeros(3, dtype), obstacles, valid & corridor,
                                           fol.stop_distance, frame="robot")
            u = follower.control(fol, jnp.zeros(3, dtype), goal, goal_vel, c.u, dt, frame="robot",
                                reverse=config.reverse)
            if config.avoidance:
                ap = avoidance.AvoidanceParams(
                    radius=robot_radius, margin=config.safety_margin, horizon=1.0,
                    v_max=fol.v_max, omega_max=fol.omega_max, a_max=fol.a_max,
                    alpha_max=fol.alpha_max, dt=dt, allow_reverse=config.reverse)
                stride = config.avoidance_stride
                known = estimators.to_frame(pose, map_outline)
                # The user walks ahead and is no obstacle to plan around (the safety stop
                # still guards them): returns within 0.45 m of their estimate are left out.
                seen = obstacles[::stride]
                seen_ok = valid[::stride] & ~(_norm(seen - rel) < 0.45)
                u, _ = avoidance.select(ap, u, c.u, jnp.concatenate([seen, known]),
                                        jnp.concatenate([seen_ok,
                                                         jnp.ones(known.shape[0], bool)]))
            # The safety stop blocks forward motion only (backing away stays possible); a user
            # unseen for longer than lost_timeout is searched for by turning on the spot.
            lost_now = unseen > config.lost_timeout
            v = jnp.where(blocked | lost_now, jnp.minimum(u[0], 0.0), u[0])
            # Unseen for longer than search_after, the robot sweeps its cameras' field of view
            # round, turning toward the side where the user was last estimated and keeping
            # that direction (the stale estimate must not make it swing back and forth).
            searching = unseen > config.search_after
            side = jnp.where(searching, c.search_side, jnp.where(rel[1] >= 0.0, 1.0, -1.0))
            target = side * config.search_rate
            if e.look is not None:
                # With colours to tell people apart, a robot that has lost its user for
                # longer than lost_timeout first turns toward the nearest person the colours
                # have not yet told apart from the user, to see them.
                lk = estimators.to_frame(odom, e.look)
                looking = e.look_ok & lost_now
                target = jnp.where(looking, jnp.clip(2.0 * jnp.arctan2(lk[1], lk[0]),
                                                     -config.search_rate, config.search_rate),
                                   target)
                searching = searching | looking
            sweep = c.u[1] + jnp.clip(target - c.u[1], -fol.alpha_max * dt, fol.alpha_max * dt)
            w = jnp.where(searching, sweep, u[1])
            u = jnp.stack([v if config.reverse else jnp.maximum(v, 0.0), w])
            # Metrics (world frame).
            user = people.pos[0]
            fp = estimators.from_frame(pose, params.follower.point)
            err = _norm(fp - user)
            est_world = estimators.from_frame(pose, rel)
            d_est = _norm(people.pos - est_world)
            d_est = jnp.where(people.mask, d_est, jnp.inf)
            who = jnp.argmin(d_est)
            on = jnp.where(d_est[who] <= LOST_DISTANCE, who, -1).astype(jnp.int32)
            switched = (on >= 0) & (c.last_id >= 0) & (on != c.last_id)
            last_id = jnp.where(on >= 0, on, c.last_id)
            leg_xy = sec.centers.reshape(P, 2, 2)
            leg_r = jnp.where(sec.mask, sec.radii, 0.0).reshape(P, 2)
            visible = _visible(ranges, lpose, leg_xy.astype(dtype), leg_r.astype(dtype), lcfg)
            visible = visible & people.mask
            hyp = estimators.from_frame(pose, estimators.to_frame(odom, e.people))
            d_rob = _norm(people.pos - pose[:2]) - robot_radius
            near = jnp.any(people.mask & (d_rob < INTIMATE))
            lw = estimators.from_frame(lpose, det.people.xy.astype(dtype))
            lu = jnp.min(jnp.where(laser_mask, jnp.sum((lw - user) ** 2, -1), jnp.inf))
            rw = estimators.from_frame(pose, rd.xy.astype(dtype))
            ru = jnp.min(jnp.where(rd.mask, jnp.sum((rw - user) ** 2, -1), jnp.inf))
            rec = Frame(pose, people.pos, people.mask, est_world, err,
                        _norm(est_world - user) > LOST_DISTANCE, visible,
                        hyp, e.people_ids, e.people_mask & multi, near, blocked, u,
                        _safe_sqrt(lu), _safe_sqrt(ru))
            new = _Carry(data, people, pose, odom, est, u,
                         estimators.from_frame(lodom, det.legs_xy.astype(dtype)),
                         det.legs_mask, unseen, last_id, c.switches + switched,
                         side.astype(dtype))
            return new, (rec, switched)

        keys = jax.random.split(k_run, config.num_frames)
        _, (frames, switched) = jax.lax.scan(frame, carry, keys)
        return frames, switched

    return rollout


def summarize(config: EpisodeConfig, frames: Frame, switched: Array) -> dict:
    """Episode metrics (module docstring) from a rollout's `Frame` record."""
    f = frames
    dtype = f.follow_error.dtype
    P = config.scene.num_people
    out = {
        "following_rms": jnp.sqrt(jnp.mean(f.follow_error**2)),
        "lost_fraction": jnp.mean(f.lost.astype(dtype)),
        "user_switches": jnp.sum(switched).astype(jnp.int32),
        "near_fraction": jnp.mean(f.near.astype(dtype)),
        "stop_fraction": jnp.mean(f.stopped.astype(dtype)),
    }
    if config.estimator.kind in ("gnn", "jpda", "nnjpda"):
        T = f.people.shape[0]
        gt_ids = jnp.broadcast_to(jnp.arange(P, dtype=jnp.int32), (T, P))
        hyp_ids = jnp.where(f.hyp_mask, f.hyp_ids, -1)
        mot = jmetrics.clear_mot(gt_ids, f.people, f.visible, hyp_ids, f.hyp_pos, f.hyp_mask,
                                 MOT_THRESHOLD, num_ids=P)
        out.update(mota=mot.mota, motp=mot.motp, mot_switches=mot.num_switches)
    else:
        out.update(mota=jnp.asarray(jnp.nan, dtype), motp=jnp.asarray(jnp.nan, dtype),
                   mot_switches=jnp.int32(-1))
    return out


def make_episode(config: EpisodeConfig):
    """Build ``episode(key, params) -> metrics`` (a dict of scalars, see the module docstring)
    for `jaxtrack.montecarlo.evaluate`.

    Example:
      >>> episode = make_episode(EpisodeConfig(scene.build()))
      >>> m = jax.jit(episode)(jax.random.PRNGKey(0), make_params(config))
    """
    rollout = make_rollout(config)

    def episode(key, params):
        return summarize(config, *rollout(key, params))

    return episode
