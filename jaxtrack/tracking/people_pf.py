r"""People particle filter fusing several detectors, with particle clustering (seed 004, Alg. 1).

One particle set ``[N, 4]`` of ``[p_x, p_y, v_x, v_y]`` represents the density of *all* people
around the robot (eq. 2). One `step`:

1. resample (systematic by default, or a differentiable scheme of `jaxtrack.filters.particle`);
2. propagate with the constant-velocity model (the proposal :math:`\pi_t` of Algorithm 1), and
   replace a fraction ``birth_fraction`` of the particles by *births* drawn around the previous
   scan's detections (beyond the seed: without births a density filter loses anyone it is not
   already tracking, and every newcomer would have to wander into existing particles; births from
   the *previous* scan must be confirmed by the current one, so a one-off false positive does not
   confirm itself);
3. weight by the product of the sensors' likelihoods (line 3 of Algorithm 1,
   :math:`\tilde w \propto \mathcal{L}_L \mathcal{L}_K`). The seed leaves the sensor models
   :math:`\mathrm{prob}(P_s \mid p)` unspecified; here each is the single-person likelihood ratio
   against clutter:

   .. math::
       \mathcal{L}_s(p) = 1 - P_D^s f_s(p) + P_D^s f_s(p) \sum_j
       \frac{\mathcal{N}(z^s_j;\, p,\, \sigma_s^2 I)}{\lambda_s},

   with :math:`f_s(p) \in [0, 1]` a smooth (sigmoid-edged) indicator of the sensor's field of view
   (bearing and range from the robot), so that a person outside the camera's 57 degrees keeps its
   weight instead of being starved by the people the camera sees;
4. cluster with Algorithms 2-5 (`jaxtrack.tracking.clustering.kclusterise`, dynamic threshold of
   eq. 5) into at most ``max_clusters`` Gaussian person estimates;
5. balance the clusters' masses (beyond the seed): one density for everyone makes people compete
   for particles, and a person the RGB-D camera missed for a scan loses most of them (the
   likelihood ratio of a detected person is ~100x that of a missed one). As in mixture particle
   filters (Vermaak, Doucet and Perez, ICCV 2003), each cluster supported by a detection this
   scan (one within ``support_radius`` whose nearest cluster it is, `supported`) is raised to
   at least ``cluster_floor`` of the mass before the next resampling; unsupported clusters (a
   false positive's births, fragments of a person's cloud) keep their mass and die out;
6. select the target (the user; the seed's selection procedure is "not described"): by
   motion continuity and, when the scans carry colour features and the state the user's colour,
   by colour (`select_target`): among the clusters within ``gate`` of the target's prediction,
   the one that minimises :math:`\tfrac12 d^2_M - \Lambda` (:math:`d_M` the Mahalanobis
   distance to the prediction, :math:`\Lambda` the colour log-likelihood ratio "user vs anyone
   else" of the RGB-D detection on the cluster, `jaxtrack.tracking.reid.evidence`), leaving out
   clusters whose colour says someone else; a target not found for ``t`` seconds may be taken
   up again, on clear colour evidence, up to ``gate + reacquire_speed t`` away (at most
   ``max_gate``). The target has its own constant-velocity Kalman filter fed with the selected
   cluster's mean and covariance.

Every shape is fixed (detections padded with masks), so a step jits once and vmaps over episodes.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxtrack import _checks
from jaxtrack.filters import _linalg, particle
from jaxtrack.models import motion
from jaxtrack.tracking import clustering
from jaxtrack.tracking import reid as reid_mod

Array = jax.Array

__all__ = ["PeoplePFConfig", "PeoplePFParams", "Scan", "PeoplePFState", "init", "step",
           "log_likelihood", "field_of_view", "select_target", "supported"]

_RESAMPLERS = ("systematic", "multinomial", "stratified", "stop_gradient", "soft")


@dataclasses.dataclass(frozen=True)
class PeoplePFConfig:
    """Static configuration (changing it recompiles).

    Attributes:
      num_particles: N.
      max_clusters: N_K of Algorithm 2.
      birth_fraction: fraction of the particles re-drawn around the previous detections.
      threshold_mode: "paper" (eq. 5 as printed, the default) or "half_mean" (half the mean
        pairwise distance; see `clustering.dynamic_threshold` for where eq. 5 fails).
      cluster_priority: `clustering.find_clusters`' order, "distance" (the paper's priority
        queue) or "order".
      threshold_floor: lower bound of the clustering threshold (m); eq. 5 gives 0 with fewer
        than two detections per sensor.
      threshold_cap: upper bound of the clustering threshold (m); eq. 5 grows with the spread
        of the detections, and in a room where furniture legs are detected too it reaches
        metres and merges people standing side by side (inf reproduces the paper).
      min_cluster_weight: a cluster lighter than this is not a person estimate.
      gate: a cluster farther than this (m) from the predicted target is not the target (by
        motion continuity alone).
      reacquire_speed, max_gate: with colours, a target lost for t seconds may be taken up
        again up to ``min(gate + reacquire_speed t, max_gate)`` away (m/s, m).
      reid: `jaxtrack.tracking.reid.ReidConfig` of the colour evidence (its ``evidence`` clip,
        ``colour_radius``, ``colour_margin`` and ``switch``: the evidence that excludes or
        re-acquires a cluster).
      resampler: "systematic" (default, exact), "multinomial", "stratified", "stop_gradient"
        (unbiased score-function gradients) or "soft" (mixing ``soft_alpha``).
      soft_alpha: mixing of soft resampling.
      cluster_floor: minimum mass of a detection-supported cluster (0 disables balancing).
      support_radius: a cluster is supported when a detection lies this close to its mean (m).
      fov_softness: width (rad and m) of the sigmoid edges of the field of view.
    """

    num_particles: int = 512
    max_clusters: int = 8
    birth_fraction: float = 0.1
    threshold_mode: str = "paper"
    cluster_priority: str = "distance"
    threshold_floor: float = 0.4
    threshold_cap: float = float("inf")
    min_cluster_weight: float = 0.03
    gate: float = 1.0
    reacquire_speed: float = 1.0
    max_gate: float = 4.0
    reid: reid_mod.ReidConfig = reid_mod.ReidConfig()
    resampler: str = "systematic"
    soft_alpha: float = 0.5
    cluster_floor: float = 0.1
    support_radius: float = 0.6
    fov_softness: float = 0.05

    def __post_init__(self):
        _checks.check_options("resampler", (self.resampler,), _RESAMPLERS)
        _checks.check_options("threshold_mode", (self.threshold_mode,), ("half_mean", "paper"))
        _checks.check_options("cluster_priority", (self.cluster_priority,), ("distance", "order"))
        if self.num_particles < 2 or self.max_clusters < 1:
            raise ValueError("need num_particles >= 2 and max_clusters >= 1")
        if not 0.0 <= self.birth_fraction < 1.0:
            raise ValueError(f"birth_fraction must be in [0, 1); got {self.birth_fraction}")
        if self.gate <= 0 or self.fov_softness <= 0:
            raise ValueError("gate and fov_softness must be > 0")

    @property
    def num_births(self) -> int:
        return int(round(self.birth_fraction * self.num_particles))

    def resampling(self):
        if self.resampler == "stop_gradient":
            return particle.stop_gradient_resampling()
        if self.resampler == "soft":
            return particle.soft_resampling(self.soft_alpha)
        return self.resampler


jax.tree_util.register_static(PeoplePFConfig)


class PeoplePFParams(NamedTuple):
    """Tunable parameters (unconstrained leaves). Build with `PeoplePFParams.create`.

    Attributes:
      log_q: log CV acceleration spectral density (m^2/s^3).
      log_std: [S] log detection-noise std of each sensor (m).
      logit_p_detect: [S] logit detection probability of each sensor.
      log_clutter_density: [S] log clutter density of each sensor (1/m^2).
      log_birth_std: log position std of births around a detection (m).
      log_birth_speed_std: log velocity std of births (m/s).
      log_colour_std: log spread of the target's colour feature (selection by colour).
      dt: scan period (s).
      config: `PeoplePFConfig` (static).
    """

    log_q: Array
    log_std: Array
    logit_p_detect: Array
    log_clutter_density: Array
    log_birth_std: Array
    log_birth_speed_std: Array
    log_colour_std: Array
    dt: Array
    config: PeoplePFConfig

    @staticmethod
    def create(config: PeoplePFConfig = PeoplePFConfig(), *, dt=0.1, q=1.0, std=(0.1, 0.3),
               p_detect=(0.8, 0.8), clutter_density=(0.05, 0.05), birth_std=0.2,
               birth_speed_std=0.5, colour_std=0.1, dtype=jnp.float32) -> "PeoplePFParams":
        """Parameters from natural values; one entry of ``std``, ``p_detect`` and
        ``clutter_density`` per sensor (defaults: laser legs 0.1 m, the project's own; RGB-D
        0.3 m as seed 003, whose laser figure is 0.2 m).

        Example:
          >>> params = PeoplePFParams.create(PeoplePFConfig(num_particles=256))
        """
        std, pd, lam = (jnp.atleast_1d(jnp.asarray(x, dtype)) for x in
                        (std, p_detect, clutter_density))
        if not std.shape == pd.shape == lam.shape:
            raise ValueError("std, p_detect and clutter_density need one entry per sensor")
        if min(q, dt, birth_std, birth_speed_std, colour_std) <= 0 or \
                bool(jnp.any(std <= 0)) or bool(jnp.any(lam <= 0)):
            raise ValueError("q, dt, std, clutter_density, colour_std and the birth stds must "
                             "be > 0")
        if bool(jnp.any((pd <= 0) | (pd >= 1))):
            raise ValueError("p_detect must be in (0, 1)")
        f = lambda x: jnp.asarray(x, dtype)  # noqa: E731
        return PeoplePFParams(f(jnp.log(q)), jnp.log(std), jnp.log(pd) - jnp.log1p(-pd),
                              jnp.log(lam), f(jnp.log(birth_std)), f(jnp.log(birth_speed_std)),
                              f(jnp.log(colour_std)), f(dt), config)


class Scan(NamedTuple):
    """One sensor's detections in the filter frame and its field of view.

    Attributes:
      xy: [M, 2] detections (filter frame); mask: [M] bools.
      fov: [3] ``(half_angle rad, min_range m, max_range m)`` around the sensor's heading.
      heading: the sensor's heading relative to the robot's (rad; a camera on a pan unit), or
        None (it looks along the robot's heading).
      colour: [M, 3] colour features of the detections (an RGB-D camera's), or None.
    """

    xy: Array
    mask: Array
    fov: Array
    heading: Array | None = None
    colour: Array | None = None


class PeoplePFState(NamedTuple):
    """Filter state.

    Attributes:
      particles: `ParticleSet` ([N, 4] in the filter frame, normalised log weights).
      clusters: `clustering.Clusters` of the last step.
      target_mean: [4] target (user) estimate; target_cov: [4, 4].
      target_found: bool, a cluster was associated with the target at the last step.
      births: [B, 2] detections of the last scan to draw births around; birth_mask: [B].
      target_colour: [3] the target's colour feature (selection by colour), or None.
      lost_time: seconds since a cluster was last associated with the target.
    """

    particles: particle.ParticleSet
    clusters: clustering.Clusters
    target_mean: Array
    target_cov: Array
    target_found: Array
    births: Array
    birth_mask: Array
    target_colour: Array | None = None
    lost_time: Array | None = None


def field_of_view(xy: Array, robot_pose: Array, fov: Array, softness: float = 0.05) -> Array:
    """Smooth indicator [..] in [0, 1] that points ``xy [..., 2]`` lie in a sensor's field of
    view ``fov = (half_angle, min_range, max_range)`` at ``robot_pose = (x, y, theta)``:
    a product of sigmoids of width ``softness`` on range, and on the cosine of the bearing (with
    width ``softness * sin(half_angle)``, i.e. about ``softness`` radians at the edge; no
    arctan2 per particle)."""
    d = xy - robot_pose[:2]
    rng = jnp.sqrt(jnp.sum(d**2, -1) + 1e-12)
    cos_b = (d[..., 0] * jnp.cos(robot_pose[2]) + d[..., 1] * jnp.sin(robot_pose[2])) / rng
    width = softness * jnp.maximum(jnp.sin(fov[0]), 0.05)
    s = jax.nn.sigmoid
    return (s((cos_b - jnp.cos(fov[0])) / width) * s((rng - fov[1]) / softness)
            * s((fov[2] - rng) / softness))


def log_likelihood(params: PeoplePFParams, positions: Array, scans: tuple[Scan, ...],
                   robot_pose: Array) -> Array:
    r"""Summed log likelihood ratios :math:`\sum_s \log \mathcal{L}_s(p)` (module docstring).

    Args:
      params: `PeoplePFParams` with one entry per scan.
      positions: [N, 2] candidate person positions (filter frame).
      scans: one `Scan` per sensor.
      robot_pose: [3] robot pose in the filter frame.

    Returns:
      [N] log likelihoods.
    """
    total = jnp.zeros(positions.shape[0], positions.dtype)
    for s, scan in enumerate(scans):
        var = jnp.exp(2 * params.log_std[s])
        d2 = jnp.sum((positions[:, None, :] - scan.xy[None, :, :]) ** 2, -1)  # [N, M]
        # Linear space: the sum is added to 1 - pd f >= 1 - pd > 0, so underflow is harmless.
        scale = jnp.exp(-params.log_clutter_density[s]) / (2 * jnp.pi * var)
        dens = scale * jnp.sum(jnp.where(scan.mask[None, :], jnp.exp(-0.5 * d2 / var), 0.0), 1)
        pose = robot_pose if scan.heading is None else robot_pose.at[2].add(scan.heading)
        pd = jax.nn.sigmoid(params.logit_p_detect[s]) * field_of_view(
            positions, pose, scan.fov, params.config.fov_softness)
        total = total + jnp.log1p(pd * (dens - 1.0))
    return total


def select_target(clusters: clustering.Clusters, predicted: Array, gate: float,
                  min_weight: float, predicted_cov: Array | None = None,
                  colour_llr: Array | None = None, wide_gate=None, switch: float = 2.0
                  ) -> tuple[Array, Array]:
    r"""The cluster that is the target.

    Without colours: among clusters heavier than ``min_weight`` and within ``gate`` (m) of the
    predicted target position [2], the nearest one -- in Mahalanobis distance :math:`d_M` under
    ``predicted_cov [2, 2] + cluster covariance`` when ``predicted_cov`` is given, else in
    metres. With ``colour_llr`` [K] (the colour log-likelihood ratio :math:`\Lambda_k` that
    cluster k is the target): the candidates within ``gate`` whose :math:`\Lambda > -` ``switch``
    and those within ``wide_gate`` whose :math:`\Lambda \ge` ``switch``; the one that minimises
    :math:`	frac12 d_M^2 - \Lambda`. Returns ``(index, found)``."""
    diff = clusters.means[:, :2] - predicted
    e2 = jnp.sum(diff**2, -1)
    heavy = clusters.mask & (clusters.weights >= min_weight)
    ok = heavy & (e2 <= gate**2)
    if predicted_cov is None:
        d2 = e2
    else:
        S = predicted_cov + clusters.covs[:, :2, :2]
        S = S + 1e-6 * jnp.eye(2, dtype=S.dtype)
        d2 = jnp.einsum("ki,kij,kj->k", diff, _linalg.inv2(S), diff)
    if colour_llr is not None:
        wide = gate if wide_gate is None else wide_gate
        ok = (ok & (colour_llr > -switch)) | (heavy & (e2 <= wide**2) & (colour_llr >= switch))
        d2 = 0.5 * d2 - colour_llr
    d2 = jnp.where(ok, d2, jnp.inf)
    idx = jnp.argmin(d2)
    return idx, jnp.isfinite(d2[idx])


def init(key: Array, params: PeoplePFParams, target_position: Array, *, position_std=0.2,
         speed_std=0.3, max_births: int = 16, target_colour: Array | None = None
         ) -> PeoplePFState:
    """Particles around the known initial target position [2] (the robot is shown whom to
    follow), zero mean velocity; ``target_colour`` [3]: the target's colour feature, for the
    selection by colour (None: by motion continuity alone).

    Example:
      >>> state = init(jax.random.PRNGKey(0), params, jnp.array([1.5, 0.0]))
    """
    cfg = params.config
    target_position = jnp.asarray(target_position, params.dt.dtype)
    _checks.check_shape("target_position", target_position, (2,))
    std = jnp.array([position_std, position_std, speed_std, speed_std], target_position.dtype)
    mean = jnp.concatenate([target_position, jnp.zeros(2, target_position.dtype)])
    x = mean + std * jax.random.normal(key, (cfg.num_particles, 4), target_position.dtype)
    n = cfg.num_particles
    lw = jnp.full(n, -jnp.log(n), x.dtype)
    k = cfg.max_clusters
    clusters = clustering.Clusters(
        jnp.zeros(k, x.dtype).at[0].set(1.0), jnp.zeros((k, 4), x.dtype).at[0].set(mean),
        jnp.tile(jnp.diag(std**2), (k, 1, 1)), jnp.zeros(k, bool).at[0].set(True),
        jnp.zeros((k, 2), x.dtype).at[0].set(target_position), jnp.zeros(n, jnp.int32))
    colour = None if target_colour is None else jnp.asarray(target_colour, x.dtype)
    return PeoplePFState(particle.ParticleSet(x, lw), clusters, mean, jnp.diag(std**2),
                         jnp.asarray(True), jnp.zeros((max_births, 2), x.dtype),
                         jnp.zeros(max_births, bool), colour,
                         None if colour is None else jnp.zeros((), x.dtype))


def step(key: Array, state: PeoplePFState, scans: tuple[Scan, ...], robot_pose: Array,
         params: PeoplePFParams) -> PeoplePFState:
    """One step of Algorithm 1 plus clustering and target selection (module docstring).

    Args:
      key: PRNG key.
      state: `PeoplePFState`.
      scans: tuple of `Scan`, one per sensor, in the order of ``params.log_std``; an empty
        sensor is a scan whose mask is all False.
      robot_pose: [3] robot pose in the filter frame (for the fields of view).
      params: `PeoplePFParams`.

    Returns:
      The new `PeoplePFState`.

    Example:
      >>> scans = (Scan(laser_xy, laser_mask, jnp.array([2.09, 0.1, 5.6])),
      ...          Scan(rgbd_xy, rgbd_mask, jnp.array([0.5, 0.5, 4.5])))
      >>> state = step(key, state, scans, robot_pose, params)
      >>> state.target_mean[:2]
    """
    _check(state, scans, robot_pose, params)
    return _step(key, state, scans, robot_pose, params)


def _step(key, state, scans, robot_pose, params):
    cfg = params.config
    dtype = state.particles.particles.dtype
    robot_pose = jnp.asarray(robot_pose, dtype)
    scans = tuple(Scan(jnp.asarray(s.xy, dtype), jnp.asarray(s.mask, bool),
                       jnp.asarray(s.fov, dtype),
                       None if s.heading is None else jnp.asarray(s.heading, dtype),
                       None if s.colour is None else jnp.asarray(s.colour, dtype))
                  for s in scans)
    F, Q = motion.constant_velocity(params.dt, jnp.exp(params.log_q))
    chol_q = _linalg.cholesky(Q + 1e-9 * jnp.eye(4, dtype=Q.dtype)).astype(dtype)
    F = F.astype(dtype)
    nb = cfg.num_births
    births, bmask = state.births, state.birth_mask

    def transition(k, x):
        k1, k2, k3 = jax.random.split(k, 3)
        x = x @ F.T + jax.random.normal(k1, x.shape, dtype) @ chol_q.T
        if nb == 0:
            return x
        # Births: uniform over the previous scan's detections.
        logits = jnp.where(bmask, 0.0, -jnp.inf)
        j = jax.random.categorical(k2, jnp.where(jnp.any(bmask), logits, 0.0), shape=(nb,))
        noise = jax.random.normal(k3, (nb, 4), dtype)
        b = jnp.concatenate([births[j] + jnp.exp(params.log_birth_std) * noise[:, :2],
                             jnp.exp(params.log_birth_speed_std) * noise[:, 2:]], 1)
        return x.at[-nb:].set(jnp.where(jnp.any(bmask), b, x[-nb:]))

    def loglik(z, x):
        return log_likelihood(params, x[:, :2], z, robot_pose)

    ps, _ = particle.step(key, state.particles, scans, transition, loglik,
                          resampler=cfg.resampling(), vectorized=True)
    all_xy = jnp.concatenate([s.xy for s in scans], 0)
    all_mask = jnp.concatenate([s.mask for s in scans], 0)
    other = scans[1] if len(scans) > 1 else Scan(scans[0].xy[:0], scans[0].mask[:0], None)
    threshold = clustering.dynamic_threshold(
        scans[0].xy, other.xy, scans[0].mask, other.mask, floor=cfg.threshold_floor,
        mode=cfg.threshold_mode)
    threshold = jnp.minimum(threshold, cfg.threshold_cap)
    clusters = clustering.kclusterise(ps.particles, ps.log_weights, threshold, cfg.max_clusters,
                                      priority=cfg.cluster_priority)
    if cfg.cluster_floor > 0:
        ps, clusters = _balance(ps, clusters, all_xy, all_mask, cfg)
    pred_mean = F @ state.target_mean
    pred_cov = F @ state.target_cov @ F.T + Q.astype(dtype)
    coloured = [s for s in scans if s.colour is not None]
    if state.target_colour is not None and coloured:
        s = coloured[0]
        llr = reid_mod.evidence(cfg.reid, reid_mod.ReidState(state.target_colour, None, None),
                                clusters.means[:, :2], clusters.mask, s.xy, s.colour, s.mask,
                                jnp.exp(params.log_colour_std))
        wide = jnp.minimum(cfg.gate + cfg.reacquire_speed * state.lost_time, cfg.max_gate)
        idx, found = select_target(clusters, pred_mean[:2], cfg.gate, cfg.min_cluster_weight,
                                   pred_cov[:2, :2], llr, wide, cfg.reid.switch)
    else:
        idx, found = select_target(clusters, pred_mean[:2], cfg.gate, cfg.min_cluster_weight,
                                   pred_cov[:2, :2])
    # The target keeps its own constant-velocity Kalman filter, updated with the selected
    # cluster's mean under the cluster's covariance: when the user brushes past someone and
    # the two clusters merge for a few scans, the spread-out merged cluster moves the estimate
    # little, and the velocity carries the prediction past the other person.
    H = jnp.eye(2, 4, dtype=dtype)
    R = clusters.covs[idx, :2, :2] + jnp.exp(2 * params.log_std[0]) * jnp.eye(2, dtype=dtype)
    S = pred_cov[:2, :2] + R
    K = (_linalg.inv2(S) @ pred_cov[:2, :]).T
    innov = clusters.means[idx, :2] - pred_mean[:2]
    IKH = jnp.eye(4, dtype=dtype) - K @ H
    post_cov = IKH @ pred_cov @ IKH.T + K @ R @ K.T
    mean = jnp.where(found, pred_mean + K @ innov, pred_mean)
    cov = jnp.where(found, 0.5 * (post_cov + post_cov.T), pred_cov)
    # The next births are drawn around this scan's detections (the first ``cap`` present).
    cap = state.births.shape[0]
    order = jnp.argsort(~all_mask, stable=True)[:cap]
    b_xy = jnp.zeros((cap, 2), dtype).at[:order.shape[0]].set(
        jnp.where(all_mask[order, None], all_xy[order], 0.0))
    b_mask = jnp.zeros(cap, bool).at[:order.shape[0]].set(all_mask[order])
    lost = None if state.lost_time is None else jnp.where(found, 0.0, state.lost_time
                                                           + params.dt).astype(dtype)
    return PeoplePFState(ps, clusters, mean, cov, found, b_xy, b_mask, state.target_colour,
                         lost)


def supported(clusters: clustering.Clusters, det_xy: Array, det_mask: Array,
              radius: float) -> Array:
    """[K] clusters supported by a detection: the nearest cluster of a detection ``det_xy``
    [M, 2] (``det_mask`` [M]) within ``radius`` (m). A detection supports one cluster only:
    the fragments that the clustering splits off one person's particle cloud are not
    supported by that person's detection.

    Example:
      >>> ok = supported(state.clusters, laser_xy, laser_mask, radius=0.6)   # [K] bools
    """
    d2 = jnp.sum((clusters.means[:, None, :2] - det_xy[None]) ** 2, -1)     # [K, M]
    d2 = jnp.where(clusters.mask[:, None], d2, jnp.inf)
    nearest = jnp.argmin(d2, 0) == jnp.arange(d2.shape[0])[:, None]          # [K, M]
    return clusters.mask & jnp.any(nearest & det_mask[None] & (d2 <= radius**2), 1)


def _balance(ps, clusters, det_xy, det_mask, cfg):
    supported_ = supported(clusters, det_xy, det_mask, cfg.support_radius)
    w = clusters.weights
    target = jnp.where(supported_, jnp.maximum(w, cfg.cluster_floor), w)
    shift = jnp.where(w > 0, jnp.log(jnp.where(w > 0, target, 1.0))
                      - jnp.log(jnp.where(w > 0, w, 1.0)), 0.0)
    lw = ps.log_weights + jnp.where(clusters.labels >= 0, shift[clusters.labels], 0.0)
    lw = particle.normalize(lw)
    total = jnp.sum(target)
    return (particle.ParticleSet(ps.particles, lw),
            clusters._replace(weights=target / jnp.where(total > 0, total, 1.0)))


def _check(state, scans, robot_pose, params):
    if not isinstance(state, PeoplePFState):
        raise TypeError(f"state must be a PeoplePFState; got {type(state).__name__}")
    if not isinstance(scans, (tuple, list)) or not scans:
        raise TypeError("scans must be a non-empty tuple of Scan")
    if len(scans) != params.log_std.shape[0]:
        raise ValueError(f"got {len(scans)} scans but parameters for {params.log_std.shape[0]}"
                         " sensors")
    for i, s in enumerate(scans):
        _checks.check_shape(f"scans[{i}].xy", s.xy, (None, 2))
        _checks.check_shape(f"scans[{i}].mask", s.mask, (s.xy.shape[0],))
        _checks.check_shape(f"scans[{i}].fov", s.fov, (3,))
    _checks.check_shape("robot_pose", robot_pose, (3,))
