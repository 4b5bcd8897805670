"""Benchmark: the seed-000 humanoid reach protocol (15 tasks x N episodes), closed loop in MJX.

Usage: python benchmarks/humanoid.py [--episodes 64] [--tracker pf|pf3|ukf]

Prints compile time (first batch) separately from the wall time of the 15 x N evaluation, the
throughput, the machine's load average, and the accuracy table.
"""

import argparse
import os
import sys

from sims.cli import run_humanoid_reach


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--episodes", type=int, default=64)
    parser.add_argument("--tracker", default="pf", choices=("pf", "pf3", "ukf"))
    parser.add_argument("--particles", type=int, default=128)
    args = parser.parse_args(argv)
    load = os.getloadavg()
    out = run_humanoid_reach(args.episodes, args.tracker, particles=args.particles)
    total = 15 * args.episodes
    print(f"load average before: {load[0]:.2f}; after: {os.getloadavg()[0]:.2f} "
          f"({os.cpu_count()} cores)")
    print(f"compile + first batch: {out['compile_seconds']:.1f} s; {total} episodes: "
          f"{out['run_seconds']:.1f} s ({total / out['run_seconds']:.1f} episodes/s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
