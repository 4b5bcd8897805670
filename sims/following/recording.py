"""Person-following recordings: the raw sensor data of an open-loop run, as a robot's bag keeps
them.

`make_recorder` / `record` run the person-following scene open loop and keep, per 10 Hz frame,
the laser ranges, the RGB-D person detections in the robot frame and the odometry pose and
twist (`sims.following.world.observe`, the odometry integrated from the start pose), with the
true robot and people for evaluation. The people walk as in `sims.following.pedestrians`; the
robot follows the true user with a simple proportional law (speed from the distance error to
``follow_distance``, turn rate from the bearing), so no estimator is in the loop. `to_records`
turns a recording into the `jaxtrack.io.bags` records that `jaxtrack.io.bags.write_bag` writes
and `jaxtrack.io.replay.track` replays; with the camera on a pan unit, `pan_record` is its
angle as a joint state.

Example:
  >>> rec = record(jax.random.PRNGKey(0), duration=3.0)
  >>> laser, odom, det = to_records(rec)
  >>> tracks = replay.track(laser, odom, det, estimator="gnn")
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import geometry
from jaxtrack.angles import wrap
from jaxtrack.control import pan_tilt
from jaxtrack.io import bags
from sims.following import lidar, pedestrians, world

Array = jax.Array

__all__ = ["Recording", "make_recorder", "record", "to_records", "pan_record"]


class Recording(NamedTuple):
    """Raw sensor data of a recording, one row per 10 Hz frame (T frames).

    Attributes:
      times: [T] seconds (``dt, 2 dt, ...``).
      ranges: [T, B] laser ranges (m; misses read ``max_range``); angles: [B].
      odom_pose: [T, 3] odometry pose (x, y, yaw) in the odometry frame (the true start pose at
        time 0, drifting after); odom_twist: [T, 3] (vx, vy, wz) of the odometry increments.
      det_xy: [T, M, 2] RGB-D person detections in the robot frame; det_mask: [T, M].
      robot: [T, 3] true robot pose; people: [T, P, 2] true people; people_mask: [T, P]
        (person 0 is the user).
      pan: [T] the RGB-D camera's pan angle relative to the robot (rad) when it sits on a pan
        unit, else None.
    """

    times: Array
    ranges: Array
    angles: Array
    odom_pose: Array
    odom_twist: Array
    det_xy: Array
    det_mask: Array
    robot: Array
    people: Array
    people_mask: Array
    pan: Array | None = None


def make_recorder(scene, *, distractors: int = 3, duration: float = 3.0, dt: float = 0.1,
                  sensors: world.SensorsConfig = world.SensorsConfig(),
                  follow_distance: float = 1.2, max_speed: float = 1.0, max_turn: float = 1.5,
                  pan: pan_tilt.PanTiltConfig | None = None, dtype=jnp.float32):
    """Build ``record(key) -> Recording`` (jittable) for a `sims.following.scene.Scene`.

    The robot's command each frame: :math:`v = \\operatorname{clip}(0.8 (d - d_f), 0,
    v_{max})`, :math:`\\omega = \\operatorname{clip}(1.5\\,\\beta, \\pm\\omega_{max})` with
    :math:`d`, :math:`\\beta` the true user's distance and bearing; the pose is integrated
    exactly for the frame. With ``pan``, the RGB-D camera sits on that pan unit, servoed to the
    true user's bearing (`jaxtrack.control.pan_tilt.servo`), and its angle is recorded.

    Example:
      >>> rec = jax.jit(make_recorder(scene.build(num_people=4)))(jax.random.PRNGKey(0))
    """
    from sims.following import scene as scene_mod

    if 1 + distractors > scene.num_people:
        raise ValueError(f"{1 + distractors} people exceed the scene's capacity of "
                         f"{scene.num_people}")
    T = int(round(duration / dt))
    if T < 1:
        raise ValueError(f"duration must hold at least one frame of {dt} s; got {duration}")
    P = scene.num_people
    pcfg = scene_mod.pedestrian_config(scene, distractors=distractors)
    laser = world.laser_world(scene, sensors.laser, dtype)

    def rec(key):
        k_init, k_col, k_run = jax.random.split(key, 3)
        people = pedestrians.init(k_init, pcfg, P, dtype)
        pose0 = pedestrians.robot_start(pcfg, people).astype(dtype)
        colours = jax.random.uniform(k_col, (P, 3), dtype)

        def frame(c, k):
            people, pose, odom, unit = c
            ks = jax.random.split(k, 4)
            rel = geometry.to_frame(pose, people.pos[0])
            dist = jnp.sqrt(jnp.sum(rel**2))
            bearing = jnp.arctan2(rel[1], rel[0])
            v = jnp.clip(0.8 * (dist - follow_distance), 0.0, max_speed)
            w = jnp.clip(1.5 * bearing, -max_turn, max_turn)
            people = pedestrians.step(ks[0], pcfg, people, pose, dt)
            new_pose = _unicycle(pose, v, w, dt)
            angle = None
            if pan is not None:
                ahead = geometry.to_frame(new_pose, people.pos[0])
                unit = pan_tilt.servo(pan, unit, jnp.arctan2(ahead[1], ahead[0]), dt)
                angle = unit.angle
            obs = world.observe(ks[1:], sensors, scene, laser, pose, new_pose, people, colours,
                                angle)
            new_odom = geometry.compose(odom, obs.increment)
            out = (obs.ranges, new_odom, obs.increment / dt, obs.rgbd.xy, obs.rgbd.mask,
                   new_pose, people.pos, people.mask, angle)
            return (people, new_pose, new_odom, unit), out

        _, out = jax.lax.scan(frame, (people, pose0, pose0, pan_tilt.init(dtype)),
                              jax.random.split(k_run, T))
        times = dt * jnp.arange(1, T + 1, dtype=jnp.float64 if jax.config.jax_enable_x64
                                else jnp.float32)
        return Recording(times, out[0], laser.angles, *out[1:])

    return rec


def record(key: Array, scene=None, **kw) -> Recording:
    """A recording as NumPy arrays (`make_recorder` compiled and run once).

    Args:
      key: PRNG key; scene: default ``scene.build(num_people=4)``; kw: `make_recorder`
        options (``distractors=3, duration=3.0``...).

    Example:
      >>> rec = record(jax.random.PRNGKey(0), duration=2.0)
    """
    if scene is None:
        from sims.following import scene as scene_mod

        scene = scene_mod.build(num_people=4)
    rec = jax.jit(make_recorder(scene, **kw))(key)
    return Recording(*(None if x is None else np.asarray(x) for x in rec))


def to_records(rec: Recording, laser: lidar.LaserConfig = lidar.LaserConfig()):
    """``(bags.LaserScans, bags.Odometry, bags.PersonDetections)`` of a recording, as
    `jaxtrack.io.bags` reads them back (ranges float32, beams at ``max_range`` masked, angles
    from the first angle and the mean increment: within 1e-6 rad of the simulation's).

    Example:
      >>> bags.write_bag("sim.bag", 1, **dict(zip(("laser", "odometry", "detections"),
      ...                                          to_records(rec))))
    """
    times = np.asarray(rec.times, np.float64)
    T = times.shape[0]
    ranges = np.asarray(rec.ranges, np.float32)
    rmax, rmin = np.float32(laser.max_range), np.float32(laser.min_range)
    mask = np.isfinite(ranges) & (ranges >= rmin) & (ranges < rmax)
    # The beam angles as a LaserScan carries them (angle_min + k * increment, float32), so
    # that the records equal what a bag gives back.
    a = np.asarray(rec.angles, np.float64)
    angles = bags.beam_angles(a[0], (a[-1] - a[0]) / (a.shape[0] - 1), a.shape[0])
    scans = bags.LaserScans(times, np.where(mask, ranges, rmax), angles, mask, float(rmin),
                            float(rmax), np.ones(T, bool))
    odom = bags.Odometry(times, np.asarray(rec.odom_pose, np.float64),
                         np.asarray(rec.odom_twist, np.float64), np.ones(T, bool))
    dmask = np.asarray(rec.det_mask, bool)
    det = bags.PersonDetections(times, np.where(dmask[..., None], rec.det_xy, 0.0)
                                .astype(np.float64), dmask, np.ones(T, bool))
    return scans, odom, det


def pan_record(rec: Recording, joint: str = "camera_pan") -> bags.JointStates:
    """The camera's pan angle of a recording as the `jaxtrack.io.bags.JointStates` that
    ``write_bag(..., joints=)`` writes as ``sensor_msgs/JointState`` (one joint, ``joint``).

    Example:
      >>> rec = record(jax.random.PRNGKey(0), pan=pan_tilt.PanTiltConfig())
      >>> bags.write_bag("sim.bag", 1, **dict(zip(("laser", "odometry", "detections"),
      ...                to_records(rec))), joints=pan_record(rec))
    """
    if rec.pan is None:
        raise ValueError("the recording has no pan angle (record it with pan=PanTiltConfig())")
    times = np.asarray(rec.times, np.float64)
    return bags.JointStates(times, (joint,), np.asarray(rec.pan, np.float64)[:, None],
                            np.ones(times.shape[0], bool))


def _unicycle(pose, v, w, dt):
    """Exact unicycle motion over ``dt`` at constant (v, w)."""
    th = pose[2]
    small = jnp.abs(w) < 1e-6
    w_safe = jnp.where(small, 1.0, w)
    dx = jnp.where(small, v * dt * jnp.cos(th),
                   v / w_safe * (jnp.sin(th + w * dt) - jnp.sin(th)))
    dy = jnp.where(small, v * dt * jnp.sin(th),
                   -v / w_safe * (jnp.cos(th + w * dt) - jnp.cos(th)))
    return jnp.stack([pose[0] + dx, pose[1] + dy, wrap(th + w * dt)])
