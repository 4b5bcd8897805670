"""Benchmark: replaying a real laser recording through detection and a user estimator, on one
core, after compilation (`jaxtrack.io.replay.track`, and `track_batch` over several copies).

Usage: python benchmarks/replay.py [--data ../shared/data/leg_tracker] [--repeats 5]
       [--copies 4] [--out FILE] [--quick]

The recording is the leg_tracker demo bag: 126 s of 10 Hz scans with 512 beams. Each row
replays all its scans with one leg detector (learned: the shipped classifier; geometric: the
thresholds) and one estimator, in chunks of 256 frames; the first call compiles, the table
gives the median of the repeats that follow (`_common.time_call`). "x real time" is the
recording's duration over the replay's wall time. The batch rows replay ``--copies`` copies of
the recording at once (`track_batch`, one vmapped program); their real time counts every copy.
The ratio column is each row's time per frame over the first row's. Measured runs:
``benchmarks/results/replay.md``.
"""

from __future__ import annotations

from pathlib import Path

import _common

_common.single_core_from_argv()

PACKAGES = ["jaxtrack", "jax", "jaxlib", "numpy"]
DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "leg_tracker"


def run(args):
    from jaxtrack.io import bags, replay

    bag = Path(args.data) / "demo_stationary_simple_environment.bag"
    laser = bags.read_laser(bag, "/scan")
    if args.quick:
        laser = laser._replace(times=laser.times[:200], ranges=laser.ranges[:200],
                               mask=laser.mask[:200], valid=laser.valid[:200])
    T = len(laser.times)
    seconds = float(laser.times[-1] - laser.times[0]) + 0.1
    for line in _common.header(PACKAGES, f"recording: {bag.name}, {T} scans, "
                               f"{laser.ranges.shape[1]} beams, {seconds:.1f} s"):
        print(line)
    rows = []
    first = None
    combos = [(d, e) for d in ("learned", "geometric") for e in ("kf", "gnn", "jpda+legs")]
    for detector, estimator in combos:
        def call(detector=detector, estimator=estimator):
            return replay.track(laser, None, None, estimator, chunk=256, progress=False,
                                detector=detector)
        timing, _ = _common.time_call(call, repeats=args.repeats)
        per_frame = timing.seconds / T
        first = first or per_frame
        rows.append([f"{detector} + {estimator}", "1", f"{timing.first_call:.1f}",
                     f"{1e6 * per_frame:.0f}", f"{seconds / timing.seconds:.0f}",
                     f"{per_frame / first:.2f}"])
        print(f"  {rows[-1]}", flush=True)
    for detector in ("learned", "geometric"):
        def call(detector=detector):
            return replay.track_batch([laser] * args.copies, None, "gnn", chunk=256,
                                      progress=False, detector=detector)
        timing, _ = _common.time_call(call, repeats=args.repeats)
        per_frame = timing.seconds / (T * args.copies)
        rows.append([f"{detector} + gnn, batch", str(args.copies), f"{timing.first_call:.1f}",
                     f"{1e6 * per_frame:.0f}", f"{args.copies * seconds / timing.seconds:.0f}",
                     f"{per_frame / first:.2f}"])
        print(f"  {rows[-1]}", flush=True)
    print()
    print(_common.format_table(["detector + estimator", "recordings", "first call s",
                                "us / frame", "x real time", "ratio"], rows))


if __name__ == "__main__":
    p = _common.parser(__doc__, timing=True, single_core=True)
    p.add_argument("--data", type=Path, default=DATA, help="the leg_tracker data folder")
    p.add_argument("--copies", type=int, default=4, help="recordings per batch")
    args = p.parse_args()
    _common.setup_jax()
    _common.report(run, args)
