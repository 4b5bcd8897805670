r"""Unicycle person following with a follower point (seed 004, section IV, Lemma 1).

The robot :math:`(x_m, \theta_m)` drives with :math:`u = (v, \omega)`. Its follower point is
:math:`x_f = x_m + R(\theta_m) P_{fm}`; the error to the person :math:`x_r` is
:math:`\tilde x = x_f - x_r` in the world frame (eq. 6) and :math:`\tilde p = R(\theta_m)^T
\tilde x` in the robot frame (eq. 7), with dynamics (eq. 8)

.. math::
    \dot{\tilde p} = -\omega S \tilde p + M u - R(\theta_m)^T \dot x_r, \qquad
    M = \begin{bmatrix} 1 & -P_{fm,2} \\ 0 & P_{fm,1} \end{bmatrix}, \quad
    S = \begin{bmatrix} 0 & -1 \\ 1 & 0 \end{bmatrix}.

The law (eq. 9) :math:`u = -M^{-1} [K \tilde p - R(\theta_m)^T \dot x_r]`,
:math:`K = \operatorname{diag}(k_1, k_2) > 0`, gives :math:`\dot{\tilde p} = -\omega S \tilde p
- K \tilde p` (eq. 10) and :math:`\frac{d}{dt}\|\tilde p\|^2 = -2 \tilde p^T K \tilde p`: the error
decays exponentially, exactly as :math:`e^{-k t}` when :math:`k_1 = k_2 = k` (Lemma 1).

What the seed leaves open and we chose:

- Limits. :math:`|v| \le v_{max}`, :math:`|\omega| \le \omega_{max}` and, given the previous
  command, :math:`|\Delta v| \le a_{max} dt`, :math:`|\Delta\omega| \le \alpha_{max} dt`. Both are
  imposed by scaling the command (or its change) as a whole, which keeps the ratio
  :math:`v / \omega`, i.e. the curvature of the path the law asks for.
- Singularity. :math:`\det M = P_{fm,1}`. A concrete :math:`P_{fm,1} = 0` raises. For traced
  values :math:`1 / P_{fm,1}` is replaced by the smooth
  :math:`P_{fm,1} / (P_{fm,1}^2 + \epsilon^2 e^{-P_{fm,1}^2 / \epsilon^2})` (``singular_eps``
  :math:`\epsilon`, 1 cm by default): bounded by :math:`0.74 / \epsilon`, and within a relative
  :math:`(\epsilon / P_{fm,1})^2 e^{-P_{fm,1}^2 / \epsilon^2}` of the exact inverse (below
  1e-10 for :math:`|P_{fm,1}| \ge 5 \epsilon`).
- Safety stop (the seed's "behaviour" layer): if any masked obstacle point is within
  ``stop_distance`` (0.3 m) of the robot's centre, the command becomes zero (``"halt"``) or keeps
  only its turn rate (``"rotate"``), immediately, without the acceleration limit.
- Gains. The seed prints none; :math:`k_1 = k_2 = 1\ s^{-1}` by default. Limits default to a
  shopping-cart-like 2 m/s, 2 rad/s, 1.5 m/s^2, 3 rad/s^2.

Public API:

- `Params` (``Params.create(k1, k2, point, v_max, omega_max, a_max, alpha_max, stop_distance)``),
  `POINT_A`, `POINT_B`, `gains`.
- `follower_point`, `error`, `control`, `safety_stop`, `unicycle_step`, `follow` (a `lax.scan`
  closed loop under ideal unicycle kinematics).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxtrack import _checks, geometry
from jaxtrack.angles import wrap

Array = jax.Array

__all__ = ["POINT_A", "POINT_B", "Params", "FollowResult", "gains", "follower_point", "error",
           "control", "safety_stop", "unicycle_step", "follow"]

POINT_A = (1.5, 0.0)
"""Follower point A of the seed's experiments: the user 1.5 m straight ahead (section V-A)."""

POINT_B = (1.0, 1.0)
"""Follower point B of the seed's experiments: the user at 45 deg front-left (section V-A)."""

_POINTS = {"A": POINT_A, "B": POINT_B}
_STOP_MODES = ("halt", "rotate", "none")


class Params(NamedTuple):
    r"""Follower parameters (a pytree; optax steps ``log_k1``, ``log_k2`` and ``point``).

    Attributes:
      log_k1, log_k2: :math:`\log k_1, \log k_2` (1/s), the unconstrained gains of eq. 9.
      point: [2] :math:`P_{fm}`, the follower point in the robot frame (m); unconstrained
        (:math:`P_{fm,1} \neq 0` is required, see the module docstring).
      v_max: speed limit (m/s). omega_max: turn-rate limit (rad/s).
      a_max: linear acceleration limit (m/s^2). alpha_max: angular acceleration limit (rad/s^2).
        Any limit may be ``inf``.
      stop_distance: safety-stop radius around the robot's centre (m).
    """

    log_k1: Array
    log_k2: Array
    point: Array
    v_max: Array
    omega_max: Array
    a_max: Array
    alpha_max: Array
    stop_distance: Array

    @classmethod
    def create(cls, k1=1.0, k2=1.0, point="A", v_max=2.0, omega_max=2.0, a_max=1.5,
               alpha_max=3.0, stop_distance=0.3, dtype=None) -> "Params":
        """Parameters from positive gains and a follower point.

        Args:
          k1, k2: positive gains (1/s).
          point: ``"A"`` (1.5, 0), ``"B"`` (1, 1) or a [2] follower point (m).
          v_max, omega_max, a_max, alpha_max: positive limits (``inf`` for none).
          stop_distance: safety-stop radius (m), >= 0.
          dtype: float dtype of the leaves (default: JAX's default float).

        Example:
          >>> params = Params.create(k1=0.8, k2=0.8, point="B")
        """
        if isinstance(point, str):
            if point not in _POINTS:
                raise ValueError(f"unknown follower point {point!r}; expected 'A', 'B' or [2]")
            point = _POINTS[point]
        _checks.check_shape("point", point, (2,), "follower point (P_fm1, P_fm2)")
        _checks.check_finite("point", point)
        _check_point(point)
        for name, value in (("k1", k1), ("k2", k2)):
            _checks.check_finite(name, value)
            if _checks.is_concrete(value) and not np.all(np.asarray(value) > 0):
                raise ValueError(f"{name} must be > 0; got {value}")
        for name, value in (("v_max", v_max), ("omega_max", omega_max), ("a_max", a_max),
                            ("alpha_max", alpha_max)):
            if _checks.is_concrete(value) and not np.all(np.asarray(value) > 0):
                raise ValueError(f"{name} must be > 0; got {value}")
        if _checks.is_concrete(stop_distance) and not np.all(np.asarray(stop_distance) >= 0):
            raise ValueError(f"stop_distance must be >= 0; got {stop_distance}")

        def leaf(x):
            return jnp.asarray(x, dtype if dtype is not None else jnp.result_type(float))

        return cls(jnp.log(leaf(k1)), jnp.log(leaf(k2)), leaf(point), leaf(v_max),
                   leaf(omega_max), leaf(a_max), leaf(alpha_max), leaf(stop_distance))


class FollowResult(NamedTuple):
    """Output of `follow`.

    Attributes:
      poses: [T + 1, 3] robot poses, the initial one first.
      commands: [T, 2] commands (v, omega).
      errors: [T, 2] :math:`\\tilde p` (robot frame) before each command.
    """

    poses: Array
    commands: Array
    errors: Array


# ---------------------------------------------------------------------------------------------
# Public functions


def gains(params: Params) -> Array:
    """The positive gains [2] :math:`(k_1, k_2)` from ``params`` (elementwise exp).

    Example:
      >>> gains(Params.create(k1=0.5, k2=2.0))  # [0.5, 2.0]
    """
    return jnp.exp(jnp.stack([jnp.asarray(params.log_k1), jnp.asarray(params.log_k2)]))


def follower_point(robot_pose: Array, point) -> Array:
    r"""The follower point :math:`x_f = x_m + R(\theta_m) P_{fm}` [2] in the world frame.

    Args:
      robot_pose: [3] (x, y, theta). point: [2] :math:`P_{fm}` in the robot frame.

    Example:
      >>> follower_point(jnp.array([0.0, 0.0, jnp.pi / 2]), POINT_A)  # (0, 1.5)
    """
    _checks.check_shape("robot_pose", robot_pose, (3,), "(x, y, theta)")
    _checks.check_shape("point", point, (2,), "follower point")
    robot_pose = jnp.asarray(robot_pose)
    return geometry.from_frame(robot_pose, jnp.asarray(point, robot_pose.dtype))


def error(robot_pose: Array, person_pos: Array, point) -> Array:
    r"""The robot-frame error :math:`\tilde p = R(\theta_m)^T (x_f - x_r)` [2] (eqs. 6-7).

    Args:
      robot_pose: [3] (x, y, theta) in the world frame.
      person_pos: [2] the person :math:`x_r` in the world frame.
      point: [2] :math:`P_{fm}`.

    In the robot frame, with the person at :math:`p_r = R(\theta_m)^T (x_r - x_m)`, the error
    is :math:`P_{fm} - p_r`, the form `control` uses.

    Example:
      >>> error(jnp.zeros(3), jnp.array([1.5, 0.0]), POINT_A)  # (0, 0)
    """
    _checks.check_shape("robot_pose", robot_pose, (3,), "(x, y, theta)")
    _checks.check_shape("person_pos", person_pos, (2,), "(x, y)")
    _checks.check_shape("point", point, (2,), "follower point")
    dtype = jnp.result_type(jnp.asarray(robot_pose).dtype, jnp.asarray(person_pos).dtype,
                            jnp.float32)
    robot_pose = jnp.asarray(robot_pose, dtype)
    rel = geometry.to_frame(robot_pose, jnp.asarray(person_pos, dtype))
    return jnp.asarray(point, dtype) - rel


def control(params: Params, person_pos: Array, person_vel: Array | None,
            prev_u: Array | None, dt, obstacles: Array | None = None,
            obstacle_mask: Array | None = None, *, stop_mode: str = "halt", singular_eps=1e-2,
            reverse: bool = True) -> Array:
    r"""Seed 004's follower law (eq. 9) with limits and a safety stop, in the robot frame.

    :math:`u^* = -M^{-1}[K \tilde p - R(\theta_m)^T \dot x_r]` with :math:`\tilde p = P_{fm} -
    p_r`, :math:`p_r` the person relative to the robot; for a robot that does not drive
    backwards (``reverse=False``), a law asking for :math:`v < 0` gets :math:`v = 0` and a turn
    on the spot toward the person instead: :math:`\omega^*` itself while the person is in front
    of the robot's axle, :math:`k_2 \beta` (:math:`\beta` the person's bearing) when behind it,
    where :math:`\omega^*` vanishes for a person straight behind. Then scaled into
    :math:`|v| \le v_{max}, |\omega| \le \omega_{max}`, then (if ``prev_u`` is given) its change
    scaled into :math:`|\Delta v| \le a_{max} dt, |\Delta \omega| \le \alpha_{max} dt`, then
    the safety stop. Inside traced code a non-finite input gives ``u = 0`` (at the boundary, with
    concrete inputs, it raises).

    Args:
      params: `Params`.
      person_pos: [2] :math:`p_r`, the person relative to the robot, in its frame (a world
        position converts with `jaxtrack.geometry.to_frame`).
      person_vel: [2] the person's world velocity in robot axes, :math:`R(\theta_m)^T \dot x_r`
        (`jaxtrack.geometry.rotate` by minus the heading), or None for a static person.
      prev_u: [2] previous command (v, omega) for the acceleration limits, or None (no limit).
      dt: control period (s), used by the acceleration limits.
      obstacles: optional [Q, 2] points (laser returns, tracked people) in the robot frame;
        obstacle_mask: [Q] bool, which rows are real (default all).
      stop_mode: ``"halt"`` (u = 0), ``"rotate"`` (v = 0, keep omega) or ``"none"``.
      singular_eps: :math:`\epsilon` of the regularised :math:`1 / P_{fm,1}` (m).
      reverse: whether the robot may drive backwards. With ``False`` the backward speed is
        dropped before the velocity limits: clipping it after them would leave the turn scaled
        down with it, and a robot whose user had walked past it would barely turn
        (measurements: docs/design_notes.md, "Person following: forward-only turns").

    Returns:
      u: [2] (v, omega).

    Example:
      >>> params = Params.create(point="A")
      >>> u = control(params, jnp.array([2.0, 0.5]), jnp.array([1.0, 0.0]), None, 0.05)
    """
    _checks.check_options("stop_mode", stop_mode, _STOP_MODES)
    if not isinstance(params, Params):
        raise TypeError(f"params must be a follower.Params; got {type(params).__name__}")
    _checks.check_shape("person_pos", person_pos, (2,), "(x, y) relative to the robot")
    _checks.check_finite("person_pos", person_pos)
    if person_vel is not None:
        _checks.check_shape("person_vel", person_vel, (2,), "(vx, vy)")
        _checks.check_finite("person_vel", person_vel)
    if prev_u is not None:
        _checks.check_shape("prev_u", prev_u, (2,), "(v, omega)")
        _checks.check_finite("prev_u", prev_u)
        if _checks.is_concrete(dt) and not float(dt) > 0:
            raise ValueError(f"dt must be > 0; got {dt}")
    _checks.check_shape("params.point", params.point, (2,), "follower point")
    _check_point(params.point)
    obstacles, obstacle_mask = _check_obstacles(obstacles, obstacle_mask)
    if _checks.is_concrete(singular_eps) and not float(singular_eps) > 0:
        raise ValueError(f"singular_eps must be > 0; got {singular_eps}")

    dtype = jnp.result_type(jnp.asarray(person_pos).dtype, jnp.float32)
    person_pos = jnp.asarray(person_pos, dtype)
    person_vel = (jnp.zeros(2, dtype) if person_vel is None
                  else jnp.asarray(person_vel, dtype))
    valid = jnp.all(jnp.isfinite(person_pos)) & jnp.all(jnp.isfinite(person_vel))
    person_pos = jnp.where(valid, person_pos, 0.0)
    person_vel = jnp.where(valid, person_vel, 0.0)

    u = _law(params, person_pos, person_vel, singular_eps)
    if not reverse:
        u = _forward_only(params, u, person_pos)
    u = _limit_velocity(u, params)
    if prev_u is not None:
        prev = jnp.asarray(prev_u, dtype)
        prev = jnp.where(jnp.all(jnp.isfinite(prev)), prev, 0.0)
        u = _limit_acceleration(u, prev, params, jnp.asarray(dt, dtype))
        u = _limit_velocity(u, params)
    if obstacles is not None and stop_mode != "none":
        stop = _too_close(jnp.asarray(obstacles, dtype), obstacle_mask, params.stop_distance)
        keep = jnp.array([0.0, 1.0], dtype) if stop_mode == "rotate" else jnp.zeros(2, dtype)
        u = jnp.where(stop, u * keep, u)
    return jnp.where(valid, u, 0.0).astype(dtype)


def safety_stop(obstacles: Array, obstacle_mask: Array | None = None,
                stop_distance=0.3) -> Array:
    """Whether any masked obstacle point is within ``stop_distance`` of the robot (bool).

    Args:
      obstacles: [Q, 2] points in the robot frame. obstacle_mask: [Q] bool (default all).
      stop_distance: radius (m).

    Example:
      >>> safety_stop(jnp.array([[0.2, 0.1]]))  # True
    """
    obstacles, obstacle_mask = _check_obstacles(obstacles, obstacle_mask)
    obstacles = jnp.asarray(obstacles)
    return _too_close(obstacles, obstacle_mask, stop_distance)


def unicycle_step(pose: Array, u: Array, dt) -> Array:
    r"""Exact unicycle motion [3] under a constant command over ``dt`` (arc of a circle).

    :math:`\dot x = v\cos\theta,\ \dot y = v \sin\theta,\ \dot\theta = \omega`, integrated in
    closed form (:math:`\frac{\sin(\omega dt)}{\omega}` evaluated stably near
    :math:`\omega = 0`); the heading is wrapped.

    Example:
      >>> unicycle_step(jnp.zeros(3), jnp.array([1.0, 0.0]), 0.1)  # (0.1, 0, 0)
    """
    _checks.check_shape("pose", pose, (3,), "(x, y, theta)")
    _checks.check_shape("u", u, (2,), "(v, omega)")
    pose = jnp.asarray(pose)
    return _unicycle(pose, jnp.asarray(u, pose.dtype), dt)


def follow(params: Params, robot_pose0: Array, person_pos: Array, person_vel: Array, dt,
           *, singular_eps=1e-2) -> FollowResult:
    r"""Closed loop of `control` with ideal unicycle kinematics (`unicycle_step`), a `lax.scan`.

    The reference loop for tests and gain tuning: no estimator, no obstacles; the acceleration
    limits act from rest.

    Args:
      params: `Params`. robot_pose0: [3] initial pose.
      person_pos: [T, 2] person positions (world) at each control step.
      person_vel: [T, 2] person velocities (world).
      dt: control period (s).

    Returns:
      `FollowResult`.

    Example:
      >>> t = jnp.arange(100) * 0.05
      >>> walk = jnp.stack([2.0 + t, jnp.zeros_like(t)], -1)
      >>> res = follow(Params.create(), jnp.zeros(3), walk, jnp.tile(jnp.array([1.0, 0.0]),
      ...              (100, 1)), 0.05)
    """
    _checks.check_shape("robot_pose0", robot_pose0, (3,), "(x, y, theta)")
    _checks.check_shape("person_pos", person_pos, (None, 2), "[T, 2] positions")
    _checks.check_shape("person_vel", person_vel, (np.shape(person_pos)[0], 2),
                        "[T, 2] velocities")
    _checks.check_finite("robot_pose0", robot_pose0)
    _checks.check_finite("person_pos", person_pos)
    _checks.check_finite("person_vel", person_vel)
    if _checks.is_concrete(dt) and not float(dt) > 0:
        raise ValueError(f"dt must be > 0; got {dt}")
    _check_point(params.point)
    dtype = jnp.result_type(jnp.asarray(robot_pose0).dtype, jnp.asarray(person_pos).dtype,
                            jnp.float32)
    pose0 = jnp.asarray(robot_pose0, dtype)

    def body(carry, xs):
        pose, prev = carry
        p, v = xs
        rel = geometry.to_frame(pose, p)
        err = jnp.asarray(params.point, dtype) - rel
        u = control(params, rel, geometry.rotate(-pose[2], v), prev, dt,
                    singular_eps=singular_eps)
        nxt = _unicycle(pose, u, dt)
        return (nxt, u), (nxt, u, err)

    xs = (jnp.asarray(person_pos, dtype), jnp.asarray(person_vel, dtype))
    _, (poses, us, errs) = lax.scan(body, (pose0, jnp.zeros(2, dtype)), xs)
    return FollowResult(jnp.concatenate([pose0[None], poses]), us, errs)


# ---------------------------------------------------------------------------------------------
# Private helpers


def _law(params, person_pos, person_vel, singular_eps):
    dtype = person_pos.dtype
    k = gains(params).astype(dtype)
    point = jnp.asarray(params.point, dtype)
    p_tilde = point - person_pos
    b = k * p_tilde - person_vel
    p1, p2 = point[0], point[1]
    eps2 = jnp.asarray(singular_eps, dtype) ** 2
    inv_p1 = p1 / (p1 * p1 + eps2 * jnp.exp(-p1 * p1 / eps2))
    # M^{-1} = [[1, P2 / P1], [0, 1 / P1]]
    omega = -b[1] * inv_p1
    v = -b[0] - p2 * b[1] * inv_p1
    return jnp.stack([v, omega])


def _forward_only(params, u, person_pos):
    """``v < 0`` of the law replaced by a turn on the spot (see `control`)."""
    bearing = jnp.arctan2(person_pos[1], person_pos[0])
    k2 = gains(params)[1].astype(u.dtype)
    omega = jnp.where(person_pos[0] >= 0.0, u[1], k2 * bearing)
    back = u[0] < 0.0
    return jnp.stack([jnp.maximum(u[0], 0.0), jnp.where(back, omega, u[1])])


def _shrink(x, limit):
    """Factor in (0, 1] bringing |x| within ``limit`` (1 when already inside; safe for inf)."""
    over = jnp.abs(x) > limit
    return jnp.where(over, limit / jnp.where(over, jnp.abs(x), 1.0), 1.0)


def _limit_velocity(u, params):
    dtype = u.dtype
    s = jnp.minimum(_shrink(u[0], jnp.asarray(params.v_max, dtype)),
                    _shrink(u[1], jnp.asarray(params.omega_max, dtype)))
    return u * s


def _limit_acceleration(u, prev, params, dt):
    dtype = u.dtype
    du = u - prev
    s = jnp.minimum(_shrink(du[0], jnp.asarray(params.a_max, dtype) * dt),
                    _shrink(du[1], jnp.asarray(params.alpha_max, dtype) * dt))
    return prev + du * s


def _too_close(obstacles, obstacle_mask, stop_distance):
    d2 = jnp.sum(obstacles * obstacles, -1)
    ok = obstacle_mask & jnp.all(jnp.isfinite(obstacles), -1)
    r = jnp.asarray(stop_distance, obstacles.dtype)
    return jnp.any(ok & (jnp.where(ok, d2, jnp.inf) <= r * r))


def _unicycle(pose, u, dt):
    v, w = u[0], u[1]
    th = pose[2]
    a = w * dt
    small = jnp.abs(a) < 1e-4
    a_safe = jnp.where(small, 1.0, a)
    # sin(a)/a and (1 - cos(a))/a with their Taylor series near a = 0.
    sinc = jnp.where(small, 1.0 - a * a / 6.0, jnp.sin(a_safe) / a_safe)
    cosc = jnp.where(small, a / 2.0 - a ** 3 / 24.0, (1.0 - jnp.cos(a_safe)) / a_safe)
    dist = v * dt
    fwd, left = dist * sinc, dist * cosc
    c, s = jnp.cos(th), jnp.sin(th)
    return jnp.stack([pose[0] + c * fwd - s * left, pose[1] + s * fwd + c * left,
                      wrap(th + a)]).astype(pose.dtype)


def _check_point(point):
    if _checks.is_concrete(point) and float(np.asarray(point)[0]) == 0.0:
        raise ValueError("follower point P_fm1 = 0 makes M singular (det M = P_fm1, seed 004 "
                         "Lemma 1); put the follower point ahead of or behind the robot axle")


def _check_obstacles(obstacles, obstacle_mask):
    if obstacles is None:
        if obstacle_mask is not None:
            raise ValueError("obstacle_mask given without obstacles")
        return None, None
    _checks.check_shape("obstacles", obstacles, (None, 2), "[Q, 2] points")
    q = np.shape(obstacles)[0]
    if obstacle_mask is None:
        obstacle_mask = jnp.ones(q, bool)
    _checks.check_shape("obstacle_mask", obstacle_mask, (q,), "[Q] bool")
    if _checks.is_concrete(obstacle_mask) and not np.issubdtype(np.asarray(obstacle_mask).dtype,
                                                                np.bool_):
        raise TypeError(f"obstacle_mask must be bool; got {np.asarray(obstacle_mask).dtype}")
    return obstacles, jnp.asarray(obstacle_mask, bool)

