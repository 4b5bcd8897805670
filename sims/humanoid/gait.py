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

Planners. The footstep rule above is the default (``planner="dcm"``). ``"preview-qp"`` is the
seed's own generator, Herdt et al.'s preview QP (`jaxtrack.control.walking_mpc`): solved every
0.1 s from the CoM's position, velocity and acceleration, its first jerk drives the CoM (the
cart-table model instead of the LIPM over a point foot) and its next footstep is the swing
foot's target. It tracks forward speeds and turns as well, and fast sideways commands a third
slow; measurements against the DCM planner: docs/humanoid_preview_qp.md.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxtrack import geometry
from jaxtrack.angles import wrap
from jaxtrack.control import walking_mpc
from sims.humanoid.scene import Scene

Array = jax.Array

__all__ = ["GaitParams", "GaitState", "PLANNERS", "preview_planner", "step_constraints", "init",
           "step", "solve_schedule", "qpos", "torso_pose", "feet"]

PLANNERS = ("dcm", "preview-qp")

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
      com_acc: [2] CoM acceleration (the preview QP's state; the LIPM's with the DCM planner).
      com_jerk: [2] the preview QP's jerk, held over its sample period.
      warm: [n] the preview QP's last solution (its warm start); [0] with the DCM planner.
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
    com_acc: Array
    com_jerk: Array
    warm: Array


def _omega(params):
    return jnp.sqrt(_G / params.com_height)


def preview_planner(planner) -> walking_mpc.PreviewConfig | None:
    """The footstep planner: None or ``"dcm"`` for the deadbeat DCM planner (module notes),
    ``"preview-qp"`` for Herdt et al.'s preview QP with its default `walking_mpc.PreviewConfig`,
    or a `walking_mpc.PreviewConfig`."""
    if planner is None or planner == "dcm":
        return None
    if planner == "preview-qp":
        return walking_mpc.PreviewConfig()
    if isinstance(planner, walking_mpc.PreviewConfig):
        return planner
    raise ValueError(f"unknown planner {planner!r}; expected one of {PLANNERS} or a "
                     "walking_mpc.PreviewConfig")


def step_constraints(params: GaitParams = GaitParams()) -> walking_mpc.StepConstraints:
    """The preview QP's feasible regions for these gait parameters (ours): strides up to
    ``max_stride`` forward or back; lateral offsets from 2 cm inside the nominal foot
    separation to ``max_stride`` outside it (so a 0.1 m/s sideways walk is feasible); the ZMP
    within 4 cm of the ankle along the foot and 0.5 cm across it.

    Why so narrow across: with the sole's +-2.5 cm, the QP met a slow sideways command within
    its one-second horizon by shifting the CoM inside the sole instead of stepping, and the
    robot walked 0.01 m/s sideways at 0.0038 m/s; with +-0.5 cm at 0.0091 m/s, and the 15 x 64
    run's success rose from 71.4 % to 90.2 % (docs/humanoid_preview_qp.md)."""
    return walking_mpc.StepConstraints(
        step_period=params.step_period, max_stride=params.max_stride,
        min_lateral=params.foot_separation - 0.02,
        max_lateral=params.foot_separation + params.max_stride, zmp_half_width=0.005)


def solve_schedule(substep: Array, dt: float, planner) -> Array | None:
    """Whether the preview QP is solved at sub-step ``substep`` (counted from the gait's first
    `step` after `init`, which lands a step): every ``sample_period / dt`` sub-steps, the
    schedule the gait follows from its phase while it walks. None for the DCM planner. Pass it
    as `step`'s ``solve`` when the sub-step count is unbatched."""
    planner = preview_planner(planner)
    if planner is None:
        return None
    per_sample = round(planner.sample_period / dt)
    if abs(per_sample * dt - planner.sample_period) > 1e-9:
        raise ValueError(f"the QP's sample period {planner.sample_period} s must be a multiple "
                         f"of the sub-step {dt} s")
    return substep % per_sample == 0


def _num_qp_variables(planner, params):
    if planner is None:
        return 0
    return 2 * (planner.horizon + walking_mpc.num_steps(planner, params.step_period))


def init(pose: Array, params: GaitParams = GaitParams(), dtype=jnp.float32,
         planner=None) -> GaitState:
    """A robot at ``pose`` (x, y, theta), on the in-place periodic orbit, about to put its
    weight on the left foot (the right-support step is just ending). ``planner``: see
    `preview_planner`.

    Example:
      >>> state = init(jnp.zeros(3))
    """
    planner = preview_planner(planner)
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
                     standing=jnp.asarray(False), com_acc=(w * w * (xy - left)).astype(dtype),
                     com_jerk=jnp.zeros(2, dtype),
                     warm=jnp.zeros(_num_qp_variables(planner, params), dtype))


def step(key: Array, state: GaitState, body_velocity: Array, turn_rate: Array, stop: Array,
         params: GaitParams = GaitParams(), dt=0.05, planner=None, solve=None) -> GaitState:
    """Advance the gait by ``dt`` under a command (one sub-step of a control period).

    Args:
      key: PRNG key (execution noise of a step starting now).
      state: `GaitState`.
      body_velocity: [2] commanded (forward, lateral) velocity in the robot frame (m/s).
      turn_rate: commanded heading rate (rad/s).
      stop: bool, the controller has stopped: finish the step, then stand.
      params: `GaitParams`; dt: sub-step (s), a divisor of the step period.
      planner: the footstep planner (`preview_planner`; static): the deadbeat DCM planner
        (default), or the preview QP, solved again at each of its sample instants (a
        model-predictive loop at 1 / sample_period) from the CoM's position, velocity and
        acceleration: the swing foot heads for the plan's next footstep, and the CoM follows
        the plan's first jerk until the next solve.
      solve: optional bool, unbatched: whether this sub-step is one of the QP's sample
        instants. The gait knows that from its phase; a caller whose episodes share their step
        timing can pass it so that ``lax.cond`` skips the solve in between under ``vmap``
        (with the phase alone, a batch computes the solve at every sub-step and discards it).
        It must agree with the phase's schedule.

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
    acc0 = jnp.where(switch, geometry.rotate(d_head, state.com_acc), state.com_acc)
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
    qp_plan = preview_planner(planner)
    if qp_plan is not None:
        # --- preview QP: the next footsteps and the CoM's jerk over the horizon -------------
        # Solved at the QP's sample instants; the jerk is held in between, as the model has it.
        due = solve_schedule(jnp.round(phase / dt).astype(jnp.int32), dt, qp_plan)

        def solve_qp(_):
            return _preview_step(qp_plan, params, com0, vel0, acc0, support, support_yaw, side,
                                 phase, heading_next, v, turn_rate, state.warm)

        if solve is None:
            jerk_n, landing_qp, warm_n = solve_qp(None)
        else:
            jerk_n, landing_qp, warm_n = jax.lax.cond(
                solve, solve_qp, lambda _: (state.com_jerk, swing_target, state.warm), None)
        jerk = jnp.where(due, jerk_n, state.com_jerk)
        warm = jnp.where(due, warm_n, state.warm)
        swing_target = jnp.where(standing | ~due, swing_target, landing_qp)
        com_n = com0 + vel0 * dt + acc0 * dt ** 2 / 2 + jerk * dt ** 3 / 6
        vel_n = vel0 + acc0 * dt + jerk * dt ** 2 / 2
        acc_n = acc0 + jerk * dt
    else:
        # --- DCM planner: the LIPM over the support foot --------------------------------
        ch, sh = jnp.cosh(w * dt), jnp.sinh(w * dt)
        rel = com0 - support
        com_n = support + rel * ch + vel0 / w * sh
        vel_n = rel * w * sh + vel0 * ch
        acc_n = w * w * (com_n - support)
        warm, jerk = state.warm, state.com_jerk
    # --- standing: the CoM glides to the middle of the feet ----------------------------------
    mid = 0.5 * (support + swing_target)
    a = 1.0 - jnp.exp(-dt / params.stand_time)
    com_stand = com0 + a * (mid - com0)
    com = jnp.where(standing, com_stand, com_n)
    com_vel = jnp.where(standing, (com_stand - com0) / dt, vel_n)
    com_acc = jnp.where(standing, 0.0, acc_n)
    phase = jnp.where(standing, T, jnp.minimum(phase + dt, T))
    return GaitState(com.astype(dtype), com_vel.astype(dtype), support, support_yaw,
                     swing_start, swing_start_yaw, swing_target, swing_target_yaw, side,
                     phase.astype(dtype), heading, heading_next, standing,
                     com_acc.astype(dtype), jerk.astype(dtype), warm)


def _preview_step(cfg, params, com, vel, acc, support, support_yaw, side, phase,
                  heading_next, body_velocity, turn_rate, warm):
    """One solve of the preview QP (`walking_mpc.plan`): its first jerk, the swing foot's
    landing and the solution (the next solve's warm start).

    The reference heading turns at the commanded rate (clipped to ``max_turn`` per step),
    reaching ``heading_next`` at the end of the current step: the footsteps' yaws follow it
    step by step, and the reference velocity is the body-frame command rotated by it."""
    dtype = com.dtype
    T = params.step_period
    m = walking_mpc.num_steps(cfg, T)
    turn = jnp.clip(turn_rate * T, -params.max_turn, params.max_turn)
    step_yaws = heading_next + turn * jnp.arange(m, dtype=dtype)
    t = phase + jnp.arange(1, cfg.horizon + 1, dtype=dtype) * cfg.sample_period
    theta = heading_next + turn * (t - T) / T
    # The reference adds the lateral sway velocity of the in-place periodic orbit (point feet,
    # `init`) to the command: Herdt's cost on the instantaneous velocity otherwise trades the
    # commanded sideways speed for less sway (0.05 m/s sideways came out at 0.0066 m/s, and
    # 0.035 m/s with this reference; docs/humanoid_preview_qp.md).
    k = jnp.floor(t / T - 1e-6)
    tau = t - k * T
    w = _omega(params)
    sway = (-side * (-1.0) ** k * 0.5 * params.foot_separation * w
            * jnp.sinh(w * (tau - 0.5 * T)) / jnp.cosh(0.5 * w * T))
    c, s = jnp.cos(theta), jnp.sin(theta)
    vx, vy = body_velocity[0], body_velocity[1] + sway
    vref = jnp.stack([c * vx - s * vy, s * vx + c * vy], -1)
    # Warm start: the last solve's solution moved one sample on (and one step on after a
    # landing), so that each variable means what it meant then.
    N = cfg.horizon
    d = warm[:2 * N].reshape(2, N)
    d = jnp.concatenate([d[:, 1:], d[:, -1:]], 1)
    st = warm[2 * N:].reshape(2, m)
    moved = jnp.concatenate([st[:, 1:], st[:, -1:] * jnp.asarray([[1.0], [-1.0]], dtype)], 1)
    st = jnp.where(phase == 0, moved, st)
    warm = jnp.concatenate([d.reshape(-1), st.reshape(-1)])
    warm_start = walking_mpc.qp.BoxQPSolution(warm, jnp.zeros((), dtype),
                                              jnp.ones(warm.shape, bool))
    plan = walking_mpc.plan(jnp.stack([com, vel, acc]), support, support_yaw, side, phase,
                            step_yaws, vref, params.com_height, cfg, step_constraints(params),
                            warm_start)
    return plan.jerk[0], plan.footsteps[0], plan.solution.x


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
