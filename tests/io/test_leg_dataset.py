"""Labelled leg datasets (`jaxtrack.io.leg_dataset`): the label / scan pairing of `read_labelled`
on written bags, `segment_dataset` against a scan-by-scan numpy labelling, `match_counts` against
scipy's assignment, `best_f1_threshold` against every threshold, and `train` on simulated scans.

Every simulated scan has the default laser's 667 beams and every segmentation the default
capacity, so the chunked segmentation compiles once for the module."""

import dataclasses
from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from jaxtrack.io import bags, leg_dataset
from jaxtrack.perception import leg_features, legs
from sims.following import lidar
from tests.perception import references

CFG = lidar.LaserConfig()
ANGLES32 = np.asarray(lidar.beam_angles(CFG), np.float32)
B = ANGLES32.shape[0]
RMAX = CFG.max_range
CAP = leg_dataset.DEFAULT_SEGMENTS
NC, NW = 8, 3                      # circle and wall capacity of the simulated scenes
LEG_R = 0.055

_segment = jax.jit(legs.segment, static_argnames=("max_segments",))
_compute = jax.jit(leg_features.compute)


# ---------------------------------------------------------------------------------------------
# Simulated scans


def _polar(r, bearing):
    return np.array([r * np.cos(bearing), r * np.sin(bearing)])


def _ranges(rng, legs_xy=(), posts=(), walls=(), noise=0.005):
    """One scan [B] float32 of circles (legs of radius LEG_R, posts (xy, radius)) and walls,
    misses inf."""
    circles = [(np.asarray(c), LEG_R) for c in legs_xy] + [(np.asarray(c), r) for c, r in posts]
    return references.laser_scan(rng, ANGLES32, circles, walls, RMAX, num_circles=NC,
                                 num_walls=NW, noise=noise)


def _random_scene(rng, legs_max=3, posts_max=3, walls_max=2):
    """Legs and posts at distinct bearings (no occlusion), walls behind them."""
    n_legs, n_posts = rng.integers(0, legs_max + 1), rng.integers(0, posts_max + 1)
    bearings = rng.permutation(np.linspace(-1.8, 1.8, 10))[: n_legs + n_posts]
    legs_xy = [_polar(rng.uniform(0.8, 3.5), b) for b in bearings[:n_legs]]
    posts = [(_polar(rng.uniform(0.8, 3.5), b), rng.uniform(0.02, 0.12))
             for b in bearings[n_legs:]]
    walls = []
    for _ in range(rng.integers(0, walls_max + 1)):
        d, a = rng.uniform(4.0, 5.2), rng.uniform(-2.0, 2.0)
        walls.append([_polar(d, a - 0.6), _polar(d, a + 0.6)])
    return legs_xy, posts, walls


def _scans(ranges, t0=100.0):
    ranges = np.asarray(ranges, np.float32)
    T = ranges.shape[0]
    return bags.LaserScans(t0 + 0.1 * np.arange(T), ranges, ANGLES32, np.isfinite(ranges),
                           0.02, RMAX, np.ones(T, bool))


# ---------------------------------------------------------------------------------------------
# read_labelled: pairing labels with scans in a bag


def _rewrite_label_stamps(src, dst, topic, stamp_sec):
    """Copy a ROS 1 bag, setting the header stamp of every ``topic`` message to ``stamp_sec``
    (the shared recordings' labels carry stamp 0); receive times unchanged."""
    from rosbags.rosbag1 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    with Reader(src) as reader, Writer(dst) as writer:
        conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=ts)
                 for c in reader.connections}
        for c, t, raw in reader.messages():
            if c.topic == topic:
                msg = ts.deserialize_ros1(raw, c.msgtype)
                stamp = dataclasses.replace(msg.header.stamp, sec=stamp_sec, nanosec=0)
                msg = dataclasses.replace(msg, header=dataclasses.replace(msg.header,
                                                                         stamp=stamp))
                raw = ts.serialize_ros1(msg, c.msgtype)
            writer.write(conns[c.id], t, raw)


PAIR_T = 7
PAIR_B = 40


def _pairing_records():
    rng = np.random.default_rng(3)
    times = 1000.0 + 0.1 * np.arange(PAIR_T)
    angles = bags.beam_angles(-1.0, 2.0 / (PAIR_B - 1), PAIR_B)
    ranges = rng.uniform(0.5, 5.0, (PAIR_T, PAIR_B)).astype(np.float32)
    mask = rng.uniform(size=(PAIR_T, PAIR_B)) < 0.8
    ranges = np.where(mask, ranges, np.float32(RMAX))
    laser = bags.LaserScans(times, ranges, angles, mask, 0.02, RMAX, np.ones(PAIR_T, bool))
    # Label messages: 1 ms before scan 0, 1 ms before scan 2, 50 ms before scan 3 (after scan
    # 2), 1 ms before scan 6 with no pose, and one after the last scan (labels nothing).
    # Scans 1, 4 and 5 have no label message before them.
    lt = np.array([times[0] - 1e-3, times[2] - 1e-3, times[3] - 0.05, times[6] - 1e-3,
                   times[6] + 0.05])
    counts = [2, 3, 1, 0, 2]
    M = 3
    xy = rng.normal(size=(len(lt), M, 2))
    lmask = np.arange(M)[None] < np.array(counts)[:, None]
    xy = np.where(lmask[..., None], xy, 0.0)
    det = bags.PersonDetections(lt, xy, lmask, np.ones(len(lt), bool))
    target = {0: 0, 1: 2, 2: 3, 3: 6}            # label message -> the scan it labels
    return laser, det, target


@pytest.fixture(scope="module")
def pairing_bags(tmp_path_factory):
    pytest.importorskip("rosbags")
    root = tmp_path_factory.mktemp("pairing")
    laser, det, target = _pairing_records()
    written = bags.write_bag(root / "stamped.bag", 1, laser=laser, detections=det,
                             detections_type=bags.POSE_ARRAY,
                             topics={"laser": "/training_scan",
                                     "detections": "/leg_cluster_positions"})
    zeroed = root / "zero_stamps.bag"
    _rewrite_label_stamps(written, zeroed, "/leg_cluster_positions", 0)
    return {"stamped": written, "zeroed": zeroed}, laser, det, target


@pytest.mark.parametrize("kind", ["stamped", "zeroed"])
def test_each_label_message_labels_the_first_scan_after_it(pairing_bags, kind):
    paths, laser, det, target = pairing_bags
    data = leg_dataset.read_labelled(paths[kind], max_labels=4)
    np.testing.assert_allclose(data.scans.times, laser.times, atol=1e-9)
    np.testing.assert_array_equal(data.scans.ranges, laser.ranges)
    assert data.labels.shape == (PAIR_T, 4, 2) and data.label_mask.shape == (PAIR_T, 4)
    want_xy = np.zeros((PAIR_T, 4, 2))
    want_mask = np.zeros((PAIR_T, 4), bool)
    for msg, scan in target.items():
        n = int(det.mask[msg].sum())
        want_xy[scan, :n] = det.xy[msg, :n]
        want_mask[scan, :n] = True
    np.testing.assert_array_equal(data.label_mask, want_mask)
    np.testing.assert_array_equal(data.labels, want_xy)
    # Scans 1, 4, 5 (no label message before them) and 6 (an empty one) have no label.
    assert not data.label_mask[[1, 4, 5, 6]].any()
    assert data.name == f"{paths[kind]}:/training_scan"


def test_max_labels_keeps_the_first_labels_of_a_message(pairing_bags):
    paths, laser, det, _ = pairing_bags
    data = leg_dataset.read_labelled(paths["stamped"], max_labels=1)
    assert data.labels.shape == (PAIR_T, 1, 2)
    np.testing.assert_array_equal(data.label_mask[:, 0],
                                  [True, False, True, True, False, False, False])
    np.testing.assert_array_equal(data.labels[[0, 2, 3], 0], det.xy[[0, 1, 2], 0])


def test_read_unlabelled_has_no_labels(pairing_bags):
    paths, laser, _, _ = pairing_bags
    data = leg_dataset.read_unlabelled(paths["stamped"], "/training_scan")
    assert data.labels.shape == (PAIR_T, 1, 2) and not data.label_mask.any()
    np.testing.assert_array_equal(data.scans.ranges, laser.ranges)


def test_a_missing_labels_topic_is_a_bag_error_naming_it(pairing_bags):
    paths, _, _, _ = pairing_bags
    with pytest.raises(bags.BagError, match="/no_such_labels"):
        leg_dataset.read_labelled(paths["stamped"], labels_topic="/no_such_labels")


# ---------------------------------------------------------------------------------------------
# segment_dataset against a scan-by-scan numpy labelling


SEG_T = 67            # over one chunk of 64 scans
SEG_K = 6
RADIUS = 0.15
JUMP = 0.13


def _reference_segments(ranges):
    """Per scan: (first, last, num_points, mean [S, 2] float64, X [S, F]) of the kept segments,
    and the scan's dropped count, from `legs.segment` and numpy means of the points."""
    out = []
    a = ANGLES32.astype(np.float64)
    for r in ranges:
        segs = _segment(jnp.asarray(r), jnp.asarray(ANGLES32), RMAX, jump=JUMP,
                        max_segments=CAP)
        X = np.asarray(_compute(jnp.asarray(r, jnp.float64), jnp.asarray(a), segs, RMAX))
        labels = np.asarray(segs.labels)
        r64 = np.asarray(r, np.float64)
        r64 = np.where(np.isfinite(r64) & (r64 < RMAX), r64, 0.0)
        xy = np.stack([r64 * np.cos(a), r64 * np.sin(a)], -1)
        n = int(np.asarray(segs.mask).sum())
        means = np.array([xy[labels == s].mean(0) for s in range(n)]).reshape(n, 2)
        counts = np.array([np.sum(labels == s) for s in range(n)], int)
        out.append((means, counts, X[:n], int(segs.dropped)))
    return out


def _reference_y(means, labels, label_mask, radius):
    y = np.zeros(len(means), int)
    for lab, m in zip(labels, label_mask):
        if not m or len(means) == 0:
            continue
        d = np.hypot(*(means - lab).T)
        j = int(np.argmin(d))
        if d[j] <= radius:
            y[j] = 1
    return y


@pytest.fixture(scope="module")
def segment_case():
    rng = np.random.default_rng(11)
    ranges = [_ranges(rng, *_random_scene(rng)) for _ in range(SEG_T - 3)]
    # Two legs side by side (two segments near each label), a fence of one-return segments
    # beyond the capacity, and an empty scan.
    ranges.append(_ranges(rng, [_polar(1.5, 0.0), _polar(1.5, 0.09)]))
    picket = np.where(np.arange(B) % 2 == 0, 2.0, np.inf).astype(np.float32)
    ranges += [picket, np.full(B, np.inf, np.float32)]
    ranges = np.stack(ranges)
    ref = _reference_segments(ranges)
    labels = rng.uniform(-4, 4, (SEG_T, SEG_K, 2))
    mask = np.zeros((SEG_T, SEG_K), bool)
    for t, (means, *_rest) in enumerate(ref):
        for k in range(SEG_K):
            kind = rng.integers(0, 4)
            if kind < 3 and len(means):          # near a segment mean, inside or outside
                j = rng.integers(len(means))
                off = rng.uniform(0.0, 0.25) * rng.choice([0.3, 1.0])
                labels[t, k] = means[j] + off * np.array([np.cos(k), np.sin(k)])
                mask[t, k] = kind < 2             # kind 2: masked, right on a segment
            else:
                mask[t, k] = rng.uniform() < 0.5  # random position, often far from any
            if mask[t, k] and len(means):        # no label on a tie (of distance or radius)
                d = np.sort(np.hypot(*(means - labels[t, k]).T))
                tie = abs(d[0] - RADIUS) < 1e-4 or (len(d) > 1 and d[1] - d[0] < 1e-4)
                mask[t, k] &= not tie
    # The two-leg scan: one label between the legs but nearer the first, one on the second.
    t2 = SEG_T - 3
    means2 = ref[t2][0]
    assert len(means2) == 2
    labels[t2, :2] = [0.6 * means2[0] + 0.4 * means2[1], means2[1]]
    mask[t2, :2], mask[t2, 2:] = True, False
    data = leg_dataset.LabelledScans(_scans(ranges), labels, mask, "sim")
    return data, ref


def test_segment_dataset_equals_the_scan_by_scan_labelling(segment_case):
    data, ref = segment_case
    seg = leg_dataset.segment_dataset(data, jump=JUMP, match_radius=RADIUS)
    scan = np.concatenate([np.full(len(m), t) for t, (m, *_r) in enumerate(ref)])
    means = np.concatenate([m for m, *_r in ref])
    counts = np.concatenate([c for _m, c, *_r in ref])
    X = np.concatenate([x for _m, _c, x, _d in ref])
    y = np.concatenate([_reference_y(m, data.labels[t], data.label_mask[t], RADIUS)
                        for t, (m, *_r) in enumerate(ref)])
    np.testing.assert_array_equal(seg.scan, scan)
    np.testing.assert_allclose(seg.mean, means, atol=2e-5)
    np.testing.assert_array_equal(seg.y, y)
    assert seg.X.shape == (len(y), leg_features.NUM_FEATURES) and seg.X.dtype == np.float64
    np.testing.assert_array_equal(seg.X[:, 0], counts)
    # Features of the same segments (float32 in the dataset, float64 in the reference).
    stable = [k for k, n in enumerate(leg_features.FEATURE_NAMES)
              if n not in ("linearity", "circularity", "radius", "mean_curvature",
                           "mean_angular_difference")]
    err = np.abs(seg.X[:, stable] - X[:, stable]) / (1 + np.abs(X[:, stable]))
    assert err.max() < 1e-4
    assert seg.dropped == sum(d for *_r, d in ref) == B // 2 + 1 - CAP
    # The case is not trivial: legs and non-legs, labels outside the radius and masked ones.
    assert 20 < y.sum() < len(y) - 100
    t2 = SEG_T - 3
    np.testing.assert_array_equal(seg.y[seg.scan == t2], [1, 1])
    assert not np.any(seg.scan == SEG_T - 1)           # the empty scan has no segment


def test_misses_as_range_max_and_unlabelled_segments(segment_case):
    data, _ = segment_case
    seg = leg_dataset.segment_dataset(data, jump=JUMP, match_radius=RADIUS)
    s = data.scans
    at_max = data._replace(scans=s._replace(ranges=np.where(np.isfinite(s.ranges), s.ranges,
                                                            np.float32(RMAX))))
    seg2 = leg_dataset.segment_dataset(at_max, jump=JUMP, match_radius=RADIUS)
    for a, b in zip(seg, seg2):
        np.testing.assert_array_equal(a, b)
    free = leg_dataset.segment_dataset(data, jump=JUMP, match_radius=RADIUS, labelled=False)
    assert np.all(free.y == -1)
    np.testing.assert_array_equal(free.X, seg.X)
    np.testing.assert_array_equal(free.scan, seg.scan)
    # A larger radius labels a superset of the segments.
    wide = leg_dataset.segment_dataset(data, jump=JUMP, match_radius=0.3)
    assert np.all(wide.y >= seg.y) and wide.y.sum() > seg.y.sum()


@pytest.mark.parametrize("radius", [0.0, -0.1, float("nan")])
def test_segment_dataset_rejects_a_bad_match_radius(segment_case, radius):
    with pytest.raises(ValueError, match="match_radius"):
        leg_dataset.segment_dataset(segment_case[0], match_radius=radius)


# ---------------------------------------------------------------------------------------------
# match_counts against scipy


def _reference_counts(det, dmask, lab, lmask, radius):
    """Min-cost assignment of labels to detections, a label unassigned at cost ``radius``,
    pairs beyond ``radius`` forbidden (scipy on the matrix augmented with dummy columns)."""
    L, D = lab[lmask], det[dmask]
    nl, nd = len(L), len(D)
    if nl == 0 or nd == 0:
        return 0, nd, nl
    d = np.hypot(*(L[:, None] - D[None]).transpose(2, 0, 1))
    big = 1e6
    cost = np.full((nl, nd + nl), big)
    cost[:, :nd] = np.where(d <= radius, d, big)
    cost[np.arange(nl), nd + np.arange(nl)] = radius
    rows, cols = linear_sum_assignment(cost)
    tp = int(np.sum((cols < nd) & (cost[rows, cols] < big)))
    return tp, nd - tp, nl - tp


def _random_matching(rng, T=200, S=6, K=5):
    lab = rng.uniform(0, 1, (T, K, 2))
    det = rng.uniform(0, 1, (T, S, 2))
    near = rng.uniform(size=(T, S)) < 0.6            # detections near a label: conflicts
    src = rng.integers(0, K, (T, S))
    det = np.where(near[..., None], lab[np.arange(T)[:, None], src]
                   + rng.normal(0, 0.09, (T, S, 2)), det)
    nl, nd = rng.integers(0, K + 1, T), rng.integers(0, S + 1, T)
    nl[:4], nd[:4] = [0, 0, 3, K], [0, 4, 0, S]      # empty scans of each kind
    # Masks: not a prefix, so the mask is honoured and not the slot order.
    lmask = np.argsort(rng.uniform(size=(T, K)), 1) < nl[:, None]
    dmask = np.argsort(rng.uniform(size=(T, S)), 1) < nd[:, None]
    return det, dmask, lab, lmask


@pytest.mark.parametrize("radius", [0.15, 0.3])
def test_match_counts_equal_the_scipy_assignment(radius):
    rng = np.random.default_rng(int(radius * 100))
    det, dmask, lab, lmask = _random_matching(rng)
    tp, fp, fn = leg_dataset.match_counts(det, dmask, lab, lmask, radius)
    ref = np.array([_reference_counts(det[t], dmask[t], lab[t], lmask[t], radius)
                    for t in range(len(det))])
    assert tp.dtype == np.int64 and tp.shape == (len(det),)
    np.testing.assert_array_equal(np.stack([tp, fp, fn], 1), ref)
    # Not trivial: many matches, many unmatched labels and detections.
    assert ref[:, 0].sum() > 100 and ref[:, 1].sum() > 50 and ref[:, 2].sum() > 50
    np.testing.assert_array_equal(tp + fp, dmask.sum(1))
    np.testing.assert_array_equal(tp + fn, lmask.sum(1))


def test_match_counts_minimise_the_distance_not_the_matches():
    # Labels l1 = (0, 0), l2 = (0.15, 0); detections d1 = (0.01, 0) (0.01 from l1, 0.14 from
    # l2) and d2 = (-0.13, 0.05) (0.139 from l1, beyond l2). Two matches cost 0.279; l1-d1 and
    # l2 unmatched cost 0.01 + 0.15 = 0.16: one match.
    lab = np.array([[[0.0, 0.0], [0.15, 0.0]]])
    det = np.array([[[0.01, 0.0], [-0.13, 0.05]]])
    ones = np.ones((1, 2), bool)
    got = leg_dataset.match_counts(det, ones, lab, ones, 0.15)
    assert [int(v[0]) for v in got] == [1, 1, 1] == list(_reference_counts(det[0], ones[0],
                                                                            lab[0], ones[0],
                                                                            0.15))
    # Greedy nearest would take l2-d1 (0.14) first... the optimum pairs l2 with d2 here.
    lab = np.array([[[0.0, 0.0], [0.2, 0.0]]])
    det = np.array([[[0.1, 0.0], [0.28, 0.0]]])
    assert [int(v[0]) for v in leg_dataset.match_counts(det, ones, lab, ones, 0.15)] == [2, 0, 0]


def test_match_counts_of_empty_shapes():
    z = leg_dataset.match_counts(np.zeros((0, 3, 2)), np.zeros((0, 3), bool),
                                 np.zeros((0, 2, 2)), np.zeros((0, 2), bool))
    assert all(v.shape == (0,) for v in z)
    lmask = np.array([[True, False, True], [False, False, False]])
    tp, fp, fn = leg_dataset.match_counts(np.zeros((2, 0, 2)), np.zeros((2, 0), bool),
                                          np.ones((2, 3, 2)), lmask)
    assert tp.tolist() == [0, 0] and fp.tolist() == [0, 0] and fn.tolist() == [2, 0]
    dmask = np.array([[True, True], [False, True]])
    tp, fp, fn = leg_dataset.match_counts(np.zeros((2, 2, 2)), dmask, np.zeros((2, 0, 2)),
                                          np.zeros((2, 0), bool))
    assert tp.tolist() == [0, 0] and fp.tolist() == [2, 1] and fn.tolist() == [0, 0]
    tp, fp, fn = leg_dataset.match_counts(np.zeros((3, 0, 2)), np.zeros((3, 0), bool),
                                          np.zeros((3, 0, 2)), np.zeros((3, 0), bool))
    assert tp.tolist() == fp.tolist() == fn.tolist() == [0, 0, 0]


@pytest.mark.parametrize("radius", [0.0, -1.0, float("nan")])
def test_match_counts_rejects_a_bad_radius(radius):
    with pytest.raises(ValueError, match="radius"):
        leg_dataset.match_counts(np.zeros((1, 1, 2)), np.ones((1, 1), bool),
                                 np.zeros((1, 1, 2)), np.ones((1, 1), bool), radius)


# ---------------------------------------------------------------------------------------------
# best_f1_threshold against every threshold


def _f1_at(scores, y, t):
    """Exact (precision, recall, F1) of ``scores >= t``."""
    pred = scores >= t
    tp, n, pos = int(np.sum(pred & (y == 1))), int(pred.sum()), int(np.sum(y == 1))
    if tp == 0:
        return Fraction(0), Fraction(0), Fraction(0)
    return Fraction(tp, n), Fraction(tp, pos), Fraction(2 * tp, n + pos)


@pytest.mark.parametrize("seed", range(12))
def test_best_f1_threshold_is_the_best_of_every_threshold(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(5, 80))
    y = (rng.uniform(size=n) < rng.uniform(0.1, 0.6)).astype(int)
    scores = np.clip(0.35 * y + rng.uniform(0, 0.7, n), 0, 1)
    if seed % 2:                                       # many ties
        scores = np.round(scores, 1)
    if not y.any():
        y[0] = 1
    t, p, r = leg_dataset.best_f1_threshold(scores, y)
    assert t in scores
    best = max(_f1_at(scores, y, s)[2] for s in np.unique(scores))
    pe, re, fe = _f1_at(scores, y, t)
    assert fe == best
    assert p == pytest.approx(float(pe), abs=1e-12) and r == pytest.approx(float(re), abs=1e-12)


def test_best_f1_threshold_does_not_split_tied_scores():
    # Cutting inside the run of 0.5s (the leg sorted first) would give F1 = 1; a threshold of
    # 0.5 takes all four (F1 4/7), 0.9 only the first (F1 2/3).
    scores = np.array([0.5, 0.9, 0.5, 0.5, 0.5])
    y = np.array([1, 1, 0, 0, 0])
    assert leg_dataset.best_f1_threshold(scores, y) == (0.9, 1.0, 0.5)
    scores = np.array([0.9, 0.5, 0.5])
    y = np.array([1, 1, 0])
    t, p, r = leg_dataset.best_f1_threshold(scores, y)
    assert (t, r) == (0.5, 1.0) and p == pytest.approx(2 / 3)


def test_best_f1_threshold_without_legs_scores_zero():
    t, p, r = leg_dataset.best_f1_threshold(np.array([0.2, 0.7, 0.7]), np.zeros(3, int))
    assert (p, r) == (0.0, 0.0) and t in (0.2, 0.7)


# ---------------------------------------------------------------------------------------------
# train on simulated recordings


TRAIN_T = 14


def _leg_recording(seed, name, walls=True):
    """Scans of two legs (at distinct bearings, 1-3 m) and posts and walls, labelled at the leg
    centres (within a few cm of their segments' mean points)."""
    rng = np.random.default_rng(seed)
    ranges, labels = [], np.zeros((TRAIN_T, 3, 2))
    mask = np.zeros((TRAIN_T, 3), bool)
    for t in range(TRAIN_T):
        b = rng.permutation(np.linspace(-1.5, 1.5, 8))
        legs_xy = [_polar(rng.uniform(1.0, 3.0), b[0]), _polar(rng.uniform(1.0, 3.0), b[1])]
        posts = [(_polar(rng.uniform(1.0, 3.0), b[2]), rng.uniform(0.12, 0.2))]
        wall = [[_polar(5.0, -0.7), _polar(5.0, 0.7)]] if walls else []     # 3.8 m ahead
        ranges.append(_ranges(rng, legs_xy, posts if walls else (), wall))
        labels[t, :2], mask[t, :2] = legs_xy, True
    return leg_dataset.LabelledScans(_scans(ranges), labels, mask, name)


def _negative_recording(seed):
    rng = np.random.default_rng(seed)
    ranges = []
    for _ in range(TRAIN_T):
        b = rng.permutation(np.linspace(-1.5, 1.5, 8))
        posts = [(_polar(rng.uniform(1.0, 3.5), b[i]), rng.uniform(0.1, 0.25)) for i in range(3)]
        posts.append((_polar(rng.uniform(1.0, 3.0), b[3]), rng.uniform(0.04, 0.07)))  # leg-like
        walls = [[_polar(rng.uniform(4.5, 5.0), -0.7), _polar(rng.uniform(4.5, 5.0), 0.7)],
                 [_polar(1.2, 2.0), _polar(3.0, 1.9)]]
        ranges.append(_ranges(rng, (), posts, walls))
    T = len(ranges)
    return leg_dataset.LabelledScans(_scans(ranges), np.zeros((T, 1, 2)),
                                     np.zeros((T, 1), bool), "negative")


@pytest.fixture(scope="module")
def recordings():
    pytest.importorskip("sklearn")
    return [_leg_recording(20, "pos0"), _leg_recording(21, "pos1")], [_negative_recording(30)]


TRAIN_KW = dict(n_estimators=8, max_depth=5, seed=3)


def _candidates(X, y):
    """The segments the model evaluates at all: 3 points or more, at most 1.5 times the widest
    leg wide (float32, as the model holds them); the others' held-out predictions count as 0."""
    X32 = X.astype(np.float32)
    return (X32[:, 0] >= 3) & (X32[:, 1] <= np.float32(1.5 * X[y == 1, 1].max()))


def test_training_set_labels_every_leg_once(recordings):
    positive, negative = recordings
    X, y, rec, scans, dropped = leg_dataset.training_set(positive, negative)
    assert scans == 3 * TRAIN_T and dropped == 0
    assert y.sum() == 2 * 2 * TRAIN_T                    # both legs of every positive scan
    assert np.all(y[rec == 2] == 0) and set(np.unique(rec)) == {0, 1, 2}
    assert X.shape == (len(y), leg_features.NUM_FEATURES) and np.all(np.isfinite(X))


def test_train_with_held_out_recordings_follows_its_definition(recordings):
    from sklearn.ensemble import RandomForestClassifier

    from jaxtrack.perception import leg_classifier

    positive, negative = recordings
    model, report = leg_dataset.train(positive, negative, **TRAIN_KW)
    X, y, rec, scans, dropped = leg_dataset.training_set(positive, negative)
    assert isinstance(model, leg_classifier.LegClassifier)
    assert report.sources == ("pos0", "pos1", "negative")
    assert (report.num_segments, report.num_legs, report.num_scans, report.dropped) == (
        len(y), int(y.sum()), scans, dropped)
    assert 0.0 < float(model.decision) < 1.0
    assert float(model.decision) == pytest.approx(report.decision, abs=1e-7)
    # Two folds: pos0 and the negative recording, then pos1, each predicted by a forest fitted
    # on the other; the threshold of best F1 on those predictions.
    fold = np.array([0, 1, 0])[rec]
    held = np.zeros(len(y))
    for f in (0, 1):
        forest = RandomForestClassifier(n_estimators=8, max_depth=5, min_samples_leaf=2,
                                        random_state=3, n_jobs=1).fit(X[fold != f], y[fold != f])
        held[fold == f] = forest.predict_proba(X[fold == f])[:, 1]
    held = np.where(_candidates(X, y), held, 0.0)
    assert (report.decision, report.held_out_precision, report.held_out_recall) == \
        leg_dataset.best_f1_threshold(held, y)
    assert 0.5 < report.held_out_recall <= 1.0 and 0.5 < report.held_out_precision <= 1.0
    # The final forest is fitted on everything.
    full = RandomForestClassifier(n_estimators=8, max_depth=5, min_samples_leaf=2,
                                  random_state=3, n_jobs=1).fit(X, y)
    p = np.asarray(leg_classifier.predict_proba(model, jnp.asarray(X)))
    np.testing.assert_allclose(p, full.predict_proba(X)[:, 1], atol=1e-6)


@pytest.mark.filterwarnings("ignore:Some inputs do not have OOB scores")
def test_train_with_one_positive_recording_uses_out_of_bag_predictions(recordings):
    from sklearn.ensemble import RandomForestClassifier

    positive, negative = recordings
    model, report = leg_dataset.train(positive[:1], negative, **TRAIN_KW)
    X, y, _, _, _ = leg_dataset.training_set(positive[:1], negative)
    forest = RandomForestClassifier(n_estimators=8, max_depth=5, min_samples_leaf=2,
                                    random_state=3, n_jobs=1, oob_score=True).fit(X, y)
    held = np.where(_candidates(X, y), np.nan_to_num(forest.oob_decision_function_[:, 1]), 0.0)
    assert (report.decision, report.held_out_precision, report.held_out_recall) == \
        leg_dataset.best_f1_threshold(held, y)
    assert report.num_legs == int(y.sum()) == 2 * TRAIN_T and 0 < report.decision < 1


def test_train_refuses_recordings_without_legs_or_non_legs(recordings):
    positive, negative = recordings
    with pytest.raises(ValueError, match="positive"):
        leg_dataset.train([], negative, **TRAIN_KW)
    far = positive[0]._replace(labels=positive[0].labels + 50.0)     # no segment near a label
    with pytest.raises(ValueError, match="0 leg segments"):
        leg_dataset.train([far], negative, **TRAIN_KW)
    only_legs = _leg_recording(22, "legs only", walls=False)          # every segment a leg
    X, y, *_ = leg_dataset.training_set([only_legs], [])
    assert y.all() and len(y) == 2 * TRAIN_T
    with pytest.raises(ValueError, match="both legs and non-legs"):
        leg_dataset.train([only_legs], [], **TRAIN_KW)
