"""Person-following episodes: wall time per estimator, and a closed-loop gradient check.

    python benchmarks/following.py [--episodes 256] [--duration 60] [--estimators kf,pf,gnn]
    python benchmarks/following.py --gradcheck [--episodes 16] [--duration 20]
        [--no-avoidance] [--people K] [--fd-step H]
    python benchmarks/following.py --quick [--gradcheck]

The timing run compiles ``vmap(episode)`` once per estimator for a batch of ``--episodes`` and
reports the compile time, the wall time of the batch, microseconds per 10 Hz step per episode
and simulated seconds per wall second, with the episode metrics (float32). The ``truth``
estimator (the controller given the true user) gives the floor of the following error.

``--gradcheck`` differentiates the mean following RMS error over ``--episodes`` episodes (common
random numbers) with respect to ``log k1``, ``log k2`` (follower gains) and the log measurement
std of the seed-002 KF estimator, by reverse mode, and compares with central finite differences
of the same mean (step ``--fd-step`` in log space).
"""

from __future__ import annotations

import sys
import time

import _common

PACKAGES = ["jaxtrack", "jax", "jaxlib", "numpy", "mujoco", "mujoco-mjx"]


def build(kind, args):
    """(episode function, parameters, config) of the scenario with estimator ``kind``.

    The one place this benchmark calls into `sims.following`.
    """
    from jaxtrack.control import behaviour
    from sims.following import episode, scene

    cfg = episode.EpisodeConfig(scene.build(num_people=8), kind, duration=args.duration,
                                distractors=args.people,
                                behaviour=behaviour.FollowingConfig(
                                    avoidance=not args.no_avoidance))
    return episode.make_episode(cfg), episode.make_params(cfg), cfg


def timing(args):
    import jax
    import numpy as np

    header = _common.header(
        PACKAGES, f"{args.episodes} episodes x {args.duration:.0f} s, 10 Hz, float32, "
        f"{args.people} distractors, avoidance {not args.no_avoidance}")
    print("\n".join(header), flush=True)
    rows = []
    for kind in args.estimators.split(","):
        episode, params, cfg = build(kind, args)
        keys = jax.random.split(jax.random.PRNGKey(args.seed), args.episodes)
        fn = jax.jit(jax.vmap(episode, (0, None)))
        t0 = time.perf_counter()
        compiled = fn.lower(keys, params).compile()
        tc = time.perf_counter() - t0
        jax.block_until_ready(compiled(keys, params))  # warm
        t0 = time.perf_counter()
        m = jax.block_until_ready(compiled(jax.random.split(jax.random.PRNGKey(args.seed + 1),
                                                            args.episodes), params))
        tr = time.perf_counter() - t0
        m = {k: np.asarray(v, float) for k, v in m.items()}
        mota = np.nanmean(m["mota"]) if np.isfinite(m["mota"]).any() else float("nan")
        rows.append(_common.Row((kind,), {
            "compile [s]": tc, "run [s]": tr,
            "us/ep-step": tr / (args.episodes * cfg.num_frames) * 1e6,
            "sim s/s": args.episodes * args.duration / tr,
            "follow RMS": f"{m['following_rms'].mean():.3f}",
            "lost": f"{m['lost_fraction'].mean():.1%}", "MOTA": f"{mota:.1%}"}))
        print(f"{kind}: compile {tc:.1f} s, run {tr:.1f} s", file=sys.stderr, flush=True)
    header.append(_common.load_line("end"))
    print("\n" + "\n".join(header) + "\n")
    print(_common.table(["estimator"], rows, ratio=None))


def gradcheck(args):
    import jax
    import jax.numpy as jnp
    import numpy as np

    episode, params, _ = build("kf", args)
    keys = jax.random.split(jax.random.PRNGKey(args.seed), args.episodes)
    names = ("log k1", "log k2", "log r (KF)")

    def with_theta(theta):
        return params._replace(
            follower=params.follower._replace(log_k1=theta[0], log_k2=theta[1]),
            estimator=params.estimator._replace(log_r=theta[2]))

    @jax.jit
    def loss(theta):
        m = jax.vmap(episode, (0, None))(keys, with_theta(theta))
        return jnp.mean(m["following_rms"])

    print("\n".join(_common.header(PACKAGES)), flush=True)
    theta0 = jnp.stack([params.follower.log_k1, params.follower.log_k2,
                        params.estimator.log_r])
    t0 = time.perf_counter()
    g = np.asarray(jax.jit(jax.grad(loss))(theta0))
    t_ad = time.perf_counter() - t0
    fd = _common.central_differences(loss, theta0, args.fd_step)
    print(f"\nclosed-loop gradient of the mean following RMS over {args.episodes} episodes x "
          f"{args.duration:.0f} s (KF estimator, {args.people} distractors, avoidance "
          f"{not args.no_avoidance}; AD {t_ad:.0f} s incl. "
          f"compile; FD step {args.fd_step} in log space)")
    print(_common.gradient_table(names, g, fd)[0])


def main(argv=None):
    ap = _common.parser(__doc__, gradcheck="reverse-mode gradient vs central finite "
                        "differences (see the module notes)")
    ap.sized("--episodes", 256, 8, "episodes per batch", gradcheck=(16, 2))
    ap.sized("--duration", 60.0, 10.0, "simulated seconds per episode", type=float,
             gradcheck=(20.0, 2.0))
    ap.add_argument("--estimators", default="kf,pf,gnn,jpda,nn_jpda,truth",
                    help="comma-separated estimator kinds to time")
    ap.add_argument("--people", type=int, default=4, help="distractors (default 4)")
    ap.add_argument("--fd-step", type=float, default=0.05,
                    help="finite-difference step in log space (default 0.05)")
    ap.add_argument("--no-avoidance", action="store_true",
                    help="without the dynamic-window layer")
    args = ap.parse_args(argv)
    return _common.report(gradcheck if args.gradcheck else timing, args)


if __name__ == "__main__":
    main()
