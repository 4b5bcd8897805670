"""``jaxtrack run person-following``: batched episodes, the metrics table and the plots."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["run_person_following", "metrics_table", "estimator_config"]

_ROWS = (("following_rms", "following RMS error [m]", "{:.3f}"),
         ("lost_fraction", "user lost [% of time]", "{:.2%}"),
         ("user_switches", "user id switches [per episode]", "{:.2f}"),
         ("mota", "MOTA", "{:.2%}"),
         ("motp", "MOTP [m]", "{:.3f}"),
         ("mot_switches", "MOT id switches [per episode]", "{:.2f}"),
         ("near_fraction", "someone within 0.45 m [% of time]", "{:.2%}"),
         ("stop_fraction", "safety stop [% of time]", "{:.2%}"))


def metrics_table(metrics: dict, title: str = "") -> str:
    """Mean (and 5-95 % range over episodes) of every episode metric."""
    lines = [title] if title else []
    width = max(len(r[1]) for r in _ROWS) + 2
    lines.append(f"{'metric':<{width}}{'mean':>12}{'5 %':>12}{'95 %':>12}")
    lines.append("-" * (width + 36))
    for key, name, fmt in _ROWS:
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
    config = user.with_sensors(user.CONFIGS[name], sensors)
    if isinstance(config, user.ParticleConfig):
        config = dataclasses.replace(config, pf=dataclasses.replace(config.pf,
                                                                    num_particles=particles))
    if appearance:
        if not isinstance(config, user.MultiTargetConfig):
            raise ValueError(f"appearance applies to the multi-target estimators, not {name!r}")
        config = dataclasses.replace(config, appearance=True)
    return config


def run_person_following(episodes: int = 256, estimator: str = "pf", follower: str = "A",
                         people: int = 4, out: Path | None = None, seed: int = 0,
                         duration: float = 60.0, sensors: str = "both", particles: int = 256,
                         batch_size: int | None = None, stream=sys.stdout,
                         appearance: bool = False) -> dict:
    """Run ``episodes`` closed-loop episodes, print the metrics table, write plots to ``out``.

    Returns ``{"table", "metrics", "compile_seconds", "run_seconds"}``.
    """
    import jax

    from jaxtrack import montecarlo
    from sims.following import episode as ep
    from sims.following import scene

    sc = scene.build(num_people=max(8, people + 1))
    cfg = ep.EpisodeConfig(sc, estimator_config(estimator, sensors, particles, appearance),
                           distractors=people, duration=duration)
    params = ep.make_params(cfg, point=follower)
    episode_fn = ep.make_episode(cfg)
    key = jax.random.PRNGKey(seed)
    t0 = time.perf_counter()
    bs = min(episodes, batch_size or 64)
    # Compile (one batch; montecarlo caches the compiled function for the run below).
    montecarlo.evaluate(episode_fn, params, jax.random.fold_in(key, 1), bs, batch_size=bs,
                        progress=False)
    first_s = time.perf_counter() - t0
    t1 = time.perf_counter()
    res = montecarlo.evaluate(episode_fn, params, key, episodes, batch_size=bs,
                              progress=True)
    run_s = time.perf_counter() - t1
    compile_s = max(first_s - run_s * bs / episodes, 0.0)
    m = {k: np.asarray(v) for k, v in res.metrics.items()}
    title = (f"person following: {episodes} episodes x {duration:.0f} s, estimator {estimator}"
             f" ({sensors}{', appearance' if appearance else ''}), follower point {follower}, "
             f"{people} distractors")
    table = metrics_table(m, title)
    print(table, file=stream)
    print(f"simulated in {run_s:.1f} s after {compile_s:.1f} s of compilation "
          f"({episodes * duration / run_s:.0f} simulated s per wall s)", file=stream)
    if out is not None:
        write_plots(Path(out), cfg, params, key)
        np.savez(Path(out) / "metrics.npz", **m)
    return {"table": table, "metrics": m, "compile_seconds": compile_s, "run_seconds": run_s}


def write_plots(out: Path, cfg, params, key, num: int = 1) -> None:
    """Top view of the first episode, following error over time, MOT timeline."""
    import jax
    import matplotlib.pyplot as plt

    from jaxtrack import plotting
    from jaxtrack.tracking import user
    from sims.following import episode as ep

    out.mkdir(parents=True, exist_ok=True)
    frames = jax.jit(ep.make_rollout(cfg))(jax.random.split(key, 1)[0], params)
    f = jax.tree_util.tree_map(np.asarray, frames)
    t = np.arange(f.robot.shape[0]) * cfg.control_dt
    fig, ax = plt.subplots(figsize=(7, 6))
    W, H = cfg.scene.room
    ax.add_patch(plt.Rectangle((-W / 2, -H / 2), W, H, fill=False, color="k"))
    fc, _ = cfg.scene.furniture_circles()
    if len(fc):
        ax.plot(fc[:, 0], fc[:, 1], "s", color="0.5", ms=3, label="furniture legs")
    for p in range(f.people.shape[1]):
        if f.people_mask[:, p].any():
            ax.plot(f.people[:, p, 0], f.people[:, p, 1], lw=1 if p else 2,
                    label="user" if p == 0 else None, color="C1" if p == 0 else "0.7")
    ax.plot(f.robot[:, 0], f.robot[:, 1], "C0", lw=2, label="robot")
    ax.plot(f.user_estimate[:, 0], f.user_estimate[:, 1], "C2:", lw=1, label="user estimate")
    ax.set_aspect("equal")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(f"person following ({user.build(cfg.estimator).name}): top view")
    fig.savefig(out / "top_view.png", dpi=110)
    fig, ax = plt.subplots(figsize=(8, 3))
    ax.plot(t, f.follow_error, label="|follower point - user|")
    ax.fill_between(t, 0, f.follow_error.max(), where=f.lost, color="C3", alpha=0.2,
                    label="user lost")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("[m]")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "following_error.png", dpi=110)
    if cfg.multi_target:
        matched = _matches(f)
        fig = plotting.mot_timeline(matched, f.visible, dt=cfg.control_dt,
                                    title="which track followed which person")
        fig.savefig(out / "mot_timeline.png", dpi=110)
    plt.close("all")


def _matches(f, threshold: float = 0.5) -> np.ndarray:
    """[T, P] id of the nearest confirmed track within ``threshold`` of each visible person."""
    d = np.linalg.norm(f.people[:, :, None] - f.hyp_pos[:, None], axis=-1)
    d = np.where(f.hyp_mask[:, None, :] & f.visible[:, :, None], d, np.inf)
    j = d.argmin(-1)
    ids = np.take_along_axis(f.hyp_ids, j, 1)
    return np.where(np.take_along_axis(d, j[..., None], 2)[..., 0] <= threshold, ids, -1)
