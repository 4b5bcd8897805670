r"""Leg tracking over laser scans, and people from the leg tracks (seed 004, section III-a,
after Arras et al., ICRA 2008).

Seed 004 tracks *legs*, not people: a leg track is :math:`p_L = (p_x, p_y, v_x, v_y)`, predicted
with a constant-velocity Kalman filter and updated with the leg detections of each scan; a track
is new, detected, or deleted when no detection is assigned to it. People are then built from
the leg tracks by four heuristics: people have two legs; the legs are close to each other; they
move in a similar direction; they occlude each other more often than other people's legs or
objects occlude them, so a track is not deleted when a leg is occluded for a short time. One
`step` per scan, at fixed capacities with masks (jittable, vmappable):

1. **Leg tracks**: `jaxtrack.tracking.tracker` with a Kalman filter on the leg candidates of
   `jaxtrack.perception.legs` (odometry frame): predict, gate, GNN assignment, update, M-of-N
   confirmation, births (also inside other legs' gates: a person's legs are 0.1-0.4 m
   apart). Arras et al. keep several association hypotheses; GNN is the single
   best one.
2. **Occlusion** (heuristic 4): a leg track with no detection this scan, behind a laser return
   -- a return within ``occlusion_radius`` of the line of sight to it, nearer to the laser by
   more than ``occlusion_margin`` -- is *occluded*, not missed: its miss is excused
   (`tracker.manage`'s ``excused``) and it coasts on its velocity, until its position std
   passes ``max_position_std``. Most often the occluder is the person's other leg. (Arras et
   al. learn adaptive occlusion probabilities; here occlusion is a geometric yes or no.)
3. **People** (heuristics 1-3): the confirmed leg tracks detected within the last
   ``report_misses + 1`` scans, or occluded, are paired closest first (`legs.pair_legs`) within
   ``pair_distance``; two legs both faster than ``min_speed`` whose velocities point more than
   ``max_motion_angle`` apart are not paired. A pair is a person at the midpoint of the legs;
   an unpaired leg track is a person too with ``single_legs`` (a leg whose partner is hidden
   or merged with it in one segment).

Example:
  >>> cfg = LegTrackerConfig()
  >>> state = init(cfg)
  >>> state, people = step(cfg, state, sensed.legs_xy, sensed.legs_mask, sensed.returns_xy,
  ...                      sensed.returns_mask, sensed.odom_pose, dt=0.1, max_people=8)
  >>> people.xy, people.mask      # [P, 2] odometry frame, [P]
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxtrack import _checks, geometry
from jaxtrack.perception import legs as legs_mod
from jaxtrack.tracking import tracker

Array = jax.Array

__all__ = ["LegTrackerConfig", "LegTrackerState", "init", "step", "occluded"]


@dataclasses.dataclass(frozen=True)
class LegTrackerConfig:
    """Static configuration (hashable; changing it recompiles).

    Attributes:
      capacity: leg track slots.
      max_candidates: at most this many leg candidates of a scan, the nearest to the robot,
        are associated (the assignment's cost grows with their number; a scan of the shop
        holds about 13).
      q: acceleration spectral density of a leg (m^2/s^3): a swinging leg goes from rest to
        about twice the walking speed within a third of a second.
      r_std: leg detection noise std (m).
      gate_prob: chi-square gate probability of the association.
      confirm_hits, confirm_window: M-of-N confirmation of a leg track.
      max_misses: consecutive unexcused misses that delete a confirmed track (tentative: 1).
      max_position_std: a track whose position std exceeds this (m) is deleted (also ends an
        occlusion).
      occlusion_radius: a return this close (m) to the line of sight to a track hides it.
      occlusion_margin: the hiding return is nearer to the laser than the track by at least
        this (m).
      laser_xy: (x, y) of the laser on the robot (robot frame), where lines of sight start.
      report_misses: confirmed tracks missed (not occluded) at most this many scans in a row
        still make people.
      pair_distance: largest distance between a person's two legs (m).
      min_speed: a leg slower than this (m/s) has no direction for the motion cue.
      max_motion_angle: two moving legs whose velocities differ in direction by more than this
        (rad) are not one person.
      single_legs: an unpaired leg track is a person.
      birth_confidence: only candidates whose detector confidence (``legs_conf`` of `step`)
        reaches this start leg tracks; any candidate updates a track. With the learned leg
        detector (`jaxtrack.perception.leg_classifier`), its best-F1 decision here and a lower
        candidate threshold (`sensing.SensingConfig.leg_threshold`) make the classifier's
        confidence initiate tracks and lower-confidence legs keep them, as the joint leg
        tracker of Leigh et al. (ICRA 2015) does. 0 (default): every candidate.
    """

    capacity: int = 16
    max_candidates: int = 24
    q: float = 8.0
    r_std: float = 0.05
    gate_prob: float = 0.999
    confirm_hits: int = 2
    confirm_window: int = 3
    max_misses: int = 2
    max_position_std: float = 0.3
    occlusion_radius: float = 0.1
    occlusion_margin: float = 0.15
    laser_xy: tuple = (0.0, 0.0)
    report_misses: int = 1
    pair_distance: float = 0.5
    min_speed: float = 0.3
    max_motion_angle: float = math.pi / 2
    single_legs: bool = True
    birth_confidence: float = 0.0

    def __post_init__(self):
        if self.capacity < 1 or self.max_candidates < 1:
            raise ValueError(f"capacity and max_candidates must be >= 1; got {self.capacity}, "
                             f"{self.max_candidates}")
        if min(self.q, self.r_std, self.max_position_std, self.pair_distance) <= 0:
            raise ValueError("q, r_std, max_position_std and pair_distance must be > 0")
        if not 0 < self.gate_prob < 1:
            raise ValueError(f"gate_prob must be in (0, 1); got {self.gate_prob}")
        if min(self.occlusion_radius, self.occlusion_margin, self.min_speed,
               self.report_misses) < 0:
            raise ValueError("occlusion_radius, occlusion_margin, min_speed and report_misses "
                             "must be >= 0")
        if len(self.laser_xy) != 2:
            raise ValueError(f"laser_xy must be (x, y); got {self.laser_xy!r}")
        if not 0.0 <= self.birth_confidence <= 1.0:
            raise ValueError(f"birth_confidence must be in [0, 1]; got "
                             f"{self.birth_confidence}")
        # The tracker configuration validates the confirmation counts.
        self.tracker

    @property
    def tracker(self) -> tracker.TrackerConfig:
        """The `tracker.TrackerConfig` of the leg tracks."""
        return tracker.TrackerConfig(
            capacity=self.capacity, association="gnn", filter="kf",
            confirm_hits=self.confirm_hits, confirm_window=self.confirm_window,
            max_misses=self.max_misses, max_tentative_misses=1,
            max_position_std=self.max_position_std, births_in_gates=True)

    def params(self, dt, dtype=jnp.float32) -> tracker.TrackerParams:
        """The leg tracks' `tracker.TrackerParams` for a scan period ``dt`` (s)."""
        return tracker.TrackerParams.create(self.tracker, dt=dt, q=self.q, r_std=(self.r_std,),
                                            init_speed_std=1.0, gate_prob=self.gate_prob,
                                            birth_confidence=self.birth_confidence,
                                            dtype=dtype)


jax.tree_util.register_static(LegTrackerConfig)


class LegTrackerState(NamedTuple):
    """tracks: the leg `tracker.Tracks` (odometry frame); occluded: [K] bools, the tracks that
    were occluded at the last scan."""

    tracks: tracker.Tracks
    occluded: Array


def init(config: LegTrackerConfig = LegTrackerConfig(), dtype=jnp.float32) -> LegTrackerState:
    """No leg tracks."""
    return LegTrackerState(tracker.init(config.tracker, dtype), jnp.zeros(config.capacity, bool))


def occluded(points: Array, returns_xy: Array, returns_mask: Array, origin: Array,
             radius, margin) -> Array:
    """[N] bools: each point [N, 2] lies behind a return (all in one frame, seen from
    ``origin`` [2]): some valid return of ``returns_xy [B, 2]`` is within ``radius`` of the
    segment from the origin to the point and nearer to the origin by more than ``margin``.

    Example:
      >>> occluded(jnp.array([[2.0, 0.0]]), jnp.array([[1.0, 0.05]]), jnp.array([True]),
      ...          jnp.zeros(2), 0.1, 0.15)      # [True]
    """
    d = points - origin                                               # [N, 2]
    rng = geometry.safe_norm(d)                                       # [N]
    u = d / jnp.maximum(rng, 1e-9)[:, None]
    r = returns_xy - origin                                           # [B, 2]
    along = r @ u.T                                                   # [B, N]
    across = jnp.abs(r[:, None, 0] * u[None, :, 1] - r[:, None, 1] * u[None, :, 0])
    hides = (returns_mask[:, None] & (along > 0) & (along < rng[None] - margin)
             & (across < radius))
    return jnp.any(hides, 0)


def step(config: LegTrackerConfig, state: LegTrackerState, legs_xy: Array, legs_mask: Array,
         returns_xy: Array, returns_mask: Array, robot_pose: Array, *, dt,
         max_people: int = 8, legs_conf: Array | None = None
         ) -> tuple[LegTrackerState, legs_mod.People]:
    """One scan (module docstring).

    Args:
      config: `LegTrackerConfig`.
      state: `LegTrackerState`.
      legs_xy: [S, 2] leg candidates of the scan (odometry frame); legs_mask: [S].
      returns_xy: [B, 2] the scan's returns in the robot frame; returns_mask: [B].
      robot_pose: [3] the robot's pose in the odometry frame.
      dt: scan period (s).
      max_people: static capacity P of the people.
      legs_conf: [S] detector confidence of each candidate (`legs.Detections.scores`), or
        None (all 1); see ``birth_confidence``.

    Returns:
      ``(state, people)``: `legs.People` in the odometry frame, whose ``legs`` are leg track
      slots.
    """
    _checks.check_shape("legs_xy", legs_xy, (None, 2), "[S, 2] leg candidates")
    _checks.check_shape("legs_mask", legs_mask, (_checks.shape_of(legs_xy)[0],))
    _checks.check_shape("returns_xy", returns_xy, (None, 2), "[B, 2] laser returns")
    _checks.check_shape("returns_mask", returns_mask, (_checks.shape_of(returns_xy)[0],))
    _checks.check_shape("robot_pose", robot_pose, (3,))
    if legs_conf is not None:
        _checks.check_shape("legs_conf", legs_conf, (_checks.shape_of(legs_xy)[0],))
    if int(max_people) < 1:
        raise ValueError(f"max_people must be >= 1; got {max_people}")
    dtype = state.tracks.mean.dtype
    params = config.params(dt, dtype)
    pose = jnp.asarray(robot_pose, dtype)
    xy = jnp.asarray(legs_xy, dtype)
    mask = jnp.asarray(legs_mask, bool)
    conf = (jnp.ones(xy.shape[0], dtype) if legs_conf is None
            else jnp.asarray(legs_conf, dtype))
    if xy.shape[0] > config.max_candidates:
        d2 = jnp.where(mask, jnp.sum((xy - pose[:2]) ** 2, -1), jnp.inf)
        keep = jnp.argsort(d2)[:config.max_candidates]
        xy, mask, conf = xy[keep], mask[keep], conf[keep]
    S = xy.shape[0]
    det = tracker.Detections(xy, mask, jnp.zeros(S, jnp.int32), conf,
                             jnp.zeros((S, 0), dtype))
    tr = state.tracks
    predicted = tracker.predict(tr, params)
    hyp = tracker.hypothesise(tr, predicted, det, params)
    assoc = tracker.associate_gnn(hyp, params)
    in_robot = geometry.to_frame(pose, predicted.mean[:, :2])
    hidden = hyp.live & ~assoc.hit & occluded(
        in_robot, jnp.asarray(returns_xy, dtype), jnp.asarray(returns_mask, bool),
        jnp.asarray(config.laser_xy, dtype), config.occlusion_radius, config.occlusion_margin)
    tr = tracker.manage(tr, hyp, assoc, params, excused=hidden)
    tr = tracker.births(tr, hyp, assoc, params).tracks
    hidden = hidden & (tr.status != tracker.FREE)
    shown = (tr.status == tracker.CONFIRMED) & ((tr.misses <= config.report_misses) | hidden)
    v = tr.mean[:, 2:]
    speed = geometry.safe_norm(v)
    moving = shown & (speed > config.min_speed)
    unit = v / jnp.maximum(speed, 1e-9)[:, None]
    compatible = (~(moving[:, None] & moving[None])
                  | (unit @ unit.T >= math.cos(config.max_motion_angle)))
    lp = legs_mod.LegParams(pair_distance=config.pair_distance,
                            single_legs=float(config.single_legs))
    people = legs_mod.pair_legs(tr.mean[:, :2], shown, lp, max_people=max_people,
                                compatible=compatible)
    return LegTrackerState(tr, hidden), people
