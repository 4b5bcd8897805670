"""The per-geom ray distances of the depth render (`sensor.geom_distances`), which the colour
render uses to know which geom each ray sees (the renderer's other tests: test_scene.py)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sims.humanoid import gait, scene, sensor


@pytest.fixture(scope="module")
def sc():
    return scene.build(24, 18)


def test_geom_distances_minimum_is_the_ray_distance(sc):
    xpos, xmat = jax.jit(lambda: scene.pose_geoms(sc, gait.qpos(sc, gait.init(
        jnp.array([0.4, 0.6, 0.7]), dtype=jnp.float64))))()
    dirs, _ = scene.camera_rays(sc.camera, jnp.float64)
    dirs = dirs.reshape(-1, 3)
    origin = jnp.asarray(sc.camera.position, jnp.float64)
    types = sc.model.geom_type
    sizes = jnp.asarray(sc.model.geom_size)
    per_geom = jax.jit(lambda p, m: sensor.geom_distances(origin, dirs, types, sizes, p, m))(
        xpos, xmat)
    nearest = jax.jit(lambda p, m: sensor.ray_distances(origin, dirs, types, sizes, p, m))(
        xpos, xmat)
    assert per_geom.shape == (sc.model.ngeom, dirs.shape[0])
    np.testing.assert_array_equal(np.asarray(jnp.min(per_geom, 0)), np.asarray(nearest))
    # Some rays see the robot, whose geoms come after the room's.
    seen = np.asarray(jnp.argmin(per_geom, 0))
    assert np.isin(seen, sc.robot_geoms).sum() >= 3


def test_geom_distances_rejects_unsupported_types():
    with pytest.raises(ValueError, match="unsupported geom types"):
        sensor.geom_distances(jnp.zeros(3), jnp.array([[0.0, 0.0, -1.0]]), np.array([5]),
                              jnp.ones((1, 3)), jnp.zeros((1, 3)), jnp.eye(3)[None])
