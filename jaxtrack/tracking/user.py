r"""Estimators of a followed user (the target person of a person-following robot).

Each is an `jaxtrack.tracking.estimator.Estimator` built from its own configuration. All work
in the robot's *odometry frame* (the frame the robot believes it moves in; it drifts from the
world with the odometry noise), take one `jaxtrack.perception.sensing.Sensed` per frame (laser
and RGB-D people in that frame, the odometry) and return a `UserEstimate` there:

- `multi_target` (seeds 001 / 003): the multi-target tracker `jaxtrack.tracking.tracker` over
  everyone (UKF constant velocity, GNN, JPDA or NN-JPDA); the user is a track kept by id, and a
  lost user is re-acquired as the track nearest to their coasting prediction, or, with
  ``appearance``, by colour (`jaxtrack.tracking.reid`); ids are stitched across occlusions
  (`jaxtrack.tracking.stitching`);
- `particle_filter` (seed 004): `jaxtrack.tracking.people_pf`, one particle density over
  everyone fusing the laser and RGB-D likelihoods, particle clustering, the user chosen among
  the clusters by a multi-target tracker over them with colour re-identification (or the
  cluster nearest to the user's prediction);
- `robot_frame_kf` (seed 002): the 6-state Kalman filter of the user in the *robot* frame with
  the odometry-driven rotation input (eqs. 4-11), measurements the nearest gated detection and
  the odometry speed, and the adaptive AR heading filter (eqs. 12-13);
- `leg_tracked` (seed 004's laser side): any of the above fed with laser people built from
  leg *tracks* (`jaxtrack.tracking.leg_tracker`, a Kalman filter per leg, people by the
  paper's four heuristics, occlusions excused) instead of the per-scan leg detector's;
- `truth`: no estimation, the true user (``Sensed.truth``, which a simulator provides): what the
  controller achieves with perfect perception, the floor of the following error.

`build` turns a configuration into its estimator; `CONFIGS` maps each estimator's one name to
its default configuration (the command line's choices).

Example:
  >>> est = multi_target(MultiTargetConfig(tracker=TRACKER._replace(association="gnn")))
  >>> params = est.params(dt=0.1)
  >>> state = est.init(key, params, Prior(jnp.array([1.5, 0.0]), jnp.zeros(3)))
  >>> state, e = est.update(key, state, sensed, params)
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxtrack import _checks, geometry
from jaxtrack.angles import wrap
from jaxtrack.filters import _linalg
from jaxtrack.filters import heading as heading_filter
from jaxtrack.filters import kalman
from jaxtrack.models import measurement, motion
from jaxtrack.perception.sensing import Sensed
from jaxtrack.tracking import leg_tracker, people_pf, reid, stitching, tracker
from jaxtrack.tracking.estimator import Estimator

Array = jax.Array

__all__ = ["SENSORS", "Prior", "UserEstimate", "MultiTargetConfig", "MultiTargetParams",
           "MultiTargetState", "ParticleConfig", "RobotFrameKFConfig", "RobotFrameKFParams",
           "RobotFrameKFState", "TruthConfig", "TruthParams", "TruthState", "LegTrackedConfig",
           "LegTrackedState", "multi_target", "particle_filter", "robot_frame_kf", "truth",
           "leg_tracked", "build", "with_sensors", "CONFIGS",
           "TRACKER"]

SENSORS = ("both", "laser", "rgbd")

TRACKER = tracker.TrackerConfig(capacity=10, association="jpda", filter="ukf", max_misses=8,
                                max_position_std=1.0, merge_distance=0.4)
"""The multi-target tracker of the user estimators: 10 slots, a UKF, tracks deleted after 8
missed scans or beyond 1 m of position std, tracks closer than 0.4 m merged."""


class Prior(NamedTuple):
    """What the robot knows at the start: it is shown its user.

    Attributes:
      user_xy: [2] the user's position (odometry frame).
      odom_pose: [3] the robot's pose in the odometry frame.
      colour: [3] the user's colour feature as the RGB-D camera saw it, or None.
    """

    user_xy: Array
    odom_pose: Array
    colour: Array | None = None


class UserEstimate(NamedTuple):
    """What the behaviour and the metrics see (odometry frame).

    Attributes:
      user: [4] ``[p_x, p_y, v_x, v_y]``; user_found: bool, measured at this frame.
      user_heading: scalar (rad); user_id: int32 identity of the estimate (-1 if none).
      people: [P, 2] every person estimate; people_ids: [P] int32; people_mask: [P].
      look: [2] where a robot that has lost its user should point its camera: the confirmed
        track, detected now, nearest to the user's last estimate whose identity the colours
        have not settled (`multi_target` with ``appearance``; None otherwise).
      look_ok: bool, whether there is such a track while the user is not measured.
    """

    user: Array
    user_found: Array
    user_heading: Array
    user_id: Array
    people: Array
    people_ids: Array
    people_mask: Array
    look: Array | None = None
    look_ok: Array | None = None


def _check_sensors(sensors):
    _checks.check_options("sensors", (sensors,), SENSORS)


def _sensor_masks(sensors, z: Sensed):
    return z.laser_mask & (sensors != "rgbd"), z.rgbd_mask & (sensors != "laser")


# ---------------------------------------------------------------------------------------------
# Multi-target tracker


@dataclasses.dataclass(frozen=True)
class MultiTargetConfig:
    """Static configuration of `multi_target`.

    Attributes:
      tracker: `tracker.TrackerConfig` (its association names the estimator: "gnn", "jpda" or
        "nn_jpda"; ``num_features`` is set from ``appearance``).
      sensors: "both", "laser" or "rgbd": which detections the tracker gets.
      appearance: use the RGB-D colour feature: in the GNN cost (seed 001's online
        classifier), and to re-identify the user (`reid`).
      reid: `reid.ReidConfig` of the re-identification.
      gate: radius (m) within which a lost user is re-acquired.
      coast: a lost user's predicted velocity decays by this factor per frame (a lost user is
        assumed to slow down, not to walk on in a straight line for ever).
      user_std: (position m, velocity m/s) std of the user's track at the start.
      report_misses: the confirmed tracks detected within the last ``report_misses + 1``
        scans are reported (as the ground truth of a simulation holds only the people the
        laser sees); tracks coasting longer through an occlusion are kept, not reported.
      stitch_time: longest occlusion (s) across which `stitching` keeps a person's reported id;
        0 turns it off.
    """

    tracker: tracker.TrackerConfig = TRACKER
    sensors: str = "both"
    appearance: bool = False
    reid: reid.ReidConfig = reid.ReidConfig()
    gate: float = 0.7
    coast: float = 0.8
    user_std: tuple = (0.2, 0.5)
    report_misses: int = 3
    stitch_time: float = 10.0

    def __post_init__(self):
        _check_sensors(self.sensors)
        if not (self.gate > 0 and 0 <= self.coast <= 1 and self.stitch_time >= 0
                and self.report_misses >= 0):
            raise ValueError("need gate > 0, 0 <= coast <= 1, stitch_time >= 0, "
                             "report_misses >= 0")

    @property
    def tracker_config(self) -> tracker.TrackerConfig:
        return dataclasses.replace(self.tracker, num_features=3 if self.appearance else 0)


jax.tree_util.register_static(MultiTargetConfig)


class MultiTargetParams(NamedTuple):
    """Tunable parameters of `multi_target`: ``tracker`` (`tracker.TrackerParams`) and
    ``colour_std``, the spread of the user's colour feature (`reid`)."""

    tracker: tracker.TrackerParams
    colour_std: Array


class MultiTargetState(NamedTuple):
    """tracks: `tracker.Tracks`; user_id: the user's track id; last: [4] the user's last
    estimate (or coasting prediction); reid: `reid.ReidState`; stitch:
    `stitching.StitchState`."""

    tracks: tracker.Tracks
    user_id: Array
    last: Array
    reid: reid.ReidState
    stitch: stitching.StitchState


def multi_target(config: MultiTargetConfig = MultiTargetConfig()) -> Estimator:
    """The multi-target user estimator (module docstring) as an `Estimator`.

    ``params(dt=0.1, laser_std=0.1, rgbd_std=0.3, q=1.0, p_detect=0.8, clutter_density=0.02,
    colour_std=0.05, dtype=float32)``: natural values (noise of the laser people 0.1 m, the
    project's figure for the simulated laser's leg-pair centre (seed 003 gives 0.2 m for
    its laser); of the RGB-D people 0.3 m, seed 003's; the colour feature's noise per
    channel 0.05, which the user's colour learnt from many looks makes usable: `reid`).

    Example:
      >>> est = multi_target(MultiTargetConfig(appearance=True))
    """
    tcfg = config.tracker_config

    def params(*, dt=0.1, laser_std=0.1, rgbd_std=0.3, q=1.0, p_detect=0.8,
               clutter_density=0.02, colour_std=0.05, dtype=jnp.float32) -> MultiTargetParams:
        tp = tracker.TrackerParams.create(
            tcfg, dt=dt, q=q, r_std=(laser_std, rgbd_std), p_detect=p_detect,
            clutter_density=clutter_density, alpha=1.0 if config.appearance else 0.0,
            dtype=dtype)
        return MultiTargetParams(tp, jnp.asarray(colour_std, dtype))

    def init(key, params: MultiTargetParams, prior: Prior) -> MultiTargetState:
        dtype = params.colour_std.dtype
        user_xy = jnp.asarray(prior.user_xy, dtype)
        tr = tracker.init(tcfg, dtype)
        # The user's track exists from the start (confirmed, id 0): the robot was shown them.
        ps, vs = config.user_std
        tr = tr._replace(mean=tr.mean.at[0, :2].set(user_xy),
                         cov=tr.cov.at[0].set(jnp.diag(jnp.array([ps**2, ps**2, vs**2, vs**2],
                                                                 dtype))),
                         id=tr.id.at[0].set(0), status=tr.status.at[0].set(tracker.CONFIRMED),
                         history=tr.history.at[0].set(1), hits=tr.hits.at[0].set(1),
                         next_id=jnp.int32(1))
        # Without the colour the robot was shown, colours tell nobody apart.
        colour = (jnp.full(3, jnp.nan, dtype) if prior.colour is None
                  else jnp.asarray(prior.colour, dtype))
        return MultiTargetState(tr, jnp.int32(0), jnp.concatenate([user_xy, jnp.zeros(2, dtype)]),
                                reid.init(config.reid, colour, tr.id), stitching.init(tr))

    def update(key, state: MultiTargetState, z: Sensed, params: MultiTargetParams):
        tr = tracker.step(state.tracks, _detections(z, config), params.tracker)
        live = tr.status != tracker.FREE
        confirmed = tr.status == tracker.CONFIRMED
        has = live & (tr.id == state.user_id)
        found_old = jnp.any(has)
        last = state.last
        pred = jnp.concatenate([last[:2] + params.tracker.dt * last[2:],
                                config.coast * last[2:]])
        d2 = jnp.sum((tr.mean[:, :2] - pred[:2]) ** 2, -1)
        ident = state.reid
        if config.appearance:
            _, rgbd_mask = _sensor_masks(config.sensors, z)
            ident = reid.update(config.reid, ident, tr.mean[:, :2], tr.id, live, z.rgbd_xy,
                                z.rgbd_colour, rgbd_mask, params.colour_std)
            slot, found, look, look_ok = _choose_by_colour(config, ident.logodds, tr, has,
                                                           found_old, live, confirmed, d2)
        else:
            d2 = jnp.where(live, d2, jnp.inf)
            near = jnp.argmin(d2)
            reacquire = ~found_old & (d2[near] <= config.gate**2)
            slot = jnp.where(found_old, jnp.argmax(has), near)
            found = found_old | reacquire
        if config.appearance:
            # The looks of a settled user teach their colour (`reid.learn`).
            settled = found & (ident.logodds[slot] >= config.reid.switch) & (tr.misses[slot] == 0)
            ident = reid.learn(config.reid, ident, tr.mean[:, :2], live, slot, settled,
                               z.rgbd_xy, z.rgbd_colour, rgbd_mask, params.colour_std)
        user_id = jnp.where(found, tr.id[slot], state.user_id)
        mean = jnp.where(found, tr.mean[slot], pred)
        stitch = state.stitch
        if config.stitch_time > 0:
            stitch = stitching.step(stitch, tr, params.tracker.dt, config.stitch_time)
            ids = stitch.alias
        else:
            ids = tr.id
        est = UserEstimate(mean, found & (tr.misses[slot] == 0), tr.heading[slot],
                           jnp.where(found, user_id, -1).astype(jnp.int32), tr.mean[:, :2],
                           ids, confirmed & (tr.misses <= config.report_misses),
                           *((look, look_ok) if config.appearance else ()))
        return MultiTargetState(tr, user_id, mean, ident, stitch), est

    return Estimator(params, init, update, config.tracker.association)


def _detections(z: Sensed, config: MultiTargetConfig) -> tracker.Detections:
    """The frame's laser and RGB-D people as one scan of the tracker (sensors 0 and 1)."""
    lm, km = _sensor_masks(config.sensors, z)
    dtype = z.odom_pose.dtype
    L, K = z.laser_xy.shape[0], z.rgbd_xy.shape[0]
    # Laser people have no colour: NaN rows, which never train a track's colour classifier.
    feats = jnp.concatenate([jnp.full((L, 3), jnp.nan, dtype), z.rgbd_colour.astype(dtype)], 0)
    return tracker.Detections(
        jnp.concatenate([z.laser_xy, z.rgbd_xy], 0).astype(dtype),
        jnp.concatenate([lm, km], 0),
        jnp.concatenate([jnp.zeros(L, jnp.int32), jnp.ones(K, jnp.int32)]),
        jnp.ones(L + K, dtype), feats if config.appearance else jnp.zeros((L + K, 0), dtype))


def _choose_by_colour(config, logodds, tr, has, found_old, live, confirmed, d2):
    """The user's slot with colour evidence: leave a track whose colours say it is someone
    else; take the track whose colours say it is the user; otherwise keep the identity, or
    re-acquire the nearest track not known to be someone else. Also whom to look at while the
    user is not measured: a confirmed track detected now whose identity is open.

    Returns ``(slot, found, look [2], look_ok)``."""
    switch = config.reid.switch
    cur = jnp.argmax(has)
    best = jnp.argmax(jnp.where(confirmed, logodds, -jnp.inf))
    cur_bad = (~found_old | (logodds[cur] < -switch)
               | (logodds[best] > logodds[cur] + 2.0 * switch))
    to_best = cur_bad & confirmed[best] & (logodds[best] > switch)
    d2 = jnp.where(live & (logodds >= -switch), d2, jnp.inf)
    near = jnp.argmin(d2)
    reacquire = ~to_best & ~found_old & (d2[near] <= config.gate**2)
    keep = found_old & ~cur_bad
    slot = jnp.where(to_best, best, jnp.where(keep, cur, near))
    found = to_best | keep | reacquire
    open_ = confirmed & (tr.misses == 0) & (jnp.abs(logodds) < switch)
    cand = jnp.argmin(jnp.where(open_, d2, jnp.inf))
    return slot, found, tr.mean[cand, :2], open_[cand] & ~(found & (tr.misses[slot] == 0))


# ---------------------------------------------------------------------------------------------
# Seed 004's people particle filter


@dataclasses.dataclass(frozen=True)
class ParticleConfig:
    """Static configuration of `particle_filter`.

    Attributes:
      pf: `people_pf.PeoplePFConfig` (256 particles, 8 clusters, a 0.7 m target gate; the
        clustering as the seed writes it: the priority-queue FindCluster and eq. 5's
        threshold. ``threshold_mode="half_mean"`` or a ``threshold_cap`` are the fixes for
        crowds, where eq. 5 merges people: docs/design_notes.md, "People PF: eq. 5 in a
        crowd").
      sensors: "both", "laser" or "rgbd".
      laser_fov, rgbd_fov: ``(half_angle rad, min_range m, max_range m)`` of the detectors.
      max_births: births are drawn around at most this many of the last scan's detections.
      colour: select the user among the clusters by the RGB-D colour too (with motion
        continuity; `people_pf.select_target`), from the colour the robot was shown. Off by
        default: the seed selects by position, and in the shop the colour rule measured no
        better yet (docs/design_notes.md, "Person following: the shop's floor").
      selection: how the user is chosen among the clusters (the seed leaves it open).
        "tracked" (default): motion continuity of everyone plus the RGB-D colour. Every
        cluster is a detection of a multi-target tracker (``clusters``, a `MultiTargetConfig`:
        GNN over the clusters and the RGB-D detections, one track per person, the colour
        re-identification of `reid`), and the user is the track the robot was shown, kept by
        id and re-identified by colour. When the user passes someone, both are predicted
        through the encounter; following only the user's own prediction, the nearest cluster
        to it is often the other person. "nearest": the cluster nearest to the user's own
        constant-velocity prediction (`people_pf.select_target`; with ``colour``, weighed by
        the colour). "tracked" loses the user far less often in the shop (docs/design_notes.md,
        "People PF: choosing the user among the clusters").
      clusters: the cluster tracker of ``selection="tracked"`` (its ``sensors`` are set from
        this configuration's).
      max_cluster_std: with ``selection="tracked"``, a cluster whose position spread (the
        square root of its covariance's largest eigenvalue) exceeds this (m) is not a person
        for the cluster tracker: it is two people the clustering merged (one person's
        particles spread about 0.1 m; two people 0.7 m apart about 0.35 m), and its mean lies
        between them, on neither. Their tracks coast through the merge on their velocities
        and the RGB-D detections. inf turns it off. Measured in the shop with eq. 5 (128
        episodes, paired): the user lost 4.7 % [1.5, 7.9] less often than without it
        (docs/design_notes.md, "People PF: merged clusters").
    """

    pf: people_pf.PeoplePFConfig = people_pf.PeoplePFConfig(num_particles=256, max_clusters=8,
                                                            gate=0.7)
    sensors: str = "both"
    laser_fov: tuple = (2.094, 0.1, 5.6)
    rgbd_fov: tuple = (0.497, 0.5, 4.5)
    max_births: int = 16
    colour: bool = False
    selection: str = "tracked"
    clusters: MultiTargetConfig = MultiTargetConfig(
        tracker=dataclasses.replace(TRACKER, association="gnn"), appearance=True)
    max_cluster_std: float = 0.25

    def __post_init__(self):
        _check_sensors(self.sensors)
        _checks.check_options("selection", (self.selection,), ("nearest", "tracked"))
        if self.max_births < 1:
            raise ValueError(f"max_births must be >= 1; got {self.max_births}")
        if not self.max_cluster_std > 0:
            raise ValueError(f"max_cluster_std must be > 0; got {self.max_cluster_std}")


jax.tree_util.register_static(ParticleConfig)


def _largest_std(covs: Array) -> Array:
    """[K] square root of the largest eigenvalue of each [K, 2, 2] covariance (closed form)."""
    a, b, c = covs[:, 0, 0], covs[:, 0, 1], covs[:, 1, 1]
    half = 0.5 * (a + c)
    return jnp.sqrt(jnp.maximum(half + jnp.sqrt(0.25 * (a - c) ** 2 + b**2), 0.0))


class ClusterTrackedParams(NamedTuple):
    """Parameters of `particle_filter` with ``selection="tracked"``: ``pf``
    (`people_pf.PeoplePFParams`) and ``tracker`` (the cluster tracker's `MultiTargetParams`)."""

    pf: people_pf.PeoplePFParams
    tracker: MultiTargetParams


class ClusterTrackedState(NamedTuple):
    """State of `particle_filter` with ``selection="tracked"``: ``pf``
    (`people_pf.PeoplePFState`) and ``tracks`` (the cluster tracker's `MultiTargetState`)."""

    pf: people_pf.PeoplePFState
    tracks: MultiTargetState


def particle_filter(config: ParticleConfig = ParticleConfig()) -> Estimator:
    """Seed 004's people particle filter (module docstring) as an `Estimator`; its state is a
    `people_pf.PeoplePFState`, its parameters a `people_pf.PeoplePFParams`.

    ``params(dt=0.1, laser_std=0.1, rgbd_std=0.3, q=1.0, colour_std=0.05, dtype=float32)``.

    Example:
      >>> est = particle_filter(ParticleConfig(sensors="laser"))
    """

    tracked = config.selection == "tracked"
    # The cluster tracker takes the clusters as its laser people, and the RGB-D detections
    # (their positions, and their colours with ``clusters.appearance``).
    cluster_tracker = (multi_target(dataclasses.replace(config.clusters, sensors=config.sensors))
                       if tracked else None)

    def params(*, dt=0.1, laser_std=0.1, rgbd_std=0.3, q=1.0, colour_std=0.05,
               dtype=jnp.float32):
        pf = people_pf.PeoplePFParams.create(config.pf, dt=dt, q=q, std=(laser_std, rgbd_std),
                                             colour_std=colour_std, dtype=dtype)
        if not tracked:
            return pf
        # The clusters are smoothed people: their tracker's measurement noise is the laser's.
        return ClusterTrackedParams(pf, cluster_tracker.params(
            dt=dt, laser_std=laser_std, rgbd_std=rgbd_std, q=q, colour_std=colour_std,
            dtype=dtype))

    def init(key, params, prior: Prior):
        pf_params = params.pf if tracked else params
        dtype = pf_params.dt.dtype
        user_xy = jnp.asarray(prior.user_xy, dtype)
        colour = None
        if config.colour:
            colour = (jnp.full(3, 0.5, dtype) if prior.colour is None
                      else jnp.asarray(prior.colour, dtype))
        state = people_pf.init(key, pf_params, user_xy, max_births=config.max_births,
                               target_colour=colour)
        if not tracked:
            return state
        return ClusterTrackedState(state, cluster_tracker.init(key, params.tracker, prior))

    def update(key, state, z: Sensed, params):
        pf_params = params.pf if tracked else params
        pf_state = state.pf if tracked else state
        lm, km = _sensor_masks(config.sensors, z)
        scans = (people_pf.Scan(z.laser_xy, lm, jnp.asarray(config.laser_fov)),
                 people_pf.Scan(z.rgbd_xy, km, jnp.asarray(config.rgbd_fov), z.camera_pan,
                                z.rgbd_colour if config.colour else None))
        pf_state = people_pf.step(key, pf_state, scans, z.odom_pose, pf_params)
        cl = pf_state.clusters
        k = cl.means.shape[0]
        if not tracked:
            heading = jnp.arctan2(pf_state.target_mean[3], pf_state.target_mean[2])
            est = UserEstimate(pf_state.target_mean, pf_state.target_found, heading,
                               jnp.where(pf_state.target_found, 0, -1).astype(jnp.int32),
                               cl.means[:, :2], jnp.arange(k, dtype=jnp.int32), cl.mask)
            return pf_state, est
        # The clusters as the laser people of one scan of the cluster tracker (the RGB-D
        # detections stay, masked out as positions, for the colour re-identification).
        people = cl.mask & (cl.weights >= config.pf.min_cluster_weight)
        if config.max_cluster_std < float("inf"):
            people = people & (_largest_std(cl.covs[:, :2, :2]) <= config.max_cluster_std)
        zc = z._replace(laser_xy=cl.means[:, :2].astype(z.laser_xy.dtype), laser_mask=people,
                        rgbd_mask=km)
        tracks, est = cluster_tracker.update(key, state.tracks, zc, params.tracker)
        return ClusterTrackedState(pf_state, tracks), est

    return Estimator(params, init, update, "pf")


# ---------------------------------------------------------------------------------------------
# Seed 002's robot-frame Kalman filter


@dataclasses.dataclass(frozen=True)
class RobotFrameKFConfig:
    """Static configuration of `robot_frame_kf`.

    Attributes:
      sensors: "both", "laser" or "rgbd".
      init_std: std of the initial state ``(position m, person velocity m/s, robot velocity
        m/s)``.
      heading: `jaxtrack.filters.heading.HeadingParams` of the AR heading filter (seed 002's
        eq. 13 by default). Its ``slow`` = 0.9 still blends 10 % of the velocity's direction
        into the heading at every frame below 0.1 m/s, where the direction of an estimated
        velocity is noise: a still person's heading wanders. ``slow=1.0`` holds it.
    """

    sensors: str = "both"
    init_std: tuple = (0.2, 0.5, 0.1)
    heading: heading_filter.HeadingParams = heading_filter.HeadingParams()

    def __post_init__(self):
        _check_sensors(self.sensors)


jax.tree_util.register_static(RobotFrameKFConfig)


class RobotFrameKFParams(NamedTuple):
    """Tunable parameters of `robot_frame_kf` (unconstrained): log acceleration variances of
    the person and of the robot, log detection std of the laser and of the RGB-D detector, log
    odometry-speed std, the chi-square gate probability, and the frame period ``dt``."""

    log_q_person: Array
    log_q_robot: Array
    log_r: Array
    log_r_odom: Array
    gate_prob: Array
    dt: Array
    log_r_rgbd: Array


class RobotFrameKFState(NamedTuple):
    """belief: `kalman.Gaussian` over seed 002's 6-state (user position and velocity, robot
    velocity, robot frame); heading: the AR filter's user heading (robot frame)."""

    belief: kalman.Gaussian
    heading: Array


def robot_frame_kf(config: RobotFrameKFConfig = RobotFrameKFConfig()) -> Estimator:
    """Seed 002's user Kalman filter (module docstring) as an `Estimator`.

    ``params(dt=0.1, q=4.0, q_robot=0.5, laser_std=0.1, odom_std=0.05, gate_prob=0.99999,
    rgbd_std=None, dtype=float32)``: ``q`` is the person's acceleration variance (a single
    target gated on its own covariance needs room for stops and turns; measurements:
    docs/design_notes.md, "Person following: the robot-frame Kalman filter's acceleration
    variance"); ``rgbd_std`` the RGB-D detections' std (None: ``laser_std``, seed 002 having a
    laser only). Each candidate is gated and, if nearest, applied with its own sensor's std.

    Example:
      >>> est = robot_frame_kf()
    """

    def params(*, dt=0.1, q=4.0, q_robot=0.5, laser_std=0.1, odom_std=0.05,
               gate_prob=0.99999, rgbd_std=None, dtype=jnp.float32) -> RobotFrameKFParams:
        f = lambda x: jnp.asarray(x, dtype)  # noqa: E731
        rgbd_std = laser_std if rgbd_std is None else rgbd_std
        return RobotFrameKFParams(f(jnp.log(q)), f(jnp.log(q_robot)), f(jnp.log(laser_std)),
                                  f(jnp.log(odom_std)), f(gate_prob), f(dt),
                                  f(jnp.log(rgbd_std)))

    def init(key, params: RobotFrameKFParams, prior: Prior) -> RobotFrameKFState:
        dtype = params.log_r.dtype
        rel = geometry.to_frame(jnp.asarray(prior.odom_pose, dtype),
                                jnp.asarray(prior.user_xy, dtype))
        mean = jnp.concatenate([rel, jnp.zeros(4, dtype)])
        p, v, r = config.init_std
        cov = jnp.diag(jnp.array([p**2, p**2, v**2, v**2, r**2, r**2], dtype))
        return RobotFrameKFState(kalman.Gaussian(mean, cov), jnp.zeros((), dtype))

    def update(key, state: RobotFrameKFState, z: Sensed, params: RobotFrameKFParams):
        lm, km = _sensor_masks(config.sensors, z)
        g = state.belief
        dtype = g.mean.dtype
        F, Q = motion.person_relative(params.dt, z.odom_rate, jnp.exp(params.log_q_person),
                                      jnp.exp(params.log_q_robot))
        g = kalman.predict(g, F.astype(dtype), Q.astype(dtype))
        H = measurement.person_relative(dtype)
        # Candidate positions in the robot frame; the nearest gated one (Mahalanobis) is the
        # user.
        xy = jnp.concatenate([z.laser_xy, z.rgbd_xy], 0)
        mask = jnp.concatenate([lm, km], 0)
        rel = geometry.to_frame(z.odom_pose, xy).astype(dtype)
        r = jnp.concatenate([jnp.full(lm.shape, jnp.exp(params.log_r), dtype),
                             jnp.full(km.shape, jnp.exp(params.log_r_rgbd), dtype)])
        S = g.cov[:2, :2] + (r**2)[:, None, None] * jnp.eye(2, dtype=dtype)
        d = rel - g.mean[:2]
        d2 = jnp.einsum("mi,mij,mj->m", d, _linalg.inv2(S), d)
        # chi-square 2-dof quantile in closed form: -2 log(1 - p)
        gate = -2.0 * jnp.log1p(-params.gate_prob)
        d2 = jnp.where(mask & (d2 <= gate), d2, jnp.inf)
        j = jnp.argmin(d2)
        found = jnp.isfinite(d2[j])
        ro = jnp.exp(params.log_r_odom)
        speed = z.odom_speed
        zv = jnp.concatenate([jnp.where(found, rel[j], 0.0),
                              jnp.stack([speed, 0.0 * speed])]).astype(dtype)
        R = jnp.diag(jnp.stack([r[j]**2, r[j]**2, ro**2, ro**2])).astype(dtype)
        zmask = jnp.stack([found, found, True, True])
        g, _ = kalman.update(g, zv, H, R, zmask)
        # The heading is kept in the robot frame, like the state: the robot's turn by
        # psi T since the last frame turns a still person's heading by -psi T there (the
        # rotation term of eqs. 10-11 applied to the pose), before eq. 12 blends in the
        # velocity's direction.
        turned = wrap(state.heading - z.odom_rate * params.dt)
        head = heading_filter.ar_heading_step(turned, g.mean[2:4], config.heading)
        user_xy = geometry.from_frame(z.odom_pose, g.mean[:2])
        user_v = geometry.rotate(z.odom_pose[2], g.mean[2:4])
        user = jnp.concatenate([user_xy, user_v])
        est = UserEstimate(user, found, wrap(head + z.odom_pose[2]), jnp.int32(0), user_xy[None],
                           jnp.zeros(1, jnp.int32), jnp.ones(1, bool))
        return RobotFrameKFState(g, head), est

    return Estimator(params, init, update, "kf")


# ---------------------------------------------------------------------------------------------
# The truth


@dataclasses.dataclass(frozen=True)
class TruthConfig:
    """The `truth` estimator has no settings."""


class TruthState(NamedTuple):
    """The `truth` estimator keeps no state."""


class TruthParams(NamedTuple):
    """The `truth` estimator has no parameters."""


def truth(config: TruthConfig = TruthConfig()) -> Estimator:
    """The true user handed to the controller (``Sensed.truth``, [4] in the odometry frame), as
    an `Estimator` with no parameters and no state: the floor of the following error.

    Example:
      >>> est = truth()
    """

    def params(*, dtype=jnp.float32, **_) -> TruthParams:
        return TruthParams()

    def init(key, params, prior: Prior) -> TruthState:
        return TruthState()

    def update(key, state, z: Sensed, params):
        if z.truth is None:
            raise ValueError('the "truth" estimator needs the true user (Sensed.truth, [4])')
        _checks.check_shape("truth", z.truth, (4,), "(p_x, p_y, v_x, v_y)")
        u = jnp.asarray(z.truth, z.odom_pose.dtype)
        none = jnp.zeros((1, 2), u.dtype)
        return state, UserEstimate(u, jnp.array(True), jnp.arctan2(u[3], u[2]), jnp.int32(0),
                                   none, jnp.full(1, -1, jnp.int32), jnp.zeros(1, bool))

    return Estimator(params, init, update, "truth")


# ---------------------------------------------------------------------------------------------
# Laser people from leg tracks


@dataclasses.dataclass(frozen=True)
class LegTrackedConfig:
    """Static configuration of `leg_tracked`.

    Attributes:
      estimator: the configuration of the estimator fed with the tracked laser people
        (`ParticleConfig`, `MultiTargetConfig` or `RobotFrameKFConfig`).
      legs: `leg_tracker.LegTrackerConfig`.
      period: the scan period (s) of the leg tracks' motion model (the episode's frame).
    """

    estimator: object = ParticleConfig()
    legs: leg_tracker.LegTrackerConfig = leg_tracker.LegTrackerConfig()
    period: float = 0.1

    def __post_init__(self):
        if type(self.estimator) not in (ParticleConfig, MultiTargetConfig, RobotFrameKFConfig):
            raise TypeError("LegTrackedConfig.estimator must be a ParticleConfig, "
                            f"MultiTargetConfig or RobotFrameKFConfig; got "
                            f"{type(self.estimator).__name__}")
        if not self.period > 0:
            raise ValueError(f"period must be > 0; got {self.period}")

    @property
    def sensors(self) -> str:
        return self.estimator.sensors


jax.tree_util.register_static(LegTrackedConfig)


class LegTrackedState(NamedTuple):
    """inner: the wrapped estimator's state; legs: `leg_tracker.LegTrackerState`."""

    inner: object
    legs: leg_tracker.LegTrackerState


def leg_tracked(config: LegTrackedConfig = LegTrackedConfig()) -> Estimator:
    """An estimator whose laser people are built from leg tracks (`leg_tracker.step` on
    ``Sensed.legs_xy``, with the scan's returns for the occlusions) rather than detected scan
    by scan: seed 004's laser side. Parameters are the wrapped estimator's; its name gets
    ``"+legs"``.

    Example:
      >>> est = leg_tracked(LegTrackedConfig(ParticleConfig()))
    """
    inner = build(config.estimator)

    def init(key, params, prior: Prior) -> LegTrackedState:
        # The leg tracks in the dtype of the wrapped estimator's parameters.
        leaves = [x for x in jax.tree_util.tree_leaves(params)
                  if jnp.issubdtype(jnp.asarray(x).dtype, jnp.floating)]
        dtype = jnp.asarray(leaves[0] if leaves else prior.odom_pose).dtype
        return LegTrackedState(inner.init(key, params, prior),
                               leg_tracker.init(config.legs, dtype))

    def update(key, state: LegTrackedState, z: Sensed, params):
        if z.legs_xy is None or z.legs_mask is None:
            raise ValueError("a leg-tracked estimator needs the leg candidates "
                             "(Sensed.legs_xy, Sensed.legs_mask)")
        legs, people = leg_tracker.step(config.legs, state.legs, z.legs_xy, z.legs_mask,
                                        z.returns_xy, z.returns_mask, z.odom_pose,
                                        dt=config.period, max_people=z.laser_xy.shape[0],
                                        legs_conf=z.legs_score)
        z = z._replace(laser_xy=people.xy.astype(z.laser_xy.dtype), laser_mask=people.mask)
        inner_state, est = inner.update(key, state.inner, z, params)
        return LegTrackedState(inner_state, legs), est

    return Estimator(inner.params, init, update, inner.name + "+legs")


# ---------------------------------------------------------------------------------------------
# Names


CONFIGS = {
    "pf": ParticleConfig(),
    "gnn": MultiTargetConfig(tracker=dataclasses.replace(TRACKER, association="gnn")),
    "jpda": MultiTargetConfig(),
    "nn_jpda": MultiTargetConfig(tracker=dataclasses.replace(TRACKER, association="nn_jpda")),
    "kf": RobotFrameKFConfig(),
    "pf+legs": LegTrackedConfig(ParticleConfig()),
    "jpda+legs": LegTrackedConfig(MultiTargetConfig()),
    "truth": TruthConfig(),
}
"""Each user estimator's one name and its default configuration."""

_BUILDERS = {MultiTargetConfig: multi_target, ParticleConfig: particle_filter,
             RobotFrameKFConfig: robot_frame_kf, TruthConfig: truth,
             LegTrackedConfig: leg_tracked}


def build(config) -> Estimator:
    """The `Estimator` of a configuration (`MultiTargetConfig`, `ParticleConfig`,
    `RobotFrameKFConfig` or `TruthConfig`); a name of `CONFIGS` gives its default.

    Example:
      >>> est = build("jpda")
      >>> est = build(ParticleConfig(sensors="laser"))
    """
    if isinstance(config, str):
        _checks.check_options("estimator", (config,), tuple(CONFIGS))
        config = CONFIGS[config]
    builder = _BUILDERS.get(type(config))
    if builder is None:
        raise TypeError(f"not a user-estimator configuration: {type(config).__name__}; "
                        f"expected one of {[c.__name__ for c in _BUILDERS]}")
    return builder(config)


def with_sensors(config, sensors: str):
    """``config`` with its ``sensors`` field set (the truth has none and is returned as is)."""
    _check_sensors(sensors)
    if isinstance(config, TruthConfig):
        return config
    if isinstance(config, LegTrackedConfig):
        return dataclasses.replace(config, estimator=with_sensors(config.estimator, sensors))
    return dataclasses.replace(config, sensors=sensors)
