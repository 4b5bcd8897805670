r"""Motion models on the ground plane, returning what the filters take.

Linear models return ``(F, Q)`` for `jaxtrack.filters.kalman`; nonlinear ones return
``(f, Q)`` (or ``f``) for `jaxtrack.filters.ekf` / `jaxtrack.filters.ukf`. State orderings:

- constant velocity: ``[p_x, p_y, v_x, v_y]``
- constant acceleration: ``[p_x, p_y, v_x, v_y, a_x, a_y]``
- coordinated turn: ``[p_x, p_y, v, heading, turn_rate]``
- unicycle: ``[p_x, p_y, heading]`` with control ``[v, omega]``
- person relative to robot (seed 002): ``[p_x, p_y, v_x, v_y, v_rx, v_ry]`` in the robot frame.

Noise intensities are spectral densities of continuous white noise (units of the driving
derivative squared per second), discretised exactly for the linear models.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import _checks

Array = jax.Array

__all__ = ["constant_velocity", "constant_acceleration", "coordinated_turn", "unicycle",
           "person_relative", "person_relative_transition"]


def _kron2(block):
    return jnp.kron(block, jnp.eye(2, dtype=block.dtype))


def _float(x):
    x = jnp.asarray(x)
    return x if jnp.issubdtype(x.dtype, jnp.floating) else x.astype(jnp.result_type(float))


def _check_positive(**values) -> None:
    """Concrete values must be finite and > 0 (dt), or >= 0 (noise densities, ``q*`` names)."""
    for name, v in values.items():
        if not _checks.is_concrete(v):
            continue
        a = np.asarray(v, np.float64)
        ok = np.all(np.isfinite(a)) and (np.all(a >= 0) if name.startswith("q") else
                                         np.all(a > 0))
        if not ok:
            bound = ">= 0" if name.startswith("q") else "> 0"
            raise ValueError(f"{name} must be finite and {bound}; got {v!r}")


def constant_velocity(dt, q) -> tuple[Array, Array]:
    r"""Nearly-constant-velocity model in 2-D (continuous white-noise acceleration).

    .. math::
        F = \begin{bmatrix} I & \Delta t I \\ 0 & I \end{bmatrix},\quad
        Q = q \begin{bmatrix} \Delta t^3/3\, I & \Delta t^2/2\, I \\ \Delta t^2/2\, I & \Delta t\, I
        \end{bmatrix}.

    Args:
      dt: time step (s). q: acceleration spectral density (m^2/s^3); may be traced (tunable).

    Returns:
      ``(F [4, 4], Q [4, 4])`` for state ``[p_x, p_y, v_x, v_y]``.

    Example:
      >>> F, Q = constant_velocity(0.1, 1.0)
    """
    _check_positive(dt=dt, q=q)
    dt = _float(dt)
    F = _kron2(jnp.array([[1.0, dt], [0.0, 1.0]], dtype=dt.dtype))
    Q = q * _kron2(jnp.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]], dtype=dt.dtype))
    return F, Q


def constant_acceleration(dt, q) -> tuple[Array, Array]:
    r"""Nearly-constant-acceleration model in 2-D (continuous white-noise jerk).

    .. math::
        F = \begin{bmatrix} I & \Delta t I & \Delta t^2/2\, I \\ 0 & I & \Delta t I \\ 0 & 0 & I
        \end{bmatrix},\quad
        Q = q \begin{bmatrix} \Delta t^5/20 & \Delta t^4/8 & \Delta t^3/6 \\ \Delta t^4/8 &
        \Delta t^3/3 & \Delta t^2/2 \\ \Delta t^3/6 & \Delta t^2/2 & \Delta t \end{bmatrix}
        \otimes I.

    Returns:
      ``(F [6, 6], Q [6, 6])`` for state ``[p_x, p_y, v_x, v_y, a_x, a_y]``.

    Example:
      >>> F, Q = constant_acceleration(0.1, 0.5)
    """
    _check_positive(dt=dt, q=q)
    dt = _float(dt)
    F = _kron2(jnp.array([[1.0, dt, dt**2 / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]], dtype=dt.dtype))
    Q = q * _kron2(jnp.array([[dt**5 / 20, dt**4 / 8, dt**3 / 6],
                              [dt**4 / 8, dt**3 / 3, dt**2 / 2],
                              [dt**3 / 6, dt**2 / 2, dt]], dtype=dt.dtype))
    return F, Q


def _arc(v, heading, turn, dt):
    """Displacement of constant speed ``v`` and turn rate over ``dt`` (exact, smooth at 0).

    Uses (sin(h + w dt) - sin h) / w = dt cos(h + w dt / 2) sinc(w dt / 2), likewise for cos,
    which has no 0/0 at w = 0 and finite gradients there.
    """
    half = 0.5 * turn * dt
    chord = v * dt * jnp.sinc(half / jnp.pi)
    mid = heading + half
    return chord * jnp.cos(mid), chord * jnp.sin(mid)


def coordinated_turn(dt, q_accel=1.0, q_turn=0.1) -> tuple[Callable, Array]:
    r"""Coordinated-turn model with polar velocity (constant speed and turn rate).

    .. math::
        p' = p + v\,\Delta t\,\mathrm{sinc}(\omega \Delta t / 2)
        [\cos(\theta + \omega\Delta t/2), \sin(\theta + \omega\Delta t/2)],\;
        v' = v,\; \theta' = \theta + \omega \Delta t,\; \omega' = \omega.

    The heading is not wrapped by ``f`` (sigma points around +-pi stay continuous); wrap it
    for display with `jaxtrack.angles.wrap`. Noise: white acceleration along the path
    (``q_accel``) and white turn acceleration (``q_turn``), with the along-track position
    variance approximated isotropically (:math:`q_a \Delta t^3/3`).

    Returns:
      ``(f, Q [5, 5])`` with ``f(x [5]) -> [5]`` for ``[p_x, p_y, v, heading, turn_rate]``.

    Example:
      >>> f, Q = coordinated_turn(0.1)
      >>> f(jnp.array([0.0, 0.0, 1.0, 0.0, 0.5]))
    """
    dt_ = _float(dt)

    def f(x):
        dx, dy = _arc(x[2], x[3], x[4], dt_)
        return jnp.stack([x[0] + dx, x[1] + dy, x[2], x[3] + x[4] * dt_, x[4]])

    d = dt_
    Q = jnp.zeros((5, 5), d.dtype)
    Q = Q.at[0, 0].set(q_accel * d**3 / 3).at[1, 1].set(q_accel * d**3 / 3)
    Q = Q.at[2, 2].set(q_accel * d)
    Q = Q.at[3, 3].set(q_turn * d**3 / 3).at[3, 4].set(q_turn * d**2 / 2)
    Q = Q.at[4, 3].set(q_turn * d**2 / 2).at[4, 4].set(q_turn * d)
    return f, Q


def unicycle(dt) -> Callable:
    r"""Unicycle kinematics integrated exactly for constant ``u = [v, omega]`` over ``dt``.

    .. math::
        p' = p + v\,\Delta t\,\mathrm{sinc}(\omega\Delta t/2)[\cos(\theta+\omega\Delta t/2),
        \sin(\theta+\omega\Delta t/2)],\; \theta' = \mathrm{wrap}(\theta + \omega\Delta t).

    Returns:
      ``f(x [3], u [2]) -> [3]`` for state ``[p_x, p_y, heading]``.

    Example:
      >>> f = unicycle(0.05)
      >>> f(jnp.zeros(3), jnp.array([1.0, 0.2]))
    """
    from jaxtrack.angles import wrap

    dt_ = _float(dt)

    def f(x, u):
        dx, dy = _arc(u[0], x[2], u[1], dt_)
        return jnp.stack([x[0] + dx, x[1] + dy, wrap(x[2] + u[1] * dt_)])

    return f


def person_relative_transition(dt, turn_rate=0.0, *, as_printed: bool = False) -> Array:
    r"""Transition of seed 002's person-relative-to-robot model (Svenstrup et al., eqs. 4-11).

    State ``[p_x, p_y, v_x, v_y, v_rx, v_ry]`` in the robot frame (person position, person
    velocity, robot velocity). Eqs. 4-5 give :math:`p(k+1) = p(k) + T(v(k) - v_r(k))`; the
    odometry-driven input of eq. 11 adds :math:`T\hat{\dot\psi}\,[p_y, -p_x]` to the position
    (the robot turning by :math:`\dot\psi` turns the person the other way in the robot frame),
    which is linear in the state, so it is folded into the matrix:

    .. math::
        F = \Phi + T\hat{\dot\psi} \begin{bmatrix} 0 & 1 \\ -1 & 0 \end{bmatrix}_{p,p}.

    The printed eq. 6 also has :math:`T` at :math:`(v_x, v_{rx})` and :math:`(v_y, v_{ry})`,
    which eqs. 4-5 do not imply and which would make the person accelerate with the robot; it is
    treated as a typo. ``as_printed=True`` reproduces the printed matrix exactly.

    Args:
      dt: sampling time T (s).
      turn_rate: robot rotation rate from odometry (rad/s); scalar, or [K] to get [K, 6, 6]
        (for ``kalman.filter(..., time_varying=("F",))``).
      as_printed: use eq. 6 exactly as printed.

    Returns:
      ``F`` [6, 6] (or [K, 6, 6]).

    Example:
      >>> F = person_relative_transition(0.1, turn_rate=0.3)
    """
    dt_ = _float(dt)
    phi = np.eye(6)
    phi_t = np.zeros((6, 6))
    phi_t[0, 2] = phi_t[1, 3] = 1.0
    phi_t[0, 4] = phi_t[1, 5] = -1.0
    if as_printed:
        phi_t[2, 4] = phi_t[3, 5] = 1.0
    rot = np.zeros((6, 6))
    rot[0, 1], rot[1, 0] = 1.0, -1.0
    rate = jnp.asarray(turn_rate, dt_.dtype)
    base = jnp.asarray(phi, dt_.dtype) + dt_ * jnp.asarray(phi_t, dt_.dtype)
    return base + (dt_ * rate)[..., None, None] * jnp.asarray(rot, dt_.dtype)


def person_relative(dt, turn_rate=0.0, q_person=0.5, q_robot=0.5, *,
                    as_printed: bool = False) -> tuple[Array, Array]:
    r"""Seed 002 model: ``(F, Q)`` with F from `person_relative_transition`.

    Q is the discrete white-noise-acceleration covariance :math:`Q = G\,\mathrm{diag}(q_p, q_p,
    q_r, q_r)\,G^T`, where a person acceleration moves the person by :math:`T^2/2` and its
    velocity by :math:`T`, and a robot acceleration moves the person by :math:`-T^2/2` (relative
    position) and the robot velocity by :math:`T`.

    Args:
      dt: T (s); turn_rate: robot rotation rate (rad/s), scalar or [K];
      q_person, q_robot: acceleration variances (m^2/s^4).

    Returns:
      ``(F [6, 6] or [K, 6, 6], Q [6, 6])``.

    Example:
      >>> F, Q = person_relative(0.1, turn_rate=0.2)
    """
    F = person_relative_transition(dt, turn_rate, as_printed=as_printed)
    dt_ = _float(dt)
    a, b = dt_**2 / 2, dt_
    zero = jnp.zeros_like(dt_)
    G = jnp.array([[a, zero, -a, zero],
                   [zero, a, zero, -a],
                   [b, zero, zero, zero],
                   [zero, b, zero, zero],
                   [zero, zero, b, zero],
                   [zero, zero, zero, b]], dtype=dt_.dtype)
    qd = jnp.stack([q_person, q_person, q_robot, q_robot]).astype(dt_.dtype)
    Q = (G * qd) @ G.T
    return F, Q
