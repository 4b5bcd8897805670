"""Every plot renders to a PNG headlessly and draws what it is given."""

import numpy as np
import pytest
from matplotlib.collections import PolyCollection
from matplotlib.quiver import Quiver

from jaxtrack import plotting, tuning


def _png(fig, path):
    fig.savefig(path)
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 1000
    return data


def test_trajectories_draws_truth_estimate_and_heading_arrows(tmp_path):
    t = np.linspace(0, 2 * np.pi, 50)
    truth = np.stack([np.cos(t), np.sin(t)], -1)
    est = truth + 0.05
    fig = plotting.trajectories(truth, est, t + np.pi / 2, t + np.pi / 2, arrow_every=10)
    ax = fig.axes[0]
    np.testing.assert_allclose(ax.lines[0].get_xydata(), truth)
    assert any(np.allclose(line.get_xydata(), est) for line in ax.lines)
    quivers = [c for c in ax.collections if isinstance(c, Quiver)]
    assert len(quivers) == 2 and quivers[0].N == 5
    _png(fig, tmp_path / "traj.png")
    batch = plotting.trajectories(np.stack([truth, truth * 2]))
    assert len(batch.axes[0].lines) == 4  # path + start marker per episode
    with pytest.raises(ValueError, match="estimate"):
        plotting.trajectories(truth, est[:10])


def test_error_boxplot_groups_by_task(tmp_path):
    rng = np.random.default_rng(0)
    errors = rng.random(30)
    groups = np.repeat(["forward", "lateral", "diagonal"], 10)
    fig = plotting.error_boxplot(errors, groups, ylabel="final error [m]")
    labels = [t.get_text() for t in fig.axes[0].get_xticklabels()]
    assert labels == ["forward", "lateral", "diagonal"]
    # the median line of the first box is the median of that group
    medians = [line for line in fig.axes[0].lines if line.get_color() in ("C1", "#ff7f0e")]
    np.testing.assert_allclose(medians[0].get_ydata()[0], np.median(errors[:10]))
    _png(fig, tmp_path / "box.png")


def test_mot_timeline_colours_each_matched_track(tmp_path):
    matches = np.array([[0, 1], [0, 1], [1, 0], [-1, 0], [1, -1]])
    present = np.array([[1, 1], [1, 1], [1, 1], [1, 1], [1, 0]], bool)
    fig = plotting.mot_timeline(matches, present, gt_ids=[7, 9])
    bars = [c for c in fig.axes[0].collections if isinstance(c, (PolyCollection,))]
    # person 7: [0,0], [1], [-1], [1] -> 4 segments; person 9: [1,1], [0,0] -> 2 segments
    assert len(bars) == 6
    assert [t.get_text() for t in fig.axes[0].get_yticklabels()] == ["7", "9"]
    _png(fig, tmp_path / "mot.png")


def test_tuning_curves_plot_loss_and_parameters(tmp_path):
    hist = tuning.History(loss=np.linspace(2, 1, 20), grad_norm=np.ones(20),
                          skipped=np.arange(20) == 5,
                          params={"log_q": np.linspace(0, 1, 21), "log_r": np.zeros(21)},
                          val_steps=np.array([0, 10, 20]), val_loss=np.array([2.0, 1.5, 1.0]))
    fig = plotting.tuning_curves(hist, transform={"log_q": np.exp})
    ax_loss, ax_par = fig.axes
    assert len(ax_loss.lines) == 3  # train, validation, skipped markers
    np.testing.assert_allclose(ax_par.lines[0].get_ydata(), np.exp(np.linspace(0, 1, 21)))
    _png(fig, tmp_path / "tuning.png")
    with pytest.raises(ValueError, match="no scalar parameter"):
        plotting.tuning_curves(hist, param_names=["nope"])
