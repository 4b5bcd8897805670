r"""The people of the service-robot scene: scripted walkers, standers, seated viewers and a person
waiting for a hand-over, with the occasional step backwards or sideways.

Every person has a *role* and a short route of waypoints:

- `WALKER`: walks its waypoints at its own speed, turning toward each, and stands at the last
  (from then on it stays where it is: a later step does not send it back);
  it stops while the robot is close ahead of it (0.7 m, within 60 deg of its heading), as a
  person would rather than walk into it;
- `STANDER`: stands at its place, facing its heading;
- `SEATED`: sits at a couch seat facing the TV (its legs stay where a seated person's shins
  are, at the front of the seat, for the laser);
- `WAITER`: walks to a point of the hand-over area, then stands there facing the way it came.

A person with ``steps`` set takes, with probability ``step_rate`` per second while standing, a
1 s step of ``step_speed`` (0.3 m/s) backwards or to either side while keeping their heading:
the motion that turns a velocity-based heading around and for which seed 002's adaptive
heading filter exists ("the person stands still, and might even move slightly backwards").
Walkers and waiters step only once at their place; seated people never step.

The state converts to the following scene's `sims.following.pedestrians.PedestrianState`
(`as_pedestrians`), so the laser, the RGB-D detector and the MJX mocap bodies of
`sims.following` see them unchanged.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from sims.following import pedestrians

Array = jax.Array

__all__ = ["WALKER", "STANDER", "SEATED", "WAITER", "People", "make", "step",
           "as_pedestrians", "STEP_SPEED", "STEP_DURATION"]

WALKER, STANDER, SEATED, WAITER = 0, 1, 2, 3
STEP_SPEED = 0.3
STEP_DURATION = 1.0
_REACHED = 0.15
_YIELD_DISTANCE = 0.7


class People(NamedTuple):
    """``P`` scripted people.

    Attributes:
      pos, vel: [P, 2] (m, m/s); heading: [P] facing direction (rad); phase: [P] gait phase.
      mask: [P] bool, present people; role: [P] int32 (`WALKER`...).
      route: [P, W, 2] waypoints; route_len: [P] int32 used waypoints (>= 1); leg: [P] int32
        the waypoint walked to; speed: [P] walking speed (m/s).
      steps: [P] bool, takes occasional steps; step_rate: [P] steps per second;
      step_timer: [P] time left in the current step (s); step_vel: [P, 2] its velocity.
    """

    pos: Array
    vel: Array
    heading: Array
    phase: Array
    mask: Array
    role: Array
    route: Array
    route_len: Array
    leg: Array
    speed: Array
    steps: Array
    step_rate: Array
    step_timer: Array
    step_vel: Array


def make(pos, heading, role, mask, route=None, route_len=None, speed=None, steps=None,
         step_rate=0.2, dtype=jnp.float32) -> People:
    """People at ``pos`` [P, 2] facing ``heading`` [P] with roles ``role`` [P]; ``route``
    [P, W, 2] (default: their own position), ``route_len`` [P] (default 1), ``speed`` [P]
    (default 0.5 m/s), ``steps`` [P] bool (default False).

    Example:
      >>> ppl = make(jnp.array([[0.0, 0.0]]), jnp.zeros(1), jnp.array([STANDER]),
      ...            jnp.array([True]))
    """
    pos = jnp.asarray(pos, dtype)
    P = pos.shape[0]
    route = pos[:, None, :] if route is None else jnp.asarray(route, dtype)
    route_len = (jnp.ones(P, jnp.int32) if route_len is None
                 else jnp.asarray(route_len, jnp.int32))
    speed = jnp.full(P, 0.5, dtype) if speed is None else jnp.asarray(speed, dtype)
    steps = jnp.zeros(P, bool) if steps is None else jnp.asarray(steps, bool)
    z = jnp.zeros(P, dtype)
    return People(pos, jnp.zeros((P, 2), dtype), jnp.asarray(heading, dtype), z,
                  jnp.asarray(mask, bool), jnp.asarray(role, jnp.int32), route, route_len,
                  jnp.zeros(P, jnp.int32), speed, steps,
                  jnp.broadcast_to(jnp.asarray(step_rate, dtype), (P,)), z,
                  jnp.zeros((P, 2), dtype))


def _unit(v):
    n = jnp.sqrt(jnp.sum(v * v, -1, keepdims=True) + 1e-12)
    return v / n, n[..., 0]


def step(key: Array, people: People, robot_pose: Array, dt) -> People:
    """One period ``dt`` of every person (module docstring); ``robot_pose`` [3] the robot's
    true pose, which walkers yield to."""
    dtype = people.pos.dtype
    P = people.pos.shape[0]
    k_start, k_dir = jax.random.split(key)
    # Where the route stands.
    idx = jnp.minimum(people.leg, people.route_len - 1)
    target = jnp.take_along_axis(people.route, idx[:, None, None], 1)[:, 0]
    direction, dist = _unit(target - people.pos)
    last = people.leg >= people.route_len - 1
    done = people.leg >= people.route_len          # arrived earlier: stays where they are
    arrived = done | (last & (dist < _REACHED))
    mobile = (people.role == WALKER) | (people.role == WAITER)
    # The occasional step, taken standing (a walker on its way does not step aside).
    start = (people.steps & (people.step_timer <= 0) & (people.role != SEATED)
             & (arrived | ~mobile)
             & (jax.random.uniform(k_start, (P,), dtype) < people.step_rate * dt))
    choice = jax.random.randint(k_dir, (P,), 0, 3)          # back, left, right
    turn = jnp.asarray([jnp.pi, 0.5 * jnp.pi, -0.5 * jnp.pi], dtype)[choice]
    d = people.heading + turn
    new_vel = STEP_SPEED * jnp.stack([jnp.cos(d), jnp.sin(d)], -1)
    timer = jnp.where(start, STEP_DURATION, people.step_timer)
    step_vel = jnp.where(start[:, None], new_vel, people.step_vel)
    stepping = timer > 0
    # Walking the route.
    to_robot, d_robot = _unit(robot_pose[:2] - people.pos)
    facing = jnp.stack([jnp.cos(people.heading), jnp.sin(people.heading)], -1)
    blocked = (d_robot < _YIELD_DISTANCE) & (jnp.sum(to_robot * facing, -1) > 0.5)
    walking = mobile & ~arrived & ~stepping & ~blocked
    speed = jnp.minimum(people.speed, dist / dt)
    vel = jnp.where(walking[:, None], speed[:, None] * direction, 0.0)
    vel = jnp.where(stepping[:, None], step_vel, vel)
    vel = jnp.where(people.mask[:, None], vel, 0.0)
    pos = people.pos + vel * dt
    heading = jnp.where(walking & (dist > 1e-3),
                        jnp.arctan2(direction[:, 1], direction[:, 0]), people.heading)
    leg = jnp.where(mobile & ~done & (dist < _REACHED), people.leg + 1, people.leg)
    spd = jnp.sqrt(jnp.sum(vel * vel, -1))
    phase = jnp.mod(people.phase + 2.0 * jnp.pi * pedestrians.cadence(spd) * dt, 2.0 * jnp.pi)
    return people._replace(pos=pos, vel=vel, heading=heading, phase=phase, leg=leg,
                           step_timer=jnp.maximum(timer - dt, 0.0), step_vel=step_vel)


def as_pedestrians(people: People) -> pedestrians.PedestrianState:
    """The following scene's `PedestrianState` of these people (for the laser, the RGB-D
    detector and the MJX bodies)."""
    P = people.pos.shape[0]
    zero = jnp.zeros(P, people.pos.dtype)
    return pedestrians.PedestrianState(
        people.pos, people.vel, people.heading, people.phase, people.mask, people.pos,
        jnp.sqrt(jnp.sum(people.vel ** 2, -1)), zero, zero, jnp.zeros(P, bool))
