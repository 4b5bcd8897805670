"""A humanoid tracker replayed on recorded ceiling depth images (seed 000's set-up from a bag).

`track_depth` runs, per depth image, the measurement the simulated humanoid episode builds
(`jaxtrack.perception.depth.ceiling_cloud`: back-projection through the ceiling camera, floor
removal, the highest ``max_points`` points) and one tracker of `jaxtrack.tracking.humanoid`
(``"pf"``, ``"pf3"``, ``"ukf"``): the same step functions as `sims.humanoid.episode`, with no
controller and no MuJoCo. Frames run in fixed-size chunks, one ``lax.scan`` each, compiled
once; the last chunk is padded with frames that leave the state unchanged.

`track_depth_bag` is ``jaxtrack track --depth-topic``: a bag in, ``trajectory.csv`` and a top
view out.

Example:
  >>> images = bags.read_depth("run.bag", "/camera/depth/image_raw")
  >>> cam = depth.CeilingCamera((0.0, 0.0, 3.0), 69.3, 69.3, 40.0, 30.0)
  >>> out = track_depth(images, cam, start=(0.0, 0.0, 0.0))
"""

from __future__ import annotations

import functools
import math
import sys
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import montecarlo
from jaxtrack.io import bags
from jaxtrack.perception import depth
from jaxtrack.tracking import humanoid

Array = jax.Array

__all__ = ["DepthTrack", "track_depth", "track_depth_bag", "write_trajectory"]


class DepthTrack(NamedTuple):
    """Tracker output, one row per depth image.

    Attributes:
      times: [T] seconds; pose: [T, 3] (x, y, heading) in the world (floor) frame;
      num_points: [T] int32, the points above the floor the tracker was given.
    """

    times: np.ndarray
    pose: np.ndarray
    num_points: np.ndarray


def track_depth(images: bags.DepthImages, camera: depth.CeilingCamera, start=None,
                tracker="pf", *, params: humanoid.DepthTrackerParams | None = None,
                key: Array | None = None, keys: Array | None = None,
                init_key: Array | None = None, turn_rate=None, max_points: int = 96,
                floor_threshold: float = 0.06, max_height: float | None = None,
                chunk: int = 64, dtype=jnp.float32, progress: bool = True,
                stream=None) -> DepthTrack:
    """Track a humanoid through recorded ceiling depth images.

    Args:
      images: `bags.DepthImages` (T images [H, W]; rows with ``valid`` False are skipped).
      camera: `depth.CeilingCamera` (position, focal lengths, principal point).
      start: [3] the initial pose (x, y, heading); default the centroid of the first image's
        points above the floor, heading 0.
      tracker: a name of `humanoid.TRACKERS` or a tracker configuration.
      params: `humanoid.DepthTrackerParams` (default the tracker's, 3.5 cm propagation noise).
      key: PRNG key (default ``PRNGKey(0)``): frame t draws with ``split(key, T)[t]`` and the
        start with ``fold_in(key, T)``. ``keys`` [T] / ``init_key`` give them explicitly
        (to replay a simulated episode with its own keys).
      turn_rate: [T] the commanded turn rate over the frame before each image (rad/s), the
        trackers' control input; default 0.
      max_points, floor_threshold, max_height: `depth.ceiling_cloud`'s (the simulated scene
        drops points above 0.7 m: `sims.humanoid.episode.EpisodeConfig.max_point_height`).
      chunk: frames per compiled ``lax.scan``.

    Returns:
      `DepthTrack`.

    Example:
      >>> out = track_depth(bags.read_depth("run.bag", "/depth"), cam, start=(0, 0, 0))
    """
    rows = np.flatnonzero(np.asarray(images.valid, bool))
    if rows.size == 0:
        raise ValueError("no depth image to replay")
    if int(chunk) < 1:
        raise ValueError(f"chunk must be >= 1; got {chunk}")
    if int(max_points) < 1:
        raise ValueError(f"max_points must be >= 1; got {max_points}")
    camera = _check_camera(camera)
    times = np.asarray(images.times, np.float64)[rows]
    T = rows.size
    dt = round(float(np.median(np.diff(times))), 6) if T > 1 else 0.25
    if not dt > 0:
        raise ValueError("image times must increase")
    config = tracker if not isinstance(tracker, str) else _named(tracker)
    est = humanoid.build(config, dt)
    np_dtype = np.dtype(jnp.dtype(dtype).name)
    images_d = np.asarray(images.depth)[rows].astype(np_dtype)
    masks = np.asarray(images.mask, bool)[rows]
    key = jax.random.PRNGKey(0) if key is None else key
    keys = jax.random.split(key, T) if keys is None else jnp.asarray(keys)
    if keys.shape[0] != T:
        raise ValueError(f"keys must hold one key per image ({T}); got {keys.shape[0]}")
    init_key = jax.random.fold_in(key, T) if init_key is None else init_key
    turn = (np.zeros(T) if turn_rate is None
            else np.asarray(turn_rate, np.float64).reshape(-1))
    if turn.shape != (T,) or not np.all(np.isfinite(turn)):
        raise ValueError(f"turn_rate must be [{T}] finite values")
    params = est.params(dtype=dtype) if params is None else params
    if max_height is not None and not math.isfinite(float(max_height)):
        raise ValueError(f"max_height must be finite or None; got {max_height}")
    limit = None if max_height is None else float(max_height)
    cloud = _cloud_fn(camera, int(max_points), float(floor_threshold), limit)
    if start is None:
        pts, mask = cloud(jnp.asarray(images_d[0]), jnp.asarray(masks[0]))
        if not bool(mask.any()):
            raise ValueError("the first image has no point above the floor: give start")
        centre = np.asarray(pts)[np.asarray(mask), :2].mean(0)
        start = (float(centre[0]), float(centre[1]), 0.0)
    start = np.asarray(start, np.float64)
    if start.shape != (3,) or not np.all(np.isfinite(start)):
        raise ValueError(f"start must be a finite (x, y, heading); got {start}")
    state = est.init(init_key, params, jnp.asarray(start, dtype))
    run = _chunk_runner(config, dt, camera, int(max_points), float(floor_threshold), limit)
    C = int(chunk)
    poses, counts = [], []
    bar = montecarlo.progress_bar(T, unit="frames", file=stream, disable=not progress)
    for s0 in range(0, T, C):
        idx = np.arange(s0, s0 + C)
        sl = np.minimum(idx, T - 1)
        xs = (jnp.asarray(images_d[sl]), jnp.asarray(masks[sl]), keys[sl],
              jnp.asarray(turn[sl], dtype), jnp.asarray(idx < T))
        state, (pose, n) = run(state, xs, params)
        n_ok = min(C, T - s0)
        poses.append(np.asarray(pose)[:n_ok])
        counts.append(np.asarray(n)[:n_ok])
        bar.update(n_ok)
    bar.close()
    return DepthTrack(times, np.concatenate(poses), np.concatenate(counts).astype(np.int32))


def _named(name):
    if name not in humanoid.TRACKERS:
        raise ValueError(f"unknown tracker {name!r}; choose from {humanoid.TRACKERS}")
    return {"pf": humanoid.DepthPFConfig(), "pf3": humanoid.DepthPF3Config(),
            "ukf": humanoid.CentroidUKFConfig()}[name]


def _check_camera(camera) -> depth.CeilingCamera:
    if not isinstance(camera, depth.CeilingCamera):
        raise TypeError(f"camera must be a depth.CeilingCamera; got {type(camera).__name__}")
    position = tuple(float(v) for v in camera.position)
    values = (*position, camera.fx, camera.fy, camera.cx, camera.cy)
    if len(position) != 3 or not all(math.isfinite(float(v)) for v in values):
        raise ValueError(f"camera values must be finite, position (x, y, z); got {camera}")
    if not (position[2] > 0 and camera.fx > 0 and camera.fy > 0):
        raise ValueError(f"the camera must be above the floor with positive focal lengths; "
                         f"got {camera}")
    return depth.CeilingCamera(position, float(camera.fx), float(camera.fy), float(camera.cx),
                               float(camera.cy))


@functools.lru_cache(maxsize=8)
def _cloud_fn(camera, max_points, floor_threshold, max_height):
    return jax.jit(lambda d, m: depth.ceiling_cloud(camera, d, m, max_points, floor_threshold,
                                                    max_height))


@functools.lru_cache(maxsize=8)
def _chunk_runner(config, dt, camera, max_points, floor_threshold, max_height):
    est = humanoid.build(config, dt)

    def run(state, xs, params):
        def frame(s, x):
            image, mask, k, turn, valid = x
            pts, pmask = depth.ceiling_cloud(camera, image, mask, max_points, floor_threshold,
                                             max_height)
            new, pose = est.update(k, s, humanoid.DepthScan(pts, pmask, turn), params)
            new = jax.tree_util.tree_map(lambda a, b: jnp.where(valid, a, b), new, s)
            return new, (pose, jnp.sum(pmask))

        return jax.lax.scan(frame, state, xs)

    return jax.jit(run)


def write_trajectory(path, track: DepthTrack) -> int:
    """Write ``time,x,y,heading`` rows (CSV with a header); returns the rows written."""
    data = np.column_stack([track.times, track.pose])
    np.savetxt(path, data, delimiter=",", header="time,x,y,heading", comments="",
               fmt=["%.9f", "%.6f", "%.6f", "%.6f"])
    return len(data)


def track_depth_bag(bag, topic: str, out, *, camera_position, focal, principal=None, start=None,
                    tracker: str = "pf", max_points: int = 96, floor_threshold: float = 0.06,
                    max_height: float | None = None, seed: int = 0, chunk: int = 64,
                    time_source: str = "header",
                    stream=None) -> dict:
    """``jaxtrack track --depth-topic``: read the depth images (``sensor_msgs/Image`` 16UC1 or
    32FC1), replay `track_depth`, write ``trajectory.csv`` (`write_trajectory`) and
    ``top_view.png`` into ``out``. The camera (`depth.CeilingCamera`): ``camera_position``
    (x, y, height), ``focal`` (fx, fy) in pixels and ``principal`` (cx, cy) from the image's
    corner (default the image centre).

    Returns ``{"track": DepthTrack, "csv": path, "plot": path, "report": bags.BagReport}``.

    Example:
      >>> track_depth_bag("run.bag", "/camera/depth/image_raw", "out",
      ...                 camera_position=(0.5, 0.5, 2.8), focal=(36.8, 38.1))
    """
    from pathlib import Path

    stream = sys.stdout if stream is None else stream
    images = bags.read_depth(bag, topic, time_source=time_source)
    H, W = images.depth.shape[1:]
    cx, cy = (W / 2.0, H / 2.0) if principal is None else principal
    camera = depth.CeilingCamera(tuple(camera_position), *focal, cx, cy)
    result = track_depth(images, camera, start, tracker, key=jax.random.PRNGKey(seed),
                         max_points=max_points, floor_threshold=floor_threshold,
                         max_height=max_height, chunk=chunk,
                         stream=stream)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    csv = out / "trajectory.csv"
    rows = write_trajectory(csv, result)
    plot = out / "top_view.png"
    _top_view(plot, result, f"{Path(bag).name}: {tracker}")
    report = images.report
    print(f"{rows} depth frames ({result.times[-1] - result.times[0]:.1f} s) tracked with "
          f"{tracker}: median {np.median(result.num_points):.0f} points per frame -> {csv}, "
          f"{plot}", file=stream)
    if report is not None and not report.complete:
        print(f"warning: {report.topic}: {report.messages} messages read: {report.detail}",
              file=stream)
    return {"track": result, "csv": csv, "plot": plot, "report": report}


def _top_view(path, track: DepthTrack, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 5))
    p = track.pose
    ax.plot(p[:, 0], p[:, 1], ".-", ms=3, lw=1, label="estimate")
    step = max(1, len(p) // 20)
    ax.quiver(p[::step, 0], p[::step, 1], np.cos(p[::step, 2]), np.sin(p[::step, 2]),
              angles="xy", scale=20, width=0.004, color="C1", label="heading")
    ax.set_aspect("equal")
    ax.set(xlabel="x [m]", ylabel="y [m]", title=title)
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)
