r"""The person-following scene (seed 004): a unicycle robot in a furnished room among people.

- The robot is a box (``robot_size``, 0.5 x 0.4 x 0.3 m by default) on three planar joints (slide
  x, slide y, hinge z) driven by three velocity actuators; a unicycle command :math:`(v, \omega)`
  becomes world-frame joint velocities (`robot_step`) and MJX integrates the physics
  (``implicitfast``: the stiff velocity servos are integrated implicitly, so ``dt`` = 0.05 s is
  stable). With ``contacts=True`` a collision sphere of ``robot_radius`` touches the walls and
  the furniture legs (the only contacts: frictionless, one row each); gravity is off (no
  vertical freedom).
- The room (``room`` = width x depth, centred at the origin) has four walls and, with
  ``furniture=True``, two tables (1.2 x 0.8 m) each with two chairs (0.45 x 0.45 m). Their legs
  are thin vertical capsules (radius 4 cm for tables, 2.5 cm for chairs; capsules rather than
  cylinders so ``mjx.ray`` sees them), which a laser at shin height cannot tell from a person's
  legs. Table tops and seats are above the laser plane.
- ``num_people`` people are mocap bodies: a torso capsule with a head sphere, and two leg
  capsules, each leg its own mocap body. They are kinematic (no contacts), posed from the
  pedestrian state by `set_people` (legs by `leg_capsules`, torso sway by
  `sims.following.pedestrians.torso_position`); inactive people are parked below the floor.

Every geom is a primitive ``mjx.ray`` handles and carries a material. The laser plane's static
geometry is exported as plain arrays (`Scene.furniture_circles`, `Scene.wall_segments`), and the
people's legs as capsules (`leg_capsules`), for analytic ray casting.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from jaxtrack import _checks
from sims.following import layout as layout_mod
from sims.following import pedestrians
from sims.following.pedestrians import GaitParams, PedestrianConfig, PedestrianState

Array = jax.Array

__all__ = ["Scene", "mjcf", "build", "reset", "robot_step", "robot_pose", "set_people",
           "leg_capsules", "pedestrian_config", "furniture_layout", "unicycle_velocity",
           "kinematics"]

leg_capsules = pedestrians.leg_capsules

_TABLE = dict(size=(1.2, 0.8), height=0.75, leg_radius=0.04, inset=0.06)
_CHAIR = dict(size=(0.45, 0.45), height=0.45, leg_radius=0.025, inset=0.03, offset=0.7)
_WALL_HEIGHT = 1.0
_WALL_THICKNESS = 0.1


def furniture_layout(room=(10.0, 8.0)) -> list[dict]:
    """Tables and chairs of a room (`sims.following.layout.room`): dicts with ``kind``,
    ``centre`` (x, y), ``size``, ``height``, ``leg_radius`` and ``legs`` [4, 2] leg centres."""
    return list(layout_mod.room(room).furniture)


def _footprints(items) -> np.ndarray:
    """One disc per table group (table + chairs) or display: [F, 3] (x, y, radius)."""
    tables = [it for it in items if it["kind"] in ("table", "display")]
    out = []
    for t in tables:
        group = [it for it in items if np.linalg.norm(it["centre"] - t["centre"]) < 1.5]
        r = max(np.linalg.norm(np.asarray(it["centre"]) - t["centre"])
                + 0.5 * math.hypot(*it["size"]) for it in group)
        out.append([t["centre"][0], t["centre"][1], r])
    return np.asarray(out, np.float64).reshape(-1, 3)


@dataclasses.dataclass(frozen=True, eq=False)
class Scene:
    """A built scene (static: closed over by jitted functions, never traced).

    Attributes:
      model: the ``mujoco.MjModel``; mjx_model: its ``mjx.Model``.
      room: (width, depth) of the room centred at the origin (m).
      dt: physics time step (s).
      num_people: capacity ``P`` of people (mocap bodies).
      gait: `GaitParams` of the people (leg radius, leg length, sway...).
      robot_radius: radius of the robot's collision sphere (m).
      torso_mocap: [P] mocap ids of the torsos; leg_mocap: [P, 2] of the left / right legs.
      robot_geom: id of the robot's collision sphere.
      physics_model: the ``mjx.Model`` `robot_step` integrates: the robot alone (plus the walls
        and furniture with contacts). The people are kinematic and, without contacts, nothing
        else acts on the robot, so leaving them out gives the same motion for a fraction of the
        cost (``mjx.step`` would otherwise pose 25 bodies and 70 geoms at every sub-step).
      furniture: tuple of furniture dicts (on legs), empty without furniture.
      footprints: [F, 3] discs (x, y, radius) around each table and its chairs, or display.
      physics_model: see above.
      layout: the `sims.following.layout.Layout` (its blocks: shelves, end caps, counters).
    """

    model: mujoco.MjModel
    mjx_model: mjx.Model
    room: tuple
    dt: float
    num_people: int
    gait: GaitParams
    robot_radius: float
    torso_mocap: np.ndarray
    leg_mocap: np.ndarray
    robot_geom: int
    furniture: tuple
    footprints: np.ndarray
    physics_model: mjx.Model
    layout: layout_mod.Layout = None

    @property
    def blocks(self) -> tuple:
        """Solid boxes (shelves, end caps, counters) of the layout; empty in the room."""
        return () if self.layout is None else self.layout.blocks

    @property
    def leg_radius(self) -> float:
        """Radius of the people's leg capsules (m)."""
        return float(self.gait.leg_radius)

    @property
    def leg_height(self) -> float:
        """Height of the top of a standing person's leg capsule (hip + radius, m)."""
        return float(self.gait.leg_length + 2.0 * self.gait.leg_radius)

    def furniture_circles(self) -> tuple[np.ndarray, np.ndarray]:
        """Cross-sections of the furniture legs in any horizontal plane below 0.45 m.

        Returns:
          ``(centres [C, 2], radii [C])`` (C = 24 with the default furniture, 0 without).
        """
        if not self.furniture:
            return np.zeros((0, 2)), np.zeros((0,))
        centres = np.concatenate([it["legs"] for it in self.furniture], 0)
        radii = np.concatenate([np.full(4, it["leg_radius"]) for it in self.furniture])
        return centres, radii

    def wall_segments(self) -> np.ndarray:
        """Inner faces of the four walls, then the edges of the blocks, as segments
        [4 + 4 B, 2, 2] (start, end) x (x, y)."""
        hw, hh = 0.5 * self.room[0], 0.5 * self.room[1]
        corners = np.array([[hw, -hh], [hw, hh], [-hw, hh], [-hw, -hh]])
        walls = np.stack([corners, np.roll(corners, -1, axis=0)], 1)
        if not self.blocks:
            return walls
        return np.concatenate([walls, layout_mod.block_segments(self.blocks)], 0)


def mjcf(num_people: int = 8, room=(10.0, 8.0), furniture: bool = True, dt: float = 0.05,
         contacts: bool = False, gait: GaitParams = GaitParams(),
         robot_size=(0.5, 0.4, 0.3), robot_radius: float = 0.3, robot_mass: float = 20.0,
         servo_rate: float = 1000.0, room_geoms: bool = True,
         layout: layout_mod.Layout | None = None) -> str:
    """The scene's MJCF string (robot at the origin facing +x, people parked below the floor).

    Args:
      servo_rate: velocity servo gain per unit mass (1/s): ``kv`` = rate x mass (x inertia for
        the hinge). 1000/s tracks a velocity step within one 0.05 s step to 2 %.
      room_geoms: include the floor, walls and furniture (`build`'s physics-only model leaves
        them out when they cannot touch the robot).
      layout: the floor plan (`sims.following.layout`); default the room of size ``room``.
      The other arguments are `build`'s.

    Example:
      >>> xml = mjcf(2, furniture=False)
    """
    W, H = room
    hw, hh, t = 0.5 * W, 0.5 * H, 0.5 * _WALL_THICKNESS
    wz = 0.5 * _WALL_HEIGHT
    bx, by, bz = (0.5 * s for s in robot_size)
    izz = robot_mass * (robot_size[0] ** 2 + robot_size[1] ** 2) / 12.0
    static = "contype=\"0\" conaffinity=\"1\"" if contacts else ""
    walls = f"""
    <geom name="wall_px" type="box" pos="{hw + t} 0 {wz}" size="{t} {hh + 2 * t} {wz}" material="wall" {static}/>
    <geom name="wall_nx" type="box" pos="{-hw - t} 0 {wz}" size="{t} {hh + 2 * t} {wz}" material="wall" {static}/>
    <geom name="wall_py" type="box" pos="0 {hh + t} {wz}" size="{hw} {t} {wz}" material="wall" {static}/>
    <geom name="wall_ny" type="box" pos="0 {-hh - t} {wz}" size="{hw} {t} {wz}" material="wall" {static}/>"""
    furn = []
    lay = layout_mod.room(room) if layout is None else layout
    if not room_geoms:
        walls = ""
    if room_geoms:
        for i, b in enumerate(lay.blocks):
            (cx, cy), (sx, sy), h = b["centre"], b["size"], b["height"]
            furn.append(f'    <geom name="{b["kind"]}{i}" type="box" pos="{cx} {cy} {0.5 * h}" '
                        f'size="{0.5 * sx} {0.5 * sy} {0.5 * h}" material="shelf" {static}/>')
    if furniture and room_geoms:
        for i, it in enumerate(lay.furniture):
            r, h = it["leg_radius"], it["height"]
            top = 0.02
            for j, (lx, ly) in enumerate(it["legs"]):
                furn.append(f'    <geom name="{it["kind"]}{i}_leg{j}" type="capsule" '
                            f'fromto="{lx} {ly} {r} {lx} {ly} {h - top - r}" size="{r}" '
                            f'material="wood" {static}/>')
            cx, cy = it["centre"]
            furn.append(f'    <geom name="{it["kind"]}{i}_top" type="box" pos="{cx} {cy} {h - top}" '
                        f'size="{0.5 * it["size"][0]} {0.5 * it["size"][1]} {top}" material="wood"/>')
    g = gait
    torso_half = 0.5 * (g.torso_top - g.torso_bottom)
    people = []
    for p in range(num_people):
        people.append(f"""
    <body name="person{p}_torso" mocap="true" pos="{p} 0 {pedestrians.PARK_DEPTH}">
      <geom name="person{p}_torso" type="capsule" fromto="0 0 {-torso_half} 0 0 {torso_half}"
            size="{g.torso_radius}" material="person"/>
      <geom name="person{p}_head" type="sphere" pos="0 0 {torso_half + g.torso_radius + 0.12}"
            size="0.11" material="skin"/>
    </body>""")
        for s, side in enumerate(("l", "r")):
            people.append(f"""
    <body name="person{p}_{side}_leg" mocap="true" pos="{p} {s} {pedestrians.PARK_DEPTH}">
      <geom name="person{p}_{side}_leg" type="capsule" size="{g.leg_radius} {0.5 * g.leg_length}"
            material="trousers"/>
    </body>""")
    flags = '<flag gravity="disable"/>' if contacts else \
        '<flag gravity="disable" contact="disable" constraint="disable"/>'
    kv = servo_rate * robot_mass
    return f"""<mujoco model="person_following">
  <compiler angle="radian"/>
  <option timestep="{dt}" integrator="implicitfast" iterations="2" ls_iterations="4">
    {flags}
  </option>
  <default><geom contype="0" conaffinity="0" condim="1"/></default>
  <asset>
    <material name="floor" rgba="0.55 0.5 0.45 1"/>
    <material name="wall" rgba="0.85 0.85 0.8 1"/>
    <material name="wood" rgba="0.6 0.4 0.25 1"/>
    <material name="shelf" rgba="0.75 0.75 0.7 1"/>
    <material name="robot" rgba="0.2 0.3 0.8 1"/>
    <material name="person" rgba="0.8 0.3 0.3 1"/>
    <material name="skin" rgba="0.9 0.75 0.6 1"/>
    <material name="trousers" rgba="0.2 0.2 0.3 1"/>
  </asset>
  <worldbody>
    {'<geom name="floor" type="plane" size="%g %g 0.05" material="floor"/>' % (hw + 1, hh + 1) if room_geoms else ''}{walls}
{chr(10).join(furn)}
    <body name="robot">
      <joint name="robot_x" type="slide" axis="1 0 0"/>
      <joint name="robot_y" type="slide" axis="0 1 0"/>
      <joint name="robot_yaw" type="hinge" axis="0 0 1"/>
      <inertial pos="0 0 {bz}" mass="{robot_mass}" diaginertia="{izz} {izz} {izz}"/>
      <geom name="robot_body" type="box" pos="0 0 {bz + 0.05}" size="{bx} {by} {bz}"
            material="robot"/>
      <geom name="robot_collision" type="sphere" pos="0 0 {robot_radius}" size="{robot_radius}"
            rgba="0 0 0 0" {'contype="1" conaffinity="0"' if contacts else ''}/>
    </body>{''.join(people)}
  </worldbody>
  <actuator>
    <velocity name="robot_vx" joint="robot_x" kv="{kv}"/>
    <velocity name="robot_vy" joint="robot_y" kv="{kv}"/>
    <velocity name="robot_wz" joint="robot_yaw" kv="{servo_rate * izz}"/>
  </actuator>
</mujoco>
"""


def build(num_people: int = 8, room=(10.0, 8.0), furniture: bool = True, dt: float = 0.05,
          contacts: bool = False, gait: GaitParams = GaitParams(), robot_size=(0.5, 0.4, 0.3),
          robot_radius: float = 0.3, layout: "str | layout_mod.Layout" = "room") -> Scene:
    """Build the scene: MJCF -> ``mujoco.MjModel`` -> ``mjx.Model``, plus the laser geometry.

    Args:
      num_people: capacity of people (mocap bodies), 1-16.
      room: (width along x, depth along y) in metres, centred at the origin.
      furniture: two tables with two chairs each (needs a room of at least 6 x 5 m).
      dt: physics time step (0.02-0.05 s); `robot_step` runs ``round(0.1 / dt)`` sub-steps per
        10 Hz control period by default.
      contacts: robot-wall and robot-furniture-leg contacts. Off by default (no constraints at
        all): with them ``mjx.step`` compiles for minutes on a 2-core CPU; the controllers' safety
        stop keeps the robot off walls and furniture anyway.
      gait: `GaitParams` of the people.
      robot_size: (length, width, height) of the robot's box (m).
      robot_radius: radius of its collision sphere (m).
      layout: "room" (a ``room``-sized room, with two tables and four chairs when
        ``furniture``) or "shop" (`sims.following.layout.shop`: its own size, shelves, counter
        and displays; ``room`` and ``furniture`` are ignored), or a
        `sims.following.layout.Layout` (its own size, blocks and furniture; e.g. the flat of
        `sims.service.flat`).

    Example:
      >>> scene = build(num_people=4, layout="shop")
    """
    if isinstance(layout, layout_mod.Layout):
        lay = layout
        room, furniture = lay.room, True
    elif layout not in layout_mod.LAYOUTS:
        raise ValueError(f"unknown layout {layout!r}; choose one of {layout_mod.LAYOUTS}")
    elif layout == "shop":
        lay = layout_mod.shop()
        room, furniture = lay.room, True
    else:
        lay = layout_mod.room(tuple(float(x) for x in room))
    if not 1 <= int(num_people) <= 16:
        raise ValueError(f"num_people must be in [1, 16]; got {num_people}")
    W, H = (float(x) for x in room)
    if W < 3.0 or H < 3.0 or (furniture and (W < 6.0 or H < 5.0)):
        raise ValueError(f"room {tuple(room)} is too small (at least 3 x 3 m, 6 x 5 m with "
                         f"furniture)")
    if not 0.005 <= dt <= 0.05:
        raise ValueError(f"dt must be in [0.005, 0.05] s; got {dt}")
    xml = mjcf(int(num_people), (W, H), furniture, dt, contacts, gait, robot_size, robot_radius,
               layout=lay)
    model = mujoco.MjModel.from_xml_string(xml)
    # On this process's own device: MJX defaults to jax.devices()[0], which in a multi-process
    # run belongs to process 0 only (and a closure over it cannot be compiled elsewhere).
    mx = mjx.put_model(model, device=jax.local_devices()[0])
    torso = np.array([model.body_mocapid[model.body(f"person{p}_torso").id]
                      for p in range(num_people)])
    legs = np.array([[model.body_mocapid[model.body(f"person{p}_{s}_leg").id] for s in "lr"]
                     for p in range(num_people)])
    items = tuple(lay.furniture) if furniture else ()
    physics = mujoco.MjModel.from_xml_string(
        mjcf(0, (W, H), furniture, dt, contacts, gait, robot_size, robot_radius,
             room_geoms=contacts, layout=lay))
    assert (physics.nq, physics.nv, physics.nu) == (model.nq, model.nv, model.nu)
    return Scene(model, mx, (W, H), float(dt), int(num_people), gait, float(robot_radius),
                 torso, legs, model.geom("robot_collision").id, items, _footprints(items),
                 mjx.put_model(physics, device=jax.local_devices()[0]), lay)


def pedestrian_config(scene: Scene, **overrides) -> PedestrianConfig:
    """A `PedestrianConfig` for the scene's room, furniture footprints, blocks and aisles, robot
    and gait.

    Example:
      >>> cfg = pedestrian_config(scene, distractors=4)
    """
    kw = dict(room=scene.room, obstacles=np.asarray(scene.footprints),
              robot_radius=scene.robot_radius, gait=scene.gait)
    if scene.layout is not None and scene.layout.blocks:
        kw.update(boxes=scene.layout.boxes(), aisles=scene.layout.aisles)
    kw.update(overrides)
    return PedestrianConfig(**kw)


def _leg_quaternions(p0, p1):
    """Quaternions [..., 4] (w, x, y, z) turning +z onto p1 - p0 (the half-way formula)."""
    d = p1 - p0
    d = d / jnp.linalg.norm(d, axis=-1, keepdims=True)
    q = jnp.stack([1.0 + d[..., 2], -d[..., 1], d[..., 0], jnp.zeros_like(d[..., 0])], -1)
    return q / jnp.linalg.norm(q, axis=-1, keepdims=True)


def set_people(scene: Scene, data: mjx.Data, people_state: PedestrianState) -> mjx.Data:
    """Write the people's torso and leg mocap poses from the pedestrian state.

    Legs are the capsules of `leg_capsules` (body at the capsule's midpoint, local z along the
    leg); torsos are at `sims.following.pedestrians.torso_position`, turned to the heading.
    Body and geom poses (``xpos``, ``geom_xpos``) follow from `kinematics`.

    Args:
      scene: `Scene` with capacity ``P``.
      data: ``mjx.Data``.
      people_state: `PedestrianState` with ``P`` people.

    Returns:
      ``data`` with new ``mocap_pos`` / ``mocap_quat``.

    Example:
      >>> data = set_people(scene, data, state)
    """
    P = scene.num_people
    _checks.check_shape("people_state.pos", people_state.pos, (P, 2),
                        f"the scene holds {P} people")
    dtype = data.mocap_pos.dtype
    p0, p1, _ = leg_capsules(people_state, scene.gait)
    torso = pedestrians.torso_position(people_state, scene.gait)
    h = 0.5 * people_state.heading
    yaw = jnp.stack([jnp.cos(h), jnp.zeros_like(h), jnp.zeros_like(h), jnp.sin(h)], -1)
    pos = data.mocap_pos.at[scene.torso_mocap].set(torso.astype(dtype))
    pos = pos.at[scene.leg_mocap].set((0.5 * (p0 + p1)).astype(dtype))
    quat = data.mocap_quat.at[scene.torso_mocap].set(yaw.astype(dtype))
    quat = quat.at[scene.leg_mocap].set(_leg_quaternions(p0, p1).astype(dtype))
    return data.replace(mocap_pos=pos, mocap_quat=quat)


def reset(scene: Scene, robot_pose: Array, people_state: PedestrianState | None = None,
          dtype=None) -> mjx.Data:
    """Fresh ``mjx.Data`` with the robot at ``robot_pose`` [3] (at rest) and the people posed.

    Only ``qpos`` and the mocap poses are set; body and geom poses follow from `kinematics`.

    Example:
      >>> data = reset(scene, jnp.array([0.0, 0.0, 0.0]), state)
    """
    _checks.check_shape("robot_pose", robot_pose, (3,), "x, y, theta")
    data = mjx.make_data(scene.mjx_model)
    dtype = data.qpos.dtype if dtype is None else dtype
    data = data.replace(qpos=jnp.asarray(robot_pose, dtype))
    if people_state is not None:
        data = set_people(scene, data, people_state)
    return data


def unicycle_velocity(theta: Array, u: Array, dt) -> Array:
    r"""World-frame joint velocities [3] that move a unicycle along its exact arc over ``dt``.

    The chord of the arc :math:`(v, \omega)` over :math:`dt` has heading
    :math:`\theta + \omega dt / 2` and length :math:`v\,dt\,\mathrm{sinc}(\omega dt / 2)`, so
    :math:`(\dot x, \dot y) = v\,\mathrm{sinc}(\omega dt/2)(\cos, \sin)(\theta + \omega dt/2)`,
    :math:`\dot\theta = \omega`.
    """
    v, w = u[0], u[1]
    half = 0.5 * w * dt
    speed = v * jnp.sinc(half / jnp.pi)
    a = theta + half
    return jnp.stack([speed * jnp.cos(a), speed * jnp.sin(a), w])


def robot_step(scene: Scene, data: mjx.Data, u: Array, substeps: int | None = None) -> mjx.Data:
    """Drive the robot by a unicycle command for one control period (``substeps`` MJX steps).

    At every sub-step the velocity actuators get `unicycle_velocity` for the current heading,
    then ``mjx.step`` integrates ``scene.physics_model`` (contacts with walls and furniture legs
    included when the scene has them). ``qpos``, ``qvel``, ``ctrl`` and ``time`` of ``data`` are
    updated; body and geom poses of the full scene are refreshed by `kinematics` (the laser
    caster works on `leg_capsules` and the exported geometry and does not need them).

    Args:
      scene: `Scene`.
      data: ``mjx.Data`` (people mocaps as set by `set_people`).
      u: [2] command (v m/s forward, omega rad/s).
      substeps: physics steps per call; default ``round(0.1 / scene.dt)`` (a 10 Hz period).

    Returns:
      The new ``mjx.Data``.

    Example:
      >>> data = robot_step(scene, data, jnp.array([0.8, 0.3]))
    """
    _checks.check_shape("u", u, (2,), "v, omega")
    n = max(1, round(0.1 / scene.dt)) if substeps is None else int(substeps)
    if n < 1:
        raise ValueError(f"substeps must be at least 1; got {substeps}")
    u = jnp.asarray(u, data.qpos.dtype)
    phys = mjx.make_data(scene.physics_model)
    phys = phys.replace(qpos=data.qpos.astype(phys.qpos.dtype),
                        qvel=data.qvel.astype(phys.qvel.dtype), time=data.time)

    def body(d, _):
        d = d.replace(ctrl=unicycle_velocity(d.qpos[2], u, scene.dt).astype(d.ctrl.dtype))
        return mjx.step(scene.physics_model, d), None

    phys = jax.lax.scan(body, phys, None, length=n)[0]
    return data.replace(qpos=phys.qpos.astype(data.qpos.dtype),
                        qvel=phys.qvel.astype(data.qvel.dtype),
                        ctrl=phys.ctrl.astype(data.ctrl.dtype), time=phys.time)


def kinematics(scene: Scene, data: mjx.Data) -> mjx.Data:
    """Body and geom poses of the whole scene (robot and mocap people) by ``mjx.kinematics``,
    e.g. before ``mjx.ray`` or rendering.

    Example:
      >>> data = kinematics(scene, set_people(scene, data, state))
    """
    return mjx.kinematics(scene.mjx_model, data)


def robot_pose(data: mjx.Data) -> Array:
    """Robot pose [3] (x, y, theta wrapped to [-pi, pi)) from ``data.qpos``."""
    q = data.qpos
    return jnp.stack([q[0], q[1], jnp.mod(q[2] + jnp.pi, 2.0 * jnp.pi) - jnp.pi])
