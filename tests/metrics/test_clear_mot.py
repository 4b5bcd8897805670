"""Tests for `jaxtrack.metrics.clear_mot` against py-motmetrics and a transcription of TrackEval.

References:
- py-motmetrics 1.4 (``MOTAccumulator`` fed Euclidean distances with NaN beyond the threshold)
  for the default ``"motmetrics"`` convention: every count equal, ratios to 1e-9, on 200 random
  sequences (``_sequences.py``) with births, deaths, occlusion gaps, shuffled slots, id changes
  and swaps, coasting tracks and false positives.
- ``trackeval_clear`` below, a line-by-line transcription of TrackEval's
  ``CLEAR.eval_sequence`` (trackeval/metrics/clear.py), for the ``"trackeval"`` convention. Its
  similarity is ``BIG - distance`` so that maximising similarity is our objective (maximum
  cardinality, then minimum distance); everything else is TrackEval's code.

One compiled function per convention runs all 200 sequences under `vmap`.
"""

import functools

import jax
import jax.numpy as jnp
import motmetrics as mm
import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from jaxtrack import metrics
from tests.metrics._sequences import G, H, THRESHOLD, T, frame_distances, random_sequence

NUM_SEQUENCES = 200
COUNTS = ["num_objects", "num_predictions", "num_matches", "num_switches", "num_misses",
          "num_false_positives", "num_fragmentations", "mostly_tracked", "partially_tracked",
          "mostly_lost", "num_unique_objects"]
RATIOS = ["mota", "motp", "precision", "recall"]


def _batched(convention):
    def episode(gt_ids, gt_pos, hyp_ids, hyp_pos, threshold):
        return metrics.clear_mot(gt_ids, gt_pos, None, hyp_ids, hyp_pos, None, threshold,
                                 convention=convention)

    return jax.jit(jax.vmap(episode, in_axes=(0, 0, 0, 0, None)))


_BATCHED = {c: _batched(c) for c in ("motmetrics", "trackeval")}
_JIT = jax.jit(metrics.clear_mot, static_argnames=("convention", "num_ids"))


def single(gt_ids, gt_pos, gt_mask, hyp_ids, hyp_pos, hyp_mask, threshold,
           convention="motmetrics"):
    """One episode of the random-sequence shape through one compiled function per convention
    (masks always given, threshold traced, num_ids fixed)."""
    gt_mask = gt_ids >= 0 if gt_mask is None else gt_mask
    hyp_mask = hyp_ids >= 0 if hyp_mask is None else hyp_mask
    return _JIT(gt_ids, gt_pos, gt_mask, hyp_ids, hyp_pos, hyp_mask, jnp.asarray(threshold),
                convention=convention, num_ids=1000)


@pytest.fixture(scope="module")
def sequences():
    seqs = [random_sequence(seed) for seed in range(NUM_SEQUENCES)]
    return seqs, {k: np.stack([s[k] for s in seqs]) for k in seqs[0]}


@pytest.fixture(scope="module")
def results(sequences):
    _, b = sequences
    args = (b["gt_ids"], b["gt_pos"], b["hyp_ids"], b["hyp_pos"], THRESHOLD)
    return {c: jax.device_get(f(*args)) for c, f in _BATCHED.items()}


def motmetrics_summary(seq, threshold=THRESHOLD):
    acc = mm.MOTAccumulator(auto_id=True)
    for t in range(seq["gt_ids"].shape[0]):
        acc.update(*frame_distances(seq, t, threshold))
    return acc


_MH = mm.metrics.create()


# ---------------------------------------------------------------------------------------------
# py-motmetrics


def test_clear_mot_equals_py_motmetrics_on_200_random_sequences(sequences, results):
    seqs, _ = sequences
    res = results["motmetrics"]
    totals = {name: 0 for name in COUNTS}
    worst = 0.0
    for i, seq in enumerate(seqs):
        ref = _MH.compute(motmetrics_summary(seq), metrics=COUNTS + RATIOS,
                          return_dataframe=False)
        for name in COUNTS:
            assert getattr(res, name)[i] == ref[name], (i, name, getattr(res, name)[i], ref[name])
            totals[name] += ref[name]
        for name in RATIOS:
            worst = max(worst, abs(getattr(res, name)[i] - ref[name]))
    assert worst <= 1e-9, worst
    # The sequences exercise every event (about 1000 switches, 1700 misses, 1600 false
    # positives and 1000 fragmentations over the 200 sequences).
    for name in ("num_switches", "num_misses", "num_false_positives", "num_fragmentations",
                 "partially_tracked", "mostly_lost"):
        assert totals[name] > 0, name


def test_combine_equals_py_motmetrics_overall(sequences, results):
    seqs = sequences[0][:6]
    batch = jax.tree.map(lambda a: a[:6], results["motmetrics"])
    overall = metrics.combine_clear_mot(batch)
    assert overall.frames is None
    ref = _MH.compute_many([motmetrics_summary(s) for s in seqs], metrics=COUNTS + RATIOS,
                           generate_overall=True).loc["OVERALL"]
    for name in COUNTS:
        assert int(getattr(overall, name)) == ref[name], name
    for name in RATIOS:
        np.testing.assert_allclose(getattr(overall, name), ref[name], rtol=0, atol=1e-9)


# ---------------------------------------------------------------------------------------------
# TrackEval

BIG = 10.0  # similarity = BIG - distance; BIG exceeds min(G, H) * THRESHOLD


def trackeval_clear(seq, threshold=THRESHOLD):
    """TrackEval's CLEAR.eval_sequence, transcribed; similarity = BIG - Euclidean distance."""
    ids = np.unique(seq["gt_ids"][seq["gt_ids"] >= 0])
    index = {int(o): i for i, o in enumerate(ids)}  # TrackEval relabels gt ids 0..n-1
    num_gt_ids = len(ids)
    res = dict(CLR_TP=0, CLR_FN=0, CLR_FP=0, IDSW=0, MOTP_sum=0.0)
    gt_id_count = np.zeros(num_gt_ids)
    gt_matched_count = np.zeros(num_gt_ids)
    gt_frag_count = np.zeros(num_gt_ids)
    prev_tracker_id = np.nan * np.zeros(num_gt_ids)
    prev_timestep_tracker_id = np.nan * np.zeros(num_gt_ids)
    sim_threshold = BIG - threshold
    for t in range(seq["gt_ids"].shape[0]):
        oids, tracker_ids_t, dist = frame_distances(seq, t, threshold=np.inf)
        gt_ids_t = np.array([index[int(o)] for o in oids], int)
        if len(gt_ids_t) == 0:
            res["CLR_FP"] += len(tracker_ids_t)
            continue
        if len(tracker_ids_t) == 0:
            res["CLR_FN"] += len(gt_ids_t)
            gt_id_count[gt_ids_t] += 1
            continue
        similarity = BIG - dist
        score_mat = tracker_ids_t[np.newaxis, :] == prev_timestep_tracker_id[gt_ids_t[:, None]]
        score_mat = 1000 * score_mat + similarity
        score_mat[similarity < sim_threshold - np.finfo("float").eps] = 0
        match_rows, match_cols = linear_sum_assignment(-score_mat)
        actually_matched = score_mat[match_rows, match_cols] > 0 + np.finfo("float").eps
        match_rows, match_cols = match_rows[actually_matched], match_cols[actually_matched]
        matched_gt_ids = gt_ids_t[match_rows]
        matched_tracker_ids = tracker_ids_t[match_cols]
        prev_matched_tracker_ids = prev_tracker_id[matched_gt_ids]
        is_idsw = (~np.isnan(prev_matched_tracker_ids)
                   & (matched_tracker_ids != prev_matched_tracker_ids))
        res["IDSW"] += np.sum(is_idsw)
        gt_id_count[gt_ids_t] += 1
        gt_matched_count[matched_gt_ids] += 1
        not_previously_tracked = np.isnan(prev_timestep_tracker_id)
        prev_tracker_id[matched_gt_ids] = matched_tracker_ids
        prev_timestep_tracker_id[:] = np.nan
        prev_timestep_tracker_id[matched_gt_ids] = matched_tracker_ids
        currently_tracked = ~np.isnan(prev_timestep_tracker_id)
        gt_frag_count += not_previously_tracked & currently_tracked
        num_matches = len(matched_gt_ids)
        res["CLR_TP"] += num_matches
        res["CLR_FN"] += len(gt_ids_t) - num_matches
        res["CLR_FP"] += len(tracker_ids_t) - num_matches
        res["MOTP_sum"] += np.sum(similarity[match_rows, match_cols])
    tracked_ratio = gt_matched_count[gt_id_count > 0] / gt_id_count[gt_id_count > 0]
    res["MT"] = np.sum(tracked_ratio > 0.8)
    res["PT"] = np.sum(tracked_ratio >= 0.2) - res["MT"]
    res["ML"] = num_gt_ids - res["MT"] - res["PT"]
    res["Frag"] = np.sum(gt_frag_count[gt_frag_count > 0] - 1)
    res["MOTA"] = (res["CLR_TP"] - res["CLR_FP"] - res["IDSW"]) / max(1.0, res["CLR_TP"]
                                                                        + res["CLR_FN"])
    res["MOTP"] = (BIG * res["CLR_TP"] - res["MOTP_sum"]) / max(1.0, res["CLR_TP"])
    return res


TRACKEVAL_FIELDS = dict(CLR_TP="num_detections", CLR_FN="num_misses",
                        CLR_FP="num_false_positives", IDSW="num_switches", MT="mostly_tracked",
                        PT="partially_tracked", ML="mostly_lost", Frag="num_fragmentations",
                        MOTA="mota", MOTP="motp")


def test_trackeval_convention_equals_trackeval_on_200_random_sequences(sequences, results):
    seqs, _ = sequences
    res, other = results["trackeval"], results["motmetrics"]
    differ = 0
    for i, seq in enumerate(seqs):
        ref = trackeval_clear(seq)
        for key, name in TRACKEVAL_FIELDS.items():
            got = getattr(res, name)[i]
            if key in ("MOTA", "MOTP"):
                assert abs(got - ref[key]) <= 1e-9, (i, name, got, ref[key])
            else:
                assert got == ref[key], (i, name, got, ref[key])
        differ += any(getattr(res, n)[i] != getattr(other, n)[i]
                      for n in ("num_switches", "num_fragmentations", "mostly_tracked"))
    # The conventions really differ on these sequences (160 of 200 when this was written).
    assert differ > NUM_SEQUENCES // 4, differ


# ---------------------------------------------------------------------------------------------
# Hand-made cases (padded to the shape of the random sequences)


def padded_case(gt, hyp):
    """gt / hyp: per frame, lists of (id, x) on a line; returns clear_mot positional inputs."""
    gt_ids, gt_pos = np.full((T, G), -1), np.zeros((T, G, 2))
    hyp_ids, hyp_pos = np.full((T, H), -1), np.zeros((T, H, 2))
    for t, frame in enumerate(gt):
        for s, (i, x) in enumerate(frame):
            gt_ids[t, s], gt_pos[t, s, 0] = i, x
    for t, frame in enumerate(hyp):
        for s, (i, x) in enumerate(frame):
            hyp_ids[t, s], hyp_pos[t, s, 0] = i, x
    return gt_ids, gt_pos, gt_ids >= 0, hyp_ids, hyp_pos, hyp_ids >= 0


def test_maximum_cardinality_is_preferred_to_the_nearest_pair():
    # A-x is the nearest pair, but matching A-y and B-x matches both objects.
    case = padded_case([[(0, 0.0), (1, 0.7)]], [[(10, 0.2), (11, -0.5)]])
    for convention in ("motmetrics", "trackeval"):
        res = single(*case, 0.6, convention=convention)
        assert int(res.num_matches) == 2 and int(res.num_misses) == 0
        np.testing.assert_allclose(res.motp, 0.5, rtol=1e-12)
        np.testing.assert_array_equal(res.frames.assignment[0, :2], [1, 0])
    ref = _MH.compute(motmetrics_summary(dict(zip(("gt_ids", "gt_pos", "_", "hyp_ids",
                                                     "hyp_pos"), case)), 0.6),
                      metrics=["num_matches", "motp"], return_dataframe=False)
    assert ref["num_matches"] == 2 and abs(ref["motp"] - 0.5) < 1e-12


def test_conventions_differ_when_an_object_is_missed_between_two_matches():
    # Frame 0: object 0 matched to hypothesis 10. Frame 1: nothing within reach (a miss).
    # Frame 2: hypotheses 10 and 11 both in reach, 11 closer. py-motmetrics keeps 10 (the last
    # match, no switch); TrackEval only keeps frame 1's matches, so it takes 11 (a switch).
    case = padded_case([[(0, 0.0)], [(0, 0.0)], [(0, 0.0)], []],
                       [[(10, 0.1)], [(10, 5.0)], [(10, 0.4), (11, 0.1)], []])
    mot = single(*case, 0.5, convention="motmetrics")
    te = single(*case, 0.5, convention="trackeval")
    assert (int(mot.num_switches), int(te.num_switches)) == (0, 1)
    assert (int(mot.num_fragmentations), int(te.num_fragmentations)) == (1, 1)
    np.testing.assert_array_equal(mot.frames.assignment[:4, 0], [0, -1, 0, -1])
    np.testing.assert_array_equal(te.frames.is_switch[:4, 0], [False, False, True, False])
    seq = dict(zip(("gt_ids", "gt_pos", "_", "hyp_ids", "hyp_pos"), case))
    ref = _MH.compute(motmetrics_summary(seq, 0.5), metrics=["num_switches"],
                      return_dataframe=False)
    assert ref["num_switches"] == 0
    assert trackeval_clear(seq, 0.5)["IDSW"] == 1


def test_masks_equal_empty_slots_and_hide_nan_positions():
    case = padded_case([[(0, 0.0), (1, 3.0)], [(0, 0.1), (1, 3.1)], [(0, 0.2)], []],
                       [[(5, 0.0), (6, 3.0)], [(6, 0.1), (5, 3.0), (7, 8.0)], [(6, 0.2)], []])
    gt_ids, gt_pos, _, hyp_ids, hyp_pos, _ = case
    gt_mask, hyp_mask = gt_ids >= 0, hyp_ids >= 0
    gt_mask[1, 1] = False
    hyp_mask[1, 2] = False
    poisoned_gt, poisoned_hyp = gt_pos.copy(), hyp_pos.copy()
    poisoned_gt[~gt_mask] = np.nan
    poisoned_hyp[~hyp_mask] = np.nan
    cleared_gt, cleared_hyp = np.where(gt_mask, gt_ids, -1), np.where(hyp_mask, hyp_ids, -1)
    a = single(gt_ids, poisoned_gt, gt_mask, hyp_ids, poisoned_hyp, hyp_mask, 0.5)
    b = single(cleared_gt, gt_pos, None, cleared_hyp, hyp_pos, None, 0.5)
    for name in COUNTS + RATIOS:
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=0, err_msg=name)
    assert int(a.num_switches) == 1 and int(a.num_objects) == 4 and np.isfinite(a.motp)


# ---------------------------------------------------------------------------------------------
# Identity by id, batching, dtypes, tracing


def test_result_depends_on_ids_not_on_slots(sequences, results):
    """Hypotheses in any slot order, objects in any slots with their relative order kept.

    The relative order of the objects matters only when two of them claim the same previous
    hypothesis (possible after a transfer): like py-motmetrics, the first one wins.
    """
    seqs, _ = sequences
    rng = np.random.default_rng(3)
    b = {k: [] for k in seqs[0]}
    for seq in seqs:
        gt_perm, hyp_perm = [], []
        for t in range(T):
            present = np.flatnonzero(seq["gt_ids"][t] >= 0)
            slots = np.sort(rng.choice(G, size=len(present), replace=False))
            perm = np.full(G, -1)
            perm[slots] = present
            perm[perm < 0] = np.setdiff1d(np.arange(G), present)
            gt_perm.append(perm)
            hyp_perm.append(rng.permutation(H))
        for k, perm in (("gt_ids", gt_perm), ("gt_pos", gt_perm), ("hyp_ids", hyp_perm),
                        ("hyp_pos", hyp_perm)):
            b[k].append(np.stack([seq[k][t][perm[t]] for t in range(T)]))
    b = {k: np.stack(v) for k, v in b.items()}
    shuffled = _BATCHED["motmetrics"](b["gt_ids"], b["gt_pos"], b["hyp_ids"], b["hyp_pos"],
                                      THRESHOLD)
    for name in COUNTS + RATIOS:
        np.testing.assert_allclose(getattr(shuffled, name), getattr(results["motmetrics"], name),
                                   rtol=1e-12, err_msg=name)


def test_vmap_over_episodes_equals_a_loop_and_threshold_may_be_traced(sequences, results):
    seqs, _ = sequences
    for i in range(3):
        s = seqs[i]
        one = single(s["gt_ids"], s["gt_pos"], None, s["hyp_ids"], s["hyp_pos"], None,
                     THRESHOLD)
        for name in COUNTS + RATIOS:
            np.testing.assert_allclose(getattr(one, name),
                                       getattr(results["motmetrics"], name)[i], rtol=1e-14,
                                       err_msg=name)
        np.testing.assert_array_equal(one.frames.assignment,
                                      results["motmetrics"].frames.assignment[i])


def test_float32_gives_the_same_counts_as_float64(sequences, results):
    _, b = sequences
    n = NUM_SEQUENCES
    res32 = _BATCHED["motmetrics"](b["gt_ids"], b["gt_pos"].astype(np.float32), b["hyp_ids"],
                                   b["hyp_pos"].astype(np.float32), np.float32(THRESHOLD))
    assert res32.motp.dtype == jnp.float32
    for name in COUNTS:
        np.testing.assert_array_equal(getattr(res32, name),
                                      getattr(results["motmetrics"], name)[:n], err_msg=name)
    np.testing.assert_allclose(res32.motp, results["motmetrics"].motp[:n], rtol=1e-5)


def test_ids_beyond_num_ids_are_counted_as_invalid_under_jit(sequences):
    seqs, _ = sequences
    s = seqs[0]
    gt_ids = np.where(s["gt_ids"] >= 0, s["gt_ids"] + 500, -1)
    with pytest.raises(ValueError, match="num_ids"):
        metrics.clear_mot(gt_ids, s["gt_pos"], None, s["hyp_ids"], s["hyp_pos"], None, 1.0)
    # Under jit the ids are not checked: out-of-range ones are left out and counted.
    mixed = np.where(np.arange(gt_ids.shape[1]) % 2 == 0, gt_ids, gt_ids + 5000)
    res = single(mixed, s["gt_pos"], None, s["hyp_ids"], s["hyp_pos"], None, THRESHOLD)
    beyond = (mixed >= 1000).sum()
    assert beyond > 0 and int(res.num_invalid) == beyond
    assert int(res.num_objects) == np.sum(mixed >= 0) - beyond


# ---------------------------------------------------------------------------------------------
# Bad input

_GOOD = dict(gt_ids=np.zeros((3, 2), int), gt_pos=np.zeros((3, 2, 2)), gt_mask=None,
             hyp_ids=np.zeros((3, 4), int), hyp_pos=np.zeros((3, 4, 2)), hyp_mask=None,
             threshold=1.0)
_GOOD["gt_ids"][:, 1] = -1
_GOOD["hyp_ids"][:, 1:] = -1


def _with(**changes):
    return functools.partial(metrics.clear_mot, **{**_GOOD, **changes})


@pytest.mark.parametrize("call,match", [
    (_with(gt_pos=np.zeros((3, 3, 2))), "gt_pos must have shape"),
    (_with(hyp_pos=np.zeros((3, 4, 3))), "hyp_pos must have shape"),
    (_with(hyp_ids=np.zeros((2, 4), int)), "hyp_ids must have shape"),
    (_with(gt_mask=np.ones((3, 3), bool)), "gt_mask must have shape"),
    (_with(gt_ids=np.zeros((3, 2))), "gt_ids must be integers"),
    (_with(gt_ids=np.zeros((3, 2), int)), "unique within a frame"),
    (_with(threshold=-1.0), "threshold must be a positive"),
    (_with(convention="py-motmetrics"), "unknown convention"),
    (_with(num_ids=0), "num_ids must be a positive"),
])
def test_bad_input_raises_a_clear_value_error(call, match):
    with pytest.raises(ValueError, match=match):
        call()
