r"""Seed 001's RGB-D people detector: a point cloud to people on the ground plane.

One frame (seed 001, section III), each stage a function of its own module:

1. **Voxel grid** (`voxel_grid.voxelise`, 0.06 m): centroids and mean colours.
2. **Ground plane** (`ground_plane.fit_ground_plane`): RANSAC + least squares from the previous
   frame's plane; its inliers, and what lies below it, are removed (`voxel_grid.select`).
3. **Euclidean clustering** (`euclidean_clustering.euclidean_clusters`) of the rest, with a
   tolerance of two voxels (0.12 m, as the seed's implementation, PCL's ground-based people
   detector).
4. **Cluster merging and filtering**: clusters whose ground-plane centres are closer than
   ``merge_distance`` are merged (an occluded person split in two becomes one), then clusters
   too low to hold a head (top below ``heads.min_height``) or too high to stand on the floor
   (bottom above ``max_base_height``) are removed.
5. **Head sub-clustering** (`head_subclustering.subcluster_heads`): the five steps of
   section III-B, or one candidate per cluster when ``heads.subcluster`` is False.
6. **Appearance**: each detection's normalised RGB histogram (``histogram_bins`` per channel)
   of its voxels' colours, the input of the tracker's online colour classifier.
7. **Confidence** (`hog`): with an RGB image, its camera and a linear SVM, the HOG person
   confidence of each detection's theoretical bounding box, from the head to the ground; without
   them, 1.

The frame's state is the ground plane, carried to the next frame. Everything is fixed-shape:
the step is jittable and vmappable over episodes; `detect_batch` runs a batch of episodes'
frames in the way that is fastest on the backend.

Example:
  >>> cfg = RGBDPeopleConfig()
  >>> state = init_state(cfg)                          # the floor at z = 0, z up
  >>> state, frame = detect(cfg, state, key, points, valid, colours, viewpoint)
  >>> frame.people.position[frame.people.mask]
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxtrack import _checks, _gather
from jaxtrack.perception import euclidean_clustering, ground_plane, head_subclustering, hog
from jaxtrack.perception.euclidean_clustering import Clusters, connected_components
from jaxtrack.perception.ground_plane import PlaneFit
from jaxtrack.perception.head_subclustering import HeadConfig, HeadDetections
from jaxtrack.perception.voxel_grid import GridSpec, VoxelGrid, grid_neighbours, select, voxelise

Array = jax.Array

__all__ = ["RGBDPeopleConfig", "RGBDPeopleState", "RGBDPeopleFrame", "init_state", "detect",
           "detect_batch", "colour_histograms"]


@dataclasses.dataclass(frozen=True)
class RGBDPeopleConfig:
    """The detector's parameters (static: a `jit` static argument).

    Attributes:
      grid: the voxel grid, in the cloud's frame. The default covers a Kinect's 0.5-4.5 m
        range ahead of a robot's base frame (x forward, z up): x in [0.3, 5.1], y in
        [-3, 3], z in [-0.3, 2.4].
      voxel_capacity: V, voxels kept per frame (a QVGA frame of a room at 0.06 m holds
        about 4,000; the floor is most of them).
      foreground_capacity: voxels above the ground kept for clustering.
      ground_threshold: ground inlier distance (m), one voxel.
      num_hypotheses: RANSAC hypotheses per frame.
      max_tilt: largest change of the ground normal between frames (rad).
      cluster_tolerance: Euclidean clustering distance (m), two voxels.
      min_cluster_size: smallest cluster (voxels) kept before merging.
      cluster_capacity: C, clusters kept per frame (largest first).
      merge_distance: clusters closer than this on the ground plane are merged (m).
      max_base_height: clusters whose lowest point is higher than this are not standing on
        the floor (m).
      heads: head sub-clustering parameters.
      histogram_bins: colour histogram bins per RGB channel.
      hog: the HOG descriptor's geometry.
    """

    grid: GridSpec = GridSpec(0.06, (0.3, -3.0, -0.3), (80, 100, 45))
    voxel_capacity: int = 6144
    foreground_capacity: int = 2048
    ground_threshold: float = 0.06
    num_hypotheses: int = 32
    max_tilt: float = math.radians(15.0)
    cluster_tolerance: float = 0.12
    min_cluster_size: int = 3
    cluster_capacity: int = 32
    merge_distance: float = 0.3
    max_base_height: float = 1.0
    heads: HeadConfig = HeadConfig()
    histogram_bins: int = 4
    hog: hog.HOGConfig = hog.HOGConfig()

    def __post_init__(self):
        for name in ("voxel_capacity", "foreground_capacity", "num_hypotheses", "min_cluster_size",
                     "cluster_capacity", "histogram_bins"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= (0 if name == "num_hypotheses" else 1)):
                raise ValueError(f"RGBDPeopleConfig.{name} must be a positive integer; "
                                 f"got {value!r}")
        for name in ("ground_threshold", "max_tilt", "cluster_tolerance", "merge_distance",
                     "max_base_height"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"RGBDPeopleConfig.{name} must be a positive number; "
                                 f"got {value!r}")


class RGBDPeopleState(NamedTuple):
    """Carried from frame to frame: ``plane`` [4], the last ground plane."""

    plane: Array


class RGBDPeopleFrame(NamedTuple):
    """One frame's people and the stages that found them (for plots and diagnostics).

    Attributes:
      people: `HeadDetections` at capacity H (positions on the ground plane, in the cloud's
        frame).
      histograms: [H, b^3] normalised colour histograms (zeros for empty rows).
      confidence: [H] the HOG person confidence in (0, 1) (1 without an SVM; 0 for empty
        rows).
      boxes: [H, 4] the theoretical bounding boxes (top, left, bottom, right) in pixels (zeros
        without a camera).
      grid: the `VoxelGrid` of the whole cloud.
      ground: the `PlaneFit` (over ``grid``).
      foreground: the `VoxelGrid` of the voxels above the ground, which the clusters, the
        people's ``point_detection`` and the histograms index.
      clusters: `Clusters` of ``foreground`` after merging and filtering.
    """

    people: HeadDetections
    histograms: Array
    confidence: Array
    boxes: Array
    grid: VoxelGrid
    ground: PlaneFit
    foreground: VoxelGrid
    clusters: Clusters


def init_state(config: RGBDPeopleConfig = RGBDPeopleConfig(), height: float = 0.0,
               up=(0.0, 0.0, 1.0), dtype=jnp.float32) -> RGBDPeopleState:
    """The first frame's prior: the floor at ``height`` along ``up`` in the cloud's frame."""
    del config
    return RGBDPeopleState(ground_plane.horizontal_plane(height, up, dtype))


def detect(config: RGBDPeopleConfig, state: RGBDPeopleState, key: Array, points: Array,
           mask: Array | None, colours: Array | None, viewpoint: Array, *,
           image: Array | None = None, camera: hog.PinholeCamera | None = None,
           svm: hog.LinearSVM | None = None) -> tuple[RGBDPeopleState, RGBDPeopleFrame]:
    """Detect the people in one RGB-D point cloud.

    Args:
      config: `RGBDPeopleConfig`.
      state: the previous frame's `RGBDPeopleState` (`init_state` at the first frame).
      key: PRNG key (RANSAC).
      points: [N, 3] the cloud (N = width x height of the depth image, say), in the frame of
        ``config.grid``; N may be 0.
      mask: [N] bool valid depth, or None. Non-finite points are ignored.
      colours: [N, 3] RGB in [0, 1], or None (histograms of zeros).
      viewpoint: [3] the camera's position in the same frame.
      image: [h, w, 3] the RGB image registered to the cloud, for the HOG confidence.
      camera: `hog.PinholeCamera` of ``image`` in the cloud's frame.
      svm: `hog.LinearSVM` (e.g. `hog.load_svm()`); the confidence is computed when
        ``image``, ``camera`` and ``svm`` are all given.

    Returns:
      (new state, `RGBDPeopleFrame`).

    Example:
      >>> state, frame = jax.jit(detect, static_argnums=0)(cfg, state, key, pts, ok, rgb, eye)
    """
    _checks.check_shape("points", points, (None, 3), "[N, 3] points")
    n = _checks.shape_of(points)[0]
    if colours is not None:
        _checks.check_shape("colours", colours, (n, 3), "[N, 3] RGB in [0, 1]")
    _checks.check_shape("viewpoint", viewpoint, (3,), "[3] camera position")
    points = jnp.asarray(points)
    if not jnp.issubdtype(points.dtype, jnp.floating):
        raise TypeError(f"points must be floating; got {points.dtype}")
    if image is not None and camera is not None and svm is not None:
        _checks.check_ndim("image", image, 3, "[h, w, 3] RGB image")
    # One compiled program: called outside jit, the stages' many small operations would each
    # be dispatched on their own (a first frame took 11.6 s that way, 2.0 s compiled). Inside
    # a caller's jit this inlines.
    return _detect(config, state, key, points, mask, colours, viewpoint, image, camera, svm)


def detect_batch(config: RGBDPeopleConfig, state: RGBDPeopleState, key: Array, points: Array,
                 mask: Array | None, colours: Array | None, viewpoint: Array, *,
                 image: Array | None = None, camera: hog.PinholeCamera | None = None,
                 svm: hog.LinearSVM | None = None,
                 method: str | None = None) -> tuple[RGBDPeopleState, RGBDPeopleFrame]:
    """Detect the people in one frame of each of B episodes: `detect` over a leading axis.

    ``method``: "map" runs the frames one after the other (`jax.lax.map`), each with its
    points first written to memory; "vmap" runs them as one batched program (`jax.vmap`);
    None picks "map" on a CPU and "vmap" elsewhere. Their outputs agree to floating-point
    rounding (positions within 2e-7 m on QVGA frames). On a CPU, vmap's batched gathers and
    scatters index with (episode, row) pairs and run as scalar loops, and a loop body that
    reads slices of its input fuses the slicing into every per-point operation: on one core,
    a QVGA frame takes 3.2 ms batched by this lax.map, 6.9 ms by vmap, 3.1 ms alone, and
    took 4.2 ms by a plain lax.map (`benchmarks/rgbd_detector.py`). On a GPU the batch's
    parallelism is what pays.

    Args:
      config: `RGBDPeopleConfig`.
      state: `RGBDPeopleState` with plane [B, 4].
      key: [B] PRNG keys.
      points: [B, N, 3]; mask: [B, N] or None; colours: [B, N, 3] or None; viewpoint: [B, 3].
      image: [B, h, w, 3] or None; camera, svm: shared by the episodes (see `detect`).
      method: "map", "vmap" or None.

    Returns:
      (new states [B], `RGBDPeopleFrame` with a leading [B] axis on every leaf).

    Example:
      >>> states = jax.vmap(lambda _: init_state(cfg))(jnp.arange(B))
      >>> states, frames = detect_batch(cfg, states, keys, points, valid, colours, eyes)
      >>> frames.people.mask.shape                      # (B, H)
    """
    if method is None:
        method = "map" if jax.default_backend() == "cpu" else "vmap"
    _checks.check_options("method", (method,), ("map", "vmap"))
    _checks.check_shape("points", points, (None, None, 3), "[B, N, 3] points")
    B, n = _checks.shape_of(points)[:2]
    for name, x, shape in (("state.plane", state.plane, (B, 4)), ("viewpoint", viewpoint, (B, 3)),
                           ("mask", mask, (B, n)), ("colours", colours, (B, n, 3))):
        if x is not None:
            _checks.check_shape(name, x, shape, f"a leading batch axis of {B}")
    if _checks.shape_of(key)[:1] != (B,):
        raise ValueError(f"key must hold one PRNG key per episode, [{B}]; got shape "
                         f"{_checks.shape_of(key)}")
    if image is not None and camera is not None and svm is not None:
        _checks.check_ndim("image", image, 4, "[B, h, w, 3] RGB images")
        if _checks.shape_of(image)[0] != B:
            raise ValueError(f"image must have a leading batch axis of {B}; got "
                             f"{_checks.shape_of(image)}")
    if not jnp.issubdtype(jnp.asarray(points).dtype, jnp.floating):
        raise TypeError(f"points must be floating; got {jnp.asarray(points).dtype}")
    return _detect_batch(config, method, state, key, points, mask, colours, viewpoint, image,
                         camera, svm)


@functools.partial(jax.jit, static_argnums=(0, 1))
def _detect_batch(cfg, method, state, key, points, mask, colours, viewpoint, image, camera,
                  svm):
    def one(x):
        st, k, p, m, c, v, im = x
        if method == "map":
            # The points written to memory once: XLA otherwise fuses the loop's slicing of its
            # input into every per-point operation of the voxel grid, which then runs 2-4x
            # slower. The other inputs are read once each, and copying them costs more than
            # it saves (QVGA with HOG: 4.98 ms without, 3.94 with the points alone, 4.36 with
            # every input).
            p = _gather.materialised(p)
        return _detect(cfg, st, k, p, m, c, v, im, camera, svm)

    xs = (state, key, jnp.asarray(points), mask, colours, viewpoint, image)
    return lax.map(one, xs) if method == "map" else jax.vmap(one)(xs)


@functools.partial(jax.jit, static_argnums=0)
def _detect(cfg, state, key, points, mask, colours, viewpoint, image, camera, svm):
    n = points.shape[0]
    dtype = points.dtype
    rgb = jnp.zeros((n, 3), dtype) if colours is None else jnp.asarray(colours, dtype)

    with jax.named_scope("voxel_grid"):
        grid = voxelise(cfg.grid, points, mask, rgb, capacity=cfg.voxel_capacity)
    with jax.named_scope("ground_plane"):
        fit = ground_plane.fit_ground_plane(key, grid.points, grid.mask, state.plane,
                                            num_hypotheses=cfg.num_hypotheses,
                                            threshold=cfg.ground_threshold,
                                            max_tilt=cfg.max_tilt)
        above = grid.mask & ~fit.inliers & (ground_plane.plane_height(fit.plane, grid.points)
                                            > 0)
        fg = select(grid, above, cfg.foreground_capacity)
    with jax.named_scope("clustering"):
        neighbours = grid_neighbours(cfg.grid, fg, cfg.cluster_tolerance)
        raw = euclidean_clustering.euclidean_clusters(neighbours, fg.mask,
                                                      min_size=cfg.min_cluster_size,
                                                      capacity=cfg.cluster_capacity,
                                                      symmetric=True)
        clusters = _merge_and_filter(cfg, fg.points, raw, fit.plane)
    with jax.named_scope("heads"):
        people = head_subclustering.subcluster_heads(cfg.heads, fg.points, fg.mask,
                                                     clusters.labels, fit.plane,
                                                     jnp.asarray(viewpoint, dtype),
                                                     num_clusters=cfg.cluster_capacity)
        hist = colour_histograms(fg.colours, fg.counts, people.point_detection,
                                 cfg.heads.max_detections, cfg.histogram_bins)
    H = cfg.heads.max_detections
    boxes = jnp.zeros((H, 4), dtype)
    confidence = people.mask.astype(dtype)
    if camera is not None:
        foot = people.head - people.height[:, None] * fit.plane[:3]
        boxes = hog.person_box(camera, people.head, foot, cfg.hog).astype(dtype)
        boxes = jnp.where(people.mask[:, None], boxes, 0)
    if image is not None and camera is not None and svm is not None:
        with jax.named_scope("hog"):
            feats = hog.descriptors(image, boxes, cfg.hog, mask=people.mask)
            confidence = jnp.where(people.mask, hog.svm_confidence(svm, feats.astype(dtype)),
                                   0)
    frame = RGBDPeopleFrame(people, hist, confidence, boxes, grid, fit, fg, clusters)
    return RGBDPeopleState(fit.plane), frame


def colour_histograms(colours: Array, weights: Array, member: Array, num_groups: int,
                      bins: int) -> Array:
    """[G, bins^3] normalised RGB histograms of the points of each group.

    Args:
      colours: [V, 3] RGB in [0, 1]; weights: [V] (e.g. raw points per voxel);
      member: [V] int32 group of each point in [0, G), -1 for none; num_groups: G; bins: per
      channel.
    """
    q = jnp.clip(jnp.floor(colours * bins), 0, bins - 1).astype(jnp.int32)
    code = (q[:, 0] * bins + q[:, 1]) * bins + q[:, 2]
    nb = bins ** 3
    seg = jnp.where(member >= 0, member * nb + code, num_groups * nb)
    w = jnp.where(member >= 0, weights, 0).astype(colours.dtype)
    hist = jax.ops.segment_sum(w, seg, num_groups * nb + 1)[:-1].reshape(num_groups, nb)
    return hist / jnp.maximum(jnp.sum(hist, -1, keepdims=True), 1e-12)


def _merge_and_filter(cfg, points, clusters: Clusters, plane) -> Clusters:
    """Merge clusters close on the ground plane; drop those too low or not on the floor."""
    C = clusters.mask.shape[0]
    labels = clusters.labels
    lab = jnp.where(labels >= 0, labels, C)
    height = ground_plane.plane_height(plane, points)
    ground = points - height[:, None] * plane[:3]
    member = labels >= 0
    count = jax.ops.segment_sum(member.astype(points.dtype), lab, C + 1)[:C]
    centre = jax.ops.segment_sum(jnp.where(member[:, None], ground, 0), lab, C + 1)[:C] \
        / jnp.maximum(count, 1)[:, None]
    d2 = jnp.sum((centre[:, None] - centre[None]) ** 2, -1)
    near = (d2 < cfg.merge_distance ** 2) & clusters.mask[:, None] & clusters.mask[None] \
        & ~jnp.eye(C, dtype=bool)
    nbrs = jnp.where(near, jnp.arange(C, dtype=jnp.int32)[None], -1)
    root = connected_components(nbrs, clusters.mask)                  # [C], C for empty rows
    merged = jnp.where(member, jnp.concatenate([root, jnp.full(1, C, jnp.int32)])[lab], C)
    top = jax.ops.segment_max(jnp.where(member, height, -jnp.inf), merged, C + 1)[:C]
    bottom = jax.ops.segment_min(jnp.where(member, height, jnp.inf), merged, C + 1)[:C]
    sizes = jax.ops.segment_sum(member.astype(jnp.int32), merged, C + 1)[:C]
    keep = (sizes > 0) & (top >= cfg.heads.min_height) & (bottom <= cfg.max_base_height)
    keep_pad = jnp.concatenate([keep, jnp.zeros(1, bool)])
    new_labels = jnp.where(member & keep_pad[merged], merged, -1).astype(jnp.int32)
    return Clusters(labels=new_labels, sizes=jnp.where(keep, sizes, 0), mask=keep,
                    num_dropped=clusters.num_dropped)
