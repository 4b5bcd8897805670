"""The service scene's experiments as batched Monte-Carlo runs: tables, top views, animations.

`run_service` is what ``jaxtrack run service --experiment ...`` calls.
"""

from __future__ import annotations

import functools
import math
import sys
from pathlib import Path

import numpy as np

__all__ = ["run_service", "metrics_table", "write_plots", "draw_flat", "paired_difference"]

_ROWS = (("success", "success", "pct"),
         ("rule", "rule holds", "pct"),
         ("time_to_goal", "time to goal [s] (episodes done)", "{:.1f}"),
         ("path_length", "path length [m]", "{:.2f}"),
         ("min_distance", "min distance to a person's centre from the body [m]", "{:.2f}"),
         ("intimate_time", "time in an intimate zone [s] (sum over people)", "{:.2f}"),
         ("personal_time", "time in a personal zone [s] (sum over people)", "{:.1f}"),
         ("intimate", "episodes with an intimate-zone intrusion", "pct"),
         ("right_pass", "passed a walker on their right", "pct"),
         ("tv_crossing", "crossed a person-TV interaction", "pct"),
         ("final_distance", "final distance to the person [m]", "{:.2f}"),
         ("final_angle", "final bearing from the person's heading [deg]", "deg"),
         ("heading_error", "person's heading error [deg]", "deg"),
         ("person_lost", "person's estimate lost (> 1 m off)", "pct"),
         ("mota", "MOTA (behaviour's tracker)", "pct"),
         ("motp", "MOTP [m]", "{:.3f}"),
         ("mota_ceiling", "MOTA, ceiling cameras only", "pct"),
         ("mota_robot", "MOTA, robot only (RGB-D + laser)", "pct"))

_PERSON = {"final_distance", "final_angle", "heading_error", "person_lost"}
_RELEVANT = {
    "avoid": {"right_pass", "tv_crossing"} | _PERSON,
    "overtake": {"tv_crossing"} | _PERSON,
    "tv": {"right_pass"} | _PERSON,
    "handover": {"right_pass", "tv_crossing"},
    "approach": {"right_pass", "tv_crossing", "time_to_goal", "mota", "motp", "rule"},
}


def _format(v, fmt):
    v = np.asarray(v, float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return "-"
    if fmt == "pct":
        return f"{100 * v.mean():.1f} %"
    if fmt == "deg":
        return f"{np.degrees(np.abs(v)).mean():.1f} (sd {np.degrees(np.abs(v)).std():.1f})"
    return fmt.format(v.mean()) + (f" (sd {fmt.format(v.std())})" if v.size > 1 else "")


def metrics_table(m: dict, title: str = "", experiment: str = "avoid") -> str:
    """A markdown table of the mean metrics of a run (``m``: name -> [N] or [N, P] arrays)."""
    lines = [f"### {title}" if title else "", "", "| metric | value |", "| --- | --- |"]
    skip = _RELEVANT.get(experiment, set())
    for key, label, fmt in _ROWS:
        if key not in m or key in skip:
            continue
        v = np.asarray(m[key], float)
        if key == "min_distance":
            v = np.nanmin(np.where(np.isfinite(v), v, np.nan), axis=-1) if v.ndim > 1 else v
        elif v.ndim > 1:
            v = np.nansum(v, axis=-1)
        lines.append(f"| {label} | {_format(v, fmt)} |")
    n = len(next(iter(m.values())))
    if "mota_ceiling" in m:
        for other, name in (("mota_ceiling", "ceiling only"), ("mota_robot", "robot only")):
            d, lo, hi = paired_difference(m["mota"], m[other])
            lines.append(f"| MOTA all sensors - {name} [points] | {100 * d:+.1f} "
                         f"[{100 * lo:+.1f}, {100 * hi:+.1f}] |")
    lines.append(f"| episodes | {n} |")
    return "\n".join(lines).strip() + "\n"


def paired_difference(a, b, z: float = 1.96):
    """Mean of ``a - b`` over episodes and its normal 95 % interval (finite pairs only)."""
    d = np.asarray(a, float) - np.asarray(b, float)
    d = d[np.isfinite(d)]
    if d.size == 0:
        return math.nan, math.nan, math.nan
    half = z * d.std(ddof=1) / math.sqrt(d.size) if d.size > 1 else math.nan
    return d.mean(), d.mean() - half, d.mean() + half


@functools.lru_cache(maxsize=16)
def _episode(experiment, perception, compare_sensors, interest, duration, heading_filter=None,
             pan=False, reverse=False, settle_iterations=0, still_at_end=0.0,
             heading_frame="odom", line_of_sight=False, replan_every=None, cell=0.1,
             corroborated_births=True):
    from jaxtrack.control import pan_tilt
    from sims.service import episode as ep

    cfg = ep.ServiceConfig(_scene(), experiment=experiment, perception=perception,
                           compare_sensors=compare_sensors, interest=interest,
                           duration=duration, heading_filter=heading_filter,
                           pan=pan_tilt.PanTiltConfig() if pan else None, reverse=reverse,
                           settle_iterations=settle_iterations, still_at_end=still_at_end,
                           heading_frame=heading_frame, line_of_sight=line_of_sight,
                           cell=cell, corroborated_births=corroborated_births,
                           **({} if replan_every is None else {"replan_every": replan_every}))
    return cfg, ep.make_episode(cfg)


@functools.lru_cache(maxsize=1)
def _scene():
    from sims.service import episode as ep

    return ep.build_scene()


def run_service(experiment: str = "avoid", episodes: int = 256, duration: float = 60.0,
                perception: str = "all", compare_sensors: bool = False,
                interest: float | None = 0.5, out: Path | None = None, seed: int = 0,
                batch_size: int | None = None, animate: bool = False, progress: bool = True,
                stream=sys.stdout, heading_filter: str | None = None, pan: bool = False,
                reverse: bool = False, settle_iterations: int = 0,
                still_at_end: float = 0.0, heading_frame: str = "odom",
                line_of_sight: bool = False, replan_every: int | None = None,
                cell: float = 0.1, corroborated_births: bool = True) -> dict:
    """Run ``episodes`` closed-loop episodes of ``experiment``, print the table, write plots.

    ``heading_filter``: the approach's heading filter, and the hand-over's source of the
    waiting person's heading; None: the scene's default for the experiment
    (`sims.service.episode.ServiceConfig`). ``replan_every``: frames between full solves of the planner's distance field (refined a
    few rounds in the frames between; None: the scene's default); ``cell``: the costmap's cell (m);
    ``corroborated_births``: RGB-D detections no ceiling camera sees start tracks only beside
    a laser detection (`sims.service.episode.ServiceConfig`).

    Returns ``{"table", "metrics", "compile_seconds", "run_seconds"}``.

    Example:
      >>> res = run_service("tv", episodes=16, duration=30.0)
    """
    import jax

    from sims._runs import timed_evaluate
    from sims.service import episode as ep

    cfg, episode_fn = _episode(experiment, perception, bool(compare_sensors),
                               None if interest is None else float(interest), float(duration),
                               heading_filter, pan, bool(reverse), int(settle_iterations),
                               float(still_at_end), heading_frame, bool(line_of_sight),
                               None if replan_every is None else int(replan_every),
                               float(cell), bool(corroborated_births))
    params = ep.make_params(cfg)
    key = jax.random.PRNGKey(seed)
    m, compile_s, run_s = timed_evaluate(episode_fn, params, key, episodes, batch_size,
                                         progress)
    pi = "estimated" if interest is None else f"{float(interest):g}"
    title = (f"service robot, experiment {experiment}: {episodes} episodes x {duration:.0f} s, "
             f"perception {perception}" + (f", person interest {pi}, heading filter "
                                           f"{cfg.heading_filter}" + (", pan unit" if pan else "")
                                           + (", reversing" if reverse else "")
                                           + (f", to the settled point ({settle_iterations} "
                                              "steps)" if settle_iterations else "")
                                           + (f", still for the last {still_at_end:g} s"
                                              if still_at_end else "")
                                           + (", heading in the map frame"
                                              if heading_frame == "map" else "")
                                           if experiment == "approach" else "")
             + (f", heading filter {cfg.heading_filter}"
                if experiment == "handover" and cfg.heading_filter != "ar" else "")
             + (", RGB-D in the laser's line of sight" if line_of_sight else "")
             + (f", full replan every {cfg.replan_every} frames"
                if cfg.replan_every != ep.ServiceConfig.replan_every else "")
             + (f", {cell:g} m cells" if cell != 0.1 else "")
             + ("" if corroborated_births else ", uncorroborated RGB-D births"))
    table = metrics_table(m, title, experiment)
    print(table, file=stream)
    print(f"simulated in {run_s:.1f} s after {compile_s:.1f} s of compilation "
          f"({episodes * duration / run_s:.0f} simulated s per wall s)", file=stream)
    if out is not None:
        out = Path(out)
        write_plots(out, cfg, params, key, animate=animate)
        np.savez(out / "metrics.npz", **m)
    return {"table": table, "metrics": m, "compile_seconds": compile_s, "run_seconds": run_s}


def draw_flat(ax, sc) -> None:
    """The flat's plan on ``ax``: outer walls, interior walls, couch, TV, counter, table legs,
    and the sitting and hand-over areas."""
    import matplotlib.pyplot as plt

    from sims.service import flat

    W, H = sc.room
    ax.add_patch(plt.Rectangle((-W / 2, -H / 2), W, H, fill=False, color="k"))
    colour = {"wall": "0.3", "couch": "C5", "tv": "k", "counter": "0.55"}
    for b in sc.blocks:
        (cx, cy), (sx, sy) = b["centre"], b["size"]
        ax.add_patch(plt.Rectangle((cx - sx / 2, cy - sy / 2), sx, sy,
                                   color=colour.get(b["kind"], "0.6"), lw=0))
    fc, _ = sc.furniture_circles()
    if len(fc):
        ax.plot(fc[:, 0], fc[:, 1], "s", color="0.4", ms=2.5)
    for (x0, y0, x1, y1), c, name in ((flat.SITTING_AREAS[0], "C5", "sitting area"),
                                      (flat.HANDOVER_AREA, "C2", "hand-over area")):
        ax.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ls="--", color=c,
                                   lw=0.8, label=name))
    ax.set_aspect("equal")
    ax.set_xlim(-W / 2 - 0.2, W / 2 + 0.2)
    ax.set_ylim(-H / 2 - 0.2, H / 2 + 0.2)


def _costmap_at(cfg, params, f, k):
    """The costmap the robot planned on at frame ``k`` (recomputed from the record)."""
    import jax.numpy as jnp

    from jaxtrack.control import costmap
    from sims.service import episode as ep
    from sims.service import flat

    g = ep.grid(cfg)
    present = f.status[k] >= 0
    attended = np.where(f.status[k] == costmap.SEATED, 0, -1).astype(np.int32)
    people = costmap.build(g, params.cost, jnp.asarray(f.hyp_pos[k, 0]),
                           jnp.asarray(f.heading[k]), jnp.asarray(np.maximum(f.status[k], 0)),
                           jnp.asarray(present), objects_xy=jnp.asarray(flat.TV[None]),
                           attended=jnp.asarray(attended))
    static = ep.static_cost(cfg)
    return np.maximum(np.asarray(people), np.where(np.isinf(static), 1.0, static))


def write_plots(out: Path, cfg, params, key, animate: bool = False) -> None:
    """Top view of the first episode over the costmap at its middle frame (``top_view.png``);
    with ``animate``, an animated top view with the costmap of each frame (``episode.gif``)."""
    import jax
    import matplotlib.pyplot as plt

    from sims.service import episode as ep

    out.mkdir(parents=True, exist_ok=True)
    frames = jax.jit(ep.make_rollout(cfg))(jax.random.split(key, 1)[0], params)
    f = jax.tree_util.tree_map(np.asarray, frames)
    T = f.robot.shape[0]
    done = np.flatnonzero(f.done)
    k_mid = int(done[0] // 2) if done.size else T // 2
    W, H = cfg.scene.room
    fig, ax = plt.subplots(figsize=(9, 6.5))
    if cfg.experiment != "approach":
        ax.imshow(_costmap_at(cfg, params, f, k_mid), origin="lower", cmap="Reds", vmin=0,
                  vmax=1, extent=(-W / 2, W / 2, -H / 2, H / 2), alpha=0.6)
    draw_flat(ax, cfg.scene)
    for p in range(f.people.shape[1]):
        if f.people_mask[:, p].any():
            ax.plot(f.people[:, p, 0], f.people[:, p, 1], color="C1", lw=1.5,
                    label="people" if p == 0 else None)
            ax.plot(*f.people[k_mid, p], "o", color="C1", ms=6)
    ax.plot(f.robot[:, 0], f.robot[:, 1], "C0", lw=2, label="robot")
    ax.plot(*f.robot[k_mid, :2], "o", color="C0", ms=6)
    ax.plot(*f.goal[-1], "*", color="C3", ms=12, label="goal")
    ax.legend(loc="upper left", fontsize=7)
    ax.set_title(f"service robot, {cfg.experiment}: top view (costmap at t = "
                 f"{k_mid * cfg.control_dt:.1f} s)")
    fig.tight_layout()
    fig.savefig(out / "top_view.png", dpi=110)
    plt.close(fig)
    if animate:
        write_animation(out / "episode.gif", cfg, params, f)


def write_animation(path, cfg, params, f, every: int = 3, fps: int = 10) -> None:
    """Animated top view of one rollout ``f`` (numpy leaves) over its costmaps (GIF)."""
    import matplotlib.pyplot as plt
    from matplotlib import animation

    W, H = cfg.scene.room
    fig, ax = plt.subplots(figsize=(8, 5.5))
    nav = cfg.experiment != "approach"
    image = ax.imshow(np.zeros((2, 2)), origin="lower", cmap="Reds", vmin=0, vmax=1,
                      extent=(-W / 2, W / 2, -H / 2, H / 2), alpha=0.6)
    draw_flat(ax, cfg.scene)
    people = ax.scatter([], [], s=40, c="C1")
    robot = plt.Circle((0, 0), cfg.robot_radius, color="C0", alpha=0.6)
    ax.add_patch(robot)
    heading, = ax.plot([], [], "C0", lw=2)
    tracks = ax.scatter([], [], s=80, facecolors="none", edgecolors="C2", lw=0.8)
    clock = ax.text(0.02, 0.96, "", transform=ax.transAxes, fontsize=8, va="top")

    def draw(k):
        if nav:
            image.set_data(_costmap_at(cfg, params, f, k))
        x, y, th = f.robot[k]
        people.set_offsets(f.people[k][f.people_mask[k]])
        robot.center = (x, y)
        heading.set_data([x, x + 0.5 * np.cos(th)], [y, y + 0.5 * np.sin(th)])
        hyp = f.hyp_pos[k, 0][f.hyp_mask[k, 0]]
        tracks.set_offsets(hyp if len(hyp) else np.zeros((0, 2)))
        clock.set_text(f"t = {k * cfg.control_dt:5.1f} s{'   done' if f.done[k] else ''}")
        return image, people, robot, heading, tracks, clock

    anim = animation.FuncAnimation(fig, draw, frames=range(0, f.robot.shape[0], every),
                                   blit=False)
    anim.save(path, writer=animation.PillowWriter(fps=fps))
    plt.close(fig)
