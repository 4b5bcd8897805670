"""Recorded ceiling depth images replayed through the humanoid tracker
(`jaxtrack.io.depth_replay`): a simulated episode written as a depth bag replays to the
episode's own track, and ``jaxtrack track --depth-topic`` writes the trajectory."""

import io

import jax
import numpy as np
import pytest

pytest.importorskip("rosbags")

from jaxtrack.io import bags, depth_replay  # noqa: E402
from jaxtrack.tracking import humanoid  # noqa: E402
from sims import cli  # noqa: E402
from sims.humanoid import episode, recording, scene, sensor  # noqa: E402

TRACKER = humanoid.DepthPFConfig(num_particles=16)
MAX_POINTS = 48


@pytest.fixture(scope="module")
def recorded():
    sc = scene.build(40, 30)
    cfg = episode.EpisodeConfig(sc, TRACKER, num_frames=24, max_points=MAX_POINTS)
    params = episode.seed_task_params()[3]
    rec = recording.record(jax.random.PRNGKey(3), cfg, params)
    return sc, params, rec


@pytest.fixture(scope="module")
def bag(recorded, tmp_path_factory):
    _, _, rec = recorded
    path = tmp_path_factory.mktemp("depth") / "walk"
    bags.write_bag(path, 2, depth=recording.to_records(rec))      # ROS 2, 32FC1
    return path


def _replay(images, sc, params, rec, **kw):
    n = min(MAX_POINTS, sensor.window_size(sc.camera) ** 2)
    return depth_replay.track_depth(images, sensor.ceiling_camera(sc.camera), rec.start,
                                    TRACKER, params=params.tracker, keys=rec.tracker_keys,
                                    init_key=rec.tracker_init_key, turn_rate=rec.turn_rate,
                                    max_points=n, progress=False, **kw)


def test_the_replayed_bag_gives_the_episodes_own_track(recorded, bag):
    sc, params, rec = recorded
    images = bags.read_depth(bag, "/camera/depth/image_raw")
    np.testing.assert_array_equal(images.depth, rec.depth)
    out = _replay(images, sc, params, rec, chunk=7)      # 24 frames: three chunks and a pad
    # Equal within float rounding: the window's depth is recovered from its back-projected
    # heights (c_z - (c_z - z)), which rounds.
    np.testing.assert_allclose(out.pose, rec.estimate, rtol=0, atol=1e-5)
    # And the episode's tracker did track the robot.
    assert np.median(np.linalg.norm(out.pose[:, :2] - rec.truth[:, :2], axis=-1)) < 0.06
    assert np.all(out.num_points > 0) and np.all(out.num_points <= MAX_POINTS)


def test_cli_track_depth_topic_writes_the_trajectory(recorded, bag, tmp_path):
    sc, _, rec = recorded
    cam = sc.camera
    buf = io.StringIO()
    from contextlib import redirect_stdout

    with redirect_stdout(buf):
        code = cli.main(["track", "--bag", str(bag), "--depth-topic", "/camera/depth/image_raw",
                         "--camera-position", *map(str, cam.position), "--focal", str(cam.fx),
                         str(cam.fy), "--start", *map(str, rec.start), "--max-points",
                         str(MAX_POINTS), "--out", str(tmp_path / "out")])
    assert code == 0 and "tracked with pf" in buf.getvalue()
    rows = np.loadtxt(tmp_path / "out" / "trajectory.csv", delimiter=",", skiprows=1)
    assert rows.shape == (len(rec.times), 4)
    np.testing.assert_allclose(rows[:, 0], rec.times, atol=1e-6)
    # Its own keys and the default tracker (128 particles): near the truth, not the episode.
    err = np.linalg.norm(rows[:, 1:3] - rec.truth[:, :2], axis=-1)
    assert np.median(err) < 0.06
    assert (tmp_path / "out" / "top_view.png").stat().st_size > 0


@pytest.mark.parametrize("args, message", [
    ([], "needs --camera-position"),
    (["--camera-position", "0", "0", "-1", "--focal", "30", "30"], "above the floor"),
    (["--camera-position", "0", "0", "2", "--focal", "30", "nan"], "finite"),
    (["--camera-position", "0", "0", "2", "--focal", "30", "30", "--laser-topic", "/scan"],
     "not both"),
])
def test_cli_depth_topic_bad_arguments_exit_2(bag, tmp_path, capsys, args, message):
    with pytest.raises(SystemExit) as exc:
        cli.main(["track", "--bag", str(bag), "--depth-topic", "/camera/depth/image_raw",
                  *args, "--out", str(tmp_path)])
    assert exc.value.code == 2 and message in capsys.readouterr().err


def test_track_depth_refuses_bad_inputs(recorded):
    sc, params, rec = recorded
    images = recording.to_records(rec)
    cam = sensor.ceiling_camera(sc.camera)
    with pytest.raises(ValueError, match="no depth image"):
        depth_replay.track_depth(images._replace(valid=np.zeros(len(rec.times), bool)), cam,
                                 progress=False)
    with pytest.raises(ValueError, match="one key per image"):
        depth_replay.track_depth(images, cam, rec.start, keys=rec.tracker_keys[:3],
                                 progress=False)
    with pytest.raises(TypeError, match="CeilingCamera"):
        depth_replay.track_depth(images, (0, 0, 3), progress=False)
    with pytest.raises(ValueError, match="above the floor"):
        depth_replay.track_depth(images, cam._replace(position=(0.0, 0.0, -1.0)),
                                 progress=False)
    with pytest.raises(ValueError, match="unknown tracker"):
        depth_replay.track_depth(images, cam, rec.start, "kcf", progress=False)
    with pytest.raises(ValueError, match="first image has no point"):
        empty = images._replace(mask=np.zeros_like(images.mask))
        depth_replay.track_depth(empty, cam, progress=False)

