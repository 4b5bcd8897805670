"""Floor plans of the person-following scene: today's furnished room, and a shop.

A `Layout` is static geometry in the world frame (metres, the floor centred at the origin):

- ``furniture``: things on legs, which the shin-height laser sees as thin posts: tables and
  chairs in the room, free-standing displays in the shop (dicts with ``kind``, ``centre``,
  ``size``, ``height``, ``leg_radius`` and ``legs`` [4, 2]);
- ``blocks``: solid, axis-aligned boxes down to the floor, which the laser sees as walls: the
  shop's shelf rows (gondolas), their end caps and the checkout counter (dicts with ``kind``,
  ``centre``, ``size``, ``height``);
- ``aisles``: the shop's walking graph (`AisleGraph`), along which shoppers go from shelf to
  shelf: nodes at aisle crossings and at shelf spots (where a shopper stops, facing the
  shelf), edges along the aisles, and the next hop of every shortest path (Dijkstra, once).

The shop (`shop`, about 14 x 11 m): three rows of shelves along x, each cut in two by a cross
aisle, with end caps at their outer ends; aisles 1.9-2.55 m wide between the rows and along the
walls, 2.0 m at the cross aisle and the ends; a checkout counter along the bottom wall and three
free-standing display tables against the walls, whose legs and corners the laser sees.

Example:
  >>> lay = shop()
  >>> lay.aisles.next_hop.shape          # [N, N]
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

__all__ = ["Layout", "AisleGraph", "room", "shop", "LAYOUTS", "by_name", "block_segments",
           "legged"]

_TABLE = dict(size=(1.2, 0.8), height=0.75, leg_radius=0.04, inset=0.06)
_CHAIR = dict(size=(0.45, 0.45), height=0.45, leg_radius=0.025, inset=0.03, offset=0.7)
_DISPLAY = dict(size=(1.0, 0.5), height=0.9, leg_radius=0.03, inset=0.05)


class AisleGraph(NamedTuple):
    """The shop's walking graph (numpy, built once).

    Attributes:
      nodes: [N, 2] node positions.
      spot: [N] bool, the node is a shelf spot (a shopper stops there).
      facing: [N] heading (rad) toward the shelf at a spot (0 elsewhere).
      pair: [N] int, a spot's neighbour 0.6 m along the shelf (a side step; itself elsewhere).
      next_hop: [N, N] int, the next node from ``i`` toward ``j`` (``i`` when ``i == j``).
      length: [N, N] path lengths (m).
      tour: [S] the spots in shopping order: aisle by aisle from the bottom, along each aisle
        in turn (a serpentine), both shelves at once.
      rank: [N] a spot's place in the tour (-1 elsewhere).
    """

    nodes: np.ndarray
    spot: np.ndarray
    facing: np.ndarray
    pair: np.ndarray
    next_hop: np.ndarray
    length: np.ndarray
    tour: np.ndarray
    rank: np.ndarray


@dataclasses.dataclass(frozen=True, eq=False)
class Layout:
    """A floor plan (module docstring).

    Attributes:
      name: "room" or "shop".
      room: (width along x, depth along y) of the floor, centred at the origin (m).
      furniture: tuple of furniture dicts (on legs).
      blocks: tuple of block dicts (solid boxes).
      aisles: `AisleGraph`, or None (people walk to random free points).
    """

    name: str
    room: tuple
    furniture: tuple
    blocks: tuple = ()
    aisles: AisleGraph | None = None

    def boxes(self) -> np.ndarray:
        """[B, 4] blocks as (centre x, centre y, half size x, half size y)."""
        if not self.blocks:
            return np.zeros((0, 4))
        return np.array([[*b["centre"], 0.5 * b["size"][0], 0.5 * b["size"][1]]
                         for b in self.blocks], float)


def legged(kind, spec, centre):
    """A piece of furniture on four legs: ``spec`` has ``size``, ``height``, ``leg_radius`` and
    ``inset`` (of the legs from the edges); returns the furniture dict (module docstring)."""
    hx, hy = 0.5 * spec["size"][0] - spec["inset"], 0.5 * spec["size"][1] - spec["inset"]
    c = np.asarray(centre, float)
    legs = c + np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
    return dict(kind=kind, centre=c, size=spec["size"], height=spec["height"],
                leg_radius=spec["leg_radius"], legs=legs)


def room(size=(10.0, 8.0)) -> Layout:
    """Today's room: two tables at :math:`(\\mp W/4, \\pm H/5)`, each with a chair on either
    long side; no blocks, no aisles."""
    W, H = size
    items = []
    for sx in (-1.0, 1.0):
        centre = np.array([0.25 * W * sx, -0.2 * H * sx])
        items.append(legged("table", _TABLE, centre))
        for dy in (-_CHAIR["offset"], _CHAIR["offset"]):
            items.append(legged("chair", _CHAIR, centre + np.array([0.0, dy])))
    return Layout("room", (float(W), float(H)), tuple(items))


# The shop's plan: rows of shelves (gondolas) along x.
_SHOP = (14.0, 11.0)
_ROW_Y = (-2.6, 0.0, 2.6)          # row centres
_ROW_DEPTH = 0.7
_ROW_X = ((-4.5, -1.0), (1.0, 4.5))  # the two segments of a row (cross aisle between)
_CAP = 0.5                         # end cap length at a row's outer end
_SHELF_HEIGHT = 1.5
_AISLE_Y = (-3.95, -1.3, 1.3, 3.95)  # walking lines along x
_AISLE_X = (-6.0, 0.0, 6.0)          # walking lines along y
_SPOT_X = (-3.8, -2.0, 2.0, 3.8)     # shelf spots along each row face
_SPOT_GAP = 0.6                      # a shopper's side step along a shelf
_SPOT_OFFSET = 0.6                   # spots stand this far from the shelf face


def shop() -> Layout:
    """The shop (module docstring)."""
    W, H = _SHOP
    blocks = []
    for y in _ROW_Y:
        for (x0, x1), outer in zip(_ROW_X, (-1, 1)):
            blocks.append(dict(kind="shelf", centre=(0.5 * (x0 + x1), y),
                               size=(x1 - x0, _ROW_DEPTH), height=_SHELF_HEIGHT))
            xo = x0 if outer < 0 else x1
            blocks.append(dict(kind="end_cap", centre=(xo + 0.5 * _CAP * outer, y),
                               size=(_CAP, _ROW_DEPTH), height=1.2))
    blocks.append(dict(kind="counter", centre=(-5.5, -0.5 * H + 0.375), size=(2.0, 0.45),
                       height=0.9))
    furniture = (legged("display", _DISPLAY, (-2.5, 0.5 * H - 0.4)),
                 legged("display", _DISPLAY, (2.5, 0.5 * H - 0.4)),
                 legged("display", _DISPLAY, (3.5, -0.5 * H + 0.4)))
    return Layout("shop", _SHOP, furniture, tuple(blocks), _aisles())


def _aisles() -> AisleGraph:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import shortest_path

    nodes, facing, spot, pair = [], [], [], []

    def add(xy, face=None):
        nodes.append(np.asarray(xy, float))
        spot.append(face is not None)
        facing.append(0.0 if face is None else face)
        pair.append(len(nodes) - 1)
        return len(nodes) - 1

    crossing = {(x, y): add((x, y)) for y in _AISLE_Y for x in _AISLE_X}
    faces = [y + s * 0.5 * _ROW_DEPTH for y in _ROW_Y for s in (-1, 1)]
    rows, cols, w = [], [], []

    def edge(i, j):
        d = float(np.linalg.norm(nodes[i] - nodes[j]))
        rows.extend([i, j])
        cols.extend([j, i])
        w.extend([d, d])

    xs = sorted(x + dx for x in _SPOT_X for dx in (0.0, _SPOT_GAP * np.sign(x)))
    for ya in _AISLE_Y:
        # Shoppers walk along the aisle's centre line and step aside to a spot at a shelf.
        on_line = {x: add((x, ya)) for x in xs}
        order = sorted(list(on_line.values()) + [crossing[(x, ya)] for x in _AISLE_X],
                       key=lambda k: nodes[k][0])
        for i, j in zip(order[:-1], order[1:]):
            edge(i, j)
        for face in faces:
            if abs(face - ya) > 1.4:
                continue
            side = 1.0 if face > ya else -1.0      # the shelf is above (+y) or below the line
            y = face - side * _SPOT_OFFSET
            for x in _SPOT_X:
                a = add((x, y), face=side * 0.5 * math.pi)
                x2 = x + _SPOT_GAP * np.sign(x)
                b = add((x2, y), face=side * 0.5 * math.pi)
                pair[a], pair[b] = b, a
                edge(a, on_line[x])
                edge(b, on_line[x2])
                edge(a, b)
    for x in _AISLE_X:
        for y0, y1 in zip(_AISLE_Y[:-1], _AISLE_Y[1:]):
            edge(crossing[(x, y0)], crossing[(x, y1)])
    N = len(nodes)
    graph = coo_matrix((w, (rows, cols)), shape=(N, N)).tocsr()
    length, pred = shortest_path(graph, method="D", directed=False, return_predecessors=True)
    if not np.all(np.isfinite(length)):
        raise ValueError("the aisle graph is not connected")
    # pred[j, i] is the node before i on the path from j: the next hop from i toward j.
    nxt = pred.T.copy()
    nxt[nxt < 0] = np.broadcast_to(np.arange(N)[:, None], (N, N))[nxt < 0]
    xy = np.stack(nodes)
    spots = np.flatnonzero(spot)
    line = np.array([min(range(len(_AISLE_Y)), key=lambda k: abs(xy[i, 1] - _AISLE_Y[k]))
                     for i in spots])
    # Serpentine: left to right along the even aisles, right to left along the odd ones.
    x = np.where(line % 2 == 0, xy[spots, 0], -xy[spots, 0])
    tour = spots[np.lexsort((x, line))]
    rank = np.full(N, -1)
    rank[tour] = np.arange(tour.size)
    return AisleGraph(xy, np.array(spot), np.array(facing), np.array(pair),
                      nxt.astype(np.int32), length, tour.astype(np.int32),
                      rank.astype(np.int32))


def block_segments(blocks) -> np.ndarray:
    """[4 B, 2, 2] the edges of the blocks, as wall segments for the laser."""
    out = []
    for b in blocks:
        (cx, cy), (sx, sy) = b["centre"], b["size"]
        hx, hy = 0.5 * sx, 0.5 * sy
        c = np.array([[cx + hx, cy - hy], [cx + hx, cy + hy], [cx - hx, cy + hy],
                      [cx - hx, cy - hy]])
        out.append(np.stack([c, np.roll(c, -1, axis=0)], 1))
    return np.concatenate(out, 0) if out else np.zeros((0, 2, 2))


LAYOUTS = ("room", "shop")


def by_name(name: str) -> Layout:
    """The layout called ``name`` (`LAYOUTS`)."""
    if name == "room":
        return room()
    if name == "shop":
        return shop()
    raise ValueError(f"unknown layout {name!r}; choose one of {LAYOUTS}")
