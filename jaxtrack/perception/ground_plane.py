r"""The ground plane of a point cloud, by RANSAC and least squares, updated frame to frame
(seed 001, section III-B).

Seed 001 assumes people walk on a ground plane and removes it before clustering: "We compute the
plane coefficients with a RANSAC-based least square method and we remove all the inliers within
a threshold distance. The ground plane equation is updated at every frame by considering as
initial condition the estimation at the previous frame."

A plane is :math:`(n, d)` with :math:`\|n\| = 1`, and :math:`h(p) = n \cdot p + d` is a point's
signed height above it, positive on the side of ``up``. One frame's estimate:

1. **Hypotheses**: the previous frame's plane, and ``num_hypotheses`` planes through three points
   drawn at random from the cloud. A fixed number, so the step has a fixed cost under `jit`.
   Hypotheses tilted more than ``max_tilt`` from the previous normal are refused: a wall or a
   table top may hold more points than the visible floor, but the floor does not jump between
   frames.
2. **Consensus**: each hypothesis scores its inliers, :math:`|h(p)| \le` ``threshold``; the
   best wins (the previous plane on ties).
3. **Least squares**: the plane is refitted to the winner's inliers (their centroid and the
   covariance's smallest eigenvector), and the inliers recomputed with it.

Example:
  >>> fit = fit_ground_plane(key, grid.points, grid.mask, previous=fit.plane)
  >>> above = grid.mask & ~fit.inliers
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxtrack import _checks

Array = jax.Array

__all__ = ["PlaneFit", "fit_ground_plane", "plane_height", "horizontal_plane"]


class PlaneFit(NamedTuple):
    r"""One frame's ground plane.

    Attributes:
      plane: [4] (n_x, n_y, n_z, d), unit normal pointing up; height :math:`n \cdot p + d`.
      inliers: [V] bool ground points, :math:`|h(p)| \le` threshold.
      num_inliers: int32.
      from_previous: bool, the previous plane won the consensus (before the refit).
    """

    plane: Array
    inliers: Array
    num_inliers: Array
    from_previous: Array


def horizontal_plane(height: float = 0.0, up=(0.0, 0.0, 1.0), dtype=jnp.float32) -> Array:
    """The plane at ``height`` along the unit vector ``up``: the prior for the first frame when
    the sensor's mount is known (a robot's camera in its base frame, z up)."""
    u = jnp.asarray(up, dtype)
    u = u / jnp.linalg.norm(u)
    return jnp.concatenate([u, jnp.asarray([-height], dtype)])


def plane_height(plane: Array, points: Array) -> Array:
    r"""[..., N] signed height :math:`n \cdot p + d` of [..., N, 3] points above a [..., 4] plane."""
    return jnp.einsum("...i,...ni->...n", plane[..., :3], points) + plane[..., 3:4]


def fit_ground_plane(key: Array, points: Array, mask: Array, previous: Array, *,
                     num_hypotheses: int = 64, threshold: float = 0.06,
                     max_tilt: float = math.radians(15.0)) -> PlaneFit:
    """Fit the ground plane of one frame, starting from the previous frame's.

    Args:
      key: PRNG key for the three-point hypotheses.
      points: [V, 3] points (typically voxel centroids).
      mask: [V] bool valid points.
      previous: [4] the previous frame's plane (or `horizontal_plane` at the first frame); its
        normal also sets which side is up.
      num_hypotheses: random three-point hypotheses per frame (static).
      threshold: inlier distance (m); seed 001's implementation removes the ground within one
        voxel (0.06 m).
      max_tilt: largest angle between a hypothesis and the previous normal (rad).

    Returns:
      `PlaneFit`. With fewer than three valid points, the previous plane is returned unchanged.

    Example:
      >>> fit = fit_ground_plane(key, pts, mask, horizontal_plane(0.0))
    """
    _checks.check_shape("points", points, (None, 3), "[V, 3] points")
    v = _checks.shape_of(points)[0]
    _checks.check_shape("mask", mask, (v,), "[V] bool")
    _checks.check_shape("previous", previous, (4,), "[4] plane (n, d)")
    if int(num_hypotheses) != num_hypotheses or num_hypotheses < 0:
        raise ValueError(f"num_hypotheses must be a non-negative integer; got {num_hypotheses}")
    for name, value in (("threshold", threshold), ("max_tilt", max_tilt)):
        if _checks.is_concrete(value) and not (math.isfinite(float(value)) and value > 0):
            raise ValueError(f"{name} must be positive and finite; got {value}")
    points = jnp.asarray(points)
    dtype = points.dtype
    previous = jnp.asarray(previous, dtype)
    up = previous[:3] / jnp.maximum(jnp.linalg.norm(previous[:3]), 1e-12)
    previous = previous / jnp.maximum(jnp.linalg.norm(previous[:3]), 1e-12)
    valid = jnp.asarray(mask, bool) & jnp.all(jnp.isfinite(points), -1)
    pts = jnp.where(valid[:, None], points, 0)
    if v == 0:
        return PlaneFit(previous, jnp.zeros(0, bool), jnp.int32(0), jnp.asarray(True))

    # Three valid points per hypothesis: uniform ranks among the valid points, located by a
    # search in their running count (cheaper than a categorical over all V points).
    rank = jax.random.randint(key, (num_hypotheses, 3), 0, jnp.maximum(jnp.sum(valid), 1))
    idx = jnp.minimum(jnp.searchsorted(jnp.cumsum(valid), rank, side="right"), v - 1)
    a, b, c = pts[idx[:, 0]], pts[idx[:, 1]], pts[idx[:, 2]]
    normal = jnp.cross(b - a, c - a)
    norm = jnp.linalg.norm(normal, axis=-1, keepdims=True)
    normal = normal / jnp.maximum(norm, 1e-12)
    normal = normal * jnp.where(normal @ up < 0, -1.0, 1.0)[:, None]
    cand = jnp.concatenate([normal, -jnp.sum(normal * a, -1, keepdims=True)], -1)
    good = (norm[:, 0] > 1e-9) & (cand[:, :3] @ up >= jnp.cos(max_tilt))
    planes = jnp.concatenate([previous[None], cand], 0)               # [1 + K, 4]
    good = jnp.concatenate([jnp.ones(1, bool), good])
    inl = (jnp.abs(plane_height(planes, pts)) <= threshold) & valid   # [1 + K, V]
    score = jnp.where(good, jnp.sum(inl, -1), -1)
    best = jnp.argmax(score)                                          # first max: previous wins ties
    refit = _least_squares_plane(pts, inl[best], up)
    enough = jnp.sum(inl[best]) >= 3
    plane = jnp.where(enough, refit, planes[best])
    inliers = (jnp.abs(plane_height(plane, pts)) <= threshold) & valid
    have = jnp.sum(valid) >= 3
    plane = jnp.where(have, plane, previous)
    inliers = jnp.where(have, inliers, jnp.zeros_like(inliers))
    return PlaneFit(plane=plane, inliers=inliers, num_inliers=jnp.sum(inliers).astype(jnp.int32),
                    from_previous=best == 0)


def _least_squares_plane(points, weights, up):
    """The total-least-squares plane of the weighted points: through their centroid, normal to
    the direction of least spread."""
    w = weights.astype(points.dtype)
    total = jnp.maximum(jnp.sum(w), 1.0)
    centroid = jnp.sum(points * w[:, None], 0) / total
    d = (points - centroid) * w[:, None]
    cov = d.T @ (points - centroid) / total
    _, vecs = jnp.linalg.eigh(cov)
    n = vecs[:, 0]
    n = jnp.where(n @ up < 0, -n, n)
    return jnp.concatenate([n, -(n @ centroid)[None]])
