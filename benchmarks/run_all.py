"""Run every benchmark in turn and keep each one's output.

Usage:
  python benchmarks/run_all.py                  # full runs (about 1 h on an idle 2-core machine)
  python benchmarks/run_all.py --quick          # smoke sizes (a few minutes)
  python benchmarks/run_all.py --only particle,filters
  python benchmarks/run_all.py --gradcheck      # also the closed-loop gradient checks

Every script is run with ``--quick`` under ``--quick``, and with ``--seed`` when it is given.
With ``--quick``, the gradient checks run at toy sizes (2 episodes): that exercises their code,
but their pass / fail verdict at that size is noise (the finite differences of 2 short
episodes), so a quick run does not count them as failures.

Each script's output goes to ``benchmarks/results/raw/<UTC date>/<name>.log`` (and to the
terminal; git ignores ``raw/``); a summary of exit codes and wall times ends the run. The exit
code is non-zero when any benchmark failed. Run from the benchmark environment (see README.md,
"Running").
"""

from __future__ import annotations

import datetime as dt
import subprocess
import sys
import time
from pathlib import Path

import _common

HERE = Path(__file__).resolve().parent

# name -> (script, arguments)
BENCHMARKS = {
    "filters": ("filters.py", []),
    "particle": ("particle.py", []),
    "association": ("association.py", []),
    "following": ("following.py", []),
    "following_sensors": ("following_sensors.py", []),
    "humanoid": ("humanoid.py", []),
}
GRADCHECKS = {
    "following_gradcheck": ("following.py", ["--gradcheck"]),
    "humanoid_gradcheck": ("humanoid.py", ["--gradcheck"]),
}


def parse_args(argv=None):
    p = _common.parser(__doc__, gradcheck="also run the gradient checks",
                       out_help="log directory (default benchmarks/results/raw/<UTC date>)")
    p.add_argument("--only", default="", help="comma-separated names (default: all): "
                   + ", ".join([*BENCHMARKS, *GRADCHECKS]))
    return p.parse_args(argv)


def selected(args) -> dict:
    table = dict(BENCHMARKS)
    if args.gradcheck or args.only:
        table.update(GRADCHECKS)
    if args.only:
        names = [n.strip() for n in args.only.split(",") if n.strip()]
        unknown = sorted(set(names) - set(table))
        if unknown:
            raise SystemExit(f"unknown benchmark(s) {unknown}; choose from {sorted(table)}")
        table = {n: table[n] for n in names}
    return table


def main(argv=None) -> int:
    args = parse_args(argv)
    table = selected(args)
    out = args.out or (HERE / "results" / "raw"
                       / dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d"))
    out.mkdir(parents=True, exist_ok=True)
    shared = [*(["--quick"] if args.quick else []),
              *(["--seed", str(args.seed)] if args.seed else [])]
    summary = []
    for i, (name, (script, extra)) in enumerate(table.items(), 1):
        cmd = [sys.executable, str(HERE / script), *extra, *shared]
        print(f"\n=== [{i}/{len(table)}] {name}: {' '.join(cmd[1:])}", flush=True)
        t0 = time.perf_counter()
        with open(out / f"{name}.log", "w") as log:
            proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                    text=True, bufsize=1)
            for line in proc.stdout:
                sys.stdout.write(line)
                log.write(line)
            code = proc.wait()
        summary.append((name, code, time.perf_counter() - t0))
    print(f"\nlogs in {out}")
    print(_common.table(["benchmark"], [_common.Row((name,), {"exit": code, "wall s": secs})
                                        for name, code, secs in summary], ratio=None))
    counted = [code for name, code, _ in summary if not (args.quick and name in GRADCHECKS)]
    if args.quick and any(name in GRADCHECKS for name, _, _ in summary):
        print("(--quick: the gradient checks' verdicts are not counted; see the docstring)")
    return int(any(code != 0 for code in counted))


if __name__ == "__main__":
    sys.exit(main())
