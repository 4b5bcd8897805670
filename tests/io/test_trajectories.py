"""Trajectory files and MOTChallenge CSV: round trips, column conventions, errors with line
numbers, and CLEAR MOT from files against py-motmetrics."""

import jax.numpy as jnp
import motmetrics as mm
import numpy as np
import pytest

from jaxtrack import metrics
from jaxtrack.io import trajectories as tj

THRESHOLD = 0.5


def random_rows(seed, num_frames=12, num_people=5, frame_step=10):
    """Rows (frame, id, x, y, vx, vy) of people entering and leaving, in random order."""
    rng = np.random.default_rng(seed)
    rows = []
    for pid in rng.choice(400, num_people, replace=False):
        start = rng.integers(0, num_frames // 2)
        stop = rng.integers(start + 2, num_frames + 1)
        p, v = rng.uniform(-5, 5, 2), rng.normal(0, 1, 2)
        for k in range(start, stop):
            rows.append((780 + frame_step * k, pid, *(p + 0.4 * k * v), *v))
    rows = np.array(rows)
    return rows[rng.permutation(len(rows))]


def expected(rows, num_cols=4):
    """Reference layout: frames sorted, people sorted by id within a frame."""
    frames = np.unique(rows[:, 0]).astype(int)
    per_frame = [rows[rows[:, 0] == f] for f in frames]
    P = max(len(r) for r in per_frame)
    ids = np.full((len(frames), P), -1)
    vals = np.zeros((len(frames), P, num_cols - 2))
    for t, r in enumerate(per_frame):
        r = r[np.argsort(r[:, 1])]
        ids[t, :len(r)] = r[:, 1]
        vals[t, :len(r)] = r[:, 2:num_cols]
    return frames, ids, vals


def write_obsmat(path, rows, height=None):
    """ETH layout: frame id x z y vx vz vy, all as %.7e floats."""
    z = np.zeros(len(rows)) if height is None else height
    cols = np.stack([rows[:, 0], rows[:, 1], rows[:, 2], z, rows[:, 3], rows[:, 4],
                     np.full(len(rows), 0.25), rows[:, 5]], 1)
    np.savetxt(path, cols, fmt="%15.7e")


def test_obsmat_reads_x_and_y_from_columns_3_and_5_and_velocities_from_6_and_8(tmp_path):
    rows = random_rows(0)
    path = tmp_path / "obsmat.txt"
    # a height column full of distinct values: it must not leak into the ground-plane position
    write_obsmat(path, rows, height=np.arange(len(rows)) + 100.0)
    traj = tj.read_obsmat(path, fps=25.0)
    frames, ids, vals = expected(rows, 6)
    np.testing.assert_array_equal(traj.frames, frames)
    np.testing.assert_array_equal(traj.ids, ids)
    np.testing.assert_array_equal(traj.mask, ids >= 0)
    # %.7e keeps 8 significant digits
    np.testing.assert_allclose(traj.pos, vals[..., :2], rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(traj.vel, vals[..., 2:], rtol=1e-7, atol=1e-7)
    assert np.all(np.asarray(traj.pos)[ids < 0] == 0) and np.all(np.asarray(traj.vel)[ids < 0] == 0)
    np.testing.assert_allclose(traj.times, frames / 25.0, rtol=1e-12)
    assert traj.ids.dtype == jnp.int32 and traj.frames.dtype == jnp.int32


def test_obsmat_of_the_eth_form_with_comments_and_blank_lines(tmp_path):
    path = tmp_path / "obsmat.txt"
    path.write_text("# ETH seq_eth\n\n"
                    "   7.8000000e+02   1.0000000e+00   8.4564598e+00   0.0000000e+00"
                    "   3.5877313e+00   1.6752954e+00   0.0000000e+00   6.5541536e-02\n"
                    "   7.8000000e+02   2.0000000e+00   9.5743862e+00   0.0000000e+00"
                    "   3.4446591e+00   1.6110932e+00   0.0000000e+00   1.1339815e-01  # walks\n")
    traj = tj.read_obsmat(path)
    np.testing.assert_array_equal(traj.frames, [780])
    np.testing.assert_array_equal(traj.ids, [[1, 2]])
    np.testing.assert_allclose(traj.pos, [[[8.4564598, 3.5877313], [9.5743862, 3.4446591]]])
    np.testing.assert_allclose(traj.vel, [[[1.6752954, 6.5541536e-02],
                                           [1.6110932, 1.1339815e-01]]])
    assert traj.times is None


@pytest.mark.parametrize("sep", [" ", "\t", ",", ", "])
def test_plain_round_trip(tmp_path, sep):
    rows = random_rows(1)[:, :4]
    path = tmp_path / "plain.txt"
    lines = ["# frame id x y", ""] + [sep.join([str(int(r[0])), str(int(r[1])), repr(float(r[2])),
                                                repr(float(r[3]))]) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    traj = tj.read_plain(path)
    frames, ids, vals = expected(rows)
    np.testing.assert_array_equal(traj.frames, frames)
    np.testing.assert_array_equal(traj.ids, ids)
    np.testing.assert_array_equal(traj.pos, vals)  # repr round-trips exactly
    assert traj.vel is None


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_mot_csv_round_trip_is_exact(tmp_path, dtype):
    rows = random_rows(2)
    frames, ids, vals = expected(rows)
    pos = jnp.asarray(vals, dtype)
    path = tmp_path / "gt.csv"
    n = tj.write_mot_csv(path, frames, ids, pos, ids >= 0)
    assert n == len(rows)
    back = tj.read_mot_csv(path, dtype=dtype)
    np.testing.assert_array_equal(back.frames, frames)
    np.testing.assert_array_equal(back.ids, ids)
    np.testing.assert_array_equal(back.mask, ids >= 0)
    assert back.pos.dtype == dtype
    np.testing.assert_array_equal(back.pos, pos)


def test_mot_csv_writes_the_ground_plane_3d_columns(tmp_path):
    path = tmp_path / "t.csv"
    tj.write_mot_csv(path, np.array([3]), np.array([[7]]), np.array([[[1.5, -2.25]]]), None)
    fields = path.read_text().strip().split(",")
    assert len(fields) == 10
    assert fields[:2] == ["3", "7"]
    assert [float(f) for f in fields[2:6]] == [-1, -1, -1, -1]  # bb_left, top, width, height
    assert float(fields[6]) == 1 and float(fields[9]) == 0      # conf, z
    assert (float(fields[7]), float(fields[8])) == (1.5, -2.25)  # x, y


def test_tracker_output_reads_back_as_the_same_rows(tmp_path):
    """Tracker layout: people in arbitrary slots, masked slots with junk, empty frames."""
    rng = np.random.default_rng(3)
    T, K = 9, 6
    ids = np.full((T, K), -1)
    for t in range(T):
        live = rng.choice(20, rng.integers(0, 4), replace=False)
        ids[t, rng.choice(K, len(live), replace=False)] = live
    pos = rng.normal(0, 3, (T, K, 2)).astype(np.float32)
    mask = ids >= 0
    mask[4, :] = False  # a frame where nothing is confirmed
    ids_with_junk = np.where(rng.random((T, K)) < 0.3, 99, ids)  # masked-out slots
    ids_with_junk[mask] = ids[mask]
    frames = np.arange(T) * 2 + 1
    path = tmp_path / "tracks.csv"
    tj.write_mot_csv(path, frames, ids_with_junk, pos, mask)
    back = tj.read_mot_csv(path, dtype=jnp.float32)

    def rowset(fr, i, p, m):
        fr, i, p, m = map(np.asarray, (fr, i, p, m))
        return sorted((int(fr[t]), int(i[t, k]), float(p[t, k, 0]), float(p[t, k, 1]))
                      for t in range(len(fr)) for k in range(i.shape[1]) if m[t, k])

    assert rowset(back.frames, back.ids, back.pos, back.mask) == rowset(frames, ids, pos, mask)


def test_mot_csv_reads_the_short_form_and_a_header(tmp_path):
    path = tmp_path / "short.csv"
    path.write_text("frame,id,x,y\n1,4,0.5,1.5\n1,2,2.0,3.0\n2,4,0.75,1.25\n")
    traj = tj.read_mot_csv(path)
    np.testing.assert_array_equal(traj.frames, [1, 2])
    np.testing.assert_array_equal(traj.ids, [[2, 4], [4, -1]])
    np.testing.assert_array_equal(traj.pos, [[[2.0, 3.0], [0.5, 1.5]], [[0.75, 1.25], [0, 0]]])
    assert tj.read(path).ids.shape == (2, 2)  # sniffed as the 4-column layout


def test_image_plane_mot_file_is_refused(tmp_path):
    path = tmp_path / "mot15_2d.csv"
    path.write_text("1,1,912,484,97,109,0.9,-1,-1,-1\n1,2,1342,417,168,380,0.8,-1,-1,-1\n")
    with pytest.raises(ValueError, match="image-plane MOT file"):
        tj.read_mot_csv(path)


def test_max_people_pads_and_names_the_frame_it_cannot_hold(tmp_path):
    path = tmp_path / "p.txt"
    path.write_text("1 1 0 0\n1 2 1 1\n2 1 0 0\n2 2 1 1\n2 3 2 2\n")
    assert tj.read_plain(path, max_people=5).ids.shape == (2, 5)
    with pytest.raises(ValueError, match=r"frame 2 has 3 people.*max_people = 2"):
        tj.read_plain(path, max_people=2)


@pytest.mark.parametrize("reader, good, bad, message", [
    (tj.read_plain, "1 2 0.5 0.5", "1 2 0.5", r"line 4: expected 4 columns"),
    (tj.read_plain, "1 2 0.5 0.5", "1 2 0.5 abc", r"line 4: not a number"),
    (tj.read_plain, "1 2 0.5 0.5", "1.5 2 0.5 0.5", r"line 4: frame must be a non-negative"),
    (tj.read_plain, "1 2 0.5 0.5", "1 -3 0.5 0.5", r"line 4: id must be a non-negative"),
    (tj.read_plain, "1 2 0.5 0.5", "1 3 nan 0.5", r"line 4: NaN or inf"),
    (tj.read_obsmat, "1 2 0.5 0 0.5 0 0 0", "1 2 0.5 0 0.5 0 0", r"line 4: expected 8 columns"),
    (tj.read_mot_csv, "1,2,0.5,0.5", "1,2,-1,-1,-1,-1,1,0.5,0.5", r"line 4: expected 4 or 10"),
    (tj.read_mot_csv, "1,2,0.5,0.5", "1,2,0.5,", r"line 4: not a number"),
])
def test_malformed_row_reports_file_and_line(tmp_path, reader, good, bad, message):
    path = tmp_path / "bad.txt"
    path.write_text(f"# header comment\n{good}\n\n{bad}\n{good.replace('1', '9', 1)}\n")
    with pytest.raises(ValueError, match=message) as err:
        reader(path)
    assert str(path) in str(err.value)


def test_duplicate_frame_and_id_names_both_lines(tmp_path):
    path = tmp_path / "dup.txt"
    path.write_text("1 1 0 0\n1 2 1 1\n2 1 0 0\n1 2 5 5\n")
    with pytest.raises(ValueError, match=r"line 4: frame 1, id 2 already given on line 2"):
        tj.read_plain(path)


@pytest.mark.parametrize("text", ["", "# only a comment\n\n"])
def test_empty_file_is_an_error(tmp_path, text):
    path = tmp_path / "empty.txt"
    path.write_text(text)
    for reader in (tj.read_plain, tj.read_obsmat, tj.read_mot_csv, tj.read):
        with pytest.raises(ValueError, match="no data rows"):
            reader(path)


def test_missing_file_and_bad_options(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.txt"):
        tj.read_obsmat(tmp_path / "nope.txt")
    with pytest.raises(FileNotFoundError):
        tj.evaluate_files(tmp_path / "nope.txt", tmp_path / "nope.csv")
    path = tmp_path / "p.txt"
    path.write_text("1 1 0 0\n")
    with pytest.raises(ValueError, match="unknown fmt"):
        tj.read(path, fmt="kitti")
    with pytest.raises(ValueError, match="threshold"):
        tj.evaluate_files(path, path, threshold=-1.0)
    with pytest.raises(ValueError, match="fps"):
        tj.read_plain(path, fps=0.0)
    with pytest.raises(ValueError, match=r"pos must have shape \[1, 1, 2\]"):
        tj.write_mot_csv(tmp_path / "o.csv", [1], [[1]], [[1.0, 2.0]], None)
    with pytest.raises(ValueError, match="ids repeat within frame 1"):
        tj.write_mot_csv(tmp_path / "o.csv", [1], [[1, 1]], np.zeros((1, 2, 2)), None)


# ---------------------------------------------------------------------------------------------
# CLEAR MOT from files


@pytest.fixture(scope="module")
def gt_file(tmp_path_factory):
    """Three people walking 20 frames (ids 11, 12, 13; 13 leaves after frame 15)."""
    path = tmp_path_factory.mktemp("gt") / "gt.txt"
    lines = []
    for f in range(20):
        for pid, (x0, y0, vx) in zip((11, 12, 13), ((0, 0, 0.1), (0, 1.0, 0.1), (3, 3, -0.1))):
            if pid == 13 and f > 15:
                continue
            lines.append(f"{f} {pid} {x0 + vx * f!r} {y0!r}")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_ground_truth_layout_feeds_clear_mot_directly(gt_file):
    gt = tj.read_plain(gt_file)
    res = metrics.clear_mot(gt.ids, gt.pos, gt.mask, gt.ids, gt.pos, gt.mask, THRESHOLD)
    assert float(res.mota) == 1.0 and float(res.motp) == 0.0
    assert int(res.num_switches) == 0 and int(res.num_matches) == int(gt.mask.sum())


def test_ground_truth_against_itself_has_mota_one(gt_file):
    res = tj.evaluate_files(gt_file, gt_file, threshold=THRESHOLD)
    assert res["mota"] == 1.0 and res["num_switches"] == 0
    assert res["num_frames"] == 20 and res["num_matches"] == 3 * 16 + 2 * 4
    assert res["num_misses"] == 0 and res["num_false_positives"] == 0


def _tracks_with_swap(gt_file, out):
    """Tracker output: ids 1, 2, 3 for 11, 12, 13, with 1 and 2 swapped from frame 10, noise,
    frame 5 missing, person 13 missed at frames 7-8, a false positive at frames 3 and 12, and an
    extra track coasting for two frames after 13 left."""
    rng = np.random.default_rng(0)
    gt = np.loadtxt(gt_file)
    rows = []
    for f, pid, x, y in gt:
        if f == 5 or (pid == 13 and f in (7, 8)):
            continue
        tid = {11: 1, 12: 2, 13: 3}[int(pid)]
        if f >= 10 and tid in (1, 2):
            tid = 3 - tid
        rows.append((int(f), tid, x + rng.normal(0, 0.05), y + rng.normal(0, 0.05)))
    rows += [(3, 9, 10.0, 10.0), (12, 9, -4.0, 2.0), (16, 3, 1.5, 3.0), (17, 3, 1.4, 3.0)]
    frames = sorted({r[0] for r in rows})
    K = 4
    ids = np.full((len(frames), K), -1)
    pos = np.zeros((len(frames), K, 2))
    for f, tid, x, y in rows:
        t = frames.index(f)
        k = int(np.argmax(ids[t] < 0))
        ids[t, k], pos[t, k] = tid, (x, y)
    tj.write_mot_csv(out, np.array(frames), ids, pos, ids >= 0)
    return out


def motmetrics_reference(gt_file, tracks_file, threshold):
    """py-motmetrics fed by files parsed with numpy, Euclidean distances, NaN beyond the
    threshold, on every frame present in either file."""
    gt = np.loadtxt(gt_file)
    hyp = np.loadtxt(tracks_file, delimiter=",")[:, [0, 1, 7, 8]]
    acc = mm.MOTAccumulator(auto_id=True)
    for f in np.union1d(gt[:, 0], hyp[:, 0]):
        g, h = gt[gt[:, 0] == f], hyp[hyp[:, 0] == f]
        d = np.sqrt(((g[:, None, 2:] - h[None, :, 2:]) ** 2).sum(-1))
        d[d > threshold] = np.nan
        acc.update(g[:, 1].astype(int), h[:, 1].astype(int), d)
    names = ["mota", "motp", "num_switches", "num_misses", "num_false_positives",
             "num_matches", "num_frames", "num_objects", "num_fragmentations"]
    summary = mm.metrics.create().compute(acc, metrics=names)
    return {n: summary[n].iloc[0] for n in names}


def test_swapped_ids_give_the_switches_motmetrics_counts(gt_file, tmp_path):
    tracks = _tracks_with_swap(gt_file, tmp_path / "tracks.csv")
    res = tj.evaluate_files(gt_file, tracks, threshold=THRESHOLD)
    ref = motmetrics_reference(gt_file, tracks, THRESHOLD)
    assert res["num_switches"] >= 2  # the swap alone makes two
    for name in ("num_switches", "num_misses", "num_false_positives", "num_matches",
                 "num_frames", "num_objects", "num_fragmentations"):
        assert res[name] == int(ref[name]), name
    assert res["mota"] == pytest.approx(ref["mota"], abs=1e-12)
    assert res["motp"] == pytest.approx(ref["motp"], abs=1e-12)
    # a frame missing from the tracks: everyone in it is missed
    assert res["num_misses"] >= 3


def test_format_clear_mot_prints_the_counts(gt_file, tmp_path):
    tracks = _tracks_with_swap(gt_file, tmp_path / "tracks.csv")
    res = tj.evaluate_files(gt_file, tracks, threshold=THRESHOLD, fmt="auto")
    text = tj.format_clear_mot(res)
    assert f"{res['mota']:.4f}" in text and "id switches" in text
    assert f"  {res['num_switches']}" in text and "20 frames" in text


def test_target_only_scoring_leaves_out_tracks_away_from_the_labelled_person(tmp_path):
    # Ground truth labels only the followed person (id 1); the tracks hold her track (with one
    # id switch and one miss), two tracks of unlabelled people far from her, and one spurious
    # track 0.3 m from her in frame 4 (within the threshold: still a false positive).
    T = 8
    target = np.stack([np.linspace(0, 3.5, T), np.zeros(T)], -1)
    gt = [(t + 1, 1, *target[t]) for t in range(T)]
    mine = [(t + 1, 7 if t < 5 else 8, target[t, 0] + 0.05, 0.02) for t in range(T) if t != 2]
    others = [(t + 1, 20 + k, 1.0 + k, 3.0 + k) for t in range(T) for k in range(2)]
    spurious = [(5, 30, target[4, 0], 0.3)]
    np.savetxt(tmp_path / "gt.txt", np.array(gt), fmt="%.6f")
    np.savetxt(tmp_path / "all.txt", np.array(mine + others + spurious), fmt="%.6f")
    np.savetxt(tmp_path / "near.txt", np.array(mine + spurious), fmt="%.6f")
    full = tj.evaluate_files(tmp_path / "gt.txt", tmp_path / "all.txt", 0.5, "plain")
    target_only = tj.evaluate_files(tmp_path / "gt.txt", tmp_path / "all.txt", 0.5, "plain",
                                    target_only=True)
    # The same as scoring a file without the far tracks (written by hand).
    by_hand = tj.evaluate_files(tmp_path / "gt.txt", tmp_path / "near.txt", 0.5, "plain")
    assert target_only == by_hand
    assert full["num_false_positives"] == 2 * T + 1
    assert target_only["num_false_positives"] == 1
    assert target_only["num_misses"] == full["num_misses"] == 1
    assert target_only["num_switches"] == full["num_switches"] == 1
    assert target_only["mota"] > full["mota"]
    assert target_only["motp"] == full["motp"]
