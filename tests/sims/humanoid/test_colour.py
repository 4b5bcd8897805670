"""The ceiling camera's colour render (`sims.humanoid.colour`): the robot's silhouette is the
depth render's, the light model's closed form on the floor, lighting draws, noise, and finite
gradients with respect to the robot's pose."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sims.humanoid import colour, gait, scene, sensor

POSE = np.array([0.35, 0.6, 0.8])


@pytest.fixture(scope="module")
def sc():
    return scene.build(40, 30)


@pytest.fixture(scope="module")
def posed(sc):
    """World geom poses of the robot a step into a walk (float64)."""
    @jax.jit
    def pose():
        g = gait.init(jnp.asarray(POSE), dtype=jnp.float64)
        g = gait.step(jax.random.PRNGKey(0), g, jnp.array([0.1, 0.0]), 0.0, False)
        return scene.pose_geoms(sc, gait.qpos(sc, g))

    return pose()


@pytest.fixture(scope="module")
def bg1(sc):
    return colour.background(sc, supersample=1, dtype=jnp.float64)


@pytest.fixture(scope="module")
def render1(sc, bg1):
    return jax.jit(lambda xpos, xmat, light: colour.render(sc, xpos, xmat, POSE[:2], bg1, light,
                                                           dtype=jnp.float64))


def _floor_only(bg, light):
    """The room's image under ``light`` (the render without the robot), sub-rays averaged."""
    gain = light.brightness * (1 + (np.asarray(bg.xy) - 0.5) @ np.asarray(light.gradient))
    sub = np.asarray(bg.radiance) * gain[..., None]
    s = bg.supersample
    h, w = sub.shape[0] // s, sub.shape[1] // s
    return sub.reshape(h, s, w, s, 3).mean(axis=(1, 3))


def test_robot_silhouette_is_the_depth_renders(sc, posed, bg1, render1):
    light = colour.Lighting(jnp.asarray(1.0), jnp.zeros(2))
    img = np.asarray(render1(*posed, light))
    robot = np.any(np.abs(img - _floor_only(bg1, light)) > 1e-9, -1)
    depth = np.asarray(jax.jit(lambda p, m: sensor.render(sc, p, m, dtype=jnp.float64))(
        *posed))
    room = np.asarray(sensor.background(sc, jnp.float64))
    on_robot = depth < room - 1e-9
    assert on_robot.sum() >= 5
    # Same rays, same intersections: at most a grazing pixel differs.
    assert np.sum(robot != on_robot) <= 1, (robot.sum(), on_robot.sum())


def test_floor_radiance_is_the_lambertian_closed_form(sc, posed, bg1, render1):
    light = colour.Lighting(jnp.asarray(0.9), jnp.array([0.2, -0.1]))
    img = np.asarray(render1(*posed, light))
    cfg, cam = colour.LightingConfig(), sc.camera
    i, j = 3, 35                                              # a floor pixel, far from the robot
    u, v = (j + 0.5 - cam.cx) / cam.fx, -(i + 0.5 - cam.cy) / cam.fy
    z = cam.position[2]
    p = np.array([cam.position[0] + z * u, cam.position[1] + z * v, 0.0])
    lamp = np.array([cam.position[0], cam.position[1], cfg.lamp_height])
    cos = (lamp - p)[2] / np.linalg.norm(lamp - p)
    want = (np.array(colour.Palette().floor) * 0.9 * (1 + (p[:2] - 0.5) @ [0.2, -0.1])
            * (cfg.ambient + cfg.diffuse * cos))
    np.testing.assert_allclose(img[i, j], want, rtol=1e-9)


def test_supersampled_image_is_in_range_and_scales_with_brightness(sc, posed):
    bg = colour.background(sc, supersample=2, dtype=jnp.float64)
    key = jax.random.PRNGKey(4)
    light = colour.draw_lighting(key, dtype=jnp.float64)
    f = jax.jit(lambda light: colour.render(sc, *posed, POSE[:2], bg, light,
                                            dtype=jnp.float64))
    clean = np.asarray(f(light))
    double = np.asarray(f(light._replace(brightness=2 * light.brightness)))
    np.testing.assert_allclose(double, 2 * clean, rtol=1e-12)
    img = np.asarray(jax.jit(lambda k: colour.image(k, sc, *posed, POSE[:2], bg, light,
                                                    dtype=jnp.float64))(key))
    assert img.shape == (30, 40, 3) and img.min() >= 0 and img.max() <= 1
    # Edge pixels mix the robot's colour with the floor's (the box filter).
    robot = np.any(np.abs(clean - _floor_only(bg, light)) > 1e-9, -1)
    assert 10 <= robot.sum() <= 60


def test_lighting_draws_stay_in_their_ranges():
    cfg = colour.LightingConfig()
    lights = jax.vmap(lambda k: colour.draw_lighting(k, cfg))(
        jax.random.split(jax.random.PRNGKey(0), 500))
    b = np.asarray(lights.brightness)
    g = np.hypot(*np.asarray(lights.gradient).T)
    assert cfg.brightness_range[0] <= b.min() and b.max() <= cfg.brightness_range[1]
    assert g.max() <= cfg.gradient_max + 1e-6 and g.max() > 0.9 * cfg.gradient_max
    one = colour.Lighting(jnp.asarray(1.0), jnp.zeros(2))
    flick = jax.vmap(lambda k: colour.flicker(k, one, cfg))(
        jax.random.split(jax.random.PRNGKey(1), 2000))
    assert abs(float(jnp.std(flick.brightness)) - cfg.flicker_std) < 0.003


def test_pixel_noise_has_its_std_and_saturates():
    img = colour.add_noise(jax.random.PRNGKey(0), jnp.full((100, 100, 3), 0.5), 0.02)
    assert abs(float(jnp.std(img)) - 0.02) < 0.001
    sat = colour.add_noise(jax.random.PRNGKey(1), jnp.full((10, 10, 3), 1.3), 0.02)
    assert np.all(np.asarray(sat) == 1.0)


def test_colour_render_has_finite_nonzero_gradients_in_the_robot_pose(sc, posed, bg1):
    """The robot's geoms moved rigidly by a pose (x, y, yaw) about its torso."""
    xpos0, xmat0 = posed
    robot = np.zeros(sc.model.ngeom, bool)
    robot[sc.robot_geoms] = True
    light = colour.Lighting(jnp.asarray(1.0), jnp.array([0.2, 0.1]))
    weights = jax.random.uniform(jax.random.PRNGKey(2), (30, 40, 3), jnp.float64)

    def loss(pose):
        c, s = jnp.cos(pose[2]), jnp.sin(pose[2])
        rot = jnp.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        centre = jnp.array([POSE[0], POSE[1], 0.0])
        shift = jnp.concatenate([pose[:2], jnp.zeros(1)])
        xpos = jnp.where(robot[:, None], (xpos0 - centre) @ rot.T + centre + shift, xpos0)
        xmat = jnp.where(robot[:, None, None], rot @ xmat0, xmat0)
        img = colour.render(sc, xpos, xmat, POSE[:2], bg1, light, dtype=jnp.float64)
        return jnp.sum(weights * img)

    pose = jnp.array([0.002, -0.001, 0.01])
    value_and_grad = jax.jit(jax.value_and_grad(loss))
    _, grad = value_and_grad(pose)
    grad = np.asarray(grad)
    assert np.all(np.isfinite(grad)) and np.all(grad != 0), grad
    # The pathwise derivative (shading and light at the hit points) matches central
    # differences small enough that no sub-ray changes geom.
    eps = 1e-7
    fd = [(value_and_grad(pose.at[i].add(eps))[0] - value_and_grad(pose.at[i].add(-eps))[0])
          / (2 * eps) for i in range(3)]
    np.testing.assert_allclose(grad, np.asarray(fd), rtol=1e-4)


def test_albedo_follows_the_palette(sc):
    rho = colour.albedo(sc)
    names = [sc.model.geom(g).name for g in range(sc.model.ngeom)]
    p = colour.Palette()
    assert tuple(rho[names.index("head")]) == p.shell
    assert tuple(rho[names.index("l_shoulder")]) == p.trim
    assert tuple(rho[names.index("r_hand")]) == p.joint
    assert tuple(rho[names.index("floor")]) == p.floor
    with pytest.raises(ValueError, match="supersample"):
        colour.background(sc, supersample=0)
    assert math.isclose(float(np.max(rho)), 0.92)
