"""Scene, renderer and gait of the humanoid sim (small resolution; analytic renderer vs mjx.ray)."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from sims.humanoid import gait, scene, sensor


@pytest.fixture(scope="module")
def sc():
    return scene.build(16, 12)


@pytest.fixture(scope="module")
def walking_qpos(sc):
    """qpos of a noisy walk, every few sub-steps (one compile for the module)."""
    params = gait.GaitParams()

    @jax.jit
    def roll(key):
        def body(st, k):
            st = gait.step(k, st, jnp.array([0.1, 0.03]), 0.2, False, params)
            return st, (gait.qpos(sc, st, params), gait.feet(st, params),
                        gait.torso_pose(st, params))
        return jax.lax.scan(body, gait.init(jnp.array([0.2, 0.1, 0.3])), jax.random.split(key, 60))

    return jax.tree_util.tree_map(np.asarray, roll(jax.random.PRNGKey(3))[1])


def _kinematics(sc, q):
    d = mujoco.MjData(sc.model)
    d.qpos[:] = q
    mujoco.mj_kinematics(sc.model, d)
    return d


def test_humanoid_is_nao_sized_and_ray_castable(sc, walking_qpos):
    d = _kinematics(sc, walking_qpos[0][0])
    top = max(d.geom_xpos[g][2] + sc.model.geom_rbound[g] for g in sc.robot_geoms)
    assert 0.55 < top < 0.60
    # All primitives MJX's ray handles; a material on every robot geom.
    assert set(sc.model.geom_type[sc.robot_geoms]) <= {2, 3, 4, 6}
    assert np.all(sc.model.geom_matid[sc.robot_geoms] >= 0)
    # Shoulders + arms about 0.27 m across.
    left = d.geom_xpos[sc.model.geom("l_upper_arm").id]
    right = d.geom_xpos[sc.model.geom("r_upper_arm").id]
    width = np.linalg.norm(left - right) + 2 * 0.03
    assert 0.24 < width < 0.30
    assert 2.5 <= sc.camera.position[2] <= 3.0


def test_leg_inverse_kinematics_puts_the_ankles_on_the_footsteps(sc, walking_qpos):
    qs, ft, _ = walking_qpos
    for i in range(0, len(qs), 5):
        d = _kinematics(sc, qs[i])
        for j, side in enumerate("lr"):
            bid = sc.model.body(f"{side}_foot").id
            target = [ft[i, j, 0], ft[i, j, 1], ft[i, j, 2] + sc.body.ankle_height]
            np.testing.assert_allclose(d.xpos[bid], target, atol=1e-5)
            np.testing.assert_allclose(d.xmat[bid].reshape(3, 3)[:, 2], [0, 0, 1], atol=1e-5)


def test_mjx_kinematics_matches_mujoco(sc, walking_qpos):
    q = walking_qpos[0][17]
    xpos, xmat = jax.jit(lambda q: scene.pose_geoms(sc, q))(jnp.asarray(q, jnp.float32))
    d = _kinematics(sc, q)
    np.testing.assert_allclose(xpos, d.geom_xpos, atol=1e-5)
    np.testing.assert_allclose(np.asarray(xmat).reshape(-1, 9), d.geom_xmat, atol=1e-5)


def test_renderer_matches_mjx_ray_to_a_millimetre(sc, walking_qpos):
    """Rays at the robot from the camera (every geom type) plus the full 16 x 12 image."""
    rng = np.random.default_rng(0)
    origin = np.asarray(sc.camera.position)
    worst = 0.0
    cast = jax.jit(jax.vmap(lambda md, v: mjx.ray(sc.mjx_model, md, jnp.asarray(origin), v)[0],
                            (None, 0)))
    ours_fn = jax.jit(lambda dirs, xpos, xmat: sensor.ray_distances(
        jnp.asarray(origin), dirs, sc.model.geom_type, jnp.asarray(sc.model.geom_size), xpos,
        xmat))
    for i in (5, 23, 41):
        q = walking_qpos[0][i]
        d = _kinematics(sc, q)
        centre = q[:3] + np.array([0, 0, 0.1])
        aims = centre + rng.uniform([-0.2, -0.2, -0.3], [0.2, 0.2, 0.3], (400, 3))
        dirs = aims - origin
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        full, _ = scene.camera_rays(sc.camera, jnp.float64)
        dirs = np.concatenate([dirs, np.asarray(full).reshape(-1, 3)])
        ours = ours_fn(jnp.asarray(dirs), jnp.asarray(d.geom_xpos),
                       jnp.asarray(d.geom_xmat.reshape(-1, 3, 3)))
        ref = cast(mjx.put_data(sc.model, d), jnp.asarray(dirs))
        ours, ref = np.asarray(ours), np.asarray(ref)
        hit_ref = ref >= 0
        np.testing.assert_array_equal(np.isfinite(ours), hit_ref)
        worst = max(worst, np.max(np.abs(ours[hit_ref] - ref[hit_ref])))
        robot_hits = np.sum(ours[:400] < origin[2] - 0.1)
        assert robot_hits > 50
    assert worst < 1e-3


def test_window_render_equals_full_render_and_has_finite_gradients(sc, walking_qpos):
    bg = sensor.background(sc)
    k = sensor.window_size(sc.camera)
    q = jnp.asarray(walking_qpos[0][30], jnp.float32)

    def window(q):
        xpos, xmat = scene.pose_geoms(sc, q)
        return sensor.render_window(sc, xpos, xmat, q[:2], k, bg)

    win = jax.jit(window)(q)
    full = jax.jit(lambda q: sensor.render(sc, *scene.pose_geoms(sc, q)))(q)
    r, c = int(win.row), int(win.col)
    np.testing.assert_allclose(win.depth, full[r:r + k, c:c + k], atol=1e-5)
    outside = np.ones(full.shape, bool)
    outside[r:r + k, c:c + k] = False
    np.testing.assert_allclose(np.asarray(full)[outside], np.asarray(bg)[outside], atol=1e-5)
    assert np.min(full) < 2.5  # the robot is in the image

    # Gradients w.r.t. the geom poses (the chain through mjx.kinematics is plain JAX, but its
    # reverse-mode compile takes about a minute on this CPU, too slow for CI).
    xpos, xmat = jax.jit(lambda q: scene.pose_geoms(sc, q))(q)

    def loss(xpos, xmat):
        depth = sensor.render_window(sc, xpos, xmat, q[:2], k, bg).depth
        return jnp.sum(jnp.where(depth < 2.7, depth, 0.0))

    gp, gm = jax.jit(jax.grad(loss, (0, 1)))(xpos, xmat)
    assert np.all(np.isfinite(gp)) and np.all(np.isfinite(gm))
    assert np.any(gp[sc.robot_geoms] != 0)


def test_back_projection_and_floor_removal(sc, walking_qpos):
    q = jnp.asarray(walking_qpos[0][10], jnp.float32)
    depth = jax.jit(lambda q: sensor.render(sc, *scene.pose_geoms(sc, q)))(q)
    valid = jnp.isfinite(depth)
    pts = sensor.back_project(sc.camera, depth, valid)
    keep = sensor.remove_floor(pts, valid)
    floor = np.asarray(pts)[~np.asarray(keep)]
    np.testing.assert_allclose(floor[:, 2], 0.0, atol=1e-4)
    robot = np.asarray(pts)[np.asarray(keep)]
    assert len(robot) >= 1
    assert np.all(robot[:, 2] < 0.6)
    assert np.all(np.linalg.norm(robot[:, :2] - np.asarray(q[:2]), axis=1) < 0.3)


def test_kinect_noise_grows_with_depth_and_drops_pixels():
    depth = jnp.concatenate([jnp.full((20000,), 1.0), jnp.full((20000,), 3.0)])
    noisy, valid = sensor.add_noise(jax.random.PRNGKey(0), depth,
                                    sensor.DepthNoise(quant_coef=1e-6, dropout=0.1))
    noisy, valid = np.asarray(noisy), np.asarray(valid)
    std_near = np.std(noisy[:20000][valid[:20000]] - 1.0)
    std_far = np.std(noisy[20000:][valid[20000:]] - 3.0)
    np.testing.assert_allclose(std_near, 1.43e-3, rtol=0.05)
    np.testing.assert_allclose(std_far, 1.43e-3 * 9, rtol=0.05)
    assert 0.08 < 1 - valid.mean() < 0.12
    quant, _ = sensor.add_noise(jax.random.PRNGKey(1), jnp.full((100,), 2.8),
                                sensor.DepthNoise(sigma_coef=0.0, dropout=0.0))
    step = 2.9e-3 * 2.8 ** 2
    np.testing.assert_allclose(np.asarray(quant) / step, np.round(np.asarray(quant) / step),
                               atol=1e-3)


def test_lipm_gait_sways_and_tracks_the_commanded_speed(sc):
    params = gait.GaitParams(stride_noise=0.0, heading_noise=0.0, slip_noise=0.0)

    @jax.jit
    def roll(v):
        def body(st, k):
            st = gait.step(k, st, v, 0.0, False, params)
            return st, gait.torso_pose(st, params)
        return jax.lax.scan(body, gait.init(jnp.zeros(3)), jax.random.split(jax.random.PRNGKey(0), 200))[1]

    poses = np.asarray(roll(jnp.array([0.1, 0.0])))
    sway = poses[100:, 1]
    assert 0.02 < (sway.max() - sway.min()) / 2 < 0.045
    speed = (poses[-1, 0] - poses[100, 0]) / (99 * 0.05)
    np.testing.assert_allclose(speed, 0.1, rtol=0.05)
    yaw = poses[100:, 2]
    assert 0.03 < np.max(np.abs(yaw)) < 0.07   # 3-deg wobble
