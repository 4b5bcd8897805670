"""Person-following recordings, and the trackers replayed on recorded data.

Recording (`make_recorder`, `record`): an open-loop run of the person-following scene that keeps
the raw sensor data, as a robot's bag would: per 10 Hz frame the laser ranges
(`sims.following.lidar.scan`), the RGB-D person detections in the robot frame
(`sims.following.rgbd.detect`) and the odometry pose and twist (`rgbd.odometry` integrated from
the start pose), with the true robot and people for evaluation. The people walk as in
`sims.following.pedestrians`; the robot follows the true user with a simple proportional law
(speed from the distance error to ``follow_distance``, turn rate from the bearing), so no
estimator is in the loop. `to_records` turns a recording into the `jaxtrack.io.bags` records
that `jaxtrack.io.bags.write_bag` writes.

Replay (`track`): leg detection (`jaxtrack.perception.legs.detect`) and one of the estimators of
`sims.following.estimators` over a recording, read from a bag or in memory: the frames are the
laser scans; odometry (the nearest message in time) and detections (the nearest message within
half a frame) are aligned to them. Everything runs in the odometry frame (the identity pose
without odometry), in fixed-size chunks: one ``lax.scan`` per chunk, compiled once, the last
chunk padded with masked frames, the estimator state carried from chunk to chunk.

Example:
  >>> rec = record(jax.random.PRNGKey(0), duration=3.0)
  >>> laser, odom, det = to_records(rec)
  >>> tracks = track(laser, odom, det, estimator="gnn")
"""

from __future__ import annotations

import functools
import sys
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack.angles import wrap
from jaxtrack.io import bags
from jaxtrack.perception import legs
from sims.following import episode, estimators, lidar, pedestrians
from sims.following import rgbd as rgbd_mod

Array = jax.Array

__all__ = ["Recording", "Tracks", "make_recorder", "record", "to_records", "track", "track_bag",
           "write_top_view"]


class Recording(NamedTuple):
    """Raw sensor data of a recording, one row per 10 Hz frame (T frames).

    Attributes:
      times: [T] seconds (``dt, 2 dt, ...``).
      ranges: [T, B] laser ranges (m; misses read ``max_range``); angles: [B].
      odom_pose: [T, 3] odometry pose (x, y, yaw) in the odometry frame (the true start pose at
        time 0, drifting after); odom_twist: [T, 3] (vx, vy, wz) of the odometry increments.
      det_xy: [T, M, 2] RGB-D person detections in the robot frame; det_mask: [T, M].
      robot: [T, 3] true robot pose; people: [T, P, 2] true people; people_mask: [T, P]
        (person 0 is the user).
    """

    times: Array
    ranges: Array
    angles: Array
    odom_pose: Array
    odom_twist: Array
    det_xy: Array
    det_mask: Array
    robot: Array
    people: Array
    people_mask: Array


class Tracks(NamedTuple):
    """Tracker output in the odometry frame, one row per laser frame.

    Attributes:
      frames: [T] int32 frame numbers (1, 2, ...); times: [T] seconds.
      ids: [T, H] int32 track identities (for ``"pf"`` the particle-cluster slot, for ``"kf"``
        0: neither keeps identities over time); pos: [T, H, 2]; mask: [T, H] confirmed tracks.
      user: [T, 2] the followed user's estimate; user_found: [T] measured at that frame.
    """

    frames: np.ndarray
    times: np.ndarray
    ids: np.ndarray
    pos: np.ndarray
    mask: np.ndarray
    user: np.ndarray
    user_found: np.ndarray


# ---------------------------------------------------------------------------------------------
# Recording


def make_recorder(scene, *, distractors: int = 3, duration: float = 3.0, dt: float = 0.1,
                  laser: lidar.LaserConfig = lidar.LaserConfig(),
                  rgbd: rgbd_mod.RGBDConfig = rgbd_mod.RGBDConfig(),
                  odometry: rgbd_mod.OdometryConfig = rgbd_mod.OdometryConfig(),
                  follow_distance: float = 1.2, max_speed: float = 1.0, max_turn: float = 1.5,
                  dtype=jnp.float32):
    """Build ``record(key) -> Recording`` (jittable) for a `sims.following.scene.Scene`.

    The robot's command each frame: :math:`v = \\operatorname{clip}(0.8 (d - d_f), 0,
    v_{max})`, :math:`\\omega = \\operatorname{clip}(1.5\\,\\beta, \\pm\\omega_{max})` with
    :math:`d`, :math:`\\beta` the true user's distance and bearing; the pose is integrated
    exactly for the frame (`rgbd.integrate`).

    Example:
      >>> rec = jax.jit(make_recorder(scene.build(num_people=4)))(jax.random.PRNGKey(0))
    """
    if 1 + distractors > scene.num_people:
        raise ValueError(f"{1 + distractors} people exceed the scene's capacity of "
                         f"{scene.num_people}")
    T = int(round(duration / dt))
    if T < 1:
        raise ValueError(f"duration must hold at least one frame of {dt} s; got {duration}")
    P = scene.num_people
    pcfg = _pedestrian_config(scene, distractors)
    angles = lidar.beam_angles(laser, dtype)
    walls, _, circles_of = episode.laser_geometry(scene, laser, dtype)

    def rec(key):
        k_init, k_col, k_run = jax.random.split(key, 3)
        people = pedestrians.init(k_init, pcfg, P, dtype)
        pose0 = pedestrians.robot_start(pcfg, people).astype(dtype)
        colours = jax.random.uniform(k_col, (P, 3), dtype)

        def frame(c, k):
            people, pose, odom = c
            ks = jax.random.split(k, 4)
            rel = estimators.to_frame(pose, people.pos[0])
            dist = jnp.sqrt(jnp.sum(rel**2))
            bearing = jnp.arctan2(rel[1], rel[0])
            v = jnp.clip(0.8 * (dist - follow_distance), 0.0, max_speed)
            w = jnp.clip(1.5 * bearing, -max_turn, max_turn)
            people = pedestrians.step(ks[0], pcfg, people, pose, dt)
            new_pose = _unicycle(pose, v, w, dt)
            delta = rgbd_mod.odometry(ks[1], odometry, pose, new_pose)
            new_odom = rgbd_mod.integrate(odom, delta)
            ranges = lidar.scan(ks[2], lidar.laser_pose(new_pose, laser), circles_of(people)[0],
                                walls, laser)
            det = rgbd_mod.detect(ks[3], rgbd, new_pose, people.pos, people.mask, colours)
            out = (ranges, new_odom, delta / dt, det.xy, det.mask, new_pose, people.pos,
                   people.mask)
            return (people, new_pose, new_odom), out

        _, out = jax.lax.scan(frame, (people, pose0, pose0), jax.random.split(k_run, T))
        times = dt * jnp.arange(1, T + 1, dtype=jnp.float64 if jax.config.jax_enable_x64
                                else jnp.float32)
        return Recording(times, out[0], angles, *out[1:])

    return rec


def record(key: Array, scene=None, **kw) -> Recording:
    """A recording as NumPy arrays (`make_recorder` compiled and run once).

    Args:
      key: PRNG key; scene: default ``scene.build(num_people=4)``; kw: `make_recorder`
        options (``distractors=3, duration=3.0``...).

    Example:
      >>> rec = record(jax.random.PRNGKey(0), duration=2.0)
    """
    if scene is None:
        from sims.following import scene as scene_mod

        scene = scene_mod.build(num_people=4)
    rec = jax.jit(make_recorder(scene, **kw))(key)
    return Recording(*(np.asarray(x) for x in rec))


def to_records(rec: Recording, laser: lidar.LaserConfig = lidar.LaserConfig()):
    """``(bags.LaserScans, bags.Odometry, bags.PersonDetections)`` of a recording, as
    `jaxtrack.io.bags` reads them back (ranges float32, beams at ``max_range`` masked, angles
    from the first angle and the mean increment: within 1e-6 rad of the simulation's).

    Example:
      >>> bags.write_bag("sim.bag", 1, **dict(zip(("laser", "odometry", "detections"),
      ...                                          to_records(rec))))
    """
    times = np.asarray(rec.times, np.float64)
    T = times.shape[0]
    ranges = np.asarray(rec.ranges, np.float32)
    rmax, rmin = np.float32(laser.max_range), np.float32(laser.min_range)
    mask = np.isfinite(ranges) & (ranges >= rmin) & (ranges < rmax)
    # The beam angles as a LaserScan carries them (angle_min + k * increment, float32), so
    # that the records equal what a bag gives back.
    a = np.asarray(rec.angles, np.float64)
    angles = bags.beam_angles(a[0], (a[-1] - a[0]) / (a.shape[0] - 1), a.shape[0])
    scans = bags.LaserScans(times, np.where(mask, ranges, rmax), angles, mask, float(rmin),
                            float(rmax), np.ones(T, bool))
    odom = bags.Odometry(times, np.asarray(rec.odom_pose, np.float64),
                         np.asarray(rec.odom_twist, np.float64), np.ones(T, bool))
    dmask = np.asarray(rec.det_mask, bool)
    det = bags.PersonDetections(times, np.where(dmask[..., None], rec.det_xy, 0.0)
                                .astype(np.float64), dmask, np.ones(T, bool))
    return scans, odom, det


def _pedestrian_config(scene, distractors):
    from sims.following import scene as scene_mod

    return scene_mod.pedestrian_config(scene, distractors=distractors)


def _unicycle(pose, v, w, dt):
    """Exact unicycle motion over ``dt`` at constant (v, w)."""
    th = pose[2]
    small = jnp.abs(w) < 1e-6
    w_safe = jnp.where(small, 1.0, w)
    dx = jnp.where(small, v * dt * jnp.cos(th),
                   v / w_safe * (jnp.sin(th + w * dt) - jnp.sin(th)))
    dy = jnp.where(small, v * dt * jnp.sin(th),
                   -v / w_safe * (jnp.cos(th + w * dt) - jnp.cos(th)))
    return jnp.stack([pose[0] + dx, pose[1] + dy, wrap(th + w * dt)])


# ---------------------------------------------------------------------------------------------
# Replay


def track(laser: bags.LaserScans, odometry: bags.Odometry | None = None,
          detections: bags.PersonDetections | None = None, estimator: str = "gnn", *,
          chunk: int = 64, key: Array | None = None, user_xy=None,
          config: estimators.EstimatorConfig | None = None, params=None,
          leg_params: legs.LegParams = legs.LegParams(), laser_mount=(0.0, 0.0),
          max_segments: int = 48, max_laser_people: int = 8, static_xy=None,
          static_radius: float = 0.3, dtype=jnp.float32, progress: bool = True,
          stream=None) -> Tracks:
    """Run leg detection + an estimator over recorded scans, in chunks of ``chunk`` frames.

    Per frame (as in `sims.following.episode`, without the controller): the odometry increment
    from the previous frame's pose; `legs.detect` on the scan with the previous frame's legs
    for the motion cue; laser people and detections (robot frame) into the odometry frame;
    `estimators.update`.

    Args:
      laser: `bags.LaserScans` (T scans; rows with ``valid`` False are skipped).
      odometry: `bags.Odometry` or None (identity pose: the tracks are in the laser's frame).
      detections: `bags.PersonDetections` in the robot frame, or None.
      estimator: "gnn", "jpda", "nnjpda", "pf" or "kf" (`estimators.ESTIMATORS`).
      chunk: frames per compiled ``lax.scan``.
      key: PRNG key (particle filter); default ``PRNGKey(0)``.
      user_xy: [2] the user in the odometry frame at the first frame; default the laser person
        nearest to the robot in front of it (else 1 m ahead).
      config, params: `estimators.EstimatorConfig` / `EstimatorParams` (defaults from
        ``estimator`` and the frame period).
      leg_params, laser_mount, max_segments, max_laser_people: the leg detector and the laser's
        (x, y) on the robot.
      static_xy: [F, 2] known leg-like fixed objects (table and chair legs) in the odometry
        frame, from a map: laser people within ``static_radius`` of one are dropped (the
        episode's ``map_filter``; furniture legs 0.3-0.5 m apart do look like a person's legs).
      progress: print a progress bar to ``stream`` (stderr).

    Returns:
      `Tracks` in the odometry frame.

    Example:
      >>> tracks = track(bags.read_laser("run.bag", "/scan"),
      ...                bags.read_odometry("run.bag", "/odom"), estimator="jpda")
    """
    estimators.EstimatorConfig(kind=estimator)  # checks the name
    if int(chunk) < 1:
        raise ValueError(f"chunk must be >= 1; got {chunk}")
    rows = np.flatnonzero(np.asarray(laser.valid, bool))
    if rows.size == 0:
        raise ValueError("no laser scan to replay")
    times = np.asarray(laser.times, np.float64)[rows]
    ranges = np.asarray(laser.ranges)[rows]
    angles = np.asarray(laser.angles)
    if ranges.ndim != 2 or ranges.shape[1] != angles.shape[0]:
        raise ValueError(f"laser ranges {ranges.shape} do not match {angles.shape[0]} angles")
    T = rows.size
    # Rounded to the microsecond: bags store nanosecond stamps, and the period is a static
    # argument of the compiled chunk (one compilation for the same recording in memory or read
    # back from a bag).
    dt = round(float(np.median(np.diff(times))), 6) if T > 1 else 0.1
    if not dt > 0:
        raise ValueError("laser times must increase")
    np_dtype = np.dtype(jnp.dtype(dtype).name)
    if odometry is not None:
        ov = np.asarray(odometry.valid, bool)
        oi = _align(np.asarray(odometry.times)[ov], times, np.inf)
        pose = np.asarray(odometry.pose)[ov][oi]
    else:
        pose = np.zeros((T, 3))
    if detections is not None:
        dv = np.asarray(detections.valid, bool)
        di = _align(np.asarray(detections.times)[dv], times, 0.5 * dt)
        dxy = np.asarray(detections.xy)[dv][np.maximum(di, 0)]
        dmask = np.asarray(detections.mask, bool)[dv][np.maximum(di, 0)] & (di >= 0)[:, None]
    else:
        dxy, dmask = np.zeros((T, 1, 2)), np.zeros((T, 1), bool)
    if config is None:
        config = estimators.EstimatorConfig(kind=estimator, sensors=(
            "both" if detections is not None else "laser"))
    if params is None:
        params = estimators.EstimatorParams.create(config, dt=dt, dtype=dtype)
    key = jax.random.PRNGKey(0) if key is None else key
    static = _Static(config, tuple(float(x) for x in leg_params), tuple(map(float, laser_mount)),
                     int(max_segments), int(max_laser_people), dt, int(chunk))
    ranges = np.where(np.isfinite(ranges), ranges, leg_params.max_range).astype(np_dtype)
    if user_xy is None:
        user_xy = _first_user(ranges[0], angles.astype(np_dtype), pose[0], static)
    static_xy = np.zeros((0, 2)) if static_xy is None else np.asarray(static_xy, np.float64)
    if static_xy.ndim != 2 or static_xy.shape[1] != 2:
        raise ValueError(f"static_xy must be [F, 2]; got shape {static_xy.shape}")
    statics = (jnp.asarray(static_xy, dtype), jnp.asarray(static_radius, dtype))
    run = _chunk_runner(static)
    carry = _init(key, params, jnp.asarray(user_xy, dtype), jnp.asarray(pose[0], dtype),
                  max_segments, dtype)
    C = int(chunk)
    outs = []
    t0 = time.perf_counter()
    for start in range(0, T, C):
        n = min(C, T - start)
        idx = np.arange(start, start + C)
        sl = np.minimum(idx, T - 1)
        xs = (jnp.asarray(ranges[sl]), jnp.asarray(pose[sl], dtype),
              jnp.asarray(dxy[sl], dtype), jnp.asarray(dmask[sl] & (idx < T)[:, None]),
              jnp.asarray(idx < T), jnp.asarray(idx, jnp.int32))
        carry, out = run(carry, xs, params, key, jnp.asarray(angles, dtype), statics)
        outs.append(jax.tree_util.tree_map(lambda x, n=n: np.asarray(x)[:n], out))
        if progress:
            _bar(start + n, T, time.perf_counter() - t0, stream)
    pos, ids, mask, user, found = (np.concatenate(x) for x in zip(*outs))
    return Tracks(np.arange(1, T + 1, dtype=np.int32), times, ids, pos, mask, user, found)


class _Static(NamedTuple):
    config: estimators.EstimatorConfig
    leg_params: tuple
    mount: tuple
    max_segments: int
    max_people: int
    dt: float
    chunk: int


def _align(src_times, dst_times, tol):
    """Index of the source sample nearest to each destination time (-1 if farther than tol)."""
    src = np.asarray(src_times, np.float64)
    if src.size == 0:
        raise ValueError("an aligned stream has no message")
    j = np.clip(np.searchsorted(src, dst_times), 1, max(src.size - 1, 1))
    cand = np.stack([np.clip(j - 1, 0, src.size - 1), np.clip(j, 0, src.size - 1)], -1)
    d = np.abs(src[cand] - dst_times[:, None])
    best = cand[np.arange(len(dst_times)), np.argmin(d, -1)]
    return np.where(np.min(d, -1) <= tol, best, -1)


def _laser_pose(pose, mount):
    cfg = lidar.LaserConfig(mount=mount)
    return lidar.laser_pose(pose, cfg)


def _first_user(ranges, angles, pose, static):
    """The laser person nearest to the robot with x > 0 (robot frame), else 1 m ahead."""
    det = _detect(jnp.asarray(ranges), jnp.asarray(angles), legs.LegParams(*static.leg_params),
                  max_segments=static.max_segments, max_people=static.max_people)
    xy = np.asarray(det.people.xy) + np.asarray(static.mount)
    ok = np.asarray(det.people.mask) & (xy[:, 0] > 0)
    rel = xy[np.argmin(np.where(ok, np.sum(xy**2, -1), np.inf))] if ok.any() else \
        np.array([1.0, 0.0])
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.asarray(pose[:2]) + np.array([c * rel[0] - s * rel[1], s * rel[0] + c * rel[1]])


_detect = jax.jit(legs.detect, static_argnames=("max_segments", "max_people"))


def _init(key, params, user_xy, pose0, S, dtype):
    est = estimators.init(jax.random.split(key)[1], params, user_xy, pose0)
    return (est, jnp.zeros((S, 2), dtype), jnp.zeros(S, bool), pose0)


@functools.lru_cache(maxsize=16)
def _chunk_runner(static: _Static):
    lp = legs.LegParams(*static.leg_params)
    dt = static.dt

    def run(carry, xs, params, key, angles, statics):
        static_xy, static_radius = statics

        def frame(c, x):
            est, prev_legs, prev_mask, prev_pose = c
            ranges, pose, dxy, dmask, valid, index = x
            d = estimators.to_frame(prev_pose, pose[:2])
            dth = wrap(pose[2] - prev_pose[2])
            lpose = _laser_pose(pose, static.mount)
            prev = estimators.to_frame(lpose, prev_legs)
            det = legs.detect(ranges, angles, lp, max_segments=static.max_segments,
                              max_people=static.max_people, prev_legs=(prev, prev_mask))
            laser_xy = estimators.from_frame(lpose, det.people.xy.astype(pose.dtype))
            d2 = jnp.sum((laser_xy[:, None] - static_xy[None]) ** 2, -1)
            laser_mask = det.people.mask & ~jnp.any(d2 < static_radius**2, 1)
            K = dxy.shape[0]
            detected = estimators.Detected(laser_xy, laser_mask,
                                           estimators.from_frame(pose, dxy), dmask,
                                           jnp.zeros((K, 3), pose.dtype))
            new_est, e = estimators.update(jax.random.fold_in(key, index), est, detected, pose,
                                           dth / dt, d[0] / dt, params)
            new = (new_est, estimators.from_frame(lpose, det.legs_xy.astype(pose.dtype)),
                   det.legs_mask, pose)
            new = jax.tree_util.tree_map(lambda a, b: jnp.where(valid, a, b), new, c)
            out = (e.people, e.people_ids, e.people_mask & valid, e.user[:2],
                   e.user_found & valid)
            return new, out

        return jax.lax.scan(frame, carry, xs)

    return jax.jit(run)


def _bar(done, total, seconds, stream=None):
    stream = sys.stderr if stream is None else stream
    filled = int(24 * done / total)
    end = "\n" if done >= total or not stream.isatty() else "\r"
    print(f"[{'#' * filled}{'.' * (24 - filled)}] {done}/{total} frames  {seconds:.1f} s",
          end=end, file=stream, flush=True)


# ---------------------------------------------------------------------------------------------
# Command line


def track_bag(bag, laser_topic: str, out, *, detections_topic: str | None = None,
              odom_topic: str | None = None, estimator: str = "gnn", chunk: int = 64,
              max_detections: int = 16, seed: int = 0, time_source: str = "header",
              static_points=None, stream=sys.stdout) -> dict:
    """``jaxtrack track``: read a bag, replay `track`, write ``tracks.csv`` (MOTChallenge
    layout, `jaxtrack.io.trajectories.write_mot_csv`) and ``top_view.png`` into ``out``.
    ``static_points``: a text file of ``x y`` rows (odometry frame), leg-like fixed objects
    (`track`'s ``static_xy``).

    Returns ``{"tracks": Tracks, "rows": CSV rows written, "csv": path, "plot": path,
    "reports": [bags.BagReport]}``.

    Example:
      >>> track_bag("run.bag", "/scan", "out", odom_topic="/odom", estimator="jpda")
    """
    from pathlib import Path

    from jaxtrack.io import trajectories

    laser = bags.read_laser(bag, laser_topic, time_source=time_source)
    odom = (bags.read_odometry(bag, odom_topic, time_source=time_source)
            if odom_topic else None)
    det = (bags.read_detections(bag, detections_topic, max_detections, time_source=time_source)
           if detections_topic else None)
    static_xy = (np.loadtxt(static_points, ndmin=2).reshape(-1, 2)
                 if static_points is not None else None)
    t0 = time.perf_counter()
    tracks = track(laser, odom, det, estimator, chunk=chunk, key=jax.random.PRNGKey(seed),
                   static_xy=static_xy)
    seconds = time.perf_counter() - t0
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    csv = out / "tracks.csv"
    rows = trajectories.write_mot_csv(csv, tracks.frames, tracks.ids, tracks.pos, tracks.mask)
    plot = out / "top_view.png"
    write_top_view(plot, tracks, odom, title=f"{Path(bag).name}: {estimator}")
    reports = [r.report for r in (laser, odom, det) if r is not None]
    n_ids = len(np.unique(tracks.ids[tracks.mask])) if tracks.mask.any() else 0
    print(f"{len(tracks.frames)} frames ({tracks.times[-1] - tracks.times[0]:.1f} s) replayed "
          f"with {estimator} in {seconds:.1f} s (compilation included): {n_ids} track ids, "
          f"{rows} rows -> {csv}, {plot}", file=stream)
    for r in reports:
        if not r.complete:
            print(f"warning: {r.topic}: {r.messages} messages read, "
                  f"{'unknown' if r.unreadable < 0 else r.unreadable} unreadable: {r.detail}",
                  file=stream)
    return {"tracks": tracks, "rows": rows, "csv": csv, "plot": plot, "reports": reports}


def write_top_view(path, tracks: Tracks, odometry: bags.Odometry | None = None, title=""):
    """Top view of the tracks (one colour per id), the user estimate and the odometry path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 6))
    cmap = plt.get_cmap("tab20")
    ids = np.unique(tracks.ids[tracks.mask]) if tracks.mask.any() else []
    for k, i in enumerate(ids):
        sel = tracks.mask & (tracks.ids == i)
        xy = tracks.pos[sel]
        ax.plot(xy[:, 0], xy[:, 1], ".-", ms=2, lw=0.8, color=cmap(k % 20))
        ax.annotate(str(int(i)), xy[-1], fontsize=6, color=cmap(k % 20))
    ax.plot(tracks.user[:, 0], tracks.user[:, 1], "k:", lw=1.5, label="user estimate")
    if odometry is not None:
        p = np.asarray(odometry.pose)[np.asarray(odometry.valid, bool)]
        ax.plot(p[:, 0], p[:, 1], "C0", lw=2, label="robot (odometry)")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m] (odometry frame)")
    ax.set_ylabel("y [m]")
    ax.set_title(title or f"{len(ids)} tracks")
    ax.legend(loc="best", fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)
