"""The service-robot episode: wall time per experiment and per planner setting.

    python benchmarks/service.py [--episodes 64] [--duration 60] [--experiments avoid,tv]
        [--variants default,cell0.2,replan10,truth]
    python benchmarks/service.py --quick

Each row compiles ``vmap(episode)`` once for a batch of ``--episodes`` and reports the compile
time, the wall time of the batch, microseconds per 10 Hz frame per episode and simulated seconds
per wall second, with the episode's success and MOTA (float32, all sensors). The variants
change what the frame computes, so their ratios to ``default`` show where its time goes:

- ``default``: 0.1 m cells, a full distance-field solve every 0.5 s, 10 refining rounds between;
- ``cell0.2``: 0.2 m cells (a quarter of the cells);
- ``replan10``: a full solve every 1 s;
- ``truth``: the behaviour given the true people (the tracker still runs, for the record).

The issue's target is 256 episodes x 60 s within 60 s after compilation on 2 cores, i.e.
256 simulated seconds per wall second.
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
    "replan10": {"replan_every": 10},
    "truth": {"perception": "truth"},
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


def main(argv=None):
    ap = _common.parser(__doc__)
    ap.sized("--episodes", 64, 4, "episodes per batch")
    ap.sized("--duration", 60.0, 5.0, "simulated seconds per episode", type=float)
    ap.add_argument("--experiments", default="avoid,tv",
                    help="comma-separated experiments (sims.service.experiments)")
    ap.add_argument("--variants", default="default,cell0.2,replan10,truth",
                    help=f"comma-separated variants of {tuple(_VARIANTS)}")
    args = ap.parse_args(argv)
    return _common.report(timing, args)


if __name__ == "__main__":
    main()
