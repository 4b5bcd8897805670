r"""The closed loop of seed 000, one episode as a pure function of (key, params).

Every control period (``frame_dt``, the seed's ~4 Hz) is five stages:

1. **world step** (world frame): the walking pattern generator (`gait`) executes the last
   command for ``frame_dt`` in sub-steps (nothing before the first command);
2. **sense**: the true gait state is posed (`gait.qpos`), MJX kinematics gives the geom poses,
   and the zenithal camera renders the robot's window (`sensor.robot_point_cloud`: the cloud's
   derivative moves rigidly with the torso, see `sensor`), adds Kinect noise, back-projects and
   removes the background (the floor, and the floor objects the camera stored,
   `sensor.static_heights`); the ``max_points`` highest points are kept (a fixed capacity: the robot
   shows about 40 points at 80 x 60);
3. **estimate**: the tracker (`jaxtrack.tracking.humanoid`: ``"pf"``, the seed's SIR over
   (x, y) with the PCA heading; ``"pf3"``, SIR over (x, y, theta); ``"ukf"``, a UKF on the
   centroid) updates its pose estimate (x, y, theta);
4. **behave**: the reach controller (`jaxtrack.control.pose`, Algorithm 1 with the 5 cm /
   10 deg latched stop) turns the estimate into a body-frame velocity and turn rate; the stop
   region is tested on the estimate averaged over the last three step cycles (see "Sway");
5. **record**: the true and estimated poses and the stop flags of the frame.

Sway. The CoM of a walking biped sways sideways by about +-3 cm at the step frequency (and the
torso yaw by +-3 deg): tested on the instantaneous estimate, the 5 cm stop fires at a sway
extreme (measurements: docs/design_notes.md, "Humanoid: the stop rule on step-cycle averages
(sway)"). The seed's ground truth is hand-marked positions smoothed by a fitted polynomial
(section 5.4), which does not hold the sway either.
So the stop rule and the success criterion both use sway-free poses, with the seed's
5 cm / 10 deg thresholds unchanged: the controller stops when the *estimate averaged over
whole step cycles* (``sway_frames`` frames, a multiple of the left-right sway period
2 * step_period / frame_dt = 4 frames, whose odd harmonics cancel exactly in the mean; three
periods, 12 frames, by default, see "Failures") is in the region, and an episode succeeds when
the *true pose averaged over the same frames* is. The command itself still follows the latest
estimate (no added lag). ``sway_frames=1`` restores the instantaneous rule and criterion.

Failures. Failed episodes mostly stop when the averaged estimate first enters the region, with
the true pose just outside it; averaging the stop pose over more whole sway periods lowers its
noise without a bias, hence three (measurements: docs/design_notes.md, "Humanoid: three sway
periods in the stop average (failures)").

`make_episode` returns ``episode(key, params) -> metrics`` for `jaxtrack.montecarlo.evaluate`;
``params`` is an `EpisodeParams` (task and tunable floats, traced: new tasks do not recompile).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack.angles import wrap
from jaxtrack.control import pose as control
from jaxtrack.tracking import humanoid
from sims.humanoid import gait, scene as scene_mod, sensor

Array = jax.Array

__all__ = ["TRACKERS", "EpisodeConfig", "EpisodeParams", "State", "make_params", "make_episode",
           "walker_positions", "floor_object_layout", "footprint_distance", "seed_task_params"]

TRACKERS = humanoid.TRACKERS
FLOOR_THRESHOLD = 0.06   # background subtraction margin (m): `sensor.remove_floor`'s default


class EpisodeParams(NamedTuple):
    """Per-episode inputs (float leaves; traced, so they can be batched or differentiated).

    Attributes:
      start: [3] initial pose (x, y, theta).
      target: [3] target pose.
      gains: `control.PoseGains` (log lambda_x, log lambda_theta).
      log_position_noise: log std (m) of the tracker's random-walk propagation per frame.
      log_temperature: None (default) for the seed's likelihood weight log(n + 1), or log T of
        the tempered weight exp(n / T) of the pf and pf3 trackers: a traced value, so the
        likelihood's sharpness can be swept or tuned by gradient without recompiling.
    """

    start: Array
    target: Array
    gains: control.PoseGains
    log_position_noise: Array
    log_temperature: Array | None = None

    @property
    def tracker(self) -> humanoid.DepthTrackerParams:
        """The tracker's parameters (`jaxtrack.tracking.humanoid.DepthTrackerParams`)."""
        return humanoid.DepthTrackerParams(self.log_position_noise, self.log_temperature)


@dataclasses.dataclass(frozen=True, eq=False)
class EpisodeConfig:
    """Static configuration of an episode (closed over; changing it recompiles), by concern.

    Attributes:
      scene: `scene.Scene` (resolution, camera).
      tracker: the tracker's configuration (`jaxtrack.tracking.humanoid`: `DepthPFConfig`
        "pf", `DepthPF3Config` "pf3" or `CentroidUKFConfig` "ukf"), or its name.
      num_frames: control periods per episode (200: the acceptance budget).
      frame_dt: control / tracking period (s); 0.25 is the seed's ~4 Hz.
      substeps: gait sub-steps per frame.
      gait_params: `gait.GaitParams`.
      planner: the gait's footstep planner (`gait.preview_planner`): ``"dcm"`` (the deadbeat
        DCM planner, default) or ``"preview-qp"`` (Herdt et al.'s preview QP, seed 000
        section 4) or a `jaxtrack.control.walking_mpc.PreviewConfig`.
      noise: `sensor.DepthNoise`.
      limits: `control.PoseLimits`.
      max_points: point-cloud capacity after floor removal.
      sway_frames: frames of the step-cycle average used by the stop rule and the success
        criterion (module notes); None: three step cycles,
        ``3 * round(2 * step_period / frame_dt)``; 1: instantaneous.
      smooth: `humanoid.SmoothConfig` for the differentiable variant (sigmoid-edged count,
        differentiable resampling, smooth stop gate) for gradient tuning; None: the seed's.
      dtype: float dtype of the simulation.
      walkers: people walking near the robot (seed 000 section 5.6: occlusion from the
        camera), each pacing back and forth at ``walker_speed`` (m/s) along a straight line
        1.5 m either side of a point 0.25-0.8 m beside the route, in a random direction
        (`walker_positions`); each is a 1.7 m tall capsule of radius 0.2 m in the depth image.
        0: none (the episode's random draws are then those of a scene without people).
      floor_objects: boxes standing on the floor beside the route (seed 000 section 5.6's
        robustness to other things in the camera's view), static for the episode
        (`floor_object_layout`): footprints 0.1-0.4 m a side at a random yaw, 0.1-0.5 m
        tall (below ``max_point_height``, so their tops enter the robot's cloud where they
        fall in its window), centred at a uniform fraction 0.1-0.9 of the way, their nearest
        edge 0.2-0.5 m to a random side of the straight route. They are seen, not felt: the
        gait walks through them, so the metrics add ``object_clearance`` (m), the least
        distance of the true torso to a footprint. Drawn from their own key: the walkers'
        and the episode's draws do not change. 0: none.
      static_background: the camera's background image holds the floor objects (stored with
        them in place before the robot entered, `sensor.static_heights`), so their points are
        background, as the floor's are; False: only the floor is known (the objects' points
        enter the cloud). Without floor objects it changes nothing.
      max_point_height: points higher than this (0.7 m) are not the robot's (a NAO is 0.57 m
        tall; the camera's noise at that range is about 1 cm): dropped before the
        ``max_points`` highest are kept, so that a person's head, shoulders and the side of
        their body facing the camera never enter the cloud.
      record: also return what a recording of the camera holds, per frame (for writing a
        depth bag: `sims.humanoid.recording`): ``window_points`` [T, K*K, 3] (every pixel of
        the rendered window back-projected, noisy; invalid pixels at the camera centre),
        ``window_row`` / ``window_col`` [T] (its top-left pixel), ``tracker_keys`` [T, 2]
        (the key the tracker drew with), ``tracker_init_key`` (the one it started with) and
        ``turn_rate`` [T] (its control input).
    """

    scene: scene_mod.Scene
    tracker: object = humanoid.DepthPFConfig()
    num_frames: int = 200
    frame_dt: float = 0.25
    substeps: int = 5
    gait_params: gait.GaitParams = gait.GaitParams()
    noise: sensor.DepthNoise = sensor.DepthNoise()
    limits: control.PoseLimits = control.PoseLimits()
    max_points: int = 96
    sway_frames: int | None = None
    smooth: humanoid.SmoothConfig | None = None
    dtype: type = jnp.float32
    walkers: int = 0
    walker_speed: float = 0.8
    max_point_height: float = 0.7
    record: bool = False
    planner: object = "dcm"
    floor_objects: int = 0
    static_background: bool = True


def make_params(target, start=(0.0, 0.0, 0.0), lambda_x=0.1, lambda_theta=0.2,
                position_noise=0.035, temperature=None, dtype=jnp.float32) -> EpisodeParams:
    """`EpisodeParams` from plain values, checked at the boundary.

    Args:
      target: [3] target pose; start: [3] initial pose (both finite; headings in rad).
      lambda_x, lambda_theta: controller gains (1/s, > 0).
      position_noise: tracker propagation std (m, > 0); 0.035 follows the CoM sway (up to 7 cm
        between two 4 Hz frames; measurements: docs/design_notes.md, "Humanoid: tracker
        propagation noise 0.035 m").
      temperature: None for the seed's weight, or T > 0 for the tempered weight exp(n / T),
        stored as the traced ``log_temperature``; the seed's weight leaves the estimate near the
        visible points' centroid, which the camera pulls toward itself (measurements:
        docs/design_notes.md, "Humanoid: the likelihood temperature").

    Example:
      >>> params = make_params([1.0, 0.0, -math.pi / 2])
    """
    target = np.asarray(target, float)
    start = np.asarray(start, float)
    for name, value in (("target", target), ("start", start)):
        if value.shape != (3,):
            raise ValueError(f"{name} must be a pose [3] (x, y, theta); got shape "
                             f"{list(value.shape)}")
        if not np.all(np.isfinite(value)):
            raise ValueError(f"{name} must be finite; got {value.tolist()}")
    positive = [("lambda_x", lambda_x), ("lambda_theta", lambda_theta),
                ("position_noise", position_noise)]
    if temperature is not None:
        positive.append(("temperature", temperature))
    for name, value in positive:
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a finite positive number; got {value}")
    tp = humanoid.depth_pf().params(position_noise=position_noise, temperature=temperature,
                                    dtype=dtype)
    return EpisodeParams(jnp.asarray(start, dtype), jnp.asarray(target, dtype),
                         control.PoseGains(jnp.asarray(math.log(lambda_x), dtype),
                                           jnp.asarray(math.log(lambda_theta), dtype)),
                         tp.log_position_noise, tp.log_temperature)


def seed_task_params(dtype=jnp.float32, **kwargs) -> list[EpisodeParams]:
    """The seed's 15 tasks (`control.seed_tasks`) as `EpisodeParams`, from (0, 0, 0)."""
    return [make_params(t, dtype=dtype, **kwargs) for t in np.asarray(control.seed_tasks())]


class Pending(NamedTuple):
    """The command the gait executes over the next frame, with its noise key: body_velocity
    [2], turn_rate, stop (bool), key; ``started`` is False before the first command."""

    body_velocity: Array
    turn_rate: Array
    stop: Array
    key: Array
    started: Array


class State(NamedTuple):
    """The closed loop between frames: gait (`gait.GaitState`, world frame), tracker (the
    estimator's state), control (`control.ReachState` or `SmoothReachState`), history [n, 3]
    (the last estimates, for the sway-free stop pose), pending (`Pending`)."""

    gait: gait.GaitState
    tracker: object
    control: object
    history: Array
    pending: Pending


def make_episode(config: EpisodeConfig):
    """Build ``episode(key, params) -> metrics`` for one static configuration.

    Each frame is: **world step** (the gait executes the last command for ``frame_dt``, in
    sub-steps) -> **sense** (pose the model, render the ceiling camera's window, keep the
    ``max_points`` highest points) -> **estimate** (the tracker) -> **behave** (the reach
    controller, its stop rule on the step-cycle average) -> **record**.

    Metrics (dict of arrays):
      ``pos_err_median``, ``pos_err_max``: tracker position error (m) over the frames up to the
      stop; ``heading_err_mean``, ``heading_err_std``: tracker heading error (deg) vs the torso
      yaw; ``success``: 1.0 if the controller stopped and the *true* pose averaged over the
      last step cycles up to the stop frame (``sway_frames`` frames) was within 5 cm and 10 deg
      of the target; ``frames_to_stop``: frames until the stop (``num_frames`` if
      never); ``final_pos_err`` (m), ``final_heading_err`` (deg): true final pose error;
      ``pos_err`` [T], ``heading_err`` [T], ``active`` [T]: per-frame errors and mask;
      ``truth`` [T, 3], ``estimate`` [T, 3]: trajectories.

    Example:
      >>> episode = make_episode(EpisodeConfig(scene.build()))
      >>> metrics = jax.jit(episode)(key, make_params([1.0, 0.0, 0.0]))
    """
    tracker = humanoid.build(config.tracker, config.frame_dt, config.smooth)
    if config.num_frames < 1 or config.substeps < 1:
        raise ValueError("num_frames and substeps must be positive")
    if config.walkers < 0 or config.floor_objects < 0:
        raise ValueError(f"walkers and floor_objects must be >= 0; got {config.walkers} and "
                         f"{config.floor_objects}")
    if getattr(config.tracker, "num_particles", 1) < 1:
        raise ValueError("num_particles must be positive")
    sc = config.scene
    dtype = config.dtype
    smooth = config.smooth is not None
    bg = sensor.background(sc, dtype)
    k_win = sensor.window_size(sc.camera)
    n_pts = min(config.max_points, k_win * k_win)
    sub_dt = config.frame_dt / config.substeps
    gp = config.gait_params
    planner = gait.preview_planner(config.planner)
    n_avg = (3 * max(1, round(2 * gp.step_period / config.frame_dt)) if config.sway_frames is None
             else config.sway_frames)
    if n_avg < 1:
        raise ValueError(f"sway_frames must be >= 1; got {config.sway_frames}")

    def world_step(g, p: Pending, frame_index=None):
        """The gait executes the pending command for one frame (nothing before the first).

        With the preview QP, ``frame_index`` (unbatched) says at which sub-steps it is solved:
        every episode starts walking at frame 1 with a step, so the QP's sample instants are
        the same sub-steps in every episode, and ``lax.cond`` skips the solve in between even
        under ``vmap`` (the gait's own schedule, from its phase, is the same)."""
        def sub(gg, x):
            kk, i = x
            solve = (None if frame_index is None else
                     gait.solve_schedule((frame_index - 1) * config.substeps + i, sub_dt, planner))
            return gait.step(kk, gg, p.body_velocity, p.turn_rate, p.stop, gp, sub_dt,
                             planner, solve), None

        stepped, _ = jax.lax.scan(sub, g, (jax.random.split(p.key, config.substeps),
                                           jnp.arange(config.substeps)))
        return jax.tree_util.tree_map(lambda a, b: jnp.where(p.started, a, b), stepped, g)

    def sense(key, g, turn_rate, walkers, objects):
        """The true torso pose, and the camera's points of the robot (world frame), in front
        of which the walkers and the floor objects (`sensor.Occluders` or None) stand."""
        truth = gait.torso_pose(g, gp)
        q = gait.qpos(sc, g, gp)
        xpos, xmat = scene_mod.pose_geoms(sc, q)
        stored = objects if config.static_background else None
        occ = [_walker_geoms(walkers, dtype)] if walkers is not None else []
        occ = _join_occluders(occ + ([objects] if objects is not None and stored is None
                                     else []))
        pts, mask = sensor.robot_point_cloud(key, sc, xpos, xmat, truth, k_win, bg,
                                             config.noise, FLOOR_THRESHOLD, dtype=dtype,
                                             occluders=occ, static=stored)
        mask = mask & (pts[:, 2] <= config.max_point_height)
        score = jnp.where(mask, pts[:, 2], -jnp.inf)
        _, idx = jax.lax.top_k(score, n_pts)
        window = ((pts, *sensor.window_origin(sc.camera, truth[:2], k_win)) if config.record
                  else ())
        return truth, humanoid.DepthScan(pts[idx], mask[idx], turn_rate), window

    def behave(s: State, est, target, params: EpisodeParams):
        """The reach controller; its stop rule sees the estimate averaged over the last step
        cycles (``stop_pose``), its command the latest estimate."""
        history = jnp.concatenate([s.history[1:], est[None]])
        if smooth:
            cstate, cmd = control.smooth_step(s.control, est, target, params.gains,
                                              config.limits, stop_pose=_pose_mean(history))
            return cstate, history, cmd, cmd.stopped > 0.5
        cstate, cmd = control.step(s.control, est, target, params.gains, config.limits,
                                   stop_pose=_pose_mean(history))
        return cstate, history, cmd, cmd.stopped

    def frame(s: State, key, target, params: EpisodeParams, walkers=None, index=None,
              objects=None):
        k_obs, k_trk, k_gait = jax.random.split(key, 3)
        g = world_step(s.gait, s.pending, index)
        truth, scan, window = sense(k_obs, g, s.pending.turn_rate, walkers, objects)
        tstate, est = tracker.update(k_trk, s.tracker, scan, params.tracker)
        recorded = (*window, k_trk, scan.turn_rate) if config.record else ()
        cstate, history, cmd, stop = behave(s, est, target, params)
        was_stopped = (s.control.moving < 0.5) if smooth else s.control.stopped
        pending = Pending(cmd.body_velocity, cmd.turn_rate.astype(dtype), stop, k_gait,
                          jnp.asarray(True))
        return State(g, tstate, cstate, history, pending), (truth, est, ~was_stopped,
                                                            cmd.stopped, recorded)

    def episode(key, params: EpisodeParams):
        start = jnp.asarray(params.start, dtype)
        target = jnp.asarray(params.target, dtype)
        k_init, k_run = jax.random.split(key)
        state = State(gait.init(start, gp, dtype, planner),
                      tracker.init(k_init, params.tracker, start),
                      control.smooth_init(dtype) if smooth else control.init(),
                      jnp.broadcast_to(start, (n_avg, 3)),
                      Pending(jnp.zeros(2, dtype), jnp.zeros((), dtype), jnp.asarray(False),
                              k_run, jnp.asarray(False)))
        keys = jax.random.split(k_run, config.num_frames)
        frames = jnp.arange(config.num_frames)
        objects = (floor_object_layout(jax.random.fold_in(key, 2), start, target,
                                       config.floor_objects) if config.floor_objects else None)
        if config.walkers:
            paths = walker_positions(jax.random.fold_in(key, 1), start, target, config.walkers,
                                     config.num_frames, config.frame_dt, config.walker_speed)
            state, (truth, est, active, stopped, recorded) = jax.lax.scan(
                lambda s, x: frame(s, x[0], target, params, x[1], x[2], objects), state,
                (keys, paths, frames))
        else:
            state, (truth, est, active, stopped, recorded) = jax.lax.scan(
                lambda s, x: frame(s, x[0], target, params, index=x[1], objects=objects),
                state, (keys, frames))
        # The last command's frame, then let a stopped robot finish its step and settle before
        # the final pose is read.
        final = gait.torso_pose(_settle(world_step(state.gait, state.pending), gp, sub_dt,
                                        planner), gp)
        metrics = _metrics(config, n_avg, start, target, truth, est, active, stopped, final)
        if objects is not None:
            metrics["object_clearance"] = jnp.min(footprint_distance(objects, truth[:, :2]))
        if config.record:
            metrics.update(zip(("window_points", "window_row", "window_col", "tracker_keys",
                                "turn_rate"), recorded))
            metrics["tracker_init_key"] = k_init
        return metrics

    return episode


def walker_positions(key, start, target, num: int, num_frames: int, frame_dt: float,
                     speed: float = 0.8) -> Array:
    """[T, num, 2] positions of people pacing near the route from ``start`` to ``target``
    (`EpisodeConfig.walkers`): walker i walks back and forth (a triangle wave, 1.5 m either
    side) along a line in a uniform random direction through a point beside the route (a
    uniform fraction 0.2-0.8 of the way, 0.25-0.8 m to a random side), at a random phase."""
    k = jax.random.split(key, 5)
    dtype = start.dtype
    route = target[:2] - start[:2]
    length = jnp.maximum(jnp.linalg.norm(route), 1e-3)
    normal = jnp.stack([-route[1], route[0]]) / length
    u = jax.random.uniform(k[0], (num,), dtype, 0.2, 0.8)
    side = jnp.where(jax.random.bernoulli(k[1], 0.5, (num,)), 1.0, -1.0).astype(dtype)
    off = jax.random.uniform(k[2], (num,), dtype, 0.25, 0.8)
    centre = start[:2] + u[:, None] * route + (side * off)[:, None] * normal
    angle = jax.random.uniform(k[3], (num,), dtype, 0.0, 2 * math.pi)
    direction = jnp.stack([jnp.cos(angle), jnp.sin(angle)], -1)
    phase = jax.random.uniform(k[4], (num,), dtype)
    amplitude = 1.5
    t = (jnp.arange(1, num_frames + 1, dtype=dtype) * frame_dt)[:, None]
    cycle = (t * speed / (4 * amplitude) + phase) % 1.0            # [T, num]
    s = amplitude * (1.0 - 4.0 * jnp.abs(cycle - 0.5))             # -A .. A .. -A
    return centre + s[..., None] * direction


def _walker_geoms(xy, dtype) -> sensor.Occluders:
    """Walkers [W, 2] as standing capsules 1.7 m tall, radius 0.2 m."""
    W = xy.shape[0]
    xpos = jnp.concatenate([xy, jnp.full((W, 1), 0.85, dtype)], -1)
    sizes = jnp.broadcast_to(jnp.asarray([0.2, 0.65, 0.0], dtype), (W, 3))
    return sensor.Occluders(np.full(W, 3), sizes, xpos.astype(dtype),
                            jnp.broadcast_to(jnp.eye(3, dtype=dtype), (W, 3, 3)))


def floor_object_layout(key, start, target, num: int) -> sensor.Occluders:
    """``num`` boxes on the floor beside the straight route from ``start`` to ``target``
    (`EpisodeConfig.floor_objects`), as `sensor.Occluders` (MuJoCo box sizes: half extents).

    Box i has half sides a, b ~ U(0.05, 0.2) m, height h ~ U(0.1, 0.5) m and yaw
    psi ~ U(0, pi); its centre lies at a fraction u ~ U(0.1, 0.9) of the route and at
    ``c + a |cos(psi - phi)| + b |sin(psi - phi)|`` to a random side of it (phi: the route's
    normal's direction), so that its nearest edge is c ~ U(0.2, 0.5) m from the route line.

    Example:
      >>> occ = floor_object_layout(key, jnp.zeros(3), jnp.array([1.0, 0.5, 0.0]), 2)
      >>> occ.sizes.shape, occ.xpos.shape, occ.xmat.shape    # (2, 3) (2, 3) (2, 3, 3)
    """
    k = jax.random.split(key, 6)
    dtype = start.dtype
    route = target[:2] - start[:2]
    length = jnp.maximum(jnp.linalg.norm(route), 1e-3)
    normal = jnp.stack([-route[1], route[0]]) / length
    half = jax.random.uniform(k[0], (num, 2), dtype, 0.05, 0.2)
    height = jax.random.uniform(k[1], (num,), dtype, 0.1, 0.5)
    yaw = jax.random.uniform(k[2], (num,), dtype, 0.0, math.pi)
    u = jax.random.uniform(k[3], (num,), dtype, 0.1, 0.9)
    side = jnp.where(jax.random.bernoulli(k[4], 0.5, (num,)), 1.0, -1.0).astype(dtype)
    clearance = jax.random.uniform(k[5], (num,), dtype, 0.2, 0.5)
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    # Half extent of the rotated footprint along the normal: a |e1 . n| + b |e2 . n|.
    across = (half[:, 0] * jnp.abs(c * normal[0] + s * normal[1])
              + half[:, 1] * jnp.abs(-s * normal[0] + c * normal[1]))
    centre = (start[:2] + u[:, None] * route
              + (side * (clearance + across))[:, None] * normal)
    xpos = jnp.concatenate([centre, 0.5 * height[:, None]], -1)
    sizes = jnp.concatenate([half, 0.5 * height[:, None]], -1)
    zero, one = jnp.zeros_like(c), jnp.ones_like(c)
    xmat = jnp.stack([jnp.stack([c, -s, zero], -1), jnp.stack([s, c, zero], -1),
                      jnp.stack([zero, zero, one], -1)], -2)
    return sensor.Occluders(np.full(num, 6), sizes, xpos, xmat)


def footprint_distance(objects: sensor.Occluders, xy: Array) -> Array:
    """[T] least distance (m) of points ``xy`` [T, 2] to the footprints of upright boxes
    `sensor.Occluders` (0 inside one; inf without boxes)."""
    rel = xy[:, None, :] - objects.xpos[None, :, :2]                       # [T, G, 2]
    local = jnp.einsum("tgi,gij->tgj", rel, objects.xmat[:, :2, :2])       # R^T (p - c)
    outside = jnp.maximum(jnp.abs(local) - objects.sizes[None, :, :2], 0.0)
    return jnp.min(jnp.linalg.norm(outside, axis=-1), axis=-1, initial=jnp.inf)


def _join_occluders(parts) -> sensor.Occluders | None:
    """One `sensor.Occluders` of several (None if there are none)."""
    if not parts:
        return None
    if len(parts) == 1:
        return parts[0]
    return sensor.Occluders(np.concatenate([p.types for p in parts]),
                            *(jnp.concatenate([getattr(p, f) for p in parts])
                              for f in ("sizes", "xpos", "xmat")))


def _metrics(config, n_avg, start, target, truth, est, active, stopped, final):
    """The episode metrics of `make_episode` from its per-frame record."""
    dtype = config.dtype
    smooth = config.smooth is not None
    pos_err = jnp.linalg.norm(est[:, :2] - truth[:, :2], axis=-1)
    head_err = jnp.rad2deg(jnp.abs(wrap(est[:, 2] - truth[:, 2])))
    stopped_any = jnp.any(stopped > 0.5) if smooth else jnp.any(stopped)
    frames_to_stop = jnp.sum(active).astype(dtype)
    final_pos_err = jnp.linalg.norm(final[:2] - target[:2])
    final_head_err = jnp.rad2deg(jnp.abs(wrap(final[2] - target[2])))
    # Success: the controller stopped and the true pose averaged over the last step cycles up
    # to the stop frame (the frames whose estimates made the stop decision; the start pose
    # before the first frame) was within the stop region (5 cm / 10 deg). The settled pose (CoM
    # between the feet) is reported separately as final_pos_err / final_heading_err.
    first = jnp.argmax(stopped > 0.5) if smooth else jnp.argmax(stopped)
    padded = jnp.concatenate([jnp.broadcast_to(start, (n_avg - 1, 3)), truth])
    at_stop = _pose_mean(jax.lax.dynamic_slice_in_dim(padded, first, n_avg))
    stop_pos_err = jnp.linalg.norm(at_stop[:2] - target[:2])
    stop_head_err = jnp.rad2deg(jnp.abs(wrap(at_stop[2] - target[2])))
    success = (stopped_any & (stop_pos_err <= config.limits.stop_distance)
               & (stop_head_err <= math.degrees(config.limits.stop_angle)))
    nan = jnp.asarray(jnp.nan, dtype)
    pos_active = jnp.where(active, pos_err, nan)
    head_active = jnp.where(active, head_err, nan)
    return {
        "pos_err_median": jnp.nanmedian(pos_active),
        "pos_err_max": jnp.nanmax(pos_active),
        "heading_err_mean": jnp.nanmean(head_active),
        "heading_err_std": jnp.nanstd(head_active),
        "success": success.astype(dtype),
        "frames_to_stop": frames_to_stop,
        "final_pos_err": final_pos_err,
        "final_heading_err": final_head_err,
        "pos_err": pos_err, "heading_err": head_err, "active": active,
        "truth": truth, "estimate": est,
    }


def _pose_mean(poses):
    """Mean of poses [K, 3]: positions averaged, headings on the circle about the latest."""
    latest = poses[-1, 2]
    heading = wrap(latest + jnp.mean(wrap(poses[:, 2] - latest)))
    return jnp.concatenate([jnp.mean(poses[:, :2], 0), heading[None]])


def _settle(gstate, gp, dt, planner=None, steps: int = 20):
    def body(g, _):
        return gait.step(jax.random.PRNGKey(0), g, jnp.zeros(2, g.com.dtype), 0.0, True, gp,
                         dt, planner), None

    return jax.lax.scan(body, gstate, None, length=steps)[0]
