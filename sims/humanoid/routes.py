r"""Experiment 1 of seed 000 (section 5.2): the humanoid walks open loop along three routes
through five locations under the ceiling camera, and is tracked on the same frames by the
depth particle filter (`jaxtrack.tracking.humanoid.depth_pf`, the seed's tracker) and by a
colour-histogram particle filter (`jaxtrack.tracking.colour_pf`, Nummiaro et al.'s, reference
histogram from the first frame).

Routes (ours: the seed's Fig. 5 shows three routes through locations numbered 1 to 5, from 1
to 5, without coordinates). Five locations in the camera's field of view (camera above
(0.5, 0.5) m at 2.8 m; the floor it sees spans x in [-1.0, 2.0] m, y in [-0.6, 1.6] m):
1 (0.0, 0.1) the start, 2 (1.0, 0.1), 3 (1.0, 0.9), 4 (0.0, 0.9), 5 (0.5, 0.5) the end.

- route A: 1-2-3-4-5, counter-clockwise round the rectangle, then to the centre (3.44 m);
- route B: 1-4-3-2-5, the same rectangle clockwise (3.44 m);
- route C: 1-2-4-3-5, a "Z": the bottom edge, the diagonal, the top edge (3.92 m).

Open loop. The robot starts at location 1 facing the route's second location and is given a
fixed command schedule computed from the nominal route (`schedule`): for each leg, turn in
place at ``turn_rate`` to face the next location, then walk straight at ``speed``; stop after
the last. No controller corrects the gait's execution noise (stride, slip and heading
errors), so the robot drifts from the route and does not reach the locations exactly, as in
the seed.

Each frame (4 Hz): **world step** (the gait executes the frame's command) -> **sense** (the
ceiling camera's depth window, as `sims.humanoid.episode`, and its colour image,
`sims.humanoid.colour`, both of the same posed robot) -> **estimate** (both trackers) ->
**record**. Each episode draws its own light (`colour.draw_lighting`).

Example:
  >>> res = run(jax.random.PRNGKey(0), episodes=4, config=RoutesConfig(scene.build()))
  >>> print(res.table)
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import sys
import time
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import montecarlo
from jaxtrack.angles import wrap
from jaxtrack.perception import colour_histogram, depth
from jaxtrack.tracking import colour_pf, humanoid
from sims.humanoid import colour, gait, scene as scene_mod, sensor

Array = jax.Array

__all__ = ["LOCATIONS", "ROUTES", "ROUTE_NAMES", "RoutesConfig", "RoutesParams", "Schedule",
           "schedule", "make_params", "make_episode", "run", "Results", "table", "plot", "main"]

LOCATIONS = ((0.0, 0.1), (1.0, 0.1), (1.0, 0.9), (0.0, 0.9), (0.5, 0.5))
ROUTES = ((0, 1, 2, 3, 4), (0, 3, 2, 1, 4), (0, 1, 3, 2, 4))
ROUTE_NAMES = ("A 1-2-3-4-5", "B 1-4-3-2-5", "C 1-2-4-3-5")
FILTERS = ("depth", "colour")


@dataclasses.dataclass(frozen=True, eq=False)
class RoutesConfig:
    """Static configuration of the experiment (closed over; changing it recompiles).

    Attributes:
      scene: `scene.Scene` (camera, resolution; 80 x 60 by default).
      depth_tracker: `humanoid.DepthPFConfig` (the seed's tracker, project defaults).
      colour_tracker: `colour_pf.ColourPFConfig`; None: the defaults on the scene's camera.
      speed: walking speed (m/s) of the schedule (0.1: a NAO's usual pace, ours).
      turn_rate: turning speed in place (rad/s) of the schedule (0.5, ours).
      settle_frames: frames after the schedule's last command that still count (the robot
        finishes its step and stands).
      frame_dt: frame period (s; 0.25, the seed's ~4 Hz); substeps: gait sub-steps per frame.
      gait_params: `gait.GaitParams` (the execution noise is what makes the route drift).
      noise: `sensor.DepthNoise`; max_points, max_point_height: the depth cloud as in
        `sims.humanoid.episode.EpisodeConfig`.
      lighting: `colour.LightingConfig`; palette: `colour.Palette`; supersample: sub-pixel
        rays per pixel side of the colour render.
      locations, routes: the five locations and the three routes (module docstring).
      dtype: float dtype.
    """

    scene: scene_mod.Scene
    depth_tracker: humanoid.DepthPFConfig = humanoid.DepthPFConfig()
    colour_tracker: colour_pf.ColourPFConfig | None = None
    speed: float = 0.1
    turn_rate: float = 0.5
    settle_frames: int = 4
    frame_dt: float = 0.25
    substeps: int = 5
    gait_params: gait.GaitParams = gait.GaitParams()
    noise: sensor.DepthNoise = sensor.DepthNoise()
    max_points: int = 96
    max_point_height: float = 0.7
    lighting: colour.LightingConfig = colour.LightingConfig()
    palette: colour.Palette = colour.Palette()
    supersample: int = 2
    locations: tuple = LOCATIONS
    routes: tuple = ROUTES
    dtype: type = jnp.float32

    def colour_config(self) -> colour_pf.ColourPFConfig:
        """The colour tracker's configuration (the defaults on the scene's camera if None)."""
        if self.colour_tracker is not None:
            return self.colour_tracker
        return colour_pf.ColourPFConfig(sensor.ceiling_camera(self.scene.camera))


class RoutesParams(NamedTuple):
    """Per-run inputs (traced): route (int32 index into the routes), depth
    (`humanoid.DepthTrackerParams`), colour (`colour_pf.ColourPFParams`)."""

    route: Array
    depth: humanoid.DepthTrackerParams
    colour: colour_pf.ColourPFParams


class Schedule(NamedTuple):
    """The open-loop commands of the routes, padded to a common length T.

    Attributes:
      start: [R, 3] start poses (location 1, facing the second location).
      command: [R, T, 3] per frame (forward speed m/s, lateral speed, turn rate rad/s).
      stop: [R, T] bools, the robot is told to stop (after the last leg).
      length: [R] frames of each route's schedule.
      num_frames: T (the longest schedule plus ``settle_frames``).
    """

    start: np.ndarray
    command: np.ndarray
    stop: np.ndarray
    length: np.ndarray
    num_frames: int


def schedule(config: RoutesConfig) -> Schedule:
    r"""The open-loop command schedules of ``config.routes`` (module docstring): per leg of
    length :math:`\ell` after a turn :math:`\Delta` (wrapped), :math:`\lceil |\Delta| /
    (\omega\,dt) \rceil` frames at :math:`\Delta / (n\,dt)` then :math:`\lceil \ell / (v\,dt)
    \rceil` frames at :math:`\ell / (n\,dt)`, so that a perfect gait would end exactly at the
    location.

    Example:
      >>> sch = schedule(RoutesConfig(scene.build()))
    """
    locs = np.asarray(config.locations, float)
    if locs.ndim != 2 or locs.shape[1] != 2:
        raise ValueError(f"locations must be [L, 2]; got shape {list(locs.shape)}")
    if not (config.speed > 0 and config.turn_rate > 0 and config.frame_dt > 0):
        raise ValueError("speed, turn_rate and frame_dt must be > 0")
    dt = config.frame_dt
    starts, commands = [], []
    for route in config.routes:
        if len(route) < 2 or min(route) < 0 or max(route) >= len(locs):
            raise ValueError(f"a route must visit >= 2 of the {len(locs)} locations; "
                             f"got {route}")
        pts = locs[list(route)]
        heading = math.atan2(*(pts[1] - pts[0])[::-1])
        starts.append([*pts[0], heading])
        cmds = []
        for a, b in zip(pts[:-1], pts[1:]):
            leg = b - a
            want = math.atan2(leg[1], leg[0])
            turn = math.remainder(want - heading, 2 * math.pi)
            n_turn = math.ceil(abs(turn) / (config.turn_rate * dt) - 1e-9)
            if n_turn:
                cmds += [[0.0, 0.0, turn / (n_turn * dt)]] * n_turn
            length = float(np.hypot(*leg))
            n_walk = math.ceil(length / (config.speed * dt) - 1e-9)
            cmds += [[length / (n_walk * dt), 0.0, 0.0]] * n_walk
            heading = want
        commands.append(np.asarray(cmds))
    lengths = np.array([len(c) for c in commands])
    T = int(lengths.max()) + int(config.settle_frames)
    command = np.zeros((len(commands), T, 3))
    stop = np.ones((len(commands), T), bool)
    for i, c in enumerate(commands):
        command[i, :len(c)] = c
        stop[i, :len(c)] = False
    return Schedule(np.asarray(starts), command, stop, lengths, T)


def make_params(route: int = 0, config: RoutesConfig | None = None, *, position_noise=0.035,
                colour_position_noise=0.035, lam=50.0, temperature=None,
                dtype=jnp.float32) -> RoutesParams:
    """`RoutesParams` from plain values (checked): the route's index, the depth tracker's
    propagation std (m) and likelihood temperature (None: the seed's weight), the colour
    tracker's propagation std (m) and :math:`\\lambda`.

    Example:
      >>> params = make_params(2)
    """
    n_routes = len(ROUTES if config is None else config.routes)
    if not 0 <= int(route) < n_routes:
        raise ValueError(f"route must be in [0, {n_routes}); got {route}")
    depth = humanoid.depth_pf().params(position_noise=position_noise, temperature=temperature,
                                       dtype=dtype)
    col = colour_pf.make_params(position_noise=colour_position_noise, lam=lam, dtype=dtype)
    return RoutesParams(jnp.asarray(int(route), jnp.int32), depth, col)


class _State(NamedTuple):
    gait: gait.GaitState
    depth: object
    colour: object
    colour_depth_heading: Array


def make_episode(config: RoutesConfig):
    """Build ``episode(key, params) -> metrics`` of one open-loop walk along route
    ``params.route``, tracked by both filters on the same frames.

    Frame 0 is the first image: the robot stands at the start, the colour tracker takes its
    reference histogram from it, and both trackers update on it; frame t >= 1 executes the
    schedule's command t - 1.

    Metrics (dict of arrays, T + 1 frames): ``truth`` [T + 1, 3] torso poses; ``depth``,
    ``colour`` [T + 1, 3] the two trackers' estimates; ``colour_depth_heading`` [T + 1] the
    seed's depth PCA
    heading (`depth.pca_heading`, the depth tracker's `humanoid.HeadingConfig`) run at the
    colour tracker's position, as the seed's pipeline does after its position estimate;
    ``active`` [T + 1] frames up to the end of the route's
    schedule plus ``settle_frames``; ``route`` the route's index; ``brightness`` the
    episode's brightness; ``final`` [3] the true pose at the last frame.

    Example:
      >>> episode = make_episode(RoutesConfig(scene.build()))
      >>> m = jax.jit(episode)(jax.random.PRNGKey(0), make_params(1))
    """
    sc = config.scene
    dtype = config.dtype
    sch = schedule(config)
    T = sch.num_frames
    gp = config.gait_params
    depth_est = humanoid.depth_pf(config.depth_tracker, config.frame_dt)
    colour_est = colour_pf.colour_pf(config.colour_config(), config.frame_dt)
    bg_depth = sensor.background(sc, dtype)
    bg_colour = colour.background(sc, config.palette, config.lighting, config.supersample,
                                  dtype)
    k_win = sensor.window_size(sc.camera)
    n_pts = min(config.max_points, k_win * k_win)
    sub_dt = config.frame_dt / config.substeps
    starts = jnp.asarray(sch.start, dtype)
    commands = jnp.asarray(sch.command, dtype)
    stops = jnp.asarray(sch.stop)
    lengths = jnp.asarray(sch.length + config.settle_frames, jnp.int32)
    valid = jnp.ones((sc.camera.height, sc.camera.width), bool)
    seed_heading = config.depth_tracker.heading

    def world_step(key, g, command, stop):
        def sub(gg, kk):
            return gait.step(kk, gg, command[:2], command[2], stop, gp, sub_dt), None

        return jax.lax.scan(sub, g, jax.random.split(key, config.substeps))[0]

    def sense(key, g, lighting):
        k_depth, k_colour = jax.random.split(key)
        truth = gait.torso_pose(g, gp)
        xpos, xmat = scene_mod.pose_geoms(sc, gait.qpos(sc, g, gp))
        pts, mask = sensor.robot_point_cloud(k_depth, sc, xpos, xmat, truth, k_win, bg_depth,
                                             config.noise, dtype=dtype)
        mask = mask & (pts[:, 2] <= config.max_point_height)
        _, idx = jax.lax.top_k(jnp.where(mask, pts[:, 2], -jnp.inf), n_pts)
        img = colour.image(k_colour, sc, xpos, xmat, truth[:2], bg_colour, lighting,
                           config.palette, config.lighting, dtype)
        return truth, pts[idx], mask[idx], img

    def episode(key, params: RoutesParams):
        route = params.route
        k_light, k_init, k_run = jax.random.split(key, 3)
        lighting = colour.draw_lighting(k_light, config.lighting, dtype)
        start = starts[route]
        k_d, k_c = jax.random.split(k_init)

        def colour_init(img):
            return colour_est.init(k_c, params.colour, colour_pf.ColourPrior(start, img, valid))

        blank = jax.eval_shape(colour_init, jnp.zeros((*valid.shape, 3), dtype))
        state = _State(gait.init(start, gp, dtype), depth_est.init(k_d, params.depth, start),
                       jax.tree_util.tree_map(lambda a: jnp.zeros(a.shape, a.dtype), blank),
                       start[2])

        def frame(s: _State, xs):
            key, command, stop, first = xs
            k_gait, k_sense, k_d, k_c = jax.random.split(key, 4)
            # ``first`` comes from the frame index, not the episode: under vmap these stay
            # branches, so the gait step and the colour tracker's initialisation run only on
            # the frames that use them
            g = jax.lax.cond(first, lambda: s.gait,
                             lambda: world_step(k_gait, s.gait, command, stop))
            truth, pts, mask, img = sense(k_sense, g, lighting)
            # Frame 0 is the first image, the robot standing at the start: the colour tracker
            # takes its reference there (the seed's user clicks the start pose on it).
            c_prev = jax.lax.cond(first, lambda: colour_init(img), lambda: s.colour)
            d_state, d_est = depth_est.update(
                k_d, s.depth, humanoid.DepthScan(pts, mask, command[2]), params.depth)
            c_state, c_est = colour_est.update(
                k_c, c_prev, colour_pf.ColourFrame(img, valid, command[2]), params.colour)
            # The seed's pipeline after any position estimate: PCA of the depth points there.
            cd_heading = depth.pca_heading(pts, mask, c_est[:2], seed_heading.pca_radius,
                                           s.colour_depth_heading, seed_heading.window,
                                           seed_heading.gain).heading
            return (_State(g, d_state, c_state, cd_heading),
                    (truth, d_est, c_est, cd_heading))

        # Frame t >= 1 executes command t - 1; frame 0 does not move.
        cmds = jnp.concatenate([jnp.zeros((1, 3), dtype), commands[route]])
        stop = jnp.concatenate([jnp.zeros((1,), bool), stops[route]])
        xs = (jax.random.split(k_run, T + 1), cmds, stop, jnp.arange(T + 1) == 0)
        final, (truth, d_est, c_est, cd_heading) = jax.lax.scan(frame, state, xs)
        return {"truth": truth, "depth": d_est, "colour": c_est,
                "colour_depth_heading": cd_heading,
                "active": jnp.arange(T + 1) <= lengths[route], "route": route,
                "brightness": lighting.brightness, "final": gait.torso_pose(final.gait, gp)}

    return episode


@functools.lru_cache(maxsize=4)
def _episode(config: RoutesConfig):
    """`make_episode` cached by configuration (by identity): runs of one configuration in a
    process share it, and so the batches `jaxtrack.montecarlo` compiled for it."""
    return make_episode(config)


class Results(NamedTuple):
    """Output of `run`: table (markdown), rows (list of dicts, one per route and filter),
    metrics (per route: dict of numpy arrays, one row per episode), compile_seconds,
    run_seconds."""

    table: str
    rows: list
    metrics: list
    compile_seconds: float
    run_seconds: float


def run(key: Array, episodes: int = 16, config: RoutesConfig | None = None,
        params: RoutesParams | None = None, progress: bool = False) -> Results:
    """Experiment 1: ``episodes`` open-loop walks per route (`jaxtrack.montecarlo.evaluate`,
    vmapped), tracked by both filters; the per-route table of `table`.

    Args:
      key: PRNG key (route i uses ``fold_in(key, i)``).
      episodes: walks per route.
      config: `RoutesConfig` (default: the 80 x 60 scene).
      params: `RoutesParams` (its route is replaced per route; default `make_params`).
      progress: show a progress bar.

    Example:
      >>> res = run(jax.random.PRNGKey(0), 16)
    """
    if int(episodes) < 1:
        raise ValueError(f"episodes must be >= 1; got {episodes}")
    config = RoutesConfig(scene_mod.build()) if config is None else config
    params = make_params(0, config, dtype=config.dtype) if params is None else params
    episode = _episode(config)
    compile_s = montecarlo.warm_up(episode, params, key, episodes)
    t1 = time.perf_counter()
    metrics = []
    bar = montecarlo.progress_bar(episodes * len(config.routes), disable=not progress)
    for i in range(len(config.routes)):
        p = params._replace(route=jnp.asarray(i, jnp.int32))
        res = montecarlo.evaluate(episode, p, jax.random.fold_in(key, i), episodes,
                                  progress=False)
        metrics.append({k: np.asarray(v) for k, v in res.metrics.items()})
        bar.update(episodes)
    bar.close()
    run_s = time.perf_counter() - t1
    rows = _rows(metrics, config)
    return Results(table(rows), rows, metrics, compile_s, run_s)


def _errors(m, filt):
    """Per-frame position error (m) [E, T] and heading errors (deg) [E, T] of one filter: its
    own, and the seed's depth PCA at its position (the same for the depth filter)."""
    pos = np.hypot(*(m[filt][..., :2] - m["truth"][..., :2]).transpose(2, 0, 1))
    own = np.rad2deg(np.abs(np.asarray(wrap(m[filt][..., 2] - m["truth"][..., 2]))))
    if filt == "colour":
        seed = np.rad2deg(np.abs(np.asarray(wrap(m["colour_depth_heading"]
                                                 - m["truth"][..., 2]))))
    else:
        seed = own
    return pos, own, seed


def _rows(metrics, config):
    names = ROUTE_NAMES if config.routes == ROUTES else [
        "-".join(str(i + 1) for i in r) for r in config.routes]
    locs = np.asarray(config.locations)
    rows = []
    for name, route, m in zip(names, config.routes, metrics):
        active = m["active"].astype(bool)
        drift = np.hypot(*(m["final"][:, :2] - locs[route[-1]]).T)
        for filt in FILTERS:
            pos, own, seed = _errors(m, filt)
            pos_cm = 100.0 * pos[active]
            per_episode = 100.0 * np.array([np.mean(p[a]) for p, a in zip(pos, active)])
            rows.append({"route": name, "filter": filt, "episodes": len(pos),
                         "frames": int(active.sum()),
                         "pos_mean": pos_cm.mean(), "pos_std": pos_cm.std(),
                         "pos_median": np.median(pos_cm),
                         "pos_p95": np.percentile(pos_cm, 95), "pos_max": pos_cm.max(),
                         "episode_mean_max": per_episode.max(),
                         "head_mean": own[active].mean(), "head_std": own[active].std(),
                         "head_depth_mean": seed[active].mean(),
                         "head_depth_std": seed[active].std(),
                         "drift": 100.0 * np.median(drift)})
    return rows


def table(rows) -> str:
    """Markdown table of `run`'s rows: per route and filter, the position error (cm, pooled
    over the frames of all episodes) mean / std / median / 95th percentile / maximum and the
    worst episode's mean; the heading error mean +- std (deg) of the filter's own heading and of the
    seed's depth PCA heading at its position; the median distance (cm) of the robot's final
    position from the route's last location (the open loop's drift); the frames pooled. The
    last rows pool the routes.

    Example:
      >>> print(table(run(jax.random.PRNGKey(0), 4).rows))
    """
    lines = ["| route | filter | position error mean / std / median / 95 % / max (cm) | worst "
             "episode mean (cm) | heading error, own PCA (deg) | heading error, depth PCA "
             "at the estimate (deg) | final drift (cm) | frames |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(f"| {r['route']} | {r['filter']} | {r['pos_mean']:.2f} / "
                     f"{r['pos_std']:.2f} / {r['pos_median']:.2f} / {r['pos_p95']:.2f} / "
                     f"{r['pos_max']:.2f} | "
                     f"{r['episode_mean_max']:.2f} | {r['head_mean']:.2f} +- "
                     f"{r['head_std']:.2f} | {r['head_depth_mean']:.2f} +- "
                     f"{r['head_depth_std']:.2f} | {r['drift']:.1f} | {r['frames']} |")
    for filt in FILTERS:
        sel = [r for r in rows if r["filter"] == filt]
        w = np.array([r["frames"] for r in sel], float)

        def pooled(key):
            mean = np.sum(w * [r[f"{key}_mean"] for r in sel]) / w.sum()
            var = np.sum(w * (np.square([r[f"{key}_std"] for r in sel])
                              + np.square(np.array([r[f"{key}_mean"] for r in sel]) - mean)))
            return mean, math.sqrt(var / w.sum())

        pos, head, head_d = pooled("pos"), pooled("head"), pooled("head_depth")
        lines.append(f"| all | {filt} | {pos[0]:.2f} / {pos[1]:.2f} / - / - / "
                     f"{max(r['pos_max'] for r in sel):.2f} | | "
                     f"{head[0]:.2f} +- {head[1]:.2f} | {head_d[0]:.2f} +- {head_d[1]:.2f} | "
                     f"| {int(w.sum())} |")
    return "\n".join(lines)


def plot(results: Results, path, config: RoutesConfig | None = None, episode: int = 0):
    """The seed's Figs. 5 and 6 side by side: per route (columns), the true path (thick black)
    and the depth and colour estimates (rows) of one episode, the locations numbered; below,
    box plots of the position error per route and filter. Written to ``path`` (PNG).

    Example:
      >>> plot(run(jax.random.PRNGKey(0), 4), "routes.png")
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    config = RoutesConfig(scene_mod.build()) if config is None else config
    locs = np.asarray(config.locations)
    n = len(results.metrics)
    fig, axes = plt.subplots(3, n, figsize=(3.2 * n, 8.4),
                             gridspec_kw={"height_ratios": [1, 1, 0.9]})
    for j, m in enumerate(results.metrics):
        a = m["active"][episode].astype(bool)
        for i, filt in enumerate(FILTERS):
            ax = axes[i, j]
            ax.plot(*m["truth"][episode, a, :2].T, color="black", lw=2.5, label="truth")
            ax.plot(*m[filt][episode, a, :2].T, color="0.6", lw=1.2, label=f"{filt} PF")
            for k, (x, y) in enumerate(locs):
                ax.annotate(str(k + 1), (x, y), color="tab:red", ha="center", va="center",
                            fontsize=11, weight="bold")
            ax.set_aspect("equal")
            ax.set_xlim(-0.35, 1.35)
            ax.set_ylim(-0.2, 1.2)
            ax.tick_params(labelsize=7)
            if j == 0:
                ax.set_ylabel(f"{filt}: y (m)", fontsize=8)
            if i == 0:
                ax.set_title(f"route {ROUTE_NAMES[j] if config.routes == ROUTES else j}",
                             fontsize=9)
            ax.legend(fontsize=6, loc="upper right")
        ax = axes[2, j]
        data = [_errors(m, filt)[0][m["active"].astype(bool)] for filt in FILTERS]
        ax.boxplot(data, showfliers=True, flierprops={"markersize": 1.5})
        ax.set_xticks([1, 2], list(FILTERS))
        ax.tick_params(labelsize=7)
        if j == 0:
            ax.set_ylabel("position error (m)", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=72)
    plt.close(fig)


def main(argv=None, prog: str = "python -m sims.humanoid.routes") -> int:
    """``jaxtrack run humanoid-routes [--episodes 16] [--seed 0] [--figure PATH]`` (or
    ``python -m sims.humanoid.routes``): run Experiment 1 and print its table (``--help`` for
    the trackers' and the scene's options: ``--particles``, ``--space``, ``--lam``,
    ``--temperature``, ``--floor``, ``--gradient-max``). Returns the exit status; a user error
    is a one-line message and exit status 2, checked before any compilation."""
    parser = argparse.ArgumentParser(prog=prog,
                                     description="Seed 000 Experiment 1: open-loop routes "
                                                 "tracked by the depth and the colour PF")
    parser.add_argument("--episodes", type=int, default=16, help="walks per route")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--particles", type=int, default=128, help="particles of both PFs")
    parser.add_argument("--space", choices=colour_histogram.SPACES, default="rgb",
                        help="colour histogram space (rgb: 8x8x8 bins, hsv: 8x8x4)")
    parser.add_argument("--lam", type=float, default=50.0, help="colour likelihood lambda")
    parser.add_argument("--temperature", type=float, default=None,
                        help="depth likelihood temperature T (default: the seed's weight)")
    parser.add_argument("--floor", default=None, metavar="R,G,B",
                        help="floor albedo in [0, 1] (default: the scene's 0.5,0.45,0.4)")
    parser.add_argument("--gradient-max", type=float, default=None,
                        help="largest illumination gradient per metre (default 0.25)")
    parser.add_argument("--figure", type=Path, default=None, help="write the figure (PNG)")
    parser.add_argument("--progress", action="store_true", help="show a progress bar")
    args = parser.parse_args(argv)
    if args.episodes < 1 or args.particles < 1 or not args.lam > 0:
        parser.error("--episodes and --particles must be >= 1, --lam > 0")
    if args.temperature is not None and not args.temperature > 0:
        parser.error("--temperature must be > 0")
    if args.gradient_max is not None and not args.gradient_max >= 0:
        parser.error("--gradient-max must be >= 0")
    palette = colour.Palette()
    if args.floor is not None:
        try:
            floor = tuple(float(v) for v in args.floor.split(","))
        except ValueError:
            floor = ()
        if len(floor) != 3 or not all(0 <= v <= 1 for v in floor):
            parser.error(f"--floor must be three numbers in [0, 1]; got {args.floor}")
        palette = palette._replace(floor=floor)
    if args.figure is not None:
        import tempfile

        try:
            args.figure.parent.mkdir(parents=True, exist_ok=True)
            with tempfile.NamedTemporaryFile(dir=args.figure.parent):
                pass
        except OSError as err:
            parser.error(f"--figure {args.figure} cannot be written ({err.strerror or err})")
    lighting = colour.LightingConfig()
    if args.gradient_max is not None:
        lighting = lighting._replace(gradient_max=args.gradient_max)
    sc = scene_mod.build()
    bins = (8, 8, 8) if args.space == "rgb" else (8, 8, 4)
    ccfg = colour_pf.ColourPFConfig(sensor.ceiling_camera(sc.camera),
                                    num_particles=args.particles,
                                    histogram=colour_histogram.HistogramConfig(args.space, bins))
    config = RoutesConfig(sc, humanoid.DepthPFConfig(num_particles=args.particles), ccfg,
                          lighting=lighting, palette=palette)
    params = make_params(0, config, lam=args.lam, temperature=args.temperature)
    res = run(jax.random.PRNGKey(args.seed), args.episodes, config, params, args.progress)
    print(res.table)
    print(f"{args.episodes} episodes per route x {len(config.routes)} routes in "
          f"{res.run_seconds:.1f} s after {res.compile_seconds:.1f} s of compilation")
    if args.figure is not None:
        plot(res, args.figure, config)
        print(f"figure: {args.figure}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
