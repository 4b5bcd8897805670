"""Replay of a real recording (the leg_tracker demo bag in ``../shared/data``): its ROS 2
copies (sqlite3 and MCAP, made with rosbags' converter) read into the same arrays and give the
same tracks as the ROS 1 original, and the scan geometry comes from the messages."""

import math
from pathlib import Path

import numpy as np
import pytest

rosbags_convert = pytest.importorskip("rosbags.convert")

from jaxtrack.io import bags, replay  # noqa: E402

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "leg_tracker"
DEMO = DATA / "demo_stationary_simple_environment.bag"
FRAMES = 96      # the replay compares this many scans (tracks compile once, chunks of 32)

pytestmark = pytest.mark.skipif(not DEMO.exists(), reason="the shared demo recording is absent")


@pytest.fixture(scope="module")
def copies(tmp_path_factory):
    from rosbags.typesys import Stores, get_typestore

    root = tmp_path_factory.mktemp("demo")
    out = {"ros1": DEMO}
    for storage in ("sqlite3", "mcap"):
        dst = root / storage
        rosbags_convert.convert([DEMO], dst, storage, 8, None, "file", None,
                                get_typestore(Stores.ROS2_HUMBLE), [], [], [], [])
        out[storage] = dst
    return out


@pytest.fixture(scope="module")
def scans(copies):
    return {k: bags.read_laser(p, "/scan") for k, p in copies.items()}


def _first(laser, n):
    return laser._replace(times=laser.times[:n], ranges=laser.ranges[:n], mask=laser.mask[:n],
                          valid=laser.valid[:n])


def test_ros2_copies_read_the_same_arrays(scans):
    ref = scans["ros1"]
    assert ref.ranges.shape == (1265, 512)
    for kind in ("sqlite3", "mcap"):
        got = scans[kind]
        for name in ("times", "ranges", "angles", "mask", "valid"):
            np.testing.assert_array_equal(getattr(got, name), getattr(ref, name),
                                          err_msg=f"{kind} {name}")
        assert (got.range_min, got.range_max) == (ref.range_min, ref.range_max)
        assert got.report.complete


def test_scan_geometry_and_invalid_returns_come_from_the_messages(copies, scans):
    from rosbags.highlevel import AnyReader

    laser = scans["ros1"]
    with AnyReader([DEMO]) as reader:
        conn = [c for c in reader.connections if c.topic == "/scan"]
        raw = [reader.deserialize(d, c.msgtype)
               for c, _, d in reader.messages(connections=conn)]
    first = raw[0]
    np.testing.assert_allclose(laser.angles[0], first.angle_min, rtol=0, atol=1e-6)
    np.testing.assert_allclose(np.diff(laser.angles), first.angle_increment, atol=1e-6)
    assert laser.range_max == pytest.approx(first.range_max)
    r = np.stack([np.asarray(m.ranges, np.float32) for m in raw])
    assert np.isnan(r).any() and np.isinf(r).any()          # both kinds in this recording
    expected = np.isfinite(r) & (r >= first.range_min) & (r < first.range_max)
    np.testing.assert_array_equal(laser.mask, expected)
    assert np.all(laser.ranges[~laser.mask] == np.float32(laser.range_max))
    assert math.isclose(float(np.median(np.diff(laser.times))), 0.1, rel_tol=0.05)


def test_ros1_and_ros2_copies_give_identical_tracks(scans):
    tracks = {k: replay.track(_first(s, FRAMES), None, None, "gnn", chunk=32, progress=False)
              for k, s in scans.items()}
    ref = tracks["ros1"]
    assert ref.mask.any(), "the learned detector finds people in the demo recording"
    for kind in ("sqlite3", "mcap"):
        for name in ("ids", "pos", "mask", "user", "user_found", "times"):
            np.testing.assert_array_equal(getattr(tracks[kind], name), getattr(ref, name),
                                          err_msg=f"{kind} {name}")
