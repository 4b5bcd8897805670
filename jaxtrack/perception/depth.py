r"""Depth tracking of a humanoid under a ceiling (zenithal) depth camera (seed 000, section 3.1).

The seed tracks a NAO robot with a SIR particle filter on the point cloud of a ceiling Kinect,
then estimates its heading by PCA of the points around the estimate. This module holds the
pieces, for points already back-projected to the world frame (z up, metres above the floor),
floor-removed and stored at a fixed capacity with a mask:

- `RobotModel`: the seed's geometric model (Fig. 2), a *cylinder* for the head (points above a
  z threshold) on top of a *cuboid* for the shoulders, arms and hands (points below it).
- `point_count`: the seed's observation, "the number of points [...] counted within a
  :math:`\theta_t` degree rotated robot model centered on the position of the particle"
  (section 3.1.1, Weighting), and `smooth_point_count`, its sigmoid-edged, differentiable twin.
- `log_likelihood`: the particle weight. The seed sets the weight *proportional to the count*,
  :math:`w^i \propto p(y_t | x^i_t) = n(x^i_t)` (eqs. 1-2), so the log-weight is
  :math:`\log(n + \epsilon)`; a tempered :math:`n / T` is offered as an option.
- `fold_half_turn`: the model is symmetric under a half turn, so a heading is only known modulo
  :math:`\pi` from the counts; this picks the representative nearest a reference (the previous
  estimate), for (x, y, theta) particle filters.
- `pca_heading`: section 3.1.2, the minor axis of the ellipse fitted (by PCA) to the floor
  projection of the points in a larger window, kept within
  :math:`[\theta_{t-1} - \theta_h, \theta_{t-1} + \theta_h]` and smoothed.

The whole seed tracker (particle filter on the position with the last heading, then the PCA
heading) is `jaxtrack.tracking.humanoid.depth_pf`.

All functions are pure, jittable and vmappable; masked or non-finite points never count.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxtrack import _checks, geometry
from jaxtrack.angles import wrap

Array = jax.Array

__all__ = ["RobotModel", "DepthFrame", "PCAHeading", "CeilingCamera", "back_project",
           "ceiling_cloud", "point_count", "smooth_point_count", "log_likelihood",
           "fold_half_turn", "pca_heading"]


class RobotModel(NamedTuple):
    """The seed's cuboid + cylinder robot model (Fig. 2), all lengths in metres.

    The seed prints no dimensions: the defaults are ours, sized for a NAO-like humanoid about
    0.57 m tall and 0.27 m across the shoulders, whose neck is at about 0.46 m. The head is seen
    from above as a disc; the shoulders, the arms hanging beside the torso and the hands (the
    seed's "shoulder and hands") as a box elongated across the shoulders.

    Attributes:
      head_radius: radius of the head cylinder (0.07: a NAO head is about 0.13-0.14 m wide).
      z_threshold: points higher than this are head points, lower ones body points (0.48:
        between the top of the shoulders and the top of the head).
      head_top: top of the head cylinder (0.65: above the 0.57 m robot, with sensor noise).
      shoulder_half_length: half-size of the cuboid across the shoulders, along the robot's
        left axis (0.15: half the 0.27 m shoulder width plus the arms).
      shoulder_half_depth: half-size of the cuboid front-back, along the facing axis (0.06).
      shoulder_bottom: bottom of the cuboid (0.15: low enough to keep the hands).
    """

    head_radius: float = 0.07
    z_threshold: float = 0.48
    head_top: float = 0.65
    shoulder_half_length: float = 0.15
    shoulder_half_depth: float = 0.06
    shoulder_bottom: float = 0.15


class DepthFrame(NamedTuple):
    """One frame of the zenithal camera, as the measurement of `log_likelihood`.

    Attributes:
      points: [P, 3] world-frame points (x, y, height), floor removed.
      mask: [P] bools, which points are valid (fixed capacity).
      heading: scalar, the heading used to rotate the cuboid when the particle state is (x, y)
        only (the seed's "estimated orientation in the last iteration").
    """

    points: Array
    mask: Array
    heading: Array


class PCAHeading(NamedTuple):
    """Output of `pca_heading`.

    Attributes:
      heading: the new heading estimate, wrapped to [-pi, pi).
      measured: the PCA facing direction closest to the previous heading (before the window and
        the smoothing); equals the previous heading when the fit is not valid.
      accepted: bool, the fit was valid and within the continuity window.
      num_points: number of points used by the fit (float).
    """

    heading: Array
    measured: Array
    accepted: Array
    num_points: Array


class CeilingCamera(NamedTuple):
    """A pinhole depth camera on the ceiling looking straight down (-z), image right along +x
    and image up along +y of the world (the seed's zenithal set-up).

    Attributes:
      position: [3] optical centre (x, y, height above the floor), metres.
      fx, fy: focal lengths (pixels).
      cx, cy: principal point, in pixel units from the image's top-left *corner* (so that the
        centre of pixel (i, j) is at (j + 1/2, i + 1/2)); the ``K`` matrix of a ROS
        ``CameraInfo`` counts from the centre of the first pixel: ``cx = K[0, 2] + 1/2``,
        ``cy = K[1, 2] + 1/2``.
    """

    position: tuple
    fx: float
    fy: float
    cx: float
    cy: float


def back_project(camera: CeilingCamera, depth: Array, valid: Array, row=0, col=0) -> Array:
    r"""World-frame points of depth pixels, :math:`X = c + z\,((j + 1/2 - c_x)/f_x,\
    -(i + 1/2 - c_y)/f_y, -1)`: the third coordinate is the height above the floor.

    Args:
      camera: `CeilingCamera`; depth: [h, w] depths along the optical axis; valid: [h, w].
      row, col: pixel offset of the block in the full image (0 for a full image).

    Returns:
      [h * w, 3] points; invalid pixels give the camera centre (mask them).

    Example:
      >>> pts = back_project(CeilingCamera((0, 0, 3), 70, 70, 40, 30), depth, depth > 0)
    """
    h, w = depth.shape
    dtype = depth.dtype
    j = jnp.arange(w, dtype=dtype) + 0.5 + jnp.asarray(col, dtype)
    i = jnp.arange(h, dtype=dtype) + 0.5 + jnp.asarray(row, dtype)
    jj, ii = jnp.meshgrid(j, i)
    z = jnp.where(valid, depth, 0.0)
    c = jnp.asarray(camera.position, dtype)
    pts = jnp.stack([c[0] + z * (jj - camera.cx) / camera.fx,
                     c[1] - z * (ii - camera.cy) / camera.fy,
                     c[2] - z], -1)
    return pts.reshape(-1, 3)


def ceiling_cloud(camera: CeilingCamera, depth: Array, valid: Array, max_points: int,
                  floor_threshold=0.06, max_height=None) -> tuple[Array, Array]:
    """The tracker's measurement from one depth image: back-projected (`back_project`), the
    floor removed (heights above ``floor_threshold``), and the ``max_points`` highest points
    kept (a humanoid's head and shoulders are its highest points), highest first.

    Args:
      camera: `CeilingCamera`; depth: [H, W] metres (non-finite or <= 0: no return);
      valid: [H, W] bools; max_points: capacity P (static).
      max_height: points higher than this (m) are dropped first (people walking by, whose
        heads and shoulders would otherwise be the highest points); None: no limit.

    Returns:
      ``(points [P, 3], mask [P])``.

    Example:
      >>> pts, mask = ceiling_cloud(camera, depth, depth > 0, 96)
    """
    _checks.check_shape("depth", depth, (None, None), "[H, W] depth image")
    _checks.check_shape("valid", valid, _checks.shape_of(depth), "one flag per pixel")
    if int(max_points) < 1:
        raise ValueError(f"max_points must be >= 1; got {max_points}")
    depth = jnp.asarray(depth)
    valid = jnp.asarray(valid) & jnp.isfinite(depth) & (depth > 0)
    pts = back_project(camera, jnp.where(valid, depth, 0.0), valid)
    mask = valid.reshape(-1) & (pts[:, 2] > floor_threshold)
    if max_height is not None:
        mask = mask & (pts[:, 2] <= max_height)
    P = min(int(max_points), mask.shape[0])
    _, idx = jax.lax.top_k(jnp.where(mask, pts[:, 2], -jnp.inf), P)
    return pts[idx], mask[idx]


# ---------------------------------------------------------------------------------------------
# Point counts


def point_count(points: Array, mask: Array, pose: Array, model: RobotModel = RobotModel()
                ) -> Array:
    r"""Number of points inside the robot model placed at ``pose`` (seed 000, section 3.1.1).

    A point :math:`p = (p_x, p_y, p_z)` counts when, with :math:`d = (p_x - x, p_y - y)` and
    :math:`(u, v) = R(-\theta)\,d` its coordinates along the facing and left axes,

    .. math::
        \underbrace{z_{th} < p_z \le z_{top},\ \|d\| \le r}_{\text{head cylinder}}
        \quad\text{or}\quad
        \underbrace{z_{bot} \le p_z \le z_{th},\ |u| \le h_{depth},\ |v| \le h_{length}}
        _{\text{shoulder cuboid}}.

    Args:
      points: [P, 3] world-frame points (x, y, height).
      mask: [P] bools; masked and non-finite points never count.
      pose: [..., 3] robot poses (x, y, theta); leading axes broadcast (e.g. [N, 3] particles).
      model: `RobotModel` sizes.

    Returns:
      [...] counts, as floats of the points' dtype (exact integers).

    Example:
      >>> n = point_count(points, mask, jnp.array([1.0, 0.5, 0.3]))
    """
    _check_cloud(points, mask)
    _check_pose(pose)
    head, body = _regions(points, mask, pose, model, None)
    return jnp.sum(head + body, -1)


def smooth_point_count(points: Array, mask: Array, pose: Array,
                       model: RobotModel = RobotModel(), softness=0.01) -> Array:
    r"""`point_count` with sigmoid edges: differentiable in the pose and the model sizes.

    Every indicator :math:`1[a \le b]` of `point_count` becomes :math:`\sigma((b - a)/s)` with
    :math:`s` = ``softness`` (metres; the head/body split on height uses the same edge, so a
    point exactly at the threshold counts half in each). Two-sided box edges are products
    :math:`\sigma((h - u)/s)\,\sigma((h + u)/s)`, smooth everywhere. As :math:`s \to 0` the
    count tends to the hard count (points exactly on an edge aside).

    Args:
      points, mask, pose, model: as `point_count`.
      softness: edge width :math:`s > 0` in metres (scalar; may be traced).

    Returns:
      [...] soft counts.

    Example:
      >>> g = jax.grad(lambda p: smooth_point_count(points, mask, p, softness=0.005))(pose)
    """
    _check_cloud(points, mask)
    _check_pose(pose)
    if _checks.is_concrete(softness) and not float(softness) > 0:
        raise ValueError(f"softness must be > 0; got {softness}")
    head, body = _regions(points, mask, pose, model, softness)
    return jnp.sum(head + body, -1)


def log_likelihood(z: DepthFrame, x: Array, model: RobotModel = RobotModel(), *, eps=1.0,
                   temperature=None, softness=None) -> Array:
    r"""Log particle weight from the point count (seed 000, eqs. 1-2).

    The seed's weight is the normalised count, :math:`w^i = n(x^i) / \sum_j n(x^j)`, i.e. the
    count *is* the likelihood up to a constant. The default returns

    .. math:: \log p(y_t | x^i_t) = \log(n(x^i_t) + \epsilon),

    where :math:`\epsilon > 0` (default 1) keeps a particle that sees no point alive with a
    small weight, so a frame with no robot points (occlusion) leaves the weights uniform
    instead of degenerate. With ``temperature`` :math:`T`, the tempered (exponential-family)
    version :math:`n(x^i_t) / T` is returned instead: much sharper (a count difference of
    :math:`T` is a factor e), not the seed's choice.

    Usable directly inside `jaxtrack.filters.particle.step` / ``filter``, with ``z`` a
    `DepthFrame` and ``x`` a particle state (x, y) — the cuboid is then rotated by
    ``z.heading`` — or (x, y, theta).

    Args:
      z: `DepthFrame` (points [P, 3], mask [P], heading scalar).
      x: [..., 2] or [..., 3] particle states; leading axes broadcast (vectorised filters).
      model: `RobotModel`.
      eps: floor added to the count before the log (ignored with ``temperature``).
      temperature: optional :math:`T > 0` for the tempered likelihood.
      softness: optional edge width: use `smooth_point_count` (differentiable in x and model).

    Returns:
      [...] log-likelihoods.

    Example:
      >>> ll = functools.partial(log_likelihood, model=RobotModel())
      >>> res = particle.filter(key, init, frames, transition, ll)
    """
    n = jnp.shape(x)[-1] if jnp.ndim(x) else 0
    if n not in (2, 3):
        raise ValueError(f"x must be [..., 2] (x, y) or [..., 3] (x, y, theta) particle "
                         f"states; got shape {list(jnp.shape(x))}")
    x = jnp.asarray(x)
    if n == 2:
        heading = jnp.broadcast_to(jnp.asarray(z.heading, x.dtype), x.shape[:-1])
        pose = jnp.concatenate([x, heading[..., None]], -1)
    else:
        pose = x
    if softness is None:
        count = point_count(z.points, z.mask, pose, model)
    else:
        count = smooth_point_count(z.points, z.mask, pose, model, softness)
    if temperature is not None:
        return count / temperature
    return jnp.log(count + eps)


# ---------------------------------------------------------------------------------------------
# Orientation


def fold_half_turn(theta: Array, reference) -> Array:
    r"""The heading equal to ``theta`` modulo :math:`\pi` nearest ``reference``.

    The cylinder + cuboid model is symmetric under a half turn, so `point_count` and
    `log_likelihood` cannot tell :math:`\theta` from :math:`\theta + \pi`: the heading
    marginal of an (x, y, theta) particle filter is bimodal and its circular mean meaningless
    once particles have drifted to both modes. Folding every particle to the half-circle
    centred on the previous estimate,

    .. math:: \theta' = \operatorname{wrap}\big(\theta_{ref} +
        \operatorname{wrap}_{\pi}(\theta - \theta_{ref})\big),
        \qquad \operatorname{wrap}_{\pi}(a) \in [-\pi/2, \pi/2),

    leaves every weight unchanged (the likelihood is :math:`\pi`-periodic) and resolves the
    ambiguity by continuity, as the seed's PCA heading does with its window (section 3.1.2).

    Args:
      theta: [...] headings (rad).
      reference: scalar or [...] reference heading(s), broadcast against ``theta``.

    Returns:
      [...] folded headings, wrapped to [-pi, pi).

    Example:
      >>> fold_half_turn(jnp.array([3.0, -0.1]), 0.0)  # [3 - pi, -0.1]
    """
    theta = jnp.asarray(theta)
    reference = jnp.asarray(reference, theta.dtype)
    half = jnp.asarray(0.5 * math.pi, theta.dtype)
    delta = jnp.mod(theta - reference + half, 2.0 * half) - half
    return wrap(reference + delta)


def pca_heading(points: Array, mask: Array, centre: Array, radius, prev_heading, window,
                gain=0.5, *, on_jump: str = "clip", min_points: int = 3,
                min_elongation=0.05) -> PCAHeading:
    r"""Heading from the PCA ellipse of the points around the estimate (seed 000, 3.1.2).

    The points of ``mask`` within ``radius`` of ``centre`` (a window larger than the robot
    model) are projected on the floor. With their covariance
    :math:`\begin{pmatrix} s_{xx} & s_{xy} \\ s_{xy} & s_{yy}\end{pmatrix}`, the major axis
    (the shoulders) is at :math:`\varphi = \tfrac12 \operatorname{atan2}(2 s_{xy},
    s_{xx} - s_{yy})` and the facing direction is the minor axis :math:`\varphi \pm \pi/2`.
    The sign is resolved by taking the candidate closest to :math:`\theta_{t-1}`, at
    :math:`\delta = \operatorname{wrap}_{\pi}(\varphi + \pi/2 - \theta_{t-1}) \in [-\pi/2,
    \pi/2)`. The seed requires :math:`\theta_t \in [\theta_{t-1} - \theta_h,
    \theta_{t-1} + \theta_h]`; beyond the window the innovation is clipped to
    :math:`\pm\theta_h` (``on_jump="clip"``, the literal reading) or dropped
    (``on_jump="keep"``: the previous heading is kept). The result is smoothed on the circle,
    :math:`\theta_t = \operatorname{wrap}(\theta_{t-1} + g\,\delta)` with gain :math:`g`
    (``gain=1``: no smoothing; the seed smooths but prints no factor, 0.5 is ours).

    With fewer than ``min_points`` points, or a nearly round cloud (elongation
    :math:`(\lambda_1 - \lambda_2)/(\lambda_1 + \lambda_2)` below ``min_elongation``, where the
    axis is meaningless), the previous heading is returned.

    Args:
      points: [P, 3] (or [P, 2]) world-frame points; only x, y are used.
      mask: [P] bools; masked and non-finite points are ignored.
      centre: [2] window centre (the particle-filter position estimate).
      radius: window radius in metres (larger than the robot model, e.g. 0.25).
      prev_heading: scalar :math:`\theta_{t-1}`.
      window: :math:`\theta_h`, the largest heading change per frame (rad, e.g. 20 deg).
      gain: smoothing gain :math:`g \in (0, 1]`.
      on_jump: "clip" or "keep", what to do with a fit outside the window.
      min_points: fewest points for a fit (static int).
      min_elongation: smallest elongation for a fit.

    Returns:
      `PCAHeading` (heading, measured, accepted, num_points).

    Example:
      >>> out = pca_heading(points, mask, est[:2], 0.25, theta, jnp.deg2rad(20.0))
      >>> theta = out.heading
    """
    _checks.check_ndim("points", points, 2, "[P, 3] or [P, 2] points")
    if _checks.shape_of(points)[1] not in (2, 3):
        raise ValueError(f"points must be [P, 3] or [P, 2]; got {list(_checks.shape_of(points))}")
    _checks.check_shape("mask", mask, (_checks.shape_of(points)[0],), "one bool per point")
    _checks.check_shape("centre", centre, (2,), "window centre (x, y)")
    _checks.check_options("on_jump", on_jump, ("clip", "keep"))
    for name, value in (("radius", radius), ("window", window), ("gain", gain)):
        _checks.check_finite(name, value)
        if _checks.is_concrete(value) and not float(value) > 0:
            raise ValueError(f"{name} must be > 0; got {value}")
    if _checks.is_concrete(gain) and float(gain) > 1:
        raise ValueError(f"gain must be in (0, 1]; got {gain}")
    _checks.check_finite("prev_heading", prev_heading)

    xy = jnp.asarray(points)[:, :2]
    dtype = xy.dtype
    finite = jnp.all(jnp.isfinite(xy), -1)
    xy = jnp.where(finite[:, None], xy, 0.0)
    centre = jnp.asarray(centre, dtype)
    prev = jnp.asarray(prev_heading, dtype)
    d = xy - centre
    inside = jnp.asarray(mask, bool) & finite & (jnp.sum(d * d, -1) <= radius**2)
    w = inside.astype(dtype)
    num = jnp.sum(w)
    mean = (w @ xy) / jnp.maximum(num, 1.0)
    dev = (xy - mean) * w[:, None]
    sxx = jnp.sum(dev[:, 0] ** 2) / jnp.maximum(num, 1.0)
    syy = jnp.sum(dev[:, 1] ** 2) / jnp.maximum(num, 1.0)
    sxy = jnp.sum(dev[:, 0] * dev[:, 1]) / jnp.maximum(num, 1.0)
    a, b = 2.0 * sxy, sxx - syy
    gap_sq = a * a + b * b
    tiny = jnp.finfo(dtype).tiny
    gap = jnp.sqrt(jnp.where(gap_sq > tiny, gap_sq, 1.0))
    valid = (num >= min_points) & (gap_sq > tiny) & (gap >= min_elongation * (sxx + syy))
    major = 0.5 * jnp.arctan2(jnp.where(valid, a, 0.0), jnp.where(valid, b, 1.0))
    delta = jnp.mod(major + 0.5 * jnp.pi - prev + 0.5 * jnp.pi, jnp.pi) - 0.5 * jnp.pi
    delta = jnp.where(valid, delta, 0.0)
    within = jnp.abs(delta) <= window
    if on_jump == "clip":
        innovation = jnp.clip(delta, -window, window)
    else:
        innovation = jnp.where(within, delta, 0.0)
    return PCAHeading(heading=wrap(prev + gain * innovation), measured=wrap(prev + delta),
                      accepted=valid & within, num_points=num)


# ---------------------------------------------------------------------------------------------
# Private helpers


def _regions(points, mask, pose, model, softness):
    """Per-point head and body membership [..., P] (hard 0/1 or soft), masked."""
    points = jnp.asarray(points)
    pose = jnp.asarray(pose)
    dtype = jnp.result_type(points.dtype, pose.dtype, jnp.float32)
    points = points.astype(dtype)
    pose = pose.astype(dtype)
    valid = jnp.asarray(mask, bool) & jnp.all(jnp.isfinite(points), -1)
    # Zeros in place of invalid points keep NaN out of the values and the gradients.
    points = jnp.where(valid[:, None], points, 0.0)
    d = points[:, :2] - pose[..., None, :2]                         # [..., P, 2]
    uv = geometry.unrotate(pose[..., None, 2], d)
    u, v = uv[..., 0], uv[..., 1]     # along the facing direction, along the robot's left
    dx, dy, z = d[..., 0], d[..., 1], points[:, 2]
    r2 = dx * dx + dy * dy
    m = model
    if softness is None:
        head = (z > m.z_threshold) & (z <= m.head_top) & (r2 <= m.head_radius**2)
        body = ((z >= m.shoulder_bottom) & (z <= m.z_threshold)
                & (jnp.abs(u) <= m.shoulder_half_depth) & (jnp.abs(v) <= m.shoulder_half_length))
        head, body = head.astype(dtype), body.astype(dtype)
    else:
        sig = jax.nn.sigmoid
        soft = softness

        def below(a, b):  # smooth 1[a <= b]
            return sig((b - a) / soft)

        # sqrt with a safe gradient at the centre.
        dist = jnp.where(r2 > 0, jnp.sqrt(jnp.where(r2 > 0, r2, 1.0)), 0.0)
        above_th = below(m.z_threshold, z)
        head = above_th * below(z, m.head_top) * below(dist, m.head_radius)
        body = ((1.0 - above_th) * below(m.shoulder_bottom, z)
                * below(u, m.shoulder_half_depth) * below(-u, m.shoulder_half_depth)
                * below(v, m.shoulder_half_length) * below(-v, m.shoulder_half_length))
    w = valid.astype(dtype)
    return head * w, body * w


def _check_cloud(points, mask):
    _checks.check_ndim("points", points, 2, "[P, 3] world-frame points")
    _checks.check_shape("points", points, (None, 3), "(x, y, height) per point")
    _checks.check_shape("mask", mask, (_checks.shape_of(points)[0],), "one bool per point")


def _check_pose(pose):
    shape = _checks.shape_of(pose)
    if len(shape) < 1 or shape[-1] != 3:
        raise ValueError(f"pose must be [..., 3] (x, y, theta); got shape "
                         f"{list(_checks.shape_of(pose))}")
    _checks.check_finite("pose", pose)
