"""The service-robot episode: wall time per experiment and per planner setting.

    python benchmarks/service.py [--episodes 64] [--duration 60] [--experiments avoid,tv]
        [--variants default,cell0.2,dense,truth,whole]
    python benchmarks/service.py --quick
    python benchmarks/service.py --profile --episodes 64 --duration 3 --experiments avoid

Each row compiles ``vmap(episode)`` once for a batch of ``--episodes`` and reports the compile
time, the wall time of the batch, microseconds per 10 Hz frame per episode and simulated seconds
per wall second, with the episode's success and MOTA (float32, all sensors). The variants
change what the frame computes, so their ratios to ``default`` show where its time goes:

- ``default``: 0.1 m cells, a full distance-field solve every 2 s, 5 refining rounds a frame
  between;
- ``cell0.2``: 0.2 m cells (a quarter of the cells);
- ``dense``: the planner's schedule before 2026-12-05: a full solve every 0.5 s, 10 refining
  rounds a frame between;
- ``truth``: the behaviour given the true people (the tracker still runs, for the record);
- ``whole``: every full solve over the whole flat, not only until the robot's cell is exact.

The issue's target is 256 episodes x 60 s within 60 s after compilation on 2 cores, i.e.
256 simulated seconds per wall second.

``--profile`` instead runs each experiment's rollout once under ``jax.profiler`` and prints
where a frame's time goes: the XLA operations' times from the trace, summed by the jitted
library function they belong to (the outermost ``jit(...)`` inside the rollout in each
operation's name: e.g. ``_field`` for the distance field's full solve, ``_refine``, ``_build``
for the costmap, ``_sequential`` for the tracker's update, its inner functions included). It
reads the profiler's trace file, whose format belongs to the profiler, not to a stable API.
Keep the runs short (a few seconds of episodes): on a 30 s run the trace held the operations
of only part of the wall time (5.1 s of 13 s), as if the profiler dropped events.
"""

from __future__ import annotations

import dataclasses
import sys
import time

import _common

PACKAGES = ["jaxtrack", "jax", "jaxlib", "numpy", "mujoco", "mujoco-mjx"]

_VARIANTS = {
    "default": {},
    "cell0.2": {"cell": 0.2},
    "dense": {"replan_every": 5, "sweeps": 10},
    "truth": {"perception": "truth"},
    "whole": {"solve_to_robot": False},
}


def build(experiment, variant, args):
    """(episode function, parameters, config): the one place this calls into `sims.service`."""
    from sims.service import episode as ep

    cfg = ep.ServiceConfig(ep.build_scene(), experiment=experiment, duration=args.duration)
    cfg = dataclasses.replace(cfg, **_VARIANTS[variant])
    return ep.make_episode(cfg), ep.make_params(cfg), cfg


def timing(args):
    import jax
    import numpy as np

    header = _common.header(PACKAGES, f"{args.episodes} episodes x {args.duration:.0f} s, "
                            "10 Hz, float32")
    print("\n".join(header), flush=True)
    rows = []
    for experiment in args.experiments.split(","):
        for variant in args.variants.split(","):
            episode, params, cfg = build(experiment, variant, args)
            keys = jax.random.split(jax.random.PRNGKey(args.seed), args.episodes)
            fn = jax.jit(jax.vmap(episode, (0, None)))
            t0 = time.perf_counter()
            compiled = fn.lower(keys, params).compile()
            tc = time.perf_counter() - t0
            t0 = time.perf_counter()
            m = jax.block_until_ready(compiled(keys, params))
            tr = time.perf_counter() - t0
            m = {k: np.asarray(v, float) for k, v in m.items()}
            rows.append(_common.Row((experiment, variant), {
                "compile [s]": tc, "run [s]": tr,
                "us/ep-frame": tr / (args.episodes * cfg.num_frames) * 1e6,
                "sim s/s": args.episodes * args.duration / tr,
                "success": f"{m['success'].mean():.1%}",
                "MOTA": f"{np.nanmean(m['mota']):.1%}"}))
            print(f"{experiment} {variant}: compile {tc:.1f} s, run {tr:.1f} s",
                  file=sys.stderr, flush=True)
    header.append(_common.load_line("end"))
    print("\n" + "\n".join(header) + "\n")
    print(_common.table(["experiment", "variant"], rows, ratio=None))


def profile(args):
    import collections
    import glob
    import gzip
    import json
    import re
    import tempfile

    import jax

    header = _common.header(PACKAGES, f"{args.episodes} episodes x {args.duration:.0f} s, "
                            "10 Hz, float32, one profiled run")
    print("\n".join(header), flush=True)
    for experiment in args.experiments.split(","):
        from sims.service import episode as ep

        cfg = ep.ServiceConfig(ep.build_scene(), experiment=experiment, duration=args.duration)
        fn = jax.jit(jax.vmap(ep.make_rollout(cfg), (0, None)))
        keys = jax.random.split(jax.random.PRNGKey(args.seed), args.episodes)
        params = ep.make_params(cfg)
        compiled = fn.lower(keys, params).compile()
        jax.block_until_ready(compiled(keys, params))
        # the operation -> its JAX name (the HLO's metadata), to group the trace's events
        names = dict(re.findall(r'^\s*(?:ROOT )?%?([\w.\-]+) = .*?metadata=\{op_name="([^"]*)"',
                                compiled.as_text(), re.M))
        with tempfile.TemporaryDirectory() as tmp:
            jax.profiler.start_trace(tmp)
            t0 = time.perf_counter()
            jax.block_until_ready(compiled(keys, params))
            wall = time.perf_counter() - t0
            jax.profiler.stop_trace()
            trace = sorted(glob.glob(f"{tmp}/**/*.trace.json.gz", recursive=True))[-1]
            events = json.load(gzip.open(trace))["traceEvents"]
        stage = collections.Counter()
        for e in events:
            if e.get("ph") == "X" and e["name"] in names:
                jits = [p for p in names[e["name"]].split("/") if p.startswith("jit(")
                        and p != "jit(rollout)"]
                stage[jits[0][4:-1] if jits else "(other)"] += e["dur"] * 1e-6
        frames = args.episodes * cfg.num_frames
        total = sum(stage.values())
        rows = [_common.Row((experiment, name), {
            "s": t, "share": f"{t / total:.0%}", "us/ep-frame": t / frames * 1e6})
            for name, t in stage.most_common(args.top)]
        print(f"\n{experiment}: {wall:.2f} s wall, {wall / frames * 1e6:.0f} us per episode-frame"
              f", {total:.2f} s in the traced operations")
        print(_common.table(["experiment", "stage"], rows, ratio=None))


def main(argv=None):
    ap = _common.parser(__doc__)
    ap.sized("--episodes", 64, 4, "episodes per batch")
    ap.sized("--duration", 60.0, 5.0, "simulated seconds per episode", type=float)
    ap.add_argument("--experiments", default="avoid,tv",
                    help="comma-separated experiments (sims.service.experiments)")
    ap.add_argument("--variants", default="default,cell0.2,dense,truth",
                    help=f"comma-separated variants of {tuple(_VARIANTS)}")
    ap.add_argument("--profile", action="store_true",
                    help="where a frame's time goes, by library function (one traced run)")
    ap.add_argument("--top", type=int, default=15, help="--profile: rows per experiment")
    args = ap.parse_args(argv)
    return _common.report(profile if args.profile else timing, args)


if __name__ == "__main__":
    main()
