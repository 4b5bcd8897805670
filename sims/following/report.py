"""``jaxtrack run person-following``: batched episodes, the metrics table and the plots."""

from __future__ import annotations

import functools
import sys
from pathlib import Path

import numpy as np

__all__ = ["run_person_following", "metrics_table", "estimator_config", "write_plots",
           "write_animation", "draw_floor"]

_ROWS = (("following_rms", "following RMS error [m]", "{:.3f}"),
         ("lost_fraction", "user lost [% of time]", "{:.2%}"),
         ("user_switches", "user id switches [per episode]", "{:.2f}"),
         ("mota", "MOTA", "{:.2%}"),
         ("motp", "MOTP [m]", "{:.3f}"),
         ("mot_switches", "MOT id switches [per episode]", "{:.2f}"),
         ("idf1", "IDF1", "{:.2%}"),
         ("hota", "HOTA", "{:.2%}"),
         ("near_fraction", "someone within 0.45 m [% of time]", "{:.2%}"),
         ("stop_fraction", "safety stop [% of time]", "{:.2%}"))
# CLEAR MOT, IDF1 and HOTA score a multi-target tracker's tracks; a single-person estimator has
# none (its episodes hold NaN and -1 there, `sims.following.episode`).
_MOT_KEYS = ("mota", "motp", "mot_switches", "idf1", "hota")


def metrics_table(metrics: dict, title: str = "", multi_target: bool | None = None) -> str:
    """Mean (and 5-95 % range over episodes) of every episode metric that applies.

    ``multi_target``: whether the estimator is a multi-target tracker (the CLEAR MOT, IDF1
    and HOTA rows apply); None decides it from the values (rows without a finite value are left
    out). Non-finite values (and the -1 of an unscored id-switch count) are left out of a row's
    statistics.

    Example:
      >>> print(metrics_table(res["metrics"], "kf", multi_target=False))
    """
    lines = [title] if title else []
    width = max(len(r[1]) for r in _ROWS) + 2
    lines.append(f"{'metric':<{width}}{'mean':>12}{'5 %':>12}{'95 %':>12}")
    lines.append("-" * (width + 36))
    for key, name, fmt in _ROWS:
        if multi_target is False and key in _MOT_KEYS:
            continue
        v = np.asarray(metrics[key], float)
        v = v[np.isfinite(v) & (v >= 0)] if key == "mot_switches" else v[np.isfinite(v)]
        if v.size == 0:
            continue
        lo, hi = np.quantile(v, [0.05, 0.95])
        lines.append(f"{name:<{width}}{fmt.format(v.mean()):>12}{fmt.format(lo):>12}"
                     f"{fmt.format(hi):>12}")
    return "\n".join(lines)


def estimator_config(name: str, sensors: str = "both", particles: int = 256,
                     appearance: bool = False):
    """The user-estimator configuration the command line means by ``name``
    (`jaxtrack.tracking.user.CONFIGS`), with its sensors, particles (``"pf"``) and colour
    re-identification (the multi-target estimators).

    Example:
      >>> estimator_config("jpda", appearance=True)
    """
    import dataclasses

    from jaxtrack.tracking import user

    user.build(name)  # a clear error for an unknown name

    def configure(config):
        if isinstance(config, user.LegTrackedConfig):
            return dataclasses.replace(config, estimator=configure(config.estimator))
        if isinstance(config, user.ParticleConfig):
            config = dataclasses.replace(config, pf=dataclasses.replace(
                config.pf, num_particles=particles))
        if appearance:
            if not isinstance(config, user.MultiTargetConfig):
                raise ValueError("appearance applies to the multi-target estimators, not "
                                 f"{name!r}")
            config = dataclasses.replace(config, appearance=True)
        return config

    return configure(user.with_sensors(user.CONFIGS[name], sensors))


def run_person_following(episodes: int = 256, estimator: str = "pf", follower: str = "A",
                         people: int = 4, out: Path | None = None, seed: int = 0,
                         duration: float = 60.0, sensors: str = "both", particles: int = 256,
                         batch_size: int | None = None, stream=sys.stdout,
                         appearance: bool = False, layout: str = "shop",
                         wander: bool = False, animate: bool = False,
                         progress: bool = True) -> dict:
    """Run ``episodes`` closed-loop episodes, print the metrics table, write plots to ``out``.

    The table has the metrics that apply to the estimator (no CLEAR MOT, IDF1 or HOTA rows
    for a single-person one); ``progress`` shows a progress bar on stderr.

    Returns ``{"table", "metrics", "compile_seconds", "run_seconds"}``.
    """
    import jax

    from sims._runs import timed_evaluate
    from sims.following import episode as ep

    cfg, episode_fn = _episode(layout, estimator, sensors, particles, appearance, wander,
                               people, float(duration))
    params = ep.make_params(cfg, point=follower)
    key = jax.random.PRNGKey(seed)
    m, compile_s, run_s = timed_evaluate(episode_fn, params, key, episodes, batch_size,
                                         progress)
    title = (f"person following ({layout}{', wandering user' if wander else ''}): {episodes} "
             f"episodes x {duration:.0f} s, estimator {estimator}"
             f" ({sensors}{', appearance' if appearance else ''}), follower point {follower}, "
             f"{people} distractors")
    table = metrics_table(m, title, multi_target=cfg.multi_target)
    print(table, file=stream)
    print(f"simulated in {run_s:.1f} s after {compile_s:.1f} s of compilation "
          f"({episodes * duration / run_s:.0f} simulated s per wall s)", file=stream)
    if out is not None:
        write_plots(Path(out), cfg, params, key, animate=animate)
        np.savez(Path(out) / "metrics.npz", **m)
    return {"table": table, "metrics": m, "compile_seconds": compile_s, "run_seconds": run_s}


@functools.lru_cache(maxsize=8)
def _episode(layout, estimator, sensors, particles, appearance, wander, people, duration):
    """``(config, episode function)`` of a run's scenario. Cached: runs of one scenario in a
    process share the episode function, and so the batches `jaxtrack.montecarlo` compiled
    for it (it caches them by function)."""
    from sims.following import episode as ep

    cfg = ep.scenario(layout, estimator_config(estimator, sensors, particles, appearance),
                      wander=wander, distractors=people, duration=duration)
    return cfg, ep.make_episode(cfg)


def draw_floor(ax, sc) -> None:
    """The floor plan of the scene ``sc`` on ``ax``: walls, blocks (shelves, end caps,
    counter) and furniture legs."""
    import matplotlib.pyplot as plt

    W, H = sc.room
    ax.add_patch(plt.Rectangle((-W / 2, -H / 2), W, H, fill=False, color="k"))
    colour = {"shelf": "0.75", "end_cap": "0.6", "counter": "0.45"}
    for b in sc.blocks:
        (cx, cy), (sx, sy) = b["centre"], b["size"]
        ax.add_patch(plt.Rectangle((cx - sx / 2, cy - sy / 2), sx, sy,
                                   color=colour.get(b["kind"], "0.6"), lw=0))
    fc, _ = sc.furniture_circles()
    if len(fc):
        ax.plot(fc[:, 0], fc[:, 1], "s", color="0.4", ms=2.5, label="furniture legs")
    ax.set_aspect("equal")
    ax.set_xlim(-W / 2 - 0.2, W / 2 + 0.2)
    ax.set_ylim(-H / 2 - 0.2, H / 2 + 0.2)


def write_plots(out: Path, cfg, params, key, num: int = 1, animate: bool = False,
                frames=None) -> None:
    """Top view of the first episode (with the camera's pan direction every second), following
    error over time with the lost intervals shaded, MOT timeline; with ``animate``, an
    animated top view (``episode.gif``).

    ``frames``: that episode's `episode.Frame` record ([T, ...] leaves), when it was already
    run; by default it is run here, from the first of ``jax.random.split(key, 1)``.
    """
    import jax
    import matplotlib.pyplot as plt

    from jaxtrack import plotting
    from jaxtrack.tracking import user
    from sims.following import episode as ep

    out.mkdir(parents=True, exist_ok=True)
    if frames is None:
        frames = jax.jit(ep.make_rollout(cfg))(jax.random.split(key, 1)[0], params)
    f = jax.tree_util.tree_map(lambda x: None if x is None else np.asarray(x), frames)
    t = np.arange(f.robot.shape[0]) * cfg.control_dt
    name = user.build(cfg.estimator).name
    fig, ax = plt.subplots(figsize=(8, 6.5))
    draw_floor(ax, cfg.scene)
    for p in range(f.people.shape[1]):
        if f.people_mask[:, p].any():
            ax.plot(f.people[:, p, 0], f.people[:, p, 1], lw=1 if p else 2,
                    label="user" if p == 0 else None, color="C1" if p == 0 else "0.7")
    ax.plot(f.robot[:, 0], f.robot[:, 1], "C0", lw=2, label="robot")
    ax.plot(f.user_estimate[:, 0], f.user_estimate[:, 1], "C2:", lw=1, label="user estimate")
    if f.pan is not None:
        every = max(1, int(round(1.0 / cfg.control_dt)))
        for k in range(0, f.robot.shape[0], every):
            x, y, th = f.robot[k]
            a = th + f.pan[k]
            ax.plot([x, x + 0.6 * np.cos(a)], [y, y + 0.6 * np.sin(a)], color="C4", lw=0.8,
                    label="camera pan (every second)" if k == 0 else None)
    ax.legend(loc="upper right", fontsize=7)
    ax.set_title(f"person following ({name}): top view")
    fig.savefig(out / "top_view.png", dpi=110)
    fig, ax = plt.subplots(figsize=(8, 3))
    ax.plot(t, f.follow_error, label="|follower point - user|")
    ax.fill_between(t, 0, max(float(f.follow_error.max()), 1e-3), where=f.lost, color="C3",
                    alpha=0.2, label="user lost")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("[m]")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "following_error.png", dpi=110)
    if animate:
        write_animation(out / "episode.gif", cfg, f, np.asarray(params.follower.point),
                        title=f"person following ({name})")
    if cfg.multi_target:
        matched = _matches(f)
        fig = plotting.mot_timeline(matched, f.visible, dt=cfg.control_dt,
                                    title="which track followed which person")
        fig.savefig(out / "mot_timeline.png", dpi=110)
    plt.close("all")


def write_animation(path, cfg, f, point=(1.5, 0.0), title: str = "", every: int = 2,
                    fps: int = 10) -> None:
    """An animated top view of one rollout's `Frame` record ``f`` (numpy leaves): the people,
    the robot's disc and heading, its follower point ``point`` (robot frame), the user
    estimate, the tracker's people and the camera's pan, every ``every``-th frame (GIF,
    `matplotlib.animation.PillowWriter`).
    """
    import matplotlib.pyplot as plt
    from matplotlib import animation

    fig, ax = plt.subplots(figsize=(7, 5.5))
    draw_floor(ax, cfg.scene)
    ax.set_title(title)
    people = ax.scatter([], [], s=30, c="0.6")
    user_dot, = ax.plot([], [], "o", color="C1", ms=8, label="user")
    robot = plt.Circle((0, 0), cfg.scene.robot_radius, color="C0", alpha=0.6, label="robot")
    ax.add_patch(robot)
    heading, = ax.plot([], [], "C0", lw=2)
    target, = ax.plot([], [], "x", color="C0", ms=8, label="follower point")
    estimate, = ax.plot([], [], "+", color="C2", ms=12, mew=2, label="user estimate")
    tracks = ax.scatter([], [], s=60, facecolors="none", edgecolors="C2", lw=0.8)
    pan, = ax.plot([], [], "C4", lw=1)
    clock = ax.text(0.02, 0.96, "", transform=ax.transAxes, fontsize=8, va="top")
    ax.legend(loc="upper right", fontsize=7)
    px, py = (float(v) for v in point)

    def draw(k):
        x, y, th = f.robot[k]
        on = f.people_mask[k]
        people.set_offsets(f.people[k][on])
        user_dot.set_data([f.people[k, 0, 0]], [f.people[k, 0, 1]])
        robot.center = (x, y)
        heading.set_data([x, x + 0.5 * np.cos(th)], [y, y + 0.5 * np.sin(th)])
        c, s = np.cos(th), np.sin(th)
        target.set_data([x + c * px - s * py], [y + s * px + c * py])
        err = f.follow_error[k]
        clock.set_text(f"t = {k * cfg.control_dt:5.1f} s   following error {err:.2f} m"
                       f"{'   user lost' if f.lost[k] else ''}")
        estimate.set_data([f.user_estimate[k, 0]], [f.user_estimate[k, 1]])
        hyp = f.hyp_pos[k][f.hyp_mask[k]]
        tracks.set_offsets(hyp if len(hyp) else np.zeros((0, 2)))
        if f.pan is not None:
            a = th + f.pan[k]
            pan.set_data([x, x + 1.0 * np.cos(a)], [y, y + 1.0 * np.sin(a)])
        return people, user_dot, robot, heading, target, estimate, tracks, pan, clock

    anim = animation.FuncAnimation(fig, draw, frames=range(0, f.robot.shape[0], every),
                                   blit=False)
    anim.save(path, writer=animation.PillowWriter(fps=fps))
    plt.close(fig)


def _matches(f, threshold: float = 0.5) -> np.ndarray:
    """[T, P] id of the nearest confirmed track within ``threshold`` of each visible person."""
    d = np.linalg.norm(f.people[:, :, None] - f.hyp_pos[:, None], axis=-1)
    d = np.where(f.hyp_mask[:, None, :] & f.visible[:, :, None], d, np.inf)
    j = d.argmin(-1)
    ids = np.take_along_axis(f.hyp_ids, j, 1)
    return np.where(np.take_along_axis(d, j[..., None], 2)[..., 0] <= threshold, ids, -1)
