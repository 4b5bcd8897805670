"""Seed 002 person interest (case base) and where the approach field ends.

The final approach poses are compared with the seed's figures (II-C and IV-B): about 2 m in
front of the person for PI = 0; about 45 deg, just outside the personal zone (1.2 m) for
PI = 0.5; from the front at the border of the intimate zone, around 0.45 m, for PI = 1.
Measured with the field's defaults, from 36 starts within 3 m: 1.959 m at 0.0 deg; 1.258 m at
47.2 deg; 0.516 m at 2.35 deg (twin minima either side of the heading line).

The PI estimate is checked against the seed's premise (an interested person walks straight at
the robot, an uninterested one avoids its path) and its learned base (Fig. 7: right in front
facing the robot, interested; pose pointing away, not interested).
"""

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.control import person_interest as pi
from jaxtrack.control import potential_field as pf

BASE = pi.CaseBase.create()
FIELD = pf.Params.create()
PERSON = np.array([1.0, -0.5, 0.6])  # off the origin and turned

interest = jax.jit(pi.interest, static_argnames="nearest")
estimate = jax.jit(pi.estimate, static_argnames="nearest")
interest_filter = jax.jit(pi.interest_filter, static_argnames="nearest")
add_case = jax.jit(pi.add_case)
approach = jax.jit(partial(pi.approach_pose, steps=3000))
retrieve = jax.jit(pi.retrieve, static_argnames="nearest")
features = jax.jit(pi.encounter_features)
interest_map = jax.jit(jax.vmap(pi.interest, in_axes=(None, 0, 0, 0)))
interest_step = jax.jit(pi.interest_step)


def to_world(q, person=PERSON):
    c, s = np.cos(person[2]), np.sin(person[2])
    return person[:2] + np.asarray(q) @ np.array([[c, s], [-s, c]])


def to_person(xy, person=PERSON):
    c, s = np.cos(person[2]), np.sin(person[2])
    return (np.asarray(xy) - person[:2]) @ np.array([[c, -s], [s, c]])


# 36 starts on rings of 0.8, 1.5 and 3 m around the person, none on the heading line
ANGLES = np.radians(15.0 + 30.0 * np.arange(12))
STARTS = np.array([[r * np.cos(a), r * np.sin(a)] for r in (0.8, 1.5, 3.0) for a in ANGLES])


def final_distance_and_bearing(interest_value, starts=STARTS, person=PERSON, dtype=np.float64):
    """Final poses [n, 3] and their distance and bearing from the person's heading (deg).

    Every call descends a [36, 2] batch (short ``starts`` are padded), so that one compilation
    per dtype serves every test."""
    n = len(starts)
    padded = np.concatenate([starts, np.tile(STARTS[:1], (len(STARTS) - n, 1))])
    poses = np.asarray(approach(FIELD, jnp.asarray(person, dtype), jnp.asarray(interest_value,
                                dtype), start_xy=jnp.asarray(to_world(padded, person), dtype)))
    poses = poses[:n]
    q = to_person(poses[:, :2], person)
    return np.hypot(q[:, 0], q[:, 1]), np.degrees(np.arctan2(q[:, 1], q[:, 0])), poses


# ---------------------------------------------------------------------------------------------
# Approach pose


def test_pi_0_ends_about_2_m_in_front_from_every_start():
    d, b, _ = final_distance_and_bearing(0.0)
    np.testing.assert_allclose(d, 1.959, atol=2e-3)  # the seed: "app. 2 meters in front"
    np.testing.assert_allclose(b, 0.0, atol=0.1)


def test_pi_half_ends_about_45_deg_just_outside_the_personal_zone():
    d, b, _ = final_distance_and_bearing(0.5)
    assert np.all(d > pf.PERSONAL) and np.all(d < pf.PERSONAL + 0.1), d  # 1.258 m
    np.testing.assert_allclose(np.abs(b), 45.0, atol=2.5)                 # 47.2 deg
    # each start settles on its own side of the person's heading line
    np.testing.assert_array_equal(np.sign(b), np.sign(to_person(to_world(STARTS))[:, 1]))


def test_pi_1_ends_in_front_at_the_border_of_the_intimate_zone():
    d, b, _ = final_distance_and_bearing(1.0)
    # the seed: "until the border of the intimate zone is reached at around 45cm"; the field
    # stops 6.6 cm outside it
    assert np.all(d > pf.INTIMATE) and np.all(d < pf.INTIMATE + 0.1), d   # 0.516 m
    assert np.all(np.abs(b) < 3.0), b                                     # 2.35 deg


def test_approach_pose_faces_the_person_and_batches_like_single_starts():
    _, _, poses = final_distance_and_bearing(1.0)
    to_p = PERSON[:2] - poses[:, :2]
    np.testing.assert_allclose(poses[:, 2], np.arctan2(to_p[:, 1], to_p[:, 0]), atol=1e-12)
    one = np.asarray(pi.approach_pose(FIELD, jnp.asarray(PERSON), 1.0,
                                      start_xy=jnp.asarray(to_world(STARTS[4])), steps=3000))
    np.testing.assert_allclose(one, poses[4], atol=1e-9)


def test_start_on_the_heading_line_stays_on_it():
    # the field is symmetric about the heading line: for PI = 0.5 the line holds a saddle
    person = np.zeros(3)
    d, b, _ = final_distance_and_bearing(0.5, np.array([[1.5, 0.0], [3.0, 0.0]]), person)
    np.testing.assert_allclose(b, 0.0, atol=1e-9)
    np.testing.assert_allclose(d, 2.156, atol=2e-3)


def test_approach_pose_float32_agrees_with_float64():
    d32, b32, p32 = final_distance_and_bearing(0.5, STARTS[:12], dtype=np.float32)
    d64, b64, _ = final_distance_and_bearing(0.5, STARTS[:12])
    assert p32.dtype == np.float32
    np.testing.assert_allclose(d32, d64, atol=1e-3)
    np.testing.assert_allclose(b32, b64, atol=0.1)


# ---------------------------------------------------------------------------------------------
# Encounter features


def test_features_of_a_person_walking_at_the_robot():
    z = pi.encounter_features(jnp.array([2.0, 0.0]), jnp.pi, jnp.array([-1.0, 0.0]))
    np.testing.assert_allclose(z, [2.0, 0.0, 1.0, 1.0], atol=1e-12)
    z = pi.encounter_features(jnp.array([0.0, -3.0]), 0.0, jnp.array([0.0, -0.5]))
    np.testing.assert_allclose(z, [3.0, np.pi / 2, 0.5, -0.5], atol=1e-12)


def test_features_do_not_change_when_the_encounter_is_rotated_about_the_robot():
    rng = np.random.default_rng(0)
    p, h, v = rng.normal(size=(20, 2)) * 2, rng.uniform(-np.pi, np.pi, 20), rng.normal(size=(20, 2))
    z = np.asarray(features(jnp.asarray(p), jnp.asarray(h), jnp.asarray(v)))
    a = 1.1
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    zr = np.asarray(features(jnp.asarray(p @ rot.T), jnp.asarray(h + a),
                                          jnp.asarray(v @ rot.T)))
    np.testing.assert_allclose(zr, z, atol=1e-9)


def test_features_are_finite_with_a_finite_gradient_at_the_robot():
    f = jax.jit(jax.value_and_grad(
        lambda p: jnp.sum(pi.encounter_features(p, 0.3, jnp.array([0.5, 0.0])))))
    value, grad = f(jnp.zeros(2))
    assert np.isfinite(value) and np.all(np.isfinite(grad))


# ---------------------------------------------------------------------------------------------
# PI estimate

DISTANCES = np.array([0.8, 1.5, 2.5, 4.0])
LATERAL = np.array([0.0, 0.3, -0.4, 0.2])


def encounters(kind):
    """Robot-frame (position, heading, velocity) of people ahead of the robot, for each distance."""
    p = np.column_stack([DISTANCES, LATERAL])
    to_robot = np.arctan2(-p[:, 1], -p[:, 0])
    heading = {"toward": to_robot, "standing facing": to_robot, "away": to_robot + np.pi,
               "standing sideways": to_robot + np.pi / 2, "standing back turned": to_robot + np.pi,
               "passing": to_robot + np.pi / 2}[kind]
    speed = 0.0 if kind.startswith("standing") else 1.0
    v = speed * np.column_stack([np.cos(heading), np.sin(heading)])
    return jnp.asarray(p), jnp.asarray(heading), jnp.asarray(v)


@pytest.mark.parametrize("nearest", [False, True])
def test_walking_at_the_robot_is_interested_walking_away_is_not_sideways_is_undecided(nearest):
    got = {k: np.asarray(interest(BASE, *encounters(k), nearest=nearest))
           for k in ("toward", "away", "standing sideways", "passing")}
    assert np.all(got["toward"] > 0.9), got["toward"]
    assert np.all(got["away"] < 0.05), got["away"]
    assert np.all((got["standing sideways"] > 0.4) & (got["standing sideways"] < 0.6))
    assert np.all(got["passing"] < 0.3), got["passing"]  # "carefully avoid the path"
    assert np.all(got["toward"] > got["standing sideways"])
    assert np.all(got["standing sideways"] > got["away"])


def test_in_front_facing_the_robot_is_interested_back_turned_is_not():
    # the seed's learned base, Fig. 7
    front = np.asarray(interest(BASE, *encounters("standing facing")))
    back = np.asarray(interest(BASE, *encounters("standing back turned")))
    assert np.all(front > 0.75), front
    assert front[0] > 0.95  # right in front
    assert np.all(back < 0.15), back


def test_estimate_stays_in_the_unit_interval_for_any_features_and_cases():
    rng = np.random.default_rng(1)
    z = rng.uniform([0, 0, 0, -3], [10, np.pi, 3, 3], (500, 4))
    z[:20] = [[100.0, 0.0, 50.0, -50.0]] * 20  # far outside every case
    cases = np.column_stack([rng.uniform(0, 4, 30), rng.uniform(0, 180, 30),
                             rng.uniform(0, 2, 30), rng.uniform(-2, 2, 30),
                             rng.choice([0.0, 1.0], 30)])
    for base in (BASE, pi.CaseBase.create(cases, bandwidth=0.05)):
        for nearest in (False, True):
            p = np.asarray(estimate(base, jnp.asarray(z), nearest=nearest))
            assert np.all(np.isfinite(p)) and np.all((p >= 0) & (p <= 1))


def test_retrieval_weights_sum_to_one_and_a_narrow_kernel_is_the_nearest_case():
    rng = np.random.default_rng(2)
    z = jnp.asarray(rng.uniform([0, 0, 0, -1], [4, np.pi, 1.5, 1], (50, 4)))
    w = np.asarray(retrieve(BASE, z))
    np.testing.assert_allclose(w.sum(-1), 1.0, atol=1e-12)
    one_hot = np.asarray(retrieve(BASE, z, nearest=True))
    np.testing.assert_array_equal(one_hot.sum(-1), 1.0)
    narrow = BASE._replace(log_bandwidth=jnp.log(0.01))
    np.testing.assert_allclose(estimate(narrow, z), estimate(BASE, z, nearest=True), atol=1e-6)


def test_an_exact_case_returns_its_own_value_with_the_nearest_lookup():
    rows = np.asarray(pi.DEFAULT_CASES)
    z = rows[:, :4].copy()
    z[:, 1] = np.radians(z[:, 1])
    np.testing.assert_allclose(estimate(BASE, jnp.asarray(z), nearest=True), rows[:, 4],
                               atol=1e-12)


def test_jit_equals_eager_and_vmap_equals_the_batch():
    p, h, v = encounters("passing")
    eager = np.asarray(pi.interest(BASE, p, h, v))
    np.testing.assert_allclose(interest(BASE, p, h, v), eager, atol=1e-12)
    np.testing.assert_allclose(interest_map(BASE, p, h, v), eager, atol=1e-12)
    # a batch of case bases (e.g. one per Monte-Carlo episode) maps too
    bases = jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), BASE)
    per_base = jax.jit(jax.vmap(pi.interest, in_axes=(0, None, None, None)))
    np.testing.assert_allclose(per_base(bases, p[0], h[0], v[0]), [eager[0]] * 2, atol=1e-12)


@pytest.mark.parametrize("dtype,tol", [(jnp.float32, 1e-5), (jnp.float64, 1e-12)])
def test_dtypes_are_kept_and_float32_agrees_with_float64(dtype, tol):
    p, h, v = encounters("toward")
    ref = np.asarray(pi.interest(BASE, p, h, v))
    got = interest(BASE, p.astype(dtype), h.astype(dtype), v.astype(dtype))
    assert got.dtype == dtype
    np.testing.assert_allclose(got, ref, atol=tol)
    base32 = pi.CaseBase.create(dtype=jnp.float32)
    assert base32.features.dtype == jnp.float32
    np.testing.assert_allclose(interest(base32, p.astype(dtype), h.astype(dtype),
                                        v.astype(dtype)), ref, atol=1e-5)


def test_gradient_of_pi_is_finite_and_points_towards_facing_the_robot():
    z = jnp.array([1.5, 1.0, 0.5, 0.2])
    g = np.asarray(jax.jit(jax.grad(lambda z: pi.estimate(BASE, z)))(z))
    assert np.all(np.isfinite(g))
    assert g[1] < 0  # turning away from the robot lowers the interest


# ---------------------------------------------------------------------------------------------
# Learning and smoothing


def test_an_empty_base_gives_the_default_and_learns_added_cases():
    empty = pi.CaseBase.create(np.zeros((0, 5)), capacity=3)
    z = jnp.array([1.5, 0.0, 0.7, 0.7])
    for nearest in (False, True):
        assert float(estimate(empty, z, nearest=nearest)) == 0.5
    base = add_case(empty, z, 1.0)
    base = add_case(base, jnp.array([1.5, np.pi, 1.0, -1.0]), 0.0)
    assert np.asarray(base.mask).tolist() == [True, True, False]
    assert float(estimate(base, z)) > 0.99
    assert float(estimate(base, jnp.array([1.4, 3.0, 1.0, -0.9]))) < 0.01
    # full: a new outcome of the same situation replaces the nearest case
    base = add_case(base, jnp.array([3.0, 1.5, 0.0, 0.0]), 0.5)
    base = add_case(base, jnp.array([1.6, 0.1, 0.7, 0.7]), 0.0)
    assert np.asarray(base.mask).all()
    np.testing.assert_allclose(base.interest, [0.0, 0.0, 0.5])
    assert float(estimate(base, z)) < 0.01


def test_interest_filter_is_a_first_order_lag_that_holds_on_missing_frames():
    p, h, v = encounters("toward")
    z = np.repeat(np.asarray(pi.encounter_features(p[1], h[1], v[1]))[None], 30, 0)
    valid = np.ones(30, bool)
    valid[5:10] = False
    z[5:10] = np.nan  # missing frames must not poison the rest
    pis = np.asarray(interest_filter(BASE, jnp.asarray(z), jnp.asarray(valid)))
    target = float(estimate(BASE, jnp.asarray(z[0])))
    expected, prev = [], 0.5
    for k in range(30):
        prev = prev + 0.2 * (target - prev) if valid[k] else prev
        expected.append(prev)
    np.testing.assert_allclose(pis, expected, atol=1e-12)
    # rate 1: no smoothing, the per-frame estimate
    zz = jnp.asarray(features(*encounters("away")))
    np.testing.assert_allclose(interest_filter(BASE, zz, rate=1.0), estimate(BASE, zz),
                               atol=1e-12)


def test_interest_step_matches_the_filter_and_gradients_pass_masked_frames():
    z = jnp.asarray(features(*encounters("passing")))
    pis = np.asarray(interest_filter(BASE, z))
    prev = 0.5
    for k in range(z.shape[0]):
        prev = interest_step(BASE, jnp.asarray(prev), z[k])
        np.testing.assert_allclose(prev, pis[k], atol=1e-12)
    zn = z.at[1].set(jnp.nan)
    valid = jnp.array([True, False, True, True])
    g = jax.jit(jax.grad(lambda f, v: interest_filter(BASE._replace(features=f, interest=v),
                                                      zn, valid)[-1], argnums=(0, 1)))(
        BASE.features, BASE.interest)
    assert all(np.all(np.isfinite(x)) for x in g)


# ---------------------------------------------------------------------------------------------
# Errors at the boundary


@pytest.mark.parametrize("call,name", [
    (lambda: pi.interest(BASE, jnp.zeros(3), 0.0, jnp.zeros(2)), "person_xy"),
    (lambda: pi.interest(BASE, jnp.ones(2), jnp.nan, jnp.zeros(2)), "heading"),
    (lambda: pi.interest(BASE, jnp.ones(2), 0.0, jnp.zeros(3)), "velocity"),
    (lambda: pi.interest(BASE, jnp.ones((3, 2)), jnp.zeros(4), jnp.zeros((3, 2))), "heading"),
    (lambda: pi.interest({"cases": 1}, jnp.ones(2), 0.0, jnp.zeros(2)), "case_base"),
    (lambda: pi.estimate(BASE, jnp.zeros(3)), "features"),
    (lambda: pi.estimate(BASE, jnp.array([1.0, 0.0, jnp.inf, 0.0])), "features"),
    (lambda: pi.CaseBase.create([(1.0, 0.0, 0.5, 0.5, 1.5)]), "PI"),
    (lambda: pi.CaseBase.create([(1.0, 200.0, 0.5, 0.5, 1.0)]), "facing angle"),
    (lambda: pi.CaseBase.create([(1.0, 0.0, 0.5, 0.5)]), "cases"),
    (lambda: pi.CaseBase.create(scales=(1.0, 0.0, 1.0, 1.0)), "scales"),
    (lambda: pi.CaseBase.create(bandwidth=-1.0), "bandwidth"),
    (lambda: pi.CaseBase.create(capacity=3), "capacity"),
    (lambda: pi.add_case(BASE, jnp.zeros(4), 1.2), "interest_value"),
    (lambda: pi.interest_filter(BASE, jnp.zeros((5, 4)), jnp.ones(4, bool)), "valid"),
    (lambda: pi.interest_filter(BASE, jnp.zeros((5, 4)), rate=0.0), "rate"),
    (lambda: pi.interest_filter(BASE, jnp.zeros((5, 4)), initial=2.0), "initial"),
    (lambda: pi.approach_pose(FIELD, jnp.zeros(3), 0.5, start_xy=jnp.zeros(3)), "start_xy"),
    (lambda: pi.approach_pose(FIELD, jnp.zeros(2), 0.5, start_xy=jnp.zeros(2)), "person_pose"),
    (lambda: pi.approach_pose(FIELD, jnp.zeros(3), 1.5, start_xy=jnp.ones(2)), "interest_value"),
    (lambda: pi.approach_pose(FIELD, jnp.zeros(3), 0.5, start_xy=jnp.ones(2), steps=0), "steps"),
    (lambda: pi.approach_pose(FIELD, jnp.zeros(3), 0.5, start_xy=jnp.ones(2), step_size=0.0),
     "step_size"),
    (lambda: pi.approach_pose(BASE, jnp.zeros(3), 0.5, start_xy=jnp.ones(2)), "params"),
])
def test_bad_input_raises_naming_the_argument(call, name):
    with pytest.raises((ValueError, TypeError), match=name):
        call()
