"""Simulated detections from trajectories: detection rate, noise covariance and clutter count
against the model by Monte-Carlo tests over many keys, field of view, fixed shapes, bad input,
and the tracker run end to end on detections of a trajectory file."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from jaxtrack import metrics, tracking
from jaxtrack.io import synthetic as sy
from jaxtrack.io import trajectories as tj

T, P, M = 10, 4, 20
NUM_KEYS = 400
REGION = np.array([[0.0, 0.0], [10.0, 6.0]])
ORIGIN = np.zeros(3)
Z_MAX = 4.5  # two-sided z bound: a false alarm about once in 150 000 checks


def people(dtype):
    """[T, P, 2] positions of four people inside REGION; person 3 absent in the first half."""
    t = np.arange(T)[:, None]
    pos = np.stack([1.0 + 0.3 * t + np.arange(P), 1.0 + 0.1 * t + np.arange(P)], -1)
    mask = np.ones((T, P), bool)
    mask[:T // 2, 3] = False
    pos[~mask] = np.nan  # absent people may carry NaN
    return jnp.asarray(pos, dtype), jnp.asarray(mask)


@jax.jit
def _batch_region(keys, pos, mask, model):
    return jax.vmap(lambda k: sy.detections(k, pos, mask, model, M, region=REGION))(keys)


@jax.jit
def _batch_pose(keys, pos, mask, model, pose):
    return jax.vmap(lambda k: sy.detections(k, pos, mask, model, M, sensor_pose=pose))(keys)


def keys(seed=0, n=NUM_KEYS):
    return jax.random.split(jax.random.key(seed), n)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_rate_noise_and_clutter_match_the_model(dtype):
    pd, std, rate = 0.7, 0.3, 3.0
    model = sy.SensorModel.create(noise_std=std, p_detect=pd, clutter_rate=rate, dtype=dtype)
    pos, mask = people(dtype)
    det = jax.device_get(_batch_region(keys(), pos, mask, model))
    assert det.z.dtype == dtype and det.z.shape == (NUM_KEYS, T, M, 2)
    assert np.all(det.num_dropped == 0)
    src, valid = det.source, det.mask
    assert np.all(src[~valid] == -1) and np.all(det.z[~valid] == 0)

    # Detection rate: each present person detected at most once per frame, with probability pd.
    counts = np.stack([np.sum(valid & (src == p), -1) for p in range(P)], -1)  # [N, T, P]
    assert counts.max() <= 1
    assert np.all(counts[:, ~np.asarray(mask)] == 0)  # absent people are never detected
    n = NUM_KEYS * int(mask.sum())
    hits = int(counts.sum())
    assert abs(hits / n - pd) / np.sqrt(pd * (1 - pd) / n) < Z_MAX

    # Noise: residuals of person detections ~ N(0, std^2 I).
    truth = np.asarray(pos, np.float64)
    person = valid & (src >= 0)
    frame_idx = np.broadcast_to(np.arange(T)[None, :, None], src.shape)
    res = det.z[person].astype(np.float64) - truth[frame_idx[person], src[person]]
    k = len(res)
    assert k == hits
    assert np.all(np.abs(res.mean(0)) / (std / np.sqrt(k)) < Z_MAX)
    for axis in range(2):
        stat = (k - 1) * res[:, axis].var(ddof=1) / std**2
        p_value = 2 * min(stats.chi2.cdf(stat, k - 1), stats.chi2.sf(stat, k - 1))
        assert p_value > 1e-5, (axis, stat / (k - 1))
    assert abs(np.corrcoef(res.T)[0, 1]) * np.sqrt(k) < Z_MAX

    # Clutter: Poisson(rate) per frame, all kept (the region is in view), uniform in REGION.
    num = det.num_clutter.ravel().astype(np.float64)
    assert abs(num.mean() - rate) / np.sqrt(rate / num.size) < Z_MAX
    # Poisson dispersion: variance equals the mean
    disp = num.var(ddof=1) * (num.size - 1) / num.mean()
    assert stats.chi2.sf(disp, num.size - 1) > 1e-5 and stats.chi2.cdf(disp, num.size - 1) > 1e-5
    np.testing.assert_array_equal(np.sum(valid & (src == -1), -1), det.num_clutter)
    clutter = det.z[valid & (src == -1)].astype(np.float64)
    assert np.all((clutter >= REGION[0]) & (clutter <= REGION[1]))
    size = REGION[1] - REGION[0]
    z_mean = (clutter.mean(0) - REGION.mean(0)) / (size / np.sqrt(12 * len(clutter)))
    assert np.all(np.abs(z_mean) < Z_MAX)


def test_slot_order_carries_no_identity():
    model = sy.SensorModel.create(noise_std=0.1, p_detect=1.0, clutter_rate=0.0)
    pos, mask = people(jnp.float64)
    det = jax.device_get(_batch_region(keys(1), pos, mask, model))
    # frames with all four people: the slot of person 0 is uniform over the four valid slots
    full = det.source[:, T // 2:]
    assert np.all(np.sort(full[..., :P], -1) == np.arange(P))
    slot = np.argmax(full == 0, -1).ravel()
    observed = np.bincount(slot, minlength=P)
    assert stats.chisquare(observed).pvalue > 1e-5, observed


def test_field_of_view_range_and_sector_clutter():
    model = sy.SensorModel.laser(p_detect=1.0, clutter_rate=2.0)
    pose = jnp.tile(jnp.array([1.0, 1.0, 0.5]), (T, 1))  # a sensor pose per frame
    # four people: in view; behind the sensor (outside 240 deg); beyond 5.6 m; inside 0.1 m
    heading = np.array([np.cos(0.5), np.sin(0.5)])
    behind = -np.array([np.cos(0.5 + 0.3), np.sin(0.5 + 0.3)])
    spots = np.array([[1, 1] + 2.0 * heading, [1, 1] + 1.5 * behind,
                      [1, 1] + 6.0 * heading, [1, 1] + 0.05 * heading])
    pos = jnp.asarray(np.broadcast_to(spots, (T, P, 2)))
    mask = jnp.ones((T, P), bool)
    det = jax.device_get(_batch_pose(keys(2, 200), pos, mask, model, pose))
    seen = [np.any(det.mask & (det.source == p)) for p in range(P)]
    assert seen == [True, False, False, False]
    assert np.all(np.sum(det.mask & (det.source == 0), -1) == 1)
    # clutter fills the sector around the sensor: in range and within +-120 deg of its heading
    clutter = det.z[det.mask & (det.source == -1)] - np.array([1.0, 1.0])
    r = np.hypot(clutter[:, 0], clutter[:, 1])
    bearing = np.angle(np.exp(1j * (np.arctan2(clutter[:, 1], clutter[:, 0]) - 0.5)))
    assert np.all((r >= 0.1 - 1e-9) & (r <= 5.6 + 1e-9))
    assert np.all(np.abs(bearing) <= np.radians(120) + 1e-9)
    # uniform over the sector's area: P(r <= 3) = (3^2 - 0.1^2) / (5.6^2 - 0.1^2)
    n, frac = len(r), (9 - 0.01) / (5.6**2 - 0.01)
    assert abs(np.mean(r <= 3) - frac) / np.sqrt(frac * (1 - frac) / n) < Z_MAX
    assert abs(det.num_clutter.mean() - 2.0) / np.sqrt(2.0 / det.num_clutter.size) < Z_MAX
    np.testing.assert_array_equal(np.sum(det.mask & (det.source == -1), -1), det.num_clutter)


def test_clutter_in_a_region_is_cut_to_the_field_of_view():
    model = sy.SensorModel.rgbd(clutter_rate=15.0)
    pose = np.array([0.0, 3.0, 0.0])  # on REGION's left edge, facing +x
    pos, mask = people(jnp.float64)
    det = jax.device_get(sy.detections(jax.random.key(3), pos, mask, model, M, region=REGION,
                                       sensor_pose=pose))
    clutter = det.z[det.mask & (det.source == -1)] - pose[:2]
    assert 0 < len(clutter) < det.num_clutter.sum()
    r = np.hypot(clutter[:, 0], clutter[:, 1])
    assert np.all((r >= 0.5) & (r <= 4.5))
    assert np.all(np.abs(np.arctan2(clutter[:, 1], clutter[:, 0])) <= np.radians(28.5) + 1e-9)


def test_capacity_keeps_a_random_subset_and_counts_the_rest():
    model = sy.SensorModel.create(p_detect=1.0, clutter_rate=40.0)
    pos, mask = people(jnp.float64)
    det = jax.device_get(sy.detections(jax.random.key(4), pos, mask, model, M, region=REGION,
                                       sensor_pose=ORIGIN))
    assert det.mask.all() and np.all(det.num_dropped > 0)
    produced = np.asarray(mask).sum(1) + det.num_clutter
    np.testing.assert_array_equal(det.num_dropped, produced - M)
    # people are kept in proportion: each kept detection is a person with probability
    # people / produced
    kept_people = np.sum(det.source >= 0, 1)
    expected = M * np.asarray(mask).sum(1) / produced
    z = (kept_people.sum() - expected.sum()) / np.sqrt(np.sum(expected * (1 - expected / M)))
    assert abs(z) < Z_MAX


def test_one_frame_step_and_keys():
    model = sy.SensorModel.create(noise_std=0.0, p_detect=1.0, clutter_rate=2.0)
    pos, mask = people(jnp.float64)
    t = 7
    one = jax.device_get(sy.detect(jax.random.key(5), pos[t], mask[t], model, M, region=REGION,
                                   sensor_pose=ORIGIN))
    assert one.z.shape == (M, 2) and one.num_clutter.shape == ()
    person = one.mask & (one.source >= 0)
    np.testing.assert_array_equal(np.sort(one.source[person]), np.arange(P))
    np.testing.assert_array_equal(one.z[person], np.asarray(pos[t])[one.source[person]])
    assert np.sum(one.mask & (one.source == -1)) == one.num_clutter
    again = sy.detect(jax.random.key(5), pos[t], mask[t], model, M, region=REGION,
                      sensor_pose=ORIGIN)
    np.testing.assert_array_equal(again.z, one.z)
    seq = sy.detections(jax.random.key(5), pos, mask, model, M, region=REGION,
                        sensor_pose=ORIGIN)
    other = sy.detections(jax.random.key(6), pos, mask, model, M, region=REGION,
                          sensor_pose=ORIGIN)
    assert not np.array_equal(other.z, seq.z)


def test_default_sensor_sees_everyone_and_clutter_fills_the_padded_bounding_box():
    pos, mask = people(jnp.float32)
    model = sy.SensorModel.create(p_detect=1.0, noise_std=0.0, clutter_rate=3.0)
    det = jax.device_get(sy.detections(jax.random.key(7), pos, mask, model, M))
    assert det.z.dtype == jnp.float32
    people_ = det.mask & (det.source >= 0)
    np.testing.assert_array_equal(np.sum(people_, 1), np.sum(mask, 1))
    truth = np.asarray(pos)
    for t in range(T):
        np.testing.assert_array_equal(det.z[t][people_[t]], truth[t, det.source[t][people_[t]]])
    present = truth[np.asarray(mask)]
    lo, hi = present.min(0) - 1.0, present.max(0) + 1.0
    clutter = det.z[det.mask & (det.source == -1)]
    assert len(clutter) == det.num_clutter.sum() > 0
    assert np.all((clutter >= lo - 1e-6) & (clutter <= hi + 1e-6))


def test_to_tracker_merges_sensors_in_argument_order():
    pos, mask = people(jnp.float64)
    a = sy.detections(jax.random.key(8), pos, mask, sy.SensorModel.ceiling_camera(), M,
                      region=REGION, sensor_pose=ORIGIN)
    b = sy.detections(jax.random.key(9), pos, mask, sy.SensorModel.create(), M, region=REGION,
                      sensor_pose=ORIGIN)
    det = sy.to_tracker(a, b)
    assert det.positions.shape == (T, 2 * M, 2) and det.features.shape == (T, 2 * M, 0)
    np.testing.assert_array_equal(det.sensor[0], [0] * M + [1] * M)
    np.testing.assert_array_equal(det.mask[:, M:], b.mask)
    np.testing.assert_array_equal(det.positions[:, :M], a.z)


@pytest.mark.parametrize("kwargs, message", [
    (dict(p_detect=1.5), r"p_detect must be in \[0, 1\]"),
    (dict(p_detect=-0.1), r"p_detect must be in \[0, 1\]"),
    (dict(noise_std=-0.1), r"noise_std must be >= 0"),
    (dict(clutter_rate=-1.0), r"clutter_rate must be >= 0"),
    (dict(min_range=2.0, max_range=1.0), r"max_range must be > min_range"),
    (dict(fov=0.0), r"fov must be > 0"),
])
def test_bad_model_values_raise(kwargs, message):
    with pytest.raises(ValueError, match=message):
        sy.SensorModel.create(**kwargs)
    # the same checks guard a model built by hand
    model = sy.SensorModel.create()._replace(**{k: jnp.asarray(v) for k, v in kwargs.items()})
    pos, mask = people(jnp.float64)
    with pytest.raises(ValueError, match=message):
        sy.detections(jax.random.key(0), pos, mask, model, M)


def test_bad_inputs_raise_clearly():
    pos, mask = people(jnp.float64)
    model = sy.SensorModel.create()
    key = jax.random.key(0)
    with pytest.raises(ValueError, match=r"traj_pos must be \[T, P, 2\]"):
        sy.detections(key, pos[0], mask, model, M)
    with pytest.raises(ValueError, match=r"traj_mask must have shape \[10, 4\]"):
        sy.detections(key, pos, mask[:, :2], model, M)
    with pytest.raises(ValueError, match="mask must be bools"):
        sy.detections(key, pos, mask.astype(int), model, M)
    with pytest.raises(ValueError, match="NaN or inf where the mask is True"):
        sy.detections(key, pos, jnp.ones((T, P), bool), model, M)
    with pytest.raises(ValueError, match="max_detections must be a positive int"):
        sy.detections(key, pos, mask, model, 0)
    with pytest.raises(ValueError, match="region must be finite with max > min"):
        sy.detections(key, pos, mask, model, M, region=REGION[::-1])
    with pytest.raises(ValueError, match=r"sensor_pose must have shape \[3\]"):
        sy.detections(key, pos, mask, model, M, sensor_pose=jnp.zeros(2))
    with pytest.raises(ValueError, match=r"sensor_pose must have shape \[10, 3\]"):
        sy.detections(key, pos, mask, model, M, sensor_pose=jnp.zeros((3, 3)))
    with pytest.raises(TypeError, match="SensorModel"):
        sy.detections(key, pos, mask, (0.1, 0.9, 0.0), M)
    with pytest.raises(ValueError, match="PRNG key"):
        sy.detections(1234, pos, mask, model, M)
    with pytest.raises(ValueError, match=r"pos must have shape \[4, 2\]"):
        sy.detect(key, pos[0, :, :1], mask[0], model, M)


# ---------------------------------------------------------------------------------------------
# End to end: trajectory file -> detections -> tracker -> CLEAR MOT

DT, T_RUN, NUM_RUNS = 0.1, 60, 4
CONFIG = tracking.TrackerConfig(capacity=8, association="gnn")
PARAMS = tracking.TrackerParams.create(CONFIG, dt=DT, q=0.5, r_std=(0.1,),
                                       clutter_density=0.02, dtype=jnp.float64)


def walkers():
    """Four people crossing an 8 m x 6 m area at 10 Hz, swaying; one arrives late, one leaves
    early. Rows ``frame id x z y vx vz vy`` of an ETH-style obsmat file."""
    t = np.arange(T_RUN) * DT
    start = np.array([[-4.0, -3.0], [4.0, -2.0], [-3.0, 3.0], [0.0, -4.0]])
    vel = np.array([[1.0, 0.5], [-1.0, 0.3], [0.8, -0.8], [0.1, 1.0]])
    sway = np.array([[0.0, 1.0], [1.0, 0.0], [1.0, 1.0], [-1.0, 0.0]])
    pos = start + vel * t[:, None, None] + 0.3 * np.sin(t)[:, None, None] * sway
    rows = []
    for k in range(T_RUN):
        for p in range(4):
            if (p == 3 and k < 15) or (p == 0 and k >= 45):
                continue
            rows.append([k, 20 + p, pos[k, p, 0], 0.0, pos[k, p, 1], *vel[p, :1], 0.0,
                         *vel[p, 1:]])
    return np.array(rows)


@jax.jit
def _track_and_score(keys, gt_ids, gt_pos, gt_mask, model):
    def one(key):
        det = sy.detections(key, gt_pos, gt_mask, model, 16)
        _, seq = tracking.run(tracking.init(CONFIG, jnp.float64), sy.to_tracker(det), PARAMS)
        confirmed = seq.status == tracking.CONFIRMED
        res = metrics.clear_mot(gt_ids, gt_pos, gt_mask, jnp.where(confirmed, seq.id, -1),
                                seq.mean[..., :2], confirmed, 0.5, num_ids=64)
        return res, seq
    return jax.vmap(one)(keys)


def test_tracker_on_detections_of_a_trajectory_file(tmp_path):
    path = tmp_path / "obsmat.txt"
    np.savetxt(path, walkers(), fmt="%.10e")
    gt = tj.read_obsmat(path, fps=1 / DT)
    assert gt.pos.shape == (T_RUN, 4, 2)
    scores, runs = {}, {}
    for rate in (0.0, 10.0):
        model = sy.SensorModel.create(noise_std=0.1, p_detect=0.9, clutter_rate=rate)
        res, seq = _track_and_score(keys(10, NUM_RUNS), gt.ids, gt.pos, gt.mask, model)
        scores[rate], runs[rate] = np.asarray(res.mota), (res, seq)
    assert scores[0.0].min() > 0.8, scores
    assert scores[10.0].mean() < scores[0.0].mean() - 0.3, scores

    # The same score through files: tracks written as MOT CSV and evaluated against obsmat.
    res, seq = runs[0.0]
    confirmed = seq.status[0] == tracking.CONFIRMED
    tj.write_mot_csv(tmp_path / "tracks.csv", gt.frames, seq.id[0], seq.mean[0, ..., :2],
                     confirmed)
    from_files = tj.evaluate_files(path, tmp_path / "tracks.csv", threshold=0.5)
    assert from_files["mota"] == pytest.approx(float(res.mota[0]), abs=1e-9)
    assert from_files["num_switches"] == int(res.num_switches[0])
