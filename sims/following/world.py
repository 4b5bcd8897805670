"""The simulated world of the person-following scene and its sensors, in the world frame.

- `World`: the MJX robot, the pedestrians and the robot's true pose; `reset` and `step` (the
  people walk, avoiding each other and the robot, then the robot applies its command through
  MJX physics for one control period);
- `SensorsConfig` and `observe`: what the robot's sensors return at one frame, as raw data in
  their own frames: the laser's ranges (`sims.following.lidar`), the RGB-D detector's people in
  the robot frame and the noisy odometry increment (`sims.following.rgbd`), plus the people's
  leg cross-sections at the laser's height (ground truth of what the laser can see).

Both the closed-loop episode (`sims.following.episode`) and the open-loop recorder
(`sims.following.recording`) use them.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import geometry
from jaxtrack.control import behaviour
from jaxtrack.perception import legs, sensing
from sims.following import lidar, pedestrians
from sims.following import rgbd as rgbd_mod
from sims.following import scene as scene_mod

Array = jax.Array

__all__ = ["SensorsConfig", "World", "Laser", "Observation", "laser_world", "observe",
           "reset", "step", "static_map", "known_map", "outline_points"]


@dataclasses.dataclass(frozen=True)
class SensorsConfig:
    """The robot's simulated sensors and its sensing step.

    Attributes:
      laser: `lidar.LaserConfig`; its range limits and mount are also the leg detector's.
      rgbd: `rgbd.RGBDConfig`; odometry: `rgbd.OdometryConfig`.
      leg_params: `legs.LegParams` of the leg detector (its range limits are the laser's). By
        default an unpaired leg is a person too, with segments up to 0.4 m wide: a standing
        person's legs often merge into one segment, and a walking person seen along their path
        hides one leg behind the other; the map filter removes the furniture legs and wall
        pieces that would otherwise become people (measurements: docs/design_notes.md,
        "Person following: single legs and wide leg segments").
      max_segments, max_laser_people: leg-detector capacities.
      map_filter: drop laser people within ``map_filter_radius`` of a furniture leg, or within
        ``wall_filter_distance`` of a wall, of the robot's map (the robot is localised in its
        map for this filter; the estimators still work in the drifting odometry frame).
    """

    laser: lidar.LaserConfig = lidar.LaserConfig()
    rgbd: rgbd_mod.RGBDConfig = rgbd_mod.RGBDConfig()
    odometry: rgbd_mod.OdometryConfig = rgbd_mod.OdometryConfig()
    leg_params: legs.LegParams = legs.LegParams(single_legs=1.0, max_width=0.4)
    max_segments: int = 48
    max_laser_people: int = 8
    map_filter: bool = True
    map_filter_radius: float = 0.3
    wall_filter_distance: float = 0.25

    @property
    def sensing(self) -> sensing.SensingConfig:
        """The `jaxtrack.perception.sensing.SensingConfig` of these sensors."""
        lp = self.leg_params._replace(min_range=self.laser.min_range,
                                      max_range=self.laser.max_range)
        return sensing.SensingConfig(lp, self.max_segments, self.max_laser_people,
                                     tuple(self.laser.mount), self.map_filter_radius,
                                     self.wall_filter_distance)


class World(NamedTuple):
    """data: the robot's ``mjx.Data``; people: `pedestrians.PedestrianState`; robot: [3] its
    true pose (x, y, theta)."""

    data: object
    people: pedestrians.PedestrianState
    robot: Array


class Laser(NamedTuple):
    """What the laser can hit besides people: walls (`lidar.Walls`: the room's, then the
    blocks' edges), furniture legs (`lidar.Circles`), and the beam angles [B]; ``blocks``:
    [S, 2, 2] the blocks' edges alone (they hide people from the camera too), or None."""

    walls: lidar.Walls
    furniture: lidar.Circles
    angles: Array
    blocks: Array | None = None


class Observation(NamedTuple):
    """Raw sensor data of one frame.

    Attributes:
      ranges: [B] laser ranges.
      rgbd: `rgbd.RGBDDetections` (robot frame).
      increment: [3] the odometry's (noisy) motion since the last frame, in the previous
        robot frame.
      legs: `lidar.Circles` of the people's legs at the laser's height ([2P], left and right
        leg of each person in turn).
    """

    ranges: Array
    rgbd: rgbd_mod.RGBDDetections
    increment: Array
    legs: lidar.Circles


def laser_world(sc: scene_mod.Scene, laser: lidar.LaserConfig, dtype) -> Laser:
    """The laser's static world in the scene ``sc``."""
    fc, fr = sc.furniture_circles()
    segments = sc.wall_segments()
    walls = lidar.Walls(jnp.asarray(segments, dtype), jnp.ones(len(segments), bool))
    furn = lidar.Circles(jnp.asarray(fc, dtype).reshape(-1, 2), jnp.asarray(fr, dtype),
                         jnp.ones(len(fr), bool))
    blocks = jnp.asarray(segments[4:], dtype) if len(segments) > 4 else None
    return Laser(walls, furn, lidar.beam_angles(laser, dtype), blocks)


def observe(keys, cfg: SensorsConfig, sc: scene_mod.Scene, laser: Laser, prev_pose: Array,
            pose: Array, people: pedestrians.PedestrianState, colours: Array,
            pan: Array | None = None) -> Observation:
    """The sensors at the robot's true pose ``pose`` [3] after moving from ``prev_pose``.

    Args:
      keys: three PRNG keys (odometry, laser, RGB-D).
      colours: [P, 3] the people's colour features.
      pan: the RGB-D camera's pan angle relative to the robot (rad), or None (fixed): its field
        of view turns with it; the detections are returned in the robot frame.
    """
    k_odom, k_laser, k_rgbd = keys
    dtype = pose.dtype
    increment = rgbd_mod.odometry(k_odom, cfg.odometry, prev_pose, pose)
    p0, p1, r = pedestrians.leg_capsules(people, sc.gait)
    sec = lidar.capsule_sections(p0.reshape(-1, 3), p1.reshape(-1, 3), r.reshape(-1),
                                 cfg.laser.height)
    circles = lidar.Circles(jnp.concatenate([sec.centers.astype(dtype), laser.furniture.centers]),
                            jnp.concatenate([sec.radii.astype(dtype), laser.furniture.radii]),
                            jnp.concatenate([sec.mask, laser.furniture.mask]))
    ranges = lidar.scan(k_laser, lidar.laser_pose(pose, cfg.laser), circles, laser.walls,
                        cfg.laser)
    camera = pose if pan is None else pose.at[2].add(pan)
    det = rgbd_mod.detect(k_rgbd, cfg.rgbd, camera, people.pos, people.mask, colours,
                          laser.blocks)
    if pan is not None:
        det = det._replace(xy=jnp.where(det.mask[:, None], geometry.rotate(pan, det.xy), 0.0))
    return Observation(ranges, det, increment, sec)


def reset(sc: scene_mod.Scene, pcfg: pedestrians.PedestrianConfig, key: Array, dtype) -> World:
    """People at their start, the robot behind its user (`pedestrians.robot_start`)."""
    people = pedestrians.init(key, pcfg, sc.num_people, dtype)
    pose = pedestrians.robot_start(pcfg, people).astype(dtype)
    return World(scene_mod.reset(sc, pose), people, pose)


def step(key: Array, sc: scene_mod.Scene, pcfg: pedestrians.PedestrianConfig, world: World,
         u: Array, dt: float) -> World:
    """One control period: the people step (seeing the robot where it was), then the robot
    applies ``u`` = (v, omega) through MJX physics."""
    people = pedestrians.step(key, pcfg, world.people, world.robot, dt)
    data = scene_mod.robot_step(sc, world.data, u, max(1, round(dt / sc.dt)))
    return World(data, people, scene_mod.robot_pose(data).astype(world.robot.dtype))


def outline_points(furniture, spacing=0.1) -> np.ndarray:
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


def static_map(sc: scene_mod.Scene, laser: Laser, enabled: bool = True) -> sensing.StaticMap:
    """The map filter's `sensing.StaticMap` (world frame): the furniture legs and the walls;
    empty when ``enabled`` is False."""
    dtype = laser.walls.endpoints.dtype
    if not enabled:
        return sensing.empty_map(dtype)
    return sensing.StaticMap(laser.furniture.centers, laser.walls.endpoints)


def known_map(sc: scene_mod.Scene):
    """The behaviour's `jaxtrack.control.behaviour.KnownMap`: furniture and block outlines,
    and the walls."""
    W, H = sc.room
    return behaviour.KnownMap(outline_points(tuple(sc.furniture) + tuple(sc.blocks)),
                              ((-W / 2, W / 2), (-H / 2, H / 2)))
