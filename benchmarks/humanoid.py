"""Benchmark: the seed-000 humanoid reach protocol (15 tasks x N episodes), closed loop in MJX.

Usage: python benchmarks/humanoid.py [--episodes 64] [--tracker pf|pf3|ukf]
       python benchmarks/humanoid.py --gradcheck [--episodes 32] [--frames 60] [--step 0.05]
       python benchmarks/humanoid.py --quick [--gradcheck]

Prints compile time (no episode run) separately from the wall time of the 15 x N evaluation, the
throughput, the machine's load average, and the accuracy table.

``--gradcheck``: the issue's gradient acceptance check. The loss is the mean over ``--episodes``
episodes (fixed keys: common random numbers) of the true final pose error, position (m) plus
heading (rad), after a ``--frames``-frame closed loop of the differentiable variant
(``EpisodeConfig(smooth=True)``: sigmoid-edged count, stop-gradient resampling, smooth stop
gate), task P1 +90 (1 m forward, final heading 90 deg). Its derivatives with respect to the
unconstrained leaves (log lambda_x, log lambda_theta, log propagation std) are computed in
forward mode (`jax.jacfwd`: three tangents, which compiles far faster than reverse mode through
``mjx.kinematics`` and the renderer) and compared with central finite differences of step
``--step`` in those logs (a relative step of the gains and std). Measured runs:
``benchmarks/results/humanoid.md``.
"""

import math
import sys
import time

import _common

PACKAGES = ["jaxtrack", "jax", "jaxlib", "numpy", "mujoco", "mujoco-mjx"]


def build(args):
    """(episode function, parameters, config) of the gradient check's scenario: the smooth
    variant, task P1 +90.

    The one place this benchmark calls into `sims.humanoid` (the timing run is the CLI's
    protocol, `sims.cli.run_humanoid_reach`).
    """
    from jaxtrack.tracking import humanoid
    from sims.humanoid import episode, scene

    trackers = {"pf": humanoid.DepthPFConfig(num_particles=args.particles),
                "pf3": humanoid.DepthPF3Config(num_particles=args.particles),
                "ukf": humanoid.CentroidUKFConfig()}
    cfg = episode.EpisodeConfig(scene.build(), tracker=trackers[args.tracker],
                                num_frames=args.frames,
                                smooth=humanoid.SmoothConfig(resampling=args.resampling))
    return episode.make_episode(cfg), episode.make_params([1.0, 0.0, math.pi / 2]), cfg


def timing(args):
    from sims.cli import run_humanoid_reach

    header = _common.header(PACKAGES, f"15 tasks x {args.episodes} episodes, {args.tracker}, "
                            f"{args.particles} particles")
    print("\n".join(header), flush=True)
    out = run_humanoid_reach(args.episodes, args.tracker, particles=args.particles,
                             seed=args.seed)
    total = 15 * args.episodes
    header.append(_common.load_line("end"))
    print("\n" + "\n".join(header) + "\n")
    print(_common.table(["tracker"], [_common.Row((args.tracker,), {
        "compile s": out["compile_seconds"],
        f"{total} episodes s": out["run_seconds"],
        "episodes/s": total / out["run_seconds"]})], ratio=None))
    return 0


def gradcheck(args, tolerance=0.25):
    """Forward-mode gradient of the mean final pose error vs central finite differences.

    Returns 0 if every derivative is finite and within ``tolerance`` (relative) of its finite
    difference, 1 otherwise.
    """
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxtrack.control import pose as control

    episode, base, _ = build(args)
    run = jax.vmap(episode, (0, None))
    keys = jax.random.split(jax.random.PRNGKey(args.seed), args.episodes)
    names = ("log lambda_x", "log lambda_theta", "log position std")

    def loss(theta):
        params = base._replace(gains=control.PoseGains(theta[0], theta[1]),
                               log_position_noise=theta[2])
        m = run(keys, params)
        return jnp.mean(m["final_pos_err"] + jnp.deg2rad(m["final_heading_err"]))

    header = _common.header(PACKAGES)
    print("\n".join(header), flush=True)
    theta0 = jnp.stack([base.gains.log_lambda_x, base.gains.log_lambda_theta,
                        base.log_position_noise])
    value = jax.jit(loss)
    t0 = time.perf_counter()
    f0 = float(value(theta0))
    t_value = time.perf_counter() - t0
    jac = jax.jit(jax.jacfwd(loss))
    t0 = time.perf_counter()
    grad = np.asarray(jac(theta0))
    t_grad = time.perf_counter() - t0
    t0 = time.perf_counter()
    fd = _common.central_differences(value, theta0, args.step)
    t_fd = time.perf_counter() - t0
    text, rel = _common.gradient_table(names, grad, fd, digits=5,
                                       derivative_name="forward-mode",
                                       differences_name="central FD")
    ok = bool(np.all(np.isfinite(grad)) and np.all(rel <= tolerance))
    print(f"\ngradcheck: {args.episodes} episodes x {args.frames} frames ({args.tracker}, "
          f"{args.particles} particles, smooth count + {args.resampling} resampling + smooth "
          f"stop), task P1 +90; loss = mean final |dx| (m) + |dtheta| (rad) = {f0:.4f}")
    print(text)
    print(f"FD step {args.step} in the logs; loss compile + run {t_value:.1f} s, jacfwd "
          f"compile + run {t_grad:.1f} s, 6 FD evaluations {t_fd:.1f} s; "
          + _common.load_line("end"))
    print("PASS" if ok else f"FAIL (finite and within {100 * tolerance:.0f} % required)")
    return 0 if ok else 1


def main(argv=None):
    ap = _common.parser(__doc__, gradcheck="gradient vs central finite differences (see the "
                        "module notes)")
    ap.sized("--episodes", 64, 2, "episodes per task, or per loss with --gradcheck",
             gradcheck=(32, 2))
    ap.add_argument("--tracker", default="pf", choices=("pf", "pf3", "ukf"))
    ap.add_argument("--particles", type=int, default=128)
    ap.sized("--frames", 60, 10, "closed-loop frames (gradcheck)")
    ap.add_argument("--step", type=float, default=0.05,
                    help="finite-difference step in the log parameters (gradcheck)")
    ap.add_argument("--resampling", default="ot", choices=("ot", "stop_gradient"),
                    help="differentiable resampler (gradcheck)")
    args = ap.parse_args(argv)
    return _common.report(gradcheck if args.gradcheck else timing, args)


if __name__ == "__main__":
    sys.exit(main())
