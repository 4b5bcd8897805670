"""ROS bags: records written with rosbags (ROS 1, ROS 2 sqlite3 and MCAP) read back equal, depth
encodings and layouts decoded against NumPy, truncated bags read up to the cut, clear errors."""

import os
import shutil
import sys
import warnings

import numpy as np
import pytest

pytest.importorskip("rosbags")

from rosbags.typesys import Stores, get_typestore  # noqa: E402

from jaxtrack.io import bags  # noqa: E402

T, B, M = 24, 40, 5
DEPTH = "/camera/depth/image_raw"
KINDS = [("ros1", 1, "sqlite3"), ("sqlite3", 2, "sqlite3"), ("mcap", 2, "mcap")]


def _records(seed=0):
    rng = np.random.default_rng(seed)
    times = 1.7e9 + 0.1 * np.arange(T)
    angles = bags.beam_angles(-1.2, 2.4 / (B - 1), B)
    ranges = rng.uniform(0.05, 6.0, (T, B)).astype(np.float32)
    mask = ranges < 5.6
    ranges = np.where(mask, ranges, np.float32(5.6))
    laser = bags.LaserScans(times, ranges, angles, mask, 0.02, 5.6, np.ones(T, bool))
    pose = np.column_stack([rng.normal(size=(T, 2)), rng.uniform(-np.pi, np.pi, T)])
    odom = bags.Odometry(times, pose, rng.normal(size=(T, 3)), np.ones(T, bool))
    dmask = rng.uniform(size=(T, M)) < 0.6
    xy = np.where(dmask[..., None], rng.normal(size=(T, M, 2)), 0.0)
    det = bags.PersonDetections(times, xy, dmask, np.ones(T, bool))
    dm = rng.uniform(size=(T, 3, 4)) < 0.8
    depth = bags.DepthImages(times, np.where(dm, rng.uniform(0.5, 4.0, (T, 3, 4)), 0)
                             .astype(np.float32), dm, np.ones(T, bool))
    return laser, odom, det, depth


def _joints(seed=1):
    rng = np.random.default_rng(seed)
    times = 1.7e9 + 0.1 * np.arange(T) + 0.03
    return bags.JointStates(times, ("camera_pan", "camera_tilt"),
                            rng.uniform(-2.6, 2.6, (T, 2)), np.ones(T, bool))


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    root = tmp_path_factory.mktemp("bags")
    recs = _records()
    paths = {}
    for name, version, storage in KINDS:
        p = root / (f"{name}.bag" if version == 1 else name)
        # Small ROS 1 chunks: the truncation test then cuts between and inside chunks.
        bags.write_bag(p, version, laser=recs[0], odometry=recs[1], detections=recs[2],
                       depth=recs[3], joints=_joints(), storage=storage, chunk_bytes=4096)
        paths[name] = p
    return recs, paths


@pytest.mark.parametrize("kind", [k[0] for k in KINDS])
def test_joint_states_roundtrip_by_name(written, kind):
    _, paths = written
    want = _joints()
    got = bags.read_joint_states(paths[kind], "/joint_states")
    assert got.names == want.names
    np.testing.assert_array_equal(got.position, want.position)        # float64 exactly
    np.testing.assert_allclose(got.times, want.times, rtol=0, atol=1e-6)
    # By name, in the order asked for; a joint no message has is NaN.
    tilt = bags.read_joint_states(paths[kind], "/joint_states", ["camera_tilt", "wheel"])
    np.testing.assert_array_equal(tilt.position[:, 0], want.position[:, 1])
    assert np.all(np.isnan(tilt.position[:, 1]))
    on_grid = bags.read_joint_states(paths[kind], "/joint_states", rate=10.0)
    assert on_grid.position.shape[1] == 2 and on_grid.valid.any()
    with pytest.raises(bags.BagError):
        bags.read_joint_states(paths[kind], "/odom")


@pytest.mark.parametrize("kind", [k[0] for k in KINDS])
def test_roundtrip_equals_originals(written, kind):
    (laser, odom, det, depth), paths = written
    p = paths[kind]
    got = bags.read_laser(p, "/scan")
    # float32 in the message: ranges and the mask exactly; angles made by beam_angles exactly;
    # stamps to the nanosecond.
    np.testing.assert_array_equal(got.ranges, laser.ranges)
    np.testing.assert_array_equal(got.mask, laser.mask)
    np.testing.assert_array_equal(got.angles, laser.angles)
    np.testing.assert_allclose(got.times, laser.times, rtol=0, atol=1e-6)
    assert got.report.complete and got.report.messages == T
    o = bags.read_odometry(p, "/odom")
    # float64 messages: positions and twists exactly, yaw through the quaternion to 1e-12.
    np.testing.assert_array_equal(o.pose[:, :2], odom.pose[:, :2])
    np.testing.assert_allclose(o.pose[:, 2], odom.pose[:, 2], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(o.twist, odom.twist)
    d = bags.read_detections(p, "/people", M)
    for t in range(T):   # masked rows are left out when writing, so compare the sets in order
        np.testing.assert_array_equal(d.xy[t][d.mask[t]], det.xy[t][det.mask[t]])
    assert np.array_equal(d.mask.sum(1), det.mask.sum(1))
    im = bags.read_depth(p, DEPTH)
    np.testing.assert_array_equal(im.depth, depth.depth)   # 32FC1: float32 exactly
    np.testing.assert_array_equal(im.mask, depth.mask)


def test_topics_and_errors(written):
    _, paths = written
    p = paths["ros1"]
    assert bags.topics(p) == {"/scan": bags.LASER_SCAN, "/odom": bags.ODOMETRY,
                              "/people": bags.POSE_ARRAY, DEPTH: bags.IMAGE,
                              "/joint_states": bags.JOINT_STATE}
    with pytest.raises(bags.BagError, match=r"'/nope'.*topics present: .*/odom .*/scan"):
        bags.read_laser(p, "/nope")
    with pytest.raises(bags.BagError, match="carries nav_msgs/msg/Odometry"):
        bags.read_laser(p, "/odom")
    with pytest.raises(FileNotFoundError):
        bags.read_laser(p.parent / "missing.bag", "/scan")
    with pytest.raises(ValueError, match="time_source"):
        bags.read_laser(p, "/scan", time_source="wall")
    assert bags.read_laser(paths["mcap"], "scan").report.topic == "/scan"  # leading slash


def test_laser_invalid_ranges_masked_and_beam_change_reported(tmp_path):
    laser, *_ = _records(1)
    ranges = laser.ranges.copy()
    ranges[0, :4] = [np.nan, np.inf, 0.01, 7.0]        # NaN, inf, below min, beyond max
    ts = get_typestore(Stores.ROS1_NOETIC)
    msgs = list(bags._laser_messages(bags._MessageMaker(ts, 1),
                                     laser._replace(ranges=ranges, mask=np.ones((T, B), bool)),
                                     "laser"))
    path = tmp_path / "raw.bag"
    from rosbags.rosbag1 import Writer

    with Writer(path) as w:
        c = w.add_connection("/scan", bags.LASER_SCAN, typestore=ts)
        for t, m in msgs:
            w.write(c, t, ts.serialize_ros1(m, bags.LASER_SCAN))
    got = bags.read_laser(path, "/scan", max_beams=B + 3)
    assert got.ranges.shape == (T, B + 3) and got.angles.shape == (B + 3,)
    assert not got.mask[0, :4].any() and np.all(got.ranges[0, :4] == np.float32(5.6))
    assert not got.mask[:, B:].any() and np.all(got.ranges[:, B:] == np.float32(5.6))
    np.testing.assert_allclose(np.diff(got.angles), np.diff(got.angles)[0], atol=1e-6)
    with pytest.raises(bags.BagError, match="max_beams"):
        bags.read_laser(path, "/scan", max_beams=B - 1)
    # One scan with a different beam count: the error names the message.
    path2 = tmp_path / "change.bag"
    with Writer(path2) as w:
        c = w.add_connection("/scan", bags.LASER_SCAN, typestore=ts)
        for i, (t, m) in enumerate(msgs[:5]):
            if i == 3:
                m.ranges = m.ranges[:-2]
            w.write(c, t, ts.serialize_ros1(m, bags.LASER_SCAN))
    with pytest.raises(bags.BagError, match=f"message 3 has {B - 2} beams"):
        bags.read_laser(path2, "/scan")


def _image_bag(path, images, version=1):
    """Images given as (encoding, is_bigendian, step, height, width, data bytes)."""
    ts = get_typestore(Stores.ROS1_NOETIC if version == 1 else Stores.ROS2_HUMBLE)
    mk = bags._MessageMaker(ts, version)
    Image = ts.types[bags.IMAGE]
    if version == 1:
        from rosbags.rosbag1 import Writer

        w = Writer(path)
        ser = ts.serialize_ros1
    else:
        from rosbags.rosbag2 import Writer

        w = Writer(path, version=9)
        ser = ts.serialize_cdr
    with w:
        c = w.add_connection(DEPTH, bags.IMAGE, typestore=ts)
        for i, (enc, big, step, h, wd, data) in enumerate(images):
            t = 10**9 * (i + 1)
            m = Image(header=mk.header(t, "cam", i), height=h, width=wd, encoding=enc,
                      is_bigendian=big, step=step, data=np.frombuffer(data, np.uint8))
            w.write(c, t, ser(m, bags.IMAGE))
    return path


@pytest.mark.parametrize("version", [1, 2])
def test_depth_encodings_endianness_and_row_step(tmp_path, version):
    rng = np.random.default_rng(2)
    H, W, pad = 3, 5, 6
    mm = rng.integers(0, 5000, (H, W)).astype(np.uint16)
    mm[0, 0] = 0                                                    # no depth
    metres = rng.uniform(0.3, 5.0, (H, W)).astype(np.float32)
    metres[1, 2] = np.nan

    def padded(a):  # rows padded with `pad` junk bytes: the step must be honoured
        rows = a.view(np.uint8).reshape(H, -1)
        return np.concatenate([rows, np.full((H, pad), 0xAB, np.uint8)], 1).tobytes()

    imgs = [("16UC1", 0, W * 2 + pad, H, W, padded(mm.astype("<u2"))),
            ("16UC1", 1, W * 2, H, W, mm.astype(">u2").tobytes()),
            ("32FC1", 0, W * 4 + pad, H, W, padded(metres.astype("<f4"))),
            ("32FC1", 1, W * 4, H, W, metres.astype(">f4").tobytes())]
    path = tmp_path / ("d.bag" if version == 1 else "d2")
    got = bags.read_depth(_image_bag(path, imgs, version), DEPTH)
    ref_mm = (mm.astype(np.float64) * 1e-3).astype(np.float32)
    for i in (0, 1):
        np.testing.assert_array_equal(got.depth[i], np.where(mm > 0, ref_mm, 0))
        np.testing.assert_array_equal(got.mask[i], mm > 0)
    for i in (2, 3):
        np.testing.assert_array_equal(got.depth[i], np.nan_to_num(metres, nan=0.0))
        np.testing.assert_array_equal(got.mask[i], np.isfinite(metres))
    bad = _image_bag(tmp_path / ("e.bag" if version == 1 else "e2"),
                     [("32FC1", 0, W * 4, H, W, metres.tobytes()),
                      ("rgb8", 0, W * 3, H, W, bytes(H * W * 3))], version)
    with pytest.raises(bags.BagError, match="image 1: depth encoding 'rgb8' is not supported"):
        bags.read_depth(bad, DEPTH)
    with pytest.raises(bags.BagError, match="depth encoding 'mono8'"):
        bags.write_bag(tmp_path / "x.bag", 1, depth=got, depth_encoding="mono8")


def test_depth_16uc1_writer_rounds_to_millimetres(tmp_path):
    *_, depth = _records(3)
    got = bags.read_depth(bags.write_bag(tmp_path / "mm.bag", 1, depth=depth,
                                         depth_encoding="16UC1"), DEPTH)
    np.testing.assert_array_equal(got.mask, depth.mask)
    np.testing.assert_allclose(got.depth, depth.depth, atol=5e-4 + 1e-7)


@pytest.mark.parametrize("version", [1, 2])
def test_people_msgs_registered_and_read(tmp_path, version):
    _, _, det, _ = _records(4)
    ts = get_typestore(Stores.ROS1_NOETIC if version == 1 else Stores.ROS2_HUMBLE)
    assert bags.POSITION_MEASUREMENT_ARRAY not in ts.types
    with pytest.raises(bags.BagError, match="register_people_msgs"):
        bags.write_bag(tmp_path / "a.bag", version, detections=det, typestore=ts,
                       detections_type=bags.POSITION_MEASUREMENT_ARRAY)
    assert bags.register_people_msgs(ts) is ts
    fields = ts.types[bags.POSITION_MEASUREMENT].__dataclass_fields__
    assert {"name", "object_id", "pos", "reliability", "covariance"} <= set(fields)
    path = tmp_path / ("p.bag" if version == 1 else "p2")
    bags.write_bag(path, version, detections=det, typestore=ts,
                   detections_type=bags.POSITION_MEASUREMENT_ARRAY)
    assert bags.topics(path)["/people"] == bags.POSITION_MEASUREMENT_ARRAY
    got = bags.read_detections(path, "/people", 3)     # fewer slots than some messages hold
    for t in range(T):
        keep = det.xy[t][det.mask[t]][:3]
        np.testing.assert_array_equal(got.xy[t][got.mask[t]], keep)
    dropped = int(np.maximum(det.mask.sum(1) - 3, 0).sum())
    assert dropped > 0 and f"{dropped} detections beyond" in got.report.detail


def _cut(src, dst, fraction):
    if src.is_dir():
        shutil.copytree(src, dst)
        f = next(x for x in dst.iterdir() if x.suffix in (".db3", ".mcap"))
    else:
        shutil.copy(src, dst)
        f = dst
    size = os.path.getsize(f)
    os.truncate(f, int(size * fraction))
    return dst


@pytest.mark.parametrize("kind", [k[0] for k in KINDS])
def test_truncated_bag_reads_prefix_and_reports(written, tmp_path, kind):
    (laser, *_), paths = written
    cut = _cut(paths[kind], tmp_path / paths[kind].name, 0.75)
    with pytest.warns(bags.BagWarning, match="unreadable"):
        got = bags.read_laser(cut, "/scan")
    n = got.report.messages
    assert 0 < n < T and got.ranges.shape == (n, B)
    assert not got.report.complete and got.report.stopped_at is not None
    assert "record by record" in got.report.detail or "row by row" in got.report.detail
    # What was read is what was written (a prefix for the sequential formats).
    idx = np.searchsorted(laser.times, got.times - 1e-6)
    np.testing.assert_array_equal(got.ranges, laser.ranges[idx])
    if kind != "ros1":  # ROS 2 metadata says how many messages the bag held
        assert got.report.unreadable == T - n
    else:               # ROS 1 keeps its counts in the lost index
        assert got.report.unreadable == -1 and np.array_equal(idx, np.arange(n))
    with pytest.raises(bags.BagError, match="topics present"):
        bags.read_laser(cut, "/nope")


def test_unrecoverable_bag_is_a_clear_error(tmp_path):
    p = tmp_path / "junk.bag"
    p.write_bytes(b"not a bag at all\n" * 4)
    with pytest.raises(bags.BagError, match="not a ROS 1 bag"):
        bags.read_laser(p, "/scan")


def test_resample_against_brute_force():
    rng = np.random.default_rng(5)
    t = np.sort(rng.uniform(0.0, 3.0, 40))
    x = rng.normal(size=(40, 2))
    rate = 7.0
    for method in ("bucket", "nearest"):
        grid, valid, (y,) = bags.resample(t, x, rate=rate, method=method)
        np.testing.assert_allclose(grid, t[0] + np.arange(len(grid)) / rate)
        for k, g in enumerate(grid):
            if method == "bucket":
                inside = np.flatnonzero((t >= g - 1e-12) & (t < g + 1 / rate - 1e-12))
                want = inside[-1] if inside.size else None
            else:
                j = int(np.argmin(np.abs(t - g)))
                want = j if abs(t[j] - g) <= 0.5 / rate else None
            assert valid[k] == (want is not None)
            np.testing.assert_array_equal(y[k], x[want] if want is not None else 0.0)
    with pytest.raises(ValueError, match="non-decreasing"):
        bags.resample(t[::-1], x, rate=1.0)
    with pytest.raises(ValueError, match="rate"):
        bags.resample(t, x, rate=0.0)
    with pytest.raises(ValueError, match="method"):
        bags.resample(t, x, rate=1.0, method="linear")
    with pytest.raises(ValueError, match="rows"):
        bags.resample(t, x[:3], rate=1.0)


def test_reader_rate_masks_empty_slots(written):
    (laser, odom, *_), paths = written
    # 25 Hz clock over 10 Hz scans: some slots are empty, every scan lands in one slot.
    got = bags.read_laser(paths["ros1"], "/scan", rate=25.0)
    assert got.valid.sum() == T and (~got.valid).sum() > 0
    assert not got.mask[~got.valid].any() and np.all(got.ranges[~got.valid] == np.float32(5.6))
    np.testing.assert_array_equal(got.ranges[got.valid], laser.ranges)
    o = bags.read_odometry(paths["sqlite3"], "/odom", rate=5.0, method="nearest")
    np.testing.assert_array_equal(o.pose[o.valid][:, :2], odom.pose[::2][:, :2])


def test_time_source_bag(written):
    (laser, *_), paths = written
    got = bags.read_laser(paths["mcap"], "/scan", time_source="bag")
    np.testing.assert_allclose(got.times, laser.times, atol=1e-6)


def test_missing_rosbags_says_how_to_install(monkeypatch, written):
    _, paths = written
    for name in list(sys.modules):
        if name == "rosbags" or name.startswith("rosbags."):
            monkeypatch.setitem(sys.modules, name, None)
    with pytest.raises(ImportError, match=r'pip install "jaxtrack\[ros\]"'):
        bags.read_laser(paths["ros1"], "/scan")


def test_write_bag_checks_arguments(tmp_path):
    laser, *_ = _records()
    with pytest.raises(ValueError, match="version"):
        bags.write_bag(tmp_path / "a.bag", 3, laser=laser)
    with pytest.raises(ValueError, match="nothing to write"):
        bags.write_bag(tmp_path / "a.bag", 1)
    with pytest.raises(ValueError, match="storage"):
        bags.write_bag(tmp_path / "a", 2, laser=laser, storage="rosbag3")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        bags.write_bag(tmp_path / "a.bag", 1, laser=laser)


def test_other_angles_roundtrip_to_float32_rounding(tmp_path):
    laser, *_ = _records()
    angles = np.linspace(-2.0944, 2.0944, B).astype(np.float32)
    got = bags.read_laser(bags.write_bag(tmp_path / "a.bag", 1,
                                         laser=laser._replace(angles=angles)), "/scan")
    np.testing.assert_allclose(got.angles, angles, rtol=0, atol=4 * np.finfo(np.float32).eps)


def test_truncated_compressed_ros1_reads_whole_chunks(tmp_path):
    laser, *_ = _records()
    for comp in ("lz4", "bz2"):
        full = bags.write_bag(tmp_path / f"{comp}.bag", 1, laser=laser, chunk_bytes=2048,
                              compression=comp)
        np.testing.assert_array_equal(bags.read_laser(full, "/scan").ranges, laser.ranges)
        cut = _cut(full, tmp_path / f"cut_{comp}.bag", 0.6)
        with pytest.warns(bags.BagWarning):
            got = bags.read_laser(cut, "/scan")
        n = got.report.messages
        assert 0 < n < T
        np.testing.assert_array_equal(got.ranges, laser.ranges[:n])
        assert got.report.stopped_at is not None and got.report.stopped_at < cut.stat().st_size
    with pytest.raises(ValueError, match="compression"):
        bags.write_bag(tmp_path / "z", 2, laser=laser, compression="lz4")


@pytest.mark.parametrize("kind", ["sqlite3", "mcap"])
def test_ros2_without_metadata_or_storage_file_alone(written, tmp_path, kind):
    (laser, odom, *_), paths = written
    d = tmp_path / kind
    shutil.copytree(paths[kind], d)
    (d / "metadata.yaml").unlink()        # a recorder that did not close the bag
    with pytest.warns(bags.BagWarning, match="metadata.yaml"):
        got = bags.read_laser(d, "/scan")
    np.testing.assert_array_equal(got.ranges, laser.ranges)
    assert got.report.unreadable == -1    # nothing says how many there were
    storage = next(d.glob("*.db3" if kind == "sqlite3" else "*.mcap"))
    with warnings.catch_warnings():   # read by rosbags or, failing that, record by record
        warnings.simplefilter("ignore", bags.BagWarning)
        o = bags.read_odometry(storage, "/odom")
    np.testing.assert_array_equal(o.twist, odom.twist)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(bags.BagError, match="no metadata.yaml and no .db3"):
        bags.read_laser(empty, "/scan")


def test_nonfinite_detections_are_left_out(tmp_path):
    *_, det, _ = _records(6)
    xy = det.xy.copy()
    xy[0, 0] = [np.nan, 1.0]
    xy[1, 0] = [np.inf, 0.0]
    det = det._replace(xy=xy, mask=det.mask.copy())
    det.mask[:2, 0] = True
    got = bags.read_detections(bags.write_bag(tmp_path / "n.bag", 1, detections=det),
                               "/people", M)
    assert np.all(np.isfinite(got.xy))
    for t in range(T):
        keep = det.xy[t][det.mask[t] & np.all(np.isfinite(det.xy[t]), -1)]
        np.testing.assert_array_equal(got.xy[t][got.mask[t]], keep)
    assert "2 detections with NaN / inf" in got.report.detail


def test_importing_bags_does_not_import_rosbags():
    import subprocess

    code = ("import sys, jaxtrack.io.bags; "
            "sys.exit(1 if any(m.split('.')[0] == 'rosbags' for m in sys.modules) else 0)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr


def test_write_bag_refuses_bad_times_empty_scans_and_shape_mismatches(tmp_path):
    laser, odom, det, depth = _records()
    p = tmp_path / "w.bag"

    def times(t):
        return laser._replace(times=t)

    bad_t = laser.times.copy()
    bad_t[3] = np.nan
    with pytest.raises(ValueError, match=r"laser\.times must be finite"):
        bags.write_bag(p, 1, laser=times(bad_t))
    with pytest.raises(ValueError, match=r"laser\.times must be finite seconds in \[0"):
        bags.write_bag(p, 1, laser=times(laser.times - 2e9))
    bad_t = laser.times.copy()
    bad_t[5] = bad_t[4]
    with pytest.raises(ValueError, match=r"laser\.times must be strictly increasing.*row 5"):
        bags.write_bag(p, 1, laser=times(bad_t))
    with pytest.raises(ValueError, match="ROS 2 stamp"):
        bags.write_bag(tmp_path / "w2", 2, laser=times(laser.times + 2.0**31))
    with pytest.raises(ValueError, match="laser has 0 beams"):
        bags.write_bag(p, 1, laser=laser._replace(angles=laser.angles[:0],
                                                  ranges=laser.ranges[:, :0],
                                                  mask=laser.mask[:, :0]))
    with pytest.raises(ValueError, match=r"laser\.mask must be \[24, 40\]"):
        bags.write_bag(p, 1, laser=laser._replace(mask=laser.mask[:, 1:]))
    with pytest.raises(ValueError, match=r"odometry\.pose must be \[24, 3\]"):
        bags.write_bag(p, 1, odometry=odom._replace(pose=odom.pose[:-1]))
    with pytest.raises(ValueError, match=r"detections\.mask must be \[24, 5\]"):
        bags.write_bag(p, 1, detections=det._replace(mask=det.mask[:, :2]))
    with pytest.raises(ValueError, match=r"depth\.mask must be"):
        bags.write_bag(p, 1, depth=depth._replace(mask=depth.mask[:, :1]))
    with pytest.raises(ValueError, match="no row to write"):
        bags.write_bag(p, 1, laser=laser._replace(valid=np.zeros(T, bool)))
    with pytest.raises(ValueError, match=r"joints\.position has 2 columns and joints\.names 1"):
        bags.write_bag(p, 1, joints=_joints()._replace(names=("camera_pan",)))
    assert not p.exists()
    # Invalid rows are not written, so their times are not checked.
    bad_t = laser.times.copy()
    bad_t[2] = np.nan
    valid = np.ones(T, bool)
    valid[2] = False
    got = bags.read_laser(bags.write_bag(p, 1, laser=laser._replace(times=bad_t, valid=valid)),
                          "/scan")
    assert got.report.complete and got.report.messages == T - 1


def test_resample_refuses_a_huge_clock_naming_rate_and_span():
    t = 1.7e9 + np.arange(5.0)
    x = np.zeros((5, 512), np.float32)
    with pytest.raises(ValueError, match=r"rate=1e\+09 Hz over 4 s .*MAX_RESAMPLE_SLOTS"):
        bags.resample(t, x, rate=1e9)
    with pytest.raises(ValueError, match="MAX_RESAMPLE_SLOTS"):
        bags.resample(t, x, rate=10.0, stop=t[0] + 1e7)
    grid, valid, _ = bags.resample(t, x, rate=(bags.MAX_RESAMPLE_SLOTS - 1) / 4.0 / 10)
    assert grid.size < bags.MAX_RESAMPLE_SLOTS and valid.sum() == 5


@pytest.mark.parametrize("kind", [k[0] for k in KINDS])
def test_a_stray_timestamp_is_left_out_and_counted(tmp_path, kind):
    laser, *_ = _records(7)
    stray = laser.times.copy()
    stray[-1] += 2.0**20          # the seconds' bit 20 flipped: 12 days later
    name, version, storage = next(k for k in KINDS if k[0] == kind)
    p = bags.write_bag(tmp_path / (f"{name}.bag" if version == 1 else name), version,
                       laser=laser._replace(times=stray), storage=storage)
    with pytest.warns(bags.BagWarning, match="1 messages at times apart from the stream"):
        got = bags.read_laser(p, "/scan", rate=25.0)
    assert got.report.dropped == 1 and got.report.messages == T - 1
    assert got.times[-1] - got.times[0] < 3.0 and got.valid.sum() == T - 1
    np.testing.assert_array_equal(got.ranges[got.valid], laser.ranges[:-1])
    # A pause between two substantial parts of a recording is kept.
    pause = laser.times + np.where(np.arange(T) >= T // 2, 600.0, 0.0)
    p2 = bags.write_bag(tmp_path / ("p.bag" if version == 1 else "p"), version,
                        laser=laser._replace(times=pause), storage=storage)
    got = bags.read_laser(p2, "/scan")
    assert got.report.complete and got.times.size == T


def test_nonfinite_odometry_is_dropped_and_counted(tmp_path):
    _, odom, *_ = _records(8)
    pose, twist = odom.pose.copy(), odom.twist.copy()
    pose[3, 0] = np.nan
    pose[7, 2] = np.inf           # written as a NaN quaternion
    twist[9, 1] = np.nan
    p = bags.write_bag(tmp_path / "o.bag", 1, odometry=odom._replace(pose=pose, twist=twist))
    with pytest.warns(bags.BagWarning, match="3 messages with a NaN / inf pose or twist dropped"):
        got = bags.read_odometry(p, "/odom")
    keep = np.setdiff1d(np.arange(T), [3, 7, 9])
    assert got.report.dropped == 3 and got.report.messages == T - 3
    np.testing.assert_array_equal(got.pose[:, :2], odom.pose[keep, :2])
    np.testing.assert_array_equal(got.twist, odom.twist[keep])
    np.testing.assert_allclose(got.times, odom.times[keep], atol=1e-6)


def test_ros1_damaged_definition_is_decoded_with_the_standard_one(written, tmp_path):
    (_, odom, *_), paths = written
    data = paths["ros1"].read_bytes()
    assert data.count(b"Quaternion orientation") >= 2   # in a chunk and in the index
    p = tmp_path / "def.bag"
    p.write_bytes(data.replace(b"Quaternion orientation", b"Quaternion orientatioN"))
    with pytest.warns(bags.BagWarning, match="lacks fields of the standard one"):
        got = bags.read_odometry(p, "/odom")
    np.testing.assert_array_equal(got.pose[:, :2], odom.pose[:, :2])
    np.testing.assert_allclose(got.pose[:, 2], odom.pose[:, 2], rtol=0, atol=1e-12)


def test_ros1_garbled_record_length_is_skipped_and_reading_resumes(written, tmp_path):
    (laser, *_), paths = written
    data = bytearray(paths["ros1"].read_bytes())
    # The third chunk record's header length made huge: the walk resumes at the next chunk.
    chunks = [i - 4 for i in range(len(data)) if data.startswith(b"\x04\x00\x00\x00op=\x05", i)]
    at = chunks[2]
    data[at:at + 4] = (2**31).to_bytes(4, "little")
    p = tmp_path / "garbled.bag"
    p.write_bytes(bytes(data))
    with pytest.warns(bags.BagWarning, match="damaged records skipped"):
        got = bags.read_laser(p, "/scan")
    r = got.report
    assert at in r.damaged and r.stopped_at is None and f"from byte {at}" in r.detail
    assert 0 < r.messages < T
    idx = np.searchsorted(laser.times, got.times - 1e-6)
    assert idx[-1] == T - 1                  # messages after the damaged chunk were read
    np.testing.assert_array_equal(got.ranges, laser.ranges[idx])


@pytest.mark.parametrize("kind", [k[0] for k in KINDS])
def test_unreadable_bag_error_names_file_and_offset(written, tmp_path, kind):
    _, paths = written
    bad = _cut(paths[kind], tmp_path / paths[kind].name, 1.0)
    f = bad if bad.is_file() else next(x for x in bad.iterdir() if x.suffix in (".db3", ".mcap"))
    data = bytearray(f.read_bytes())
    data[:16] = bytes(16)
    f.write_bytes(bytes(data))
    with pytest.raises(bags.BagError, match=rf"{f.name}.*bad magic at byte 0"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", bags.BagWarning)
            bags.read_laser(bad, "/scan")


def test_cli_track_on_a_damaged_bag_prints_one_line_and_exits_2(written, tmp_path, capsys):
    from sims import cli

    _, paths = written
    bad = tmp_path / "damaged.bag"
    data = bytearray(paths["ros1"].read_bytes())
    data[:4096] = bytes(4096)
    bad.write_bytes(bytes(data))
    with pytest.raises(SystemExit) as exc:
        cli.main(["track", "--bag", str(bad), "--laser-topic", "/scan",
                  "--out", str(tmp_path / "out")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxtrack track: ") and "damaged.bag" in err
    assert err.count("\n") == 1 and "Traceback" not in err


# -- sensor_msgs/PointCloud2 and colour images ---------------------------------------------------

CLOUD = "/camera/depth/points"


def _cloud_bag(path, clouds, version=1):
    """Clouds given as (fields [(name, offset, datatype)], is_bigendian, point_step, row_step,
    height, width, data bytes)."""
    ts = get_typestore(Stores.ROS1_NOETIC if version == 1 else Stores.ROS2_HUMBLE)
    mk = bags._MessageMaker(ts, version)
    PC2, PF = ts.types[bags.POINT_CLOUD2], ts.types[bags.POINT_FIELD]
    if version == 1:
        from rosbags.rosbag1 import Writer

        w, ser = Writer(path), ts.serialize_ros1
    else:
        from rosbags.rosbag2 import Writer

        w, ser = Writer(path, version=9), ts.serialize_cdr
    with w:
        c = w.add_connection(CLOUD, bags.POINT_CLOUD2, typestore=ts)
        for i, (fields, big, step, row_step, h, wd, data) in enumerate(clouds):
            t = 10**9 * (i + 1)
            m = PC2(header=mk.header(t, "cam", i), height=h, width=wd,
                    fields=[PF(name=n, offset=o, datatype=d, count=1) for n, o, d in fields],
                    is_bigendian=bool(big), point_step=step, row_step=row_step,
                    data=np.frombuffer(data, np.uint8), is_dense=False)
            w.write(c, t, ser(m, bags.POINT_CLOUD2))
    return path


def _points(n, rng, nan=()):
    xyz = rng.uniform(-4, 4, (n, 3))
    for k in nan:
        xyz[k, k % 3] = np.nan
    return xyz, rng.integers(0, 256, (n, 4)).astype(np.uint32)   # r, g, b, a


def _cloud_records(rng):
    """Three clouds built with NumPy: (message tuple, xyz [n, 3] float64, rgb8 [n, 3] or None)."""
    out = []
    # 1. float32 x, y, z and PCL's packed float rgb, little-endian, 4 padding bytes per point.
    xyz, c = _points(5, rng, nan=(1,))
    dt = np.dtype({"names": ["x", "y", "z", "rgb"], "formats": ["<f4"] * 4,
                   "offsets": [0, 4, 8, 12], "itemsize": 20})
    a = np.zeros(5, dt)
    a["x"], a["y"], a["z"] = xyz.T
    a["rgb"] = ((c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]).view(np.float32)
    out.append(((([("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("rgb", 12, 7)]), 0, 20, 100, 1, 5,
                 a.tobytes()), xyz.astype(np.float32), c[:, :3]))
    # 2. float64 x, y, z and a uint32 rgba (alpha in the high byte), big-endian, fields in
    #    another order.
    xyz, c = _points(6, rng)
    dt = np.dtype({"names": ["rgba", "z", "y", "x"], "formats": [">u4", ">f8", ">f8", ">f8"],
                   "offsets": [0, 8, 16, 24], "itemsize": 32})
    a = np.zeros(6, dt)
    a["x"], a["y"], a["z"] = xyz.T
    a["rgba"] = (c[:, 3] << 24) | (c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]
    out.append((([("rgba", 0, 6), ("z", 8, 8), ("y", 16, 8), ("x", 24, 8)], 1, 32, 192, 1, 6,
                 a.tobytes()), xyz.astype(np.float32), c[:, :3]))
    # 3. organised 3 x 4 without colour, NaN points, 5 padding bytes after each row.
    xyz, _ = _points(12, rng, nan=(0, 5, 7))
    rows = np.zeros((3, 4), np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")]))
    rows["x"], rows["y"], rows["z"] = (v.reshape(3, 4) for v in xyz.T)
    data = np.concatenate([rows.view(np.uint8).reshape(3, 48), np.full((3, 5), 7, np.uint8)], 1)
    out.append((([("x", 0, 7), ("y", 4, 7), ("z", 8, 7)], 0, 12, 53, 3, 4, data.tobytes()),
                xyz.astype(np.float32), None))
    return out


@pytest.mark.parametrize("version", [1, 2])
def test_point_cloud2_decoded_against_numpy(tmp_path, version):
    records = _cloud_records(np.random.default_rng(5))
    path = _cloud_bag(tmp_path / ("c.bag" if version == 1 else "c2"), [r[0] for r in records],
                      version)
    got = bags.read_point_clouds(path, CLOUD)
    assert got.points.shape == (3, 12, 3) and got.image_shape is None   # mixed shapes
    for i, (_, xyz, rgb) in enumerate(records):
        n = xyz.shape[0]
        ok = np.all(np.isfinite(xyz), -1)
        np.testing.assert_array_equal(got.mask[i, :n], ok)
        np.testing.assert_array_equal(got.points[i, :n], np.where(ok[:, None], xyz, 0))
        want = (np.zeros((n, 3), np.float32) if rgb is None
                else rgb.astype(np.float32) / np.float32(255))
        np.testing.assert_array_equal(got.colours[i, :n], want)
        assert not got.mask[i, n:].any() and not got.points[i, n:].any()  # padding
    np.testing.assert_allclose(got.times, [1, 2, 3])
    assert got.report.complete


def test_point_cloud2_organised_max_points_and_errors(tmp_path):
    rng = np.random.default_rng(6)
    organised = _cloud_records(rng)[2][0]
    path = _cloud_bag(tmp_path / "o.bag", [organised, organised])
    got = bags.read_point_clouds(path, CLOUD)
    assert got.image_shape == (3, 4) and got.mask.sum(1).tolist() == [9, 9]
    # max_points: more points than N keep their valid ones, in order (the layout is lost).
    small = bags.read_point_clouds(path, CLOUD, max_points=9)
    assert small.image_shape is None and small.mask.all()
    np.testing.assert_array_equal(small.points[0], got.points[0][got.mask[0]])
    wide = bags.read_point_clouds(path, CLOUD, max_points=20)
    assert wide.image_shape == (3, 4) and wide.points.shape == (2, 20, 3)
    with pytest.raises(bags.BagError, match="cloud 0 has 9 valid points, more than max_points=8"):
        bags.read_point_clouds(path, CLOUD, max_points=8)
    with pytest.raises(ValueError, match="max_points must be a positive integer"):
        bags.read_point_clouds(path, CLOUD, max_points=0)
    fields, big, step, row_step, h, w, data = organised
    cases = [
        ([("x", 0, 7), ("y", 4, 7)], "cloud 0 has no z field"),
        ([("x", 0, 3), ("y", 4, 7), ("z", 8, 7)], "field 'x' is INT16; supported: FLOAT32 or "
                                                  "FLOAT64"),
        ([*fields, ("rgb", 8, 2)], "field 'rgb' is UINT8; supported: UINT32 or FLOAT32"),
        ([("x", 0, 7), ("y", 4, 7), ("z", 10, 7)], "runs past the point step 12"),
    ]
    for k, (bad, message) in enumerate(cases):
        p = _cloud_bag(tmp_path / f"bad{k}.bag", [(bad, big, step, row_step, h, w, data)])
        with pytest.raises(bags.BagError, match=message):
            bags.read_point_clouds(p, CLOUD)
    p = _cloud_bag(tmp_path / "short.bag", [(fields, big, step, row_step, h, w, data[:-10])])
    with pytest.raises(bags.BagError, match="do not hold 3x4 points"):
        bags.read_point_clouds(p, CLOUD)
    # An empty cloud is a row of no points.
    p = _cloud_bag(tmp_path / "empty.bag", [(fields, big, step, 0, 1, 0, b"")])
    empty = bags.read_point_clouds(p, CLOUD)
    assert empty.points.shape == (1, 0, 3) and empty.mask.shape == (1, 0)
    with pytest.raises(bags.BagError, match="carries sensor_msgs/msg/PointCloud2"):
        bags.read_depth(path, CLOUD)


@pytest.mark.parametrize("kind", [k[0] for k in KINDS])
def test_write_bag_point_clouds_roundtrip(tmp_path, kind):
    rng = np.random.default_rng(7)
    times = 5.0 + 0.1 * np.arange(3)
    pts = rng.uniform(-3, 3, (3, 12, 3)).astype(np.float32)
    mask = rng.uniform(size=(3, 12)) < 0.7
    colours = rng.uniform(0, 1, (3, 12, 3)).astype(np.float32)
    level = np.round(colours.astype(np.float64) * 255).astype(np.float32) / np.float32(255)
    _, version, storage = next(k for k in KINDS if k[0] == kind)
    for shape in ((3, 4), None):          # organised (NaN where masked), then the valid points
        rec = bags.PointClouds(times, np.where(mask[..., None], pts, 0), colours, mask,
                               np.ones(3, bool), None, shape)
        p = tmp_path / f"{kind}{shape is None}{'.bag' if version == 1 else ''}"
        got = bags.read_point_clouds(bags.write_bag(p, version, clouds=rec, storage=storage),
                                     CLOUD)
        np.testing.assert_allclose(got.times, times, rtol=0, atol=1e-9)
        assert got.image_shape == shape
        if shape is None:
            for i in range(3):
                n = mask[i].sum()
                np.testing.assert_array_equal(got.points[i, :n], pts[i][mask[i]])
                np.testing.assert_array_equal(got.colours[i, :n], level[i][mask[i]])
                assert got.mask[i, :n].all() and not got.mask[i, n:].any()
        else:
            np.testing.assert_array_equal(got.mask, mask)
            np.testing.assert_array_equal(got.points, rec.points)
            np.testing.assert_array_equal(got.colours, level)
    on_grid = bags.read_point_clouds(p, CLOUD, rate=5.0)
    assert on_grid.points.shape[1:] == (mask.sum(1).max(), 3) and on_grid.valid.any()
    with pytest.raises(ValueError, match=r"clouds.mask must be \[3, 12\]"):
        bags.write_bag(tmp_path / "bad.bag", 1, clouds=rec._replace(mask=mask[:, :5]))
    with pytest.raises(ValueError, match="image_shape"):
        bags.write_bag(tmp_path / "bad.bag", 1, clouds=rec._replace(image_shape=(4, 4)))


@pytest.mark.parametrize("version", [1, 2])
def test_colour_encodings_decoded_against_numpy(tmp_path, version):
    rng = np.random.default_rng(8)
    H, W, pad = 3, 4, 2
    rgb = rng.integers(0, 256, (H, W, 3)).astype(np.uint8)
    alpha = rng.integers(0, 256, (H, W, 1)).astype(np.uint8)
    grey = rng.integers(0, 256, (H, W)).astype(np.uint8)

    def padded(a):
        rows = a.reshape(H, -1)
        return np.concatenate([rows, np.full((H, pad), 0xCD, np.uint8)], 1).tobytes()

    imgs = [("rgb8", 0, W * 3, H, W, rgb.tobytes()),
            ("bgr8", 0, W * 3 + pad, H, W, padded(rgb[..., ::-1])),
            ("rgba8", 0, W * 4, H, W, np.concatenate([rgb, alpha], -1).tobytes()),
            ("bgra8", 0, W * 4 + pad, H, W, padded(np.concatenate([rgb[..., ::-1], alpha], -1))),
            ("mono8", 0, W, H, W, grey.tobytes())]
    got = bags.read_colour(_image_bag(tmp_path / ("i.bag" if version == 1 else "i2"), imgs,
                                      version), DEPTH)
    want = rgb.astype(np.float32) / np.float32(255)
    for i in range(4):
        np.testing.assert_array_equal(got.colour[i], want)
    np.testing.assert_array_equal(got.colour[4], np.repeat(grey[..., None], 3, -1)
                                  .astype(np.float32) / np.float32(255))
    bad = _image_bag(tmp_path / ("j.bag" if version == 1 else "j2"),
                     [("rgb8", 0, W * 3, H, W, rgb.tobytes()),
                      ("rgb16", 0, W * 6, H, W, bytes(H * W * 6))], version)
    with pytest.raises(bags.BagError, match="image 1: colour encoding 'rgb16' is not supported"):
        bags.read_colour(bad, DEPTH)
    short = _image_bag(tmp_path / ("k.bag" if version == 1 else "k2"),
                       [("rgb8", 0, W * 3, H, W, rgb.tobytes()[:-1])], version)
    with pytest.raises(bags.BagError, match="do not hold 3x4 rgb8 pixels"):
        bags.read_colour(short, DEPTH)


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8", "rgba8", "bgra8", "mono8"])
def test_colour_images_roundtrip_through_write_bag(tmp_path, encoding):
    rng = np.random.default_rng(9)
    times = 1.0 + 0.1 * np.arange(2)
    colour = rng.uniform(0, 1, (2, 3, 5, 3)).astype(np.float32)
    if encoding == "mono8":
        colour[:] = colour[..., :1]
    rec = bags.ColourImages(times, colour, np.ones(2, bool))
    for version in (1, 2):
        p = bags.write_bag(tmp_path / f"{encoding}{'.bag' if version == 1 else ''}", version,
                           colour=rec, colour_encoding=encoding)
        got = bags.read_colour(p, "/camera/color/image_raw")
        np.testing.assert_array_equal(
            got.colour, np.round(colour.astype(np.float64) * 255).astype(np.float32)
            / np.float32(255))
    with pytest.raises(bags.BagError, match="colour encoding 'yuv422'"):
        bags.write_bag(tmp_path / "x.bag", 1, colour=rec, colour_encoding="yuv422")
