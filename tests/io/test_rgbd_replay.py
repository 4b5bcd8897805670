"""Recorded RGB-D replayed through the people detector and tracker (`jaxtrack.io.rgbd_replay`):
a simulated episode of `sims.following.crowd` written as a PointCloud2 bag and as a depth + colour
bag replays to the episode's own detections and tracks; back-projection against a per-pixel loop;
pairing by time; ``jaxtrack track --cloud-topic`` / ``--rgbd-topics``."""

import dataclasses
import io
import math
from contextlib import redirect_stdout

import jax
import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("rosbags")

from jaxtrack.io import bags, rgbd_replay, trajectories  # noqa: E402
from jaxtrack.perception import hog, rgbd_people  # noqa: E402
from sims import cli  # noqa: E402
from sims.following import crowd, kinect  # noqa: E402

# 64 x 48 pixels, 20 frames, 4-6 people: seed 11 has three people tracked (36 detections, two
# under the confidence threshold, none within 0.008 of it). 12 tracks and chunks of 6 frames
# (three chunks and a padded one): the command line's defaults but --chunk, so one compiled
# chunk serves every replay of this file.
CFG = crowd.CrowdConfig(duration=2.0, camera=kinect.KinectConfig(width=64, height=48),
                        min_people=4)
SEED, CHUNK = 11, 6
CLOUDS, DEPTH, COLOUR = "/camera/depth/points", "/camera/depth/image_raw", "/camera/color/image_raw"
# uint8 -> float32 as the readers decode it: k / 255 rounded once (a jitted k / 255 becomes
# k * (1 / 255), one ulp off for 60 % of the values).
LEVELS = np.arange(256, dtype=np.float32) / np.float32(255)


@pytest.fixture(scope="module")
def episode():
    """The episode's record (`crowd.frames`), with what its Kinect sensed in every frame.

    A camera's rgb8 image holds 8 bits per channel, the simulation's colour float32: the
    episode here runs with its colour image rounded to 8 bits, so that the bags hold exactly
    what its detector saw. Each frame's depth, mask and colour leave the compiled episode
    through an ordered callback."""
    sensed = []
    sense = crowd.sense

    def sense_8bit(key, cfg, robot, people_state, people, scene):
        z = sense(key, cfg, robot, people_state, people, scene)
        colour = jnp.asarray(LEVELS)[jnp.round(z.colour * 255).astype(jnp.int32)]
        z = z._replace(colour=colour, points_rgb=colour.reshape(-1, 3))
        jax.debug.callback(lambda *a: sensed.append([np.asarray(x) for x in a]),
                           z.depth, z.valid, colour, ordered=True)
        return z

    key = jax.random.PRNGKey(SEED)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(crowd, "sense", sense_8bit)
        rec = jax.jit(lambda k: crowd.frames(k, CFG, crowd.Pipeline(), hog.load_svm()))(key)
        rec = jax.tree_util.tree_map(np.asarray, rec)
    depth, valid, colour = (np.stack(x) for x in zip(*sensed))
    # The detector's keys: frames() splits its key in three, the third into one key per
    # frame, and each frame's in two (sensing, detection).
    T = CFG.num_frames
    frame_keys = jax.random.split(jax.random.split(key, 3)[2], T)
    det_keys = jnp.stack([jax.random.split(k)[1] for k in frame_keys])
    return rec, depth, valid, colour, det_keys


@pytest.fixture(scope="module")
def recorded(episode, tmp_path_factory):
    """The episode as a ROS 1 bag of organised PointCloud2 in the optical frame and as a ROS 2
    bag of 32FC1 depth + bgr8 colour images, both with the robot's odometry."""
    rec, depth, valid, colour, _ = episode
    T, H, W = depth.shape
    times = 1000.0 + np.arange(T) / CFG.rate
    rays = np.asarray(kinect.rays(CFG.camera, jnp.eye(3, dtype=jnp.float32))).reshape(-1, 3)
    z = np.where(valid, depth, 0).reshape(T, -1, 1)
    clouds = bags.PointClouds(times, (z * rays).astype(np.float32), colour.reshape(T, -1, 3),
                              valid.reshape(T, -1), np.ones(T, bool), None, (H, W))
    odom = bags.Odometry(times, rec["robot"].astype(np.float64), np.zeros((T, 3)),
                         np.ones(T, bool))
    root = tmp_path_factory.mktemp("rgbd")
    cloud_bag = bags.write_bag(root / "clouds.bag", 1, clouds=clouds, odometry=odom)
    # 32FC1 holds the simulated float32 depth exactly (16UC1 would round it to millimetres).
    images = bags.DepthImages(times, np.where(valid, depth, 0), valid, np.ones(T, bool))
    rgbd_bag = bags.write_bag(root / "rgbd", 2, depth=images, odometry=odom,
                              colour=bags.ColourImages(times, colour, np.ones(T, bool)),
                              colour_encoding="bgr8")
    return cloud_bag, rgbd_bag


def _camera():
    return rgbd_replay.mount(CFG.camera.mount, CFG.camera.tilt)


def test_the_simulated_robots_mount_detector_and_tracker_are_the_defaults():
    eye, rot = kinect.mount_pose(CFG.camera)
    cam = _camera()
    np.testing.assert_array_equal(cam.position, eye)
    np.testing.assert_array_equal(cam.rotation, rot)
    assert crowd.Pipeline().detector() == rgbd_people.RGBDPeopleConfig()
    ours = rgbd_replay.tracker_params(1.0 / CFG.rate, capacity=CFG.tracks)
    theirs = crowd.Pipeline().tracker(CFG)
    assert ours.config == theirs.config
    for a, b in zip(ours, theirs):
        np.testing.assert_array_equal(a, b)
    # Ahead, 5 degrees down; the optical y axis points down and to the ground.
    np.testing.assert_allclose(cam.rotation[:, 2], [math.cos(CFG.camera.tilt), 0,
                                                    -math.sin(CFG.camera.tilt)], atol=1e-7)
    assert cam.rotation[2, 1] < 0


def test_the_replayed_bags_give_the_episodes_detections_and_tracks(episode, recorded):
    rec, _, _, colour, det_keys = episode
    cloud_bag, rgbd_bag = recorded
    T, H, W = colour.shape[:3]
    from_clouds = bags.read_point_clouds(cloud_bag, CLOUDS)
    from_images = rgbd_replay.rgbd_clouds(bags.read_depth(rgbd_bag, DEPTH),
                                          bags.read_colour(rgbd_bag, COLOUR), CFG.camera.focal)
    # Both bags give the same cloud, the episode's colours exactly.
    assert from_clouds.image_shape == from_images.image_shape == (H, W)
    for field in ("points", "colours", "mask", "times"):
        np.testing.assert_array_equal(getattr(from_clouds, field), getattr(from_images, field))
    np.testing.assert_array_equal(from_clouds.colours.reshape(colour.shape), colour)

    cam = CFG.camera
    eye, rot = jax.vmap(lambda p: kinect.camera_pose(cam, p))(jnp.asarray(rec["robot"]))
    in_view = jax.vmap(lambda e, r, xy: crowd._in_view(cam, e, r, xy))
    for clouds, bag in ((from_clouds, cloud_bag), (from_images, rgbd_bag)):
        out = rgbd_replay.track_rgbd(clouds, _camera(), focal=cam.focal, keys=det_keys,
                                     odometry=bags.read_odometry(bag, "/odom"), chunk=CHUNK,
                                     progress=False)
        assert out.ids.shape == (T, CFG.tracks) and out.detections.shape[0] == T
        # Detections: the same people kept, at the same places to float rounding (the cloud
        # is rotated into the base frame as p R^T + e, the simulation as e + z (d R^T)).
        np.testing.assert_array_equal(out.det_mask, rec["det_mask"])
        m = rec["det_mask"]
        assert m.sum() == 36
        np.testing.assert_allclose(out.detections[m], rec["detections"][m], rtol=0, atol=1e-5)
        # The HOG confidence moves by up to 1e-3 with boxes moved by 1e-5 pixels (its
        # orientation bins are hard).
        np.testing.assert_allclose(out.confidence, rec["confidence"], rtol=0, atol=2e-3)
        # Tracks: the episode reports its confirmed tracks in the camera's view.
        shown = out.mask & np.asarray(in_view(eye, rot, jnp.asarray(out.pos, jnp.float32)))
        np.testing.assert_array_equal(shown, rec["track_mask"])
        np.testing.assert_array_equal(out.ids[shown], rec["track_id"][shown])
        np.testing.assert_allclose(out.pos[shown], rec["track_pos"][shown], rtol=0, atol=1e-5)
        assert len(np.unique(out.ids[shown])) == 3
        np.testing.assert_array_equal(out.num_points, clouds.mask.sum(1))


def test_depth_cloud_against_per_pixel_back_projection():
    rng = np.random.default_rng(0)
    H, W = 5, 7
    depth = rng.uniform(0.4, 5.0, (H, W)).astype(np.float32)
    depth[0, 0], depth[1, 2], depth[3, 4], depth[4, 6] = 0.0, np.nan, -1.0, np.inf
    colour = rng.uniform(0, 1, (H, W, 3)).astype(np.float32)
    mask = np.ones((H, W), bool)
    mask[2, 3] = False
    focal, principal = (6.5, 5.5), (3.2, 2.6)
    pts, rgb, ok = (np.asarray(a) for a in
                    rgbd_replay.depth_cloud(depth, focal, principal, colour, mask))
    for i in range(H):
        for j in range(W):
            k = i * W + j
            z = float(depth[i, j])
            good = math.isfinite(z) and z > 0 and mask[i, j]
            assert ok[k] == good
            want = ([z * (j + 0.5 - principal[0]) / focal[0],
                     z * (i + 0.5 - principal[1]) / focal[1], z] if good else [0.0, 0.0, 0.0])
            np.testing.assert_allclose(pts[k], want, rtol=1e-6, atol=1e-7)
            np.testing.assert_array_equal(rgb[k], colour[i, j])
    # Without colour: zeros. The principal point at the image's centre puts the central
    # pixels' rays either side of the axis.
    _, rgb, _ = rgbd_replay.depth_cloud(depth, focal, (W / 2, H / 2))
    assert not np.asarray(rgb).any()
    with pytest.raises(ValueError, match=r"colour must be \[5, 7, 3\]"):
        rgbd_replay.depth_cloud(depth, focal, principal, colour[:, :3])


def test_rgbd_clouds_pairs_by_nearest_time_and_leaves_out_the_unpaired():
    H, W = 2, 3
    dt = np.array([10.0, 10.1, 10.2, 10.3])
    ct = np.array([9.98, 10.13, 10.21, 10.45, 10.5])    # none within 0.05 s of 10.3
    depth = bags.DepthImages(dt, np.full((4, H, W), 2.0, np.float32), np.ones((4, H, W), bool),
                             np.ones(4, bool),
                             bags.BagReport("x.bag", DEPTH, bags.IMAGE, 4, 0, None, ""))
    colour = bags.ColourImages(ct, np.broadcast_to(np.arange(5, dtype=np.float32)[:, None, None,
                                                                                  None] / 8,
                                                   (5, H, W, 3)).copy(), np.ones(5, bool))
    out = rgbd_replay.rgbd_clouds(depth, colour, (2.0, 2.0))
    np.testing.assert_array_equal(out.times, dt[:3])
    np.testing.assert_array_equal(out.colours[:, 0, 0], np.array([0, 1, 2]) / 8)
    assert out.report.dropped == 1 and "1 depth images without a colour" in out.report.detail
    assert out.image_shape == (H, W) and out.mask.all()
    # A looser tolerance pairs the last one too; none pairs nothing: zero frames.
    assert rgbd_replay.rgbd_clouds(depth, colour, (2.0, 2.0), tolerance=0.2).times.size == 4
    empty = rgbd_replay.rgbd_clouds(depth, colour._replace(times=ct + 100), (2.0, 2.0))
    assert empty.points.shape == (0, H * W, 3)
    with pytest.raises(ValueError, match="registered"):
        rgbd_replay.rgbd_clouds(depth, colour._replace(colour=colour.colour[:, :1]), (2.0, 2.0))


def test_track_rgbd_empty_input_and_bad_inputs(recorded):
    clouds = bags.read_point_clouds(recorded[0], CLOUDS)
    cam = _camera()
    none = rgbd_replay.track_rgbd(clouds._replace(valid=np.zeros(len(clouds.times), bool)), cam,
                                  progress=False)
    assert none.ids.shape == (0, 12) and none.detections.shape == (0, 16, 2)
    assert none.times.shape == (0,)
    with pytest.raises(TypeError, match="Mount"):
        rgbd_replay.track_rgbd(clouds, (0.0, 0.0, 1.0), progress=False)
    with pytest.raises(ValueError, match="rotation matrix"):
        rgbd_replay.track_rgbd(clouds, cam._replace(rotation=2 * cam.rotation), progress=False)
    with pytest.raises(ValueError, match="one key per valid cloud"):
        rgbd_replay.track_rgbd(clouds, cam, keys=jax.random.split(jax.random.PRNGKey(0), 3),
                               progress=False)
    with pytest.raises(ValueError, match="num_features"):
        params = rgbd_replay.tracker_params(0.1)
        rgbd_replay.track_rgbd(clouds, cam, progress=False, params=params._replace(
            config=dataclasses.replace(params.config, num_features=8)))
    with pytest.raises(ValueError, match="cloud_frame"):
        rgbd_replay.track_rgbd(clouds, cam, cloud_frame="camera", progress=False)
    with pytest.raises(ValueError, match="position must be"):
        rgbd_replay.mount((0.0, 1.0))


def _run_cli(args):
    buf = io.StringIO()
    with redirect_stdout(buf):
        code = cli.main(["track", *map(str, args)])
    return code, buf.getvalue()


def test_cli_rgbd_topics_and_cloud_topic_write_the_tracks(recorded, tmp_path):
    cloud_bag, rgbd_bag = recorded
    cam = CFG.camera
    common = ["--focal", *cam.focal, "--mount", *cam.mount, "--tilt",
              math.degrees(cam.tilt), "--odom-topic", "/odom", "--chunk", CHUNK]
    code, text = _run_cli(["--bag", rgbd_bag, "--rgbd-topics", DEPTH, COLOUR, *common,
                           "--out", tmp_path / "rgbd"])
    assert code == 0 and "20 RGB-D frames" in text and "HOG confidence on" in text
    code, _ = _run_cli(["--bag", cloud_bag, "--cloud-topic", CLOUDS, *common,
                        "--out", tmp_path / "cloud"])
    assert code == 0
    # The command line's replay (its own keys, seed 0) is `track_rgbd`'s, and both bags give it.
    clouds = bags.read_point_clouds(cloud_bag, CLOUDS)
    want = rgbd_replay.track_rgbd(clouds, _camera(), focal=cam.focal, chunk=CHUNK,
                                  odometry=bags.read_odometry(cloud_bag, "/odom"),
                                  progress=False)
    trajectories.write_mot_csv(tmp_path / "want.csv", want.frames, want.ids, want.pos, want.mask)
    expected = (tmp_path / "want.csv").read_text()
    assert expected.count("\n") > 20
    for name in ("rgbd", "cloud"):
        assert (tmp_path / name / "tracks.csv").read_text() == expected
        assert (tmp_path / name / "top_view.png").stat().st_size > 0


@pytest.mark.parametrize("args, message", [
    (["--cloud-topic", CLOUDS, "--rgbd-topics", DEPTH, COLOUR, "--mount", 0, 0, 1],
     "give --cloud-topic or --rgbd-topics, not both"),
    (["--cloud-topic", CLOUDS, "--laser-topic", "/scan", "--mount", 0, 0, 1],
     "give --laser-topic or --cloud-topic, not both"),
    (["--rgbd-topics", DEPTH, COLOUR, "--depth-topic", DEPTH, "--mount", 0, 0, 1],
     "give --depth-topic or --rgbd-topics, not both"),
    (["--cloud-topic", CLOUDS], "needs --mount X Y Z"),
    (["--rgbd-topics", DEPTH, COLOUR, "--mount", 0, 0, 1], "needs --focal"),
    (["--cloud-topic", CLOUDS, "--mount", 0, 0, "nan"], "must be finite"),
    (["--cloud-topic", CLOUDS, "--mount", 0, 0, 1, "--focal", 50, -1], "--focal must be positive"),
    (["--cloud-topic", CLOUDS, "--mount", 0, 0, 1, "--bag", "/nonexistent/run.bag"],
     "--bag /nonexistent/run.bag does not exist"),
    (["--cloud-topic", "/nope", "--mount", 0, 0, 1], "topic '/nope' is not in"),
    (["--rgbd-topics", DEPTH, "/odom", "--mount", 0, 0, 1, "--focal", 50, 50],
     "carries nav_msgs/msg/Odometry"),
])
def test_cli_rgbd_bad_arguments_exit_2_with_one_line(recorded, tmp_path, capsys, args, message):
    bag = recorded[1] if "--rgbd-topics" in args else recorded[0]
    with pytest.raises(SystemExit) as exc:
        cli.main(["track", "--bag", str(bag), *map(str, args), "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and message in err, err
    assert err.startswith("jaxtrack track: ") and err.count("\n") == 1
