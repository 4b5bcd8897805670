r"""Fixed-capacity detection frames: padding to a capacity, per-sensor measurement noise.

A scan of detections is a fixed-capacity array ``zs`` [M, m] with a boolean ``meas_mask`` [M]
(rule 3 of DESIGN.md). Several sensors may report in the same scan (seed 003: ceiling cameras
with 0.1 m noise, RGB-D with 0.3 m, laser legs with 0.2 m); each detection then carries a
``sensor`` index [M] into a stack of noise covariances ``R`` [S, m, m], and every association
function takes ``R`` either as one shared [m, m] matrix or as such a stack plus ``sensor``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import _checks

Array = jax.Array

__all__ = ["pad_detections", "noise_per_detection"]


def pad_detections(detections, capacity: int, sensor=None, *, fill: float = np.nan):
    """Pad a variable-length list of detections to a fixed capacity (host side, not traced).

    Use this at the boundary, where detections arrive from a sensor driver, to build the
    fixed-shape frames the jitted association functions take.

    Args:
      detections: [N, m] array-like of detections, N <= ``capacity``.
      capacity: the fixed number of detection slots M.
      sensor: optional [N] integer sensor index of each detection.
      fill: value of the padded rows (NaN by default: padded rows are ignored under their
        False mask, and a forgotten mask shows up as NaN rather than as a phantom detection).

    Returns:
      ``(zs, meas_mask)``, or ``(zs, meas_mask, sensor)`` when ``sensor`` is given:
      zs [capacity, m] (dtype of ``detections``, float), meas_mask [capacity] bool,
      sensor [capacity] int32 (0 in padded slots).

    Raises:
      ValueError: more detections than ``capacity``, or inconsistent shapes.

    Example:
      >>> zs, mask = pad_detections([[0.0, 1.0], [2.0, 3.0]], capacity=8)
      >>> zs.shape, int(mask.sum())
      ((8, 2), 2)
    """
    if not _checks.is_concrete(detections):
        raise TypeError("pad_detections runs on the host, outside jit; got a traced array")
    det = np.asarray(detections)
    if det.dtype.kind not in "fc":
        det = det.astype(np.float64 if jax.config.jax_enable_x64 else np.float32)
    if det.ndim == 1 and det.size == 0:
        raise ValueError("detections is empty and 1-D; pass an empty [0, m] array to give m")
    _checks.check_ndim("detections", det, 2, "an [N, m] array of detections")
    n, m = det.shape
    capacity = int(capacity)
    if capacity < 0:
        raise ValueError(f"capacity must be non-negative; got {capacity}")
    if n > capacity:
        raise ValueError(f"{n} detections do not fit in the capacity of {capacity} slots; "
                         "raise the capacity (it fixes the compiled shape) or drop detections")
    zs = np.full((capacity, m), fill, det.dtype)
    zs[:n] = det
    mask = np.zeros(capacity, bool)
    mask[:n] = True
    if sensor is None:
        return jnp.asarray(zs), jnp.asarray(mask)
    sensor = np.asarray(sensor)
    _checks.check_shape("sensor", sensor, (n,), "one sensor index per detection")
    if sensor.size and sensor.dtype.kind not in "iu":
        raise ValueError(f"sensor must hold integers; got dtype {sensor.dtype}")
    padded = np.zeros(capacity, np.int32)
    padded[:n] = sensor
    return jnp.asarray(zs), jnp.asarray(mask), jnp.asarray(padded)


def noise_per_detection(R: Array, sensor: Array | None, num_detections: int) -> Array:
    """The measurement-noise covariance of every detection slot, [M, m, m].

    Args:
      R: [m, m] (one sensor) or [S, m, m] (one covariance per sensor).
      sensor: [M] integer sensor index of each detection (required iff ``R`` is [S, m, m]).
        Indices are clipped to [0, S - 1] inside traced code; `check_noise` rejects
        out-of-range concrete indices at the boundary.
      num_detections: M.

    Returns:
      [M, m, m] covariances ``R[sensor[j]]`` (or ``R`` broadcast).

    Example:
      >>> R = jnp.stack([0.1**2 * jnp.eye(2), 0.3**2 * jnp.eye(2), 0.2**2 * jnp.eye(2)])
      >>> noise_per_detection(R, jnp.array([0, 2, 1]), 3).shape
      (3, 2, 2)
    """
    R = jnp.asarray(R)
    if R.ndim == 2:
        return jnp.broadcast_to(R, (num_detections,) + R.shape)
    idx = jnp.clip(jnp.asarray(sensor), 0, R.shape[0] - 1)
    return R[idx]


def check_noise(R, sensor, num_detections: int, m: int) -> None:
    """Boundary check of ``R`` [m, m] or [S, m, m] and ``sensor`` [M] (see module docstring)."""
    ndim = np.ndim(R)
    if ndim == 2:
        _checks.check_covariance("R", R, m)
        if sensor is not None:
            raise ValueError("sensor was given but R is a single [m, m] covariance; "
                             "pass R as [S, m, m], one covariance per sensor")
        return
    if ndim != 3:
        raise ValueError(f"R must be [m, m] or [S, m, m] (one per sensor); got shape "
                         f"{_checks.shape_of(R)}")
    _checks.check_covariance("R", R, m, batch_axes=1)
    if sensor is None:
        raise ValueError("R is a per-sensor stack [S, m, m]; pass sensor [M] with the sensor "
                         "index of every detection")
    _checks.check_shape("sensor", sensor, (num_detections,), "one sensor index per detection")
    if not jnp.issubdtype(jnp.result_type(sensor), jnp.integer):
        raise ValueError(f"sensor must hold integers; got dtype {jnp.result_type(sensor)}")
    if _checks.is_concrete(sensor):
        s = np.asarray(sensor)
        if s.size and (s.min() < 0 or s.max() >= np.shape(R)[0]):
            raise ValueError(f"sensor indices must lie in [0, {np.shape(R)[0] - 1}]; "
                             f"got values in [{s.min()}, {s.max()}]")


def check_frame(zs, H, n: int, meas_mask) -> tuple[int, int]:
    """Boundary check of a frame ``zs`` [M, m] against ``H`` [m, n] and ``meas_mask`` [M];
    returns (M, m)."""
    _checks.check_ndim("zs", zs, 2, "[M, m] detections")
    M, m = _checks.shape_of(zs)
    _checks.check_shape("H", H, (m, n), "measurement matrix")
    if meas_mask is not None:
        _checks.check_shape("meas_mask", meas_mask, (M,), "one flag per detection slot")
    return M, m
