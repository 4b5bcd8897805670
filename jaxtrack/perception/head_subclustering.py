r"""Head-based sub-clustering of point clusters into people (seed 001, section III-B).

When people stand close together, or beside a wall or a table, Euclidean clustering merges them
into one cluster. Seed 001 splits such a cluster by its heads, "because there is a one to one
person-head correspondence and heads are the body parts least likely to be occluded", in five
steps, each implemented here at fixed capacity:

1. **Height map**: for every cluster, a 1-D map of ``bin_size`` bins "along the direction
   corresponding to the image x axis", each holding the largest height above the ground plane
   of the cluster's points in it. The image x axis is taken as the horizontal direction across
   the line of sight from ``viewpoint`` (the sensor) to the cluster, so a panned camera needs
   no special case.
2. **Local maxima** of the height map: a bin higher than both neighbours (an empty or missing
   neighbour counts as lower). Maxima below ``min_height`` are not heads.
3. **The intimate distance**: of two maxima closer than ``intimate_distance`` (0.3 m, "people
   heads are not often nearer than the intimate distance") on the ground plane, only the higher
   is kept (greedy, highest first).
4. **Assignment**: each point joins the nearest kept maximum of its cluster, on the ground
   plane, if it is nearer than the intimate distance.
5. **Pruning**: sub-clusters with fewer than ``min_points`` points, or whose head lies outside
   [``min_height``, ``max_height``], are discarded.

With ``subcluster=False`` (the seed's ablation), every cluster is one candidate whose head is
its highest point, pruned by the same rules.

A detection's position is the ground-plane projection of its points' centroid.

Example:
  >>> dets = subcluster_heads(HeadConfig(), pts, mask, clusters.labels, fit.plane,
  ...                         viewpoint=jnp.array([0., 0., 1.1]), num_clusters=32)
  >>> dets.position[dets.mask]        # people on the ground plane
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxtrack import _checks
from jaxtrack.perception.ground_plane import plane_height

Array = jax.Array

__all__ = ["HeadConfig", "HeadDetections", "subcluster_heads"]


@dataclasses.dataclass(frozen=True)
class HeadConfig:
    """Sub-clustering parameters (static: pass as a `jit` static argument).

    Attributes:
      bin_size: height-map bin width (m); one voxel, 0.06.
      num_bins: bins per cluster's height map (static); 64 spans 3.84 m, wider clusters share
        the last bin.
      intimate_distance: seed 001's 0.3 m, between heads and from a head to its points.
      min_height, max_height: a head's height above the ground (m); 1.3 and 2.3 (the seed's
        implementation, PCL's ground-based people detector, uses these).
      min_points: fewest points (voxels) in a sub-cluster; 30, PCL's value at 0.06 m voxels.
        A person seen whole at 4 m from a QVGA Kinect is about 150 such voxels.
      max_candidates: maxima considered per frame, highest first (static).
      max_detections: H, detections returned (static).
      subcluster: split clusters by heads (True) or keep one candidate per cluster.
    """

    bin_size: float = 0.06
    num_bins: int = 64
    intimate_distance: float = 0.3
    min_height: float = 1.3
    max_height: float = 2.3
    min_points: int = 30
    max_candidates: int = 32
    max_detections: int = 16
    subcluster: bool = True

    def __post_init__(self):
        for name in ("bin_size", "intimate_distance", "min_height", "max_height"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and value > 0):
                raise ValueError(f"HeadConfig.{name} must be a positive number; got {value!r}")
        if self.max_height <= self.min_height:
            raise ValueError("HeadConfig.max_height must exceed min_height; got "
                             f"{self.min_height}, {self.max_height}")
        for name in ("num_bins", "min_points", "max_candidates", "max_detections"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1):
                raise ValueError(f"HeadConfig.{name} must be a positive integer; got {value!r}")


class HeadDetections(NamedTuple):
    """People found as heads, at capacity H, highest head first.

    Attributes:
      position: [H, 3] ground-plane projection of the sub-cluster's centroid.
      head: [H, 3] the head point (the top of its height-map bin).
      height: [H] the head's height above the ground plane.
      num_points: [H] int32 points in the sub-cluster.
      cluster: [H] int32 the cluster it came from.
      mask: [H] bool.
      point_detection: [V] int32 the detection each point belongs to, -1 for none.
      num_dropped: int32 detections beyond the capacity.
    """

    position: Array
    head: Array
    height: Array
    num_points: Array
    cluster: Array
    mask: Array
    point_detection: Array
    num_dropped: Array


def subcluster_heads(config: HeadConfig, points: Array, mask: Array, labels: Array,
                     plane: Array, viewpoint: Array, *, num_clusters: int) -> HeadDetections:
    """Split clusters into people by their heads (the five steps above).

    Args:
      config: `HeadConfig`.
      points: [V, 3] points (voxel centroids), in the frame of ``plane``.
      mask: [V] bool.
      labels: [V] int32 cluster of each point in [0, num_clusters), -1 for none.
      plane: [4] ground plane (unit normal up, offset), see `fit_ground_plane`.
      viewpoint: [3] the sensor's position, for the image x axis.
      num_clusters: C, the cluster capacity (static).

    Returns:
      `HeadDetections`.

    Example:
      >>> dets = subcluster_heads(HeadConfig(), pts, mask, labels, plane, eye, num_clusters=32)
    """
    _checks.check_shape("points", points, (None, 3), "[V, 3] points")
    v = _checks.shape_of(points)[0]
    _checks.check_shape("mask", mask, (v,), "[V] bool")
    _checks.check_shape("labels", labels, (v,), "[V] int cluster labels")
    _checks.check_shape("plane", plane, (4,), "[4] plane")
    _checks.check_shape("viewpoint", viewpoint, (3,), "[3] sensor position")
    cfg = config
    points = jnp.asarray(points)
    dtype = points.dtype
    C, B, K, H = int(num_clusters), cfg.num_bins, cfg.max_candidates, cfg.max_detections
    plane = jnp.asarray(plane, dtype)
    normal = plane[:3]
    labels = jnp.asarray(labels, jnp.int32)
    member = jnp.asarray(mask, bool) & (labels >= 0) & (labels < C) \
        & jnp.all(jnp.isfinite(points), -1)
    lab = jnp.where(member, labels, C)                                 # C: nobody's cluster
    if v == 0:
        return HeadDetections(jnp.zeros((H, 3), dtype), jnp.zeros((H, 3), dtype),
                              jnp.zeros(H, dtype), jnp.zeros(H, jnp.int32),
                              jnp.full(H, -1, jnp.int32), jnp.zeros(H, bool),
                              jnp.zeros(0, jnp.int32), jnp.int32(0))
    height = plane_height(plane, points)
    ground = points - height[:, None] * normal                         # [V, 3]
    eye = jnp.asarray(viewpoint, dtype)
    eye = eye - plane_height(plane, eye[None])[0] * normal

    # Step 1: the height map along each cluster's image x axis.
    count = jax.ops.segment_sum(member.astype(dtype), lab, C + 1)[:C]
    centre = jax.ops.segment_sum(jnp.where(member[:, None], ground, 0), lab, C + 1)[:C] \
        / jnp.maximum(count, 1)[:, None]
    sight = centre - eye
    sight = sight / jnp.maximum(jnp.linalg.norm(sight, axis=-1, keepdims=True), 1e-9)
    across = jnp.cross(normal, sight)                                  # [C, 3]
    across_pad = jnp.concatenate([across, jnp.zeros((1, 3), dtype)])
    s = jnp.sum((ground - eye) * across_pad[lab], -1)
    s_min = jax.ops.segment_min(jnp.where(member, s, jnp.inf), lab, C + 1)[:C]
    s_min_pad = jnp.concatenate([s_min, jnp.zeros(1, dtype)])
    b = jnp.clip(jnp.floor((s - s_min_pad[lab]) / cfg.bin_size), 0, B - 1).astype(jnp.int32)
    cell = jnp.where(member, lab * B + b, C * B)
    h_member = jnp.where(member, height, -jnp.inf)
    hmap = jax.ops.segment_max(h_member, cell, C * B + 1)[:C * B]       # [C * B]
    idx = jnp.arange(v, dtype=jnp.int32)
    hmap_pad = jnp.concatenate([hmap, jnp.full(1, -jnp.inf, dtype)])
    is_top = member & (height >= hmap_pad[cell])
    top = jax.ops.segment_min(jnp.where(is_top, idx, v), cell, C * B + 1)[:C * B]

    if cfg.subcluster:
        # Step 2: local maxima of each cluster's map.
        grid = hmap.reshape(C, B)
        lower = jnp.full((C, 1), -jnp.inf, dtype)
        left = jnp.concatenate([lower, grid[:, :-1]], 1)
        right = jnp.concatenate([grid[:, 1:], lower], 1)
        peak = (grid > left) & (grid > right) & jnp.isfinite(grid) & (grid >= cfg.min_height)
        cand_h = jnp.where(peak.reshape(-1), hmap, -jnp.inf)
    else:
        best_bin = jnp.argmax(hmap.reshape(C, B), axis=1)
        is_best = jnp.zeros((C, B), bool).at[jnp.arange(C), best_bin].set(True).reshape(-1)
        cand_h = jnp.where(is_best & jnp.isfinite(hmap), hmap, -jnp.inf)
    kk = min(K, C * B)
    cand_h, cand = lax.top_k(cand_h, kk)                               # highest first
    cand_ok = jnp.isfinite(cand_h)
    cand_point = jnp.minimum(top[cand], v - 1)
    cand_cluster = cand // B
    cand_ground = ground[cand_point]

    # Step 3: the intimate distance between heads, highest first.
    if cfg.subcluster:
        close = jnp.sum((cand_ground[:, None] - cand_ground[None]) ** 2, -1) \
            < cfg.intimate_distance ** 2
        same = cand_cluster[:, None] == cand_cluster[None]
        earlier = jnp.arange(kk)[None, :] < jnp.arange(kk)[:, None]
        rival = close & same & earlier                                  # [k, j]: j suppresses k

        def keep_step(k, kept):
            beaten = jnp.any(rival[k] & kept)
            return kept.at[k].set(cand_ok[k] & ~beaten)

        kept = lax.fori_loop(0, kk, keep_step, jnp.zeros(kk, bool))
    else:
        kept = cand_ok

    # Step 4: points join the nearest kept head of their cluster within the intimate distance.
    if cfg.subcluster:
        # [k, V], one axis at a time, reduced along the heads: XLA's CPU loops vectorise
        # neither a trailing axis of 3 nor a minimum over a trailing axis of k.
        d2 = sum((ground[:, a][None] - cand_ground[:, a][:, None]) ** 2 for a in range(3))
        ok = kept[:, None] & (cand_cluster[:, None] == lab[None]) & member[None]
        d2 = jnp.where(ok, d2, jnp.inf)
        nearest, best = jnp.zeros(v, jnp.int32), d2[0]     # argmin as a running minimum
        for j in range(1, kk):
            nearer = d2[j] < best
            nearest, best = jnp.where(nearer, j, nearest), jnp.where(nearer, d2[j], best)
        joined = best < cfg.intimate_distance ** 2
    else:
        ok = kept[None] & (cand_cluster[None] == lab[:, None]) & member[:, None]
        nearest = jnp.argmax(ok, axis=1)
        joined = jnp.any(ok, axis=1)
    sub = jnp.where(joined, nearest, kk)

    # Step 5: prune small or implausible sub-clusters.
    npts = jax.ops.segment_sum(jnp.ones(v, jnp.int32), sub, kk + 1)[:kk]
    alive = kept & (npts >= cfg.min_points) & (cand_h >= cfg.min_height) \
        & (cand_h <= cfg.max_height)
    centroid = jax.ops.segment_sum(jnp.where((sub < kk)[:, None], ground, 0), sub,
                                   kk + 1)[:kk] / jnp.maximum(npts, 1)[:, None]
    order = jnp.argsort(~alive, stable=True)                          # alive first, by height
    hh = min(H, kk)
    pick = order[:hh]
    out_alive = alive[pick]

    def pad(x, fill):
        x = jnp.where(out_alive.reshape((-1,) + (1,) * (x.ndim - 1)), x, fill)
        return jnp.concatenate([x, jnp.full((H - hh,) + x.shape[1:], fill, x.dtype)])

    slot = jnp.full(kk + 1, -1, jnp.int32).at[jnp.where(out_alive, pick, kk)].set(
        jnp.arange(hh, dtype=jnp.int32)).at[kk].set(-1)
    return HeadDetections(position=pad(centroid[pick], 0), head=pad(points[cand_point][pick], 0),
                          height=pad(cand_h[pick], 0), num_points=pad(npts[pick], 0),
                          cluster=pad(cand_cluster[pick].astype(jnp.int32), -1),
                          mask=pad(out_alive, False), point_detection=slot[sub],
                          num_dropped=(jnp.sum(alive) - jnp.sum(out_alive)).astype(jnp.int32))
