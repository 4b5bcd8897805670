"""Person-following episodes: wall time per estimator, and a closed-loop gradient check.

    python benchmarks/following.py [--episodes 256] [--duration 60] [--estimators kf,pf,gnn]
    python benchmarks/following.py --gradcheck [--episodes 16] [--duration 20]
        [--no-avoidance] [--people K] [--fd-step H]

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

import argparse
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from sims.following import episode as ep  # noqa: E402
from sims.following import estimators, scene  # noqa: E402


def timing(args):
    sc = scene.build(num_people=8)
    rows = []
    for kind in args.estimators.split(","):
        cfg = ep.EpisodeConfig(sc, estimators.EstimatorConfig(kind=kind), duration=args.duration)
        params = ep.make_params(cfg)
        keys = jax.random.split(jax.random.PRNGKey(args.seed), args.episodes)
        fn = jax.jit(jax.vmap(ep.make_episode(cfg), (0, None)))
        t0 = time.perf_counter()
        compiled = fn.lower(keys, params).compile()
        tc = time.perf_counter() - t0
        jax.block_until_ready(compiled(keys, params))  # warm
        t0 = time.perf_counter()
        m = jax.block_until_ready(compiled(jax.random.split(jax.random.PRNGKey(args.seed + 1),
                                                            args.episodes), params))
        tr = time.perf_counter() - t0
        m = {k: np.asarray(v, float) for k, v in m.items()}
        us = tr / (args.episodes * cfg.num_frames) * 1e6
        rows.append((kind, tc, tr, us, args.episodes * args.duration / tr, m))
        print(f"{kind}: compile {tc:.1f} s, run {tr:.1f} s", file=sys.stderr, flush=True)
    print(f"\n{args.episodes} episodes x {args.duration:.0f} s, 10 Hz, float32, "
          f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    print(f"{'estimator':<10}{'compile [s]':>12}{'run [s]':>10}{'us/ep-step':>12}"
          f"{'sim s/s':>10}{'follow RMS':>12}{'lost':>8}{'MOTA':>8}")
    for kind, tc, tr, us, rate, m in rows:
        mota = np.nanmean(m["mota"]) if np.isfinite(m["mota"]).any() else float("nan")
        print(f"{kind:<10}{tc:>12.1f}{tr:>10.1f}{us:>12.0f}{rate:>10.0f}"
              f"{m['following_rms'].mean():>12.3f}{m['lost_fraction'].mean():>8.1%}"
              f"{mota:>8.1%}")


def gradcheck(args):
    sc = scene.build(num_people=8)
    cfg = ep.EpisodeConfig(sc, estimators.EstimatorConfig(kind="kf"), duration=args.duration,
                           distractors=args.people,
                           avoidance=not args.no_avoidance)
    params = ep.make_params(cfg)
    episode = ep.make_episode(cfg)
    keys = jax.random.split(jax.random.PRNGKey(args.seed), args.episodes)
    names = ("log k1", "log k2", "log r (KF)")

    def with_theta(theta):
        f = params.follower._replace(log_k1=theta[0], log_k2=theta[1])
        e = params.estimator._replace(kf_log_r=theta[2])
        return ep.EpisodeParams(f, e)

    @jax.jit
    def loss(theta):
        m = jax.vmap(episode, (0, None))(keys, with_theta(theta))
        return jnp.mean(m["following_rms"])

    theta0 = jnp.stack([params.follower.log_k1, params.follower.log_k2,
                        params.estimator.kf_log_r])
    t0 = time.perf_counter()
    g = np.asarray(jax.jit(jax.grad(loss))(theta0))
    t_ad = time.perf_counter() - t0
    h = args.fd_step
    fd = []
    for i in range(3):
        e = jnp.zeros(3).at[i].set(h)
        fd.append(float((loss(theta0 + e) - loss(theta0 - e)) / (2 * h)))
    print(f"\nclosed-loop gradient of the mean following RMS over {args.episodes} episodes x "
          f"{args.duration:.0f} s (KF estimator, {args.people} distractors, avoidance "
          f"{not args.no_avoidance}; AD {t_ad:.0f} s incl. "
          f"compile; FD step {h} in log space)")
    print(f"{'parameter':<14}{'AD':>12}{'FD':>12}{'rel. diff':>12}")
    for n, a, b in zip(names, g, fd):
        print(f"{n:<14}{a:>12.4f}{b:>12.4f}{abs(a - b) / max(abs(b), 1e-12):>12.1%}")


def main():
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--episodes", type=int, default=None)
    p.add_argument("--duration", type=float, default=None)
    p.add_argument("--estimators", default="kf,pf,gnn,jpda,nnjpda,truth")
    p.add_argument("--people", type=int, default=4)
    p.add_argument("--gradcheck", action="store_true")
    p.add_argument("--fd-step", type=float, default=0.05)
    p.add_argument("--no-avoidance", action="store_true",
                   help="gradient check without the dynamic-window layer")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    if args.gradcheck:
        args.episodes = args.episodes or 16
        args.duration = args.duration or 20.0
        gradcheck(args)
    else:
        args.episodes = args.episodes or 256
        args.duration = args.duration or 60.0
        timing(args)


if __name__ == "__main__":
    main()
