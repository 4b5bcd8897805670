"""Person following in the shop: every user estimator on the same episodes, paired.

    python benchmarks/following_acceptance.py [--episodes 256] [--duration 60]
        [--estimators truth,pf,pf_hm,pf_laser,pf_rgbd,jpda,jpda_app,nn_jpda_app]
        [--point A] [--layout shop] [--quick] [--out FILE]

The scenario is `sims.following.episode.scenario` (4 distractor shoppers); every estimator
runs the same keys, so the per-episode differences are paired. The table gives, per
estimator, the mean of the per-episode following RMS, the RMS over all frames ("pooled"),
both as multiples of the ``truth`` row (the floor: perfect perception), the fraction of frames
the user is lost (estimate > 0.5 m from them), user switches per episode and MOTA. The pairs
after it are the paired differences (95 % CI, normal approximation) that seed 004's claim and
the PF's variants are judged by.

Estimator names: those of `jaxtrack.tracking.user.CONFIGS`, plus ``pf_hm`` (the PF's crowd
fix of the clustering threshold), ``pf_laser`` / ``pf_rgbd`` (the PF on one sensor),
``jpda_app`` / ``nn_jpda_app`` (with the RGB-D colour), ``jpda_imm`` / ``nn_jpda_app_imm``
(their tracker with the walking / standing IMM, ``TrackerConfig(motion="imm")``). The table also
gives IDF1 and HOTA, and the pairs the differences of user switches, MOTA, IDF1 and HOTA.
"""

from __future__ import annotations

import dataclasses
import sys
import time

import _common

PACKAGES = ["jaxtrack", "jax", "jaxlib", "mujoco", "mujoco-mjx"]

PAIRS = [("pf", "pf_laser"), ("pf", "pf_rgbd"), ("pf_hm", "pf"), ("jpda_app", "jpda"),
         ("nn_jpda_app", "jpda_app"), ("pf", "jpda_app"), ("jpda_imm", "jpda"),
         ("nn_jpda_app_imm", "nn_jpda_app")]


def configs():
    """Estimator name -> user-estimator configuration."""
    from jaxtrack.tracking import user

    pf = user.ParticleConfig()
    jpda_app = user.MultiTargetConfig(appearance=True)
    nn_jpda = dataclasses.replace(user.TRACKER, association="nn_jpda")
    return {
        **user.CONFIGS,
        "pf_hm": dataclasses.replace(pf, pf=dataclasses.replace(
            pf.pf, threshold_mode="half_mean", threshold_cap=0.6)),
        "pf_laser": user.with_sensors(pf, "laser"),
        "pf_rgbd": user.with_sensors(pf, "rgbd"),
        "jpda_app": jpda_app,
        "nn_jpda_app": dataclasses.replace(jpda_app, tracker=nn_jpda),
        "jpda_imm": user.MultiTargetConfig(
            tracker=dataclasses.replace(user.TRACKER, motion="imm")),
        "nn_jpda_app_imm": dataclasses.replace(
            jpda_app, tracker=dataclasses.replace(nn_jpda, motion="imm")),
    }


def run(args):
    import jax
    import numpy as np

    from sims.following import episode

    names = args.estimators.split(",")
    known = configs()
    unknown = [n for n in names if n not in known]
    if unknown:
        raise SystemExit(f"unknown estimators {unknown}; choose from {sorted(known)}")
    print("\n".join(_common.header(
        PACKAGES, f"{args.layout}, follower {args.point}, {args.episodes} episodes x "
        f"{args.duration:.0f} s, 4 distractors, seed {args.seed}, float32")), flush=True)
    keys = jax.random.split(jax.random.PRNGKey(args.seed), args.episodes)
    metrics, walls = {}, {}
    for name in names:
        cfg = episode.scenario(args.layout, known[name], duration=args.duration)
        params = episode.make_params(cfg, point=args.point)
        fn = jax.jit(jax.vmap(episode.make_episode(cfg), (0, None))).lower(keys, params).compile()
        t0 = time.perf_counter()
        m = jax.block_until_ready(fn(keys, params))
        walls[name] = time.perf_counter() - t0
        metrics[name] = {k: np.asarray(v, float) for k, v in m.items()}
        print(f"{name}: {walls[name]:.1f} s", file=sys.stderr, flush=True)

    def rms_pooled(m):
        return m["following_rms"].mean(), np.sqrt(np.mean(m["following_rms"] ** 2))

    floor = rms_pooled(metrics["truth"]) if "truth" in metrics else None
    rows = []
    for name in names:
        m = metrics[name]
        rms, pooled = rms_pooled(m)
        ratios = ["-", "-"] if floor is None else [f"{rms / floor[0]:.2f}x",
                                                   f"{pooled / floor[1]:.2f}x"]
        ident = []
        for key in ("mota", "idf1", "hota"):
            x = m[key][np.isfinite(m[key])]
            ident.append(f"{x.mean():.1%}" if x.size else "-")
        rows.append([name, f"{rms:.3f}", f"{pooled:.3f}", *ratios,
                     f"{m['lost_fraction'].mean():.1%}", f"{m['user_switches'].mean():.2f}",
                     *ident, f"{walls[name]:.1f}"])
    print(_common.format_table(["estimator", "RMS [m]", "pooled [m]", "RMS / floor",
                                "pooled / floor", "lost", "user switches", "MOTA", "IDF1",
                                "HOTA", "run [s]"], rows))
    print("\nPaired differences (first minus second, mean [95 % CI]; MOTA, IDF1 and HOTA over "
          "the episodes where both are defined):")
    for a, b in PAIRS:
        if a in metrics and b in metrics:
            parts = []
            for key, scale, unit in (("following_rms", 1.0, " m"), ("lost_fraction", 100.0, " %"),
                                     ("user_switches", 1.0, ""), ("mota", 100.0, " %"),
                                     ("idf1", 100.0, " %"), ("hota", 100.0, " %")):
                d = scale * (metrics[a][key] - metrics[b][key])
                d = d[np.isfinite(d)]
                if d.size < 2:
                    continue
                h = 1.96 * d.std(ddof=1) / np.sqrt(d.size)
                parts.append(f"{key} {d.mean():+.3f}{unit} [{d.mean() - h:+.3f}, "
                             f"{d.mean() + h:+.3f}]")
            print(f"- {a} vs {b}: " + "; ".join(parts))


def main(argv=None):
    p = _common.parser(__doc__)
    p.sized("--episodes", 256, 8, "episodes per estimator")
    p.sized("--duration", 60.0, 10.0, "simulated seconds per episode", type=float)
    p.add_argument("--estimators",
                   default="truth,pf,pf_hm,pf_laser,pf_rgbd,jpda,jpda_app,nn_jpda_app")
    p.add_argument("--point", default="A", choices=["A", "B"])
    p.add_argument("--layout", default="shop", choices=["shop", "room"])
    args = p.parse_args(argv)
    _common.report(run, args)


if __name__ == "__main__":
    main()
