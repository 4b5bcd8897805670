r"""CLEAR MOT metrics (MOTA, MOTP, identity switches, fragmentations, mostly tracked / lost) of
one episode, jittable: a `lax.scan` over frames with fixed ground-truth and hypothesis
capacities and masks.

Bernardin & Stiefelhagen, "Evaluating multiple object tracking performance: the CLEAR MOT
metrics", EURASIP J. Image and Video Processing, 2008. At every frame:

1. correspondences carried over from the past are kept if the pair is still within the
   distance threshold;
2. the remaining objects and hypotheses are matched by the Hungarian algorithm, which finds, among
   the pairs within the threshold, a matching of maximum cardinality and, among those, of minimum
   total distance;
3. a matched object whose hypothesis differs from the one it was last matched to counts a
   switch; unmatched objects are misses, unmatched hypotheses false positives.

.. math::
    \mathrm{MOTA} = 1 - \frac{\sum_t (\mathrm{miss}_t + \mathrm{fp}_t + \mathrm{switch}_t)}
    {\sum_t g_t},\qquad
    \mathrm{MOTP} = \frac{\sum_{t, i} d_{t,i}}{\sum_t c_t}

with :math:`g_t` the objects present at frame t, :math:`c_t` the matched pairs (switches
included) and :math:`d_{t,i}` their Euclidean distances in metres.

**Conventions.** Tools disagree on step 1 (py-motmetrics issues #126 and #132):

- ``"motmetrics"`` (default) reproduces py-motmetrics 1.4: an object keeps priority for the
  hypothesis it was *last matched to*, however many frames ago (also across frames where it was
  missed or absent). Fragmentations count the interruptions of tracking within an object's
  tracked span, frames where the object is absent not counting; mostly tracked means a tracked
  ratio >= 0.8.
- ``"trackeval"`` reproduces TrackEval's CLEAR (the MOTChallenge evaluation): priority is given
  only to the correspondences of the *previous evaluated frame* (the last frame with at least one
  object and one hypothesis). Fragmentations count every return to tracked after a frame not
  tracked, absent frames included; mostly tracked means a tracked ratio > 0.8.

Both count a switch against the last matched hypothesis, however long ago, and both match the
rest by maximum cardinality then minimum total distance (TrackEval maximises a similarity score
instead; with a similarity ``big - distance`` the two objectives coincide). The default is
``"motmetrics"`` because it is the rule checked to exact agreement with an established library
in the tests (py-motmetrics, on 200 random sequences) and it never lets a hypothesis that was
tracking an object lose its priority just because the object was briefly unmatched; use
``"trackeval"`` to compare with numbers reported by MOTChallenge / TrackEval. The two differ
only when an object is unmatched or absent between two of its matches, or is tracked in exactly
80% of its frames.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax import lax

from jaxtrack import _checks
from jaxtrack.metrics import _pairs

Array = jax.Array

__all__ = ["ClearMOTResult", "FrameEvents", "clear_mot", "combine", "CONVENTIONS"]

CONVENTIONS = ("motmetrics", "trackeval")


class FrameEvents(NamedTuple):
    """Per-frame correspondences of `clear_mot`.

    Attributes:
      assignment: [T, G] ints, the hypothesis slot matched to each ground-truth slot (-1 if none).
      is_switch: [T, G] bools, True where the match is an identity switch.
      distance: [T, G] distance (m) of each match (0 where unmatched).
    """

    assignment: Array
    is_switch: Array
    distance: Array


class ClearMOTResult(NamedTuple):
    """CLEAR MOT counts and scores (field names and meanings as in py-motmetrics).

    Attributes:
      mota: 1 - (misses + false positives + switches) / objects; NaN if no object.
      motp: mean distance (m) of the matched pairs (switches included); NaN if none.
      precision: detections / (detections + false positives); NaN if both are 0.
      recall: detections / objects; NaN if no object.
      num_objects: object presences summed over frames.
      num_predictions: hypothesis presences summed over frames.
      num_matches: matched pairs that are not switches.
      num_switches: identity switches.
      num_detections: all matched pairs, ``num_matches + num_switches``.
      num_misses: objects present but unmatched.
      num_false_positives: hypotheses present but unmatched.
      num_fragmentations: interruptions of tracking (definition per convention, see module doc).
      mostly_tracked: objects tracked in at least (motmetrics) or more than (trackeval) 80% of
        the frames where they are present.
      partially_tracked: the others tracked in at least 20% of their frames.
      mostly_lost: objects tracked in less than 20% of their frames.
      num_unique_objects: distinct object ids seen.
      total_distance: sum of the matched distances (m), so results can be combined.
      num_invalid: present ground-truth slots whose id is outside [0, num_ids) (only possible
        under tracing; they are left out of every count).
      frames: per-frame `FrameEvents`; None after `combine`.
    """

    mota: Array
    motp: Array
    precision: Array
    recall: Array
    num_objects: Array
    num_predictions: Array
    num_matches: Array
    num_switches: Array
    num_detections: Array
    num_misses: Array
    num_false_positives: Array
    num_fragmentations: Array
    mostly_tracked: Array
    partially_tracked: Array
    mostly_lost: Array
    num_unique_objects: Array
    total_distance: Array
    num_invalid: Array
    frames: FrameEvents | None


_COUNTS = ("num_objects", "num_predictions", "num_matches", "num_switches", "num_detections",
           "num_misses", "num_false_positives", "num_fragmentations", "mostly_tracked",
           "partially_tracked", "mostly_lost", "num_unique_objects", "total_distance",
           "num_invalid")


def clear_mot(gt_ids: Array, gt_pos: Array, gt_mask: Array | None, hyp_ids: Array,
              hyp_pos: Array, hyp_mask: Array | None, threshold: float | Array, *,
              convention: str = "motmetrics", num_ids: int | None = None,
              distance: str = "euclidean") -> ClearMOTResult:
    r"""CLEAR MOT metrics of one episode (Bernardin & Stiefelhagen 2008; see the module doc).

    A slot is present where its mask is True (or the mask is None) and its id is >= 0; -1 marks an
    empty slot. Identities are the ids, not the slots: an object may move between slots from one
    frame to the next. A pair can be matched when its Euclidean distance is <= ``threshold``;
    non-finite positions never match (the object is missed, the hypothesis a false positive).

    Args:
      gt_ids: [T, G] integer object ids in [0, num_ids), -1 for empty slots; unique per frame.
      gt_pos: [T, G, d] object positions (m), or boxes [T, G, 4] (left, top, width, height) with
        ``distance="iou"``.
      gt_mask: optional [T, G] bools.
      hyp_ids: [T, H] integer hypothesis (track) ids >= 0, -1 for empty slots; unique per frame.
      hyp_pos: [T, H, d] hypothesis positions (m) or boxes.
      hyp_mask: optional [T, H] bools.
      threshold: largest distance of a correspondence: metres, or ``1 - IoU`` for boxes
        (MOTChallenge: 0.5); may be traced.
      convention: ``"motmetrics"`` (default) or ``"trackeval"``: how correspondences are carried
        over and fragmentations counted (module doc). Static.
      num_ids: static bound on the object ids (memory per object is indexed by id); default
        ``T * G``, which holds any numbering 0, 1, 2, ... of the objects.
      distance: ``"euclidean"`` (default) or ``"iou"``: image boxes matched by ``1 - IoU``,
        which is then also what MOTP averages (py-motmetrics' MOTChallenge convention). Static.

    Returns:
      `ClearMOTResult` (scalars, plus per-frame `FrameEvents` [T, G]). Integer counts are int32.

    Example:
      >>> from jaxtrack import metrics
      >>> res = metrics.clear_mot(gt_ids, gt_pos, None, hyp_ids, hyp_pos, None, threshold=0.5)
      >>> res.mota, res.motp, res.num_switches
    """
    if not isinstance(convention, str) or convention not in CONVENTIONS:
        raise ValueError(f"unknown convention {convention!r}; expected one of {list(CONVENTIONS)}")
    T, G, H = _pairs.check_inputs(gt_ids, gt_pos, gt_mask, hyp_ids, hyp_pos, hyp_mask)
    _pairs.check_distance(distance, np.shape(gt_pos)[2])
    if num_ids is None:
        num_ids = max(T * G, 1)
    if not isinstance(num_ids, (int, np.integer)) or num_ids <= 0:
        raise ValueError(f"num_ids must be a positive int; got {num_ids!r}")
    _check_ids(gt_ids, gt_mask, hyp_ids, hyp_mask, int(num_ids))
    if _checks.is_concrete(threshold):
        if np.ndim(threshold) != 0 or not float(threshold) > 0:
            raise ValueError(f"threshold must be a positive scalar (m); got {threshold!r}")
    elif jnp.ndim(threshold) != 0:
        raise ValueError(f"threshold must be a scalar; got shape {list(jnp.shape(threshold))}")
    threshold = jnp.asarray(threshold, jnp.result_type(gt_pos, hyp_pos, float))
    return _clear_mot(gt_ids, gt_pos, gt_mask, hyp_ids, hyp_pos, hyp_mask, threshold,
                      convention, int(num_ids), distance)


def combine(results: ClearMOTResult) -> ClearMOTResult:
    r"""Pool the CLEAR MOT results of a batch of episodes (sums of counts, then the ratios).

    MOTA and MOTP over several episodes are ratios of summed counts, not means of per-episode
    ratios (py-motmetrics ``compute_overall``, TrackEval ``combine_sequences``).

    Args:
      results: a `ClearMOTResult` whose leaves have leading batch axes (e.g. from `jax.vmap`).

    Returns:
      A `ClearMOTResult` of scalars with ``frames=None``.

    Example:
      >>> per_episode = jax.vmap(metrics.clear_mot, in_axes=(0, 0, 0, 0, 0, 0, None))
      >>> batch = per_episode(gt_ids, gt_pos, gt_mask, hyp_ids, hyp_pos, hyp_mask, 0.5)
      >>> metrics.combine_clear_mot(batch).mota
    """
    if not isinstance(results, ClearMOTResult):
        raise TypeError(f"results must be a ClearMOTResult; got {type(results).__name__}")
    return _combine({name: getattr(results, name) for name in _COUNTS})


# ---------------------------------------------------------------------------------------------
# Internals


class _Memory(NamedTuple):
    """What the scan carries: per-object state indexed by id, and running totals."""

    last_hyp: Array          # [K] hypothesis id last matched to the object, -1 if never
    last_match_frame: Array  # [K] frame of that match (-2 if never)
    num_present: Array       # [K] frames where the object is present
    num_tracked: Array       # [K] frames where it is matched
    tracked_before: Array    # [K] matched at least once (motmetrics fragmentations)
    in_gap: Array            # [K] missed since its last match (motmetrics fragmentations)
    num_runs: Array          # [K] returns to tracked (trackeval fragmentations)
    last_eval_frame: Array   # frame of the last frame with objects and hypotheses (-1: none)
    totals: dict


@functools.partial(jax.jit, static_argnames=("convention", "num_ids", "distance"))
def _clear_mot(gt_ids, gt_pos, gt_mask, hyp_ids, hyp_pos, hyp_mask, threshold, convention,
               num_ids, distance="euclidean"):
    T, G = gt_ids.shape
    dtype = jnp.result_type(gt_pos, hyp_pos, float)
    gt_ids = jnp.asarray(gt_ids)
    hyp_ids = jnp.asarray(hyp_ids)
    gt_present = gt_ids >= 0
    if gt_mask is not None:
        gt_present = gt_present & jnp.asarray(gt_mask, bool)
    invalid = gt_present & (gt_ids >= num_ids)
    gt_present = gt_present & ~invalid
    hyp_present = hyp_ids >= 0
    if hyp_mask is not None:
        hyp_present = hyp_present & jnp.asarray(hyp_mask, bool)
    threshold = jnp.asarray(threshold, dtype)

    K = num_ids
    int_ = jnp.int32
    zeros_k = jnp.zeros((K,), int_)
    totals = {name: jnp.zeros((), int_) for name in
              ("num_objects", "num_predictions", "num_matches", "num_switches", "num_misses",
               "num_false_positives", "num_fragmentations")}
    totals["total_distance"] = jnp.zeros((), dtype)
    init = _Memory(jnp.full((K,), -1, hyp_ids.dtype), jnp.full((K,), -2, int_), zeros_k, zeros_k,
                   jnp.zeros((K,), bool), jnp.zeros((K,), bool), zeros_k,
                   jnp.asarray(-1, int_), totals)

    def step(mem, inp):
        t, oid, opos, opresent, hid, hpos, hpresent = inp
        memory, events = _frame(mem, t, oid.astype(int_), opos.astype(dtype), opresent,
                                hid, hpos.astype(dtype), hpresent, threshold, convention,
                                distance)
        return memory, events

    frames_in = (jnp.arange(T, dtype=int_), gt_ids, gt_pos, gt_present, hyp_ids, hyp_pos,
                 hyp_present)
    mem, frames = lax.scan(step, init, frames_in)

    seen = mem.num_present > 0
    # Integer forms of tracked / present >= 0.8 and < 0.2, free of rounding.
    tracked5, present = 5 * mem.num_tracked, mem.num_present
    mostly = (tracked5 >= 4 * present) if convention == "motmetrics" else (tracked5 > 4 * present)
    lost = tracked5 < present
    if convention == "motmetrics":
        fragmentations = mem.totals["num_fragmentations"]
    else:
        fragmentations = jnp.sum(jnp.maximum(mem.num_runs - 1, 0))
    sums = dict(mem.totals)
    sums.update(
        num_detections=sums["num_matches"] + sums["num_switches"],
        num_fragmentations=fragmentations.astype(int_),
        mostly_tracked=jnp.sum(seen & mostly).astype(int_),
        mostly_lost=jnp.sum(seen & lost).astype(int_),
        partially_tracked=jnp.sum(seen & ~mostly & ~lost).astype(int_),
        num_unique_objects=jnp.sum(seen).astype(int_),
        num_invalid=jnp.sum(invalid).astype(int_),
    )
    return _finish(sums, frames)


def _frame(mem, t, oid, opos, opresent, hid, hpos, hpresent, threshold, convention, distance):
    G, H = oid.shape[0], hid.shape[0]
    K = mem.last_hyp.shape[0]
    safe_oid = jnp.where(opresent, oid, 0)
    dist = _pairs.distance_matrix(opos, hpos, distance)
    allowed = opresent[:, None] & hpresent[None, :] & (dist <= threshold)

    # 1. Carried-over correspondences: an object claims its previous hypothesis; when several
    #    objects claim one hypothesis (possible after a transfer) the first slot wins, as in
    #    py-motmetrics' loop over objects.
    previous = jnp.where(opresent, mem.last_hyp[safe_oid], -1)
    if convention == "trackeval":
        fresh = mem.last_match_frame[safe_oid] == mem.last_eval_frame
        previous = jnp.where(fresh, previous, -1)
    claim = allowed & (previous[:, None] >= 0) & (previous[:, None] == hid[None, :])
    rows = jnp.arange(G)
    kept = claim
    if G > 0:
        kept = claim & (rows[:, None] == jnp.argmax(claim, axis=0)[None, :])

    # 2. Hungarian on the rest. Forbidden pairs cost more than any gain in cardinality can buy
    #    back (py-motmetrics' add_expensive_edges), so the optimum is the minimum-distance
    #    matching among the maximum-cardinality ones on the allowed pairs.
    free = allowed & ~jnp.any(kept, 1)[:, None] & ~jnp.any(kept, 0)[None, :]
    matched = kept
    if G > 0 and H > 0:
        scale = jnp.max(jnp.where(free, dist, 0.0)) + 1.0
        forbidden = 2.0 * min(G, H) * scale + 1.0
        # The assignment is piecewise constant in the positions: no gradient flows through it.
        cost = lax.stop_gradient(jnp.where(free, dist, forbidden))
        r, c = optax.assignment.hungarian_algorithm(cost)
        chosen = jnp.zeros((G, H), bool).at[r, c].set(free[r, c])
        matched = matched | chosen

    # 3. Events.
    is_matched = jnp.any(matched, 1)
    col = jnp.where(is_matched, jnp.argmax(matched, 1), -1) if H > 0 else jnp.full((G,), -1)
    matched_hid = (jnp.where(is_matched, hid[jnp.maximum(col, 0)], -1) if H > 0
                   else jnp.full((G,), -1, hid.dtype))
    match_dist = jnp.where(matched, dist, 0.0).sum(1)
    last = jnp.where(opresent, mem.last_hyp[safe_oid], -1)
    is_switch = is_matched & (last >= 0) & (last != matched_hid)
    hyp_matched = jnp.any(matched, 0)

    # Fragmentations, both conventions.
    tracked_before = mem.tracked_before[safe_oid]
    in_gap = mem.in_gap[safe_oid]
    new_fragment = is_matched & in_gap
    in_gap_next = jnp.where(is_matched, False, in_gap | tracked_before)
    returned = is_matched & (mem.last_match_frame[safe_oid] != mem.last_eval_frame)

    at = jnp.where(opresent, oid, K)          # out of bounds: dropped
    at_matched = jnp.where(is_matched, oid, K)
    int_ = mem.num_present.dtype
    totals = dict(mem.totals)
    totals["num_objects"] += jnp.sum(opresent).astype(int_)
    totals["num_predictions"] += jnp.sum(hpresent).astype(int_)
    totals["num_matches"] += jnp.sum(is_matched & ~is_switch).astype(int_)
    totals["num_switches"] += jnp.sum(is_switch).astype(int_)
    totals["num_misses"] += jnp.sum(opresent & ~is_matched).astype(int_)
    totals["num_false_positives"] += jnp.sum(hpresent & ~hyp_matched).astype(int_)
    totals["num_fragmentations"] += jnp.sum(new_fragment).astype(int_)
    totals["total_distance"] += jnp.sum(match_dist)
    evaluated = jnp.any(opresent) & jnp.any(hpresent)
    memory = _Memory(
        last_hyp=mem.last_hyp.at[at_matched].set(matched_hid, mode="drop"),
        last_match_frame=mem.last_match_frame.at[at_matched].set(t, mode="drop"),
        num_present=mem.num_present.at[at].add(1, mode="drop"),
        num_tracked=mem.num_tracked.at[at_matched].add(1, mode="drop"),
        tracked_before=mem.tracked_before.at[at].set(tracked_before | is_matched, mode="drop"),
        in_gap=mem.in_gap.at[at].set(in_gap_next, mode="drop"),
        num_runs=mem.num_runs.at[at].add(returned.astype(int_), mode="drop"),
        last_eval_frame=jnp.where(evaluated, t, mem.last_eval_frame),
        totals=totals,
    )
    return memory, FrameEvents(col.astype(int_), is_switch, match_dist)


@jax.jit
def _combine(counts):
    return _finish({name: jnp.sum(value) for name, value in counts.items()}, frames=None)


def _ratio(num, den):
    den = jnp.asarray(den)
    return jnp.where(den > 0, num / jnp.where(den > 0, den, 1), jnp.nan)


def _finish(sums, frames):
    dtype = jnp.result_type(sums["total_distance"])
    objects = sums["num_objects"].astype(dtype)
    detections = sums["num_detections"].astype(dtype)
    errors = (sums["num_misses"] + sums["num_false_positives"]
              + sums["num_switches"]).astype(dtype)
    positives = detections + sums["num_false_positives"].astype(dtype)
    return ClearMOTResult(
        mota=1.0 - _ratio(errors, objects),
        motp=_ratio(sums["total_distance"], detections),
        precision=_ratio(detections, positives),
        recall=_ratio(detections, objects),
        frames=frames,
        **{name: sums[name] for name in _COUNTS},
    )


def _check_ids(gt_ids, gt_mask, hyp_ids, hyp_mask, num_ids):
    """Range and per-frame uniqueness of the present ids, when they are concrete."""
    for name, ids, mask in (("gt_ids", gt_ids, gt_mask), ("hyp_ids", hyp_ids, hyp_mask)):
        if not (_checks.is_concrete(ids) and (mask is None or _checks.is_concrete(mask))):
            continue
        ids = np.asarray(ids)
        present = ids >= 0 if mask is None else (ids >= 0) & np.asarray(mask, bool)
        if name == "gt_ids" and np.any(ids[present] >= num_ids):
            raise ValueError(f"gt_ids must lie in [0, num_ids={num_ids}); got "
                             f"{int(ids[present].max())} (pass a larger num_ids)")
        # Absent slots get distinct negative values so that only present ids can collide.
        values = np.where(present, ids, -1 - np.arange(ids.shape[1]))
        ordered = np.sort(values, axis=1)
        repeated = np.any(ordered[:, 1:] == ordered[:, :-1], axis=1)
        if np.any(repeated):
            t = int(np.argmax(repeated))
            raise ValueError(f"{name} must be unique within a frame; frame {t} has "
                             f"{sorted(ids[t][present[t]].tolist())}")
