"""Tests for `jaxtrack.metrics.identity_metrics` (IDF1 / IDP / IDR) against py-motmetrics.

The reference is py-motmetrics 1.4 (``MOTAccumulator`` fed Euclidean distances with NaN beyond
the threshold, then ``idf1 / idp / idr / idtp / idfp / idfn``), on the 200 random sequences of
``_sequences.py`` (births, deaths, gaps, id changes and swaps, false positives with reused ids)
and on the same sequences drawn as image boxes matched by IoU. One compiled function per
distance runs all sequences under `vmap`.
"""

import jax
import jax.numpy as jnp
import motmetrics as mm
import numpy as np
import pytest

from jaxtrack import metrics
from tests.metrics._sequences import (G, H, THRESHOLD, T, frame_distances,
                                      sequences_with_boxes)

NUM_SEQUENCES = 200
FIELDS = ["idf1", "idp", "idr", "idtp", "idfp", "idfn"]
_MH = mm.metrics.create()


def _batched(distance):
    def episode(gt_ids, gt_pos, hyp_ids, hyp_pos, threshold):
        return metrics.identity_metrics(gt_ids, gt_pos, None, hyp_ids, hyp_pos, None, threshold,
                                        distance=distance, max_ids=T * G, max_hyp_ids=T * H)

    return jax.jit(jax.vmap(episode, in_axes=(0, 0, 0, 0, None)))


_BATCHED = {d: _batched(d) for d in ("euclidean", "iou")}


@pytest.fixture(scope="module")
def sequences():
    return sequences_with_boxes(NUM_SEQUENCES, box_seed=0)


def motmetrics_accumulator(seq, distance="euclidean", threshold=THRESHOLD):
    acc = mm.MOTAccumulator(auto_id=True)
    for t in range(seq["gt_ids"].shape[0]):
        if distance == "euclidean":
            acc.update(*frame_distances(seq, t, threshold))
        else:
            gm, hm = seq["gt_ids"][t] >= 0, seq["hyp_ids"][t] >= 0
            d = mm.distances.iou_matrix(seq["gt_box"][t][gm], seq["hyp_box"][t][hm],
                                        max_iou=threshold)
            acc.update(seq["gt_ids"][t][gm], seq["hyp_ids"][t][hm],
                       d if d.size else np.empty((gm.sum(), hm.sum())))
    return acc


@pytest.mark.parametrize("distance", ["euclidean", "iou"])
def test_identity_equals_py_motmetrics_on_200_random_sequences(sequences, distance):
    seqs, b = sequences
    key = "pos" if distance == "euclidean" else "box"
    threshold = THRESHOLD if distance == "euclidean" else 0.5
    res = jax.device_get(_BATCHED[distance](b["gt_ids"], b[f"gt_{key}"], b["hyp_ids"],
                                            b[f"hyp_{key}"], threshold))
    worst, imperfect = 0.0, 0
    for i, seq in enumerate(seqs):
        ref = _MH.compute(motmetrics_accumulator(seq, distance, threshold), metrics=FIELDS,
                          return_dataframe=False)
        for name in ("idtp", "idfp", "idfn"):
            assert getattr(res, name)[i] == ref[name], (i, name, getattr(res, name)[i], ref[name])
        for name in ("idf1", "idp", "idr"):
            worst = max(worst, abs(getattr(res, name)[i] - ref[name]))
        imperfect += ref["idtp"] < ref["idtp"] + ref["idfn"]
    assert worst <= 1e-9, worst
    assert imperfect > NUM_SEQUENCES // 2  # the sequences do exercise the matching
    assert np.all(res.num_invalid == 0)


def test_combine_equals_py_motmetrics_overall(sequences):
    seqs, b = sequences
    res = _BATCHED["euclidean"](b["gt_ids"][:6], b["gt_pos"][:6], b["hyp_ids"][:6],
                                b["hyp_pos"][:6], THRESHOLD)
    overall = metrics.combine_identity(res)
    ref = _MH.compute_many([motmetrics_accumulator(s) for s in seqs[:6]], metrics=FIELDS,
                           generate_overall=True).loc["OVERALL"]
    for name in FIELDS:
        np.testing.assert_allclose(getattr(overall, name), ref[name], rtol=0, atol=1e-9)


def test_float32_gives_the_same_counts(sequences):
    seqs, b = sequences
    n = 20
    r64 = _BATCHED["euclidean"](b["gt_ids"][:n], b["gt_pos"][:n], b["hyp_ids"][:n],
                                b["hyp_pos"][:n], THRESHOLD)
    r32 = _BATCHED["euclidean"](b["gt_ids"][:n], b["gt_pos"][:n].astype(np.float32),
                                b["hyp_ids"][:n], b["hyp_pos"][:n].astype(np.float32),
                                np.float32(THRESHOLD))
    # Distances within 1e-6 of the threshold could flip; the sequences have none.
    np.testing.assert_array_equal(r32.idtp, r64.idtp)
    np.testing.assert_allclose(r32.idf1, r64.idf1, rtol=1e-6)


def test_perfect_tracker_and_single_swap_closed_form():
    # Two objects tracked for 10 frames; the tracker swaps their ids after frame 6.
    T_, pos = 10, np.array([[0.0, 0.0], [5.0, 0.0]])
    gt_ids = np.tile([0, 1], (T_, 1))
    gt_pos = np.tile(pos, (T_, 1, 1))
    hyp_ids = np.where(np.arange(T_)[:, None] < 6, [7, 9], [9, 7])
    perfect = metrics.identity_metrics(gt_ids, gt_pos, None, gt_ids + 3, gt_pos, None, 0.5)
    assert float(perfect.idf1) == 1.0 and int(perfect.idtp) == 2 * T_
    swapped = metrics.identity_metrics(gt_ids, gt_pos, None, hyp_ids, gt_pos, None, 0.5)
    # Each object keeps its first hypothesis for 6 of 10 frames: IDTP = 12 of 20.
    assert int(swapped.idtp) == 12 and int(swapped.idfn) == 8 and int(swapped.idfp) == 8
    np.testing.assert_allclose(swapped.idf1, 0.6)


def test_empty_inputs_are_defined():
    gt_ids = np.tile([0, 1], (4, 1))
    gt_pos = np.zeros((4, 2, 2))
    no_hyp = metrics.identity_metrics(gt_ids, gt_pos, None, np.full((4, 0), -1, int),
                                      np.zeros((4, 0, 2)), None, 0.5)
    assert int(no_hyp.idtp) == 0 and int(no_hyp.idfn) == 8 and float(no_hyp.idf1) == 0.0
    assert np.isnan(no_hyp.idp) and float(no_hyp.idr) == 0.0
    zero_t = metrics.identity_metrics(np.zeros((0, 2), int), np.zeros((0, 2, 2)), None,
                                      np.zeros((0, 3), int), np.zeros((0, 3, 2)), None, 0.5)
    assert int(zero_t.num_objects) == 0 and np.isnan(zero_t.idf1)
    all_absent = metrics.identity_metrics(-np.ones((3, 2), int), np.zeros((3, 2, 2)), None,
                                          -np.ones((3, 2), int), np.zeros((3, 2, 2)), None, 0.5)
    assert int(all_absent.idtp) == 0 and np.isnan(all_absent.idf1)


def test_nan_positions_never_agree():
    gt_ids = np.zeros((3, 1), int)
    gt_pos = np.zeros((3, 1, 2))
    hyp_pos = gt_pos.copy()
    hyp_pos[1] = np.nan
    res = metrics.identity_metrics(gt_ids, gt_pos, None, gt_ids, hyp_pos, None, 0.5)
    assert int(res.idtp) == 2 and int(res.idfp) == 1 and int(res.idfn) == 1


def test_bad_input_is_refused():
    ids, pos = np.zeros((3, 1), int), np.zeros((3, 1, 2))
    with pytest.raises(ValueError, match="distance"):
        metrics.identity_metrics(ids, pos, None, ids, pos, None, 0.5, distance="cosine")
    with pytest.raises(ValueError, match="boxes"):
        metrics.identity_metrics(ids, pos, None, ids, pos, None, 0.5, distance="iou")
    with pytest.raises(ValueError, match="threshold"):
        metrics.identity_metrics(ids, pos, None, ids, pos, None, -1.0)
    with pytest.raises(ValueError, match="max_hyp_ids"):
        metrics.identity_metrics(ids, pos, None, np.arange(3)[:, None], pos, None, 0.5,
                                 max_hyp_ids=2)
    with pytest.raises(ValueError, match="integers"):
        metrics.identity_metrics(ids.astype(float), pos, None, ids, pos, None, 0.5)


def test_ids_beyond_the_bound_under_jit_are_counted_invalid():
    f = jax.jit(lambda h: metrics.identity_metrics(np.zeros((3, 1), int), np.zeros((3, 1, 2)),
                                                   None, h, np.zeros((3, 1, 2)), None, 0.5,
                                                   max_hyp_ids=2))
    res = f(jnp.arange(3)[:, None])
    assert int(res.num_invalid) == 1 and int(res.num_predictions) == 2
