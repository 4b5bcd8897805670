"""The timed Monte-Carlo run the scenes' commands share: compile once, evaluate with a progress
bar, and report the compile and run times."""

from __future__ import annotations

import time

import numpy as np

__all__ = ["timed_evaluate"]


def timed_evaluate(episode_fn, params, key, episodes: int, batch_size: int | None = None,
                   progress: bool = True) -> tuple[dict, float, float]:
    """``(metrics, compile_seconds, run_seconds)`` of ``episodes`` episodes of ``episode_fn``
    (`jaxtrack.montecarlo.evaluate`, batches of ``batch_size``, default up to 64); the metrics
    as numpy arrays, one row per episode."""
    from jaxtrack import montecarlo

    bs = min(episodes, batch_size or 64)
    compile_s = montecarlo.warm_up(episode_fn, params, key, bs)
    bar = montecarlo.progress_bar(episodes, disable=not progress)
    t1 = time.perf_counter()
    res = montecarlo.evaluate(episode_fn, params, key, episodes, batch_size=bs, progress=False,
                              on_batch=lambda done, total: bar.update(done - bar.n))
    bar.close()
    run_s = time.perf_counter() - t1
    return {k: np.asarray(v) for k, v in res.metrics.items()}, compile_s, run_s
