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

**Sustained motion** (``segments`` = n >= 2). Two steps in a row (0.6 m in 2 s), the end of
a walk followed by a step sideways, or an estimate that jumps to clutter, also cover 0.5 m, and
turn the heading towards a direction the person never faced. With ``segments``, the window's
W positions (the newest included) are cut into n consecutive pieces and each piece is averaged,
:math:`c_1 \dots c_n` (the averages also take the frame-to-frame noise of the estimate out,
0.1-0.3 m with a 0.3 m RGB-D sensor). Each move between neighbouring pieces must cover
:math:`d_{min}/n` the way of the whole, :math:`D = c_n - c_1` (cosine at least
``SUSTAINED_COS``):

.. math::
    \|c_{j+1} - c_j\| \ge d_{min}/n,\qquad (c_{j+1} - c_j) \cdot D \ge
    c_{min}\,\|c_{j+1} - c_j\|\,\|D\| \qquad (j = 1 \dots n-1).

With :math:`W` = 2 s, n = 3 and :math:`d_{min}` = 0.8 m, a person walking at 0.5 m/s passes
(0.33 m between pieces two thirds of a second apart, against 0.27 m needed), while a 1 s step
at 0.3 m/s (0.2 m) never does, alone, twice in a row, or after a walk, and neither does a
single jump of the estimate. The sustained filter also turns towards the *chord* of the walk
rather than the window's displacement: from the point :math:`a` where the sustained motion
began (:math:`c_1` at its first sustained frame), pulled along at most ``chord`` metres behind
the person, :math:`\phi = \operatorname{atan2}(c_n - a)`. A laser's position estimate errs
across the walk by about 0.1 m; over the window's 1 m that is 6 deg, over a 2 m walk 3 deg.
The speed in eq. 13 is then :math:`\|D\| / ((n-1) W \Delta t / n)`.
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
           "WindowedHeading", "windowed_heading_init", "windowed_heading_step",
           "SUSTAINED_COS"]

# the pieces of a sustained window may turn from its whole by up to about 45 deg (a walker's turn)
SUSTAINED_COS = 0.7


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
      anchor: [2] where the current sustained motion began (``segments`` >= 2 only).
      moving: bool, the last frame's motion was sustained (``segments`` >= 2 only).
    """

    positions: Array
    count: Array
    heading: Array
    anchor: Array
    moving: Array


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
                           jnp.int32(0), jnp.asarray(heading0, dtype), position.astype(dtype),
                           jnp.asarray(False))


def windowed_heading_step(state: WindowedHeading, position: Array, dt,
                          params: HeadingParams = HeadingParams(),
                          min_distance=0.5, segments: int = 1,
                          chord=2.5) -> WindowedHeading:
    r"""One step of the windowed AR filter (module docstring).

    Args:
      state: `WindowedHeading` (from `windowed_heading_init`).
      position: [2] the person's estimated position this frame (the heading's frame).
      dt: the frame period (s).
      params: eq. 13's coefficients, applied to the window's mean speed.
      min_distance: :math:`d_{min}` (m), the displacement over the window below which the
        heading is held.
      segments: n (static); from 2, require each of n pieces of the window to cover
        ``min_distance / n`` the way of the whole, and turn towards the walk's chord (module
        docstring); 1: the plain windowed filter.
      chord: with ``segments`` >= 2, the longest chord (m) the heading is taken over.

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
    d_min = jnp.asarray(min_distance, d.dtype)
    moved = jnp.sum(d * d) >= d_min ** 2
    sustained = int(segments) >= 2
    if sustained:
        n = int(segments)
        if n > W:
            raise ValueError(f"segments ({n}) must not exceed the window ({W} frames)")
        # the window's W positions, oldest first, the newest being this frame's
        order = (state.count + 1 + jnp.arange(W)) % W
        window = state.positions.at[slot].set(position)[order]
        cuts = [(j * W) // n for j in range(n + 1)]
        centres = jnp.stack([jnp.mean(window[a:b], 0) for a, b in zip(cuts[:-1], cuts[1:])])
        moves = centres[1:] - centres[:-1]                                  # [n - 1, 2]
        lengths = jnp.sqrt(jnp.sum(moves * moves, -1))
        whole = centres[-1] - centres[0]
        total = jnp.sqrt(jnp.sum(whole * whole))
        moved = jnp.all((lengths >= d_min / n)
                        & (moves @ whole >= SUSTAINED_COS * lengths * total))
        anchor = jnp.where(moved & ~state.moving, centres[0], state.anchor)
        along = centres[-1] - anchor
        length = jnp.sqrt(jnp.sum(along * along))
        pull = moved & (length > chord)
        anchor = jnp.where(pull, centres[-1] - along * (chord / jnp.where(pull, length, 1.0)),
                           anchor)
        # eq. 13's coefficient from the pieces' speed, the direction from the chord
        speed = total / ((n - 1) * W * dt / n)
        mean_velocity = along * (speed / jnp.where(length > 0, length, 1.0))
    # a missing position (NaN) is skipped: no turn, and the window does not advance
    finite = jnp.all(jnp.isfinite(position))
    turned = ar_heading_step(state.heading, mean_velocity, params)
    heading = jnp.where(moved & finite, turned, state.heading).astype(state.heading.dtype)
    positions = jnp.where(finite, state.positions.at[slot].set(position), state.positions)
    if sustained:
        anchor = jnp.where(finite, anchor, state.anchor).astype(state.anchor.dtype)
        moving = jnp.where(finite, moved, state.moving)
    else:
        anchor, moving = state.anchor, state.moving
    return WindowedHeading(positions, state.count + finite.astype(jnp.int32), heading, anchor,
                           moving)
