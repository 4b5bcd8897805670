"""Motion models against independent references: Van Loan discretisation, ODE integration."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from jaxtrack.filters import kalman
from jaxtrack.models import measurement, motion


def van_loan(A, G, q, dt):
    """Discretise dx = A x dt + G dW (spectral density q) exactly: returns (F, Q)."""
    n = A.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -A
    M[:n, n:] = q * G @ G.T
    M[n:, n:] = A.T
    E = expm(M * dt)
    F = E[n:, n:].T
    return F, F @ E[:n, n:]


@pytest.mark.parametrize("dt,q", [(0.1, 1.0), (0.033, 0.2), (1.0, 3.0)])
def test_constant_velocity_equals_van_loan_discretisation(dt, q):
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    G = np.zeros((4, 2))
    G[2, 0] = G[3, 1] = 1.0
    F_ref, Q_ref = van_loan(A, G, q, dt)
    F, Q = motion.constant_velocity(dt, q)
    np.testing.assert_allclose(F, F_ref, atol=1e-12)
    np.testing.assert_allclose(Q, Q_ref, rtol=1e-9, atol=1e-14)


@pytest.mark.parametrize("dt,q", [(0.1, 1.0), (0.5, 0.3)])
def test_constant_acceleration_equals_van_loan_discretisation(dt, q):
    A = np.zeros((6, 6))
    A[0, 2] = A[1, 3] = A[2, 4] = A[3, 5] = 1.0
    G = np.zeros((6, 2))
    G[4, 0] = G[5, 1] = 1.0
    F_ref, Q_ref = van_loan(A, G, q, dt)
    F, Q = motion.constant_acceleration(dt, q)
    np.testing.assert_allclose(F, F_ref, atol=1e-12)
    np.testing.assert_allclose(Q, Q_ref, rtol=1e-9, atol=1e-15)


def _integrate_turn(x, dt):
    """Integrate p' = v [cos h, sin h], h' = w with scipy."""
    def rhs(_, s):
        return [s[2] * np.cos(s[3]), s[2] * np.sin(s[3]), 0.0, s[4], 0.0]
    sol = solve_ivp(rhs, (0.0, dt), np.asarray(x, float), rtol=1e-11, atol=1e-12)
    return sol.y[:, -1]


@pytest.mark.parametrize("turn", [0.0, 1e-9, 0.7, -2.5])
def test_coordinated_turn_equals_ode_integration(turn):
    f, Q = motion.coordinated_turn(0.4)
    x = np.array([1.0, -2.0, 1.3, 2.9, turn])
    np.testing.assert_allclose(f(jnp.asarray(x)), _integrate_turn(x, 0.4), atol=1e-8)
    assert np.min(np.linalg.eigvalsh(np.asarray(Q))) >= 0.0


def test_coordinated_turn_has_finite_jacobian_at_zero_turn_rate():
    f, _ = motion.coordinated_turn(0.1)
    J = jax.jacfwd(f)(jnp.array([0.0, 0.0, 1.0, 0.3, 0.0]))
    assert np.all(np.isfinite(J))
    # d p_x / d turn_rate at w = 0 is -v dt^2 sin(h) / 2
    np.testing.assert_allclose(J[0, 4], -1.0 * 0.1**2 * np.sin(0.3) / 2, rtol=1e-9)


def test_unicycle_equals_ode_integration_and_wraps_heading():
    f = motion.unicycle(0.5)
    x = np.array([0.5, 0.2, 3.0])
    u = np.array([0.8, 1.2])
    ref = _integrate_turn(np.array([x[0], x[1], u[0], x[2], u[1]]), 0.5)
    out = np.asarray(f(jnp.asarray(x), jnp.asarray(u)))
    np.testing.assert_allclose(out[:2], ref[:2], atol=1e-8)
    assert -np.pi <= out[2] < np.pi
    np.testing.assert_allclose(np.cos(out[2]), np.cos(ref[3]), atol=1e-10)
    np.testing.assert_allclose(np.sin(out[2]), np.sin(ref[3]), atol=1e-10)


# --- Seed 002 (Svenstrup et al.): person relative to the robot ---------------------------------

def paper_phi(T):
    """Eq. 6 exactly as printed."""
    return np.array([[1, 0, T, 0, -T, 0],
                     [0, 1, 0, T, 0, -T],
                     [0, 0, 1, 0, T, 0],
                     [0, 0, 0, 1, 0, T],
                     [0, 0, 0, 0, 1, 0],
                     [0, 0, 0, 0, 0, 1]], float)


def paper_h():
    """Eq. 7."""
    return np.array([[1, 0, 0, 0, 0, 0],
                     [0, 1, 0, 0, 0, 0],
                     [0, 0, 0, 0, 1, 0],
                     [0, 0, 0, 0, 0, 1]], float)


@pytest.mark.parametrize("T", [0.1, 0.25])
def test_person_relative_matrices_equal_the_paper(T):
    np.testing.assert_array_equal(motion.person_relative_transition(T, as_printed=True),
                                  paper_phi(T))
    np.testing.assert_array_equal(measurement.person_relative(), paper_h())
    # The default differs from the printed eq. 6 only in the two velocity-coupling entries
    # that eqs. 4-5 do not imply.
    diff = np.asarray(motion.person_relative_transition(T)) - paper_phi(T)
    expected = np.zeros((6, 6))
    expected[2, 4] = expected[3, 5] = -T
    np.testing.assert_allclose(diff, expected, atol=1e-15)


def test_person_relative_turn_input_equals_eq_11():
    T, rate = 0.1, 0.4
    x = np.array([2.0, -0.5, 0.3, 0.1, 0.2, 0.0])
    F = np.asarray(motion.person_relative_transition(T, rate))
    gamma_u = np.array([x[1], -x[0], 0, 0, 0, 0]) * T * rate
    np.testing.assert_allclose(F @ x, np.asarray(motion.person_relative_transition(T)) @ x
                               + gamma_u, atol=1e-14)
    Fs = motion.person_relative_transition(T, jnp.array([0.0, rate]))
    assert Fs.shape == (2, 6, 6)
    np.testing.assert_allclose(Fs[1], F, atol=1e-15)
    _, Q = motion.person_relative(T, rate)
    assert np.min(np.linalg.eigvalsh(np.asarray(Q))) > -1e-15
    np.testing.assert_allclose(Q, np.asarray(Q).T, atol=0)


def _robot_turning_episode(T_steps=300, dt=0.1, turn=0.3, v_robot=0.4, seed=0):
    """A person walks straight in the world while the robot drives on a circle.

    Returns measurements (person position in the robot frame + noise, robot velocity in the
    robot frame from odometry + noise), odometry turn rates and the true relative positions.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(1, T_steps + 1) * dt
    person = np.stack([1.5 + 0.8 * t * np.cos(0.5), 0.5 + 0.8 * t * np.sin(0.5)], -1)
    yaw = turn * t
    # robot position: integrate unicycle with constant v, w
    robot = np.stack([v_robot / turn * np.sin(yaw), v_robot / turn * (1 - np.cos(yaw))], -1)
    d = person - robot
    c, s = np.cos(yaw), np.sin(yaw)
    rel = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], -1)
    z = np.concatenate([rel + 0.05 * rng.standard_normal(rel.shape),
                        np.stack([np.full(T_steps, v_robot), np.zeros(T_steps)], -1)
                        + 0.02 * rng.standard_normal((T_steps, 2))], -1)
    rates = turn + 0.01 * rng.standard_normal(T_steps)
    return z, rates, rel


def test_person_walking_straight_while_robot_turns_is_tracked_in_robot_frame():
    dt = 0.1
    z, rates, rel = _robot_turning_episode(dt=dt)
    H = measurement.person_relative()
    R = np.diag([0.05**2, 0.05**2, 0.02**2, 0.02**2])
    init = kalman.Gaussian(jnp.array([z[0, 0], z[0, 1], 0.0, 0.0, 0.4, 0.0]), jnp.eye(6))
    rmse = {}
    for name, r in (("with_turn_input", rates), ("without", np.zeros_like(rates))):
        F, Q = motion.person_relative(dt, jnp.asarray(r), q_person=0.5, q_robot=0.5)
        res = kalman.filter(init, jnp.asarray(z), F, Q, H, jnp.asarray(R),
                            time_varying=("F",))
        err = np.asarray(res.means[50:, :2]) - rel[50:]
        rmse[name] = float(np.sqrt(np.mean(np.sum(err**2, -1))))
    # Position noise is 0.05 m per axis (0.07 m radial): filtering must do better than that,
    # and the odometry-driven rotation input of eq. 11 must help when the robot turns.
    assert rmse["with_turn_input"] < 0.06
    assert rmse["with_turn_input"] < 0.8 * rmse["without"]


@pytest.mark.parametrize("model", [motion.constant_velocity, motion.constant_acceleration])
@pytest.mark.parametrize("dt, q, message", [(0.1, -0.5, "q must be"), (0.0, 1.0, "dt must be"),
                                            (0.1, float("nan"), "q must be"),
                                            (float("inf"), 1.0, "dt must be")])
def test_negative_noise_and_bad_time_steps_are_refused(model, dt, q, message):
    with pytest.raises(ValueError, match=message):
        model(dt, q)
    F, Q = model(0.1, 0.0)  # zero noise is a valid (deterministic) model
    assert np.all(np.linalg.eigvalsh(np.asarray(Q)) >= -1e-15)
