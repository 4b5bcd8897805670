"""Seed 002's adaptive autoregressive heading filter (eqs. 12-13)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.filters import heading


def beta_eq13(v):
    if v < 0.1:
        return 0.9
    if v <= 0.6:
        return 1.04 - 1.4 * v
    return 0.2


@pytest.mark.parametrize("v", [0.0, 0.05, 0.1, 0.3, 0.6, 0.61, 2.0])
def test_coefficient_equals_eq_13(v):
    np.testing.assert_allclose(heading.ar_coefficient(jnp.asarray(v)), beta_eq13(v), atol=1e-12)


def test_filter_equals_eq_12_away_from_the_angle_cut():
    rng = np.random.default_rng(0)
    vel = np.stack([1.0 + 0.3 * rng.standard_normal(40), 0.4 * rng.standard_normal(40)], -1)
    vel[::5] *= 0.1  # some slow steps
    thetas = heading.ar_heading_filter(0.2, jnp.asarray(vel))
    th, ref = 0.2, []
    for vx, vy in vel:
        b = beta_eq13(np.hypot(vx, vy))
        th = b * th + (1 - b) * np.arctan2(vy, vx)
        ref.append(th)
    np.testing.assert_allclose(thetas, ref, atol=1e-12)


def test_step_averages_on_the_circle_across_pi():
    th = np.deg2rad(179.0)
    v = 1.0 * np.array([np.cos(np.deg2rad(-179.0)), np.sin(np.deg2rad(-179.0))])
    out = float(heading.ar_heading_step(jnp.asarray(th), jnp.asarray(v)))
    # beta = 0.2: 80 % of the way from 179 deg to 181 deg = 180.6 deg, i.e. -179.4 deg.
    np.testing.assert_allclose(np.rad2deg(out), -179.4, atol=1e-9)


def test_slow_backward_shuffle_barely_changes_the_heading():
    thetas = heading.ar_heading_filter(0.0, jnp.tile(jnp.array([[-0.05, 0.0]]), (3, 1)))
    # beta = 0.9 at 0.05 m/s: each step moves 10 % of the way towards pi (either side).
    assert abs(float(thetas[0])) == pytest.approx(0.1 * np.pi, abs=1e-9)
    assert np.all(np.abs(np.asarray(thetas)) < np.pi / 2)


def test_heading_filter_is_differentiable_in_its_coefficients():
    vel = jnp.array([[0.3, 0.1], [0.35, 0.2], [0.2, 0.25]])

    def final(slope):
        return heading.ar_heading_filter(0.0, vel, heading.HeadingParams(slope=slope))[-1]

    g = jax.grad(final)(1.4)
    eps = 1e-6
    fd = (final(1.4 + eps) - final(1.4 - eps)) / (2 * eps)
    np.testing.assert_allclose(g, fd, rtol=1e-6)


def test_bad_velocity_shape_is_rejected():
    with pytest.raises(ValueError, match="velocities"):
        heading.ar_heading_filter(0.0, jnp.zeros((5, 3)))
