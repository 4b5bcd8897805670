r"""The sensing step of a person-following robot: laser legs and RGB-D people in the estimators'
frame.

One call of `sense` per frame, the same for a simulated episode and for a recording replayed
from a bag:

1. the leg detector (`jaxtrack.perception.legs.detect`) on the laser scan, with the previous
   frame's leg candidates for its motion cue (kept in the odometry frame, brought into the
   current sensor frame);
2. the laser people from the sensor frame into the odometry frame (the estimators' frame) and
   into the frame of a static map, where people at a known leg-like fixed object (a table or
   chair leg) or on a wall are dropped (`StaticMap`: furniture legs 0.3-0.5 m apart look like a
   person's legs, and at grazing incidence range jumps cut a wall into leg-sized segments);
3. the RGB-D people from the robot frame into the odometry frame;
4. the laser returns in the robot frame, the obstacle points of the behaviour's safety layers;
5. the leg candidates in the odometry frame, off the map, for a leg tracker
   (`jaxtrack.tracking.leg_tracker`, seed 004's laser side).

Frames: *sensor* (the laser, at ``mount`` on the robot, facing its heading), *robot*, *odometry*
(dead reckoning from the start pose; it drifts from the world), *map* (the static map's; in
simulation the world, the robot being localised in its map; replaying a bag, the odometry
frame).

Example:
  >>> cfg = SensingConfig()
  >>> state = init(cfg, jnp.float32)
  >>> state, sensed = sense(cfg, state, ranges, angles, Odometry(pose, increment), rgbd_xy,
  ...                       rgbd_mask, rgbd_colour, empty_map(), map_pose=pose, period=0.1)
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxtrack import _checks, geometry
from jaxtrack.perception import leg_classifier, legs

Array = jax.Array

__all__ = ["SensingConfig", "StaticMap", "Odometry", "SensingState", "Sensed", "empty_map",
           "init", "sense", "sensor_pose", "wall_distance"]


@dataclasses.dataclass(frozen=True)
class SensingConfig:
    """Static settings of the sensing step (hashable; changing them recompiles).

    Attributes:
      leg_params: `legs.LegParams` of the leg detector; its ``min_range`` / ``max_range`` also
        decide which returns are obstacle points.
      max_segments, max_people: leg-detector capacities (scan segments, laser people).
      laser_mount: the laser's pose on the robot: ``(x, y)`` (facing the robot's heading) or
        ``(x, y, yaw)``; or, for several lasers fused in one step, a tuple of such mounts, one
        per laser (`sense` then takes ``[N, B]`` ranges and angles).
      merge_radius: with several lasers, a leg or a person another laser already detected
        within this distance (m) is the same one, seen twice where the fields of view overlap.
      static_radius: laser people within this (m) of a fixed leg of the `StaticMap` are dropped.
      wall_distance: laser people within this (m) of a wall of the `StaticMap` are dropped.
      detector: which segments are legs: ``"geometric"`` (the thresholds of ``leg_params``),
        ``"learned"`` (the shipped classifier, `leg_classifier.default`, trained on real
        0.35 deg scans) or the path of a model trained with ``jaxtrack train-legs``. The
        simulated scenes keep the geometric detector: their simulated legs are exact arcs,
        not the trousers the learned one was trained on.
      leg_threshold: with a learned detector, the leg probability from which a segment is a
        leg candidate (0.05). Lower than the classifier's own best-F1 decision (0.235 for the
        shipped model): the trackers confirm candidates over scans, so they want recall.
        Measured on the leg_tracker demo bag (a different scanner from the training bags): 0.8
        legs per scan at 0.235 and 2.7 at 0.05, and with the ``gnn`` estimator 13 track ids
        (20 with the geometric detector, which also tracks furniture).
      max_leg_candidates: leg-sized segments per scan the learned classifier evaluates
        (`legs.detect`'s ``max_candidates``).
    """

    leg_params: legs.LegParams = legs.LegParams()
    max_segments: int = 48
    max_people: int = 8
    laser_mount: tuple = (0.0, 0.0)
    static_radius: float = 0.3
    wall_distance: float = 0.25
    detector: str = "geometric"
    leg_threshold: float = 0.05
    max_leg_candidates: int = 16
    merge_radius: float = 0.2

    def __post_init__(self):
        if self.detector not in ("geometric", "learned") and not Path(self.detector).is_file():
            raise ValueError(f"detector must be 'geometric', 'learned' or a model file; got "
                             f"{self.detector!r}")
        if self.max_leg_candidates < 1:
            raise ValueError(f"max_leg_candidates must be >= 1; got {self.max_leg_candidates}")
        if not 0.0 <= self.leg_threshold <= 1.0:
            raise ValueError(f"leg_threshold must be in [0, 1]; got {self.leg_threshold}")
        if self.max_segments < 1 or self.max_people < 1:
            raise ValueError(f"max_segments and max_people must be >= 1; got "
                             f"{self.max_segments}, {self.max_people}")
        if not (self.static_radius >= 0 and self.wall_distance >= 0):
            raise ValueError("static_radius and wall_distance must be >= 0")
        self.mounts  # noqa: B018  (validates laser_mount)
        if not self.merge_radius >= 0:
            raise ValueError(f"merge_radius must be >= 0; got {self.merge_radius}")

    @property
    def multi(self) -> bool:
        """Several lasers: ``laser_mount`` is a tuple of mounts."""
        return len(self.laser_mount) > 0 and isinstance(self.laser_mount[0], (tuple, list))

    @property
    def mounts(self) -> tuple:
        """The mounts as ``((x, y, yaw), ...)``, one per laser."""
        given = self.laser_mount if self.multi else (self.laser_mount,)
        if not given:
            raise ValueError("laser_mount holds no laser mount")
        out = []
        for m in given:
            try:
                m = tuple(float(v) for v in m)
            except (TypeError, ValueError):
                m = ()
            if len(m) not in (2, 3) or not all(map(math.isfinite, m)):
                raise ValueError(f"laser_mount: a laser mount is (x, y) or (x, y, yaw), "
                                 f"finite; got {self.laser_mount!r}")
            out.append(m + (0.0,) * (3 - len(m)))
        return tuple(out)

    @property
    def num_lasers(self) -> int:
        return len(self.mounts)


jax.tree_util.register_static(SensingConfig)


class StaticMap(NamedTuple):
    """What the robot knows of its surroundings, in the map frame.

    Attributes:
      legs: [F, 2] leg-like fixed objects (table and chair legs); F may be 0.
      walls: [W, 2, 2] wall segments (segment, end, xy); W may be 0.
    """

    legs: Array
    walls: Array


class Odometry(NamedTuple):
    """Dead reckoning at one frame.

    Attributes:
      pose: [3] the robot's pose in the odometry frame.
      increment: [3] (dx, dy, dtheta) of the last period, in the previous robot frame.
    """

    pose: Array
    increment: Array


class SensingState(NamedTuple):
    """The previous frame's leg candidates in the odometry frame: legs_xy [S, 2], legs_mask [S]."""

    legs_xy: Array
    legs_mask: Array


class Sensed(NamedTuple):
    """What one sensing step gives the estimators and the behaviour.

    Attributes:
      laser_xy: [L, 2] laser people (odometry frame); laser_mask: [L] (map filter applied).
      laser_map_xy: [L, 2] the same people in the map frame.
      rgbd_xy: [K, 2] RGB-D people (odometry frame); rgbd_mask: [K]; rgbd_colour: [K, 3].
      odom_pose: [3] robot pose in the odometry frame; odom_speed, odom_rate: forward speed
        (m/s) and turn rate (rad/s) of the last period, from the odometry.
      returns_xy: [B, 2] laser returns in the robot frame (0 where invalid); returns_mask: [B].
      truth: [4] the true user ``(p_x, p_y, v_x, v_y)`` in the odometry frame where a
        simulator knows it (the ``truth`` estimator's input), else None.
      camera_pan: the RGB-D camera's pan angle relative to the robot's heading (rad) when it
        sits on a pan unit, else None (it looks straight ahead).
      legs_xy: [S, 2] the scan's leg candidates (odometry frame), the input of a leg tracker
        (`jaxtrack.tracking.leg_tracker`); legs_mask: [S] (the map filter applied); None where
        not given.
      legs_score: [S] the leg detector's confidence in each candidate (the learned
        classifier's probability; 1 for the geometric detector's), or None (all 1).
    """

    laser_xy: Array
    laser_mask: Array
    laser_map_xy: Array
    rgbd_xy: Array
    rgbd_mask: Array
    rgbd_colour: Array
    odom_pose: Array
    odom_speed: Array
    odom_rate: Array
    returns_xy: Array
    returns_mask: Array
    truth: Array | None = None
    camera_pan: Array | None = None
    legs_xy: Array | None = None
    legs_mask: Array | None = None
    legs_score: Array | None = None


def empty_map(dtype=jnp.float32) -> StaticMap:
    """A `StaticMap` with no fixed legs and no walls."""
    return StaticMap(jnp.zeros((0, 2), dtype), jnp.zeros((0, 2, 2), dtype))


def init(config: SensingConfig, dtype=jnp.float32) -> SensingState:
    """The sensing state before the first scan (no previous legs)."""
    S = config.max_segments
    return SensingState(jnp.zeros((S, 2), dtype), jnp.zeros(S, bool))


def sensor_pose(robot_pose: Array, mount) -> Array:
    """Pose [3] of a sensor mounted at ``mount`` (x, y) on a robot at ``robot_pose`` [3],
    facing the robot's heading (no wrapping: the heading is the robot's, bit for bit), or at
    ``mount`` (x, y, yaw) [3], turned by yaw (not wrapped either)."""
    if len(mount) == 3 and not (isinstance(mount, tuple) and float(mount[2]) == 0.0):
        m = jnp.asarray(mount, robot_pose.dtype)
        return jnp.concatenate([geometry.from_frame(robot_pose, m[:2]), robot_pose[2:] + m[2:]])
    xy = geometry.from_frame(robot_pose, jnp.asarray(mount[:2], robot_pose.dtype))
    return jnp.concatenate([xy, robot_pose[2:]])


def wall_distance(xy: Array, segments: Array) -> Array:
    """[N] distance from points [N, 2] to the nearest of the segments [W, 2, 2] (W >= 1)."""
    a, b = segments[None, :, 0], segments[None, :, 1]
    ab = b - a
    t = jnp.clip(jnp.sum((xy[:, None] - a) * ab, -1) / jnp.sum(ab * ab, -1), 0.0, 1.0)
    return jnp.min(geometry.safe_norm(xy[:, None] - (a + t[..., None] * ab)), 1)


def sense(config: SensingConfig, state: SensingState, ranges: Array, angles: Array,
          odometry: Odometry, rgbd_xy: Array, rgbd_mask: Array, rgbd_colour: Array | None,
          static_map: StaticMap, map_pose: Array, period) -> tuple[SensingState, Sensed]:
    """One sensing step (module docstring).

    Args:
      config: `SensingConfig`.
      state: `SensingState` of the previous frame.
      ranges: [B] laser ranges; angles: [B] beam angles (sensor frame). With several lasers
        (``config.laser_mount`` a tuple of mounts): [N, B] each, one scan per laser (pad
        shorter scans with NaN ranges); the outputs then hold every laser's: the people
        [max_people] and legs [max_segments] left after merging, and the returns [N * B].
      odometry: `Odometry` at this frame.
      rgbd_xy: [K, 2] RGB-D person detections in the robot frame; rgbd_mask: [K];
        rgbd_colour: [K, 3] colour features, or None (zeros).
      static_map: `StaticMap` (map frame).
      map_pose: [3] the robot's pose in the map frame.
      period: frame period (s), for the odometry's speed and turn rate.

    Returns:
      ``(SensingState, Sensed)``.
    """
    if config.multi:
        N = config.num_lasers
        _checks.check_shape("ranges", ranges, (N, None), f"[{N}, B] ranges, one scan per laser")
        _checks.check_shape("angles", angles, _checks.shape_of(ranges), "one angle per beam")
    else:
        _checks.check_shape("ranges", ranges, (None,), "[B] ranges")
        _checks.check_shape("angles", angles, (_checks.shape_of(ranges)[0],),
                            "one angle per beam")
    _checks.check_shape("rgbd_xy", rgbd_xy, (None, 2), "[K, 2] detections")
    _checks.check_shape("rgbd_mask", rgbd_mask, (_checks.shape_of(rgbd_xy)[0],))
    dtype = odometry.pose.dtype
    odom = odometry.pose
    if config.multi:
        laser = _fused_lasers(config, state, ranges, angles, odom, map_pose)
    else:
        laser = _one_laser(config, state, ranges, angles, odom, map_pose, config.laser_mount)
    people, people_map, people_mask, legs_odom, legs_map, legs_mask, scores, returns, valid = laser
    laser_mask = _off_map(config, static_map, people_map, people_mask)
    legs_shown = _off_map(config, static_map, legs_map, legs_mask)
    K = rgbd_xy.shape[0]
    colour = jnp.zeros((K, 3), dtype) if rgbd_colour is None else rgbd_colour.astype(dtype)
    sensed = Sensed(people, laser_mask, people_map,
                    geometry.from_frame(odom, rgbd_xy.astype(dtype)), rgbd_mask, colour, odom,
                    odometry.increment[0] / period, odometry.increment[2] / period, returns,
                    valid, legs_xy=legs_odom, legs_mask=legs_shown,
                    legs_score=scores.astype(dtype))
    new = SensingState(legs_odom, legs_mask)
    return new, sensed


def _one_laser(config, state, ranges, angles, odom, map_pose, mount):
    """One laser's people and leg candidates (odometry and map frames) and its returns (robot
    frame): ``(people, people_map, people_mask, legs, legs_map, legs_mask, scores, returns,
    valid)``."""
    dtype = odom.dtype
    in_odom = sensor_pose(odom, mount)
    in_map = sensor_pose(map_pose, mount)
    det = legs.detect(ranges, angles, config.leg_params, max_segments=config.max_segments,
                      max_people=config.max_people,
                      prev_legs=(geometry.to_frame(in_odom, state.legs_xy), state.legs_mask),
                      classifier=leg_classifier.resolve(config.detector),
                      threshold=config.leg_threshold,
                      max_candidates=config.max_leg_candidates)
    people = det.people.xy.astype(dtype)
    leg_xy = det.legs_xy.astype(dtype)
    if len(mount) == 2 or mount[2] == 0.0:
        returns = det.points + jnp.asarray(mount[:2], dtype)
    else:
        returns = geometry.from_frame(jnp.asarray(mount, dtype), det.points.astype(dtype))
    return (geometry.from_frame(in_odom, people), geometry.from_frame(in_map, people),
            det.people.mask, geometry.from_frame(in_odom, leg_xy),
            geometry.from_frame(in_map, leg_xy), det.legs_mask, det.scores, returns, det.valid)


def _fused_lasers(config, state, ranges, angles, odom, map_pose):
    """Several lasers at once: each detects on its own scan (the previous frame's fused legs
    for its motion cue); their people, legs and returns are concatenated, laser by laser, and
    a leg or person within ``merge_radius`` of one an earlier laser detected is dropped (one
    pass, no chains: where fields of view overlap the same leg is seen twice). The people and
    legs left are compacted into ``max_people`` and ``max_segments`` slots, in laser order
    (beyond those, the last laser's are dropped)."""
    outs = [_one_laser(config, state, ranges[i], angles[i], odom, map_pose, m)
            for i, m in enumerate(config.mounts)]
    cat = [jnp.concatenate(x) for x in zip(*outs)]
    people, people_map, people_mask, legs_odom, legs_map, legs_mask, scores, returns, valid = cat
    P, S = config.max_people, config.max_segments
    people_mask = people_mask & ~_seen_before(people, people_mask, P, config.merge_radius)
    legs_mask = legs_mask & ~_seen_before(legs_odom, legs_mask, S, config.merge_radius)
    # The kept ones, compacted into one laser's capacity: the estimators' cost grows with the
    # number of detection slots (a 3-laser replay ran 2.4x slower with all 3 x 8 slots).
    keep = jnp.argsort(~people_mask, stable=True)[:P]
    people, people_map, people_mask = people[keep], people_map[keep], people_mask[keep]
    keep = jnp.argsort(~legs_mask, stable=True)[:S]
    legs_odom, legs_map, legs_mask, scores = (legs_odom[keep], legs_map[keep], legs_mask[keep],
                                              scores[keep])
    return (people, people_map, people_mask, legs_odom, legs_map, legs_mask, scores, returns,
            valid)


def _seen_before(xy, mask, per_laser, radius):
    """[N * per_laser] points within ``radius`` of a masked point of an earlier laser."""
    group = jnp.arange(xy.shape[0]) // per_laser
    d2 = jnp.sum((xy[:, None] - xy[None]) ** 2, -1)
    earlier = group[None, :] < group[:, None]
    return jnp.any(earlier & mask[None, :] & (d2 < radius**2), 1)


def _off_map(config, static_map, xy_map, mask):
    """``mask`` without the points [N, 2] (map frame) at a fixed leg or on a wall of the map."""
    if static_map.legs.shape[0]:
        d2 = jnp.sum((xy_map[:, None] - static_map.legs[None]) ** 2, -1)
        mask = mask & ~jnp.any(d2 < config.static_radius**2, 1)
    if static_map.walls.shape[0]:
        mask = mask & (wall_distance(xy_map, static_map.walls) > config.wall_distance)
    return mask
