"""Replay on recorded data (`jaxtrack.io.replay`): a simulated person-following recording
written as ROS 1 and ROS 2 bags reads back equal, the estimator's output from the bag equals
its output from memory and follows the true user, chunking does not change it, the command
line writes a MOT CSV, and none of it needs MuJoCo."""

import io
import os
import subprocess
import sys
import textwrap
from contextlib import redirect_stdout

import jax
import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("rosbags")

from jaxtrack import geometry  # noqa: E402
from jaxtrack.io import bags, replay, trajectories  # noqa: E402
from sims import cli  # noqa: E402
from sims.following import lidar  # noqa: E402

CHUNK = 16
# Simulated legs are exact arcs, the geometric detector's model; the learned one (the replay's
# default) is trained on real scans and tested on them (tests/io/test_replay_real.py).
DETECTOR = "geometric"


@pytest.fixture(scope="module")
def recording(following_recording):
    return following_recording


@pytest.fixture(scope="module")
def written(recording, tmp_path_factory):
    _, _, (laser, odom, det) = recording
    root = tmp_path_factory.mktemp("replay")
    paths = {"ros1": root / "run.bag", "ros2": root / "run"}
    bags.write_bag(paths["ros1"], 1, laser=laser, odometry=odom, detections=det)
    bags.write_bag(paths["ros2"], 2, laser=laser, odometry=odom, detections=det)
    return paths


def _furniture(sc):
    # The robot's map of table and chair legs (odometry frame = world frame at the start).
    return sc.furniture_circles()[0]


@pytest.fixture(scope="module")
def memory_tracks(recording):
    sc, _, (laser, odom, det) = recording
    return replay.track(laser, odom, det, "gnn", chunk=CHUNK, progress=False, detector=DETECTOR,
                        static_xy=_furniture(sc))


def _read(path, M):
    return (bags.read_laser(path, "/scan"), bags.read_odometry(path, "/odom"),
            bags.read_detections(path, "/people", M))


@pytest.mark.parametrize("kind", ["ros1", "ros2"])
def test_bag_arrays_equal_the_recording(recording, written, kind):
    _, rec, (laser, odom, det) = recording
    got_l, got_o, got_d = _read(written[kind], det.xy.shape[1])
    # LaserScan ranges are float32 like the simulation: exact. The angles are those of the
    # records (first angle + k * increment, exact), within float32 rounding of the simulation's.
    np.testing.assert_array_equal(got_l.ranges, laser.ranges)
    np.testing.assert_array_equal(got_l.mask, rec.ranges < lidar.LaserConfig().max_range)
    np.testing.assert_array_equal(got_l.angles, laser.angles)
    np.testing.assert_allclose(got_l.angles, rec.angles, rtol=0, atol=1e-6)
    np.testing.assert_allclose(got_l.times, rec.times, rtol=0, atol=1e-9)
    # Odometry is float64 in the message: the float32 simulation values exactly (yaw through
    # the quaternion to 1e-12).
    np.testing.assert_array_equal(got_o.pose[:, :2], rec.odom_pose[:, :2])
    np.testing.assert_allclose(got_o.pose[:, 2], rec.odom_pose[:, 2], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(got_o.twist, rec.odom_twist)
    assert np.array_equal(got_d.mask.sum(1), rec.det_mask.sum(1))
    for t in range(len(rec.times)):
        np.testing.assert_array_equal(got_d.xy[t][got_d.mask[t]], rec.det_xy[t][rec.det_mask[t]])


@pytest.mark.parametrize("kind", ["ros1", "ros2"])
def test_tracker_from_bag_equals_in_memory_and_follows_the_user(recording, written,
                                                                memory_tracks, kind):
    sc, rec, (_, _, det) = recording
    got = replay.track(*_read(written[kind], det.xy.shape[1]), "gnn", chunk=CHUNK,
                       progress=False, detector=DETECTOR, static_xy=_furniture(sc))
    for name in ("ids", "pos", "mask", "user", "user_found", "frames"):
        np.testing.assert_array_equal(getattr(got, name), getattr(memory_tracks, name), name)
    # Independent check against the truth: the user estimate sits on the user (odometry frame
    # = world frame at the start, drifting by less than 0.3 m, see above).
    err = np.linalg.norm(memory_tracks.user - rec.people[:, 0], axis=-1)
    assert np.median(err) < 0.3
    # Confirmed tracks are mostly on true people (furniture legs are filtered by the map).
    pos, mask = memory_tracks.pos, memory_tracks.mask
    d = np.linalg.norm(pos[:, :, None] - rec.people[:, None], axis=-1).min(-1)
    assert np.mean(d[mask] < 0.5) > 0.7


def test_chunking_does_not_change_the_output(recording, memory_tracks):
    sc, _, (laser, odom, det) = recording
    # 30 frames in chunks of 7: four full chunks and a padded one, state carried across.
    got = replay.track(laser, odom, det, "gnn", chunk=7, progress=False, detector=DETECTOR,
                       static_xy=_furniture(sc))
    for name in ("ids", "pos", "mask", "user", "user_found"):
        np.testing.assert_allclose(getattr(got, name), getattr(memory_tracks, name),
                                   rtol=0, atol=1e-6, err_msg=name)


def test_track_rejects_bad_arguments(recording):
    _, _, (laser, odom, det) = recording
    with pytest.raises(ValueError, match="estimator"):
        replay.track(laser, odom, det, "kcf", progress=False, detector=DETECTOR)
    with pytest.raises(ValueError, match="chunk"):
        replay.track(laser, odom, det, "gnn", chunk=0, progress=False, detector=DETECTOR)
    with pytest.raises(ValueError, match="no laser scan"):
        replay.track(laser._replace(valid=np.zeros_like(laser.valid)), progress=False,
                     detector=DETECTOR)


def test_one_laser_fused_with_its_copy_equals_the_laser_alone(recording, written,
                                                            memory_tracks, tmp_path):
    # The copy sees every leg and person the laser sees, at the same place: all merged away
    # (`sensing.SensingConfig.merge_radius`), so the fused replay is the single one. The
    # copy's clock runs 30 % of a period late: aligned to the same scans.
    sc, _, (laser, odom, det) = recording
    furniture = tmp_path / "furniture.txt"
    np.savetxt(furniture, _furniture(sc))
    out = replay.track_bag(written["ros1"], ["/scan", "/scan"], tmp_path / "out",
                           odom_topic="/odom", detections_topic="/people",
                           max_detections=det.xy.shape[1], chunk=CHUNK,
                           static_points=furniture, detector=DETECTOR,
                           laser_mounts=[(0.0, 0.0, 0.0)] * 2, stream=io.StringIO())
    late = laser._replace(times=laser.times + 0.3 * np.median(np.diff(laser.times)))
    mem = replay.track([laser, late], odom, det, "gnn", chunk=CHUNK, progress=False,
                       detector=DETECTOR, static_xy=_furniture(sc),
                       laser_mount=[(0.0, 0.0, 0.0)] * 2)
    assert len(out["reports"]) == 4      # two lasers, odometry, detections
    for got in (out["tracks"], mem):
        for name in ("ids", "pos", "mask", "user", "user_found"):
            np.testing.assert_allclose(getattr(got, name), getattr(memory_tracks, name),
                                       rtol=0, atol=1e-6, err_msg=name)
    with pytest.raises(ValueError, match="2 laser mounts for 3 lasers"):
        replay.track([laser] * 3, laser_mount=[(0, 0, 0)] * 2, progress=False)
    with pytest.raises(TypeError, match="LaserScans"):
        replay.track([], progress=False)
    with pytest.raises(TypeError, match="one bags.LaserScans per recording"):
        replay.track_batch([[laser, laser]], progress=False)


def test_cli_track_needs_one_mount_per_laser_topic(written, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["track", "--bag", str(written["ros1"]), "--laser-topic", "/scan", "/scan",
                  "--laser-mount", "0", "0", "0", "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert "1 --laser-mount for 2 --laser-topic" in capsys.readouterr().err


def test_cli_track_writes_a_mot_csv_and_evaluate_prints_the_summary(recording, written,
                                                                  memory_tracks, tmp_path,
                                                                  capsys):
    sc, rec, (_, _, det) = recording
    out = tmp_path / "out"
    furniture = tmp_path / "furniture.txt"
    np.savetxt(furniture, _furniture(sc))
    code = cli.main(["track", "--bag", str(written["ros1"]), "--laser-topic", "/scan",
                     "--detector", "geometric",
                     "--odom-topic", "/odom", "--detections-topic", "/people",
                     "--max-detections", str(det.xy.shape[1]), "--estimator", "gnn",
                     "--chunk", str(CHUNK), "--static-points", str(furniture),
                     "--out", str(out)])
    assert code == 0
    assert (out / "top_view.png").stat().st_size > 0
    csv = trajectories.read_mot_csv(out / "tracks.csv")
    t = memory_tracks
    want = sorted((int(f), int(i), x, y) for f, ids, pos, m in zip(t.frames, t.ids, t.pos,
                                                                   t.mask)
                  for i, (x, y), k in zip(ids, pos, m) if k)
    have = sorted((int(f), int(i), x, y) for f, ids, pos, m in zip(csv.frames, csv.ids,
                                                                   csv.pos, csv.mask)
                  for i, (x, y), k in zip(ids, pos, m) if k)
    assert [w[:2] for w in want] == [h[:2] for h in have]
    np.testing.assert_allclose([h[2:] for h in have], [w[2:] for w in want], atol=1e-5)
    # Ground truth of the recording in the same layout, then `jaxtrack evaluate`.
    gt = tmp_path / "gt.csv"
    P = rec.people.shape[1]
    trajectories.write_mot_csv(gt, t.frames, np.broadcast_to(np.arange(P), (len(t.frames), P)),
                               rec.people, rec.people_mask)
    capsys.readouterr()
    buf = io.StringIO()
    with redirect_stdout(buf):
        assert cli.main(["evaluate", "--gt", str(gt), "--tracks", str(out / "tracks.csv"),
                         "--threshold", "0.5"]) == 0
    row = trajectories.evaluate_files(gt, out / "tracks.csv", threshold=0.5)
    expected = trajectories.format_summary({gt.parent.name: row})
    assert buf.getvalue().splitlines()[1:] == expected.splitlines()


def test_cli_track_unknown_topic_lists_the_topics(written, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["track", "--bag", str(written["ros2"]), "--laser-topic", "/base_scan",
                  "--out", str(tmp_path)])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "'/base_scan'" in err and "/scan (sensor_msgs/msg/LaserScan)" in err
    with pytest.raises(SystemExit):
        cli.main(["track", "--bag", str(written["ros2"]), "--laser-topic", "/scan",
                  "--detector", "geometric",
                  "--estimator", "kcf", "--out", str(tmp_path)])
    assert "invalid choice: 'kcf'" in capsys.readouterr().err


def test_cli_track_without_rosbags_says_how_to_install_it(written, tmp_path, capsys,
                                                         monkeypatch):
    import sys

    for name in [m for m in sys.modules if m == "rosbags" or m.startswith("rosbags.")]:
        monkeypatch.setitem(sys.modules, name, None)
    with pytest.raises(SystemExit) as exc:
        cli.main(["track", "--bag", str(written["ros2"]), "--laser-topic", "/scan",
                  "--detector", "geometric",
                  "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert 'pip install "jaxtrack[ros]"' in capsys.readouterr().err


def test_laser_only_without_odometry_tracks_in_the_robot_frame(recording):
    _, rec, (laser, _, _) = recording
    # No odometry: the identity pose, so the estimate is in the current robot frame (the
    # seed-002 Kalman filter, which works in that frame anyway). In float64 (the other
    # replays run in float32).
    got = replay.track(laser, None, None, "kf", chunk=CHUNK, progress=False, detector=DETECTOR,
                       dtype=jnp.float64)
    assert got.user.dtype == np.float64 and got.pos.dtype == np.float64
    truth = np.stack([np.asarray(geometry.to_frame(jnp.asarray(r), jnp.asarray(p[0])))
                      for r, p in zip(rec.robot, rec.people)])
    err = np.linalg.norm(got.user - truth, axis=-1)
    assert got.user_found.mean() > 0.5 and np.median(err) < 0.3


def test_track_and_evaluate_run_where_mujoco_cannot_be_imported(recording, written, tmp_path):
    # The replay path never touches MJX: in a fresh interpreter where `import mujoco` fails,
    # the command line still replays the bag and scores it. (The same command as the CLI test
    # above, so that the persistent compilation cache can serve it.)
    sc, _, (_, _, det) = recording
    out = tmp_path / "out"
    furniture = tmp_path / "furniture.txt"
    np.savetxt(furniture, _furniture(sc))
    script = textwrap.dedent(f"""
        import sys
        class NoMuJoCo:
            def find_spec(self, name, path=None, target=None):
                if name.split(".")[0] == "mujoco":
                    raise ImportError("mujoco is not installed here")
        sys.meta_path.insert(0, NoMuJoCo())
        from sims import cli
        assert cli.main(["track", "--bag", {str(written["ros1"])!r}, "--laser-topic", "/scan",
                         "--detector", "geometric",
                         "--odom-topic", "/odom", "--detections-topic", "/people",
                         "--max-detections", "{det.xy.shape[1]}", "--estimator", "gnn",
                         "--chunk", "{CHUNK}", "--static-points", {str(furniture)!r},
                         "--out", {str(out)!r}]) == 0
        assert cli.main(["evaluate", "--gt", {str(out / "tracks.csv")!r},
                         "--tracks", {str(out / "tracks.csv")!r}]) == 0
        assert not any(m.split(".")[0] == "mujoco" for m in sys.modules)
        try:
            import mujoco  # noqa: F401
        except ImportError:
            print("no mujoco")
    """)
    cache = jax.config.jax_compilation_cache_dir
    env = dict(os.environ, JAX_PLATFORMS="cpu", JAX_ENABLE_X64="1",
               JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0.5",
               **({"JAX_COMPILATION_CACHE_DIR": cache} if cache else {}))
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         env=env, cwd=os.path.dirname(os.path.dirname(os.path.dirname(
                             os.path.abspath(__file__)))), timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "no mujoco" in res.stdout
    assert (out / "tracks.csv").stat().st_size > 0


@pytest.fixture(scope="module")
def pan_recording(tmp_path_factory):
    """A recording with the RGB-D camera on the pan unit, the robot not turning, so that the
    camera has to turn to keep the user (their bearing sweeps 1.5 rad in 2 s), written into a
    bag with the pan angle as sensor_msgs/JointState: ``(unit, rec, records, joints, bag)``."""
    from jaxtrack.control import pan_tilt
    from sims.following import recording as rec_mod
    from sims.following import scene

    unit = pan_tilt.PanTiltConfig()
    rec = rec_mod.record(jax.random.PRNGKey(0), scene.build(num_people=3), distractors=2,
                         duration=2.0, pan=unit, max_turn=0.0)
    laser, odom, det = rec_mod.to_records(rec)
    joints = rec_mod.pan_record(rec)
    path = tmp_path_factory.mktemp("pan") / "pan.bag"
    bags.write_bag(path, 1, laser=laser, odometry=odom, detections=det, joints=joints)
    return unit, rec, (laser, odom, det), joints, path


def test_the_pan_angle_is_recorded_on_the_users_bearing_and_read_back_exactly(pan_recording):
    from sims.following import recording as rec_mod

    unit, rec, _, _, path = pan_recording
    assert rec.pan.shape == (20,) and np.all(np.abs(rec.pan) <= unit.limit)
    rel = jax.vmap(geometry.to_frame)(jnp.asarray(rec.robot), jnp.asarray(rec.people[:, 0]))
    bearing = np.arctan2(rel[:, 1], rel[:, 0])
    assert np.ptp(rec.pan) > 1.0
    # The servo lags by about its rate over its gain (here < 0.3 rad).
    assert np.max(np.abs(rec.pan - bearing)) < 0.3
    back = bags.read_joint_states(path, "/joint_states")
    np.testing.assert_array_equal(back.position[:, 0], rec.pan)
    with pytest.raises(ValueError, match="no pan angle"):
        rec_mod.pan_record(rec._replace(pan=None))


def test_the_replayed_pf_turns_its_camera_with_the_recorded_pan(pan_recording):
    # The replayed PF's camera field of view turns with the pan: the output from the bag's
    # angles equals the in-memory replay's, and differs from the camera held straight ahead.
    _, _, (laser, odom, det), joints, path = pan_recording
    back = bags.read_joint_states(path, "/joint_states")
    kw = dict(progress=False, detector=DETECTOR, chunk=CHUNK)
    with_pan = replay.track(laser, odom, det, "pf", pan=joints, **kw)
    again = replay.track(laser, odom, det, "pf", pan=back, **kw)
    np.testing.assert_array_equal(with_pan.user, again.user)
    with pytest.raises(ValueError, match="no joint"):
        replay.track(laser, odom, det, "pf", pan=joints, pan_joint="tilt", **kw)
    ahead = replay.track(laser, odom, det, "pf", **kw)
    assert not np.array_equal(with_pan.user, ahead.user)


def test_a_batch_of_recordings_equals_each_replayed_alone(recording):
    _, _, (laser, odom, _) = recording

    def first(n):
        return laser._replace(times=laser.times[:n], ranges=laser.ranges[:n],
                              mask=laser.mask[:n], valid=laser.valid[:n])

    parts = [laser, first(17)]
    keys = jnp.stack([jax.random.PRNGKey(3), jax.random.PRNGKey(4)])
    batch = replay.track_batch(parts, [odom, odom], "gnn", chunk=CHUNK, keys=keys,
                               progress=False, detector=DETECTOR)
    assert [len(b.times) for b in batch] == [len(laser.times), 17]
    for part, got, key in zip(parts, batch, keys):
        alone = replay.track(part, odom, None, "gnn", chunk=CHUNK, key=key, progress=False,
                             detector=DETECTOR)
        # The vmapped program rounds float32 differently, nothing else.
        np.testing.assert_array_equal(got.ids, alone.ids)
        np.testing.assert_array_equal(got.mask, alone.mask)
        np.testing.assert_allclose(got.pos, alone.pos, atol=1e-4)
        np.testing.assert_allclose(got.user, alone.user, atol=1e-4)
    assert replay.track_batch([], progress=False) == []
    with pytest.raises(ValueError, match="beam counts"):
        replay.track_batch([laser, laser._replace(ranges=laser.ranges[:, :-1],
                                                  angles=laser.angles[:-1],
                                                  mask=laser.mask[:, :-1])],
                           progress=False, detector=DETECTOR)
    with pytest.raises(ValueError, match="odometries"):
        replay.track_batch(parts, [odom], progress=False, detector=DETECTOR)
