"""A humanoid episode as a ceiling camera's recording: full depth images a bag can hold, and
the keys and inputs that let `jaxtrack.io.depth_replay.track_depth` replay the episode's own
tracker on them.

The episode renders only a window of pixels around the robot (`sensor.render_window`); the
rest of each image is the static room (`sensor.background`, noise-free). `record` runs the
closed-loop episode with ``EpisodeConfig.record`` and pastes each frame's noisy window into
the background: the image the episode's tracker saw.

Example:
  >>> rec = record(jax.random.PRNGKey(0), EpisodeConfig(scene.build(40, 30), num_frames=40),
  ...              make_params([1.0, 0.0, 0.0]))
  >>> bags.write_bag("walk.bag", 1, depth=to_records(rec))
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import numpy as np

from jaxtrack.io import bags
from sims.humanoid import episode as episode_mod
from sims.humanoid import sensor

__all__ = ["Recording", "record", "to_records"]


class Recording(NamedTuple):
    """One recorded episode.

    Attributes:
      times: [T] seconds (frame t at ``(t + 1) * frame_dt``).
      depth: [T, H, W] float32 metres (0: no return); mask: [T, H, W].
      estimate: [T, 3] the episode's own tracker estimates; truth: [T, 3] the torso poses.
      tracker_keys: [T] keys the tracker drew with; tracker_init_key: its start key;
      turn_rate: [T] its control input; start: [3] the start pose.
      metrics: the episode's other metrics.
    """

    times: np.ndarray
    depth: np.ndarray
    mask: np.ndarray
    estimate: np.ndarray
    truth: np.ndarray
    tracker_keys: np.ndarray
    tracker_init_key: np.ndarray
    turn_rate: np.ndarray
    start: np.ndarray
    metrics: dict


def record(key, config: episode_mod.EpisodeConfig,
           params: episode_mod.EpisodeParams) -> Recording:
    """Run one closed-loop episode and keep its camera images (module docstring)."""
    cfg = dataclasses.replace(config, record=True)
    m = jax.jit(episode_mod.make_episode(cfg))(key, params)
    m = {k: np.asarray(v) for k, v in m.items()}
    sc = cfg.scene
    cam = sc.camera
    bg = np.asarray(sensor.background(sc, cfg.dtype))
    K = sensor.window_size(cam)
    T = m["window_points"].shape[0]
    depth = np.broadcast_to(np.where(np.isfinite(bg), bg, 0), (T, *bg.shape)).copy()
    # Back-projection gives height = c_z - depth, so the window's depth is c_z - height (0 where
    # the pixel had no return: its point is the camera centre).
    window = (np.float32(cam.position[2]) - m["window_points"][..., 2]).reshape(T, K, K)
    for t in range(T):
        r, c = int(m["window_row"][t]), int(m["window_col"][t])
        depth[t, r:r + K, c:c + K] = window[t]
    depth = depth.astype(np.float32)
    mask = depth > 0
    times = (np.arange(T) + 1) * cfg.frame_dt
    rest = {k: v for k, v in m.items()
            if k not in ("window_points", "window_row", "window_col", "tracker_keys",
                         "tracker_init_key", "turn_rate")}
    return Recording(times, np.where(mask, depth, 0).astype(np.float32), mask, m["estimate"],
                     m["truth"], m["tracker_keys"], m["tracker_init_key"], m["turn_rate"],
                     np.asarray(params.start), rest)


def to_records(rec: Recording) -> bags.DepthImages:
    """The `bags.DepthImages` that `bags.write_bag(..., depth=...)` writes."""
    return bags.DepthImages(rec.times, rec.depth, rec.mask, np.ones(len(rec.times), bool))
