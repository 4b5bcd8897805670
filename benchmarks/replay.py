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
The ratio column is each row's time per frame over the first row's.

A second table replays the person-free bag (``training/negative_2.bag``: three 768-beam
lasers, 10 Hz, on a robot moving through empty rooms) with the three lasers fused in each
frame (`track` with a list of scans) and with one laser: every confirmed track there is false.
The bag holds no transforms; the mounts are assumed (``MOUNTS``: the left and right lasers at
the front corners turned 45 deg out, the rear one turned back), which moves where the lasers'
views overlap but not what each sees. The shipped classifier was trained on this bag too (the
held-out figures are in ``leg_detector.md``). Measured runs: ``benchmarks/results/replay.md``.
"""

from __future__ import annotations

from pathlib import Path

import _common

_common.single_core_from_argv()

PACKAGES = ["jaxtrack", "jax", "jaxlib", "numpy"]
DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "leg_tracker"
NEGATIVE_TOPICS = ("/left_scan", "/rear_scan", "/right_scan")
MOUNTS = ((0.3, 0.25, 0.785), (-0.3, 0.0, 3.1416), (0.3, -0.25, -0.785))


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
    print()
    fused(args)


def fused(args):
    import numpy as np

    from jaxtrack.io import bags, replay

    bag = Path(args.data) / "training" / "negative_2.bag"
    scans = [bags.read_laser(bag, t) for t in NEGATIVE_TOPICS]
    if args.quick:
        scans = [s._replace(times=s.times[:100], ranges=s.ranges[:100], mask=s.mask[:100],
                            valid=s.valid[:100]) for s in scans]
    T = int(np.sum(scans[0].valid))
    seconds = float(scans[0].times[-1] - scans[0].times[0]) + 0.1
    print(f"person-free recording: {bag.name}, {T} frames, {len(scans)} lasers x "
          f"{scans[0].ranges.shape[1]} beams, {seconds:.1f} s; estimator gnn")
    rows = []
    for detector in ("learned", "geometric"):
        for name, lasers, mounts in (("3 fused", scans, MOUNTS),
                                     (NEGATIVE_TOPICS[0], scans[0], (0.0, 0.0))):
            def call(lasers=lasers, mounts=mounts, detector=detector):
                return replay.track(lasers, None, None, "gnn", chunk=256, progress=False,
                                    detector=detector, laser_mount=mounts)
            timing, tracks = _common.time_call(call, repeats=args.repeats)
            ids = len(np.unique(tracks.ids[tracks.mask])) if tracks.mask.any() else 0
            rows.append([detector, name, f"{timing.first_call:.1f}",
                         f"{1e6 * timing.seconds / T:.0f}", f"{seconds / timing.seconds:.0f}",
                         f"{tracks.mask.sum(1).mean():.3f}", str(ids)])
            print(f"  {rows[-1]}", flush=True)
    print()
    print(_common.format_table(["detector", "lasers", "first call s", "us / frame",
                                "x real time", "false tracks / frame", "false track ids"],
                               rows))


if __name__ == "__main__":
    p = _common.parser(__doc__, timing=True, single_core=True)
    p.add_argument("--data", type=Path, default=DATA, help="the leg_tracker data folder")
    p.add_argument("--copies", type=int, default=4, help="recordings per batch")
    args = p.parse_args()
    _common.setup_jax()
    _common.report(run, args)
