"""``jaxtrack train-legs``: a model trained on written bags (scans + PoseArray labels, and a
person-free bag) that `leg_classifier.load` reads, with its counts in the metadata; one-line
errors with exit code 2 for every bad argument, found before any work."""

import sys

import numpy as np
import pytest

pytest.importorskip("rosbags")
pytest.importorskip("sklearn")

from jaxtrack.io import bags, leg_dataset  # noqa: E402
from jaxtrack.perception import leg_classifier  # noqa: E402
from sims import cli  # noqa: E402
from sims.following import lidar  # noqa: E402
from tests.perception import references  # noqa: E402

CFG = lidar.LaserConfig()
ANGLES = np.asarray(lidar.beam_angles(CFG), np.float32)     # 667 beams, as the other tests
RMAX = CFG.max_range
T = 12
SCAN, LABELS = "/training_scan", "/leg_cluster_positions"


def _polar(r, bearing):
    return np.array([r * np.cos(bearing), r * np.sin(bearing)])


def _scan(rng, circles, walls):
    """One scan (float32, misses inf) of circles [(xy, radius)] and walls, up to 5 and 2."""
    return references.laser_scan(rng, ANGLES, circles, walls, RMAX, num_circles=5, num_walls=2)


def _laser(ranges, t0):
    ranges = np.stack(ranges)
    return bags.LaserScans(t0 + 0.1 * np.arange(len(ranges)), ranges, ANGLES,
                           np.isfinite(ranges), 0.02, RMAX, np.ones(len(ranges), bool))


def _positive(seed, label_offset=0.0):
    """Scans of two legs (5.5 cm circles), a post and a wall; label messages (the leg centres)
    1 ms before their scans."""
    rng = np.random.default_rng(seed)
    ranges, labels = [], np.zeros((T, 2, 2))
    for t in range(T):
        b = rng.permutation(np.linspace(-1.5, 1.5, 8))
        legs_xy = [_polar(rng.uniform(1.0, 3.0), b[0]), _polar(rng.uniform(1.0, 3.0), b[1])]
        post = (_polar(rng.uniform(1.0, 3.0), b[2]), rng.uniform(0.04, 0.2))
        wall = [_polar(5.0, -0.7), _polar(5.0, 0.7)]
        ranges.append(_scan(rng, [(c, 0.055) for c in legs_xy] + [post], [wall]))
        labels[t] = legs_xy
    laser = _laser(ranges, 50.0 + seed)
    det = bags.PersonDetections(laser.times - 1e-3, labels + label_offset, np.ones((T, 2), bool),
                                np.ones(T, bool))
    return laser, det


def _negative(seed):
    rng = np.random.default_rng(seed)
    ranges = []
    for _ in range(T):
        b = rng.permutation(np.linspace(-1.5, 1.5, 8))
        posts = [(_polar(rng.uniform(1.0, 3.5), b[i]), rng.uniform(0.04, 0.25)) for i in range(4)]
        ranges.append(_scan(rng, posts, [[_polar(4.6, -0.7), _polar(4.6, 0.7)],
                                         [_polar(1.2, 2.0), _polar(3.0, 1.9)]]))
    return _laser(ranges, 70.0)


@pytest.fixture(scope="module")
def bag_files(tmp_path_factory):
    root = tmp_path_factory.mktemp("train_legs")
    names = {"laser": SCAN, "detections": LABELS}
    files = {}
    for i in (0, 1):
        laser, det = _positive(i)
        files[f"pos{i}"] = bags.write_bag(root / f"pos{i}.bag", 1, laser=laser, detections=det,
                                          detections_type=bags.POSE_ARRAY, topics=names)
    laser, det = _positive(5, label_offset=40.0)       # labels far from every segment
    files["far"] = bags.write_bag(root / "far.bag", 1, laser=laser, detections=det,
                                  detections_type=bags.POSE_ARRAY, topics=names)
    files["unlabelled"] = bags.write_bag(root / "unlabelled.bag", 1, laser=laser,
                                         topics={"laser": SCAN})
    files["neg"] = bags.write_bag(root / "neg.bag", 1, laser=_negative(9),
                                  topics={"laser": "/rear_scan"})
    files["no_scan"] = bags.write_bag(root / "no_scan.bag", 1, detections=det,
                                      detections_type=bags.POSE_ARRAY)
    return {k: str(v) for k, v in files.items()}


ARGS = ["--trees", "5", "--depth", "4", "--seed", "2"]


def test_trains_a_model_that_loads_with_its_counts(bag_files, tmp_path, capsys):
    out = tmp_path / "models" / "legs.npz"          # the folder is created
    argv = ["train-legs", "--positive", bag_files["pos0"], bag_files["pos1"],
            "--negative", bag_files["neg"], "--out", str(out)] + ARGS
    assert cli.main(argv) == 0
    lines = capsys.readouterr().out.splitlines()
    model = leg_classifier.load(out)
    meta = leg_classifier.metadata(out)
    # The same recordings read by the library, and the counts of the simulation itself: both
    # legs of every positive scan are legs, nothing else is.
    positive = [leg_dataset.read_labelled(bag_files[k]) for k in ("pos0", "pos1")]
    negative = [leg_dataset.read_unlabelled(bag_files["neg"], "/rear_scan")]
    X, y, rec, scans, dropped = leg_dataset.training_set(positive, negative)
    assert int(y.sum()) == 2 * 2 * T and scans == 3 * T and dropped == 0
    assert meta["legs"] == int(y.sum()) and meta["segments"] == len(y)
    assert meta["scans"] == scans
    assert meta["sources"].splitlines() == [f"{bag_files['pos0']}:{SCAN}",
                                            f"{bag_files['pos1']}:{SCAN}",
                                            f"{bag_files['neg']}:/rear_scan"]
    assert lines[0] == f"{scans} scans, {len(y)} segments, {int(y.sum())} legs (0 segments " \
                       "beyond capacity)"
    assert lines[-1] == f"wrote {out}"
    # The model is `train` on those recordings with the command's settings.
    ref, report = leg_dataset.train(positive, negative, n_estimators=5, max_depth=4, seed=2)
    for name in leg_classifier.LegClassifier._fields:
        np.testing.assert_array_equal(getattr(model, name), getattr(ref, name), err_msg=name)
    assert meta["held_out_precision"] == report.held_out_precision
    assert meta["held_out_recall"] == report.held_out_recall
    assert lines[1].startswith(f"decision threshold {report.decision:.3f}")
    assert 0 < float(model.decision) < 1 and float(model.jump) == pytest.approx(0.13)
    assert model.feature.shape[0] == 5


def test_negative_topics_pick_the_scans_of_the_negative_bags(bag_files, tmp_path, capsys):
    out = tmp_path / "m.npz"
    argv = ["train-legs", "--positive", bag_files["pos0"], bag_files["pos1"],
            "--negative", bag_files["neg"], "--negative-topics", "/rear_scan",
            "--jump", "0.2", "--match-radius", "0.045", "--out", str(out)] + ARGS
    assert cli.main(argv) == 0
    capsys.readouterr()
    positive = [leg_dataset.read_labelled(bag_files[k]) for k in ("pos0", "pos1")]
    negative = [leg_dataset.read_unlabelled(bag_files["neg"], "/rear_scan")]
    _, y, *_ = leg_dataset.training_set(positive, negative, jump=0.2, match_radius=0.045)
    meta = leg_classifier.metadata(out)
    assert (meta["segments"], meta["legs"]) == (len(y), int(y.sum()))
    # The labels are the leg centres, about 4.5 cm behind the mean of the returns: the radius
    # reached the labelling (the default radius labels all 2 * 2 * T legs).
    assert 0 < meta["legs"] < 2 * 2 * T
    assert float(leg_classifier.load(out).jump) == pytest.approx(0.2)


@pytest.fixture
def no_work(monkeypatch):
    """Reading or training fails the test: bad arguments must be found first."""
    def fail(*a, **k):
        pytest.fail("work started despite a bad argument")

    for name in ("read_labelled", "read_unlabelled", "train", "training_set"):
        monkeypatch.setattr(leg_dataset, name, fail)


def _exit_2(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2, argv
    err = capsys.readouterr().err
    lines = [line for line in err.strip().splitlines() if not line.startswith("usage:")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize("extra, message", [
    (["--jump", "0"], "--jump and --match-radius must be positive and finite"),
    (["--jump", "-0.1"], "--jump and --match-radius must be positive and finite"),
    (["--jump", "nan"], "--jump and --match-radius must be positive and finite"),
    (["--jump", "inf"], "--jump and --match-radius must be positive and finite"),
    (["--match-radius", "0"], "--jump and --match-radius must be positive and finite"),
    (["--match-radius", "-1"], "--jump and --match-radius must be positive and finite"),
    (["--match-radius", "nan"], "--jump and --match-radius must be positive and finite"),
    (["--trees", "0"], "--trees and --depth must be positive"),
    (["--trees", "-3"], "--trees and --depth must be positive"),
    (["--depth", "0"], "--trees and --depth must be positive"),
])
def test_bad_numbers_exit_2_with_one_line_before_any_work(bag_files, tmp_path, capsys, no_work,
                                                          extra, message):
    out = tmp_path / "sub" / "m.npz"
    line = _exit_2(["train-legs", "--positive", bag_files["pos0"], "--out", str(out)] + extra,
                   capsys)
    assert message in line
    assert not out.parent.exists()                      # found before the output folder


def test_missing_bags_and_an_unwritable_out_exit_2_before_any_work(bag_files, tmp_path, capsys,
                                                                   no_work):
    missing = tmp_path / "missing.bag"
    out = str(tmp_path / "m.npz")
    line = _exit_2(["train-legs", "--positive", str(missing), "--out", out], capsys)
    assert f"{missing} does not exist" in line
    line = _exit_2(["train-legs", "--positive", bag_files["pos0"], "--negative", str(missing),
                    "--out", out], capsys)
    assert f"{missing} does not exist" in line
    blocker = tmp_path / "file"
    blocker.write_text("")
    line = _exit_2(["train-legs", "--positive", bag_files["pos0"], "--out",
                    str(blocker / "sub" / "m.npz")], capsys)
    assert "--out" in line and "not a writable directory" in line
    assert blocker.read_text() == ""


def test_without_scikit_learn_exit_2_before_any_work(bag_files, tmp_path, capsys, no_work,
                                                     monkeypatch):
    monkeypatch.setitem(sys.modules, "sklearn", None)        # import sklearn: ImportError
    line = _exit_2(["train-legs", "--positive", bag_files["pos0"], "--out",
                    str(tmp_path / "m.npz")], capsys)
    assert "needs scikit-learn" in line


def test_bag_and_data_errors_exit_2_with_one_line(bag_files, tmp_path, capsys):
    out = tmp_path / "m.npz"
    base = ["--out", str(out)] + ARGS
    line = _exit_2(["train-legs", "--positive", bag_files["unlabelled"]] + base, capsys)
    assert line.startswith("jaxtrack train-legs:") and repr(LABELS) in line
    line = _exit_2(["train-legs", "--positive", bag_files["pos0"], "--labels-topic", "/labels"]
                   + base, capsys)
    assert "'/labels'" in line
    line = _exit_2(["train-legs", "--positive", bag_files["pos0"], "--negative",
                    bag_files["no_scan"]] + base, capsys)
    assert f"{bag_files['no_scan']} has no LaserScan topic" in line
    line = _exit_2(["train-legs", "--positive", bag_files["far"]] + base, capsys)
    assert "0 leg segments" in line
    assert not out.exists()


def test_an_out_without_the_npz_suffix_is_the_file_written(bag_files, tmp_path, capsys):
    out = tmp_path / "legs_model"
    argv = ["train-legs", "--positive", bag_files["pos0"], bag_files["pos1"],
            "--out", str(out)] + ARGS
    assert cli.main(argv) == 0
    said = capsys.readouterr().out.splitlines()[-1].removeprefix("wrote ")
    leg_classifier.load(said)
