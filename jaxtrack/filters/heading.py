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

**Windowed variant** (`windowed_heading_step`, ours). Run at 10 Hz, eq. 13 lets a 1 s step
backwards at 0.3 m/s (:math:`\beta = 0.62` per frame) turn the heading most of the way round:
the seed's "moving slightly backwards" is handled only below 0.1 m/s. The windowed filter
drives eqs. 12-13 with the mean velocity over the last :math:`W` frames,
:math:`\bar v = (p_k - p_{k-W}) / (W\,\Delta t)`, and holds the heading while that
displacement is shorter than :math:`d_{min}`:

.. math::
    \theta(k+1) = \begin{cases} \beta(\|\bar v\|)\,\theta(k) + (1-\beta(\|\bar v\|))
    \operatorname{atan2}(\bar v_y, \bar v_x) & \|p_k - p_{k-W}\| \ge d_{min} \\
    \theta(k) & \text{otherwise.} \end{cases}

A step (a few tenths of a metre, then still) never reaches :math:`d_{min}` = 0.5 m within the
2 s window; walking at 0.5 m/s does after 1 s, and the heading then follows as in the seed.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxtrack import _checks
from jaxtrack.angles import wrap

Array = jax.Array

__all__ = ["HeadingParams", "ar_coefficient", "ar_heading_step", "ar_heading_filter",
           "WindowedHeading", "windowed_heading_init", "windowed_heading_step"]


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


class WindowedHeading(NamedTuple):
    """State of `windowed_heading_step`.

    Attributes:
      positions: [W, 2] the last W positions, a ring buffer (oldest at ``count % W``).
      count: int32 steps taken.
      heading: scalar heading (rad).
    """

    positions: Array
    count: Array
    heading: Array


def windowed_heading_init(heading0, position: Array, window: int) -> WindowedHeading:
    """The filter's state at the first frame: the buffer filled with ``position`` [2].

    Example:
      >>> state = windowed_heading_init(0.0, jnp.zeros(2), window=20)
    """
    if int(window) != window or window < 1:
        raise ValueError(f"window must be a positive number of frames; got {window}")
    position = jnp.asarray(position)
    _checks.check_shape("position", position, (2,), "(x, y)")
    dtype = jnp.result_type(position.dtype, jnp.float32)
    return WindowedHeading(jnp.broadcast_to(position.astype(dtype), (int(window), 2)),
                           jnp.int32(0), jnp.asarray(heading0, dtype))


def windowed_heading_step(state: WindowedHeading, position: Array, dt,
                          params: HeadingParams = HeadingParams(),
                          min_distance=0.5) -> WindowedHeading:
    r"""One step of the windowed AR filter (module docstring).

    Args:
      state: `WindowedHeading` (from `windowed_heading_init`).
      position: [2] the person's estimated position this frame (the heading's frame).
      dt: the frame period (s).
      params: eq. 13's coefficients, applied to the window's mean speed.
      min_distance: :math:`d_{min}` (m), the displacement over the window below which the
        heading is held.

    Returns:
      The next `WindowedHeading`; its ``heading`` is wrapped to [-pi, pi).

    Example:
      >>> s = windowed_heading_init(0.0, jnp.zeros(2), 20)
      >>> for k in range(40):                      # walking along +y at 0.5 m/s
      ...     s = windowed_heading_step(s, jnp.array([0.0, 0.05 * (k + 1)]), 0.1)
      >>> float(s.heading)                         # about pi / 2
    """
    W = state.positions.shape[0]
    position = jnp.asarray(position, state.positions.dtype)
    slot = state.count % W
    d = position - state.positions[slot]
    mean_velocity = d / (W * dt)
    moved = jnp.sum(d * d) >= jnp.asarray(min_distance, d.dtype) ** 2
    # a missing position (NaN) is skipped: no turn, and the window does not advance
    finite = jnp.all(jnp.isfinite(position))
    turned = ar_heading_step(state.heading, mean_velocity, params)
    heading = jnp.where(moved & finite, turned, state.heading).astype(state.heading.dtype)
    positions = jnp.where(finite, state.positions.at[slot].set(position), state.positions)
    return WindowedHeading(positions, state.count + finite.astype(jnp.int32), heading)
