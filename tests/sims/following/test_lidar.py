"""2-D laser caster of the following scene against mjx.ray on an MJX model of capsules and boxes."""

import functools
import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from sims.following import lidar

CFG = lidar.LaserConfig()
H = CFG.height
MAX = CFG.max_range

# Vertical capsules (legs, table legs; one whose top cap is cut by the plane), a tilted capsule
# (group 3, compared separately: its section is an ellipse) and z-rotated boxes (walls, a table
# block). Capsule axes: (x, y, z0, z1, radius).
VERTICAL = np.array([
    [1.5, 0.3, 0.05, 0.85, 0.06],
    [1.7, 0.1, 0.05, 0.85, 0.055],
    [2.6, -1.2, 0.05, 0.70, 0.03],
    [-0.8, 1.4, 0.05, 0.70, 0.04],
    [0.9, -0.9, 0.05, 0.27, 0.06],      # top cap crosses z = 0.3
    [3.0, 2.0, 0.05, 0.20, 0.06],       # below the plane: invisible
])
TILT = math.radians(15.0)
TILTED = (np.array([0.6, 1.2, 0.05]), 0.8, 0.07)   # foot, length, radius; leans towards +x
BOXES = np.array([                      # cx, cy, half x, half y, yaw
    [4.0, 0.0, 0.05, 3.0, 0.0],
    [0.0, -3.2, 4.0, 0.05, 0.0],
    [-2.0, 1.0, 0.3, 0.2, 0.6],
    [1.0, 3.5, 0.5, 0.05, -0.3],
])
ORIGINS = np.array([[0.2, -0.1, 0.4], [0.0, 0.5, -2.0], [2.2, -0.4, 2.6]])


def _tilted_ends():
    foot, length, _ = TILTED
    top = foot + length * np.array([math.sin(TILT), 0.0, math.cos(TILT)])
    return foot, top


def _xml():
    geoms = []
    for x, y, z0, z1, r in VERTICAL:
        geoms.append(f'<geom type="capsule" fromto="{x} {y} {z0} {x} {y} {z1}" size="{r}" '
                     'material="grey"/>')
    foot, top = _tilted_ends()
    geoms.append(f'<geom type="capsule" group="3" fromto="{" ".join(map(str, foot))} '
                 f'{" ".join(map(str, top))}" size="{TILTED[2]}" material="grey"/>')
    for cx, cy, hx, hy, yaw in BOXES:
        geoms.append(f'<geom type="box" pos="{cx} {cy} 0.5" size="{hx} {hy} 0.5" '
                     f'euler="0 0 {yaw}" material="grey"/>')
    # mjx.ray reads material colours, so every geom gets one.
    return ('<mujoco><compiler angle="radian"/><asset><material name="grey" rgba=".5 .5 .5 1"/>'
            f'</asset><worldbody>{"".join(geoms)}</worldbody></mujoco>')


@pytest.fixture(scope="module")
def mj():
    model = mujoco.MjModel.from_xml_string(_xml())
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    return model, mjx.put_model(model), mjx.put_data(model, data)


def _scene(dtype=jnp.float64):
    v = VERTICAL
    circles = lidar.capsule_sections(jnp.asarray(np.c_[v[:, :2], v[:, 2]], dtype),
                                     jnp.asarray(np.c_[v[:, :2], v[:, 3]], dtype),
                                     jnp.asarray(v[:, 4], dtype), H)
    walls = lidar.box_walls(jnp.asarray(BOXES[:, :2], dtype), jnp.asarray(BOXES[:, 2:4], dtype),
                            jnp.asarray(BOXES[:, 4], dtype))
    return circles, walls


cast = jax.jit(lidar.cast)
cast_many = jax.jit(jax.vmap(lidar.cast, (0, None, None, None, None)))


@functools.partial(jax.jit, static_argnums=4)
def _mjx_cast(mx, dx, pnt, vecs, groups):
    return jax.vmap(lambda v: mjx.ray(mx, dx, pnt, v, groups))(vecs)


def _mjx_ranges(mj, pose, angles, group):
    _, mx, dx = mj
    phi = pose[2] + np.asarray(angles)
    vecs = jnp.asarray(np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], -1))
    pnt = jnp.array([pose[0], pose[1], H])
    dist, gid = _mjx_cast(mx, dx, pnt, vecs, tuple(int(g == group) for g in range(6)))
    dist, gid = np.asarray(dist), np.asarray(gid)
    miss = (gid < 0) | (dist > MAX)
    return np.where(miss, MAX, dist), miss


def test_capsule_sections_of_vertical_capsules_are_exact():
    circles, _ = _scene()
    np.testing.assert_array_equal(circles.mask, [True] * 5 + [False])
    np.testing.assert_allclose(circles.centers[:5], VERTICAL[:5, :2])
    cap = math.sqrt(0.06 ** 2 - (H - 0.27) ** 2)
    np.testing.assert_allclose(circles.radii[:5], [0.06, 0.055, 0.03, 0.04, cap], rtol=1e-12)


def test_cast_matches_mjx_ray_on_hits_and_misses(mj):
    angles = lidar.beam_angles(CFG)
    circles, walls = _scene()
    for pose in ORIGINS:
        ours = np.asarray(cast(jnp.asarray(pose), angles, circles, walls, MAX))
        ref, miss = _mjx_ranges(mj, pose, angles, 0)
        np.testing.assert_array_equal(ours == MAX, miss)
        np.testing.assert_allclose(ours, ref, atol=1e-5)
        assert 0.05 < miss.mean() < 0.9     # the scene has both


def test_tilted_capsule_section_within_the_mean_radius_bound(mj):
    foot, top = _tilted_ends()
    r = TILTED[2]
    circles = lidar.capsule_sections(jnp.asarray(foot[None]), jnp.asarray(top[None]),
                                     jnp.array([r]), H)
    axis_x = foot[0] + (H - foot[2]) * math.tan(TILT)
    np.testing.assert_allclose(circles.centers[0], [axis_x, foot[1]], atol=1e-12)
    bound = 0.5 * r * (1 / math.cos(TILT) - 1)
    angles = lidar.beam_angles(CFG)
    no_walls = lidar.Walls(jnp.zeros((0, 2, 2)), jnp.zeros(0, bool))
    for x, y, _ in ORIGINS:
        pose = np.array([x, y, math.atan2(foot[1] - y, axis_x - x) + 1.0])
        ours = np.asarray(cast(jnp.asarray(pose), angles, circles, no_walls, MAX))
        ref, miss = _mjx_ranges(mj, pose, angles, 3)
        both = (ours < MAX) & ~miss
        assert both.sum() >= 3
        # mjx's hit points (on the ellipse) are within the bound of our circle; ranges along
        # beams that graze the silhouette can differ by more.
        phi = pose[2] + np.asarray(angles)[both]
        hits = pose[:2] + ref[both, None] * np.stack([np.cos(phi), np.sin(phi)], -1)
        off = np.abs(np.linalg.norm(hits - np.asarray(circles.centers[0]), axis=-1)
                     - float(circles.radii[0]))
        assert np.max(off) <= bound + 1e-9
        assert np.median(np.abs(ours[both] - ref[both])) <= 1.5 * bound
        assert np.sum((ours < MAX) != ~miss) <= 2   # only grazing beams at the edges


def test_gradients_match_central_differences():
    circles, walls = _scene()
    angles = lidar.beam_angles(lidar.LaserConfig(step_deg=3.0))
    w = jnp.asarray(np.random.default_rng(0).uniform(0.5, 1.5, angles.shape))
    pose = jnp.asarray(ORIGINS[0])

    def loss(pose, centers, radii, ends):
        r = lidar.cast(pose, angles, lidar.Circles(centers, radii, circles.mask),
                       lidar.Walls(ends, walls.mask), MAX)
        return jnp.sum(w * r)

    args = (pose, circles.centers, circles.radii, walls.endpoints)
    grads = jax.jit(jax.grad(loss, argnums=(0, 1, 2, 3)))(*args)
    f = jax.jit(loss)
    eps = 1e-6
    for i, (a, g) in enumerate(zip(args, grads)):
        assert np.all(np.isfinite(g))
        flat = np.asarray(a).ravel()
        fd = np.zeros_like(flat)
        for j in range(flat.size):
            up, dn = flat.copy(), flat.copy()
            up[j] += eps
            dn[j] -= eps
            new = list(args)
            new[i] = jnp.asarray(up.reshape(np.shape(a)))
            fu = f(*new)
            new[i] = jnp.asarray(dn.reshape(np.shape(a)))
            fd[j] = (fu - f(*new)) / (2 * eps)
        np.testing.assert_allclose(np.asarray(g).ravel(), fd, atol=1e-5, rtol=1e-5)
    assert np.any(np.asarray(grads[1]) != 0) and np.any(np.asarray(grads[3]) != 0)


def test_gradient_is_finite_on_grazing_and_tangent_rays():
    # A beam exactly tangent to a circle and one through a segment's end point.
    circles = lidar.Circles(jnp.array([[2.0, 0.5]]), jnp.array([0.5]), jnp.array([True]))
    walls = lidar.Walls(jnp.array([[[3.0, 0.0], [3.0, -1.0]]]), jnp.array([True]))
    grad = jax.jit(jax.grad(lambda c, a: jnp.sum(lidar.cast(jnp.zeros(3), a, lidar.Circles(
        c, circles.radii, circles.mask), walls, MAX))))
    # Tangent to the circle's bottom (y = 0), then through the wall's end point (3, 0) from
    # below, and a beam that misses everything.
    g = grad(circles.centers, jnp.array([0.0, -1e-9, 3.0]))
    assert np.all(np.isfinite(g))


def test_float32_agrees_with_float64_and_vmap_matches_loop():
    angles = lidar.beam_angles(CFG)
    c64, w64 = _scene()
    c32, w32 = _scene(jnp.float32)
    r64 = cast_many(jnp.asarray(ORIGINS), angles, c64, w64, MAX)
    r32 = cast_many(jnp.asarray(ORIGINS, jnp.float32), angles.astype(jnp.float32), c32, w32, MAX)
    assert r32.dtype == jnp.float32 and r64.dtype == jnp.float64
    hit = (np.asarray(r64) < MAX) & (np.asarray(r32) < MAX)
    assert np.max(np.abs(np.asarray(r32)[hit] - np.asarray(r64)[hit])) < 2e-5
    assert np.mean((np.asarray(r64) < MAX) != (np.asarray(r32) < MAX)) < 0.005
    for k, pose in enumerate(ORIGINS):
        np.testing.assert_allclose(r64[k], cast(jnp.asarray(pose), angles, c64, w64, MAX),
                                   atol=1e-12)


def test_scan_noise_clipping_mount_and_points():
    cfg = lidar.LaserConfig(mount=(0.3, 0.1))
    circles, walls = _scene()
    robot = jnp.array([0.1, 0.2, 0.7])
    angles = lidar.beam_angles(cfg)
    clean = cast(lidar.laser_pose(robot, cfg), angles, circles, walls, MAX)
    noisy = jax.jit(lidar.scan, static_argnums=4)(jax.random.PRNGKey(0),
                                                  lidar.laser_pose(robot, cfg), circles, walls,
                                                  cfg)
    hit = np.asarray(clean) < MAX
    np.testing.assert_array_equal(np.asarray(noisy)[~hit], MAX)
    err = np.asarray(noisy - clean)[hit]
    assert 0.008 < err.std() < 0.012 and abs(err.mean()) < 0.002
    assert np.all((np.asarray(noisy) >= cfg.min_range) & (np.asarray(noisy) <= MAX))
    xy, valid = lidar.scan_points(noisy, angles, cfg)
    np.testing.assert_array_equal(valid, np.asarray(noisy) < MAX)
    np.testing.assert_allclose(np.linalg.norm(xy, axis=-1)[valid], np.asarray(noisy)[valid])
    # Mount: the laser at (0.3, 0.1) in the robot frame, rotated by the heading.
    c, s = math.cos(0.7), math.sin(0.7)
    np.testing.assert_allclose(lidar.laser_pose(robot, cfg),
                               [0.1 + 0.3 * c - 0.1 * s, 0.2 + 0.3 * s + 0.1 * c, 0.7])
    assert cfg.num_beams == 667 and abs(float(angles[-1]) - math.radians(119.88)) < 1e-9


def test_bad_input_raises():
    circles, walls = _scene()
    angles = lidar.beam_angles(CFG)
    with pytest.raises(ValueError, match="pose"):
        lidar.cast(jnp.zeros(2), angles, circles, walls, MAX)
    with pytest.raises(ValueError, match="circles.radii"):
        lidar.cast(jnp.zeros(3), angles, lidar.Circles(circles.centers, circles.radii[:2],
                                                        circles.mask), walls, MAX)
    with pytest.raises(ValueError, match="walls.endpoints"):
        lidar.cast(jnp.zeros(3), angles, circles, lidar.Walls(walls.endpoints[:, 0],
                                                              walls.mask), MAX)
    with pytest.raises(ValueError, match="NaN"):
        lidar.cast(jnp.array([0.0, jnp.nan, 0.0]), angles, circles, walls, MAX)
    with pytest.raises(ValueError, match=">= 0"):
        lidar.cast(jnp.zeros(3), angles, lidar.Circles(circles.centers, -circles.radii,
                                                        circles.mask), walls, MAX)
    with pytest.raises(ValueError, match="p1"):
        lidar.capsule_sections(jnp.zeros((2, 3)), jnp.zeros((3, 3)), jnp.ones(2), H)
    with pytest.raises(ValueError, match="agree"):
        lidar.scan_points(jnp.ones(5), angles)
