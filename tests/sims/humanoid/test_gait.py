"""The gait's preview-QP planner (Herdt et al.'s walking pattern generator in the step cycle):
command tracking, the footsteps' heading constraints, the ZMP in the sole, stopping, and the
planner option's errors."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.control import walking_mpc
from sims.humanoid import gait

QUIET = gait.GaitParams(stride_noise=0.0, heading_noise=0.0, slip_noise=0.0)
DT = 0.05


def _rollout(dtype, velocity, turn_rate, params, steps, stop_after=None, scheduled=False):
    """Sub-steps of the gait under a constant command (stop after ``stop_after`` sub-steps;
    ``scheduled``: pass `gait.solve_schedule` as the step's ``solve``)."""
    v = jnp.asarray(velocity, dtype)

    def body(st, x):
        k, i = x
        stop = False if stop_after is None else i >= stop_after
        solve = gait.solve_schedule(i, DT, "preview-qp") if scheduled else None
        st = gait.step(k, st, v, jnp.asarray(turn_rate, dtype), stop, params, DT, "preview-qp",
                       solve)
        return st, st

    keys = jax.random.split(jax.random.PRNGKey(0), steps)
    init = gait.init(jnp.zeros(3, dtype), params, dtype, "preview-qp")
    return jax.lax.scan(body, init, (keys, jnp.arange(steps)))[1]


_rollout_jit = jax.jit(_rollout, static_argnums=(0, 3, 4, 5, 6))


def _roll(*args):
    return jax.tree_util.tree_map(np.asarray, _rollout_jit(*args))


def _speed(states, cycles=10):
    """Mean velocity over the last whole step cycles (two steps each)."""
    n = cycles * round(2 * QUIET.step_period / DT)
    return (states.com[-1] - states.com[-1 - n]) / (n * DT)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_preview_qp_gait_tracks_forward_and_backward_commands(dtype):
    for command in (0.1, -0.1):
        states = _roll(dtype, (command, 0.0), 0.0, QUIET, 240)
        speed = _speed(states)
        # float64 2 % slow, float32 4 % fast (docs/humanoid_preview_qp.md).
        np.testing.assert_allclose(speed, [command, 0.0], atol=0.006)
        sway = states.com[-100:, 1]
        assert np.ptp(sway) < 0.1


@pytest.mark.parametrize("command, low, high", [(0.1, 0.06, 0.09), (0.01, 0.008, 0.011)])
def test_preview_qp_gait_walks_sideways(command, low, high):
    """Sideways commands: fast ones come out about a third slow (0.1 m/s at 0.066 m/s), slow
    ones nearly whole (0.01 m/s at 0.0091 m/s; with the sole's full width as the ZMP's lateral
    band they came out at 0.0038 m/s: `gait.step_constraints`). Measured, not targets."""
    states = _roll(jnp.float64, (0.0, command), 0.0, QUIET, 240)
    speed = _speed(states)
    assert abs(speed[0]) < 0.005
    assert low < speed[1] < high


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_footsteps_respect_the_heading_constraints_while_turning(dtype):
    """Every landing lies in the rectangle placed on the previous foot and rotated by its yaw
    (`gait.step_constraints`), and the feet's yaws follow the commanded turn step by step."""
    turn_rate = 0.5
    states = _roll(dtype, (0.06, 0.02), turn_rate, QUIET, 200)
    con = gait.step_constraints(QUIET)
    switch = np.flatnonzero(np.diff(states.side) != 0) + 1
    feet, yaws, sides = states.support[switch], states.support_yaw[switch], states.side[switch]
    assert len(feet) >= 15
    tol = 1e-4
    for i in range(1, len(feet)):
        c, s = math.cos(yaws[i - 1]), math.sin(yaws[i - 1])
        d = feet[i] - feet[i - 1]
        local = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])
        assert abs(local[0]) <= con.max_stride + tol
        assert con.min_lateral - tol <= sides[i] * local[1] <= con.max_lateral + tol
    turn = min(turn_rate * QUIET.step_period, QUIET.max_turn)
    np.testing.assert_allclose((np.diff(yaws) + np.pi) % (2 * np.pi) - np.pi, turn, atol=1e-5)


def test_zmp_stays_in_the_sole_between_landings():
    """The ZMP of the executed motion, c - c'' / omega^2, in the support foot's frame, stays
    within 2 mm of the QP's box (which holds at the sample ends; the held jerk moves the ZMP in
    between, by up to 1.1 mm here), except in the first sub-step after a landing (the support
    switches there)."""
    states = _roll(jnp.float64, (0.1, 0.0), 0.3, QUIET, 200)
    omega2 = 9.81 / QUIET.com_height
    zmp = states.com - states.com_acc / omega2 - states.support
    c, s = np.cos(states.support_yaw), np.sin(states.support_yaw)
    local = np.stack([c * zmp[:, 0] + s * zmp[:, 1], -s * zmp[:, 0] + c * zmp[:, 1]], -1)
    settled = states.phase > DT + 1e-6
    con = gait.step_constraints(QUIET)
    assert np.all(np.abs(local[settled, 0]) <= con.zmp_half_length + 2e-3)
    assert np.all(np.abs(local[settled, 1]) <= con.zmp_half_width + 2e-3)


def test_noisy_preview_qp_gait_stays_balanced_and_stops():
    """With the execution noise, the CoM stays over its feet; after a stop the robot finishes
    its step, stands, and the CoM settles between the feet."""
    states = _roll(jnp.float32, (0.08, 0.03), 0.2, gait.GaitParams(), 240, 160)
    assert np.all(np.isfinite(states.com))
    assert np.max(np.linalg.norm(states.com - states.support, axis=-1)) < 0.1
    assert states.standing[-1] and not states.standing[150]
    mid = 0.5 * (states.support[-1] + states.swing_target[-1])
    assert np.linalg.norm(states.com[-1] - mid) < 0.005


def test_the_solve_schedule_is_the_gaits_own():
    """Passing `gait.solve_schedule` as ``solve`` (which lets ``lax.cond`` skip the solves in
    between) changes nothing: float64 trajectories agree to rounding, stop included. (In
    float32 the QP's conditioning amplifies the two programs' different rounding.)"""
    a = _roll(jnp.float64, (0.08, 0.03), 0.2, gait.GaitParams(), 120, 90, False)
    b = _roll(jnp.float64, (0.08, 0.03), 0.2, gait.GaitParams(), 120, 90, True)
    np.testing.assert_allclose(a.com, b.com, atol=1e-9)
    np.testing.assert_allclose(a.swing_target, b.swing_target, atol=1e-9)
    assert np.ptp(a.com[:, 0]) > 0.1


def test_planner_option():
    assert gait.preview_planner(None) is None
    assert gait.preview_planner("dcm") is None
    assert gait.preview_planner("preview-qp") == walking_mpc.PreviewConfig()
    custom = walking_mpc.PreviewConfig(iterations=20)
    assert gait.preview_planner(custom) is custom
    with pytest.raises(ValueError, match="unknown planner 'herdt'"):
        gait.preview_planner("herdt")
    assert gait.solve_schedule(4, DT, "dcm") is None
    assert bool(gait.solve_schedule(4, DT, "preview-qp")) and not bool(
        gait.solve_schedule(5, DT, "preview-qp"))
    with pytest.raises(ValueError, match="multiple of the sub-step"):
        gait.solve_schedule(0, 0.03, "preview-qp")
    # The DCM planner's state carries no QP warm start.
    assert gait.init(jnp.zeros(3)).warm.shape == (0,)
    assert gait.init(jnp.zeros(3), planner="preview-qp").warm.shape == (24,)
