r"""Batched Monte-Carlo evaluation of an episode function over keys and devices.

``episode_fn(key, params) -> pytree of per-episode metrics`` is written for *one* episode;
`evaluate` runs it for ``num_episodes`` keys derived from one key. Every compiled call runs one
*block* of episodes per device (``block``, default `DEFAULT_BLOCK`; fewer when there are fewer
episodes), sharded over the episode axis across every device JAX sees (`jax.sharding.Mesh` +
`NamedSharding`); a batch is one or more such calls, and the last call is padded. With several
processes (`jax.distributed.initialize`) the same code shards across hosts: every process
builds the same global batch of keys and contributes its addressable shards.

**Reproducibility.** Episode ``i`` always uses ``jax.random.split(key, num_episodes)[i]`` and
is always computed by the same compiled per-device program (a vmap over ``block`` episodes) at
the same lane, ``i mod block``. A closed loop amplifies float rounding, and XLA rounds a vmap
of 16 episodes differently from one of 32 (a humanoid episode's estimates differed in every
episode between batch sizes 16 and 32 before this rule), so the results of a key are
bit-identical for any ``batch_size`` and any number of devices, for a given ``block``. Changing
``block`` changes the rounding, not the statistics. Each finished batch is written to ``out``
(an ``.npz`` file, replaced atomically), so an interrupted run resumes where it stopped and
loses nothing already computed.

On a cluster, start one process per host with the same script and call
``jax.distributed.initialize(coordinator_address="host0:1234", num_processes=P,
process_id=p)`` before `evaluate`; every process gets the same metrics.

The summary gives, for every scalar metric, the mean, standard deviation, median, 5 / 95 %
quantiles and the 95 % confidence interval of the mean (normal approximation,
:math:`\bar x \pm 1.96\, s / \sqrt{n}`), over the finite values (non-finite ones are counted).
"""

from __future__ import annotations

import functools
import hashlib
import math
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from tqdm import tqdm

__all__ = ["Summary", "MonteCarloResult", "evaluate", "warm_up", "summarize", "format_summary",
           "progress_bar", "DEFAULT_BLOCK"]

#: Episodes per device in one compiled call (see the module doc, "Reproducibility").
DEFAULT_BLOCK = 64


class Summary(NamedTuple):
    """Statistics of one scalar metric over episodes (finite values only)."""

    mean: float
    std: float
    median: float
    q05: float
    q95: float
    ci_low: float
    ci_high: float
    num_finite: int
    num_nonfinite: int


class MonteCarloResult(NamedTuple):
    """Output of `evaluate`.

    Attributes:
      metrics: the pytree returned by ``episode_fn`` with a leading [num_episodes] axis
        (numpy arrays).
      summary: ``{metric name: Summary}`` for every scalar-per-episode leaf.
      seconds: wall time of the batches computed in this call (excluding resumed ones).
      episodes_per_second: throughput of this call (first batch includes compilation).
      num_devices: devices the batches were sharded over.
    """

    metrics: Any
    summary: dict
    seconds: float
    episodes_per_second: float
    num_devices: int


def evaluate(episode_fn: Callable, params, key, num_episodes: int,
             batch_size: int | None = None, out: str | os.PathLike | None = None,
             progress: bool = True, devices=None,
             on_batch: Callable | None = None, block: int | None = None) -> MonteCarloResult:
    """Run ``episode_fn`` over ``num_episodes`` keys in sharded batches and summarise.

    Args:
      episode_fn: ``episode_fn(key, params) -> pytree`` of per-episode metrics (scalars, or
        arrays such as trajectories).
      params: parameter pytree passed to every episode (traced, so new values do not
        recompile).
      key: PRNG key; episode ``i`` uses ``jax.random.split(key, num_episodes)[i]``.
      num_episodes: number of episodes.
      batch_size: episodes per saved batch (default: all, capped at 1024), rounded up to a
        multiple of ``block`` times the device count. It does not change the results.
      out: optional ``.npz`` path; finished batches are saved there after every batch and a
        later call with the same key and ``num_episodes`` resumes from it.
      progress: show a progress bar (batches, episodes/s; `progress_bar`) on stderr and print
        the summary table there at the end.
      devices: devices to shard over (default: all of ``jax.devices()``).
      on_batch: optional ``on_batch(done, num_episodes)`` called after each saved batch.
      block: episodes per device in one compiled call (default `DEFAULT_BLOCK`, at most
        ``num_episodes``): the unit of reproducibility (module doc).

    Returns:
      `MonteCarloResult`; the summary table is also printed when ``progress`` is True.

    Example:
      >>> def episode(key, params):
      ...     return {"error": jnp.abs(jax.random.normal(key)) * params["scale"]}
      >>> res = evaluate(episode, {"scale": 1.0}, jax.random.PRNGKey(0), 10_000)
      >>> res.summary["error"].mean
    """
    if not callable(episode_fn):
        raise TypeError("episode_fn must be callable as episode_fn(key, params)")
    if int(num_episodes) != num_episodes or num_episodes < 1:
        raise ValueError(f"num_episodes must be a positive integer; got {num_episodes}")
    devices = list(jax.devices() if devices is None else devices)
    n_dev = len(devices)
    if batch_size is None:
        batch_size = min(num_episodes, 1024)
    if isinstance(batch_size, bool) or int(batch_size) != batch_size or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer; got {batch_size}")
    call = _block(block, num_episodes) * n_dev
    batch_size = int(math.ceil(batch_size / call) * call)

    keys = jax.random.split(key, num_episodes)
    key_data = np.asarray(jax.random.key_data(keys)) if _is_typed_key(keys) else np.asarray(keys)
    fingerprint = hashlib.sha256(key_data.tobytes()).hexdigest()[:16]

    run, sharding = _compiled(episode_fn, tuple(devices))

    done, chunks = 0, []
    if out is not None:
        out = Path(out)
        if out.suffix != ".npz":
            raise ValueError(f"out must be an .npz path; got {out}")
        done, chunks = _load(out, fingerprint, num_episodes)

    treedef = None
    if chunks:
        treedef = jax.tree_util.tree_structure(
            jax.eval_shape(lambda k: episode_fn(k, params), keys[0]))
    synced = jax.process_count() == 1
    start = time.perf_counter()
    computed = 0
    num_batches = math.ceil(num_episodes / batch_size)
    bar = progress_bar(num_episodes, initial=done, disable=not progress)
    while done < num_episodes:
        count = min(batch_size, num_episodes - done)
        parts = []
        for start_call in range(done, done + count, call):
            # One block per device; the last call is padded by wrapping (one shape).
            idx = np.arange(start_call, start_call + call) % num_episodes
            outputs = run(_shard(keys, idx, sharding), params)
            if not synced:
                # The first gather sets up the CPU collectives with a 30 s deadline, shorter
                # than a scene's compile time can differ between processes: meet first.
                _barrier(f"jaxtrack.montecarlo.{fingerprint}.{start_call}")
                synced = True
            parts.append(jax.tree_util.tree_map(_gather, outputs))
        outputs = jax.tree_util.tree_map(lambda *x: np.concatenate(x, 0)[:count], *parts)
        leaves, treedef = jax.tree_util.tree_flatten(outputs)
        chunks.append(leaves)
        done += count
        computed += count
        if out is not None:
            _save(out, chunks, done, fingerprint, num_episodes)
        bar.set_postfix_str(f"batch {math.ceil(done / batch_size)}/{num_batches}",
                            refresh=False)
        bar.update(count)
        if on_batch is not None:
            on_batch(done, num_episodes)
    bar.close()
    seconds = time.perf_counter() - start
    leaves = [np.concatenate(parts, 0) for parts in zip(*chunks)]
    metrics = jax.tree_util.tree_unflatten(treedef, leaves)
    summary = summarize(metrics)
    if progress:
        print(format_summary(summary, num_episodes), file=sys.stderr)
    rate = computed / seconds if computed else 0.0
    return MonteCarloResult(metrics, summary, seconds, rate, n_dev)


def warm_up(episode_fn: Callable, params, key, num_episodes: int, devices=None,
            block: int | None = None) -> float:
    """Compile ``episode_fn`` for `evaluate`'s calls without running an episode.

    A later `evaluate` with the same ``episode_fn`` (the same object), a key of the same type,
    parameters of the same structure and dtypes, the same devices and block, and
    ``num_episodes`` episodes (or any number at least ``block``) then starts without compiling,
    so that compilation and simulation can be timed apart.

    Args:
      episode_fn, params, key, devices, block: as for `evaluate`.
      num_episodes: the episodes of the evaluation that follows (only
        ``min(block, num_episodes)`` matters).

    Returns:
      the seconds spent tracing and compiling.

    Example:
      >>> seconds = warm_up(episode, {"scale": 1.0}, jax.random.PRNGKey(0), 64)
      >>> res = evaluate(episode, {"scale": 1.0}, jax.random.PRNGKey(1), 256, batch_size=64)
    """
    devices = tuple(jax.devices() if devices is None else devices)
    if isinstance(num_episodes, bool) or int(num_episodes) != num_episodes or num_episodes < 1:
        raise ValueError(f"num_episodes must be a positive integer; got {num_episodes}")
    call = _block(block, num_episodes) * len(devices)
    t0 = time.perf_counter()
    run, sharding = _compiled(episode_fn, devices)
    keys = jax.random.split(key, call)
    run.lower(_shard(keys, np.arange(call), sharding), params).compile()
    return time.perf_counter() - t0


def _barrier(name: str, timeout_s: float = 3600.0) -> None:
    """Wait until every process reaches ``name`` (the distributed runtime's barrier; JAX has no
    public one that avoids device collectives)."""
    from jax._src import distributed

    client = distributed.global_state.client
    if client is not None:
        client.wait_at_barrier(name, int(timeout_s * 1000))


def _block(block, num_episodes) -> int:
    if block is None:
        block = DEFAULT_BLOCK
    if isinstance(block, bool) or int(block) != block or block < 1:
        raise ValueError(f"block must be a positive integer; got {block}")
    return int(min(block, num_episodes))


def progress_bar(total: int, unit: str = "episodes", file=None, **kwargs) -> tqdm:
    """A `tqdm` progress bar counting ``unit`` (rate in ``unit``/s) on ``file`` (default
    stderr), as `evaluate` and the command line show it; ``kwargs`` go to `tqdm` (e.g.
    ``disable``, ``initial``)."""
    fmt = ("{l_bar}{bar}| {n_fmt}/{total_fmt} " + unit
           + " [{elapsed}<{remaining}, {rate_noinv_fmt}{postfix}]")
    return tqdm(total=total, unit=" " + unit, bar_format=fmt,
                file=sys.stderr if file is None else file, dynamic_ncols=True, **kwargs)


def summarize(metrics) -> dict:
    """``{name: Summary}`` for every leaf of ``metrics`` with shape [num_episodes]."""
    out = {}
    for path, leaf in jax.tree_util.tree_leaves_with_path(metrics):
        x = np.asarray(leaf)
        if x.ndim != 1:
            continue
        name = jax.tree_util.keystr(path).strip("[]'\".") or "value"
        name = name.replace("']['", ".").replace("'", "")
        finite = x[np.isfinite(x)].astype(np.float64)
        n = finite.size
        if n == 0:
            nan = float("nan")
            out[name] = Summary(nan, nan, nan, nan, nan, nan, nan, 0, int(x.size))
            continue
        mean, std = float(finite.mean()), float(finite.std(ddof=1)) if n > 1 else 0.0
        half = 1.96 * std / math.sqrt(n)
        q05, med, q95 = np.quantile(finite, [0.05, 0.5, 0.95])
        out[name] = Summary(mean, std, float(med), float(q05), float(q95), mean - half,
                            mean + half, n, int(x.size - n))
    return out


def format_summary(summary: dict, num_episodes: int | None = None) -> str:
    """A fixed-width table of a summary dict."""
    head = (f"{'metric':<24}{'mean':>11}{'std':>11}{'median':>11}{'5%':>11}{'95%':>11}"
            f"{'95% CI of mean':>26}{'non-finite':>11}")
    lines = [] if num_episodes is None else [f"Monte-Carlo summary over {num_episodes} episodes"]
    lines += [head, "-" * len(head)]
    for name, s in summary.items():
        ci = f"[{s.ci_low:.4g}, {s.ci_high:.4g}]"
        lines.append(f"{name:<24}{s.mean:>11.4g}{s.std:>11.4g}{s.median:>11.4g}{s.q05:>11.4g}"
                     f"{s.q95:>11.4g}{ci:>26}{s.num_nonfinite:>11d}")
    return "\n".join(lines)


@functools.lru_cache(maxsize=32)
def _compiled(episode_fn, devices):
    """The batched, sharded episode function; cached so repeated evaluations reuse compiles."""
    mesh = Mesh(np.array(devices), ("episodes",))
    sharding = NamedSharding(mesh, PartitionSpec("episodes"))
    return jax.jit(jax.vmap(episode_fn, in_axes=(0, None)), out_shardings=sharding), sharding


def _is_typed_key(keys) -> bool:
    return jnp.issubdtype(keys.dtype, jax.dtypes.prng_key)


def _shard(keys, idx, sharding):
    """Global batch keys[idx], built shard by shard (works with several processes)."""
    host = keys[idx]
    if jax.process_count() == 1:
        return jax.device_put(host, sharding)
    local = np.asarray(jax.random.key_data(host)) if _is_typed_key(host) else np.asarray(host)
    arr = jax.make_array_from_callback(local.shape, sharding, lambda i: local[i])
    return jax.random.wrap_key_data(arr) if _is_typed_key(host) else arr


def _gather(x):
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        return np.asarray(multihost_utils.process_allgather(x, tiled=True))
    return np.asarray(x)


def _save(path: Path, chunks, done, fingerprint, num_episodes):
    if jax.process_index() != 0:
        return
    leaves = [np.concatenate(parts, 0) for parts in zip(*chunks)]
    arrays = {f"leaf_{i}": a for i, a in enumerate(leaves)}
    tmp = path.with_name(path.name + ".tmp.npz")
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(tmp, __done__=done, __fingerprint__=fingerprint, __num_episodes__=num_episodes,
             __num_leaves__=len(leaves), **arrays)
    os.replace(tmp, path)


def _load(path: Path, fingerprint, num_episodes):
    if not path.exists():
        return 0, []
    with np.load(path) as f:
        if str(f["__fingerprint__"]) != fingerprint or int(f["__num_episodes__"]) != num_episodes:
            raise ValueError(f"{path} holds results of a different run (other key or "
                             "num_episodes); remove it or choose another out path")
        done = int(f["__done__"])
        leaves = [f[f"leaf_{i}"] for i in range(int(f["__num_leaves__"]))]
    return done, [leaves]

