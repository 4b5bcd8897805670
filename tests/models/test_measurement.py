"""Measurement models against closed forms."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.models import measurement


def test_position_selects_leading_components():
    H = measurement.position(6, dim=3)
    x = np.arange(6.0)
    np.testing.assert_array_equal(H @ x, x[:3])
    with pytest.raises(ValueError, match="dim"):
        measurement.position(2, dim=3)


@pytest.mark.parametrize("xy,origin", [((3.0, 4.0), None), ((-1.0, -1e-9), None),
                                       ((2.0, 1.0), (1.0, 3.0))])
def test_range_bearing_matches_polar_coordinates(xy, origin):
    x = jnp.array([*xy, 0.5, -0.2])
    o = None if origin is None else jnp.asarray(origin)
    out = measurement.range_bearing(x, o)
    d = np.asarray(xy) - (np.zeros(2) if origin is None else np.asarray(origin))
    np.testing.assert_allclose(out, [np.hypot(*d), np.arctan2(d[1], d[0])], rtol=1e-12)


def test_range_bearing_gradient_is_finite_at_the_sensor():
    g = jax.jacfwd(measurement.range_bearing)(jnp.zeros(4))
    assert np.all(np.isfinite(g))


def test_range_bearing_residual_wraps_only_the_bearing():
    a = jnp.array([5.0, np.pi - 0.05])
    b = jnp.array([1.0, -np.pi + 0.05])
    r = measurement.range_bearing_residual(a, b)
    np.testing.assert_allclose(r, [4.0, -0.1], atol=1e-12)
