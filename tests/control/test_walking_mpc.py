"""The preview-QP walking pattern generator (Herdt et al. 2010): prediction matrices against a
direct simulation, the plan's constraints (ZMP in the sole, footsteps in the region placed
and rotated by the heading), optimality against scipy, and a model-predictive walk."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize

from jaxtrack.control import walking_mpc as wm

H_COM = 0.25
CFG = wm.PreviewConfig()
CON = wm.StepConstraints()
M_STEPS = wm.num_steps(CFG, CON.step_period)
OMEGA = math.sqrt(9.81 / H_COM)


def _simulate(c0, jerks, T):
    """Cart-table states after each constant-jerk sample (numpy, float64)."""
    c, out = np.array(c0, float), []
    for j in jerks:
        c = np.array([c[0] + c[1] * T + c[2] * T * T / 2 + j * T ** 3 / 6,
                      c[1] + c[2] * T + j * T * T / 2, c[2] + j * T])
        out.append(c)
    return np.array(out)


def test_preview_matrices_match_simulation():
    rng = np.random.default_rng(0)
    mats = wm.preview_matrices(0.1, 7, H_COM)
    c0, jerks = rng.normal(size=3), rng.normal(size=7)
    states = _simulate(c0, jerks, 0.1)
    np.testing.assert_allclose(mats["Pps"] @ c0 + mats["Ppu"] @ jerks, states[:, 0], atol=1e-12)
    np.testing.assert_allclose(mats["Pvs"] @ c0 + mats["Pvu"] @ jerks, states[:, 1], atol=1e-12)
    zmp = states[:, 0] - H_COM / 9.81 * states[:, 2]
    np.testing.assert_allclose(mats["Pzs"] @ c0 + mats["Pzu"] @ jerks, zmp, atol=1e-12)


@pytest.mark.parametrize("phase, first_on_next_foot", [(0.0, 5), (0.05, 4), (0.25, 2),
                                                       (0.45, 0)])
def test_support_index(phase, first_on_next_foot):
    k = np.asarray(wm.support_index(jnp.asarray(phase), CFG, 0.5))
    t = np.arange(1, CFG.horizon + 1) * CFG.sample_period
    np.testing.assert_array_equal(k, np.floor((phase + t) / 0.5 - 1e-6).astype(int))
    assert np.argmax(k > 0) == first_on_next_foot
    assert k.max() <= M_STEPS


def test_num_steps():
    assert wm.num_steps(CFG, 0.5) == 2
    assert wm.num_steps(wm.PreviewConfig(horizon=16), 0.5) == 4
    assert wm.num_steps(wm.PreviewConfig(horizon=15), 0.5) == 3


def _orbit_state(dtype):
    """Mid-step of the in-place periodic orbit: left foot at +5 cm in support, the CoM at the
    origin moving towards it, the ZMP on the support foot."""
    u = 0.05 * OMEGA * math.tanh(0.5 * OMEGA * 0.5)
    com = jnp.zeros((3, 2), dtype).at[1, 1].set(u).at[2, 1].set(-OMEGA ** 2 * 0.05)
    return com, jnp.asarray([0.0, 0.05], dtype), jnp.asarray(1.0, dtype)


_plan = jax.jit(wm.plan, static_argnames=("com_height", "config", "constraints"))


def _turning_plan(dtype=jnp.float64, phase=0.3, yaw0=0.4, turn=0.25):
    com, support, side = _orbit_state(dtype)
    t = jnp.arange(1, CFG.horizon + 1, dtype=dtype) * CFG.sample_period
    theta = yaw0 + turn * (phase + t) / 0.5
    vref = 0.1 * jnp.stack([jnp.cos(theta), jnp.sin(theta)], -1)
    yaws = yaw0 + turn * jnp.arange(1, M_STEPS + 1, dtype=dtype)
    return _plan(com, support, jnp.asarray(yaw0, dtype), side, jnp.asarray(phase, dtype),
                 yaws, vref, com_height=H_COM, config=wm.PreviewConfig(iterations=40),
                 constraints=CON), (com, support, yaw0, yaws, vref, phase)


def _rot(a):
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_footsteps_respect_the_heading_constraints(dtype):
    p, (com, support, yaw0, yaws, _, _) = _turning_plan(dtype)
    tol = 1e-6 if dtype == jnp.float64 else 1e-4
    feet = np.vstack([np.asarray(support, float), np.asarray(p.footsteps, float)])
    all_yaws = np.concatenate([[yaw0], np.asarray(yaws, float)])
    sides = np.asarray(1.0) * (-1.0) ** np.arange(len(feet))       # support is the left foot
    for i in range(1, len(feet)):
        local = _rot(all_yaws[i - 1]).T @ (feet[i] - feet[i - 1])  # in the previous foot's frame
        assert abs(local[0]) <= CON.max_stride + tol
        assert CON.min_lateral - tol <= sides[i] * local[1] <= CON.max_lateral + tol
    # The ZMP of every sample is inside the sole of the foot then in support, in its frame.
    k = np.asarray(p.support)
    for j in range(CFG.horizon):
        local = _rot(all_yaws[k[j]]).T @ (np.asarray(p.zmp[j], float) - feet[k[j]])
        assert abs(local[0]) <= CON.zmp_half_length + tol
        assert abs(local[1]) <= CON.zmp_half_width + tol
    np.testing.assert_allclose(np.asarray(p.zmp_local), np.asarray(
        [_rot(all_yaws[k[j]]).T @ (np.asarray(p.zmp[j]) - feet[k[j]])
         for j in range(CFG.horizon)]), atol=tol)


def test_plan_is_consistent_with_the_cart_table_model():
    p, (com, *_rest) = _turning_plan()
    c0 = np.asarray(com, float)
    for axis in range(2):
        states = _simulate(c0[:, axis], np.asarray(p.jerk[:, axis]), CFG.sample_period)
        np.testing.assert_allclose(np.asarray(p.com[:, axis]), states[:, 0], atol=1e-9)
        np.testing.assert_allclose(np.asarray(p.zmp[:, axis]),
                                   states[:, 0] - H_COM / 9.81 * states[:, 2], atol=1e-9)


def test_plan_is_the_optimum_of_herdts_cost():
    """scipy minimises the same cost, written from a direct simulation of the jerks, over the
    same bounded variables; the plan's cost is no higher, from scipy's start or from the
    plan's."""
    p, (com, support, yaw0, yaws, vref, phase) = _turning_plan()
    N, m, T = CFG.horizon, M_STEPS, CFG.sample_period
    c0 = np.asarray(com, float)
    all_yaws = np.concatenate([[yaw0], np.asarray(yaws, float)])
    k = np.floor((phase + np.arange(1, N + 1) * T) / 0.5 - 1e-6).astype(int)
    # Jerk -> (position, velocity, ZMP) by simulating unit jerks (independent of the module).
    basis = np.stack([_simulate([0, 0, 0], np.eye(N)[i], T) for i in range(N)], -1)  # [N,3,N]
    free = _simulate(c0[:, 0], np.zeros(N), T), _simulate(c0[:, 1], np.zeros(N), T)
    zmp_of_jerk = basis[:, 0] - H_COM / 9.81 * basis[:, 2]
    sides = (-1.0) ** np.arange(1, m + 1)
    nominal = np.stack([np.zeros(m), sides * 0.5 * (CON.min_lateral + CON.max_lateral)], -1)

    def unpack(u):
        d = np.stack([u[:N], u[N:2 * N]], -1)
        delta = np.stack([u[2 * N:2 * N + m], u[2 * N + m:]], -1)
        return d, delta

    def cost(u):
        d, delta = unpack(u)
        feet = [np.asarray(support, float)]
        for i in range(m):
            feet.append(feet[-1] + _rot(all_yaws[i]) @ delta[i])
        zmp = np.array([feet[k[j]] + _rot(all_yaws[k[j]]) @ d[j] for j in range(N)])
        total = 0.0
        for a in range(2):
            z_free = free[a][:, 0] - H_COM / 9.81 * free[a][:, 2]
            jerk = np.linalg.solve(zmp_of_jerk, zmp[:, a] - z_free)
            vel = free[a][:, 1] + basis[:, 1] @ jerk
            total += (0.5 * CFG.jerk_weight * jerk @ jerk
                      + 0.5 * CFG.velocity_weight * np.sum((vel - np.asarray(vref)[:, a]) ** 2))
        return (total + 0.5 * CFG.zmp_weight * np.sum(d * d)
                + 0.5 * CFG.step_weight * np.sum((delta - nominal) ** 2))

    lat = [(CON.min_lateral, CON.max_lateral) if s > 0 else (-CON.max_lateral, -CON.min_lateral)
           for s in sides]
    bounds = ([(-CON.zmp_half_length, CON.zmp_half_length)] * N
              + [(-CON.zmp_half_width, CON.zmp_half_width)] * N
              + [(-CON.max_stride, CON.max_stride)] * m + lat)
    x0 = np.array([0.5 * (lo + hi) for lo, hi in bounds])
    ref = scipy.optimize.minimize(cost, x0, bounds=bounds, method="L-BFGS-B",
                                  options=dict(ftol=1e-15, gtol=1e-12, maxiter=20000))
    ours = np.concatenate([np.asarray(p.zmp_local).T.ravel(), np.asarray(p.steps_local).T.ravel()])
    assert cost(ours) <= ref.fun + 1e-9 * max(1.0, abs(ref.fun))
    # The problem is ill-conditioned (scipy stops short from the box's centre), so also start
    # scipy at the plan: it finds nothing lower.
    again = scipy.optimize.minimize(cost, ours, bounds=bounds, method="L-BFGS-B",
                                    options=dict(ftol=1e-15, gtol=1e-12, maxiter=20000))
    assert again.fun >= cost(ours) - 1e-9 * max(1.0, abs(ref.fun))
    assert float(p.solution.residual) < 1e-8


def test_plan_is_differentiable():
    """d(first jerk)/d(reference speed) against central differences (float64)."""
    com, support, side = _orbit_state(jnp.float64)

    def first_jerk(speed):
        vref = jnp.stack([jnp.full(CFG.horizon, speed), jnp.zeros(CFG.horizon)], -1)
        p = wm.plan(com, support, 0.0, side, 0.2, jnp.zeros(M_STEPS), vref, H_COM,
                    wm.PreviewConfig(iterations=40), CON)
        return p.jerk[0, 0] + p.footsteps[0, 0]

    g = jax.jit(jax.grad(first_jerk))(0.08)
    f = jax.jit(first_jerk)
    h = 1e-5
    fd = (f(0.08 + h) - f(0.08 - h)) / (2 * h)
    assert abs(float(fd)) > 1e-3
    np.testing.assert_allclose(float(g), float(fd), rtol=1e-4)


def _walk(dtype, velocity, num_ticks=200, dt=0.05):
    """A model-predictive walk: the QP is solved every ``dt`` from the cart-table state, its
    first jerk applied for ``dt``; the swing foot lands on the plan's next footstep."""
    vel = jnp.asarray(velocity, dtype)

    def tick(state, _):
        com, support, side, phase, warm = state
        vref = jnp.broadcast_to(vel, (CFG.horizon, 2))
        p = wm.plan(com, support, 0.0, side, phase, jnp.zeros(M_STEPS, dtype), vref, H_COM,
                    CFG, CON, warm)
        j = p.jerk[0]
        com = jnp.stack([com[0] + com[1] * dt + com[2] * dt ** 2 / 2 + j * dt ** 3 / 6,
                         com[1] + com[2] * dt + j * dt ** 2 / 2, com[2] + j * dt])
        phase = phase + dt
        switch = phase >= CON.step_period - 1e-6
        support = jnp.where(switch, p.footsteps[0], support)
        return ((com, support, jnp.where(switch, -side, side), jnp.where(switch, 0.0, phase),
                 p.solution), (com[0], com[1], p.zmp_local[0], p.solution.residual))

    com, support, side = _orbit_state(dtype)
    first = wm.plan(com, support, 0.0, side, 0.0, jnp.zeros(M_STEPS, dtype),
                    jnp.broadcast_to(vel, (CFG.horizon, 2)), H_COM,
                    wm.PreviewConfig(iterations=40), CON)
    state = (com, support, side, jnp.zeros((), dtype), first.solution)
    return jax.lax.scan(tick, state, None, length=num_ticks)[1]


_walk_jit = jax.jit(_walk, static_argnums=(0,))


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
@pytest.mark.parametrize("velocity", [(0.1, 0.0), (-0.05, 0.0), (0.0, 0.0)])
def test_model_predictive_walk_tracks_the_reference(dtype, velocity):
    pos, vel, zmp_local, residual = map(np.asarray, _walk_jit(dtype, velocity))
    half = len(pos) // 2
    mean_velocity = (pos[-1] - pos[-101]) / (100 * 0.05)        # the last ten step cycles
    # float64 walks 2.0 % under the reference (the ZMP-centring weight pulls against it);
    # float32 3.8 % over it (its solves stop about 2e-3 from the optimum:
    # docs/humanoid_preview_qp.md).
    tol = (0.03 if dtype == jnp.float64 else 0.06) * abs(velocity[0]) + 1e-4
    np.testing.assert_allclose(mean_velocity, velocity, atol=tol)
    # The lateral sway stays bounded (the in-place orbit's is about +-2.5 cm).
    assert np.ptp(pos[half:, 1]) < 0.06
    # Every plan keeps its ZMP in the sole.
    assert np.all(np.abs(zmp_local[:, 0]) <= CON.zmp_half_length + 1e-4)
    assert np.all(np.abs(zmp_local[:, 1]) <= CON.zmp_half_width + 1e-4)
    assert np.median(residual) < 1e-2


def test_vmap_equals_single_plans():
    com, support, side = _orbit_state(jnp.float64)
    speeds = jnp.asarray([0.0, 0.05, 0.1])

    def one(speed):
        vref = jnp.stack([jnp.full(CFG.horizon, speed), jnp.zeros(CFG.horizon)], -1)
        return wm.plan(com, support, 0.0, side, 0.1, jnp.zeros(M_STEPS), vref, H_COM, CFG,
                       CON).footsteps

    batched = jax.jit(jax.vmap(one))(speeds)
    for i, s in enumerate(speeds):
        np.testing.assert_allclose(np.asarray(batched[i]), np.asarray(jax.jit(one)(s)),
                                   atol=1e-12)
