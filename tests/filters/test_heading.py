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


# --- the windowed variant -------------------------------------------------------------------

def _windowed_reference(heading0, positions, window, dt, min_distance, segments=1,
                        chord=2.5):
    """A plain loop over a list of past positions (the first repeated before the start)."""
    past = [np.asarray(positions[0], float)] * window
    th, out = heading0, []
    anchor, was_moving = None, False
    for p in positions:
        p = np.asarray(p, float)
        d = p - past[-window]
        moved = np.hypot(*d) >= min_distance
        v = d / (window * dt)
        if segments > 1:
            # the last `window` positions (this one included), cut into `segments` pieces,
            # each averaged
            last = np.array(past[-(window - 1):] + [p]) if window > 1 else np.array([p])
            cuts = [(j * window) // segments for j in range(segments + 1)]
            c = [last[a:b].mean(0) for a, b in zip(cuts[:-1], cuts[1:])]
            whole = c[-1] - c[0]
            moved = all(np.hypot(*(b - a)) >= min_distance / segments
                        and (b - a) @ whole >= heading.SUSTAINED_COS * np.hypot(*(b - a))
                        * np.hypot(*whole) for a, b in zip(c[:-1], c[1:]))
            if moved and not was_moving:
                anchor = c[0]                                   # the sustained walk's start
            was_moving = moved
            if moved:
                chord_vec = c[-1] - anchor
                if np.hypot(*chord_vec) > chord:                 # pulled along behind
                    anchor = c[-1] - chord_vec * chord / np.hypot(*chord_vec)
                    chord_vec = c[-1] - anchor
                speed = np.hypot(*whole) / ((segments - 1) * window * dt / segments)
                v = chord_vec / np.hypot(*chord_vec) * speed     # the chord's direction
        if moved:
            b = beta_eq13(np.hypot(*v))
            e = (np.arctan2(v[1], v[0]) - th + np.pi) % (2 * np.pi) - np.pi
            th = (th + (1 - b) * e + np.pi) % (2 * np.pi) - np.pi
        past.append(p)
        out.append(th)
    return np.asarray(out)


def _run_windowed(heading0, positions, window=20, dt=0.1, min_distance=0.5, segments=1):
    positions = jnp.asarray(positions)
    s0 = heading.windowed_heading_init(heading0, positions[0], window)

    def body(s, p):
        s = heading.windowed_heading_step(s, p, dt, min_distance=min_distance,
                                          segments=segments)
        return s, s.heading

    return np.asarray(jax.lax.scan(body, s0, positions)[1])


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_windowed_filter_equals_a_loop_over_the_window(dtype):
    rng = np.random.default_rng(3)
    # walk, stand, walk the other way, with position noise
    v = np.concatenate([np.tile([0.5, 0.1], (40, 1)), np.zeros((30, 2)),
                        np.tile([-0.2, 0.45], (40, 1))])
    pos = np.cumsum(v * 0.1, 0) + 0.01 * rng.standard_normal(v.shape)
    out = _run_windowed(0.3, pos.astype(dtype))
    ref = _windowed_reference(0.3, pos.astype(dtype).astype(float), 20, 0.1, 0.5)
    np.testing.assert_allclose(out, ref, atol=1e-5 if dtype == jnp.float32 else 1e-10)
    assert out.dtype == dtype


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
@pytest.mark.parametrize("window,segments", [(20, 4), (25, 2), (23, 3)])
def test_sustained_filter_equals_a_loop_over_the_window(dtype, window, segments):
    rng = np.random.default_rng(4)
    # walk, turn sharply, two steps back, walk slowly, with position noise
    v = np.concatenate([np.tile([0.5, 0.1], (40, 1)), np.tile([-0.1, 0.5], (70, 1)),
                        np.tile([-0.3, 0.0], (20, 1)), np.zeros((10, 2)),
                        np.tile([0.3, 0.3], (40, 1))])
    pos = np.cumsum(v * 0.1, 0) + 0.01 * rng.standard_normal(v.shape)
    out = _run_windowed(0.3, pos.astype(dtype), window, min_distance=0.8, segments=segments)
    ref = _windowed_reference(0.3, pos.astype(dtype).astype(float), window, 0.1, 0.8,
                              segments)
    np.testing.assert_allclose(out, ref, atol=1e-5 if dtype == jnp.float32 else 1e-10)
    assert out.dtype == dtype
    assert np.ptp(out) > 1.0                     # it did turn, more than once


def test_two_steps_in_a_row_or_a_step_after_a_walk_turn_only_the_plain_window():
    # facing +x, two 1 s steps backwards at 0.3 m/s back to back: 0.6 m in 2 s
    v = np.concatenate([np.zeros((30, 2)), np.tile([-0.3, 0.0], (20, 1)), np.zeros((30, 2))])
    pos = np.cumsum(v * 0.1, 0)
    assert np.max(np.abs(_run_windowed(0.0, pos))) > 2.5              # windowed: turned
    np.testing.assert_array_equal(
        _run_windowed(0.0, pos, min_distance=0.8, segments=3), 0.0)
    # walking along +x at 0.5 m/s for 4 s, then at once a 1 s step to the left
    v = np.concatenate([np.tile([0.5, 0.0], (40, 1)), np.tile([0.0, 0.3], (10, 1)),
                        np.zeros((30, 2))])
    pos = np.cumsum(v * 0.1, 0)
    plain = _run_windowed(np.pi / 2, pos)
    held = _run_windowed(np.pi / 2, pos, min_distance=0.8, segments=3)
    np.testing.assert_allclose(held[39], 0.0, atol=1e-3)        # the walk was followed
    assert abs(plain[-1]) > np.radians(10)                       # the step swung the plain one
    # standing after a walk along +x, the estimate jumps 0.3 m onwards for good (clutter)
    v = np.concatenate([np.tile([0.5, 0.0], (40, 1)), np.zeros((8, 2)), [[3.0, 1.0]],
                        np.zeros((30, 2))])
    pos = np.cumsum(v * 0.1, 0)
    assert np.degrees(abs(_run_windowed(0.0, pos)[-1])) > 3                 # plain: turned
    np.testing.assert_allclose(_run_windowed(0.0, pos, min_distance=0.8, segments=3)[-1], 0.0,
                               atol=1e-6)
    # (back to the step after the walk) the sustained heading turns only while the step's
    # first tenths of a second still pass as
    # the walk's end, and then along the 2 m chord: under 2 deg
    assert abs(held[-1]) < np.radians(2)


def test_a_step_backwards_leaves_the_windowed_heading_but_turns_eq_12s():
    # standing facing +x, then a 1 s step backwards at 0.3 m/s, then still again
    v = np.concatenate([np.zeros((30, 2)), np.tile([-0.3, 0.0], (10, 1)), np.zeros((30, 2))])
    pos = np.cumsum(v * 0.1, 0)
    windowed = _run_windowed(0.0, pos)
    np.testing.assert_array_equal(windowed, 0.0)
    ar = np.asarray(heading.ar_heading_filter(0.0, jnp.asarray(v)))
    assert np.max(np.abs(ar)) > 2.5          # eq. 12-13 at 10 Hz: turned almost round


def test_walking_turns_the_windowed_heading_to_the_direction_of_motion():
    v = np.tile([0.0, 0.5], (40, 1))         # along +y at 0.5 m/s from heading 0
    out = _run_windowed(0.0, np.cumsum(v * 0.1, 0))
    assert out[8] == 0.0                      # under 0.5 m moved: held
    np.testing.assert_allclose(out[-1], np.pi / 2, atol=1e-3)


def test_windowed_filter_skips_a_missing_position_and_refuses_a_bad_window():
    pos = np.cumsum(np.tile([0.5, 0.0], (30, 1)) * 0.1, 0)
    with_gap = pos.copy()
    with_gap[12] = np.nan
    out = _run_windowed(1.0, with_gap)
    assert np.all(np.isfinite(out))
    with pytest.raises(ValueError, match="window"):
        heading.windowed_heading_init(0.0, jnp.zeros(2), 0)
    with pytest.raises(ValueError, match="position"):
        heading.windowed_heading_init(0.0, jnp.zeros(3), 5)
    with pytest.raises(ValueError, match="segments"):
        heading.windowed_heading_step(heading.windowed_heading_init(0.0, jnp.zeros(2), 2),
                                      jnp.zeros(2), 0.1, segments=3)
    # a missing position leaves the sustained filter's state as it was
    s = heading.windowed_heading_init(0.5, jnp.zeros(2), 20)
    s = heading.windowed_heading_step(s, jnp.ones(2), 0.1, min_distance=0.8, segments=3)
    after = heading.windowed_heading_step(s, jnp.full(2, jnp.nan), 0.1, min_distance=0.8,
                                          segments=3)
    for a, b in zip(after, s):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
