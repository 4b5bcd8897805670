"""Tests for the MOTChallenge summary of `jaxtrack.io.trajectories` (`evaluate_sequences`,
`read_mot_boxes`, `format_summary`, `write_summary`).

References: the TUD-Campus and TUD-Stadtmitte files shipped inside the py-motmetrics wheel,
scored by py-motmetrics' own pipeline (``loadtxt``, ``compare_to_groundtruth(..., "iou",
distth=0.5)``, ``compute_many(..., motchallenge_metrics, generate_overall=True)``) and by the
values py-motmetrics publishes for them in its test suite; HOTA by TrackEval's
``HOTA.eval_sequence`` on the same boxes.
"""

import json
import os

import motmetrics as mm
import numpy as np
import pytest
from trackeval.datasets._base_dataset import _BaseDataset
from trackeval.metrics.hota import HOTA

from jaxtrack.io import trajectories as tj

DATA = os.path.join(os.path.dirname(mm.__file__), "data")
NAMES = ["TUD-Campus", "TUD-Stadtmitte"]
MM_KEYS = ["idf1", "idp", "idr", "recall", "precision", "num_unique_objects", "mostly_tracked",
           "partially_tracked", "mostly_lost", "num_false_positives", "num_misses",
           "num_switches", "num_fragmentations", "mota", "motp"]
# py-motmetrics 1.4, tests/test_metrics.py::test_motchallenge_files (rows: the two sequences,
# then OVERALL; columns MM_KEYS).
PUBLISHED = {
    "TUD-Campus": [0.557659, 0.729730, 0.451253, 0.582173, 0.941441, 8, 1, 6, 1, 13, 150, 7,
                   7, 0.526462, 0.277201],
    "TUD-Stadtmitte": [0.644619, 0.819760, 0.531142, 0.608997, 0.939920, 10, 5, 4, 1, 45, 452,
                       7, 6, 0.564014, 0.345904],
    "OVERALL": [0.624296, 0.799176, 0.512211, 0.602640, 0.940268, 18, 6, 10, 2, 58, 602, 14, 13,
                0.555116, 0.330177],
}


@pytest.fixture(scope="module")
def rows():
    return tj.evaluate_sequences({n: (os.path.join(DATA, n, "gt.txt"),
                                      os.path.join(DATA, n, "test.txt")) for n in NAMES})


def test_tud_summary_equals_the_published_values(rows):
    assert list(rows) == NAMES + ["OVERALL"]
    for name, values in PUBLISHED.items():
        for key, value in zip(MM_KEYS, values):
            assert rows[name][key] == pytest.approx(value, abs=6e-7), (name, key)
        assert rows[name]["plane"] == "image"


def test_tud_summary_equals_py_motmetrics_run_now(rows):
    accs = [mm.utils.compare_to_groundtruth(mm.io.loadtxt(os.path.join(DATA, n, "gt.txt")),
                                            mm.io.loadtxt(os.path.join(DATA, n, "test.txt")),
                                            "iou", distth=0.5) for n in NAMES]
    mh = mm.metrics.create()
    ref = mh.compute_many(accs, metrics=MM_KEYS, names=NAMES, generate_overall=True)
    for name in NAMES + ["OVERALL"]:
        for key in MM_KEYS:
            assert rows[name][key] == pytest.approx(float(ref.loc[name, key]), abs=1e-9), \
                (name, key)


def test_tud_hota_equals_trackeval(rows):
    per = {}
    for name in NAMES:
        gt = np.loadtxt(os.path.join(DATA, name, "gt.txt"), delimiter=",")
        tr = np.loadtxt(os.path.join(DATA, name, "test.txt"), delimiter=",")
        frames = np.union1d(gt[:, 0], tr[:, 0])
        gt_all, tr_all = np.unique(gt[:, 1]), np.unique(tr[:, 1])
        data = dict(gt_ids=[], tracker_ids=[], similarity_scores=[], num_gt_ids=len(gt_all),
                    num_tracker_ids=len(tr_all), num_gt_dets=len(gt), num_tracker_dets=len(tr))
        for f in frames:
            g, t = gt[gt[:, 0] == f], tr[tr[:, 0] == f]
            data["gt_ids"].append(np.searchsorted(gt_all, g[:, 1]))
            data["tracker_ids"].append(np.searchsorted(tr_all, t[:, 1]))
            data["similarity_scores"].append(_BaseDataset._calculate_box_ious(g[:, 2:6],
                                                                              t[:, 2:6]))
        per[name] = HOTA().eval_sequence(data)
        for key in ("HOTA", "DetA", "AssA", "LocA"):
            assert rows[name][key.lower()] == pytest.approx(np.mean(per[name][key]), abs=1e-9)
    overall = HOTA().combine_sequences(per)
    assert rows["OVERALL"]["hota"] == pytest.approx(np.mean(overall["HOTA"]), abs=1e-9)


def test_format_and_write_summary(rows, tmp_path):
    text = tj.format_summary(rows)
    lines = text.splitlines()
    assert lines[0].split() == [h for _, h, _ in tj.SUMMARY_COLUMNS]
    assert lines[1].split()[:3] == ["TUD-Campus", "55.8%", "73.0%"]
    assert lines[3].startswith("OVERALL") and "0.330" in lines[3]
    tj.write_summary(rows, tmp_path / "s.csv", tmp_path / "s.json")
    csv_rows = np.genfromtxt(tmp_path / "s.csv", delimiter=",", names=True, dtype=None,
                             encoding="utf-8")
    assert list(csv_rows["name"]) == NAMES + ["OVERALL"]
    np.testing.assert_allclose(csv_rows["idf1"], [rows[n]["idf1"] for n in rows], rtol=1e-15)
    back = json.loads((tmp_path / "s.json").read_text())
    assert back["OVERALL"]["num_switches"] == 14 and back["TUD-Campus"]["hota"] == rows[
        "TUD-Campus"]["hota"]


def test_read_mot_boxes_nine_columns_and_min_confidence(tmp_path):
    path = tmp_path / "gt.txt"
    path.write_text("1,1,10,20,30,40,1,1,1.0\n1,2,50,60,30,40,0,7,0.5\n2,1,12,20,30,40,1,1,1\n")
    assert tj._sniff(path) == "mot2d"
    traj = tj.read(path)
    assert traj.pos.shape == (2, 2, 4)
    np.testing.assert_array_equal(traj.pos[0, 1], [50, 60, 30, 40])
    kept = tj.read_mot_boxes(path, min_confidence=1)
    np.testing.assert_array_equal(kept.ids, [[1], [1]])
    with pytest.raises(ValueError, match="no row has conf"):
        tj.read_mot_boxes(path, min_confidence=2)
    bad = tmp_path / "bad.txt"
    bad.write_text("1,1,10,20,-30,40,1,1,1\n")
    with pytest.raises(ValueError, match="line 1: negative box"):
        tj.read_mot_boxes(bad)


def test_planes_cannot_be_mixed(tmp_path):
    boxes = tmp_path / "boxes.txt"
    boxes.write_text("1,1,10,20,30,40,1,-1,-1,-1\n")
    ground = tmp_path / "ground.txt"
    ground.write_text("1 1 0.5 0.5\n")
    with pytest.raises(ValueError, match="without the image boxes"):
        tj.evaluate_files(boxes, ground)
    written = tmp_path / "written.csv"
    tj.write_mot_csv(written, [1], [[1]], [[[0.5, 0.5]]], None)
    with pytest.raises(ValueError, match="every box is -1"):
        tj.evaluate_files(written, boxes)
    with pytest.raises(ValueError, match="sequences is empty"):
        tj.evaluate_sequences({})
