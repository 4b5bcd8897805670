r"""Proportional reach control of position and heading (seed 000, Algorithm 1 and 5.3.1).

The tracker gives the robot's pose :math:`(x^{ref}_{CoM}, \theta^{ref}_c)`; the controller
imposes exponential convergence of the errors :math:`e_x = x - x_t` and
:math:`e_\theta = \operatorname{wrap}(\theta - \theta_t)`:

.. math::
    \dot x^{ref}_{CoM} = -\lambda_x (x^{ref}_{CoM} - x_t), \qquad
    \dot\theta^{ref}_c = -\lambda_\theta \operatorname{wrap}(\theta^{ref}_c - \theta_t),

saturated to the walking limits (the speed by scaling the whole vector, which keeps its
direction; the turn rate by clipping), and hands them to an omnidirectional walking pattern
generator, in the world frame or as forward/lateral velocities in the robot frame. "While
outside the stopping region": the seed stops within 5 cm of the target position (section 5.3.1)
and within 10 deg of the target heading; the stop is *latched* — once stopped, the command stays
zero (the seed ends the experiment there, and walking in place near the target would only add
tracker noise).

- `step`: one control step with the latched stop, state `ReachState`.
- `smooth_step`: the same with a sigmoid stop gate, for gradient tuning (see its docstring for
  what the gradient means).
- `reach`: a `lax.scan` rollout under ideal kinematics (:math:`x \mathrel{+}= \dot x\,dt`), the
  reference closed loop for tests and gain tuning.
- `seed_tasks`: the seed's 15 target poses (section 5.3).

Gains are tuned as unconstrained logs (`PoseGains`); `gains` maps them to positive values.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxtrack import _checks, geometry
from jaxtrack.angles import wrap

Array = jax.Array

__all__ = ["PoseGains", "Gains", "PoseLimits", "PoseCommand", "ReachState", "SmoothReachState",
           "ReachResult", "gains", "pose_gains", "reference_velocity", "to_body_frame",
           "in_stop_region", "stop_probability", "init", "smooth_init", "step", "smooth_step",
           "reach", "seed_tasks"]

_LAMBDA_X = 0.1
_LAMBDA_THETA = 0.2


class PoseGains(NamedTuple):
    r"""Unconstrained controller parameters: log-gains (optax steps these).

    The seed prints no gain values. :math:`\lambda_x = 0.1\ s^{-1}` reproduces its reach time:
    an exponential approach from 1 m to 5 cm takes :math:`\ln(20)/\lambda_x \approx 30` s, 120
    frames at the seed's ~4 Hz, where the seed reports 110-120 frames (section 5.4); it also
    starts at 0.1 m/s, a NAO walking speed. :math:`\lambda_\theta = 0.2\ s^{-1}` is ours: a
    90-deg turn gets within 10 deg in :math:`\ln 9 / 0.2 \approx 11` s, before the position.

    Attributes:
      log_lambda_x: :math:`\log \lambda_x` (1/s).
      log_lambda_theta: :math:`\log \lambda_\theta` (1/s).
    """

    log_lambda_x: float = math.log(_LAMBDA_X)
    log_lambda_theta: float = math.log(_LAMBDA_THETA)


class Gains(NamedTuple):
    """Positive gains :math:`(\\lambda_x, \\lambda_\\theta)` in 1/s, from `gains`."""

    lambda_x: Array
    lambda_theta: Array


class PoseLimits(NamedTuple):
    """Walking limits and the stop rule (not tuned by gradient; plain positive floats).

    Attributes:
      max_speed: largest linear speed (m/s); 0.1 (ours: a NAO walks at about 0.1 m/s).
      max_turn_rate: largest turn rate (rad/s); 0.5 (ours, NAO-like).
      stop_distance: stop radius (m); 0.05 (seed, section 5.3.1).
      stop_angle: stop heading tolerance (rad); 10 deg (seed, section 5.3.1).
    """

    max_speed: float = 0.1
    max_turn_rate: float = 0.5
    stop_distance: float = 0.05
    stop_angle: float = math.radians(10.0)


class PoseCommand(NamedTuple):
    """A velocity command.

    Attributes:
      velocity: [2] linear velocity in the world frame (m/s).
      turn_rate: scalar angular velocity (rad/s).
      body_velocity: [2] (forward, lateral) velocity in the robot frame, for an
        omnidirectional walking pattern generator.
      stopped: `step`: bool, the latched stop; `smooth_step`: float in [0, 1], the probability
        of having stopped under the randomised rule.
    """

    velocity: Array
    turn_rate: Array
    body_velocity: Array
    stopped: Array


class ReachState(NamedTuple):
    """State of `step`: ``stopped`` (bool), latched once the stop region is entered."""

    stopped: Array


class SmoothReachState(NamedTuple):
    """State of `smooth_step`: ``moving`` (float in [0, 1]), the probability of not having
    stopped yet."""

    moving: Array


class ReachResult(NamedTuple):
    """Output of `reach`.

    Attributes:
      poses: [T + 1, 3] poses, the initial one first.
      commands: `PoseCommand` with a leading [T] axis.
      steps_to_stop: number of commands issued before the stop (T if it never stopped; for the
        smooth rollout, the expected number, sum of ``1 - stopped``).
    """

    poses: Array
    commands: PoseCommand
    steps_to_stop: Array


# ---------------------------------------------------------------------------------------------
# Parameters


def gains(params: PoseGains) -> Gains:
    """Positive gains from the unconstrained `PoseGains` (elementwise exp).

    Example:
      >>> gains(PoseGains()).lambda_x  # 0.1
    """
    return Gains(jnp.exp(jnp.asarray(params.log_lambda_x)),
                 jnp.exp(jnp.asarray(params.log_lambda_theta)))


def pose_gains(lambda_x=_LAMBDA_X, lambda_theta=_LAMBDA_THETA) -> PoseGains:
    """`PoseGains` from positive gains (the inverse of `gains`).

    Example:
      >>> params = pose_gains(0.2, 0.4)
    """
    for name, value in (("lambda_x", lambda_x), ("lambda_theta", lambda_theta)):
        _checks.check_finite(name, value)
        if _checks.is_concrete(value) and not np.all(np.asarray(value) > 0):
            raise ValueError(f"{name} must be > 0; got {value}")
    return PoseGains(jnp.log(jnp.asarray(lambda_x)), jnp.log(jnp.asarray(lambda_theta)))


def seed_tasks(dtype=None) -> Array:
    """The seed's 15 target poses [15, 3] from the start pose (0, 0, 0) (section 5.3, Fig. 7).

    Three positions 1 m away — P1 forward (1, 0), P2 horizontal (0, 1), P3 diagonal
    (1/sqrt 2, 1/sqrt 2) — times five final headings -90, -45, 0, 45, 90 deg, in that order
    (position-major). The figure giving the horizontal side is lost in our copy: we use the
    robot's left (+y).

    Example:
      >>> targets = seed_tasks()  # targets[7] = (0, 1, 0)
    """
    s = 1.0 / math.sqrt(2.0)
    positions = np.array([[1.0, 0.0], [0.0, 1.0], [s, s]])
    headings = np.deg2rad([-90.0, -45.0, 0.0, 45.0, 90.0])
    rows = [[px, py, h] for px, py in positions for h in headings]
    return jnp.asarray(np.array(rows), dtype)


# ---------------------------------------------------------------------------------------------
# Control law


def reference_velocity(pose: Array, target: Array, params: PoseGains = PoseGains(),
                       limits: PoseLimits = PoseLimits()) -> tuple[Array, Array]:
    r"""Algorithm 1's references, saturated, without the stop rule.

    :math:`v = \operatorname{sat}_{v_{max}}(-\lambda_x (x - x_t))` with
    :math:`\operatorname{sat}_{m}(v) = v \min(1, m / \|v\|)` (keeps the direction) and
    :math:`\omega = \operatorname{clip}(-\lambda_\theta \operatorname{wrap}(\theta - \theta_t),
    \pm\omega_{max})`.

    Args:
      pose: [3] current pose (x, y, theta).
      target: [3] target pose.
      params: `PoseGains`.
      limits: `PoseLimits`.

    Returns:
      ``(velocity [2] world frame, turn_rate scalar)``.

    Example:
      >>> v, w = reference_velocity(jnp.zeros(3), jnp.array([1.0, 0.0, 0.5]))
    """
    _check_poses(pose, target)
    _check_limits(limits)
    return _reference(*_as_arrays(pose, target), params, limits)


def to_body_frame(velocity: Array, heading: Array) -> Array:
    r"""World-frame velocity [..., 2] to (forward, lateral) in the robot frame:
    :math:`R(-\theta) v`.

    Example:
      >>> to_body_frame(jnp.array([0.0, 1.0]), jnp.pi / 2)  # (1, 0)
    """
    return geometry.unrotate(heading, velocity)


def in_stop_region(pose: Array, target: Array, limits: PoseLimits = PoseLimits()) -> Array:
    """Whether ``pose`` is within ``stop_distance`` and ``stop_angle`` of ``target`` (bool).

    Example:
      >>> in_stop_region(jnp.array([0.97, 0.0, 0.1]), jnp.array([1.0, 0.0, 0.0]))  # True
    """
    _check_poses(pose, target)
    pose, target = _as_arrays(pose, target)
    dist, ang = _errors(pose, target)
    return (dist <= limits.stop_distance) & (ang <= limits.stop_angle)


def stop_probability(pose: Array, target: Array, limits: PoseLimits = PoseLimits(),
                     distance_softness=0.005, angle_softness=math.radians(1.0)) -> Array:
    r"""Smooth `in_stop_region`:
    :math:`\sigma\big(\frac{d_{stop} - d}{s_d}\big)\,\sigma\big(\frac{a_{stop} - |e_\theta|}
    {s_a}\big)`.

    Since :math:`\sigma((d_{stop} - d)/s) = P(d \le d_{stop} + s L)` for a standard logistic
    :math:`L`, this is the probability that the pose is inside a stop region whose two
    thresholds are jittered by independent logistic noise of scales :math:`s_d, s_a`. It tends
    to the hard indicator as the softnesses go to 0.

    Example:
      >>> p = stop_probability(pose, target, distance_softness=0.002)
    """
    _check_poses(pose, target)
    pose, target = _as_arrays(pose, target)
    return _stop_probability(pose, target, limits, distance_softness, angle_softness)


def init() -> ReachState:
    """Initial `ReachState` (not stopped).

    Example:
      >>> state, cmd = step(init(), pose, target)
    """
    return ReachState(jnp.asarray(False))


def smooth_init(dtype=None) -> SmoothReachState:
    """Initial `SmoothReachState` (moving with probability 1) of the given float dtype.

    Example:
      >>> state, cmd = smooth_step(smooth_init(), pose, target)
    """
    return SmoothReachState(jnp.asarray(1.0, dtype))


def step(state: ReachState, pose: Array, target: Array, params: PoseGains = PoseGains(),
         limits: PoseLimits = PoseLimits(), stop_pose: Array | None = None
         ) -> tuple[ReachState, PoseCommand]:
    r"""One step of Algorithm 1 with the latched stop rule of section 5.3.1.

    :math:`s_k = s_{k-1} \lor (\|x - x_t\| \le d_{stop} \land |e_\theta| \le a_{stop})`; the
    command is `reference_velocity` while :math:`\lnot s_k` and zero after. A non-finite pose
    or target inside traced code gives a zero command and leaves the state unchanged (at the
    boundary, with concrete inputs, it raises).

    Args:
      state: `ReachState` (from `init`).
      pose: [3] current pose estimate (x, y, theta).
      target: [3] target pose.
      params: `PoseGains`; limits: `PoseLimits`.
      stop_pose: optional [3] pose on which the stop region is tested instead of ``pose``
        (the command still follows ``pose``): e.g. the estimate averaged over a step cycle, so
        that the lateral sway of a walking robot does not trigger the stop at a sway extreme.

    Returns:
      ``(state, PoseCommand)``.

    Example:
      >>> state = init()
      >>> state, cmd = step(state, pose, target)
      >>> cmd.body_velocity, cmd.stopped
    """
    if not isinstance(state, ReachState):
        raise TypeError(f"state must be a pose.ReachState; got {type(state).__name__}")
    _check_poses(pose, target)
    _check_limits(limits)
    pose, target, stop_pose, valid = _prepare(pose, target, stop_pose)
    dist, ang = _errors(stop_pose, target)
    inside = (dist <= limits.stop_distance) & (ang <= limits.stop_angle)
    stopped = jnp.asarray(state.stopped, bool) | (valid & inside)
    velocity, turn_rate = _reference(pose, target, params, limits)
    go = valid & ~stopped
    velocity = jnp.where(go, velocity, 0.0)
    turn_rate = jnp.where(go, turn_rate, 0.0)
    cmd = PoseCommand(velocity, turn_rate, to_body_frame(velocity, pose[2]), stopped)
    return ReachState(stopped), cmd


def smooth_step(state: SmoothReachState, pose: Array, target: Array,
                params: PoseGains = PoseGains(), limits: PoseLimits = PoseLimits(),
                distance_softness=0.005, angle_softness=math.radians(1.0),
                stop_pose: Array | None = None) -> tuple[SmoothReachState, PoseCommand]:
    r"""`step` with a differentiable (sigmoid-gated) stop, for gradient tuning.

    The latch :math:`\lnot s_k = \lnot s_{k-1} \land \lnot \text{inside}_k` becomes
    :math:`m_k = m_{k-1}\,(1 - p_k)` with :math:`p_k` = `stop_probability` and the command is
    :math:`m_k` times `reference_velocity`. For a given pose sequence, :math:`m_k` is exactly
    the probability of not having stopped by step k, and the command the expected command, when
    the stop thresholds are jittered by independent logistic noise at every step; the gradient
    is the exact gradient of that expectation (the hard rule's gradient with respect to the
    thresholds is zero almost everywhere). In closed loop the rollout integrates the *expected*
    command (a mean-field surrogate), so its gradient is that of a smooth surrogate of the
    hard loop, which it approaches as the softnesses go to 0.

    Args:
      state: `SmoothReachState` (from `smooth_init`).
      pose, target, params, limits, stop_pose: as `step`.
      distance_softness: logistic scale of the distance threshold (m).
      angle_softness: logistic scale of the heading threshold (rad).

    Returns:
      ``(state, PoseCommand)`` with ``stopped = 1 - m_k`` (a probability).

    Example:
      >>> state, cmd = smooth_step(smooth_init(), pose, target, params)
    """
    if not isinstance(state, SmoothReachState):
        raise TypeError(f"state must be a pose.SmoothReachState; got {type(state).__name__}")
    _check_poses(pose, target)
    _check_limits(limits)
    for name, value in (("distance_softness", distance_softness),
                        ("angle_softness", angle_softness)):
        if _checks.is_concrete(value) and not float(value) > 0:
            raise ValueError(f"{name} must be > 0; got {value}")
    pose, target, stop_pose, valid = _prepare(pose, target, stop_pose)
    p_in = _stop_probability(stop_pose, target, limits, distance_softness, angle_softness)
    moving = state.moving * jnp.where(valid, 1.0 - p_in, 1.0)
    velocity, turn_rate = _reference(pose, target, params, limits)
    gate = jnp.where(valid, moving, 0.0)
    velocity = gate * velocity
    turn_rate = gate * turn_rate
    cmd = PoseCommand(velocity, turn_rate, to_body_frame(velocity, pose[2]), 1.0 - moving)
    return SmoothReachState(moving.astype(pose.dtype)), cmd


def reach(pose0: Array, target: Array, params: PoseGains = PoseGains(),
          limits: PoseLimits = PoseLimits(), dt=0.25, num_steps: int = 160, *,
          smooth: bool = False, distance_softness=0.005,
          angle_softness=math.radians(1.0)) -> ReachResult:
    r"""Closed loop under ideal omnidirectional kinematics, as a `lax.scan`.

    :math:`x_{k+1} = x_k + \dot x_k\,dt`, :math:`\theta_{k+1} = \operatorname{wrap}(\theta_k +
    \dot\theta_k\,dt)` with the commands of `step` (or `smooth_step` if ``smooth``). No
    tracker, no walking noise: the reference behaviour of the control law (the seed's ~4 Hz
    gives ``dt = 0.25``).

    Args:
      pose0: [3] initial pose. target: [3] target pose.
      params, limits: as `step`.
      dt: control period (s).
      num_steps: T, number of control steps (static).
      smooth: use the differentiable `smooth_step`.
      distance_softness, angle_softness: as `smooth_step`.

    Returns:
      `ReachResult`.

    Example:
      >>> res = jax.vmap(lambda t: reach(jnp.zeros(3), t))(seed_tasks())
      >>> res.steps_to_stop  # [15]
    """
    _check_poses(pose0, target)
    _check_limits(limits)
    if num_steps < 1:
        raise ValueError(f"num_steps must be >= 1; got {num_steps}")
    if _checks.is_concrete(dt) and not float(dt) > 0:
        raise ValueError(f"dt must be > 0; got {dt}")
    pose0, target = _as_arrays(pose0, target)
    dtype = pose0.dtype

    def body(carry, _):
        pose, state = carry
        if smooth:
            state, cmd = smooth_step(state, pose, target, params, limits, distance_softness,
                                     angle_softness)
        else:
            state, cmd = step(state, pose, target, params, limits)
        nxt = jnp.concatenate([pose[:2] + cmd.velocity * dt,
                               wrap(pose[2] + cmd.turn_rate * dt)[None]]).astype(dtype)
        return (nxt, state), (nxt, cmd)

    state0 = smooth_init(dtype) if smooth else init()
    _, (poses, cmds) = lax.scan(body, (pose0, state0), None, length=num_steps)
    poses = jnp.concatenate([pose0[None], poses])
    if smooth:
        steps = jnp.sum(1.0 - cmds.stopped)
    else:
        steps = jnp.sum(~cmds.stopped)
    return ReachResult(poses, cmds, steps)


# ---------------------------------------------------------------------------------------------
# Private helpers


def _as_arrays(pose, target):
    pose = jnp.asarray(pose)
    target = jnp.asarray(target)
    dtype = jnp.result_type(pose.dtype, target.dtype, jnp.float32)
    return pose.astype(dtype), target.astype(dtype)


def _prepare(pose, target, stop_pose):
    """Arrays of one dtype, the validity flag, non-finite inputs zeroed (see `_sanitise`)."""
    if stop_pose is None:
        pose, target = _as_arrays(pose, target)
        valid = jnp.all(jnp.isfinite(pose)) & jnp.all(jnp.isfinite(target))
        pose, target = _sanitise(pose, target, valid)
        return pose, target, pose, valid
    _checks.check_shape("stop_pose", stop_pose, (3,), "(x, y, theta)")
    _checks.check_finite("stop_pose", stop_pose)
    pose, target = _as_arrays(pose, target)
    stop_pose = jnp.asarray(stop_pose, pose.dtype)
    valid = (jnp.all(jnp.isfinite(pose)) & jnp.all(jnp.isfinite(target))
             & jnp.all(jnp.isfinite(stop_pose)))
    pose, target = _sanitise(pose, target, valid)
    stop_pose = jnp.where(valid, stop_pose, 0.0)
    return pose, target, stop_pose, valid


def _sanitise(pose, target, valid):
    # Zeros in place of non-finite inputs keep NaN out of the (discarded) command and gradients.
    return jnp.where(valid, pose, 0.0), jnp.where(valid, target, 0.0)


def _errors(pose, target):
    return geometry.safe_norm(pose[:2] - target[:2]), jnp.abs(wrap(pose[2] - target[2]))


def _reference(pose, target, params, limits):
    dtype = pose.dtype
    g = gains(params)
    lam_x = jnp.asarray(g.lambda_x, dtype)
    lam_th = jnp.asarray(g.lambda_theta, dtype)
    v = -lam_x * (pose[:2] - target[:2])
    speed = geometry.safe_norm(v)
    v = v * (limits.max_speed / jnp.maximum(speed, limits.max_speed))
    w = jnp.clip(-lam_th * wrap(pose[2] - target[2]), -limits.max_turn_rate,
                 limits.max_turn_rate)
    return v.astype(dtype), w.astype(dtype)


def _stop_probability(pose, target, limits, distance_softness, angle_softness):
    dist, ang = _errors(pose, target)
    return (jax.nn.sigmoid((limits.stop_distance - dist) / distance_softness)
            * jax.nn.sigmoid((limits.stop_angle - ang) / angle_softness))


def _check_poses(pose, target):
    _checks.check_shape("pose", pose, (3,), "(x, y, theta)")
    _checks.check_shape("target", target, (3,), "(x, y, theta)")
    _checks.check_finite("pose", pose)
    _checks.check_finite("target", target)


def _check_limits(limits):
    if not isinstance(limits, PoseLimits):
        raise TypeError(f"limits must be a pose.PoseLimits; got {type(limits).__name__}")
    for name, value in limits._asdict().items():
        if _checks.is_concrete(value) and not np.all(np.asarray(value) > 0):
            raise ValueError(f"limits.{name} must be > 0; got {value}")
