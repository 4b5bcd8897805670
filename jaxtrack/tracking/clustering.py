r"""K-clustering of particles into people (seed 004: Algorithms 2-5 and eq. 5).

The particle filter of the shopping-cart paper keeps one multimodal posterior over everybody in
view; KClusterise (Algorithm 2) extracts up to ``N_K`` people from it:

- `find_clusters` (Algorithm 3): make a particle a centroid when it is farther than
  :math:`\delta_{far}` from every centroid found so far (at most ``N_K``). The paper adds them
  "using a priority queue principle, considering the distance", so that "K will contain the
  most distant N_K points" (``priority="distance"``, the default): the next centroid is the far
  particle most distant from the centroids so far (the first particle to begin with), i.e.
  farthest-point sampling stopped at :math:`\delta_{far}`. ``priority="order"`` takes the far
  particles in the order the loop visits them instead.
- `classify_particles` (Algorithm 4): give each particle to the *first* centroid (in order)
  closer than :math:`\delta_{far}`; particles with none are outliers.
- `spread_outliers` (Algorithm 5): give each outlier to its nearest centroid.
- `dynamic_threshold` (eq. 5): :math:`\delta_{far}` from the detections of both sensors.

Each cluster is then summarised by its weight, mean and covariance: the Gaussian approximation
handed to the controller. Everything is fixed-shape with masks and jittable.

Both orders vectorise: each round picks the next centroid among the particles far from all
centroids so far (the most distant one, or the first one: every earlier particle was already
close to a subset of them), so `find_clusters` runs ``N_K`` vectorised rounds instead of an
N-step loop, with the same output as the loop.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxtrack import _checks
from jaxtrack.filters import _linalg
from jaxtrack.filters.particle import normalize

Array = jax.Array

__all__ = ["Clusters", "dynamic_threshold", "find_clusters", "classify_particles",
           "spread_outliers", "kclusterise"]


class Clusters(NamedTuple):
    """Result of `kclusterise`.

    Attributes:
      weights: [N_K] total normalised particle weight of each cluster (0 for unused slots).
      means: [N_K, n] weighted means of the member particles.
      covs: [N_K, n, n] weighted covariances of the member particles.
      mask: [N_K] bools, which cluster slots are used.
      centroids: [N_K, d] the centroid positions found by Algorithm 3.
      labels: [N] cluster index of every particle (-1 for masked-out particles).
    """

    weights: Array
    means: Array
    covs: Array
    mask: Array
    centroids: Array
    labels: Array


def _pairwise_sum(points, mask):
    d = points[:, None, :] - points[None, :, :]
    sq = jnp.sum(d**2, -1)
    pair = mask[:, None] & mask[None, :] & (sq > 0)  # coincident pairs add 0 (safe gradient)
    dist = jnp.where(pair, jnp.sqrt(jnp.where(pair, sq, 1.0)), 0.0)
    return jnp.sum(dist)


def dynamic_threshold(laser: Array, camera: Array, laser_mask: Array | None = None,
                      camera_mask: Array | None = None, floor: float = 0.0,
                      mode: str = "paper") -> Array:
    r"""Dynamic threshold distance :math:`\delta_{far}` from the detections (eq. 5).

    ``mode="paper"`` is eq. 5 as printed, over ordered pairs of present laser detections
    :math:`P_L` and camera detections :math:`P_K`:

    .. math::
        \delta_{far} = \frac{\sum_{i \ne j} \|p_L^i - p_L^j\| + \sum_{i \ne j}
        \|p_K^i - p_K^j\|}{|P_L| + |P_K|}.

    Its numerator grows with the square of the number of people and its denominator linearly,
    so the threshold grows with the crowd: two people d apart give d (a particle of the second
    person is "far" from the first only half the time), and three people 3-5 m apart give about
    8 m, which merges them. ``mode="half_mean"`` returns half the mean pairwise distance
    instead: d / 2 for two people, and it stays between people as the crowd grows.

    With fewer than two detections per sensor both give 0; ``floor`` (m) is a lower bound for
    that case (0 reproduces the paper).

    Args:
      laser: [L, 2] laser person detections; camera: [K, 2] RGB-D detections.
      laser_mask, camera_mask: optional [L] / [K] bools.
      floor: minimum returned value.
      mode: "paper" or "half_mean".

    Returns:
      Scalar threshold (m).

    Example:
      >>> dynamic_threshold(jnp.array([[0., 0.], [2., 0.]]), jnp.zeros((0, 2)))  # 4 / 2 = 2
    """
    _checks.check_options("mode", (mode,), ("paper", "half_mean"))
    _checks.check_shape("laser", laser, (None, None))
    _checks.check_shape("camera", camera, (None, jnp.shape(laser)[1]))
    lm = jnp.ones(laser.shape[0], bool) if laser_mask is None else jnp.asarray(laser_mask, bool)
    cm = jnp.ones(camera.shape[0], bool) if camera_mask is None else jnp.asarray(camera_mask, bool)
    lm = lm & jnp.all(jnp.isfinite(laser), -1)
    cm = cm & jnp.all(jnp.isfinite(camera), -1)
    laser = jnp.where(lm[:, None], laser, 0.0)
    camera = jnp.where(cm[:, None], camera, 0.0)
    total = _pairwise_sum(laser, lm) + _pairwise_sum(camera, cm)
    n_l, n_k = jnp.sum(lm), jnp.sum(cm)
    if mode == "paper":
        count = n_l + n_k
    else:
        count = 2 * (n_l * (n_l - 1) + n_k * (n_k - 1))
    value = jnp.where(count > 0, total / jnp.maximum(count, 1), 0.0)
    return jnp.maximum(value, floor)


def _distances(points, centroids):
    sq = jnp.sum((points[:, None, :] - centroids[None, :, :]) ** 2, -1)
    return jnp.sqrt(jnp.maximum(sq, 0.0))


def find_clusters(points: Array, threshold, max_clusters: int,
                  mask: Array | None = None, priority: str = "distance"
                  ) -> tuple[Array, Array]:
    """Algorithm 3 (FindCluster): up to ``max_clusters`` mutually distant centroids.

    Args:
      points: [N, d] particle positions, in the order Algorithm 3 visits them.
      threshold: :math:`\\delta_{far}` (m); a particle may become a centroid when it is
        strictly farther than this from every centroid so far.
      max_clusters: N_K (static).
      mask: optional [N] bools; masked or non-finite points are skipped.
      priority: "distance" (the paper's priority queue: the far particle most distant from the
        centroids so far comes next; ties to the first) or "order" (the first far particle).

    Returns:
      ``(centroids [N_K, d], centroid_mask [N_K])``; centroids are in discovery order.

    Example:
      >>> centroids, found = find_clusters(particles[:, :2], 0.6, 8)
    """
    _checks.check_options("priority", (priority,), ("distance", "order"))
    valid = _valid(points, mask)
    points = jnp.where(valid[:, None], points, 0.0)
    n = points.shape[0]
    dtype = points.dtype

    def round_(d_min, _):
        candidate = valid & (d_min > threshold)
        found = jnp.any(candidate)
        if priority == "distance":
            idx = jnp.argmax(jnp.where(candidate, d_min, -1.0))
        else:
            idx = jnp.argmax(candidate)
        centroid = points[idx]
        d = jnp.sqrt(jnp.sum((points - centroid) ** 2, -1))
        d_min = jnp.where(found, jnp.minimum(d_min, d), d_min)
        return d_min, (centroid, found)

    _, (centroids, found) = lax.scan(round_, jnp.full(n, jnp.inf, dtype), None,
                                     length=max_clusters)
    return jnp.where(found[:, None], centroids, 0.0), found


def classify_particles(points: Array, centroids: Array, centroid_mask: Array, threshold,
                       mask: Array | None = None) -> Array:
    """Algorithm 4 (ClassifyParticles): first centroid (in order) closer than the threshold.

    Returns:
      labels [N]: the cluster index, or -1 for outliers and masked points.
    """
    valid = _valid(points, mask)
    d = _distances(jnp.where(valid[:, None], points, 0.0), centroids)
    within = (d < threshold) & centroid_mask[None, :]
    first = jnp.argmax(within, -1)
    return jnp.where(valid & jnp.any(within, -1), first, -1).astype(jnp.int32)


def spread_outliers(points: Array, centroids: Array, centroid_mask: Array, labels: Array,
                    mask: Array | None = None) -> Array:
    """Algorithm 5 (SpreadOutliers): outliers (label -1) go to their nearest centroid.

    Returns:
      labels [N] with no -1 left among valid points (if any centroid exists).
    """
    valid = _valid(points, mask)
    d = _distances(jnp.where(valid[:, None], points, 0.0), centroids)
    d = jnp.where(centroid_mask[None, :], d, jnp.inf)
    nearest = jnp.argmin(d, -1)
    outlier = valid & (labels < 0) & jnp.any(centroid_mask)
    return jnp.where(outlier, nearest, labels).astype(jnp.int32)


def kclusterise(particles: Array, log_weights: Array, threshold, max_clusters: int,
                position_dims: int = 2, mask: Array | None = None,
                priority: str = "distance") -> Clusters:
    """Algorithm 2 (KClusterise) and the Gaussian summary of every cluster.

    Distances use the first ``position_dims`` components; means and covariances cover the whole
    particle state (e.g. position and velocity).

    Args:
      particles: [N, n]; log_weights: [N]; threshold: delta_far (see `dynamic_threshold`);
      max_clusters: N_K (static); position_dims: d; mask: optional [N] bools.
      priority: `find_clusters`' order ("distance", the paper's, or "order").

    Returns:
      `Clusters`.

    Example:
      >>> thr = dynamic_threshold(laser_xy, camera_xy, laser_mask, camera_mask)
      >>> people = kclusterise(ps.particles, ps.log_weights, thr, max_clusters=8)
      >>> people.means[people.mask]
    """
    _checks.check_ndim("particles", particles, 2, "[N, n] particles")
    _checks.check_shape("log_weights", log_weights, (jnp.shape(particles)[0],))
    if not 1 <= position_dims <= jnp.shape(particles)[1]:
        raise ValueError(f"position_dims must be in [1, n]; got {position_dims}")
    if max_clusters < 1:
        raise ValueError(f"max_clusters must be >= 1; got {max_clusters}")
    valid = _valid(particles, mask) & ~jnp.isnan(log_weights)
    pos = particles[:, :position_dims]
    centroids, cmask = find_clusters(pos, threshold, max_clusters, valid, priority)
    labels = classify_particles(pos, centroids, cmask, threshold, valid)
    labels = spread_outliers(pos, centroids, cmask, labels, valid)
    lw = normalize(jnp.where(valid, log_weights, -jnp.inf))
    w = jnp.where(valid, jnp.exp(lw), 0.0)
    x = jnp.where(valid[:, None], particles, 0.0)
    onehot = (labels[:, None] == jnp.arange(max_clusters)[None, :]) * w[:, None]  # [N, N_K]
    weights = jnp.sum(onehot, 0)
    safe = jnp.where(weights > 0, weights, 1.0)
    means = (onehot.T @ x) / safe[:, None]
    dev = x[None, :, :] - means[:, None, :]  # [N_K, N, n]
    covs = jnp.einsum("kn,kni,knj->kij", onehot.T, dev, dev) / safe[:, None, None]
    return Clusters(weights, means, _linalg.symmetrize(covs), cmask & (weights > 0), centroids,
                    jnp.where(valid, labels, -1))


def _valid(points, mask):
    finite = jnp.all(jnp.isfinite(points), -1)
    return finite if mask is None else finite & jnp.asarray(mask, bool)
