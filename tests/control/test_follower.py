"""Seed 004 follower-point law (eq. 9) on a unicycle: Lemma 1, limits, singularity, safety stop.

References: the error dynamics are differentiated independently with `jax.jvp` through the
unicycle and person kinematics (eq. 8 must become eq. 10); the continuous closed loop is
integrated by scipy's `solve_ivp` and compared with the closed form
:math:`\\|\\tilde p(t)\\| = \\|\\tilde p(0)\\| e^{-kt}` (:math:`k_1 = k_2 = k`) and with the
Lyapunov bounds :math:`e^{-k_{max} t} \\le \\|\\tilde p(t)\\| / \\|\\tilde p(0)\\| \\le
e^{-k_{min} t}` (:math:`k_1 \\ne k_2`).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from jaxtrack import geometry
from jaxtrack.control import follower

INF = math.inf
S = np.array([[0.0, -1.0], [1.0, 0.0]])


def free_params(k1=1.0, k2=1.0, point="A", dtype=None):
    return follower.Params.create(k1=k1, k2=k2, point=point, v_max=INF, omega_max=INF,
                                  a_max=INF, alpha_max=INF, dtype=dtype)


def world_control(params, pose, person, vel, prev, dt, obstacles=None, obstacle_mask=None,
                  **kw):
    """The law (robot frame) for a robot at ``pose`` and a person and obstacles given in the
    world frame."""
    rel = geometry.to_frame(pose, person)
    v = None if vel is None else geometry.rotate(-pose[2], vel)
    obs = None if obstacles is None else geometry.to_frame(pose, obstacles)
    return follower.control(params, rel, v, prev, dt, obs, obstacle_mask, **kw)


control = jax.jit(world_control, static_argnames=("stop_mode",))
control_free = jax.jit(lambda p, pose, x, v: world_control(p, pose, x, v, None, 0.1))
control_prev = jax.jit(lambda p, pose, x, v, prev, dt: world_control(p, pose, x, v, prev, dt))
follow = jax.jit(follower.follow)


def p_tilde(pose, person, point):
    c, s = jnp.cos(pose[2]), jnp.sin(pose[2])
    rt = jnp.array([[c, s], [-s, c]])
    return rt @ (pose[:2] + rt.T @ point - person)


@jax.jit
def error_rate(params, pose, person, person_vel):
    """(p~, d p~/dt under the commanded u, u) by forward-mode differentiation of eqs. 6-7."""
    u = world_control(params, pose, person, person_vel, None, 0.1)
    pose_dot = jnp.array([u[0] * jnp.cos(pose[2]), u[0] * jnp.sin(pose[2]), u[1]])
    p, p_dot = jax.jvp(lambda a, b: p_tilde(a, b, params.point), (pose, person),
                       (pose_dot, person_vel))
    return p, p_dot, u


@pytest.mark.parametrize("dtype,tol", [(jnp.float64, 1e-10), (jnp.float32, 2e-5)])
def test_commanded_error_dynamics_are_eq10(dtype, tol):
    rng = np.random.default_rng(0)
    for point in ["A", "B", (0.7, -0.4), (-1.0, 0.5)]:
        k1, k2 = rng.uniform(0.3, 3.0, 2)
        params = free_params(k1, k2, point, dtype)
        pose = jnp.asarray(rng.uniform([-2, -2, -np.pi], [2, 2, np.pi]), dtype)
        person = jnp.asarray(rng.uniform(-3, 3, 2), dtype)
        vel = jnp.asarray(rng.normal(size=2), dtype)
        p, p_dot, u = error_rate(params, pose, person, vel)
        p, p_dot, w = np.asarray(p, float), np.asarray(p_dot, float), float(u[1])
        expected = -w * S @ p - np.diag([k1, k2]) @ p
        np.testing.assert_allclose(p_dot, expected, atol=tol * (1 + np.abs(expected).max()))


@jax.jit
def closed_loop_rhs(params, t, pose, person0, person_vel):
    person = person0 + person_vel * t
    u = world_control(params, pose, person, person_vel, None, 0.1)
    return jnp.array([u[0] * jnp.cos(pose[2]), u[0] * jnp.sin(pose[2]), u[1]])


p_tilde_path = jax.jit(jax.vmap(p_tilde, in_axes=(0, 0, None)))


def closed_loop(params, pose0, person0, person_vel, t_end):
    """Continuous closed loop integrated by solve_ivp; returns t, p~(t) [T, 2]."""
    person0, pv = jnp.asarray(person0, float), jnp.asarray(person_vel, float)
    t_eval = np.linspace(0.0, t_end, 41)
    sol = solve_ivp(lambda t, y: np.asarray(closed_loop_rhs(params, t, jnp.asarray(y), person0,
                                                            pv)),
                    (0.0, t_end), np.asarray(pose0, float), t_eval=t_eval, rtol=1e-9,
                    atol=1e-11)
    assert sol.success
    people = np.asarray(person0) + np.outer(sol.t, np.asarray(pv))
    return sol.t, np.asarray(p_tilde_path(jnp.asarray(sol.y.T), jnp.asarray(people),
                                          params.point))


STARTS = [((0.0, 0.0, 0.0), (3.0, 1.0)), ((1.0, -2.0, 2.5), (-1.0, 0.5)),
          ((-1.0, 1.0, -1.2), (0.5, 3.0))]


@pytest.mark.parametrize("person_vel", [(0.0, 0.0), (0.8, -0.3)])
@pytest.mark.parametrize("point", ["A", "B"])
def test_lemma1_error_decays_exactly_at_rate_k(point, person_vel):
    k = 0.9
    params = free_params(k, k, point)
    for pose0, person0 in STARTS:
        t, errs = closed_loop(params, pose0, person0, person_vel, 4.0)
        norms = np.linalg.norm(errs, axis=1)
        np.testing.assert_allclose(norms, norms[0] * np.exp(-k * t), rtol=1e-5)
        assert norms[-1] < 0.05 * norms[0]


def test_lemma1_unequal_gains_stay_within_lyapunov_bounds():
    k1, k2 = 0.5, 2.0
    params = free_params(k1, k2, "B")
    for pose0, person0 in STARTS:
        t, errs = closed_loop(params, pose0, person0, (0.6, 0.4), 5.0)
        ratio = np.linalg.norm(errs, axis=1) / np.linalg.norm(errs[0])
        assert np.all(ratio <= np.exp(-k1 * t) * (1 + 1e-6))
        assert np.all(ratio >= np.exp(-k2 * t) * (1 - 1e-6))
        assert ratio[-1] < np.exp(-k1 * 5.0) * 1.0001


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_discrete_loop_with_limits_converges_for_points_a_and_b(dtype):
    dt, steps = 0.05, 300
    t = np.arange(steps) * dt
    for point in ["A", "B"]:
        params = follower.Params.create(k1=1.0, k2=1.0, point=point, dtype=dtype)
        for pose0, person0 in STARTS:
            walk = np.asarray(person0) + np.outer(t, [0.7, 0.2])
            vel = np.tile([0.7, 0.2], (steps, 1))
            res = follow(params, jnp.asarray(pose0, dtype), jnp.asarray(walk, dtype),
                         jnp.asarray(vel, dtype), dt)
            norms = np.linalg.norm(np.asarray(res.errors, float), axis=1)
            assert np.all(np.isfinite(norms))
            assert norms[-1] < 1e-3
            # Once unsaturated, the zero-order-hold loop decays at nearly k = 1 /s (slower
            # than eq. 10 by O(omega dt) while the robot still turns).
            window = (t >= 3.0) & (t <= 9.0)
            rate = -np.polyfit(t[window], np.log(norms[window]), 1)[0]
            assert 0.75 < rate < 1.1
            u = np.asarray(res.commands, float)
            assert np.all(np.abs(u[:, 0]) <= 2.0 * (1 + 1e-6))
            assert np.all(np.abs(u[:, 1]) <= 2.0 * (1 + 1e-6))
            du = np.diff(np.vstack([np.zeros(2), u]), axis=0)
            assert np.all(np.abs(du[:, 0]) <= 1.5 * dt * (1 + 1e-5))
            assert np.all(np.abs(du[:, 1]) <= 3.0 * dt * (1 + 1e-5))


control_free_batch = jax.jit(jax.vmap(control_free, in_axes=(None, 0, 0, 0)))
control_prev_batch = jax.jit(jax.vmap(control_prev, in_axes=(None, 0, 0, 0, 0, None)))


def test_limits_hold_and_keep_the_curvature_of_the_law():
    rng = np.random.default_rng(1)
    params = follower.Params.create(k1=2.0, k2=2.0, point="B", v_max=0.8, omega_max=0.6,
                                    a_max=0.5, alpha_max=0.7)
    free = free_params(2.0, 2.0, "B")
    dt, n = 0.1, 64
    pose = jnp.asarray(rng.uniform([-2, -2, -np.pi], [2, 2, np.pi], (n, 3)))
    person = jnp.asarray(rng.uniform(-3, 3, (n, 2)))
    vel = jnp.asarray(rng.normal(size=(n, 2)))
    prev = rng.uniform([-0.8, -0.6], [0.8, 0.6], (n, 2))
    u_free = np.asarray(control_free_batch(free, pose, person, vel))
    u_vel = np.asarray(control_free_batch(params, pose, person, vel))
    u = np.asarray(control_prev_batch(params, pose, person, vel, jnp.asarray(prev), dt))
    assert np.all(np.abs(u[:, 0]) <= 0.8 + 1e-12) and np.all(np.abs(u[:, 1]) <= 0.6 + 1e-12)
    assert np.all(np.abs(u[:, 0] - prev[:, 0]) <= 0.5 * dt + 1e-12)
    assert np.all(np.abs(u[:, 1] - prev[:, 1]) <= 0.7 * dt + 1e-12)
    # velocity limits scale the law's command as a whole: same direction in (v, omega)
    np.testing.assert_allclose(u_vel[:, 0] * u_free[:, 1], u_vel[:, 1] * u_free[:, 0],
                               atol=1e-12)
    assert np.all(np.linalg.norm(u_vel, axis=1) <= np.linalg.norm(u_free, axis=1) + 1e-12)
    # the random states do exercise every limit
    assert np.any(np.abs(u_vel[:, 0]) > 0.8 - 1e-9) and np.any(np.abs(u_vel[:, 1]) > 0.6 - 1e-9)
    assert np.any(np.abs(u[:, 0] - prev[:, 0]) > 0.05 - 1e-9)
    assert np.any(np.abs(u[:, 1] - prev[:, 1]) > 0.07 - 1e-9)
    # Inside the limits the command is the law's.
    near = jnp.array([[0.0, 0.0, 0.0]]), jnp.array([[1.05, 0.98]]), jnp.zeros((1, 2))
    inside = np.asarray(control_free_batch(free, *near))
    assert np.all(np.abs(inside) < [0.8, 0.6])
    np.testing.assert_allclose(control_free_batch(params, *near), inside, rtol=1e-12)


control_fwd_batch = jax.jit(jax.vmap(
    lambda p, pose, x, v: world_control(p, pose, x, v, None, 0.1, reverse=False),
    in_axes=(None, 0, 0, 0)))


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_forward_only_robot_turns_on_the_spot_instead_of_backing_up(dtype):
    rng = np.random.default_rng(7)
    k2, w_max = 1.3, 2.0
    params = follower.Params.create(k1=0.9, k2=k2, point="A", v_max=1.5, omega_max=w_max,
                                    a_max=INF, alpha_max=INF, dtype=dtype)
    free = free_params(0.9, k2, "A", dtype)
    n = 256
    pose = jnp.asarray(rng.uniform([-2, -2, -np.pi], [2, 2, np.pi], (n, 3)), dtype)
    person = jnp.asarray(rng.uniform(-4, 4, (n, 2)), dtype)
    vel = jnp.asarray(0.3 * rng.normal(size=(n, 2)), dtype)
    law = np.asarray(control_free_batch(free, pose, person, vel), float)
    both = np.asarray(control_free_batch(params, pose, person, vel), float)
    fwd = np.asarray(control_fwd_batch(params, pose, person, vel), float)
    tol = 1e-5 if dtype == jnp.float32 else 1e-12
    ahead = law[:, 0] >= 0
    assert 20 < ahead.sum() < n - 20
    # A law that drives forward is untouched.
    np.testing.assert_allclose(fwd[ahead], both[ahead], rtol=tol, atol=tol)
    # A law that backs up: v = 0, and a turn not shrunk by the backward speed.
    p = np.asarray(pose, float)
    rel = person - p[:, :2]
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    x, y = c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]
    expect = np.where(x >= 0, law[:, 1], k2 * np.arctan2(y, x))
    expect = np.clip(expect, -w_max, w_max)
    np.testing.assert_allclose(fwd[~ahead, 0], 0.0, atol=tol)
    np.testing.assert_allclose(fwd[~ahead, 1], expect[~ahead], rtol=10 * tol, atol=10 * tol)
    # Behind the robot the law's own turn is far smaller: the case the rule exists for.
    behind = ~ahead & (x < 0) & (np.abs(np.arctan2(y, x)) > 2.0)
    assert behind.sum() > 5
    assert np.all(np.abs(fwd[behind, 1]) >= np.minimum(k2 * 2.0, w_max) - tol)
    # Clipping v at 0 after the limits (what the rule replaces) turned at a fraction of this.
    assert np.all(np.abs(fwd[behind, 1]) >= np.abs(both[behind, 1]) - tol)
    assert np.median(np.abs(both[behind, 1])) < 0.4 * w_max


def test_singular_follower_point_raises_when_static_and_is_regularised_when_traced():
    with pytest.raises(ValueError, match="P_fm1 = 0"):
        follower.Params.create(point=(0.0, 1.0))
    singular = free_params(point="A")._replace(point=jnp.array([0.0, 1.0]))
    with pytest.raises(ValueError, match="P_fm1 = 0"):
        follower.control(singular, jnp.array([1.0, 1.0]), None, None, 0.1)
    u = np.asarray(control_free(singular, jnp.zeros(3), jnp.array([1.0, 2.0]), jnp.zeros(2)))
    assert np.all(np.isfinite(u))
    # |omega| <= 0.74 |b_2| / eps with b = K p~ - R^T x_r_dot = (-1, -1), eps = 1 cm
    assert abs(u[1]) <= 0.74 / 1e-2
    x = np.linspace(-0.1, 0.1, 2001)
    inv = np.array([float(control_free(singular._replace(point=jnp.array([xi, 0.0])),
                                       jnp.zeros(3), jnp.array([xi, 1.0]), jnp.zeros(2))[1])
                    for xi in x[::50]])
    assert np.all(np.abs(inv) <= 0.74 / 1e-2) and np.all(np.isfinite(inv))
    grad = jax.grad(lambda pt: jnp.sum(control_free(singular._replace(point=pt), jnp.zeros(3),
                                                    jnp.array([1.0, 2.0]), jnp.zeros(2)) ** 2))
    assert np.all(np.isfinite(grad(jnp.array([0.0, 1.0]))))
    # Away from the singularity (|P_fm1| >= 5 eps) the command is eq. 9's.
    params = free_params(point=(0.5, 0.3))
    pose, person = jnp.array([0.2, -0.1, 0.4]), jnp.array([2.0, 1.0])
    u = np.asarray(control_free(params, pose, person, jnp.zeros(2)))
    p = np.asarray(p_tilde(pose, person, params.point))
    m = np.array([[1.0, -0.3], [0.0, 0.5]])
    exact = -np.linalg.solve(m, p)
    np.testing.assert_allclose(u, exact, rtol=1e-10)


def test_safety_stop_halts_or_rotates_for_anything_within_30_cm():
    params = follower.Params.create(point="A")
    pose = jnp.array([1.0, 2.0, 0.7])
    person, vel = jnp.array([3.0, 3.5]), jnp.array([0.3, 0.1])
    u_go = np.asarray(control(params, pose, person, vel, None, 0.1))
    assert np.linalg.norm(u_go) > 0.1
    near = jnp.array([[1.0 + 0.29 * np.cos(2.0), 2.0 + 0.29 * np.sin(2.0)], [9.0, 9.0]])
    far = jnp.array([[1.31, 2.0], [9.0, 9.0]])
    np.testing.assert_array_equal(control(params, pose, person, vel, None, 0.1, near), 0.0)
    rot = np.asarray(control(params, pose, person, vel, None, 0.1, near, stop_mode="rotate"))
    assert rot[0] == 0.0 and rot[1] == pytest.approx(u_go[1])
    np.testing.assert_allclose(control(params, pose, person, vel, None, 0.1, far), u_go)
    masked = jnp.array([False, True])
    np.testing.assert_allclose(control(params, pose, person, vel, None, 0.1, near, masked), u_go)
    np.testing.assert_allclose(control(params, pose, person, vel, None, 0.1, near,
                                       stop_mode="none"), u_go)
    assert bool(follower.safety_stop(geometry.to_frame(pose, near)))
    assert not bool(follower.safety_stop(geometry.to_frame(pose, far)))
    # The law itself takes the person relative to the robot, in its frame (numpy reference).
    c, s = np.cos(0.7), np.sin(0.7)
    rt = np.array([[c, s], [-s, c]])
    rel_person = jnp.asarray(rt @ (np.asarray(person) - [1.0, 2.0]))
    rel_vel = jnp.asarray(rt @ np.asarray(vel))
    np.testing.assert_allclose(follower.control(params, rel_person, rel_vel, None, 0.1), u_go,
                               atol=1e-12)
    assert bool(follower.safety_stop(jnp.array([[0.2, -0.2]])))


def loss(log_k, dtype=jnp.float64):
    params = follower.Params.create(point="B", dtype=dtype)._replace(log_k1=log_k[0],
                                                                     log_k2=log_k[1])
    steps, dt = 60, 0.05
    t = jnp.arange(steps, dtype=dtype) * dt
    walk = jnp.stack([2.0 + 0.8 * t, 1.5 + 0.3 * jnp.sin(t)], -1)
    vel = jnp.stack([0.8 + 0 * t, 0.3 * jnp.cos(t)], -1)
    res = follower.follow(params, jnp.asarray([0.0, 0.0, 0.5], dtype), walk, vel, dt)
    return jnp.mean(jnp.sum(res.errors ** 2, -1))


loss_and_grad = jax.jit(jax.value_and_grad(loss), static_argnums=1)


def test_gradients_wrt_gains_match_finite_differences():
    x = jnp.log(jnp.array([0.7, 1.3]))
    _, g = loss_and_grad(x)
    g = np.asarray(g)
    h = 1e-5
    fd = [(float(loss_and_grad(x.at[i].add(h))[0]) - float(loss_and_grad(x.at[i].add(-h))[0]))
          / (2 * h) for i in range(2)]
    np.testing.assert_allclose(g, fd, rtol=1e-4)
    assert np.all(g < 0)  # larger gains, smaller mean error here


def test_non_finite_inputs_inside_jit_give_a_zero_command():
    params = follower.Params.create()
    u = jax.jit(follower.control, static_argnames=('stop_mode',))(
        params, jnp.array([jnp.nan, 1.0]), None, None, 0.1)
    np.testing.assert_array_equal(u, 0.0)


def test_unicycle_step_is_the_exact_arc():
    pose = jnp.array([0.5, -0.2, 0.3])
    for v, w in [(1.0, 0.0), (0.7, 1.5), (-0.4, -2.0), (0.0, 1.0)]:
        nxt = np.asarray(follower.unicycle_step(pose, jnp.array([v, w]), 0.4))
        sol = solve_ivp(lambda t, y: [v * np.cos(y[2]), v * np.sin(y[2]), w], (0, 0.4),
                        np.asarray(pose), rtol=1e-11, atol=1e-12)
        np.testing.assert_allclose(nxt, sol.y[:, -1], atol=1e-9)


def test_bad_input_raises_clear_errors():
    params = follower.Params.create()
    pose, person = jnp.zeros(3), jnp.ones(2)
    with pytest.raises(ValueError, match="unknown follower point"):
        follower.Params.create(point="C")
    with pytest.raises(ValueError, match="k1 must be > 0"):
        follower.Params.create(k1=0.0)
    with pytest.raises(ValueError, match="v_max must be > 0"):
        follower.Params.create(v_max=-1.0)
    with pytest.raises(ValueError, match="point must have shape"):
        follower.Params.create(point=(1.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="person_pos must have shape"):
        follower.control(params, jnp.zeros(3), None, None, 0.1)
    with pytest.raises(ValueError, match="person_pos contains NaN"):
        follower.control(params, jnp.array([np.nan, 0.0]), None, None, 0.1)
    with pytest.raises(ValueError, match="person_vel must have shape"):
        follower.control(params, person, jnp.zeros(3), None, 0.1)
    with pytest.raises(ValueError, match="dt must be > 0"):
        follower.control(params, person, None, jnp.zeros(2), 0.0)
    with pytest.raises(ValueError, match="unknown stop_mode"):
        follower.control(params, person, None, None, 0.1, stop_mode="brake")
    with pytest.raises(ValueError, match="obstacles must have shape"):
        follower.control(params, person, None, None, 0.1, jnp.zeros(4))
    with pytest.raises(ValueError, match="obstacle_mask must have shape"):
        follower.control(params, person, None, None, 0.1, jnp.zeros((4, 2)),
                         jnp.ones(3, bool))
    with pytest.raises(TypeError, match="obstacle_mask must be bool"):
        follower.control(params, person, None, None, 0.1, jnp.zeros((4, 2)), jnp.ones(4))
    with pytest.raises(TypeError, match="follower.Params"):
        follower.control((1.0, 1.0), person, None, None, 0.1)
    with pytest.raises(ValueError, match=r"person_vel must have shape \[3, 2\]"):
        follower.follow(params, pose, jnp.zeros((3, 2)), jnp.zeros((4, 2)), 0.1)
