"""Angle helpers against numpy / scipy."""

import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import circmean

from jaxtrack import angles


@settings(max_examples=50, deadline=None)
@given(st.floats(-100.0, 100.0))
def test_wrap_lands_in_range_and_preserves_direction(a):
    w = float(angles.wrap(jnp.asarray(a)))
    assert -np.pi <= w < np.pi + 1e-12
    np.testing.assert_allclose([np.cos(w), np.sin(w)], [np.cos(a), np.sin(a)], atol=1e-9)


def test_difference_is_the_shortest_signed_angle():
    np.testing.assert_allclose(angles.difference(jnp.array(-3.1), jnp.array(3.1)),
                               2 * np.pi - 6.2, atol=1e-12)


def test_circular_mean_matches_scipy_circmean():
    rng = np.random.default_rng(1)
    a = np.pi + 0.3 * rng.standard_normal(100)
    ref = circmean(a, high=np.pi, low=-np.pi)
    out = float(angles.circular_mean(jnp.asarray(a)))
    np.testing.assert_allclose(np.exp(1j * out), np.exp(1j * ref), atol=1e-12)
    w = rng.random(100)
    ref_w = np.angle(np.sum(w * np.exp(1j * a)))
    np.testing.assert_allclose(angles.circular_mean(jnp.asarray(a), jnp.asarray(w)), ref_w,
                               atol=1e-12)
