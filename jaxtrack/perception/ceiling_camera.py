r"""People on the floor seen by a tilted ceiling RGB camera, through the ground-plane homography
(seed 003, section III-C: the AXIS cameras of the lab's ceiling).

Seed 003 detects people in the images of four ceiling cameras (ACF + CNN bounding boxes) and
brings each detection to the map "using a homography to the ground plane (assuming that people
are on the ground)", with a measurement noise of 0.1 m for these cameras in the tracker (0.3 m
for the robot's RGB-D camera, 0.2 m for the laser). This module holds that camera:

- `CeilingCamera` and `look_at`: a pinhole camera (intrinsics, pose, image size, range);
- `ground_homography` / `inverse_ground_homography`, `floor_to_image` / `image_to_floor`: the
  floor plane :math:`z = 0` to pixels and back;
- `project_people`: the bounding boxes of people modelled as upright cylinders, and which of
  them the camera sees (in front, in the image, in range, not hidden by nearer people);
- `visible_among`: whether people at query points would be visible among the others (the
  occlusion test alone, for many queries against the same people);
- `boxes_to_floor`: the seed's measurement, the bottom centre of a box (the feet) on the floor;
- `detect`: a simulated detector with the seed's noise, misses and Poisson clutter, at a fixed
  capacity with a mask.

Conventions. World: x, y on the floor, z up (metres). Camera: x right, y down, z along the
optical axis (OpenCV); ``rotation`` maps world to camera coordinates,
:math:`p_c = R\,(X - c)`. Pixels: :math:`(u, v)` from the image's top-left *corner*, u to
the right, v down (as `jaxtrack.perception.depth.CeilingCamera`: the centre of pixel (i, j) is
at (j + 1/2, i + 1/2)); the image is :math:`[0, W] \times [0, H]`.

Homography. A floor point :math:`X = (x, y, 0)` projects to
:math:`\tilde u \sim K R (X - c) = K R A\,(x, y, 1)^T` with
:math:`A = [e_1\; e_2\; -c]`, so

.. math::  \mathcal{H} = K\,R\,A, \qquad \mathcal{H}^{-1} = A^{-1} R^T K^{-1},\qquad
           A^{-1} = \begin{pmatrix} 1 & 0 & -c_x/c_z \\ 0 & 1 & -c_y/c_z \\
                                    0 & 0 & -1/c_z \end{pmatrix},

and the third homogeneous coordinate of :math:`\mathcal{H}(x, y, 1)^T` is the floor point's
depth along the optical axis (positive in front of the camera). The inverse is written in
closed form (no matrix inversion), which keeps float32 round trips at ~1e-6 m.

All functions are pure, jittable and vmappable (over keys, people or cameras: `CeilingCamera`
is a pytree of arrays); shapes are fixed and counts are masks.

Example:
  >>> cam = look_at((0.0, 0.0, 3.0), (3.0, 0.0, 0.0))
  >>> zs, valid = detect(cam, jax.random.PRNGKey(0), people_xy, heights, radii, mask,
  ...                    capacity=8, p_detect=0.9, clutter_rate=0.2)
"""

from __future__ import annotations

import itertools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import _checks

Array = jax.Array

__all__ = ["CeilingCamera", "Projection", "look_at", "ground_homography",
           "inverse_ground_homography", "floor_to_image", "image_to_floor", "in_footprint",
           "project_people", "visible_among", "boxes_to_floor", "detect"]

# A point nearer than this (m) to the camera's image plane counts as behind it: its projection
# is unbounded.
_NEAR = 0.01


class CeilingCamera(NamedTuple):
    """A pinhole RGB camera mounted high and looking down at the floor at an angle.

    Every field is an array (a pytree leaf), so cameras stack and vmap; build one with
    `look_at`.

    Attributes:
      position: [3] optical centre (x, y, height above the floor), metres; height > 0.
      rotation: [3, 3] world-to-camera rotation :math:`R` (rows: the camera's x right, y down
        and z optical axis in world coordinates), :math:`p_c = R (X - c)`.
      fx, fy: focal lengths (pixels).
      cx, cy: principal point (pixels from the image's top-left corner).
      width, height: image size (pixels).
      max_range: the detector's range (m): people (and clutter) whose floor point is farther
        than this from the optical centre are not detected (too small in the image).
    """

    position: Array
    rotation: Array
    fx: Array
    fy: Array
    cx: Array
    cy: Array
    width: Array
    height: Array
    max_range: Array


class Projection(NamedTuple):
    """People as one camera sees them (`project_people`).

    Attributes:
      boxes: [P, 4] bounding boxes ``(u_min, v_min, u_max, v_max)`` in pixels (zeros for
        people behind the camera).
      feet: [P, 2] the box's bottom centre ``((u_min + u_max) / 2, v_max)``, the seed's feet
        point.
      distance: [P] floor distance (m) from the camera's nadir to the person's axis, the
        occlusion order.
      in_front: [P] every point of the cylinder is in front of the camera.
      in_image: [P] the feet point is in the image and at least ``min_in_image`` of the box is.
      in_range: [P] the feet are within ``max_range`` of the optical centre.
      occlusion: [P] fraction of the box's in-image part covered by the boxes of nearer people
        and by the static occluders.
      visible: [P] masked in, valid, in front, in the image, in range and occluded by at most
        ``max_occlusion``.
    """

    boxes: Array
    feet: Array
    distance: Array
    in_front: Array
    in_image: Array
    in_range: Array
    occlusion: Array
    visible: Array


def look_at(position, target, *, fx=500.0, fy=None, cx=None, cy=None, width=640, height=480,
            max_range=10.0, up=(0.0, 0.0, 1.0), dtype=None) -> CeilingCamera:
    r"""A `CeilingCamera` at ``position`` whose optical axis passes through ``target``.

    The optical axis is :math:`z_c = (t - c) / |t - c|`, the image's x axis (right) is
    :math:`x_c = z_c \times up` normalised (horizontal for the default ``up``), and
    :math:`y_c = z_c \times x_c` (image down). For an axis parallel to ``up`` (a camera looking
    straight down) the image's top is turned towards world +y instead.

    The default intrinsics (640 x 480 pixels, 500 px focal length: a 65 deg x 51 deg field of
    view, and a 10 m range) are ours: the seed does not give the AXIS P1344 calibration.

    Args:
      position: [3] optical centre; its height (third coordinate) must be > 0.
      target: [3] a point on the optical axis (often on the floor, z = 0).
      fx, fy: focal lengths in pixels (``fy`` defaults to ``fx``).
      cx, cy: principal point (defaults: the image centre).
      width, height: image size in pixels.
      max_range: detection range in metres (finite, > 0).
      up: [3] the world's up direction for the image's horizon.
      dtype: float dtype of the fields (default: float32, or the inputs' float64).

    Returns:
      A `CeilingCamera`.

    Example:
      >>> cam = look_at((0.0, 0.0, 3.0), (3.0, 0.0, 0.0), fx=600.0, width=800, height=600)
    """
    if dtype is None:
        dtype = _float_dtype(position, target)
    _checks.check_shape("position", position, (3,), "optical centre (x, y, z)")
    _checks.check_shape("target", target, (3,), "a point on the optical axis")
    _checks.check_shape("up", up, (3,), "the world's up direction")
    fy = fx if fy is None else fy
    cx = width / 2 if cx is None else cx
    cy = height / 2 if cy is None else cy
    _check_intrinsics(fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height,
                      max_range=max_range)
    if _checks.is_concrete(position) and _checks.is_concrete(target):
        p, t = np.asarray(position, np.float64), np.asarray(target, np.float64)
        _checks.check_finite("position", p)
        _checks.check_finite("target", t)
        if not p[2] > 0:
            raise ValueError(f"position must be above the floor (z > 0); got {p.tolist()}")
        if not np.linalg.norm(t - p) > 0:
            raise ValueError("target must differ from position")
    scalar = lambda a: jnp.asarray(a, dtype)  # noqa: E731
    c = jnp.asarray(position, dtype)
    return CeilingCamera(c, _look_at_rotation(c, jnp.asarray(target, dtype),
                                              jnp.asarray(up, dtype)),
                         scalar(fx), scalar(fy), scalar(cx), scalar(cy), scalar(width),
                         scalar(height), scalar(max_range))


@jax.jit
def _look_at_rotation(c, target, up):
    dtype = c.dtype
    axis = target - c
    z_c = axis / jnp.linalg.norm(axis)
    right = jnp.cross(z_c, up)
    # Looking along ``up``: no horizon to level the image on; put world +y at the image's top.
    fallback = jnp.cross(z_c, jnp.asarray((0.0, 1.0, 0.0), dtype))
    fallback = jnp.where(jnp.linalg.norm(fallback) > 1e-6, fallback,
                         jnp.cross(z_c, jnp.asarray((1.0, 0.0, 0.0), dtype)))
    right = jnp.where(jnp.linalg.norm(right) > 1e-6, right, fallback)
    x_c = right / jnp.linalg.norm(right)
    y_c = jnp.cross(z_c, x_c)
    return jnp.stack([x_c, y_c, z_c])


def ground_homography(camera: CeilingCamera) -> Array:
    r"""[3, 3] homography :math:`\mathcal{H} = K R A` from floor points :math:`(x, y, 1)` to
    homogeneous pixels (module docstring); the third coordinate is the depth along the optical
    axis.

    Example:
      >>> uv = floor_to_image(ground_homography(cam), xy)
    """
    _check_camera(camera)
    return _homography_jit(camera)


def inverse_ground_homography(camera: CeilingCamera) -> Array:
    r"""[3, 3] :math:`\mathcal{H}^{-1} = A^{-1} R^T K^{-1}` (closed form), from homogeneous
    pixels to floor points: the ray through the pixel meets the floor where the third
    coordinate is positive; a pixel above the horizon gives a negative one (the ray goes up).

    Example:
      >>> xy = image_to_floor(inverse_ground_homography(cam), uv)
    """
    _check_camera(camera)
    return _inverse_homography_jit(camera)


def floor_to_image(H: Array, xy: Array) -> Array:
    r"""Pixels [N, 2] of floor points xy [N, 2]: :math:`(u, v) = (p_0 / p_2, p_1 / p_2)`,
    :math:`p = \mathcal{H} (x, y, 1)^T`.

    Points behind the camera (:math:`p_2 \le 0`) get a meaningless pixel; `in_footprint` says
    which points are seen.

    Example:
      >>> uv = floor_to_image(ground_homography(cam), jnp.array([[3.0, 0.0]]))
    """
    _checks.check_shape("H", H, (3, 3), "a homography")
    _checks.check_shape("xy", xy, (None, 2), "[N, 2] floor points")
    return _apply_jit(H, xy)


def image_to_floor(H_inv: Array, uv: Array) -> Array:
    r"""Floor points [N, 2] of pixels uv [N, 2]: :math:`p = \mathcal{H}^{-1} (u, v, 1)^T`,
    :math:`(x, y) = (p_0 / p_2, p_1 / p_2)`.

    Pixels above the horizon (:math:`p_2 < 0`) give the point where the ray's backward
    extension meets the floor, behind the camera.

    Example:
      >>> xy = image_to_floor(inverse_ground_homography(cam), jnp.array([[320.0, 400.0]]))
    """
    _checks.check_shape("H_inv", H_inv, (3, 3), "an inverse homography")
    _checks.check_shape("uv", uv, (None, 2), "[N, 2] pixels")
    return _apply_jit(H_inv, uv)


def in_footprint(camera: CeilingCamera, xy: Array) -> Array:
    """[N] bools: floor points xy [N, 2] the camera sees (in front of it, inside the image and
    within ``max_range`` of its optical centre). Clutter of `detect` is uniform on this set.

    Example:
      >>> seen = in_footprint(cam, jnp.array([[3.0, 0.0], [-3.0, 0.0]]))   # [True, False]
    """
    _check_camera(camera)
    _checks.check_shape("xy", xy, (None, 2), "[N, 2] floor points")
    dtype = _float_dtype(xy)
    return _in_footprint_jit(_cast(camera, dtype), jnp.asarray(xy, dtype))


def project_people(camera: CeilingCamera, people_xy: Array, heights: Array, radii: Array,
                   mask: Array, *, occluders: Array | None = None, max_occlusion=0.5,
                   min_in_image=0.5, rim_points: int = 32,
                   occlusion_grid: int = 8) -> Projection:
    r"""Bounding boxes of people (upright cylinders standing on the floor) and their visibility.

    A person is a cylinder of radius ``r`` from the floor to height ``h`` around its floor
    point; its box is the bounding box of the projections of ``rim_points`` points on each of
    its bottom and top circles (the box of the cylinder's silhouette, to
    :math:`r (1 - \cos(\pi / N))` on each side).

    Occlusion: person *j* hides part of person *i* when *j* is nearer to the camera's nadir
    (on the floor) and in front of the camera; the covered fraction of *i*'s box (its part in
    the image) is measured on an ``occlusion_grid`` x ``occlusion_grid`` grid of cell centres,
    covered when inside any nearer person's box or any static occluder box. *i* is hidden when
    more than ``max_occlusion`` of it is covered (a box detector then misses it).

    Args:
      camera: `CeilingCamera`.
      people_xy: [P, 2] floor positions (P may be 0).
      heights: [P] heights (m, > 0); radii: [P] cylinder radii (m, >= 0).
      mask: [P] bools, present people; masked people neither are seen nor hide others
        (their values may be anything, NaN included).
      occluders: optional [O, 4] static pixel boxes ``(u_min, v_min, u_max, v_max)`` in front
        of everyone (a pillar, a shelf in this camera's image).
      max_occlusion: largest covered fraction of a visible box, in [0, 1].
      min_in_image: smallest fraction of the box inside the image, in [0, 1].
      rim_points: points per circle of the cylinder (static).
      occlusion_grid: samples per side of the occlusion grid (static).

    Returns:
      A `Projection`.

    Example:
      >>> proj = project_people(cam, jnp.array([[3.0, 0.0], [4.0, 0.0]]),
      ...                       jnp.array([1.8, 1.8]), jnp.array([0.25, 0.25]),
      ...                       jnp.array([True, True]))
      >>> proj.visible    # [True, False]: the second person is behind the first
    """
    P, dtype = _check_people(camera, people_xy, heights, radii, mask)
    occluders = _check_occluders(occluders, dtype)
    _check_fraction("max_occlusion", max_occlusion)
    _check_fraction("min_in_image", min_in_image)
    for name, value in (("rim_points", rim_points), ("occlusion_grid", occlusion_grid)):
        _check_count(name, value, 3 if name == "rim_points" else 1)
    return _project_jit(_cast(camera, dtype), jnp.asarray(people_xy, dtype),
                        jnp.asarray(heights, dtype), jnp.asarray(radii, dtype),
                        jnp.asarray(mask, bool), occluders, jnp.asarray(max_occlusion, dtype),
                        jnp.asarray(min_in_image, dtype), rim_points, occlusion_grid)


def visible_among(camera: CeilingCamera, query_xy: Array, query_heights: Array,
                  query_radii: Array, people_xy: Array, heights: Array, radii: Array,
                  may_occlude: Array, *, occluders: Array | None = None, max_occlusion=0.5,
                  min_in_image=0.5, rim_points: int = 32, occlusion_grid: int = 8) -> Array:
    r"""Whether a person at each query point would be visible among other people ([Q] bools).

    Query *q* is visible when `project_people` of the people plus *q* alone, with the people
    masked by ``may_occlude[q]``, finds *q* visible: in front of the camera, in its image
    (``min_in_image``) and range, and covered by at most ``max_occlusion`` by the boxes of the
    allowed people nearer the nadir and by the static ``occluders``. The people's boxes are
    projected once for all queries, and only the queries' occlusion is measured, instead of
    one `project_people` of P + 1 people (and their P^2 occlusion tests) per query.

    Args:
      camera: `CeilingCamera`.
      query_xy: [Q, 2] floor points; query_heights, query_radii: [Q] their cylinders.
      people_xy, heights, radii: [P, 2], [P], [P] the people who may hide the queries.
      may_occlude: [Q, P] bools, the people that may hide each query (e.g. not the track on
        the query itself); a person no row allows is not projected.
      occluders, max_occlusion, min_in_image, rim_points, occlusion_grid: `project_people`.

    Returns:
      [Q] bools (Q = 0: an empty array).

    Example:
      >>> seen = visible_among(cam, jnp.array([[4.0, 0.0]]), jnp.array([1.7]),
      ...                      jnp.array([0.25]), jnp.array([[3.0, 0.0]]), jnp.array([1.8]),
      ...                      jnp.array([0.25]), jnp.array([[True]]))     # [False]: hidden
    """
    _checks.check_shape("query_xy", query_xy, (None, 2), "[Q, 2] floor points")
    _checks.check_shape("people_xy", people_xy, (None, 2), "[P, 2] floor positions")
    Q, P = _checks.shape_of(query_xy)[0], _checks.shape_of(people_xy)[0]
    _checks.check_shape("may_occlude", may_occlude, (Q, P), "[Q, P] bools")
    if _dtype_of(may_occlude) != np.bool_:
        raise TypeError(f"may_occlude must hold bools; got dtype {_dtype_of(may_occlude)}")
    _checks.check_finite("query_xy", query_xy)     # (under jit such a query is not visible)
    _, dtype = _check_people(camera, query_xy, query_heights, query_radii, np.ones(Q, bool))
    # only the people some query allows are checked (the others may hold anything)
    _check_people(camera, people_xy, heights, radii, jnp.any(jnp.asarray(may_occlude), 0))
    occluders = _check_occluders(occluders, dtype)
    _check_fraction("max_occlusion", max_occlusion)
    _check_fraction("min_in_image", min_in_image)
    _check_count("rim_points", rim_points, 3)
    _check_count("occlusion_grid", occlusion_grid, 1)
    cast = lambda a: jnp.asarray(a, dtype)  # noqa: E731
    return _visible_among_jit(_cast(camera, dtype), cast(query_xy), cast(query_heights),
                              cast(query_radii), cast(people_xy), cast(heights), cast(radii),
                              jnp.asarray(may_occlude, bool), occluders,
                              cast(max_occlusion), cast(min_in_image), rim_points,
                              occlusion_grid)


def boxes_to_floor(camera: CeilingCamera, boxes: Array, feet_offset=0.0, *,
                   upright: bool = False) -> Array:
    r"""Floor positions [N, 2] of people from their boxes [N, 4] (seed 003's measurement).

    The box's bottom centre :math:`((u_{min} + u_{max}) / 2, v_{max})` is taken as the feet on
    the floor and mapped by :math:`\mathcal{H}^{-1}` (`image_to_floor`), then moved
    ``feet_offset`` metres away from the camera's nadir, along the floor.

    Two biases of the seed's bottom centre, both systematic:

    - the bottom of a person's box is the image of the *nearest* rim of the feet, so the plain
      homography (``feet_offset=0``) places a person about one body radius nearer the camera
      than their centre; a calibrated ``feet_offset`` (a typical body radius) removes most of
      it;
    - under a tilted camera, vertical lines converge to the image of the nadir direction
      :math:`v_\downarrow \sim -K R e_z`, so a person off the image's centre column leans and
      the box's bottom centre is beside the feet (0.2 m for a person 1 m off the axis 4 m away
      under a camera 3 m high). ``upright=True`` takes the feet on the line from the box centre
      to :math:`v_\downarrow` instead, at the box's bottom edge.

    Args:
      camera: `CeilingCamera`.
      boxes: [N, 4] pixel boxes ``(u_min, v_min, u_max, v_max)``.
      feet_offset: metres added along the floor direction away from the nadir.
      upright: correct the lean of tilted views (static); False is the seed's bottom centre.

    Returns:
      [N, 2] floor points.

    Example:
      >>> xy = boxes_to_floor(cam, jnp.array([[300.0, 120.0, 340.0, 260.0]]), feet_offset=0.2)
    """
    _check_camera(camera)
    _checks.check_shape("boxes", boxes, (None, 4), "[N, 4] (u_min, v_min, u_max, v_max)")
    _check_real("feet_offset", feet_offset)
    dtype = _float_dtype(boxes)
    return _boxes_to_floor_jit(_cast(camera, dtype), jnp.asarray(boxes, dtype),
                               jnp.asarray(feet_offset, dtype), bool(upright))


def detect(camera: CeilingCamera, key: Array, people_xy: Array, heights: Array, radii: Array,
           mask: Array, *, capacity: int, sigma=0.1, p_detect=0.9, clutter_rate=0.0,
           feet_offset=0.0, upright: bool = False, occluders: Array | None = None,
           max_occlusion=0.5, min_in_image=0.5,
           clutter_candidates: int | None = None) -> tuple[Array, Array]:
    r"""Simulated person detections of one ceiling camera, on the floor (seed 003).

    1. `project_people`: boxes and visibility;
    2. each visible person is detected with probability ``p_detect`` (independently);
    3. a detection is the box's feet point on the floor (`boxes_to_floor`) plus isotropic
       Gaussian noise :math:`\mathcal{N}(0, \sigma^2 I_2)` *in the floor frame*:
       :math:`z = \mathcal{H}^{-1}(u_{feet}) + \delta\,\hat e + \epsilon`, with
       :math:`\delta` = ``feet_offset`` and :math:`\hat e` the floor direction away from the
       camera's nadir;
    4. clutter: :math:`N_c \sim \mathrm{Poisson}(\lambda)` false detections (``clutter_rate``
       per frame) uniform on the camera's floor footprint (`in_footprint`), :math:`N_c` capped
       at ``capacity``.

    The seed's 0.1 m for the ceiling cameras is the detection noise it set in the tracker, in
    map coordinates, so the noise is added on the floor (a fixed pixel noise would instead grow
    with the distance to the camera; the seed does not model that). The systematic feet biases
    of step 3 (`boxes_to_floor`) come on top; with ``feet_offset`` set to the body radius and
    ``upright=True`` they stay within a few centimetres.

    Slots: the people's detections first, in person order, then the clutter; beyond
    ``capacity`` the last ones are dropped. Clutter positions are drawn by rejection from
    ``clutter_candidates`` uniform points in the footprint's bounding box (clipped to the
    range), so :math:`N_c` is also truncated to the number of accepted candidates (unlikely to
    bind with the default, 8 per slot).

    Gradients flow from ``zs`` to the people's positions and the camera through the feet
    point; visibility, misses and clutter are hard (masks).

    Args:
      camera: `CeilingCamera`.
      key: a `jax.random` key.
      people_xy, heights, radii, mask: the people (`project_people`).
      capacity: number of detection slots (static, >= 1).
      sigma: noise standard deviation on the floor (m), seed 003: 0.1.
      p_detect: detection probability of a visible person, in [0, 1].
      clutter_rate: expected number of clutter detections per frame (>= 0).
      feet_offset, upright: `boxes_to_floor`'s corrections; 0 and False are the seed's plain
        homography of the bottom centre.
      occluders, max_occlusion, min_in_image: as in `project_people`.
      clutter_candidates: uniform candidates for the clutter (static; default 8 x capacity).

    Returns:
      ``(zs [capacity, 2], valid [capacity])``: floor detections (zeros where not valid).

    Example:
      >>> cam = look_at((0.0, 0.0, 3.0), (3.0, 0.0, 0.0))
      >>> zs, valid = detect(cam, jax.random.PRNGKey(0), xy, heights, radii, mask, capacity=8,
      ...                    p_detect=0.9, clutter_rate=0.5)
    """
    P, dtype = _check_people(camera, people_xy, heights, radii, mask)
    occluders = _check_occluders(occluders, dtype)
    _check_key(key)
    _check_count("capacity", capacity, 1)
    candidates = 8 * capacity if clutter_candidates is None else clutter_candidates
    _check_count("clutter_candidates", candidates, 1)
    _check_fraction("p_detect", p_detect)
    _check_fraction("max_occlusion", max_occlusion)
    _check_fraction("min_in_image", min_in_image)
    _check_real("sigma", sigma, minimum=0.0)
    _check_real("clutter_rate", clutter_rate, minimum=0.0)
    _check_real("feet_offset", feet_offset)
    cast = lambda a: jnp.asarray(a, dtype)  # noqa: E731
    return _detect_jit(_cast(camera, dtype), key, cast(people_xy), cast(heights), cast(radii),
                       jnp.asarray(mask, bool), occluders, cast(sigma), cast(p_detect),
                       cast(clutter_rate), cast(feet_offset), cast(max_occlusion),
                       cast(min_in_image), capacity, candidates, bool(upright))


# ---------------------------------------------------------------------------------------------
# Traced implementation


def _intrinsic_matrix(camera):
    zero, one = jnp.zeros_like(camera.fx), jnp.ones_like(camera.fx)
    return jnp.stack([jnp.stack([camera.fx, zero, camera.cx]),
                      jnp.stack([zero, camera.fy, camera.cy]),
                      jnp.stack([zero, zero, one])])


def _homography(camera):
    c = camera.position
    zero, one = jnp.zeros_like(c[0]), jnp.ones_like(c[0])
    A = jnp.stack([jnp.stack([one, zero, -c[0]]), jnp.stack([zero, one, -c[1]]),
                   jnp.stack([zero, zero, -c[2]])])
    return _intrinsic_matrix(camera) @ camera.rotation @ A


def _inverse_homography(camera):
    c = camera.position
    zero, one = jnp.zeros_like(c[0]), jnp.ones_like(c[0])
    A_inv = jnp.stack([jnp.stack([one, zero, -c[0] / c[2]]),
                       jnp.stack([zero, one, -c[1] / c[2]]),
                       jnp.stack([zero, zero, -one / c[2]])])
    K_inv = jnp.stack([jnp.stack([one / camera.fx, zero, -camera.cx / camera.fx]),
                       jnp.stack([zero, one / camera.fy, -camera.cy / camera.fy]),
                       jnp.stack([zero, zero, one])])
    return A_inv @ camera.rotation.T @ K_inv


def _apply(H, pts):
    dtype = jnp.promote_types(jnp.result_type(H, pts), jnp.float32)
    H, pts = jnp.asarray(H, dtype), jnp.asarray(pts, dtype)
    p = pts @ H[:, :2].T + H[:, 2]
    w = p[:, 2:]
    w = jnp.where(jnp.abs(w) > jnp.finfo(dtype).tiny, w, jnp.finfo(dtype).tiny)
    return p[:, :2] / w


_homography_jit = jax.jit(_homography)
_inverse_homography_jit = jax.jit(_inverse_homography)
_apply_jit = jax.jit(_apply)


def _project_points(camera, X):
    """Pixels [..., 2] and depths [...] of world points X [..., 3].

    The rotation :math:`p_c = R (X - c)` is written out as three sums of three products
    rather than a matrix product: XLA:CPU runs a [..., 3] x [3, 3] product as a library call
    that neither vectorises its 3-long axes nor fuses with what follows (the service scene's
    four cameras spent 9 % of a frame there); the sums fuse into the projection's loop."""
    d = X - camera.position
    R = camera.rotation

    def row(i):
        return d[..., 0] * R[i, 0] + d[..., 1] * R[i, 1] + d[..., 2] * R[i, 2]

    x, y, z = row(0), row(1), row(2)
    z_safe = jnp.where(z > _NEAR, z, 1.0)
    uv = jnp.stack([camera.fx * x / z_safe + camera.cx, camera.fy * y / z_safe + camera.cy], -1)
    return uv, z


def _inside_image(camera, uv):
    return ((uv[..., 0] >= 0) & (uv[..., 0] <= camera.width) & (uv[..., 1] >= 0)
            & (uv[..., 1] <= camera.height))


def _in_footprint(camera, xy):
    X = jnp.concatenate([xy, jnp.zeros_like(xy[:, :1])], -1)
    uv, z = _project_points(camera, X)
    rng = jnp.sqrt(jnp.sum((X - camera.position) ** 2, -1))
    return (z > _NEAR) & _inside_image(camera, uv) & (rng <= camera.max_range)


_in_footprint_jit = jax.jit(_in_footprint)


def _boxes(camera, xy, heights, radii, mask, min_in_image, rim_points):
    """The per-person part of `_project`: (ok, boxes, feet, distance, in_front, in_image,
    in_range, clipped boxes)."""
    dtype = xy.dtype
    ok = (mask & jnp.all(jnp.isfinite(xy), -1) & jnp.isfinite(heights) & (heights > 0)
          & jnp.isfinite(radii) & (radii >= 0))
    xy = jnp.where(ok[:, None], xy, 0.0)
    heights = jnp.where(ok, heights, 1.0)
    radii = jnp.where(ok, radii, 0.0)
    angle = 2 * math.pi * jnp.arange(rim_points, dtype=dtype) / rim_points
    circle = jnp.stack([jnp.cos(angle), jnp.sin(angle)], -1)              # [N, 2]
    rim = xy[:, None] + radii[:, None, None] * circle                     # [P, N, 2]
    bottom = jnp.concatenate([rim, jnp.zeros_like(rim[..., :1])], -1)
    top = jnp.concatenate([rim, jnp.broadcast_to(heights[:, None, None], rim[..., :1].shape)],
                          -1)
    uv, z = _project_points(camera, jnp.concatenate([bottom, top], 1))   # [P, 2N, 2], [P, 2N]
    in_front = ok & jnp.all(z > _NEAR, -1)
    boxes = jnp.concatenate([jnp.min(uv, 1), jnp.max(uv, 1)], -1)
    boxes = jnp.where(in_front[:, None], boxes, 0.0)
    feet = jnp.stack([0.5 * (boxes[:, 0] + boxes[:, 2]), boxes[:, 3]], -1)
    distance = jnp.sqrt(jnp.sum((xy - camera.position[:2]) ** 2, -1))
    in_range = jnp.sqrt(distance**2 + camera.position[2] ** 2) <= camera.max_range

    W, H = camera.width, camera.height
    clipped = jnp.stack([jnp.clip(boxes[:, 0], 0, W), jnp.clip(boxes[:, 1], 0, H),
                         jnp.clip(boxes[:, 2], 0, W), jnp.clip(boxes[:, 3], 0, H)], -1)
    area = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    area_in = (clipped[:, 2] - clipped[:, 0]) * (clipped[:, 3] - clipped[:, 1])
    enough = area_in >= min_in_image * area
    in_image = in_front & _inside_image(camera, feet) & enough & (area_in > 0)
    return ok, boxes, feet, distance, in_front, in_image, in_range, clipped


def _occlusion(clipped, distance, boxes, in_front, occluder_distance, may_occlude, occluders,
               grid):
    """[Q] covered fractions of the clipped boxes [Q, 4] at floor distances [Q] by the boxes
    [P, 4] nearer the nadir (``occluder_distance`` [P]) that are in front and allowed
    (``may_occlude`` [Q, P]), and by the static occluders [O, 4]."""
    dtype = clipped.dtype
    # cell centres of each box, covered by a nearer person or an occluder
    t = (jnp.arange(grid, dtype=dtype) + 0.5) / grid
    su = clipped[:, 0, None] + t * (clipped[:, 2] - clipped[:, 0])[:, None]     # [Q, G]
    sv = clipped[:, 1, None] + t * (clipped[:, 3] - clipped[:, 1])[:, None]
    su = jnp.broadcast_to(su[:, :, None], su.shape + (grid,)).reshape(-1, grid * grid)
    sv = jnp.broadcast_to(sv[:, None, :], sv.shape[:1] + (grid, grid)).reshape(-1, grid * grid)

    def inside(b, u, v):  # boxes [B, 4], samples [Q, S] -> [Q, B, S]
        return ((u[:, None] >= b[None, :, 0, None]) & (u[:, None] <= b[None, :, 2, None])
                & (v[:, None] >= b[None, :, 1, None]) & (v[:, None] <= b[None, :, 3, None]))

    nearer = may_occlude & in_front[None, :] & (occluder_distance[None, :] < distance[:, None])
    covered = jnp.any(nearer[:, :, None] & inside(boxes, su, sv), 1)
    covered = covered | jnp.any(inside(occluders, su, sv), 1)
    return jnp.mean(covered.astype(dtype), -1)


def _project(camera, xy, heights, radii, mask, occluders, max_occlusion, min_in_image,
             rim_points, grid):
    _, boxes, feet, distance, in_front, in_image, in_range, clipped = _boxes(
        camera, xy, heights, radii, mask, min_in_image, rim_points)
    everyone = jnp.ones((xy.shape[0], xy.shape[0]), bool)
    occlusion = _occlusion(clipped, distance, boxes, in_front, distance, everyone, occluders,
                           grid)
    visible = in_front & in_image & in_range & (occlusion <= max_occlusion)
    return Projection(boxes, feet, distance, in_front, in_image, in_range, occlusion, visible)


def _visible_among(camera, query_xy, query_heights, query_radii, xy, heights, radii,
                   may_occlude, occluders, max_occlusion, min_in_image, rim_points, grid):
    _, q_boxes, _, q_distance, q_front, q_image, q_range, q_clipped = _boxes(
        camera, query_xy, query_heights, query_radii, jnp.ones(query_xy.shape[0], bool),
        min_in_image, rim_points)
    ok, boxes, _, distance, in_front, _, _, _ = _boxes(
        camera, xy, heights, radii, jnp.any(may_occlude, 0), min_in_image, rim_points)
    occlusion = _occlusion(q_clipped, q_distance, boxes, in_front, distance, may_occlude & ok,
                           occluders, grid)
    return q_front & q_image & q_range & (occlusion <= max_occlusion)


_visible_among_jit = jax.jit(_visible_among, static_argnames=("rim_points", "grid"))


_project_jit = jax.jit(_project, static_argnames=("rim_points", "grid"))


def _feet_pixels(camera, boxes, upright):
    """[N, 2] feet points of boxes [N, 4]: the bottom centre, or with ``upright`` the point of
    the bottom edge on the line from the box centre to the nadir's vanishing point."""
    bottom = jnp.stack([0.5 * (boxes[:, 0] + boxes[:, 2]), boxes[:, 3]], -1)
    if not upright:
        return bottom
    down = -_intrinsic_matrix(camera) @ camera.rotation[:, 2]      # image of the direction -z
    centre = jnp.stack([0.5 * (boxes[:, 0] + boxes[:, 2]), 0.5 * (boxes[:, 1] + boxes[:, 3]),
                        jnp.ones_like(boxes[:, 0])], -1)
    axis = jnp.cross(centre, down)
    edge = jnp.stack([jnp.zeros_like(boxes[:, 3]), jnp.ones_like(boxes[:, 3]), -boxes[:, 3]], -1)
    p = jnp.cross(axis, edge)
    ok = jnp.abs(p[:, 2]) > 1e-9 * jnp.max(jnp.abs(p), -1)
    u = p[:, 0] / jnp.where(ok, p[:, 2], 1.0)
    return jnp.stack([jnp.where(ok & jnp.isfinite(u), u, bottom[:, 0]), bottom[:, 1]], -1)


def _boxes_to_floor(camera, boxes, feet_offset, upright):
    feet = _feet_pixels(camera, boxes, upright)
    xy = _apply(_inverse_homography(camera), feet)
    away = xy - camera.position[:2]
    norm = jnp.sqrt(jnp.sum(away**2, -1, keepdims=True))
    unit = jnp.where(norm > 0, away / jnp.where(norm > 0, norm, 1.0), 0.0)
    return xy + feet_offset * unit


_boxes_to_floor_jit = jax.jit(_boxes_to_floor, static_argnames=("upright",))


# The pairs of the nine half-planes whose intersections are the footprint polygon's vertices.
_PAIRS = np.array(list(itertools.combinations(range(9), 2)))


def _footprint_box(camera):
    """Bounding box ``(lo [2], hi [2], nonempty)`` of the floor footprint: the polygon cut by
    the four image edges, the front half-space and the range square around the nadir; its
    vertices are the feasible pairwise intersections of those nine lines."""
    dtype = camera.position.dtype
    H = _homography(camera)
    c = camera.position
    reach = jnp.sqrt(jnp.maximum(camera.max_range**2 - c[2] ** 2, 0.0))
    one, zero = jnp.ones_like(reach), jnp.zeros_like(reach)
    lines = jnp.stack([H[0], camera.width * H[2] - H[0], H[1], camera.height * H[2] - H[1],
                       H[2] - jnp.stack([zero, zero, _NEAR * one]),
                       jnp.stack([one, zero, reach - c[0]]),
                       jnp.stack([-one, zero, reach + c[0]]),
                       jnp.stack([zero, one, reach - c[1]]),
                       jnp.stack([zero, -one, reach + c[1]])])
    # Scaled so that a line's value is a signed floor distance (m).
    scale = jnp.sqrt(jnp.sum(lines[:, :2] ** 2, -1, keepdims=True))
    lines = lines / jnp.where(scale > 1e-12, scale, 1.0)
    p = jnp.cross(lines[_PAIRS[:, 0]], lines[_PAIRS[:, 1]])
    finite = jnp.abs(p[:, 2]) > 1e-9
    vertex = p[:, :2] / jnp.where(finite, p[:, 2], 1.0)[:, None]
    value = vertex @ lines[:, :2].T + lines[:, 2]
    tol = 1e-3 if dtype == jnp.float32 else 1e-8
    feasible = finite & jnp.all(value >= -tol * (1.0 + jnp.abs(reach)), -1)
    big = jnp.asarray(jnp.finfo(dtype).max, dtype)
    lo = jnp.min(jnp.where(feasible[:, None], vertex, big), 0)
    hi = jnp.max(jnp.where(feasible[:, None], vertex, -big), 0)
    nonempty = jnp.any(feasible)
    return jnp.where(nonempty, lo, c[:2]), jnp.where(nonempty, hi, c[:2]), nonempty


def _detect(camera, key, xy, heights, radii, mask, occluders, sigma, p_detect, clutter_rate,
            feet_offset, max_occlusion, min_in_image, capacity, candidates, upright):
    dtype = xy.dtype
    P = xy.shape[0]
    # One draw for everything (each random call site compiles its own threefry): per person
    # two uniforms for the Box-Muller noise and one for the miss, then the clutter count and
    # the candidates.
    u = jax.random.uniform(key, (3 * P + 1 + 2 * candidates,), dtype)
    u_radius, u_angle, u_miss = u[:P], u[P:2 * P], u[2 * P:3 * P]
    proj = _project(camera, xy, heights, radii, mask, occluders, max_occlusion, min_in_image,
                    32, 8)
    people = _boxes_to_floor(camera, proj.boxes, feet_offset, upright)
    radius = jnp.sqrt(-2.0 * jnp.log1p(-u_radius))
    angle = 2 * math.pi * u_angle
    people = people + sigma * radius[:, None] * jnp.stack([jnp.cos(angle), jnp.sin(angle)], -1)
    detected = proj.visible & (u_miss < p_detect)

    lo, hi, nonempty = _footprint_box(camera)
    clutter = lo + (hi - lo) * u[3 * P + 1:].reshape(candidates, 2)
    accepted = nonempty & _in_footprint(camera, clutter)
    count = _poisson_capped(u[3 * P], clutter_rate, capacity)
    rank = jnp.cumsum(accepted) - 1
    kept = accepted & (rank < count)

    zs = jnp.concatenate([people, clutter])
    valid = jnp.concatenate([detected, kept])
    order = jnp.argsort(~valid, stable=True)[:capacity]
    zs, valid = zs[order], valid[order]
    return jnp.where(valid[:, None], zs, 0.0), valid


def _poisson_capped(u, rate, cap):
    """min(N, cap) for N ~ Poisson(rate), by inverting the CDF over 0..cap (at most ``cap``
    clutter detections fit in the slots anyway; a fixed-size sum also compiles far faster than
    `jax.random.poisson`'s rejection loop); ``u`` is a uniform draw."""
    k = jnp.arange(cap, dtype=rate.dtype)
    log_pmf = k * jnp.log(jnp.maximum(rate, jnp.finfo(rate.dtype).tiny)) - rate \
        - jax.scipy.special.gammaln(k + 1)
    cdf = jnp.cumsum(jnp.where(rate > 0, jnp.exp(log_pmf), (k == 0).astype(rate.dtype)))
    return jnp.sum(u >= cdf)


_detect_jit = jax.jit(_detect, static_argnames=("capacity", "candidates", "upright"))


# ---------------------------------------------------------------------------------------------
# Input checks (outside jit; values only when concrete)


def _float_dtype(*arrays):
    """float64 if any input array is float64 (and x64 is on), else float32: Python numbers and
    lists, as JAX's default, do not promote."""
    wide = any(getattr(a, "dtype", None) == np.float64 for a in arrays)
    return jnp.dtype(jnp.float64) if wide and jax.config.jax_enable_x64 else jnp.dtype(jnp.float32)


def _dtype_of(x):
    return x.dtype if hasattr(x, "dtype") else np.asarray(x).dtype


def _cast(camera, dtype):
    return CeilingCamera(*(jnp.asarray(f, dtype) for f in camera))


def _check_camera(camera):
    if not isinstance(camera, CeilingCamera):
        raise TypeError(f"camera must be a CeilingCamera (see look_at); got "
                        f"{type(camera).__name__}")
    _checks.check_shape("camera.position", camera.position, (3,), "optical centre")
    _checks.check_shape("camera.rotation", camera.rotation, (3, 3), "world-to-camera rotation")
    for name in ("fx", "fy", "cx", "cy", "width", "height", "max_range"):
        _checks.check_shape(f"camera.{name}", getattr(camera, name), (), "a scalar")
    if _checks.is_concrete(camera.position) and not float(np.asarray(camera.position)[2]) > 0:
        raise ValueError(f"camera.position must be above the floor (z > 0); got "
                         f"{np.asarray(camera.position).tolist()}")
    _check_intrinsics(**{f"camera.{n}": getattr(camera, n)
                         for n in ("fx", "fy", "cx", "cy", "width", "height", "max_range")})


def _check_intrinsics(**values):
    for name, value in values.items():
        if not _checks.is_concrete(value):
            continue
        a = float(np.asarray(value))
        positive = not name.endswith(("cx", "cy"))
        if not math.isfinite(a) or (positive and not a > 0):
            need = "finite and > 0" if positive else "finite"
            raise ValueError(f"{name} must be {need}; got {value!r}")


def _check_people(camera, people_xy, heights, radii, mask):
    _check_camera(camera)
    _checks.check_shape("people_xy", people_xy, (None, 2), "[P, 2] floor positions")
    P = _checks.shape_of(people_xy)[0]
    _checks.check_shape("heights", heights, (P,), "one height per person")
    _checks.check_shape("radii", radii, (P,), "one radius per person")
    _checks.check_shape("mask", mask, (P,), "one flag per person")
    if _dtype_of(mask) != np.bool_:
        raise TypeError(f"mask must hold bools; got dtype {_dtype_of(mask)}")
    for name, value in (("people_xy", people_xy), ("heights", heights), ("radii", radii)):
        if not np.issubdtype(_dtype_of(value), np.number):
            raise TypeError(f"{name} must be numeric; got dtype {_dtype_of(value)}")
    if all(_checks.is_concrete(a) for a in (people_xy, heights, radii, mask)):
        m = np.asarray(mask, bool)
        if not np.all(np.isfinite(np.asarray(people_xy, np.float64)[m])):
            raise ValueError("people_xy contains NaN or inf for a masked-in person")
        h, r = np.asarray(heights, np.float64)[m], np.asarray(radii, np.float64)[m]
        if not np.all(np.isfinite(h) & (h > 0)):
            raise ValueError(f"heights must be finite and > 0; got {h.tolist()}")
        if not np.all(np.isfinite(r) & (r >= 0)):
            raise ValueError(f"radii must be finite and >= 0; got {r.tolist()}")
    return P, _float_dtype(people_xy)


def _check_occluders(occluders, dtype):
    if occluders is None:
        return jnp.zeros((0, 4), dtype)
    _checks.check_shape("occluders", occluders, (None, 4),
                        "[O, 4] pixel boxes (u_min, v_min, u_max, v_max)")
    _checks.check_finite("occluders", occluders)
    return jnp.asarray(occluders, dtype)


def _check_key(key):
    dtype = _dtype_of(key)
    typed = jnp.issubdtype(dtype, jax.dtypes.prng_key)
    raw = dtype == jnp.uint32 and _checks.shape_of(key) == (2,)
    if not (typed and _checks.shape_of(key) == ()) and not raw:
        raise TypeError(f"key must be one jax.random key; got dtype {dtype}, shape "
                        f"{list(_checks.shape_of(key))}")


def _check_count(name, value, minimum):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an int; got {type(value).__name__}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}; got {value}")


def _check_fraction(name, value):
    _checks.check_shape(name, value, (), "a scalar")
    _checks.check_probability(name, value)


def _check_real(name, value, minimum=None):
    _checks.check_shape(name, value, (), "a scalar")
    if not _checks.is_concrete(value):
        return
    a = float(np.asarray(value))
    if not math.isfinite(a) or (minimum is not None and a < minimum):
        bound = "" if minimum is None else f" and >= {minimum}"
        raise ValueError(f"{name} must be finite{bound}; got {value!r}")
