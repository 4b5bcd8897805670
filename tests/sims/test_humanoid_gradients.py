"""Derivatives of the humanoid closed loop: the point cloud's derivative with respect to the
robot's pose (against finite differences averaged over the pixel grid's phase) and a short
closed-loop gradient against central finite differences (common random numbers)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.control import pose as control
from sims.humanoid import episode, gait, scene, sensor

F64 = jnp.float64


@pytest.fixture(scope="module")
def sc():
    return scene.build(32, 24)


@pytest.fixture(scope="module")
def cloud_fns(sc):
    """Robot-point centroid and a yaw-sensitive moment of a standing robot moved rigidly by
    (dx, dyaw), through the reparameterised cloud and through the plain fixed-pixel one."""
    gp = gait.GaitParams()
    bg = sensor.background(sc, F64)
    k = sensor.window_size(sc.camera)
    noise = sensor.DepthNoise(dropout=0.0)

    def cloud(key, base, d, follow):
        g = gait.init(base + d, gp, F64)
        torso = gait.torso_pose(g, gp)
        xpos, xmat = scene.pose_geoms(sc, gait.qpos(sc, g, gp))
        if follow:
            return sensor.robot_point_cloud(key, sc, xpos, xmat, torso, k, bg, noise,
                                            dtype=F64), torso
        win = sensor.render_window(sc, xpos, xmat, torso[:2], k, bg, F64)
        return sensor.point_cloud(key, sc, win, noise), torso

    def features(key, base, d, follow):
        (pts, mask), torso = cloud(key, base, d, follow)
        w = (mask & (pts[:, 2] > 0.15)).astype(F64)
        centroid = (w @ pts[:, :2]) / jnp.sum(w)
        # Cross moment of the forward and left axes at the unperturbed heading: it is zero
        # for a symmetric robot and its derivative with respect to the yaw is the difference
        # of the spreads along the two axes, so it measures how the cloud turns with the robot.
        rel = pts[:, :2] - jax.lax.stop_gradient(centroid)
        c, s = jnp.cos(base[2]), jnp.sin(base[2])
        cross = (w @ ((rel @ jnp.stack([c, s])) * (rel @ jnp.stack([-s, c])))) / jnp.sum(w)
        return jnp.stack([centroid[0], cross])

    batched = {}
    for follow in (True, False):
        f = lambda key, base, d, follow=follow: features(key, base, d, follow)  # noqa: E731
        value = jax.jit(jax.vmap(f, (0, 0, None)))
        tangent = jax.jit(jax.vmap(
            lambda key, base, t, f=f: jax.jvp(lambda d: f(key, base, d), (jnp.zeros(3, F64),),
                                              (t,))[1], (0, 0, None)))
        batched[follow] = (value, tangent)
    return cloud, batched


def test_robot_point_cloud_equals_the_fixed_pixel_cloud_in_value(sc, cloud_fns):
    cloud, _ = cloud_fns
    key = jax.random.PRNGKey(3)
    base = jnp.array([0.4, 0.3, 0.6], F64)
    (p1, m1), _ = jax.jit(lambda: cloud(key, base, jnp.zeros(3, F64), True))()
    (p0, m0), _ = jax.jit(lambda: cloud(key, base, jnp.zeros(3, F64), False))()
    np.testing.assert_array_equal(m1, m0)
    np.testing.assert_allclose(p1, p0, rtol=0, atol=1e-12)
    assert int(np.sum(m1)) >= 4


def test_cloud_derivative_follows_the_robot_like_phase_averaged_differences(cloud_fns):
    """Averaged over robot positions spread across a whole pixel footprint (the grid's phase),
    finite differences of the centroid move one-for-one with the robot and the cloud's cross
    moment turns with it. The reparameterised cloud's derivative agrees; the
    fixed-pixel cloud's derivative misses the silhouette and is near zero."""
    _, batched = cloud_fns
    n = 96
    rng = np.random.default_rng(0)
    # A pixel is about 9.5 cm on the floor at 32 x 24: spread the bases over 20 cm x 20 cm.
    base = np.column_stack([rng.uniform(0.3, 0.5, n), rng.uniform(0.2, 0.4, n),
                            np.full(n, 0.5)])
    base = jnp.asarray(base, F64)
    keys = jax.random.split(jax.random.PRNGKey(0), n)
    value, tangent = batched[True]
    h = 0.01
    for t_dir, column in ((jnp.array([1.0, 0, 0], F64), 0), (jnp.array([0, 0, 1.0], F64), 1)):
        fd = (np.asarray(value(keys, base, h * t_dir)) - np.asarray(value(keys, base, -h * t_dir))
              ) / (2 * h)
        fd_mean = fd[:, column].mean()
        fd_sem = fd[:, column].std() / math.sqrt(n)
        ad = np.asarray(tangent(keys, base, t_dir))[:, column]
        assert np.all(np.isfinite(ad))
        assert abs(ad.mean() - fd_mean) < 3 * fd_sem + 0.1 * abs(fd_mean), (ad.mean(), fd_mean)
        if column == 0:
            np.testing.assert_allclose(fd_mean, 1.0, atol=0.25)
        ad_fixed = np.asarray(batched[False][1](keys, base, t_dir))[:, column]
        assert abs(ad_fixed.mean()) < 0.25 * abs(fd_mean)
