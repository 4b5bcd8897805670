r"""The closed loop of seed 000, one episode as a pure function of (key, params).

Every control period (``frame_dt``, the seed's ~4 Hz):

1. the true gait state is posed (`gait.qpos`), MJX kinematics gives the geom poses, and the
   zenithal camera renders the robot's window (`sensor.robot_point_cloud`: the cloud's
   derivative moves rigidly with the torso, see `sensor`), adds Kinect noise, back-projects
   and removes the floor; the ``max_points`` highest points are kept (a fixed
   capacity: the robot shows about 40 points at 80 x 60);
2. the tracker updates its estimate (x, y, theta):

   - ``"pf"``: the seed's tracker, SIR over (x, y) with the point-count likelihood rotated by
     the last heading, then the PCA heading with the continuity window
     (`jaxtrack.perception.depth`);
   - ``"pf3"``: SIR over (x, y, theta) with the same likelihood (heading random walk); the
     likelihood is symmetric under a half turn, so the heading particles are folded to the
     half-circle of the previous estimate (`depth.fold_half_turn`) before their circular mean,
     and the heading particles are propagated with the turn rate commanded over the last frame;
   - ``"ukf"``: a constant-velocity UKF on the centroid of the points near the prediction, with
     the PCA heading;

3. the reach controller (`jaxtrack.control.pose`, Algorithm 1 with the 5 cm / 10 deg latched
   stop) turns the estimate into a body-frame velocity and turn rate; the stop region is
   tested on the estimate averaged over the last three step cycles (see "Sway" below);
4. the walking pattern generator (`gait`) executes it for ``frame_dt`` in sub-steps.

Sway. The CoM of a walking biped sways sideways by about +-3 cm at the step frequency (and the
torso yaw by +-3 deg). Tested on the instantaneous estimate, the 5 cm stop fires when a sway
extreme first grazes the region while the robot's mean position is still 2-3 cm further, and
the true CoM at that instant is as often just outside. The seed's ground truth is hand-marked
positions smoothed by a fitted polynomial (section 5.4), which does not hold the sway either.
So the stop rule and the success criterion both use sway-free poses, with the seed's
5 cm / 10 deg thresholds unchanged: the controller stops when the *estimate averaged over
whole step cycles* (``sway_frames`` frames, a multiple of the left-right sway period
2 * step_period / frame_dt = 4 frames, whose odd harmonics cancel exactly in the mean; three
periods, 12 frames, by default, see "Failures") is in the region, and an episode succeeds when
the *true pose averaged over the same frames* is. The command itself still follows the latest
estimate (no added lag). ``sway_frames=1`` restores the instantaneous rule and criterion.

Failures. With pf on the seed tasks (480 episodes, one-cycle average) the ~5 % failures are
neither timeouts (every episode stopped, 95 % within 135 frames, all within 160), heading
flips nor sway: the stop fires when the averaged estimate first enters the 5 cm / 10 deg
region, where the robot creeps in at lambda_x * 5 cm = 5 mm/s, so the true pose is then at
the threshold give or take the averaged estimate's error, and the *first* entry selects an
error pointing inward (true distance 5.0-5.8 cm, or true heading 10.1-11.9 deg in one failure
out of six). Halving the tracker's error with a sharper likelihood (``temperature=3``) also
removes its lag behind the robot and leaves the rate unchanged (94.8 -> 94.2 %); averaging the
stop pose over more whole sway periods lowers its noise without adding a bias: 1 / 2 / 3
periods gave 94.8 / 95.4 / 96.0 % success and 115 / 117 / 119 median frames to stop (seed:
110-120) on the same keys.

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
from jaxtrack.filters import kalman, particle, ukf
from jaxtrack.perception import depth
from sims.humanoid import gait, scene as scene_mod, sensor

Array = jax.Array

__all__ = ["TRACKERS", "EpisodeConfig", "EpisodeParams", "make_params", "make_episode",
           "seed_task_params"]

TRACKERS = ("pf", "pf3", "ukf")


class EpisodeParams(NamedTuple):
    """Per-episode inputs (float leaves; traced, so they can be batched or differentiated).

    Attributes:
      start: [3] initial pose (x, y, theta).
      target: [3] target pose.
      gains: `control.PoseGains` (log lambda_x, log lambda_theta).
      log_position_noise: log std (m) of the tracker's random-walk propagation per frame.
      log_temperature: None (default) to use ``EpisodeConfig.temperature``, or log T of the
        tempered likelihood weight exp(n / T) of the pf and pf3 trackers, overriding the
        configuration: a traced value, so the likelihood's sharpness can be swept or tuned
        by gradient without recompiling.
    """

    start: Array
    target: Array
    gains: control.PoseGains
    log_position_noise: Array
    log_temperature: Array | None = None


@dataclasses.dataclass(frozen=True, eq=False)
class EpisodeConfig:
    """Static configuration of an episode (closed over; changing it recompiles).

    Attributes:
      scene: `scene.Scene` (resolution, camera).
      tracker: "pf", "pf3" or "ukf".
      num_particles: particles of the PF trackers.
      num_frames: control periods per episode (200: the acceptance budget).
      frame_dt: control / tracking period (s); 0.25 is the seed's ~4 Hz.
      substeps: gait sub-steps per frame.
      gait_params: `gait.GaitParams`.
      noise: `sensor.DepthNoise`.
      model: `depth.RobotModel` of the likelihood.
      limits: `control.PoseLimits`.
      max_points: point-cloud capacity after floor removal.
      heading_noise: heading random-walk std per frame of "pf3" (rad).
      pca_radius, heading_window, heading_gain: PCA heading (`depth.pca_heading`).
      turn_prediction: "pf" and "ukf" trackers: predict the heading with the commanded turn,
        theta_{t-1} + omega * frame_dt, before the PCA update (the seed has no prediction:
        False). The smoothed PCA heading otherwise lags a turning robot, and lowering
        ``heading_gain`` to cut its noise lengthens the lag. Mean heading error over 15 tasks
        x 16 episodes: default gains 3.56 deg without, 3.48 with (gain 0.5), 3.44 / 2.99
        (gain 0.3); gains lambda_x 0.41, lambda_theta 0.93: 3.97 / 3.40 (gain 0.5), 6.06 /
        2.91 (gain 0.3).
      init_spread: std (m) of the initial particle cloud around the given start.
      sway_frames: frames of the step-cycle average used by the stop rule and the success
        criterion (module notes); None: three step cycles,
        ``3 * round(2 * step_period / frame_dt)``; 1: instantaneous.
      smooth: differentiable variant (sigmoid-edged count with ``softness``, differentiable
        resampling, smooth stop gate) for gradient tuning.
      softness: edge width (m) of the smooth count.
      smooth_resampling: resampler of the smooth variant: "stop_gradient" (Scibior & Wood:
        unbiased score of the expected estimate, but its variance grows with the horizon) or
        "ot" (entropy-regularised optimal transport, ``ot_epsilon``: a pathwise-differentiable
        surrogate, the particle cloud moves smoothly with the weights).
      temperature: None for the seed's weight (proportional to the count), or T > 0 for the
        tempered weight exp(n / T) of `depth.log_likelihood` (pf and pf3). With the seed's
        weight the posterior is broad and its mean is close to the centroid of the visible
        points, which the camera pulls toward itself (it sees the near side of the head and
        torso: 2.1 cm on average on the seed tasks, 2.3-2.9 cm at 0.7 m from the optical
        axis); T = 3 sharpens it toward the count's mode: position error median / 95 %
        2.63 / 5.38 -> 1.39 / 2.41 cm on 480 pf episodes, success unchanged (94.8 -> 94.2 %).
        A per-episode ``EpisodeParams.log_temperature`` overrides it (traced).
      dtype: float dtype of the simulation.
    """

    scene: scene_mod.Scene
    tracker: str = "pf"
    num_particles: int = 128
    num_frames: int = 200
    frame_dt: float = 0.25
    substeps: int = 5
    gait_params: gait.GaitParams = gait.GaitParams()
    noise: sensor.DepthNoise = sensor.DepthNoise()
    model: depth.RobotModel = depth.RobotModel()
    limits: control.PoseLimits = control.PoseLimits()
    max_points: int = 96
    heading_noise: float = math.radians(4.0)
    pca_radius: float = 0.25
    heading_window: float = math.radians(20.0)
    heading_gain: float = 0.5
    turn_prediction: bool = False
    init_spread: float = 0.02
    sway_frames: int | None = None
    smooth: bool = False
    softness: float = 0.01
    smooth_resampling: str = "stop_gradient"
    ot_epsilon: float = 0.1
    temperature: float | None = None
    dtype: type = jnp.float32


def make_params(target, start=(0.0, 0.0, 0.0), lambda_x=0.1, lambda_theta=0.2,
                position_noise=0.035, temperature=None, dtype=jnp.float32) -> EpisodeParams:
    """`EpisodeParams` from plain values, checked at the boundary.

    Args:
      target: [3] target pose; start: [3] initial pose (both finite; headings in rad).
      lambda_x, lambda_theta: controller gains (1/s, > 0).
      position_noise: tracker propagation std (m, > 0); 0.035 follows the CoM sway (up to
        7 cm between two 4 Hz frames): 0.02 gave 3.4 / 8.1 cm median / 95 % errors, 0.035
        2.6 / 5.1 cm, 0.05 2.5 / 4.5 cm on 128 episodes of four seed tasks.
      temperature: None to keep ``EpisodeConfig.temperature`` (by default the seed's weight), or
        T > 0 for the tempered weight exp(n / T), stored as the traced ``log_temperature``.

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
    log_t = None if temperature is None else jnp.asarray(math.log(temperature), dtype)
    return EpisodeParams(jnp.asarray(start, dtype), jnp.asarray(target, dtype),
                         control.PoseGains(jnp.asarray(math.log(lambda_x), dtype),
                                           jnp.asarray(math.log(lambda_theta), dtype)),
                         jnp.asarray(math.log(position_noise), dtype), log_t)


def seed_task_params(dtype=jnp.float32, **kwargs) -> list[EpisodeParams]:
    """The seed's 15 tasks (`control.seed_tasks`) as `EpisodeParams`, from (0, 0, 0)."""
    return [make_params(t, dtype=dtype, **kwargs) for t in np.asarray(control.seed_tasks())]


def make_episode(config: EpisodeConfig):
    """Build ``episode(key, params) -> metrics`` for one static configuration.

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
    if config.tracker not in TRACKERS:
        raise ValueError(f"unknown tracker {config.tracker!r}; choose one of {TRACKERS}")
    if config.num_frames < 1 or config.substeps < 1 or config.num_particles < 1:
        raise ValueError("num_frames, substeps and num_particles must be positive")
    sc = config.scene
    dtype = config.dtype
    bg = sensor.background(sc, dtype)
    k_win = sensor.window_size(sc.camera)
    n_pts = min(config.max_points, k_win * k_win)
    sub_dt = config.frame_dt / config.substeps
    gp = config.gait_params
    n_avg = (3 * max(1, round(2 * gp.step_period / config.frame_dt)) if config.sway_frames is None
             else config.sway_frames)
    if n_avg < 1:
        raise ValueError(f"sway_frames must be >= 1; got {config.sway_frames}")

    def observe(key, gstate, torso):
        q = gait.qpos(sc, gstate, gp)
        xpos, xmat = scene_mod.pose_geoms(sc, q)
        pts, mask = sensor.robot_point_cloud(key, sc, xpos, xmat, torso, k_win, bg,
                                             config.noise, dtype=dtype)
        score = jnp.where(mask, pts[:, 2], -jnp.inf)
        _, idx = jax.lax.top_k(score, n_pts)
        return pts[idx], mask[idx]

    tracker_init, tracker_step = _tracker(config)

    def episode(key, params: EpisodeParams):
        start = jnp.asarray(params.start, dtype)
        target = jnp.asarray(params.target, dtype)
        k_init, k_run = jax.random.split(key)
        gstate = gait.init(start, gp, dtype)
        tstate = tracker_init(k_init, start)
        cstate = control.smooth_init(dtype) if config.smooth else control.init()
        history = jnp.broadcast_to(start, (n_avg, 3))
        turn = jnp.zeros((), dtype)

        def frame(carry, k):
            gstate, tstate, cstate, history, turn = carry
            k_obs, k_trk, k_gait = jax.random.split(k, 3)
            truth = gait.torso_pose(gstate, gp)
            pts, mask = observe(k_obs, gstate, truth)
            tstate, est = tracker_step(k_trk, tstate, pts, mask, params, turn)
            history = jnp.concatenate([history[1:], est[None]])
            est_avg = _pose_mean(history)
            stopped_before = (cstate.moving < 0.5) if config.smooth else cstate.stopped
            if config.smooth:
                cstate, cmd = control.smooth_step(cstate, est, target, params.gains,
                                                  config.limits, stop_pose=est_avg)
                stop = cmd.stopped > 0.5
            else:
                cstate, cmd = control.step(cstate, est, target, params.gains, config.limits,
                                           stop_pose=est_avg)
                stop = cmd.stopped

            def sub(g, kk):
                return gait.step(kk, g, cmd.body_velocity, cmd.turn_rate, stop, gp,
                                 sub_dt), None

            gstate, _ = jax.lax.scan(sub, gstate, jax.random.split(k_gait, config.substeps))
            return ((gstate, tstate, cstate, history, cmd.turn_rate.astype(dtype)),
                    (truth, est, ~stopped_before, cmd.stopped))

        (gstate, tstate, cstate, _, _), (truth, est, active, stopped) = jax.lax.scan(
            frame, (gstate, tstate, cstate, history, turn),
            jax.random.split(k_run, config.num_frames))
        # Let a stopped robot finish its step and settle before the final pose is read.
        final = gait.torso_pose(_settle(gstate, gp, sub_dt), gp)
        pos_err = jnp.linalg.norm(est[:, :2] - truth[:, :2], axis=-1)
        head_err = jnp.rad2deg(jnp.abs(wrap(est[:, 2] - truth[:, 2])))
        stopped_any = jnp.any(stopped > 0.5) if config.smooth else jnp.any(stopped)
        frames_to_stop = jnp.sum(active).astype(dtype)
        final_pos_err = jnp.linalg.norm(final[:2] - target[:2])
        final_head_err = jnp.rad2deg(jnp.abs(wrap(final[2] - target[2])))
        # Success: the controller stopped and the true pose averaged over the last step cycles
        # up to the stop frame (the frames whose estimates made the stop decision; the start
        # pose before the first frame) was within the stop region (5 cm / 10 deg). The settled
        # pose (CoM between the feet) is reported separately as final_pos_err /
        # final_heading_err.
        first = jnp.argmax(stopped > 0.5) if config.smooth else jnp.argmax(stopped)
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

    return episode


def _temperature(config: EpisodeConfig, params: EpisodeParams):
    """The likelihood temperature: the traced ``params.log_temperature`` if given, else the
    configuration's (None: the seed's weight)."""
    if params.log_temperature is None:
        return config.temperature
    return jnp.exp(params.log_temperature).astype(config.dtype)


def _pose_mean(poses):
    """Mean of poses [K, 3]: positions averaged, headings on the circle about the latest."""
    latest = poses[-1, 2]
    heading = wrap(latest + jnp.mean(wrap(poses[:, 2] - latest)))
    return jnp.concatenate([jnp.mean(poses[:, :2], 0), heading[None]])


def _settle(gstate, gp, dt, steps: int = 20):
    def body(g, _):
        return gait.step(jax.random.PRNGKey(0), g, jnp.zeros(2, g.com.dtype), 0.0, True, gp,
                         dt), None

    return jax.lax.scan(body, gstate, None, length=steps)[0]


class _PFState(NamedTuple):
    particles: particle.ParticleSet
    heading: Array


class _UKFState(NamedTuple):
    belief: kalman.Gaussian
    heading: Array


def _tracker(config: EpisodeConfig):
    """(init(key, start) -> state, step(key, state, points, mask, params, turn) -> (state, est)),
    ``turn`` being the turn rate (rad/s) commanded over the last frame (used by "pf3")."""
    n = config.num_particles
    dtype = config.dtype
    model = config.model
    if not config.smooth:
        resampler = particle.systematic
    elif config.smooth_resampling == "ot":
        resampler = particle.optimal_transport_resampling(config.ot_epsilon)
    elif config.smooth_resampling == "stop_gradient":
        resampler = particle.stop_gradient_resampling()
    else:
        raise ValueError(f"unknown smooth_resampling {config.smooth_resampling!r}; choose "
                         f"'stop_gradient' or 'ot'")
    softness = config.softness if config.smooth else None

    def heading_from_pca(points, mask, centre, prev, turn):
        if config.turn_prediction:
            prev = wrap(prev + turn * config.frame_dt)
        return depth.pca_heading(points, mask, centre, config.pca_radius, prev,
                                 config.heading_window, config.heading_gain).heading

    if config.tracker == "pf":
        def init(key, start):
            eps = jax.random.normal(key, (n, 2), dtype)
            return _PFState(particle.ParticleSet(start[:2] + config.init_spread * eps,
                                                 jnp.full((n,), -math.log(n), dtype)), start[2])

        def step(key, state, points, mask, params, turn):
            sigma = jnp.exp(params.log_position_noise).astype(dtype)
            frame = depth.DepthFrame(points, mask, state.heading)
            ps, _ = particle.step(
                key, state.particles, frame,
                lambda k, x: x + sigma * jax.random.normal(k, x.shape, x.dtype),
                lambda z, x: depth.log_likelihood(z, x, model, softness=softness,
                                                 temperature=_temperature(config, params)),
                resampler, vectorized=True)
            position = particle.weighted_mean(ps)
            heading = heading_from_pca(points, mask, position, state.heading, turn)
            return _PFState(ps, heading), jnp.concatenate([position, heading[None]])

        return init, step

    if config.tracker == "pf3":
        def init(key, start):
            eps = jax.random.normal(key, (n, 3), dtype)
            spread = jnp.array([config.init_spread, config.init_spread, math.radians(3.0)],
                               dtype)
            return _PFState(particle.ParticleSet(start + spread * eps,
                                                 jnp.full((n,), -math.log(n), dtype)), start[2])

        def step(key, state, points, mask, params, turn):
            sigma = jnp.exp(params.log_position_noise).astype(dtype)
            scale = jnp.stack([sigma, sigma, jnp.asarray(config.heading_noise, dtype)])
            frame = depth.DepthFrame(points, mask, state.heading)

            def transition(k, x):
                # The commanded turn drives the heading (a control input, as odometry would):
                # a pure random walk of 4 deg per frame lags a 7 deg-per-frame turn, and the
                # count's weak grip on the heading does not pull it back.
                x = x + scale * jax.random.normal(k, x.shape, x.dtype)
                return x.at[:, 2].set(wrap(x[:, 2] + turn * config.frame_dt))

            ps, _ = particle.step(
                key, state.particles, frame, transition,
                lambda z, x: depth.log_likelihood(z, x, model, softness=softness,
                                                 temperature=_temperature(config, params)),
                resampler, vectorized=True)
            # The likelihood cannot tell theta from theta + pi: fold the heading particles to
            # the half-circle of the previous estimate (weights unchanged) so that they never
            # split between the two modes and the circular mean stays meaningful.
            theta = depth.fold_half_turn(ps.particles[:, 2], state.heading)
            ps = ps._replace(particles=ps.particles.at[:, 2].set(theta))
            est = particle.weighted_mean(ps, angle_dims=(2,))
            return _PFState(ps, est[2]), est

        return init, step

    # "ukf": constant-velocity UKF on the centroid of the robot points near the prediction.
    F = jnp.array([[1, 0, config.frame_dt, 0], [0, 1, 0, config.frame_dt], [0, 0, 1, 0],
                   [0, 0, 0, 1]], dtype)

    def init(key, start):
        cov = jnp.diag(jnp.array([config.init_spread ** 2] * 2 + [0.05 ** 2] * 2, dtype))
        mean = jnp.concatenate([start[:2], jnp.zeros(2, dtype)])
        return _UKFState(kalman.Gaussian(mean, cov), start[2])

    def step(key, state, points, mask, params, turn):
        sigma = jnp.exp(params.log_position_noise).astype(dtype)
        q = jnp.diag(jnp.stack([sigma ** 2, sigma ** 2, (2 * sigma) ** 2, (2 * sigma) ** 2]))
        pred = ukf.predict(state.belief, lambda x: F @ x, q)
        d = points[:, :2] - pred.mean[:2]
        near = mask & (jnp.sum(d * d, -1) <= config.pca_radius ** 2) & (
            points[:, 2] >= model.shoulder_bottom)
        w = near.astype(dtype)
        count = jnp.sum(w)
        centroid = (w @ points[:, :2]) / jnp.maximum(count, 1.0)
        r = jnp.eye(2, dtype=dtype) * 0.015 ** 2
        post, _ = ukf.update(pred, centroid, lambda x: x[:2], r, mask=count >= 3)
        heading = heading_from_pca(points, mask, post.mean[:2], state.heading, turn)
        return (_UKFState(post, heading), jnp.concatenate([post.mean[:2], heading[None]]))

    return init, step
