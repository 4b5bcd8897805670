"""Simulated RGB-D person detector and odometry: statistics over many keys vs the configuration.

The occlusion rule is checked against a dense numpy sampling of the angular extents; the miss
rate, noise std and false-positive count against their configured values within binomial /
sampling tolerances (4 standard errors); odometry against an exact noise-free round trip.
"""

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack import geometry
from sims.following import rgbd

N = 4000
# One capacity for every test, so that each batched function compiles once (the float fields
# of the configuration are traced leaves).
CFG = rgbd.RGBDConfig(miss_prob=0.2, false_rate=0.0, max_false=6)
ROBOT = jnp.array([0.5, -1.0, 0.4])

detect_keys = jax.jit(jax.vmap(rgbd.detect, in_axes=(0, None, None, None, None, None)))
visible = jax.jit(rgbd.visible, static_argnums=0)
visible_many = jax.jit(jax.vmap(rgbd.visible, in_axes=(None, None, 0, None)), static_argnums=0)


def world(rel, robot=ROBOT):
    """Robot-frame points [..., 2] to world coordinates."""
    c, s = np.cos(robot[2]), np.sin(robot[2])
    return np.asarray(robot[:2]) + np.asarray(rel) @ np.array([[c, s], [-s, c]])


def polar(r, b):
    return np.stack([r * np.cos(b), r * np.sin(b)], -1)


def test_field_of_view_and_range_limits():
    half = math.radians(57.0) / 2
    r = np.array([0.45, 0.55, 2.0, 4.4, 4.6, 2.0, 2.0, 2.0, 3.0])
    b = np.array([0.0, 0.0, 0.0, 0.1, 0.1, half - 0.01, half + 0.01, -half + 0.01, np.pi])
    expected = np.array([0, 1, 1, 1, 0, 1, 0, 1, 0], bool)
    people = jnp.asarray(world(polar(r, b))[:, None, :])          # one person per frame
    got = np.asarray(visible_many(CFG, ROBOT, people, jnp.array([True])))[:, 0]
    np.testing.assert_array_equal(got, expected)


def coverage_reference(rel, mask, i, radius=0.25, samples=4001):
    """Covered fraction of person i's angular extent, by dense numpy sampling."""
    d = np.hypot(rel[:, 0], rel[:, 1])
    b = np.arctan2(rel[:, 1], rel[:, 0])
    w = np.arcsin(np.minimum(1.0, radius / d))
    a = b[i] + w[i] * np.linspace(-1, 1, samples)
    covered = np.zeros(samples, bool)
    for j in range(len(d)):
        if j != i and mask[j] and d[j] < d[i]:
            covered |= np.abs((a - b[j] + np.pi) % (2 * np.pi) - np.pi) <= w[j]
    return covered.mean()


def test_occlusion_by_nearer_people_matches_dense_angular_coverage():
    # directly behind, half hidden, slightly offset, behind a masked-out person, side by side
    cases = [
        ([[2.0, 0.0], [3.5, 0.0]], [True, True], [True, False]),
        ([[2.0, 0.0], [3.5, 0.3]], [True, True], None),
        ([[2.0, 0.0], [3.5, 0.6]], [True, True], [True, True]),
        ([[2.0, 0.0], [3.5, 0.0]], [False, True], [False, True]),
        ([[2.0, -0.3], [2.0, 0.3]], [True, True], [True, True]),
        ([[1.0, 0.0], [2.0, 0.2], [3.0, 0.5]], [True, True, True], None),
    ]
    rng = np.random.default_rng(0)
    for _ in range(30):  # random crowds in front of the robot
        rel = polar(rng.uniform(0.6, 4.4, 4), rng.uniform(-0.5, 0.5, 4))
        cases.append((rel.tolist(), [True] * 4, None))
    checked = 0
    for rel, mask, expected in cases:
        rel, mask = np.asarray(rel, float), np.asarray(mask)
        got = np.asarray(visible(CFG, ROBOT, jnp.asarray(world(rel)), jnp.asarray(mask)))
        if expected is not None:
            np.testing.assert_array_equal(got, expected)
        for i in range(len(rel)):
            if not mask[i]:
                assert not got[i]
                continue
            frac = coverage_reference(rel, mask, i)
            if abs(frac - 0.5) > 0.07:   # 16 samples resolve the fraction to 1/16
                assert got[i] == (frac <= 0.5), (rel, i, frac)
                checked += 1
    assert checked > 60


def test_miss_rate_and_noise_match_the_configuration():
    rel = np.array([[2.0, 0.4], [3.0, -0.8]])
    colour = jnp.array([[0.9, 0.2, 0.1], [0.1, 0.5, 0.8]])
    keys = jax.random.split(jax.random.key(1), N)
    det = detect_keys(keys, CFG, ROBOT, jnp.asarray(world(rel)), jnp.array([True, True]),
                      colour)
    mask, ids = np.asarray(det.mask), np.asarray(det.person_id)
    assert np.all(ids[~mask] == -1) and np.all(ids[mask] >= 0)  # no false positives configured
    for i in range(2):
        hit = np.any(mask & (ids == i), axis=1)
        miss_rate = 1 - hit.mean()
        assert abs(miss_rate - 0.2) < 4 * math.sqrt(0.2 * 0.8 / N)
        rows, cols = np.nonzero(mask & (ids == i))
        err = np.asarray(det.xy)[rows, cols] - rel[i]
        n = len(err)
        np.testing.assert_allclose(err.mean(0), 0.0, atol=4 * 0.3 / math.sqrt(n))
        np.testing.assert_allclose(err.std(0), 0.3, rtol=4 / math.sqrt(2 * n))
        col_err = np.asarray(det.colour)[rows, cols] - np.asarray(colour[i])
        inner = np.abs(np.asarray(colour[i]) - 0.5) < 0.35   # unaffected by the clip to [0, 1]
        np.testing.assert_allclose(col_err[:, inner].std(0), 0.05, rtol=0.1)
    # the rows are shuffled: person 0's row varies from frame to frame
    rows0 = np.argmax(ids == 0, axis=1)[np.any(ids == 0, axis=1)]
    assert len(np.unique(rows0)) == mask.shape[1]


def test_false_positives_are_poisson_uniform_in_the_field_of_view():
    cfg = dataclasses.replace(CFG, false_rate=1.5)
    people, mask, colour = jnp.zeros((2, 2)), jnp.array([False, False]), jnp.zeros((2, 3))
    keys = jax.random.split(jax.random.key(2), N)
    det = detect_keys(keys, cfg, ROBOT, people, mask, colour)
    mask = np.asarray(det.mask)
    assert mask.shape == (N, 8)
    count = mask.sum(1)
    # Poisson(1.5): mean 1.5, variance 1.5 (truncation at 6 removes 1e-3 of the mass)
    assert abs(count.mean() - 1.5) < 4 * math.sqrt(1.5 / N)
    assert abs(count.var() - 1.5) < 0.15
    xy = np.asarray(det.xy)[mask]
    r, b = np.hypot(xy[:, 0], xy[:, 1]), np.arctan2(xy[:, 1], xy[:, 0])
    assert r.min() >= 0.5 and r.max() <= 4.5 and np.abs(b).max() <= math.radians(57) / 2
    # uniform over the sector's area: P(r < 2.5) = (2.5^2 - 0.5^2) / (4.5^2 - 0.5^2) = 0.3
    frac = (r < 2.5).mean()
    assert abs(frac - 0.3) < 4 * math.sqrt(0.3 * 0.7 / len(r))
    assert np.all(np.asarray(det.person_id)[mask] == -1)
    col = np.asarray(det.colour)[mask]
    assert col.min() >= 0 and col.max() <= 1 and abs(col.mean() - 0.5) < 0.02
    capped = detect_keys(keys, dataclasses.replace(CFG, false_rate=9.0), ROBOT, people,
                         jnp.array([False, False]), colour)
    assert np.asarray(capped.mask).sum(1).max() == 6


def test_no_false_positive_falls_behind_a_wall():
    """A wall across the view 2 m ahead: the false positives are those of the open view (same
    keys) in front of it, at the same places."""
    cfg = dataclasses.replace(CFG, false_rate=1.5)
    people, mask, colour = jnp.zeros((2, 2)), jnp.array([False, False]), jnp.zeros((2, 3))
    wall = geometry.from_frame(ROBOT, jnp.array([[2.0, -3.0], [2.0, 3.0]]))[None]
    keys = jax.random.split(jax.random.key(5), 500)
    walled = jax.jit(jax.vmap(functools.partial(rgbd.detect, walls=wall),
                              in_axes=(0, None, None, None, None, None)))
    a = detect_keys(keys, cfg, ROBOT, people, mask, colour)
    b = walled(keys, cfg, ROBOT, people, mask, colour)
    a_mask, b_mask, a_xy = np.asarray(a.mask), np.asarray(b.mask), np.asarray(a.xy)
    in_front = a_mask & (a_xy[..., 0] < 2.0)
    assert in_front.sum() > 100 and (a_mask & ~in_front).sum() > 400
    np.testing.assert_array_equal(b_mask, in_front)
    np.testing.assert_allclose(np.asarray(b.xy)[b_mask], a_xy[in_front], rtol=1e-6)


def test_detect_jits_and_vmaps_over_robot_poses_and_noise_levels():
    people = jnp.array([[2.0, 0.0], [-2.0, 0.0], [np.nan, np.nan]])
    mask = jnp.array([True, True, False])
    colour = jnp.full((3, 3), 0.5)
    # a batch of two frames: different robot poses *and* noise levels (traced config leaves)
    poses = jnp.asarray([[0.0, 0.0, 0.0], [0.0, 0.0, np.pi]])
    cfgs = jax.tree_util.tree_map(lambda x: jnp.asarray([x, x]), rgbd.RGBDConfig(miss_prob=0.0))
    cfgs = dataclasses.replace(cfgs, position_std=jnp.array([0.0, 0.3]))
    f = jax.jit(jax.vmap(rgbd.detect, in_axes=(None, 0, 0, None, None, None)))
    det = f(jax.random.key(3), cfgs, poses, people, mask, colour)
    ids = np.asarray(det.person_id)
    assert sorted(ids[0][ids[0] >= 0]) == [0] and sorted(ids[1][ids[1] >= 0]) == [1]
    assert np.all(np.isfinite(np.asarray(det.xy)))
    np.testing.assert_allclose(np.asarray(det.xy)[0][ids[0] == 0], [[2.0, 0.0]], atol=1e-12)

    def err(std):
        cfg = dataclasses.replace(rgbd.RGBDConfig(miss_prob=0.0), position_std=std)
        d = rgbd.detect(jax.random.key(5), cfg, jnp.zeros(3), people, mask, colour)
        return jnp.sum(jnp.where(d.mask[:, None], d.xy - jnp.array([2.0, 0.0]), 0.0))
    # the detection is the truth plus std times a fixed normal draw: d err / d std = err / std
    value, grad = jax.jit(jax.value_and_grad(err))(0.3)
    assert float(grad) != 0.0
    np.testing.assert_allclose(float(grad), float(value) / 0.3, rtol=1e-10)


odometry = jax.jit(rgbd.odometry)
odometry_keys = jax.jit(jax.vmap(rgbd.odometry, in_axes=(0, None, None, None)))


@pytest.mark.parametrize("dtype,tol", [(jnp.float64, 1e-12), (jnp.float32, 1e-5)])
def test_noise_free_odometry_round_trips(dtype, tol):
    rng = np.random.default_rng(4)
    exact = rgbd.OdometryConfig(0.0, 0.0, 0.0, 0.0)
    prev = rng.uniform([-3, -3, -np.pi], [3, 3, np.pi], (30, 3))
    step = np.column_stack([rng.normal(0, 0.3, (30, 2)), rng.normal(0, 0.5, 30)])
    step[0, :2] = 0.0                                    # pure rotation
    step[1] = [-0.2 * np.cos(prev[1, 2]), -0.2 * np.sin(prev[1, 2]), 0.1]   # reversing
    poses = prev + step
    for a, b in zip(prev, poses):
        odo = odometry(jax.random.key(0), exact, jnp.asarray(a, dtype), jnp.asarray(b, dtype))
        back = np.asarray(rgbd.integrate(jnp.asarray(a, dtype), odo), float)
        np.testing.assert_allclose(back[:2], b[:2], atol=tol * 10)
        assert abs((back[2] - b[2] + np.pi) % (2 * np.pi) - np.pi) < tol * 10
    # reversing reads as a negative forward increment, not a half turn
    odo = np.asarray(odometry(jax.random.key(0), exact, jnp.asarray(prev[1]),
                              jnp.asarray(poses[1])))
    np.testing.assert_allclose(odo, [-0.2, 0.0, 0.1], atol=1e-9)
    path = rgbd.accumulate(jnp.asarray(prev[0]), jnp.tile(jnp.array([0.1, 0.0, 0.0]), (5, 1)))
    np.testing.assert_allclose(path[-1, :2], prev[0, :2] + 0.5 * np.array(
        [np.cos(prev[0, 2]), np.sin(prev[0, 2])]), atol=1e-12)


def test_odometry_noise_is_proportional_to_motion():
    cfg = rgbd.OdometryConfig(alpha1=0.01, alpha2=0.002, alpha3=0.004, alpha4=0.001)
    keys = jax.random.split(jax.random.key(7), N)
    for length in (0.5, 1.0):
        odo = np.asarray(odometry_keys(keys, cfg, jnp.zeros(3), jnp.array([length, 0.0, 0.0])))
        # straight: rot1 = rot2 = 0, trans = L: std(trans) = sqrt(a3) L, std(rot_k) = sqrt(a2) L
        np.testing.assert_allclose(odo[:, 0].std(), math.sqrt(0.004) * length, rtol=0.1)
        np.testing.assert_allclose(odo[:, 2].std(), math.sqrt(2 * 0.002) * length, rtol=0.1)
        # dy = trans sin(rot1): std about L sqrt(a2) L
        np.testing.assert_allclose(odo[:, 1].std(), math.sqrt(0.002) * length ** 2, rtol=0.1)
        assert abs(odo[:, 0].mean() - length) < 4 * math.sqrt(0.004) * length / math.sqrt(N)
    turn = np.asarray(odometry_keys(keys, cfg, jnp.zeros(3), jnp.array([0.0, 0.0, 0.8])))
    # pure rotation: all in rot2, std sqrt(a1) |rot|; translation noise sqrt(a4) |rot|
    np.testing.assert_allclose(turn[:, 2].std(), math.sqrt(0.01) * 0.8, rtol=0.1)
    np.testing.assert_allclose(np.abs(turn[:, 0]).mean(),
                               math.sqrt(0.001) * 0.8 * math.sqrt(2 / math.pi), rtol=0.1)
    still = np.asarray(odometry_keys(keys[:10], cfg, jnp.zeros(3), jnp.zeros(3)))
    np.testing.assert_array_equal(still, 0.0)
    # turning on the spot while the centre slides 0.1 mm sideways: still a pure rotation's
    # noise (the decomposition alone would read two quarter turns: yaw std 0.22 rad)
    slide = np.asarray(odometry_keys(keys, cfg, jnp.zeros(3), jnp.array([0.0, 1e-4, 0.12])))
    np.testing.assert_allclose(slide[:, 2].std(), math.sqrt(0.01) * 0.12, rtol=0.1)
    # from 1 cm on, the decomposition's: a 2 cm sideways step turns by 90 deg and back
    side = np.asarray(odometry_keys(keys, cfg, jnp.zeros(3), jnp.array([0.0, 0.02, 0.0])))
    assert side[:, 2].std() > 10 * math.sqrt(2 * 0.002) * 0.02


def test_bad_input_raises_clear_errors():
    people, mask, colour = jnp.zeros((2, 2)), jnp.array([True, True]), jnp.zeros((2, 3))
    key = jax.random.key(0)
    with pytest.raises(TypeError, match="RGBDConfig"):
        rgbd.detect(key, {"fov": 1.0}, jnp.zeros(3), people, mask, colour)
    with pytest.raises(ValueError, match="cfg.miss_prob must be in"):
        rgbd.detect(key, rgbd.RGBDConfig(miss_prob=1.5), jnp.zeros(3), people, mask, colour)
    with pytest.raises(ValueError, match="cfg.max_range must be > min_range"):
        rgbd.detect(key, rgbd.RGBDConfig(max_range=0.4), jnp.zeros(3), people, mask, colour)
    with pytest.raises(ValueError, match="cfg.max_false must be an int"):
        rgbd.detect(key, rgbd.RGBDConfig(max_false=-1), jnp.zeros(3), people, mask, colour)
    with pytest.raises(ValueError, match="cfg.position_std must be finite"):
        rgbd.detect(key, rgbd.RGBDConfig(position_std=math.nan), jnp.zeros(3), people, mask,
                    colour)
    with pytest.raises(ValueError, match="people_xy must have shape"):
        rgbd.detect(key, rgbd.RGBDConfig(), jnp.zeros(3), jnp.zeros((2, 3)), mask, colour)
    with pytest.raises(ValueError, match="people_mask must have shape"):
        rgbd.detect(key, rgbd.RGBDConfig(), jnp.zeros(3), people, mask[:1], colour)
    with pytest.raises(TypeError, match="people_mask must be bool"):
        rgbd.detect(key, rgbd.RGBDConfig(), jnp.zeros(3), people, jnp.ones(2), colour)
    with pytest.raises(ValueError, match="people_colour must have shape"):
        rgbd.detect(key, rgbd.RGBDConfig(), jnp.zeros(3), people, mask, jnp.zeros((2, 4)))
    with pytest.raises(ValueError, match="people_mask is True"):
        rgbd.detect(key, rgbd.RGBDConfig(), jnp.zeros(3), people.at[0, 0].set(jnp.nan), mask,
                    colour)
    with pytest.raises(ValueError, match="robot_pose contains NaN"):
        rgbd.visible(rgbd.RGBDConfig(), jnp.array([0.0, jnp.nan, 0.0]), people, mask)
    with pytest.raises(TypeError, match="OdometryConfig"):
        rgbd.odometry(key, rgbd.RGBDConfig(), jnp.zeros(3), jnp.zeros(3))
    with pytest.raises(ValueError, match="cfg.alpha3 must be >= 0"):
        rgbd.odometry(key, rgbd.OdometryConfig(alpha3=-0.1), jnp.zeros(3), jnp.zeros(3))
    with pytest.raises(ValueError, match="pose must have shape"):
        rgbd.odometry(key, rgbd.OdometryConfig(), jnp.zeros(3), jnp.zeros(2))
    with pytest.raises(ValueError, match="odom must have shape"):
        rgbd.integrate(jnp.zeros(3), jnp.zeros(2))


def test_a_shelf_hides_the_people_behind_it():
    # Two people ahead; a shelf edge crosses the line of sight to the second only.
    cfg = rgbd.RGBDConfig(miss_prob=0.0, false_rate=0.0)
    people = jnp.array([[2.0, 0.5], [3.0, -0.6]])
    shelf = jnp.array([[[2.0, -1.0], [2.0, -0.1]]])
    colours = jnp.full((2, 3), 0.5)
    mask = jnp.array([True, True])
    free = rgbd.detect(jax.random.PRNGKey(0), cfg, jnp.zeros(3), people, mask, colours)
    hidden = rgbd.detect(jax.random.PRNGKey(0), cfg, jnp.zeros(3), people, mask, colours,
                         walls=shelf)
    assert sorted(np.asarray(free.person_id)[np.asarray(free.mask)].tolist()) == [0, 1]
    assert np.asarray(hidden.person_id)[np.asarray(hidden.mask)].tolist() == [0]
    # The same test from a camera turned away: nobody (the field of view turns with it).
    back = rgbd.detect(jax.random.PRNGKey(0), cfg, jnp.array([0.0, 0.0, np.pi]), people, mask,
                       colours)
    assert not np.asarray(back.mask).any()
