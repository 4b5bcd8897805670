"""ROS 1 and ROS 2 bags in and out of fixed-shape arrays.

Reads ROS 1 bags (``.bag``) and ROS 2 bags (a directory with ``metadata.yaml`` and ``.db3`` or
``.mcap`` storage) through the pure-Python ``rosbags`` package (``pip install "jaxtrack[ros]"``;
imported only when a bag is read or written), into NumPy arrays that jitted pipelines take
as they are: one row per message, fixed sizes, boolean masks for missing data, timestamps in
seconds.

- `read_laser`: ``sensor_msgs/LaserScan`` -> `LaserScans` (ranges [T, B], the beams without a
  return masked and set to ``range_max``: what `jaxtrack.perception.legs.detect` expects).
- `read_depth`: ``sensor_msgs/Image`` depth (16UC1 millimetres or 32FC1 metres) ->
  `DepthImages` in metres.
- `read_colour`: ``sensor_msgs/Image`` colour (rgb8, bgr8, rgba8, bgra8, mono8) ->
  `ColourImages`, RGB in [0, 1].
- `read_point_clouds`: ``sensor_msgs/PointCloud2`` -> `PointClouds` (points [T, N, 3] in the
  message's frame, their colours and a mask).
- `read_odometry`: ``nav_msgs/Odometry`` -> `Odometry` (x, y, yaw) and (vx, vy, wz).
- `read_joint_states`: ``sensor_msgs/JointState`` -> `JointStates` (e.g. a camera's pan
  angle), the named joints' positions [T, J].
- `read_detections`: ``geometry_msgs/PoseArray`` or ``people_msgs/PositionMeasurementArray``
  (`register_people_msgs`) -> `PersonDetections` [T, M, 2] with a mask.
- `resample`: streams onto a common fixed-rate clock (buckets or nearest sample), with a mask
  for the empty slots; every reader also takes ``rate=``.
- `write_bag`: the inverse, for bags made from simulations.

Each record has ``valid [T]`` (False only for empty slots after resampling) and a `BagReport`.
A bag whose end is missing (a recording cut by a crash or a full disk has no index) is read
record by record up to the cut: what is readable is returned, and the report (also issued as a
`BagWarning`) says where reading stopped and how many messages were lost when the bag says how
many it holds (ROS 2 ``metadata.yaml``). A damaged record inside the file (a flipped bit, a
zeroed block) is skipped and its byte offset listed in the report; a file from which nothing of
the topic can be read raises `BagError` naming the file and, when known, the offset. Times are
the messages' header stamps (``time_source="header"``) or the bag's receive times (``"bag"``); a
few messages whose time lies apart from the rest of the stream (more than `OUTLIER_GAP` from it:
a flipped bit in a stamp) are left out and counted in the report.

Example:
  >>> scans = read_laser("run.bag", "/scan")
  >>> det = jax.vmap(lambda r: legs.detect(r, scans.angles))(scans.ranges)
"""

from __future__ import annotations

import math
import mmap
import shutil
import sqlite3
import struct
import tempfile
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import numpy as np

__all__ = ["LaserScans", "DepthImages", "ColourImages", "PointClouds", "Odometry",
           "PersonDetections", "BagReport", "BagError", "BagWarning", "read_laser", "read_depth",
           "read_colour", "read_point_clouds", "read_odometry", "read_tf",
           "People", "read_people",
           "read_detections", "JointStates", "read_joint_states", "resample",
           "register_people_msgs", "write_bag", "topics", "beam_angles",
           "LASER_SCAN", "IMAGE", "POINT_CLOUD2", "ODOMETRY", "TF_MESSAGE", "POSE_ARRAY",
           "POSITION_MEASUREMENT_ARRAY", "JOINT_STATE", "MAX_RESAMPLE_SLOTS", "OUTLIER_GAP"]

LASER_SCAN = "sensor_msgs/msg/LaserScan"
IMAGE = "sensor_msgs/msg/Image"
POINT_CLOUD2 = "sensor_msgs/msg/PointCloud2"
POINT_FIELD = "sensor_msgs/msg/PointField"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
POSE_ARRAY = "geometry_msgs/msg/PoseArray"
JOINT_STATE = "sensor_msgs/msg/JointState"
POSITION_MEASUREMENT_ARRAY = "people_msgs/msg/PositionMeasurementArray"
POSITION_MEASUREMENT = "people_msgs/msg/PositionMeasurement"

# `resample` refuses a clock of more slots than this (10 Hz for 11.5 days): a wrong rate or a
# stray timestamp would otherwise allocate tens of GiB before anything else fails.
MAX_RESAMPLE_SLOTS = 10**7

# Seconds: the readers split a topic's sorted times at gaps longer than
# max(OUTLIER_GAP, 100 x the median interval) and leave out every part but the largest that holds
# at most max(2, 1 %) of the messages. A bit flipped in a stamp's seconds (2^6 s and more) puts a
# message that far away; a genuine pause between two substantial parts of a recording is kept.
OUTLIER_GAP = 60.0

_INSTALL = 'reading and writing ROS bags needs the rosbags package: pip install "jaxtrack[ros]"'

# people_msgs (the ROS people stack): not in the standard type stores.
_POSITION_MEASUREMENT_MSG = """\
std_msgs/Header header
string name
string object_id
geometry_msgs/Point pos
float64 reliability
float64[9] covariance
byte initialization
"""
_POSITION_MEASUREMENT_ARRAY_MSG = """\
std_msgs/Header header
people_msgs/PositionMeasurement[] people
float32[] cooccurrence
"""


class BagError(ValueError):
    """A bag cannot give what was asked: missing topic, wrong message type or encoding, a
    change of shape between messages, or no readable data."""


class BagWarning(UserWarning):
    """Part of a bag could not be read (see the record's `BagReport`)."""


class BagReport(NamedTuple):
    """What was read from one topic of one bag.

    Attributes:
      path: the bag; topic; msgtype: its message type (``pkg/msg/Name``).
      messages: messages read and kept (the rows of the record before any resampling).
      unreadable: messages that could not be read: counted against the bag's own message count
        when it has one (ROS 2 metadata, ROS 1 index), else the messages cut or undecodable;
        -1 if unknown.
      stopped_at: byte offset at which the storage file stops being readable (None if it was
        read to the end).
      detail: a sentence on what went wrong ("" when nothing did).
      dropped: messages read but left out of the arrays (times apart from the stream, see
        `OUTLIER_GAP`; odometry with NaN / inf values); ``detail`` says which and when.
      damaged: byte offsets of the records skipped as damaged when the file was read record by
        record (a record inside a compressed chunk: the chunk's offset), in file order.
    """

    path: str
    topic: str
    msgtype: str
    messages: int
    unreadable: int
    stopped_at: int | None
    detail: str
    dropped: int = 0
    damaged: tuple = ()

    @property
    def complete(self) -> bool:
        return (self.unreadable == 0 and self.stopped_at is None and not self.detail
                and self.dropped == 0 and not self.damaged)


class LaserScans(NamedTuple):
    """Laser scans of one topic.

    Attributes:
      times: [T] float64 seconds.
      ranges: [T, B] float32 metres; beams without a valid return (NaN, inf, outside
        [range_min, range_max), padding) hold ``range_max``.
      angles: [B] float32 beam angles (rad), ``angle_min + k * angle_increment``.
      mask: [T, B] bool, valid returns.
      range_min, range_max: float, of the first message.
      valid: [T] bool, a scan is present (False: empty slot after resampling).
      report: `BagReport`.
    """

    times: np.ndarray
    ranges: np.ndarray
    angles: np.ndarray
    mask: np.ndarray
    range_min: float
    range_max: float
    valid: np.ndarray
    report: BagReport | None = None


class DepthImages(NamedTuple):
    """Depth images of one topic.

    Attributes:
      times: [T] float64 seconds.
      depth: [T, H, W] float32 metres (0 where not ``mask``).
      mask: [T, H, W] bool, valid depths (finite, > 0; 16UC1: non-zero).
      valid: [T] bool; report: `BagReport`.
    """

    times: np.ndarray
    depth: np.ndarray
    mask: np.ndarray
    valid: np.ndarray
    report: BagReport | None = None


class ColourImages(NamedTuple):
    """Colour images of one topic.

    Attributes:
      times: [T] float64 seconds.
      colour: [T, H, W, 3] float32 RGB in [0, 1] (the 8-bit value / 255; mono8: grey in the
        three channels).
      valid: [T] bool; report: `BagReport`.
    """

    times: np.ndarray
    colour: np.ndarray
    valid: np.ndarray
    report: BagReport | None = None


class PointClouds(NamedTuple):
    """Point clouds of one topic (``sensor_msgs/PointCloud2``), N points per row.

    Attributes:
      times: [T] float64 seconds.
      points: [T, N, 3] float32 (x, y, z) in the message's frame (0 where not ``mask``).
      colours: [T, N, 3] float32 RGB in [0, 1], of every point read (masked or not; zeros if
        the cloud has no ``rgb`` / ``rgba`` field, and for padding).
      mask: [T, N] bool: the message's points with finite x, y, z; False for padding.
      valid: [T] bool; report: `BagReport`.
      image_shape: ``(height, width)`` when every message is an organised cloud (height > 1)
        of that shape kept in its layout (point ``h * width + w`` is pixel (h, w)); else None.
    """

    times: np.ndarray
    points: np.ndarray
    colours: np.ndarray
    mask: np.ndarray
    valid: np.ndarray
    report: BagReport | None = None
    image_shape: tuple | None = None


class Odometry(NamedTuple):
    """Odometry of one topic (float64).

    Attributes:
      times: [T] seconds.
      pose: [T, 3] (x, y, yaw) in the odometry frame (yaw from the quaternion, rad).
      twist: [T, 3] (vx, vy, wz) in the robot (child) frame.
      valid: [T] bool; report: `BagReport`.
    """

    times: np.ndarray
    pose: np.ndarray
    twist: np.ndarray
    valid: np.ndarray
    report: BagReport | None = None


class JointStates(NamedTuple):
    """Joint positions of one topic (float64), for the joints asked for.

    Attributes:
      times: [T] seconds.
      names: the J joint names, in column order.
      position: [T, J] positions (rad or m; NaN where a message lacks the joint).
      valid: [T] bool; report: `BagReport`.
    """

    times: np.ndarray
    names: tuple
    position: np.ndarray
    valid: np.ndarray
    report: BagReport | None = None


class PersonDetections(NamedTuple):
    """Person detections of one topic, at most M per message.

    Attributes:
      times: [T] float64 seconds.
      xy: [T, M, 2] float64 positions in the message's frame (0 where not ``mask``).
      mask: [T, M] bool.
      valid: [T] bool; report: `BagReport` (``detail`` counts detections beyond M, dropped).
    """

    times: np.ndarray
    xy: np.ndarray
    mask: np.ndarray
    valid: np.ndarray
    report: BagReport | None = None


# ---------------------------------------------------------------------------------------------
# Public readers


def read_laser(path, topic: str, *, max_beams: int | None = None, rate: float | None = None,
               method: str = "bucket", time_source: str = "header", typestore=None
               ) -> LaserScans:
    """Read ``sensor_msgs/LaserScan`` messages into fixed-shape arrays.

    A beam is valid when its range is finite and ``range_min <= r < range_max`` (ROS: values
    outside the limits are to be discarded; a reading at ``range_max`` is no return); the
    others are masked and set to ``range_max``, so `jaxtrack.perception.legs.detect` sees them as
    no return. The beam count must not change within the topic.

    Args:
      path: ``.bag`` file or ROS 2 bag directory.
      topic: e.g. ``"/scan"``.
      max_beams: pad every scan to this many beams (masked, angles continued), e.g. to share one
        compiled pipeline between bags; an error if a scan has more.
      rate, method: optional resampling (`resample`).
      time_source: ``"header"`` (the stamps) or ``"bag"`` (receive times).
      typestore: ``rosbags`` type store for bags without message definitions.

    Returns:
      `LaserScans` with T messages (or slots) and B beams.

    Example:
      >>> scans = read_laser("run.bag", "/scan")
      >>> scans.ranges.shape, scans.angles.shape      # (T, B), (B,)
    """
    msgs, report = _read_topic(path, topic, (LASER_SCAN,), time_source, typestore)
    if not msgs:
        raise _no_messages(LASER_SCAN, topic, path, report)
    first = msgs[0][1]
    beams = len(first.ranges)
    for i, (_, m) in enumerate(msgs):
        if len(m.ranges) != beams:
            raise BagError(f"{topic!r} in {path}: message {i} has {len(m.ranges)} beams, the "
                           f"first has {beams}; scans of different sizes cannot share an array")
    width = beams if max_beams is None else int(max_beams)
    if width < beams:
        raise BagError(f"{topic!r} has {beams} beams, more than max_beams={max_beams}")
    rmin, rmax = float(first.range_min), float(first.range_max)
    T = len(msgs)
    ranges = np.full((T, width), np.float32(rmax), np.float32)
    mask = np.zeros((T, width), bool)
    for i, (_, m) in enumerate(msgs):
        r = np.asarray(m.ranges, np.float32)
        ok = np.isfinite(r) & (r >= m.range_min) & (r < m.range_max)
        ranges[i, :beams] = np.where(ok, r, np.float32(rmax))
        mask[i, :beams] = ok
    angles = beam_angles(first.angle_min, first.angle_increment, width)
    times = np.array([t for t, _ in msgs], np.float64)
    out = LaserScans(times, ranges, angles, mask, rmin, rmax,
                     np.ones(T, bool), report)
    if rate is None:
        return out
    grid, valid, (ranges, mask) = _resample(report, times, ranges, mask, rate=rate,
                                            method=method)
    ranges[~valid] = np.float32(rmax)
    return out._replace(times=grid, ranges=ranges, mask=mask, valid=valid)


def read_depth(path, topic: str, *, rate: float | None = None, method: str = "bucket",
               time_source: str = "header", typestore=None) -> DepthImages:
    """Read ``sensor_msgs/Image`` depth images (16UC1 millimetres or 32FC1 metres) in metres.

    The row step (bytes per row, possibly padded) and the big-endian flag of each message are
    honoured. Other encodings raise `BagError` naming the encoding; so does a change of image
    size.

    Returns:
      `DepthImages` with depth [T, H, W] float32.

    Example:
      >>> depth = read_depth("run.bag", "/camera/depth/image_raw")
    """
    msgs, report = _read_topic(path, topic, (IMAGE,), time_source, typestore)
    if not msgs:
        raise _no_messages(IMAGE, topic, path, report)
    H, W = int(msgs[0][1].height), int(msgs[0][1].width)
    images = []   # each checked against its own bytes before any [T, H, W] array is made
    for i, (_, m) in enumerate(msgs):
        if (int(m.height), int(m.width)) != (H, W):
            raise BagError(f"{topic!r} in {path}: image {i} is {m.height}x{m.width}, the first "
                           f"is {H}x{W}")
        images.append(_depth_image(m, i, topic))
    depth = np.stack(images)
    mask = np.isfinite(depth) & (depth > 0)
    depth = np.where(mask, depth, np.float32(0))
    times = np.array([t for t, _ in msgs], np.float64)
    out = DepthImages(times, depth, mask, np.ones(len(msgs), bool), report)
    if rate is None:
        return out
    grid, valid, (depth, mask) = _resample(report, times, depth, mask, rate=rate, method=method)
    return out._replace(times=grid, depth=depth, mask=mask, valid=valid)


def read_colour(path, topic: str, *, rate: float | None = None, method: str = "bucket",
                time_source: str = "header", typestore=None) -> ColourImages:
    """Read ``sensor_msgs/Image`` colour images (rgb8, bgr8, rgba8, bgra8; mono8 as grey) as
    RGB in [0, 1] (the 8-bit value / 255, alpha dropped).

    The row step of each message is honoured. Other encodings raise `BagError` naming the
    encoding; so does a change of image size.

    Returns:
      `ColourImages` with colour [T, H, W, 3] float32.

    Example:
      >>> rgb = read_colour("run.bag", "/camera/color/image_raw")
      >>> rgb.colour.shape                            # (T, H, W, 3)
    """
    msgs, report = _read_topic(path, topic, (IMAGE,), time_source, typestore)
    if not msgs:
        raise _no_messages(IMAGE, topic, path, report)
    H, W = int(msgs[0][1].height), int(msgs[0][1].width)
    images = []
    for i, (_, m) in enumerate(msgs):
        if (int(m.height), int(m.width)) != (H, W):
            raise BagError(f"{topic!r} in {path}: image {i} is {m.height}x{m.width}, the first "
                           f"is {H}x{W}")
        images.append(_colour_image(m, i, topic))
    colour = np.stack(images)
    times = np.array([t for t, _ in msgs], np.float64)
    out = ColourImages(times, colour, np.ones(len(msgs), bool), report)
    if rate is None:
        return out
    grid, valid, (colour,) = _resample(report, times, colour, rate=rate, method=method)
    return out._replace(times=grid, colour=colour, valid=valid)


def read_point_clouds(path, topic: str, *, max_points: int | None = None,
                      rate: float | None = None, method: str = "bucket",
                      time_source: str = "header", typestore=None) -> PointClouds:
    """Read ``sensor_msgs/PointCloud2`` messages into fixed-shape arrays, in the message's frame.

    Decoded with NumPy from each message's fields: ``x``, ``y``, ``z`` stored as FLOAT32 or
    FLOAT64; the colour from an ``rgb`` or ``rgba`` field stored as FLOAT32 (PCL's packed
    convention: the bits of ``0x00RRGGBB``, or ``0xAARRGGBB``) or UINT32 (zeros without one);
    ``is_bigendian``, ``point_step`` and ``row_step`` (padded points and rows); organised clouds
    (height > 1) are read row by row. A point is valid when x, y and z are finite (organised
    clouds mark missing depth with NaN).

    Rows hold N points: without ``max_points``, N is the largest message's height x width and
    every message keeps its layout, padded at the end. With ``max_points``, N = ``max_points``;
    a message of more points keeps its valid ones, in order, and one with more *valid* points
    than ``max_points`` is a `BagError` (never truncated). ``image_shape`` is set when every
    message is organised, of one shape, and kept in its layout.

    Args:
      path: ``.bag`` file or ROS 2 bag directory; topic: e.g. ``"/camera/depth/points"``.
      max_points: N, points per row (>= 1), e.g. to share one compiled pipeline between bags.
      rate, method: optional resampling (`resample`).
      time_source: ``"header"`` or ``"bag"``; typestore: as `read_laser`.

    Returns:
      `PointClouds` with points [T, N, 3] float32.

    Raises:
      BagError: a missing x / y / z field, a field stored in an unsupported type, a message
        whose bytes do not hold its points, more valid points than ``max_points``.

    Example:
      >>> clouds = read_point_clouds("run.bag", "/camera/depth/points")
      >>> clouds.points.shape, clouds.mask.shape      # (T, N, 3), (T, N)
    """
    if max_points is not None and not (int(max_points) == max_points and max_points >= 1):
        raise ValueError(f"max_points must be a positive integer or None; got {max_points!r}")
    msgs, report = _read_topic(path, topic, (POINT_CLOUD2,), time_source, typestore)
    if not msgs:
        raise _no_messages(POINT_CLOUD2, topic, path, report)
    decoded = [_cloud_points(m, i, topic) for i, (_, m) in enumerate(msgs)]
    sizes = [xyz.shape[0] for xyz, _, _, _ in decoded]
    N = max(sizes) if max_points is None else int(max_points)
    T = len(msgs)
    points = np.zeros((T, N, 3), np.float32)
    colours = np.zeros((T, N, 3), np.float32)
    mask = np.zeros((T, N), bool)
    shapes = {shape for _, _, _, shape in decoded}
    in_layout = True
    for i, (xyz, rgb, ok, _) in enumerate(decoded):
        if xyz.shape[0] > N:
            count = int(ok.sum())
            if count > N:
                raise BagError(f"{topic!r} in {path}: cloud {i} has {count} valid points, more "
                               f"than max_points={N}")
            xyz, rgb, ok = xyz[ok], rgb[ok], ok[ok]
            in_layout = False
        n = xyz.shape[0]
        points[i, :n] = np.where(ok[:, None], xyz, np.float32(0))
        colours[i, :n] = rgb
        mask[i, :n] = ok
    shape = next(iter(shapes)) if len(shapes) == 1 else None
    image_shape = shape if shape is not None and shape[0] > 1 and in_layout else None
    times = np.array([t for t, _ in msgs], np.float64)
    out = PointClouds(times, points, colours, mask, np.ones(T, bool), report, image_shape)
    if rate is None:
        return out
    grid, valid, (points, colours, mask) = _resample(report, times, points, colours, mask,
                                                     rate=rate, method=method)
    return out._replace(times=grid, points=points, colours=colours, mask=mask, valid=valid)


def read_odometry(path, topic: str, *, rate: float | None = None, method: str = "bucket",
                  time_source: str = "header", typestore=None) -> Odometry:
    """Read ``nav_msgs/Odometry`` into planar poses (x, y, yaw) and twists (vx, vy, wz).

    The yaw is :math:`\\operatorname{atan2}(2(wz + xy), 1 - 2(y^2 + z^2))` of the orientation
    quaternion (the rotation about z of a planar robot). Messages whose pose or twist holds NaN
    or inf (a lost localisation, a damaged message) are dropped, not masked: they are not rows
    of the result, ``report.dropped`` counts them and ``report.detail`` says so (a
    `BagWarning` too).

    Example:
      >>> odom = read_odometry("run.bag", "/odom")
      >>> odom.pose[:, 2]                              # yaw [T]
    """
    msgs, report = _read_topic(path, topic, (ODOMETRY,), time_source, typestore)
    if not msgs:
        raise _no_messages(ODOMETRY, topic, path, report)
    pose = np.zeros((len(msgs), 3))
    twist = np.zeros((len(msgs), 3))
    for i, (_, m) in enumerate(msgs):
        p, q = m.pose.pose.position, m.pose.pose.orientation
        yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
        pose[i] = (p.x, p.y, yaw)
        v, w = m.twist.twist.linear, m.twist.twist.angular
        twist[i] = (v.x, v.y, w.z)
    times = np.array([t for t, _ in msgs], np.float64)
    finite = np.all(np.isfinite(pose), 1) & np.all(np.isfinite(twist), 1)
    if not finite.all():
        bad = int((~finite).sum())
        if not finite.any():
            raise BagError(f"every {ODOMETRY} message on {topic!r} in {path} has a NaN / inf "
                           f"pose or twist")
        times, pose, twist = times[finite], pose[finite], twist[finite]
        report = report._replace(
            messages=int(finite.sum()), dropped=report.dropped + bad,
            detail="; ".join(([report.detail] if report.detail else [])
                             + [f"{bad} messages with a NaN / inf pose or twist dropped"]))
        _warn(report, stacklevel=3)
    out = Odometry(times, pose, twist, np.ones(len(times), bool), report)
    if rate is None:
        return out
    grid, valid, (pose, twist) = _resample(report, times, pose, twist, rate=rate, method=method)
    return out._replace(times=grid, pose=pose, twist=twist, valid=valid)


def read_tf(path, parent: str, child: str, *, topic: str = "/tf",
            static_topic: str | None = "/tf_static", time_source: str = "header",
            typestore=None) -> Odometry:
    """The planar pose of frame ``child`` in frame ``parent`` over time, from the transform
    tree of a bag (``tf2_msgs/TFMessage`` on ``topic`` and, when present, ``static_topic``):
    e.g. ``read_tf(bag, "odom", "base_link")`` where a robot publishes its odometry as a
    transform rather than a ``nav_msgs/Odometry`` topic.

    Frame names are compared without a leading slash (ROS 1 ``/odom`` is ROS 2 ``odom``). The
    chain from ``parent`` to ``child`` may pass through several frames, in either direction;
    its transforms are composed in the plane (x, y and the yaw of each quaternion). The result
    has one row per message of the chain's first moving link, each other link taken at its
    nearest message in time (static links: their one transform). The twist is not in a
    transform tree: it is the pose difference over the time step, in the child frame (0 for
    the first row).

    Returns:
      `Odometry` (times, pose [T, 3] of the child in the parent frame, twist, valid, report).

    Example:
      >>> odom = read_tf("run.bag", "odom", "base_link")
    """
    parent, child = _frame(parent), _frame(child)
    if parent == child:
        raise ValueError(f"parent and child are the same frame {parent!r}")
    edges: dict = {}                 # (parent, child) -> [(time, (x, y, yaw))]
    dynamic: set = set()
    msgs, report = _read_topic(path, topic, (TF_MESSAGE,), time_source, typestore)
    sources = [(msgs, True)]
    if static_topic is not None:
        try:
            static, _ = _read_topic(path, static_topic, (TF_MESSAGE,), time_source, typestore)
            sources.append((static, False))
        except BagError as err:
            if "is not in" not in str(err):
                raise
    for messages, moving in sources:
        for t_msg, m in messages:
            for tr in m.transforms:
                key = (_frame(tr.header.frame_id), _frame(tr.child_frame_id))
                s = tr.header.stamp
                t = s.sec + 1e-9 * s.nanosec if time_source == "header" else t_msg
                v, q = tr.transform.translation, tr.transform.rotation
                yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y),
                                 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
                edges.setdefault(key, []).append((t, (v.x, v.y, yaw)))
                if moving:
                    dynamic.add(key)
    chain = _tf_chain(edges, parent, child)
    if chain is None:
        known = sorted({f for e in edges for f in e})
        raise BagError(f"no chain of transforms from {parent!r} to {child!r} in {path} "
                       f"(frames: {', '.join(known) or 'none'})")
    series = []
    for a, b, forward in chain:
        rows = sorted(edges[(a, b)])
        times = np.array([t for t, _ in rows])
        poses = np.array([p for _, p in rows], np.float64)
        series.append((times, poses, forward, (a, b) in dynamic))
    moving = [s for s in series if s[3] and len(s[0]) > 1]
    times = moving[0][0] if moving else series[0][0][:1]
    pose = np.zeros((len(times), 3))
    for link_times, poses, forward, _ in series:
        i = _align(link_times, times)
        link = poses[i]
        if not forward:
            link = _se2_inverse(link)
        pose = _se2_compose(pose, link)
    finite = np.all(np.isfinite(pose), 1)
    if not finite.all():
        times, pose = times[finite], pose[finite]
        report = report._replace(detail="; ".join(
            ([report.detail] if report.detail else [])
            + [f"{int((~finite).sum())} transforms with NaN / inf dropped"]))
    twist = np.zeros_like(pose)
    if len(times) > 1:
        d = np.diff(pose, axis=0)
        dt = np.maximum(np.diff(times), 1e-9)[:, None]
        c, s_ = np.cos(pose[:-1, 2]), np.sin(pose[:-1, 2])
        twist[1:, 0] = (c * d[:, 0] + s_ * d[:, 1]) / dt[:, 0]
        twist[1:, 1] = (-s_ * d[:, 0] + c * d[:, 1]) / dt[:, 0]
        twist[1:, 2] = np.angle(np.exp(1j * d[:, 2])) / dt[:, 0]
    report = report._replace(topic=f"{topic} {parent} -> {child}", messages=len(times))
    return Odometry(times, pose, twist, np.ones(len(times), bool), report)


def _frame(name: str) -> str:
    return str(name).lstrip("/")


def _tf_chain(edges, parent, child):
    """[(a, b, forward)] links from ``parent`` to ``child`` (breadth first over the tree, each
    stored edge usable both ways), or None."""
    from collections import deque

    graph: dict = {}
    for a, b in edges:
        graph.setdefault(a, []).append((b, (a, b, True)))
        graph.setdefault(b, []).append((a, (a, b, False)))
    prev = {parent: None}
    queue = deque([parent])
    while queue:
        f = queue.popleft()
        if f == child:
            break
        for g, link in graph.get(f, []):
            if g not in prev:
                prev[g] = (f, link)
                queue.append(g)
    if child not in prev:
        return None
    path = []
    f = child
    while prev[f] is not None:
        f, link = prev[f]
        path.append(link)
    return path[::-1]


def _align(src, dst):
    """Index of the nearest ``src`` time to each ``dst`` time."""
    j = np.clip(np.searchsorted(src, dst), 1, max(len(src) - 1, 1))
    lo = np.clip(j - 1, 0, len(src) - 1)
    hi = np.clip(j, 0, len(src) - 1)
    return np.where(np.abs(src[lo] - dst) <= np.abs(src[hi] - dst), lo, hi)


def _se2_compose(a, b):
    """Poses [N, 3]: b expressed in a's frame, composed (a then b)."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.stack([a[:, 0] + c * b[:, 0] - s * b[:, 1], a[:, 1] + s * b[:, 0] + c * b[:, 1],
                     np.angle(np.exp(1j * (a[:, 2] + b[:, 2])))], -1)


def _se2_inverse(p):
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    return np.stack([-c * p[:, 0] - s * p[:, 1], s * p[:, 0] - c * p[:, 1], -p[:, 2]], -1)


class People(NamedTuple):
    """People with identities, one topic (e.g. ground truth), at most M per message.

    Attributes:
      times: [T] float64 seconds.
      ids: [T, M] int64 identities (-1 where absent); string identities are numbered in order
        of first appearance (``names`` maps them back).
      xy: [T, M, 2] float64 positions in the message's frame (0 where absent).
      valid: [T] bool; names: tuple of the string identities (empty for integer ones);
      report: `BagReport`.
    """

    times: np.ndarray
    ids: np.ndarray
    xy: np.ndarray
    valid: np.ndarray
    names: tuple = ()
    report: BagReport | None = None


_ID_FIELDS = ("object_id", "track_id", "id", "name", "label")
_POSITION_FIELDS = ("pos", "position", "pose", "point", "center")


def read_people(path, topic: str, max_people: int, *, time_source: str = "header",
                typestore=None) -> People:
    """Read identified people (ground truth, or another tracker's output) from any message
    type that holds a list of entries with an identity and a position.

    The message's first list field whose entries have an identity field (one of
    ``object_id``, ``track_id``, ``id``, ``name``, ``label``) and a position field (``pos``,
    ``position``, ``pose``, ``point``, ``center``; a pose's ``position``, a pose with
    covariance's ``pose.position``) is read: ``people_msgs/PositionMeasurementArray``,
    ``spencer_tracking_msgs/TrackedPersons``, or a custom message whose definition the bag
    carries (ROS 1 bags always do). Entries with NaN / inf positions are left out; entries
    beyond ``max_people`` too, and counted in the report.

    Example:
      >>> gt = read_people("run.bag", "/people_gt", 16)
      >>> gt.ids.shape, gt.xy.shape                 # (T, 16), (T, 16, 2)
    """
    M = int(max_people)
    if M < 1:
        raise ValueError(f"max_people must be >= 1; got {max_people}")
    msgs, report = _read_topic(path, topic, None, time_source, typestore)
    if not msgs:
        raise _no_messages(report.msgtype or "people", topic, path, report)
    field = _people_field(msgs[0][1])
    if field is None:
        raise BagError(f"{topic!r} in {path} ({report.msgtype}) has no list of entries with "
                       f"an identity ({', '.join(_ID_FIELDS)}) and a position "
                       f"({', '.join(_POSITION_FIELDS)})")
    list_name, id_name, pos_name = field
    names: dict = {}
    ids = np.full((len(msgs), M), -1, np.int64)
    xy = np.zeros((len(msgs), M, 2))
    dropped = nonfinite = 0
    for i, (_, m) in enumerate(msgs):
        k = 0
        for entry in getattr(m, list_name):
            x, y = _position(getattr(entry, pos_name))
            if not (math.isfinite(x) and math.isfinite(y)):
                nonfinite += 1
                continue
            if k >= M:
                dropped += 1
                continue
            raw = getattr(entry, id_name)
            ids[i, k] = names.setdefault(raw, len(names)) if isinstance(raw, str) else int(raw)
            xy[i, k] = (x, y)
            k += 1
    notes = [f"{dropped} people beyond max_people={M} dropped"] if dropped else []
    notes += [f"{nonfinite} people with NaN / inf positions dropped"] if nonfinite else []
    if notes:
        report = report._replace(detail="; ".join(([report.detail] if report.detail else [])
                                                  + notes))
    times = np.array([t for t, _ in msgs], np.float64)
    return People(times, ids, xy, np.ones(len(msgs), bool), tuple(names), report)


def _people_field(msg):
    """(list field, identity field, position field) of a people message, or None."""
    for name in getattr(msg, "__dataclass_fields__", {}):
        value = getattr(msg, name)
        if not isinstance(value, (list, tuple)) or not value:
            continue
        entry = value[0]
        fields = getattr(entry, "__dataclass_fields__", {})
        id_name = next((f for f in _ID_FIELDS if f in fields), None)
        pos_name = next((f for f in _POSITION_FIELDS if f in fields), None)
        if id_name and pos_name:
            try:
                _position(getattr(entry, pos_name))
            except AttributeError:
                continue
            return name, id_name, pos_name
    return None


def _position(p):
    """(x, y) of a point, a pose (its ``position``) or a pose with covariance."""
    for _ in range(3):
        if hasattr(p, "x") and hasattr(p, "y"):
            return float(p.x), float(p.y)
        p = getattr(p, "position", None) or getattr(p, "pose")
    raise AttributeError("no position")


def read_joint_states(path, topic: str, names=None, *, rate: float | None = None,
                      method: str = "nearest", time_source: str = "header",
                      typestore=None) -> JointStates:
    """Read ``sensor_msgs/JointState`` positions of the joints ``names`` (default: those of the
    first message), by name in every message.

    Example:
      >>> pan = read_joint_states("run.bag", "/camera/joint_states", ["camera_pan"])
      >>> pan.position[:, 0]                           # [T] rad
    """
    msgs, report = _read_topic(path, topic, (JOINT_STATE,), time_source, typestore)
    if not msgs:
        raise _no_messages(JOINT_STATE, topic, path, report)
    names = tuple(msgs[0][1].name) if names is None else tuple(names)
    pos = np.full((len(msgs), len(names)), np.nan)
    for i, (_, m) in enumerate(msgs):
        index = {n: k for k, n in enumerate(m.name)}
        for j, n in enumerate(names):
            if n in index and index[n] < len(m.position):
                pos[i, j] = m.position[index[n]]
    times = np.array([t for t, _ in msgs], np.float64)
    out = JointStates(times, names, pos, np.ones(len(msgs), bool), report)
    if rate is None:
        return out
    grid, valid, (pos,) = _resample(report, times, pos, rate=rate, method=method)
    return out._replace(times=grid, position=pos, valid=valid)


def read_detections(path, topic: str, max_detections: int, *, rate: float | None = None,
                    method: str = "bucket", time_source: str = "header", typestore=None
                    ) -> PersonDetections:
    """Read person detections: ``geometry_msgs/PoseArray`` (the poses' x, y) or
    ``people_msgs/PositionMeasurementArray`` (the people's ``pos`` x, y).

    A bag carries its own message definitions (ROS 1 always, ROS 2 from Iron on); for a bag
    without them, pass a ``typestore`` where `register_people_msgs` registered people_msgs.
    Messages with more than ``max_detections`` entries keep the first ones; entries with NaN or
    inf positions are left out; the report counts both.

    Returns:
      `PersonDetections` with xy [T, M, 2], M = ``max_detections``.

    Example:
      >>> det = read_detections("run.bag", "/people", max_detections=8)
    """
    M = int(max_detections)
    if M < 1:
        raise ValueError(f"max_detections must be >= 1; got {max_detections}")
    msgs, report = _read_topic(path, topic, (POSE_ARRAY, POSITION_MEASUREMENT_ARRAY),
                               time_source, typestore)
    xy = np.zeros((len(msgs), M, 2))
    mask = np.zeros((len(msgs), M), bool)
    dropped = nonfinite = 0
    for i, (_, m) in enumerate(msgs):
        points = ([p.position for p in m.poses] if hasattr(m, "poses")
                  else [p.pos for p in m.people])
        finite = [p for p in points if math.isfinite(p.x) and math.isfinite(p.y)]
        nonfinite += len(points) - len(finite)
        dropped += max(len(finite) - M, 0)
        for j, p in enumerate(finite[:M]):
            xy[i, j] = (p.x, p.y)
            mask[i, j] = True
    notes = [f"{dropped} detections beyond max_detections={M} dropped"] if dropped else []
    notes += [f"{nonfinite} detections with NaN / inf positions dropped"] if nonfinite else []
    if notes:
        report = report._replace(detail="; ".join(([report.detail] if report.detail else [])
                                                  + notes))
    times = np.array([t for t, _ in msgs], np.float64)
    out = PersonDetections(times, xy, mask, np.ones(len(msgs), bool), report)
    if rate is None:
        return out
    grid, valid, (xy, mask) = _resample(report, times, xy, mask, rate=rate, method=method)
    return out._replace(times=grid, xy=xy, mask=mask, valid=valid)


def beam_angles(angle_min, angle_increment, num_beams: int) -> np.ndarray:
    """Beam angles [B] float32 of a ``LaserScan``: ``angle_min + k * angle_increment``
    (float32 message fields, summed in float64).

    `write_bag` stores ``angle_min = angles[0]`` and the mean increment, so angles made by this
    function round-trip exactly; others to float32 rounding.

    Example:
      >>> beam_angles(-2.0944, 0.0062832, 667)
    """
    k = np.arange(int(num_beams), dtype=np.float64)
    a0 = np.float64(np.float32(angle_min))
    inc = np.float64(np.float32(angle_increment))
    return (a0 + k * inc).astype(np.float32)


def topics(path, *, typestore=None) -> dict[str, str]:
    """``{topic: message type}`` of a bag.

    Example:
      >>> topics("run.bag")          # {'/odom': 'nav_msgs/msg/Odometry', '/scan': ...}
    """
    path = _check_path(path)
    AnyReader, ts = _reader_parts(path, typestore)
    try:
        with AnyReader([path], default_typestore=ts) as reader:
            return {name: info.msgtype for name, info in reader.topics.items()}
    except Exception:  # noqa: BLE001 - unreadable index: fall back to a record scan
        salvage = _salvage(path, None)
        return {c.topic: c.msgtype for c in salvage.connections.values()}


def resample(times, *arrays, rate: float, method: str = "bucket", start: float | None = None,
             stop: float | None = None, tolerance: float | None = None):
    """Put one stream on the fixed-rate clock :math:`t_k = t_0 + k / \\text{rate}`.

    - ``"bucket"``: slot k holds the last sample with :math:`t_k \\le t < t_{k+1}` (what a
      real-time consumer running at ``rate`` has at the end of the period);
    - ``"nearest"``: slot k holds the sample nearest to :math:`t_k`, if within ``tolerance``
      (default half a period).

    Empty slots are zero (False for boolean arrays) and ``valid`` is False there. A clock of
    more than `MAX_RESAMPLE_SLOTS` (10^7) slots is refused with a ValueError naming the rate and
    the time span, before anything is allocated (a rate in Hz given in slots per nanosecond, or
    a stray timestamp, would ask for tens of GiB); the readers leave out stray timestamps
    before resampling (see `OUTLIER_GAP`).

    Args:
      times: [T] sample times (s), non-decreasing.
      arrays: each [T, ...].
      rate: slots per second.
      start, stop: clock range (default: the first and last sample times).

    Returns:
      ``(grid [K], valid [K], tuple of arrays [K, ...])``.

    Example:
      >>> grid, valid, (pose,) = resample(odom.times, odom.pose, rate=10.0)
    """
    t = np.asarray(times, np.float64)
    if t.ndim != 1:
        raise ValueError(f"times must be [T]; got shape {t.shape}")
    if np.any(~np.isfinite(t)) or np.any(np.diff(t) < 0):
        raise ValueError("times must be finite and non-decreasing")
    if not (rate is not None and np.isfinite(rate) and rate > 0):
        raise ValueError(f"rate must be a positive number of slots per second; got {rate}")
    if method not in ("bucket", "nearest"):
        raise ValueError(f"method must be 'bucket' or 'nearest'; got {method!r}")
    arrays = [np.asarray(a) for a in arrays]
    for i, a in enumerate(arrays):
        if a.shape[:1] != t.shape:
            raise ValueError(f"array {i} has {a.shape[:1]} rows; times has {t.shape[0]}")
    if t.size == 0:
        raise ValueError("cannot resample an empty stream")
    t0 = float(t[0] if start is None else start)
    t1 = float(t[-1] if stop is None else stop)
    if not (math.isfinite(t0) and math.isfinite(t1) and t1 >= t0):
        raise ValueError(f"start and stop must be finite with start <= stop; got {t0}, {t1}")
    slots = (t1 - t0) * float(rate)
    if not slots < MAX_RESAMPLE_SLOTS:
        raise ValueError(f"resampling at rate={float(rate):g} Hz over {t1 - t0:.6g} s ({t0:.3f} "
                         f"to {t1:.3f} s) needs {slots + 1:.3g} slots, more than "
                         f"MAX_RESAMPLE_SLOTS = {MAX_RESAMPLE_SLOTS:.0e}: lower the rate or "
                         f"pass start / stop")
    K = int(math.floor(slots + 1e-9)) + 1
    grid = t0 + np.arange(K) / rate
    src = np.full(K, -1)
    if method == "bucket":
        k = np.floor((t - t0) * rate + 1e-9).astype(np.int64)
        inside = (k >= 0) & (k < K)
        src[k[inside]] = np.flatnonzero(inside)   # later samples overwrite earlier ones
    else:
        tol = 0.5 / rate if tolerance is None else float(tolerance)
        j = np.clip(np.searchsorted(t, grid), 1, max(t.size - 1, 1))
        cand = np.stack([np.clip(j - 1, 0, t.size - 1), np.clip(j, 0, t.size - 1)], -1)
        d = np.abs(t[cand] - grid[:, None])
        best = cand[np.arange(K), np.argmin(d, -1)]
        src = np.where(np.min(d, -1) <= tol, best, -1)
    valid = src >= 0
    out = []
    for a in arrays:
        r = np.zeros((K,) + a.shape[1:], a.dtype)
        r[valid] = a[src[valid]]
        out.append(r)
    return grid, valid, tuple(out)


def _resample(report: BagReport, times, *arrays, rate, method):
    """`resample` for a reader: a clock too long for the bag's own times (damaged stamps that
    `OUTLIER_GAP` does not catch: several messages moved together) is a `BagError` naming the
    bag."""
    if rate is not None and np.isfinite(rate) and rate > 0 and len(times):
        span = float(times[-1] - times[0])
        if not span * rate < MAX_RESAMPLE_SLOTS:
            raise BagError(f"{report.path} {report.topic}: the messages' times span {span:.6g} s "
                           f"({times[0]:.3f} to {times[-1]:.3f} s); at rate={float(rate):g} Hz "
                           f"that is more than MAX_RESAMPLE_SLOTS = {MAX_RESAMPLE_SLOTS:.0e} "
                           f"slots: a rate too high, or damaged stamps (read without rate= "
                           f"to see them)")
    return resample(times, *arrays, rate=rate, method=method)


def register_people_msgs(typestore):
    """Register ``people_msgs/PositionMeasurement`` and ``PositionMeasurementArray`` (the ROS
    people stack's detector output) in a ``rosbags`` type store; returns the store.

    Example:
      >>> from rosbags.typesys import Stores, get_typestore
      >>> ts = register_people_msgs(get_typestore(Stores.ROS1_NOETIC))
      >>> ts.types["people_msgs/msg/PositionMeasurementArray"]
    """
    _, _, get_types_from_msg = _rosbags_typesys()
    types = {}
    types.update(get_types_from_msg(_POSITION_MEASUREMENT_MSG, POSITION_MEASUREMENT))
    types.update(get_types_from_msg(_POSITION_MEASUREMENT_ARRAY_MSG,
                                    POSITION_MEASUREMENT_ARRAY))
    typestore.register(types)
    return typestore


# ---------------------------------------------------------------------------------------------
# Writer


def write_bag(path, version: int = 1, *, laser: LaserScans | None = None,
              odometry: Odometry | None = None, detections: PersonDetections | None = None,
              depth: DepthImages | None = None, joints: JointStates | None = None,
              clouds: PointClouds | None = None, colour: ColourImages | None = None,
              topics: dict | None = None,
              detections_type: str = POSE_ARRAY, depth_encoding: str = "32FC1",
              colour_encoding: str = "rgb8",
              storage: str = "sqlite3", frames: dict | None = None, typestore=None,
              chunk_bytes: int | None = None, compression: str | None = None) -> Path:
    """Write records (e.g. a simulated recording) as a ROS 1 or ROS 2 bag.

    Only rows with ``valid`` are written. Laser beams outside ``mask`` are written as ``inf``
    (no return); masked detections are left out; masked depths are written as 0 (16UC1) or NaN
    (32FC1). Odometry yaw becomes the quaternion :math:`(0, 0, \\sin(\\psi/2), \\cos(\\psi/2))`.
    Point clouds are ``sensor_msgs/PointCloud2`` with x, y, z FLOAT32 and a packed FLOAT32
    ``rgb`` (PCL's convention, 8 bits per channel, rounded): organised (height x width, NaN
    where not ``mask``) when the record has an ``image_shape``, else one row of the valid
    points. Colour images are 8 bits per channel, rounded (mono8: the mean of the channels).

    Args:
      path: new ``.bag`` file (version 1) or new directory (version 2); must not exist.
      version: 1 or 2.
      laser, odometry, detections, depth, joints, clouds, colour: records to write (any
        subset, at least one); ``joints`` as ``sensor_msgs/JointState`` (e.g. the camera's
        pan angle), ``clouds`` (`PointClouds`) as ``sensor_msgs/PointCloud2``, ``colour``
        (`ColourImages`) as ``sensor_msgs/Image``.
      topics: topic names, default ``{"laser": "/scan", "odometry": "/odom",
        "detections": "/people", "depth": "/camera/depth/image_raw",
        "joints": "/joint_states", "clouds": "/camera/depth/points",
        "colour": "/camera/color/image_raw"}``.
      detections_type: `POSE_ARRAY` or `POSITION_MEASUREMENT_ARRAY`.
      depth_encoding: "32FC1" (metres) or "16UC1" (millimetres, rounded).
      colour_encoding: "rgb8", "bgr8", "rgba8" (alpha 255), "bgra8" or "mono8".
      storage: ROS 2 storage, "sqlite3" or "mcap".
      frames: frame ids, default ``{"laser": "laser", "odom": "odom", "base": "base_link",
        "camera": "camera_depth_optical_frame"}`` (the camera's for depth, clouds and colour).
      typestore: ``rosbags`` type store (default: ROS 1 Noetic / ROS 2 Humble, plus
        people_msgs).
      chunk_bytes: ROS 1 chunk size (default rosbags' 1 MiB).
      compression: ROS 1 chunk compression, None, "lz4" or "bz2".

    Returns:
      The path written.

    Raises:
      ValueError naming the record and field: times (of the rows written) not finite, negative,
      not strictly increasing or beyond the stamp's range (2^32 s for ROS 1, 2^31 s for ROS 2);
      no row to write; 0 beams, an empty image or no joint; arrays whose shapes do not agree
      (laser ranges / mask [T, B] with angles [B]; odometry pose / twist [T, 3]; detections xy
      [T, M, 2] with mask [T, M]; depth and mask [T, H, W]; joint positions [T, J] with J
      names; cloud points / colours [T, N, 3] with mask [T, N] and an image_shape of at most
      N pixels; colour [T, H, W, 3]; valid [T]).

    Example:
      >>> write_bag("sim.bag", 1, laser=scans, odometry=odom)
    """
    path = Path(path)
    if version not in (1, 2):
        raise ValueError(f"version must be 1 or 2; got {version!r}")
    if storage not in ("sqlite3", "mcap"):
        raise ValueError(f"storage must be 'sqlite3' or 'mcap'; got {storage!r}")
    if detections_type not in (POSE_ARRAY, POSITION_MEASUREMENT_ARRAY):
        raise ValueError(f"detections_type must be {POSE_ARRAY!r} or "
                         f"{POSITION_MEASUREMENT_ARRAY!r}; got {detections_type!r}")
    if compression not in (None, "lz4", "bz2") or (compression and version != 1):
        raise ValueError(f"compression must be None, 'lz4' or 'bz2' (ROS 1); got "
                         f"{compression!r} for version {version}")
    if depth_encoding not in ("32FC1", "16UC1"):
        raise BagError(f"depth encoding {depth_encoding!r} is not supported (32FC1, 16UC1)")
    if colour_encoding not in _COLOUR_ENCODINGS:
        raise BagError(f"colour encoding {colour_encoding!r} is not supported "
                       f"({', '.join(_COLOUR_ENCODINGS)})")
    streams = {"laser": laser, "odometry": odometry, "detections": detections, "depth": depth,
               "joints": joints, "clouds": clouds, "colour": colour}
    if all(v is None for v in streams.values()):
        raise ValueError("nothing to write: give laser, odometry, detections, depth, joints, "
                         "clouds and/or colour")
    for key, rec in streams.items():
        if rec is not None:
            _check_record(key, rec, version)
    names = {"laser": "/scan", "odometry": "/odom", "detections": "/people",
             "depth": "/camera/depth/image_raw", "joints": "/joint_states",
             "clouds": "/camera/depth/points", "colour": "/camera/color/image_raw"}
    names.update(topics or {})
    fr = {"laser": "laser", "odom": "odom", "base": "base_link",
          "camera": "camera_depth_optical_frame"}
    fr.update(frames or {})
    Stores, get_typestore, _ = _rosbags_typesys()
    if typestore is None:
        typestore = get_typestore(Stores.ROS1_NOETIC if version == 1 else Stores.ROS2_HUMBLE)
        register_people_msgs(typestore)
    ts = typestore
    types = {"laser": LASER_SCAN, "odometry": ODOMETRY, "detections": detections_type,
             "depth": IMAGE, "joints": JOINT_STATE, "clouds": POINT_CLOUD2, "colour": IMAGE}
    for key, rec in streams.items():
        if rec is not None and types[key] not in ts.types:
            raise BagError(f"message type {types[key]} is not in the type store"
                           + (" (call register_people_msgs)" if "people" in types[key] else ""))
    messages = []  # (t_ns, key, message)
    make = _MessageMaker(ts, version)
    if laser is not None:
        for t, m in _laser_messages(make, laser, fr["laser"]):
            messages.append((t, "laser", m))
    if odometry is not None:
        for t, m in _odometry_messages(make, odometry, fr["odom"], fr["base"]):
            messages.append((t, "odometry", m))
    if detections is not None:
        for t, m in _detection_messages(make, detections, detections_type, fr["base"]):
            messages.append((t, "detections", m))
    if depth is not None:
        for t, m in _depth_messages(make, depth, depth_encoding, fr["camera"]):
            messages.append((t, "depth", m))
    if joints is not None:
        for t, m in _joint_messages(make, joints, fr["base"]):
            messages.append((t, "joints", m))
    if clouds is not None:
        for t, m in _cloud_messages(make, clouds, fr["camera"]):
            messages.append((t, "clouds", m))
    if colour is not None:
        for t, m in _colour_messages(make, colour, colour_encoding, fr["camera"]):
            messages.append((t, "colour", m))
    messages.sort(key=lambda x: x[0])
    if version == 1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
        if compression:
            writer.set_compression(getattr(Writer.CompressionFormat, compression.upper()))
        with writer:
            if chunk_bytes is not None:
                writer.chunk_threshold = int(chunk_bytes)
            conns = {k: writer.add_connection(names[k], types[k], typestore=ts)
                     for k, v in streams.items() if v is not None}
            for t, key, m in messages:
                writer.write(conns[key], t, ts.serialize_ros1(m, types[key]))
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        with Writer(path, version=9, storage_plugin=plugin) as writer:
            conns = {k: writer.add_connection(names[k], types[k], typestore=ts)
                     for k, v in streams.items() if v is not None}
            for t, key, m in messages:
                writer.write(conns[key], t, ts.serialize_cdr(m, types[key]))
    return path


# ---------------------------------------------------------------------------------------------
# Message construction


class _MessageMaker:
    def __init__(self, ts, version):
        self.ts, self.version = ts, version
        self.T = ts.types

    def header(self, t_ns, frame_id, seq):
        H = self.T["std_msgs/msg/Header"]
        stamp = self.T["builtin_interfaces/msg/Time"](sec=int(t_ns // 10**9),
                                                       nanosec=int(t_ns % 10**9))
        if "seq" in H.__dataclass_fields__:
            return H(seq=seq, stamp=stamp, frame_id=frame_id)
        return H(stamp=stamp, frame_id=frame_id)

    def vec(self, x=0.0, y=0.0, z=0.0):
        return self.T["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))

    def point(self, x=0.0, y=0.0, z=0.0):
        return self.T["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=float(z))

    def quat_yaw(self, yaw):
        with np.errstate(invalid="ignore"):  # a NaN / inf yaw is written as a NaN quaternion
            z, w = float(np.sin(0.5 * yaw)), float(np.cos(0.5 * yaw))
        return self.T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=z, w=w)


def _ns(t) -> int:
    return int(round(float(t) * 1e9))


def _check_record(key: str, rec, version: int):
    """The checks of `write_bag` on one record (``key``: its argument name)."""
    times = np.asarray(rec.times)
    if times.ndim != 1:
        raise ValueError(f"write_bag: {key}.times must be [T]; got shape {times.shape}")
    T = times.shape[0]

    def shape(field, want):
        got = np.shape(getattr(rec, field))
        if len(got) != len(want) or any(w is not None and g != w for g, w in zip(got, want)):
            spec = ", ".join("?" if w is None else str(w) for w in want)
            raise ValueError(f"write_bag: {key}.{field} must be [{spec}] (T = {T} times); got "
                             f"shape {got}")
        return got

    if rec.valid is not None:
        shape("valid", (T,))
    rows = _rows(rec)
    if rows.size == 0:
        raise ValueError(f"write_bag: {key} has no row to write (T = {T}, valid rows: 0)")
    t = times[rows].astype(np.float64)
    limit = 2.0**32 if version == 1 else 2.0**31
    if not np.all(np.isfinite(t)) or np.any(t < 0) or np.any(t >= limit):
        raise ValueError(f"write_bag: {key}.times must be finite seconds in [0, {limit:.0f}) "
                         f"(the ROS {version} stamp); got {t[~((t >= 0) & (t < limit))][:3]}")
    if np.any(np.diff(t) <= 0):
        i = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise ValueError(f"write_bag: {key}.times must be strictly increasing over the rows "
                         f"written; row {rows[i + 1]} ({t[i + 1]!r} s) follows {t[i]!r} s")
    if key == "laser":
        (B,) = shape("angles", (None,))
        if B == 0:
            raise ValueError("write_bag: laser has 0 beams (angles is empty)")
        shape("ranges", (T, B))
        shape("mask", (T, B))
        if not (np.isfinite(rec.range_min) and np.isfinite(rec.range_max)
                and np.all(np.isfinite(rec.angles))):
            raise ValueError("write_bag: laser.angles, range_min and range_max must be finite")
    elif key == "odometry":
        shape("pose", (T, 3))
        shape("twist", (T, 3))
    elif key == "detections":
        _, M, _ = shape("xy", (T, None, 2))
        shape("mask", (T, M))
    elif key == "depth":
        _, H, W = shape("depth", (T, None, None))
        if H * W == 0:
            raise ValueError(f"write_bag: depth images are empty ({H}x{W})")
        shape("mask", (T, H, W))
    elif key == "joints":
        _, J = shape("position", (T, None))
        if J == 0 or len(rec.names) != J:
            raise ValueError(f"write_bag: joints.position has {J} columns and joints.names "
                             f"{len(rec.names)} names; give one name per column, at least one")
    elif key == "clouds":
        _, N, _ = shape("points", (T, None, 3))
        shape("colours", (T, N, 3))
        shape("mask", (T, N))
        if rec.image_shape is not None:
            H, W = (int(v) for v in rec.image_shape)
            if not (H >= 1 and W >= 1 and H * W <= N):
                raise ValueError(f"write_bag: clouds.image_shape {tuple(rec.image_shape)} "
                                 f"must be (H >= 1, W >= 1) with H x W <= N = {N}")
    elif key == "colour":
        _, H, W, _ = shape("colour", (T, None, None, 3))
        if H * W == 0:
            raise ValueError(f"write_bag: colour images are empty ({H}x{W})")


def _rows(rec):
    valid = np.ones(len(rec.times), bool) if rec.valid is None else np.asarray(rec.valid, bool)
    return np.flatnonzero(valid)


def _laser_messages(make, rec: LaserScans, frame_id):
    angles = np.asarray(rec.angles, np.float64)
    B = angles.shape[0]
    inc = (angles[-1] - angles[0]) / (B - 1) if B > 1 else 0.0
    dt = float(np.median(np.diff(rec.times))) if len(rec.times) > 1 else 0.0
    LS = make.T[LASER_SCAN]
    for seq, i in enumerate(_rows(rec)):
        t = _ns(rec.times[i])
        ranges = np.where(rec.mask[i], np.asarray(rec.ranges[i], np.float32),
                          np.float32(np.inf)).astype(np.float32)
        yield t, LS(header=make.header(t, frame_id, seq), angle_min=float(angles[0]),
                    angle_max=float(angles[-1]), angle_increment=float(inc),
                    time_increment=0.0, scan_time=dt, range_min=float(rec.range_min),
                    range_max=float(rec.range_max), ranges=ranges,
                    intensities=np.zeros(0, np.float32))


def _joint_messages(make, rec: JointStates, frame_id):
    JS = make.T[JOINT_STATE]
    names = [str(n) for n in rec.names]
    empty = np.zeros(0, np.float64)
    for seq, i in enumerate(_rows(rec)):
        t = _ns(rec.times[i])
        yield t, JS(header=make.header(t, frame_id, seq), name=names,
                    position=np.asarray(rec.position[i], np.float64), velocity=empty,
                    effort=empty)


def _odometry_messages(make, rec: Odometry, frame_id, child):
    T = make.T
    cov = np.zeros(36, np.float64)
    for seq, i in enumerate(_rows(rec)):
        t = _ns(rec.times[i])
        x, y, yaw = (float(v) for v in rec.pose[i])
        vx, vy, wz = (float(v) for v in rec.twist[i])
        pose = T["geometry_msgs/msg/Pose"](position=make.point(x, y),
                                           orientation=make.quat_yaw(yaw))
        twist = T["geometry_msgs/msg/Twist"](linear=make.vec(vx, vy), angular=make.vec(0, 0, wz))
        pose = T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov)
        twist = T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=cov)
        yield t, T[ODOMETRY](header=make.header(t, frame_id, seq), child_frame_id=child,
                             pose=pose, twist=twist)


def _detection_messages(make, rec: PersonDetections, msgtype, frame_id):
    T = make.T
    for seq, i in enumerate(_rows(rec)):
        t = _ns(rec.times[i])
        pts = np.asarray(rec.xy[i], np.float64)[np.asarray(rec.mask[i], bool)]
        header = make.header(t, frame_id, seq)
        if msgtype == POSE_ARRAY:
            poses = [T["geometry_msgs/msg/Pose"](position=make.point(*p),
                                                 orientation=make.quat_yaw(0.0)) for p in pts]
            yield t, T[POSE_ARRAY](header=header, poses=poses)
        else:
            PM = T[POSITION_MEASUREMENT]
            people = [PM(header=make.header(t, frame_id, seq), name="person",
                         object_id=str(j), pos=make.point(*p), reliability=1.0,
                         covariance=np.zeros(9, np.float64), initialization=0)
                      for j, p in enumerate(pts)]
            yield t, T[POSITION_MEASUREMENT_ARRAY](header=header, people=people,
                                                   cooccurrence=np.zeros(0, np.float32))


def _depth_messages(make, rec: DepthImages, encoding, frame_id):
    Image = make.T[IMAGE]
    for seq, i in enumerate(_rows(rec)):
        t = _ns(rec.times[i])
        d = np.asarray(rec.depth[i], np.float64)
        m = np.asarray(rec.mask[i], bool)
        H, W = d.shape
        if encoding == "16UC1":
            px = np.where(m, np.clip(np.round(d * 1000.0), 0, 65535), 0).astype("<u2")
        else:
            px = np.where(m, d, np.nan).astype("<f4")
        yield t, Image(header=make.header(t, frame_id, seq), height=H, width=W,
                       encoding=encoding, is_bigendian=0, step=W * px.itemsize,
                       data=np.frombuffer(px.tobytes(), np.uint8))


def _quantise8(colour):
    """RGB in [0, 1] -> uint8 (rounded, clipped)."""
    return np.round(np.clip(np.asarray(colour, np.float64), 0.0, 1.0) * 255).astype(np.uint8)


def _colour_messages(make, rec: ColourImages, encoding, frame_id):
    Image = make.T[IMAGE]
    channels, order = _COLOUR_ENCODINGS[encoding]
    for seq, i in enumerate(_rows(rec)):
        t = _ns(rec.times[i])
        q = _quantise8(rec.colour[i])
        H, W = q.shape[:2]
        if encoding == "mono8":
            px = np.round(q.astype(np.float64).mean(-1)).astype(np.uint8)[..., None]
        else:
            px = np.full((H, W, channels), 255, np.uint8)
            px[..., list(order)] = q
        yield t, Image(header=make.header(t, frame_id, seq), height=H, width=W,
                       encoding=encoding, is_bigendian=0, step=W * channels,
                       data=np.frombuffer(px.tobytes(), np.uint8))


_CLOUD_POINT = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])


def _cloud_messages(make, rec: PointClouds, frame_id):
    PC2, PF = make.T[POINT_CLOUD2], make.T[POINT_FIELD]
    fields = [PF(name=name, offset=4 * k, datatype=7, count=1)
              for k, name in enumerate(("x", "y", "z", "rgb"))]
    shape = rec.image_shape
    for seq, i in enumerate(_rows(rec)):
        t = _ns(rec.times[i])
        pts = np.asarray(rec.points[i], np.float32)
        ok = np.asarray(rec.mask[i], bool)
        rgb = _quantise8(rec.colours[i]).astype(np.uint32)
        if shape is not None:             # organised: every pixel, NaN where not valid
            H, W = shape
            pts, ok, rgb = pts[:H * W], ok[:H * W], rgb[:H * W]
        else:                             # unorganised: the valid points
            pts, rgb = pts[ok], rgb[ok]
            H, W, ok = 1, int(pts.shape[0]), ok[ok]
        buf = np.zeros(H * W, _CLOUD_POINT)
        for k, name in enumerate("xyz"):
            buf[name] = np.where(ok, pts[:, k], np.float32(np.nan))
        buf["rgb"] = (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]   # PCL's packed float
        yield t, PC2(header=make.header(t, frame_id, seq), height=H, width=W, fields=fields,
                     is_bigendian=False, point_step=_CLOUD_POINT.itemsize,
                     row_step=_CLOUD_POINT.itemsize * W,
                     data=np.frombuffer(buf.tobytes(), np.uint8), is_dense=bool(ok.all()))


def _depth_image(m, index, topic):
    enc = str(m.encoding)
    if enc in ("16UC1", "mono16"):
        dtype, scale = np.dtype(">u2" if m.is_bigendian else "<u2"), 1e-3
    elif enc == "32FC1":
        dtype, scale = np.dtype(">f4" if m.is_bigendian else "<f4"), 1.0
    else:
        raise BagError(f"{topic!r} image {index}: depth encoding {enc!r} is not supported "
                       f"(16UC1 millimetres, 32FC1 metres)")
    H, W, step = int(m.height), int(m.width), int(m.step)
    data = np.asarray(m.data, np.uint8)
    if step < W * dtype.itemsize or data.size < H * step:
        raise BagError(f"{topic!r} image {index}: {data.size} bytes with row step {step} do not "
                       f"hold {H}x{W} {enc} pixels")
    rows = data[:H * step].reshape(H, step)[:, :W * dtype.itemsize]
    px = np.ascontiguousarray(rows).view(dtype).reshape(H, W)
    return (px.astype(np.float64) * scale).astype(np.float32)


# 8-bit colour encodings: (channels, the channel indices of R, G, B).
_COLOUR_ENCODINGS = {"rgb8": (3, (0, 1, 2)), "bgr8": (3, (2, 1, 0)), "rgba8": (4, (0, 1, 2)),
                     "bgra8": (4, (2, 1, 0)), "mono8": (1, (0, 0, 0))}


def _colour_image(m, index, topic):
    enc = str(m.encoding)
    if enc not in _COLOUR_ENCODINGS:
        raise BagError(f"{topic!r} image {index}: colour encoding {enc!r} is not supported "
                       f"({', '.join(_COLOUR_ENCODINGS)})")
    channels, order = _COLOUR_ENCODINGS[enc]
    H, W, step = int(m.height), int(m.width), int(m.step)
    data = np.asarray(m.data, np.uint8)
    if step < W * channels or data.size < H * step:
        raise BagError(f"{topic!r} image {index}: {data.size} bytes with row step {step} do not "
                       f"hold {H}x{W} {enc} pixels")
    px = data[:H * step].reshape(H, step)[:, :W * channels].reshape(H, W, channels)
    return px[..., list(order)].astype(np.float32) / np.float32(255)


# sensor_msgs/PointField datatypes: NumPy type and name.
_POINT_TYPES = {1: ("i1", "INT8"), 2: ("u1", "UINT8"), 3: ("i2", "INT16"), 4: ("u2", "UINT16"),
                5: ("i4", "INT32"), 6: ("u4", "UINT32"), 7: ("f4", "FLOAT32"),
                8: ("f8", "FLOAT64")}


def _cloud_points(m, index, topic):
    """``(xyz [n, 3] float32, rgb [n, 3] float32 in [0, 1], finite [n], (height, width))`` of
    one ``PointCloud2``, n = height x width, in the message's row-major point order."""
    where = f"{topic!r} cloud {index}"
    fields = {str(f.name): f for f in m.fields}
    missing = [c for c in "xyz" if c not in fields]
    if missing:
        raise BagError(f"{where} has no {', '.join(missing)} field (fields: "
                       f"{', '.join(fields) or 'none'})")
    colour = "rgb" if "rgb" in fields else "rgba" if "rgba" in fields else None
    H, W = int(m.height), int(m.width)
    step, row_step = int(m.point_step), int(m.row_step)
    order = ">" if m.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for name, allowed in (("x", (7, 8)), ("y", (7, 8)), ("z", (7, 8)), (colour, (6, 7))):
        if name is None:
            continue
        f = fields[name]
        kind = int(f.datatype)
        if kind not in allowed:
            got = _POINT_TYPES.get(kind, (None, f"datatype {kind}"))[1]
            want = " or ".join(_POINT_TYPES[k][1] for k in allowed)
            raise BagError(f"{where}: field {name!r} is {got}; supported: {want}")
        # A packed colour is read as its 32 bits whatever its declared type.
        fmt = order + ("u4" if name == colour else _POINT_TYPES[kind][0])
        if int(f.offset) + np.dtype(fmt).itemsize > step:
            raise BagError(f"{where}: field {name!r} at offset {f.offset} runs past the point "
                           f"step {step}")
        names.append(name)
        formats.append(fmt)
        offsets.append(int(f.offset))
    n = H * W
    data = np.asarray(m.data, np.uint8)
    if n and (row_step < W * step or data.size < H * row_step):
        raise BagError(f"{where}: {data.size} bytes with point step {step} and row step "
                       f"{row_step} do not hold {H}x{W} points")
    if n == 0:
        return (np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32), np.zeros(0, bool),
                (H, W))
    raw = np.ascontiguousarray(data[:H * row_step].reshape(H, row_step)[:, :W * step])
    rec = raw.reshape(n, step).view(np.dtype({"names": names, "formats": formats,
                                              "offsets": offsets, "itemsize": step}))[:, 0]
    with np.errstate(over="ignore", invalid="ignore"):   # FLOAT64 beyond float32: inf, masked
        xyz = np.stack([rec["x"], rec["y"], rec["z"]], -1).astype(np.float32)
    finite = np.all(np.isfinite(xyz), -1)
    rgb = np.zeros((n, 3), np.float32)
    if colour is not None:
        v = rec[colour].astype(np.uint32)
        rgb = (np.stack([(v >> 16) & 255, (v >> 8) & 255, v & 255], -1).astype(np.float32)
               / np.float32(255))
    return xyz, rgb, finite, (H, W)


# ---------------------------------------------------------------------------------------------
# Reading


def _rosbags_typesys():
    try:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError(_INSTALL) from err
    return Stores, get_typestore, get_types_from_msg


def _check_path(path) -> Path:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no bag at {path}")
    return path


def _reader_parts(path: Path, typestore):
    try:
        from rosbags.highlevel import AnyReader
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError(_INSTALL) from err
    Stores, get_typestore, _ = _rosbags_typesys()
    if typestore is None:
        typestore = get_typestore(Stores.ROS1_NOETIC if path.suffix == ".bag"
                                  else Stores.ROS2_HUMBLE)
        register_people_msgs(typestore)
    return AnyReader, typestore


def _time_of(t_ns, msg, time_source):
    if time_source == "header" and hasattr(msg, "header"):
        s = msg.header.stamp
        return s.sec + 1e-9 * s.nanosec
    return 1e-9 * t_ns


def _resolve_topic(topic, available, path):
    if topic in available:
        return topic
    alt = topic[1:] if topic.startswith("/") else "/" + topic
    if alt in available:
        return alt
    listing = ", ".join(f"{n} ({t})" for n, t in sorted(available.items())) or "none"
    raise BagError(f"topic {topic!r} is not in {path}; topics present: {listing}")


def _check_type(topic, msgtype, accepted, path):
    if accepted is None:       # any type: the caller inspects the messages
        return
    if msgtype not in accepted:
        raise BagError(f"topic {topic!r} in {path} carries {msgtype}; expected "
                       + " or ".join(accepted))


def _read_topic(path, topic, accepted, time_source, typestore):
    """[(time s, message)] of one topic, sorted by time, and its `BagReport`."""
    if time_source not in ("header", "bag"):
        raise ValueError(f"time_source must be 'header' or 'bag'; got {time_source!r}")
    path = _check_path(path)
    AnyReader, ts = _reader_parts(path, typestore)
    try:
        reader = AnyReader([path], default_typestore=ts)
        reader.open()
    except Exception as err:  # noqa: BLE001 - any damage to the index: scan the records
        return _read_salvaged(path, topic, accepted, time_source, ts, str(err))
    out, bad, notes = [], 0, []
    decode_errors = _decode_errors()
    try:
        available = {n: i.msgtype for n, i in reader.topics.items()}
        name = _resolve_topic(topic, available, path)
        msgtype = available[name]
        _check_type(name, msgtype, accepted, path)
        conns = [c for c in reader.connections if c.topic == name]
        expected = sum(c.msgcount for c in conns)
        decode, note = _decoder(reader.typestore, ts, msgtype, ros1=not reader.is2)
        notes += [note] if note else []
        try:
            for conn, t, raw in reader.messages(connections=conns):
                try:
                    msg = decode(raw)
                except decode_errors:
                    bad += 1
                    continue
                out.append((_time_of(t, msg, time_source), msg))
        except Exception as err:  # noqa: BLE001 - storage damaged behind a valid index
            notes.insert(0, f"reading stopped: {err}")
    finally:
        reader.close()
    if bad:
        notes.append(f"{bad} messages could not be decoded")
    if notes and notes[0].startswith("reading stopped"):
        # The index is whole but the storage behind it is not: reading record by record
        # may recover the messages past the damage.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", BagWarning)
            try:
                salvaged = _read_salvaged(path, topic, accepted, time_source, ts, notes[0])
            except BagError:
                salvaged = None
        if salvaged is not None and len(salvaged[0]) > len(out):
            _warn(salvaged[1])
            return salvaged
    return _finish(path, name, msgtype, out, max(expected - len(out), bad), None, notes, ())


def _decode_errors() -> tuple:
    """What a decoder raises on bytes that do not hold its message (a length field pointing past
    the data, a string that is not UTF-8, ...)."""
    from rosbags.highlevel import AnyReaderError
    from rosbags.serde import SerdeError

    return (SerdeError, AnyReaderError, struct.error, IndexError, ValueError, TypeError,
            KeyError, OverflowError)


def _decoder(bag_store, ts, msgtype: str, ros1: bool):
    """``decode(raw) -> message`` of ``msgtype``, and a note for the report.

    The bag's own definition is used unless the type store ``ts`` knows the type and the bag's
    definition lacks one of its fields: a bit flipped in a field name would decode every message
    into one without the field. (A definition with more fields is kept: a ROS 1 header's ``seq``
    read with a ROS 2 store.)"""
    store, note = bag_store, ""
    if (bag_store is not ts and msgtype in ts.fielddefs
            and not _field_paths(ts.fielddefs, msgtype)
            <= _field_paths(getattr(bag_store, "fielddefs", {}), msgtype)):
        store = ts
        note = (f"the bag's definition of {msgtype} lacks fields of the standard one (damaged); "
                f"decoded with the standard definition")
    deserialize = store.deserialize_ros1 if ros1 else store.deserialize_cdr
    return (lambda raw: deserialize(raw, msgtype)), note


def _field_paths(fielddefs: dict, msgtype: str, prefix: str = "", depth: int = 0) -> set:
    """Dotted names of every field of ``msgtype``, nested types followed."""
    from rosbags.interfaces import Nodetype

    if msgtype not in fielddefs or depth > 16:
        return set()
    out = set()
    for name, (kind, detail) in fielddefs[msgtype][1]:
        path = f"{prefix}{name}"
        out.add(path)
        if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            kind, detail = detail[0]
        if kind == Nodetype.NAME:
            out |= _field_paths(fielddefs, detail, path + ".", depth + 1)
    return out


def _finish(path, name, msgtype, out, unreadable, stopped_at, notes, damaged):
    """Sort by time, leave out the messages apart from the stream, build and issue the report."""
    out.sort(key=lambda x: x[0])
    apart = _apart(np.array([t for t, _ in out], np.float64))
    dropped = int(apart.sum())
    if dropped:
        times = [t for (t, _), a in zip(out, apart) if a]
        kept = [t for (t, _), a in zip(out, apart) if not a]
        notes.append(f"{dropped} messages at times apart from the stream left out (at "
                     + ", ".join(f"{t:.3f}" for t in times[:5]) + (", ..." if dropped > 5 else "")
                     + f" s; the stream spans {kept[0]:.3f} to {kept[-1]:.3f} s)")
        out = [x for x, a in zip(out, apart) if not a]
    report = BagReport(str(path), name, msgtype, len(out), unreadable, stopped_at,
                       "; ".join(notes), dropped, tuple(damaged))
    _warn(report)
    return out, report


def _apart(t: np.ndarray) -> np.ndarray:
    """[T] bool: the sorted times ``t`` that lie apart from the stream (see `OUTLIER_GAP`)."""
    out = np.zeros(t.size, bool)
    if t.size < 3:
        return out
    gaps = np.diff(t)
    cuts = np.flatnonzero(gaps > max(OUTLIER_GAP, 100.0 * float(np.median(gaps)))) + 1
    if cuts.size == 0:
        return out
    parts = np.split(np.arange(t.size), cuts)
    largest = max(range(len(parts)), key=lambda i: parts[i].size)
    small = max(2, t.size // 100)
    for i, part in enumerate(parts):
        if i != largest and part.size <= small:
            out[part] = True
    return out


def _warn(report: BagReport, stacklevel: int = 5):
    if not report.complete:
        where = "" if report.stopped_at is None else f"; unreadable from byte {report.stopped_at}"
        if report.damaged:
            where += (f"; {len(report.damaged)} damaged records skipped (at byte "
                      + ", ".join(str(o) for o in report.damaged[:5])
                      + (", ..." if len(report.damaged) > 5 else "") + ")")
        lost = "unknown" if report.unreadable < 0 else str(report.unreadable)
        warnings.warn(f"{report.path} {report.topic}: read {report.messages} messages, "
                      f"unreadable messages: {lost}{where} ({report.detail})", BagWarning,
                      stacklevel=stacklevel)


def _no_messages(msgtype, topic, path, report: BagReport) -> BagError:
    """The error of a reader that got no message: where the file stopped, what was damaged."""
    where = ""
    if report is not None and report.stopped_at is not None:
        where += f"; the file is unreadable from byte {report.stopped_at}"
    if report is not None and report.damaged:
        where += f"; damaged records at byte {', '.join(str(o) for o in report.damaged[:5])}"
    if report is not None and report.detail:
        where += f" ({report.detail})"
    return BagError(f"no readable {msgtype} message on {topic!r} in {path}{where}")


def _read_salvaged(path, topic, accepted, time_source, ts, reason):
    s = _salvage(path, topic)
    types = {}
    for c in s.connections.values():
        types.setdefault(c.topic, set()).add(c.msgtype)
    if not types:
        where = "" if s.stopped_at is None else f"; unreadable from byte {s.stopped_at}"
        raise BagError(f"{path} is not readable ({reason}); no message could be recovered"
                       f"{where}")
    # A damaged connection record may give a topic a second, garbled type: keep the one asked for.
    available = {t: min(m & set(accepted or ()) or m) for t, m in types.items()}
    name = _resolve_topic(topic, available, path)
    msgtype = available[name]
    _check_type(name, msgtype, accepted, path)
    ids = {cid for cid, c in s.connections.items() if c.topic == name and c.msgtype == msgtype}
    decode, note = _salvage_decoder(s, ts, ids, msgtype, path)
    decode_errors = _decode_errors()
    out, bad = [], 0
    for cid, t, raw in s.messages:
        if cid not in ids:
            continue
        try:
            msg = decode(raw)
        except decode_errors:
            bad += 1
            continue
        out.append((_time_of(t, msg, time_source), msg))
    expected = s.counts.get(name)
    unreadable = expected - len(out) if expected is not None else (-1 if not bad else bad)
    notes = [reason] + ([s.detail] if s.detail else []) + ([note] if note else [])
    notes += [f"{bad} messages could not be decoded"] if bad else []
    return _finish(path, name, msgtype, out, unreadable, s.stopped_at, notes, s.damaged)


class _Conn(NamedTuple):
    topic: str
    msgtype: str
    msgdef: str        # definition text ("" if unknown)
    fmt: str           # "msg" or "idl"


class _Salvage(NamedTuple):
    connections: dict  # id -> _Conn
    messages: list     # (id, t_ns, raw)
    counts: dict       # topic -> messages the bag says it holds (when known)
    stopped_at: int | None
    detail: str
    ros1: bool
    damaged: tuple | list = ()  # byte offsets of damaged records


def _salvage_decoder(s: _Salvage, ts, ids, msgtype, path):
    """`_decoder` over the definitions the bag gives for the connections ``ids``; a definition
    that does not parse is replaced by the type store's."""
    from rosbags.typesys import Stores, TypesysError, get_types_from_idl, get_types_from_msg
    _, get_typestore, _ = _rosbags_typesys()

    store, types, broken = get_typestore(Stores.EMPTY), {}, False
    for cid in sorted(ids):
        c = s.connections[cid]
        try:
            if c.msgdef and c.fmt == "msg":
                types.update(get_types_from_msg(c.msgdef, c.msgtype))
            elif c.msgdef:
                types.update(get_types_from_idl(c.msgdef))
        except (TypesysError, ValueError, IndexError, KeyError):
            broken = True
    try:
        store.register(types)
    except (TypesysError, ValueError, KeyError):
        store, broken = get_typestore(Stores.EMPTY), True
    if msgtype not in store.fielddefs:
        if msgtype not in ts.fielddefs:
            raise BagError(f"{path}: the bag's definition of {msgtype} is "
                           + ("damaged" if broken else "missing")
                           + " and the type store does not hold it (pass typestore=)")
        store = ts
    decode, note = _decoder(store, ts, msgtype, s.ros1)
    if broken and not note:
        note = f"a definition of {msgtype} in the bag is damaged"
    return decode, note


def _salvage(path: Path, topic: str | None) -> _Salvage:
    """Connections of a damaged bag and the messages of ``topic`` (none if None)."""
    if path.is_dir():
        return _salvage_ros2(path, topic)
    if path.suffix in (".mcap", ".db3"):  # a ROS 2 storage file given on its own
        return _salvage_ros2_files([path], {}, [], topic)
    return _salvage_mapped(_scan_ros1, path, topic)


def _same_topic(a, b: str | None) -> bool:
    return isinstance(a, str) and b is not None and a.strip("/") == b.strip("/")


def _mapped(f: Path):
    """The file's bytes, memory-mapped (a damaged bag may be gigabytes)."""
    if f.stat().st_size == 0:
        raise BagError(f"{f} is empty")
    with open(f, "rb") as fh:
        return mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)


# -- ROS 1: records (header length, header fields, data length, data), Bag format 2.0 ----------

# What a damaged record raises while its fields are taken apart: a missing field, a field of the
# wrong length, text that is not UTF-8.
_RECORD_ERRORS = (KeyError, IndexError, struct.error, UnicodeDecodeError)

# What decompressing a damaged chunk raises (lz4: RuntimeError; bz2: OSError, EOFError; an
# unknown compression name: KeyError; a garbled size: MemoryError).
_DECOMPRESS_ERRORS = (KeyError, RuntimeError, OSError, EOFError, ValueError, MemoryError,
                      ImportError)


def _ros1_fields(buf: bytes) -> dict:
    fields, pos = {}, 0
    while pos + 4 <= len(buf):
        (n,) = struct.unpack_from("<I", buf, pos)
        pos += 4
        name, _, value = buf[pos:pos + n].partition(b"=")
        fields[name.decode(errors="replace")] = value
        pos += n
    return fields


def _ros1_records(buf: bytes, pos: int
                  ) -> Iterator[tuple[int, int, dict, bytes | None, int]]:
    """(record offset, data offset, header fields, data (None or short if cut), data length)
    until the buffer ends."""
    while pos < len(buf):
        if pos + 4 > len(buf):
            yield pos, pos, {}, None, 0
            return
        (hlen,) = struct.unpack_from("<I", buf, pos)
        if pos + 8 + hlen > len(buf):
            yield pos, pos, {}, None, 0
            return
        fields = _ros1_fields(buf[pos + 4:pos + 4 + hlen])
        (dlen,) = struct.unpack_from("<I", buf, pos + 4 + hlen)
        start = pos + 8 + hlen
        yield pos, start, fields, buf[start:start + dlen], dlen
        pos = start + dlen


def _ros1_next_chunk(buf, pos: int) -> int | None:
    """Offset of the next chunk record at or after ``pos`` whose header reads whole (fields
    ``op=5``, ``compression``, ``size`` filling the header length exactly), or None."""
    while True:
        p = buf.find(b"\x04\x00\x00\x00op=\x05", pos)
        if p < 0:
            return None
        # rosbags writes op first, rosbag (C++) after compression=...: try the starts before it.
        for start in range(p - 4, max(p - 4 - 64, pos - 1), -1):
            (hlen,) = struct.unpack_from("<I", buf, start)
            if 16 <= hlen <= 256 and start + 8 + hlen <= len(buf) and start + 4 <= p:
                f = _ros1_fields(buf[start + 4:start + 4 + hlen])
                if (f.get("op") == b"\x05" and "compression" in f and len(f.get("size", b"")) == 4
                        and _ros1_fields_length(buf[start + 4:start + 4 + hlen]) == hlen):
                    return start
        pos = p + 1


def _ros1_fields_length(buf: bytes) -> int:
    """Bytes the length-prefixed fields of ``buf`` take, walked from its start."""
    pos = 0
    while pos + 4 <= len(buf):
        (n,) = struct.unpack_from("<I", buf, pos)
        pos += 4 + n
    return pos


def _salvage_mapped(scan, path: Path, topic: str | None) -> _Salvage:
    """Run ``scan(path, buffer, topic)`` over the file memory-mapped, and unmap it."""
    buf = _mapped(path)
    try:
        return scan(path, buf, topic)
    finally:
        buf.close()


def _scan_ros1(path, buf, topic) -> _Salvage:
    """Connections and messages of a ROS 1 bag read record by record. A damaged record is
    skipped (its offset listed); when the walk loses the record boundaries it resumes at the
    next chunk record."""
    from rosbags.rosbag1.reader import decompressors
    from rosbags.typesys.msg import normalize_msgtype

    magic = b"#ROSBAG V2.0\n"
    if buf[:len(magic)] != magic:
        raise BagError(f"{path} is not a ROS 1 bag (format 2.0): bad magic at byte 0")
    conns, msgs, orphans, damaged = {}, [], [], []
    stopped, notes = None, []

    def record(op, f, d, at):
        try:
            if op == 7:  # connection: topic in the record header, type and definition in its data
                c = _ros1_fields(d)
                (cid,) = struct.unpack("<I", f["conn"])
                # The first intact copy wins (chunks repeat it, the index at the end too).
                conns.setdefault(cid, _Conn(f["topic"].decode(),
                                            normalize_msgtype(c["type"].decode()),
                                            c.get("message_definition", b"").decode(), "msg"))
            elif op == 2:  # message data
                (cid,) = struct.unpack("<I", f["conn"])
                sec, nsec = struct.unpack("<II", f["time"])
                if cid in conns:
                    if _same_topic(conns[cid].topic, topic):
                        msgs.append((cid, sec * 10**9 + nsec, bytes(d)))
                elif topic is not None:  # its connection record may come later (the index)
                    orphans.append((cid, sec * 10**9 + nsec, bytes(d)))
        except _RECORD_ERRORS:
            damaged.append(at)

    def chunk(data, base, whole):
        """Records of a chunk's (uncompressed) data; returns the offset of a cut record."""
        for off, _, f, d, dlen in _ros1_records(data, 0):
            if d is None or len(d) < dlen:
                return base + off
            record(f["op"][0] if f.get("op") else None, f, d, base + off if whole else base)
        return None

    pos = len(magic)
    while pos is not None:
        resume = None
        for off, start, f, d, dlen in _ros1_records(buf, pos):
            op = f["op"][0] if f.get("op") else None
            cut = d is None or len(d) < dlen
            if op == 5:
                comp = f.get("compression", b"none").decode(errors="replace")
                if comp == "none":
                    # A cut uncompressed chunk still holds whole message records before the cut.
                    at = chunk(d or b"", start, True)
                    if cut:
                        stopped = at if at is not None else off
                elif not cut:
                    try:
                        data = decompressors[comp](d)
                    except _DECOMPRESS_ERRORS:
                        damaged.append(off)
                        notes.append(f"a {comp} chunk could not be decompressed")
                    else:
                        if chunk(data, off, False) is not None:
                            damaged.append(off)
                else:
                    stopped = off
                    notes.append(f"a {comp}-compressed chunk is cut")
            elif not cut:
                record(op, f, d, off)
            if cut:
                stopped = off if stopped is None else stopped
                # A garbled length may have sent the walk past the end: look for a next chunk.
                resume = _ros1_next_chunk(buf, off + 1)
                if resume is not None:
                    damaged.append(off)
                    notes.append(f"records from byte {off} to {resume} skipped")
                    stopped = None
                break
        pos = resume
    msgs += [m for m in orphans if m[0] in conns and _same_topic(conns[m[0]].topic, topic)]
    detail = f"file of {len(buf)} bytes read record by record"
    if damaged:
        detail += f", {len(damaged)} damaged records skipped"
    if notes:
        detail += " (" + ", ".join(sorted(set(notes))) + ")"
    return _Salvage(conns, msgs, {}, stopped, detail, True, damaged)


# -- ROS 2: metadata.yaml + MCAP or sqlite3 storage ---------------------------------------------


def _ros2_metadata(path: Path) -> dict | None:
    meta = path / "metadata.yaml"
    if not meta.exists():
        return None
    from ruamel.yaml import YAML
    from ruamel.yaml.error import YAMLError

    try:
        data = YAML(typ="safe").load(meta.read_text())
        return data["rosbag2_bagfile_information"]
    except (YAMLError, UnicodeDecodeError, KeyError, TypeError) as err:
        raise BagError(f"{meta} is not readable: {err}") from None


def _salvage_ros2(path: Path, topic: str | None) -> _Salvage:
    info = _ros2_metadata(path)
    if info is None:
        # A recorder that did not finish writes no metadata.yaml: read the storage files.
        files = sorted(path.glob("*.db3")) + sorted(path.glob("*.mcap"))
        if not files:
            raise BagError(f"{path} is not a ROS 2 bag: no metadata.yaml and no .db3 / .mcap "
                           f"file")
        return _salvage_ros2_files(files, {}, ["no metadata.yaml (recording not closed)"],
                                   topic)
    counts = {}
    try:
        for entry in info.get("topics_with_message_count", []):
            counts[entry["topic_metadata"]["name"]] = int(entry["message_count"])
        files = [path / f for f in info.get("relative_file_paths", [])]
    except (AttributeError, KeyError, TypeError, ValueError) as err:
        raise BagError(f"{path / 'metadata.yaml'} is not a rosbag2 description: {err!r}"
                       ) from None
    return _salvage_ros2_files(files, counts, [], topic)


def _salvage_ros2_files(files, counts, notes, topic) -> _Salvage:
    conns, msgs, stopped, damaged = {}, [], None, []
    for f in files:
        if not f.exists():
            notes.append(f"{f.name} is missing")
            continue
        part = (_salvage_mapped(_scan_mcap, f, topic) if f.suffix == ".mcap"
                else _salvage_sqlite(f, topic))
        offset = max(conns, default=0)
        conns.update({cid + offset: c for cid, c in part.connections.items()})
        msgs.extend((cid + offset, t, raw) for cid, t, raw in part.messages)
        if part.stopped_at is not None and stopped is None:
            stopped = part.stopped_at
        damaged += list(part.damaged)
        if part.detail:
            notes.append(part.detail)
    return _Salvage(conns, msgs, counts, stopped, "; ".join(notes), False, damaged)


def _scan_mcap(f, buf, topic) -> _Salvage:
    """Schemas, channels and messages of an MCAP file read record by record; a damaged record
    (or a chunk that does not decompress) is skipped and its offset listed."""
    if buf[:8] != b"\x89MCAP0\r\n":
        raise BagError(f"{f} is not an MCAP file: bad magic at byte 0")
    schemas, conns, msgs, orphans, damaged = {}, {}, [], [], []
    stopped, notes = None, []

    def string(b, p):
        (n,) = struct.unpack_from("<I", b, p)
        if p + 4 + n > len(b):
            raise IndexError("string runs past its record")
        return bytes(b[p + 4:p + 4 + n]).decode(), p + 4 + n

    def record(op, body, at):
        try:
            if op == 0x03:
                (sid,) = struct.unpack_from("<H", body, 0)
                name, p = string(body, 2)
                enc, p = string(body, p)
                (dl,) = struct.unpack_from("<I", body, p)
                schemas.setdefault(sid, (name, enc, bytes(body[p + 4:p + 4 + dl]).decode()))
            elif op == 0x04:
                cid, sid = struct.unpack_from("<HH", body, 0)
                channel_topic, p = string(body, 4)
                name, enc, text = schemas.get(sid, ("", "", ""))
                # The first copy wins (the summary section repeats the channels).
                conns.setdefault(cid, _Conn(channel_topic, name, text,
                                            "idl" if enc == "ros2idl" else "msg"))
            elif op == 0x05:
                cid, _, log_time, _ = struct.unpack_from("<HIQQ", body, 0)
                if cid in conns:
                    if _same_topic(conns[cid].topic, topic):
                        msgs.append((cid, log_time, bytes(body[22:])))
                elif topic is not None:
                    orphans.append((cid, log_time, bytes(body[22:])))
        except _RECORD_ERRORS:
            damaged.append(at)

    def records(b, pos, base):
        """Records of ``b`` from ``pos``; ``base``: the file offset of ``b`` (or of the
        compressed chunk it came from, when ``whole`` offsets are not known: negative)."""
        nonlocal stopped
        while pos < len(b):
            at = base + pos if base >= 0 else -base - 1
            if pos + 9 > len(b):
                if base >= 0:
                    stopped = at if stopped is None else stopped
                else:
                    damaged.append(at)
                return
            op = b[pos]
            (n,) = struct.unpack_from("<Q", b, pos + 1)
            body = b[pos + 9:pos + 9 + n]
            if len(body) < n:
                if op == 0x06 and len(body) >= 40:
                    # A cut uncompressed chunk: read the whole records it still holds.
                    try:
                        comp, p = string(body, 28)
                    except _RECORD_ERRORS:
                        comp, p = None, 0
                    if comp == "":
                        records(body[p + 8:], 0, base + pos + 9 + p + 8 if base >= 0 else base)
                    elif comp is not None:
                        notes.append(f"a {comp} chunk is cut")
                if base >= 0:
                    stopped = at if stopped is None else stopped
                else:
                    damaged.append(at)
                return
            if op == 0x06:
                chunk(body, at, base + pos + 9 if base >= 0 else base)
            else:
                record(op, body, at)
            pos += 9 + n

    def chunk(body, at, body_base):
        try:
            comp, p = string(body, 28)
            (size,) = struct.unpack_from("<Q", body, p)
        except _RECORD_ERRORS:
            damaged.append(at)
            return
        data = body[p + 8:p + 8 + size]
        if comp == "":
            records(data, 0, body_base + p + 8 if body_base >= 0 else body_base)
            return
        try:
            if comp == "lz4":
                from lz4.frame import decompress
            else:
                from compression.zstd import decompress  # Python >= 3.14
            data = decompress(data)
        except _DECOMPRESS_ERRORS:
            damaged.append(at)
            notes.append(f"a {comp} chunk could not be decompressed")
            return
        records(data, 0, -at - 1)

    records(buf, 8, 0)
    msgs += [m for m in orphans if m[0] in conns and _same_topic(conns[m[0]].topic, topic)]
    detail = f"{f.name}: {len(buf)} bytes read record by record"
    if damaged:
        detail += f", {len(damaged)} damaged records skipped"
    if notes:
        detail += " (" + ", ".join(sorted(set(notes))) + ")"
    return _Salvage(conns, msgs, {}, stopped, detail, False, damaged)


def _salvage_sqlite(f: Path, topic: str | None) -> _Salvage:
    """Rows of a damaged ``.db3`` by id, from a copy whose page count matches its length."""
    buf = bytearray(f.read_bytes())
    if not buf.startswith(b"SQLite format 3\x00") or len(buf) < 100:
        raise BagError(f"{f} is not an sqlite3 file: bad magic at byte 0")
    (page,) = struct.unpack_from(">H", buf, 16)
    page = 65536 if page == 1 else page
    if page < 512 or page & (page - 1):
        raise BagError(f"{f}: the page size at byte 16 ({page}) is not a power of two "
                       f">= 512; the database header is damaged")
    pages = len(buf) // page
    whole = pages * page
    stopped = whole if whole < len(buf) or _sqlite_short(buf, pages) else None
    buf = buf[:whole]
    buf[28:32] = struct.pack(">I", pages)
    conns, msgs, notes = {}, [], []
    bad_rows = 0
    tmp = tempfile.mkdtemp(prefix="jaxtrack-bag-")
    try:
        copy = Path(tmp) / "salvage.db3"
        copy.write_bytes(bytes(buf))
        con = sqlite3.connect(f"file:{copy}?mode=ro", uri=True)
        try:
            defs = {}
            try:
                for typ, enc, text in con.execute(
                        "SELECT topic_type, encoding, encoded_message_definition "
                        "FROM message_definitions"):
                    if isinstance(typ, str) and isinstance(text, str):
                        defs[typ] = (text, "idl" if enc == "ros2idl" else "msg")
            except sqlite3.Error:
                pass
            try:
                for cid, name, typ in con.execute("SELECT id, name, type FROM topics"):
                    if isinstance(name, str) and isinstance(typ, str):
                        text, fmt = defs.get(typ, ("", "msg"))
                        conns[cid] = _Conn(name, typ, text, fmt)
            except sqlite3.Error as err:
                notes.append(f"topics table unreadable ({err})")
            wanted = {cid for cid, c in conns.items() if _same_topic(c.topic, topic)}
            misses, rowid = 0, 1
            while wanted and misses < 1000:
                try:
                    row = con.execute("SELECT topic_id, timestamp, data FROM messages "
                                      "WHERE id = ?", (rowid,)).fetchone()
                except sqlite3.Error:
                    row = None
                if row is None:
                    misses += 1
                else:
                    misses = 0
                    if row[0] in wanted:
                        if isinstance(row[1], int) and isinstance(row[2], bytes):
                            msgs.append((row[0], row[1], row[2]))
                        else:
                            bad_rows += 1
                rowid += 1
        finally:
            con.close()
    except sqlite3.Error as err:
        notes.append(f"database unreadable ({err})")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if bad_rows:
        notes.append(f"{bad_rows} rows without a time or data")
    detail = f"{f.name}: {len(buf)} bytes, messages read row by row"
    if notes:
        detail += " (" + ", ".join(notes) + ")"
    return _Salvage(conns, msgs, {}, stopped, detail, False)


def _sqlite_short(buf, pages) -> bool:
    (declared,) = struct.unpack_from(">I", buf, 28)
    return declared > pages
