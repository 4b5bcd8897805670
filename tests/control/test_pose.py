"""Seed 000 reach controller (Algorithm 1) with the 5 cm / 10 deg latched stop.

The reference closed loop is integrated in numpy (x += x_dot dt, theta += theta_dot dt) around
the jitted `step`; the control law itself is checked against Algorithm 1 written out by hand.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.control import pose

DT = 0.25           # the seed's ~4 Hz
STEPS = 140         # the seed reports 110-120 frames per task
LIMITS = pose.PoseLimits()
TASKS = np.asarray(pose.seed_tasks(jnp.float64))

step = jax.jit(pose.step)
reference_velocity = jax.jit(pose.reference_velocity)
reach = jax.jit(pose.reach, static_argnames=("num_steps", "smooth"))
reach_all = jax.jit(jax.vmap(lambda t, g: pose.reach(jnp.zeros(3, t.dtype), t, g, LIMITS, DT,
                                                      STEPS), in_axes=(0, None)))


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def numpy_loop(target, params=pose.PoseGains(), steps=STEPS):
    """Closed loop with the jitted `step` and numpy integration; returns poses, commands."""
    p = np.zeros(3)
    state = pose.init()
    poses, cmds = [p.copy()], []
    for _ in range(steps):
        state, cmd = step(state, p, target, params, LIMITS)
        v, w = np.asarray(cmd.velocity), float(cmd.turn_rate)
        p = np.array([p[0] + v[0] * DT, p[1] + v[1] * DT, wrap(p[2] + w * DT)])
        poses.append(p.copy())
        cmds.append((v, w, np.asarray(cmd.body_velocity), bool(cmd.stopped)))
    return np.array(poses), cmds


def test_seed_tasks_are_fifteen_targets_one_metre_away():
    assert TASKS.shape == (15, 3)
    np.testing.assert_allclose(np.linalg.norm(TASKS[:, :2], axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.rad2deg(TASKS[:5, 2]), [-90, -45, 0, 45, 90], atol=1e-12)
    assert len({tuple(np.round(t, 6)) for t in TASKS}) == 15


@pytest.fixture(scope="module")
def loops():
    return [numpy_loop(t) for t in TASKS]


def test_every_seed_task_stops_within_5_cm_and_10_deg_in_bounded_steps(loops):
    for target, (poses, cmds) in zip(TASKS, loops):
        stopped = np.array([c[3] for c in cmds])
        assert stopped.any()
        k = int(np.argmax(stopped))          # first stopped step
        assert 100 <= k <= 125               # the seed: 110-120 frames
        final = poses[-1]
        assert np.linalg.norm(final[:2] - target[:2]) <= 0.05
        assert abs(wrap(final[2] - target[2])) <= math.radians(10.0)
        np.testing.assert_array_equal(poses[k:], np.repeat(poses[k:k + 1], len(poses) - k, 0))


def test_vmapped_scan_over_tasks_equals_the_python_loop(loops):
    res = reach_all(jnp.asarray(TASKS), pose.PoseGains())
    for i, (poses, cmds) in enumerate(loops):
        np.testing.assert_allclose(res.poses[i], poses, atol=1e-12)
        np.testing.assert_array_equal(res.commands.stopped[i], [c[3] for c in cmds])
        assert int(res.steps_to_stop[i]) == int(np.argmax([c[3] for c in cmds]))


def test_commands_equal_algorithm_1_when_unsaturated():
    p = np.array([0.3, -0.2, math.radians(170.0)])
    t = np.array([0.5, 0.1, math.radians(-170.0)])
    params = pose.pose_gains(0.2, 0.5)
    v, w = reference_velocity(p, t, params, LIMITS)
    np.testing.assert_allclose(v, -0.2 * (p[:2] - t[:2]), atol=1e-12)
    # The heading error is -20 deg across the cut, not 340 deg: turn left.
    np.testing.assert_allclose(w, -0.5 * math.radians(-20.0), atol=1e-12)
    _, cmd = step(pose.init(), p, t, params, LIMITS)
    c, s = math.cos(p[2]), math.sin(p[2])
    body = np.array([[c, s], [-s, c]]) @ np.asarray(v)
    np.testing.assert_allclose(cmd.body_velocity, body, atol=1e-12)


def test_saturation_keeps_direction_and_respects_the_limits():
    params = pose.pose_gains(5.0, 5.0)
    rng = np.random.default_rng(0)
    for _ in range(20):
        p = np.concatenate([rng.uniform(-2, 2, 2), rng.uniform(-np.pi, np.pi, 1)])
        t = np.concatenate([rng.uniform(-2, 2, 2), rng.uniform(-np.pi, np.pi, 1)])
        _, cmd = step(pose.init(), p, t, params, LIMITS)
        v = np.asarray(cmd.velocity)
        e = t[:2] - p[:2]
        want_speed = min(5.0 * np.linalg.norm(e), LIMITS.max_speed)
        np.testing.assert_allclose(np.linalg.norm(v), want_speed, rtol=1e-12)
        np.testing.assert_allclose(v / np.linalg.norm(v), e / np.linalg.norm(e), atol=1e-12)
        assert abs(float(cmd.turn_rate)) <= LIMITS.max_turn_rate + 1e-15
        np.testing.assert_allclose(np.linalg.norm(cmd.body_velocity), np.linalg.norm(v))


def test_rollout_commands_stay_within_the_limits(loops):
    res = reach_all(jnp.asarray(TASKS), pose.pose_gains(1.0, 2.0))
    speed = np.linalg.norm(np.asarray(res.commands.velocity), axis=-1)
    assert speed.max() <= LIMITS.max_speed * (1 + 1e-12)
    assert np.abs(res.commands.turn_rate).max() <= LIMITS.max_turn_rate * (1 + 1e-12)
    assert speed.max() > 0.99 * LIMITS.max_speed  # the limit is actually reached
    assert np.all(res.commands.stopped[:, -1])


def test_stop_is_latched():
    target = np.array([1.0, 0.0, 0.0])
    state, cmd = step(pose.init(), np.array([0.97, 0.01, 0.1]), target, pose.PoseGains(), LIMITS)
    assert bool(state.stopped) and bool(cmd.stopped)
    np.testing.assert_array_equal(cmd.velocity, 0.0)
    assert float(cmd.turn_rate) == 0.0
    # Pushed out of the stop region (walking in place, tracker noise): still stopped.
    state, cmd = step(state, np.array([0.5, 0.3, 1.0]), target, pose.PoseGains(), LIMITS)
    assert bool(state.stopped)
    np.testing.assert_array_equal(cmd.velocity, 0.0)
    # Position inside but heading 12 deg off: keeps turning, not stopped.
    state, cmd = step(pose.init(), np.array([0.99, 0.0, math.radians(12.0)]), target,
                      pose.PoseGains(), LIMITS)
    assert not bool(state.stopped) and float(cmd.turn_rate) < 0


def test_stop_pose_decides_the_stop_and_pose_the_command():
    """With ``stop_pose`` (e.g. a sway-averaged estimate) the stop region is tested on it, while
    the command still follows ``pose``; the smooth gate does the same."""
    target = np.array([1.0, 0.0, 0.0])
    swaying = np.array([0.97, 0.01, 0.05])       # inside, at a sway extreme
    average = np.array([0.96, 0.04, 0.05])       # the step-cycle mean: 5.7 cm away
    state, cmd = step(pose.init(), swaying, target, pose.PoseGains(), LIMITS, average)
    assert not bool(state.stopped)
    want_v, want_w = reference_velocity(swaying, target, pose.PoseGains(), LIMITS)
    np.testing.assert_allclose(cmd.velocity, want_v, rtol=1e-12)
    np.testing.assert_allclose(cmd.turn_rate, want_w, rtol=1e-12)
    state, cmd = step(pose.init(), average, target, pose.PoseGains(), LIMITS, swaying)
    assert bool(state.stopped)
    np.testing.assert_array_equal(cmd.velocity, 0.0)
    # Without it, the stop is tested on ``pose`` as before.
    state, _ = step(pose.init(), swaying, target, pose.PoseGains(), LIMITS, None)
    assert bool(state.stopped)
    smooth_state, _ = pose.smooth_step(pose.smooth_init(), swaying, target, stop_pose=average)
    np.testing.assert_allclose(1.0 - smooth_state.moving,
                               pose.stop_probability(average, target), rtol=1e-12)
    # A NaN stop pose inside jit gives a zero command, like a NaN pose.
    state, cmd = step(pose.init(), swaying, target, pose.PoseGains(), LIMITS,
                      jnp.array([jnp.nan, 0.0, 0.0]))
    assert not bool(state.stopped)
    np.testing.assert_array_equal(cmd.velocity, 0.0)
    with pytest.raises(ValueError, match="stop_pose"):
        pose.step(pose.init(), swaying, target, stop_pose=np.zeros(2))


def test_nan_and_bad_inputs_raise_at_the_boundary():
    good = np.zeros(3)
    with pytest.raises(ValueError, match="target"):
        pose.step(pose.init(), good, np.array([1.0, np.nan, 0.0]))
    with pytest.raises(ValueError, match="pose"):
        pose.step(pose.init(), np.array([np.inf, 0.0, 0.0]), good)
    with pytest.raises(ValueError, match="target"):
        pose.reach(good, np.array([np.nan, 0.0, 0.0]))
    with pytest.raises(ValueError, match="target"):
        pose.step(pose.init(), good, np.zeros(2))
    with pytest.raises(ValueError, match="max_speed"):
        pose.step(pose.init(), good, good, limits=pose.PoseLimits(max_speed=-0.1))
    with pytest.raises(ValueError, match="lambda_x"):
        pose.pose_gains(0.0, 1.0)
    with pytest.raises(TypeError, match="ReachState"):
        pose.step(pose.SmoothReachState(1.0), good, good)


def test_nan_pose_inside_jit_gives_zero_command_and_keeps_the_state():
    state, cmd = step(pose.init(), jnp.array([jnp.nan, 0.0, 0.0]), jnp.array([1.0, 0.0, 0.0]),
                      pose.PoseGains(), LIMITS)
    assert not bool(state.stopped)
    np.testing.assert_array_equal(cmd.velocity, 0.0)
    assert float(cmd.turn_rate) == 0.0


def test_float32_rollouts_match_float64():
    res32 = reach_all(jnp.asarray(TASKS, jnp.float32), pose.PoseGains())
    res64 = reach_all(jnp.asarray(TASKS), pose.PoseGains())
    assert res32.poses.dtype == jnp.float32 and res32.commands.velocity.dtype == jnp.float32
    np.testing.assert_allclose(res32.poses, res64.poses, atol=1e-5)
    assert np.abs(np.asarray(res32.steps_to_stop) - np.asarray(res64.steps_to_stop)).max() <= 1


def test_gains_round_trip_and_defaults():
    g = pose.gains(pose.pose_gains(0.3, 0.7))
    np.testing.assert_allclose([g.lambda_x, g.lambda_theta], [0.3, 0.7], rtol=1e-12)
    d = pose.gains(pose.PoseGains())
    np.testing.assert_allclose([d.lambda_x, d.lambda_theta], [0.1, 0.2], rtol=1e-12)


def test_smooth_stop_tends_to_the_hard_stop():
    target = jnp.asarray(TASKS[8])
    hard = reach(jnp.zeros(3), target, pose.PoseGains(), LIMITS, DT, num_steps=STEPS)
    soft = reach(jnp.zeros(3), target, pose.PoseGains(), LIMITS, DT, num_steps=STEPS,
                 smooth=True, distance_softness=1e-6, angle_softness=1e-6)
    np.testing.assert_allclose(soft.poses, hard.poses, atol=1e-9)
    np.testing.assert_allclose(soft.commands.stopped, hard.commands.stopped, atol=1e-9)
    np.testing.assert_allclose(soft.steps_to_stop, hard.steps_to_stop, atol=1e-6)


def test_stop_probability_is_the_logistic_jitter_probability():
    t = np.array([1.0, 0.0, 0.0])
    p = np.array([0.96, 0.0, math.radians(9.0)])
    got = float(pose.stop_probability(p, t, LIMITS, 0.01, math.radians(2.0)))
    want = 1 / (1 + np.exp(-(0.05 - 0.04) / 0.01)) / (1 + np.exp(-(1.0) / 2.0))
    np.testing.assert_allclose(got, want, rtol=1e-12)
    inside = bool(pose.in_stop_region(p, t, LIMITS))
    assert inside and float(pose.stop_probability(p, t, LIMITS, 1e-6, 1e-6)) == 1.0


def test_smooth_rollout_gradient_in_the_log_gains_matches_finite_differences():
    target = jnp.asarray(TASKS[13])

    def loss(params):
        res = pose.reach(jnp.zeros(3), target, params, LIMITS, DT, 80, smooth=True,
                         distance_softness=0.01, angle_softness=math.radians(2.0))
        final = res.poses[-1]
        return (jnp.sum((final[:2] - target[:2]) ** 2) + (final[2] - target[2]) ** 2
                + 1e-3 * res.steps_to_stop)

    params = pose.pose_gains(0.15, 0.3)
    value_and_grad = jax.jit(jax.value_and_grad(loss))
    f = jax.jit(loss)
    _, g = value_and_grad(params)
    h = 1e-6
    for name in params._fields:
        up = params._replace(**{name: getattr(params, name) + h})
        down = params._replace(**{name: getattr(params, name) - h})
        fd = (f(up) - f(down)) / (2 * h)
        assert np.isfinite(getattr(g, name))
        np.testing.assert_allclose(getattr(g, name), fd, rtol=1e-4, atol=1e-8)
    assert float(g.log_lambda_x) < 0  # faster position gain: closer at the horizon
