"""People walking near the humanoid (seed 000 section 5.6): their paths, their occlusion of the
robot in the depth image, and the episode that runs among them."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.tracking import humanoid
from sims import cli
from sims.humanoid import episode, gait, scene, sensor


def test_walkers_pace_beside_the_route_at_their_speed():
    start, target = jnp.array([0.0, 0.0, 0.0]), jnp.array([1.0, 0.5, 0.0])
    dt, speed = 0.25, 0.8
    xy = np.asarray(episode.walker_positions(jax.random.PRNGKey(0), start, target, 6, 400, dt,
                                             speed))
    assert xy.shape == (400, 6, 2)
    step = np.linalg.norm(np.diff(xy, axis=0), axis=-1) / dt
    # A triangle wave: the speed except in the frames that hold a turn.
    assert np.mean(np.abs(step - speed) < 1e-4) > 0.9 and np.all(step <= speed + 1e-4)
    # Each paces a 3 m segment whose middle lies 0.25-0.8 m beside the route (sampled every
    # 0.2 m of walking, so the ends are seen to within 0.1 m).
    centre = 0.5 * (xy.min(0) + xy.max(0))
    extent = np.linalg.norm(xy.max(0) - xy.min(0), axis=-1)
    assert np.all((extent > 2.8) & (extent < 3.0 + 1e-4))
    route = np.asarray(target[:2] - start[:2])
    normal = np.array([-route[1], route[0]]) / np.linalg.norm(route)
    off = np.abs(centre @ normal)
    along = (centre @ route) / (route @ route)
    assert np.all((off > 0.25 - 0.1) & (off < 0.8 + 0.1))
    assert np.all((along > 0.2 - 0.1) & (along < 0.8 + 0.1))


def test_a_walker_between_the_camera_and_the_robot_hides_it():
    sc = scene.build(80, 60)
    gp = gait.GaitParams()
    pose = jnp.array([1.3, 0.9, 0.4])
    g = gait.init(pose, gp)
    xpos, xmat = scene.pose_geoms(sc, gait.qpos(sc, g, gp))
    truth = gait.torso_pose(g, gp)
    k = sensor.window_size(sc.camera)
    bg = sensor.background(sc)
    # The camera is at (0.5, 0.5, 2.8): a person 0.35 m from the robot towards it stands in
    # the line of sight of the robot's nearer half.
    towards = np.asarray(sc.camera.position[:2]) - np.asarray(pose[:2])
    near = np.asarray(pose[:2]) + 0.35 * towards / np.linalg.norm(towards)
    far = np.asarray(pose[:2]) - 0.6 * towards / np.linalg.norm(towards)

    @jax.jit
    def cloud(walkers):
        occ = episode._walker_geoms(walkers, jnp.float32)
        return sensor.robot_point_cloud(jax.random.PRNGKey(0), sc, xpos, xmat, truth, k, bg,
                                        sensor.DepthNoise(dropout=0.0), occluders=occ)

    def robot_points(walker):
        pts, mask = cloud(jnp.asarray([walker], jnp.float32))
        pts, mask = np.asarray(pts), np.asarray(mask)
        robot = mask & (pts[:, 2] < 0.7) & (np.linalg.norm(pts[:, :2] - pose[:2], axis=1) < 0.25)
        return int(robot.sum()), pts[mask]

    alone, _ = robot_points([10.0, 10.0])         # far outside the window
    hidden, seen = robot_points(near)
    behind, _ = robot_points(far)
    assert alone > 20 and hidden < 0.7 * alone and behind == alone
    # What the occluder shows is high (its head and shoulders) or its camera-facing side.
    assert np.any(seen[:, 2] > 1.0)


def test_an_episode_among_two_walkers_runs_and_the_command_checks_the_count(capsys):
    cfg = episode.EpisodeConfig(scene.build(24, 18), humanoid.DepthPFConfig(num_particles=16),
                                num_frames=12, max_points=32, walkers=2)
    m = jax.jit(episode.make_episode(cfg))(jax.random.PRNGKey(0), episode.seed_task_params()[0])
    assert np.all(np.isfinite(np.asarray(m["pos_err"])))
    assert float(m["pos_err_median"]) < 0.15
    with pytest.raises(SystemExit) as exc:
        cli.main(["run", "humanoid-reach", "--walkers", "-1"])
    assert exc.value.code == 2 and "--walkers" in capsys.readouterr().err
    assert math.isfinite(float(m["frames_to_stop"]))
