r"""Noisy person detections simulated from recorded trajectories, in pure `jax.numpy`.

A person detector on a robot (or a ceiling camera) sees the people of a trajectory file the way
seed 003 (cooperative perception with ceiling cameras, an RGB-D camera and a laser) models its
sensors for the JPDA tracker (section III-D, "People Tracking", eq. 6): each person in the
field of view is detected with probability :math:`P_D`, at its position plus Gaussian noise,

.. math::
    z = p + \varepsilon, \qquad \varepsilon \sim \mathcal{N}(0, \sigma^2 I_2),

and each frame adds a Poisson number of false detections (clutter), uniform over a region.
Each detection, miss and false detection is independent of the others and of other frames.

Defaults, with where they come from:

- noise std per axis, section III-D (the ``detector.yaml`` tuning): leg detector on the laser
  0.2 m, RGB-D person detector on the robot (ASUS Xtion) 0.3 m, ceiling cameras (AXIS) 0.1 m;
- fields of view: of the sensors listed in section III-B (datasheet figures, the same as in
  `sims/following`): the Hokuyo URG-04LX laser sweeps 240 deg, 0.1-5.6 m; the Xtion sees
  57 deg, 0.5-4.5 m; the ceiling cameras together see the whole room;
- detection probability and clutter rate: the paper's JPDA (eq. 6) has :math:`P_D` and a
  Poisson clutter model but reports no values. The presets use :math:`P_D = 0.9` (the
  tracker's default, `jaxtrack.tracking.TrackerParams.create`), one false detection per laser
  scan (section IV, experiment 1, shows laser false positives on tables and chairs) and 0.2 per
  camera frame. These two are our choices, not measurements.

Occlusion between people is not modelled (`sims.following.rgbd` does it for the simulated
scene).

Clutter region: the sensor's field-of-view sector when its range is finite and no ``region``
is given (then ``clutter_rate`` is the mean count in the sector); otherwise the box ``region``
(default in `detections`: the bounding box of the trajectories, padded by 1 m), where
``clutter_rate`` is the mean count in the box and points the sensor cannot see are dropped.

Detections are in the world frame of the trajectories, fixed capacity M with a mask, in random
order (a slot's index says nothing about who it is); ``source`` gives the truth for evaluation.
Several sensors: call `detections` once per `SensorModel` and merge with `to_tracker`.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import _checks, geometry
from jaxtrack.tracking import tracker

Array = jax.Array

__all__ = ["SensorModel", "SimulatedDetections", "detect", "detections", "to_tracker",
           "in_view"]


class SensorModel(NamedTuple):
    """Parameters of a simulated person detector (float leaves; may be traced or batched).

    Build with `SensorModel.create` or a preset (`laser`, `rgbd`, `ceiling_camera`).

    Attributes:
      noise_std: position noise std per axis (m), >= 0.
      p_detect: probability of detecting a visible person, in [0, 1].
      clutter_rate: mean number of false detections per frame over the clutter region, >= 0.
      fov: full angular field of view (rad) centred on the sensor's x axis; >= 2 pi sees all.
      min_range, max_range: range limits (m); ``max_range = inf`` for no limit.
    """

    noise_std: Array
    p_detect: Array
    clutter_rate: Array
    fov: Array
    min_range: Array
    max_range: Array

    @staticmethod
    def create(noise_std=0.2, p_detect=0.9, clutter_rate=0.0, fov=2 * math.pi, min_range=0.0,
               max_range=math.inf, dtype=None) -> "SensorModel":
        """A model from natural values (default: everything visible, seed 003's laser noise,
        no clutter). Checks the values.

        Example:
          >>> model = SensorModel.create(noise_std=0.1, p_detect=0.95, clutter_rate=2.0)
        """
        dtype = jnp.result_type(float) if dtype is None else dtype
        model = SensorModel(*(jnp.asarray(v, dtype) for v in (
            noise_std, p_detect, clutter_rate, fov, min_range, max_range)))
        _check_model(model)
        return model

    @staticmethod
    def laser(**overrides) -> "SensorModel":
        """Seed 003's leg detector on the URG-04LX laser: 0.2 m, 240 deg, 0.1-5.6 m,
        P_D 0.9, one false detection per scan."""
        kw = dict(noise_std=0.2, p_detect=0.9, clutter_rate=1.0, fov=math.radians(240.0),
                  min_range=0.1, max_range=5.6)
        return SensorModel.create(**{**kw, **overrides})

    @staticmethod
    def rgbd(**overrides) -> "SensorModel":
        """Seed 003's RGB-D (Xtion) person detector: 0.3 m, 57 deg, 0.5-4.5 m, P_D 0.9,
        0.2 false detections per frame."""
        kw = dict(noise_std=0.3, p_detect=0.9, clutter_rate=0.2, fov=math.radians(57.0),
                  min_range=0.5, max_range=4.5)
        return SensorModel.create(**{**kw, **overrides})

    @staticmethod
    def ceiling_camera(**overrides) -> "SensorModel":
        """Seed 003's ceiling cameras: 0.1 m, the whole room visible, P_D 0.9, 0.2 false
        detections per frame over the region."""
        kw = dict(noise_std=0.1, p_detect=0.9, clutter_rate=0.2)
        return SensorModel.create(**{**kw, **overrides})


class SimulatedDetections(NamedTuple):
    """Detections with fixed capacity M (leading [T] axis from `detections`).

    Attributes:
      z: [..., M, 2] positions (m, world frame); 0 in empty slots.
      mask: [..., M] bools.
      source: [..., M] int32 person slot index p (into the trajectories' P axis) that caused
        the detection, -1 for clutter and in empty slots.
      num_clutter: [...] int32 false detections drawn in the region (a Poisson count capped at
        M), before the field-of-view cut and the capacity limit.
      num_dropped: [...] int32 detections lost because more than M were produced.
    """

    z: Array
    mask: Array
    source: Array
    num_clutter: Array
    num_dropped: Array


def in_view(xy: Array, model: SensorModel, sensor_pose: Array) -> Array:
    """[...] bools: positions ``xy`` [..., 2] inside the field of view of a sensor at
    ``sensor_pose`` [3] (x, y, heading): bearing within fov / 2 and range within the limits."""
    rel = geometry.to_frame(sensor_pose, xy)
    fwd, left = rel[..., 0], rel[..., 1]
    dist = jnp.sqrt(fwd * fwd + left * left)
    bearing = jnp.arctan2(left, fwd)
    return (((model.fov >= 2 * jnp.pi) | (jnp.abs(bearing) <= 0.5 * model.fov))
            & (dist >= model.min_range) & (dist <= model.max_range))


def detect(key: Array, pos: Array, mask: Array, model: SensorModel, max_detections: int,
           region: Array | None = None, sensor_pose: Array | None = None
           ) -> SimulatedDetections:
    r"""One frame of simulated detections (module doc; seed 003, section III-D).

    Args:
      key: PRNG key.
      pos: [P, 2] true positions (m), finite where ``mask`` is True; mask: [P] bools.
      model: `SensorModel`.
      max_detections: M, the capacity (static).
      region: [2, 2] clutter box ``[[x_min, y_min], [x_max, y_max]]``; None: the sensor's
        field-of-view sector (needs a finite ``max_range``; with an infinite range and no
        region no clutter is drawn).
      sensor_pose: [3] ``(x, y, heading)``; default the origin facing +x.

    Returns:
      `SimulatedDetections` with [M] fields and scalar counts.

    Example:
      >>> det = detect(jax.random.key(0), jnp.array([[1.0, 2.0]]), jnp.array([True]),
      ...              SensorModel.create(clutter_rate=1.0), 8, region=jnp.array([[0., 0], [5, 5]]))
    """
    pos, mask, region, sensor_pose, M = _check_frame(pos, mask, model, max_detections, region,
                                                     sensor_pose)
    return _detect(key, pos, mask, model, region, sensor_pose, M)


def detections(key: Array, traj_pos: Array, traj_mask: Array, model: SensorModel,
               max_detections: int, region: Array | None = None,
               sensor_pose: Array | None = None) -> SimulatedDetections:
    r"""Simulated detections of every frame of a trajectory set (the model of `detect`, frame by
    frame, independent across frames). Jittable and vmappable over ``key``.

    Args:
      key: PRNG key.
      traj_pos: [T, P, 2] positions (m), e.g. `Trajectories.pos`.
      traj_mask: [T, P] bools, e.g. `Trajectories.mask`.
      model: `SensorModel`.
      max_detections: M (static).
      region: [2, 2] clutter box; default the bounding box of the present positions padded by
        1 m, unless the sensor's range is finite (then its field-of-view sector, see module doc).
      sensor_pose: [3] fixed or [T, 3] per-frame sensor poses (x, y, heading); default origin.

    Returns:
      `SimulatedDetections` with leading [T] axis.

    Example:
      >>> traj = trajectories.read_obsmat("obsmat.txt")
      >>> det = detections(jax.random.key(0), traj.pos, traj.mask, SensorModel.laser(), 16,
      ...                  sensor_pose=jnp.array([5.0, 3.0, 0.0]))
      >>> tracker_input = to_tracker(det)
    """
    _checks.check_ndim("traj_pos", traj_pos, 3, "[T, P, 2] positions")
    T, P, _ = _checks.shape_of(traj_pos)
    _checks.check_shape("traj_pos", traj_pos, (T, P, 2), "[T, P, 2] positions")
    _checks.check_shape("traj_mask", traj_mask, (T, P), "[T, P] bools")
    _check_key(key)
    _check_positions(traj_pos, traj_mask)
    pose = _check_pose(sensor_pose, T)
    if region is not None:
        _check_region(region)
    M = _check_capacity(max_detections)
    _check_model(model)
    return _sequence(key, traj_pos, traj_mask, model, region, pose, M)


def to_tracker(*dets: SimulatedDetections, confidence=1.0) -> tracker.Detections:
    """Merge the detections of one or more sensors into `jaxtrack.tracking.Detections`
    (sensor index = argument position, matching ``TrackerParams.r_std``), keeping any leading
    axes. Features are empty.

    Example:
      >>> det = to_tracker(detections(k1, pos, mask, SensorModel.laser(), 8),
      ...                  detections(k2, pos, mask, SensorModel.rgbd(), 8))
      >>> params = TrackerParams.create(config, r_std=(0.2, 0.3))
    """
    if not dets:
        raise ValueError("to_tracker needs at least one SimulatedDetections")
    for d in dets:
        if not isinstance(d, SimulatedDetections):
            raise TypeError(f"expected SimulatedDetections; got {type(d).__name__}")
    z = jnp.concatenate([d.z for d in dets], -2)
    mask = jnp.concatenate([d.mask for d in dets], -1)
    sensor = jnp.concatenate([jnp.full(d.mask.shape, s, jnp.int32) for s, d in enumerate(dets)],
                             -1)
    conf = jnp.full(mask.shape, confidence, z.dtype)
    return tracker.Detections(z, mask, sensor, conf, jnp.zeros(mask.shape + (0,), z.dtype))


# ---------------------------------------------------------------------------------------------
# Internals


@functools.partial(jax.jit, static_argnames=("M",))
def _sequence(key, pos, mask, model, region, pose, M):
    pos, mask = _as_arrays(pos, mask)
    model, pose = _cast(model, pose, pos.dtype)
    region_given = region is not None
    region = _bounding_box(pos, mask) if region is None else jnp.asarray(region, pos.dtype)
    T, P = mask.shape
    # One draw for the whole sequence: per-frame keys (split, then a draw each) compile much
    # slower, Threefry being most of the compile time (measurements: docs/design_notes.md,
    # "Synthetic detections: one random draw per sequence").
    u = jax.random.uniform(key, (T, _num_uniforms(P, M)), pos.dtype)
    frame = functools.partial(_frame, model=model, region=region, M=M,
                              region_given=region_given)
    return jax.vmap(lambda u_t, p, m, s: frame(u_t, p, m, sensor_pose=s),
                    in_axes=(0, 0, 0, 0 if pose.ndim == 2 else None))(u, pos, mask, pose)


@functools.partial(jax.jit, static_argnames=("M",))
def _detect(key, pos, mask, model, region, pose, M):
    pos, mask = _as_arrays(pos, mask)
    model, pose = _cast(model, pose, pos.dtype)
    region_given = region is not None
    region = jnp.zeros((2, 2), pos.dtype) if region is None else jnp.asarray(region, pos.dtype)
    u = jax.random.uniform(key, (_num_uniforms(mask.shape[0], M),), pos.dtype)
    return _frame(u, pos, mask, model=model, region=region, sensor_pose=pose, M=M,
                  region_given=region_given)


def _num_uniforms(P, M):
    return 4 * P + 5 * M + 1


def _as_arrays(pos, mask):
    """Float positions, zeroed where absent; NaN / inf slots count as absent."""
    pos = jnp.asarray(pos)
    if not jnp.issubdtype(pos.dtype, jnp.floating):
        pos = pos.astype(jnp.result_type(float))
    mask = jnp.asarray(mask, bool) & jnp.all(jnp.isfinite(pos), -1)
    return jnp.where(mask[..., None], pos, 0.0), mask


def _cast(model, pose, dtype):
    model = jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype), model)
    pose = jnp.zeros(3, dtype) if pose is None else jnp.asarray(pose, dtype)
    return model, pose


def _frame(u, pos, mask, *, model, region, sensor_pose, M, region_given):
    """One frame from ``u`` [_num_uniforms(P, M)] uniforms in [0, 1)."""
    dtype = pos.dtype
    P = pos.shape[0]
    u_det, u_num, u_box = u[:P], u[P], u[P + 1:P + 1 + 2 * M].reshape(M, 2)
    u_bear, u_rng = u[P + 1 + 2 * M:P + 1 + 3 * M], u[P + 1 + 3 * M:P + 1 + 4 * M]
    u_order = u[P + 1 + 4 * M:2 * P + 1 + 5 * M]
    u_noise = u[2 * P + 1 + 5 * M:].reshape(P, 2)
    # Normals by the inverse CDF, as `jax.random.normal` computes them.
    v = jnp.maximum(2 * u_noise - 1, jnp.nextafter(jnp.asarray(-1, dtype), 1))
    normal = jnp.sqrt(jnp.asarray(2, dtype)) * jax.lax.erf_inv(v)

    seen = mask & in_view(pos, model, sensor_pose)
    hit = seen & (u_det < model.p_detect)
    z_people = pos + model.noise_std * normal

    # Clutter: up to M points (more could never be kept).
    n = _truncated_poisson(u_num, model.clutter_rate, M)
    lo, hi = region[0], region[1]
    box = lo + (hi - lo) * u_box
    bearing = (u_bear - 0.5) * jnp.minimum(model.fov, 2 * jnp.pi)
    r_lo, r_hi = model.min_range, jnp.where(jnp.isfinite(model.max_range), model.max_range, 1.0)
    r = jnp.sqrt(r_lo**2 + u_rng * (r_hi**2 - r_lo**2))
    ang = bearing + sensor_pose[2]
    sector = sensor_pose[:2] + jnp.stack([r * jnp.cos(ang), r * jnp.sin(ang)], -1)
    # Without a region, a sensor of finite range draws its clutter in its own sector; otherwise
    # in the box, of which it reports only what it can see.
    use_sector = jnp.isfinite(model.max_range) & (not region_given)
    clutter_xy = jnp.where(use_sector, sector, box)
    keep = use_sector | (in_view(box, model, sensor_pose) & jnp.all(hi > lo))
    clutter_mask = (jnp.arange(M) < n) & keep

    cand_z = jnp.concatenate([z_people, clutter_xy])
    cand_mask = jnp.concatenate([hit, clutter_mask])
    cand_src = jnp.concatenate([jnp.arange(P, dtype=jnp.int32), jnp.full((M,), -1, jnp.int32)])
    # Valid candidates first, in uniformly random order (a random sort key in [0, 1) for the
    # valid ones, [1, 2) for the others): a uniformly random subset of at most M valid
    # detections, in random order.
    order_key = u_order + (~cand_mask).astype(dtype)
    first = jnp.argsort(order_key)[:M]
    out_mask = cand_mask[first]
    z = jnp.where(out_mask[:, None], cand_z[first], 0.0)
    src = jnp.where(out_mask, cand_src[first], -1)
    dropped = jnp.sum(cand_mask) - jnp.sum(out_mask)
    return SimulatedDetections(z, out_mask, src, n.astype(jnp.int32), dropped.astype(jnp.int32))


def _truncated_poisson(u, rate, cap):
    """min(N, cap) for N ~ Poisson(rate), from a uniform ``u`` by inverting the CDF at
    0 .. cap - 1 (exact, and cheaper to compile than `jax.random.poisson`'s samplers)."""
    k = jnp.arange(cap, dtype=rate.dtype)
    log_pmf = k * jnp.log(jnp.maximum(rate, jnp.finfo(rate.dtype).tiny)) - jax.lax.lgamma(k + 1)
    cdf = jnp.cumsum(jnp.exp(log_pmf - rate))
    cdf = jnp.where(rate > 0, cdf, 1.0)
    return jnp.sum(u >= cdf).astype(jnp.int32)


def _bounding_box(pos, mask, pad=1.0):
    big = jnp.asarray(jnp.finfo(pos.dtype).max, pos.dtype)
    lo = jnp.min(jnp.where(mask[..., None], pos, big), axis=tuple(range(pos.ndim - 1)))
    hi = jnp.max(jnp.where(mask[..., None], pos, -big), axis=tuple(range(pos.ndim - 1)))
    anyone = jnp.any(mask)
    lo = jnp.where(anyone, lo - pad, -pad)
    hi = jnp.where(anyone, hi + pad, pad)
    return jnp.stack([lo, hi])


def _check_positions(pos, mask):
    mask_dtype = mask.dtype if hasattr(mask, "dtype") else np.asarray(mask).dtype
    if mask_dtype != np.bool_:
        raise ValueError(f"mask must be bools; got dtype {mask_dtype}")
    if _checks.is_concrete(pos) and _checks.is_concrete(mask):
        finite = np.all(np.isfinite(np.asarray(pos)), -1)
        if not np.all(finite | ~np.asarray(mask)):
            raise ValueError("positions contain NaN or inf where the mask is True")


def _check_key(key):
    k = jnp.asarray(key) if not hasattr(key, "dtype") else key
    if not (jnp.issubdtype(k.dtype, jax.dtypes.prng_key)
            or (k.dtype == jnp.uint32 and k.shape == (2,))):
        raise ValueError(f"key must be a PRNG key (jax.random.key); got {k.dtype} {k.shape}")


def _check_capacity(M):
    if isinstance(M, bool) or not isinstance(M, (int, np.integer)) or M < 1:
        raise ValueError(f"max_detections must be a positive int; got {M!r}")
    return int(M)


def _check_pose(pose, T=None):
    if pose is None:
        return None
    if T is not None and np.ndim(pose) == 2:
        _checks.check_shape("sensor_pose", pose, (T, 3), "[T, 3] per-frame poses")
    else:
        _checks.check_shape("sensor_pose", pose, (3,), "(x, y, heading), or [T, 3]")
    _checks.check_finite("sensor_pose", pose)
    return pose


def _check_region(region):
    _checks.check_shape("region", region, (2, 2), "[[x_min, y_min], [x_max, y_max]]")
    if _checks.is_concrete(region):
        r = np.asarray(region, np.float64)
        if not np.all(np.isfinite(r)) or not np.all(r[1] > r[0]):
            raise ValueError(f"region must be finite with max > min per axis; got {r.tolist()}")


def _check_model(model):
    if not isinstance(model, SensorModel):
        raise TypeError(f"model must be a SensorModel; got {type(model).__name__}")
    for name in SensorModel._fields:
        v = getattr(model, name)
        if np.ndim(v) != 0:
            raise ValueError(f"SensorModel.{name} must be a scalar; got shape "
                             f"{list(np.shape(v))}")
    if not all(_checks.is_concrete(v) for v in model):
        return
    v = {name: float(getattr(model, name)) for name in SensorModel._fields}
    rules = [("noise_std", np.isfinite(v["noise_std"]) and v["noise_std"] >= 0, ">= 0"),
             ("p_detect", 0 <= v["p_detect"] <= 1, "in [0, 1]"),
             ("clutter_rate", np.isfinite(v["clutter_rate"]) and v["clutter_rate"] >= 0,
              ">= 0"),
             ("fov", v["fov"] > 0, "> 0 (rad)"),
             ("min_range", np.isfinite(v["min_range"]) and v["min_range"] >= 0, ">= 0"),
             ("max_range", v["max_range"] > v["min_range"], "> min_range")]
    for name, ok, what in rules:
        if not ok:
            raise ValueError(f"SensorModel.{name} must be {what}; got {v[name]}")


def _check_frame(pos, mask, model, M, region, pose):
    _checks.check_ndim("pos", pos, 2, "[P, 2] positions")
    P = _checks.shape_of(pos)[0]
    _checks.check_shape("pos", pos, (P, 2), "[P, 2] positions")
    _checks.check_shape("mask", mask, (P,), "[P] bools")
    _check_positions(pos, mask)
    _check_model(model)
    M = _check_capacity(M)
    if region is not None:
        _check_region(region)
    return pos, mask, region, _check_pose(pose), M
