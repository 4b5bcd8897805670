"""Segment features of the learned leg detector against a numpy transcription of their
definitions (one segment and one point at a time), on simulated scans and, when the shared data
is present, on real ones."""

import functools
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.perception import leg_features, legs
from sims.following import lidar
from tests.perception import references

CFG = lidar.LaserConfig()
ANGLES = lidar.beam_angles(CFG)
DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "leg_tracker"

_scan = jax.jit(lidar.scan, static_argnums=4)


@functools.partial(jax.jit, static_argnames="cap")
def _features(ranges, angles, max_range, cap):
    segs = legs.segment(ranges, angles, max_range, jump=0.13, max_segments=cap)
    return leg_features.compute(ranges, angles, segs, max_range), segs


def _room(seed, dtype=jnp.float64):
    """A scan of legs (circles), posts and two walls at random."""
    rng = np.random.default_rng(seed)
    n = 10
    centres = rng.uniform([-1.0, -4.0], [5.0, 4.0], (n, 2))
    radii = rng.uniform(0.015, 0.08, n)
    circles = lidar.Circles(jnp.asarray(centres, dtype), jnp.asarray(radii, dtype),
                            jnp.ones(n, bool))
    walls = lidar.Walls(jnp.asarray([[[4.5, -4.0], [5.0, 4.0]], [[-1.0, 3.5], [4.0, 3.0]]],
                                    dtype), jnp.ones(2, bool))
    return _scan(jax.random.PRNGKey(seed), jnp.zeros(3, dtype), circles, walls, CFG)


def _reference(ranges, angles, max_range, segs):
    r = np.asarray(ranges, np.float64)
    a = np.asarray(angles, np.float64)
    valid = np.isfinite(r) & (r > 0) & (r < max_range)
    xy = np.stack([np.where(valid, r, 0) * np.cos(a), np.where(valid, r, 0) * np.sin(a)], -1)
    return references.leg_features(xy, valid, np.asarray(segs.first), np.asarray(segs.last),
                                   np.asarray(segs.mask))


def _assert_close(X, R, rtol):
    # Scale-relative: each feature's error over 1 + |value|.
    err = np.abs(np.asarray(X, np.float64) - R) / (1.0 + np.abs(R))
    worst = np.unravel_index(np.argmax(err), err.shape)
    assert err.max() <= rtol, (f"feature {leg_features.FEATURE_NAMES[worst[1]]} of segment "
                               f"{worst[0]}: {X[worst]} vs {R[worst]}")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_features_equal_the_numpy_transcription_float64(seed):
    ranges = _room(seed)
    X, segs = _features(ranges, ANGLES, CFG.max_range, 64)
    assert int(segs.found) > 8
    _assert_close(np.asarray(X), _reference(ranges, ANGLES, CFG.max_range, segs), 1e-8)


def test_features_float32_within_float32_precision():
    ranges = _room(3)
    X32, segs32 = _features(ranges.astype(jnp.float32), ANGLES.astype(jnp.float32),
                            CFG.max_range, 64)
    X64, segs64 = _features(ranges, ANGLES, CFG.max_range, 64)
    assert X32.dtype == jnp.float32
    assert np.array_equal(segs32.mask, segs64.mask)
    ref = _reference(ranges, ANGLES, CFG.max_range, segs64)
    # The scatter sums (linearity, circularity) lose the most: sums of squares of centimetres.
    cols = [k for k, n in enumerate(leg_features.FEATURE_NAMES)
            if n not in ("linearity", "circularity", "radius", "mean_curvature",
                         "mean_angular_difference")]
    _assert_close(np.asarray(X32)[:, cols], ref[:, cols], 1e-4)
    assert np.all(np.isfinite(X32))


def test_features_of_kept_segments_do_not_depend_on_the_capacity():
    ranges = _room(4)
    big, segs = _features(ranges, ANGLES, CFG.max_range, 64)
    found = int(segs.found)
    small, small_segs = _features(ranges, ANGLES, CFG.max_range, found // 2)
    assert int(small_segs.dropped) == found - found // 2
    # The last kept segment's gap_after is to the (dropped) next segment, not MAX_GAP.
    np.testing.assert_allclose(small, big[: found // 2], rtol=1e-12)


def test_a_leg_arc_and_a_wall_differ_as_defined():
    # A 6 cm leg seen from 2 m and a straight wall piece of the same width.
    circles = lidar.Circles(jnp.asarray([[2.0, 0.0]]), jnp.asarray([0.06]), jnp.ones(1, bool))
    walls = lidar.Walls(jnp.asarray([[[3.0, 0.4], [3.0, 0.5]]]), jnp.ones(1, bool))
    ranges = lidar.cast(jnp.zeros(3), ANGLES, circles, walls, CFG.max_range)
    X, segs = _features(ranges, ANGLES, CFG.max_range, 8)
    X = np.asarray(X)
    leg, wall = X[0], X[1]
    f = {n: k for k, n in enumerate(leg_features.FEATURE_NAMES)}
    assert int(segs.found) == 2
    assert abs(leg[f["radius"]] - 0.06) < 0.005                 # an exact arc: Kasa's radius
    assert leg[f["circularity"]] < 1e-12
    assert wall[f["radius"]] == leg_features.MAX_RADIUS        # collinear: no circle
    assert wall[f["linearity"]] < 1e-12 and leg[f["linearity"]] > 1e-5
    # Beams sweep counter-clockwise: an arc facing the sensor turns one way all along.
    assert abs(leg[f["mean_angular_difference"]]) > 0.05
    assert abs(wall[f["mean_angular_difference"]]) < 1e-6
    assert leg[f["gap_before"]] == leg_features.MAX_GAP        # nothing before the first
    assert wall[f["gap_after"]] == leg_features.MAX_GAP
    np.testing.assert_allclose(leg[f["gap_after"]], wall[f["gap_before"]])
    np.testing.assert_allclose(leg[f["range"]], 2.0 - 0.06 * math.pi / 4, atol=0.01)


def test_vmap_equals_one_scan_at_a_time_and_one_point_segments_are_finite():
    scans = jnp.stack([_room(s) for s in (5, 6)])
    # An isolated single return, then a two-point segment.
    lone = jnp.full(ANGLES.shape, jnp.inf).at[100].set(2.0).at[300:302].set(3.0)
    scans = jnp.concatenate([scans, lone[None]])
    batched = jax.vmap(lambda r: _features(r, ANGLES, CFG.max_range, 64)[0])(scans)
    for k in range(3):
        np.testing.assert_array_equal(batched[k], _features(scans[k], ANGLES, CFG.max_range,
                                                            64)[0])
    X = np.asarray(batched[2])
    assert np.all(np.isfinite(X))
    assert X[0, 0] == 1 and X[1, 0] == 2 and X[2:].sum() == 0     # masked rows are 0


def test_bad_scans_are_refused_by_name():
    segs = legs.segment(jnp.ones(4), jnp.arange(4.0), 5.6)
    with pytest.raises(ValueError, match="angles"):
        leg_features.compute(jnp.ones(4), jnp.arange(3.0), segs)
    with pytest.raises(ValueError, match="ranges"):
        leg_features.compute(jnp.ones((2, 4)), jnp.arange(4.0), segs)


@pytest.mark.skipif(not DATA.exists(), reason="the shared leg_tracker recordings are absent")
def test_features_equal_the_transcription_on_real_scans():
    from jaxtrack.io import bags

    s = bags.read_laser(DATA / "training" / "positive_1_extracted.bag", "/training_scan")
    angles = jnp.asarray(s.angles, jnp.float64)
    for t in (0, 90, 180):
        r = jnp.asarray(s.ranges[t], jnp.float64)
        X, segs = _features(r, angles, s.range_max, 128)
        assert int(segs.found) > 20
        _assert_close(np.asarray(X), _reference(r, angles, s.range_max, segs), 1e-8)
