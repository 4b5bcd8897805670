"""``jaxtrack run rgbd-people`` and ``jaxtrack train-hog``: seed 001's evaluation and its
ablations over batched episodes of `sims.following.crowd`, the table, a figure of one frame, and
the training of the HOG confidence's linear SVM."""

from __future__ import annotations

import functools
import math
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import montecarlo
from jaxtrack.perception import hog, rgbd_people
from sims.following import crowd, kinect

__all__ = ["run_rgbd_people", "ablation_table", "write_frame_figure", "train_hog"]

_COUNTS = ("misses", "false_positives", "id_switches", "objects", "matches", "det_matches",
           "det_false_positives", "det_misses")


def _pooled(m: dict) -> dict:
    """Seed 001's scores over all frames of all episodes (eq. 3: the errors summed over the
    frames, over the ground-truth instances summed over the frames)."""
    s = {k: float(np.sum(m[k])) for k in _COUNTS}
    gt = max(s["objects"], 1.0)
    motp = np.asarray(m["motp"], float)
    w = np.asarray(m["matches"], float)
    ok = np.isfinite(motp) & (w > 0)
    return dict(mota=1 - (s["misses"] + s["false_positives"] + s["id_switches"]) / gt,
                motp=float(np.sum(motp[ok] * w[ok]) / max(np.sum(w[ok]), 1.0)),
                fp=s["false_positives"] / gt, fn=s["misses"] / gt, id_switches=s["id_switches"],
                precision=s["det_matches"] / max(s["det_matches"] + s["det_false_positives"], 1),
                recall=s["det_matches"] / max(s["det_matches"] + s["det_misses"], 1))


def _episode_mota(m: dict) -> np.ndarray:
    gt = np.maximum(np.asarray(m["objects"], float), 1.0)
    err = (np.asarray(m["misses"], float) + np.asarray(m["false_positives"], float)
           + np.asarray(m["id_switches"], float))
    return 1.0 - err / gt


def ablation_table(results: dict, title: str = "") -> str:
    """The table of `run_rgbd_people`: pooled MOTA, MOTP (m), FP and FN (% of ground truth), id
    switches, detector precision and recall per pipeline, and each ablation's paired MOTA
    change from "full" with its 95 % confidence interval over episodes (normal)."""
    lines = [title] if title else []
    head = (f"{'pipeline':<20}{'MOTA':>8}{'MOTP[m]':>9}{'FP':>7}{'FN':>7}{'ID sw':>7}"
            f"{'det P':>8}{'det R':>8}   {'dMOTA vs full [95% CI]':<24}")
    lines += [head, "-" * len(head)]
    full = _episode_mota(results["full"]) if "full" in results else None
    for name, m in results.items():
        p = _pooled(m)
        diff = ""
        if full is not None and name != "full":
            d = _episode_mota(m) - full
            half = 1.96 * d.std(ddof=1) / math.sqrt(len(d)) if len(d) > 1 else float("nan")
            diff = f"{100 * d.mean():+.1f} [{100 * (d.mean() - half):+.1f}, " \
                   f"{100 * (d.mean() + half):+.1f}]"
        lines.append(f"{name:<20}{p['mota']:>8.1%}{p['motp']:>9.3f}{p['fp']:>7.1%}"
                     f"{p['fn']:>7.1%}{p['id_switches']:>7.0f}{p['precision']:>8.1%}"
                     f"{p['recall']:>8.1%}   {diff}")
    return "\n".join(lines)


@functools.lru_cache(maxsize=None)
def _episode_fn(cfg: crowd.CrowdConfig, pipeline: crowd.Pipeline):
    def episode(key, svm):
        return crowd.episode(key, cfg, pipeline, svm)
    return episode


def run_rgbd_people(episodes: int = 32, scenario: str = "complex", duration: float = 20.0,
                    resolution=(160, 120), ablations=tuple(crowd.ABLATIONS), seed: int = 0,
                    out: Path | None = None, batch_size: int | None = None,
                    svm: hog.LinearSVM | None = None, progress: bool = True) -> dict:
    """Evaluate the full pipeline and its ablations on the same episodes (same keys) and print
    `ablation_table`.

    Args:
      episodes: episodes per pipeline; scenario: "simple", "complex" or "obstacles";
      duration: seconds per episode; resolution: (width, height) of the Kinect;
      ablations: names of `crowd.ABLATIONS` (or `crowd.FLOORS`) to run; seed: PRNG seed; out: folder for the table
      (``rgbd_people.txt``), the per-episode metrics (``metrics.npz``) and a figure of one
      frame (``frame.png``); batch_size: episodes per batch; svm: the confidence's SVM
      (default: the shipped one).

    Returns:
      {pipeline name: per-episode metrics (numpy)}.
    """
    cam = kinect.KinectConfig(width=int(resolution[0]), height=int(resolution[1]))
    cfg = crowd.CrowdConfig(scenario=scenario, duration=duration, camera=cam)
    svm = hog.load_svm() if svm is None else svm
    key = jax.random.key(seed)
    results = {}
    for name in ablations:
        t0 = time.perf_counter()
        pipeline = {**crowd.ABLATIONS, **crowd.FLOORS}[name]
        res = montecarlo.evaluate(_episode_fn(cfg, pipeline), svm, key, episodes,
                                  batch_size=batch_size, progress=False)
        results[name] = {k: np.asarray(v) for k, v in res.metrics.items()}
        if progress:
            print(f"  {name}: {episodes} episodes in {time.perf_counter() - t0:.1f} s",
                  file=sys.stderr, flush=True)
    title = (f"rgbd-people, scenario {scenario}: {episodes} episodes x {duration:g} s at "
             f"{cfg.rate:g} Hz, Kinect {cam.width} x {cam.height}, seed {seed}")
    table = ablation_table(results, title)
    print(table)
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "rgbd_people.txt").write_text(table + "\n")
        np.savez(out / "metrics.npz", **{f"{n}/{k}": v for n, m in results.items()
                                          for k, v in m.items()})
        write_frame_figure(out / "frame.png", cfg, jax.random.fold_in(key, 1), svm)
    return results


def write_frame_figure(path: Path, cfg: crowd.CrowdConfig, key, svm=None,
                       time_s: float | None = None) -> None:
    """One frame of an episode: the RGB image with the people's theoretical boxes and their HOG
    confidence, the depth image, and a top view of the cloud (ground removed), the clusters,
    the heads and the detections beside the true positions."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pipe = crowd.Pipeline()
    dcfg = pipe.detector()
    t = 0.5 * cfg.duration if time_s is None else time_s
    kp, ks, kd = jax.random.split(key, 3)
    people = crowd.sample_people(kp, cfg)
    robot = jnp.asarray([-3.8 + cfg.robot_speed * t, 0.0, 0.0])
    state = crowd.people_at(people, t)
    z = crowd.sense(ks, cfg, robot, state, people, crowd.static_scene(cfg))
    camera = crowd.base_camera(cfg)
    _, f = rgbd_people.detect(dcfg, rgbd_people.init_state(dcfg), kd, z.points, z.points_ok,
                              z.points_rgb, camera.position, image=z.colour, camera=camera,
                              svm=svm)
    depth = z.depth
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8))
    ax = axes[0]
    ax.imshow(np.asarray(z.colour))
    m = np.asarray(f.people.mask)
    for b, c in zip(np.asarray(f.boxes)[m], np.asarray(f.confidence)[m]):
        top, left, bottom, right = b
        ax.add_patch(plt.Rectangle((left, top), right - left, bottom - top, fill=False,
                                   color="lime" if c >= 0.5 else "red", lw=1.5))
        ax.text(left, top - 1, f"{c:.2f}", color="white", fontsize=7,
                bbox=dict(facecolor="black", alpha=0.5, pad=0.5))
    ax.set_title("RGB, theoretical boxes and HOG confidence")
    ax.axis("off")
    axes[1].imshow(np.asarray(depth), cmap="viridis")
    axes[1].set_title("Kinect depth (noise, quantisation, edge dropout)")
    axes[1].axis("off")
    ax = axes[2]
    grid, fg = f.grid, f.foreground
    g = np.asarray(grid.points)[np.asarray(grid.mask) & np.asarray(f.ground.inliers)]
    ax.scatter(g[:, 0], g[:, 1], s=1, c="0.8", label="ground voxels")
    lab = np.asarray(f.clusters.labels)
    fm = np.asarray(fg.mask)
    pts_fg = np.asarray(fg.points)
    ax.scatter(pts_fg[fm & (lab < 0), 0], pts_fg[fm & (lab < 0), 1], s=2, c="0.5",
               label="other voxels")
    pd = np.asarray(f.people.point_detection)
    sel = fm & (pd >= 0)
    ax.scatter(pts_fg[sel, 0], pts_fg[sel, 1], s=3, c=pd[sel], cmap="tab10", vmin=0, vmax=9,
               label="sub-clusters")
    heads = np.asarray(f.people.head)[m]
    ax.scatter(heads[:, 0], heads[:, 1], marker="^", s=60, c="k", label="heads")
    pos = np.asarray(f.people.position)[m]
    ax.scatter(pos[:, 0], pos[:, 1], marker="x", s=80, c="r", label="detections")
    c, s = np.cos(float(robot[2])), np.sin(float(robot[2]))
    truth = (np.asarray(state.pos) - np.asarray(robot[:2])) @ np.array([[c, -s], [s, c]])
    tm = np.asarray(people.mask)
    ax.scatter(truth[tm, 0], truth[tm, 1], marker="o", s=80, facecolors="none",
               edgecolors="b", label="true people")
    ax.set_xlim(0, 5.5)
    ax.set_ylim(-3, 3)
    ax.set_aspect("equal")
    ax.set_xlabel("x forward [m]")
    ax.set_ylabel("y left [m]")
    ax.legend(fontsize=7, loc="upper right")
    ax.set_title("top view, robot frame")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def train_hog(frames: int = 1500, out: Path | None = None, seed: int = 0,
              c: float = 0.01) -> dict:
    """Train the confidence's linear SVM (scikit-learn's `LinearSVC`, Dalal and Triggs'
    C = 0.01) on HOG features of simulated crops (`crowd.training_crops`) from the three
    scenarios at 160 x 120, and report its accuracy on a held-out fifth.

    Returns:
      {"weights", "bias", "train_accuracy", "test_accuracy", "positives", "negatives"}; with
      ``out``, also written there as ``.npz`` (the file `hog.load_svm` reads).
    """
    from sklearn.svm import LinearSVC

    feats, labels = [], []
    for i, scenario in enumerate(crowd.SCENARIOS):
        cfg = crowd.CrowdConfig(scenario=scenario)
        f, y, ok = crowd.training_crops(jax.random.fold_in(jax.random.key(seed), i), cfg,
                                        max(1, frames // len(crowd.SCENARIOS)))
        feats.append(f[ok])
        labels.append(y[ok])
    x = np.concatenate(feats).astype(np.float64)
    y = np.concatenate(labels)
    rng = np.random.default_rng(seed)
    test = rng.uniform(size=len(y)) < 0.2
    svm = LinearSVC(C=c, class_weight="balanced", max_iter=20000).fit(x[~test], y[~test])
    result = dict(weights=svm.coef_[0].astype(np.float32),
                  bias=np.float32(svm.intercept_[0]),
                  train_accuracy=float(svm.score(x[~test], y[~test])),
                  test_accuracy=float(svm.score(x[test], y[test])),
                  positives=int(y.sum()), negatives=int((1 - y).sum()))
    if out is not None:
        np.savez(out, **result)
    return result

