r"""Linear model-predictive walking pattern generator with automatic footstep placement
(Herdt et al. 2010, "Online walking motion generation with automatic footstep placement"; the
generator seed 000 drives its robot with, section 4).

Model: the CoM at constant height :math:`h` follows the cart-table model with piecewise-constant
jerk over samples of :math:`T` (per horizontal axis, state :math:`\hat c = (c, \dot c, \ddot c)`),
and the ZMP is :math:`z = c - \tfrac{h}{g}\ddot c`. Over a horizon of :math:`N` samples the
positions, velocities and ZMPs are affine in the jerks :math:`\dddot C`:
:math:`\dot C = P_{vs}\hat c + P_{vu}\dddot C`, :math:`Z = P_{zs}\hat c + P_{zu}\dddot C`
(`preview_matrices`). The QP of Herdt et al. (their eq. 20) is

.. math::
    \min\ \tfrac{\alpha}{2}\|\dddot C\|^2 + \tfrac{\beta}{2}\|\dot C - \dot C^{ref}\|^2
    + \tfrac{\gamma}{2}\|Z - Z^{ref}\|^2

over the jerks and the positions of the next :math:`m` footsteps, with the ZMP at each sample
inside the (rotated) sole of the foot then in support and each footstep inside a rectangle
placed on the previous foot, rotated by its yaw. The yaws over the horizon come from the
reference heading (the seed: "the reference orientation is used to express the inequality
constraints that define the admissible region to place the next footstep"), so every
constraint is linear. :math:`Z^{ref}` is the centre of the support foot.

Variables. Because :math:`P_{zu}` is invertible, we optimise the ZMP instead of the jerk, and
write both the ZMP and the footsteps in local coordinates: :math:`z_j = F_{k(j)} +
R(\theta_{k(j)}) d_j` (:math:`d_j` the ZMP in the frame of the foot :math:`k(j)` supporting
sample :math:`j`) and :math:`F_i = F_{i-1} + R(\theta_{i-1}) \delta_i` (:math:`\delta_i` step
:math:`i` in the frame of the foot before it). The ZMP polygon and the footstep region, both
rectangles, become bounds on :math:`(d, \delta)`: a box QP, solved by a fixed number of primal
active-set iterations (`jaxtrack.control.qp`), so the generator jits, vmaps and
differentiates. The cost is Herdt's, rewritten with
:math:`\dddot C = P_{zu}^{-1}(Z - P_{zs}\hat c)`, plus a small ``step_weight`` pull of each
:math:`\delta_i` to its nominal step (ours: it fixes the footsteps that no sample of the
horizon constrains).

`sims.humanoid.gait` runs it in the humanoid's step cycle (planner ``"preview-qp"``), with the
in-place orbit's sway added to the velocity reference and a narrow lateral ZMP band;
measurements, and where it falls short of the DCM planner (sideways walking):
docs/humanoid_preview_qp.md.

The sample :math:`j` (ending :math:`(j + 1) T` from now) is supported by foot
:math:`k(j) = \lfloor (\phi + (j + 1) T) / T_{step} - \epsilon \rfloor` (:math:`\phi` the
time into the current step): foot 0 is the one in support now, foot 1 the swing foot's
landing. Single support only: the support switches at the step boundary.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack.control import qp

Array = jax.Array

__all__ = ["PreviewConfig", "StepConstraints", "Plan", "preview_matrices", "num_steps",
           "support_index", "plan"]

_G = 9.81


class PreviewConfig(NamedTuple):
    """The preview QP's horizon, weights and solver (static).

    Attributes:
      sample_period: :math:`T` (s); 0.1 is Herdt et al.'s.
      horizon: :math:`N` samples. Herdt et al. preview 1.6 s, two of HRP-2's 0.8 s steps in
        their implementation's configuration (0.7 s single and 0.1 s double support, CoM at
        0.814 m), with :math:`\\omega N T = 5.6` pendulum time constants; 10 samples preview
        two of our 0.5 s steps, :math:`\\omega N T = 6.3` for a 0.25 m CoM. Their 16 samples
        would be :math:`\\omega N T = 10`: the ZMP-to-jerk map's condition number grows as
        :math:`e^{\\omega N T}` (2.4e3 at N = 10, 4.6e5 at N = 16), and at 16 the closed
        loop diverged even in float64 (docs/humanoid_preview_qp.md).
      jerk_weight, velocity_weight: :math:`\\alpha, \\beta`; 1e-5 and 1 are the weights of
        Herdt et al.'s implementation (jrl-walkgen).
      zmp_weight: :math:`\\gamma`. Theirs is 1e-6; ours is 1, because with a negligible
        :math:`\\gamma` moving a footstep and the ZMP offsets on it in opposite directions
        costs almost nothing, the Hessian's condition number passes 1e11 and float32 solves
        fail (NaN); at 1 a model-predictive walk tracks 0.1 m/s within 2 % in float64 and 4 %
        in float32.
      step_weight: pull of each step to its nominal one (ours; small).
      iterations: active-set iterations per solve (`qp.solve_box_qp`), warm-started from the
        last solve; 10 is ours.
    """

    sample_period: float = 0.1
    horizon: int = 10
    jerk_weight: float = 1e-5
    velocity_weight: float = 1.0
    zmp_weight: float = 1.0
    step_weight: float = 1e-3
    iterations: int = 10


class StepConstraints(NamedTuple):
    """The feasible regions (m, in the foot's frame; defaults ours, for a NAO-sized robot).

    Attributes:
      step_period: :math:`T_{step}` (s), the duration of one single-support phase.
      zmp_half_length, zmp_half_width: the ZMP's box about the ankle (the sole less margins).
      max_stride: largest forward or backward step, :math:`|\\delta_x|`.
      min_lateral, max_lateral: range of the step's lateral offset towards its own side,
        :math:`s\\,\\delta_y \\in [\\text{min}, \\text{max}]` (feet never cross).
    """

    step_period: float = 0.5
    zmp_half_length: float = 0.04
    zmp_half_width: float = 0.025
    max_stride: float = 0.08
    min_lateral: float = 0.08
    max_lateral: float = 0.15


class Plan(NamedTuple):
    """One solve of the preview QP (world frame unless stated).

    Attributes:
      jerk: [N, 2] CoM jerk per sample; apply ``jerk[0]`` until the next solve.
      zmp: [N, 2] ZMP at the end of each sample; com: [N, 2] CoM there.
      footsteps: [m, 2] the next footsteps (``footsteps[0]``: the swing foot's landing).
      zmp_local: [N, 2] the ZMP in its support foot's frame; steps_local: [m, 2] each step in
        the previous foot's frame (both inside their boxes).
      support: [N] int, the foot supporting each sample (0: the current one).
      solution: the `qp.BoxQPSolution` (for warm starts and its residual).
    """

    jerk: Array
    zmp: Array
    com: Array
    footsteps: Array
    zmp_local: Array
    steps_local: Array
    support: Array
    solution: qp.BoxQPSolution


def preview_matrices(sample_period: float, horizon: int, com_height: float) -> dict:
    """The cart-table prediction matrices (float64 numpy): ``Pps, Ppu`` (position), ``Pvs,
    Pvu`` (velocity), ``Pzs, Pzu`` (ZMP); ``X = Ps @ c_hat + Pu @ jerks`` per axis, rows for
    samples 1..N. Built by iterating the exact discretisation
    :math:`\\hat c_{k+1} = A\\hat c_k + B\\dddot c_k`."""
    T, N = float(sample_period), int(horizon)
    A = np.array([[1.0, T, T * T / 2], [0.0, 1.0, T], [0.0, 0.0, 1.0]])
    B = np.array([T ** 3 / 6, T * T / 2, T])
    Ps = np.zeros((N, 3, 3))
    Pu = np.zeros((N, 3, N))
    s, u = np.eye(3), np.zeros((3, N))
    for i in range(N):
        s, u = A @ s, A @ u
        u[:, i] += B
        Ps[i], Pu[i] = s, u
    hg = com_height / _G
    out = {"Pps": Ps[:, 0], "Ppu": Pu[:, 0], "Pvs": Ps[:, 1], "Pvu": Pu[:, 1]}
    out["Pzs"] = Ps[:, 0] - hg * Ps[:, 2]
    out["Pzu"] = Pu[:, 0] - hg * Pu[:, 2]
    return out


def num_steps(config: PreviewConfig, step_period: float) -> int:
    """m, the most footsteps a horizon can start (the current step has just begun)."""
    return int(math.ceil(config.horizon * config.sample_period / step_period - 1e-9))


def support_index(phase: Array, config: PreviewConfig, step_period: float) -> Array:
    """[N] int: the foot supporting each sample (0: the current support foot), from the time
    ``phase`` into the current step."""
    t = (jnp.arange(1, config.horizon + 1) * config.sample_period)
    k = jnp.floor((phase + t) / step_period - 1e-6).astype(jnp.int32)
    return jnp.clip(k, 0, num_steps(config, step_period))


def plan(com: Array, support: Array, support_yaw: Array, side: Array, phase: Array,
         step_yaws: Array, velocity_ref: Array, com_height: float,
         config: PreviewConfig = PreviewConfig(),
         constraints: StepConstraints = StepConstraints(),
         warm_start: qp.BoxQPSolution | None = None) -> Plan:
    """Solve the preview QP once (module notes). Pure; vmap for batches.

    Args:
      com: [3, 2] CoM position, velocity and acceleration (world x, y).
      support: [2] the support foot; support_yaw: its yaw; side: +1 if it is the left foot.
      phase: time into the current step (s), in [0, step_period).
      step_yaws: [m] yaws of the next m footsteps (from the reference heading).
      velocity_ref: [N, 2] reference CoM velocity at the end of each sample (world).
      com_height: :math:`h` (m).
      config: `PreviewConfig` (static); constraints: `StepConstraints`.
      warm_start: a previous `Plan.solution`.

    Returns:
      `Plan`.

    Example:
      >>> cfg = PreviewConfig()
      >>> m = num_steps(cfg, 0.5)
      >>> p = plan(jnp.zeros((3, 2)), jnp.array([0.0, -0.05]), 0.0, -1.0, 0.0, jnp.zeros(m),
      ...          jnp.tile(jnp.array([0.1, 0.0]), (cfg.horizon, 1)), 0.25)
    """
    dtype = jnp.result_type(com, float)
    N, T = config.horizon, config.sample_period
    m = num_steps(config, constraints.step_period)
    mats = preview_matrices(T, N, com_height)
    M = np.linalg.inv(mats["Pzu"])                            # jerks = M (Z - Pzs c_hat)
    Wv = mats["Pvu"] @ M                                      # velocities from ZMPs
    Q = config.jerk_weight * M.T @ M + config.velocity_weight * Wv.T @ Wv
    cst = lambda a: jnp.asarray(a, dtype)                     # noqa: E731
    com = jnp.asarray(com, dtype)
    support = jnp.asarray(support, dtype)
    side = jnp.asarray(side, dtype)
    # Affine maps per axis: jerk = M Z - jerk0; velocity = Wv Z + vel0.
    jerk0 = cst(M @ mats["Pzs"]) @ com                        # [N, 2]
    vel0 = cst(mats["Pvs"] - Wv @ mats["Pzs"]) @ com          # [N, 2]
    # The ZMP's map from the local variables u = (d [N, 2], delta [m, 2]): Z = F0 + G u.
    k = support_index(phase, config, constraints.step_period)            # [N]
    yaws = jnp.concatenate([jnp.asarray(support_yaw, dtype)[None],
                            jnp.asarray(step_yaws, dtype)])              # [m + 1]
    c, s = jnp.cos(yaws), jnp.sin(yaws)
    rot = jnp.stack([jnp.stack([c, -s], -1), jnp.stack([s, c], -1)], -2)  # [m + 1, 2, 2]
    Gd = rot[k]                                                           # [N, 2, 2]
    taken = (jnp.arange(1, m + 1)[None, :] <= k[:, None]).astype(dtype)   # [N, m]
    Gs = taken[:, :, None, None] * rot[None, :m]                          # [N, m, 2, 2]
    n_d, n_s = 2 * N, 2 * m
    # Dense G [2N (axis-major), 2N + 2m], with u laid out as (d_x, d_y, delta_x, delta_y).
    G_d = jnp.einsum("jab,jl->ajbl", Gd, jnp.eye(N, dtype=dtype)).reshape(2 * N, n_d)
    G_s = jnp.einsum("jiab->ajbi", Gs).reshape(2 * N, n_s)
    G = jnp.concatenate([G_d, G_s], 1)
    Qb = jnp.kron(jnp.eye(2, dtype=dtype), cst(Q))                       # [2N, 2N]
    # Linear term of the ZMP cost at Z: Q Z - M^T a jerk0 + Wv^T b (vel0 - vref), per axis.
    lin = (-config.jerk_weight * cst(M.T) @ jerk0
           + config.velocity_weight * cst(Wv.T) @ (vel0 - jnp.asarray(velocity_ref, dtype)))
    F0 = jnp.broadcast_to(support, (N, 2))
    qz = Qb @ F0.T.reshape(-1) + lin.T.reshape(-1)
    # Nominal steps: in place, at the middle of the lateral range.
    step_side = side * (-1.0) ** jnp.arange(1, m + 1, dtype=dtype)                   # [m]
    nominal_y = step_side * 0.5 * (constraints.min_lateral + constraints.max_lateral)
    nominal = jnp.stack([jnp.zeros(m, dtype), nominal_y], -1)
    reg = jnp.concatenate([jnp.full(n_d, config.zmp_weight, dtype),
                           jnp.full(n_s, config.step_weight, dtype)])
    H = G.T @ Qb @ G + jnp.diag(reg)
    H = 0.5 * (H + H.T)
    g = G.T @ qz - jnp.concatenate([jnp.zeros(n_d, dtype),
                                    config.step_weight * nominal.T.reshape(-1)])
    hl, hw = constraints.zmp_half_length, constraints.zmp_half_width
    lat_lo = jnp.where(step_side > 0, constraints.min_lateral, -constraints.max_lateral)
    lat_hi = jnp.where(step_side > 0, constraints.max_lateral, -constraints.min_lateral)
    lower = jnp.concatenate([jnp.full(N, -hl, dtype), jnp.full(N, -hw, dtype),
                             jnp.full(m, -constraints.max_stride, dtype), lat_lo])
    upper = jnp.concatenate([jnp.full(N, hl, dtype), jnp.full(N, hw, dtype),
                             jnp.full(m, constraints.max_stride, dtype), lat_hi])
    sol = qp.solve_box_qp(H, g, lower, upper, config.iterations,
                          x0=None if warm_start is None else warm_start.x)
    u = sol.x
    zmp = (F0.T.reshape(-1) + G @ u).reshape(2, N).T                     # [N, 2]
    jerk = cst(M) @ zmp - jerk0
    com_pred = cst(mats["Pps"]) @ com + cst(mats["Ppu"]) @ jerk
    d_local = u[:n_d].reshape(2, N).T
    steps_local = u[n_d:].reshape(2, m).T
    footsteps = support + jnp.cumsum(jnp.einsum("iab,ib->ia", rot[:m], steps_local), 0)
    return Plan(jerk, zmp, com_pred, footsteps, d_local, steps_local, k, sol)
