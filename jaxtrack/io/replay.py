"""User estimators replayed on recorded laser scans (a ROS bag or arrays in memory).

`track` runs, per laser scan, the sensing step of the closed loop
(`jaxtrack.perception.sensing.sense`: leg detection with the previous frame's legs, laser and
RGB-D people into the odometry frame, the static-map filter) and one user estimator of
`jaxtrack.tracking.user`: the same step functions the simulated episode runs, with no controller
and no MuJoCo. The frames are the laser scans; odometry (the nearest message in time) and
detections (the nearest message within half a frame) are aligned to them. Everything runs in the
odometry frame (the identity pose without odometry), in fixed-size chunks: one ``lax.scan`` per
chunk, compiled once, the last chunk padded with masked frames, the estimator state carried
from chunk to chunk.

`track_bag` is ``jaxtrack track``: a bag in, ``tracks.csv`` (MOTChallenge layout) and a top
view out.

Example:
  >>> laser = bags.read_laser("run.bag", "/scan")
  >>> tracks = track(laser, bags.read_odometry("run.bag", "/odom"), estimator="jpda")
"""

from __future__ import annotations

import dataclasses
import functools
import sys
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import geometry, montecarlo
from jaxtrack.io import bags
from jaxtrack.perception import leg_classifier, legs, sensing
from jaxtrack.tracking import user

Array = jax.Array

__all__ = ["Tracks", "track", "track_batch", "track_bag", "write_top_view", "top_view",
           "write_animation"]


class Tracks(NamedTuple):
    """Estimator output in the odometry frame, one row per laser frame.

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


class _Static(NamedTuple):
    estimator: object
    sensing: sensing.SensingConfig
    dt: float
    pan: bool = False


def track(laser, odometry: bags.Odometry | None = None,
          detections: bags.PersonDetections | None = None, estimator="gnn", *,
          chunk: int = 64, key: Array | None = None, user_xy=None, params=None,
          leg_params: legs.LegParams | None = None, laser_mount=(0.0, 0.0),
          detector: str = "learned", max_segments: int = 64, max_laser_people: int = 8,
          static_xy=None,
          static_radius: float = 0.3, pan: bags.JointStates | None = None,
          pan_joint: str = "camera_pan", dtype=jnp.float32, progress: bool = True,
          stream=None) -> Tracks:
    """Run the sensing step and a user estimator over recorded scans, ``chunk`` frames at a time.

    Args:
      laser: `bags.LaserScans` (T scans; rows with ``valid`` False are skipped), or a list of
        them, one per laser of the robot, fused in each frame (`sensing.sense` with several
        mounts): the first laser's scans are the frames, each other laser contributes its
        scan nearest in time within half its own period (none otherwise), and ``laser_mount``
        then lists each laser's ``(x, y, yaw)`` on the robot.
      odometry: `bags.Odometry` or None (identity pose: the tracks are in the laser's frame).
      detections: `bags.PersonDetections` in the robot frame, or None.
      estimator: a name of `jaxtrack.tracking.user.CONFIGS` ("gnn", "jpda", "nn_jpda", "pf",
        "kf"; with no detections, its laser-only version) or a user-estimator configuration.
      chunk: frames per compiled ``lax.scan``.
      key: PRNG key (particle filter); default ``PRNGKey(0)``.
      user_xy: [2] the user in the odometry frame at the first frame; default the laser person
        nearest to the robot in front of it (else 1 m ahead).
      params: the estimator's parameters (default its ``params`` at the scans' period).
      leg_params, laser_mount, max_segments, max_laser_people: the leg detector and the laser's
        (x, y) or (x, y, yaw) on the robot (`sensing.SensingConfig`). By default ``leg_params``
        takes its range limits from the scans (``range_min`` / ``range_max`` of the
        messages; with several lasers, the widest, each laser's own beyond its limits being
        masked).
      detector: ``"learned"`` (the shipped leg classifier, trained on real scans),
        ``"geometric"`` or a model file of ``jaxtrack train-legs`` (`sensing.SensingConfig`).
        With a learned detector, a leg-tracked estimator named by string (``"pf+legs"``,
        ``"jpda+legs"``) starts leg tracks only on legs at the classifier's decision
        threshold (`leg_tracker.LegTrackerConfig.birth_confidence`).
      static_xy: [F, 2] known leg-like fixed objects (table and chair legs) in the odometry
        frame, from a map: laser people within ``static_radius`` of one are dropped (furniture
        legs 0.3-0.5 m apart do look like a person's legs).
      pan: `bags.JointStates` holding the RGB-D camera's pan angle (joint ``pan_joint``,
        relative to the robot's heading), or None (the camera looks ahead): the nearest
        message to each scan turns the camera's field of view (`sensing.Sensed.camera_pan`).
      progress: print a progress bar to ``stream`` (stderr).

    Returns:
      `Tracks` in the odometry frame.

    Example:
      >>> tracks = track(bags.read_laser("run.bag", "/scan"),
      ...                bags.read_odometry("run.bag", "/odom"), estimator="jpda")
    """
    config = _config(estimator, detections is not None, detector)
    est = user.build(config)
    if int(chunk) < 1:
        raise ValueError(f"chunk must be >= 1; got {chunk}")
    lasers = None
    if not isinstance(laser, bags.LaserScans):
        lasers = list(laser)
        if not lasers or not all(isinstance(x, bags.LaserScans) for x in lasers):
            raise TypeError("laser must be a bags.LaserScans or a non-empty list of them")
        mounts = ([(0.0, 0.0, 0.0)] * len(lasers) if tuple(laser_mount) == (0.0, 0.0)
                  else [tuple(map(float, m)) for m in laser_mount])
        if len(mounts) != len(lasers):
            raise ValueError(f"{len(mounts)} laser mounts for {len(lasers)} lasers")
        laser_mount = tuple(mounts)
        laser, ranges_all, angles_all, limits = _fuse_scans(lasers)
    inp = _inputs(laser, odometry, detections, pan, pan_joint)
    T, dt = len(inp.times), inp.dt
    np_dtype = np.dtype(jnp.dtype(dtype).name)
    if params is None:
        params = est.params(dt=dt, dtype=dtype)
    key = jax.random.PRNGKey(0) if key is None else key
    scfg, leg_params = _sensing_config(limits if lasers else laser, leg_params, max_segments,
                                       max_laser_people, laser_mount, static_radius, detector)
    static_map = _static_map(static_xy, dtype)
    static = _Static(config, scfg, dt, pan is not None)
    if lasers:
        rows = np.flatnonzero(np.asarray(laser.valid, bool))
        ranges = np.where(np.isfinite(ranges_all[rows]), ranges_all[rows],
                          leg_params.max_range).astype(np_dtype)
        inp = inp._replace(angles=angles_all)
        first = (ranges[0, 0], angles_all[0].astype(np_dtype))
    else:
        ranges = np.where(np.isfinite(inp.ranges), inp.ranges,
                          leg_params.max_range).astype(np_dtype)
        first = (ranges[0], inp.angles.astype(np_dtype))
    if user_xy is None:
        user_xy = _first_user(*first, inp.pose[0], scfg)
    run = _chunk_runner(static, int(chunk))
    pose0 = jnp.asarray(inp.pose[0], dtype)
    prior = user.Prior(jnp.asarray(user_xy, dtype), pose0)
    carry = (est.init(jax.random.split(key)[1], params, prior), sensing.init(scfg, dtype), pose0)
    C = int(chunk)
    outs = []
    bar = montecarlo.progress_bar(T, unit="frames", file=stream, disable=not progress)
    for start in range(0, T, C):
        n = min(C, T - start)
        xs = _chunk_xs(inp, ranges, start, C, T, dtype)
        carry, out = run(carry, xs, params, key, jnp.asarray(inp.angles, dtype), static_map)
        outs.append(jax.tree_util.tree_map(lambda x, n=n: np.asarray(x)[:n], out))
        bar.update(n)
    bar.close()
    pos, ids, mask, user_xy, found = (np.concatenate(x) for x in zip(*outs))
    return Tracks(np.arange(1, T + 1, dtype=np.int32), inp.times, ids, pos, mask, user_xy,
                  found)


def track_batch(lasers, odometries=None, estimator="gnn", *, chunk: int = 64,
                keys: Array | None = None, leg_params: legs.LegParams | None = None,
                laser_mount=(0.0, 0.0), detector: str = "learned", max_segments: int = 64,
                max_laser_people: int = 8, static_radius: float = 0.3, dtype=jnp.float32,
                progress: bool = True, stream=None) -> list[Tracks]:
    """`track` on several recordings at once: one compiled chunk, vmapped over the
    recordings, each carrying its own estimator state (laser, and optionally odometry).

    The recordings must share the beam count (read them with ``bags.read_laser(...,
    max_beams=B)`` to pad) and the scan period; shorter ones are padded with masked frames.
    Recording ``b`` uses ``keys[b]`` (default ``fold_in(PRNGKey(0), b)``) and its own range
    limits unless ``leg_params`` is given. Other arguments as in `track`.

    Returns:
      one `Tracks` per recording, in order.

    Example:
      >>> out = track_batch([bags.read_laser(p, "/scan", max_beams=512) for p in paths])
    """
    lasers = list(lasers)
    if not lasers:
        return []
    if not all(isinstance(x, bags.LaserScans) for x in lasers):
        raise TypeError("track_batch replays one bags.LaserScans per recording (fuse several "
                        "lasers of one robot with track)")
    odometries = [None] * len(lasers) if odometries is None else list(odometries)
    if len(odometries) != len(lasers):
        raise ValueError(f"{len(odometries)} odometries for {len(lasers)} recordings")
    if int(chunk) < 1:
        raise ValueError(f"chunk must be >= 1; got {chunk}")
    config = _config(estimator, False, detector)
    est = user.build(config)
    inps = [_inputs(lz, od, None, None, "") for lz, od in zip(lasers, odometries)]
    beams = {i.angles.shape[0] for i in inps}
    if len(beams) > 1:
        raise ValueError(f"the recordings have different beam counts {sorted(beams)}; read "
                         "them with bags.read_laser(..., max_beams=B)")
    dts = sorted({i.dt for i in inps})
    if dts[-1] - dts[0] > 1e-3 * dts[0]:
        raise ValueError(f"the recordings have different scan periods {dts}")
    dt = inps[0].dt
    np_dtype = np.dtype(jnp.dtype(dtype).name)
    N = len(inps)
    keys = (jax.vmap(lambda b: jax.random.fold_in(jax.random.PRNGKey(0), b))(jnp.arange(N))
            if keys is None else jnp.asarray(keys))
    params = est.params(dt=dt, dtype=dtype)
    # One static sensing configuration: the range limits are per recording, so they enter as
    # data (the leg parameters are float leaves) through a vmapped LegParams.
    scfg, _ = _sensing_config(lasers[0], leg_params, max_segments, max_laser_people,
                              laser_mount, static_radius, detector)
    per = [leg_params or legs.LegParams(max_range=float(lz.range_max),
                                        min_range=max(float(lz.range_min), 0.0))
           for lz in lasers]
    leg_batch = legs.LegParams(*(jnp.asarray([float(p[k]) for p in per], dtype)
                                 for k in range(len(legs.LegParams._fields))))
    static = _Static(config, scfg, dt, False)
    ranges = [np.where(np.isfinite(i.ranges), i.ranges, p.max_range).astype(np_dtype)
              for i, p in zip(inps, per)]
    carries = []
    for b, (i, r, p) in enumerate(zip(inps, ranges, per)):
        user_xy = _first_user(r[0], i.angles.astype(np_dtype), i.pose[0],
                              dataclasses.replace(scfg, leg_params=p))
        pose0 = jnp.asarray(i.pose[0], dtype)
        prior = user.Prior(jnp.asarray(user_xy, dtype), pose0)
        carries.append((est.init(jax.random.split(keys[b])[1], params, prior),
                        sensing.init(scfg, dtype), pose0))
    carry = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *carries)
    angles = jnp.asarray(np.stack([i.angles for i in inps]), dtype)
    T = max(len(i.times) for i in inps)
    run = _batch_runner(static, int(chunk))
    static_map = _static_map(None, dtype)
    C = int(chunk)
    outs = []
    bar = montecarlo.progress_bar(T * N, unit="frames", file=stream, disable=not progress)
    for start in range(0, T, C):
        xs = [_chunk_xs(i, r, start, C, len(i.times), dtype) for i, r in zip(inps, ranges)]
        xs = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *xs)
        carry, out = run(carry, xs, params, keys, angles, static_map, leg_batch)
        outs.append(jax.tree_util.tree_map(np.asarray, out))
        bar.update(min(C, T - start) * N)
    bar.close()
    pos, ids, mask, user_xy, found = (np.concatenate(x, axis=1) for x in zip(*outs))
    result = []
    for b, i in enumerate(inps):
        n = len(i.times)
        result.append(Tracks(np.arange(1, n + 1, dtype=np.int32), i.times, ids[b, :n],
                             pos[b, :n], mask[b, :n], user_xy[b, :n], found[b, :n]))
    return result


class _Inputs(NamedTuple):
    times: np.ndarray
    ranges: np.ndarray
    angles: np.ndarray
    pose: np.ndarray
    dxy: np.ndarray
    dmask: np.ndarray
    pan: np.ndarray
    dt: float


def _config(estimator, with_detections: bool, detector: str):
    if not isinstance(estimator, str):
        return estimator
    config = user.CONFIGS.get(estimator)
    user.build(estimator)  # a clear error for an unknown name
    if not with_detections:
        config = user.with_sensors(config, "laser")
    if isinstance(config, user.LegTrackedConfig) and detector != "geometric":
        # Leg tracks start on the classifier's confident legs (its decision threshold) and
        # are kept by the candidates above the sensing threshold.
        decision = float(leg_classifier.resolve(detector).decision)
        config = dataclasses.replace(config, legs=dataclasses.replace(
            config.legs, birth_confidence=decision))
    return config


def _inputs(laser, odometry, detections, pan, pan_joint) -> _Inputs:
    """One recording's per-frame arrays, aligned to its valid laser scans."""
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
    if pan is not None:
        if pan_joint not in tuple(pan.names):
            raise ValueError(f"no joint {pan_joint!r} in the joint states {tuple(pan.names)}")
        pv = np.asarray(pan.valid, bool)
        pi = _align(np.asarray(pan.times)[pv], times, np.inf)
        pan_angle = np.asarray(pan.position)[pv][pi, list(pan.names).index(pan_joint)]
        if not np.all(np.isfinite(pan_angle)):
            raise ValueError(f"joint {pan_joint!r} has no position in some joint states")
    else:
        pan_angle = np.zeros(T)
    return _Inputs(times, ranges, angles, pose, dxy, dmask, pan_angle, dt)


def _sensing_config(laser, leg_params, max_segments, max_laser_people, laser_mount,
                    static_radius, detector):
    if leg_params is None:
        leg_params = legs.LegParams(max_range=float(laser.range_max),
                                    min_range=max(float(laser.range_min), 0.0))
    scfg = sensing.SensingConfig(legs.LegParams(*(float(x) for x in leg_params)),
                                 int(max_segments), int(max_laser_people),
                                 _mount_tuple(laser_mount), float(static_radius),
                                 detector=str(detector))
    return scfg, leg_params


def _mount_tuple(mount):
    if len(mount) and isinstance(mount[0], (tuple, list, np.ndarray)):
        return tuple(tuple(map(float, m)) for m in mount)
    return tuple(map(float, mount))


class _Limits(NamedTuple):
    range_min: float
    range_max: float


def _fuse_scans(lasers):
    """Several lasers on the first one's clock: ``(first laser, ranges [T, N, B] with NaN
    where a laser has no valid return or no scan within half its period, angles [N, B],
    widest range limits)``. Beam counts may differ: shorter scans are padded with NaN."""
    B = max(lz.angles.shape[0] for lz in lasers)
    base = lasers[0]
    times = np.asarray(base.times, np.float64)
    T = times.shape[0]
    ranges = np.full((T, len(lasers), B), np.nan, np.float32)
    angles = np.zeros((len(lasers), B), np.float32)
    for i, lz in enumerate(lasers):
        n = lz.angles.shape[0]
        a = np.asarray(lz.angles, np.float32)
        angles[i, :n], angles[i, n:] = a, a[-1]
        r = np.where(np.asarray(lz.mask, bool), np.asarray(lz.ranges, np.float32), np.nan)
        if i == 0:
            ranges[:, 0, :n] = r
            continue
        ok = np.asarray(lz.valid, bool)
        if not ok.any():
            continue
        lt = np.asarray(lz.times, np.float64)[ok]
        period = float(np.median(np.diff(lt))) if lt.size > 1 else np.inf
        j = _align(lt, times, 0.5 * period)
        ranges[:, i, :n] = np.where((j >= 0)[:, None], r[ok][np.maximum(j, 0)], np.nan)
    limits = _Limits(min(max(float(lz.range_min), 0.0) for lz in lasers),
                     max(float(lz.range_max) for lz in lasers))
    return base, ranges, angles, limits


def _static_map(static_xy, dtype):
    static_xy = np.zeros((0, 2)) if static_xy is None else np.asarray(static_xy, np.float64)
    if static_xy.ndim != 2 or static_xy.shape[1] != 2:
        raise ValueError(f"static_xy must be [F, 2]; got shape {static_xy.shape}")
    return sensing.StaticMap(jnp.asarray(static_xy, dtype), jnp.zeros((0, 2, 2), dtype))


def _chunk_xs(inp: _Inputs, ranges, start, C, T, dtype):
    """The scanned inputs of frames ``start .. start + C`` (past T: repeated, masked)."""
    idx = np.arange(start, start + C)
    sl = np.minimum(idx, T - 1)
    return (jnp.asarray(ranges[sl]), jnp.asarray(inp.pose[sl], dtype),
            jnp.asarray(inp.dxy[sl], dtype), jnp.asarray(inp.dmask[sl] & (idx < T)[:, None]),
            jnp.asarray(inp.pan[sl], dtype), jnp.asarray(idx < T), jnp.asarray(idx, jnp.int32))


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


_detect = jax.jit(legs.detect,
                  static_argnames=("max_segments", "max_people", "max_candidates"))


def _first_user(ranges, angles, pose, cfg: sensing.SensingConfig):
    """The laser person nearest to the robot with x > 0 (robot frame), else 1 m ahead (the
    first laser's people, with several)."""
    det = _detect(jnp.asarray(ranges), jnp.asarray(angles), cfg.leg_params,
                  max_segments=cfg.max_segments, max_people=cfg.max_people,
                  classifier=leg_classifier.resolve(cfg.detector),
                  threshold=cfg.leg_threshold, max_candidates=cfg.max_leg_candidates)
    mount = np.asarray(cfg.mounts[0], np.float64)
    c, s = np.cos(mount[2]), np.sin(mount[2])
    p = np.asarray(det.people.xy, np.float64)
    xy = mount[:2] + p @ np.array([[c, s], [-s, c]])
    ok = np.asarray(det.people.mask) & (xy[:, 0] > 0)
    rel = (xy[np.argmin(np.where(ok, np.sum(xy**2, -1), np.inf))] if ok.any()
           else np.array([1.0, 0.0]))
    with jax.enable_x64(True):  # host-side, at the recording's float64 precision
        return np.asarray(geometry.from_frame(jnp.asarray(pose, jnp.float64),
                                              jnp.asarray(rel, jnp.float64)))


def _chunk_fn(static: _Static):
    est = user.build(static.estimator)
    dt = static.dt

    def run(carry, xs, params, key, angles, static_map, leg_params=None):
        config = (static.sensing if leg_params is None
                  else dataclasses.replace(static.sensing, leg_params=leg_params))

        def frame(c, x):
            est_state, sensing_state, prev_pose = c
            ranges, pose, dxy, dmask, pan, valid, index = x
            odometry = sensing.Odometry(pose, geometry.relative(prev_pose, pose))
            new_sensing, sensed = sensing.sense(
                config, sensing_state, ranges, angles, odometry, dxy, dmask, None,
                static_map, map_pose=pose, period=dt)
            if static.pan:
                sensed = sensed._replace(camera_pan=pan)
            new_est, e = est.update(jax.random.fold_in(key, index), est_state, sensed, params)
            new = jax.tree_util.tree_map(lambda a, b: jnp.where(valid, a, b),
                                         (new_est, new_sensing, pose), c)
            out = (e.people, e.people_ids, e.people_mask & valid, e.user[:2],
                   e.user_found & valid)
            return new, out

        return jax.lax.scan(frame, carry, xs)

    return run


@functools.lru_cache(maxsize=16)
def _chunk_runner(static: _Static, chunk: int):
    return jax.jit(_chunk_fn(static))


@functools.lru_cache(maxsize=16)
def _batch_runner(static: _Static, chunk: int):
    return jax.jit(jax.vmap(_chunk_fn(static), in_axes=(0, 0, None, 0, 0, None, 0)))


def track_bag(bag, laser_topic, out, *, detections_topic: str | None = None,
              odom_topic: str | None = None, estimator: str = "gnn", chunk: int = 64,
              max_detections: int = 16, seed: int = 0, time_source: str = "header",
              static_points=None, pan_topic: str | None = None,
              pan_joint: str = "camera_pan", detector: str = "learned",
              animate: bool = False, tf_frames: tuple[str, str] | None = None,
              gt_topic: str | None = None, gt_threshold: float = 0.5,
              target_only: bool = False, max_gt_people: int = 32,
              laser_mounts=None, stream=None) -> dict:
    """``jaxtrack track``: read a bag, replay `track`, write ``tracks.csv`` (MOTChallenge
    layout, `jaxtrack.io.trajectories.write_mot_csv`) and ``top_view.png`` into ``out``.
    ``static_points``: a text file of ``x y`` rows (odometry frame), leg-like fixed objects
    (`track`'s ``static_xy``). ``pan_topic``: ``sensor_msgs/JointState`` of the camera's
    pan unit (joint ``pan_joint``). ``detector``: `track`'s. ``animate``: also write
    ``replay.gif`` (`write_animation`, every second frame). ``tf_frames``: ``(parent,
    child)``, the odometry from the bag's transform tree instead (`bags.read_tf`, e.g.
    ``("odom", "base_link")``). ``gt_topic``: people ground truth in the bag (ids and
    positions in the tracks' frame: `bags.read_people`), written as ``gt.csv`` aligned to the
    scans (nearest message within half a frame) and scored against the tracks with
    `trajectories.evaluate_files` (``gt_threshold`` m, ``target_only``); the summary is printed
    and returned under ``"summary"``. ``laser_topic``: one topic, or several (one per laser of
    the robot, fused: `track`), with ``laser_mounts`` their ``(x, y, yaw)`` on the robot
    (default all at the origin, facing ahead); the animation draws the first laser's scans.

    Returns ``{"tracks": Tracks, "rows": CSV rows written, "csv": path, "plot": path,
    "reports": [bags.BagReport]}``.

    Example:
      >>> track_bag("run.bag", "/scan", "out", odom_topic="/odom", estimator="jpda")
    """
    from pathlib import Path

    from jaxtrack.io import trajectories

    stream = sys.stdout if stream is None else stream

    topics = [laser_topic] if isinstance(laser_topic, str) else list(laser_topic)
    if not topics:
        raise ValueError("no laser topic")
    scans = [bags.read_laser(bag, t, time_source=time_source) for t in topics]
    laser = scans[0]
    mounts = laser_mounts
    if len(scans) > 1:
        mounts = [(0.0, 0.0, 0.0)] * len(scans) if laser_mounts is None else list(laser_mounts)
        if len(mounts) != len(scans):
            raise ValueError(f"{len(mounts)} laser mounts for {len(scans)} laser topics")
    elif laser_mounts is not None:
        mounts = list(laser_mounts)
        if len(mounts) != 1:
            raise ValueError(f"{len(mounts)} laser mounts for 1 laser topic")
        mounts = tuple(mounts[0])
    if odom_topic and tf_frames:
        raise ValueError("give odom_topic or tf_frames, not both")
    odom = (bags.read_odometry(bag, odom_topic, time_source=time_source) if odom_topic
            else bags.read_tf(bag, *tf_frames, time_source=time_source) if tf_frames else None)
    det = (bags.read_detections(bag, detections_topic, max_detections, time_source=time_source)
           if detections_topic else None)
    pan = (bags.read_joint_states(bag, pan_topic, [pan_joint], time_source=time_source)
           if pan_topic else None)
    static_xy = (np.loadtxt(static_points, ndmin=2).reshape(-1, 2)
                 if static_points is not None else None)
    t0 = time.perf_counter()
    tracks = track(scans if len(scans) > 1 else laser, odom, det, estimator, chunk=chunk,
                   key=jax.random.PRNGKey(seed), static_xy=static_xy, pan=pan,
                   pan_joint=pan_joint, detector=detector,
                   laser_mount=(0.0, 0.0) if mounts is None else mounts)
    seconds = time.perf_counter() - t0
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    csv = out / "tracks.csv"
    rows = trajectories.write_mot_csv(csv, tracks.frames, tracks.ids, tracks.pos, tracks.mask)
    plot = out / "top_view.png"
    write_top_view(plot, tracks, odom, title=f"{Path(bag).name}: {estimator}")
    if animate:
        write_animation(out / "replay.gif", tracks, laser, odom, every=2, fps=5,
                        title=f"{Path(bag).name}: {estimator}")
    gt = None
    summary = None
    if gt_topic:
        gt = bags.read_people(bag, gt_topic, max_gt_people, time_source=time_source)
        gi = _align(gt.times, tracks.times, 0.5 * float(np.median(np.diff(tracks.times)))
                    if len(tracks.times) > 1 else np.inf)
        ids = np.where((gi >= 0)[:, None], gt.ids[np.maximum(gi, 0)], -1)
        trajectories.write_mot_csv(out / "gt.csv", tracks.frames, ids,
                                   gt.xy[np.maximum(gi, 0)], ids >= 0)
        summary = trajectories.evaluate_files(out / "gt.csv", csv, gt_threshold, "mot",
                                              target_only=target_only)
        print(trajectories.format_summary({Path(bag).name: summary}), file=stream)
    reports = [r.report for r in (*scans, odom, det, pan, gt) if r is not None]
    n_ids = len(np.unique(tracks.ids[tracks.mask])) if tracks.mask.any() else 0
    print(f"{len(tracks.frames)} frames ({tracks.times[-1] - tracks.times[0]:.1f} s) replayed "
          f"with {estimator} in {seconds:.1f} s (compilation included): {n_ids} track ids, "
          f"{rows} rows -> {csv}, {plot}", file=stream)
    for r in reports:
        if not r.complete:
            print(f"warning: {r.topic}: {r.messages} messages read, "
                  f"{'unknown' if r.unreadable < 0 else r.unreadable} unreadable: {r.detail}",
                  file=stream)
    return {"tracks": tracks, "rows": rows, "csv": csv, "plot": plot, "reports": reports,
            "summary": summary}


def write_top_view(path, tracks: Tracks, odometry: bags.Odometry | None = None, title=""):
    """Top view of the tracks (one colour per id), the user estimate and the odometry path."""
    def user(ax):
        ax.plot(tracks.user[:, 0], tracks.user[:, 1], "k:", lw=1.5, label="user estimate")

    top_view(path, tracks.ids, tracks.pos, tracks.mask, odometry, title, after=user)


def top_view(path, ids, pos, mask, odometry: bags.Odometry | None = None, title="", *,
             before=None, after=None) -> None:
    """A top-view PNG of tracks ``ids`` [T, K], ``pos`` [T, K, 2], ``mask`` [T, K] (one colour
    per id, labelled at its last position) and the odometry path; ``before`` / ``after``
    (callables of the axes) draw under / over the tracks."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 6))
    if before is not None:
        before(ax)
    cmap = plt.get_cmap("tab20")
    track_ids = np.unique(ids[mask]) if mask.any() else []
    for k, i in enumerate(track_ids):
        xy = pos[mask & (ids == i)]
        ax.plot(xy[:, 0], xy[:, 1], ".-", ms=2, lw=0.8, color=cmap(k % 20))
        ax.annotate(str(int(i)), xy[-1], fontsize=6, color=cmap(k % 20))
    if after is not None:
        after(ax)
    if odometry is not None:
        p = np.asarray(odometry.pose)[np.asarray(odometry.valid, bool)]
        ax.plot(p[:, 0], p[:, 1], "C0", lw=2, label="robot (odometry)")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m] (odometry frame)")
    ax.set_ylabel("y [m]")
    ax.set_title(title or f"{len(track_ids)} tracks")
    ax.legend(loc="best", fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_animation(path, tracks: Tracks, laser: bags.LaserScans,
                    odometry: bags.Odometry | None = None, *, every: int = 1, fps: int = 10,
                    trail: int = 20, frames: int | None = None, title: str = "") -> None:
    """An animated top view of a replay (GIF, `matplotlib.animation.PillowWriter`): each scan's
    returns, the tracks with their ids and a trail of their last ``trail`` positions, and the
    user estimate, in the odometry frame (the laser's frame without odometry; the laser is
    taken at the robot's origin).

    Args:
      path: output ``.gif``.
      tracks: `track`'s output; laser: the `bags.LaserScans` it replayed (valid rows).
      odometry: the odometry it used, or None.
      every: draw every ``every``-th frame; fps: frames per second of the GIF.
      frames: only the first ``frames`` frames (default all).

    Example:
      >>> write_animation("replay.gif", tracks, laser, every=2, frames=300)
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import animation

    if int(every) < 1 or int(trail) < 0:
        raise ValueError(f"every must be >= 1 and trail >= 0; got {every}, {trail}")
    rows = np.flatnonzero(np.asarray(laser.valid, bool))
    T = len(tracks.frames) if frames is None else min(int(frames), len(tracks.frames))
    if T < 1 or len(rows) < T:
        raise ValueError(f"laser has {len(rows)} valid scans for {len(tracks.frames)} frames")
    ranges = np.asarray(laser.ranges)[rows[:T]]
    mask = np.asarray(laser.mask, bool)[rows[:T]]
    angles = np.asarray(laser.angles)
    if odometry is not None:
        ov = np.asarray(odometry.valid, bool)
        oi = _align(np.asarray(odometry.times)[ov], np.asarray(tracks.times[:T]), np.inf)
        pose = np.asarray(odometry.pose)[ov][oi]
    else:
        pose = np.zeros((T, 3))
    c, s = np.cos(pose[:, 2:3] + angles), np.sin(pose[:, 2:3] + angles)
    pts = np.stack([pose[:, :1] + ranges * c, pose[:, 1:2] + ranges * s], -1)
    ids_seen = np.unique(tracks.ids[:T][tracks.mask[:T]]) if tracks.mask[:T].any() else []
    colour = {int(i): plt.get_cmap("tab20")(k % 20) for k, i in enumerate(ids_seen)}
    lim = pts[mask]
    fig, ax = plt.subplots(figsize=(6.5, 6))
    if len(lim):
        lo, hi = np.percentile(lim, 1, 0) - 0.5, np.percentile(lim, 99, 0) + 0.5
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    scan = ax.scatter([], [], s=2, c="0.4")
    heads = ax.scatter([], [], s=80, facecolors="none", lw=1.5)
    user, = ax.plot([], [], "k+", ms=14, mew=2, label="user estimate")
    trails = []
    labels = []
    clock = ax.text(0.02, 0.97, "", transform=ax.transAxes, fontsize=8, va="top")
    ax.legend(loc="upper right", fontsize=7)

    def draw(k):
        for artist in trails + labels:
            artist.remove()
        trails.clear()
        labels.clear()
        scan.set_offsets(pts[k][mask[k]] if mask[k].any() else np.zeros((0, 2)))
        on = tracks.mask[k]
        xy = tracks.pos[k][on]
        heads.set_offsets(xy if len(xy) else np.zeros((0, 2)))
        heads.set_edgecolors([colour[int(i)] for i in tracks.ids[k][on]])
        for i, p in zip(tracks.ids[k][on], xy):
            lo = max(k - int(trail), 0)
            sel = tracks.mask[lo:k + 1] & (tracks.ids[lo:k + 1] == i)
            path = tracks.pos[lo:k + 1][sel]
            trails.append(ax.plot(path[:, 0], path[:, 1], "-", lw=1, color=colour[int(i)])[0])
            labels.append(ax.annotate(str(int(i)), p, fontsize=7, color=colour[int(i)],
                                      xytext=(4, 4), textcoords="offset points"))
        if tracks.user_found[k]:
            user.set_data([tracks.user[k, 0]], [tracks.user[k, 1]])
        else:
            user.set_data([], [])
        clock.set_text(f"t = {tracks.times[k] - tracks.times[0]:5.1f} s   "
                       f"{int(on.sum())} tracks")
        return scan, heads, user, clock

    anim = animation.FuncAnimation(fig, draw, frames=range(0, T, int(every)), blit=False)
    anim.save(path, writer=animation.PillowWriter(fps=int(fps)))
    plt.close(fig)
