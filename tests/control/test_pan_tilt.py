"""The camera's pan servo (`jaxtrack.control.pan_tilt`): it holds a moving target within its
rate, acceleration and range limits."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.control import pan_tilt

DT = 0.1


def _run(cfg, bearings, dtype=jnp.float32):
    def body(s, b):
        s = pan_tilt.servo(cfg, s, b, DT)
        return s, s

    _, states = jax.jit(lambda b: jax.lax.scan(body, pan_tilt.init(dtype), b))(
        jnp.asarray(bearings, dtype))
    return np.asarray(states.angle, float), np.asarray(states.rate, float)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_the_pan_holds_a_moving_target_within_its_limits(dtype):
    cfg = pan_tilt.PanTiltConfig()
    t = np.arange(200) * DT
    # A target sweeping at 45 deg/s between +-100 deg, then jumping behind the robot.
    bearing = np.deg2rad(100.0) * np.sin(2 * np.pi * t / 8.9)
    bearing[150:] = np.deg2rad(175.0)
    angle, rate = _run(cfg, bearing, dtype)
    assert np.all(np.abs(angle) <= cfg.limit + 1e-6)
    assert np.all(np.abs(rate) <= cfg.max_rate + 1e-6)
    accel = np.diff(np.concatenate([[0.0], rate])) / DT
    assert np.all(np.abs(accel) <= cfg.max_accel * (1 + 1e-5))
    # Tracking, once caught up: no worse than the continuous first-order lag of a proportional
    # servo on a sinusoid, amplitude A w / sqrt(k^2 + w^2) (17 deg here; the rate limit, 90
    # deg/s, is above the target's 71 deg/s peak).
    w = 2 * np.pi / 8.9
    lag = 100.0 * w / np.hypot(cfg.gain, w)
    err = np.rad2deg(np.abs(angle[30:150] - bearing[30:150]))
    assert err.max() < lag and err.mean() < 2 / np.pi * lag
    # A target behind the robot: the pan stops at its limit.
    assert abs(angle[-1] - cfg.limit) < 1e-5 and abs(rate[-1]) < 1e-4


def test_a_step_is_reached_at_the_rate_limit():
    cfg = pan_tilt.PanTiltConfig(gain=100.0)
    angle, rate = _run(cfg, np.full(40, math.radians(90.0)))
    # 90 deg at 90 deg/s after a 0.25 s ramp: about 1.1 s.
    reached = np.argmax(np.abs(angle - math.radians(90.0)) < math.radians(2.0)) * DT
    assert 0.9 <= reached <= 1.5
    assert np.abs(rate).max() == pytest.approx(cfg.max_rate, rel=1e-5)


def test_bad_configuration_is_refused():
    with pytest.raises(ValueError, match="limit"):
        pan_tilt.PanTiltConfig(limit=4.0)
    with pytest.raises(ValueError, match="positive"):
        pan_tilt.PanTiltConfig(max_rate=0.0)
