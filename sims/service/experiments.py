r"""The five experiments of the service-robot scene, as random initial conditions.

Each `sample` draws, from one key, the people (`sims.service.people`), the robot's start pose
and its task in the flat (`sims.service.flat`):

- ``avoid``: the robot crosses the corridor from its left end to its right end (10.4 m); two or
  three people stand in the corridor at random places and headings, spaced so that a way past
  them outside their intimate zones exists. Rule: never inside anyone's intimate zone.
- ``overtake``: the robot crosses the corridor the same way; a person walks ahead of it, in the
  same direction, keeping to the right of the corridor (0.1-0.35 m right of its centre line), at
  0.35-0.5 m/s, starting 1.2-1.6 m ahead, and turns into the living room at its door. Rule:
  pass them on their left.
- ``tv``: the robot crosses the living room from below the couch-TV axis to above it; one to
  three people sit on the couch watching the TV. Rule: never cross a person-TV interaction.
- ``handover``: a person walks into the kitchen's hand-over area and waits there; the robot
  comes from the corridor. Task: stop inside their personal zone (0.45-1.2 m), in front of them
  (within 30 deg of their heading), facing them.
- ``approach`` (seed 002): a person walks 2 m to a place in the kitchen and stands there,
  stepping backwards or sideways now and then; the robot starts 2.5-3.5 m from that place and
  follows the gradient of the person-interest potential field. Task: the final pose seed 002
  gives for the person's interest.

Capacity: `NUM_PEOPLE` people (unused rows masked).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from sims.service import flat
from sims.service import people as people_mod

Array = jax.Array

__all__ = ["EXPERIMENTS", "NUM_PEOPLE", "Setup", "sample"]

EXPERIMENTS = ("avoid", "overtake", "tv", "handover", "approach")
NUM_PEOPLE = 4
CORRIDOR_Y = -2.7


class Setup(NamedTuple):
    """An episode's start: people (`People`), robot [3] pose, goal [2] (the navigation goal;
    for ``handover`` and ``approach`` the person's start), target: int32 index of the person
    the task is about (-1 none)."""

    people: people_mod.People
    robot: Array
    goal: Array
    target: Array


def _pad(x, P, fill=0.0):
    x = jnp.asarray(x)
    pad = [(0, P - x.shape[0])] + [(0, 0)] * (x.ndim - 1)
    return jnp.pad(x, pad, constant_values=fill)


def _setup(people_rows, robot, goal, target, dtype):
    """``people_rows``: dict of [n, ...] arrays for the present people, padded to NUM_PEOPLE."""
    P = NUM_PEOPLE
    n = people_rows["pos"].shape[0]
    route = people_rows.get("route", people_rows["pos"][:, None, :])
    W = route.shape[1]
    ppl = people_mod.make(
        _pad(people_rows["pos"], P), _pad(people_rows["heading"], P),
        _pad(people_rows["role"], P, people_mod.STANDER).astype(jnp.int32),
        jnp.arange(P) < n, route=_pad(route, P).reshape(P, W, 2),
        route_len=_pad(people_rows.get("route_len", jnp.ones(n, jnp.int32)), P, 1),
        speed=_pad(people_rows.get("speed", jnp.full(n, 0.5)), P, 0.5),
        steps=_pad(people_rows.get("steps", jnp.zeros(n, bool)), P, False), dtype=dtype)
    return Setup(ppl, jnp.asarray(robot, dtype), jnp.asarray(goal, dtype), jnp.int32(target))


def _avoid(key, dtype):
    k = jax.random.split(key, 5)
    n = jax.random.randint(k[0], (), 2, 4)
    # one person per corridor third, so a way past each one exists
    x = jnp.array([-2.6, 0.2, 3.0]) + jax.random.uniform(k[1], (3,), minval=-0.6, maxval=0.6)
    y = jax.random.uniform(k[2], (3,), minval=-3.3, maxval=-2.1)
    heading = jax.random.uniform(k[3], (3,), minval=-jnp.pi, maxval=jnp.pi)
    rows = dict(pos=jnp.stack([x, y], -1), heading=heading,
                role=jnp.full(3, people_mod.STANDER))
    s = _setup(rows, [-5.2, CORRIDOR_Y, 0.0], [5.2, CORRIDOR_Y], -1, dtype)
    return s._replace(people=s.people._replace(mask=s.people.mask & (jnp.arange(NUM_PEOPLE) < n)))


def _overtake(key, dtype):
    k = jax.random.split(key, 4)
    # they keep to the right of the corridor (its lower half, walking along +x), as walkers
    # do: a 0.6 m robot passing on their left then keeps out of their intimate zone
    y = CORRIDOR_Y + jax.random.uniform(k[0], (), minval=-0.35, maxval=-0.1)
    x0 = -5.2 + jax.random.uniform(k[1], (), minval=1.2, maxval=1.6)
    speed = jax.random.uniform(k[2], (), minval=0.35, maxval=0.5)
    # along the corridor, then up through the living room's door
    route = jnp.stack([jnp.stack([2.9, y]), jnp.array([3.0, -0.4])])[None]
    rows = dict(pos=jnp.array([[x0, y]]), heading=jnp.zeros(1), role=jnp.array([0]),
                route=route, route_len=jnp.array([2]), speed=speed[None])
    ry = CORRIDOR_Y + jax.random.uniform(k[3], (), minval=-0.15, maxval=0.15)
    return _setup(rows, [-5.2, ry, 0.0], [5.2, CORRIDOR_Y], 0, dtype)


def _tv(key, dtype):
    k = jax.random.split(key, 3)
    n = jax.random.randint(k[0], (), 1, 4)
    order = jax.random.permutation(k[1], 3)
    seats = jnp.asarray(flat.SEATS)[order]
    rows = dict(pos=seats, heading=jnp.zeros(3), role=jnp.full(3, people_mod.SEATED))
    x = 4.3 + jax.random.uniform(k[2], (2,), minval=-0.5, maxval=0.5)
    s = _setup(rows, [x[0], -0.8, 0.5 * jnp.pi], [x[1], 3.4], -1, dtype)
    return s._replace(people=s.people._replace(mask=s.people.mask & (jnp.arange(NUM_PEOPLE) < n)))


def _handover(key, dtype):
    k = jax.random.split(key, 3)
    x0, y0, x1, y1 = flat.HANDOVER_AREA
    u = jax.random.uniform(k[0], (2,))
    wait = jnp.array([x0 + 0.3 + u[0] * (x1 - x0 - 0.6), y0 + 0.3 + u[1] * (y1 - y0 - 0.6)])
    # they come from the left part of the kitchen or from its top, and face the way they came
    starts = jnp.array([[-4.8, -0.6], [-4.8, 2.6], [-2.0, 3.1], [-0.6, 3.1]])
    start = starts[jax.random.randint(k[1], (), 0, 4)]
    rows = dict(pos=start[None], heading=jnp.zeros(1), role=jnp.array([people_mod.WAITER]),
                route=wait[None, None], speed=jnp.array([0.6]))
    rx = -3.0 + jax.random.uniform(k[2], (), minval=-1.5, maxval=1.5)
    return _setup(rows, [rx, CORRIDOR_Y, 0.5 * jnp.pi], wait, 0, dtype)


def _approach(key, dtype):
    k = jax.random.split(key, 4)
    stop = jnp.array([-2.4, 1.0]) + jax.random.uniform(k[0], (2,), minval=-0.4, maxval=0.4)
    heading = jax.random.uniform(k[1], (), minval=-jnp.pi, maxval=jnp.pi)
    # they walk 2 m to their place along their final heading (so that the heading can be
    # estimated from their motion), then stand there
    start = stop - 2.0 * jnp.array([jnp.cos(heading), jnp.sin(heading)])
    # the robot starts 2.5-3.5 m from that place, within 120 deg of the heading, in the kitchen
    bearing = heading + jax.random.uniform(k[2], (), minval=-2.1, maxval=2.1)
    r = jax.random.uniform(k[3], (), minval=2.5, maxval=3.5)
    lo, hi = jnp.array([-5.5, -0.9]), jnp.array([-0.5, 3.1])
    robot_xy = jnp.clip(stop + r * jnp.array([jnp.cos(bearing), jnp.sin(bearing)]), lo, hi)
    start = jnp.clip(start, lo, hi)
    toward = jnp.arctan2(stop[1] - robot_xy[1], stop[0] - robot_xy[0])
    rows = dict(pos=start[None], heading=heading[None], role=jnp.array([people_mod.WAITER]),
                route=stop[None, None], speed=jnp.array([0.5]), steps=jnp.array([True]))
    return _setup(rows, jnp.append(robot_xy, toward), stop, 0, dtype)


_SAMPLERS = dict(avoid=_avoid, overtake=_overtake, tv=_tv, handover=_handover,
                 approach=_approach)


def sample(key: Array, experiment: str, dtype=jnp.float32) -> Setup:
    """The start of one episode of ``experiment`` (`EXPERIMENTS`).

    Example:
      >>> s = sample(jax.random.key(0), "tv")
      >>> s.people.pos.shape      # (NUM_PEOPLE, 2)
    """
    if experiment not in _SAMPLERS:
        raise ValueError(f"unknown experiment {experiment!r}; choose one of {EXPERIMENTS}")
    return _SAMPLERS[experiment](key, dtype)


def free_floor() -> np.ndarray:
    """[R, 4] boxes (x0, y0, x1, y1) of the flat's rooms and corridor."""
    return np.array([flat.CORRIDOR, flat.KITCHEN, flat.LIVING_ROOM])
