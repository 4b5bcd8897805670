"""Seed 003 person status and heading: the 0.1 m/s walking threshold, sitting and hand-over
areas (oriented boxes checked against an independent half-plane test), the heading kept while
still, masks, dtypes, jit / vmap, gradients and errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.control import costmap
from jaxtrack.tracking import status as st
from jaxtrack.tracking import tracker

classify = jax.jit(st.classify)
inside = jax.jit(st.inside)
from_tracks = jax.jit(st.from_tracks, static_argnames="confirmed_only")

COUCH = st.Areas.create(center=[[2.0, 1.0]], half_size=[[1.0, 0.4]], angle=[0.5])
DOOR = st.Areas.create(center=[[-2.0, 0.0], [9.0, 9.0]], half_size=[[0.5, 0.5], [1.0, 1.0]],
                       mask=[True, False])


def reference_inside(centers, half_sizes, angles, mask, xy):
    """Point in any convex quadrilateral: on the inner side of all four edges (corners first)."""
    out = np.zeros(len(xy), bool)
    for c, h, a, m in zip(centers, half_sizes, angles, mask):
        if not m:
            continue
        rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        corners = c + np.array([[-h[0], -h[1]], [h[0], -h[1]], [h[0], h[1]],
                                [-h[0], h[1]]]) @ rot.T
        ok = np.ones(len(xy), bool)
        for k in range(4):
            p, q = corners[k], corners[(k + 1) % 4]
            cross = (q[0] - p[0]) * (xy[:, 1] - p[1]) - (q[1] - p[1]) * (xy[:, 0] - p[0])
            ok &= cross >= -1e-12
        out |= ok
    return out


def test_status_codes_are_shared_with_the_costmap_and_match_the_imm_modes():
    assert (costmap.WALKING, costmap.STANDING, costmap.SEATED, costmap.HANDOVER) == (
        st.WALKING, st.STANDING, st.SEATED, st.HANDOVER)
    assert len({st.WALKING, st.STANDING, st.SEATED, st.HANDOVER}) == st.NUM_STATUSES == 4
    assert (st.WALKING, st.STANDING) == (tracker.WALKING, tracker.STANDING)
    assert st.WALKING_SPEED == 0.1


def test_walking_above_the_seed_threshold_with_heading_of_the_velocity():
    speeds = np.array([0.0, 0.05, 0.09, 0.11, 0.5, 1.5])
    angles = np.array([0.3, -2.0, 1.0, 2.5, -0.7, 3.0])
    vel = speeds[:, None] * np.stack([np.cos(angles), np.sin(angles)], -1)
    prev = np.full(6, 0.25)
    s = classify(jnp.zeros((6, 2)), jnp.asarray(vel), jnp.asarray(prev))
    walking = speeds > 0.1
    np.testing.assert_array_equal(np.asarray(s.status),
                                  np.where(walking, st.WALKING, st.STANDING))
    # walking: the direction of the velocity; still: the previous heading, whatever the noise
    np.testing.assert_allclose(np.asarray(s.heading), np.where(walking, angles, prev),
                               atol=1e-12)
    np.testing.assert_allclose(np.asarray(s.speed), speeds, atol=1e-12)
    assert np.all(np.asarray(s.mask))
    # the threshold is a parameter
    s2 = classify(jnp.zeros((6, 2)), jnp.asarray(vel), jnp.asarray(prev), walking_speed=0.6)
    np.testing.assert_array_equal(np.asarray(s2.status) == st.WALKING, speeds > 0.6)


def test_inside_oriented_boxes_matches_an_independent_half_plane_test():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-4, 5, (2000, 2))
    areas = st.Areas.create(center=[[2.0, 1.0], [-2.0, 0.0], [0.0, 3.0]],
                            half_size=[[1.0, 0.4], [0.5, 0.5], [2.0, 0.2]],
                            angle=[0.5, 0.0, -1.2], mask=[True, True, False])
    got = np.asarray(inside(areas, jnp.asarray(xy)))
    want = reference_inside(np.asarray(areas.center), np.asarray(areas.half_size),
                            np.asarray(areas.angle), np.asarray(areas.mask), xy)
    np.testing.assert_array_equal(got, want)
    assert 50 < got.sum() < 400                          # the test sees both sides
    # batch shape [..., 2] -> [...]; no areas -> nothing inside
    assert inside(areas, jnp.zeros((3, 4, 2))).shape == (3, 4)
    none = st.Areas.create(np.zeros((0, 2)), np.zeros((0, 2)))
    assert not np.any(np.asarray(inside(none, jnp.asarray(xy))))


def test_still_people_in_areas_are_seated_or_hand_over_walking_people_are_not():
    xy = np.array([[2.0, 1.0],     # on the couch, still: seated
                   [2.0, 1.0],     # on the couch, walking through: walking
                   [-2.2, 0.1],    # in the postman area, still: hand-over
                   [-2.2, 0.1],    # in the postman area, walking: walking
                   [9.0, 9.0],     # in a masked area: standing
                   [0.0, 0.0]])    # nowhere: standing
    vel = np.array([[0.0, 0.05], [0.5, 0.0], [0.0, 0.0], [0.0, -0.3], [0.0, 0.0], [0.01, 0.0]])
    s = classify(jnp.asarray(xy), jnp.asarray(vel), jnp.zeros(6), sitting=COUCH, handover=DOOR)
    np.testing.assert_array_equal(np.asarray(s.status),
                                  [st.SEATED, st.WALKING, st.HANDOVER, st.WALKING,
                                   st.STANDING, st.STANDING])
    # without areas, every still person stands
    s = classify(jnp.asarray(xy), jnp.asarray(vel), jnp.zeros(6))
    np.testing.assert_array_equal(np.asarray(s.status) == st.WALKING,
                                  [False, True, False, True, False, False])


def test_hand_over_wins_where_a_hand_over_area_overlaps_a_sitting_area():
    s = classify(jnp.array([[2.0, 1.0]]), jnp.zeros((1, 2)), jnp.zeros(1), sitting=COUCH,
                 handover=st.Areas.create([[2.0, 1.0]], [[0.3, 0.3]]))
    assert int(s.status[0]) == st.HANDOVER


def test_masked_and_non_finite_tracks_are_standing_masked_and_poison_nothing():
    xy = jnp.array([[0.0, 0.0], [np.nan, 1.0], [1.0, 1.0], [2.0, 1.0]])
    vel = jnp.array([[1.0, 0.0], [1.0, 0.0], [np.inf, 0.0], [0.0, 1.0]])
    mask = jnp.array([True, True, True, False])
    s = classify(xy, vel, jnp.zeros(4), mask, sitting=COUCH)
    np.testing.assert_array_equal(np.asarray(s.mask), [True, False, False, False])
    np.testing.assert_array_equal(np.asarray(s.status), [st.WALKING] + [st.STANDING] * 3)
    assert np.all(np.isfinite(np.asarray(s.heading))) and np.all(np.isfinite(np.asarray(s.speed)))

    def loss(v):
        return jnp.sum(st.classify(xy, v, jnp.zeros(4), mask).heading)
    assert np.all(np.isfinite(np.asarray(jax.grad(loss)(vel))))


def test_heading_gradient_is_finite_at_zero_velocity_and_correct_while_walking():
    def heading(v):
        return st.classify(jnp.zeros((1, 2)), v[None], jnp.array([0.7])).heading[0]
    g0 = jax.grad(heading)(jnp.zeros(2))
    np.testing.assert_array_equal(np.asarray(g0), [0.0, 0.0])    # still: previous heading
    v = jnp.array([0.3, 0.4])
    np.testing.assert_allclose(np.asarray(jax.grad(heading)(v)),
                               np.array([-0.4, 0.3]) / 0.25, rtol=1e-10)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_dtypes_jit_equals_no_jit_and_vmap_over_episodes(dtype):
    rng = np.random.default_rng(3)
    xy = jnp.asarray(rng.uniform(-3, 4, (5, 8, 2)), dtype)
    vel = jnp.asarray(rng.normal(0, 0.15, (5, 8, 2)), dtype)
    prev = jnp.asarray(rng.uniform(-3, 3, (5, 8)), dtype)
    couch = st.Areas.create([[2.0, 1.0]], [[1.0, 0.4]], [0.5], dtype=dtype)
    batched = jax.vmap(lambda a, b, c: classify(a, b, c, sitting=couch, handover=DOOR))(
        xy, vel, prev)
    assert batched.heading.dtype == dtype and batched.status.dtype == jnp.int32
    for e in range(5):
        eager = st.classify(xy[e], vel[e], prev[e], sitting=couch, handover=DOOR)
        np.testing.assert_array_equal(np.asarray(eager.status), np.asarray(batched.status[e]))
        np.testing.assert_allclose(np.asarray(eager.heading), np.asarray(batched.heading[e]),
                                   rtol=1e-6 if dtype == jnp.float32 else 1e-12)


def test_from_tracks_classifies_live_tracks_of_the_tracker_state():
    tracks = tracker.init(tracker.TrackerConfig(capacity=4), jnp.float64)
    mean = jnp.array([[2.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.8], [5.0, 5.0, 0.0, 0.0],
                      [-2.0, 0.0, 0.0, 0.0]])
    # settled velocity estimates (std 0.05 m/s): significant at 0.8 m/s
    cov = jnp.tile(jnp.diag(jnp.array([0.01, 0.01, 0.0025, 0.0025])), (4, 1, 1))
    tracks = tracks._replace(mean=mean, cov=cov, heading=jnp.array([1.0, 0.0, 0.0, 2.0]),
                             status=jnp.array([tracker.CONFIRMED, tracker.CONFIRMED,
                                               tracker.FREE, tracker.TENTATIVE], jnp.int32))
    s = from_tracks(tracks, sitting=COUCH, handover=DOOR)
    np.testing.assert_array_equal(np.asarray(s.mask), [True, True, False, True])
    np.testing.assert_array_equal(np.asarray(s.status),
                                  [st.SEATED, st.WALKING, st.STANDING, st.HANDOVER])
    np.testing.assert_allclose(np.asarray(s.heading)[[0, 1, 3]], [1.0, np.pi / 2, 2.0])
    s = from_tracks(tracks, confirmed_only=True)
    np.testing.assert_array_equal(np.asarray(s.mask), [True, True, False, False])


def test_bad_input_raises_naming_the_argument():
    z2, z1 = jnp.zeros((3, 2)), jnp.zeros(3)
    with pytest.raises(ValueError, match="velocity must have shape"):
        st.classify(z2, jnp.zeros((2, 2)), z1)
    with pytest.raises(ValueError, match="position must have shape"):
        st.classify(jnp.zeros((3, 3)), z2, z1)
    with pytest.raises(ValueError, match="previous_heading must have shape"):
        st.classify(z2, z2, jnp.zeros(4))
    with pytest.raises(ValueError, match="mask must have shape"):
        st.classify(z2, z2, z1, jnp.ones(2, bool))
    with pytest.raises(ValueError, match="walking_speed must be > 0"):
        st.classify(z2, z2, z1, walking_speed=0.0)
    with pytest.raises(TypeError, match="sitting must be a status.Areas"):
        st.classify(z2, z2, z1, sitting=np.zeros((1, 4)))
    with pytest.raises(ValueError, match="half_size must be > 0"):
        st.Areas.create([[0.0, 0.0]], [[1.0, -0.1]])
    with pytest.raises(ValueError, match="center contains NaN"):
        st.Areas.create([[np.nan, 0.0]], [[1.0, 1.0]])
    with pytest.raises(ValueError, match="half_size must have shape"):
        st.Areas.create([[0.0, 0.0]], [[1.0, 1.0], [1.0, 1.0]])
    with pytest.raises(TypeError, match="tracks must be a tracker.Tracks"):
        st.from_tracks(z2)


def test_an_uncertain_velocity_is_not_walking_until_it_is_significant():
    """Speed 0.3 m/s with velocity std 1 m/s (a new track) is not walking; with std 0.05 m/s
    it is; the threshold is the chi-square quantile: d2 = 0.09 / var against -2 log(1 - a)."""
    v = jnp.array([[0.3, 0.0], [0.3, 0.0], [0.0, 0.3]])
    cov = jnp.stack([jnp.eye(2), 0.05 ** 2 * jnp.eye(2), 0.05 ** 2 * jnp.eye(2)])
    s = classify(jnp.zeros((3, 2)), v, jnp.array([0.5, 0.5, 0.5]), velocity_cov=cov)
    np.testing.assert_array_equal(np.asarray(s.status), [st.STANDING, st.WALKING, st.WALKING])
    np.testing.assert_allclose(np.asarray(s.heading), [0.5, 0.0, np.pi / 2], atol=1e-6)
    # at the boundary: var such that d2 = chi2 quantile (9.21 for 0.99) -> just above / below
    q = -2 * np.log(1 - 0.99)
    for scale, walks in ((0.99, True), (1.01, False)):
        var = 0.09 / q * scale
        s = classify(jnp.zeros((1, 2)), v[:1], jnp.zeros(1),
                     velocity_cov=var * jnp.eye(2)[None], significance=0.99)
        assert (int(s.status[0]) == st.WALKING) == walks
    # without covariances the seed's plain threshold
    s = classify(jnp.zeros((1, 2)), v[:1], jnp.zeros(1))
    assert int(s.status[0]) == st.WALKING
    # from_tracks uses the tracks' own covariances: a fresh track's is wide
    tracks = tracker.init(tracker.TrackerConfig(capacity=2), jnp.float64)
    tracks = tracks._replace(mean=jnp.array([[0.0, 0.0, 0.3, 0.0], [1.0, 0.0, 0.3, 0.0]]),
                             cov=jnp.stack([jnp.eye(4), jnp.diag(jnp.array([1.0, 1, 1e-3, 1e-3]))]),
                             status=jnp.array([tracker.CONFIRMED] * 2, jnp.int32))
    np.testing.assert_array_equal(np.asarray(from_tracks(tracks).status),
                                  [st.STANDING, st.WALKING])
    with pytest.raises(ValueError, match="significance"):     # checked where concrete
        st.classify(jnp.zeros((1, 2)), v[:1], jnp.zeros(1), significance=1.0)
    with pytest.raises(ValueError, match="velocity_cov"):
        st.classify(jnp.zeros((1, 2)), v[:1], jnp.zeros(1), velocity_cov=jnp.eye(2))
