"""Runs a scene's Monte-Carlo evaluation in a fresh process for the reproducibility tests
(``python -m tests.sims._montecarlo_runner SCENE MODE OUT [...]``); writes the metrics as .npz.

Modes:
- ``single``: batch size 8 on the first device, the reference of the other modes;
- ``sizes``: batch sizes 8, 16 and 32 on the first device;
- ``devices``: batch size 16 on every device (run with
  ``XLA_FLAGS=--xla_force_host_platform_device_count=2``);
- ``process PID NPROC PORT``: one of NPROC processes (`jax.distributed.initialize`, CPU);
- ``resumable``: a run saved batch by batch to ``OUT.run.npz`` (to be killed), then
- ``resume``: the same run resumed from that file.

The tests point ``JAX_COMPILATION_CACHE_DIR`` at one folder for every run, so the one-device
program compiles once for all the modes that use it (`_env` of the tests).
"""

import sys

import jax
import numpy as np

EPISODES, BLOCK = 16, 4


def scene(name):
    if name == "humanoid":
        from sims import cli
        from sims.humanoid import episode

        fn = cli._humanoid_episode("pf", 16, 20, (32, 24), 0.5, False)
        return fn, episode.seed_task_params()[3]
    from sims.following import episode, report

    cfg, fn = report._episode("shop", "kf", "laser", 32, False, False, 2, 1.0)
    return fn, episode.make_params(cfg, point="A")


def main(argv):
    name, mode, out = argv[:3]
    if mode == "process":
        pid, nproc, port = int(argv[3]), int(argv[4]), argv[5]
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
        jax.distributed.initialize(coordinator_address=f"localhost:{port}",
                                   num_processes=nproc, process_id=pid)
    from jaxtrack import montecarlo

    fn, params = scene(name)
    key = jax.random.PRNGKey(7)

    def run(**kw):
        res = montecarlo.evaluate(fn, params, key, EPISODES, progress=False, block=BLOCK, **kw)
        return {k: np.asarray(v) for k, v in res.metrics.items()}

    results = {}
    if mode == "sizes":
        for bs in (8, 16, 32):
            results[f"one_{bs}"] = run(batch_size=bs, devices=jax.devices()[:1])
    elif mode == "devices":
        results["all_16"] = run(batch_size=16)
        results["num_devices"] = {"n": np.asarray(len(jax.devices()))}
    elif mode == "single":
        results["one_8"] = run(batch_size=8, devices=jax.devices()[:1])
    elif mode == "process":
        results["run"] = run(batch_size=8)
        out = f"{out}.{pid}"
    elif mode == "resumable":
        run(batch_size=BLOCK, out=out + ".run.npz",
            on_batch=lambda done, total: print("saved", done, flush=True))
        return
    elif mode == "resume":
        results["resumed"] = run(batch_size=BLOCK, out=out + ".run.npz")
    np.savez(out + ".npz", **{f"{k}/{m}": v for k, d in results.items() for m, v in d.items()})


if __name__ == "__main__":
    main(sys.argv[1:])
