"""The sensing step with several lasers fused (`jaxtrack.perception.sensing`): scans from the
following scene's ray caster at known mounts; each laser sees the people in its own field of
view, the fused step sees them all once, in the right place."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.perception import legs, sensing
from sims.following import lidar

CFG = lidar.LaserConfig(fov_deg=180.0, step_deg=0.5, noise_std=0.0)
ANGLES = lidar.beam_angles(CFG, jnp.float32)
FRONT, REAR = (0.2, 0.0, 0.0), (-0.2, 0.0, math.pi)
ROBOT = np.array([1.0, -0.5, 0.3])      # the robot's pose in the odometry (= map) frame
LP = legs.LegParams(max_range=CFG.max_range, min_range=CFG.min_range)


def _people_circles(mids):
    """Two legs 0.3 m apart, across the line of sight from the robot, per person (world)."""
    centres = []
    for m in mids:
        d = np.asarray(m) - ROBOT[:2]
        u = np.array([-d[1], d[0]]) / np.linalg.norm(d)
        centres += [m + 0.15 * u, m - 0.15 * u]
    n = len(centres)
    return lidar.Circles(jnp.asarray(np.array(centres), jnp.float32),
                         jnp.full(n, 0.06, jnp.float32), jnp.ones(n, bool))


def _scan(mount, circles):
    walls = lidar.Walls(jnp.zeros((0, 2, 2), jnp.float32), jnp.zeros(0, bool))
    pose = sensing.sensor_pose(jnp.asarray(ROBOT, jnp.float32), mount)
    return lidar.scan(jax.random.PRNGKey(0), pose, circles, walls, CFG)


def _sense(cfg, ranges, angles):
    odom = sensing.Odometry(jnp.asarray(ROBOT, jnp.float32), jnp.zeros(3, jnp.float32))
    return jax.jit(sensing.sense, static_argnums=0)(
        cfg, sensing.init(cfg), ranges, angles, odom, jnp.zeros((1, 2)), jnp.zeros(1, bool),
        None, sensing.empty_map(), odom.pose, 0.1)


def _found(sensed):
    return np.asarray(sensed.laser_xy)[np.asarray(sensed.laser_mask)]


def _world(rel):
    c, s = math.cos(ROBOT[2]), math.sin(ROBOT[2])
    return ROBOT[:2] + np.array([[c, -s], [s, c]]) @ np.asarray(rel)


AHEAD, BEHIND = _world([2.0, 0.4]), _world([-1.8, -0.6])


@pytest.fixture(scope="module")
def two_lasers():
    circles = _people_circles([AHEAD, BEHIND])
    ranges = jnp.stack([_scan(FRONT, circles), _scan(REAR, circles)])
    cfg = sensing.SensingConfig(LP, 32, 4, (FRONT, REAR))
    return cfg, ranges, _sense(cfg, ranges, jnp.stack([ANGLES, ANGLES]))


def test_front_and_rear_lasers_fused_see_the_people_ahead_and_behind(two_lasers):
    cfg, ranges, (state, sensed) = two_lasers
    found = _found(sensed)
    assert found.shape == (2, 2)
    err = np.linalg.norm(found[:, None] - np.array([AHEAD, BEHIND])[None], axis=-1).min(0)
    assert np.all(err < 0.03), err
    # Each laser alone sees only its own side.
    for i, (mount, expected) in enumerate(((FRONT, AHEAD), (REAR, BEHIND))):
        one = sensing.SensingConfig(LP, 32, 4, mount)
        alone = _found(_sense(one, ranges[i], ANGLES)[1])
        assert alone.shape == (1, 2) and np.linalg.norm(alone[0] - expected) < 0.03
    # Shapes: one laser's capacity (compacted); four legs; every return, in the robot frame.
    assert sensed.laser_xy.shape == (4, 2) and sensed.legs_xy.shape == (32, 2)
    assert sensed.returns_xy.shape == (2 * ANGLES.shape[0], 2)
    assert int(sensed.legs_mask.sum()) == 4 and state.legs_xy.shape == (32, 2)
    rear_returns = np.asarray(sensed.returns_xy)[ANGLES.shape[0]:][
        np.asarray(sensed.returns_mask)[ANGLES.shape[0]:]]
    assert len(rear_returns) and np.all(rear_returns[:, 0] < -0.2)


def test_a_person_both_lasers_see_is_detected_once():
    # Two forward lasers 0.4 m apart: their fields of view overlap ahead.
    left, right = (0.2, 0.2, 0.0), (0.2, -0.2, 0.0)
    circles = _people_circles([AHEAD])
    ranges = jnp.stack([_scan(left, circles), _scan(right, circles)])
    angles = jnp.stack([ANGLES, ANGLES])
    _, merged = _sense(sensing.SensingConfig(LP, 32, 4, (left, right)), ranges, angles)
    assert len(_found(merged)) == 1 and int(merged.legs_mask.sum()) == 2
    assert np.linalg.norm(_found(merged)[0] - AHEAD) < 0.03
    _, twice = _sense(sensing.SensingConfig(LP, 32, 4, (left, right), merge_radius=0.0),
                      ranges, angles)
    assert len(_found(twice)) == 2 and int(twice.legs_mask.sum()) == 4


def test_one_mount_in_a_tuple_equals_the_single_laser_step():
    circles = _people_circles([AHEAD])
    ranges = _scan(FRONT, circles)
    _, single = _sense(sensing.SensingConfig(LP, 32, 4, FRONT[:2]), ranges, ANGLES)
    _, multi = _sense(sensing.SensingConfig(LP, 32, 4, (FRONT,)), ranges[None], ANGLES[None])
    for a, b in zip(single, multi):
        if a is not None:
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_a_turned_mount_puts_the_people_where_they_are():
    # A laser facing left (yaw 90 deg): the person to the robot's left is in its view.
    mount = (0.0, 0.1, math.pi / 2)
    left_of_robot = _world([0.3, 2.0])
    ranges = _scan(mount, _people_circles([left_of_robot]))
    _, sensed = _sense(sensing.SensingConfig(LP, 32, 4, mount), ranges, ANGLES)
    found = _found(sensed)
    assert found.shape == (1, 2) and np.linalg.norm(found[0] - left_of_robot) < 0.03


@pytest.mark.parametrize("mount", [(0.0,), (0.0, 0.0, 0.0, 0.0), (0.0, float("nan")), (),
                                   ((0.0, 0.0), (1.0,))])
def test_bad_mounts_are_refused(mount):
    with pytest.raises(ValueError, match="laser mount|laser_mount"):
        sensing.SensingConfig(laser_mount=mount)


def test_ranges_must_hold_one_scan_per_laser(two_lasers):
    cfg, ranges, _ = two_lasers
    with pytest.raises(ValueError, match="ranges"):
        _sense(cfg, ranges[0], ANGLES)
    with pytest.raises(ValueError, match="merge_radius"):
        sensing.SensingConfig(merge_radius=-1.0)


def test_beyond_one_lasers_capacity_the_later_lasers_people_are_dropped(two_lasers):
    _, ranges, _ = two_lasers
    cfg = sensing.SensingConfig(LP, 32, 1, (FRONT, REAR))
    found = _found(_sense(cfg, ranges, jnp.stack([ANGLES, ANGLES]))[1])
    assert found.shape == (1, 2) and np.linalg.norm(found[0] - AHEAD) < 0.03
