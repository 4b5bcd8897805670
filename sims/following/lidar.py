r"""2-D laser range finder: an exact, differentiable ray caster in the laser plane.

The laser scans a horizontal plane at shin height (URG-04LX-like: 240 deg field of view,
0.36 deg steps, 5.6 m range, about 1 cm noise; the laser of seeds 002 and 004). In that plane
the scene is a set of *circles* (cross-sections of people's legs, table and chair legs: vertical
or nearly vertical capsules and cylinders, see `capsule_sections`) and *wall segments* (the
footprint edges of walls and boxes). `cast` returns, for every beam, the distance to the nearest
hit, exactly (the same numbers as ``mjx.ray`` on the 3-D geoms, tested to 1e-5 m in float64).

A beam from :math:`o` along the unit vector :math:`d` hits

- a circle (centre :math:`c`, radius :math:`r`) at the smallest non-negative root of
  :math:`t^2 + 2 b t + k = 0`, :math:`b = (o - c) \cdot d`, :math:`k = \|o - c\|^2 - r^2`,
  i.e. :math:`t = -b \mp \sqrt{b^2 - k}` when :math:`b^2 - k = r^2 - ((o - c) \times d)^2 > 0`
  (the right-hand form is the one computed: it keeps float32 accurate far from the sensor);
- a segment :math:`p + s e`, :math:`s \in [0, 1]`, at
  :math:`t = ((p - o) \times e) / (d \times e)` when
  :math:`s = ((p - o) \times d) / (d \times e) \in [0, 1]` and :math:`t \ge 0`.

Gradients. Misses take ``max_range``. Square roots and divisions see only safe arguments (the
double-``where`` trick: the *input* is replaced on a miss, not only the output), so ``jax.grad``
of the ranges is finite everywhere, and on a hit it is the exact derivative of the hit
distance (for a circle, :math:`\partial t / \partial c = n / (n \cdot d)` with :math:`n` the
unit normal at the hit point). Where ``mjx.ray`` is differentiated at a grazing ray it gives
NaN; this caster gives 0 (the miss side) or the hit derivative.

Cost: :math:`B (C + S)` ray-primitive tests per scan, all vectorised; no loops, no MJX data.

Example:
  >>> cfg = LaserConfig()
  >>> circles = Circles(jnp.array([[2.0, 0.1]]), jnp.array([0.06]), jnp.array([True]))
  >>> walls = Walls(jnp.array([[[4.0, -3.0], [4.0, 3.0]]]), jnp.array([True]))
  >>> r = scan(jax.random.PRNGKey(0), jnp.zeros(3), circles, walls, cfg)   # [667]
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import _checks
from jaxtrack.perception import sensing

Array = jax.Array

__all__ = ["LaserConfig", "Circles", "Walls", "beam_angles", "laser_pose", "capsule_sections",
           "box_walls", "cast", "scan", "scan_points"]


@dataclasses.dataclass(frozen=True)
class LaserConfig:
    """Static laser settings (hashable: pass to `jit` as a static argument or close over it).

    Attributes:
      fov_deg: field of view, centred on the sensor's x axis (240 for the URG-04LX).
      step_deg: angular step between beams (0.36).
      max_range: beyond this nothing is returned; misses read exactly ``max_range`` (5.6 m).
      min_range: returns closer than this are invalid (0.02 m).
      noise_std: Gaussian range noise std on hits (0.01 m: the URG-04LX's 1 % / 1 cm).
      height: height of the scan plane above the floor (0.3 m: shin height).
      mount: (x, y) of the laser in the robot frame; the laser faces the robot's heading.
    """

    fov_deg: float = 240.0
    step_deg: float = 0.36
    max_range: float = 5.6
    min_range: float = 0.02
    noise_std: float = 0.01
    height: float = 0.3
    mount: tuple[float, float] = (0.0, 0.0)

    @property
    def num_beams(self) -> int:
        """``floor(fov / step) + 1`` beams (667 for the defaults)."""
        return int(math.floor(self.fov_deg / self.step_deg + 1e-9)) + 1


class Circles(NamedTuple):
    """Circles in the laser plane (fixed capacity C).

    Attributes:
      centers: [C, 2] world-frame centres.
      radii: [C] radii (> 0 where masked in).
      mask: [C] bools, which circles exist.
    """

    centers: Array
    radii: Array
    mask: Array


class Walls(NamedTuple):
    """Wall segments in the laser plane (fixed capacity S).

    Attributes:
      endpoints: [S, 2, 2] world-frame endpoints (segment, end, xy).
      mask: [S] bools, which segments exist.
    """

    endpoints: Array
    mask: Array


def beam_angles(cfg: LaserConfig = LaserConfig(), dtype=None) -> Array:
    """Beam angles in the sensor frame, symmetric about 0, ascending (counter-clockwise).

    Returns:
      [B] angles in radians, ``B = cfg.num_beams``; beam k is at ``(k - (B-1)/2) * step``.

    Example:
      >>> beam_angles().shape
      (667,)
    """
    n = cfg.num_beams
    k = np.arange(n) - 0.5 * (n - 1)
    return jnp.asarray(np.deg2rad(cfg.step_deg) * k, dtype=dtype)


def laser_pose(robot_pose: Array, cfg: LaserConfig = LaserConfig()) -> Array:
    """World pose (x, y, theta) [3] of the laser on a robot at ``robot_pose`` [3]
    (`jaxtrack.perception.sensing.sensor_pose` at the mount)."""
    return sensing.sensor_pose(jnp.asarray(robot_pose), cfg.mount)


def capsule_sections(p0: Array, p1: Array, radius: Array, height, *,
                     max_tilt_deg: float = 60.0) -> Circles:
    r"""Cross-sections of capsules with the horizontal plane :math:`z = h`, as circles.

    A capsule is the set of points within :math:`r` of its axis segment :math:`p_0 p_1`.

    - Where the axis crosses the plane (:math:`t^* = (h - z_0)/(z_1 - z_0) \in [0, 1]`) the
      section is, up to the caps, the ellipse of the slanted cylinder: centre :math:`a(t^*)`,
      semi-axes :math:`r` across the tilt and :math:`r / \cos\alpha` along it (:math:`\alpha`
      the axis tilt from vertical). We return the circle at :math:`a(t^*)` whose radius is the
      mean semi-axis :math:`\tfrac{r}{2}(1 + 1/\cos\alpha)`: exact for vertical capsules;
      otherwise every point of the ellipse is within :math:`\tfrac{r}{2}(1/\cos\alpha - 1)` of
      the circle (1.9 mm for a 6 cm leg tilted 20 deg, a fifth of the laser noise; a range
      along a beam grazing the silhouette can be off by more, and a beam within that band of
      the silhouette may hit one and miss the other).
    - Beyond an end (:math:`|h - z_e| < r` for the nearest end :math:`e`) the plane cuts the
      spherical cap: the circle centred below/above :math:`e` with radius
      :math:`\sqrt{r^2 - (h - z_e)^2}` (exact for vertical capsules).
    - Otherwise the capsule does not reach the plane: mask False.

    Capsules tilted more than ``max_tilt_deg`` (bars, seats) are not circles in the plane:
    they are masked out; give their footprint to `cast` as wall segments instead.

    Args:
      p0, p1: [C, 3] axis end points (world frame, z up).
      radius: [C] capsule radii.
      height: scalar plane height :math:`h`.
      max_tilt_deg: static tilt limit.

    Returns:
      `Circles` (centers [C, 2], radii [C], mask [C]).

    Example:
      >>> circ = capsule_sections(foot, hip, jnp.full(2, 0.06), 0.3)
    """
    _checks.check_ndim("p0", p0, 2, "[C, 3] capsule axis starts")
    C = _checks.shape_of(p0)[0]
    _checks.check_shape("p0", p0, (C, 3))
    _checks.check_shape("p1", p1, (C, 3))
    _checks.check_shape("radius", radius, (C,))
    for name, v in (("p0", p0), ("p1", p1), ("radius", radius), ("height", height)):
        _checks.check_finite(name, v)
    p0, p1, radius = jnp.asarray(p0), jnp.asarray(p1), jnp.asarray(radius)
    h = jnp.asarray(height, p0.dtype)
    d = p1 - p0
    dz = d[:, 2]
    length = jnp.sqrt(jnp.sum(d * d, -1) + jnp.finfo(p0.dtype).tiny)
    cos_tilt = jnp.abs(dz) / length
    upright = cos_tilt >= math.cos(math.radians(max_tilt_deg))
    safe_dz = jnp.where(upright, dz, 1.0)
    t = (h - p0[:, 2]) / safe_dz
    crosses = upright & (t >= 0.0) & (t <= 1.0)
    axis_xy = p0[:, :2] + jnp.clip(t, 0.0, 1.0)[:, None] * d[:, :2]
    slant_r = 0.5 * radius * (1.0 + 1.0 / jnp.where(upright, cos_tilt, 1.0))
    near0 = jnp.abs(h - p0[:, 2]) <= jnp.abs(h - p1[:, 2])
    end = jnp.where(near0[:, None], p0, p1)
    dh = h - end[:, 2]
    cap_sq = radius ** 2 - dh ** 2
    in_cap = upright & ~crosses & (cap_sq > 0.0)
    cap_r = jnp.sqrt(jnp.where(in_cap, cap_sq, 1.0))
    centers = jnp.where(crosses[:, None], axis_xy, end[:, :2])
    radii = jnp.where(crosses, slant_r, jnp.where(in_cap, cap_r, 0.0))
    return Circles(centers, radii, crosses | in_cap)


def box_walls(center: Array, half_size: Array, yaw: Array) -> Walls:
    """The four footprint edges of z-rotated boxes as wall segments.

    Args:
      center: [K, 2] box centres (xy); half_size: [K, 2] half extents; yaw: [K] rotations.

    Returns:
      `Walls` with endpoints [4K, 2, 2] (box k owns rows 4k..4k+3) and an all-True mask.
    """
    center, half_size, yaw = jnp.asarray(center), jnp.asarray(half_size), jnp.asarray(yaw)
    corners = jnp.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]], center.dtype)
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    rot = jnp.stack([jnp.stack([c, -s], -1), jnp.stack([s, c], -1)], -2)   # [K, 2, 2]
    pts = center[:, None] + jnp.einsum("kij,kcj->kci", rot, corners * half_size[:, None])
    ends = jnp.stack([pts, jnp.roll(pts, -1, axis=1)], 2)                   # [K, 4, 2, 2]
    return Walls(ends.reshape(-1, 2, 2), jnp.ones(ends.shape[0] * 4, bool))


def cast(pose: Array, angles: Array, circles: Circles, walls: Walls, max_range) -> Array:
    r"""Noise-free ranges of every beam: distance to the nearest circle or wall hit.

    Args:
      pose: [3] laser pose (x, y, theta) in the world (see `laser_pose` for a robot pose).
      angles: [B] beam angles in the sensor frame (`beam_angles`).
      circles: `Circles` (centers [C, 2], radii [C], mask [C]); C may be 0.
      walls: `Walls` (endpoints [S, 2, 2], mask [S]); S may be 0.
      max_range: scalar; beams that hit nothing closer read exactly ``max_range``.

    Returns:
      [B] ranges in ``[0, max_range]``, in the dtype of ``pose``/``angles`` (promoted).
      Differentiable in pose, angles, centres, radii and endpoints with finite gradients.

    Example:
      >>> r = cast(jnp.zeros(3), beam_angles(), circles, walls, 5.6)
    """
    _check_scene(pose, angles, circles, walls)
    return _cast(jnp.asarray(pose), jnp.asarray(angles), Circles(*map(jnp.asarray, circles)),
                 Walls(*map(jnp.asarray, walls)), max_range)


def scan(key: Array, pose: Array, circles: Circles, walls: Walls,
         cfg: LaserConfig = LaserConfig()) -> Array:
    """One noisy laser scan from the laser at ``pose`` (like `cast`).

    Hits get :math:`\\mathcal N(0, \\sigma^2)` range noise (``cfg.noise_std``) and are clipped
    to ``[min_range, max_range]``; misses read exactly ``max_range`` (no noise, so they never
    turn into returns). Beam angles are `beam_angles(cfg)`.

    Args:
      key: PRNG key.
      pose: [3] *laser* pose (x, y, theta) in the world; for a robot pose use
        ``laser_pose(robot_pose, cfg)``.
      circles, walls: the scene, as for `cast`.
      cfg: `LaserConfig` (static).

    Returns:
      [B] ranges, ``B = cfg.num_beams``.

    Example:
      >>> ranges = scan(jax.random.PRNGKey(0), laser_pose(robot_pose, cfg), circles, walls, cfg)
    """
    angles = beam_angles(cfg, jnp.result_type(pose, float))
    _check_scene(pose, angles, circles, walls)
    pose = jnp.asarray(pose)
    clean = _cast(pose, angles, Circles(*map(jnp.asarray, circles)),
                  Walls(*map(jnp.asarray, walls)), cfg.max_range)
    hit = clean < cfg.max_range
    noisy = clean + cfg.noise_std * jax.random.normal(key, clean.shape, clean.dtype)
    return jnp.where(hit, jnp.clip(noisy, cfg.min_range, cfg.max_range), cfg.max_range)


def scan_points(ranges: Array, angles: Array, cfg: LaserConfig = LaserConfig()
                ) -> tuple[Array, Array]:
    """Sensor-frame points of a scan and the mask of valid returns.

    A return is valid when it is finite and ``min_range < r < max_range`` (readings clipped to
    either bound are not returns).

    Args:
      ranges: [..., B] ranges; angles: [B] beam angles.
      cfg: `LaserConfig` for the range bounds.

    Returns:
      (xy [..., B, 2], mask [..., B]); invalid returns have xy = 0.

    Example:
      >>> xy, valid = scan_points(ranges, beam_angles())
    """
    ranges, angles = jnp.asarray(ranges), jnp.asarray(angles)
    if ranges.shape[-1:] != angles.shape or angles.ndim != 1:
        raise ValueError(f"ranges [..., B] and angles [B] must agree; got {list(ranges.shape)} "
                         f"and {list(angles.shape)}")
    valid = jnp.isfinite(ranges) & (ranges > cfg.min_range) & (ranges < cfg.max_range)
    r = jnp.where(valid, ranges, 0.0)
    return jnp.stack([r * jnp.cos(angles), r * jnp.sin(angles)], -1), valid


# ---------------------------------------------------------------------------------------------


def _cross(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _cast(pose, angles, circles, walls, max_range):
    dtype = jnp.result_type(pose, angles, circles.centers, walls.endpoints, float)
    pose, angles = pose.astype(dtype), angles.astype(dtype)
    origin = pose[:2]
    # Beam directions: the sensor-frame directions (shared by every episode of a vmap, so
    # computed once) rotated by the heading, instead of 2 B trig calls per scan.
    ca, sa = jnp.cos(angles), jnp.sin(angles)
    c, s = jnp.cos(pose[2]), jnp.sin(pose[2])
    dx, dy = c * ca - s * sa, s * ca + c * sa                             # [B]
    far = jnp.asarray(max_range, dtype)

    # Laid out [primitives, beams] and reduced over the primitives: the loops then run along
    # the beams (a minimum over a trailing axis of a dozen primitives ran as a scalar loop on
    # a CPU, over materialised [B, C] and [B, S] arrays).
    # Circles: smallest non-negative root of t^2 + 2 b t + k = 0.
    m = origin - circles.centers.astype(dtype)                            # [C, 2]
    b = m[:, 0, None] * dx[None] + m[:, 1, None] * dy[None]               # [C, B]
    # b^2 - k = r^2 - (m x d)^2: no cancellation of two large squares in float32.
    cross = m[:, 0, None] * dy[None] - m[:, 1, None] * dx[None]
    radii = circles.radii.astype(dtype)[:, None]
    disc = radii ** 2 - cross * cross
    touches = (circles.mask & (circles.radii > 0))[:, None] & (disc > 0)
    root = jnp.sqrt(jnp.where(touches, disc, 1.0))
    near, far_root = -b - root, -b + root
    t_circ = jnp.where(near >= 0, near, far_root)
    t_circ = jnp.where(touches & (t_circ >= 0), t_circ, far)

    # Segments p + s e: t = ((p - o) x e) / (d x e), s = ((p - o) x d) / (d x e).
    p = walls.endpoints[:, 0].astype(dtype)                               # [S, 2]
    e = walls.endpoints[:, 1].astype(dtype) - p
    q = p - origin
    denom = e[:, 1, None] * dx[None] - e[:, 0, None] * dy[None]           # [S, B]
    length = jnp.sqrt(jnp.sum(e * e, -1))
    ok = walls.mask[:, None] & (jnp.abs(denom) > 1e-12 * jnp.maximum(length, 1e-30)[:, None])
    inv = 1.0 / jnp.where(ok, denom, 1.0)
    t_seg = _cross(q, e)[:, None] * inv
    s_seg = (q[:, 0, None] * dy[None] - q[:, 1, None] * dx[None]) * inv
    hit = ok & (t_seg >= 0) & (s_seg >= 0) & (s_seg <= 1)
    t_seg = jnp.where(hit, t_seg, far)

    # Two reductions, no [C + S, B] concatenation (it would be materialised).
    return jnp.minimum(jnp.minimum(jnp.min(t_circ, 0, initial=far),
                                   jnp.min(t_seg, 0, initial=far)), far)


def _check_scene(pose, angles, circles, walls):
    _checks.check_shape("pose", pose, (3,), "laser pose (x, y, theta)")
    _checks.check_ndim("angles", angles, 1, "[B] beam angles")
    if len(circles) != 3:
        raise ValueError("circles must be (centers [C, 2], radii [C], mask [C])")
    if len(walls) != 2:
        raise ValueError("walls must be (endpoints [S, 2, 2], mask [S])")
    centers, radii, cmask = circles
    _checks.check_ndim("circles.centers", centers, 2, "[C, 2] centres")
    C = _checks.shape_of(centers)[0]
    _checks.check_shape("circles.centers", centers, (C, 2))
    _checks.check_shape("circles.radii", radii, (C,))
    _checks.check_shape("circles.mask", cmask, (C,))
    ends, wmask = walls
    _checks.check_ndim("walls.endpoints", ends, 3, "[S, 2, 2] segment endpoints")
    S = _checks.shape_of(ends)[0]
    _checks.check_shape("walls.endpoints", ends, (S, 2, 2))
    _checks.check_shape("walls.mask", wmask, (S,))
    for name, v in (("pose", pose), ("angles", angles), ("circles.centers", centers),
                    ("circles.radii", radii), ("walls.endpoints", ends)):
        _checks.check_finite(name, v)
    if _checks.is_concrete(radii) and np.any(np.asarray(radii) < 0):
        raise ValueError("circles.radii must be >= 0")
