"""Benchmark: the jittable grid planner's distance field against scipy's Dijkstra, on one core,
after compilation.

Usage: python benchmarks/grid_planner.py [--sizes 64,128] [--goals 8] [--repeats 5]
       [--md benchmarks/results/grid_planner.md] [--out FILE] [--quick]

The costmaps are service-robot rooms: furniture as random lethal rectangles (``inf``, about
15 % of the cells) and people as Gaussian cost bumps (peak 4, sigma 3 cells, 8 of them), cell
0.05 m, 8-connected. One call computes the cost-to-go from ``--goals`` random free goals (one
at a time, except in the vmapped row). Rows:

- **jaxtrack edges**: `grid_planner.distance_field` (the default, plain Bellman-Ford on
  shifted arrays), jitted;
- **jaxtrack lines**: the same with ``method="lines"`` (exact line relaxations);
- **jaxtrack edges, vmap**: ``--goals`` goals in one vmapped call (time per goal);
- **scipy dijkstra**: ``scipy.sparse.csgraph.dijkstra`` from the goal on the same graph, built
  once beforehand (the graph construction is not timed);
- **scipy, graph + dijkstra**: the same with the sparse graph built from the costmap in numpy
  in every call, which a planner whose costmap changes every frame (moving people) pays.

The ratio column is each row's time per goal over scipy dijkstra's (< 1: faster than scipy).
Relaxation rounds (from the same jitted code) and the largest relative difference to scipy's
distances are listed too. Measured runs: ``benchmarks/results/grid_planner.md``.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import _common

_common.single_core_from_argv()

PACKAGES = ["jaxtrack", "jax", "jaxlib", "numpy", "scipy"]
ROOT = Path(__file__).resolve().parents[1]
CELL = 0.05


def room(size, seed):
    """A [size, size] costmap: lethal rectangles (furniture) and Gaussian people."""
    import numpy as np

    rng = np.random.default_rng(seed)
    i, j = np.mgrid[0:size, 0:size]
    cost = np.zeros((size, size))
    for _ in range(8):
        ci, cj = rng.uniform(0, size, 2)
        cost += 4.0 * np.exp(-((i - ci) ** 2 + (j - cj) ** 2) / (2 * 3.0 ** 2))
    lethal = np.zeros((size, size), bool)
    while lethal.mean() < 0.15:
        h, w = rng.integers(2, max(3, size // 6), 2)
        r, c = rng.integers(0, size - h), rng.integers(0, size - w)
        lethal[r:r + h, c:c + w] = True
    cost[lethal] = np.inf
    return cost


def graph(cost, cell=CELL):
    """The planner's 8-connected graph (corner-free diagonals, trapezoid edge costs) as a scipy
    CSR matrix, built with shifted arrays."""
    import numpy as np
    from scipy.sparse import coo_matrix

    H, W = cost.shape
    ok = np.isfinite(cost)
    c = np.where(ok, cost, 0.0)
    idx = np.arange(H * W).reshape(H, W)
    rows, cols, w = [], [], []
    for di, dj in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = (slice(0, H - di), slice(max(0, -dj), W - max(0, dj)))
        b = (slice(di, H), slice(max(0, dj), W - max(0, -dj)))
        edge = ok[a] & ok[b]
        if di and dj:
            side1 = ok[a[0], b[1]]
            side2 = ok[b[0], a[1]]
            edge &= side1 & side2
        weight = cell * math.hypot(di, dj) * (1.0 + 0.5 * (c[a] + c[b]))
        rows += [idx[a][edge], idx[b][edge]]
        cols += [idx[b][edge], idx[a][edge]]
        w += [weight[edge]] * 2
    return coo_matrix((np.concatenate(w), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(H * W, H * W)).tocsr()


def run(args):
    import jax
    import jax.numpy as jnp
    import numpy as np
    from scipy.sparse.csgraph import dijkstra

    from jaxtrack.control import grid_planner as gp

    for line in _common.header(PACKAGES, f"costmaps: rooms, 15 % lethal rectangles, 8 people "
                               f"(peak cost 4), cell {CELL} m, 8-connected; {args.goals} goals "
                               f"per call; float64 distances"):
        print(line)
    jax.config.update("jax_enable_x64", True)
    rows = []
    for size in args.sizes:
        cost = room(size, args.seed + size)
        free = np.argwhere(np.isfinite(cost))
        rng = np.random.default_rng(args.seed)
        goals = free[rng.choice(len(free), args.goals, replace=False)].astype(np.int32)
        g = graph(cost)
        flat_goals = goals[:, 0] * size + goals[:, 1]
        cost_j = jnp.asarray(cost)
        goals_j = jnp.asarray(goals)

        fields = {m: jax.jit(lambda c, q, m=m: gp._field(c, q, 8, math.inf, CELL, m))
                  for m in ("lines", "edges")}
        batch = jax.jit(jax.vmap(lambda c, q: gp._field(c, q, 8, math.inf, CELL, "edges")[0],
                                 (None, 0)))

        def one_by_one(method):
            f = fields[method]
            return lambda: [f(cost_j, q)[0] for q in goals_j]

        calls = {
            "edges": (one_by_one("edges"), ()),
            "lines": (one_by_one("lines"), ()),
            "vmap": (lambda: batch(cost_j, goals_j), ()),
            "scipy": (lambda: dijkstra(g, indices=flat_goals), ()),
            "scipy+graph": (lambda: dijkstra(graph(cost), indices=flat_goals), ()),
        }
        res = _common.time_interleaved(calls, repeats=args.repeats,
                                       min_repeat_s=args.min_repeat_s,
                                       compiled=("lines", "edges", "vmap"))
        ref = res["scipy"][1].reshape(args.goals, size, size)
        rounds = {m: [int(fields[m](cost_j, q)[1]) for q in goals_j] for m in fields}
        per = {k: res[k][0].seconds / args.goals for k in calls}

        def diff(out):
            d = np.stack([np.asarray(x) for x in out]) if isinstance(out, list) else np.asarray(out)
            same_inf = np.array_equal(np.isinf(d), np.isinf(ref))
            fin = np.isfinite(ref) & (ref > 0)
            rel = float(np.max(np.abs(d[fin] - ref[fin]) / ref[fin]))
            return f"{rel:.1e}" if same_inf else "inf differs"

        labels = {"edges": "jaxtrack edges", "lines": "jaxtrack lines",
                  "vmap": f"jaxtrack edges, vmap {args.goals}", "scipy": "scipy dijkstra",
                  "scipy+graph": "scipy, graph + dijkstra"}
        for k, title in labels.items():
            first = res[k][0].first_call
            r = rounds.get("edges" if k == "vmap" else k)
            rows.append([f"{size} x {size}", title, f"{1e3 * per[k]:.3f}",
                         f"{per[k] / per['scipy']:.2f}",
                         "-" if first is None else f"{first:.2f}",
                         "-" if r is None else f"{min(r)}-{max(r)}",
                         "-" if k.startswith("scipy") else diff(res[k][1]),
                         f"{res[k][0].clean}/{res[k][0].repeats}"])
            print(f"  {rows[-1]}", flush=True)
    print()
    print(_common.format_table(["grid", "method", "ms / goal", "vs scipy", "first call s",
                                "rounds", "max rel. diff", "clean"], rows))
    print(_common.load_line("end"))


def main():
    p = _common.parser(__doc__, timing=True, single_core=True)
    p.sized("--goals", 8, 2, "goals per call")
    p.add_argument("--sizes", type=lambda s: [int(v) for v in s.split(",")], default=None,
                   help="grid sizes (default 64,128; --quick 32,64)")
    p.add_argument("--md", type=Path, default=ROOT / "benchmarks" / "results" / "grid_planner.md",
                   help="write the report as this markdown file ('' for none)")
    args = p.parse_args()
    if args.sizes is None:
        args.sizes = [32, 64] if args.quick else [64, 128]
    _common.setup_jax()
    md = str(args.md) if args.md else ""
    with _common.tee(args.out):
        if not md:
            run(args)
            return
        import io

        buf = io.StringIO()
        terminal = sys.stdout
        sys.stdout = _common._Tee(terminal, buf)
        try:
            run(args)
        finally:
            sys.stdout = terminal
    command = "python benchmarks/grid_planner.py " + " ".join(sys.argv[1:])
    Path(md).parent.mkdir(parents=True, exist_ok=True)
    Path(md).write_text(
        "# Grid planner: distance field against scipy's Dijkstra\n\n"
        f"`{command.strip()}`, one core, after compilation. Time per goal; ratio = time / "
        "scipy dijkstra's (< 1: faster). See the script's docstring for the rows.\n\n"
        "```\n" + buf.getvalue() + "```\n")


if __name__ == "__main__":
    main()
