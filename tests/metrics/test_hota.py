"""Tests for `jaxtrack.metrics.hota` against TrackEval.

The reference is TrackEval 1.3's own ``HOTA.eval_sequence`` and ``combine_sequences``, fed the
similarities of TrackEval's ``_calculate_euclidean_similarity`` (ground plane) and
``_calculate_box_ious`` (boxes), on the 200 random sequences of ``_sequences.py``. One compiled
function per similarity runs all sequences under `vmap`.
"""

import jax
import numpy as np
import pytest
from trackeval.datasets._base_dataset import _BaseDataset
from trackeval.metrics.hota import HOTA

from jaxtrack import metrics
from tests.metrics._sequences import G, H, T, sequences_with_boxes

NUM_SEQUENCES = 200
ZERO_DISTANCE = 1.5
FIELDS = dict(HOTA="hota_alpha", DetA="deta_alpha", AssA="assa_alpha", LocA="loca_alpha",
              DetRe="detre_alpha", DetPr="detpr_alpha", AssRe="assre_alpha",
              AssPr="asspr_alpha", HOTA_TP="tp", HOTA_FN="fn", HOTA_FP="fp")
_TE = HOTA()


def _batched(similarity):
    def episode(gt_ids, gt_pos, hyp_ids, hyp_pos):
        return metrics.hota(gt_ids, gt_pos, None, hyp_ids, hyp_pos, None, similarity=similarity,
                            zero_distance=ZERO_DISTANCE, max_ids=T * G, max_hyp_ids=T * H)

    return jax.jit(jax.vmap(episode))


_BATCHED = {s: _batched(s) for s in ("euclidean", "iou")}


@pytest.fixture(scope="module")
def sequences():
    return sequences_with_boxes(NUM_SEQUENCES, box_seed=1)


def trackeval_data(seq, similarity):
    """TrackEval's per-sequence data dict: ids relabelled 0..n-1, per-frame similarities."""
    gt_all = np.unique(seq["gt_ids"][seq["gt_ids"] >= 0])
    hyp_all = np.unique(seq["hyp_ids"][seq["hyp_ids"] >= 0])
    data = dict(gt_ids=[], tracker_ids=[], similarity_scores=[])
    for t in range(seq["gt_ids"].shape[0]):
        gm, hm = seq["gt_ids"][t] >= 0, seq["hyp_ids"][t] >= 0
        data["gt_ids"].append(np.searchsorted(gt_all, seq["gt_ids"][t][gm]))
        data["tracker_ids"].append(np.searchsorted(hyp_all, seq["hyp_ids"][t][hm]))
        if similarity == "euclidean":
            s = _BaseDataset._calculate_euclidean_similarity(
                seq["gt_pos"][t][gm], seq["hyp_pos"][t][hm], ZERO_DISTANCE)
        else:
            s = _BaseDataset._calculate_box_ious(seq["gt_box"][t][gm], seq["hyp_box"][t][hm])
        data["similarity_scores"].append(s)
    data.update(num_gt_ids=len(gt_all), num_tracker_ids=len(hyp_all),
                num_gt_dets=int(np.sum(seq["gt_ids"] >= 0)),
                num_tracker_dets=int(np.sum(seq["hyp_ids"] >= 0)))
    return data


@pytest.fixture(scope="module")
def results(sequences):
    _, b = sequences
    return {
        "euclidean": jax.device_get(_BATCHED["euclidean"](b["gt_ids"], b["gt_pos"],
                                                          b["hyp_ids"], b["hyp_pos"])),
        "iou": jax.device_get(_BATCHED["iou"](b["gt_ids"], b["gt_box"], b["hyp_ids"],
                                              b["hyp_box"])),
    }


@pytest.mark.parametrize("similarity", ["euclidean", "iou"])
def test_hota_equals_trackeval_on_200_random_sequences(sequences, results, similarity):
    seqs, _ = sequences
    res = results[similarity]
    worst = 0.0
    for i, seq in enumerate(seqs):
        ref = _TE.eval_sequence(trackeval_data(seq, similarity))
        for key, name in FIELDS.items():
            worst = max(worst, float(np.max(np.abs(getattr(res, name)[i] - ref[key]))))
        np.testing.assert_allclose(res.hota[i], np.mean(ref["HOTA"]), rtol=0, atol=1e-9)
        np.testing.assert_allclose(res.loca[i], np.mean(ref["LocA"]), rtol=0, atol=1e-9)
    assert worst <= 1e-9, worst
    # Not degenerate: association and localisation are imperfect, detection partial.
    assert 0.05 < np.mean(res.hota) < 0.95 and np.min(res.assa) < 0.9


def test_combine_equals_trackeval_combine_sequences(sequences, results):
    seqs, _ = sequences
    per = {i: _TE.eval_sequence(trackeval_data(seqs[i], "euclidean")) for i in range(8)}
    ref = _TE.combine_sequences(per)
    got = metrics.combine_hota(jax.tree.map(lambda a: a[:8], results["euclidean"]))
    for key, name in FIELDS.items():
        np.testing.assert_allclose(getattr(got, name), ref[key], rtol=0, atol=1e-9)


def test_float32_close_to_float64(sequences, results):
    _, b = sequences
    n = 20
    r32 = _BATCHED["euclidean"](b["gt_ids"][:n], b["gt_pos"][:n].astype(np.float32),
                                b["hyp_ids"][:n], b["hyp_pos"][:n].astype(np.float32))
    assert r32.hota.dtype == np.float32
    np.testing.assert_allclose(r32.hota, results["euclidean"].hota[:n], atol=2e-5)


def test_empty_sides_follow_trackeval():
    gt_ids = np.tile([0, 1], (4, 1))
    gt_pos = np.zeros((4, 2, 2))
    no_hyp = metrics.hota(gt_ids, gt_pos, None, -np.ones((4, 2), int), gt_pos, None)
    ref = _TE.eval_sequence(dict(num_tracker_dets=0, num_gt_dets=8))
    for key, name in FIELDS.items():
        np.testing.assert_allclose(getattr(no_hyp, name), ref[key], err_msg=key)
    no_gt = metrics.hota(-np.ones((4, 2), int), gt_pos, None, gt_ids, gt_pos, None)
    ref = _TE.eval_sequence(dict(num_tracker_dets=8, num_gt_dets=0))
    for key, name in FIELDS.items():
        np.testing.assert_allclose(getattr(no_gt, name), ref[key], err_msg=key)
    zero_t = metrics.hota(np.zeros((0, 2), int), np.zeros((0, 2, 2)), None,
                          np.zeros((0, 0), int), np.zeros((0, 0, 2)), None)
    assert float(zero_t.hota) == 0.0 and float(zero_t.loca) == 1.0


def test_perfect_tracking_scores_one():
    gt_ids = np.tile([0, 1, 2], (5, 1))
    gt_pos = np.random.default_rng(0).uniform(0, 10, (5, 3, 2))
    res = metrics.hota(gt_ids, gt_pos, None, gt_ids + 10, gt_pos, None)
    for name in ("hota", "deta", "assa", "loca"):
        np.testing.assert_allclose(getattr(res, name), 1.0)


def test_bad_input_is_refused():
    ids, pos = np.zeros((3, 1), int), np.zeros((3, 1, 2))
    with pytest.raises(ValueError, match="similarity"):
        metrics.hota(ids, pos, None, ids, pos, None, similarity="giou")
    with pytest.raises(ValueError, match="boxes"):
        metrics.hota(ids, pos, None, ids, pos, None, similarity="iou")
    with pytest.raises(ValueError, match="zero_distance"):
        metrics.hota(ids, pos, None, ids, pos, None, zero_distance=0.0)
    with pytest.raises(ValueError, match="max_ids"):
        metrics.hota(np.arange(3)[:, None], pos, None, ids, pos, None, max_ids=1)
