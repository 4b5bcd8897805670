"""People detected and tracked in recorded RGB-D: point clouds, or depth and colour image pairs.

`track_rgbd` runs, per frame, the perception and tracking steps of the simulated robot of
`sims.following.crowd` (seed 001), without the renderer:

1. the cloud from the camera's optical frame (x right, y down, z forward) into the robot's base
   frame (x forward, y left, z up) through the camera's `Mount`;
2. the people detector, `jaxtrack.perception.rgbd_people.detect`, with its HOG confidence when
   the cloud is organised (its colours are the image) and the camera's focal lengths are given;
3. the detections into the odometry frame (the nearest odometry message; the identity pose
   without odometry), those under ``min_confidence`` dropped;
4. the tracker, `jaxtrack.tracking.step` with seed 001's settings (`tracker_params`).

Frames run in fixed-size chunks, one ``lax.scan`` each, compiled once; the last chunk is padded
with frames that leave the state unchanged.

- `depth_cloud`: a depth image (and colour image) with pinhole intrinsics -> the optical-frame
  cloud.
- `rgbd_clouds`: recorded depth and colour images paired by nearest time -> `bags.PointClouds`.
- `mount`: the camera's `Mount` from its position, downward tilt and pan.
- `track_rgbd_bag` is ``jaxtrack track --cloud-topic`` / ``--rgbd-topics``: a bag in,
  ``tracks.csv`` (MOTChallenge layout) and a top view out.

Example:
  >>> clouds = bags.read_point_clouds("run.bag", "/camera/depth/points")
  >>> cam = mount((0.1, 0.0, 1.1), tilt=math.radians(5.0))
  >>> out = track_rgbd(clouds, cam, focal=(147.3, 152.3), odometry=odom)
  >>> out.pos[out.mask]                      # confirmed tracks, odometry frame
"""

from __future__ import annotations

import functools
import math
import sys
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import geometry, montecarlo, tracking
from jaxtrack.io import bags
from jaxtrack.perception import hog, rgbd_people
from jaxtrack.perception.rgbd_people import RGBDPeopleConfig

Array = jax.Array

__all__ = ["Mount", "RGBDTracks", "mount", "depth_cloud", "rgbd_clouds", "tracker_params",
           "track_rgbd", "track_rgbd_bag", "write_top_view"]


class Mount(NamedTuple):
    """The camera on the robot, in the base frame (x forward, y left, z up).

    Attributes:
      position: [3] the optical centre (m).
      rotation: [3, 3] whose columns are the optical axes (x right, y down, z forward): a
        point ``p`` of the optical frame is ``position + rotation @ p`` in the base frame.
    """

    position: Array
    rotation: Array


class RGBDTracks(NamedTuple):
    """Detector and tracker output, one row per frame, in the odometry frame.

    Attributes:
      frames: [T] int32 frame numbers (1, 2, ...); times: [T] float64 seconds.
      ids: [T, K] int32 track ids (-1 in free slots); pos: [T, K, 2] track positions;
      mask: [T, K] bool, confirmed tracks.
      detections: [T, M, 2] detected people on the ground plane; det_mask: [T, M] the
        detections handed to the tracker (confidence >= ``min_confidence``);
      confidence: [T, M] their HOG confidence (1 without HOG; 0 for empty rows).
      num_points: [T] int32 valid points of each frame's cloud.
    """

    frames: np.ndarray
    times: np.ndarray
    ids: np.ndarray
    pos: np.ndarray
    mask: np.ndarray
    detections: np.ndarray
    det_mask: np.ndarray
    confidence: np.ndarray
    num_points: np.ndarray


def mount(position, tilt: float = 0.0, pan: float = 0.0, dtype=jnp.float32) -> Mount:
    """A camera at ``position`` (x forward, y left, z up, m) in the base frame, looking ahead,
    tilted down by ``tilt`` and turned left by ``pan`` (rad): the Kinect's mount of
    `sims.following.kinect.mount_pose`, computed the same way.

    Example:
      >>> cam = mount((0.1, 0.0, 1.1), tilt=math.radians(5.0))
      >>> cam.rotation[:, 2]                   # the optical axis: ahead and slightly down
    """
    position = np.asarray(position, np.float64)
    if position.shape != (3,) or not np.all(np.isfinite(position)):
        raise ValueError(f"position must be a finite (x, y, z); got {position}")
    if not (math.isfinite(float(tilt)) and math.isfinite(float(pan))):
        raise ValueError(f"tilt and pan must be finite; got {tilt}, {pan}")
    pan = jnp.asarray(pan, dtype)
    cp, sp = jnp.cos(pan), jnp.sin(pan)
    ct, st = math.cos(float(tilt)), math.sin(float(tilt))
    forward = jnp.stack([cp * ct, sp * ct, jnp.asarray(-st, dtype)])
    right = jnp.stack([sp, -cp, jnp.zeros((), dtype)])
    down = jnp.cross(forward, right)
    return Mount(jnp.asarray(tuple(position), dtype), jnp.stack([right, down, forward], -1))


def depth_cloud(depth: Array, focal, principal, colour: Array | None = None,
                mask: Array | None = None) -> tuple[Array, Array, Array]:
    r"""Back-project a depth image into the camera's optical frame (x right, y down, z forward).

    Pixel (row i, column j) with depth :math:`z` (along the optical axis) is the point
    :math:`z\,((j + 1/2 - c_x) / f_x,\ (i + 1/2 - c_y) / f_y,\ 1)`: the principal point
    counts from the image's corner, as `jaxtrack.perception.depth.CeilingCamera` (a ROS
    ``CameraInfo``'s ``K[0, 2] + 1/2``, ``K[1, 2] + 1/2``). Depths that are 0, negative or not
    finite (or outside ``mask``) are invalid: their points are 0 and masked.

    Args:
      depth: [H, W] metres.
      focal: (fx, fy) pixels; principal: (cx, cy) pixels from the image's corner.
      colour: [H, W, 3] RGB in [0, 1] registered to the depth image, or None (zeros).
      mask: [H, W] bool, or None.

    Returns:
      ``(points [H * W, 3], colours [H * W, 3], mask [H * W])``, row-major pixel order.

    Example:
      >>> pts, rgb, ok = depth_cloud(depth, (147.3, 152.3), (80.0, 60.0), colour)
    """
    depth = jnp.asarray(depth)
    if depth.ndim != 2:
        raise ValueError(f"depth must be [H, W]; got shape {depth.shape}")
    dtype = depth.dtype if jnp.issubdtype(depth.dtype, jnp.floating) else jnp.float32
    depth = depth.astype(dtype)
    H, W = depth.shape
    fx, fy = (jnp.asarray(v, dtype) for v in focal)
    cx, cy = (jnp.asarray(v, dtype) for v in principal)
    ok = jnp.isfinite(depth) & (depth > 0)
    if mask is not None:
        ok &= jnp.asarray(mask, bool)
    z = jnp.where(ok, depth, 0.0)
    u = (jnp.arange(W, dtype=dtype) + 0.5 - cx) / fx
    v = (jnp.arange(H, dtype=dtype) + 0.5 - cy) / fy
    rays = jnp.stack(jnp.broadcast_arrays(u[None, :], v[:, None], jnp.ones((), dtype)), -1)
    points = (z[..., None] * rays).reshape(-1, 3)
    if colour is None:
        rgb = jnp.zeros((H * W, 3), dtype)
    else:
        colour = jnp.asarray(colour, dtype)
        if colour.shape != (H, W, 3):
            raise ValueError(f"colour must be [{H}, {W}, 3] like the depth; got {colour.shape}")
        rgb = colour.reshape(-1, 3)
    return points, rgb, ok.reshape(-1)


_depth_cloud = jax.jit(depth_cloud)


def rgbd_clouds(depth: bags.DepthImages, colour: bags.ColourImages, focal, principal=None, *,
                tolerance: float | None = None) -> bags.PointClouds:
    """Pair recorded depth and colour images by nearest time and back-project each pair
    (`depth_cloud`) into an organised optical-frame cloud.

    The frames are the depth images; each takes the colour image nearest in time within
    ``tolerance`` (default half the depth images' median period). Depth images without one are
    left out, counted in the report (``dropped``, ``detail``). The images must be registered:
    the same size.

    Args:
      depth: `bags.DepthImages` [T, H, W]; colour: `bags.ColourImages` [T', H, W, 3].
      focal: (fx, fy); principal: (cx, cy) from the image's corner (default the centre).

    Returns:
      `bags.PointClouds` with N = H x W points per frame and ``image_shape`` (H, W); zero
      frames when no depth image has a colour image within ``tolerance``.

    Example:
      >>> clouds = rgbd_clouds(bags.read_depth(bag, "/depth"), bags.read_colour(bag, "/rgb"),
      ...                      focal=(147.3, 152.3))
    """
    H, W = np.shape(depth.depth)[1:]
    if np.shape(colour.colour)[1:] != (H, W, 3):
        raise ValueError(f"the colour images are {np.shape(colour.colour)[1:3]} and the depth "
                         f"images {(H, W)}: pairs must be registered, of one size")
    focal, principal = _intrinsics(focal, principal, (H, W))
    rows = np.flatnonzero(np.asarray(depth.valid, bool))
    crows = np.flatnonzero(np.asarray(colour.valid, bool))
    times = np.asarray(depth.times, np.float64)[rows]
    if tolerance is None:
        tolerance = 0.5 * float(np.median(np.diff(times))) if rows.size > 1 else np.inf
    if not float(tolerance) >= 0:
        raise ValueError(f"tolerance must be >= 0; got {tolerance}")
    if crows.size and rows.size:
        ctimes = np.asarray(colour.times, np.float64)[crows]
        near = _nearest(ctimes, times)
        paired = np.abs(ctimes[near] - times) <= float(tolerance)
    else:
        near, paired = np.zeros(rows.size, int), np.zeros(rows.size, bool)
    d_rows, c_rows = rows[paired], crows[near[paired]] if crows.size else rows[:0]
    T = d_rows.size
    points = np.zeros((T, H * W, 3), np.float32)
    colours = np.zeros((T, H * W, 3), np.float32)
    mask = np.zeros((T, H * W), bool)
    for k, (i, j) in enumerate(zip(d_rows, c_rows)):
        p, c, m = _depth_cloud(np.asarray(depth.depth[i], np.float32),
                               focal, principal, np.asarray(colour.colour[j], np.float32),
                               np.asarray(depth.mask[i], bool))
        points[k], colours[k], mask[k] = np.asarray(p), np.asarray(c), np.asarray(m)
    report = depth.report
    lost = int(rows.size - T)
    if lost and report is not None:
        report = report._replace(dropped=report.dropped + lost, detail="; ".join(
            ([report.detail] if report.detail else [])
            + [f"{lost} depth images without a colour image within {tolerance:.3g} s left out"]))
    return bags.PointClouds(times[paired], points, colours, mask, np.ones(T, bool), report,
                            (int(H), int(W)))


def tracker_params(dt: float, *, capacity: int = 12, appearance: bool = True,
                   confidence: bool = True, histogram_bins: int = 4,
                   dtype=jnp.float32) -> tracking.TrackerParams:
    """Seed 001's tracker (`sims.following.crowd.Pipeline().tracker`) at the frame period
    ``dt`` (s): GNN, UKF, the Mahalanobis distance of position and of the velocity over about
    1 s (``velocity_window`` = round(1 / dt) frames, open_ptrack's baseline); with
    ``appearance``, the colour classifier's cost term over ``histogram_bins`` ^ 3 histograms;
    with ``confidence``, the HOG confidence's cost term and the 0.5 birth threshold.

    Example:
      >>> params = tracker_params(1 / 30, capacity=16)
    """
    tc = tracking.TrackerConfig(
        capacity=int(capacity), association="gnn", filter="ukf", motion_term="position_velocity",
        distance="mahalanobis", num_features=histogram_bins ** 3 if appearance else 0,
        confirm_hits=3, confirm_window=5, max_misses=10, max_tentative_misses=2,
        merge_distance=0.3, births_in_gates=True, velocity_window=max(1, round(1.0 / dt)))
    return tracking.TrackerParams.create(
        tc, dt=dt, q=1.0, r_std=(0.15,), init_speed_std=1.0, gamma=1.0,
        alpha=1.0 if appearance else 0.0, beta=2.0 if confidence else 0.0,
        birth_confidence=0.5 if confidence else 0.0, gate_prob=0.999, dtype=dtype)


def track_rgbd(clouds: bags.PointClouds, mount: Mount, *,
               config: RGBDPeopleConfig = RGBDPeopleConfig(),
               params: tracking.TrackerParams | None = None, min_confidence: float = 0.5,
               focal=None, principal=None, svm="shipped",
               odometry: bags.Odometry | None = None, cloud_frame: str = "optical",
               chunk: int = 64, seed: int = 0, keys: Array | None = None, dtype=jnp.float32,
               progress: bool = True, stream=None) -> RGBDTracks:
    """Detect and track people through recorded RGB-D clouds (module docstring).

    Args:
      clouds: `bags.PointClouds` (T clouds of N points; rows with ``valid`` False are
        skipped), in the camera's optical frame (`bags.read_point_clouds`, `rgbd_clouds`).
      mount: the camera's `Mount` in the robot's base frame (`mount`).
      config: the detector's `RGBDPeopleConfig` (its grid is laid in the base frame).
      params: the tracker's `tracking.TrackerParams`; default `tracker_params` at the clouds'
        median period (rounded to the microsecond), 12 tracks.
      min_confidence: detections less confident are not handed to the tracker.
      focal, principal: (fx, fy) and (cx, cy) of the camera (principal point from the image's
        corner, default the centre): with an organised cloud (``clouds.image_shape``) and an
        ``svm``, each detection's HOG confidence on the cloud's colours as the image; without,
        confidence 1.
      svm: `hog.LinearSVM`, ``"shipped"`` (`hog.load_svm`) or None (no HOG).
      odometry: `bags.Odometry` of the robot (the nearest message to each frame), or None
        (the base frame is the tracks' frame).
      cloud_frame: ``"optical"``, or ``"base"`` for clouds already in the base frame (the
        mount then gives only the camera's viewpoint and HOG pose).
      chunk: frames per compiled ``lax.scan``.
      seed, keys: frame t's detector key (RANSAC) is ``split(PRNGKey(seed), T)[t]``, or
        ``keys[t]`` when ``keys`` [T] is given.

    Returns:
      `RGBDTracks`; T = 0 rows when no cloud is valid.

    Example:
      >>> out = track_rgbd(bags.read_point_clouds("run.bag", "/points"), mount((0, 0, 1.1)))
    """
    if not isinstance(clouds, bags.PointClouds):
        raise TypeError(f"clouds must be a bags.PointClouds; got {type(clouds).__name__}")
    if cloud_frame not in ("optical", "base"):
        raise ValueError(f"cloud_frame must be 'optical' or 'base'; got {cloud_frame!r}")
    if int(chunk) < 1:
        raise ValueError(f"chunk must be >= 1; got {chunk}")
    if not math.isfinite(float(min_confidence)):
        raise ValueError(f"min_confidence must be finite; got {min_confidence}")
    np_dtype = np.dtype(jnp.dtype(dtype).name)
    cam = _check_mount(mount, np_dtype)
    points = np.asarray(clouds.points)
    if points.ndim != 3 or points.shape[2] != 3:
        raise ValueError(f"clouds.points must be [T, N, 3]; got shape {points.shape}")
    T_all, N = points.shape[:2]
    for name, want in (("colours", (T_all, N, 3)), ("mask", (T_all, N)), ("valid", (T_all,)),
                       ("times", (T_all,))):
        if np.shape(getattr(clouds, name)) != want:
            raise ValueError(f"clouds.{name} must be {list(want)}; got "
                             f"{list(np.shape(getattr(clouds, name)))}")
    rows = np.flatnonzero(np.asarray(clouds.valid, bool))
    T = rows.size
    times = np.asarray(clouds.times, np.float64)[rows]
    dt = round(float(np.median(np.diff(times))), 6) if T > 1 else 0.1
    if not dt > 0:
        raise ValueError("cloud times must increase")
    params = tracker_params(dt, dtype=dtype) if params is None else params
    F, bins = params.config.num_features, config.histogram_bins
    if F not in (0, bins ** 3):
        raise ValueError(f"the tracker's num_features ({F}) must be 0 (no appearance) or the "
                         f"detector's histogram size {bins}^3 = {bins ** 3}")
    K, M = params.config.capacity, config.heads.max_detections
    if keys is None:
        keys = jax.random.split(jax.random.PRNGKey(seed), T) if T else None
    elif np.shape(keys)[0] != T:
        raise ValueError(f"keys must hold one key per valid cloud ({T}); got "
                         f"{np.shape(keys)[0]}")
    pose = np.zeros((T, 3))
    if odometry is not None:
        ov = np.asarray(odometry.valid, bool)
        if not ov.any():
            raise ValueError("the odometry has no valid message")
        pose = np.asarray(odometry.pose, np.float64)[ov][
            _nearest(np.asarray(odometry.times, np.float64)[ov], times)]
    if svm == "shipped":
        svm = hog.load_svm(dtype=dtype)
    elif svm is not None and not isinstance(svm, hog.LinearSVM):
        raise TypeError(f"svm must be a hog.LinearSVM, 'shipped' or None; got {svm!r}")
    shape = clouds.image_shape
    camera = None
    if shape is not None and focal is not None and svm is not None:
        shape = (int(shape[0]), int(shape[1]))
        if shape[0] * shape[1] > N:
            raise ValueError(f"clouds.image_shape {shape} holds more pixels than N = {N}")
        f, c = _intrinsics(focal, principal, shape)
        camera = hog.PinholeCamera(jnp.asarray(f, dtype), jnp.asarray(c, dtype),
                                   jnp.asarray(cam.position), jnp.asarray(cam.rotation))
        svm = hog.LinearSVM(jnp.asarray(svm.weights, dtype), jnp.asarray(svm.bias, dtype))
    else:
        shape, svm = None, None
    if T == 0:
        z = np.zeros
        return RGBDTracks(z(0, np.int32), times, z((0, K), np.int32), z((0, K, 2)),
                          z((0, K), bool), z((0, M, 2)), z((0, M), bool), z((0, M)),
                          z(0, np.int32))
    pts = points[rows].astype(np_dtype)
    rgb = np.asarray(clouds.colours)[rows].astype(np_dtype)
    ok = np.asarray(clouds.mask, bool)[rows] & np.all(np.isfinite(pts), -1)
    run = _chunk_runner(config, shape, cloud_frame)
    carry = (rgbd_people.init_state(config, dtype=dtype), tracking.init(params.config, dtype))
    jcam = Mount(jnp.asarray(cam.position), jnp.asarray(cam.rotation))
    threshold = jnp.asarray(min_confidence, dtype)
    C = int(chunk)
    outs = []
    bar = montecarlo.progress_bar(T, unit="frames", file=stream, disable=not progress)
    for s0 in range(0, T, C):
        idx = np.arange(s0, s0 + C)
        sl = np.minimum(idx, T - 1)
        xs = (jnp.asarray(pts[sl]), jnp.asarray(rgb[sl]), jnp.asarray(ok[sl]),
              jnp.asarray(pose[sl], dtype), keys[sl], jnp.asarray(idx < T))
        carry, out = run(carry, xs, params, jcam, camera, svm, threshold)
        n = min(C, T - s0)
        outs.append([np.asarray(o)[:n] for o in out])
        bar.update(n)
    bar.close()
    ids, pos, mask, det, det_mask, conf, count = (np.concatenate(x) for x in zip(*outs))
    return RGBDTracks(np.arange(1, T + 1, dtype=np.int32), times, ids, pos, mask, det,
                      det_mask, conf, count.astype(np.int32))


def _nearest(src, dst):
    """[len(dst)] index of the ``src`` time nearest to each ``dst`` time (``src`` sorted,
    non-empty)."""
    j = np.clip(np.searchsorted(src, dst), 1, max(len(src) - 1, 1))
    lo, hi = np.clip(j - 1, 0, len(src) - 1), np.clip(j, 0, len(src) - 1)
    return np.where(np.abs(src[lo] - dst) <= np.abs(src[hi] - dst), lo, hi)


def _intrinsics(focal, principal, shape):
    """((fx, fy), (cx, cy)) as floats, checked; the principal point defaults to the centre."""
    H, W = shape
    focal = tuple(float(v) for v in focal)
    principal = (W / 2.0, H / 2.0) if principal is None else tuple(float(v) for v in principal)
    if len(focal) != 2 or len(principal) != 2:
        raise ValueError(f"focal and principal must be (fx, fy) and (cx, cy); got {focal}, "
                         f"{principal}")
    if not all(math.isfinite(v) for v in focal + principal) or min(focal) <= 0:
        raise ValueError(f"focal lengths must be positive and finite, the principal point "
                         f"finite; got {focal}, {principal}")
    return focal, principal


def _check_mount(mount, np_dtype) -> Mount:
    if not isinstance(mount, Mount):
        raise TypeError(f"mount must be a rgbd_replay.Mount (see mount()); got "
                        f"{type(mount).__name__}")
    position = np.asarray(mount.position, np.float64)
    rotation = np.asarray(mount.rotation, np.float64)
    if position.shape != (3,) or rotation.shape != (3, 3):
        raise ValueError(f"mount position must be [3] and rotation [3, 3]; got "
                         f"{position.shape}, {rotation.shape}")
    if not (np.all(np.isfinite(position)) and np.all(np.isfinite(rotation))
            and np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-4)
            and np.linalg.det(rotation) > 0):
        raise ValueError("the mount must be finite with a rotation matrix (orthonormal, "
                         f"determinant 1); got {mount}")
    return Mount(np.asarray(mount.position).astype(np_dtype),
                 np.asarray(mount.rotation).astype(np_dtype))


@functools.lru_cache(maxsize=8)
def _chunk_runner(config: RGBDPeopleConfig, image_shape, cloud_frame: str):
    def run(carry, xs, params, cam, camera, svm, threshold):
        def frame(c, x):
            det_state, tracks = c
            pts, rgb, ok, pose, key, valid = x
            base = pts if cloud_frame == "base" else pts @ cam.rotation.T + cam.position
            image = (None if image_shape is None
                     else rgb[:image_shape[0] * image_shape[1]].reshape(*image_shape, 3))
            new_det, seen = rgbd_people.detect(config, det_state, key, base, ok, rgb,
                                               cam.position, image=image, camera=camera,
                                               svm=svm)
            xy = geometry.from_frame(pose, seen.people.position[:, :2])
            kept = seen.people.mask & (seen.confidence >= threshold)
            M = kept.shape[0]
            features = (seen.histograms if params.config.num_features
                        else jnp.zeros((M, 0), xy.dtype))
            dets = tracking.Detections(xy, kept, jnp.zeros(M, jnp.int32), seen.confidence,
                                       features)
            new_tracks = tracking.step(tracks, dets, params)
            new = jax.tree_util.tree_map(lambda a, b: jnp.where(valid, a, b),
                                         (new_det, new_tracks), c)
            confirmed = (new_tracks.status == tracking.CONFIRMED) & valid
            out = (new_tracks.id, new_tracks.mean[:, :2], confirmed, xy, kept & valid,
                   seen.confidence, jnp.sum(ok))
            return new, out

        return jax.lax.scan(frame, carry, xs)

    return jax.jit(run)


def track_rgbd_bag(bag, out, *, mount: Mount, cloud_topic: str | None = None,
                   depth_topic: str | None = None, colour_topic: str | None = None,
                   focal=None, principal=None, odom_topic: str | None = None,
                   tf_frames: tuple[str, str] | None = None, cloud_frame: str = "optical",
                   max_points: int | None = None, min_confidence: float = 0.5,
                   seed: int = 0, chunk: int = 64, time_source: str = "header",
                   stream=None) -> dict:
    """``jaxtrack track --cloud-topic`` / ``--rgbd-topics``: read a bag's point clouds
    (``cloud_topic``, `bags.read_point_clouds`) or depth and colour images (``depth_topic``
    and ``colour_topic``, paired by `rgbd_clouds`, which needs ``focal``), replay `track_rgbd`
    and write ``tracks.csv`` (MOTChallenge layout, `jaxtrack.io.trajectories.write_mot_csv`)
    and ``top_view.png`` into ``out``. ``focal`` / ``principal`` also give the HOG
    confidence on an organised cloud; ``odom_topic`` (``nav_msgs/Odometry``) or ``tf_frames``
    (``(parent, child)``, `bags.read_tf`) the odometry.

    Returns ``{"tracks": RGBDTracks, "rows": CSV rows written, "csv": path, "plot": path,
    "reports": [bags.BagReport]}``.

    Example:
      >>> track_rgbd_bag("run.bag", "out", mount=mount((0.1, 0, 1.1), math.radians(5)),
      ...                depth_topic="/camera/depth/image_raw",
      ...                colour_topic="/camera/color/image_raw", focal=(147.3, 152.3))
    """
    from pathlib import Path

    from jaxtrack.io import trajectories

    stream = sys.stdout if stream is None else stream
    if (cloud_topic is None) == (depth_topic is None and colour_topic is None):
        raise ValueError("give cloud_topic, or depth_topic and colour_topic, not both")
    if cloud_topic is None and (depth_topic is None or colour_topic is None):
        raise ValueError("depth images need their colour images: give depth_topic and "
                         "colour_topic")
    if cloud_topic is None and focal is None:
        raise ValueError("depth images need the camera's focal lengths (focal)")
    if odom_topic and tf_frames:
        raise ValueError("give odom_topic or tf_frames, not both")
    reports = []
    if cloud_topic is not None:
        clouds = bags.read_point_clouds(bag, cloud_topic, max_points=max_points,
                                        time_source=time_source)
        source = cloud_topic
    else:
        depth = bags.read_depth(bag, depth_topic, time_source=time_source)
        colour = bags.read_colour(bag, colour_topic, time_source=time_source)
        reports.append(colour.report)
        clouds = rgbd_clouds(depth, colour, focal, principal)
        source = f"{depth_topic} + {colour_topic}"
    reports.insert(0, clouds.report)
    odom = (bags.read_odometry(bag, odom_topic, time_source=time_source) if odom_topic
            else bags.read_tf(bag, *tf_frames, time_source=time_source) if tf_frames else None)
    reports += [odom.report] if odom is not None else []
    hog_on = clouds.image_shape is not None and focal is not None
    t0 = time.perf_counter()
    result = track_rgbd(clouds, mount, focal=focal, principal=principal, odometry=odom,
                        cloud_frame=cloud_frame, min_confidence=min_confidence, chunk=chunk,
                        seed=seed, stream=stream)
    seconds = time.perf_counter() - t0
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    csv = out / "tracks.csv"
    rows = trajectories.write_mot_csv(csv, result.frames, result.ids, result.pos, result.mask)
    plot = out / "top_view.png"
    write_top_view(plot, result, odom, title=f"{Path(bag).name}: {source}")
    T = len(result.frames)
    n_ids = len(np.unique(result.ids[result.mask])) if result.mask.any() else 0
    span = result.times[-1] - result.times[0] if T else 0.0
    print(f"{T} RGB-D frames ({span:.1f} s, median "
          f"{np.median(result.num_points) if T else 0:.0f} points) tracked in {seconds:.1f} s "
          f"(compilation included), HOG confidence {'on' if hog_on else 'off'}: "
          f"{int(result.det_mask.sum())} detections, {n_ids} track ids, {rows} rows -> {csv}, "
          f"{plot}", file=stream)
    for r in reports:
        if r is not None and not r.complete:
            print(f"warning: {r.topic}: {r.messages} messages read, "
                  f"{'unknown' if r.unreadable < 0 else r.unreadable} unreadable: {r.detail}",
                  file=stream)
    return {"tracks": result, "rows": rows, "csv": csv, "plot": plot, "reports": reports}


def write_top_view(path, tracks: RGBDTracks, odometry: bags.Odometry | None = None,
                   title: str = "") -> None:
    """Top view of a replay: the detections handed to the tracker (grey), the confirmed
    tracks (one colour per id) and the odometry path.

    Example:
      >>> write_top_view("top_view.png", track_rgbd(clouds, cam))
    """
    from jaxtrack.io.replay import top_view

    def detections(ax):
        det = tracks.detections[tracks.det_mask]
        ax.plot(det[:, 0], det[:, 1], ".", ms=2, color="0.6", label="detections")

    top_view(path, tracks.ids, tracks.pos, tracks.mask, odometry, title, before=detections)
