"""Evaluation: the learned leg detector against the geometric one on the real labelled scans
of ``../shared/data/leg_tracker`` (precision / recall at 0.15 m on held-out bags, false
positives per scan on the person-free bag).

Usage: python benchmarks/leg_detector.py [--data ../shared/data/leg_tracker] [--out FILE]
       [--figure docs/figures/leg_detector_pr.png] [--quick]

Protocol (whole recordings held out, never scans):

* **Precision / recall**, leave one bag out: for each of the six labelled bags, a forest is
  trained (`jaxtrack.io.leg_dataset.train`) on the five others and the three lasers of the
  person-free bag, and scored on the held-out bag. A detection is a segment classified as a
  leg, at its mean point; it is a true positive when an assignment gated at 0.15 m matches it
  to a labelled leg of its scan (`leg_dataset.match_counts`). The PR curve sweeps the
  forest's probability threshold; the marked point is the trained decision threshold. The
  geometric detector (`legs.leg_candidates`, default `LegParams` but the scan's own maximum
  range) is one point per bag. The trackers take the learned detector's candidates at the
  lower threshold 0.05 (`sensing.SensingConfig.leg_threshold`); its precision and recall are
  listed too.
* **False positives per scan** on the person-free bag, leave one laser out: trained on the six
  labelled bags and the other two lasers, scored on the held-out laser's scans.

The labelled bags' unlabelled segments count as false positives: their recordings were made
so that legs appear only where labelled (README beside the data), and most of them are table
and chair legs, which look like legs. Measured runs: ``benchmarks/results/leg_detector.md``.
"""

from __future__ import annotations

import glob
import os
import sys
from pathlib import Path

import _common

PACKAGES = ["jaxtrack", "jax", "jaxlib", "numpy", "scikit-learn"]
ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "leg_tracker"
NEGATIVE_TOPICS = ("/left_scan", "/rear_scan", "/right_scan")
RADIUS = 0.15
TRACKING_THRESHOLD = 0.05   # `sensing.SensingConfig.leg_threshold`: the trackers' candidates


def geometric(data, params):
    """The geometric detector's legs on every scan: (mean [T, S, 2], legs [T, S])."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxtrack.perception import legs

    @jax.jit
    def run(ranges, angles):
        def one(r):
            det = legs.detect(r, angles, params, max_segments=128)
            return det.features.mean, det.legs_mask
        return jax.vmap(one)(ranges)

    s = data.scans
    mean, mask = run(jnp.asarray(s.ranges, jnp.float32), jnp.asarray(s.angles, jnp.float32))
    return np.asarray(mean, np.float64), np.asarray(mask)


def learned_scores(model, data):
    """The learned detector's segments: (mean [T, S, 2], segment mask [T, S], P(leg) [T, S],
    -1 for segments the detector does not evaluate)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxtrack.io import leg_dataset
    from jaxtrack.perception import leg_classifier

    s = data.scans
    X, mean, mask, _ = leg_dataset._scan_segments(
        np.asarray(s.ranges, np.float32), jnp.asarray(s.angles, jnp.float32),
        jnp.float32(s.range_max), jnp.float32(model.jump), leg_dataset.DEFAULT_SEGMENTS)
    p = np.asarray(leg_classifier.predict_proba(model, jnp.asarray(X)))
    cand = jax.vmap(leg_classifier.candidates, (None, 0, 0))(model, jnp.asarray(X),
                                                            jnp.asarray(mask))
    p = np.where(np.asarray(cand), p, -1.0)
    return mean, mask, p


def scores_at(mean, det, data):
    import numpy as np

    from jaxtrack.io import leg_dataset

    tp, fp, fn = leg_dataset.match_counts(mean, det, data.labels, data.label_mask, RADIUS)
    tp, fp, fn = int(tp.sum()), int(fp.sum()), int(fn.sum())
    precision = tp / max(tp + fp, 1)
    recall = tp / max(tp + fn, 1)
    f1 = 2 * precision * recall / max(precision + recall, 1e-12)
    return precision, recall, f1, fp / len(data.scans.times), np.nan


def run(args):
    import numpy as np

    from jaxtrack.io import leg_dataset
    from jaxtrack.perception import legs

    data_dir = Path(args.data)
    positives = sorted(glob.glob(str(data_dir / "training" / "positive_*_extracted.bag")))
    negative_bag = data_dir / "training" / "negative_2.bag"
    if not positives or not negative_bag.exists():
        sys.exit(f"no labelled bags under {data_dir}")
    if args.quick:
        positives = positives[:2]
    for line in _common.header(PACKAGES, f"data: {data_dir}"):
        print(line)
    pos = [leg_dataset.read_labelled(p) for p in positives]
    neg = [leg_dataset.read_unlabelled(negative_bag, t) for t in NEGATIVE_TOPICS]
    names = [Path(p).name.replace("_extracted.bag", "") for p in positives]
    kw = dict(n_estimators=16 if args.quick else 48, seed=args.seed)
    thresholds = np.linspace(0.0, 1.0, 101)

    print("\n## Leg detection on held-out labelled bags (precision / recall at 0.15 m)\n")
    rows, curves = [], {}
    for k, (name, data) in enumerate(zip(names, pos)):
        model, rep = leg_dataset.train([d for j, d in enumerate(pos) if j != k], neg, **kw)
        mean, mask, p = learned_scores(model, data)
        pr = [scores_at(mean, p >= t, data)[:2] for t in thresholds]
        curves[name] = (np.array(pr), scores_at(mean, p >= rep.decision, data)[:2])
        lp, lr, lf1, _, _ = scores_at(mean, p >= rep.decision, data)
        params = legs.LegParams(max_range=float(data.scans.range_max))
        gmean, gdet = geometric(data, params)
        gp, gr, gf1, _, _ = scores_at(gmean, gdet, data)
        curves[name] += ((gp, gr),)
        tp_, tr_, tf1, _, _ = scores_at(mean, p >= TRACKING_THRESHOLD, data)
        labels = int(data.label_mask.sum())
        rows.append([name, len(data.scans.times), labels, f"{rep.decision:.2f}", f"{lp:.3f}",
                     f"{lr:.3f}", f"{lf1:.3f}", f"{tp_:.3f} / {tr_:.3f}", f"{gp:.3f}",
                     f"{gr:.3f}", f"{gf1:.3f}", "yes" if lf1 > gf1 else "NO"])
        print(f"  {name}: learned F1 {lf1:.3f}, geometric F1 {gf1:.3f}", file=sys.stderr)
    print(_common.format_table(
        ["held-out bag", "scans", "legs", "threshold", "learned P", "learned R", "learned F1",
         f"learned P / R at {TRACKING_THRESHOLD}", "geometric P", "geometric R",
         "geometric F1", "learned better"], rows))

    print("\n## False positives per scan on the person-free bag (one laser held out)\n")
    rows = []
    for k, topic in enumerate(NEGATIVE_TOPICS):
        model, rep = leg_dataset.train(pos, [d for j, d in enumerate(neg) if j != k], **kw)
        data = neg[k]
        mean, mask, p = learned_scores(model, data)
        scans = len(data.scans.times)
        learned_fp = float(np.sum(p >= rep.decision)) / scans
        tracking_fp = float(np.sum(p >= TRACKING_THRESHOLD)) / scans
        gmean, gdet = geometric(data, legs.LegParams(max_range=float(data.scans.range_max)))
        geo_fp = float(gdet.sum()) / scans
        segs = float(mask.sum()) / scans
        rows.append([topic, scans, f"{segs:.1f}", f"{learned_fp:.3f}", f"{tracking_fp:.3f}",
                     f"{geo_fp:.3f}", "yes" if learned_fp < geo_fp else "NO"])
    print(_common.format_table(["held-out laser", "scans", "segments / scan",
                                "learned FP / scan", f"learned FP / scan at {TRACKING_THRESHOLD}",
                                "geometric FP / scan", "learned fewer"], rows))

    model, rep = leg_dataset.train(pos, neg, **kw)
    print(f"\nAll bags (the shipped model's training set): {rep.num_segments} segments, "
          f"{rep.num_legs} legs, {rep.num_scans} scans, {rep.dropped} segments beyond capacity; "
          f"decision threshold {rep.decision:.3f} (held-out segment precision "
          f"{rep.held_out_precision:.3f}, recall {rep.held_out_recall:.3f}, 3 folds).")
    if args.figure:
        figure(curves, args.figure)
        print(f"\nFigure: {os.path.relpath(args.figure, ROOT)}")


def figure(curves, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 5.2))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for (name, (pr, point, geo)), c in zip(curves.items(), colours):
        ok = pr[:, 0] + pr[:, 1] > 0
        ax.plot(pr[ok, 1], pr[ok, 0], "-", color=c, label=f"{name} learned")
        ax.plot(point[1], point[0], "o", color=c)
        ax.plot(geo[1], geo[0], "x", color=c, ms=9, mew=2)
    ax.plot([], [], "ko", label="learned, trained threshold")
    ax.plot([], [], "kx", ms=9, mew=2, label="geometric detector")
    ax.set_xlabel("recall (legs within 0.15 m)")
    ax.set_ylabel("precision")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.set_title("Leg detection on held-out labelled bags")
    ax.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    p = _common.parser(__doc__)
    p.add_argument("--data", type=Path, default=DATA, help="the leg_tracker data folder")
    p.add_argument("--figure", type=Path, default=None, help="write the PR figure here")
    args = p.parse_args()
    _common.setup_jax()
    _common.report(run, args)
