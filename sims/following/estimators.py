"""User estimators of the person-following scene, chosen by name.

All work in the robot's *odometry frame* (the frame in which the robot believes it moves; it
drifts from the world frame with the odometry noise), take the people detected by the laser leg
detector and by the RGB-D detector in that frame, and return the user's estimate there:

- ``"pf"`` (seed 004): `jaxtrack.tracking.people_pf`, one particle density over everyone fusing
  the laser and RGB-D likelihoods, particle clustering, the user being the cluster nearest to the
  last user estimate; ``sensors="laser"`` or ``"rgbd"`` gives the single-sensor versions;
- ``"gnn"``, ``"jpda"``, ``"nnjpda"`` (seeds 001 / 003): the multi-target tracker
  `jaxtrack.tracking.tracker` over everyone (UKF constant velocity), the user being a track
  (kept by id; re-acquired as the track nearest to the last estimate when it dies);
- ``"kf"`` (seed 002): the 6-state Kalman filter of the user in the *robot* frame with the
  odometry-driven rotation input (eqs. 4-11), measurements the nearest gated detection and the
  odometry velocity, and the adaptive AR heading filter (eqs. 12-13);
- ``"truth"``: no estimation, the true user (the episode passes it): what the controller
  achieves with perfect perception, the floor of the following error.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxtrack import _checks
from jaxtrack.angles import wrap
from jaxtrack.filters import _linalg
from jaxtrack.filters import heading as heading_filter
from jaxtrack.filters import kalman
from jaxtrack.models import measurement, motion
from jaxtrack.tracking import people_pf, tracker

Array = jax.Array

__all__ = ["ESTIMATORS", "EstimatorConfig", "EstimatorParams", "Estimate", "Detected", "init",
           "update", "to_frame", "from_frame", "rotate"]

ESTIMATORS = ("pf", "gnn", "jpda", "nnjpda", "kf", "truth")
SENSORS = ("both", "laser", "rgbd")


@dataclasses.dataclass(frozen=True)
class EstimatorConfig:
    """Static estimator choice.

    Attributes:
      kind: one of `ESTIMATORS`.
      sensors: "both", "laser" or "rgbd" (which detections the estimator uses).
      num_particles, max_clusters: particle filter sizes.
      resampler: particle filter resampler ("systematic", or a differentiable scheme, see
        `people_pf.PeoplePFConfig`).
      capacity: tracker slots.
      jpda_method: "exact" or "lbp".
      appearance: use the RGB-D colour feature: in the GNN cost (seed 001's online
        classifier), and for the multi-target estimators to re-identify the user (each track
        accumulates the log-odds that it is the user from the colours of the RGB-D detections
        nearest to it, fading with a half-life of 1.4 s, or 7 s for evidence against; the
        user's track is abandoned for another when their colours say so).
      gate: user re-acquisition radius (m).
      cluster_cap: largest particle-clustering distance (m), see `people_pf.PeoplePFConfig`.
      laser_fov, rgbd_fov: ``(half_angle rad, min_range m, max_range m)`` of the detectors.
      stitch_time: a confirmed track that dies and a new track confirmed within this long
        (s) near where it was last detected (0.5 m plus 0.5 m/s of the gap, at most 2 m;
        mutual nearest pairs) are one person lost through an occlusion: the new track is
        reported under the old id. 0 turns it off.
      report_misses: the multi-target estimators report (to the metrics, as the tracker's
        output) the confirmed tracks detected within the last ``report_misses + 1`` scans;
        tracks coasting longer through an occlusion are kept but not reported, as the ground
        truth holds only the people the laser sees.
    """

    kind: str = "pf"
    sensors: str = "both"
    num_particles: int = 256
    max_clusters: int = 8
    resampler: str = "systematic"
    capacity: int = 10
    jpda_method: str = "exact"
    appearance: bool = False
    gate: float = 0.7
    cluster_cap: float = 0.6
    laser_fov: tuple = (2.094, 0.1, 5.6)
    rgbd_fov: tuple = (0.497, 0.5, 4.5)
    report_misses: int = 3
    stitch_time: float = 10.0

    def __post_init__(self):
        _checks.check_options("estimator", (self.kind,), ESTIMATORS)
        _checks.check_options("sensors", (self.sensors,), SENSORS)


jax.tree_util.register_static(EstimatorConfig)


class EstimatorParams(NamedTuple):
    """Tunable estimator parameters: ``pf`` (`people_pf.PeoplePFParams`), ``tracker``
    (`tracker.TrackerParams`), and for ``"kf"``: log acceleration variances of person and robot,
    log detection std, log odometry-velocity std, chi-square gate probability; ``colour_std``:
    spread of the user's colour feature for re-identification (``appearance=True``)."""

    pf: people_pf.PeoplePFParams
    tracker: tracker.TrackerParams
    kf_log_q_person: Array
    kf_log_q_robot: Array
    kf_log_r: Array
    kf_log_r_odom: Array
    kf_gate: Array
    colour_std: Array
    config: EstimatorConfig

    @staticmethod
    def create(config: EstimatorConfig = EstimatorConfig(), *, dt=0.1, laser_std=0.1,
               rgbd_std=0.3, q=1.0, kf_q=4.0, colour_std=0.1, dtype=jnp.float32
               ) -> "EstimatorParams":
        """Natural-value defaults: laser people 0.1 m, RGB-D 0.3 m (seed 003); acceleration
        variance ``q`` (m^2/s^4) of the trackers and ``kf_q`` of the ``"kf"`` estimator (a single
        target gated on its own covariance needs room for stops and turns: measured with no
        distractors, the user was lost 51 % of the time with 1 and 8 % with 4)."""
        pf_cfg = people_pf.PeoplePFConfig(num_particles=config.num_particles,
                                          max_clusters=config.max_clusters, gate=config.gate,
                                          resampler=config.resampler,
                                          threshold_cap=config.cluster_cap)
        pf = people_pf.PeoplePFParams.create(pf_cfg, dt=dt, q=q, std=(laser_std, rgbd_std),
                                             dtype=dtype)
        assoc = {"gnn": "gnn", "jpda": "jpda", "nnjpda": "nn_jpda"}.get(config.kind, "gnn")
        tcfg = tracker.TrackerConfig(capacity=config.capacity, association=assoc,
                                     jpda_method=config.jpda_method, filter="ukf",
                                     num_features=3 if config.appearance else 0,
                                     max_misses=8, max_position_std=1.0, merge_distance=0.4)
        tparams = tracker.TrackerParams.create(
            tcfg, dt=dt, q=q, r_std=(laser_std, rgbd_std), p_detect=0.8, clutter_density=0.02,
            alpha=1.0 if config.appearance else 0.0, dtype=dtype)
        f = lambda x: jnp.asarray(x, dtype)  # noqa: E731
        return EstimatorParams(pf, tparams, f(jnp.log(kf_q)), f(jnp.log(0.5)),
                               f(jnp.log(laser_std)), f(jnp.log(0.05)), f(0.99999),
                               f(colour_std), config)


class Detected(NamedTuple):
    """Detections of one 10 Hz frame in the odometry frame.

    Attributes:
      laser_xy: [L, 2]; laser_mask: [L].
      rgbd_xy: [K, 2]; rgbd_mask: [K]; rgbd_colour: [K, 3].
    """

    laser_xy: Array
    laser_mask: Array
    rgbd_xy: Array
    rgbd_mask: Array
    rgbd_colour: Array


class Estimate(NamedTuple):
    """What the controller and the metrics see (odometry frame).

    Attributes:
      user: [4] ``[p_x, p_y, v_x, v_y]``; user_found: bool, measured at this frame.
      user_heading: scalar (rad); user_id: int32 identity of the estimate (-1 if none).
      people: [P, 2] every person estimate; people_ids: [P] int32; people_mask: [P].
      look: [2] where a robot that has lost its user should point its camera: the confirmed
        track, detected now, nearest to the user's last estimate whose identity the colours
        have not settled (multi-target estimators with ``appearance``; None otherwise).
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


def to_frame(pose: Array, xy: Array) -> Array:
    """World points [..., 2] into the frame of ``pose = (x, y, theta)``."""
    c, s = jnp.cos(pose[2]), jnp.sin(pose[2])
    d = xy - pose[:2]
    return jnp.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], -1)


def from_frame(pose: Array, xy: Array) -> Array:
    """Points [..., 2] in the frame of ``pose`` into the parent frame."""
    c, s = jnp.cos(pose[2]), jnp.sin(pose[2])
    return pose[:2] + jnp.stack([c * xy[..., 0] - s * xy[..., 1],
                                 s * xy[..., 0] + c * xy[..., 1]], -1)


def rotate(theta, v: Array) -> Array:
    """Vectors [..., 2] rotated by ``theta`` (e.g. robot-frame velocities into the parent
    frame; ``-theta`` for the inverse)."""
    c, s = jnp.cos(theta), jnp.sin(theta)
    return jnp.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], -1)


def _sensor_masks(cfg, det):
    lm = det.laser_mask & (cfg.sensors != "rgbd")
    km = det.rgbd_mask & (cfg.sensors != "laser")
    return lm, km


def init(key: Array, params: EstimatorParams, user_xy: Array, odom_pose: Array,
         user_colour: Array | None = None):
    """Initial state; the robot is shown its user at ``user_xy`` [2] (odometry frame), and
    sees their colour feature ``user_colour`` [3] (used with ``appearance=True``)."""
    cfg = params.config
    dtype = params.kf_log_r.dtype
    user_xy = jnp.asarray(user_xy, dtype)
    if cfg.kind == "pf":
        # Births are drawn around at most 16 of the last scan's detections (laser + RGB-D).
        return people_pf.init(key, params.pf, user_xy, max_births=16)
    if cfg.kind == "truth":
        return jnp.zeros((), dtype)
    if cfg.kind == "kf":
        rel = to_frame(jnp.asarray(odom_pose, dtype), user_xy)
        mean = jnp.concatenate([rel, jnp.zeros(4, dtype)])
        cov = jnp.diag(jnp.array([0.04, 0.04, 0.25, 0.25, 0.01, 0.01], dtype))
        return (kalman.Gaussian(mean, cov), jnp.zeros((), dtype))
    tr = tracker.init(params.tracker.config, dtype)
    # The user's track exists from the start (confirmed, id 0), as the robot was shown its user.
    tr = tr._replace(mean=tr.mean.at[0, :2].set(user_xy),
                     cov=tr.cov.at[0].set(jnp.diag(jnp.array([0.04, 0.04, 0.25, 0.25], dtype))),
                     id=tr.id.at[0].set(0), status=tr.status.at[0].set(tracker.CONFIRMED),
                     history=tr.history.at[0].set(1), hits=tr.hits.at[0].set(1),
                     next_id=jnp.int32(1))
    K = tr.mean.shape[0]
    colour = (jnp.full(3, 0.5, dtype) if user_colour is None
              else jnp.asarray(user_colour, dtype))
    ident = _Identity(colour, jnp.zeros(K, dtype).at[0].set(_LOGODDS_MAX), tr.id)
    stitch = _Stitch(tr.id, tr.id, tr.status == tracker.CONFIRMED, tr.mean[:, :2],
                     jnp.zeros(K, jnp.int32), jnp.full(K, -1, jnp.int32),
                     jnp.zeros((K, 2), dtype), jnp.zeros(K, jnp.int32))
    return (tr, jnp.int32(0), jnp.concatenate([user_xy, jnp.zeros(2, dtype)]), ident, stitch)


def update(key: Array, state, det: Detected, odom_pose: Array, odom_rate: Array,
           odom_speed: Array, params: EstimatorParams, truth: Array | None = None):
    """One 10 Hz frame. ``odom_pose`` [3]: robot pose in the odometry frame after the motion;
    ``odom_rate``, ``odom_speed``: the odometry's turn rate (rad/s) and forward speed (m/s) over
    the last period; ``truth`` [4]: the true user ``[p_x, p_y, v_x, v_y]`` in the odometry
    frame (needed by, and only used by, ``"truth"``). Returns ``(state, Estimate)``."""
    cfg = params.config
    if cfg.kind == "truth":
        if truth is None:
            raise ValueError('the "truth" estimator needs the true user (truth=[4])')
        _checks.check_shape("truth", truth, (4,), "(p_x, p_y, v_x, v_y)")
        truth = jnp.asarray(truth, state.dtype)
        none = jnp.zeros((1, 2), state.dtype)
        return state, Estimate(truth, jnp.array(True), jnp.arctan2(truth[3], truth[2]),
                               jnp.int32(0), none, jnp.full(1, -1, jnp.int32),
                               jnp.zeros(1, bool))
    lm, km = _sensor_masks(cfg, det)
    if cfg.kind == "pf":
        scans = (people_pf.Scan(det.laser_xy, lm, jnp.asarray(cfg.laser_fov)),
                 people_pf.Scan(det.rgbd_xy, km, jnp.asarray(cfg.rgbd_fov)))
        state = people_pf.step(key, state, scans, odom_pose, params.pf)
        cl = state.clusters
        heading = jnp.arctan2(state.target_mean[3], state.target_mean[2])
        k = cl.means.shape[0]
        est = Estimate(state.target_mean, state.target_found, heading,
                       jnp.where(state.target_found, 0, -1).astype(jnp.int32), cl.means[:, :2],
                       jnp.arange(k, dtype=jnp.int32), cl.mask)
        return state, est
    if cfg.kind == "kf":
        return _kf_update(state, det, lm, km, odom_pose, odom_rate, odom_speed, params)
    return _tracker_update(state, det, lm, km, params)


class _Identity(NamedTuple):
    """User re-identification state: the user's colour [3], per-slot log-odds that the track
    is the user [K], and the track id each log-odds belongs to [K] (a reused slot restarts)."""

    colour: Array
    logodds: Array
    ids: Array


_LOGODDS_MAX = 6.0   # log-odds saturate here (probability 0.9975)
_EVIDENCE = (-4.0, 3.0)   # one detection moves the log-odds by at most this much
_SWITCH = 2.0   # a track is (not) the user beyond +- this log-odds
_COLOUR_RADIUS = 0.45   # an RGB-D detection informs the nearest track within this (m) ...
_COLOUR_MARGIN = 0.2    # ... when the second nearest is this much farther (m)
_COAST = 0.8   # a lost user's velocity decays by this factor per frame
_FADE = 0.95   # colour log-odds fade by this factor per frame (half-life 1.4 s at 10 Hz)
_FADE_OTHER = 0.99   # ... but a track's evidence of being someone else by 0.99 (half-life 7 s)


def _colour_evidence(ident, tr, det, km, live, params):
    """Per-slot log-likelihood ratio 'user vs anyone else' from the frame's RGB-D colours.

    Other people's colours are taken as uniform in [0, 1]^3 (density 1), the user's as
    Gaussian around the colour shown at the start with std ``colour_std``."""
    dtype = tr.mean.dtype
    s2 = params.colour_std**2
    dc = jnp.sum((det.rgbd_colour.astype(dtype) - ident.colour) ** 2, -1)
    llr = -0.5 * dc / s2 - 1.5 * jnp.log(2.0 * jnp.pi * s2)
    llr = jnp.clip(llr, *_EVIDENCE)
    d2 = jnp.sum((det.rgbd_xy[:, None, :] - tr.mean[None, :, :2]) ** 2, -1)   # [M, K]
    d2 = jnp.where(live[None], d2, jnp.inf)
    first = jnp.argmin(d2, 1)
    d1 = jnp.take_along_axis(d2, first[:, None], 1)[:, 0]
    second = jnp.min(jnp.where(jnp.arange(d2.shape[1]) == first[:, None], jnp.inf, d2), 1)
    r1 = jnp.sqrt(jnp.minimum(d1, 1e6))
    r2 = jnp.sqrt(jnp.minimum(second, 1e6))
    use = km & (r1 <= _COLOUR_RADIUS) & (r2 - r1 >= _COLOUR_MARGIN)
    onehot = (first[:, None] == jnp.arange(d2.shape[1])) & use[:, None]
    return jnp.sum(jnp.where(onehot, llr[:, None], 0.0), 0)


class _Stitch(NamedTuple):
    """Reported ids across occlusions (per track slot, [K]): the id each slot's track is
    reported under, last frame's track id and confirmation, where and how many frames ago the
    track was last detected; and a memory of recently deleted confirmed tracks (reported id,
    last detected position, frames since then; id -1: empty)."""

    alias: Array
    prev_id: Array
    prev_confirmed: Array
    hit_pos: Array
    hit_age: Array
    mem_id: Array
    mem_pos: Array
    mem_age: Array


def _stitch(st: _Stitch, tr, dt, stitch_time):
    K = tr.id.shape[0]
    live = tr.status != tracker.FREE
    confirmed = tr.status == tracker.CONFIRMED
    same = live & (tr.id == st.prev_id)
    died = (st.prev_id >= 0) & ~same & st.prev_confirmed
    mem_id = jnp.where(died, st.alias, st.mem_id)
    mem_pos = jnp.where(died[:, None], st.hit_pos, st.mem_pos)
    mem_age = jnp.where(died, st.hit_age, st.mem_age) + 1
    mem_ok = (mem_id >= 0) & (mem_age * dt <= stitch_time)
    hit = live & (tr.misses == 0)
    hit_pos = jnp.where((hit | ~same)[:, None], tr.mean[:, :2], st.hit_pos)
    hit_age = jnp.where(hit | ~same, 0, st.hit_age + 1)
    new = confirmed & ~(same & st.prev_confirmed)
    alias = jnp.where(same, st.alias, tr.id)
    d = jnp.sqrt(jnp.sum((tr.mean[:, None, :2] - mem_pos[None]) ** 2, -1) + 1e-12)
    radius = jnp.minimum(0.5 + 0.5 * dt * mem_age, 2.0)
    d = jnp.where(new[:, None] & mem_ok[None] & (d <= radius[None]), d, jnp.inf)
    j = jnp.argmin(d, 1)
    k = jnp.argmin(d, 0)
    mutual = jnp.isfinite(jnp.min(d, 1)) & (k[j] == jnp.arange(K))
    alias = jnp.where(mutual, mem_id[j], alias)
    used = jnp.zeros(K, bool).at[jnp.where(mutual, j, K)].set(True, mode="drop")
    mem_id = jnp.where(used | ~mem_ok, -1, mem_id)
    return _Stitch(alias, jnp.where(live, tr.id, -1), confirmed, hit_pos, hit_age, mem_id,
                   mem_pos, mem_age)


def _tracker_update(state, det, lm, km, params):
    tr, user_id, last, ident, stitch = state
    cfg = params.config
    dtype = tr.mean.dtype
    L, K = det.laser_xy.shape[0], det.rgbd_xy.shape[0]
    feats = jnp.concatenate([jnp.zeros((L, 3), dtype), det.rgbd_colour.astype(dtype)], 0)
    dets = tracker.Detections(
        jnp.concatenate([det.laser_xy, det.rgbd_xy], 0).astype(dtype),
        jnp.concatenate([lm, km], 0),
        jnp.concatenate([jnp.zeros(L, jnp.int32), jnp.ones(K, jnp.int32)]),
        jnp.ones(L + K, dtype), feats if cfg.appearance else jnp.zeros((L + K, 0), dtype))
    tr = tracker.step(tr, dets, params.tracker)
    live = tr.status != tracker.FREE
    confirmed = tr.status == tracker.CONFIRMED
    has = live & (tr.id == user_id)
    found_old = jnp.any(has)
    # A lost user is assumed to slow down, not to walk on in a straight line for ever.
    pred = jnp.concatenate([last[:2] + params.tracker.dt * last[2:], _COAST * last[2:]])
    d2 = jnp.sum((tr.mean[:, :2] - pred[:2]) ** 2, -1)
    if cfg.appearance:
        # Evidence fades (a track's past colours say less about who it is now: tracks can
        # swap people in a crowd), then this frame's colours are added. Evidence that a track
        # is someone else fades five times slower: otherwise a distractor seen a second ago
        # becomes a candidate for re-acquisition as soon as the user is lost near them.
        fade = jnp.where(ident.logodds < 0.0, _FADE_OTHER, _FADE)
        logodds = jnp.where(live & (tr.id == ident.ids), fade * ident.logodds, 0.0)
        logodds = jnp.clip(logodds + _colour_evidence(ident, tr, det, km, live, params),
                           -_LOGODDS_MAX, _LOGODDS_MAX)
        ident = ident._replace(logodds=logodds, ids=tr.id)
        cur = jnp.argmax(has)
        best = jnp.argmax(jnp.where(confirmed, logodds, -jnp.inf))
        # Leave a track whose colours say it is someone else; take the track whose colours
        # say it is the user; otherwise keep the identity, or re-acquire the nearest track
        # not known to be someone else.
        cur_bad = (~found_old | (logodds[cur] < -_SWITCH)
                   | (logodds[best] > logodds[cur] + 2.0 * _SWITCH))
        to_best = cur_bad & confirmed[best] & (logodds[best] > _SWITCH)
        d2 = jnp.where(live & (logodds >= -_SWITCH), d2, jnp.inf)
        near = jnp.argmin(d2)
        reacquire = ~to_best & ~found_old & (d2[near] <= cfg.gate**2)
        keep = found_old & ~cur_bad
        slot = jnp.where(to_best, best, jnp.where(keep, cur, near))
        found = to_best | keep | reacquire
        # Whom to look at while the user is not measured: detected now, identity open.
        open_ = confirmed & (tr.misses == 0) & (jnp.abs(logodds) < _SWITCH)
        cand = jnp.argmin(jnp.where(open_, d2, jnp.inf))
        look, look_ok = tr.mean[cand, :2], open_[cand] & ~(found & (tr.misses[slot] == 0))
    else:
        d2 = jnp.where(live, d2, jnp.inf)
        near = jnp.argmin(d2)
        reacquire = ~found_old & (d2[near] <= cfg.gate**2)
        slot = jnp.where(found_old, jnp.argmax(has), near)
        found = found_old | reacquire
    user_id = jnp.where(found, tr.id[slot], user_id)
    mean = jnp.where(found, tr.mean[slot], pred)
    if cfg.stitch_time > 0:
        stitch = _stitch(stitch, tr, params.tracker.dt, cfg.stitch_time)
        ids = stitch.alias
    else:
        ids = tr.id
    est = Estimate(mean, found & (tr.misses[slot] == 0), tr.heading[slot],
                   jnp.where(found, user_id, -1).astype(jnp.int32), tr.mean[:, :2],
                   ids, confirmed & (tr.misses <= cfg.report_misses),
                   *((look, look_ok) if cfg.appearance else ()))
    return (tr, user_id, mean, ident, stitch), est


def _kf_update(state, det, lm, km, odom_pose, odom_rate, odom_speed, params):
    g, head = state
    dtype = g.mean.dtype
    dt = params.tracker.dt
    F, Q = motion.person_relative(dt, odom_rate, jnp.exp(params.kf_log_q_person),
                                  jnp.exp(params.kf_log_q_robot))
    g = kalman.predict(g, F.astype(dtype), Q.astype(dtype))
    H = measurement.person_relative(dtype)
    # Candidate positions in the robot frame; nearest gated one (Mahalanobis) is the user.
    xy = jnp.concatenate([det.laser_xy, det.rgbd_xy], 0)
    mask = jnp.concatenate([lm, km], 0)
    rel = to_frame(odom_pose, xy).astype(dtype)
    r = jnp.exp(params.kf_log_r)
    S = g.cov[:2, :2] + r**2 * jnp.eye(2, dtype=dtype)
    d = rel - g.mean[:2]
    d2 = jnp.einsum("mi,ij,mj->m", d, _linalg.inv2(S), d)
    # chi-square 2-dof quantile in closed form: -2 log(1 - p)
    gate = -2.0 * jnp.log1p(-params.kf_gate)
    d2 = jnp.where(mask & (d2 <= gate), d2, jnp.inf)
    j = jnp.argmin(d2)
    found = jnp.isfinite(d2[j])
    ro = jnp.exp(params.kf_log_r_odom)
    z = jnp.concatenate([jnp.where(found, rel[j], 0.0), jnp.stack([odom_speed, 0.0 * odom_speed])
                         ]).astype(dtype)
    R = jnp.diag(jnp.stack([r**2, r**2, ro**2, ro**2])).astype(dtype)
    zmask = jnp.stack([found, found, True, True])
    g, _ = kalman.update(g, z, H, R, zmask)
    head = heading_filter.ar_heading_step(head, g.mean[2:4])
    user_xy = from_frame(odom_pose, g.mean[:2])
    user_v = rotate(odom_pose[2], g.mean[2:4])
    user = jnp.concatenate([user_xy, user_v])
    est = Estimate(user, found, wrap(head + odom_pose[2]), jnp.int32(0), user_xy[None],
                   jnp.zeros(1, jnp.int32), jnp.ones(1, bool))
    return (g, head), est
