"""Shared helpers for the benchmark scripts: single-core setup, timing, machine info, tables.

Call `single_core_env()` before anything imports jax (the XLA flags are read once, when the
CPU backend starts). Nothing here imports jax at module level for that reason.
"""

from __future__ import annotations

import dataclasses
import datetime
import importlib.metadata
import os
import platform
import statistics
import time
from collections.abc import Callable, Sequence

SINGLE_CORE_ENV = {
    # One Eigen thread for XLA:CPU; the BLAS libraries numpy / scipy link against (used by
    # filterpy and Stone Soup) are pinned the same way. "intra_op_parallelism_threads=1" is not
    # an XLA flag: XLA ignores tokens without "--" (and rejects "--intra_op_parallelism_threads"
    # as unknown); it is kept because the benchmark issue asks for it. What actually keeps XLA
    # on one core is the CPU affinity set by `single_core_env` (see there).
    "XLA_FLAGS": "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1",
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "VECLIB_MAXIMUM_THREADS": "1",
    "NUMEXPR_NUM_THREADS": "1",
}


def single_core_env(pin: bool = True) -> dict[str, str]:
    """Run on one core: thread-count environment variables (``os.environ.setdefault``: an
    explicit environment wins) and, with ``pin``, the process's CPU affinity restricted to one
    core (the last one it may use), which is what ``taskset -c`` does.

    The affinity is needed because XLA:CPU's runtime executes independent operations of a
    program concurrently on its intra-op thread pool (one thread per core), whatever XLA_FLAGS
    say; on a 2-core machine a jitted filter at N = 1 otherwise runs on both cores and pays
    cross-core wake-ups. Must run before jax or numpy is imported (threads inherit the
    affinity when they are created). Returns the settings in effect.
    """
    for key, value in SINGLE_CORE_ENV.items():
        os.environ.setdefault(key, value)
    settings = {key: os.environ[key] for key in SINGLE_CORE_ENV}
    if pin and hasattr(os, "sched_setaffinity"):
        cpu = max(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cpu})
    if hasattr(os, "sched_getaffinity"):
        settings["affinity"] = ",".join(str(c) for c in sorted(os.sched_getaffinity(0)))
    return settings


def block(out):
    """Wait for every array in the pytree ``out`` (numpy leaves are already done)."""
    import jax

    for leaf in jax.tree_util.tree_leaves(out):
        ready = getattr(leaf, "block_until_ready", None)
        if ready is not None:
            ready()
    return out


@dataclasses.dataclass(frozen=True)
class Timing:
    """Wall time of one call.

    ``seconds`` is the median over the clean repeats (each repeat is the mean of ``number``
    back-to-back calls); ``cpu_seconds`` the median process CPU time per call over the same
    repeats. A repeat is clean when the process CPU time was at least ``CLEAN_CPU_PER_WALL`` of
    its wall time, i.e. the process was not descheduled by other load on a shared machine.
    ``first_call`` is the first call's wall time minus ``seconds`` (for jitted functions:
    tracing + compilation). ``spread`` is (max - min) / median over the clean repeats.
    """

    seconds: float
    cpu_seconds: float
    repeats: int
    clean: int
    number: int
    first_call: float | None
    cpu_per_wall: float
    spread: float

    def per_step_us(self, episodes: int, steps: int) -> float:
        return 1e6 * self.seconds / (episodes * steps)

    def cpu_per_step_us(self, episodes: int, steps: int) -> float:
        return 1e6 * self.cpu_seconds / (episodes * steps)


CLEAN_CPU_PER_WALL = 0.9


def _calibrate(fn, args, min_repeat_s, max_number):
    t0 = time.perf_counter()
    block(fn(*args))
    once = time.perf_counter() - t0
    return max(1, min(max_number, int(min_repeat_s / max(once, 1e-9))))


def _timed(fn, args, number):
    """(wall seconds per call, cpu seconds per call) over ``number`` calls."""
    cpu0, t0 = time.process_time(), time.perf_counter()
    for _ in range(number):
        block(fn(*args))
    wall = time.perf_counter() - t0
    return wall / number, (time.process_time() - cpu0) / number


def time_interleaved(calls: dict[str, tuple[Callable, tuple]], *, repeats: int = 7,
                     min_repeat_s: float = 0.2, max_number: int = 1000,
                     compiled: Sequence[str] = (),
                     max_rounds: int | None = None) -> dict[str, tuple[Timing, object]]:
    """Time several ``fn(*args)`` against each other; returns ``{name: (Timing, first_output)}``.

    Each function is called once as a warm-up (for jitted code: tracing + compilation; its extra
    time is reported as ``first_call`` for the names in ``compiled``). The number of calls per
    repeat is chosen so that one repeat lasts at least ``min_repeat_s`` (as
    `timeit.Timer.autorange` does). The repeats are interleaved round-robin, rotating the order,
    so that background load on a shared machine hits every contender alike. Rounds continue
    (up to ``max_rounds``, default ``3 * repeats``) until every function has ``repeats`` clean
    repeats (see `Timing`); if some never get there, all their repeats are used.
    """
    max_rounds = max_rounds or 3 * repeats
    first, outs, numbers = {}, {}, {}
    for name, (fn, args) in calls.items():
        t0 = time.perf_counter()
        outs[name] = block(fn(*args))
        first[name] = time.perf_counter() - t0
        numbers[name] = _calibrate(fn, args, min_repeat_s, max_number)
    samples = {name: [] for name in calls}
    names = list(calls)

    def clean(name):
        return [s for s in samples[name] if s[1] >= CLEAN_CPU_PER_WALL * s[0]]

    for r in range(max_rounds):
        todo = [n for n in names if len(samples[n]) < repeats or len(clean(n)) < repeats]
        if not todo:
            break
        k = r % len(todo)
        for name in todo[k:] + todo[:k]:
            fn, args = calls[name]
            samples[name].append(_timed(fn, args, numbers[name]))
    result = {}
    for name in names:
        used = clean(name)
        if len(used) < repeats:
            used = samples[name]
        walls = [w for w, _ in used]
        med = statistics.median(walls)
        cpu_med = statistics.median([c for _, c in used])
        spread = (max(walls) - min(walls)) / med
        first_call = max(first[name] - med, 0.0) if name in compiled else None
        cpu_per_wall = sum(c for _, c in used) / sum(walls)
        result[name] = (Timing(med, cpu_med, len(samples[name]), len(clean(name)),
                               numbers[name], first_call, cpu_per_wall, spread), outs[name])
    return result


def time_call(fn: Callable, *args, repeats: int = 7, min_repeat_s: float = 0.2,
              max_number: int = 1000, measure_first: bool = True) -> tuple[Timing, object]:
    """Time one ``fn(*args)``, blocking on its (jax) outputs; see `time_interleaved`."""
    out = time_interleaved({"fn": (fn, args)}, repeats=repeats, min_repeat_s=min_repeat_s,
                           max_number=max_number, compiled=("fn",) if measure_first else ())
    return out["fn"]


def load_average() -> str:
    try:
        one, five, fifteen = os.getloadavg()
    except OSError:
        return "unknown"
    return f"{one:.2f} {five:.2f} {fifteen:.2f}"


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def versions(packages: Sequence[str]) -> dict[str, str]:
    out = {}
    for name in packages:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def machine_info(packages: Sequence[str]) -> list[str]:
    """Lines describing the run: date, CPU, core count, Python and package versions."""
    lines = [
        f"date: {datetime.datetime.now().astimezone().strftime('%Y-%m-%d %H:%M %Z')}",
        f"machine: {cpu_model()}, nproc {os.cpu_count()}, {platform.system()} "
        f"{platform.release()}",
        f"python {platform.python_version()}; "
        + ", ".join(f"{k} {v}" for k, v in versions(packages).items()),
    ]
    return lines


def format_table(header: Sequence[str], rows: Sequence[Sequence[object]],
                 align: str | None = None) -> str:
    """Plain fixed-width table. ``align`` has one character per column, 'l' or 'r'
    (default: first column left, the rest right)."""
    cells = [[str(c) for c in header]] + [["" if c is None else str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    align = align or "l" + "r" * (len(header) - 1)

    def fmt(row):
        return "  ".join(c.ljust(w) if a == "l" else c.rjust(w)
                         for c, w, a in zip(row, widths, align)).rstrip()

    rule = "  ".join("-" * w for w in widths)
    return "\n".join([fmt(cells[0]), rule] + [fmt(r) for r in cells[1:]])


def fmt_float(x: float | None, digits: int = 3) -> str:
    """Format with ``digits`` significant digits, without switching to exponent notation for
    the ranges a benchmark table shows."""
    if x is None:
        return "-"
    if x == 0:
        return "0"
    mag = abs(x)
    if mag >= 10 ** (digits - 1):
        return f"{x:.0f}"
    decimals = digits - 1 - int(f"{mag:e}".split("e")[1])
    return f"{x:.{max(decimals, 0)}f}"


def git_describe(path: str | None = None) -> str:
    """``git describe --always --dirty`` of the repository holding ``path`` (default: the
    repository of this file), or "unknown"."""
    import subprocess

    root = os.path.dirname(os.path.abspath(path or __file__))
    try:
        return subprocess.run(["git", "-C", root, "describe", "--always", "--dirty"],
                              capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
