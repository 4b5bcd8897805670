r"""The robot's RGB-D person detector and wheel odometry, simulated in pure `jax.numpy`.

RGB-D detector (seeds 003 and 004: a Kinect / Xtion on the robot running a people detector).
For each person (a disc of radius ``person_radius`` at ``people_xy``), in the robot frame:

1. **Field of view and range**: the centre's bearing within :math:`\pm` ``fov / 2`` (57 deg by
   default) and its range within [``min_range``, ``max_range``] (0.5-4.5 m, the sensor's depth
   range).
2. **Occlusion**: the person's angular extent :math:`[b - w, b + w]`,
   :math:`w = \arcsin(\min(1, \rho / d))`, is sampled at ``occlusion_samples`` evenly spaced
   bearings; a sample is covered if it falls inside the angular extent of a *nearer* real person
   (any person, in the field of view or not). The person is occluded (never detected) if the
   covered fraction exceeds ``occlusion_threshold`` (0.5: "mostly covered").
3. **Miss**: a visible person is missed with probability ``miss_prob``, independently.
4. **Noise**: a detection is the true position plus isotropic Gaussian noise of std
   ``position_std`` per axis (0.3 m, seed 003's RGB-D figure), in the robot frame; its colour
   feature is the person's colour plus Gaussian noise ``colour_std``, clipped to [0, 1].
5. **False positives**: a Poisson number with mean ``false_rate`` per frame, truncated at the
   capacity ``max_false``, uniform over the area of the field-of-view sector between the range
   limits, with colours uniform in [0, 1]^3. With ``walls``, those behind a wall are dropped:
   a detector finds its false positives in what the camera sees (its clutter is a constant
   density over the visible part of the sector), not through walls.

The output has fixed capacity M = P + ``max_false``; its rows are randomly permuted so that a
row's index says nothing about who it is (``person_id`` gives the truth, for evaluation only).

Odometry: the standard odometry motion model (Thrun, Burgard and Fox, *Probabilistic Robotics*,
section 5.4). The motion between two poses is decomposed into a rotation
:math:`\delta_{rot1}`, a translation :math:`\delta_{trans}` and a rotation
:math:`\delta_{rot2}`; each gets zero-mean Gaussian noise of variance
:math:`\alpha_1 \delta_{rot1}^2 + \alpha_2 \delta_{trans}^2`,
:math:`\alpha_3 \delta_{trans}^2 + \alpha_4 (\delta_{rot1}^2 + \delta_{rot2}^2)`,
:math:`\alpha_1 \delta_{rot2}^2 + \alpha_2 \delta_{trans}^2` (standard deviations proportional
to the motion). Backward motion is decomposed with a negative translation (so reversing does
not read as a half turn). Below ``MIN_TRANSLATION`` (1 cm per step) the noise is that of a
pure rotation, :math:`\delta_{rot1} = 0` and :math:`\delta_{rot2} = \Delta\theta`, as in
ROS's AMCL: a robot turning on the spot slides its centre by fractions of a millimetre, in
any direction, and the decomposition would otherwise read that as two turns of up to 180 deg
and give the step a yaw noise of several degrees. The increment itself stays exact (with
all alphas 0, integrating it gives the true pose).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxtrack import _checks, geometry
from jaxtrack.angles import wrap

Array = jax.Array

__all__ = ["RGBDConfig", "RGBDDetections", "OdometryConfig", "MIN_TRANSLATION", "detect",
           "visible", "odometry", "integrate", "accumulate"]


@dataclasses.dataclass(frozen=True)
class RGBDConfig:
    """RGB-D detector parameters.

    A frozen, hashable dataclass (pass it as a static argument) that is also a pytree whose
    float fields are leaves (so noise levels can be traced, batched or differentiated); the two
    integer fields are static.

    Attributes:
      fov: horizontal field of view (rad); 57 deg.
      min_range, max_range: depth range (m); 0.5, 4.5.
      position_std: detection position noise std per axis (m); 0.3 (seed 003).
      miss_prob: probability of missing a visible person; 0.1.
      false_rate: mean number of false positives per frame; 0.2.
      colour_std: colour-feature noise std (colours in [0, 1]); 0.05.
      person_radius: a person's radius for occlusion (m); 0.25.
      occlusion_threshold: occluded if more than this fraction of the angular extent is
        covered by nearer people; 0.5.
      max_false: capacity for false positives (static); 4.
      occlusion_samples: bearings sampled across a person's extent (static); 16.
    """

    fov: float = math.radians(57.0)
    min_range: float = 0.5
    max_range: float = 4.5
    position_std: float = 0.3
    miss_prob: float = 0.1
    false_rate: float = 0.2
    colour_std: float = 0.05
    person_radius: float = 0.25
    occlusion_threshold: float = 0.5
    max_false: int = 4
    occlusion_samples: int = 16


_RGBD_DATA = ("fov", "min_range", "max_range", "position_std", "miss_prob", "false_rate",
              "colour_std", "person_radius", "occlusion_threshold")
jax.tree_util.register_dataclass(RGBDConfig, data_fields=list(_RGBD_DATA),
                                 meta_fields=["max_false", "occlusion_samples"])


MIN_TRANSLATION = 0.01
"""Translation per step (m) below which `odometry`'s noise is that of a turn on the spot."""


@dataclasses.dataclass(frozen=True)
class OdometryConfig:
    r"""Odometry noise of the standard model (module docstring), a pytree of float leaves.

    Attributes:
      alpha1: rotation variance per squared rotation (rad^2 / rad^2); 0.01.
      alpha2: rotation variance per squared translation (rad^2 / m^2); 0.001.
      alpha3: translation variance per squared translation (m^2 / m^2); 0.004.
      alpha4: translation variance per squared rotation (m^2 / rad^2); 0.001.
    """

    alpha1: float = 0.01
    alpha2: float = 0.001
    alpha3: float = 0.004
    alpha4: float = 0.001


jax.tree_util.register_dataclass(OdometryConfig,
                                 data_fields=["alpha1", "alpha2", "alpha3", "alpha4"],
                                 meta_fields=[])


class RGBDDetections(NamedTuple):
    """One frame of RGB-D detections, fixed capacity M = P + max_false.

    Attributes:
      xy: [M, 2] positions in the robot frame (m); zeros where not ``mask``.
      mask: [M] bool, real detections.
      colour: [M, 3] colour features in [0, 1].
      person_id: [M] int32 index into the people array, -1 for false positives and empty rows
        (ground truth, for evaluation only).
    """

    xy: Array
    mask: Array
    colour: Array
    person_id: Array


# ---------------------------------------------------------------------------------------------
# RGB-D detector


def visible(cfg: RGBDConfig, robot_pose: Array, people_xy: Array, people_mask: Array) -> Array:
    """Which people the detector can see [P] bool: in the field of view and range, not occluded.

    Steps 1-2 of the module docstring (no randomness).

    Example:
      >>> visible(RGBDConfig(), jnp.zeros(3), jnp.array([[2.0, 0.0], [3.0, 0.0]]),
      ...         jnp.array([True, True]))  # [True, False]: the second is behind the first
    """
    _check_rgbd(cfg)
    robot_pose, people_xy, people_mask = _check_people(robot_pose, people_xy, people_mask)
    return _visible(cfg, robot_pose, people_xy, people_mask)[0]


def detect(key: Array, cfg: RGBDConfig, robot_pose: Array, people_xy: Array,
           people_mask: Array, people_colour: Array, walls: Array | None = None
           ) -> RGBDDetections:
    """Simulate one frame of the RGB-D person detector (module docstring, steps 1-5).

    Args:
      key: PRNG key.
      cfg: `RGBDConfig`.
      robot_pose: [3] robot (x, y, theta) in the world frame.
      people_xy: [P, 2] people positions in the world frame (rows outside ``people_mask`` may
        hold anything, NaN included).
      people_mask: [P] bool, which rows are real people.
      people_colour: [P, 3] each person's colour vector in [0, 1].
      walls: optional [S, 2, 2] wall segments (world frame) that hide the people behind them
        (shelves): a person whose centre is out of sight of the camera is not detected, and
        no false positive falls behind a wall.

    Returns:
      `RGBDDetections` with M = P + cfg.max_false rows, in random order (positions in the
      frame of ``robot_pose``: for a camera on a pan unit, pass the camera's pose).

    Example:
      >>> det = detect(jax.random.key(0), RGBDConfig(), jnp.zeros(3),
      ...              jnp.array([[2.0, 0.3]]), jnp.array([True]), jnp.array([[1.0, 0, 0]]))
      >>> det.xy[det.mask]  # about (2.0, 0.3) +- 0.3 m, unless missed
    """
    _check_rgbd(cfg)
    robot_pose, people_xy, people_mask = _check_people(robot_pose, people_xy, people_mask)
    p = people_xy.shape[0]
    _checks.check_shape("people_colour", people_colour, (p, 3), "[P, 3] colours")
    dtype = people_xy.dtype
    colour = jnp.asarray(people_colour, dtype)
    colour = jnp.where(people_mask[:, None] & jnp.all(jnp.isfinite(colour), -1, keepdims=True),
                       colour, 0.0)
    k_miss, k_pos, k_col, k_n, k_fa, k_fr, k_fc, k_perm = jax.random.split(key, 8)

    seen, rel = _visible(cfg, robot_pose, people_xy, people_mask, walls)
    hit = seen & (jax.random.uniform(k_miss, (p,), dtype) >= cfg.miss_prob)
    xy = rel + cfg.position_std * jax.random.normal(k_pos, (p, 2), dtype)
    col = jnp.clip(colour + cfg.colour_std * jax.random.normal(k_col, (p, 3), dtype), 0.0, 1.0)

    f = cfg.max_false
    n_false = _truncated_poisson(k_n, jnp.asarray(cfg.false_rate, dtype), f)
    false_mask = jnp.arange(f) < n_false
    bearing = (jax.random.uniform(k_fa, (f,), dtype) - 0.5) * cfg.fov
    r2 = cfg.min_range ** 2 + jax.random.uniform(k_fr, (f,), dtype) * (cfg.max_range ** 2
                                                                      - cfg.min_range ** 2)
    r = jnp.sqrt(r2)
    false_xy = jnp.stack([r * jnp.cos(bearing), r * jnp.sin(bearing)], -1)
    if walls is not None and walls.shape[0] and f:
        false_mask = false_mask & ~_behind_walls(
            robot_pose[:2], geometry.from_frame(robot_pose, false_xy),
            jnp.asarray(walls, dtype))
    false_col = jax.random.uniform(k_fc, (f, 3), dtype)

    all_xy = jnp.concatenate([xy, false_xy])
    all_mask = jnp.concatenate([hit, false_mask])
    all_col = jnp.concatenate([col, false_col])
    ids = jnp.concatenate([jnp.arange(p, dtype=jnp.int32), jnp.full((f,), -1, jnp.int32)])
    order = jax.random.permutation(k_perm, p + f)
    all_mask = all_mask[order]
    return RGBDDetections(jnp.where(all_mask[:, None], all_xy[order], 0.0), all_mask,
                          jnp.where(all_mask[:, None], all_col[order], 0.0),
                          jnp.where(all_mask, ids[order], -1))


def _truncated_poisson(key, rate, cap):
    """min(N, cap) for N ~ Poisson(rate), by inverting the CDF at its first ``cap`` values."""
    if cap == 0:
        return jnp.zeros((), jnp.int32)
    k = jnp.arange(cap, dtype=rate.dtype)
    log_terms = k * jnp.log(jnp.maximum(rate, 1e-30)) - lax.lgamma(k + 1.0)
    cdf = jnp.cumsum(jnp.exp(log_terms - rate))      # P(N <= k), k = 0 .. cap - 1
    cdf = jnp.where(rate > 0, cdf, 1.0)
    u = jax.random.uniform(key, (), rate.dtype)
    return jnp.sum(u > cdf).astype(jnp.int32)


def _visible(cfg, robot_pose, people_xy, people_mask, walls=None):
    """(visible [P], positions in the robot frame [P, 2])."""
    dtype = people_xy.dtype
    ok = people_mask & jnp.all(jnp.isfinite(people_xy), -1)
    # Absent people (NaN allowed) are put 1 m away; `ok` leaves them out below.
    xy = jnp.where(ok[:, None], people_xy, robot_pose[:2] + jnp.array([1.0, 0.0], dtype))
    rel = geometry.to_frame(robot_pose, xy)
    dist = jnp.sqrt(jnp.sum(rel * rel, -1))
    bearing = jnp.arctan2(rel[:, 1], rel[:, 0])
    in_view = (ok & (jnp.abs(bearing) <= 0.5 * cfg.fov) & (dist >= cfg.min_range)
               & (dist <= cfg.max_range))
    half = jnp.arcsin(jnp.clip(cfg.person_radius / jnp.maximum(dist, 1e-9), 0.0, 1.0))
    k = cfg.occlusion_samples
    offsets = (jnp.arange(k, dtype=dtype) + 0.5) / k * 2.0 - 1.0
    samples = bearing[:, None] + half[:, None] * offsets                       # [P, K]
    inside = jnp.abs(wrap(samples[:, :, None] - bearing[None, None, :])) <= half[None, None, :]
    nearer = ok[None, :] & (dist[None, :] < dist[:, None])                     # [i, j]
    covered = jnp.any(inside & nearer[:, None, :], -1)                          # [P, K]
    occluded = jnp.mean(covered.astype(dtype), -1) > cfg.occlusion_threshold
    if walls is not None and walls.shape[0]:
        occluded = occluded | _behind_walls(robot_pose[:2], xy, jnp.asarray(walls, dtype))
    return in_view & ~occluded, jnp.where(ok[:, None], rel, 0.0)


def _behind_walls(eye, xy, walls):
    """[P] the segment from ``eye`` [2] to each person [P, 2] crosses a wall segment [S, 2, 2]
    (the line of sight to the person's centre is blocked: shelves hide whom they stand
    behind)."""
    a, b = walls[None, :, 0], walls[None, :, 1]                              # [1, S, 2]
    d = xy[:, None, :] - eye                                                  # [P, 1, 2]
    e = b - a

    def cross(u, v):
        return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]

    den = cross(d, e)
    w = a - eye
    ok = jnp.abs(den) > 1e-12
    t = cross(w, e) / jnp.where(ok, den, 1.0)       # along the line of sight
    s = cross(w, d) / jnp.where(ok, den, 1.0)       # along the wall
    return jnp.any(ok & (t > 0.0) & (t < 1.0) & (s >= 0.0) & (s <= 1.0), -1)


# ---------------------------------------------------------------------------------------------
# Odometry


def odometry(key: Array, cfg: OdometryConfig, pose_prev: Array, pose: Array) -> Array:
    r"""Noisy odometry [3] (dx, dy, dtheta) in the previous robot frame (module docstring).

    Noise-free when all alphas are 0: then ``integrate(pose_prev, odometry(...)) == pose``.

    Args:
      key: PRNG key. cfg: `OdometryConfig`.
      pose_prev, pose: [3] true poses (x, y, theta) at the previous and current step.

    Example:
      >>> odo = odometry(jax.random.key(0), OdometryConfig(), jnp.zeros(3),
      ...                jnp.array([0.1, 0.0, 0.05]))
    """
    _check_odometry(cfg)
    for name, value in (("pose_prev", pose_prev), ("pose", pose)):
        _checks.check_shape(name, value, (3,), "(x, y, theta)")
        _checks.check_finite(name, value)
    dtype = jnp.result_type(jnp.asarray(pose_prev).dtype, jnp.asarray(pose).dtype, jnp.float32)
    pose_prev, pose = jnp.asarray(pose_prev, dtype), jnp.asarray(pose, dtype)
    d = pose[:2] - pose_prev[:2]
    dist2 = jnp.sum(d * d)
    moved = dist2 > 1e-18
    dist = jnp.sqrt(jnp.where(moved, dist2, 1.0))
    heading = jnp.arctan2(jnp.where(moved, d[1], 0.0), jnp.where(moved, d[0], 1.0))
    backward = jnp.cos(heading - pose_prev[2]) < 0.0
    rot1 = jnp.where(moved, wrap(heading - pose_prev[2] + jnp.where(backward, jnp.pi, 0.0)),
                     0.0)
    trans = jnp.where(moved, jnp.where(backward, -dist, dist), 0.0)
    rot2 = wrap(pose[2] - pose_prev[2] - rot1)

    # the noise's rotations: a turn on the spot is all rot2 (module docstring)
    spot = dist2 < MIN_TRANSLATION ** 2
    r1 = jnp.where(spot, 0.0, rot1)
    r2 = jnp.where(spot, wrap(pose[2] - pose_prev[2]), rot2)
    e = jax.random.normal(key, (3,), dtype)
    a1, a2, a3, a4 = (jnp.asarray(getattr(cfg, f"alpha{i}"), dtype) for i in (1, 2, 3, 4))
    rot1_n = rot1 + _std(a1 * r1 ** 2 + a2 * trans ** 2) * e[0]
    trans_n = trans + _std(a3 * trans ** 2 + a4 * (r1 ** 2 + r2 ** 2)) * e[1]
    rot2_n = rot2 + _std(a1 * r2 ** 2 + a2 * trans ** 2) * e[2]
    return jnp.stack([trans_n * jnp.cos(rot1_n), trans_n * jnp.sin(rot1_n),
                      wrap(rot1_n + rot2_n)])


def integrate(pose: Array, odom: Array) -> Array:
    r"""Compose a pose [3] with an odometry increment [3] given in its frame.

    :math:`x' = x + R(\theta) (dx, dy)`, :math:`\theta' = \operatorname{wrap}(\theta + d\theta)`.

    Example:
      >>> integrate(jnp.array([0.0, 0.0, jnp.pi / 2]), jnp.array([1.0, 0.0, 0.0]))  # (0, 1, pi/2)
    """
    _checks.check_shape("pose", pose, (3,), "(x, y, theta)")
    _checks.check_shape("odom", odom, (3,), "(dx, dy, dtheta)")
    pose = jnp.asarray(pose)
    return geometry.compose(pose, jnp.asarray(odom, pose.dtype))


def accumulate(pose0: Array, odoms: Array) -> Array:
    """Dead reckoning: poses [T, 3] after each of ``odoms`` [T, 3], from ``pose0`` [3].

    Example:
      >>> path = accumulate(jnp.zeros(3), jnp.tile(jnp.array([0.1, 0.0, 0.1]), (20, 1)))
    """
    _checks.check_shape("pose0", pose0, (3,), "(x, y, theta)")
    _checks.check_shape("odoms", odoms, (None, 3), "[T, 3] increments")
    pose0 = jnp.asarray(pose0)

    def body(pose, odom):
        nxt = geometry.compose(pose, odom)
        return nxt, nxt

    return lax.scan(body, pose0, jnp.asarray(odoms, pose0.dtype))[1]


def _std(var):
    # sqrt with a zero (not NaN) gradient at zero motion
    pos = var > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, var, 1.0)), 0.0)


# ---------------------------------------------------------------------------------------------
# Checks


def _check_rgbd(cfg):
    if not isinstance(cfg, RGBDConfig):
        raise TypeError(f"cfg must be an rgbd.RGBDConfig; got {type(cfg).__name__}")
    if not isinstance(cfg.max_false, int) or cfg.max_false < 0:
        raise ValueError(f"cfg.max_false must be an int >= 0; got {cfg.max_false!r}")
    if not isinstance(cfg.occlusion_samples, int) or cfg.occlusion_samples < 1:
        raise ValueError(f"cfg.occlusion_samples must be an int >= 1; got "
                         f"{cfg.occlusion_samples!r}")
    v = {name: getattr(cfg, name) for name in _RGBD_DATA}
    if not all(_checks.is_concrete(x) for x in v.values()):
        return
    v = {name: float(np.asarray(x)) for name, x in v.items()}
    for name, x in v.items():
        if not math.isfinite(x):
            raise ValueError(f"cfg.{name} must be finite; got {x}")
    rules = [("fov", 0 < v["fov"] <= 2 * math.pi, "in (0, 2 pi]"),
             ("min_range", v["min_range"] >= 0, ">= 0"),
             ("max_range", v["max_range"] > v["min_range"], "> min_range"),
             ("position_std", v["position_std"] >= 0, ">= 0"),
             ("miss_prob", 0 <= v["miss_prob"] <= 1, "in [0, 1]"),
             ("false_rate", v["false_rate"] >= 0, ">= 0"),
             ("colour_std", v["colour_std"] >= 0, ">= 0"),
             ("person_radius", v["person_radius"] > 0, "> 0"),
             ("occlusion_threshold", 0 <= v["occlusion_threshold"] <= 1, "in [0, 1]")]
    for name, ok, what in rules:
        if not ok:
            raise ValueError(f"cfg.{name} must be {what}; got {v[name]}")


def _check_people(robot_pose, people_xy, people_mask):
    _checks.check_shape("robot_pose", robot_pose, (3,), "(x, y, theta)")
    _checks.check_finite("robot_pose", robot_pose)
    _checks.check_shape("people_xy", people_xy, (None, 2), "[P, 2] positions")
    p = np.shape(people_xy)[0]
    _checks.check_shape("people_mask", people_mask, (p,), "[P] bool")
    if _checks.is_concrete(people_mask):
        if not np.issubdtype(np.asarray(people_mask).dtype, np.bool_):
            raise TypeError(f"people_mask must be bool; got {np.asarray(people_mask).dtype}")
        if _checks.is_concrete(people_xy):
            real = np.asarray(people_xy)[np.asarray(people_mask)]
            if not np.all(np.isfinite(real)):
                raise ValueError("people_xy contains NaN or inf in rows where people_mask is "
                                 "True")
    dtype = jnp.result_type(jnp.asarray(robot_pose).dtype, jnp.asarray(people_xy).dtype,
                            jnp.float32)
    return (jnp.asarray(robot_pose, dtype), jnp.asarray(people_xy, dtype),
            jnp.asarray(people_mask, bool))


def _check_odometry(cfg):
    if not isinstance(cfg, OdometryConfig):
        raise TypeError(f"cfg must be an rgbd.OdometryConfig; got {type(cfg).__name__}")
    for name in ("alpha1", "alpha2", "alpha3", "alpha4"):
        x = getattr(cfg, name)
        if _checks.is_concrete(x) and not float(np.asarray(x)) >= 0:
            raise ValueError(f"cfg.{name} must be >= 0; got {x}")
