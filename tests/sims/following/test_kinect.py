"""The Kinect renderer against MuJoCo's ray casting (`mjx.ray`) on the same primitives, and its
measurement model."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sims.following import kinect, layout, pedestrians

CFG = kinect.KinectConfig(width=32, height=24, noise=False, quantise=False)


def _scene():
    """A capsule (a leg), a sphere (a head), a box turned 30 deg (a shelf), the floor."""
    f = lambda x: jnp.asarray(x, jnp.float64)  # noqa: E731
    return kinect.Primitives(
        capsule_a=f([[2.0, 0.3, 0.06], [2.5, -0.4, 1.6]]),
        capsule_b=f([[2.1, 0.3, 0.9], [2.5, -0.4, 1.6]]),
        capsule_radius=f([0.08, 0.12]), capsule_colour=f([[1, 0, 0], [0, 1, 0]]),
        box_centre=f([[3.2, 0.0, 0.6]]), box_half=f([[0.3, 0.8, 0.6]]),
        box_yaw=f([math.radians(30.0)]), box_colour=f([[0, 0, 1]]),
        floor_colour=f([0.5, 0.5, 0.5]))


def _mjcf(prims):
    geoms = ['<geom type="plane" size="50 50 0.1" material="grey"/>']
    for a, b, r in zip(np.asarray(prims.capsule_a), np.asarray(prims.capsule_b),
                       np.asarray(prims.capsule_radius)):
        if np.allclose(a, b):
            geoms.append(f'<geom type="sphere" size="{r}" pos="{a[0]} {a[1]} {a[2]}" '
                         'material="grey"/>')
        else:
            geoms.append(f'<geom type="capsule" size="{r}" fromto="{" ".join(map(str, a))} '
                         f'{" ".join(map(str, b))}" material="grey"/>')
    for c, h, y in zip(np.asarray(prims.box_centre), np.asarray(prims.box_half),
                       np.asarray(prims.box_yaw)):
        geoms.append(f'<geom type="box" size="{h[0]} {h[1]} {h[2]}" pos="{c[0]} {c[1]} {c[2]}" '
                     f'euler="0 0 {math.degrees(y)}" material="grey"/>')
    # mjx.ray reads material colours, so every geom gets one.
    return ('<mujoco><asset><material name="grey" rgba=".5 .5 .5 1"/></asset>'
            f'<worldbody>{"".join(geoms)}</worldbody></mujoco>')


def test_depth_equals_mjx_ray_on_the_same_primitives():
    mujoco = pytest.importorskip("mujoco")
    from mujoco import mjx

    prims = _scene()
    model = mujoco.MjModel.from_xml_string(_mjcf(prims))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)                  # geom poses (the model has no joints)
    m, d = mjx.put_model(model), mjx.put_data(model, data)
    eye, rot = kinect.camera_pose(CFG, jnp.asarray([0.0, 0.0, 0.1]))
    frame = kinect.render(CFG, eye, rot, prims)
    dirs = kinect.rays(CFG, rot).reshape(-1, 3)
    unit = dirs / jnp.linalg.norm(dirs, axis=-1, keepdims=True)
    dist, geom = jax.vmap(lambda v: mjx.ray(m, d, eye, v))(unit)
    mine = np.asarray(frame.depth).reshape(-1) * np.linalg.norm(np.asarray(dirs), axis=-1)
    ref = np.where(np.asarray(geom) >= 0, np.asarray(dist), np.inf)
    # MuJoCo's plane is finite (50 m): compare the rays that end within 40 m by either count.
    near = (mine < 40) | (ref < 40)
    mine, ref, geom = mine[near], ref[near], np.asarray(geom)[near]
    hit = np.isfinite(ref)
    np.testing.assert_array_equal(np.isfinite(mine), hit)
    np.testing.assert_allclose(mine[hit], ref[hit], rtol=1e-6, atol=1e-6)
    # Which primitive: MuJoCo's geom 0 is the plane, then the capsules, then the box.
    ours = np.asarray(frame.hit).reshape(-1)[near]
    n = prims.capsule_a.shape[0] + prims.box_centre.shape[0]
    theirs = np.where(np.asarray(geom) == 0, n, np.asarray(geom) - 1)
    np.testing.assert_array_equal(ours[hit], theirs[hit])
    assert len(set(ours[hit].tolist())) == 4                  # every primitive is seen


def test_camera_geometry_field_of_view_and_tilt():
    cfg = kinect.KinectConfig()
    eye, rot = kinect.mount_pose(cfg, dtype=jnp.float64)
    d = np.asarray(kinect.rays(cfg, rot))
    np.testing.assert_allclose(eye, cfg.mount)
    centre = d[cfg.height // 2, cfg.width // 2]
    # The optical axis points forward and down by the tilt.
    assert abs(math.degrees(math.atan2(-centre[2], centre[0])) - 5.0) < 0.3
    left, right = d[cfg.height // 2, 0], d[cfg.height // 2, -1]
    span = math.degrees(math.atan2(left[1], left[0]) - math.atan2(right[1], right[0]))
    assert abs(span - 57.0) < 0.5
    np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-12)


def test_point_cloud_inverts_the_render():
    prims = _scene()
    robot = jnp.asarray([0.0, 0.0, 0.1])
    eye, rot = kinect.camera_pose(CFG, robot)
    frame = kinect.render(CFG, eye, rot, prims)
    valid = jnp.isfinite(frame.depth)
    pts, ok, _ = kinect.point_cloud(CFG, frame.depth, valid, eye, rot)
    p = np.asarray(pts)[np.asarray(ok)]
    hit = np.asarray(frame.hit).reshape(-1)[np.asarray(ok)]
    floor = hit == 3
    np.testing.assert_allclose(p[floor, 2], 0.0, atol=1e-9)    # floor points lie on z = 0
    head = hit == 1                                             # head points on the sphere
    np.testing.assert_allclose(np.linalg.norm(p[head] - [2.5, -0.4, 1.6], axis=1), 0.12,
                               atol=1e-9)


def test_measurement_noise_grows_with_the_square_of_the_range():
    cfg = kinect.KinectConfig(width=64, height=64, quantise=False, edge_dropout=0.0)
    for z in (1.0, 3.0):
        depth, valid = kinect.measure(jax.random.key(0), cfg, jnp.full((64, 64), z))
        std = float(jnp.std(depth))
        assert abs(std / (1.425e-3 * z ** 2) - 1) < 0.05
        assert bool(valid.all())


def test_quantisation_steps_are_those_of_the_disparity():
    cfg = kinect.KinectConfig(noise=False, width=8, height=8, edge_dropout=0.0)
    z = jnp.linspace(1.0, 4.0, 64).reshape(8, 8)
    q, _ = kinect.measure(jax.random.key(0), cfg, z)
    q = np.asarray(q)
    k = 351.0
    np.testing.assert_allclose(q, k / np.round(k / np.asarray(z)))
    assert np.abs(q - np.asarray(z)).max() <= 0.5 * 2.85e-3 * 4.0 ** 2 * 1.1


def test_range_limits_and_edge_dropout():
    cfg = kinect.KinectConfig(width=16, height=1, noise=False, quantise=False, edge_dropout=1.0)
    z = jnp.asarray([[0.3, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 3.0, 3.0, 3.0, 3.0, 3.0, 5.0, jnp.inf,
                      2.0, 2.0]])
    depth, valid = kinect.measure(jax.random.key(0), cfg, z)
    v = np.asarray(valid)[0]
    assert not v[0] and not v[12] and not v[13]                # too near, too far, no return
    assert not v[6] and not v[7]                               # the 1 m / 3 m edge is lost
    assert v[3] and v[9]
    assert np.isnan(np.asarray(depth)[0, ~v]).all()


def test_people_and_room_primitives():
    P = 3
    pos = jnp.asarray([[2.0, 0.0], [3.0, 1.0], [0.0, 0.0]])
    st = pedestrians.PedestrianState(
        pos=pos, vel=jnp.zeros((P, 2)), heading=jnp.zeros(P), phase=jnp.zeros(P),
        mask=jnp.asarray([True, True, False]), goal=pos, speed=jnp.zeros(P),
        stop_timer=jnp.zeros(P), goal_timer=jnp.zeros(P), crossing=jnp.zeros(P, bool))
    prims = kinect.people_primitives(st, jnp.asarray([1.75, 1.9, 1.7]), kinect.CLOTHING[:P])
    assert prims.capsule_a.shape == (6 * P, 3)
    r = np.asarray(prims.capsule_radius).reshape(6, P)
    assert (r[:, 2] == 0).all() and (r[:, :2] > 0).all()       # inactive people are hidden
    head = np.asarray(prims.capsule_a).reshape(6, P, 3)[5]
    top = head[:, 2] + r[5]
    np.testing.assert_allclose(top[:2], [1.745, 1.9 * 1.745 / 1.75], atol=1e-6)
    room = kinect.layout_primitives(layout.room())
    assert room.box_centre.shape[0] == 4 + 6 + 4               # walls, tops, chair backs
    assert room.capsule_a.shape[0] == 6 * 4                    # four legs each


@pytest.mark.parametrize("kw", [dict(width=0), dict(fov_x=4.0), dict(min_range=5.0),
                                dict(edge_dropout=1.5)])
def test_bad_config_is_refused(kw):
    with pytest.raises(ValueError, match="KinectConfig"):
        kinect.KinectConfig(**kw)
