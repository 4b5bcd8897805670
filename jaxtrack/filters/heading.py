r"""Adaptive autoregressive heading filter of seed 002 (Svenstrup et al., eqs. 12-13).

The heading (pose) of a person is filtered from the estimated velocity so that a person
shuffling backwards does not flip around:

.. math::
    \theta(k+1) = \beta\,\theta(k) + (1 - \beta)\operatorname{atan2}(v_y, v_x),\qquad
    \beta = \begin{cases} 0.9 & v < 0.1\ \mathrm{m/s} \\ 1.04 - 1.4 v & 0.1 \le v \le 0.6 \\
    0.2 & v > 0.6 \end{cases}

The blend is taken on the circle, :math:`\theta + (1-\beta)\,\mathrm{wrap}(\phi - \theta)`, so
that 179 deg and -179 deg average to 180 deg rather than 0. The coefficients are leaves of
`HeadingParams`, so they can be tuned; the paper's values are the defaults.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxtrack import _checks
from jaxtrack.angles import wrap

Array = jax.Array

__all__ = ["HeadingParams", "ar_coefficient", "ar_heading_step", "ar_heading_filter"]


class HeadingParams(NamedTuple):
    """beta = slow below v_slow, intercept - slope * v in between, fast above v_fast."""

    slow: float = 0.9
    intercept: float = 1.04
    slope: float = 1.4
    fast: float = 0.2
    v_slow: float = 0.1
    v_fast: float = 0.6


def ar_coefficient(speed: Array, params: HeadingParams = HeadingParams()) -> Array:
    """The adaptive coefficient beta(v) of eq. 13 (elementwise)."""
    mid = params.intercept - params.slope * speed
    return jnp.where(speed < params.v_slow, params.slow,
                     jnp.where(speed > params.v_fast, params.fast, mid))


def ar_heading_step(heading: Array, velocity: Array,
                    params: HeadingParams = HeadingParams()) -> Array:
    """One step of eq. 12 on the circle.

    Args:
      heading: scalar current heading (rad).
      velocity: [2] estimated person velocity (same frame as the heading).
      params: filter coefficients.

    Returns:
      The new heading, wrapped to [-pi, pi).

    Example:
      >>> ar_heading_step(0.0, jnp.array([0.0, 1.0]))  # 0.8 * pi / 2
    """
    vx, vy = velocity[..., 0], velocity[..., 1]
    sq = vx**2 + vy**2
    speed = jnp.where(sq > 0, jnp.sqrt(jnp.where(sq > 0, sq, 1.0)), 0.0)
    beta = ar_coefficient(speed, params)
    direction = jnp.arctan2(vy, vx)
    return wrap(heading + (1.0 - beta) * wrap(direction - heading))


def ar_heading_filter(heading0: Array, velocities: Array,
                      params: HeadingParams = HeadingParams()) -> Array:
    """Run `ar_heading_step` over velocities [T, 2] under `lax.scan`; returns headings [T].

    Example:
      >>> thetas = ar_heading_filter(0.0, result.means[:, 2:4])
    """
    _checks.check_ndim("velocities", velocities, 2, "[T, 2] velocities")
    _checks.check_shape("velocities", velocities, (None, 2))

    def body(theta, v):
        nxt = ar_heading_step(theta, v, params)
        return nxt, nxt

    _, thetas = lax.scan(body, jnp.asarray(heading0, jnp.result_type(velocities)), velocities)
    return thetas
