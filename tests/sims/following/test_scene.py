"""MJX person-following scene: unicycle robot physics, mocap people, laser-plane geometry."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from sims.following import pedestrians as pd
from sims.following import scene

CONTROL_STEPS = 10
# (v, omega) per episode of the batch: arcs both ways, a straight line, a turn on the spot.
COMMANDS = np.array([[0.8, 0.5], [1.0, -0.7], [0.6, 0.0], [0.0, 1.2]])
STARTS = np.array([[0.0, 0.0, 0.3], [-1.0, -2.0, -1.0], [1.0, 2.5, 3.0], [-3.5, -3.0, 0.0]])


@pytest.fixture(scope="module")
def sc():
    return scene.build(num_people=4)


@pytest.fixture(scope="module")
def episodes(sc):
    """A batch of 4 one-second closed loops (pedestrians -> set_people -> robot_step), one
    compilation for the module."""
    cfg = scene.pedestrian_config(sc, distractors=2)

    @jax.jit
    @jax.vmap
    def run(key, start, u, people):
        data = scene.reset(sc, start, people)

        def body(carry, k):
            data, ped = carry
            ped = pd.step(k, cfg, ped, scene.robot_pose(data), 0.1)
            data = scene.set_people(sc, data, ped)
            data = scene.robot_step(sc, data, u)
            return (data, ped), scene.robot_pose(data)

        (data, ped), poses = jax.lax.scan(body, (data, people),
                                          jax.random.split(key, CONTROL_STEPS))
        return scene.kinematics(sc, data), ped, poses

    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    people = [pd.init(k, cfg, 4, jnp.float32) for k in keys]
    people = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *people)
    out = run(jax.random.split(jax.random.PRNGKey(1), 4), jnp.asarray(STARTS),
              jnp.asarray(COMMANDS), people)
    return jax.tree_util.tree_map(np.asarray, out)


def _arc(start, u, t):
    x, y, th = start
    v, w = u
    if abs(w) < 1e-12:
        return np.array([x + v * t * np.cos(th), y + v * t * np.sin(th), th])
    return np.array([x + v / w * (np.sin(th + w * t) - np.sin(th)),
                     y - v / w * (np.cos(th + w * t) - np.cos(th)), th + w * t])


def test_robot_follows_the_unicycle_arc(episodes):
    _, _, poses = episodes
    for b in range(4):
        for k in range(CONTROL_STEPS):
            ref = _arc(STARTS[b], COMMANDS[b], 0.1 * (k + 1))
            np.testing.assert_allclose(poses[b, k, :2], ref[:2], atol=3e-3)
            dth = np.angle(np.exp(1j * (poses[b, k, 2] - ref[2])))
            assert abs(dth) < 2e-3
            assert -np.pi <= poses[b, k, 2] < np.pi


def test_set_people_puts_the_mocap_legs_where_leg_capsules_says(sc, episodes):
    data, ped, _ = episodes
    half = 0.5 * sc.gait.leg_length
    for b in range(4):
        st = jax.tree_util.tree_map(lambda x: x[b], ped)
        p0, p1, r = (np.asarray(a) for a in scene.leg_capsules(st, sc.gait))
        for p in range(sc.num_people):
            for s, side in enumerate("lr"):
                g = sc.model.geom(f"person{p}_{side}_leg").id
                # MJX's own kinematics of the mocap body.
                centre = data.geom_xpos[b, g]
                axis = data.geom_xmat[b, g].reshape(3, 3)[:, 2]
                np.testing.assert_allclose(centre - half * axis, p0[p, s], atol=2e-5)
                np.testing.assert_allclose(centre + half * axis, p1[p, s], atol=2e-5)
        torso = sc.model.geom("person0_torso").id
        np.testing.assert_allclose(data.geom_xpos[b, torso],
                                   np.asarray(pd.torso_position(st, sc.gait))[0], atol=2e-5)
    # Active people's legs are above the floor, inactive ones parked below it.
    assert np.all(ped.mask[:, :3]) and not np.any(ped.mask[:, 3])
    legs = sc.leg_mocap
    assert np.all(data.mocap_pos[:, legs[:3], 2] > 0.3)
    assert np.all(data.mocap_pos[:, legs[3], 2] < -10)


def test_mujoco_cpu_kinematics_agrees_on_the_legs(sc, episodes):
    """The mocap poses, read by MuJoCo on the CPU, give the same capsule end points."""
    data, ped, _ = episodes
    d = mujoco.MjData(sc.model)
    d.qpos[:] = data.qpos[2]
    d.mocap_pos[:] = data.mocap_pos[2]
    d.mocap_quat[:] = data.mocap_quat[2]
    mujoco.mj_kinematics(sc.model, d)
    st = jax.tree_util.tree_map(lambda x: x[2], ped)
    p0, p1, _ = (np.asarray(a) for a in scene.leg_capsules(st, sc.gait))
    for p in range(3):
        g = sc.model.geom(f"person{p}_r_leg").id
        axis = d.geom_xmat[g].reshape(3, 3)[:, 2]
        np.testing.assert_allclose(d.geom_xpos[g] + 0.5 * sc.gait.leg_length * axis, p1[p, 1],
                                   atol=2e-5)
    np.testing.assert_allclose(d.xpos[sc.model.body("robot").id][:2], data.qpos[2, :2],
                               atol=1e-5)


def test_laser_plane_geometry_matches_mj_ray(sc):
    """Rays at shin height (0.3 m) from the robot's position hit the exported circles and
    walls at their analytic distances."""
    centres, radii = sc.furniture_circles()
    assert centres.shape == (24, 2) and radii.shape == (24,)
    assert set(np.round(radii, 3)) == {0.04, 0.025}
    walls = sc.wall_segments()
    assert walls.shape == (4, 2, 2)
    d = mujoco.MjData(sc.model)
    d.mocap_pos[:] = [0.0, 0.0, -50.0]
    mujoco.mj_kinematics(sc.model, d)
    geomid = np.zeros(1, np.int32)
    robot = sc.model.body("robot").id
    item_centres = np.repeat([it["centre"] for it in sc.furniture], 4, axis=0)
    for c, r, ic in zip(centres, radii, item_centres):
        out = (c - ic) / np.linalg.norm(c - ic)
        start = np.array([*(c - 0.3 * out), 0.3])  # 0.3 m inside the table / chair
        got = mujoco.mj_ray(sc.model, d, start, np.array([*out, 0.0]), None, 1, robot, geomid)
        np.testing.assert_allclose(got, 0.3 - r, atol=1e-6)
    origin = np.array([0.0, 0.0, 0.3])
    for (a, b) in walls:
        mid = 0.5 * (a + b)
        v = np.array([mid[0], mid[1], 0.0])
        got = mujoco.mj_ray(sc.model, d, origin, v / np.linalg.norm(v), None, 1, robot, geomid)
        np.testing.assert_allclose(got, np.linalg.norm(mid), atol=1e-6)
    # Every geom is a primitive mjx.ray handles and has a material.
    assert set(sc.model.geom_type) <= {0, 2, 3, 6}
    assert np.all(sc.model.geom_matid[sc.model.geom_rgba[:, 3] > 0] >= 0)
    # Furniture footprints cover the legs (pedestrians walk around them).
    fp = sc.footprints
    inside = np.linalg.norm(centres[:, None] - fp[None, :, :2], axis=-1) < fp[None, :, 2]
    assert np.all(inside.any(1))


def test_contacts_are_robot_against_walls_and_furniture_only():
    sc = scene.build(num_people=2, contacts=True)
    m = sc.model
    d = mujoco.MjData(m)
    centres, radii = sc.furniture_circles()
    d.qpos[:] = [centres[0, 0] + 0.2, centres[0, 1], 0.0]  # sphere overlapping a table leg
    d.mocap_pos[:] = [centres[0, 0] + 0.2, centres[0, 1], 0.5]  # people there too
    mujoco.mj_forward(m, d)
    assert d.ncon >= 1
    pairs = {tuple(sorted((d.contact[i].geom1, d.contact[i].geom2))) for i in range(d.ncon)}
    assert all(sc.robot_geom in p for p in pairs)
    names = {m.geom(g).name for p in pairs for g in p} - {"robot_collision"}
    assert all("_leg" in n and n.startswith(("table", "chair")) for n in names)
    free = scene.build(num_people=2, contacts=False).model
    assert free.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT


def test_bad_input_raises_clearly(sc):
    with pytest.raises(ValueError, match="num_people"):
        scene.build(num_people=0)
    with pytest.raises(ValueError, match="too small"):
        scene.build(room=(4.0, 4.0))
    with pytest.raises(ValueError, match="dt"):
        scene.build(dt=0.2)
    cfg = scene.pedestrian_config(sc, distractors=4)
    with pytest.raises(ValueError, match="capacity"):
        pd.init(jax.random.PRNGKey(0), cfg, sc.num_people)
    data = scene.reset(sc, jnp.zeros(3))
    wrong = pd.init(jax.random.PRNGKey(0), cfg._replace(distractors=1), 6)
    with pytest.raises(ValueError, match="4 people"):
        scene.set_people(sc, data, wrong)
    with pytest.raises(ValueError, match="u must"):
        scene.robot_step(sc, data, jnp.zeros(3))
    with pytest.raises(ValueError, match="robot_pose"):
        scene.reset(sc, jnp.zeros(2))
