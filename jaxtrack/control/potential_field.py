r"""Person-interest-adapted potential field and gradient-following approach (seed 002, II-C).

The field lives in the person's frame: :math:`q = R(-\phi)(r - p)` is the robot position
relative to the person at :math:`p` with heading :math:`\phi` (:math:`q_x` ahead, :math:`q_y` to
the left). It is a weighted sum of four unnormalised Gaussians
:math:`G(q; \Sigma) = \exp(-\tfrac12 q^T \Sigma^{-1} q)`, all centred on the person, one negated:

.. math::
    f(q) = -w_a G(q; \Sigma_a) + (1 - g(q_x))\, w_r G(q; \Sigma_r)
           + g(q_x) \big[w_\parallel G(\bar q; \Sigma_\parallel(PI))
                        + w_\perp G(\bar q; \Sigma_\perp(PI))\big],

- attractor :math:`\Sigma_a = 7.5 I` (seed), rear :math:`\Sigma_r = \operatorname{diag}(2, 1)`
  (seed), applied behind the person;
- parallel :math:`\Sigma_\parallel = R(\alpha) \operatorname{diag}(\sigma_{\parallel,1}^2,
  \sigma_{\parallel,2}^2) R(\alpha)^T` (major axis along :math:`x_p`) and perpendicular
  :math:`\Sigma_\perp = R(\alpha) \operatorname{diag}(\sigma_{\perp,2}^2, \sigma_{\perp,1}^2)
  R(\alpha)^T` (major axis along :math:`y_p`), applied in front, scaled and rotated with the
  person-interest indicator :math:`PI \in [0, 1]`.

The robot descends the field: the minimum is where it should stand. The seed gives the attractor
and rear covariances, and describes where the minimum lies (Fig. 3 and section IV-B): about 2 m
in front for :math:`PI = 0`; about 45 deg, just outside the personal zone (1.2 m), for
:math:`PI = 0.5`; in front at the border of the intimate zone (0.45 m) for :math:`PI = 1`. The
rest is ours, chosen so that the minimum lands there and the field has no other local minimum
(checked on a 2 cm grid over 8 x 8 m by the tests):

- Weights :math:`w_a = w_r = w_\parallel = w_\perp = 1` (the Gaussians are unnormalised, so a
  weight is a peak height; the seed adapts only covariances to PI, so do we).
- The PI-dependent variances are tabulated at :math:`PI = 0, 0.5, 1` and interpolated piecewise
  linearly in log-variance (rotation :math:`\alpha` linearly): (major, minor) variances in m^2
  parallel (0.02, 0.01), (1.0, 0.1), (0.02, 0.01); perpendicular (0.8, 0.75), (0.5, 0.1),
  (0.5, 0.02); :math:`\alpha = 0` at all three (the |y| fold below already gives the 45-deg
  valleys, from the cross of the parallel and perpendicular Gaussians). The minima land at
  1.96 m ahead (PI = 0), 1.26 m at 47 deg (PI = 0.5) and 0.52 m ahead (PI = 1),
  moving continuously in between. All tabulated
  values are unconstrained leaves of `Params`, so they can be fitted.
- Left/right symmetry: the frontal Gaussians are evaluated at :math:`\bar q = (q_x, |q_y|)`, so a
  rotation :math:`\alpha` turns both sides' valleys alike (the field is continuous; its
  gradient has a kink on the person's heading line only where :math:`\alpha \neq 0`).
- Front/rear switch: the seed applies the rear Gaussian behind the person and the frontal ones
  in front; we blend with the logistic gate :math:`g(q_x) = \sigma(q_x / s)`, :math:`s = 0.05` m,
  so that the field is smooth (:math:`s \to 0` recovers the hard switch).

`approach_velocity` turns the gradient into unicycle commands: the desired velocity is
:math:`\dot x_d = \dot p - c \nabla f` (the person's velocity, if given, plus the descent; so the
speed is high where the field is steep and low near the minimum, as the seed wants), then
:math:`v = \|\dot x_d\| \max(\cos e, 0)`, :math:`\omega = k_\theta e` with :math:`e` the heading
error to :math:`\dot x_d` (blended towards facing the person as :math:`\dot x_d \to 0`), both
clipped to their limits.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax import lax

from jaxtrack import _checks, geometry
from jaxtrack.angles import wrap

Array = jax.Array

__all__ = ["INTIMATE", "PERSONAL", "SOCIAL", "Params", "potential", "gradient",
           "gradient_step", "settle_point", "approach_velocity"]

INTIMATE = 0.45
"""Hall's intimate-zone radius (m), seed 002 II-C."""
PERSONAL = 1.2
"""Hall's personal-zone radius (m); the social zone starts here."""
SOCIAL = 3.6
"""Hall's social-zone radius (m); the public zone starts here."""

_PI_NODES = (0.0, 0.5, 1.0)
_PARALLEL_VAR = ((0.02, 0.01), (1.0, 0.1), (0.02, 0.01))
_PERPENDICULAR_VAR = ((0.8, 0.75), (0.5, 0.1), (0.5, 0.02))


class Params(NamedTuple):
    r"""Potential-field parameters, all unconstrained (a pytree optax can step).

    Attributes:
      log_weights: [4] log peak heights (attractor, rear, parallel, perpendicular).
      log_attractor_var: log :math:`\sigma^2` of the isotropic attractor (seed: 7.5 m^2).
      log_rear_var: [2] log variances (along, across the heading) of the rear Gaussian
        (seed: 2, 1 m^2).
      log_parallel_var: [3, 2] log (major, minor) variances of the parallel Gaussian at
        PI = 0, 0.5, 1 (major axis along the heading before rotation).
      log_perpendicular_var: [3, 2] the same for the perpendicular Gaussian (major axis across
        the heading before rotation).
      rotation: [3] :math:`\alpha` (rad) at PI = 0, 0.5, 1.
      log_gate_width: log of the front/rear blending width :math:`s` (m).
    """

    log_weights: Array
    log_attractor_var: Array
    log_rear_var: Array
    log_parallel_var: Array
    log_perpendicular_var: Array
    rotation: Array
    log_gate_width: Array

    @classmethod
    def create(cls, weights=(1.0, 1.0, 1.0, 1.0), attractor_var=7.5, rear_var=(2.0, 1.0),
               parallel_var=_PARALLEL_VAR, perpendicular_var=_PERPENDICULAR_VAR,
               rotation=(0.0, 0.0, 0.0), gate_width=0.05, dtype=None) -> "Params":
        """Parameters from positive weights and variances (defaults: the module docstring's).

        Example:
          >>> params = Params.create(attractor_var=10.0)
        """
        shapes = {"weights": (4,), "attractor_var": (), "rear_var": (2,),
                  "parallel_var": (3, 2), "perpendicular_var": (3, 2), "gate_width": ()}
        values = {"weights": weights, "attractor_var": attractor_var, "rear_var": rear_var,
                  "parallel_var": parallel_var, "perpendicular_var": perpendicular_var,
                  "gate_width": gate_width}
        for name, value in values.items():
            _checks.check_shape(name, value, shapes[name])
            _checks.check_finite(name, value)
            if _checks.is_concrete(value) and not np.all(np.asarray(value) > 0):
                raise ValueError(f"{name} must be > 0; got {value}")
        _checks.check_shape("rotation", rotation, (3,), "alpha at PI = 0, 0.5, 1")
        _checks.check_finite("rotation", rotation)
        dtype = dtype if dtype is not None else jnp.result_type(float)

        def log(x):
            return jnp.log(jnp.asarray(x, dtype))

        return cls(log(weights), log(attractor_var), log(rear_var), log(parallel_var),
                   log(perpendicular_var), jnp.asarray(rotation, dtype), log(gate_width))


def potential(params: Params, robot_xy: Array, person_pose: Array, interest) -> Array:
    r"""The field :math:`f` [...] at robot positions (module docstring; seed 002, II-C).

    Args:
      params: `Params`.
      robot_xy: [..., 2] robot positions in the world frame.
      person_pose: [3] person (x, y, heading) in the world frame.
      interest: PI in [0, 1], scalar.

    Returns:
      [...] potential values (dimensionless; lower is where the robot should be).

    Example:
      >>> xy = jnp.stack(jnp.meshgrid(jnp.linspace(-3, 3, 61), jnp.linspace(-3, 3, 61)), -1)
      >>> f = potential(Params.create(), xy, jnp.zeros(3), 0.5)  # [61, 61]
    """
    _check_params(params)
    _check_xy(robot_xy)
    _check_person(person_pose, interest)
    robot_xy, person_pose, interest = _as_arrays(robot_xy, person_pose, interest)
    return _potential(params, robot_xy, person_pose, interest)


def gradient(params: Params, robot_xy: Array, person_pose: Array, interest) -> Array:
    r""":math:`\nabla_r f` [..., 2] in the world frame (by `jax.grad`).

    Example:
      >>> g = gradient(Params.create(), jnp.array([1.0, 1.0]), jnp.zeros(3), 1.0)
    """
    _check_params(params)
    _check_xy(robot_xy)
    _check_person(person_pose, interest)
    robot_xy, person_pose, interest = _as_arrays(robot_xy, person_pose, interest)
    return _gradient(params, robot_xy, person_pose, interest)


def gradient_step(params: Params, robot_xy: Array, person_pose: Array, interest,
                  step_size=0.1) -> Array:
    r"""One step of gradient descent :math:`r \leftarrow r - \eta \nabla f(r)` [..., 2].

    A holonomic robot following the field (seed 002: "the gradient of the potential field is
    derived"); ``step_size`` :math:`\eta` in m^2 per unit potential.

    Example:
      >>> xy = jnp.array([3.0, 1.0])
      >>> for _ in range(200):
      ...     xy = gradient_step(Params.create(), xy, jnp.zeros(3), 0.0, 0.5)
    """
    if _checks.is_concrete(step_size) and not float(step_size) > 0:
        raise ValueError(f"step_size must be > 0; got {step_size}")
    return robot_xy - step_size * gradient(params, robot_xy, person_pose, interest)


REVERSE_COS = 0.3   # `approach_velocity`'s band (cosine) where reversing is by the smaller turn


def settle_point(params: Params, robot_xy: Array, person_pose: Array, interest, *,
                 iterations: int = 60, max_step=0.05, min_curvature=0.01) -> Array:
    r"""Where the gradient flow of the field from ``robot_xy`` settles: its local minimum.

    ``iterations`` saddle-free Newton steps,
    :math:`x \leftarrow x - V\,\mathrm{diag}(1/\max(|\lambda_i|, \mu))\,V^\top \nabla f(x)`
    with :math:`H = V \mathrm{diag}(\lambda) V^\top` the field's 2 x 2 Hessian, each clipped
    to ``max_step`` (m) and shortened by optax's backtracking (Armijo) line search until
    :math:`f` decreases enough. The field's valleys are nearly flat across the person's
    heading (curvature 0.007 / m^2 at PI = 0), where plain gradient steps crawl; the
    curvature scaling crosses them in a step, and taking :math:`|\lambda|` keeps the step
    downhill where the field curves down. The clip keeps every step shorter than the
    narrowest Gaussian of the field (0.1 m), so the point follows the flow into the robot's
    own basin rather than jumping over the person into another. (Optax has the line search
    and the clip but no Newton direction for a function this small, hence the direction
    here.)

    Args:
      params: `Params`. robot_xy: [2] the start. person_pose: [3] (x, y, heading).
      interest: PI in [0, 1].
      iterations: steps (static). max_step: m. min_curvature: :math:`\mu` (1/m^2).

    Returns:
      [2] the settled point (at most ``iterations * max_step`` from the start).

    Example:
      >>> settle_point(Params.create(), jnp.array([3.0, 1.0]), jnp.zeros(3), 1.0)  # ~(0.52, 0)
    """
    _check_params(params)
    _checks.check_shape("robot_xy", robot_xy, (2,), "(x, y)")
    _checks.check_finite("robot_xy", robot_xy)
    _check_person(person_pose, interest)
    xy, person_pose, interest = _as_arrays(robot_xy, person_pose, interest)

    def f(x):
        return _potential(params, x, person_pose, interest)

    opt = optax.chain(optax.clip_by_global_norm(max_step),
                      optax.scale_by_backtracking_linesearch(max_backtracking_steps=15))
    mu = jnp.asarray(min_curvature, xy.dtype)

    def body(_, carry):
        x, state = carry
        value, grad = jax.value_and_grad(f)(x)
        curvature, axes = jnp.linalg.eigh(jax.hessian(f)(x))
        direction = -(axes @ ((axes.T @ grad) / jnp.maximum(jnp.abs(curvature), mu)))
        updates, state = opt.update(direction, state, x, value=value, grad=grad, value_fn=f)
        return optax.apply_updates(x, updates), state

    x, _ = lax.fori_loop(0, int(iterations), body, (xy, opt.init(xy)))
    return x


def approach_velocity(params: Params, robot_pose: Array, person_pose: Array, interest,
                      person_vel: Array | None = None, *, gain=1.0, v_max=0.6,
                      omega_max=1.5, heading_gain=2.0, face_speed=0.02,
                      reverse: bool = False, settle_iterations: int = 0,
                      target: Array | None = None) -> Array:
    r"""Gradient following as unicycle commands u = (v, omega) [2] (the "approach" behaviour).

    :math:`\dot x_d = \dot p - c \nabla f(r)`; the heading target is the direction of
    :math:`\dot x_d + v_f \hat u` (:math:`\hat u` the unit vector from robot to person, so the
    robot turns to face the person once :math:`\|\dot x_d\| \ll v_f`);
    :math:`e = \operatorname{wrap}(\text{target} - \theta)`,
    :math:`v = \min(\|\dot x_d\| \max(\cos e, 0), v_{max})`,
    :math:`\omega = \operatorname{clip}(k_\theta e, \pm\omega_{max})`.

    With ``reverse``, the robot may also drive backwards along :math:`\dot x_d`, its heading
    target then the direction of :math:`-\dot x_d + v_f \hat u` and :math:`v \le 0`: always
    when :math:`\dot x_d` leads away from the person (:math:`\cos(\dot x_d, \hat u) < -0.3`),
    never when it leads to them (:math:`> 0.3`), and in between whichever needs the smaller
    turn, by a margin growing with the cosine: backwards iff
    :math:`|e_{back}| - |e| < -(\pi / 0.3)\cos(\dot x_d, \hat u)`. A unicycle that backs
    away from the person or
    goes round them then keeps its front, and the sensors on it, towards them (seed 002's
    omnidirectional robot can face the person whatever its motion).

    With ``settle_iterations`` > 0, the robot drives to where the gradient flow settles
    instead (`settle_point`, that many iterations): :math:`\dot x_d = \dot p + c\,(x^* - r)`,
    ``gain`` :math:`c` then in 1/s. The field's gradient is tiny in its flat valleys, so
    following it leaves the robot short of the minimum for tens of seconds; the settled point
    is the same minimum (seed 002's pose), reached at the robot's own speed. A caller may
    pass that point as ``target`` instead (from `settle_point`, or the robot's own position
    to stand and face the person: a unicycle chasing a point that the person estimate's noise
    moves by centimetres turns to and fro, so a caller parks it with some hysteresis).

    Args:
      params: `Params`. robot_pose: [3] (x, y, theta). person_pose: [3] (x, y, heading).
      interest: PI in [0, 1].
      person_vel: optional [2] person velocity (world), fed forward.
      gain: :math:`c`, m/s per unit gradient (1/m). v_max (m/s), omega_max (rad/s): limits.
      heading_gain: :math:`k_\theta` (1/s). face_speed: :math:`v_f` (m/s).
      reverse: allow driving backwards (static).
      settle_iterations: `settle_point` iterations (static); 0 follows the gradient itself.
      target: optional [2] point to drive to, instead of the gradient or ``settle_iterations``.

    Returns:
      [2] (v, omega).

    Example:
      >>> u = approach_velocity(Params.create(), jnp.array([3.0, 1.0, 3.0]), jnp.zeros(3), 1.0)
    """
    _check_params(params)
    _checks.check_shape("robot_pose", robot_pose, (3,), "(x, y, theta)")
    _checks.check_finite("robot_pose", robot_pose)
    _check_person(person_pose, interest)
    if person_vel is not None:
        _checks.check_shape("person_vel", person_vel, (2,), "(vx, vy)")
        _checks.check_finite("person_vel", person_vel)
    for name, value in (("gain", gain), ("v_max", v_max), ("omega_max", omega_max),
                        ("heading_gain", heading_gain), ("face_speed", face_speed)):
        if _checks.is_concrete(value) and not float(value) > 0:
            raise ValueError(f"{name} must be > 0; got {value}")
    robot_pose, person_pose, interest = _as_arrays(robot_pose, person_pose, interest)
    dtype = robot_pose.dtype
    pv = jnp.zeros(2, dtype) if person_vel is None else jnp.asarray(person_vel, dtype)
    if target is None and settle_iterations:
        target = settle_point(params, robot_pose[:2], person_pose, interest,
                              iterations=settle_iterations)
    if target is not None:
        _checks.check_shape("target", target, (2,), "(x, y)")
        desired = pv + gain * (jnp.asarray(target, dtype) - robot_pose[:2])
    else:
        desired = pv - gain * _gradient(params, robot_pose[:2], person_pose, interest)
    to_person = person_pose[:2] - robot_pose[:2]
    distance = jnp.sqrt(jnp.sum(to_person ** 2) + 1e-12)
    facing = face_speed * to_person / distance

    def heading_error(aim):
        aim = jnp.where(jnp.sum(aim ** 2) > 0, aim, jnp.array([1.0, 0.0], dtype))
        return wrap(jnp.arctan2(aim[1], aim[0]) - robot_pose[2])

    e = heading_error(desired + facing)
    speed = jnp.sqrt(jnp.sum(desired ** 2) + 1e-24)
    v = jnp.minimum(speed * jnp.maximum(jnp.cos(e), 0.0), v_max)
    if reverse:
        e_back = heading_error(-desired + facing)
        # Leaving the person (cos < -0.3 between the motion and the way to them): backwards;
        # approaching (cos > 0.3): forwards; in between (going round them) the smaller turn,
        # so that the robot's own heading holds the choice. The turns are compared against a
        # margin that grows continuously with the cosine (pi at +-0.3), not against hard
        # bands: a robot near the edge of a band would otherwise flip between backing and
        # turning at every frame.
        along = jnp.sum(desired * to_person) / (speed * distance)
        back = jnp.abs(e_back) - jnp.abs(e) < -(jnp.pi / REVERSE_COS) * along
        e = jnp.where(back, e_back, e)
        v = jnp.where(back, -jnp.minimum(speed * jnp.maximum(jnp.cos(e_back), 0.0), v_max), v)
    w = jnp.clip(heading_gain * e, -omega_max, omega_max)
    return jnp.stack([v, w]).astype(dtype)


# ---------------------------------------------------------------------------------------------
# Private helpers


def _as_arrays(xy, person_pose, interest):
    xy = jnp.asarray(xy)
    person_pose = jnp.asarray(person_pose)
    dtype = jnp.result_type(xy.dtype, person_pose.dtype, jnp.float32)
    return (xy.astype(dtype), person_pose.astype(dtype),
            jnp.clip(jnp.asarray(interest, dtype), 0.0, 1.0))


def _gaussian(q, var_major, var_minor, alpha):
    """exp(-q^T Sigma^-1 q / 2) with Sigma = R(alpha) diag(var_major, var_minor) R(alpha)^T."""
    ab = geometry.unrotate(alpha, q)
    a, b = ab[..., 0], ab[..., 1]
    return jnp.exp(-0.5 * (a * a / var_major + b * b / var_minor))


def _interp(interest, table):
    nodes = jnp.asarray(_PI_NODES, table.dtype)
    return jnp.interp(interest, nodes, table)


def _potential(params, xy, person_pose, interest):
    dtype = xy.dtype
    p = jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype), params)
    c, s = jnp.cos(person_pose[2]), jnp.sin(person_pose[2])
    d = xy - person_pose[:2]
    qx = c * d[..., 0] + s * d[..., 1]
    qy = -s * d[..., 0] + c * d[..., 1]
    q = jnp.stack([qx, qy], -1)
    folded = jnp.stack([qx, jnp.abs(qy)], -1)
    w = jnp.exp(p.log_weights)
    var_a = jnp.exp(p.log_attractor_var)
    var_r = jnp.exp(p.log_rear_var)
    par = jnp.exp(jnp.stack([_interp(interest, p.log_parallel_var[:, k]) for k in range(2)]))
    perp = jnp.exp(jnp.stack([_interp(interest, p.log_perpendicular_var[:, k])
                              for k in range(2)]))
    alpha = _interp(interest, p.rotation)
    front = jax.nn.sigmoid(qx / jnp.exp(p.log_gate_width))
    attractor = -w[0] * _gaussian(q, var_a, var_a, 0.0)
    rear = w[1] * _gaussian(q, var_r[0], var_r[1], 0.0)
    parallel = w[2] * _gaussian(folded, par[0], par[1], alpha)
    # perpendicular: major axis across the heading, i.e. (x, y) variances (minor, major)
    perpendicular = w[3] * _gaussian(folded, perp[1], perp[0], alpha)
    return attractor + (1.0 - front) * rear + front * (parallel + perpendicular)


def _gradient(params, xy, person_pose, interest):
    # Each value depends on its own position only, so the gradient of the sum is per point.
    return jax.grad(lambda r: jnp.sum(_potential(params, r, person_pose, interest)))(xy)


def _check_params(params):
    if not isinstance(params, Params):
        raise TypeError(f"params must be a potential_field.Params; got {type(params).__name__}")


def _check_xy(robot_xy):
    _checks.check_shape("robot_xy", robot_xy, (*np.shape(robot_xy)[:-1], 2), "[..., 2]")
    _checks.check_finite("robot_xy", robot_xy)


def _check_person(person_pose, interest):
    _checks.check_shape("person_pose", person_pose, (3,), "(x, y, heading)")
    _checks.check_finite("person_pose", person_pose)
    _checks.check_shape("interest", interest, (), "scalar PI")
    if _checks.is_concrete(interest) and not 0.0 <= float(interest) <= 1.0:
        raise ValueError(f"interest (PI) must be in [0, 1]; got {interest}")

