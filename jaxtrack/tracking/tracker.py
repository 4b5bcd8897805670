r"""Multi-target tracker with fixed capacity: predict -> gate -> associate -> update -> manage.

Every track slot ``k < K`` holds a constant-velocity ground-plane Gaussian over
``[p_x, p_y, v_x, v_y]`` plus bookkeeping: id, age, hits, misses, an M-of-N hit history, status
(free / tentative / confirmed), heading and an online colour classifier. One call of `step`
processes one scan of detections (fixed capacity M with a mask, optionally from several sensors
each with its own noise, seed 003):

1. predict every live track (KF, or UKF by config: seed 001 uses a UKF; with the linear CV model
   both give the same moments);
2. gate with the chi-square quantile of the squared Mahalanobis distance;
3. associate, by static config:
   - ``"gnn"`` (seed 001): optimal assignment (Hungarian) of the three-term cost of eq. 2,
     :math:`\gamma D^2_M - \alpha c_{online} - \beta c_{det}` (the paper writes a sum of
     negative log-likelihoods; with confidences in [0, 1] the signs are folded into
     :math:`\alpha, \beta \ge 0`), then a Kalman update per assigned track;
   - ``"jpda"`` (seed 003): JPDA marginals with Poisson clutter and detection probability,
     then the combined-innovation update;
   - ``"nn_jpda"`` (seed 003, eq. 9): the MAP detection per track from the JPDA marginals,
     then a standard update;
4. manage: a track is *hit* when it got a detection (JPDA: probability of detection > 1/2);
   tentative tracks are confirmed after ``confirm_hits`` hits in the last ``confirm_window``
   scans; tracks are deleted after ``max_misses`` consecutive misses (``max_tentative_misses``
   for tentative ones), when the position standard deviation exceeds ``max_position_std`` or
   when the state is not finite; detections left unassociated, outside every live gate, whose
   detector confidence is at least ``birth_confidence`` (seed 001) start tentative tracks in
   free slots, with ids
   ``next_id, next_id + 1, ...``: unique and increasing, slots recycled.

People (seed 003): `is_walking` thresholds the speed at 0.1 m/s; the heading follows the
velocity while walking, directly or through seed 002's adaptive AR filter.

Motion (``config.motion``): ``"cv"`` is the constant-velocity model above; ``"imm"`` is an
interacting multiple model (`jaxtrack.filters.imm`) of a *walking* mode (the same constant
velocity) and a *standing* mode (velocity zero, position a slow random walk), the two motions of
people trackers such as SPENCER's. Each track then also carries its mode-matched Gaussians and
log mode probabilities (``Tracks.modes``); gating and association read the moment-matched
combined prediction (the usual IMM-JPDA / IMM-GNN approximation), the chosen association updates
every mode, and ``mean`` / ``cov`` stay the combined estimate that management and every consumer
read (`predict_modes`, `associate`).

`step` chains five stages, each a public function with a named result, which a closed loop may
also call one by one (e.g. to read the association of a scan) -- Stone Soup's tracker loop::

    predicted = predict(state, params)                            # Gaussian [K, 4]
    hyp = hypothesise(state, predicted, detections, params)      # gates [K, M]: Hypotheses
    assoc = associate(hyp, params)       # associate_gnn / _jpda / _nn_jpda: Association
    tracks = manage(state, hyp, assoc, params)                   # confirm / delete / merge
    tracks = births(tracks, hyp, assoc, params).tracks           # new tracks in free slots
"""

from __future__ import annotations

import dataclasses
import numbers
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxtrack import _checks, association
from jaxtrack.filters import heading as heading_filter
from jaxtrack.filters import imm, ukf
from jaxtrack.filters.kalman import Gaussian
from jaxtrack.models import measurement, motion
from jaxtrack.tracking import appearance

Array = jax.Array

__all__ = ["TrackerConfig", "TrackerParams", "Tracks", "Detections", "init", "step", "run",
           "is_walking", "make_detections", "FREE", "TENTATIVE", "CONFIRMED", "WALKING",
           "STANDING", "Hypotheses", "Association", "Births", "predict", "predict_modes",
           "hypothesise", "associate",
           "associate_gnn", "associate_jpda", "associate_nn_jpda", "manage", "births"]

FREE, TENTATIVE, CONFIRMED = 0, 1, 2
WALKING, STANDING = 0, 1
"""Indices of the modes of ``motion="imm"`` in ``Tracks.modes``."""


@dataclasses.dataclass(frozen=True)
class TrackerConfig:
    r"""Static configuration (changing it recompiles).

    Attributes:
      capacity: K track slots.
      association: "gnn", "jpda" or "nn_jpda".
      jpda_method: "exact" or "lbp" (for "jpda" and "nn_jpda").
      filter: "kf" or "ukf".
      heading: "velocity" or "ar" (seed 002's adaptive AR filter).
      motion: "cv" (constant velocity) or "imm" (walking / standing IMM, see the module
        docstring; it predicts with the Kalman filter whatever ``filter`` says: both give the
        same moments for its linear modes).
      confirm_hits, confirm_window: M-of-N confirmation.
      max_misses, max_tentative_misses: consecutive misses before deletion.
      max_position_std: delete a track whose position std (sqrt of the largest position
        variance) exceeds this (m).
      num_features: length of the appearance feature (0: no appearance term).
      merge_distance: two live tracks closer than this (m) are one person seen twice (e.g.
        born from two sensors, or two tracks that converged): the weaker one -- tentative
        before confirmed, then fewer hits, then the newer id -- is deleted. Also, of the
        detections that start tracks in one scan, one closer than this to an earlier one (the
        earlier sensor first) starts none. ``0`` turns both off. People's centres are never
        closer than about 0.5 m, so up to 0.4 m is safe for them.
      births_in_gates: an unassociated detection inside a live track's gate may start a track
        (off for people: the track would be a duplicate; on for legs, whose neighbours'
        gates reach across the 0.1-0.4 m between a person's two legs).
      tentative_outside_confirmed: a detection inside a confirmed track's gate updates no
        tentative track (it is the confirmed track's, or clutter beside it). Off, a tentative
        track born of clutter beside a person takes that person's noisier detections (a 0.3 m
        RGB-D detection lands in its wide new gate) and is confirmed by them: a false track
        that then coasts away. Tracks start outside live gates anyway (``births_in_gates``).
      tentative_from_births: a detection under ``birth_confidence`` updates no tentative
        track: one that may not start a track does not confirm one either (else clutter of a
        sensor trusted to start tracks, confirmed by the clutter of one that is not, becomes
        a false track that neither sensor alone makes).
      motion_term: the Mahalanobis distance of the GNN cost and gate. "position": of the
        detected position. "position_velocity" (seed 001, section IV-B: "the Mahalanobis
        distance of the detection position and estimated velocity from the predicted state"):
        of the position and of the velocity it implies over about ``velocity_window`` scans,
        :math:`(z - p_{t-L}) / (L \Delta t)` from the track's position L scans earlier, gated
        with 4 degrees of freedom; the assigned track is updated with both (seed 001's
        implementation, open_ptrack; see `_position_velocity_d2`). Only with
        ``association="gnn"``.
      velocity_window: L, in scans, of "position_velocity" (open_ptrack: 1 s, so 10 at
        10 Hz); the baseline is never older than the track's first scan or younger than its
        last detection, and never longer than 2 L. Each track keeps its last 2 L - 1 positions
        (``Tracks.trail``).
      velocity_noise_ratio: the velocity measurement's noise variance over the position's, per
        axis (open_ptrack: 16, in (m/s)^2 per m^2).
      distance: how the GNN cost weighs it: "squared" (:math:`\gamma d^2`) or "mahalanobis"
        (:math:`\gamma d`, seed 001's eq. 2 writes the distance, not its square).
      sensor_update: how "jpda" and "nn_jpda" use a scan of several sensors. "joint": one
        association over all the scan's detections. "sequential": one association and update
        per sensor, each starting from the previous sensor's posterior
        (`jaxtrack.association.sequential_jpda_update`; Pao and Frei 1995): a person seen by
        three sensors yields three detections in one scan, which a joint JPDA, where each track
        takes at most one detection, must call clutter or other people. Only with
        ``motion="cv"`` and ``motion_term="position"``.
    """

    capacity: int = 16
    association: str = "jpda"
    jpda_method: str = "exact"
    filter: str = "kf"
    heading: str = "velocity"
    motion: str = "cv"
    confirm_hits: int = 3
    confirm_window: int = 5
    max_misses: int = 5
    max_tentative_misses: int = 2
    max_position_std: float = 1.5
    num_features: int = 0
    merge_distance: float = 0.0
    births_in_gates: bool = False
    tentative_outside_confirmed: bool = False
    tentative_from_births: bool = False
    motion_term: str = "position"
    velocity_window: int = 10
    velocity_noise_ratio: float = 16.0
    distance: str = "squared"
    sensor_update: str = "joint"

    def __post_init__(self):
        _checks.check_options("association", (self.association,), ("gnn", "jpda", "nn_jpda"))
        _checks.check_options("jpda_method", (self.jpda_method,), ("exact", "lbp"))
        _checks.check_options("filter", (self.filter,), ("kf", "ukf"))
        _checks.check_options("heading", (self.heading,), ("velocity", "ar"))
        _checks.check_options("motion", (self.motion,), ("cv", "imm"))
        _checks.check_options("motion_term", (self.motion_term,),
                              ("position", "position_velocity"))
        _checks.check_options("distance", (self.distance,), ("squared", "mahalanobis"))
        _checks.check_options("sensor_update", (self.sensor_update,), ("joint", "sequential"))
        if self.sensor_update == "sequential" and (self.association == "gnn"
                                                   or self.motion != "cv"):
            raise ValueError('sensor_update="sequential" needs association="jpda" or "nn_jpda" '
                             'and motion="cv"')
        if self.motion_term == "position_velocity" and self.association != "gnn":
            raise ValueError('motion_term="position_velocity" needs association="gnn" (the '
                             'JPDA likelihoods are those of the position)')
        if self.capacity < 1:
            raise ValueError(f"capacity must be >= 1; got {self.capacity}")
        if not (isinstance(self.velocity_window, numbers.Integral)
                and not isinstance(self.velocity_window, bool) and self.velocity_window >= 1):
            raise ValueError(f"velocity_window must be an int >= 1 (scans); got "
                             f"{self.velocity_window!r}")
        if not (np.isfinite(self.velocity_noise_ratio) and self.velocity_noise_ratio > 0):
            raise ValueError(f"velocity_noise_ratio must be finite and > 0; got "
                             f"{self.velocity_noise_ratio}")
        if not 1 <= self.confirm_hits <= self.confirm_window <= 30:
            raise ValueError("need 1 <= confirm_hits <= confirm_window <= 30")
        if self.max_misses < 1 or self.max_tentative_misses < 1:
            raise ValueError("max_misses and max_tentative_misses must be >= 1")
        if not self.merge_distance >= 0:
            raise ValueError(f"merge_distance must be >= 0; got {self.merge_distance}")

    @property
    def num_modes(self) -> int:
        """Motion modes per track in ``Tracks.modes``: 2 for "imm", 0 for "cv"."""
        return 2 if self.motion == "imm" else 0

    @property
    def trail_length(self) -> int:
        """Earlier positions per track in ``Tracks.trail``: 2 ``velocity_window`` - 1 for
        ``motion_term="position_velocity"``, 0 otherwise."""
        return 2 * self.velocity_window - 1 if self.motion_term == "position_velocity" else 0


jax.tree_util.register_static(TrackerConfig)


class TrackerParams(NamedTuple):
    """Tunable parameters (unconstrained float leaves) and the static config.

    Build with `TrackerParams.create` from natural values.

    Attributes:
      log_q: log acceleration spectral density of the CV model (m^2/s^3).
      log_r_std: [S] log position-noise std of each sensor (m).
      logit_p_detect: logit of the detection probability.
      log_clutter_density: log clutter density (1/m^2).
      log_init_speed_std: log std of the initial velocity of a new track (m/s).
      gamma, alpha, beta: weights of the GNN cost (Mahalanobis, appearance, detector).
      birth_confidence: minimum detector confidence to start a track.
      gate_prob: chi-square gate probability.
      walking_speed: standing / walking threshold (m/s).
      appearance_lr: learning rate of the online colour classifier.
      dt: scan period (s).
      mode_logits: [2, 2] logits of the IMM mode transition per scan (row i: from mode i,
        `WALKING` or `STANDING`; ``jaxtrack.filters.imm.transition_from_logits``).
      log_q_standing: log process noise of the standing mode (m^2/s).
      logit_init_standing: logit of a new track's standing probability.
      config: `TrackerConfig` (static).

    The last three are read only with ``config.motion = "imm"``.
    """

    log_q: Array
    log_r_std: Array
    logit_p_detect: Array
    log_clutter_density: Array
    log_init_speed_std: Array
    gamma: Array
    alpha: Array
    beta: Array
    birth_confidence: Array
    gate_prob: Array
    walking_speed: Array
    appearance_lr: Array
    dt: Array
    mode_logits: Array
    log_q_standing: Array
    logit_init_standing: Array
    config: TrackerConfig

    @staticmethod
    def create(config: TrackerConfig = TrackerConfig(), *, dt=0.1, q=0.5,
               r_std=(0.1, 0.3, 0.2), p_detect=0.9, clutter_density=0.01, init_speed_std=1.0,
               gamma=1.0, alpha=0.0, beta=0.0, birth_confidence=0.0, gate_prob=0.9999,
               walking_speed=0.1, appearance_lr=0.5,
               mode_transition=((0.98, 0.02), (0.02, 0.98)), q_standing=0.005,
               init_standing=0.5, dtype=jnp.float32) -> "TrackerParams":
        """Parameters from natural values. Defaults: seed 003's sensor noise (ceiling cameras
        0.1 m, RGB-D 0.3 m, laser legs 0.2 m) and walking threshold 0.1 m/s; a wide gate
        (0.9999): with 0.99 one noisy detection that bends a velocity estimate can put the next
        detection outside the gate, and the person is re-acquired by a new track (an identity
        switch), as measured in the crossing tests.

        The IMM (``motion="imm"``): ``mode_transition`` [2, 2], the probabilities of going
        from mode i (row; `WALKING`, `STANDING`) to mode j per scan, entries in (0, 1), rows
        summing to one (default: either motion lasts 5 s on average at 10 Hz); ``q_standing``
        the standing mode's process noise (m^2/s, > 0: a position std of 2.2 cm per 0.1 s);
        ``init_standing`` in (0, 1), a new track's standing probability. To force one mode
        (transition probabilities 0 or 1) set the logits of the returned params directly.

        Example:
          >>> params = TrackerParams.create(TrackerConfig(association="gnn"), r_std=(0.2,))
        """
        # Concrete values are checked here; traced ones (a sweep under jit / vmap) cannot be.
        def concrete(x):
            return all(map(_checks.is_concrete, jax.tree_util.tree_leaves(x)))

        if concrete(p_detect) and not 0 < p_detect < 1:
            raise ValueError(f"p_detect must be in (0, 1); got {p_detect}")
        positive = [x for x in (q, clutter_density, init_speed_std, dt, r_std) if concrete(x)]
        # Written so that NaN fails too (NaN <= 0 is False).
        if not all(np.all(np.asarray(x, float) > 0) and np.all(np.isfinite(x)) for x in positive):
            raise ValueError("q, r_std, clutter_density, init_speed_std and dt must be > 0 "
                             "and finite")
        for name, x in (("gamma", gamma), ("alpha", alpha), ("beta", beta),
                        ("birth_confidence", birth_confidence), ("walking_speed", walking_speed),
                        ("appearance_lr", appearance_lr)):
            if concrete(x) and not np.all(np.isfinite(np.asarray(x, float))):
                raise ValueError(f"{name} must be finite; got {x!r}")
        if concrete(gate_prob) and not 0 < gate_prob < 1:
            raise ValueError(f"gate_prob must be in (0, 1); got {gate_prob}")
        _checks.check_shape("mode_transition", mode_transition, (2, 2),
                            "[2, 2] walking / standing transition probabilities")
        if concrete(mode_transition):
            a = np.asarray(mode_transition, float)
            if not np.all((a > 0) & (a < 1)):
                raise ValueError("mode_transition entries must be finite probabilities in "
                                 f"(0, 1); got {a.tolist()}")
            if np.max(np.abs(a.sum(1) - 1)) > 1e-6:
                raise ValueError(f"each row of mode_transition must sum to 1; got {a.tolist()}")
        if concrete(q_standing) and not (np.isfinite(q_standing) and q_standing > 0):
            raise ValueError(f"q_standing must be finite and > 0; got {q_standing}")
        if concrete(init_standing) and not 0 < init_standing < 1:
            raise ValueError(f"init_standing must be in (0, 1); got {init_standing}")
        f = lambda x: jnp.asarray(x, dtype)  # noqa: E731
        return TrackerParams(
            f(jnp.log(q)), f(jnp.log(jnp.asarray(r_std))),
            f(jnp.log(p_detect) - jnp.log1p(-p_detect)), f(jnp.log(clutter_density)),
            f(jnp.log(init_speed_std)), f(gamma), f(alpha), f(beta), f(birth_confidence),
            f(gate_prob), f(walking_speed), f(appearance_lr), f(dt),
            f(jnp.log(jnp.asarray(mode_transition))), f(jnp.log(q_standing)),
            f(jnp.log(init_standing) - jnp.log1p(-init_standing)), config)


class Tracks(NamedTuple):
    """Tracker state with K slots.

    Attributes:
      mean: [K, 4] ``[p_x, p_y, v_x, v_y]``; cov: [K, 4, 4].
      id: [K] int32 track id (-1 in free slots). age, hits, misses: [K] int32.
      history: [K] int32 bit mask of hits in the last scans (bit 0 = this scan).
      status: [K] int32, `FREE`, `TENTATIVE` or `CONFIRMED`.
      heading: [K] heading (rad).
      appearance: per-track colour classifiers.
      next_id: scalar int32, the id the next new track gets.
      num_dropped: scalar int32, births that found no free slot.
      modes: `jaxtrack.filters.imm.IMMState` of every slot, means [K, D, 4], covs
        [K, D, 4, 4], log_mode_probs [K, D], with D = ``config.num_modes`` (2 for
        ``motion="imm"``: `WALKING`, `STANDING`; 0 for "cv"). ``mean`` / ``cov`` are their
        combined (moment-matched) estimate. A track of age 0 (just born, or placed by hand
        with ``_replace`` as `jaxtrack.tracking.user.multi_target` places its user) starts its
        modes from ``mean`` / ``cov`` in `predict_modes`.
      trail: [K, T, 2] the track's positions (``mean[:2]`` after each scan) before the last
        scan, newest first: ``trail[:, i]`` is that of i + 1 scans before ``mean``; a new track
        fills it with its first position. T = ``config.trail_length`` (0 unless
        ``motion_term="position_velocity"``, which reads it).
    """

    mean: Array
    cov: Array
    id: Array
    age: Array
    hits: Array
    misses: Array
    history: Array
    status: Array
    heading: Array
    appearance: appearance.Appearance
    next_id: Array
    num_dropped: Array
    modes: imm.IMMState
    trail: Array


class Detections(NamedTuple):
    """One scan: positions [M, 2], mask [M], sensor [M] int32, confidence [M],
    features [M, F] (F may be 0). Build with `make_detections`.

    A detection without an appearance (a laser person among RGB-D ones) has a row of NaN
    features: its colour confidence is 1/2 for every track (no evidence) and it never trains a
    track's classifier, as a positive or as a negative."""

    positions: Array
    mask: Array
    sensor: Array
    confidence: Array
    features: Array


def make_detections(positions, capacity: int, sensor=None, confidence=None, features=None,
                    num_features: int = 0) -> Detections:
    """Pad a variable-length list of detections into a fixed-capacity `Detections` (host side).

    Raises a ValueError when there are more detections than ``capacity``.

    Example:
      >>> det = make_detections([[1.0, 2.0], [3.0, 0.5]], capacity=8)
    """
    pos = jnp.asarray(positions)
    n = 0 if pos.size == 0 else pos.shape[0]
    if pos.size == 0:
        pos = jnp.zeros((0, 2))
    sensor = jnp.zeros(n, jnp.int32) if sensor is None else jnp.asarray(sensor, jnp.int32)
    zs, mask, sens = association.pad_detections(pos, capacity, sensor)
    conf = jnp.ones(n, zs.dtype) if confidence is None else jnp.asarray(confidence, zs.dtype)
    _checks.check_shape("confidence", conf, (n,), "one confidence per detection")
    conf = jnp.zeros(capacity, zs.dtype).at[:n].set(conf)
    if features is None:
        feats = jnp.zeros((capacity, num_features), zs.dtype)
    else:
        f = jnp.asarray(features, zs.dtype)
        _checks.check_shape("features", f, (n, None), "one feature row per detection")
        feats = jnp.zeros((capacity, f.shape[1]), zs.dtype).at[:n].set(f)
    return Detections(zs, mask, sens, conf, feats)


def init(config: TrackerConfig = TrackerConfig(), dtype=jnp.float32) -> Tracks:
    """An empty tracker state.

    Example:
      >>> tracks = init(TrackerConfig(capacity=8))
    """
    K, D = config.capacity, config.num_modes
    zi = jnp.zeros(K, jnp.int32)
    modes = imm.IMMState(jnp.zeros((K, D, 4), dtype),
                         jnp.tile(jnp.eye(4, dtype=dtype), (K, D, 1, 1)),
                         jnp.full((K, D), -np.log(max(D, 1)), dtype))
    return Tracks(jnp.zeros((K, 4), dtype), jnp.tile(jnp.eye(4, dtype=dtype), (K, 1, 1)),
                  jnp.full(K, -1, jnp.int32), zi, zi, zi, zi, zi, jnp.zeros(K, dtype),
                  appearance.init(K, config.num_features, dtype), jnp.int32(0), jnp.int32(0),
                  modes, jnp.zeros((K, config.trail_length, 2), dtype))


def step(state: Tracks, detections: Detections, params: TrackerParams) -> Tracks:
    """Process one scan (see the module docstring for the algorithm).

    Args:
      state: `Tracks` with K slots.
      detections: `Detections` with M slots (NaN positions under a False mask are ignored).
      params: `TrackerParams` (its ``config`` is static).

    Returns:
      The new `Tracks`.

    Example:
      >>> params = TrackerParams.create(TrackerConfig(capacity=8))
      >>> tracks = step(init(params.config), make_detections([[1.0, 2.0]], 8), params)
    """
    _check(state, detections, params)
    return _step(state, detections, params)


def run(state: Tracks, detections: Detections, params: TrackerParams):
    """`step` over a sequence of scans (leaves of ``detections`` with a leading [T] axis).

    Returns:
      ``(final Tracks, per-scan Tracks)``; e.g. for `jaxtrack.metrics.clear_mot` use
      ``hyp_ids = where(status == CONFIRMED, id, -1)`` and ``hyp_pos = mean[..., :2]``.
    """
    if jnp.shape(detections.positions)[0] == 0:
        # Zero scans: a scan over nothing leaves the state unchanged and gives an empty
        # per-scan record (leaves with a leading axis of 0).
        frame0 = jax.tree_util.tree_map(lambda x: jnp.zeros(x.shape[1:], x.dtype), detections)
    else:
        frame0 = jax.tree_util.tree_map(lambda x: x[0], detections)
    _check(state, frame0, params)

    def body(s, det):
        s = _step(s, det, params)
        return s, s

    return lax.scan(body, state, detections)


def is_walking(tracks: Tracks, params: TrackerParams) -> Array:
    """[K] bools: speed above ``walking_speed`` (seed 003: 0.1 m/s), live tracks only."""
    speed = jnp.sqrt(jnp.sum(tracks.mean[:, 2:] ** 2, -1))
    return (speed > params.walking_speed) & (tracks.status != FREE)


def _step(state, det, params):
    # Stone Soup's MultiTargetTracker loop for one scan: predict and gate (hypothesise), then
    # associate and update, then confirm / delete / merge, then start tracks in free slots.
    predicted = predict(state, params)
    hypotheses = hypothesise(state, predicted, det, params)
    assoc = associate(hypotheses, params)
    tracks = manage(state, hypotheses, assoc, params)
    return births(tracks, hypotheses, assoc, params).tracks


# ---------------------------------------------------------------------------------------------
# Stages of one scan (what `step` chains; public for closed loops that run them one by one)


class Hypotheses(NamedTuple):
    r"""One scan gated against the predicted tracks: what association, management and births read.

    Attributes:
      predicted: Gaussian, mean [K, 4] and cov [K, 4, 4] (from `predict`).
      live: [K] bools, the slots that held a track before the scan (not `FREE`).
      zs: [M, 2] detection positions, 0 where ``mask`` is False.
      mask: [M] bools, detections present and finite.
      sensor: [M] int32 sensor index, clipped to the S sensors of ``params.log_r_std``.
      R: [S, 2, 2] noise covariance of each sensor, :math:`r_s^2 I`.
      innovations: `jaxtrack.association.Innovations`, ``d2`` / ``log_likelihood`` / ``valid``
        [K, M] with the noise of each detection's sensor.
      gated: [K, M] bools, :math:`d^2_{kj} \le \chi^2_2{}^{-1}(P_G)` for live tracks and present
        detections (and ``allowed`` pairs).
      appearance: [K, M] colour confidence of each track's classifier (0 without features).
      confidence: [M] detector confidence.
      features: [M, F] appearance features, in the tracks' dtype.
      modes: ``motion="imm"``: the mode-matched predictions (`predict_modes`), means
        [K, 2, 4], covs [K, 2, 4, 4], log_mode_probs [K, 2] (the mixed :math:`\log c_j`), of
        which ``predicted`` is the combined estimate; None for "cv".
      motion_d2: [K, M] the squared Mahalanobis distance of the GNN cost: that of
        ``innovations`` for ``motion_term="position"``, of position and velocity for
        "position_velocity".
      allowed: [K, M] bools, the pairs the association may use at all (``gated`` is within
        them): all but a tentative track's with a detection in a confirmed track's gate
        (``tentative_outside_confirmed``); None: all.
      velocity: ``motion_term="position_velocity"``: [K, M, 2] the velocity each detection
        implies for each track over its baseline (`_position_velocity_d2`), which the GNN
        update also measures; None otherwise.
    """

    predicted: Gaussian
    live: Array
    zs: Array
    mask: Array
    sensor: Array
    R: Array
    innovations: association.Innovations
    gated: Array
    appearance: Array
    confidence: Array
    features: Array
    modes: imm.IMMState | None = None
    motion_d2: Array | None = None
    allowed: Array | None = None
    velocity: Array | None = None


class Association(NamedTuple):
    """The result of associating one scan and updating the tracks.

    Attributes:
      posterior: Gaussian, mean [K, 4] and cov [K, 4, 4]: live tracks updated, the other slots
        as predicted.
      hit: [K] bools, live tracks that got a detection (JPDA: probability of detection > 1/2).
      col: [K] int, the detection each track took, -1 for none (JPDA: the detection of marginal
        > 1/2, if any).
      used: [M] bools, detections taken by a track (JPDA: total marginal over live tracks
        >= 1/2); they start no track.
      modes: ``motion="imm"``: the mode-matched posteriors and the updated log mode
        probabilities, [K, 2, ...] (``posterior`` is their combined estimate); None for "cv".
    """

    posterior: Gaussian
    hit: Array
    col: Array
    used: Array
    modes: imm.IMMState | None = None


class Births(NamedTuple):
    """The result of `births`.

    Attributes:
      tracks: the `Tracks` with the new tentative (or, when ``confirm_hits`` is 1, confirmed)
        tracks in free slots.
      born: [M] bools, detections that started a track.
      slot: [M] int, the slot of each new track (K where ``born`` is False).
    """

    tracks: Tracks
    born: Array
    slot: Array


def predict(state: Tracks, params: TrackerParams) -> Gaussian:
    r"""Predict every live track one scan ahead with the constant-velocity model.

    .. math:: m' = F m,\qquad P' = F P F^T + Q

    with :math:`F, Q` of `jaxtrack.models.motion.constant_velocity` (period ``dt``, spectral
    density ``exp(log_q)``); ``config.filter = "ukf"`` propagates sigma points instead
    (`jaxtrack.filters.ukf.predict`, the same moments for this linear model). The covariance is
    symmetrised.

    Args:
      state: `Tracks` with K slots.
      params: `TrackerParams`.

    Returns:
      Gaussian with mean [K, 4] and cov [K, 4, 4]; free slots keep their values.

    Example:
      >>> predicted = predict(tracks, params)
    """
    _check_stage(params, state=state)
    cfg = params.config
    live = state.status != FREE
    if cfg.motion == "imm":
        combined = jax.vmap(imm.estimate)(_predict_modes(state, params))
        return Gaussian(jnp.where(live[:, None], combined.mean, state.mean),
                        jnp.where(live[:, None, None], combined.cov, state.cov))
    F, Q = motion.constant_velocity(params.dt, jnp.exp(params.log_q))
    F, Q = F.astype(state.mean.dtype), Q.astype(state.mean.dtype)
    if cfg.filter == "kf":
        mean = state.mean @ F.T
        cov = F @ state.cov @ F.T + Q
    else:
        pred = jax.vmap(lambda m, P: ukf.predict(Gaussian(m, P), lambda x: F @ x, Q))(
            state.mean, state.cov)
        mean, cov = pred.mean, pred.cov
    cov = 0.5 * (cov + jnp.swapaxes(cov, -1, -2))
    return Gaussian(jnp.where(live[:, None], mean, state.mean),
                    jnp.where(live[:, None, None], cov, state.cov))


def predict_modes(state: Tracks, params: TrackerParams) -> imm.IMMState:
    r"""The IMM prediction of every live track (``config.motion = "imm"``): `jaxtrack.filters.imm`
    ``mix`` with the transition :math:`p_{ij}` = softmax of ``mode_logits``, then each mode's
    Kalman prediction.

    .. math::
        \text{walking: } F_w = \begin{bmatrix} I & \Delta t I \\ 0 & I \end{bmatrix},\;
        Q_w = q \begin{bmatrix} \Delta t^3/3\, I & \Delta t^2/2\, I \\
        \Delta t^2/2\, I & \Delta t\, I \end{bmatrix};\qquad
        \text{standing: } F_s = \begin{bmatrix} I & 0 \\ 0 & 0 \end{bmatrix},\;
        Q_s = q_s \begin{bmatrix} \Delta t\, I & 0 \\ 0 & I / \Delta t \end{bmatrix}

    (walking: `jaxtrack.models.motion.constant_velocity`, :math:`q` = ``exp(log_q)``, the "cv"
    model; standing: the velocity is zero up to the apparent velocity of a position random
    walk of density :math:`q_s` = ``exp(log_q_standing)``). A track of age 0 (just born, or
    placed by hand) first takes its modes from its ``mean`` / ``cov``, with mode probabilities
    :math:`(1 - \pi_0, \pi_0)`, :math:`\pi_0` = ``sigmoid(logit_init_standing)``.

    Args:
      state: `Tracks` with K slots and ``config.motion = "imm"``.
      params: `TrackerParams`.

    Returns:
      `jaxtrack.filters.imm.IMMState`, means [K, 2, 4], covs [K, 2, 4, 4], log_mode_probs
      [K, 2] (the mixed log probabilities :math:`\log c_j`); free slots keep their values.
      `predict` returns its combined estimate.

    Example:
      >>> modes = predict_modes(tracks, params)
      >>> jnp.exp(modes.log_mode_probs[:, STANDING])   # predicted standing probabilities
    """
    _check_stage(params, state=state)
    if params.config.motion != "imm":
        raise ValueError('predict_modes needs config.motion = "imm"')
    return _predict_modes(state, params)


def _predict_modes(state, params):
    dtype = state.mean.dtype
    live = state.status != FREE
    fresh = live & (state.age == 0)
    logit0 = params.logit_init_standing.astype(dtype)
    log_p0 = jnp.stack([jax.nn.log_sigmoid(-logit0), jax.nn.log_sigmoid(logit0)])
    start = imm.IMMState(
        jnp.where(fresh[:, None, None], state.mean[:, None], state.modes.means),
        jnp.where(fresh[:, None, None, None], state.cov[:, None], state.modes.covs),
        jnp.where(fresh[:, None], log_p0, state.modes.log_mode_probs))
    transition = imm.transition_from_logits(params.mode_logits.astype(dtype))
    pred = jax.vmap(lambda s: imm.predict(imm.mix(s, transition), _mode_models(params, dtype)))(
        start)
    return jax.tree_util.tree_map(
        lambda p, s: jnp.where(live.reshape((-1,) + (1,) * (p.ndim - 1)), p, s), pred,
        state.modes)


def _mode_models(params, dtype):
    """`imm.LinearModels` of the walking and standing modes (`predict_modes`)."""
    # the walking mode built exactly as `predict` builds the "cv" model
    F_w, Q_w = motion.constant_velocity(params.dt, jnp.exp(params.log_q))
    dt = jnp.asarray(params.dt, dtype)
    q_s = jnp.exp(params.log_q_standing).astype(dtype)
    F_s = jnp.diag(jnp.array([1.0, 1.0, 0.0, 0.0], dtype))
    Q_s = q_s * jnp.diag(jnp.stack([dt, dt, 1 / dt, 1 / dt]))
    H = jnp.broadcast_to(_position(dtype), (2, 2, 4))
    R = jnp.broadcast_to(jnp.eye(2, dtype=dtype), (2, 2, 2))
    return imm.LinearModels(jnp.stack([F_w.astype(dtype), F_s]),
                            jnp.stack([Q_w.astype(dtype), Q_s]), H, R)


def hypothesise(state: Tracks, predicted: Gaussian, detections: Detections,
                params: TrackerParams) -> Hypotheses:
    r"""Gate a scan of detections against the predicted tracks (Stone Soup's hypothesiser).

    Detections under a False mask or with a non-finite position are dropped. For every pair of a
    live track k and a present detection j from sensor s,

    .. math:: S_{kj} = H P_k H^T + r_s^2 I,\quad d^2_{kj} = y_{kj}^T S_{kj}^{-1} y_{kj},\quad
        \text{gated} \iff d^2_{kj} \le \chi^2_2{}^{-1}(P_G)

    (`jaxtrack.association.innovations` and `gate`, :math:`P_G` = ``gate_prob``), plus the
    colour confidence of the track's online classifier when ``config.num_features > 0``.
    With ``config.motion = "imm"`` the gates are those of the combined prediction (the
    IMM-JPDA / IMM-GNN approximation), and the hypotheses also carry the mode-matched
    predictions (`predict_modes`), which the association updates.

    Args:
      state: `Tracks` with K slots, before the scan (its status says which slots are live).
      predicted: Gaussian [K, 4] / [K, 4, 4] from `predict`.
      detections: `Detections` with M slots.
      params: `TrackerParams`.

    Returns:
      `Hypotheses` ([K, M] innovations, gates and appearance confidences, and the cleaned scan).

    Example:
      >>> hyp = hypothesise(tracks, predict(tracks, params), detections, params)
      >>> hyp.gated.shape    # (K, M)
    """
    _check(state, detections, params)
    _check_stage(params, predicted=predicted)
    cfg = params.config
    dtype = state.mean.dtype
    K, M = cfg.capacity, detections.positions.shape[0]
    live = state.status != FREE
    mask = detections.mask & jnp.all(jnp.isfinite(detections.positions), -1)
    zs = jnp.where(mask[:, None], detections.positions, 0.0).astype(dtype)
    R = _noise(params, dtype)
    sensor = jnp.clip(detections.sensor, 0, R.shape[0] - 1)
    inn = association.innovations(predicted.mean, predicted.cov, zs, _position(dtype), R,
                                  sensor=sensor, track_mask=live, meas_mask=mask)
    velocity = None
    if cfg.motion_term == "position_velocity":
        past, span = _baseline(state, cfg)
        dt = jnp.maximum(jnp.asarray(params.dt, dtype), 1e-6)
        velocity = (zs[None, :, :] - past[:, None, :]) / (span.astype(dtype) * dt)[:, None, None]
        d2 = _position_velocity_d2(predicted, zs, velocity, R[sensor], cfg.velocity_noise_ratio)
        d2 = jnp.where(live[:, None] & mask[None, :], d2, jnp.inf)
        gated = association.gate(d2, 4, params.gate_prob, live, mask)
    else:
        d2 = inn.d2
        gated = association.gate(d2, 2, params.gate_prob, live, mask)
    allowed = None
    tentative = (state.status == TENTATIVE)[:, None]
    if cfg.tentative_outside_confirmed:
        claimed = jnp.any(gated & (state.status == CONFIRMED)[:, None], 0)      # [M]
        allowed = ~(tentative & claimed[None, :])                              # [K, M]
    if cfg.tentative_from_births:
        unborn = detections.confidence < params.birth_confidence                # [M]
        unborn_ok = ~(tentative & unborn[None, :])
        allowed = unborn_ok if allowed is None else allowed & unborn_ok
    if allowed is not None:
        gated = gated & allowed
    features = detections.features.astype(dtype)
    if cfg.num_features:
        has = _has_features(features)
        conf_app = jnp.where(has[None, :], appearance.confidence(
            state.appearance, jnp.where(has[:, None], features, 0.0)), 0.5)
    else:
        conf_app = jnp.zeros((K, M), dtype)
    modes = _predict_modes(state, params) if cfg.motion == "imm" else None
    return Hypotheses(predicted, live, zs, mask, sensor, R, inn, gated, conf_app,
                      detections.confidence, features, modes, d2, allowed, velocity)


def _baseline(state, cfg):
    r"""Each track's position at the start of its velocity baseline, [K, 2], and the
    baseline's length L_k in scans, [K] int32.

    open_ptrack's rule (``Track::getMahalanobisDistance``), in scans: the baseline starts
    ``velocity_window`` scans ago, but no earlier than the track's first scan (``age + 1``
    scans ago) and no later than its last detection (``misses + 1`` ago), and never more
    than 2 ``velocity_window`` scans ago. The position there is the track's estimate after
    that scan: filtered when it was detected, predicted when it was not."""
    window = cfg.velocity_window
    span = jnp.maximum(jnp.minimum(window, state.age + 1), state.misses + 1)
    span = jnp.clip(span, 1, 2 * window)
    earlier = jnp.concatenate([state.mean[:, None, :2], state.trail], 1)    # [K, 2 L, 2]
    past = jnp.take_along_axis(earlier, (span - 1)[:, None, None], 1)[:, 0]
    return past, span


def _position_velocity_d2(predicted, zs, velocity, R, ratio):
    r"""[K, M] seed 001's motion distance: the squared Mahalanobis distance of
    :math:`y = (z - \hat p,\ v_{kj} - \hat v)` under :math:`S = \hat P + \mathrm{diag}(R,
    \rho R)`, with :math:`v_{kj} = (z_j - p_{k, t-L_k}) / (L_k \Delta t)` (``velocity``
    [K, M, 2], from `_baseline`) and :math:`\rho` = ``velocity_noise_ratio``.

    This is open_ptrack's (seed 001's implementation): the velocity is measured over about
    1 s, from the track's estimate then, and the innovation covariance is that of a
    measurement of all four states with noise :math:`\mathrm{diag}(R, \rho R)`,
    :math:`\rho = 16` in open_ptrack. Measured over
    one scan instead (:math:`L = 1`), the term would add nothing: with a constant-velocity
    prediction :math:`\hat p = p_{t-1} + \hat v \Delta t`, the velocity's innovation is the
    position's over :math:`\Delta t`. Over L scans it compares the detection with where the
    track was a second ago, which one noisy estimate of the velocity does not contain."""
    y_pos = zs[None, :, :] - predicted.mean[:, None, :2]                     # [K, M, 2]
    y = jnp.concatenate([y_pos, velocity - predicted.mean[:, None, 2:]], -1)  # [K, M, 4]
    S = predicted.cov[:, None] + _position_velocity_noise(R, ratio)[None]   # [K, M, 4, 4]
    S = 0.5 * (S + jnp.swapaxes(S, -1, -2))
    chol = jnp.linalg.cholesky(S)
    w = jax.scipy.linalg.solve_triangular(chol, y[..., None], lower=True)[..., 0]
    d2 = jnp.sum(w ** 2, -1)
    return jnp.where(jnp.isfinite(d2), d2, jnp.inf)


def _position_velocity_noise(R, ratio):
    r"""[..., 4, 4] :math:`\mathrm{diag}(R, \rho R)` of [..., 2, 2] position noises R."""
    zero = jnp.zeros_like(R)
    return jnp.concatenate([jnp.concatenate([R, zero], -1),
                            jnp.concatenate([zero, ratio * R], -1)], -2)


def associate(hypotheses: Hypotheses, params: TrackerParams) -> Association:
    """Associate and update with the method of ``params.config.association``: `associate_gnn`,
    `associate_jpda` or `associate_nn_jpda`.

    Example:
      >>> assoc = associate(hypothesise(tracks, predict(tracks, params), dets, params), params)
    """
    _check_stage(params)
    return _ASSOCIATORS[params.config.association](hypotheses, params)


def associate_gnn(hypotheses: Hypotheses, params: TrackerParams) -> Association:
    r"""GNN (seed 001): the optimal assignment inside the gates, then a Kalman update per track.

    The cost of pairing track k with detection j is seed 001's eq. 2,
    :math:`C_{kj} = \gamma d^2_{kj} - \alpha c^{app}_{kj} - \beta c^{det}_j`, or with
    :math:`\gamma d_{kj}` when ``config.distance="mahalanobis"`` (:math:`d^2` of position and
    velocity when ``config.motion_term="position_velocity"``) (``gamma``,
    ``alpha``, ``beta`` of the params), minimised over the assignments that use gated pairs only
    (`jaxtrack.association.gnn`); each assigned track gets a Joseph-form Kalman update with its
    detection and that detection's sensor noise (`jaxtrack.association.nn_update`).

    Args:
      hypotheses: `Hypotheses` of the scan (K tracks, M detections).
      params: `TrackerParams`.

    Returns:
      `Association`: posterior [K, 4] / [K, 4, 4], hit [K], col [K] int32, used [M].

    Example:
      >>> assoc = associate_gnn(hypothesise(tracks, predict(tracks, params), dets, params),
      ...                       params)
    """
    _check_stage(params, hypotheses=hypotheses)
    h = hypotheses
    dtype = h.zs.dtype
    d2 = h.innovations.d2 if h.motion_d2 is None else h.motion_d2
    motion_cost = (jnp.sqrt(jnp.maximum(d2, 0.0)) if params.config.distance == "mahalanobis"
                   else d2)
    cost = (params.gamma * motion_cost - params.alpha * h.appearance
            - params.beta * h.confidence.astype(dtype)[None, :])
    col = association.gnn(jnp.where(h.gated, cost, jnp.inf), h.gated, track_mask=h.live,
                          meas_mask=h.mask)
    return _hard_update(h, col, params)


def associate_jpda(hypotheses: Hypotheses, params: TrackerParams) -> Association:
    r"""JPDA (seed 003): marginal association probabilities, then the combined-innovation update.

    :math:`\beta` [K, M + 1] are the JPDA marginals of the gated likelihoods with detection
    probability :math:`P_D = \sigma(` ``logit_p_detect`` :math:`)` and Poisson clutter of density
    ``exp(log_clutter_density)`` (`jaxtrack.association.jpda_marginals`, ``config.jpda_method``);
    every live track gets the PDA update with its row (`jaxtrack.association.jpda_update`). A
    track is hit when :math:`\beta_{k\varnothing} < 1/2`; it took detection j when
    :math:`\beta_{kj} > 1/2`; a detection is used when :math:`\sum_k \beta_{kj} \ge 1/2`.

    With ``config.motion = "imm"`` the marginals are those of the combined prediction and every
    mode i gets the PDA update with the same row; the mode probabilities are updated by the
    beta-weighted mixture likelihood of each mode,

    .. math:: \mu_i^+ \propto c_i \Big(\beta_{k\varnothing}\lambda
        + \sum_j \beta_{kj} N(z_j; H m_{k,i}, H P_{k,i} H^T + R_{s(j)})\Big)

    (:math:`c_i` the mixed mode probabilities, :math:`m_{k,i}, P_{k,i}` mode i's prediction,
    :math:`\lambda` the clutter density: no detection weighs as much as clutter, so without a
    detection the modes keep :math:`c`), and the posterior is the combined estimate of the modes.

    Args:
      hypotheses: `Hypotheses` of the scan (K tracks, M detections).
      params: `TrackerParams`.

    Returns:
      `Association`: posterior [K, 4] / [K, 4, 4], hit [K], col [K] int, used [M].

    Example:
      >>> assoc = associate_jpda(hypothesise(tracks, predict(tracks, params), dets, params),
      ...                        params)
    """
    _check_stage(params, hypotheses=hypotheses)
    h = hypotheses
    M = h.zs.shape[0]
    if params.config.sensor_update == "sequential":
        return _sequential_update(h, params, hard=False)
    beta = _marginals(h, params)
    if h.modes is None:
        posts = association.jpda_update(h.predicted, h.zs, beta, _position(h.zs.dtype), h.R,
                                        sensor=h.sensor, meas_mask=h.mask, track_mask=h.live)
        modes = None
    else:
        posts, modes = _imm_jpda_update(h, beta, params)
    hit = h.live & (beta[:, M] < 0.5)
    if M == 0:  # an empty scan: nothing to take
        col = jnp.full(hit.shape, -1, jnp.int32)
    else:
        best = jnp.argmax(beta[:, :M], -1)
        col = jnp.where(hit & (jnp.max(beta[:, :M], -1) > 0.5), best, -1)
    used = jnp.sum(jnp.where(h.live[:, None], beta[:, :M], 0.0), 0) >= 0.5
    return Association(posts, hit, col, used, modes)


def associate_nn_jpda(hypotheses: Hypotheses, params: TrackerParams) -> Association:
    r"""NN-JPDA (seed 003, eq. 9): the MAP detection of each track from the JPDA marginals, then a
    Kalman update with it.

    The marginals are those of `associate_jpda`; the choice is
    :math:`\hat j_k = \arg\max_j \beta_{kj}` with conflicts resolved greedily
    (`jaxtrack.association.nn_jpda`), and the update is `jaxtrack.association.nn_update`.

    Args:
      hypotheses: `Hypotheses` of the scan (K tracks, M detections).
      params: `TrackerParams`.

    Returns:
      `Association`: posterior [K, 4] / [K, 4, 4], hit [K], col [K] int32, used [M].

    Example:
      >>> assoc = associate_nn_jpda(hypothesise(tracks, predict(tracks, params), dets, params),
      ...                           params)
    """
    _check_stage(params, hypotheses=hypotheses)
    h = hypotheses
    if params.config.sensor_update == "sequential":
        return _sequential_update(h, params, hard=True)
    col = jnp.where(h.live, association.nn_jpda(_marginals(h, params)), -1)
    return _hard_update(h, col, params)


def _sequential_update(h, params, hard):
    r"""``sensor_update="sequential"``: `jaxtrack.association.sequential_jpda_update` over the
    scan's sensors. A track is hit when any sensor's pass gave it a detection
    (:math:`\beta^s_{k\varnothing} < 1/2`, or an NN-JPDA choice); ``col`` is the first such
    pass's detection; a detection is used when its own sensor's marginals sum to >= 1/2 over the
    live tracks (each detection has weight only in its sensor's pass; NN-JPDA: a track chose
    it)."""
    M = h.zs.shape[0]
    out = association.sequential_jpda_update(
        h.predicted, h.zs, _position(h.zs.dtype), h.R, h.sensor,
        p_detect=jax.nn.sigmoid(params.logit_p_detect),
        clutter_density=jnp.exp(params.log_clutter_density), gate_prob=params.gate_prob,
        meas_mask=h.mask, track_mask=h.live, hard=hard, method=params.config.jpda_method,
        pair_mask=h.allowed)
    beta = out.beta                                            # [S, K, M + 1]
    live = h.live
    if hard:
        chosen = out.col_for_row                               # [S, K]
        hit_s = chosen >= 0
    else:
        hit_s = beta[:, :, M] < 0.5
        best = jnp.argmax(beta[:, :, :M], -1) if M else jnp.full(hit_s.shape, -1)
        strong = (jnp.max(beta[:, :, :M], -1) > 0.5) if M else jnp.zeros(hit_s.shape, bool)
        chosen = jnp.where(hit_s & strong, best, -1)
    hit = live & jnp.any(hit_s, 0)
    first = jnp.argmax(chosen >= 0, 0)                         # first sensor with a choice
    col = jnp.where(live, jnp.take_along_axis(chosen, first[None], 0)[0], -1).astype(jnp.int32)
    mass = jnp.sum(jnp.where(live[None, :, None], beta[:, :, :M], 0.0), (0, 1))
    taken = jnp.zeros(M, bool).at[jnp.where(live[None] & (chosen >= 0), chosen, M)].set(
        True, mode="drop")
    used = taken if hard else (mass >= 0.5) | taken
    posterior = Gaussian(jnp.where(live[:, None], out.posterior.mean, h.predicted.mean),
                         jnp.where(live[:, None, None], out.posterior.cov, h.predicted.cov))
    return Association(posterior, hit, col, used)


def manage(state: Tracks, hypotheses: Hypotheses, assoc: Association,
           params: TrackerParams, excused: Array | None = None) -> Tracks:
    r"""Track management after the update: hit history, confirmation, deletion, merging,
    appearance and heading.

    For each live track: the hit history (bit 0 = this scan, ``confirm_window`` bits), hits,
    consecutive misses and age are counted; a tentative track with at least ``confirm_hits`` hits
    in the window is confirmed; a track is deleted (its slot freed: id -1, counters 0) after
    ``max_tentative_misses`` (tentative) or ``max_misses`` (confirmed) consecutive misses, when
    its position std :math:`\sqrt{\max(P_{xx}, P_{yy})}` exceeds ``max_position_std``, when its
    mean is not finite, or (``merge_distance > 0``) when a stronger live track is within
    ``merge_distance``. The colour classifier of every surviving track takes one step on the
    scan (`jaxtrack.tracking.appearance.update`); the heading follows the velocity while the
    speed exceeds ``walking_speed`` (or seed 002's AR filter, ``config.heading = "ar"``).

    Args:
      state: `Tracks` with K slots, before the scan.
      hypotheses: `Hypotheses` of the scan.
      assoc: `Association` of the scan (its posterior becomes the tracks' mean and cov).
      params: `TrackerParams`.
      excused: optional [K] bools, tracks whose miss this scan is not counted (e.g. occluded:
        `jaxtrack.perception.leg_tracker`); they coast, and the position-std limit still
        deletes them.

    Returns:
      The updated `Tracks` (``next_id`` and ``num_dropped`` unchanged; no births yet; with
      ``motion="imm"`` the modes of ``assoc``).

    Example:
      >>> tracks = manage(state, hyp, associate(hyp, params), params)
    """
    _check_stage(params, state=state, hypotheses=hypotheses, assoc=assoc)
    cfg = params.config
    live, hit = hypotheses.live, assoc.hit
    mean, cov = assoc.posterior
    window = (1 << cfg.confirm_window) - 1
    history = jnp.where(live, ((state.history << 1) | hit.astype(jnp.int32)) & window, 0)
    hits = state.hits + (live & hit)
    counted = live if excused is None else live & ~jnp.asarray(excused, bool)
    misses = jnp.where(hit, 0, state.misses + counted)
    age = state.age + live
    recent = _popcount(history, cfg.confirm_window)
    status = jnp.where(live & (state.status == TENTATIVE) & (recent >= cfg.confirm_hits),
                       CONFIRMED, state.status)
    pos_var = jnp.maximum(cov[:, 0, 0], cov[:, 1, 1])
    dead = live & (
        ((status == TENTATIVE) & (misses >= cfg.max_tentative_misses))
        | ((status == CONFIRMED) & (misses >= cfg.max_misses))
        | (pos_var > cfg.max_position_std**2)
        | ~jnp.all(jnp.isfinite(mean), -1))
    status = jnp.where(dead, FREE, status)
    if cfg.merge_distance > 0:
        status = jnp.where(_merged(mean, status, hits, state.id, cfg.merge_distance), FREE,
                           status)

    app = state.appearance
    if cfg.num_features:
        # Detections without features (NaN rows) neither teach a track nor serve as negatives.
        has = _has_features(hypotheses.features)
        has_col = jnp.concatenate([has, jnp.zeros(1, bool)])[
            jnp.where(assoc.col >= 0, assoc.col, has.shape[0])]
        col = jnp.where(has_col, assoc.col, -1)
        app = appearance.update(app, jnp.where(has[:, None], hypotheses.features, 0.0), col,
                                hypotheses.mask & has, live & ~dead, params.appearance_lr)

    if cfg.heading == "ar":
        head = jax.vmap(heading_filter.ar_heading_step)(state.heading, mean[:, 2:])
    else:
        speed = jnp.sqrt(jnp.sum(mean[:, 2:] ** 2, -1))
        head = jnp.where(speed > params.walking_speed, jnp.arctan2(mean[:, 3], mean[:, 2]),
                         state.heading)

    modes = state.modes
    if cfg.motion == "imm":
        if assoc.modes is None:
            raise ValueError('with config.motion = "imm" the association must carry the '
                             "mode posteriors (assoc.modes), as the associate_* stages give")
        modes = assoc.modes

    # The trail moves on by one scan: the position before this scan becomes its newest.
    trail = jnp.concatenate([state.mean[:, None, :2], state.trail[:, :-1]], 1)[
        :, :cfg.trail_length]

    free = status == FREE
    return Tracks(mean, cov, jnp.where(free, -1, state.id), jnp.where(free, 0, age),
                  jnp.where(free, 0, hits), jnp.where(free, 0, misses),
                  jnp.where(free, 0, history), status, head, app, state.next_id,
                  state.num_dropped, modes, trail)


def births(tracks: Tracks, hypotheses: Hypotheses, assoc: Association,
           params: TrackerParams) -> Births:
    r"""Start tracks from the unexplained detections of a scan, in free slots.

    A present detection starts a track when no track used it, it lies outside every live gate
    (it would be explained by that track, even unassigned, and a duplicate would compete with
    it; unless ``births_in_gates``) and its detector confidence is at least
    ``birth_confidence`` (seed 001); with ``merge_distance > 0`` one closer than that to an
    earlier eligible detection (lower index) starts none. The i-th eligible detection
    (i = 0, 1, ...) takes the i-th free slot, if there is one (else it is counted in
    ``num_dropped``), with id ``next_id + i``: ids are unique and increasing. A new track has
    mean :math:`[z, 0, 0]`, covariance :math:`\mathrm{diag}(R_s, \sigma_v^2 I)`
    (:math:`\sigma_v` = ``exp(log_init_speed_std)``), one hit, and status `TENTATIVE`
    (`CONFIRMED` when ``confirm_hits`` is 1); with ``motion="imm"`` both modes start from that
    Gaussian, with standing probability ``sigmoid(logit_init_standing)``.

    Args:
      tracks: `Tracks` after `manage`.
      hypotheses: `Hypotheses` of the scan (M detections).
      assoc: `Association` of the scan.
      params: `TrackerParams`.

    Returns:
      `Births`: the tracks with the new ones, born [M] and slot [M].

    Example:
      >>> new = births(manage(state, hyp, assoc, params), hyp, assoc, params)
      >>> new.tracks.id[new.slot[new.born]]    # next_id, next_id + 1, ...
    """
    _check_stage(params, tracks=tracks, hypotheses=hypotheses, assoc=assoc)
    cfg = params.config
    h = hypotheses
    dtype = h.zs.dtype
    K, M = cfg.capacity, h.zs.shape[0]
    free = tracks.status == FREE
    in_gate = jnp.any(h.gated & h.live[:, None], 0) & (not cfg.births_in_gates)
    eligible = h.mask & ~assoc.used & ~in_gate & (h.confidence >= params.birth_confidence)
    if cfg.merge_distance > 0:
        d2 = jnp.sum((h.zs[:, None] - h.zs[None]) ** 2, -1)
        earlier = jnp.tril(jnp.ones((M, M), bool), -1)  # [j, i]: i < j
        eligible = eligible & ~jnp.any(earlier & eligible[None, :]
                                       & (d2 < cfg.merge_distance**2), 1)
    rank = jnp.cumsum(eligible) - 1
    num_free = jnp.sum(free)
    free_slots = jnp.argsort(~free, stable=True)  # free slot indices first, in order
    born = eligible & (rank < num_free)
    slot = jnp.where(born, free_slots[jnp.clip(rank, 0, K - 1)], K)
    new_ids = tracks.next_id + rank
    r_det = h.R[h.sensor]
    v0 = jnp.exp(params.log_init_speed_std).astype(dtype) ** 2
    cov0 = jnp.zeros((M, 4, 4), dtype).at[:, :2, :2].set(r_det)
    cov0 = cov0.at[:, 2, 2].set(v0).at[:, 3, 3].set(v0)
    mean0 = jnp.concatenate([h.zs, jnp.zeros((M, 2), dtype)], -1)

    def put(arr, values):
        return arr.at[slot].set(values, mode="drop")

    first = jnp.where(cfg.confirm_hits <= 1, CONFIRMED, TENTATIVE)
    num_born = jnp.sum(born).astype(jnp.int32)
    app = tracks.appearance
    D = cfg.num_modes
    logit0 = params.logit_init_standing.astype(dtype)
    log_p0 = jnp.stack([jax.nn.log_sigmoid(-logit0), jax.nn.log_sigmoid(logit0)])[:D]
    modes = imm.IMMState(put(tracks.modes.means, jnp.repeat(mean0[:, None], D, 1)),
                         put(tracks.modes.covs, jnp.repeat(cov0[:, None], D, 1)),
                         put(tracks.modes.log_mode_probs, jnp.broadcast_to(log_p0, (M, D))))
    new = Tracks(
        put(tracks.mean, mean0), put(tracks.cov, cov0),
        put(tracks.id, new_ids.astype(jnp.int32)), put(tracks.age, jnp.zeros(M, jnp.int32)),
        put(tracks.hits, jnp.ones(M, jnp.int32)), put(tracks.misses, jnp.zeros(M, jnp.int32)),
        put(tracks.history, jnp.ones(M, jnp.int32)),
        put(tracks.status, jnp.full(M, first, jnp.int32)),
        put(tracks.heading, jnp.zeros(M, dtype)),
        appearance.Appearance(put(app.weights, jnp.zeros((M, cfg.num_features), dtype)),
                              put(app.bias, jnp.zeros(M, dtype))),
        tracks.next_id + num_born,
        tracks.num_dropped + jnp.sum(eligible & ~born).astype(jnp.int32), modes,
        put(tracks.trail, jnp.broadcast_to(h.zs[:, None], (M, cfg.trail_length, 2))))
    return Births(new, born, slot)


# ---------------------------------------------------------------------------------------------


def _has_features(features):
    """[M] rows of finite appearance features (NaN rows: a detection without appearance)."""
    return jnp.all(jnp.isfinite(features), -1)


def _noise(params, dtype):
    r = jnp.exp(params.log_r_std).astype(dtype)
    return (r**2)[:, None, None] * jnp.eye(2, dtype=dtype)


def _position(dtype):
    return measurement.position(4, dtype=dtype)


def _marginals(h, params):
    """JPDA marginals [K, M + 1] of the gated pairs (`associate_jpda`)."""
    loglik = jnp.where(h.gated, h.innovations.log_likelihood, -jnp.inf)
    p_d = jax.nn.sigmoid(params.logit_p_detect)
    return association.jpda_marginals(loglik, p_d, jnp.exp(params.log_clutter_density), h.live,
                                      h.mask, params.config.jpda_method, log=True)


def _hard_update(h, col, params):
    r"""`Association` of one detection per track (col [K], -1 none): a Kalman update each (of
    each mode with ``motion="imm"``, whose probabilities then follow each mode's likelihood of
    the detection, :math:`\mu_i^+ \propto c_i N(z; H m_i, S_i)`; unchanged without one).

    With ``motion_term="position_velocity"`` the update measures position and velocity,
    :math:`(z_j, v_{kj})` with :math:`H = I_4` and noise :math:`\mathrm{diag}(R, \rho R)`, as
    open_ptrack's filter does (``KalmanFilter::update(x, y, vx, vy)``)."""
    M = h.zs.shape[0]
    hit = col >= 0
    used = jnp.zeros(M, bool).at[jnp.where(hit, col, M)].set(True, mode="drop")
    if h.velocity is None or M == 0:
        zs, H, R, sensor, rows = h.zs, _position(h.zs.dtype), h.R, h.sensor, col
    else:
        # Each track measures its own velocity of the detection: one measurement row per track.
        K = col.shape[0]
        j = jnp.clip(col, 0, M - 1)
        v = jnp.take_along_axis(h.velocity, j[:, None, None], 1)[:, 0]           # [K, 2]
        zs = jnp.concatenate([h.zs[j], v], -1)                                   # [K, 4]
        H = jnp.eye(4, dtype=h.zs.dtype)
        R = _position_velocity_noise(h.R[h.sensor[j]], params.config.velocity_noise_ratio)
        sensor, rows = jnp.arange(K), jnp.where(hit, jnp.arange(K), -1)
    if h.modes is None:
        posts, _ = association.nn_update(h.predicted, zs, rows, H, R, sensor=sensor,
                                         track_mask=h.live)
        return Association(posts, hit, col, used)
    updates = [association.nn_update(g, zs, rows, H, R, sensor=sensor, track_mask=h.live)
               for g in _mode_gaussians(h.modes)]
    log_lik = jnp.stack([ll for _, ll in updates], -1)  # [K, D], 0 without a detection
    posts, modes = _imm_posterior(h, [g for g, _ in updates], log_lik)
    return Association(posts, hit, col, used, modes)


def _mode_gaussians(modes):
    """The D mode-matched Gaussians [K, 4] of an [K, D, ...] `imm.IMMState`."""
    return [Gaussian(modes.means[:, i], modes.covs[:, i]) for i in range(modes.means.shape[1])]


def _imm_jpda_update(h, beta, params):
    """Every mode's PDA update with the marginals ``beta`` [K, M + 1], and the mode
    probabilities by the beta-weighted mixture likelihood (`associate_jpda`)."""
    dtype = h.zs.dtype
    H = _position(dtype)
    M = h.zs.shape[0]
    log_clutter = params.log_clutter_density.astype(dtype)
    posts, log_lik = [], []
    for g in _mode_gaussians(h.modes):
        posts.append(association.jpda_update(g, h.zs, beta, H, h.R, sensor=h.sensor,
                                             meas_mask=h.mask, track_mask=h.live))
        inn = association.innovations(g.mean, g.cov, h.zs, H, h.R, sensor=h.sensor,
                                      track_mask=h.live, meas_mask=h.mask)
        ok = inn.valid & (beta[:, :M] > 0)
        terms = jnp.concatenate([jnp.where(ok, inn.log_likelihood, -jnp.inf),
                                 jnp.broadcast_to(log_clutter, (beta.shape[0], 1))], -1)
        # a slot that is not live weighs only the clutter term (finite, no NaN gradient)
        miss = jnp.where(h.live, beta[:, M], 1.0)[:, None]
        weights = jnp.concatenate([jnp.where(ok, beta[:, :M], 0.0), miss], -1)
        log_lik.append(jax.nn.logsumexp(terms, axis=-1, b=weights))
    return _imm_posterior(h, posts, jnp.stack(log_lik, -1))


def _imm_posterior(h, posts, log_lik):
    r"""Mode probabilities :math:`\mu_i^+ \propto c_i L_i` from log_lik [K, D], the mode
    posteriors ``posts`` (D Gaussians [K, 4]) and their combined estimate; slots that are not
    live keep their predictions."""
    joint = h.modes.log_mode_probs + jnp.where(h.live[:, None], log_lik, 0.0)
    log_mu = joint - jax.nn.logsumexp(joint, axis=-1, keepdims=True)
    log_mu = jnp.where(h.live[:, None], log_mu, h.modes.log_mode_probs)
    modes = imm.IMMState(jnp.stack([p.mean for p in posts], 1),
                         jnp.stack([p.cov for p in posts], 1), log_mu)
    combined = jax.vmap(imm.estimate)(modes)
    live = h.live
    posterior = Gaussian(jnp.where(live[:, None], combined.mean, h.predicted.mean),
                         jnp.where(live[:, None, None], combined.cov, h.predicted.cov))
    return posterior, modes


_ASSOCIATORS = {"gnn": associate_gnn, "jpda": associate_jpda, "nn_jpda": associate_nn_jpda}


def _merged(mean, status, hits, ids, distance):
    """[K] bool: live tracks within ``distance`` of a stronger live track (confirmed before
    tentative, then more hits, then the older id)."""
    live = status != FREE
    d2 = jnp.sum((mean[:, None, :2] - mean[None, :, :2]) ** 2, -1)
    key = (status, hits, -ids)

    def stronger(a, b):  # a[:, None] beats b[None, :]
        s_a, h_a, i_a = (x[:, None] for x in a)
        s_b, h_b, i_b = (x[None, :] for x in b)
        return (s_a > s_b) | ((s_a == s_b) & ((h_a > h_b) | ((h_a == h_b) & (i_a > i_b))))

    beats = stronger(key, key) & live[:, None] & live[None, :] & (d2 < distance**2)
    return live & jnp.any(beats, 0)


def _popcount(x, bits):
    return sum((x >> i) & 1 for i in range(bits))


def _check_stage(params, **args):
    """TypeError unless ``params`` and each named stage argument have their types; the shape of
    the tracks against ``params.config.capacity``."""
    if not isinstance(params, TrackerParams):
        raise TypeError(f"params must be TrackerParams; got {type(params).__name__}")
    types = {"state": Tracks, "tracks": Tracks, "predicted": Gaussian, "hypotheses": Hypotheses,
             "assoc": Association}
    for name, value in args.items():
        if not isinstance(value, types[name]):
            raise TypeError(f"{name} must be a tracker.{types[name].__name__}; got "
                            f"{type(value).__name__}")
        if types[name] is Tracks:
            _check_tracks_shape(name, value, params.config)


def _check_tracks_shape(name, tracks, cfg):
    _checks.check_shape(f"{name}.mean", tracks.mean, (cfg.capacity, 4),
                        "the tracker capacity of params.config")
    _checks.check_shape(f"{name}.modes.means", tracks.modes.means,
                        (cfg.capacity, cfg.num_modes, 4),
                        f'the motion of params.config ("{cfg.motion}"; build with init(config))')
    _checks.check_shape(f"{name}.trail", tracks.trail, (cfg.capacity, cfg.trail_length, 2),
                        "the motion_term and velocity_window of params.config (build with "
                        "init(config))")


def _check(state, det, params):
    if not isinstance(params, TrackerParams):
        raise TypeError(f"params must be TrackerParams; got {type(params).__name__}")
    if not isinstance(det, Detections):
        raise TypeError("detections must be tracking.Detections (see make_detections)")
    if not isinstance(state, Tracks):
        raise TypeError("state must be tracking.Tracks (see init)")
    cfg = params.config
    _check_tracks_shape("state", state, cfg)
    _checks.check_shape("detections.positions", det.positions, (None, 2))
    M = jnp.shape(det.positions)[0]
    for name, x, shape in (("mask", det.mask, (M,)), ("sensor", det.sensor, (M,)),
                           ("confidence", det.confidence, (M,)),
                           ("features", det.features, (M, cfg.num_features))):
        _checks.check_shape(f"detections.{name}", x, shape)
    if _checks.is_concrete(det.sensor) and M:
        s = np.asarray(det.sensor)
        S = jnp.shape(params.log_r_std)[0]
        if int(s.min()) < 0 or int(s.max()) >= S:
            raise ValueError(f"detections.sensor must index the {S} sensors of params.log_r_std")
