"""Derivatives of the humanoid closed loop: the point cloud's derivative with respect to the
robot's pose (against finite differences averaged over the pixel grid's phase) and a short
closed-loop gradient against central finite differences (common random numbers)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.control import pose as control
from jaxtrack.tracking import humanoid
from sims.humanoid import episode, gait, scene, sensor

F64 = jnp.float64


@pytest.fixture(scope="module")
def sc():
    return scene.build(32, 24)


@pytest.fixture(scope="module")
def probe(sc):
    """One compiled function: for a batch of (key, base pose) and a direction ``t`` of rigid
    robot motion (dx, dy, dyaw), two features of the robot's points — the centroid's x and the
    cross moment of the forward and left axes, whose derivative with respect to the yaw is
    the difference of the spreads along the two axes — their values at +-h, their derivative
    through `sensor.robot_point_cloud` and through the fixed-pixel cloud, and the largest
    difference between the two clouds' values."""
    gp = gait.GaitParams()
    bg = sensor.background(sc, F64)
    k = sensor.window_size(sc.camera)
    noise = sensor.DepthNoise(dropout=0.0)

    def features(key, base, geoms, d, follow):
        # The standing robot at base, moved rigidly by d = (dx, dy, dyaw) about its torso.
        xpos, xmat = geoms
        c, s = jnp.cos(d[2]), jnp.sin(d[2])
        rot = jnp.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], F64)
        rot = rot.at[0, 0].set(c).at[0, 1].set(-s).at[1, 0].set(s).at[1, 1].set(c)
        centre = jnp.concatenate([base[:2], jnp.zeros(1, F64)])
        shift = jnp.concatenate([d[:2], jnp.zeros(1, F64)])
        xpos = (xpos - centre) @ rot.T + centre + shift
        xmat = jnp.einsum("ij,gjk->gik", rot, xmat)
        torso = base + d
        if follow:
            pts, mask = sensor.robot_point_cloud(key, sc, xpos, xmat, torso, k, bg, noise,
                                                 dtype=F64)
        else:
            win = sensor.render_window(sc, xpos, xmat, torso[:2], k, bg, F64)
            pts, mask = sensor.point_cloud(key, sc, win, noise)
        w = (mask & (pts[:, 2] > 0.15)).astype(F64)
        centroid = (w @ pts[:, :2]) / jnp.sum(w)
        rel = pts[:, :2] - jax.lax.stop_gradient(centroid)
        c, s = jnp.cos(base[2]), jnp.sin(base[2])
        cross = (w @ ((rel @ jnp.stack([c, s])) * (rel @ jnp.stack([-s, c])))) / jnp.sum(w)
        return jnp.stack([centroid[0], cross]), (pts, mask)

    def one(key, base, t, h):
        zero = jnp.zeros(3, F64)
        geoms = scene.pose_geoms(sc, gait.qpos(sc, gait.init(base, gp, F64), gp))
        (f0, (p1, m1)), (ad, _) = jax.jvp(lambda d: features(key, base, geoms, d, True),
                                          (zero,), (t,))
        (_, (p0, m0)), (ad_fixed, _) = jax.jvp(
            lambda d: features(key, base, geoms, d, False), (zero,), (t,))
        fd = (features(key, base, geoms, h * t, True)[0]
              - features(key, base, geoms, -h * t, True)[0]) / (2 * h)
        diff = jnp.max(jnp.where(m1[:, None], jnp.abs(p1 - p0), 0.0))
        return f0, ad, ad_fixed, fd, diff, jnp.all(m1 == m0), jnp.sum(m1)

    return jax.jit(jax.vmap(one, (0, 0, None, None)))


def _bases(n, seed=0):
    rng = np.random.default_rng(seed)
    # A pixel is about 9.5 cm on the floor at 32 x 24: spread the robot over 20 cm x 20 cm so
    # that its position relative to the pixel grid (the grid's phase) is about uniform.
    return jnp.asarray(np.column_stack([rng.uniform(0.3, 0.5, n), rng.uniform(0.2, 0.4, n),
                                        np.full(n, 0.5)]), F64)


def test_robot_point_cloud_derivative_matches_phase_averaged_differences(probe):
    """Averaged over the grid's phase, finite differences of the centroid move one-for-one
    with the robot and the cross moment turns with it. The reparameterised cloud has the same
    values as the fixed-pixel one and its derivative agrees with the differences; the
    fixed-pixel cloud's derivative misses the silhouette and is near zero."""
    n = 64
    keys = jax.random.split(jax.random.PRNGKey(0), n)
    bases = _bases(n)
    for t, column in ((jnp.array([1.0, 0.0, 0.0], F64), 0), (jnp.array([0.0, 0.0, 1.0], F64), 1)):
        f0, ad, ad_fixed, fd, diff, same_mask, count = map(np.asarray, probe(keys, bases, t, 0.01))
        assert np.all(same_mask) and np.all(count >= 3)
        assert np.max(diff) < 1e-12
        assert np.all(np.isfinite(ad))
        fd_mean = fd[:, column].mean()
        fd_sem = fd[:, column].std() / math.sqrt(n)
        assert abs(ad[:, column].mean() - fd_mean) < 3 * fd_sem + 0.1 * abs(fd_mean), (
            ad[:, column].mean(), fd_mean, fd_sem)
        if column == 0:
            np.testing.assert_allclose(fd_mean, 1.0, atol=0.25)
            np.testing.assert_allclose(ad[:, 0], 1.0, atol=0.05)
        assert abs(ad_fixed[:, column].mean()) < 0.25 * abs(fd_mean)


def test_short_closed_loop_gradient_matches_central_differences():
    """The gains' derivatives of the mean final pose error after an 8-frame closed loop
    (smooth count, stop-gradient resampling, smooth stop) agree with central differences of
    the same loss (common random numbers) within 25 %; the propagation std's is finite (it is
    two orders smaller here, below the differences' noise). One compiled function: the
    differences use the primal outputs of the JVP at the shifted parameters."""
    cfg = episode.EpisodeConfig(scene.build(40, 30), humanoid.DepthPFConfig(num_particles=16),
                                num_frames=8, max_points=48, smooth=humanoid.SmoothConfig(),
                                dtype=F64)
    run = jax.vmap(episode.make_episode(cfg), (0, None))
    base = episode.make_params([0.4, 0.3, math.pi / 4], dtype=F64)
    keys = jax.random.split(jax.random.PRNGKey(0), 16)

    def loss(theta):
        params = base._replace(gains=control.PoseGains(theta[0], theta[1]),
                               log_position_noise=theta[2])
        m = run(keys, params)
        return jnp.mean(m["final_pos_err"] + jnp.deg2rad(m["final_heading_err"]))

    jvp = jax.jit(lambda theta, t: jax.jvp(loss, (theta,), (t,)))
    theta0 = jnp.stack([base.gains.log_lambda_x, base.gains.log_lambda_theta,
                        base.log_position_noise])
    step = 0.1
    for i in range(3):
        e = jnp.zeros(3, F64).at[i].set(1.0)
        ad = float(jvp(theta0, e)[1])
        fd = (float(jvp(theta0 + step * e, e)[0]) - float(jvp(theta0 - step * e, e)[0])) / (
            2 * step)
        assert np.isfinite(ad)
        if i < 2:
            assert abs(fd) > 0.02      # the gains matter over 8 frames
            assert abs(ad - fd) <= 0.25 * abs(fd), (i, ad, fd)
