r"""Measurement models: position, range-bearing, and seed 002's person + odometry sensor."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack.angles import wrap

Array = jax.Array

__all__ = ["position", "range_bearing", "range_bearing_residual", "person_relative"]


def position(n: int, dim: int = 2, dtype=None) -> Array:
    r"""Position sensor :math:`H = [I_{dim}\; 0]`, for states whose first ``dim`` entries are the
    position (all motion models of `jaxtrack.models.motion`).

    Returns:
      ``H`` [dim, n].

    Example:
      >>> H = position(4)  # [[1, 0, 0, 0], [0, 1, 0, 0]]
    """
    if dim > n:
        raise ValueError(f"dim ({dim}) must be <= n ({n})")
    return jnp.eye(dim, n, dtype=dtype)


def range_bearing(x: Array, origin: Array | None = None) -> Array:
    r"""Range and bearing of the position ``x[:2]`` seen from ``origin`` (default the origin).

    .. math:: h(x) = [\sqrt{\Delta x^2 + \Delta y^2},\; \operatorname{atan2}(\Delta y, \Delta x)].

    Use with ``residual=range_bearing_residual`` so the bearing innovation is wrapped. Range and
    bearing are computed safely at the sensor position itself (value 0, finite gradients).

    Args:
      x: [n] state with the position first. origin: optional [2] sensor position.

    Returns:
      [2] ``(range, bearing)``.

    Example:
      >>> range_bearing(jnp.array([1.0, 1.0, 0.0, 0.0]))  # [1.414, 0.785]
    """
    d = x[:2] if origin is None else x[:2] - origin
    sq = d[0] ** 2 + d[1] ** 2
    away = sq > 0
    rng = jnp.where(away, jnp.sqrt(jnp.where(away, sq, 1.0)), 0.0)
    bearing = jnp.where(away, jnp.arctan2(jnp.where(away, d[1], 0.0), jnp.where(away, d[0], 1.0)),
                        0.0)
    return jnp.stack([rng, bearing])


def range_bearing_residual(a: Array, b: Array) -> Array:
    """``a - b`` with the bearing component wrapped to [-pi, pi)."""
    d = a - b
    return d.at[..., 1].set(wrap(d[..., 1]))


def person_relative(dtype=None) -> Array:
    r"""Seed 002's measurement matrix (eq. 7): person position from the laser and robot velocity
    from odometry, for the state ``[p_x, p_y, v_x, v_y, v_rx, v_ry]``.

    Returns:
      ``H`` [4, 6].

    Example:
      >>> H = person_relative()
    """
    H = np.zeros((4, 6))
    H[0, 0] = H[1, 1] = H[2, 4] = H[3, 5] = 1.0
    return jnp.asarray(H, dtype=dtype)
