"""The ground plane against Open3D's ``segment_plane`` and a least-squares closed form."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.perception.ground_plane import fit_ground_plane, horizontal_plane, plane_height
from tests.perception import _clouds
from tests.perception._open3d import cloud, open3d

_fit = jax.jit(fit_ground_plane, static_argnames=("num_hypotheses",))


def _room(seed, wall_points=900, angle=0.05, lift=-0.02):
    rng = np.random.default_rng(seed)
    pts = np.concatenate([_clouds.floor(rng, 2000), _clouds.wall(rng, wall_points),
                          _clouds.person(rng, (2.0, 0.0), n=500)])
    return _clouds.tilt(pts, angle, lift)


def _angle(a, b):
    return math.degrees(math.acos(min(1.0, abs(float(np.dot(a, b))))))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_plane_and_inliers_agree_with_open3d_segment_plane(seed):
    pts = _room(seed)
    o3d = open3d()
    o3d.utility.random.seed(seed)
    model, inl = cloud(pts).segment_plane(distance_threshold=0.06, ransac_n=3,
                                          num_iterations=1000)
    model = np.asarray(model) * np.sign(model[2])
    fit = _fit(jax.random.key(seed), jnp.asarray(pts), jnp.ones(len(pts), bool),
               horizontal_plane(0.0))
    plane = np.asarray(fit.plane)
    assert _angle(plane[:3], model[:3]) < 0.5
    assert abs(plane[3] - model[3]) < 0.005
    ref = np.zeros(len(pts), bool)
    ref[inl] = True
    assert (np.asarray(fit.inliers) == ref).mean() > 0.99
    # The refit is the total-least-squares plane of its own inliers.
    sel = pts[np.asarray(fit.inliers)]
    _, _, vt = np.linalg.svd(sel - sel.mean(0))
    assert _angle(plane[:3], vt[-1]) < 0.05


def test_a_wall_larger_than_the_floor_does_not_win():
    pts = _room(4, wall_points=4000)
    model, _ = cloud(pts).segment_plane(0.06, 3, 1000)
    assert abs(model[0]) > 0.9                                   # Open3D picks the wall
    fit = _fit(jax.random.key(0), jnp.asarray(pts), jnp.ones(len(pts), bool),
               horizontal_plane(0.0))
    assert _angle(np.asarray(fit.plane)[:3], _clouds.tilt(np.eye(3), 0.05)[2]) < 0.5
    assert np.asarray(fit.plane)[2] > 0                          # up stays up


def test_previous_plane_wins_ties_and_tracks_a_rocking_camera():
    plane = horizontal_plane(0.0, dtype=jnp.float64)
    for k, angle in enumerate(np.linspace(0.0, 0.12, 7)):       # 1 deg per frame
        pts = _room(10 + k, angle=angle, lift=0.01 * k)
        fit = _fit(jax.random.key(k), jnp.asarray(pts), jnp.ones(len(pts), bool), plane,
                   num_hypotheses=8)
        plane = fit.plane
        truth = _clouds.tilt(np.eye(3), angle)[2]
        assert _angle(np.asarray(plane)[:3], truth) < 0.3
        assert abs(float(plane_height(plane, jnp.asarray([[0.0, 0.0, 0.01 * k]]))[0])) < 0.01


def test_no_hypotheses_refits_the_previous_plane():
    pts = _room(5, angle=0.0, lift=0.03)
    fit = fit_ground_plane(jax.random.key(0), jnp.asarray(pts), jnp.ones(len(pts), bool),
                           horizontal_plane(0.0), num_hypotheses=0)
    assert bool(fit.from_previous)
    assert abs(float(fit.plane[3]) + 0.03) < 0.005


def test_masked_and_nan_points_do_not_count():
    pts = _room(6)
    pts[:50] = np.nan
    mask = np.ones(len(pts), bool)
    mask[50:100] = False
    fit = fit_ground_plane(jax.random.key(0), jnp.asarray(pts), jnp.asarray(mask),
                           horizontal_plane(0.0))
    assert np.isfinite(np.asarray(fit.plane)).all()
    assert not np.asarray(fit.inliers)[:100].any()


@pytest.mark.parametrize("n", [0, 2])
def test_too_few_points_return_the_previous_plane(n):
    prior = horizontal_plane(0.1)
    fit = fit_ground_plane(jax.random.key(0), jnp.zeros((n, 3)), jnp.ones(n, bool), prior)
    np.testing.assert_allclose(fit.plane, prior)
    assert int(fit.num_inliers) == 0


def test_float32_matches_float64():
    pts = _room(7)
    f64 = fit_ground_plane(jax.random.key(1), jnp.asarray(pts), jnp.ones(len(pts), bool),
                           horizontal_plane(0.0, dtype=jnp.float64))
    f32 = fit_ground_plane(jax.random.key(1), jnp.asarray(pts, jnp.float32),
                           jnp.ones(len(pts), bool), horizontal_plane(0.0))
    assert f32.plane.dtype == jnp.float32
    np.testing.assert_allclose(f32.plane, f64.plane, atol=1e-4)


@pytest.mark.parametrize("kw, match", [(dict(threshold=-1.0), "threshold"),
                                       (dict(num_hypotheses=-1), "num_hypotheses"),
                                       (dict(previous=jnp.zeros(3)), "previous")])
def test_bad_input_is_refused(kw, match):
    args = dict(previous=horizontal_plane()) | kw
    previous = args.pop("previous")
    with pytest.raises(ValueError, match=match):
        fit_ground_plane(jax.random.key(0), jnp.zeros((5, 3)), jnp.ones(5, bool), previous,
                         **args)
