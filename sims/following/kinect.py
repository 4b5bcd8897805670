r"""A robot-mounted Kinect v1, rendered analytically in pure `jax.numpy` (seed 001's sensor).

Every pixel's ray is intersected in closed form with the scene's primitives, the way
`sims.humanoid.sensor` renders the ceiling camera: capsules (legs, torso, arms, the head as a
zero-length capsule, table and chair legs), boxes turned about z (shelves, table tops, seats,
walls) and the floor plane z = 0. The nearest hit gives the pixel's depth (along the optical
axis) and colour. The clean render is differentiable almost everywhere in the primitives and the
camera pose.

Geometry: 57 x 43 deg, 0.5-4.5 m, QVGA 320 x 240 by default (VGA 640 x 480, or seed 001's
160 x 120, by ``width``/``height``); the camera sits ``mount`` ahead of and above the robot's
base (about 1.1 m high) and is tilted down by ``tilt``; it may pan. Optical frame: x right,
y down, z forward.

The measurement (`measure`) adds what a Kinect v1 does to a depth image (Khoshelham and Elberink
2012, "Accuracy and resolution of Kinect depth data for indoor mapping applications"):

- **noise** growing with the square of the range, :math:`\sigma_z = 1.425 \cdot 10^{-3} z^2`;
- **quantisation** of the disparity: depth is :math:`K / \mathrm{round}(K / z)` with
  :math:`K = 351` m, a depth step of :math:`2.85 \cdot 10^{-3} z^2` (their resolution figure);
- **dropout** at depth edges: a pixel whose 4-neighbourhood spans more than ``edge_jump`` in
  depth is lost with probability ``edge_dropout`` (the projector's shadow and mixed pixels);
- **range**: no depth outside [``min_range``, ``max_range``].

Example:
  >>> cfg = KinectConfig()
  >>> eye, rot = camera_pose(cfg, robot_pose)
  >>> frame = render(cfg, eye, rot, primitives)
  >>> depth, valid = measure(key, cfg, frame.depth)
  >>> points, ok = point_cloud(cfg, depth, valid, *mount_pose(cfg))   # robot base frame
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from sims.following import pedestrians
from sims.following.layout import Layout

Array = jax.Array

__all__ = ["KinectConfig", "Primitives", "Frame", "camera_pose", "mount_pose", "rays",
           "render", "measure", "point_cloud", "people_primitives", "layout_primitives",
           "concat", "CLOTHING"]

# Shirt, trousers and skin colours (RGB in [0, 1]) the simulated people wear.
CLOTHING = np.array([
    [[0.80, 0.10, 0.10], [0.15, 0.15, 0.35], [0.85, 0.65, 0.50]],
    [[0.10, 0.45, 0.80], [0.25, 0.20, 0.15], [0.55, 0.38, 0.26]],
    [[0.95, 0.85, 0.20], [0.10, 0.10, 0.10], [0.90, 0.72, 0.60]],
    [[0.15, 0.60, 0.25], [0.40, 0.40, 0.45], [0.45, 0.30, 0.20]],
    [[0.90, 0.90, 0.90], [0.20, 0.25, 0.55], [0.80, 0.60, 0.45]],
    [[0.55, 0.20, 0.60], [0.60, 0.50, 0.35], [0.70, 0.50, 0.35]],
    [[0.95, 0.50, 0.10], [0.05, 0.05, 0.20], [0.85, 0.70, 0.55]],
    [[0.30, 0.30, 0.30], [0.70, 0.65, 0.55], [0.60, 0.42, 0.30]],
])


@dataclasses.dataclass(frozen=True)
class KinectConfig:
    r"""The camera (static: a `jit` static argument).

    Attributes:
      width, height: image size (pixels); QVGA 320 x 240.
      fov_x, fov_y: field of view (rad); 57 and 43 deg.
      min_range, max_range: depth range (m); 0.5 and 4.5.
      mount: (forward, left, up) of the camera's centre from the robot's base (m); 1.1 m up.
      tilt: downward pitch (rad); 5 deg puts both the floor beyond 2.2 m and the heads of
        1.8 m people beyond 2.2 m in view.
      depth_noise: :math:`\sigma_z / z^2` (1/m); 1.425e-3.
      disparity_constant: K (m); 351.
      edge_jump: depth span of a pixel's neighbourhood that makes it an edge pixel (m).
      edge_dropout: probability of losing an edge pixel.
      noise, quantise: apply the noise and the quantisation (off: a clean depth image).
    """

    width: int = 320
    height: int = 240
    fov_x: float = math.radians(57.0)
    fov_y: float = math.radians(43.0)
    min_range: float = 0.5
    max_range: float = 4.5
    mount: tuple[float, float, float] = (0.1, 0.0, 1.1)
    tilt: float = math.radians(5.0)
    depth_noise: float = 1.425e-3
    disparity_constant: float = 351.0
    edge_jump: float = 0.1
    edge_dropout: float = 0.5
    noise: bool = True
    quantise: bool = True

    def __post_init__(self):
        for name in ("width", "height"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1):
                raise ValueError(f"KinectConfig.{name} must be a positive integer; got {value!r}")
        for name in ("fov_x", "fov_y"):
            value = getattr(self, name)
            if not 0 < value < math.pi:
                raise ValueError(f"KinectConfig.{name} must lie in (0, pi); got {value!r}")
        if not 0 <= self.min_range < self.max_range:
            raise ValueError("KinectConfig needs 0 <= min_range < max_range; got "
                             f"{self.min_range}, {self.max_range}")
        if not 0 <= self.edge_dropout <= 1:
            raise ValueError(f"KinectConfig.edge_dropout must be a probability; "
                             f"got {self.edge_dropout}")

    @property
    def focal(self) -> tuple[float, float]:
        """(fx, fy) in pixels."""
        return (0.5 * self.width / math.tan(0.5 * self.fov_x),
                0.5 * self.height / math.tan(0.5 * self.fov_y))


class Primitives(NamedTuple):
    """A scene as primitives (world frame, metres, RGB in [0, 1]).

    Attributes:
      capsule_a, capsule_b: [Nc, 3] end points (equal for a sphere).
      capsule_radius: [Nc] (0 hides a capsule).
      capsule_colour: [Nc, 3].
      box_centre: [Nb, 3]; box_half: [Nb, 3] half sizes (0 hides a box); box_yaw: [Nb] turn
        about z; box_colour: [Nb, 3].
      floor_colour: [3] the plane z = 0.
    """

    capsule_a: Array
    capsule_b: Array
    capsule_radius: Array
    capsule_colour: Array
    box_centre: Array
    box_half: Array
    box_yaw: Array
    box_colour: Array
    floor_colour: Array


class Frame(NamedTuple):
    """A clean render: ``depth`` [H, W] along the optical axis (inf: no hit), ``colour``
    [H, W, 3], ``hit`` [H, W] int32 (capsules 0..Nc-1, boxes Nc.., floor Nc+Nb, -1 none)."""

    depth: Array
    colour: Array
    hit: Array


def mount_pose(cfg: KinectConfig, pan=0.0, dtype=jnp.float32) -> tuple[Array, Array]:
    """The camera in the robot's base frame: position [3] and rotation [3, 3] whose columns
    are the optical axes (x right, y down, z forward) in the base frame (x forward, z up)."""
    pan = jnp.asarray(pan, dtype)
    cp, sp = jnp.cos(pan), jnp.sin(pan)
    ct, st = math.cos(cfg.tilt), math.sin(cfg.tilt)
    forward = jnp.stack([cp * ct, sp * ct, jnp.asarray(-st, dtype)])
    right = jnp.stack([sp, -cp, jnp.zeros((), dtype)])
    down = jnp.cross(forward, right)
    return jnp.asarray(cfg.mount, dtype), jnp.stack([right, down, forward], -1)


def camera_pose(cfg: KinectConfig, robot_pose: Array, pan=0.0) -> tuple[Array, Array]:
    """The camera in the world frame for a robot at ``robot_pose`` (x, y, yaw): position [3]
    and rotation [3, 3] (columns: optical x, y, z in the world frame)."""
    robot_pose = jnp.asarray(robot_pose)
    dtype = robot_pose.dtype
    eye, rot = mount_pose(cfg, pan, dtype)
    c, s = jnp.cos(robot_pose[2]), jnp.sin(robot_pose[2])
    yaw = jnp.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype)
    return yaw @ eye + jnp.concatenate([robot_pose[:2], jnp.zeros(1, dtype)]), yaw @ rot


def rays(cfg: KinectConfig, rot: Array) -> Array:
    """[H, W, 3] unnormalised ray directions, optical z component 1 (so the depth is the ray
    parameter), rotated by ``rot``; pixel centres at (u + 0.5, v + 0.5)."""
    fx, fy = cfg.focal
    dtype = rot.dtype
    u = (jnp.arange(cfg.width, dtype=dtype) + 0.5 - 0.5 * cfg.width) / fx
    v = (jnp.arange(cfg.height, dtype=dtype) + 0.5 - 0.5 * cfg.height) / fy
    d = jnp.stack(jnp.broadcast_arrays(u[None, :], v[:, None], jnp.ones((), dtype)), -1)
    return d @ rot.T


def render(cfg: KinectConfig, eye: Array, rot: Array, prims: Primitives) -> Frame:
    r"""The clean depth and colour images (module docstring).

    Args:
      cfg: `KinectConfig`; eye: [3] camera position; rot: [3, 3] camera rotation (columns:
        optical axes), both in the primitives' frame (`camera_pose`); prims: `Primitives`.

    Returns:
      `Frame`. Depth is :math:`t` for the ray :math:`e + t\,d` with :math:`d_z^{opt} = 1`.
    """
    d = rays(cfg, rot).reshape(-1, 3)                                  # [R, 3]
    dtype = d.dtype
    t_cap = _capsules(eye, d, prims.capsule_a, prims.capsule_b, prims.capsule_radius)
    t_box = _boxes(eye, d, prims.box_centre, prims.box_half, prims.box_yaw)
    t_floor = jnp.where(d[:, 2] < -1e-9, -eye[2] / jnp.where(d[:, 2] < -1e-9, d[:, 2], -1.0),
                        jnp.inf)
    t_floor = jnp.where(t_floor > 0, t_floor, jnp.inf)
    t_all = jnp.concatenate([t_cap, t_box, t_floor[:, None]], 1)      # [R, Nc + Nb + 1]
    hit = jnp.argmin(t_all, axis=1)
    t = jnp.min(t_all, axis=1)
    colours = jnp.concatenate([prims.capsule_colour.astype(dtype), prims.box_colour.astype(dtype),
                               jnp.asarray(prims.floor_colour, dtype)[None]], 0)
    found = jnp.isfinite(t)
    colour = jnp.where(found[:, None], colours[hit], 0.0)
    shape = (cfg.height, cfg.width)
    return Frame(depth=t.reshape(shape), colour=colour.reshape(shape + (3,)),
                 hit=jnp.where(found, hit, -1).astype(jnp.int32).reshape(shape))


def measure(key: Array, cfg: KinectConfig, depth: Array) -> tuple[Array, Array]:
    """A Kinect's measurement of a clean depth image (module docstring).

    Args:
      key: PRNG key; cfg: `KinectConfig`; depth: [H, W] clean depth (inf: no return).

    Returns:
      (depth [H, W] with NaN where invalid, valid [H, W] bool).
    """
    k_noise, k_drop = jax.random.split(key)
    z = depth
    finite = jnp.isfinite(z)
    zf = jnp.where(finite, z, cfg.max_range)
    if cfg.noise:
        zf = zf + cfg.depth_noise * zf ** 2 * jax.random.normal(k_noise, z.shape, z.dtype)
    if cfg.quantise:
        k = cfg.disparity_constant
        zf = k / jnp.maximum(jnp.round(k / jnp.maximum(zf, 1e-3)), 1.0)
    valid = finite & (zf >= cfg.min_range) & (zf <= cfg.max_range)
    far = jnp.where(finite, z, 1e3)
    pad = jnp.pad(far, 1, mode="edge")
    neighbours = jnp.stack([pad[:-2, 1:-1], pad[2:, 1:-1], pad[1:-1, :-2], pad[1:-1, 2:]])
    span = jnp.maximum(jnp.max(neighbours, 0), far) - jnp.minimum(jnp.min(neighbours, 0), far)
    edge = span > cfg.edge_jump
    lost = edge & (jax.random.uniform(k_drop, z.shape, z.dtype) < cfg.edge_dropout)
    valid &= ~lost
    return jnp.where(valid, zf, jnp.nan), valid


def point_cloud(cfg: KinectConfig, depth: Array, valid: Array, eye: Array, rot: Array,
                colour: Array | None = None) -> tuple[Array, Array, Array]:
    """Back-project a depth image: points [H * W, 3] in the frame of (``eye``, ``rot``)
    (`mount_pose` for the robot's base frame), their mask [H * W] and colours [H * W, 3]."""
    d = rays(cfg, rot).reshape(-1, 3)
    z = jnp.where(valid, depth, 0.0).reshape(-1)
    pts = eye + z[:, None] * d
    rgb = jnp.zeros_like(pts) if colour is None else colour.reshape(-1, 3)
    return pts, valid.reshape(-1), rgb


# Body of a simulated person: heights (m) for a stature of 1.75 m, scaled by stature / 1.75.
_TORSO = (0.95, 1.38, 0.15)       # bottom, top, radius
_ARM = (0.80, 1.40, 0.045, 0.21)  # bottom, top, radius, sideways offset
_HEAD = (1.64, 0.105)             # centre height, radius
_STATURE = 1.75


def people_primitives(state: pedestrians.PedestrianState, stature: Array, clothing: Array,
                      params: pedestrians.GaitParams = pedestrians.GaitParams()) -> Primitives:
    """Capsules of every person: two legs (`pedestrians.leg_capsules`, in trousers), a torso
    and two arms (shirt, hands at the ends in skin colour are ignored), and a head (skin).

    Args:
      state: `PedestrianState` with P people (inactive people get radius 0).
      stature: [P] heights (m); the body above the legs scales with it.
      clothing: [P, 3, 3] shirt, trousers and skin RGB (`CLOTHING` rows).

    Returns:
      `Primitives` with 6 P capsules and no boxes.
    """
    dtype = state.pos.dtype
    P = state.pos.shape[0]
    s = (jnp.asarray(stature, dtype) / _STATURE)[:, None]
    a_leg, b_leg, r_leg = pedestrians.leg_capsules(state, params)
    torso = pedestrians.torso_position(state, params)[:, :2]
    heading = jnp.stack([jnp.cos(state.heading), jnp.sin(state.heading)], -1)
    left = jnp.stack([-heading[:, 1], heading[:, 0]], -1)
    on = state.mask[:, None]

    def at(xy, z):
        z = jnp.where(on, z, pedestrians.PARK_DEPTH)
        return jnp.concatenate([xy, z], -1)

    a_torso, b_torso = at(torso, _TORSO[0] * s), at(torso, _TORSO[1] * s)
    arms_a = [at(torso + sgn * _ARM[3] * left, _ARM[0] * s) for sgn in (1.0, -1.0)]
    arms_b = [at(torso + sgn * _ARM[3] * left, _ARM[1] * s) for sgn in (1.0, -1.0)]
    head = at(torso, _HEAD[0] * s)
    a = jnp.concatenate([a_leg[:, 0], a_leg[:, 1], a_torso, arms_a[0], arms_a[1], head])
    b = jnp.concatenate([b_leg[:, 0], b_leg[:, 1], b_torso, arms_b[0], arms_b[1], head])
    radius = jnp.concatenate([r_leg[:, 0], r_leg[:, 1],
                              jnp.full(P, _TORSO[2], dtype) * s[:, 0],
                              jnp.full(P, _ARM[2], dtype), jnp.full(P, _ARM[2], dtype),
                              jnp.full(P, _HEAD[1], dtype) * s[:, 0]])
    radius = radius * jnp.tile(state.mask, 6)
    cl = jnp.asarray(clothing, dtype)
    colour = jnp.concatenate([cl[:, 1], cl[:, 1], cl[:, 0], cl[:, 0], cl[:, 0], cl[:, 2]])
    empty3 = jnp.zeros((0, 3), dtype)
    return Primitives(a, b, radius, colour, empty3, empty3, jnp.zeros(0, dtype), empty3,
                      jnp.asarray([0.55, 0.5, 0.45], dtype))


def layout_primitives(layout: Layout, wall_height: float = 2.6,
                      dtype=jnp.float32) -> Primitives:
    """The static scene: four walls, the blocks (shelves, counters) as boxes, and the
    furniture on legs as a top box on four leg capsules (tables, chairs, displays; a chair
    gets a backrest)."""
    W, H = layout.room
    boxes = []                                                         # centre, half, colour
    t = 0.05
    wall = (0.85, 0.85, 0.8)
    for cx, cy, hx, hy in ((0, 0.5 * H + t, 0.5 * W, t), (0, -0.5 * H - t, 0.5 * W, t),
                           (0.5 * W + t, 0, t, 0.5 * H), (-0.5 * W - t, 0, t, 0.5 * H)):
        boxes.append(((cx, cy, 0.5 * wall_height), (hx, hy, 0.5 * wall_height), wall))
    for blk in layout.blocks:
        boxes.append(((*blk["centre"], 0.5 * blk["height"]),
                      (0.5 * blk["size"][0], 0.5 * blk["size"][1], 0.5 * blk["height"]),
                      (0.6, 0.45, 0.3) if blk["kind"] != "counter" else (0.3, 0.3, 0.35)))
    caps = []                                                          # a, b, radius, colour
    for item in layout.furniture:
        top = item["height"]
        wood = (0.55, 0.35, 0.2) if item["kind"] != "display" else (0.7, 0.7, 0.75)
        boxes.append(((*item["centre"], top - 0.02),
                      (0.5 * item["size"][0], 0.5 * item["size"][1], 0.02), wood))
        for leg in item["legs"]:
            caps.append(((*leg, 0.0), (*leg, top - 0.04), item["leg_radius"], wood))
        if item["kind"] == "chair":
            c = np.asarray(item["centre"])
            back = c + np.array([0.0, 0.5 * item["size"][1] * (1 if c[1] > 0 else -1)])
            boxes.append(((*back, top + 0.25), (0.5 * item["size"][0], 0.02, 0.25), wood))
    def f(rows, i, width=3):
        return jnp.asarray(np.array([r[i] for r in rows], float).reshape(len(rows), width), dtype)

    return Primitives(f(caps, 0), f(caps, 1), f(caps, 2, 1)[:, 0], f(caps, 3), f(boxes, 0),
                      f(boxes, 1), jnp.zeros(len(boxes), dtype), f(boxes, 2),
                      jnp.asarray([0.55, 0.5, 0.45], dtype))


def concat(*parts: Primitives) -> Primitives:
    """One scene from several (capsules and boxes concatenated; the first floor colour)."""
    fields = [jnp.concatenate([getattr(p, name) for p in parts], 0)
              for name in Primitives._fields[:-1]]
    return Primitives(*fields, parts[0].floor_colour)


def _capsules(eye, d, a, b, radius):
    r"""[R, Nc] ray parameter of the first hit of each ray with each capsule (inf: none).

    The ray :math:`e + t d` hits the cylinder part where
    :math:`|(o + t d) - ((o + t d) \cdot \hat u) \hat u|^2 = r^2` (:math:`o = e - a`,
    :math:`u = b - a`) with the axial coordinate in [0, |u|], else one of the end spheres."""
    ba = b - a                                                         # [Nc, 3]
    oa = eye[None] - a                                                 # [Nc, 3]
    baba = jnp.sum(ba * ba, -1)                                        # [Nc]
    bard = d @ ba.T                                                    # [R, Nc]
    baoa = jnp.sum(ba * oa, -1)                                        # [Nc]
    rdoa = d @ oa.T                                                    # [R, Nc]
    oaoa = jnp.sum(oa * oa, -1)
    rdrd = jnp.sum(d * d, -1)[:, None]                                 # [R, 1]
    r2 = radius ** 2
    qa = baba * rdrd - bard ** 2
    qb = baba * rdoa - baoa * bard
    qc = baba * oaoa - baoa ** 2 - r2 * baba
    h = qb ** 2 - qa * qc
    body = (baba > 1e-12) & (qa > 1e-12) & (h >= 0)
    t_body = (-qb - jnp.sqrt(jnp.where(body, h, 0.0))) / jnp.where(body, qa, 1.0)
    y = baoa + t_body * bard
    body &= (y > 0) & (y < baba) & (t_body > 0)
    # End spheres: the nearer end to where the ray meets the axis line.
    end_b = (y >= baba) & (baba > 1e-12)
    ob = eye[None] - b
    sb = jnp.where(end_b, d @ ob.T, rdoa)
    sc = jnp.where(end_b, jnp.sum(ob * ob, -1), oaoa) - r2
    hs = sb ** 2 - rdrd * sc
    sphere = hs >= 0
    t_sph = (-sb - jnp.sqrt(jnp.where(sphere, hs, 0.0))) / rdrd
    sphere &= t_sph > 0
    t = jnp.where(body, t_body, jnp.where(sphere, t_sph, jnp.inf))
    return jnp.where(radius > 0, t, jnp.inf)


def _boxes(eye, d, centre, half, yaw):
    """[R, Nb] ray parameter of the entry into each box turned by ``yaw`` about z (slabs)."""
    c, s = jnp.cos(yaw), jnp.sin(yaw)                                  # [Nb]
    rel = eye[None] - centre                                           # [Nb, 3]
    o = jnp.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1], rel[:, 2]], -1)
    dx = d[:, 0:1] * c + d[:, 1:2] * s                                 # [R, Nb]
    dy = -d[:, 0:1] * s + d[:, 1:2] * c
    dz = jnp.broadcast_to(d[:, 2:3], dx.shape)
    lo, hi = -jnp.inf, jnp.inf
    for k, dk in enumerate((dx, dy, dz)):
        safe = jnp.where(jnp.abs(dk) < 1e-12, 1e-12, dk)
        t1 = (-half[:, k] - o[:, k]) / safe
        t2 = (half[:, k] - o[:, k]) / safe
        lo = jnp.maximum(lo, jnp.minimum(t1, t2))
        hi = jnp.minimum(hi, jnp.maximum(t1, t2))
    hitbox = (hi >= jnp.maximum(lo, 0.0)) & (lo > 0) & jnp.all(half > 0, -1)
    return jnp.where(hitbox, lo, jnp.inf)
