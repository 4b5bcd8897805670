r"""A camera on a pan unit, servoed to keep a target centred (seed 004, section V: the Kinect
sits on a pan/tilt unit that follows the user all around the robot).

The pan angle :math:`\psi` (relative to the robot's heading) follows the target's bearing
:math:`\beta` in the robot frame with a proportional rate command, limited in rate and in
acceleration, and clipped to the unit's range:

.. math::
    \dot\psi^* = \operatorname{clip}\big(k\,(\operatorname{clip}(\beta, \pm\psi_{max}) - \psi),
    \pm\dot\psi_{max}\big), \qquad
    \dot\psi_t = \dot\psi_{t-1} + \operatorname{clip}(\dot\psi^* - \dot\psi_{t-1},
    \pm\ddot\psi_{max}\,dt), \qquad
    \psi_t = \operatorname{clip}(\psi_{t-1} + \dot\psi_t\,dt, \pm\psi_{max}).

The tilt is fixed (people are seen at a fixed height); only the pan is servoed.

Example:
  >>> cfg = PanTiltConfig()
  >>> state = init()
  >>> state = servo(cfg, state, bearing=0.8, dt=0.1)
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxtrack.angles import wrap

Array = jax.Array

__all__ = ["PanTiltConfig", "PanState", "init", "servo"]


@dataclasses.dataclass(frozen=True)
class PanTiltConfig:
    """The pan unit.

    Attributes:
      limit: the pan range, +- this (rad; 150 deg).
      max_rate: rate limit (rad/s; 90 deg/s).
      max_accel: acceleration limit (rad/s^2; 360 deg/s^2).
      gain: proportional gain k of the rate command (1/s).
    """

    limit: float = math.radians(150.0)
    max_rate: float = math.radians(90.0)
    max_accel: float = math.radians(360.0)
    gain: float = 4.0

    def __post_init__(self):
        if not (0 < self.limit <= math.pi and self.max_rate > 0 and self.max_accel > 0
                and self.gain > 0):
            raise ValueError("need 0 < limit <= pi and positive max_rate, max_accel and gain")


class PanState(NamedTuple):
    """angle: the pan angle relative to the robot's heading (rad); rate: its rate (rad/s)."""

    angle: Array
    rate: Array


def init(dtype=jnp.float32) -> PanState:
    """The camera looking straight ahead, at rest."""
    return PanState(jnp.zeros((), dtype), jnp.zeros((), dtype))


def servo(config: PanTiltConfig, state: PanState, bearing, dt) -> PanState:
    """One servo step toward the target's ``bearing`` (robot frame, rad) over ``dt`` (s)
    (module docstring).

    Example:
      >>> state = servo(PanTiltConfig(), init(), 1.0, 0.1)   # turning toward 1 rad
    """
    dtype = state.angle.dtype
    bearing = wrap(jnp.asarray(bearing, dtype))
    goal = jnp.clip(bearing, -config.limit, config.limit)
    wanted = jnp.clip(config.gain * (goal - state.angle), -config.max_rate, config.max_rate)
    step = config.max_accel * dt
    rate = state.rate + jnp.clip(wanted - state.rate, -step, step)
    angle = state.angle + rate * dt
    clipped = jnp.clip(angle, -config.limit, config.limit)
    # At the end of its range the unit stops.
    rate = jnp.where(clipped != angle, 0.0, rate)
    return PanState(clipped.astype(dtype), rate.astype(dtype))
