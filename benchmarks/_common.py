"""The scaffold every benchmark script stands on.

- `parser`: the shared options (``--quick``, ``--seed``, ``--out``; ``--repeats`` for timed
  comparisons, ``--cpu`` / ``--no-pin`` for single-core runs) and sizes that ``--quick`` shrinks.
- `single_core_from_argv`: one pinned core, set before jax starts.
- `time_interleaved` / `time_call`: median wall and CPU time over clean, interleaved repeats.
- `header`: the lines that open a report (date, machine, versions, git describe, load).
- `Row`, `timing_row`, `table`: one line per contender, its ratio to a reference row.
- `report` / `tee`: the report to the terminal and to ``--out``.

Call `single_core_env()` (or `single_core_from_argv()`) before anything imports jax (the XLA
flags are read once, when the CPU backend starts). Nothing here imports jax at module level for
that reason.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import datetime
import importlib.metadata
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

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


def single_core_env(pin: bool = True, cpu: int | None = None) -> dict[str, str]:
    """Run on one core: thread-count environment variables (``os.environ.setdefault``: an
    explicit environment wins) and, with ``pin``, the process's CPU affinity restricted to one
    core (``cpu``, by default the last one it may use), which is what ``taskset -c`` does.

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
        os.sched_setaffinity(0, {max(os.sched_getaffinity(0)) if cpu is None else cpu})
    if hasattr(os, "sched_getaffinity"):
        settings["affinity"] = affinity()
    return settings


def single_core_from_argv(argv: Sequence[str] | None = None) -> dict[str, str]:
    """`single_core_env` as ``--no-pin`` / ``--cpu N`` in ``argv`` (default ``sys.argv``) ask.

    Reads the two options itself because the affinity must be set before jax is imported,
    which is before the script's parser runs (`parser` declares them for ``--help``).
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    cpu = None
    for i, a in enumerate(argv):
        if a == "--cpu" and i + 1 < len(argv):
            cpu = int(argv[i + 1])
        elif a.startswith("--cpu="):
            cpu = int(a.split("=", 1)[1])
    return single_core_env(pin="--no-pin" not in argv, cpu=cpu)


def affinity() -> str:
    """The CPUs this process may run on, e.g. "0,1"."""
    if not hasattr(os, "sched_getaffinity"):
        return "unknown"
    return ",".join(str(c) for c in sorted(os.sched_getaffinity(0)))


def setup_jax() -> None:
    """Compile every timed function afresh (a warm persistent cache would hide compile time, a
    reported column) and keep the peers' deprecation warnings out of the report."""
    import warnings

    import jax

    jax.config.update("jax_enable_compilation_cache", False)
    warnings.filterwarnings("ignore", category=DeprecationWarning)


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


# ---------------------------------------------------------------------------------------------
# Options


class Parser(argparse.ArgumentParser):
    """An `argparse.ArgumentParser` whose `sized` options take their default from ``--quick``
    (and ``--gradcheck``, where the script has it) when not given."""

    def __init__(self, *args, timing: bool = False, **kwargs):
        super().__init__(*args, **kwargs)
        self._sizes: dict[str, tuple[tuple, tuple | None]] = {}
        self._timing = timing

    def sized(self, flag: str, full, quick, help: str, *, type=int,
              gradcheck: tuple | None = None) -> None:
        """``flag`` defaults to ``full``, or ``quick`` under ``--quick``; with ``gradcheck``
        (a (full, quick) pair), to those under ``--gradcheck``."""
        text = f"{help} (default {full}; --quick {quick}"
        if gradcheck is not None:
            text += f"; with --gradcheck {gradcheck[0]}, --quick {gradcheck[1]}"
        action = self.add_argument(flag, type=type, default=None, help=text + ")")
        self._sizes[action.dest] = ((full, quick), gradcheck)

    def parse_args(self, args=None, namespace=None):
        ns = super().parse_args(args, namespace)
        for dest, (sizes, grad) in self._sizes.items():
            if getattr(ns, dest) is None:
                full, quick = grad if grad is not None and getattr(ns, "gradcheck", False) \
                    else sizes
                setattr(ns, dest, quick if ns.quick else full)
        if self._timing:
            # Short repeats at smoke sizes, where the calls are short too.
            ns.min_repeat_s = 0.02 if ns.quick else 0.2
        return ns


def parser(description: str, *, timing: bool = False, single_core: bool = False,
           agreement: bool = False, gradcheck: str | None = None,
           out_help: str = "also write the report to this file (e.g. under "
                           "benchmarks/results/raw/, which git ignores)") -> Parser:
    """The benchmark's argument parser, with the options every script shares.

    ``description``: the script's docstring (its first paragraph is shown). Every parser has
    ``--quick`` (smoke sizes), ``--seed`` (offset of the data and key seeds; 0 gives the logged
    runs) and ``--out``. ``timing``: ``--repeats`` and ``args.min_repeat_s`` for
    `time_interleaved`. ``single_core``: ``--cpu`` / ``--no-pin`` (read by
    `single_core_from_argv` before jax starts). ``agreement``: ``--no-check``, to skip the
    agreement check. ``gradcheck``: a ``--gradcheck`` flag with this help.
    """
    p = Parser(description=description.strip().split("\n\n")[0], timing=timing)
    p.add_argument("--quick", action="store_true", help="smoke-test sizes")
    p.add_argument("--seed", type=int, default=0,
                   help="seed offset of the simulated data and keys (default 0)")
    p.add_argument("--out", type=Path, default=None, help=out_help)
    if timing:
        p.sized("--repeats", 7, 3, "timing repeats, interleaved over the contenders")
    if single_core:
        p.add_argument("--cpu", type=int, default=None,
                       help="pin to this CPU (read before jax starts; default: the last one)")
        p.add_argument("--no-pin", action="store_true",
                       help="do not restrict the process to one CPU (read before jax starts)")
    if agreement:
        p.add_argument("--no-check", action="store_true", help="skip the agreement check")
    if gradcheck is not None:
        p.add_argument("--gradcheck", action="store_true", help=gradcheck)
    return p


class _Tee:
    def __init__(self, *streams):
        self.streams = streams

    def write(self, text):
        for stream in self.streams:
            stream.write(text)
        return len(text)

    def flush(self):
        for stream in self.streams:
            stream.flush()


def report(run: Callable, args: argparse.Namespace):
    """``run(args)``, what it prints also written to ``args.out`` (when given)."""
    with tee(args.out):
        return run(args)


@contextlib.contextmanager
def tee(path: Path | str | None) -> Iterator[None]:
    """Print to the terminal and, with ``path``, to that file as well."""
    if path is None:
        yield
        return
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    terminal = sys.stdout
    with open(path, "w") as f:
        sys.stdout = _Tee(terminal, f)
        try:
            yield
        finally:
            sys.stdout = terminal


# ---------------------------------------------------------------------------------------------
# Reports


def header(packages: Sequence[str], *lines: str, threads: dict[str, str] | None = None
           ) -> list[str]:
    """The lines that open a report: date, machine, python and package versions, jaxtrack's git
    describe and the jax backend, the thread settings (``threads``, from `single_core_env`;
    default: the CPU affinity) and the load average at the start, then ``lines``."""
    import jax

    import jaxtrack

    threads = threads or {"affinity": affinity()}
    return [*machine_info(packages),
            f"jaxtrack git {git_describe(jaxtrack.__file__)}; jax backend "
            f"{jax.default_backend()}, devices {jax.devices()}",
            "threads: " + ", ".join(f"{k}={v!r}" for k, v in threads.items()),
            load_line("start"), *lines]


def load_line(when: str) -> str:
    return f"load average at {when} (1, 5, 15 min): {load_average()}"


@dataclasses.dataclass(frozen=True)
class Row:
    """A line of a results table.

    ``label``: the leading columns, what ran (case, contender, sizes). ``figures``: column ->
    value, in order; the first is the headline that ratios compare. ``ratio``: the headline
    over a reference row's (`vs`). ``note``: the last column.
    """

    label: tuple
    figures: dict[str, object]
    ratio: float | None = None
    note: str = ""

    @property
    def headline(self) -> float:
        return next(iter(self.figures.values()))

    def vs(self, reference: Row) -> Row:
        """This row with its ratio to ``reference``."""
        return dataclasses.replace(self, ratio=self.headline / reference.headline)


def timing_row(label: tuple, timing: Timing, episodes: int, steps: int = 1, *, unit: str,
               note: str = "") -> Row:
    """A `Row` of the timing figures per ``unit`` of work, one call covering ``episodes x
    steps`` units: wall and CPU microseconds, the first call's extra seconds, clean repeats,
    spread."""
    return Row(label, {f"us/{unit}": timing.per_step_us(episodes, steps),
                       "first call s": timing.first_call,
                       f"cpu us/{unit}": timing.cpu_per_step_us(episodes, steps),
                       "clean": f"{timing.clean}/{timing.repeats}",
                       "spread": f"{100 * timing.spread:.0f}%"}, note=note)


def progress(name: str, row: Row, timing: Timing) -> None:
    """One line on a contender as soon as it is timed (the table comes at the end)."""
    unit = next(iter(row.figures))
    print(f"  {name:<24} {fmt_float(row.headline):>9} {unit}  ({timing.number} calls x "
          f"{timing.repeats} repeats, {timing.clean} clean, spread "
          f"{100 * timing.spread:.0f}%)", flush=True)


def table(columns: Sequence[str], rows: Sequence[Row], ratio: str | None = "vs jaxtrack"
          ) -> str:
    """``rows`` as a fixed-width table: the label columns (named by ``columns``), the figures,
    with the ratio column (named ``ratio``; None: none) after the headline, and the notes when
    any row has one. Floats are shown with `fmt_float`, None as "-"."""
    if not rows:
        return "(no rows)"
    names = list(rows[0].figures)
    header = [*columns, names[0], *([ratio] if ratio else []), *names[1:]]
    notes = any(r.note for r in rows)
    if notes:
        header.append("notes")

    def cell(v):
        return fmt_float(v) if isinstance(v, float) or v is None else str(v)

    body = []
    for r in rows:
        values = [r.figures[n] for n in names]
        body.append([*map(cell, r.label), cell(values[0]),
                     *([cell(r.ratio)] if ratio else []), *map(cell, values[1:]),
                     *([r.note] if notes else [])])
    align = "".join("l" if isinstance(v, str) else "r" for v in rows[0].label)
    align += "r" * (len(header) - len(align) - notes) + "l" * notes
    return format_table(header, body, align=align)


# ---------------------------------------------------------------------------------------------
# Gradient checks


def central_differences(f: Callable, x, step: float):
    """Central finite differences of the scalar ``f`` at the 1-D array ``x``, one coordinate at
    a time (2 evaluations each)."""
    import jax.numpy as jnp
    import numpy as np

    out = []
    for i in range(x.shape[0]):
        e = jnp.zeros_like(x).at[i].set(step)
        out.append((float(f(x + e)) - float(f(x - e))) / (2 * step))
    return np.asarray(out)


def gradient_table(names: Sequence[str], derivative, differences, *, digits: int = 4,
                   derivative_name: str = "AD", differences_name: str = "FD"):
    """(table of derivative vs finite difference per parameter, relative differences)."""
    import numpy as np

    derivative, differences = np.asarray(derivative), np.asarray(differences)
    rel = np.abs(derivative - differences) / np.maximum(np.abs(differences), 1e-12)
    rows = [Row((n,), {derivative_name: f"{a:.{digits}f}", differences_name: f"{b:.{digits}f}",
                       "rel. diff": f"{100 * r:.1f}%"})
            for n, a, b, r in zip(names, derivative, differences, rel)]
    return table(["parameter"], rows, ratio=None), rel
