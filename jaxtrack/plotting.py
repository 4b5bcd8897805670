"""Plots for tracking results (matplotlib; headless; every function returns a Figure).

Figures are built with `matplotlib.figure.Figure` directly, without pyplot's global state, so
they work on machines without a display; save with ``fig.savefig("x.png")`` or let a notebook
display them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.figure import Figure

__all__ = ["trajectories", "error_boxplot", "mot_timeline", "tuning_curves"]


def _axes(ax, figsize):
    if ax is not None:
        return ax.figure, ax
    fig = Figure(figsize=figsize, layout="constrained")
    return fig, fig.add_subplot()


def trajectories(truth, estimate=None, truth_heading=None, estimate_heading=None, *,
                 arrow_every: int = 10, arrow_length: float = 0.15, labels=("truth", "estimate"),
                 ax=None, title: str | None = None) -> Figure:
    """Top view of true and estimated ground-plane trajectories with heading arrows.

    Args:
      truth: [T, 2] or [E, T, 2] true positions (m).
      estimate: optional array of the same shape.
      truth_heading, estimate_heading: optional [T] / [E, T] headings (rad), drawn as arrows
        every ``arrow_every`` steps.
      ax: optional matplotlib Axes to draw into.

    Returns:
      The Figure.

    Example:
      >>> fig = trajectories(xs[:, :2], res.means[:, :2])
      >>> fig.savefig("trajectory.png")
    """
    truth = np.asarray(truth)
    if truth.ndim == 2:
        truth = truth[None]
        estimate = None if estimate is None else np.asarray(estimate)[None]
        truth_heading = None if truth_heading is None else np.asarray(truth_heading)[None]
        estimate_heading = None if estimate_heading is None else np.asarray(estimate_heading)[None]
    if truth.ndim != 3 or truth.shape[-1] != 2:
        raise ValueError(f"truth must be [T, 2] or [E, T, 2]; got {truth.shape}")
    if estimate is not None and np.shape(estimate) != truth.shape:
        raise ValueError(f"estimate must have the shape of truth {truth.shape}; got "
                         f"{np.shape(estimate)}")
    fig, ax = _axes(ax, (5.5, 5))
    for e in range(truth.shape[0]):
        first = e == 0
        ax.plot(truth[e, :, 0], truth[e, :, 1], "-", color="0.3", lw=1.5,
                label=labels[0] if first else None)
        ax.plot(*truth[e, 0], "o", color="0.3", ms=4)
        if estimate is not None:
            est = np.asarray(estimate)[e]
            ax.plot(est[:, 0], est[:, 1], "--", color="C1", lw=1.2,
                    label=labels[1] if first else None)
        for pos, head, color in ((truth[e], truth_heading, "0.3"),
                                 (None if estimate is None else np.asarray(estimate)[e],
                                  estimate_heading, "C1")):
            if pos is None or head is None:
                continue
            h = np.asarray(head)[e][::arrow_every]
            p = pos[::arrow_every]
            ax.quiver(p[:, 0], p[:, 1], np.cos(h), np.sin(h), color=color, angles="xy",
                      scale_units="xy", scale=1.0 / arrow_length, width=0.004)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
    if title:
        ax.set_title(title)
    return fig


def error_boxplot(errors: Mapping[str, Sequence[float]] | Sequence, groups=None, *,
                  ylabel: str = "error", title: str | None = None, ax=None) -> Figure:
    """Box plots of per-episode errors grouped by task (or by method).

    Args:
      errors: ``{group name: values}``, or a flat array [E] with ``groups`` [E] labels.
      groups: labels when ``errors`` is an array.

    Returns:
      The Figure.

    Example:
      >>> fig = error_boxplot({"forward": e1, "lateral": e2}, ylabel="final error [m]")
    """
    if not isinstance(errors, Mapping):
        values = np.asarray(errors)
        if groups is None:
            errors = {"all": values}
        else:
            groups = np.asarray(groups)
            if groups.shape != values.shape:
                raise ValueError("groups must have one label per error")
            errors = {str(g): values[groups == g] for g in dict.fromkeys(groups.tolist())}
    names = list(errors)
    data = [np.asarray(errors[n], float)[np.isfinite(np.asarray(errors[n], float))]
            for n in names]
    fig, ax = _axes(ax, (max(4.0, 0.7 * len(names) + 2), 4))
    ax.boxplot(data, showmeans=True)
    ax.set_xticks(range(1, len(names) + 1), names, rotation=30 if len(names) > 5 else 0)
    ax.set_ylabel(ylabel)
    ax.grid(axis="y", alpha=0.3)
    if title:
        ax.set_title(title)
    return fig


def mot_timeline(matched_hyp_ids, gt_mask=None, gt_ids=None, *, dt: float = 1.0,
                 title: str | None = None, ax=None) -> Figure:
    """Which track covered which person when.

    One row per ground-truth object; each frame is coloured by the id of the hypothesis
    matched to it (white where the object is present but missed, blank where absent).

    Args:
      matched_hyp_ids: [T, G] hypothesis id matched to each object (-1 for none).
      gt_mask: optional [T, G] bools, object present.
      gt_ids: optional [G] labels of the objects.
      dt: frame period (s) for the time axis.

    Returns:
      The Figure.

    Example:
      >>> fig = mot_timeline(matches, gt_mask)
    """
    m = np.asarray(matched_hyp_ids)
    if m.ndim != 2:
        raise ValueError(f"matched_hyp_ids must be [T, G]; got {m.shape}")
    T, G = m.shape
    present = np.ones_like(m, bool) if gt_mask is None else np.asarray(gt_mask, bool)
    labels = [str(g) for g in (range(G) if gt_ids is None else np.asarray(gt_ids).tolist())]
    fig, ax = _axes(ax, (8, 0.45 * G + 1.5))
    ids = sorted(set(m[(m >= 0) & present].tolist()))
    colour = {h: f"C{i % 10}" for i, h in enumerate(ids)}
    for g in range(G):
        t = 0
        while t < T:
            if not present[t, g]:
                t += 1
                continue
            h = m[t, g]
            start = t
            while t < T and present[t, g] and m[t, g] == h:
                t += 1
            face = colour.get(h, "white")
            ax.broken_barh([(start * dt, (t - start) * dt)], (g - 0.4, 0.8), facecolors=face,
                           edgecolors="0.4", linewidth=0.5)
            if h >= 0 and (t - start) * dt > 0.05 * T * dt:
                ax.text((start + t) / 2 * dt, g, str(h), ha="center", va="center", fontsize=7)
    ax.set_yticks(range(G), labels)
    ax.set_ylim(-0.6, G - 0.4)
    ax.set_xlim(0, T * dt)
    ax.set_xlabel("time [s]" if dt != 1.0 else "frame")
    ax.set_ylabel("person")
    if title:
        ax.set_title(title)
    return fig


def tuning_curves(history, param_names: Sequence[str] | None = None, *,
                  transform=None, title: str | None = None) -> Figure:
    """Loss (training and validation) and parameter traces of a `jaxtrack.tuning.fit` run.

    Args:
      history: a `jaxtrack.tuning.History`.
      param_names: leaves to plot (dict keys of ``history.params``); default all scalar leaves.
      transform: optional ``{name: f}`` mapping unconstrained values to the plotted ones
        (e.g. ``{"log_q": np.exp}``).

    Returns:
      The Figure.

    Example:
      >>> fig = tuning_curves(history, transform={"log_q": np.exp})
    """
    params = history.params
    if isinstance(params, Mapping):
        scalars = {k: np.asarray(v) for k, v in params.items() if np.asarray(v).ndim == 1}
    else:
        scalars = {}
    if param_names is not None:
        missing = [n for n in param_names if n not in scalars]
        if missing:
            raise ValueError(f"no scalar parameter named {missing}")
        scalars = {n: scalars[n] for n in param_names}
    transform = transform or {}
    fig = Figure(figsize=(9, 3.5), layout="constrained")
    ax_loss, ax_par = fig.subplots(1, 2)
    steps = np.arange(len(history.loss))
    ax_loss.plot(steps, history.loss, lw=1, label="train")
    if len(history.val_loss):
        ax_loss.plot(history.val_steps, history.val_loss, "o-", ms=3, label="validation")
    if np.any(history.skipped):
        ax_loss.plot(steps[history.skipped], history.loss[history.skipped], "rx",
                     label="skipped")
    ax_loss.set_xlabel("step")
    ax_loss.set_ylabel("loss")
    ax_loss.legend()
    ax_loss.grid(alpha=0.3)
    for name, values in scalars.items():
        f = transform.get(name)
        ax_par.plot(np.arange(len(values)), f(values) if f else values, label=name)
    ax_par.set_xlabel("step")
    ax_par.set_ylabel("parameter")
    if scalars:
        ax_par.legend()
    ax_par.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    return fig
