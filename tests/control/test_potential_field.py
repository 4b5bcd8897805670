"""Seed 002 person-interest-adapted potential field: where its minimum lands, gradient following.

The field is checked against an independent numpy sum of four Gaussian densities
(scipy.stats.multivariate_normal, rescaled to unit peak); the minimum is found by brute-force
grid search and compared with the seed's description (Fig. 3, section IV-B): about 2 m in
front for PI = 0, about 45 deg just outside the personal zone (1.2 m) for PI = 0.5, in front at
the border of the intimate zone (0.45 m) for PI = 1.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import multivariate_normal

from jaxtrack.control import follower
from jaxtrack.control import potential_field as pf

PARAMS = pf.Params.create()
PERSON = np.array([1.0, -0.5, 0.6])  # the person, off the origin and turned
GRID = np.linspace(-4.0, 4.0, 401)   # 2 cm, in the person's frame

potential = jax.jit(pf.potential)
gradient = jax.jit(pf.gradient)


def to_world(q, person=PERSON):
    c, s = np.cos(person[2]), np.sin(person[2])
    return person[:2] + np.asarray(q) @ np.array([[c, s], [-s, c]])


def to_person(xy, person=PERSON):
    c, s = np.cos(person[2]), np.sin(person[2])
    return (np.asarray(xy) - person[:2]) @ np.array([[c, -s], [s, c]])


def unit_gaussian(q, cov):
    return multivariate_normal(np.zeros(2), cov).pdf(q) / multivariate_normal(
        np.zeros(2), cov).pdf(np.zeros(2))


def reference_field(q, interest):
    """The four-Gaussian field written independently from the module's docstring."""
    q = np.atleast_2d(q)
    lerp = lambda table: np.exp(np.interp(interest, [0, 0.5, 1], np.log(table)))  # noqa: E731
    par = [lerp([0.02, 1.0, 0.02]), lerp([0.01, 0.1, 0.01])]
    perp = [lerp([0.8, 0.5, 0.5]), lerp([0.75, 0.1, 0.02])]
    front = 1.0 / (1.0 + np.exp(-q[:, 0] / 0.05))
    folded = np.stack([q[:, 0], np.abs(q[:, 1])], -1)
    return (-unit_gaussian(q, 7.5 * np.eye(2)) + (1 - front) * unit_gaussian(q, np.diag([2, 1]))
            + front * (unit_gaussian(folded, np.diag(par))
                       + unit_gaussian(folded, np.diag([perp[1], perp[0]]))))


def grid_minimum(interest):
    qx, qy = np.meshgrid(GRID, GRID, indexing="ij")
    q = np.stack([qx, qy], -1)
    f = np.asarray(potential(PARAMS, jnp.asarray(to_world(q.reshape(-1, 2)).reshape(q.shape)),
                             jnp.asarray(PERSON), interest))
    i = np.unravel_index(np.argmin(f), f.shape)
    return q[i], f


def test_field_matches_an_independent_sum_of_gaussian_densities():
    rng = np.random.default_rng(0)
    q = rng.uniform(-3, 3, (200, 2))
    for interest in [0.0, 0.25, 0.5, 0.8, 1.0]:
        got = np.asarray(potential(PARAMS, jnp.asarray(to_world(q)), jnp.asarray(PERSON),
                                   interest))
        np.testing.assert_allclose(got, reference_field(q, interest), atol=1e-12)


@pytest.mark.parametrize("interest,distance,bearing", [
    (0.0, (1.8, 2.2), (0.0, 3.0)),                     # about 2 m in front
    (0.5, (pf.PERSONAL, 1.4), (40.0, 50.0)),           # about 45 deg, just outside 1.2 m
    (1.0, (pf.INTIMATE, 0.6), (0.0, 3.0)),             # in front, just outside 0.45 m
])
def test_grid_minimum_lands_where_the_seed_says(interest, distance, bearing):
    q, f = grid_minimum(interest)
    r, b = np.hypot(*q), np.degrees(np.arctan2(abs(q[1]), q[0]))
    assert distance[0] < r < distance[1], r
    assert bearing[0] <= b <= bearing[1], b
    # the only local minima are q and its mirror image across the heading
    inner = f[1:-1, 1:-1]
    local = np.ones_like(inner, bool)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            if dx or dy:
                local &= inner <= f[1 + dx:f.shape[0] - 1 + dx, 1 + dy:f.shape[1] - 1 + dy]
    minima = {(round(GRID[i + 1], 2), round(abs(GRID[j + 1]), 2)) for i, j in np.argwhere(local)}
    assert minima == {(round(q[0], 2), round(abs(q[1]), 2))}


@jax.jit
def descend(xy, interest):
    def body(xy, _):
        return pf.gradient_step(PARAMS, xy, jnp.asarray(PERSON), interest, 1.0), None
    # the PI = 0 valley is flat across the heading (curvature 0.007 / m^2): many small steps
    return jax.lax.scan(body, xy, None, length=3000)[0]


STARTS = np.array([[3.0, 0.4], [2.5, -2.0], [-2.0, 1.0], [-1.5, -2.5], [0.3, 3.0],
                   [0.6, -0.2]])


@pytest.mark.parametrize("interest", [0.0, 0.5, 1.0])
def test_gradient_descent_from_several_starts_reaches_the_grid_minimum(interest):
    q_min, _ = grid_minimum(interest)
    ends = np.asarray(jax.vmap(descend, in_axes=(0, None))(jnp.asarray(to_world(STARTS)),
                                                             interest))
    q_end = to_person(ends)
    for start, q in zip(STARTS, q_end):
        # mirror image on the start's side for the two-valley PI = 0.5 field
        target = np.array([q_min[0], np.sign(q[1]) * abs(q_min[1])])
        assert np.linalg.norm(q - target) < 0.03, (start, q, target)


def drive_from_starts(drive, interest):
    """[6, 3] end poses of ``drive(pose, interest)`` from STARTS, at assorted headings."""
    headings = np.array([0.0, 2.0, -2.5, 1.0, 3.0, -1.0])
    poses = jnp.asarray(np.column_stack([to_world(STARTS), headings]))
    return np.asarray(jax.vmap(drive, in_axes=(0, None))(poses, interest))


@jax.jit
def approach(pose, interest):
    def body(pose, _):
        u = pf.approach_velocity(PARAMS, pose, jnp.asarray(PERSON), interest, gain=10.0)
        return follower.unicycle_step(pose, u, 0.05), None
    return jax.lax.scan(body, pose, None, length=1600)[0]


@pytest.mark.parametrize("interest", [0.0, 1.0])
def test_unicycle_gradient_following_settles_at_the_minimum_and_faces_the_person(interest):
    q_min, _ = grid_minimum(interest)
    ends = drive_from_starts(approach, interest)
    for end in ends:
        q = to_person(end[:2])
        assert np.linalg.norm(q - q_min) < 0.1, q
    # at the minimum (no gradient left) the robot turns to face the person
    xy = to_world(q_min)
    bearing = np.arctan2(*(PERSON[:2] - xy)[::-1])
    for offset in (1.0, -1.0):
        u = pf.approach_velocity(PARAMS, jnp.asarray([xy[0], xy[1], bearing + offset]),
                                 jnp.asarray(PERSON), interest, gain=0.1)
        assert np.sign(float(u[1])) == -offset


_SETTLE = jax.jit(jax.vmap(
    lambda xy, interest: pf.settle_point(PARAMS, xy, jnp.asarray(PERSON, xy.dtype), interest,
                                         iterations=200), in_axes=(0, None)))


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
@pytest.mark.parametrize("interest", [0.0, 0.5, 1.0])
def test_settle_point_is_where_the_gradient_flow_ends(interest, dtype):
    # the same minima as 3000 plain gradient steps reach (the grid minimum, on the start's
    # side), in 200 clipped, line-searched Newton steps
    q_min, _ = grid_minimum(interest)
    ends = np.asarray(_SETTLE(jnp.asarray(to_world(STARTS), dtype), interest))
    assert ends.dtype == dtype
    for start, q in zip(STARTS, to_person(ends)):
        target = np.array([q_min[0], np.sign(q[1]) * abs(q_min[1])])
        assert np.linalg.norm(q - target) < 0.03, (start, q, target)
    # no step longer than max_step: a handful of iterations reach at most that far
    near = pf.settle_point(PARAMS, jnp.asarray(to_world([3.0, 0.4])), jnp.asarray(PERSON),
                           interest, iterations=4, max_step=0.05)
    assert np.linalg.norm(np.asarray(near) - to_world([3.0, 0.4])) <= 4 * 0.05 + 1e-6


@jax.jit
def approach_settling(pose, interest):
    def body(pose, _):
        target = pf.settle_point(PARAMS, pose[:2], jnp.asarray(PERSON), interest,
                                 iterations=200)
        # parked within 8 cm: stand and face the person
        near = jnp.sum((target - pose[:2]) ** 2) < 0.08 ** 2
        u = pf.approach_velocity(PARAMS, pose, jnp.asarray(PERSON), interest, gain=1.0,
                                 v_max=0.6, reverse=True,
                                 target=jnp.where(near, pose[:2], target))
        return follower.unicycle_step(pose, u, 0.1), None
    return jax.lax.scan(body, pose, None, length=300)[0]


@pytest.mark.parametrize("interest", [0.0, 1.0])
def test_driving_to_the_settle_point_reaches_the_minimum_within_30_s(interest):
    # gain 1 (m/s per unit gradient) leaves the gradient follower far from the PI = 0 and
    # PI = 1 minima after 30 s (their valleys are flat); driving to the settled point does not
    q_min, _ = grid_minimum(interest)
    ends = drive_from_starts(approach_settling, interest)
    for end in ends:
        q = to_person(end[:2])
        assert np.linalg.norm(q - q_min) < 0.08 + 0.03, q
        # stopped there facing the person
        bearing = np.arctan2(*(PERSON[:2] - end[:2])[::-1])
        assert abs(wrap_np(bearing - end[2])) < 0.05


@functools.partial(jax.jit, static_argnames="park")
def hold_near_noisy_person(pose, key, park):
    def body(carry, k):
        pose, parked = carry
        # the person stands still; their estimate jitters by 3 cm
        person = jnp.asarray(PERSON) + jnp.append(0.03 * jax.random.normal(k, (2,)), 0.0)
        target = pf.settle_point(PARAMS, pose[:2], person, 0.5, iterations=60)
        away = jnp.sqrt(jnp.sum((target - pose[:2]) ** 2))
        if park:                                     # the service scene's hysteresis
            parked = (away < 0.05) | (parked & (away < 0.25))
        u = pf.approach_velocity(PARAMS, pose, person, 0.5, gain=1.0, v_max=0.8,
                                 omega_max=1.2, reverse=True,
                                 target=jnp.where(parked, pose[:2], target))
        return (follower.unicycle_step(pose, u, 0.1), parked), u
    (pose, _), u = jax.lax.scan(body, (pose, jnp.asarray(False)), jax.random.split(key, 300))
    return pose, u


def test_parking_at_the_settled_point_stops_turning_to_and_fro():
    # arrived near the PI = 0.5 minimum from several headings, with a jittering estimate:
    # chasing the settled point, the unicycle turns to and fro; parked (with hysteresis) it
    # stands and faces the person
    q_min, _ = grid_minimum(0.5)
    xy = to_world(q_min + np.array([0.05, -0.04]))
    chased = []
    for k, heading in enumerate(np.linspace(-np.pi, np.pi, 6, endpoint=False)):
        pose = jnp.asarray([xy[0], xy[1], heading])
        end, u = hold_near_noisy_person(pose, jax.random.key(k), True)
        swing = np.ptp(np.cumsum(np.asarray(u)[100:, 1]) * 0.1)      # after 10 s
        assert swing < 0.1, heading                  # it only trims its facing (3 cm jitter)
        assert np.linalg.norm(to_person(np.asarray(end[:2])) - q_min) < 0.15
        bearing = np.arctan2(*(PERSON[:2] - np.asarray(end[:2]))[::-1])
        assert abs(wrap_np(bearing - end[2])) < 0.1                 # facing the person
        chased.append(np.ptp(np.cumsum(np.asarray(
            hold_near_noisy_person(pose, jax.random.key(k), False)[1])[100:, 1]) * 0.1))
    assert np.mean(chased) > 0.5                     # what parking prevents (0.9 rad)


def test_approach_velocity_respects_limits_and_feeds_the_person_velocity_forward():
    rng = np.random.default_rng(2)
    for _ in range(5):
        pose = jnp.asarray(rng.uniform([-3, -3, -np.pi], [3, 3, np.pi]))
        u = np.asarray(pf.approach_velocity(PARAMS, pose, jnp.asarray(PERSON), 0.3,
                                            jnp.asarray(rng.normal(size=2)), v_max=0.4,
                                            omega_max=0.7))
        assert 0.0 <= u[0] <= 0.4 + 1e-12 and abs(u[1]) <= 0.7 + 1e-12
    # at the minimum, a person walking straight ahead: drive along with them
    q_min, _ = grid_minimum(0.0)
    xy = to_world(q_min)
    pose = jnp.asarray([xy[0], xy[1], PERSON[2]])
    vel = 0.5 * np.array([np.cos(PERSON[2]), np.sin(PERSON[2])])
    u = np.asarray(pf.approach_velocity(PARAMS, pose, jnp.asarray(PERSON), 0.0,
                                        jnp.asarray(vel)))
    assert u[0] == pytest.approx(0.5, abs=0.03) and abs(u[1]) < 0.1


@jax.jit
def approach_reversing(pose, interest):
    def body(pose, _):
        u = pf.approach_velocity(PARAMS, pose, jnp.asarray(PERSON), interest, gain=10.0,
                                 reverse=True)
        off = jnp.abs(wrap_np(jnp.arctan2(*(PERSON[:2] - pose[:2])[::-1]) - pose[2]))
        return follower.unicycle_step(pose, u, 0.05), off
    return jax.lax.scan(body, pose, None, length=1600)


def wrap_np(a):
    return (a + jnp.pi) % (2 * jnp.pi) - jnp.pi


def test_reversing_backs_away_facing_the_person_and_settles_at_the_same_minimum():
    # Too close for PI 0 (whose minimum is 2 m ahead), facing the person: forward only, the
    # robot must turn its back on them to leave; reversing, it backs off still facing them.
    q_min, _ = grid_minimum(0.0)
    xy = to_world([0.6, 0.0])
    pose = jnp.asarray([xy[0], xy[1], PERSON[2] + np.pi])            # facing the person
    fwd = np.asarray(pf.approach_velocity(PARAMS, pose, jnp.asarray(PERSON), 0.0, gain=10.0))
    back = np.asarray(pf.approach_velocity(PARAMS, pose, jnp.asarray(PERSON), 0.0, gain=10.0,
                                           reverse=True))
    assert fwd[0] == 0.0 and abs(fwd[1]) > 1.0                        # turns on the spot
    assert back[0] < -0.3 and abs(back[1]) < 0.1                      # backs straight off
    end, off = approach_reversing(pose, 0.0)
    assert np.linalg.norm(to_person(np.asarray(end[:2])) - q_min) < 0.1
    # the person stays in front of the robot (bearing off its heading below 90 deg throughout)
    assert np.max(np.asarray(off)) < np.pi / 2


def test_reversing_backs_away_drives_towards_and_still_descends():
    rng = np.random.default_rng(4)
    for _ in range(20):
        pose = jnp.asarray(rng.uniform([-3, -3, -np.pi], [3, 3, np.pi]))
        for interest in (0.0, 0.5, 1.0):
            fwd = np.asarray(pf.approach_velocity(PARAMS, pose, jnp.asarray(PERSON), interest,
                                                  gain=10.0, v_max=0.6))
            back = np.asarray(pf.approach_velocity(PARAMS, pose, jnp.asarray(PERSON),
                                                   interest, gain=10.0, v_max=0.6,
                                                   reverse=True))
            assert abs(back[0]) <= 0.6 + 1e-9
            grad = np.asarray(gradient(PARAMS, pose[:2], jnp.asarray(PERSON), interest))
            to_p = PERSON[:2] - np.asarray(pose[:2])
            cos = -grad @ to_p / (np.linalg.norm(grad) * np.linalg.norm(to_p) + 1e-30)
            if cos > pf.REVERSE_COS:          # towards the person: forwards, unchanged
                np.testing.assert_allclose(back, fwd)
            elif cos < -pf.REVERSE_COS:       # away from them: backwards
                assert back[0] <= 0.0
            else:                             # round them: the smaller turn
                assert abs(back[1]) <= abs(fwd[1]) + 1e-9
            # the motion never climbs the field: v (cos, sin)(theta) . -grad >= 0 ...
            heading = np.array([np.cos(pose[2]), np.sin(pose[2])])
            if np.linalg.norm(grad) * 10.0 > 0.2:     # ... where the facing term is small
                assert back[0] * heading @ -grad >= -1e-9
            # a forward command is the forward-only one
            if back[0] > 0:
                np.testing.assert_allclose(back, fwd)


@pytest.mark.parametrize("dtype,rtol", [(jnp.float64, 1e-6), (jnp.float32, 2e-2)])
def test_gradient_matches_central_finite_differences(dtype, rtol):
    rng = np.random.default_rng(1)
    xy = rng.uniform(-2.5, 3.5, (20, 2))
    xy = xy[np.abs(to_person(xy)[:, 1]) > 0.05]   # away from the |y| fold
    for interest in [0.0, 0.5, 1.0]:
        g = np.asarray(gradient(PARAMS, jnp.asarray(xy, dtype), jnp.asarray(PERSON, dtype),
                                interest), float)
        h = 1e-6 if dtype == jnp.float64 else 1e-2
        fd = np.zeros_like(xy)
        for k in range(2):
            e = np.zeros(2)
            e[k] = h
            fd[:, k] = (reference_field(to_person(xy + e), interest)
                        - reference_field(to_person(xy - e), interest)) / (2 * h)
        np.testing.assert_allclose(g, fd, rtol=rtol, atol=rtol * np.abs(fd).max())


def test_gradients_wrt_parameters_are_finite():
    def loss(params):
        return jnp.sum(pf.potential(params, jnp.asarray(to_world(STARTS)), jnp.asarray(PERSON),
                                    0.7))
    grads = jax.jit(jax.grad(loss))(PARAMS)
    for leaf in jax.tree_util.tree_leaves(grads):
        assert np.all(np.isfinite(np.asarray(leaf)))
    assert np.any(np.asarray(grads.log_parallel_var) != 0)


def test_bad_input_raises_clear_errors():
    xy, person = jnp.zeros(2), jnp.zeros(3)
    with pytest.raises(ValueError, match=r"interest \(PI\) must be in \[0, 1\]"):
        pf.potential(PARAMS, xy, person, 1.5)
    with pytest.raises(ValueError, match="person_pose must have shape"):
        pf.potential(PARAMS, xy, jnp.zeros(2), 0.5)
    with pytest.raises(ValueError, match="robot_xy must have shape"):
        pf.potential(PARAMS, jnp.zeros((4, 3)), person, 0.5)
    with pytest.raises(ValueError, match="robot_xy contains NaN"):
        pf.potential(PARAMS, jnp.array([np.nan, 0.0]), person, 0.5)
    with pytest.raises(ValueError, match="person_pose contains NaN"):
        pf.gradient(PARAMS, xy, jnp.array([0.0, np.nan, 0.0]), 0.5)
    with pytest.raises(ValueError, match="interest must have shape"):
        pf.potential(PARAMS, xy, person, jnp.array([0.5, 0.5]))
    with pytest.raises(TypeError, match="potential_field.Params"):
        pf.potential({"w": 1.0}, xy, person, 0.5)
    with pytest.raises(ValueError, match="rear_var must be > 0"):
        pf.Params.create(rear_var=(2.0, -1.0))
    with pytest.raises(ValueError, match="parallel_var must have shape"):
        pf.Params.create(parallel_var=(1.0, 1.0))
    with pytest.raises(ValueError, match="step_size must be > 0"):
        pf.gradient_step(PARAMS, xy, person, 0.5, 0.0)
    with pytest.raises(ValueError, match="v_max must be > 0"):
        pf.approach_velocity(PARAMS, jnp.zeros(3), person, 0.5, v_max=0.0)
    with pytest.raises(ValueError, match="robot_pose must have shape"):
        pf.approach_velocity(PARAMS, xy, person, 0.5)
    with pytest.raises(ValueError, match="target must have shape"):
        pf.approach_velocity(PARAMS, jnp.zeros(3), person, 0.5, target=jnp.zeros(3))
    with pytest.raises(ValueError, match="robot_xy must have shape"):
        pf.settle_point(PARAMS, jnp.zeros(3), person, 0.5)
    with pytest.raises(ValueError, match="robot_xy"):
        pf.settle_point(PARAMS, jnp.array([np.nan, 0.0]), person, 0.5)
    with pytest.raises(ValueError, match="interest"):
        pf.settle_point(PARAMS, jnp.zeros(2), person, 1.5)
