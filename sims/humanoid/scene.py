r"""Scene 1 of seed 000: a NAO-sized humanoid in a room under a zenithal depth camera.

The humanoid is built only from primitives that MJX's ``ray`` handles (boxes, capsules,
spheres, ellipsoids; it ignores cylinders) and the model carries a ``<material>`` (MJX's ray
crashes without one). Sizes follow the NAO v4 (about 0.57 m tall, shoulders with the arms about
0.27 m across, hip at 0.25 m, neck at 0.46 m):

- a free-floating ``torso`` body (the pelvis/CoM frame of the walking pattern generator) with a
  torso box, a neck capsule and an ellipsoid head;
- two arms (shoulder pitch, elbow) of capsules with sphere hands;
- two legs with hip yaw / roll / pitch, knee, ankle pitch / roll, capsule thigh and shin and a
  box foot.

Contacts are disabled (``contype = conaffinity = 0``): the scene is posed kinematically from
the walking pattern generator (see `sims.humanoid.gait` for why), never integrated.

The room is a floor plane and four walls, placed outside the camera's field of view at the
floor. The camera is zenithal (looking straight down, image right = world +x, image up =
world +y), ``camera_height`` above the floor (2.5-3 m), with a Kinect-like 57 x 43 deg field of
view and a resolution that is a parameter (80 x 60 by default).

`build` returns a `Scene`: the ``mujoco.MjModel``, its ``mjx.Model``, the `Camera` and the index
tables the gait, the renderer and the episode need. `pose_geoms` maps a ``qpos`` to world geom
poses with ``mjx.kinematics`` (jittable, vmappable).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

Array = jax.Array

__all__ = ["Body", "Camera", "Scene", "mjcf", "build", "pose_geoms", "camera_rays",
           "LEG_JOINTS", "ARM_JOINTS"]

LEG_JOINTS = ("hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle_pitch", "ankle_roll")
ARM_JOINTS = ("shoulder_pitch", "elbow")


class Body(NamedTuple):
    """Humanoid dimensions (metres), NAO v4-like.

    Attributes:
      hip_height: height of the hip joints above the floor when the legs are straight minus a
        small bend (the LIPM CoM height is ``com_height`` in the gait).
      hip_offset: lateral offset of each hip joint from the pelvis centre.
      thigh, shin: thigh and shin lengths (hip-knee, knee-ankle).
      ankle_height: ankle joint above the sole.
      pelvis_to_neck: neck joint above the hip line.
      shoulder_offset: lateral offset of the shoulder joints; shoulder_drop: below the neck.
      upper_arm, forearm: arm segment lengths.
      head_size: ellipsoid half sizes of the head (front-back, left-right, up-down).
    """

    hip_offset: float = 0.05
    thigh: float = 0.10
    shin: float = 0.1029
    ankle_height: float = 0.0455
    pelvis_to_neck: float = 0.211
    shoulder_offset: float = 0.098
    shoulder_drop: float = 0.025
    upper_arm: float = 0.105
    forearm: float = 0.10
    head_size: tuple = (0.058, 0.065, 0.062)


class Camera(NamedTuple):
    """Pinhole zenithal camera (looking down -z, image right = +x, image up = +y).

    Attributes:
      position: [3] optical centre in the world frame.
      width, height: resolution (static ints).
      fx, fy: focal lengths in pixels; cx, cy: principal point (pixel units, centre of image).
    """

    position: tuple
    width: int
    height: int
    fx: float
    fy: float

    @property
    def cx(self) -> float:
        return self.width / 2.0

    @property
    def cy(self) -> float:
        return self.height / 2.0


@dataclasses.dataclass(frozen=True, eq=False)
class Scene:
    """A built scene (static: closed over by jitted functions, never traced).

    Attributes:
      model: the ``mujoco.MjModel``.
      mjx_model: the ``mjx.Model`` (``mjx.put_model``).
      camera: `Camera`.
      body: `Body` dimensions.
      robot_geoms: [G] ids of the humanoid's geoms (the renderer's dynamic geoms).
      static_geoms: ids of the room's geoms.
      leg_qpos: [2, 6] qpos addresses of the left / right leg joints (`LEG_JOINTS` order).
      arm_qpos: [2, 2] qpos addresses of the left / right arm joints.
      head_qpos: qpos address of the head yaw joint.
      standing_height: height of the free joint (pelvis) with the standing leg bend.
    """

    model: mujoco.MjModel
    mjx_model: mjx.Model
    camera: Camera
    body: Body
    robot_geoms: np.ndarray
    static_geoms: np.ndarray
    leg_qpos: np.ndarray
    arm_qpos: np.ndarray
    head_qpos: int
    standing_height: float


def mjcf(body: Body = Body(), camera_position=(0.5, 0.5, 2.8), fovy_deg: float = 43.0,
         room_half_size: float = 2.0) -> str:
    """The scene's MJCF string (humanoid at the origin, facing +x).

    Args:
      body: `Body` dimensions.
      camera_position: zenithal camera centre (x, y, height); the height should be 2.5-3 m.
      fovy_deg: vertical field of view (Kinect: 43 deg).
      room_half_size: the walls stand this far from the camera's (x, y).

    Example:
      >>> xml = mjcf(Body(), (0.5, 0.5, 2.8))
    """
    b = body
    cx, cy, cz = camera_position
    hx, hy, hz = b.head_size
    leg_length = b.thigh + b.shin + b.ankle_height
    r = room_half_size
    legs = []
    for side, sign in (("l", 1.0), ("r", -1.0)):
        legs.append(f"""
      <body name="{side}_thigh" pos="0 {sign * b.hip_offset} 0">
        <joint name="{side}_hip_yaw" axis="0 0 1"/>
        <joint name="{side}_hip_roll" axis="1 0 0"/>
        <joint name="{side}_hip_pitch" axis="0 1 0"/>
        <geom name="{side}_thigh" type="capsule" fromto="0 0 -0.015 0 0 {-b.thigh + 0.01}"
              size="0.033" material="robot"/>
        <body name="{side}_shin" pos="0 0 {-b.thigh}">
          <joint name="{side}_knee" axis="0 1 0"/>
          <geom name="{side}_shin" type="capsule" fromto="0 0 -0.01 0 0 {-b.shin + 0.015}"
                size="0.028" material="robot"/>
          <body name="{side}_foot" pos="0 0 {-b.shin}">
            <joint name="{side}_ankle_pitch" axis="0 1 0"/>
            <joint name="{side}_ankle_roll" axis="1 0 0"/>
            <geom name="{side}_foot" type="box" pos="0.02 {sign * 0.005} {-b.ankle_height + 0.015}"
                  size="0.08 0.045 0.015" material="robot"/>
          </body>
        </body>
      </body>
      <body name="{side}_upper_arm" pos="0 {sign * b.shoulder_offset}
            {b.pelvis_to_neck - b.shoulder_drop}">
        <joint name="{side}_shoulder_pitch" axis="0 1 0"/>
        <geom name="{side}_shoulder" type="sphere" size="0.035" material="robot"/>
        <geom name="{side}_upper_arm" type="capsule" fromto="0 {sign * 0.005} -0.02
              0 {sign * 0.005} {-b.upper_arm + 0.01}" size="0.03" material="robot"/>
        <body name="{side}_forearm" pos="0 {sign * 0.005} {-b.upper_arm}">
          <joint name="{side}_elbow" axis="0 1 0"/>
          <geom name="{side}_forearm" type="capsule" fromto="0 0 -0.01 0 0 {-b.forearm + 0.02}"
                size="0.025" material="robot"/>
          <geom name="{side}_hand" type="sphere" pos="0 0 {-b.forearm}" size="0.025"
                material="robot"/>
        </body>
      </body>""")
    return f"""<mujoco model="nao_like_humanoid">
  <compiler angle="radian"/>
  <visual><global offwidth="640" offheight="480"/></visual>
  <default><geom contype="0" conaffinity="0"/></default>
  <asset>
    <material name="robot" rgba="0.9 0.9 0.95 1"/>
    <material name="floor" rgba="0.5 0.45 0.4 1"/>
    <material name="wall" rgba="0.8 0.8 0.75 1"/>
  </asset>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 0.05" material="floor"/>
    <geom name="wall_px" type="box" pos="{cx + r} {cy} 1.25" size="0.05 {r} 1.25" material="wall"/>
    <geom name="wall_nx" type="box" pos="{cx - r} {cy} 1.25" size="0.05 {r} 1.25" material="wall"/>
    <geom name="wall_py" type="box" pos="{cx} {cy + r} 1.25" size="{r} 0.05 1.25" material="wall"/>
    <geom name="wall_ny" type="box" pos="{cx} {cy - r} 1.25" size="{r} 0.05 1.25" material="wall"/>
    <camera name="zenithal" pos="{cx} {cy} {cz}" xyaxes="1 0 0 0 1 0" fovy="{fovy_deg}"/>
    <body name="torso" pos="0 0 {leg_length}">
      <freejoint name="root"/>
      <geom name="pelvis" type="box" pos="0 0 0.02" size="0.04 0.07 0.035" material="robot"/>
      <geom name="chest" type="box" pos="0 0 0.125" size="0.045 0.075 0.07" material="robot"/>
      <body name="head" pos="0 0 {b.pelvis_to_neck}">
        <joint name="head_yaw" axis="0 0 1"/>
        <geom name="neck" type="capsule" fromto="0 0 0 0 0 0.02" size="0.02" material="robot"/>
        <geom name="head" type="ellipsoid" pos="0 0 {hz + 0.005}" size="{hx} {hy} {hz}"
              material="robot"/>
      </body>{''.join(legs)}
    </body>
  </worldbody>
</mujoco>
"""


def build(width: int = 80, height: int = 60, camera_height: float = 2.8,
          camera_xy=(0.5, 0.5), body: Body = Body(), fov_deg=(57.0, 43.0),
          knee_bend: float = 0.35) -> Scene:
    """Build the scene: MJCF -> ``mujoco.MjModel`` -> ``mjx.Model``, plus the camera.

    Args:
      width, height: depth image resolution (80 x 60 by default; Kinect 640 x 480).
      camera_height: camera height above the floor (2.5-3 m).
      camera_xy: camera (x, y) above the floor (centre of the workspace).
      body: `Body` dimensions.
      fov_deg: (horizontal, vertical) field of view; Kinect 57 x 43 deg.
      knee_bend: knee angle (rad) of the standing / walking posture (sets ``standing_height``).

    Example:
      >>> scene = build(16, 12)
    """
    if width < 2 or height < 2:
        raise ValueError(f"resolution must be at least 2 x 2; got {width} x {height}")
    if not 1.0 <= camera_height <= 5.0:
        raise ValueError(f"camera_height must be in [1, 5] m; got {camera_height}")
    hfov, vfov = fov_deg
    xml = mjcf(body, (camera_xy[0], camera_xy[1], camera_height), vfov)
    model = mujoco.MjModel.from_xml_string(xml)
    # On this process's own device: MJX defaults to jax.devices()[0], which in a multi-process
    # run belongs to process 0 only (and a closure over it cannot be compiled elsewhere).
    mx = mjx.put_model(model, device=jax.local_devices()[0])
    cam = Camera((float(camera_xy[0]), float(camera_xy[1]), float(camera_height)), int(width),
                 int(height), (width / 2.0) / math.tan(math.radians(hfov) / 2.0),
                 (height / 2.0) / math.tan(math.radians(vfov) / 2.0))
    torso = model.body("torso").id
    robot_body = np.array([model.body_rootid[model.geom_bodyid[g]] == torso
                           for g in range(model.ngeom)])
    robot_geoms = np.nonzero(robot_body)[0]
    static_geoms = np.nonzero(~robot_body)[0]

    def adr(name):
        return int(model.jnt_qposadr[model.joint(name).id])

    leg_qpos = np.array([[adr(f"{s}_{j}") for j in LEG_JOINTS] for s in ("l", "r")])
    arm_qpos = np.array([[adr(f"{s}_{j}") for j in ARM_JOINTS] for s in ("l", "r")])
    # Standing posture: knees bent by knee_bend, hip and ankle pitch compensating.
    a, b = body.thigh, body.shin
    leg = math.sqrt(a * a + b * b + 2 * a * b * math.cos(knee_bend))
    return Scene(model, mx, cam, body, robot_geoms, static_geoms, leg_qpos, arm_qpos,
                 adr("head_yaw"), leg + body.ankle_height)


def pose_geoms(scene: Scene, qpos: Array) -> tuple[Array, Array]:
    """World poses of every geom for a configuration, by ``mjx.kinematics``.

    Args:
      scene: `Scene`.
      qpos: [nq] generalised coordinates (free joint position + quaternion, then hinges).

    Returns:
      ``(geom_xpos [ngeom, 3], geom_xmat [ngeom, 3, 3])``.

    Example:
      >>> xpos, xmat = pose_geoms(scene, jnp.asarray(scene.model.qpos0))
    """
    if jnp.shape(qpos) != (scene.model.nq,):
        raise ValueError(f"qpos must be [{scene.model.nq}]; got {list(jnp.shape(qpos))}")
    data = mjx.make_data(scene.mjx_model)
    data = data.replace(qpos=jnp.asarray(qpos, data.qpos.dtype))
    data = mjx.kinematics(scene.mjx_model, data)
    return data.geom_xpos, data.geom_xmat


def camera_rays(camera: Camera, dtype=jnp.float32) -> tuple[Array, Array]:
    """Unit ray directions of every pixel and their optical-axis cosines.

    Pixel (i, j) (row i from the top, column j from the left) looks along
    :math:`d \\propto ((j + 1/2 - c_x)/f_x,\\ -(i + 1/2 - c_y)/f_y,\\ -1)`.

    Returns:
      ``(directions [H, W, 3], cosines [H, W])``; depth = distance * cosine.
    """
    j = jnp.arange(camera.width, dtype=dtype) + 0.5
    i = jnp.arange(camera.height, dtype=dtype) + 0.5
    u = (j - camera.cx) / camera.fx
    v = -(i - camera.cy) / camera.fy
    uu, vv = jnp.meshgrid(u, v)
    d = jnp.stack([uu, vv, -jnp.ones_like(uu)], -1)
    norm = jnp.linalg.norm(d, axis=-1)
    return d / norm[..., None], 1.0 / norm
