"""Laser leg detector on synthetic scans from the following scene's caster, and against numpy
references (a plain loop for the segmentation, least squares for the circle fit)."""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.perception import legs
from sims.following import lidar

CFG = lidar.LaserConfig()
ANGLES = lidar.beam_angles(CFG)
S, P = 32, 8

_scan = jax.jit(lidar.scan, static_argnums=4)
_cast = jax.jit(lidar.cast)
_features = jax.jit(legs.features)
_pair = jax.jit(legs.pair_legs, static_argnames="max_people")
_detect = jax.jit(functools.partial(legs.detect, max_segments=S, max_people=P))
_detect_people = jax.jit(functools.partial(legs.detect_people, max_segments=S, max_people=P))


def _person(mid, across, sep=0.3, radius=0.06):
    """Leg centres of a person at ``mid`` whose legs are ``sep`` apart along ``across``."""
    u = np.array([math.cos(across), math.sin(across)])
    return [mid + 0.5 * sep * u, mid - 0.5 * sep * u], [radius, radius]


def _no_walls(dtype=jnp.float64):
    return lidar.Walls(jnp.zeros((0, 2, 2), dtype), jnp.zeros(0, bool))


def _circles(centres, radii, dtype=jnp.float64):
    return lidar.Circles(jnp.asarray(np.array(centres), dtype), jnp.asarray(radii, dtype),
                         jnp.ones(len(radii), bool))


def _side_by_side(rng, n):
    """Random people seen from the sensor with their legs side by side (across the beam)."""
    out = []
    for _ in range(n):
        rng_, bearing = rng.uniform(1.0, 4.0), rng.uniform(-1.5, 1.5)
        mid = rng_ * np.array([math.cos(bearing), math.sin(bearing)])
        across = bearing + math.pi / 2 + rng.uniform(-0.4, 0.4)
        out.append((mid, _person(mid, across, rng.uniform(0.2, 0.4), rng.uniform(0.05, 0.07))))
    return out


# --- segmentation and features vs numpy -------------------------------------------------------


def _segment_loop(ranges, angles, max_range, min_range, jump, cap):
    xy = np.stack([ranges * np.cos(angles), ranges * np.sin(angles)], -1)
    valid = np.isfinite(ranges) & (ranges > min_range) & (ranges < max_range)
    labels = np.full(len(ranges), -1)
    k = -1
    for i in range(len(ranges)):
        if not valid[i]:
            continue
        if i == 0 or not valid[i - 1] or np.linalg.norm(xy[i] - xy[i - 1]) > jump:
            k += 1
        if k < cap:
            labels[i] = k
    return labels, k + 1


_segment32 = jax.jit(functools.partial(legs.segment, max_segments=S))
_segment6 = jax.jit(functools.partial(legs.segment, jump=0.1, min_range=0.02, max_segments=6))


def test_segmentation_matches_a_plain_loop_including_overflow():
    rng = np.random.default_rng(1)
    B = 90
    angles = np.linspace(-2.0, 2.0, B)
    seg = _segment6
    overflowed = 0
    for _ in range(12):
        # Piecewise-smooth ranges with jumps, invalid beams (max range, inf, too close).
        pieces = np.repeat(rng.uniform(0.5, 6.0, 15), rng.multinomial(B, np.ones(15) / 15))
        ranges = pieces + 0.003 * rng.standard_normal(B)
        ranges[rng.uniform(size=B) < 0.05] = np.inf
        ranges[rng.uniform(size=B) < 0.03] = 0.01
        out = seg(jnp.asarray(ranges), jnp.asarray(angles), 5.6)
        labels, found = _segment_loop(ranges, angles, 5.6, 0.02, 0.1, 6)
        np.testing.assert_array_equal(out.labels, labels)
        assert int(out.found) == found and int(out.dropped) == max(found - 6, 0)
        overflowed += found > 6
        for k in range(6):
            beams = np.nonzero(labels == k)[0]
            assert bool(out.mask[k]) == (beams.size > 0)
            if beams.size:
                assert (out.first[k], out.last[k], out.num_points[k]) == (
                    beams[0], beams[-1], beams.size)
    assert overflowed >= 3


def test_features_match_least_squares_circle_and_line_fits():
    rng = np.random.default_rng(2)
    centres, radii = [[2.0, 0.5], [3.0, -1.0], [1.2, 1.6]], [0.06, 0.1, 0.04]
    walls = lidar.Walls(jnp.array([[[4.5, -4.0], [4.5, 4.0]]]), jnp.array([True]))
    ranges = _cast(jnp.zeros(3), ANGLES, _circles(centres, radii), walls, CFG.max_range)
    ranges = jnp.where(ranges < CFG.max_range,
                       ranges + 0.002 * jnp.asarray(rng.standard_normal(ranges.shape)), ranges)
    segs = _segment32(ranges, ANGLES, CFG.max_range)
    f = _features(ranges, ANGLES, segs, CFG.max_range)
    xy = np.stack([ranges * np.cos(ANGLES), ranges * np.sin(ANGLES)], -1)
    checked = 0
    for k in np.nonzero(np.asarray(segs.mask))[0]:
        pts = xy[np.asarray(segs.labels) == k]
        assert f.num_points[k] == len(pts)
        np.testing.assert_allclose(f.mean[k], pts.mean(0), atol=1e-12)
        np.testing.assert_allclose(f.width[k], np.linalg.norm(pts[-1] - pts[0]), atol=1e-12)
        c = pts - pts.mean(0)
        lam = max(np.linalg.eigvalsh(c.T @ c)[0], 0.0)
        np.testing.assert_allclose(f.linearity[k], math.sqrt(lam / len(pts)), atol=1e-9)
        if len(pts) >= 3 and f.radius[k] < 1.0:     # circles, not ill-conditioned wall fits
            o = pts.mean(0)
            A = np.c_[pts - o, np.ones(len(pts))]
            sol = np.linalg.lstsq(A, -((pts - o) ** 2).sum(1), rcond=None)[0]
            centre = -0.5 * sol[:2]
            rad = math.sqrt(centre @ centre - sol[2])
            centre = centre + o
            np.testing.assert_allclose(f.radius[k], rad, rtol=1e-6)
            np.testing.assert_allclose(f.circle_center[k], centre, atol=1e-6 * max(rad, 1))
            res = np.linalg.norm(pts - centre, axis=1) - rad
            np.testing.assert_allclose(f.circularity[k], math.sqrt(np.mean(res ** 2)),
                                       rtol=1e-5, atol=1e-9)
            checked += 1
    assert checked >= 3
    # The circle fits recover the true radii (2 mm noise), the wall pieces are straight.
    for centre, r in zip(centres, radii):
        k = int(np.argmin(np.linalg.norm(np.asarray(f.circle_center) - centre, axis=1)))
        assert abs(float(f.radius[k]) - r) < 0.01
        assert np.linalg.norm(np.asarray(f.position[k]) - centre) < 0.015


# --- detection on synthetic scans -------------------------------------------------------------


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_one_person_one_detection_at_the_leg_midpoint(dtype):
    rng = np.random.default_rng(3)
    errors = []
    for i, (mid, (centres, radii)) in enumerate(_side_by_side(rng, 8)):
        ranges = _scan(jax.random.PRNGKey(i), jnp.zeros(3, dtype), _circles(centres, radii, dtype),
                       _no_walls(dtype), CFG)
        xy, mask = _detect_people(ranges, ANGLES.astype(dtype))
        assert xy.dtype == dtype
        assert int(mask.sum()) == 1
        errors.append(np.linalg.norm(np.asarray(xy[0], np.float64) - mid))
    assert max(errors) < 0.03


def test_wall_and_lone_table_leg_are_not_people_but_close_chair_legs_are():
    person_mid = np.array([2.5, 0.8])
    centres, radii = _person(person_mid, math.pi / 2 + 0.3)
    table_leg, chair = [1.2, -0.3], [[1.6, -1.4], [1.6, -1.8]]
    walls = lidar.Walls(jnp.array([[[4.0, -4.0], [4.0, 4.0]], [[1.0, 2.2], [2.0, 2.2]]]),
                        jnp.array([True, True]))
    circles = _circles(centres + [table_leg] + chair, radii + [0.025, 0.03, 0.03])
    ranges = _scan(jax.random.PRNGKey(5), jnp.zeros(3), circles, walls, CFG)
    det = _detect(ranges, ANGLES)
    f, cand = det.features, np.asarray(det.legs_mask)
    # The table leg looks like a leg (a candidate) but has no partner within 0.5 m.
    k_table = int(np.argmin(np.linalg.norm(np.asarray(f.position) - table_leg, axis=1)))
    assert cand[k_table]
    # No wall piece is a candidate.
    wall_like = np.asarray(f.mask) & (np.asarray(f.width) > 0.5)
    assert wall_like.sum() >= 2 and not np.any(cand & wall_like)
    found = np.asarray(det.people.xy)[np.asarray(det.people.mask)]
    assert len(found) == 2
    d_person = np.linalg.norm(found - person_mid, axis=1)
    d_chair = np.linalg.norm(found - np.mean(chair, 0), axis=1)
    # The person, and (the limit) two chair legs 0.4 m apart paired as a person.
    assert d_person.min() < 0.03 and d_chair.min() < 0.05


def test_two_people_two_detections_and_vmap_matches_single_scans():
    rng = np.random.default_rng(7)
    keys, scans, truth = [], [], []
    for i in range(3):
        people = _side_by_side(rng, 2)
        while np.linalg.norm(people[0][0] - people[1][0]) < 1.2:
            people = _side_by_side(rng, 2)
        centres = people[0][1][0] + people[1][1][0]
        radii = people[0][1][1] + people[1][1][1]
        keys.append(jax.random.PRNGKey(10 + i))
        scans.append(_scan(keys[-1], jnp.zeros(3), _circles(centres, radii), _no_walls(), CFG))
        truth.append(np.array([people[0][0], people[1][0]]))
    batch_xy, batch_mask = jax.vmap(_detect_people, (0, None))(jnp.stack(scans), ANGLES)
    for i in range(3):
        xy, mask = _detect_people(scans[i], ANGLES)
        np.testing.assert_array_equal(batch_mask[i], mask)
        np.testing.assert_allclose(batch_xy[i], xy, atol=1e-12)
        found = np.asarray(xy)[np.asarray(mask)]
        assert len(found) == 2
        err = np.linalg.norm(found[:, None] - truth[i][None], axis=-1).min(0)
        assert np.all(err < 0.03)


def test_single_leg_option_recovers_an_occluded_person():
    # Legs one behind the other along the beam: the far leg is hidden.
    mid = np.array([2.0, 0.0])
    centres, radii = _person(mid, 0.0, sep=0.3)
    ranges = _scan(jax.random.PRNGKey(2), jnp.zeros(3), _circles(centres, radii), _no_walls(), CFG)
    _, mask = _detect_people(ranges, ANGLES)
    assert int(mask.sum()) == 0
    xy, mask = _detect_people(ranges, ANGLES, legs.LegParams(single_legs=1.0))
    assert int(mask.sum()) == 1 and np.linalg.norm(np.asarray(xy[0]) - centres[1]) < 0.03


def test_pairing_is_greedy_closest_first_with_capacity_and_motion_cue():
    xy = jnp.array([[0.0, 0.0], [0.3, 0.0], [0.55, 0.0], [3.0, 0.0], [3.0, 0.45], [9.0, 9.0]])
    mask = jnp.array([True, True, True, True, True, False])
    people = _pair(xy, mask, max_people=4)
    # Closest pair first: (1, 2) at 0.25 m, then (3, 4) at 0.45 m; leg 0 left alone.
    np.testing.assert_array_equal(people.legs[:2], [[1, 2], [3, 4]])
    np.testing.assert_array_equal(people.mask, [True, True, False, False])
    np.testing.assert_allclose(people.xy[0], [0.425, 0.0])
    singles = _pair(xy, mask, legs.LegParams(single_legs=1.0), max_people=4)
    np.testing.assert_array_equal(singles.legs[2], [0, -1])
    assert int(singles.dropped) == 0
    small = _pair(xy, mask, legs.LegParams(single_legs=1.0), max_people=1)
    assert int(small.mask.sum()) == 1 and int(small.dropped) == 2
    # Legs 1 and 2 moved 10 cm in opposite directions: not one person with the motion cue.
    prev = (xy + jnp.array([[0, 0], [0.1, 0], [-0.1, 0], [0, 0], [0, 0], [0, 0]]), mask)
    moved = _pair(xy, mask, max_people=4, prev_legs=prev)
    np.testing.assert_array_equal(moved.legs[:2], [[0, 1], [3, 4]])
    # Same direction: paired as without the cue.
    same = _pair(xy, mask, max_people=4, prev_legs=(xy - 0.1, mask))
    np.testing.assert_array_equal(same.legs, people.legs)


def test_segment_capacity_drops_and_counts():
    centres = [[1.0 + 0.5 * k, -2.0 + 0.4 * k] for k in range(9)]
    ranges = _cast(jnp.zeros(3), ANGLES, _circles(centres, [0.05] * 9), _no_walls(),
                   CFG.max_range)
    segs = jax.jit(functools.partial(legs.segment, max_segments=4))(ranges, ANGLES, CFG.max_range)
    assert int(segs.found) == 9 and int(segs.dropped) == 5 and bool(segs.mask.all())
    assert np.all(np.asarray(segs.labels) < 4)


def test_bad_input_raises():
    with pytest.raises(ValueError, match="angles"):
        legs.detect_people(jnp.ones(10), jnp.ones(9))
    with pytest.raises(ValueError, match="ranges"):
        legs.segment(jnp.ones((2, 5)), jnp.ones(5), 5.6)
    with pytest.raises(ValueError, match="NaN"):
        legs.detect_people(jnp.array([1.0, jnp.nan]), jnp.zeros(2))
    with pytest.raises(ValueError, match="max_segments"):
        legs.segment(jnp.ones(5), jnp.linspace(0, 1, 5), 5.6, max_segments=0)
    with pytest.raises(ValueError, match="legs_mask"):
        legs.pair_legs(jnp.zeros((4, 2)), jnp.ones(3, bool))
    with pytest.raises(ValueError, match="prev_legs"):
        legs.pair_legs(jnp.zeros((4, 2)), jnp.ones(4, bool), prev_legs=(jnp.zeros((3, 3)),
                                                                        jnp.ones(3, bool)))


@jax.jit
def _candidate_with_and_without_convexity(ranges, angles):
    segs = legs.segment(ranges, angles, 5.6, max_segments=2)
    f = legs.features(ranges, angles, segs, 5.6)
    return jnp.stack([legs.leg_candidates(f, legs.LegParams(convex_only=c))[0]
                      for c in (0.0, 1.0)])


def test_convex_only_rejects_arcs_that_bulge_away_from_the_sensor():
    # A 12 cm arc 2 m away, bulging 4 cm towards (leg-like) or away from the sensor.
    angles = jnp.linspace(-0.03, 0.03, 9)
    bump = 0.04 * (1.0 - (np.asarray(angles) / 0.03) ** 2)
    keep = [np.asarray(_candidate_with_and_without_convexity(jnp.asarray(2.0 - sign * bump),
                                                             angles)).tolist()
            for sign in (1.0, -1.0)]
    assert keep == [[True, True], [True, False]]


def _greedy_reference(xy, mask, pair_distance, single_legs, max_people):
    """Seed 004's pairing as a plain loop: take the closest allowed pair (lowest i, then j on
    ties), remove both legs, repeat; then the unpaired legs in index order."""
    n = len(xy)
    free = list(np.flatnonzero(mask))
    pairs = []
    while True:
        best = None
        for i in free:
            for j in free:
                if i < j:
                    d = np.sqrt(np.sum((xy[i] - xy[j]) ** 2))
                    if d <= pair_distance and (best is None or d < best[0]):
                        best = (d, i, j)
        if best is None:
            break
        pairs.append([best[1], best[2]])
        free = [k for k in free if k not in best[1:]]
    people = pairs + ([[k, -1] for k in range(n) if k in free] if single_legs else [])
    legs_out = np.full((max_people, 2), -1)
    legs_out[:min(len(people), max_people)] = people[:max_people]
    return legs_out, max(len(people) - max_people, 0)


_pair_batch = jax.jit(jax.vmap(lambda xy, mask, single: legs.pair_legs(
    xy, mask, legs.LegParams(single_legs=single), max_people=5)))


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_pairing_matches_a_plain_greedy_loop_including_ties(dtype):
    rng = np.random.default_rng(3)
    n = 64
    xy = rng.uniform(0.0, 1.2, (n, 10, 2))
    xy[::2] = np.round(xy[::2] * 4) / 4          # grid points: many equal distances
    xy = xy.astype(dtype)
    mask = rng.random((n, 10)) < 0.8
    single = (np.arange(n) % 2).astype(dtype)
    people = _pair_batch(jnp.asarray(xy), jnp.asarray(mask), jnp.asarray(single))
    for k in range(n):
        ref, dropped = _greedy_reference(xy[k], mask[k], 0.5, single[k] > 0, 5)
        np.testing.assert_array_equal(people.legs[k], ref)
        assert int(people.dropped[k]) == dropped


def test_gradient_of_people_wrt_ranges_is_finite_with_one_point_segments():
    # Isolated single returns make one-point segments (zero width, zero scatter); their sqrt
    # derivatives must not turn the gradient of the detected people into NaN.
    rng = np.random.default_rng(4)
    angles = jnp.linspace(-1.0, 1.0, 121)
    ranges = np.full(121, 5.6)
    ranges[10], ranges[40], ranges[41], ranges[90] = 2.0, 3.0, 3.5, 1.5
    ranges[60:66] = 2.0 + 0.01 * rng.normal(size=6)
    ranges[70:76] = 2.0 + 0.01 * rng.normal(size=6)

    def f(r):
        d = legs.detect(r, angles, max_segments=16, max_people=4)
        return jnp.sum(jnp.where(d.people.mask[:, None], d.people.xy, 0.0)) + jnp.sum(
            jnp.where(d.features.mask, d.features.width + d.features.linearity, 0.0))

    g = jax.grad(f)(jnp.asarray(ranges))
    assert np.all(np.isfinite(np.asarray(g)))
    assert np.any(np.asarray(g) != 0)


def test_a_scan_without_beams_and_no_legs_give_no_people():
    det = legs.detect(jnp.zeros((0,)), jnp.zeros((0,)), max_people=4)
    assert det.points.shape == (0, 2) and det.valid.shape == (0,)
    assert not bool(jnp.any(det.people.mask)) and not bool(jnp.any(det.legs_mask))
    people = legs.pair_legs(jnp.zeros((0, 2)), jnp.zeros((0,), bool), max_people=3)
    assert people.mask.shape == (3,) and not bool(jnp.any(people.mask))
