r"""Euclidean clustering at fixed capacity: connected components of the neighbour graph.

Seed 001 (section III-B) clusters the non-ground points "by labeling neighboring 3D points on
the basis of their Euclidean distances": two points belong to one cluster when a chain of
points, each within the cluster tolerance of the next, joins them. That is the connected
components of the graph whose edges join points closer than the tolerance (DBSCAN with one
point per core; PCL's ``EuclideanClusterExtraction``).

The components are found by min-label propagation with hooking and pointer jumping, which
needs only gathers and scatter-minima, and so runs batched under `vmap` on any device: every
point starts with its own index as label; each round it takes the smallest label among itself
and its neighbours, :math:`\ell_i \leftarrow \min(\ell_i, \min_{j \in N(i)} \ell_j)`, then
hooks (the point :math:`\ell_i` names takes the smallest new label of the points naming it)
and jumps, :math:`\ell_i \leftarrow \ell_{\ell_i}`, until no label changes. Every label stays
the index of a point of the same component, so the fixed point is each component's smallest
index. The neighbour lists come from `jaxtrack.perception.voxel_grid.grid_neighbours` (or any
[V, K] index array with -1 for "none").

The components are then ranked by size (largest first, ties by smallest index), those below
``min_size`` discarded, and the first ``capacity`` kept.

Example:
  >>> nbrs = grid_neighbours(spec, grid, radius=0.12, keep=~ground)
  >>> clusters = euclidean_clusters(nbrs, grid.mask & ~ground, min_size=5, capacity=32)
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxtrack import _checks
from jaxtrack._gather import take

Array = jax.Array

__all__ = ["Clusters", "connected_components", "euclidean_clusters"]


class Clusters(NamedTuple):
    """Clusters of V points at capacity C, largest first.

    Attributes:
      labels: [V] int32 the cluster of each point in [0, C), -1 for none.
      sizes: [C] int32 points per cluster (0 for empty rows).
      mask: [C] bool rows holding a cluster.
      num_dropped: int32 components of at least ``min_size`` points beyond the capacity.
    """

    labels: Array
    sizes: Array
    mask: Array
    num_dropped: Array


def connected_components(neighbours: Array, mask: Array, *, symmetric: bool = False) -> Array:
    """Label each point with the smallest index of its connected component.

    Args:
      neighbours: [V, K] int32 neighbour indices, -1 for none. They need not be symmetric: an
        edge in either list joins the two points.
      mask: [V] bool points taking part; edges to or from masked-out points are ignored.
      symmetric: promise that j lists i whenever i lists j (as `grid_neighbours` does), which
        saves a scatter per round.

    Returns:
      [V] int32 component labels (the component's smallest index), V for masked-out points.
    """
    _checks.check_ndim("neighbours", neighbours, 2, "[V, K] neighbour indices")
    v = _checks.shape_of(neighbours)[0]
    _checks.check_shape("mask", mask, (v,), "[V] bool")
    mask = jnp.asarray(mask, bool)
    nb = jnp.asarray(neighbours, jnp.int32)
    none = jnp.int32(v)
    # Each edge's far end, or V (a row of "none" labels) where there is none, laid out [K, V]
    # so that each round's gather and minimum run along the points (a minimum over the
    # trailing K ran as a slow reduce-window on a CPU). An edge to a masked-out point needs
    # no test: that point keeps the label "none", which no minimum picks, and names no one.
    far = jnp.where((nb >= 0) & (nb < v) & mask[:, None], nb, v).T
    if not symmetric:   # (there a push would give the masked-out point a label: drop them)
        far = jnp.where(jnp.concatenate([mask, jnp.zeros(1, bool)])[far], far, v)
    labels0 = _with_none(jnp.where(mask, jnp.arange(v, dtype=jnp.int32), none))

    def body(state):
        padded, _ = state                   # [V + 1] labels, and V at row V
        labels = padded[:v]
        # (`take`: no wrapping of negative indices, added to every round's gather and not
        # hoisted, and a cheap gather under vmap)
        pulled = take(padded, far)
        new = jnp.minimum(labels, jnp.min(pulled, axis=0))
        if not symmetric:
            # Push as well: an edge listed only at i (j's list lacks i) must still lower j.
            new = jnp.minimum(new, jnp.full(v + 1, none).at[far].min(
                jnp.broadcast_to(labels[None], far.shape))[:v])
        # Hooking (Shiloach and Vishkin): the point a label names takes the smallest new label
        # among the points that named it, and each point then takes its label's. Labels stay
        # indices of points of the same component, so the fixed point is unchanged; on the
        # RGB-D frames the rounds fall from 6-28 to 3-5.
        new = jnp.minimum(new, _hook(labels, new, v)[:v])
        new = jnp.minimum(new, _hook(labels, new, v)[new])
        new = _with_none(_with_none(new)[new])[new]      # two jumps, l_i <- l_(l_i)
        return _with_none(new), jnp.any(new != labels)

    labels, _ = lax.while_loop(lambda s: s[1], body, (labels0, jnp.asarray(v > 0)))
    return labels[:v]


def _with_none(labels):
    """[V + 1] ``labels`` [V] and, at row V, the label V ("none")."""
    return jnp.concatenate([labels, jnp.full(1, labels.shape[0], labels.dtype)])


def _hook(labels, new, v):
    """[V + 1] the smallest ``new`` among the points whose ``labels`` name each point (row V
    collects the masked-out points)."""
    return jnp.full(v + 1, v, jnp.int32).at[labels].min(new)


def euclidean_clusters(neighbours: Array, mask: Array, *, min_size: int = 1,
                       capacity: int, symmetric: bool = False) -> Clusters:
    """Clusters: the connected components with at least ``min_size`` points, largest first.

    Args:
      neighbours: [V, K] int32 neighbour indices (-1 for none), e.g. from `grid_neighbours`.
      mask: [V] bool points to cluster.
      min_size: smallest cluster kept (points).
      capacity: C, clusters kept (static).
      symmetric: the neighbour lists are symmetric (see `connected_components`).

    Returns:
      `Clusters`.

    Example:
      >>> clusters = euclidean_clusters(nbrs, mask, min_size=5, capacity=32)
      >>> clusters.labels        # [V], -1 outside the kept clusters
    """
    if int(capacity) != capacity or capacity < 1:
        raise ValueError(f"capacity must be a positive integer; got {capacity}")
    if int(min_size) != min_size or min_size < 1:
        raise ValueError(f"min_size must be a positive integer; got {min_size}")
    labels = connected_components(neighbours, mask, symmetric=symmetric)
    v = labels.shape[0]
    sizes = jax.ops.segment_sum(jnp.ones(v, jnp.int32), labels, v + 1)[:v]
    is_root = labels == jnp.arange(v, dtype=jnp.int32)
    score = jnp.where(is_root & (sizes >= min_size), sizes, -1)
    order = jnp.argsort(-score, stable=True)
    take = min(int(capacity), v)
    roots = order[:take]
    kept = score[roots] > 0
    rank = jnp.full(v + 1, -1, jnp.int32).at[jnp.where(kept, roots, v)].set(
        jnp.arange(take, dtype=jnp.int32))
    rank = rank.at[v].set(-1)
    point_label = rank[labels]
    out_sizes = jnp.zeros(capacity, jnp.int32).at[:take].set(jnp.where(kept, sizes[roots], 0))
    out_mask = jnp.zeros(capacity, bool).at[:take].set(kept)
    num_dropped = jnp.sum(score > 0) - jnp.sum(kept)
    return Clusters(labels=point_label, sizes=out_sizes, mask=out_mask,
                    num_dropped=num_dropped.astype(jnp.int32))
