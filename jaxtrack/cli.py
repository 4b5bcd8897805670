"""Command-line entry point: ``jaxtrack demo``."""

from __future__ import annotations

import argparse
import sys


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="jaxtrack", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="KF / EKF / UKF over many vmapped episodes: accuracy and "
                                       "speed table")
    demo.add_argument("--episodes", type=int, default=1000)
    demo.add_argument("--steps", type=int, default=200)
    demo.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.command == "demo":
        if args.episodes < 1 or args.steps < 1:
            parser.error("--episodes and --steps must be positive")
        from jaxtrack import demo as demo_mod

        demo_mod.run(args.episodes, args.steps, args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
