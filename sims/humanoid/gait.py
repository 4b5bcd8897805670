r"""Walking pattern generator: linear inverted pendulum with footstep placement, stochastic
execution, and leg inverse kinematics (seed 000, section 4).

Why kinematic. Full contact physics of a walking humanoid runs far slower than kinematic posing
(measurements: docs/design_notes.md, "Humanoid: a kinematic walking pattern generator"), and
would need a trained walking policy. The seed's robot walks with a walking pattern generator
too (a preview QP on the LIPM); we keep its *observable* behaviour — a dynamically consistent
CoM that sways sideways at the step frequency, a torso that wobbles in yaw, discrete noisy
footsteps, walking in place near the target — and pose the MJX model kinematically (``qpos``
from this module, geom poses from ``mjx.kinematics``).

Model. The CoM moves at constant height :math:`z_c` over the support foot :math:`p` (LIPM):
:math:`\ddot c = \omega^2 (c - p)`, :math:`\omega = \sqrt{g / z_c}`, integrated in closed form
over each sub-step. Its divergent component of motion :math:`\xi = c + \dot c/\omega` obeys
:math:`\dot\xi = \omega(\xi - p)`. At each step start (period :math:`T`,
:math:`e = e^{\omega T}`), the swing foot's target is chosen so that the DCM is on the periodic
orbit of the commanded walk at the next step start:

.. math::
    p_{k+1} = \xi(T) - R(\theta_{k+1}) \Big(\frac{v_x T}{e - 1},\;
    s_k \frac{w}{1 + e} + \frac{v_y T}{e - 1}\Big),

with :math:`(v_x, v_y)` the commanded body-frame velocity, :math:`w` the foot separation,
:math:`s_k = \pm 1` the side of the current support foot, and
:math:`\theta_{k+1} = \theta_k + \operatorname{clip}(\omega_{cmd} T)`. With no noise this is a
deadbeat DCM controller: the gait reaches the commanded velocity in one step and sways by
:math:`\pm \tfrac{w}{2}(1 - 1/\cosh(\omega T/2))` sideways (about 3 cm with the defaults).

Stochastic execution (per step): at each landing the robot is displaced rigidly (CoM, both feet,
heading) by a stride error :math:`\epsilon_\ell\, v T` (relative step length error), a foot
slip (Gaussian offset) and a heading error :math:`\delta_\theta` (rotation about the landing
foot); the next footstep is planned from the perturbed state, so errors accumulate as drift
that only the closed loop corrects. Near the
target the commanded velocity is small and the robot walks in place (seed section 5.3.1),
still subject to the slip and heading noise. Once the controller has stopped, the current step
is finished and the robot stands: the CoM glides to the middle of the feet.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxtrack import geometry
from jaxtrack.angles import wrap
from sims.humanoid.scene import Scene

Array = jax.Array

__all__ = ["GaitParams", "GaitState", "init", "step", "qpos", "torso_pose", "feet"]

_G = 9.81


class GaitParams(NamedTuple):
    """Walking pattern generator parameters (float leaves; NAO-like defaults, ours).

    Attributes:
      com_height: LIPM height :math:`z_c` (m).
      step_period: :math:`T` (s).
      foot_separation: :math:`w`, lateral distance between the feet (m).
      step_height: swing foot apex (m).
      max_stride: largest stride length per step (m).
      max_turn: largest heading change per step (rad).
      yaw_wobble: torso yaw wobble amplitude (rad), alternating with the support foot.
      arm_swing: shoulder pitch swing amplitude (rad).
      stride_noise: std of the relative stride length error :math:`\\epsilon_\\ell`.
      heading_noise: std of the per-step heading error :math:`\\delta_\\theta` (rad).
      slip_noise: std of the foot slip per step (m, per axis).
      stand_time: time constant of the CoM glide when standing (s).
    """

    com_height: float = 0.25
    step_period: float = 0.5
    foot_separation: float = 0.10
    step_height: float = 0.015
    max_stride: float = 0.08
    max_turn: float = math.radians(20.0)
    yaw_wobble: float = math.radians(3.0)
    arm_swing: float = 0.25
    stride_noise: float = 0.10
    heading_noise: float = math.radians(1.5)
    slip_noise: float = 0.004
    stand_time: float = 0.15


class GaitState(NamedTuple):
    """State of the walking pattern generator (world frame).

    Attributes:
      com, com_vel: [2] CoM position and velocity.
      support, swing_start, swing_target: [2] support foot, swing foot lift-off and landing
        positions (ankle projected on the floor).
      support_yaw, swing_start_yaw, swing_target_yaw: foot yaws.
      side: +1 when the support foot is the left one, -1 for the right.
      phase: time since the step started (s).
      heading, heading_next: walking heading at the start and end of the current step.
      standing: bool, the robot has stopped walking.
    """

    com: Array
    com_vel: Array
    support: Array
    support_yaw: Array
    swing_start: Array
    swing_start_yaw: Array
    swing_target: Array
    swing_target_yaw: Array
    side: Array
    phase: Array
    heading: Array
    heading_next: Array
    standing: Array


def _omega(params):
    return jnp.sqrt(_G / params.com_height)


def init(pose: Array, params: GaitParams = GaitParams(), dtype=jnp.float32) -> GaitState:
    """A robot at ``pose`` (x, y, theta), on the in-place periodic orbit, about to put its
    weight on the left foot (the right-support step is just ending).

    Example:
      >>> state = init(jnp.zeros(3))
    """
    pose = jnp.asarray(pose, dtype)
    xy, th = pose[:2], pose[2]
    half = 0.5 * params.foot_separation
    left = xy + geometry.rotate(th, jnp.array([0.0, half], dtype))
    right = xy + geometry.rotate(th, jnp.array([0.0, -half], dtype))
    w = _omega(params)
    u = half * w * jnp.tanh(0.5 * w * params.step_period)
    zero = jnp.zeros((), dtype)
    return GaitState(com=xy, com_vel=geometry.rotate(th, jnp.stack([zero, u.astype(dtype)])),
                     support=right, support_yaw=th, swing_start=left, swing_start_yaw=th,
                     swing_target=left, swing_target_yaw=th, side=jnp.asarray(-1.0, dtype),
                     phase=jnp.asarray(params.step_period, dtype), heading=th, heading_next=th,
                     standing=jnp.asarray(False))


def step(key: Array, state: GaitState, body_velocity: Array, turn_rate: Array, stop: Array,
         params: GaitParams = GaitParams(), dt=0.05) -> GaitState:
    """Advance the gait by ``dt`` under a command (one sub-step of a control period).

    Args:
      key: PRNG key (execution noise of a step starting now).
      state: `GaitState`.
      body_velocity: [2] commanded (forward, lateral) velocity in the robot frame (m/s).
      turn_rate: commanded heading rate (rad/s).
      stop: bool, the controller has stopped: finish the step, then stand.
      params: `GaitParams`; dt: sub-step (s), a divisor of the step period.

    Returns:
      The new `GaitState`.
    """
    dtype = state.com.dtype
    T = params.step_period
    # --- step switch: the swing foot lands, the next footstep is planned --------------------
    switch = (state.phase >= T - 1e-6) & ~state.standing
    stand = switch & stop
    v = jnp.asarray(body_velocity, dtype)
    k_len, k_head, k_slip = jax.random.split(key, 3)
    # Execution noise: the landing foot slips and the step comes out longer or shorter and
    # turned; the whole robot (CoM, both feet, heading) is displaced rigidly about the landing
    # foot, which keeps the CoM consistent with its feet (a perturbed foot alone would need an
    # e^{omega T} ~ 20x larger recovery step, see the module notes).
    walking = switch & ~stand
    d_head = jnp.where(walking, params.heading_noise * jax.random.normal(k_head, (), dtype), 0.0)
    shift = (params.stride_noise * jax.random.normal(k_len, (), dtype)
             * geometry.rotate(state.heading_next, v * T)
             + params.slip_noise * jax.random.normal(k_slip, (2,), dtype))
    shift = jnp.where(walking, shift, 0.0)
    pivot = state.swing_target + shift

    def rigid(x):
        return pivot + geometry.rotate(d_head, x + shift - pivot)

    com0 = jnp.where(switch, rigid(state.com), state.com)
    vel0 = jnp.where(switch, geometry.rotate(d_head, state.com_vel), state.com_vel)
    new_support = pivot
    new_support_yaw = state.swing_target_yaw + d_head
    swing_from = rigid(state.support)
    swing_from_yaw = state.support_yaw + d_head
    new_side = -state.side
    w = _omega(params)
    e = jnp.exp(w * T)
    xi = com0 + vel0 / w
    xi_T = new_support + (xi - new_support) * e
    turn = jnp.clip(turn_rate * T, -params.max_turn, params.max_turn)
    heading_now = wrap(state.heading_next + d_head)
    heading_next = wrap(heading_now + turn)
    b = jnp.stack([v[0] * T / (e - 1.0),
                   new_side * params.foot_separation / (1.0 + e) + v[1] * T / (e - 1.0)])
    target = xi_T - geometry.rotate(heading_next, b)
    in_place = new_support + geometry.rotate(heading_next, jnp.stack(
        [jnp.zeros((), dtype), -new_side * params.foot_separation]))
    stride = target - in_place
    length = jnp.sqrt(jnp.sum(stride * stride) + 1e-12)
    landing = in_place + stride * jnp.minimum(1.0, params.max_stride / length)
    landing = jnp.where(stand, swing_from, landing)
    landing_yaw = jnp.where(stand, swing_from_yaw, heading_next)
    sel = lambda new, old: jnp.where(switch, new, old)  # noqa: E731
    support = sel(new_support, state.support)
    support_yaw = sel(new_support_yaw, state.support_yaw)
    swing_start = sel(swing_from, state.swing_start)
    swing_start_yaw = sel(swing_from_yaw, state.swing_start_yaw)
    swing_target = sel(landing, state.swing_target)
    swing_target_yaw = sel(landing_yaw, state.swing_target_yaw)
    side = sel(new_side, state.side)
    heading = sel(heading_now, state.heading)
    heading_next = sel(jnp.where(stand, heading_now, heading_next), state.heading_next)
    phase = jnp.where(switch, 0.0, state.phase)
    standing = state.standing | stand
    # --- CoM: LIPM over the support foot, or glide to the middle of the feet ----------------
    ch, sh = jnp.cosh(w * dt), jnp.sinh(w * dt)
    rel = com0 - support
    com_walk = support + rel * ch + vel0 / w * sh
    vel_walk = rel * w * sh + vel0 * ch
    mid = 0.5 * (support + swing_target)
    a = 1.0 - jnp.exp(-dt / params.stand_time)
    com_stand = com0 + a * (mid - com0)
    com = jnp.where(standing, com_stand, com_walk)
    com_vel = jnp.where(standing, (com_stand - com0) / dt, vel_walk)
    phase = jnp.where(standing, T, jnp.minimum(phase + dt, T))
    return GaitState(com.astype(dtype), com_vel.astype(dtype), support, support_yaw,
                     swing_start, swing_start_yaw, swing_target, swing_target_yaw, side,
                     phase.astype(dtype), heading, heading_next, standing)


def _progress(state, params):
    return jnp.clip(state.phase / params.step_period, 0.0, 1.0)


def torso_pose(state: GaitState, params: GaitParams = GaitParams()) -> Array:
    """True torso pose [3] (CoM x, y and torso yaw, wobble included)."""
    s = _progress(state, params)
    heading = state.heading + wrap(state.heading_next - state.heading) * s
    wobble = jnp.where(state.standing, 0.0,
                       params.yaw_wobble * state.side * jnp.sin(jnp.pi * s))
    return jnp.concatenate([state.com, wrap(heading + wobble)[None]])


def feet(state: GaitState, params: GaitParams = GaitParams()) -> tuple[Array, Array]:
    """Left and right foot (x, y, lift, yaw) [2, 4] in the world."""
    s = _progress(state, params)
    blend = 0.5 * (1.0 - jnp.cos(jnp.pi * s))
    swing_xy = state.swing_start + (state.swing_target - state.swing_start) * blend
    swing_yaw = state.swing_start_yaw + wrap(state.swing_target_yaw
                                             - state.swing_start_yaw) * blend
    lift = jnp.where(state.standing, 0.0, params.step_height * jnp.sin(jnp.pi * s))
    zero = jnp.zeros_like(lift)
    support = jnp.concatenate([state.support, zero[None], state.support_yaw[None]])
    swing = jnp.concatenate([swing_xy, lift[None], swing_yaw[None]])
    left_support = state.side > 0
    left = jnp.where(left_support, support, swing)
    right = jnp.where(left_support, swing, support)
    return jnp.stack([left, right])


def qpos(scene: Scene, state: GaitState, params: GaitParams = GaitParams()) -> Array:
    """The MJX model's ``qpos`` [nq] for a gait state (leg IK, arm swing, torso wobble).

    Leg IK (per leg, torso upright): with :math:`d` the hip-to-ankle vector in the hip-yaw
    frame, roll :math:`r = \\operatorname{atan2}(d_y, -d_z)`, knee from the law of cosines
    :math:`L^2 = a^2 + b^2 + 2ab\\cos q_k`, hip pitch
    :math:`\\operatorname{atan2}(-d_x, \\sqrt{d_y^2 + d_z^2}) -
    \\operatorname{atan2}(b \\sin q_k, a + b\\cos q_k)`; the ankle keeps the sole flat.
    """
    body = scene.body
    dtype = state.com.dtype
    pose = torso_pose(state, params)
    psi = pose[2]
    z_root = jnp.asarray(scene.standing_height, dtype)
    q = jnp.zeros((scene.model.nq,), dtype)
    q = q.at[0:2].set(pose[:2]).at[2].set(z_root)
    q = q.at[3].set(jnp.cos(0.5 * psi)).at[6].set(jnp.sin(0.5 * psi))
    ft = feet(state, params)
    a, b = body.thigh, body.shin
    s = _progress(state, params)
    for i, sign in enumerate((1.0, -1.0)):
        hip = pose[:2] + geometry.rotate(psi, jnp.array([0.0, sign * body.hip_offset], dtype))
        d_xy = geometry.rotate(-psi, ft[i, :2] - hip)
        dz = ft[i, 2] + body.ankle_height - z_root
        yaw = wrap(ft[i, 3] - psi)
        d = jnp.concatenate([geometry.rotate(-yaw, d_xy), dz[None]])
        roll = jnp.arctan2(d[1], -d[2])
        vz = jnp.sqrt(d[1] ** 2 + d[2] ** 2)
        L2 = d[0] ** 2 + vz ** 2
        cos_k = jnp.clip((L2 - a * a - b * b) / (2 * a * b), -0.999, 0.999)
        knee = jnp.arccos(cos_k)
        pitch = jnp.arctan2(-d[0], vz) - jnp.arctan2(b * jnp.sin(knee), a + b * jnp.cos(knee))
        angles = jnp.stack([yaw, roll, pitch, knee, -(pitch + knee), -roll])
        q = q.at[scene.leg_qpos[i]].set(angles)
        # Arms swing against the legs: the left arm goes forward with the right foot.
        swing = jnp.where(state.standing, 0.0,
                          params.arm_swing * state.side * sign * jnp.sin(jnp.pi * s))
        q = q.at[scene.arm_qpos[i]].set(jnp.stack([-swing, jnp.asarray(-0.3, dtype)]))
    return q
