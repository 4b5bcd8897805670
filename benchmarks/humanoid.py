"""Benchmark: the seed-000 humanoid reach protocol (15 tasks x N episodes), closed loop in MJX.

Usage: python benchmarks/humanoid.py [--episodes 64] [--tracker pf|pf3|ukf]
       python benchmarks/humanoid.py --gradcheck [--episodes 32] [--frames 60] [--step 0.05]

Prints compile time (first batch) separately from the wall time of the 15 x N evaluation, the
throughput, the machine's load average, and the accuracy table.

Measured (15 x 64 episodes, 128 particles, 80 x 60, 200 frames, on 2 cores shared with other
jobs at a load average of 11-14): pf 129 s after 38 s of compilation (98 s in an earlier run
at load 11), pf3 136 s / 42 s, ukf 132 s / 45 s. Per batch of 64 episodes and frame, the
window render (19 x 19 rays against the robot's geoms) takes 35 ms of the ~40 ms step: the
tracker 2.7 ms, the gait 0.3 ms, kinematics 0.8 ms, point selection 0.4 ms.

``--gradcheck``: the issue's gradient acceptance check. The loss is the mean over ``--episodes``
episodes (fixed keys: common random numbers) of the true final pose error, position (m) plus
heading (rad), after a ``--frames``-frame closed loop of the differentiable variant
(``EpisodeConfig(smooth=True)``: sigmoid-edged count, stop-gradient resampling, smooth stop
gate), task P1 +90 (1 m forward, final heading 90 deg). Its derivatives with respect to the
unconstrained leaves (log lambda_x, log lambda_theta, log propagation std) are computed in
forward mode (`jax.jacfwd`: three tangents, which compiles far faster than reverse mode through
``mjx.kinematics`` and the renderer) and compared with central finite differences of step
``--step`` in those logs (a relative step of the gains and std).

Cause of the earlier failure, found stage by stage (one tracker frame, derivatives with respect
to a rigid move of the robot, mean over 256 keys, AD vs central FD): the derivative of the blob
centroid was 0.04 by AD against about 1 by FD, and that of the PCA heading with respect to the
yaw 0.10 against about 1. A pixel looks along a fixed ray, so AD only sees depths change, not
the silhouette sweep across the pixel grid; the loop's gradient then lost the tracker's
feedback (the gain derivatives came out +1.6 / -1.6 against FD -0.31 / -0.20). The renderer now
moves the pixel grid with the torso in the derivative only (`sensor.robot_point_cloud`), after
which the same stage derivatives are 1.00 / 0.999 and the PF position's 0.345 against FD 0.348.

Result (32 episodes, 128 particles, OT resampling, step 0.05; load average 10.6 on 2 cores):
PASS. log lambda_x AD -0.389 vs FD -0.353 (10.1 %), log lambda_theta -0.188 vs -0.207 (9.2 %),
log position std 0.0247 vs 0.0213 (16.1 %). With 64 episodes and 64 particles, FD steps
0.025 / 0.05 / 0.1 / 0.2 give -0.361 / -0.352 / -0.360 / -0.351 for lambda_x (AD -0.381),
-0.202 / -0.193 / -0.185 / -0.191 for lambda_theta (AD -0.194) and 0.032 / 0.020 / 0.020 /
0.026 for the std (AD 0.017): the std derivative is an order of magnitude smaller than the
gains' and its FD carries most of the noise.
"""

import argparse
import math
import os
import sys
import time


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--episodes", type=int, default=None,
                        help="episodes per task (default 64), or per loss with --gradcheck "
                             "(default 32)")
    parser.add_argument("--tracker", default="pf", choices=("pf", "pf3", "ukf"))
    parser.add_argument("--particles", type=int, default=128)
    parser.add_argument("--gradcheck", action="store_true",
                        help="gradient vs central finite differences (see the module notes)")
    parser.add_argument("--frames", type=int, default=60, help="closed-loop frames (gradcheck)")
    parser.add_argument("--step", type=float, default=0.05,
                        help="finite-difference step in the log parameters (gradcheck)")
    parser.add_argument("--resampling", default="ot", choices=("ot", "stop_gradient"),
                        help="differentiable resampler (gradcheck)")
    args = parser.parse_args(argv)
    if args.gradcheck:
        return gradcheck(args.episodes or 32, args.frames, args.particles, args.step,
                         args.tracker, args.resampling)
    episodes = args.episodes or 64
    from sims.cli import run_humanoid_reach

    load = os.getloadavg()
    out = run_humanoid_reach(episodes, args.tracker, particles=args.particles)
    total = 15 * episodes
    print(f"load average before: {load[0]:.2f}; after: {os.getloadavg()[0]:.2f} "
          f"({os.cpu_count()} cores)")
    print(f"compile + first batch: {out['compile_seconds']:.1f} s; {total} episodes: "
          f"{out['run_seconds']:.1f} s ({total / out['run_seconds']:.1f} episodes/s)")
    return 0


def gradcheck(episodes=32, frames=60, particles=128, step=0.05, tracker="pf",
              resampling="ot", tolerance=0.25):
    """Forward-mode gradient of the mean final pose error vs central finite differences.

    Returns 0 if every derivative is finite and within ``tolerance`` (relative) of its finite
    difference, 1 otherwise.
    """
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxtrack.control import pose as control
    from sims.humanoid import episode, scene

    cfg = episode.EpisodeConfig(scene.build(), tracker=tracker, num_particles=particles,
                                num_frames=frames, smooth=True, smooth_resampling=resampling)
    run = jax.vmap(episode.make_episode(cfg), (0, None))
    base = episode.make_params([1.0, 0.0, math.pi / 2])
    keys = jax.random.split(jax.random.PRNGKey(0), episodes)
    names = ("log lambda_x", "log lambda_theta", "log position std")

    def loss(theta):
        params = base._replace(gains=control.PoseGains(theta[0], theta[1]),
                               log_position_noise=theta[2])
        m = run(keys, params)
        return jnp.mean(m["final_pos_err"] + jnp.deg2rad(m["final_heading_err"]))

    theta0 = jnp.stack([base.gains.log_lambda_x, base.gains.log_lambda_theta,
                        base.log_position_noise])
    load = os.getloadavg()[0]
    value = jax.jit(loss)
    t0 = time.perf_counter()
    f0 = float(value(theta0))
    t_value = time.perf_counter() - t0
    jac = jax.jit(jax.jacfwd(loss))
    t0 = time.perf_counter()
    grad = np.asarray(jac(theta0))
    t_grad = time.perf_counter() - t0
    t0 = time.perf_counter()
    fd = []
    for i in range(3):
        e = jnp.zeros(3, theta0.dtype).at[i].set(step)
        fd.append((float(value(theta0 + e)) - float(value(theta0 - e))) / (2 * step))
    fd = np.asarray(fd)
    t_fd = time.perf_counter() - t0
    rel = np.abs(grad - fd) / np.maximum(np.abs(fd), 1e-12)
    ok = bool(np.all(np.isfinite(grad)) and np.all(rel <= tolerance))
    print(f"gradcheck: {episodes} episodes x {frames} frames ({tracker}, {particles} particles, "
          f"smooth count + {resampling} resampling + smooth stop), task P1 +90; "
          f"loss = mean final |dx| (m) + |dtheta| (rad) = {f0:.4f}")
    print(f"{'parameter':<20}{'forward-mode':>14}{'central FD':>14}{'rel. diff':>11}")
    for n, g, d, r in zip(names, grad, fd, rel):
        print(f"{n:<20}{g:>14.5f}{d:>14.5f}{100 * r:>10.1f}%")
    print(f"FD step {step} in the logs; loss compile + run {t_value:.1f} s, jacfwd compile + "
          f"run {t_grad:.1f} s, 6 FD evaluations {t_fd:.1f} s; load average {load:.2f} "
          f"({os.cpu_count()} cores)")
    print("PASS" if ok else f"FAIL (finite and within {100 * tolerance:.0f} % required)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
