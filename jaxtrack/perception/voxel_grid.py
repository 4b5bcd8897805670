r"""Voxel-grid downsampling of a point cloud at fixed capacity (seed 001, section III-A).

Space is divided into cubic voxels of side ``size``; every point inside a voxel is replaced by
the centroid of the voxel's points (and its colour by their mean colour). Seed 001 uses
0.06 m: it shrinks a Kinect cloud by an order of magnitude and makes the point density
independent of the distance to the sensor, so a cluster's voxel count measures its real size.

The voxel of a point :math:`p` is :math:`\lfloor (p - \ell) / s \rfloor` for the grid's lower
corner :math:`\ell` and side :math:`s` (Open3D's ``voxel_down_sample`` uses
:math:`\ell = \min_i p_i - s / 2`; pass that as ``lower`` to reproduce it).

Fixed shapes: the grid is a dense box of ``shape`` cells (a sensor's frustum at 0.06 m is a few
hundred thousand cells), and the occupied voxels are compacted, in the order of their cell
index, into ``capacity`` rows with a mask. A dense box rather than a sort of the cells' keys
because a scatter into a few hundred thousand cells and one prefix sum are cheaper than sorting
the 77k points of a QVGA frame, on a CPU as on a GPU, and a box of the same cells serves as
the voxels' neighbour lookup (`grid_neighbours`, `cell_lookup`). Points outside the box,
masked or non-finite points and the points of voxels beyond the capacity are dropped and
counted.

Example:
  >>> spec = GridSpec(size=0.06, lower=(-3.0, -3.0, -0.5), shape=(100, 100, 50))
  >>> grid = voxelise(spec, points, mask, colours, capacity=4096)
  >>> grid.points[grid.mask]          # the voxel centroids
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import _checks
from jaxtrack._gather import materialised, put, segment_sum, take

Array = jax.Array

__all__ = ["GridSpec", "VoxelGrid", "voxelise", "select", "cell_lookup", "grid_neighbours",
           "open3d_lower"]


@dataclasses.dataclass(frozen=True)
class GridSpec:
    """A dense voxel grid: static (hashable), so it may be a `jit` static argument.

    Attributes:
      size: voxel side (m); 0.06 in seed 001.
      lower: the grid's lower corner (m), in the cloud's frame.
      shape: cells along each axis; the grid spans ``lower + size * shape``.
    """

    size: float = 0.06
    lower: tuple[float, float, float] = (-0.5, -3.0, -0.5)
    shape: tuple[int, int, int] = (84, 100, 50)

    def __post_init__(self):
        if not (math.isfinite(self.size) and self.size > 0):
            raise ValueError(f"GridSpec.size must be a positive finite length; got {self.size}")
        if len(self.lower) != 3 or not all(math.isfinite(v) for v in self.lower):
            raise ValueError(f"GridSpec.lower must be 3 finite numbers; got {self.lower}")
        if len(self.shape) != 3 or not all(int(n) == n and n >= 1 for n in self.shape):
            raise ValueError(f"GridSpec.shape must be 3 positive integers; got {self.shape}")
        if math.prod(self.shape) >= 2**31 - 1:
            raise ValueError(f"GridSpec.shape {self.shape} has too many cells for int32 indices")
        object.__setattr__(self, "lower", tuple(float(v) for v in self.lower))
        object.__setattr__(self, "shape", tuple(int(n) for n in self.shape))

    @property
    def num_cells(self) -> int:
        return math.prod(self.shape)


class VoxelGrid(NamedTuple):
    """Occupied voxels, compacted into a fixed capacity V, in the order of their cell index.

    Attributes:
      points: [V, 3] centroid of each voxel's points.
      colours: [V, C] mean colour of each voxel's points (C = 0 without colours).
      counts: [V] int32 points in each voxel.
      cells: [V, 3] int32 cell coordinates of each voxel.
      mask: [V] bool, occupied rows.
      point_voxel: [N] int32 the voxel of each input point, -1 where it was dropped.
      num_dropped: int32 valid points dropped: outside the grid or beyond the capacity.
    """

    points: Array
    colours: Array
    counts: Array
    cells: Array
    mask: Array
    point_voxel: Array
    num_dropped: Array


def open3d_lower(points, size: float) -> tuple[float, float, float]:
    """The lower corner Open3D's ``voxel_down_sample`` uses: the cloud's minimum minus half a
    voxel (for reproducing it; a fixed corner keeps voxels stable from frame to frame)."""
    p = np.asarray(points, dtype=np.float64)
    return tuple(float(v) for v in p.min(axis=0) - 0.5 * size)


def voxelise(spec: GridSpec, points: Array, mask: Array | None = None,
             colours: Array | None = None, *, capacity: int) -> VoxelGrid:
    r"""Downsample a cloud to its voxel centroids.

    Args:
      spec: the grid.
      points: [N, 3] points (any frame the grid is laid in); N may be 0.
      mask: [N] bool valid points, or None (all). Non-finite points are dropped regardless.
      colours: [N, C] per-point colours (or any features to average), or None.
      capacity: V, the maximum number of voxels kept (static).

    Returns:
      A `VoxelGrid`. Centroid :math:`\bar p_v = \frac{1}{n_v} \sum_{i \in v} p_i`.

    Example:
      >>> grid = voxelise(GridSpec(0.06, (-3., -3., -.5), (100, 100, 50)), pts, capacity=4096)
    """
    _checks.check_shape("points", points, (None, 3), "[N, 3] points")
    n = _checks.shape_of(points)[0]
    if mask is not None:
        _checks.check_shape("mask", mask, (n,), "[N] bool")
    if colours is not None:
        _checks.check_ndim("colours", colours, 2, "[N, C] colours")
        _checks.check_shape("colours", colours, (n, None), "[N, C] colours")
    if int(capacity) != capacity or capacity < 1:
        raise ValueError(f"capacity must be a positive integer; got {capacity}")
    points = jnp.asarray(points)
    if not jnp.issubdtype(points.dtype, jnp.floating):
        raise TypeError(f"points must be floating; got {points.dtype}")
    dtype = points.dtype
    colours = jnp.zeros((n, 0), dtype) if colours is None else jnp.asarray(colours, dtype)
    # One axis at a time: XLA's CPU loops do not vectorise over a trailing axis of 3 (the
    # [N, 3] form of these lines ran 3x slower).
    axes = [points[:, a] for a in range(3)]
    valid = jnp.isfinite(axes[0]) & jnp.isfinite(axes[1]) & jnp.isfinite(axes[2])
    if mask is not None:
        valid &= jnp.asarray(mask, bool)
    total = spec.num_cells
    ijk, inside = [], valid
    for a in range(3):
        rel = (axes[a] - jnp.asarray(spec.lower[a], dtype)) / spec.size
        # Clip before the cast: a point far outside would overflow int32 and wrap inside.
        c = jnp.floor(jnp.clip(jnp.where(valid, rel, -1.0), -1.0, 2.0**30)).astype(jnp.int32)
        inside &= (c >= 0) & (c < spec.shape[a])
        ijk.append(c)
    # Each point's cell (-1 outside), written to memory once: XLA otherwise recomputes it
    # (the finite tests, the clip, the floor) inside each of its four consumers.
    linear = _rows_materialised(jnp.where(
        inside, (ijk[0] * spec.shape[1] + ijk[1]) * spec.shape[2] + ijk[2], -1))
    inside = linear >= 0
    rank = _cell_ranks(spec, linear // spec.shape[2], linear % spec.shape[2], inside)
    kept = inside & (rank < capacity)
    point_voxel = jnp.where(kept, rank, -1)
    seg = jnp.where(point_voxel >= 0, point_voxel, capacity)
    # Each row's cell, written by its points (a voxel's points all write the same cell).
    cells = put(jnp.full(capacity + 1, total, jnp.int32), seg, linear)[:capacity]

    # (`segment_sum`, `take` and `put` of `jaxtrack._gather`: cheap under vmap as well)
    counts = segment_sum(jnp.ones(n, jnp.int32), seg, capacity + 1)[:capacity]
    denom = jnp.maximum(counts, 1).astype(dtype)[:, None]
    # One segment sum of the points and colours side by side: a CPU's scatter costs about the
    # same per row for rows this short (three [N] sums took as long as one of [N, 3] rows).
    sums = segment_sum(jnp.where(inside[:, None], jnp.concatenate([points, colours], 1), 0),
                       seg, capacity + 1)[:capacity]
    centroids = sums[:, :3] / denom
    mean_colour = sums[:, 3:] / denom
    vmask = cells < total
    cell_ijk = jnp.stack([cells // (spec.shape[1] * spec.shape[2]),
                          (cells // spec.shape[2]) % spec.shape[1],
                          cells % spec.shape[2]], -1).astype(jnp.int32)
    num_dropped = jnp.sum(valid) - jnp.sum(point_voxel >= 0)
    return VoxelGrid(points=jnp.where(vmask[:, None], centroids, 0),
                     colours=jnp.where(vmask[:, None], mean_colour, 0),
                     counts=counts, cells=jnp.where(vmask[:, None], cell_ijk, -1), mask=vmask,
                     point_voxel=point_voxel.astype(jnp.int32),
                     num_dropped=num_dropped.astype(jnp.int32))


def _rows_materialised(x: Array) -> Array:
    """[N] ``x`` written to memory (`materialised`) as rows of 64 when N allows: one scatter
    of a few long rows instead of N single elements."""
    n = x.shape[0]
    if n % 64:
        return materialised(x)
    return materialised(x.reshape(64, n // 64)).reshape(n)


_WORD_BITS = 24     # cells per packed word of `_cell_ranks` (exact in float32)


def _cell_ranks(spec: GridSpec, col: Array, z: Array, inside: Array) -> Array:
    """[N] each point's cell's rank among the occupied cells in cell-index order (its voxel's
    row, as ``jnp.nonzero`` would number the cells), without a prefix sum over the whole box
    (XLA's over a few hundred thousand cells took 4.7 of the 6.9 ms of a QVGA frame's
    voxelisation on a CPU); anything for points outside.

    Each column of cells along the last axis is stored as 24-bit words, one bit per cell; a
    prefix sum of the words' bit counts (24x fewer entries) gives each word's first rank. A
    point's rank adds the bits of its word below its cell.

    Args:
      spec: the grid; col, z: [N] int32 each point's column of cells (i s_1 + j) and cell
      along it (k); inside: [N] bool points in the grid.
    """
    s2 = spec.shape[2]
    words = -(-s2 // _WORD_BITS)
    width = words * _WORD_BITS                      # a column's cells, padded to whole words
    cols = spec.shape[0] * spec.shape[1]
    outside = ~inside
    padded = jnp.where(outside, cols * width, col * width + z)
    occupied = put(jnp.zeros(cols * width + 1, jnp.uint8), padded,
                   jnp.ones_like(padded, jnp.uint8))[:cols * width]
    # Packed by a float32 product: its sums of distinct powers of two below 2^24 are exact,
    # and XLA runs it several times faster than an integer sum of shifted bits on a CPU.
    bit = 2.0 ** np.arange(_WORD_BITS, dtype=np.float32)
    packed = (occupied.reshape(cols * words, _WORD_BITS).astype(jnp.float32) @ bit).astype(
        jnp.uint32)
    counts = jax.lax.population_count(packed).astype(jnp.int32)
    # (materialised: fused, the prefix sum's last levels were redone at every point's gather)
    first = materialised(jnp.cumsum(counts) - counts)
    word = jnp.where(outside, 0, col * words + z // _WORD_BITS)
    below = (jnp.left_shift(jnp.uint32(1), (z % _WORD_BITS).astype(jnp.uint32))
             - jnp.uint32(1))
    return take(first, word) + jax.lax.population_count(take(packed, word) & below).astype(
        jnp.int32)


def select(grid: VoxelGrid, keep: Array, capacity: int) -> VoxelGrid:
    """The voxels of ``grid`` where ``keep`` holds, compacted into ``capacity`` rows (in order),
    with the points' voxels renumbered: e.g. the non-ground voxels, so that
    clustering pays only for them. Kept voxels beyond the capacity are dropped and their points
    counted in ``num_dropped``.

    Args:
      grid: a `VoxelGrid` of V rows; keep: [V] bool; capacity: V' (static).
    """
    v = grid.mask.shape[0]
    _checks.check_shape("keep", keep, (v,), "[V] bool")
    keep = grid.mask & jnp.asarray(keep, bool)
    (rows,) = jnp.nonzero(keep, size=capacity, fill_value=v)
    renumber = jnp.full(v + 1, -1, jnp.int32).at[rows].set(
        jnp.arange(capacity, dtype=jnp.int32)).at[v].set(-1)
    taken = rows < v
    dest = jnp.where(renumber[:v] >= 0, renumber[:v], capacity)   # new rows; capacity: none

    def rows_of(x, fill):
        # A scatter, not a gather of the kept rows: XLA fuses a gather into its consumers,
        # and the neighbour search's gathers then recomputed it for each neighbour (3x the
        # time of the rest of a detector frame).
        return jnp.full((capacity + 1,) + x.shape[1:], fill, x.dtype).at[dest].set(x)[:capacity]

    lost = jnp.sum(jnp.where(keep, grid.counts, 0)) - jnp.sum(rows_of(grid.counts, 0))
    return VoxelGrid(points=rows_of(grid.points, 0), colours=rows_of(grid.colours, 0),
                     counts=rows_of(grid.counts, 0), cells=rows_of(grid.cells, -1), mask=taken,
                     point_voxel=renumber[jnp.where(grid.point_voxel >= 0, grid.point_voxel, v)],
                     num_dropped=(grid.num_dropped + lost).astype(jnp.int32))


def cell_lookup(spec: GridSpec, grid: VoxelGrid) -> Array:
    """[num_cells] int32 the voxel row of each cell of the grid, -1 for cells without one.

    Built on demand rather than kept in `VoxelGrid`: the detector never reads it, and filling
    and renumbering a frustum's few hundred thousand cells in every frame is not free
    (`grid_neighbours` builds the padded box it needs itself).

    Example:
      >>> row = cell_lookup(spec, grid)[np.ravel_multi_index(ijk, spec.shape)]
    """
    total = spec.num_cells
    s1, s2 = spec.shape[1], spec.shape[2]
    linear = (grid.cells[:, 0] * s1 + grid.cells[:, 1]) * s2 + grid.cells[:, 2]
    rows = jnp.arange(grid.mask.shape[0], dtype=jnp.int32)
    return put(jnp.full(total + 1, -1, jnp.int32), jnp.where(grid.mask, linear, total),
               rows)[:total]


def grid_neighbours(spec: GridSpec, grid: VoxelGrid, radius: float,
                    keep: Array | None = None) -> Array:
    r"""Each voxel's neighbours within ``radius`` (centroid to centroid), by grid lookup.

    Two centroids closer than ``radius`` lie at most :math:`r = \lceil radius / size \rceil`
    cells apart along each axis, so the :math:`(2r+1)^3 - 1` surrounding cells hold every
    neighbour; only those within ``radius`` are returned.

    Args:
      spec, grid: the grid and its voxels.
      radius: the neighbourhood radius (m), static (it sets the number of cells searched).
      keep: [V] bool voxels that take part (e.g. the non-ground ones), or None (all occupied).

    Returns:
      [V, K] int32 neighbour rows, -1 where there is none; K = (2r+1)^3 - 1.
    """
    if not (math.isfinite(radius) and radius > 0):
        raise ValueError(f"radius must be a positive finite length; got {radius}")
    r = int(math.ceil(radius / spec.size - 1e-9))
    offsets = np.array([o for o in itertools.product(range(-r, r + 1), repeat=3) if any(o)],
                       np.int32)                                    # [K, 3]
    subset = keep is not None
    keep = grid.mask & keep if subset else grid.mask
    # A lookup of the voxels' rows in a box padded by r empty cells on every side, scattered
    # from the voxels themselves: every neighbour cell's index is then valid, with no bounds
    # test per neighbour, and the scatter is materialised (XLA fused the bounds test, and a
    # gather or pad of ``grid.lookup``, into every gather below). The coordinates go one
    # axis at a time: XLA's CPU loops do not vectorise over a trailing axis of 3 ([V, K, 3]
    # arrays made this 4x slower).
    shape = tuple(n + 2 * r for n in spec.shape)
    total = math.prod(shape)
    v = grid.mask.shape[0]
    cells = [jnp.where(grid.mask, grid.cells[:, a], 0) + r for a in range(3)]
    base = (cells[0] * shape[1] + cells[1]) * shape[2] + cells[2]
    # (rows as int16 where they fit: half the memory to fill and gather)
    index = jnp.int16 if v < 2**15 else jnp.int32
    lookup = put(jnp.full(total + 1, -1, index), jnp.where(grid.mask, base, total),
                 jnp.arange(v, dtype=index))
    step = (offsets[:, 0] * shape[1] + offsets[:, 1]) * shape[2] + offsets[:, 2]
    # (`take`: gathers that stay cheap under vmap)
    rows = take(lookup, base[:, None] + step[None]).astype(jnp.int32)
    coords = [grid.points[:, a] for a in range(3)]
    ok = (rows >= 0) & keep[:, None]
    safe = jnp.maximum(rows, 0)
    if subset:   # (the lookup holds occupied rows only: without a subset they all take part)
        ok &= take(keep, safe)
    d2 = sum((take(c, safe) - c[:, None]) ** 2 for c in coords)
    ok &= d2 <= radius ** 2
    return jnp.where(ok, rows, -1)
