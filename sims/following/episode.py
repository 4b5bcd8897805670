"""One closed-loop person-following episode: people walk, the robot senses, estimates, follows.

Each 10 Hz frame (``control_dt``) is five stages, each in one frame of reference:

1. **world step** (world frame, `sims.following.world.step`): the pedestrians step (avoiding each
   other and the robot), and the robot applies the last command through MJX physics;
2. **sense**: the simulated sensors (`sims.following.world.observe`: odometry, laser, RGB-D
   detector), then the sensing step (`jaxtrack.perception.sensing.sense`: leg detection, laser
   and RGB-D people into the odometry frame, the map filter);
3. **estimate** (odometry frame): the user estimator (`jaxtrack.tracking.user`);
4. **behave** (robot frame): the following behaviour (`jaxtrack.control.behaviour`: follower law,
   route, avoidance, safety stop, search);
5. **record** (world frame): the per-frame `Frame`, every world-frame metric computed once.

Metrics (per episode, `summarize`; the frames are ``T = duration / control_dt``):

- ``following_rms``: RMS distance between the true follower point and the true user (m);
- ``lost_fraction``: fraction of frames the user estimate is farther than 0.5 m from the user;
- ``user_switches``: times the person the estimate sits on (the true person within 0.5 m of
  it, if any) changes from one person to another;
- ``mota``, ``motp``, ``mot_switches`` (multi-target estimators; NaN otherwise): CLEAR MOT of
  the confirmed tracks, with as ground truth the people inside the laser's field of view and range
  and not fully occluded (some beam's return is one of their legs), threshold 0.5 m;
- ``idf1`` (the identity F1 at the same threshold) and ``hota`` (similarity
  ``max(0, 1 - d / 1 m)``, so that its 0.5 level is the 0.5 m threshold) of the same tracks;
  ``mot_invalid`` counts track presences left out because an episode used more than
  `MAX_TRACK_IDS` track ids (0 in every run measured);
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

from jaxtrack import geometry
from jaxtrack import metrics as jmetrics
from jaxtrack.control import behaviour as behaviour_mod
from jaxtrack.control import follower, pan_tilt
from jaxtrack.perception import sensing
from jaxtrack.tracking import user
from sims.following import lidar, pedestrians, world
from sims.following import scene as scene_mod

Array = jax.Array

__all__ = ["EpisodeConfig", "EpisodeParams", "State", "Frame", "make_params", "make_episode",
           "make_rollout", "summarize", "scenario", "SHOP_BEHAVIOUR", "LOST_DISTANCE",
           "INTIMATE", "MOT_THRESHOLD"]

LOST_DISTANCE = 0.5
INTIMATE = 0.45
MOT_THRESHOLD = 0.5
#: Static bound on the distinct track ids of one episode for the identity metrics and HOTA.
MAX_TRACK_IDS = 512


@dataclasses.dataclass(frozen=True, eq=False)
class EpisodeConfig:
    """Static episode configuration (closed over by `make_episode`), by concern.

    Attributes:
      scene: `sims.following.scene.Scene`.
      estimator: a user-estimator configuration of `jaxtrack.tracking.user`, or the name of
        one (`user.CONFIGS`: its default).
      sensors: `sims.following.world.SensorsConfig` (simulated sensors and the sensing step).
      behaviour: `jaxtrack.control.behaviour.FollowingConfig` (the robot's radius comes from the
        scene, its period from ``control_dt``).
      user: `pedestrians.UserBehaviour` (the shop's user shops by default; ``wander=True``
        gives random walks, the stress test).
      distractors: people besides the user (``1 + distractors <= scene.num_people``).
      duration: simulated seconds; control_dt: control / sensing period (s).
      dtype: float dtype of the estimators and metrics.
    """

    scene: scene_mod.Scene
    estimator: object = user.ParticleConfig()
    sensors: world.SensorsConfig = world.SensorsConfig()
    behaviour: behaviour_mod.FollowingConfig = behaviour_mod.FollowingConfig()
    user: pedestrians.UserBehaviour = pedestrians.UserBehaviour()
    distractors: int = 4
    duration: float = 60.0
    control_dt: float = 0.1
    dtype: object = jnp.float32

    @property
    def num_frames(self) -> int:
        return int(round(self.duration / self.control_dt))

    @property
    def multi_target(self) -> bool:
        """Whether the estimator tracks everyone with identities (CLEAR MOT is scored)."""
        inner = self.estimator
        if isinstance(inner, user.LegTrackedConfig):
            inner = inner.estimator
        return isinstance(inner, user.MultiTargetConfig)

    def __post_init__(self):
        if 1 + self.distractors > self.scene.num_people:
            raise ValueError(f"{1 + self.distractors} people (user + {self.distractors} "
                             f"distractors) exceed the scene's capacity of "
                             f"{self.scene.num_people}")
        if self.distractors < 0 or self.duration <= 0 or self.control_dt <= 0:
            raise ValueError("distractors must be >= 0, duration and control_dt > 0")
        user.build(self.estimator)  # a clear error for what is not an estimator configuration
        if isinstance(self.estimator, str):
            object.__setattr__(self, "estimator", user.CONFIGS[self.estimator])


SHOP_BEHAVIOUR = behaviour_mod.FollowingConfig(safety_margin=0.1, route_clearance=0.4,
                                               reverse=True, pan=pan_tilt.PanTiltConfig())
"""The following behaviour in the shop: the RGB-D camera on a pan unit (seed 004, section V),
a 0.1 m safety margin in 1.9 m aisles, and backing off (at most 0.5 m/s) when the user turns
back toward the cart (docs/design_notes.md, "Person following: the shop's floor")."""


def scenario(layout: str = "shop", estimator="pf", *, wander: bool = False,
             distractors: int = 4, duration: float = 60.0, num_people: int = 8,
             **overrides) -> EpisodeConfig:
    """The person-following scenario of a floor plan: ``"shop"`` (a shopper who leads, among
    other shoppers, followed with `SHOP_BEHAVIOUR`) or ``"room"`` (today's furnished room and
    wandering people, with the default behaviour and a fixed camera).

    Args:
      layout: "shop" or "room" (`sims.following.layout.LAYOUTS`).
      estimator: a user-estimator configuration or name (`jaxtrack.tracking.user`).
      wander: in the shop, the user walks randomly (the stress test) instead of shopping.
      distractors, duration: `EpisodeConfig`'s; num_people: the scene's capacity.
      overrides: other `EpisodeConfig` fields.

    Example:
      >>> config = scenario("shop", "jpda", distractors=4)
    """
    sc = scene_mod.build(num_people=max(num_people, distractors + 1), layout=layout)
    kw = dict(behaviour=SHOP_BEHAVIOUR) if layout == "shop" else {}
    kw.update(user=pedestrians.UserBehaviour(wander=wander))
    kw.update(overrides)
    return EpisodeConfig(sc, estimator, distractors=distractors, duration=duration, **kw)


class EpisodeParams(NamedTuple):
    """Tunable parameters: the follower's (`follower.Params`) and the estimator's."""

    follower: follower.Params
    estimator: object


def make_params(config: EpisodeConfig, point="A", k1=1.0, k2=1.0, **estimator_kw
                ) -> EpisodeParams:
    """Default parameters: follower point ``"A"`` (1.5, 0) or ``"B"`` (1, 1), gains k1, k2, and
    the estimator's ``params(**estimator_kw)`` at the episode's period.

    Example:
      >>> params = make_params(config, point="B", k1=0.8, laser_std=0.15)
    """
    dt = config.dtype
    fp = follower.Params.create(k1=k1, k2=k2, point=point, v_max=1.5, omega_max=2.0,
                                a_max=1.5, alpha_max=4.0,
                                stop_distance=(config.scene.robot_radius
                                               + config.behaviour.safety_margin),
                                dtype=dt)
    ep = user.build(config.estimator).params(dt=config.control_dt, dtype=dt, **estimator_kw)
    return EpisodeParams(fp, ep)


class State(NamedTuple):
    """The closed loop's state between frames.

    Attributes:
      world: `world.World` (world frame). sensing: `sensing.SensingState` (odometry frame).
      odom_pose: [3] the robot's pose in the odometry frame. estimator: the estimator's state.
      behaviour: `behaviour.FollowingState`. last_id, switches: the true person the user
        estimate last sat on, and how often that changed (`Frame.user_switched`).
    """

    world: world.World
    sensing: sensing.SensingState
    odom_pose: Array
    estimator: object
    behaviour: behaviour_mod.FollowingState
    last_id: Array
    switches: Array


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
    user_switched: Array  # the estimate moved from one true person to another
    pan: Array | None = None  # the RGB-D camera's pan angle (rad; None: a fixed camera)
    direct: Array | None = None     # the robot steered straight at the user (not a route)
    avoidance: Array | None = None  # the avoidance layer: 0 kept, 1 replaced, 2 blocked


def _safe_sqrt(x):
    ok = (x > 0) & jnp.isfinite(x)
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, x, 1.0)), jnp.where(x > 0, jnp.inf, 0.0))


def _visible(ranges, laser_pose, leg_xy, leg_r, cfg, window=12):
    """[P] a person is visible (not fully occluded) when some beam's return is one of their
    legs: the beam crosses the leg's cross-section within range, and reads no shorter than
    where it enters it (less 5 cm for the range noise). Only the ``2 window + 1`` beams around
    the one nearest to each leg are tested (every beam that can touch a 6 cm leg 0.8 m away
    or farther; the people the laser sees nearer are in plain view)."""
    P = leg_xy.shape[0]
    xy, r = leg_xy.reshape(-1, 2), leg_r.reshape(-1)
    rel = geometry.to_frame(laser_pose, xy)                                  # [2P, 2]
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


def make_rollout(config: EpisodeConfig):
    """Build ``rollout(key, params) -> Frame`` stacked over the T frames (for plots and tests).

    Example:
      >>> frames = jax.jit(make_rollout(config))(key, make_params(config))
    """
    sc = config.scene
    P = sc.num_people
    dtype = config.dtype
    dt = config.control_dt
    pcfg = scene_mod.pedestrian_config(sc, distractors=config.distractors, user=config.user)
    scfg = config.sensors
    laser = world.laser_world(sc, scfg.laser, dtype)
    static = world.static_map(sc, laser, scfg.map_filter)
    estimator = user.build(config.estimator)
    behave = behaviour_mod.following(config.behaviour, robot_radius=sc.robot_radius, dt=dt,
                                     known=world.known_map(sc), dtype=dtype)
    multi = config.multi_target

    def reset(keys, params: EpisodeParams) -> tuple[State, Array]:
        """The start: people placed, the robot behind its user and shown them; returns the
        state and the people's colours [P, 3]."""
        k_init, k_est, k_col = keys
        w = world.reset(sc, pcfg, k_init, dtype)
        k_col, k_shown = jax.random.split(k_col)
        colours = jax.random.uniform(k_col, (P, 3), dtype)
        # The robot is shown its user: one look at them gives their colour feature.
        shown = jnp.clip(colours[0] + scfg.rgbd.colour_std
                         * jax.random.normal(k_shown, (3,), dtype), 0.0, 1.0)
        prior = user.Prior(w.people.pos[0], w.robot, shown)
        state = State(w, sensing.init(scfg.sensing, dtype), w.robot,
                      estimator.init(k_est, params.estimator, prior), behave.init(dtype),
                      jnp.int32(0), jnp.int32(0))
        return state, colours

    def frame(s: State, key, params: EpisodeParams, colours):
        ks = jax.random.split(key, 6)
        w = world.step(ks[0], sc, pcfg, s.world, s.behaviour.u, dt)
        obs, sensing_state, sensed = sense(ks[1:4], s, w, colours)
        est_state, e = estimator.update(ks[4], s.estimator, sensed, params.estimator)
        beh_state, cmd = behave.step(s.behaviour, _behaviour_inputs(e, sensed, w.robot),
                                     params.follower)
        rec, last_id = record(s, w, obs, sensed, e, cmd, params)
        new = State(w, sensing_state, sensed.odom_pose, est_state, beh_state, last_id,
                    s.switches + rec.user_switched)
        return new, rec

    def sense(keys, s: State, w: world.World, colours):
        """Simulated sensors, then the sensing step; the true user joins the measurement for
        the ``truth`` estimator (odometry frame)."""
        pan = None if s.behaviour.pan is None else s.behaviour.pan.angle
        obs = world.observe(keys, scfg, sc, laser, s.world.robot, w.robot, w.people, colours,
                            pan)
        odom = geometry.compose(s.odom_pose, obs.increment)
        sensing_state, sensed = sensing.sense(
            scfg.sensing, s.sensing, obs.ranges, laser.angles,
            sensing.Odometry(odom, obs.increment), obs.rgbd.xy, obs.rgbd.mask, obs.rgbd.colour,
            static, map_pose=w.robot, period=dt)
        truth = jnp.concatenate([
            geometry.from_frame(odom, geometry.to_frame(w.robot, w.people.pos[0])),
            geometry.rotate(odom[2] - w.robot[2], w.people.vel[0])]).astype(dtype)
        return obs, sensing_state, sensed._replace(truth=truth, camera_pan=pan)

    def record(s: State, w: world.World, obs, sensed, e, cmd, params):
        """The frame's `Frame` in the world frame."""
        pose, people = w.robot, w.people
        user_xy = people.pos[0]
        err = geometry.safe_norm(geometry.from_frame(pose, params.follower.point) - user_xy)
        est_world = geometry.from_frame(pose, geometry.to_frame(sensed.odom_pose, e.user[:2]))
        d_est = geometry.safe_norm(people.pos - est_world)
        d_est = jnp.where(people.mask, d_est, jnp.inf)
        who = jnp.argmin(d_est)
        on = jnp.where(d_est[who] <= LOST_DISTANCE, who, -1).astype(jnp.int32)
        switched = (on >= 0) & (s.last_id >= 0) & (on != s.last_id)
        last_id = jnp.where(on >= 0, on, s.last_id)
        leg_xy = obs.legs.centers.reshape(P, 2, 2)
        leg_r = jnp.where(obs.legs.mask, obs.legs.radii, 0.0).reshape(P, 2)
        visible = _visible(obs.ranges, lidar.laser_pose(pose, scfg.laser), leg_xy.astype(dtype),
                           leg_r.astype(dtype), scfg.laser) & people.mask
        hyp = geometry.from_frame(pose, geometry.to_frame(sensed.odom_pose, e.people))
        d_rob = geometry.safe_norm(people.pos - pose[:2]) - sc.robot_radius
        near = jnp.any(people.mask & (d_rob < INTIMATE))
        lu = jnp.min(jnp.where(sensed.laser_mask,
                               jnp.sum((sensed.laser_map_xy - user_xy) ** 2, -1), jnp.inf))
        rw = geometry.from_frame(pose, obs.rgbd.xy.astype(dtype))
        ru = jnp.min(jnp.where(obs.rgbd.mask, jnp.sum((rw - user_xy) ** 2, -1), jnp.inf))
        rec = Frame(pose, people.pos, people.mask, est_world, err,
                    geometry.safe_norm(est_world - user_xy) > LOST_DISTANCE, visible, hyp,
                    e.people_ids, e.people_mask & multi, near, cmd.stopped, cmd.u,
                    _safe_sqrt(lu), _safe_sqrt(ru), switched, sensed.camera_pan, cmd.direct,
                    cmd.avoidance)
        return rec, last_id

    def rollout(key, params: EpisodeParams) -> Frame:
        k_init, k_est, k_col, k_run = jax.random.split(key, 4)
        state, colours = reset((k_init, k_est, k_col), params)
        keys = jax.random.split(k_run, config.num_frames)
        _, frames = jax.lax.scan(lambda s, k: frame(s, k, params, colours), state, keys)
        return frames

    return rollout


def _behaviour_inputs(e: user.UserEstimate, sensed: sensing.Sensed, map_pose
                      ) -> behaviour_mod.FollowingInputs:
    """The estimate (odometry frame) and the laser returns in the robot frame."""
    odom = sensed.odom_pose
    look = None if e.look is None else geometry.to_frame(odom, e.look)
    return behaviour_mod.FollowingInputs(
        geometry.to_frame(odom, e.user[:2]), geometry.rotate(-odom[2], e.user[2:]),
        e.user_found, sensed.returns_xy, sensed.returns_mask, map_pose, look, e.look_ok)


def _sequential_mean(x: Array) -> Array:
    """Mean over the frames, summed in frame order by a scan. XLA orders a vectorised sum by
    the program's layout, which differs between one device and a sharded batch (a float32 RMS
    then differs in the 7th digit); a sequential sum is the same everywhere, so the metric is
    bit-identical for any batch size and device count (`jaxtrack.montecarlo`)."""
    total, _ = jax.lax.scan(lambda c, v: (c + v, None), jnp.zeros((), x.dtype), x)
    return total / x.shape[0]


def summarize(config: EpisodeConfig, frames: Frame) -> dict:
    """Episode metrics (module docstring) from a rollout's `Frame` record."""
    f = frames
    dtype = f.follow_error.dtype
    P = config.scene.num_people
    out = {
        "following_rms": jnp.sqrt(_sequential_mean(f.follow_error**2)),
        "lost_fraction": jnp.mean(f.lost.astype(dtype)),
        "user_switches": jnp.sum(f.user_switched).astype(jnp.int32),
        "near_fraction": jnp.mean(f.near.astype(dtype)),
        "stop_fraction": jnp.mean(f.stopped.astype(dtype)),
    }
    if config.multi_target:
        T = f.people.shape[0]
        gt_ids = jnp.broadcast_to(jnp.arange(P, dtype=jnp.int32), (T, P))
        hyp_ids = jnp.where(f.hyp_mask, f.hyp_ids, -1)
        mot = jmetrics.clear_mot(gt_ids, f.people, f.visible, hyp_ids, f.hyp_pos, f.hyp_mask,
                                 MOT_THRESHOLD, num_ids=P)
        ident = jmetrics.identity_metrics(gt_ids, f.people, f.visible, hyp_ids, f.hyp_pos,
                                          f.hyp_mask, MOT_THRESHOLD, max_ids=P,
                                          max_hyp_ids=MAX_TRACK_IDS)
        h = jmetrics.hota(gt_ids, f.people, f.visible, hyp_ids, f.hyp_pos, f.hyp_mask,
                          zero_distance=2 * MOT_THRESHOLD, max_ids=P, max_hyp_ids=MAX_TRACK_IDS)
        out.update(mota=mot.mota, motp=mot.motp, mot_switches=mot.num_switches,
                   idf1=ident.idf1.astype(dtype), hota=h.hota.astype(dtype),
                   mot_invalid=ident.num_invalid)
    else:
        nan = jnp.asarray(jnp.nan, dtype)
        out.update(mota=nan, motp=nan, mot_switches=jnp.int32(-1), idf1=nan, hota=nan,
                   mot_invalid=jnp.int32(0))
    return out


def make_episode(config: EpisodeConfig):
    """Build ``episode(key, params) -> metrics`` (a dict of scalars, see the module docstring)
    for `jaxtrack.montecarlo.evaluate`.

    Example:
      >>> config = EpisodeConfig(scene.build())
      >>> m = jax.jit(make_episode(config))(jax.random.PRNGKey(0), make_params(config))
    """
    rollout = make_rollout(config)

    def episode(key, params):
        return summarize(config, rollout(key, params))

    return episode
