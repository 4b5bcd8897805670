"""Angles on the circle: wrapping, differences and weighted circular means."""

from __future__ import annotations

import jax
import jax.numpy as jnp

Array = jax.Array

__all__ = ["wrap", "difference", "circular_mean"]


def wrap(angle: Array) -> Array:
    """Wrap to [-pi, pi). Elementwise; differentiable (derivative 1 away from the cut).

    Example:
      >>> wrap(jnp.array(3 * jnp.pi / 2))  # -pi/2
    """
    return jnp.mod(angle + jnp.pi, 2.0 * jnp.pi) - jnp.pi


def difference(a: Array, b: Array) -> Array:
    """Shortest signed angle from ``b`` to ``a``: wrap(a - b), in [-pi, pi)."""
    return wrap(a - b)


def circular_mean(angles: Array, weights: Array | None = None, axis: int = 0) -> Array:
    r"""Weighted circular mean :math:`\operatorname{atan2}(\sum w \sin a, \sum w \cos a)`.

    Args:
      angles: [..., N, ...] angles in radians.
      weights: optional weights broadcastable to ``angles`` (need not be normalised; may be
        negative, as unscented weights are).
      axis: axis to reduce.

    Example:
      >>> circular_mean(jnp.array([3.1, -3.1]))  # close to pi, not 0
    """
    w = jnp.ones_like(angles) if weights is None else weights
    return jnp.arctan2(jnp.sum(w * jnp.sin(angles), axis), jnp.sum(w * jnp.cos(angles), axis))
