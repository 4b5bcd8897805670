r"""People detection from a 2-D laser scan by their legs (seed 004, section III-a; seed 002).

Seed 004 detects legs in the scan of a shin-height laser (Arras et al.'s leg tracker: segments of
the scan classified by geometric features) and extracts people from legs with four heuristics:
people have two legs; the legs are close to each other; they move in a similar direction; they
occlude each other more often than other things occlude them. This module is that pipeline for
one scan, at fixed capacities with masks (jittable, vmappable):

1. `segment`: split the scan where consecutive returns are more than ``jump`` apart (the jump
   distance of Arras et al. 2007) or where a beam has no valid return. At most ``max_segments``
   segments are kept, in beam order; further ones are dropped and counted
   (``Segments.dropped``).
2. `features`: per segment, the number of points, the width (first to last point), the mean
   point, the rms distance to the total-least-squares line (linearity), the algebraic circle
   fit of Kasa (1976) (radius, centre, rms residual) and the estimated leg axis position.
3. `leg_candidates`: segments whose point count, width and circle radius fit a human leg
   (`LegParams`; widths 3-25 cm, near typical leg detectors', where seed 004 trains AdaBoost).
4. `pair_legs`: greedy pairing, closest pair first, of candidates within ``pair_distance``
   (legs are close); optional motion cue from the previous frame's legs (pairs whose legs both
   moved, in directions more than ``max_motion_angle`` apart, are not paired); unpaired legs
   may count as people (``single_legs``: a leg occluded by the other). A person is the
   midpoint of their two legs.
5. `detect` / `detect_people`: the whole chain.

Limits, measured in the tests: any two leg-like objects closer than ``pair_distance`` make a
person -- table and chair legs *do* look like legs (a 3 cm table leg is a candidate at most
ranges); only their spacing keeps them apart. One leg hidden behind the other leaves a single
leg: a person only with ``single_legs``. Two legs closer than ``jump`` merge into one
segment, up to 0.3 m wide, which is too wide for a leg: with ``single_legs`` off such a person
is missed; the motion cue needs legs associated over frames, here by nearest neighbour.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxtrack import _checks, geometry

Array = jax.Array

__all__ = ["LegParams", "Segments", "SegmentFeatures", "People", "Detections", "segment",
           "features", "leg_candidates", "pair_legs", "detect", "detect_people", "scan_returns",
           "segment_returns", "check_scan", "kasa_circle"]


class LegParams(NamedTuple):
    """Leg detector thresholds (float leaves: may be traced or vmapped).

    Attributes:
      max_range: laser maximum range; returns at or beyond it are not returns (5.6 m).
      min_range: returns at or below this are not returns (0.02 m).
      jump: segment break distance between consecutive returns (0.1 m).
      min_points: fewest points of a leg segment (3).
      min_width, max_width: leg segment width range, first to last point (0.03-0.25 m).
      min_radius, max_radius: Kasa circle-fit radius range of a leg (0.01-0.25 m; fits on
        3-4 noisy points are loose, hence the wide range).
      pair_distance: largest distance between the two legs of a person (0.5 m: a walking
        stride at shin height).
      single_legs: 1.0 to make every unpaired leg a person (occluded other leg), 0.0 not to.
      motion_gate: a leg's motion is its displacement from the nearest previous-frame leg
        within this distance (0.3 m); otherwise unknown.
      min_motion: displacements shorter than this count as standing (0.03 m).
      max_motion_angle: two moving legs whose displacement directions differ by more than
        this (radians) are not one person (pi / 2).
      convex_only: 1.0 to require the fitted circle's centre to lie farther from the sensor
        than the segment's mean point (a leg bulges towards the laser). Off by default: on
        noisy scans it also drops some thin posts and leaves many short wall pieces
        (measurements: docs/design_notes.md, "Leg detector: no convexity test by default").
    """

    max_range: float = 5.6
    min_range: float = 0.02
    jump: float = 0.1
    min_points: float = 3.0
    min_width: float = 0.03
    max_width: float = 0.25
    min_radius: float = 0.01
    max_radius: float = 0.25
    pair_distance: float = 0.5
    single_legs: float = 0.0
    motion_gate: float = 0.3
    min_motion: float = 0.03
    max_motion_angle: float = math.pi / 2
    convex_only: float = 0.0


class Segments(NamedTuple):
    """Output of `segment` (fixed capacity S).

    Attributes:
      labels: [B] int32 segment of each beam, -1 for invalid returns and dropped segments.
      first, last: [S] int32 first and last beam of each segment (0 where masked).
      num_points: [S] int32 returns per segment.
      mask: [S] bools, which segments exist.
      found: scalar int32, number of segments in the scan (may exceed S).
      dropped: scalar int32, ``max(found - S, 0)``, the segments left out (the last ones in
        beam order).
    """

    labels: Array
    first: Array
    last: Array
    num_points: Array
    mask: Array
    found: Array
    dropped: Array


class SegmentFeatures(NamedTuple):
    """Geometric features of each segment (output of `features`), sensor frame.

    Attributes:
      num_points: [S] point counts (floats).
      width: [S] distance from the first to the last point.
      mean: [S, 2] mean point.
      linearity: [S] rms distance of the points to their total-least-squares line.
      radius: [S] Kasa circle-fit radius (inf with fewer than 3 points or collinear points).
      circle_center: [S, 2] circle-fit centre (the mean point where the fit is undefined).
      circularity: [S] rms distance of the points to the fitted circle (inf where undefined).
      position: [S, 2] estimated leg axis: the mean point moved away from the sensor by
        :math:`(\\pi/4)\\,w/2` (the mean depth of a half circle of radius :math:`w/2` seen
        from afar), less noisy than the circle centre on a few points.
      mask: [S] bools.
    """

    num_points: Array
    width: Array
    mean: Array
    linearity: Array
    radius: Array
    circle_center: Array
    circularity: Array
    position: Array
    mask: Array


class People(NamedTuple):
    """Output of `pair_legs` (fixed capacity P).

    Attributes:
      xy: [P, 2] person positions (midpoint of the legs, or the single leg); 0 where masked.
      mask: [P] bools. Pairs come first (closest pair first), then single legs.
      legs: [P, 2] int32 leg (segment) indices, -1 where absent (second leg of a single).
      num_legs: [P] int32, 2, 1 or 0.
      dropped: scalar int32, people that did not fit in P.
    """

    xy: Array
    mask: Array
    legs: Array
    num_legs: Array
    dropped: Array


class Detections(NamedTuple):
    """Output of `detect`: people, the leg candidates (for the next frame's motion cue) and the
    intermediate results.

    Attributes:
      people: `People`. legs_xy: [S, 2] leg candidates' positions; legs_mask: [S].
      segments: `Segments`; features: `SegmentFeatures`.
      points: [B, 2] the scan's return points (sensor frame, 0 where invalid); valid: [B]
        returns within ``(min_range, max_range)``, e.g. obstacle points for a safety layer.
      scores: [S] leg probability of each segment with a learned classifier (0 for segments
        it did not evaluate); 1.0 / 0.0 for the geometric candidates.
      candidates_dropped: scalar int32, leg-sized segments beyond ``max_candidates`` (learned
        detector), not evaluated.
    """

    people: People
    legs_xy: Array
    legs_mask: Array
    segments: Segments
    features: SegmentFeatures
    points: Array
    valid: Array
    scores: Array
    candidates_dropped: Array


# ---------------------------------------------------------------------------------------------


def segment(ranges: Array, angles: Array, max_range, *, jump=0.1, min_range=0.0,
            max_segments: int = 64) -> Segments:
    """Split a scan into segments at range jumps and invalid returns.

    Beam :math:`i` with a valid return (finite, ``min_range < r < max_range``) starts a new
    segment when beam :math:`i - 1` has no valid return or
    :math:`\\|p_i - p_{i-1}\\| > \\text{jump}` (:math:`p` the return points). Segments are
    numbered in beam order; those beyond ``max_segments`` are dropped (their beams get label -1)
    and counted.

    Args:
      ranges: [B] ranges; angles: [B] beam angles (radians, ascending).
      max_range: scalar, readings at or beyond it are not returns.
      jump: break distance (m); min_range: readings at or below it are not returns.
      max_segments: static capacity S.

    Returns:
      `Segments`.

    Example:
      >>> segs = segment(ranges, angles, 5.6, jump=0.1, max_segments=32)
    """
    _check_scan(ranges, angles)
    if int(max_segments) < 1:
        raise ValueError(f"max_segments must be >= 1; got {max_segments}")
    if _checks.shape_of(ranges)[0] == 0:   # no beam: one beam without a return, then none
        dtype = jnp.result_type(ranges, angles, float)
        segs = segment(jnp.full((1,), jnp.inf, dtype), jnp.zeros((1,), dtype), max_range,
                       jump=jump, min_range=min_range, max_segments=max_segments)
        return segs._replace(labels=segs.labels[:0])
    return _segment_scan(jnp.asarray(ranges), jnp.asarray(angles), min_range, max_range, jump,
                         int(max_segments))


@functools.partial(jax.jit, static_argnums=5)
def _segment_scan(ranges, angles, min_range, max_range, jump, S):
    xy, valid = _points(ranges, angles, min_range, max_range)
    return _segment(xy, valid, jump, S)


def features(ranges: Array, angles: Array, segments: Segments, max_range=5.6, min_range=0.0
             ) -> SegmentFeatures:
    r"""Per-segment geometric features (the leg features of Arras et al. 2007, a subset).

    The Kasa fit minimises :math:`\sum_i (x_i^2 + y_i^2 + D x_i + E y_i + F)^2` on coordinates
    centred at the segment mean, so :math:`F = -\overline{x^2 + y^2}` and
    :math:`[S_{xx}\ S_{xy};\ S_{xy}\ S_{yy}]\,(D, E)^T = -(S_{xz}, S_{yz})^T`; centre
    :math:`(-D/2, -E/2)`, radius :math:`\sqrt{(D^2 + E^2)/4 - F}`.

    Args:
      ranges, angles: [B] the scan given to `segment`.
      segments: `Segments`.
      max_range, min_range: as given to `segment`.

    Returns:
      `SegmentFeatures`.

    Example:
      >>> f = features(ranges, angles, segment(ranges, angles, 5.6))
    """
    _check_scan(ranges, angles)
    xy, _ = _points(jnp.asarray(ranges), jnp.asarray(angles), min_range, max_range)
    return _features(xy, segments)


def leg_candidates(feats: SegmentFeatures, params: LegParams = LegParams()) -> Array:
    """Segments that look like a leg: point count, width and circle radius in range (and, with
    ``convex_only``, bulging towards the sensor).

    Returns:
      [S] bools.

    Example:
      >>> is_leg = leg_candidates(features(ranges, angles, segs))
    """
    p = params
    convex = (jnp.sum(feats.circle_center ** 2, -1) > jnp.sum(feats.mean ** 2, -1))
    return (feats.mask & (feats.num_points >= p.min_points)
            & (feats.width >= p.min_width) & (feats.width <= p.max_width)
            & (feats.radius >= p.min_radius) & (feats.radius <= p.max_radius)
            & (convex | (p.convex_only <= 0)))


def pair_legs(legs_xy: Array, legs_mask: Array, params: LegParams = LegParams(), *,
              max_people: int = 16, prev_legs: tuple[Array, Array] | None = None,
              compatible: Array | None = None) -> People:
    """Pair legs into people (seed 004's heuristics: two legs, close, moving alike).

    Greedy matching: repeatedly take the closest remaining pair of legs if it is within
    ``pair_distance`` (and motion-compatible when ``prev_legs`` is given); each pair is a
    person at the midpoint. With ``params.single_legs`` > 0 the remaining legs are people too.

    Motion cue: with ``prev_legs = (xy [L, 2], mask [L])``, a leg's displacement is taken from
    its nearest previous leg within ``motion_gate``; two legs that both moved more than
    ``min_motion`` in directions more than ``max_motion_angle`` apart are not paired (a walking
    person's stance leg barely moves, so this mostly separates legs of people who cross).

    Args:
      legs_xy: [S, 2] leg positions; legs_mask: [S] bools (e.g. `leg_candidates`).
      params: `LegParams`.
      max_people: static capacity P.
      prev_legs: optional previous-frame legs, same frame of reference.
      compatible: optional [S, S] bools, a further condition on the pairs (e.g. the motion
        cue of tracked legs' velocities, `jaxtrack.tracking.leg_tracker`).

    Returns:
      `People`.

    Example:
      >>> people = pair_legs(f.position, leg_candidates(f), max_people=8)
    """
    _checks.check_ndim("legs_xy", legs_xy, 2, "[S, 2] leg positions")
    S = _checks.shape_of(legs_xy)[0]
    _checks.check_shape("legs_xy", legs_xy, (S, 2))
    _checks.check_shape("legs_mask", legs_mask, (S,))
    if prev_legs is not None:
        if len(prev_legs) != 2:
            raise ValueError("prev_legs must be (xy [L, 2], mask [L])")
        _checks.check_ndim("prev_legs xy", prev_legs[0], 2, "[L, 2] leg positions")
        L = _checks.shape_of(prev_legs[0])[0]
        _checks.check_shape("prev_legs xy", prev_legs[0], (L, 2))
        _checks.check_shape("prev_legs mask", prev_legs[1], (L,))
    if compatible is not None:
        _checks.check_shape("compatible", compatible, (S, S))
    if int(max_people) < 1:
        raise ValueError(f"max_people must be >= 1; got {max_people}")
    legs_xy, legs_mask = jnp.asarray(legs_xy), jnp.asarray(legs_mask, bool)
    if S == 0:  # no leg: one absent leg slot gives the same (empty) people
        legs_xy = jnp.zeros((1, 2), legs_xy.dtype)
        legs_mask = jnp.zeros((1,), bool)
        compatible = None
    return _pair(legs_xy, legs_mask, params, int(max_people), prev_legs, compatible)


def detect(ranges: Array, angles: Array, params: LegParams = LegParams(), *,
           max_segments: int = 64, max_people: int = 16,
           prev_legs: tuple[Array, Array] | None = None, classifier=None,
           threshold=None, max_candidates: int | None = 16) -> Detections:
    """The whole leg detector on one scan: `segment` -> `features` -> `leg_candidates` ->
    `pair_legs`. Everything in the sensor frame.

    With a ``classifier`` (`jaxtrack.perception.leg_classifier.LegClassifier`, e.g. its
    ``default()``), the legs are the segments it classifies as legs (on the segmentation it
    was trained with: its ``jump`` replaces ``params.jump``) instead of the geometric
    thresholds of `leg_candidates`; the rest of the chain is the same.

    Args:
      ranges: [B] ranges; angles: [B] beam angles.
      params: `LegParams`.
      max_segments, max_people: static capacities S and P.
      prev_legs: optional ``(legs_xy, legs_mask)`` of the previous `Detections` (expressed in
        the current sensor frame when the robot moved) for the motion cue.
      classifier: optional learned leg classifier (a pytree; may be traced).
      threshold: with a classifier, the leg probability from which a segment is a leg
        (default the classifier's ``decision``).
      max_candidates: with a classifier, the static number of leg-sized segments it
        evaluates per scan (`leg_classifier.is_leg`'s capacity; None: all S). Further ones
        are not legs and are counted in ``Detections.candidates_dropped``.

    Returns:
      `Detections` (people, legs_xy [S, 2], legs_mask [S], segments, features, points [B, 2],
      valid [B]).

    Example:
      >>> det = detect(ranges, angles)
      >>> det = detect(next_ranges, angles, prev_legs=(det.legs_xy, det.legs_mask))
    """
    _check_scan(ranges, angles)
    for name, v in (("max_segments", max_segments), ("max_people", max_people)):
        if int(v) < 1:
            raise ValueError(f"{name} must be >= 1; got {v}")
    if _checks.shape_of(ranges)[0] == 0:
        # A scan without beams: detect on one beam without a return, then drop that beam.
        dtype = jnp.result_type(ranges, angles, float)
        det = detect(jnp.full((1,), jnp.inf, dtype), jnp.zeros((1,), dtype), params,
                     max_segments=max_segments, max_people=max_people, prev_legs=prev_legs,
                     classifier=classifier, threshold=threshold,
                     max_candidates=max_candidates)
        return det._replace(points=det.points[:0], valid=det.valid[:0],
                            segments=det.segments._replace(labels=det.segments.labels[:0]))
    return _detect(jnp.asarray(ranges), jnp.asarray(angles), params, prev_legs, classifier,
                   threshold, max_segments=int(max_segments), max_people=int(max_people),
                   max_candidates=None if max_candidates is None else int(max_candidates))


@functools.partial(jax.jit, static_argnames=("max_segments", "max_people", "max_candidates"))
def _detect(ranges, angles, params, prev_legs, classifier, threshold, *, max_segments,
            max_people, max_candidates):
    """`detect` after its checks, compiled as one program: called outside ``jit``, the
    detector is one dispatch instead of some hundred (and compiles once per shape)."""
    xy, valid = _points(ranges, angles, params.min_range, params.max_range)
    jump = params.jump if classifier is None else classifier.jump
    segs = _segment(xy, valid, jump, max_segments)
    feats = _features(xy, segs)
    if classifier is None:
        legs = leg_candidates(feats, params)
        scores = legs.astype(xy.dtype)
        dropped = jnp.zeros((), jnp.int32)
    else:
        # Imported here: the feature and classifier modules build on this one.
        from jaxtrack.perception import leg_classifier, leg_features
        X = leg_features.segment_features(xy, valid, segs)
        legs, scores, dropped = leg_classifier.is_leg(classifier, X, segs.mask,
                                                      capacity=max_candidates,
                                                      threshold=threshold)
        scores = scores.astype(xy.dtype)
    people = pair_legs(feats.position, legs, params, max_people=max_people, prev_legs=prev_legs)
    return Detections(people, feats.position, legs, segs, feats, xy, valid, scores, dropped)


def detect_people(ranges: Array, angles: Array, params: LegParams = LegParams(), *,
                  max_segments: int = 64, max_people: int = 16) -> tuple[Array, Array]:
    """People positions from one laser scan (see `detect`).

    Args:
      ranges: [B] ranges; angles: [B] beam angles (sensor frame).
      params: `LegParams`; max_segments, max_people: static capacities.

    Returns:
      (xy [P, 2], mask [P]) in the sensor frame.

    Example:
      >>> xy, mask = jax.jit(detect_people)(ranges, angles)
    """
    people = detect(ranges, angles, params, max_segments=max_segments,
                    max_people=max_people).people
    return people.xy, people.mask


# ---------------------------------------------------------------------------------------------


# A one-point segment has zero width and scatter; a NaN derivative of their square roots
# there would poison the gradient of every range through the segment sums, though those
# segments are masked out.
_sqrt0 = geometry.safe_sqrt


def scan_returns(ranges: Array, angles: Array, min_range, max_range) -> tuple[Array, Array]:
    """The returns of a scan in the sensor frame: ``(xy [B, 2], valid [B])``, valid where the
    range is finite and within ``(min_range, max_range)`` (0 where not valid). No checks: the
    building block of `segment` and `jaxtrack.perception.leg_features`."""
    return _points(ranges, angles, min_range, max_range)


def segment_returns(xy: Array, valid: Array, jump, max_segments: int) -> Segments:
    """`segment` on the returns of `scan_returns` (static ``max_segments``; no checks)."""
    return _segment(xy, valid, jump, int(max_segments))


def check_scan(ranges, angles) -> None:
    """The checks of a scan at the public boundary: ranges [B], angles [B] finite, no NaN
    range (inf or ``max_range`` for beams without a return)."""
    _check_scan(ranges, angles)


def _points(ranges, angles, min_range, max_range):
    valid = jnp.isfinite(ranges) & (ranges > min_range) & (ranges < max_range)
    r = jnp.where(valid, ranges, 0.0)
    return jnp.stack([r * jnp.cos(angles), r * jnp.sin(angles)], -1), valid


def _segment(xy, valid, jump, S):
    B = xy.shape[0]
    step = xy[1:] - xy[:-1]
    gap = jnp.sum(step * step, -1) > jnp.asarray(jump, xy.dtype) ** 2
    prev_ok = jnp.concatenate([jnp.zeros(1, bool), valid[:-1] & ~gap])
    start = valid & ~prev_ok
    index = jnp.cumsum(start) - 1
    found = jnp.sum(start).astype(jnp.int32)
    labels = jnp.where(valid & (index < S), index, -1).astype(jnp.int32)
    ids = jnp.where(labels >= 0, labels, S)
    # Segments are runs of consecutive valid beams, each with one first and one last beam: a
    # single segment_sum (XLA:CPU scatters are serial loops over the beams) gives both.
    continues = valid & prev_ok                      # beam i is in beam i-1's segment
    end = valid & ~jnp.concatenate([continues[1:], jnp.zeros(1, bool)])
    beams = jnp.arange(B, dtype=jnp.int32)
    ends = jnp.stack([jnp.where(start, beams, 0), jnp.where(end, beams, 0)], -1)
    bounds = jax.ops.segment_sum(ends, ids, S + 1)[:S]
    mask = jnp.arange(S) < found
    first, last = bounds[:, 0], bounds[:, 1]
    num = jnp.where(mask, last - first + 1, 0)
    return Segments(labels, first, last, num, mask, found, jnp.maximum(found - S, 0))


def _features(xy, segs):
    S = segs.first.shape[0]
    dtype = xy.dtype
    ids = jnp.where(segs.labels >= 0, segs.labels, S)
    inside = (segs.labels >= 0)[:, None]

    def total(v):
        return jax.ops.segment_sum(jnp.where(inside if v.ndim == 2 else inside[:, 0], v, 0.0),
                                   ids, S + 1)[:S]

    n = segs.num_points.astype(dtype)
    safe_n = jnp.maximum(n, 1.0)
    mean = total(xy) / safe_n[:, None]
    u = xy - mean[jnp.minimum(ids, S - 1)]
    z = jnp.sum(u * u, -1)
    # One scatter for all six moments (XLA:CPU scatters are serial loops over the beams).
    moments = total(jnp.stack([u[:, 0] ** 2, u[:, 1] ** 2, u[:, 0] * u[:, 1], u[:, 0] * z,
                               u[:, 1] * z, z], -1))
    suu, svv, suv, suz, svz, sz = (moments[:, k] for k in range(6))

    # Linearity: smallest eigenvalue of the scatter, per point.
    half_tr, half_diff = 0.5 * (suu + svv), 0.5 * (suu - svv)
    lam_min = half_tr - _sqrt0(half_diff ** 2 + suv ** 2)
    linearity = _sqrt0(jnp.maximum(lam_min, 0.0) / safe_n)

    fit, local, rho = kasa_circle(segs.mask, n, moments)
    radius = jnp.where(fit, rho, jnp.inf)
    circle = jnp.concatenate([local, rho[:, None]], -1)
    circle = circle[jnp.minimum(ids, S - 1)]                  # one gather: [B, 3]
    resid = _sqrt0(jnp.sum((u - circle[:, :2]) ** 2, -1)) - circle[:, 2]
    circularity = jnp.where(fit, _sqrt0(total(resid ** 2) / safe_n), jnp.inf)

    width = _sqrt0(jnp.sum((xy[segs.last] - xy[segs.first]) ** 2, -1))
    dist = _sqrt0(jnp.sum(mean**2, -1))
    outward = mean / jnp.where(dist > 0, dist, 1.0)[:, None]
    position = mean + (0.125 * math.pi) * width[:, None] * outward
    zero = jnp.zeros_like(mean)
    m1 = segs.mask
    return SegmentFeatures(
        num_points=n, width=jnp.where(m1, width, 0.0), mean=jnp.where(m1[:, None], mean, zero),
        linearity=jnp.where(m1, linearity, 0.0), radius=radius,
        circle_center=jnp.where(m1[:, None], mean + local, zero), circularity=circularity,
        position=jnp.where(m1[:, None], position, zero), mask=m1)


def kasa_circle(mask: Array, n: Array, moments: Array) -> tuple[Array, Array, Array]:
    """Kasa's circle fit of each segment from its centred moments (see `features`).

    Args:
      mask: [S] segments; n: [S] point counts (float).
      moments: [S, 6] sums over the points of :math:`u^2, v^2, uv, uz, vz, z` with
        :math:`(u, v)` a point minus the segment mean and :math:`z = u^2 + v^2`.

    Returns:
      ``(fit [S] bools, centre [S, 2] relative to the mean, radius [S])``; the fit is
      undefined (centre and radius 0) for fewer than 3 points or (numerically) collinear ones.
    """
    suu, svv, suv, suz, svz, sz = (moments[:, k] for k in range(6))
    half_tr = 0.5 * (suu + svv)
    det = suu * svv - suv ** 2
    fit = mask & (n >= 3) & (det > 1e-6 * jnp.maximum(half_tr, 1e-30) ** 2)
    safe_det = jnp.where(fit, det, 1.0)
    D = -(svv * suz - suv * svz) / safe_det
    E = -(suu * svz - suv * suz) / safe_det
    F = -sz / jnp.maximum(n, 1.0)
    rho_sq = 0.25 * (D * D + E * E) - F
    fit = fit & (rho_sq > 0)
    rho = jnp.where(fit, jnp.sqrt(jnp.where(fit, rho_sq, 1.0)), 0.0)
    centre = jnp.where(fit[:, None], jnp.stack([-0.5 * D, -0.5 * E], -1), 0.0)
    return fit, centre, rho


def _pair(xy, mask, params, P, prev_legs, compatible=None):
    S = xy.shape[0]
    dtype = xy.dtype
    dist = jnp.sqrt(_pairwise_sq(xy, xy) + jnp.eye(S, dtype=dtype))
    allowed = mask[:, None] & mask[None] & ~jnp.eye(S, dtype=bool) & (dist <= params.pair_distance)
    if prev_legs is not None:
        allowed = allowed & _motion_compatible(xy, mask, prev_legs, params)
    if compatible is not None:
        allowed = allowed & jnp.asarray(compatible, bool)
    cost = jnp.where(allowed, dist, jnp.inf)
    legs_idx = jnp.arange(S, dtype=jnp.int32)

    # Greedy matching (closest pair first, ties to the lowest flat index i * S + j) without a
    # sequential scan: under the strict order (distance, row, column) of the cost matrix, the
    # greedy choice's pairs are exactly the mutual nearest neighbours among the free legs; every
    # round matches all of them at once and frees the rest for the next round.
    def round_(state):
        free, partner, pair_dist, _ = state
        c = jnp.where(free[:, None] & free[None], cost, jnp.inf)
        best = jnp.min(c, 1)
        nearest = jnp.min(jnp.where(c == best[:, None], legs_idx[None], S), 1)
        onehot = (legs_idx[None] == nearest[:, None]) & jnp.isfinite(best)[:, None]
        mutual = jnp.any(onehot & (nearest[None] == legs_idx[:, None]), 1)
        return (free & ~mutual, jnp.where(mutual, nearest, partner),
                jnp.where(mutual, best, pair_dist), jnp.any(mutual))

    init = (mask, jnp.full(S, -1, jnp.int32), jnp.full(S, jnp.inf, dtype), jnp.array(True))
    _, partner, pair_dist, _ = lax.while_loop(lambda s: s[3], round_, init)
    paired = partner > legs_idx                                   # the lower leg of each pair
    n_pairs = jnp.sum(paired)
    # Greedy order of the pairs: by distance, then by lower leg index.
    earlier = paired[None] & ((pair_dist[None] < pair_dist[:, None])
                              | ((pair_dist[None] == pair_dist[:, None])
                                 & (legs_idx[None] < legs_idx[:, None])))
    rank = jnp.sum(earlier, 1)
    single = mask & (partner < 0) & (params.single_legs > 0)
    n_single = jnp.sum(single)
    # People slots: the pairs (closest first), then the singles in leg order.
    slot = jnp.where(paired, rank, jnp.where(single, n_pairs + jnp.cumsum(single) - 1, -1))
    at = slot[None] == jnp.arange(P)[:, None]                      # [P, S]
    first = jnp.max(jnp.where(at, legs_idx[None], -1), 1)
    second = jnp.max(jnp.where(at & paired[None], partner[None], -1), 1)
    legs = jnp.stack([first, second], -1).astype(jnp.int32)
    num_legs = jnp.sum(legs >= 0, -1).astype(jnp.int32)
    a = xy[jnp.maximum(first, 0)]
    b = xy[jnp.maximum(second, 0)]
    person = jnp.where((num_legs == 2)[:, None], 0.5 * (a + b), a)
    present = num_legs > 0
    dropped = jnp.maximum(n_pairs + n_single - P, 0).astype(jnp.int32)
    return People(jnp.where(present[:, None], person, 0.0), present, legs, num_legs, dropped)


def _motion_compatible(xy, mask, prev_legs, params):
    prev_xy, prev_mask = jnp.asarray(prev_legs[0], xy.dtype), jnp.asarray(prev_legs[1], bool)
    dist = jnp.sqrt(_pairwise_sq(xy, prev_xy) + 1e-30)
    dist = jnp.where(prev_mask[None], dist, jnp.inf)
    # Nearest previous leg (first on ties, as argmin), selected by a one-hot row.
    best = jnp.min(dist, -1)
    prev_idx = jnp.arange(prev_xy.shape[0])
    nearest = jnp.min(jnp.where(dist == best[:, None], prev_idx[None], prev_xy.shape[0]), -1)
    onehot = prev_idx[None] == nearest[:, None]
    known = mask & (best <= params.motion_gate)
    disp = [xy[:, a] - jnp.sum(jnp.where(onehot, prev_xy[None, :, a], 0.0), 1) for a in (0, 1)]
    speed = jnp.sqrt(disp[0] * disp[0] + disp[1] * disp[1] + 1e-30)
    moving = known & (speed > params.min_motion)
    ux, uy = disp[0] / speed, disp[1] / speed
    cos = ux[:, None] * ux[None] + uy[:, None] * uy[None]
    return ~(moving[:, None] & moving[None]) | (cos >= jnp.cos(params.max_motion_angle))


def _pairwise_sq(a, b):
    """[N, M] squared distances between the points of ``a`` [N, 2] and ``b`` [M, 2], one axis at
    a time: XLA:CPU runs a sum over a trailing axis of 2 as a scalar loop (the [S, S, 2] form
    took 5 % of a service-scene frame)."""
    dx = a[:, 0][:, None] - b[:, 0][None]
    dy = a[:, 1][:, None] - b[:, 1][None]
    return dx * dx + dy * dy


def _check_scan(ranges, angles):
    _checks.check_ndim("ranges", ranges, 1, "[B] ranges")
    B = _checks.shape_of(ranges)[0]
    _checks.check_shape("angles", angles, (B,), "beam angles, one per range")
    _checks.check_finite("angles", angles)
    if _checks.is_concrete(ranges) and np.any(np.isnan(np.asarray(ranges))):
        raise ValueError("ranges contains NaN (use max_range or inf for beams with no return)")
