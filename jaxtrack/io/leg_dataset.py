r"""Labelled leg segments from recorded scans: training sets for
`jaxtrack.perception.leg_classifier` and detection precision / recall against labels.

Two kinds of recordings, as the ROS leg tracker's training data comes:

* *positive* bags: a scan topic and a ``geometry_msgs/PoseArray`` topic of leg-cluster positions
  (labels). Every scan segment nearest to a label, and within ``match_radius`` of it, is a leg;
  every other segment is not (legs appear only where they are labelled);
* *negative* bags: scans with no person in them, every segment a non-leg.

Pairing labels with scans: the labels carry no usable stamp (0 in the shared recordings), so
each label message is paired with the first scan that follows it in bag (receive-time) order.
On the six shared positive bags this puts the labels on the scan returns (median 1 cm from the
nearest return) where the scan before them misses by 3-9 cm.

Detection scoring (`match_counts`): in each scan, detections are matched one-to-one to the
labels by a minimum-distance assignment gated at ``radius`` (0.15 m); matched detections are
true positives, the others false positives, unmatched labels misses.

Example:
  >>> data = read_labelled("positive_1_extracted.bag")
  >>> segs = segment_dataset(data.scans, data.labels, data.label_mask, jump=0.13)
  >>> model, _ = leg_classifier.fit(segs.X, segs.y)
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack.association import assignment
from jaxtrack.io import bags
from jaxtrack.perception import leg_features, legs

__all__ = ["LabelledScans", "SegmentSet", "read_labelled", "read_unlabelled",
           "segment_dataset", "match_counts", "DEFAULT_SEGMENTS"]

DEFAULT_SEGMENTS = 128   # segment capacity per scan for training and evaluation


class LabelledScans(NamedTuple):
    """Scans and the leg positions labelled in them.

    Attributes:
      scans: `bags.LaserScans` (T scans).
      labels: [T, K, 2] labelled leg positions (laser frame), 0 where masked.
      label_mask: [T, K] bools (all False for a negative recording).
      name: the recording and topic, for reports.
    """

    scans: bags.LaserScans
    labels: np.ndarray
    label_mask: np.ndarray
    name: str


class SegmentSet(NamedTuple):
    """The segments of many scans, flattened.

    Attributes:
      X: [M, NUM_FEATURES] features; y: [M] int labels (1 leg, 0 not, -1 unlabelled).
      scan: [M] int scan index; mean: [M, 2] segment mean point (laser frame).
      dropped: number of segments beyond the capacity (not in the set).
    """

    X: np.ndarray
    y: np.ndarray
    scan: np.ndarray
    mean: np.ndarray
    dropped: int


def read_labelled(path, scan_topic: str = "/training_scan",
                  labels_topic: str = "/leg_cluster_positions", *, max_labels: int = 8,
                  max_beams: int | None = None) -> LabelledScans:
    """Scans with the leg positions labelled in them (labels paired with the next scan in bag
    order; scans without a label message get no labels).

    Example:
      >>> data = read_labelled("training/positive_1_extracted.bag")
      >>> data.labels.shape                        # (197, 8, 2)
    """
    scans = bags.read_laser(path, scan_topic, time_source="bag", max_beams=max_beams)
    det = bags.read_detections(path, labels_topic, max_labels, time_source="bag")
    labels = np.zeros((len(scans.times), int(max_labels), 2))
    mask = np.zeros((len(scans.times), int(max_labels)), bool)
    idx = np.searchsorted(scans.times, det.times, side="right")
    ok = idx < len(scans.times)
    labels[idx[ok]] = det.xy[ok]
    mask[idx[ok]] = det.mask[ok]
    return LabelledScans(scans, labels, mask, f"{path}:{scan_topic}")


def read_unlabelled(path, scan_topic: str, *, max_beams: int | None = None) -> LabelledScans:
    """Scans without labels: a negative recording (every segment a non-leg)."""
    scans = bags.read_laser(path, scan_topic, max_beams=max_beams)
    T = len(scans.times)
    return LabelledScans(scans, np.zeros((T, 1, 2)), np.zeros((T, 1), bool),
                         f"{path}:{scan_topic}")


_CHUNK = 64   # scans per compiled call: one compilation per beam count and capacity


@functools.partial(jax.jit, static_argnames=("max_segments",))
def _chunk_segments(ranges, angles, max_range, jump, max_segments):
    def one(r):
        xy, valid = legs.scan_returns(r, angles, 0.0, max_range)
        segs = legs.segment_returns(xy, valid, jump, max_segments)
        X = leg_features.segment_features(xy, valid, segs)
        n = jnp.maximum(segs.num_points, 1).astype(xy.dtype)
        ids = jnp.where(segs.labels >= 0, segs.labels, max_segments)
        mean = jax.ops.segment_sum(jnp.where((segs.labels >= 0)[:, None], xy, 0.0), ids,
                                   max_segments + 1)[:max_segments] / n[:, None]
        return X, mean, segs.mask, segs.dropped

    return jax.vmap(one)(ranges)


def _scan_segments(ranges, angles, max_range, jump, max_segments):
    """Features, means, masks and drop counts of every scan [T, B], in fixed chunks."""
    T = ranges.shape[0]
    pad = (-T) % _CHUNK
    r = np.concatenate([ranges, np.full((pad, ranges.shape[1]), np.inf, ranges.dtype)])
    parts = [_chunk_segments(jnp.asarray(r[i:i + _CHUNK]), angles, max_range, jump,
                             max_segments) for i in range(0, len(r), _CHUNK)]
    return [np.concatenate([np.asarray(p[k]) for p in parts])[:T] for k in range(4)]


def segment_dataset(data: LabelledScans, *, jump: float = 0.13,
                    max_segments: int = DEFAULT_SEGMENTS, match_radius: float = 0.15,
                    labelled: bool = True) -> SegmentSet:
    """Segment every scan, compute the leg features and label the segments.

    Args:
      data: `LabelledScans` (`read_labelled` or `read_unlabelled`).
      jump: segmentation break distance (m); max_segments: capacity per scan.
      match_radius: a segment is a leg when it is the nearest segment (by mean point) to a
        label and within this distance of it.
      labelled: False to mark every segment -1 (unknown) instead of 0 / 1.

    Returns:
      `SegmentSet` of the segments of all scans.
    """
    if not float(match_radius) > 0:
        raise ValueError(f"match_radius must be > 0; got {match_radius}")
    s = data.scans
    if len(s.times) == 0:
        F = leg_features.NUM_FEATURES
        return SegmentSet(np.zeros((0, F)), np.zeros(0, np.int64), np.zeros(0, np.int64),
                          np.zeros((0, 2)), 0)
    X, mean, mask, dropped = _scan_segments(
        np.asarray(s.ranges, np.float32), jnp.asarray(s.angles, jnp.float32),
        jnp.float32(s.range_max), jnp.float32(jump), int(max_segments))
    y = np.zeros(mask.shape, np.int64)
    if labelled:
        d = np.linalg.norm(mean[:, :, None] - data.labels[:, None], axis=-1)   # [T, S, K]
        d = np.where(mask[:, :, None] & data.label_mask[:, None], d, np.inf)
        nearest = np.argmin(d, 1)                                            # [T, K]
        best = np.take_along_axis(d, nearest[:, None], 1)[:, 0]
        t, k = np.nonzero(best <= match_radius)
        y[t, nearest[t, k]] = 1
    else:
        y[:] = -1
    t_idx = np.broadcast_to(np.arange(mask.shape[0])[:, None], mask.shape)
    return SegmentSet(X[mask].astype(np.float64), y[mask], t_idx[mask], mean[mask],
                      int(dropped.sum()))


@functools.partial(jax.jit, static_argnames=())
def _counts(det_xy, det_mask, labels, label_mask, radius):
    def one(d, dm, lab, lm):
        cost = jnp.sqrt(jnp.sum((lab[:, None] - d[None]) ** 2, -1))
        cost = jnp.where(cost <= radius, cost, jnp.inf)
        col = assignment.linear_sum_assignment(cost, unassigned_cost=radius, row_mask=lm,
                                               col_mask=dm)
        tp = jnp.sum(col >= 0)
        return tp, jnp.sum(dm) - tp, jnp.sum(lm) - tp

    return jax.vmap(one)(det_xy, det_mask, labels, label_mask)


def match_counts(det_xy, det_mask, labels, label_mask, radius: float = 0.15):
    """True positives, false positives and misses of detections against labels, per scan.

    Args:
      det_xy: [T, S, 2] detected leg positions; det_mask: [T, S].
      labels: [T, K, 2] labelled positions; label_mask: [T, K].
      radius: the largest distance of a match (m).

    Returns:
      (tp [T], fp [T], fn [T]) int arrays.

    Example:
      >>> tp, fp, fn = match_counts(xy, mask, data.labels, data.label_mask)
      >>> precision, recall = tp.sum() / (tp + fp).sum(), tp.sum() / (tp + fn).sum()
    """
    if not float(radius) > 0:
        raise ValueError(f"radius must be > 0; got {radius}")
    det_xy = np.asarray(det_xy, np.float64)
    labels = np.asarray(labels, np.float64)
    if det_xy.shape[0] == 0:
        z = np.zeros(0, np.int64)
        return z, z, z
    if det_xy.shape[1] == 0 or labels.shape[1] == 0:
        dm = np.asarray(det_mask, bool)
        lm = np.asarray(label_mask, bool)
        return (np.zeros(len(dm), np.int64), dm.sum(1).astype(np.int64),
                lm.sum(1).astype(np.int64))
    det_xy, labels = jnp.asarray(det_xy), jnp.asarray(labels)   # float32 unless x64 is on
    out = _counts(det_xy, jnp.asarray(det_mask, bool), labels, jnp.asarray(label_mask, bool),
                  jnp.asarray(radius, det_xy.dtype))
    return tuple(np.asarray(v, np.int64) for v in out)


class TrainingReport(NamedTuple):
    """What `train` did: the recordings, segment counts and the decision threshold.

    Attributes:
      sources: the recordings and topics used (positive first).
      num_segments, num_legs: training segments and leg segments among them.
      num_scans: scans read; dropped: segments beyond the capacity (left out).
      decision: the probability threshold chosen (best F1 on held-out recordings, see
        `train`).
      held_out_precision, held_out_recall: segment precision / recall of the held-out
        predictions at that threshold.
    """

    sources: tuple
    num_segments: int
    num_legs: int
    num_scans: int
    dropped: int
    decision: float
    held_out_precision: float
    held_out_recall: float


def training_set(positive, negative, *, jump: float = 0.13,
                 max_segments: int = DEFAULT_SEGMENTS, match_radius: float = 0.15):
    """Segments of labelled (``positive``) and person-free (``negative``) `LabelledScans`.

    Returns:
      ``(X [M, F], y [M], recording [M] index into positive + negative, num_scans, dropped)``.
    """
    X, y, rec, scans, dropped = [], [], [], 0, 0
    sources = [(d, True) for d in positive] + [(d, False) for d in negative]
    for i, (data, is_positive) in enumerate(sources):
        seg = segment_dataset(data, jump=jump, max_segments=max_segments,
                              match_radius=match_radius)
        X.append(seg.X)
        y.append(seg.y if is_positive else np.zeros_like(seg.y))
        rec.append(np.full(len(seg.y), i))
        scans += len(data.scans.times)
        dropped += seg.dropped
    return np.concatenate(X), np.concatenate(y), np.concatenate(rec), scans, dropped


def train(positive, negative, *, jump: float = 0.13, n_estimators: int = 48,
          max_depth: int = 16, min_samples_leaf: int = 2, seed: int = 0, folds: int = 3,
          max_segments: int = DEFAULT_SEGMENTS, match_radius: float = 0.15):
    """Train a leg classifier on recordings (scikit-learn needed).

    The decision threshold is the one of best segment F1 on predictions for recordings the
    forest did not see: ``folds``-fold cross-validation with whole recordings held out
    (positive recording i and negative recording j in fold ``i % folds`` and ``j % folds``),
    then the forest is fitted on everything. Legs are a few percent of the segments, so 0.5
    would trade most of the recall for precision; and out-of-bag predictions are no guide,
    because a leg's segments in consecutive scans are near copies of each other (measured on
    the shared bags: out-of-bag picks 0.33 where held-out bags want about 0.1). With a single
    positive recording the out-of-bag predictions are used all the same.

    Args:
      positive: `LabelledScans` with leg labels (`read_labelled`).
      negative: `LabelledScans` of person-free scans (`read_unlabelled`).
      jump, max_segments, match_radius: as in `segment_dataset`.
      n_estimators, max_depth, min_samples_leaf, seed: the random forest's.
      folds: cross-validation folds for the threshold (at most the positive recordings).

    Returns:
      ``(LegClassifier, TrainingReport)``.

    Example:
      >>> model, report = train([read_labelled(p) for p in bags],
      ...                       [read_unlabelled(neg, "/rear_scan")])
    """
    from jaxtrack.perception import leg_classifier

    positive, negative = list(positive), list(negative)
    if not positive:
        raise ValueError("train needs at least one positive (labelled) recording")
    X, y, rec, scans, dropped = training_set(positive, negative, jump=jump,
                                             max_segments=max_segments,
                                             match_radius=match_radius)
    if not 0 < y.sum() < len(y):
        raise ValueError(f"the recordings give {int(y.sum())} leg segments out of {len(y)}; "
                         "training needs both legs and non-legs")
    kw = dict(n_estimators=n_estimators, max_depth=max_depth,
              min_samples_leaf=min_samples_leaf, seed=seed, jump=jump)
    k = min(int(folds), len(positive))
    if k >= 2:
        n_pos = len(positive)
        fold = np.where(rec < n_pos, rec % k, (rec - n_pos) % k)
        held = np.zeros(len(y))
        for f in range(k):
            test = fold == f
            _, forest = leg_classifier.fit(X[~test], y[~test], **kw)
            held[test] = forest.predict_proba(X[test])[:, 1]
        model, _ = leg_classifier.fit(X, y, **kw)
    else:
        model, forest = leg_classifier.fit(X, y, oob_score=True, **kw)
        held = np.nan_to_num(forest.oob_decision_function_[:, 1])
    # Segments the model never evaluates (too few points, too wide) are not legs.
    held = np.where(np.asarray(leg_classifier.candidates(model, jnp.asarray(X, jnp.float32),
                                                         jnp.ones(len(y), bool))), held, 0.0)
    decision, precision, recall = best_f1_threshold(held, y)
    model = model._replace(decision=jnp.asarray(decision, jnp.float32))
    report = TrainingReport(tuple(d.name for d in positive + negative), len(y), int(y.sum()),
                            scans, dropped, decision, precision, recall)
    return model, report


def best_f1_threshold(scores, y):
    """The threshold on ``scores`` of best F1 for labels ``y`` (1 = leg), and the precision and
    recall there: ``(threshold, precision, recall)``."""
    scores, y = np.asarray(scores, np.float64), np.asarray(y)
    if scores.shape != y.shape or scores.ndim != 1:
        raise ValueError(f"scores and y must be [M] each; got {scores.shape}, {y.shape}")
    if scores.size == 0:     # nothing to detect: no threshold selects anything
        return float("inf"), 0.0, 0.0
    order = np.argsort(-scores, kind="stable")
    s, t = scores[order], (y[order] == 1)
    tp = np.cumsum(t)
    n = np.arange(1, len(s) + 1)
    last = np.r_[s[1:] != s[:-1], True]           # the end of each run of equal scores
    precision, recall = tp / n, tp / max(t.sum(), 1)
    f1 = np.where(tp > 0, 2 * precision * recall / np.maximum(precision + recall, 1e-300), 0.0)
    f1 = np.where(last, f1, -1.0)
    k = int(np.argmax(f1))
    return float(s[k]), float(precision[k]), float(recall[k])
