r"""Shape features of laser-scan segments for a learned leg classifier (Arras et al., "Using
boosted features for the detection of people in 2D range data", ICRA 2007; the feature set of
the ROS leg trackers that seed 004 builds on).

One row of `NUM_FEATURES` floats per segment of `jaxtrack.perception.legs.segment`, computed
with segment sums over the beams (no loop over segments or points: jittable, vmappable over
scans). With :math:`x_1 .. x_n` the segment's points in beam order, :math:`\bar x` their mean,
:math:`d_j = \|x_j - x_{j-1}\|` the :math:`n - 1` steps between neighbours and
:math:`\lambda_{\min} \le \lambda_{\max}` the eigenvalues of the scatter
:math:`\sum_i (x_i - \bar x)(x_i - \bar x)^T`:

===  =======================  ===============================================================
 k   name                     definition
===  =======================  ===============================================================
 0   num_points               :math:`n`
 1   width                    :math:`\|x_n - x_1\|`
 2   length                   extent of the points along the scatter's major axis
                              (:math:`\max - \min` of the projections)
 3   std                      :math:`\sqrt{\sum_i \|x_i - \bar x\|^2 / (n - 1)}` (0 for n = 1)
 4   linearity                :math:`\lambda_{\min}`: residual sum of squares of the
                              total-least-squares line
 5   circularity              :math:`\sum_i (\rho - \|x_i - c\|)^2` for the Kasa circle
                              :math:`(c, \rho)`; the linearity where no circle fits
 6   radius                   :math:`\min(\rho, \text{MAX_RADIUS})`; MAX_RADIUS where no
                              circle fits (fewer than 3 points, collinear points)
 7   boundary_length          :math:`\sum_j d_j`
 8   boundary_regularity      standard deviation of the :math:`d_j` (0 for n < 3)
 9   mean_curvature           mean over the inner points of the Menger curvature
                              :math:`2 |(x_j - x_{j-1}) \times (x_{j+1} - x_{j-1})|
                              / (d_j\, d_{j+1}\, \|x_{j+1} - x_{j-1}\|)` (0 for n < 3)
10   mean_angular_difference  mean over the inner points of the *signed* turning angle from
                              :math:`x_j - x_{j-1}` to :math:`x_{j+1} - x_j` (0 for n < 3).
                              Signed, so that a leg's arc, which turns one way all along,
                              is told from a noisy wall, whose turns cancel
11   gap_before               distance from :math:`x_1` to the last point of the previous
                              segment (MAX_GAP for the first segment)
12   gap_after                distance from :math:`x_n` to the first point of the next
                              segment (MAX_GAP for the last one)
13   range                    :math:`\|\bar x\|`, distance from the sensor: point counts and
                              steps scale with it
===  =======================  ===============================================================

All features are finite on every segment (capped where a fit is undefined) so that a tree
ensemble, and scikit-learn when training, can split on them. Masked rows are 0.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from jaxtrack import _checks, geometry
from jaxtrack.perception import legs as legs_mod

Array = jax.Array

__all__ = ["FEATURE_NAMES", "NUM_FEATURES", "MAX_RADIUS", "MAX_GAP", "compute",
           "segment_features"]

FEATURE_NAMES = ("num_points", "width", "length", "std", "linearity", "circularity", "radius",
                 "boundary_length", "boundary_regularity", "mean_curvature",
                 "mean_angular_difference", "gap_before", "gap_after", "range")
NUM_FEATURES = len(FEATURE_NAMES)
MAX_RADIUS = 10.0   # m: the radius of a circle that does not fit, and the cap of any radius
MAX_GAP = 100.0     # m: the gap of a segment without a neighbour on that side


def compute(ranges: Array, angles: Array, segments: legs_mod.Segments, max_range=5.6,
            min_range=0.0) -> Array:
    """Features of every segment of one scan.

    Args:
      ranges: [B] ranges; angles: [B] beam angles (radians, ascending).
      segments: `legs.Segments` of this scan (capacity S).
      max_range, min_range: as given to `legs.segment`.

    Returns:
      [S, NUM_FEATURES] features (columns in `FEATURE_NAMES` order; rows of masked segments 0).

    Example:
      >>> segs = legs.segment(ranges, angles, 5.6, jump=0.13)
      >>> X = compute(ranges, angles, segs, 5.6)          # [S, 14]
    """
    legs_mod.check_scan(ranges, angles)
    if _checks.shape_of(ranges)[0] == 0:        # no beam, no segment
        dtype = jnp.result_type(ranges, angles, float)
        return jnp.zeros((segments.first.shape[0], NUM_FEATURES), dtype)
    return _compute(jnp.asarray(ranges), jnp.asarray(angles), segments, min_range, max_range)


@jax.jit
def _compute(ranges, angles, segments, min_range, max_range):
    xy, valid = legs_mod.scan_returns(ranges, angles, min_range, max_range)
    return segment_features(xy, valid, segments)


def segment_features(xy: Array, valid: Array, segs: legs_mod.Segments) -> Array:
    """`compute` on the scan's points: xy [B, 2] (sensor frame), valid [B] returns, segs with
    capacity S.

    Returns:
      [S, NUM_FEATURES].
    """
    S = segs.first.shape[0]
    B = xy.shape[0]
    dtype = xy.dtype
    labels = segs.labels
    ids = jnp.where(labels >= 0, labels, S)
    inside = labels >= 0
    sqrt0 = geometry.safe_sqrt

    def total(v):                    # segment sums of per-beam rows [B, K] -> [S, K]
        return jax.ops.segment_sum(jnp.where(inside[:, None], v, 0.0), ids, S + 1)[:S]

    n = segs.num_points.astype(dtype)
    safe_n = jnp.maximum(n, 1.0)
    mean = total(xy) / safe_n[:, None]
    seg_of_beam = jnp.minimum(ids, S - 1)
    u = xy - mean[seg_of_beam]
    z = jnp.sum(u * u, -1)

    # Neighbouring points within the segment (beam order).
    prev_xy = jnp.concatenate([xy[:1], xy[:-1]])
    next_xy = jnp.concatenate([xy[1:], xy[-1:]])
    prev_same = jnp.concatenate([jnp.zeros(1, bool), (labels[1:] == labels[:-1])]) & inside
    next_same = jnp.concatenate([(labels[:-1] == labels[1:]), jnp.zeros(1, bool)]) & inside
    inner = prev_same & next_same
    a = xy - prev_xy                                   # x_j - x_{j-1}
    b = next_xy - xy                                   # x_{j+1} - x_j
    step = jnp.where(prev_same, sqrt0(jnp.sum(a * a, -1)), 0.0)
    step_next = sqrt0(jnp.sum(b * b, -1))
    chord = next_xy - prev_xy
    chord_len = sqrt0(jnp.sum(chord * chord, -1))
    cross_ab = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    dot_ab = jnp.sum(a * b, -1)
    denom = step * step_next * chord_len
    ok_curv = inner & (denom > 0)
    curvature = jnp.where(ok_curv, 2.0 * jnp.abs(cross_ab) / jnp.where(ok_curv, denom, 1.0), 0.0)
    ok_turn = inner & ((jnp.abs(cross_ab) + jnp.abs(dot_ab)) > 0)
    turn = jnp.where(ok_turn, jnp.arctan2(cross_ab, jnp.where(ok_turn, dot_ab, 1.0)), 0.0)

    # One scatter for every per-beam sum (XLA:CPU scatters are serial loops over the beams).
    sums = total(jnp.stack([u[:, 0] ** 2, u[:, 1] ** 2, u[:, 0] * u[:, 1], u[:, 0] * z,
                            u[:, 1] * z, z, step, step ** 2, curvature, turn,
                            inner.astype(dtype)], -1))
    suu, svv, suv, suz, svz, sz, s_step, s_step2, s_curv, s_turn, n_inner = (
        sums[:, k] for k in range(11))

    half_tr, half_diff = 0.5 * (suu + svv), 0.5 * (suu - svv)
    root = sqrt0(half_diff ** 2 + suv ** 2)
    lam_min = jnp.maximum(half_tr - root, 0.0)
    std = sqrt0(sz / jnp.maximum(n - 1.0, 1.0))

    # Major axis of the scatter: eigenvector of lam_max = half_tr + root.
    vx, vy = root + half_diff, suv                     # (lam_max - svv, suv)
    alt = root - half_diff                             # the other form, better when vx ~ 0
    use_alt = jnp.abs(vx) < jnp.abs(alt)
    vx, vy = jnp.where(use_alt, suv, vx), jnp.where(use_alt, alt, vy)
    norm = sqrt0(vx ** 2 + vy ** 2)
    ok_axis = norm > 0
    ax = jnp.where(ok_axis, vx / jnp.where(ok_axis, norm, 1.0), 1.0)
    ay = jnp.where(ok_axis, vy / jnp.where(ok_axis, norm, 1.0), 0.0)
    proj = u[:, 0] * ax[seg_of_beam] + u[:, 1] * ay[seg_of_beam]
    hi = jax.ops.segment_max(jnp.where(inside, proj, -jnp.inf), ids, S + 1)[:S]
    lo = jax.ops.segment_min(jnp.where(inside, proj, jnp.inf), ids, S + 1)[:S]
    length = jnp.where(segs.mask, hi - lo, 0.0)

    # Kasa circle (as in legs.features), residual sum of squares to it.
    fit, centre, rho = legs_mod.kasa_circle(segs.mask, n, sums[:, :6])
    circle = jnp.concatenate([centre, rho[:, None]], -1)[seg_of_beam]
    resid = sqrt0(jnp.sum((u - circle[:, :2]) ** 2, -1)) - circle[:, 2]
    circ_rss = total(resid[:, None] ** 2)[:, 0]
    circularity = jnp.where(fit, circ_rss, lam_min)
    radius = jnp.where(fit, jnp.minimum(rho, MAX_RADIUS), MAX_RADIUS)

    n_steps = jnp.maximum(n - 1.0, 1.0)
    mean_step = s_step / n_steps
    regularity = jnp.where(n >= 3, sqrt0(jnp.maximum(s_step2 / n_steps - mean_step ** 2, 0.0)),
                           0.0)
    safe_inner = jnp.maximum(n_inner, 1.0)
    mean_curv = s_curv / safe_inner
    mean_turn = s_turn / safe_inner

    first_xy, last_xy = xy[segs.first], xy[segs.last]
    width = sqrt0(jnp.sum((last_xy - first_xy) ** 2, -1))
    # Segments are runs of valid beams, so the neighbouring segments' nearest points are the
    # nearest valid beams before the first and after the last beam (also when the neighbour
    # was dropped for capacity).
    beams = jnp.arange(B)
    prev_valid = lax.cummax(jnp.where(valid, beams, -1))          # last valid beam <= i
    next_valid = lax.cummin(jnp.where(valid, beams, B), reverse=True)
    before = jnp.concatenate([jnp.full(1, -1), prev_valid[:-1]])[segs.first]
    after = jnp.concatenate([next_valid[1:], jnp.full(1, B)])[segs.last]
    gap_before = jnp.where(before >= 0, sqrt0(jnp.sum(
        (first_xy - xy[jnp.maximum(before, 0)]) ** 2, -1)), MAX_GAP)
    gap_after = jnp.where(after < B, sqrt0(jnp.sum(
        (xy[jnp.minimum(after, B - 1)] - last_xy) ** 2, -1)), MAX_GAP)
    rng = sqrt0(jnp.sum(mean ** 2, -1))

    out = jnp.stack([n, width, length, std, lam_min, circularity, radius, s_step, regularity,
                     mean_curv, mean_turn, gap_before, gap_after, rng], -1)
    return jnp.where(segs.mask[:, None], out, 0.0).astype(dtype)
