r"""The flat of the service-robot scene (seed 003's setting): a corridor, a kitchen and a living
room with a couch facing a TV.

Plan (metres, the origin at the flat's centre, x to the right, y up)::

    y = 4  +-------------------------+---------------------------+
           | counter                 |                         T |
           |                         |        couch            V |
           |   table      hand-over  door     [==]  seats ->     |
           |                area     |        [==]               |
    y=-1.4 +------door---------------+---------------door--------+
           |                     corridor                        |
    y = -4 +-----------------------------------------------------+
          x = -6                   x = 0                       x = 6

- **Walls** are blocks (solid boxes, 2 m high): the wall along :math:`y = -1.4` with a door
  into the kitchen (:math:`x \in [-3.6, -2.4]`) and one into the living room
  (:math:`x \in [2.4, 3.6]`), and the wall along :math:`x = 0` with a door
  (:math:`y \in [1.0, 2.2]`). The corridor is 2.6 m wide: a robot of radius 0.3 m can pass a
  person standing in its middle outside the 0.45 m intimate zone.
- **Living room**: the couch (a 0.9 x 2.2 m block, 0.8 m high) faces the TV on the right wall;
  its three seats (`SEATS`) are where a seated person's centre is. Between a seated person and
  the TV lies a person-object interaction a robot must never cross. Behind the couch a 1.9 m
  passage leads around it.
- **Kitchen**: a counter along the top wall, a table on legs, and the hand-over area
  (`HANDOVER_AREA`) where a person waits for the robot to bring something.

The sitting and hand-over areas (`SITTING_AREAS`, `HANDOVER_AREA`) are axis-aligned boxes
(x0, y0, x1, y1): the tracker's status step calls a person inside one seated or waiting.
"""

from __future__ import annotations

import numpy as np

from sims.following import layout as layout_mod

__all__ = ["SIZE", "CORRIDOR", "SEATS", "TV", "SITTING_AREAS", "HANDOVER_AREA", "KITCHEN",
           "LIVING_ROOM", "flat", "walls"]

SIZE = (12.0, 8.0)
WALL_HEIGHT = 2.0
WALL = 0.1                                     # interior wall thickness
CORRIDOR = (-6.0, -4.0, 6.0, -1.4 - 0.5 * WALL)   # x0, y0, x1, y1 of its free floor
KITCHEN = (-6.0, -1.4 + 0.5 * WALL, -0.5 * WALL, 4.0)
LIVING_ROOM = (0.5 * WALL, -1.4 + 0.5 * WALL, 6.0, 4.0)
COUCH = dict(kind="couch", centre=(2.4, 1.3), size=(0.9, 2.2), height=0.8)
TV_BLOCK = dict(kind="tv", centre=(5.85, 1.3), size=(0.2, 1.4), height=1.2)
TV = np.array([5.75, 1.3])                     # the screen's centre on the floor plan
SEATS = np.array([[3.0, 0.6], [3.0, 1.3], [3.0, 2.0]])  # seated people's centres, facing +x
SITTING_AREAS = np.array([[1.95, 0.2, 3.3, 2.4]])
HANDOVER_AREA = np.array([-2.6, 0.4, -0.8, 2.6])
_COUNTER = dict(kind="counter", centre=(-3.0, 3.7), size=(4.0, 0.6), height=0.9)
_TABLE = dict(size=(1.2, 0.8), height=0.75, leg_radius=0.04, inset=0.06)


def _wall(x0, y0, x1, y1):
    return dict(kind="wall", centre=(0.5 * (x0 + x1), 0.5 * (y0 + y1)),
                size=(x1 - x0, y1 - y0), height=WALL_HEIGHT)


def walls() -> tuple:
    """The interior walls as blocks, doors left open."""
    y, t = -1.4, 0.5 * WALL
    return (_wall(-6.0, y - t, -3.6, y + t), _wall(-2.4, y - t, 2.4, y + t),
            _wall(3.6, y - t, 6.0, y + t),
            _wall(-t, y + t, t, 1.0), _wall(-t, 2.2, t, 4.0))


def flat() -> layout_mod.Layout:
    """The flat as a `sims.following.layout.Layout` (blocks: walls, couch, TV, counter;
    furniture: the kitchen table)."""
    table = layout_mod.legged("table", _TABLE, (-4.2, 1.0))
    return layout_mod.Layout("flat", SIZE, (table,),
                             walls() + (COUCH, TV_BLOCK, _COUNTER))
