"""Behaviour fingerprint: the metrics of both scenes and every estimator on fixed keys, saved
and compared bit for bit, to check that a refactoring preserves behaviour.

    python benchmarks/fingerprint.py --save before.npz [--episodes 64] [--duration 60]
    python benchmarks/fingerprint.py --save after.npz && \\
        python benchmarks/fingerprint.py --compare before.npz after.npz

The runs: person following (every user estimator, the particle filter with each sensor alone,
the multi-target trackers with colour re-identification, follower point B, the truth with no
route and no avoidance), one rollout's per-frame record, the replay of a simulated recording
with each estimator, and the humanoid trackers (pf, pf3, ukf, pf with turn prediction and a
temperature, the smooth variant) on two seed tasks. The comparison prints one line per run:
bit-identical, or the largest difference of each metric that differs.
"""

from __future__ import annotations

import dataclasses
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import _common  # noqa: E402


def following_configs():
    """{run name: (estimator configuration, follower point)}."""
    from jaxtrack.tracking import user

    c = user.CONFIGS
    app = dataclasses.replace
    return {"pf": (c["pf"], "A"), "pf_laser": (user.with_sensors(c["pf"], "laser"), "A"),
            "pf_rgbd": (user.with_sensors(c["pf"], "rgbd"), "A"), "gnn": (c["gnn"], "A"),
            "jpda": (c["jpda"], "A"), "jpda_B": (c["jpda"], "B"), "nn_jpda": (c["nn_jpda"], "A"),
            "jpda_app": (app(c["jpda"], appearance=True), "A"),
            "gnn_app": (app(c["gnn"], appearance=True), "A"), "kf": (c["kf"], "A"),
            "truth": (c["truth"], "A"), "truth_B": (c["truth"], "B")}


def fingerprint(episodes: int, duration: float, seed: int = 0) -> dict:
    """{run/metric: array} of every run (module docstring)."""
    import jax
    import numpy as np

    from jaxtrack import montecarlo
    from jaxtrack.control import behaviour
    from jaxtrack.io import replay
    from jaxtrack.tracking import humanoid, user
    from sims.following import episode as ep
    from sims.following import recording, scene
    from sims.humanoid import episode as hep
    from sims.humanoid import scene as hscene

    out = {}
    key = jax.random.PRNGKey(seed)
    sc = scene.build(num_people=8)

    def following(name, cfg, point):
        t0 = time.perf_counter()
        res = montecarlo.evaluate(ep.make_episode(cfg), ep.make_params(cfg, point=point), key,
                                  episodes, batch_size=min(episodes, 64), progress=False)
        out.update({f"following/{name}/{k}": np.asarray(v) for k, v in res.metrics.items()})
        print(f"following {name}: {time.perf_counter() - t0:.0f} s", file=sys.stderr,
              flush=True)

    for name, (est, point) in following_configs().items():
        following(name, ep.EpisodeConfig(sc, est, duration=duration), point)
    following("truth_noroute", ep.EpisodeConfig(
        sc, user.CONFIGS["truth"], duration=duration,
        behaviour=behaviour.FollowingConfig(route=False, avoidance=False)), "A")
    cfg = ep.EpisodeConfig(sc, dataclasses.replace(user.CONFIGS["jpda"], appearance=True),
                           duration=min(duration, 10.0))
    frames = jax.jit(ep.make_rollout(cfg))(jax.random.fold_in(key, 3), ep.make_params(cfg))
    out.update({f"rollout/{k}": np.asarray(v) for k, v in frames._asdict().items()})
    rec = recording.record(jax.random.fold_in(key, 1), duration=min(duration, 20.0))
    laser, odom, det = recording.to_records(rec)
    for name in ("gnn", "jpda", "nn_jpda", "pf", "kf"):
        tracks = replay.track(laser, odom, det, name, progress=False)
        out.update({f"replay/{name}/{k}": np.asarray(v) for k, v in tracks._asdict().items()})
    hsc = hscene.build()
    turn = humanoid.DepthPFConfig(heading=humanoid.HeadingConfig(turn_prediction=True))
    runs = {"pf": ({}, {}), "pf3": (dict(tracker="pf3"), {}), "ukf": (dict(tracker="ukf"), {}),
            "pf_turn": (dict(tracker=turn), dict(temperature=2.0)),
            "pf_smooth": (dict(smooth=humanoid.SmoothConfig()), {})}
    for name, (cfg_kw, params_kw) in runs.items():
        fn = hep.make_episode(hep.EpisodeConfig(hsc, **cfg_kw))
        for task in (2, 13):
            params = hep.seed_task_params(**params_kw)[task]
            res = montecarlo.evaluate(fn, params, jax.random.fold_in(key, task),
                                      max(episodes // 2, 1), progress=False)
            out.update({f"humanoid/{name}/{task}/{k}": np.asarray(v)
                        for k, v in res.metrics.items()})
        print(f"humanoid {name}", file=sys.stderr, flush=True)
    return out


def compare(before: str, after: str) -> int:
    """Print one line per run; 0 if every array is bit-identical."""
    import numpy as np

    a, b = np.load(before), np.load(after)
    runs: dict[str, list[str]] = {}
    for k in a.files:
        run, metric = k.rsplit("/", 1)
        runs.setdefault(run, [])
        if k not in b.files:
            runs[run].append(f"{metric} (missing)")
            continue
        x, y = a[k], b[k]
        if x.shape != y.shape or x.dtype != y.dtype:
            runs[run].append(f"{metric} ({x.shape} {x.dtype} vs {y.shape} {y.dtype})")
        elif not np.array_equal(x, y, equal_nan=True):
            d = np.nanmax(np.abs(x.astype(float) - y.astype(float)))
            runs[run].append(f"{metric} (max |diff| {d:.3g})")
    rows = [(run, "bit-identical" if not bad else "differs: " + ", ".join(bad[:5]))
            for run, bad in runs.items()]
    print(_common.format_table(("run", "result"), rows, align="ll"))
    return int(any(bad for bad in runs.values()))


def main() -> int:
    p = _common.parser(__doc__)
    p.sized("--episodes", 64, 4, "episodes per person-following run (half per humanoid task)")
    p.sized("--duration", 60.0, 3.0, "seconds per person-following episode", type=float)
    p.add_argument("--save", default=None, help="write the fingerprint to this .npz")
    p.add_argument("--compare", nargs=2, metavar=("BEFORE", "AFTER"), default=None,
                   help="compare two saved fingerprints")
    args = p.parse_args()
    if args.compare:
        return compare(*args.compare)
    if not args.save:
        p.error("give --save FILE or --compare BEFORE AFTER")
    import numpy as np

    print("\n".join(_common.header(("jax", "mujoco"))), flush=True)
    out = fingerprint(args.episodes, args.duration, args.seed)
    np.savez_compressed(args.save, **out)
    print(f"{len(out)} arrays -> {args.save}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
