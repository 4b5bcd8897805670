r"""Zenithal depth camera: analytic, differentiable ray casting of primitive geoms, Kinect-like
noise, back-projection to a world-frame point cloud and floor removal.

Rendering. Every pixel's ray :math:`o + t d` (unit :math:`d`) is intersected analytically with
every primitive in its geom frame (:math:`p = R^T(o - x_g)`, :math:`v = R^T d`): planes,
spheres, capsules, ellipsoids (quadratics :math:`a t^2 + 2 b t + c = 0`) and boxes (slabs), the
nearest non-negative root wins, and the depth is the distance times the cosine to the optical
axis. This is the algorithm of ``mjx.ray`` (and is tested against it to 1 mm), written so that
gradients are finite: square roots and divisions only see safe arguments (``jnp.where`` on the
*inputs*, not only the outputs), where ``jax.grad`` through ``mjx.ray`` gives NaN on spheres and
capsules (the derivative of :math:`\sqrt{\max(\Delta, 0)}` at a grazing ray).

Speed. The room is static: its depth is rendered once (`background`). The humanoid only covers a
small part of the image, so each frame renders its geoms in a fixed-size square *window* of
pixels centred on the projection of the robot (`window_size` from a bounding radius); pixels
outside the window see the background. This is exact as long as the robot fits its bounding
radius (tested), and costs :math:`K^2 G` ray-geom tests instead of :math:`H W G`.

Noise (Kinect v1, Khoshelham & Elberink 2012): depth std :math:`\sigma(z) = k_\sigma z^2`,
quantisation to steps :math:`q(z) = k_q z^2` (disparity quantisation), and missing pixels with
probability ``dropout``. Quantisation uses a straight-through gradient.

Gradients of the point cloud with respect to the robot's pose (`robot_point_cloud`). A pixel
looks along a fixed ray, so the pathwise derivative of its back-projected point is that of the
*depth* along that ray: when the robot slides sideways, a point on its flat head or shoulders
does not move at all (the head's top is level), and the cloud's true motion — pixels at the
silhouette switching between floor and robot — is a discontinuity that automatic
differentiation never sees: AD then gives the blob centroid and the PCA heading a small
fraction of their true derivatives (measurements: docs/design_notes.md, "Humanoid: the point
cloud's derivative moves with the torso"). Through a closed loop this removes the feedback from
the gradient (the controller seems to act on a robot that never moves), which can flip the
sign of the gain derivatives. The fix is a reparameterisation: the pixel grid is moved rigidly with
the robot's torso pose :math:`T = (x, y, \psi)` in the derivative only. The geoms are rendered
in the frame :math:`T_\delta^{-1}`, :math:`\delta = T - \perp(T)` (the identity in value), and
the robot's points are mapped back by :math:`T_\delta`: the values are unchanged, and the
derivative of the cloud with respect to the torso pose is the rigid motion :math:`\partial T`
plus the pathwise derivative of the limbs *relative* to the torso. This is the exact derivative
of the expected cloud when the grid's phase relative to the robot is uniform (a camera at a
random sub-pixel offset: the cloud is then distributed as the same cloud moved with the robot),
and what the robot's motion in a real camera averages to over frames and keys.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxtrack.perception import depth as depth_mod
from sims.humanoid.scene import Camera, Scene, camera_rays

Array = jax.Array

__all__ = ["DepthNoise", "Window", "Occluders", "ray_distances", "geom_distances", "render",
           "background", "window_size", "render_window", "add_noise", "ceiling_camera",
           "back_project", "window_origin", "remove_floor", "static_heights", "point_cloud",
           "robot_point_cloud"]

_PLANE, _SPHERE, _CAPSULE, _ELLIPSOID, _BOX = 0, 2, 3, 4, 6


class DepthNoise(NamedTuple):
    """Kinect-like depth noise (float leaves; defaults for a Kinect v1).

    Attributes:
      sigma_coef: :math:`k_\\sigma` in :math:`\\sigma(z) = k_\\sigma z^2` (1/m); 1.43e-3 gives
        1.1 cm at 2.8 m (Khoshelham & Elberink 2012).
      quant_coef: :math:`k_q` in the quantisation step :math:`q(z) = k_q z^2` (1/m); 2.9e-3
        (one disparity unit at 1/8 pixel) gives 2.3 cm at 2.8 m.
      dropout: probability that a pixel returns no depth.
    """

    sigma_coef: float = 1.43e-3
    quant_coef: float = 2.9e-3
    dropout: float = 0.02


class Window(NamedTuple):
    """A square window of the depth image rendered with the robot.

    Attributes:
      depth: [K, K] depth along the optical axis (inf where no return).
      row, col: pixel indices of the window's top-left corner.
    """

    depth: Array
    row: Array
    col: Array


# ---------------------------------------------------------------------------------------------
# Ray casting


class Occluders(NamedTuple):
    """Other bodies in the camera's view (people walking by), as primitives.

    Attributes:
      types: [G] static ``mjtGeom`` codes (`ray_distances`'); sizes: [G, 3];
      xpos: [G, 3] world centres; xmat: [G, 3, 3] orientations.
    """

    types: np.ndarray
    sizes: Array
    xpos: Array
    xmat: Array


def _render_occluders(scene: Scene, occ: Occluders, row, col, size, dtype):
    """[size, size] depth of the occluders alone in the window at (row, col)."""
    dirs, cos = camera_rays(scene.camera, dtype)
    dirs = lax.dynamic_slice(dirs, (row, col, jnp.int32(0)), (size, size, 3))
    cos = lax.dynamic_slice(cos, (row, col), (size, size))
    dist = ray_distances(jnp.asarray(scene.camera.position, dtype), dirs.reshape(-1, 3),
                         occ.types, jnp.asarray(occ.sizes, dtype), jnp.asarray(occ.xpos, dtype),
                         jnp.asarray(occ.xmat, dtype))
    return dist.reshape(size, size) * cos


def ray_distances(origin: Array, dirs: Array, geom_types: np.ndarray, sizes: Array,
                  xpos: Array, xmat: Array) -> Array:
    """Distance along each ray to the nearest primitive (inf if none).

    Args:
      origin: [3] ray origin (the camera centre).
      dirs: [R, 3] unit directions.
      geom_types: [G] static ``mjtGeom`` codes (plane 0, sphere 2, capsule 3, ellipsoid 4,
        box 6); other types raise.
      sizes: [G, 3] geom sizes (MuJoCo convention).
      xpos: [G, 3] geom centres; xmat: [G, 3, 3] geom orientations (columns: geom axes).

    Returns:
      [R] distances (differentiable in origin, dirs, sizes, xpos, xmat).

    Example:
      >>> dist = ray_distances(cam, dirs, types, model.geom_size, xpos, xmat)
    """
    best = jnp.full(dirs.shape[:1], jnp.inf, dirs.dtype)
    for _, t in _distances_by_type(origin, dirs, geom_types, sizes, xpos, xmat):
        best = jnp.minimum(best, jnp.min(t, 0))
    return best


def geom_distances(origin: Array, dirs: Array, geom_types: np.ndarray, sizes: Array,
                   xpos: Array, xmat: Array) -> Array:
    """Distance along each ray to each primitive, before the nearest is taken (`ray_distances`
    is its minimum over the geoms): what a renderer needs to know *which* geom a ray sees.

    Args:
      origin, dirs, geom_types, sizes, xpos, xmat: as `ray_distances`.

    Returns:
      [G, R] distances (inf where geom g is not hit by ray r), in the order of ``geom_types``.

    Example:
      >>> dist = geom_distances(cam, dirs, types, sizes, xpos, xmat)
      >>> seen = jnp.argmin(dist, 0)          # [R] index of the geom each ray sees
    """
    dist = jnp.full((xpos.shape[0], dirs.shape[0]), jnp.inf, dirs.dtype)
    for idx, t in _distances_by_type(origin, dirs, geom_types, sizes, xpos, xmat):
        dist = dist.at[idx].set(t)
    return dist


def _distances_by_type(origin, dirs, geom_types, sizes, xpos, xmat):
    """``(geom indices [n], distances [n, R])`` for each primitive type present (static)."""
    geom_types = np.asarray(geom_types)
    bad = set(geom_types.tolist()) - {_PLANE, _SPHERE, _CAPSULE, _ELLIPSOID, _BOX}
    if bad:
        raise ValueError(f"unsupported geom types {sorted(bad)} (planes, spheres, capsules, "
                         "ellipsoids and boxes only)")
    # Ray in each geom frame: [G, R, 3].
    pnt = jnp.einsum("gji,gj->gi", xmat, origin[None, :] - xpos)
    pnt = jnp.broadcast_to(pnt[:, None, :], (xpos.shape[0], dirs.shape[0], 3))
    vec = jnp.einsum("gji,rj->gri", xmat, dirs)
    out = []
    for code, fn in ((_PLANE, _plane), (_SPHERE, _sphere), (_CAPSULE, _capsule),
                     (_ELLIPSOID, _ellipsoid), (_BOX, _box)):
        idx = np.nonzero(geom_types == code)[0]
        if idx.size:
            out.append((idx, fn(sizes[idx][:, None, :], pnt[idx], vec[idx])))
    return out


def render(scene: Scene, xpos: Array, xmat: Array, geoms=None, dtype=jnp.float32) -> Array:
    """Full depth image [H, W] (distance along the optical axis; inf where no return).

    Args:
      scene: `Scene`.
      xpos, xmat: world geom poses (from `scene.pose_geoms`).
      geoms: optional static ids of the geoms to render (default all).

    Example:
      >>> depth = render(scene, *pose_geoms(scene, qpos))
    """
    cam = scene.camera
    dirs, cos = camera_rays(cam, dtype)
    ids = np.arange(scene.model.ngeom) if geoms is None else np.asarray(geoms)
    origin = jnp.asarray(cam.position, dtype)
    dist = ray_distances(origin, dirs.reshape(-1, 3), scene.model.geom_type[ids],
                         jnp.asarray(scene.model.geom_size[ids], dtype),
                         jnp.asarray(xpos, dtype)[ids], jnp.asarray(xmat, dtype)[ids])
    return dist.reshape(cos.shape) * cos


def background(scene: Scene, dtype=jnp.float32) -> Array:
    """Depth image [H, W] of the static room alone (rendered once per scene)."""
    xpos = jnp.asarray(scene.model.geom_pos, dtype)
    xmat = jnp.asarray(np.stack([_quat_to_mat(q) for q in scene.model.geom_quat]), dtype)
    return jax.jit(lambda p, m: render(scene, p, m, scene.static_geoms, dtype))(xpos, xmat)


def window_size(camera: Camera, radius: float = 0.3) -> int:
    """Side K (pixels) of a window that holds a robot of horizontal bounding ``radius`` (m)
    standing on the floor, wherever it is in the image (the floor is the farthest plane)."""
    k = 2.0 * radius * max(camera.fx, camera.fy) / camera.position[2]
    return int(min(math.ceil(k) + 2, camera.width, camera.height))


def render_window(scene: Scene, xpos: Array, xmat: Array, centre: Array, size: int,
                  background_depth: Array, dtype=jnp.float32) -> Window:
    """Depth in a ``size`` x ``size`` window centred on the image of ``centre``.

    The window is the robot's part of the image: the robot's geoms are rendered in it and
    combined with the precomputed ``background_depth``; outside it the image equals the
    background (exact when the robot fits in the window, see `window_size`).

    Args:
      scene: `Scene`; xpos, xmat: world geom poses.
      centre: [2] world (x, y) of the robot (the window follows the true robot).
      size: K (static).
      background_depth: [H, W] from `background`.

    Returns:
      `Window`.
    """
    cam = scene.camera
    cpos = np.asarray(cam.position)
    row, col = window_origin(cam, centre, size)
    dirs, cos = camera_rays(cam, dtype)
    dirs = lax.dynamic_slice(dirs, (row, col, jnp.int32(0)), (size, size, 3))
    cos = lax.dynamic_slice(cos, (row, col), (size, size))
    ids = scene.robot_geoms
    dist = ray_distances(jnp.asarray(cpos, dtype), dirs.reshape(-1, 3), scene.model.geom_type[ids],
                         jnp.asarray(scene.model.geom_size[ids], dtype),
                         jnp.asarray(xpos, dtype)[ids], jnp.asarray(xmat, dtype)[ids])
    depth = dist.reshape(size, size) * cos
    bg = lax.dynamic_slice(jnp.asarray(background_depth, dtype), (row, col), (size, size))
    return Window(jnp.minimum(depth, bg), row, col)


# ---------------------------------------------------------------------------------------------
# Noise, back-projection, floor removal


def add_noise(key: Array, depth: Array, noise: DepthNoise = DepthNoise()) -> tuple[Array, Array]:
    r"""Kinect-like measurement of a depth image.

    :math:`\tilde z = q(z) \operatorname{round}((z + \sigma(z)\,\varepsilon) / q(z))` with
    :math:`\varepsilon \sim N(0, 1)`, straight-through gradient for the rounding; pixels are
    missing with probability ``dropout`` or when there is no return.

    Args:
      key: PRNG key; depth: [...] true depths (inf: no return).
      noise: `DepthNoise`.

    Returns:
      ``(measured depth [...], valid [...] bools)``; invalid pixels hold 0.
    """
    k_n, k_d = jax.random.split(key)
    hit = jnp.isfinite(depth)
    z = jnp.where(hit, depth, 1.0)
    noisy = z + noise.sigma_coef * z * z * jax.random.normal(k_n, z.shape, z.dtype)
    step = noise.quant_coef * z * z
    quant = step * jnp.round(noisy / step)
    noisy = noisy + lax.stop_gradient(quant - noisy)
    valid = hit & (jax.random.uniform(k_d, z.shape, z.dtype) >= noise.dropout)
    return jnp.where(valid, noisy, 0.0), valid


def ceiling_camera(camera: Camera) -> depth_mod.CeilingCamera:
    """The scene's camera as a `jaxtrack.perception.depth.CeilingCamera` (the replay's)."""
    return depth_mod.CeilingCamera(tuple(camera.position), camera.fx, camera.fy, camera.cx,
                                   camera.cy)


def back_project(camera: Camera, depth: Array, valid: Array, row=0, col=0) -> Array:
    """`jaxtrack.perception.depth.back_project` with the scene's camera: [h * w, 3] world
    points (x, y, height) of a depth block at pixel offset (row, col)."""
    return depth_mod.back_project(ceiling_camera(camera), depth, valid, row, col)


def window_origin(camera: Camera, centre, size: int) -> tuple[Array, Array]:
    """Top-left pixel (row, col) [int32] of the ``size`` window centred on the image of the
    world point ``centre`` [2] (clipped to the image; no gradient)."""
    cpos = np.asarray(camera.position)
    u = camera.cx + camera.fx * (centre[0] - cpos[0]) / cpos[2]
    v = camera.cy - camera.fy * (centre[1] - cpos[1]) / cpos[2]
    col = jnp.clip(jnp.round(u - size / 2.0), 0, camera.width - size).astype(jnp.int32)
    row = jnp.clip(jnp.round(v - size / 2.0), 0, camera.height - size).astype(jnp.int32)
    return lax.stop_gradient(row), lax.stop_gradient(col)


def remove_floor(points: Array, valid: Array, floor_threshold=0.06) -> Array:
    """Mask of points higher than ``floor_threshold`` above the floor (z = 0), the floor
    plane of the zenithal set-up being known; [P] bools."""
    return valid.reshape(-1) & (points[:, 2] > floor_threshold)


def static_heights(scene: Scene, static: Occluders, centre: Array, size: int,
                   dtype=jnp.float32) -> Array:
    """[K*K] height (m) of the static background each pixel of the window centred on the
    image of ``centre`` sees: the floor (0) or a ``static`` primitive (objects on the floor).

    A fixed camera can store this image before the robot enters the room (seed 000 section
    3.1 separates the robot from the background in the depth image); with the zenithal
    camera a pixel's height is the camera's height minus its depth, so keeping points higher
    than ``static_heights + threshold`` is background subtraction, of which `remove_floor` is
    the case without objects.

    Example:
      >>> h = static_heights(sc, boxes, pose[:2], window_size(sc.camera))
      >>> mask = mask & (pts[:, 2] > h + 0.06)
    """
    row, col = window_origin(scene.camera, lax.stop_gradient(centre), size)
    return _heights(scene, _render_occluders(scene, static, row, col, size, dtype))


def _heights(scene: Scene, depth: Array) -> Array:
    """[K*K] heights of a window's depths [K, K] seen by the zenithal camera (0 for none)."""
    depth = depth.reshape(-1)
    height = jnp.asarray(scene.camera.position[2], depth.dtype) - depth
    return lax.stop_gradient(jnp.where(jnp.isfinite(depth), jnp.maximum(height, 0.0), 0.0))


def point_cloud(key: Array, scene: Scene, window: Window, noise: DepthNoise = DepthNoise(),
                floor_threshold=0.06) -> tuple[Array, Array]:
    """Noisy, floor-removed world point cloud of a `Window`: ``(points [K*K, 3], mask)``."""
    depth, valid = add_noise(key, window.depth, noise)
    pts = back_project(scene.camera, depth, valid, window.row, window.col)
    return pts, remove_floor(pts, valid, floor_threshold)


def robot_point_cloud(key: Array, scene: Scene, xpos: Array, xmat: Array, pose: Array,
                      size: int, background_depth: Array, noise: DepthNoise = DepthNoise(),
                      floor_threshold=0.06, dtype=jnp.float32,
                      occluders: Occluders | None = None,
                      static: Occluders | None = None) -> tuple[Array, Array]:
    r"""Noisy, floor-removed point cloud of the robot's window, differentiable in its pose.

    The values are those of `render_window` (centred on ``pose[:2]``) followed by
    `point_cloud`. The derivative with respect to the torso ``pose`` moves the robot's points
    rigidly with it (module notes, "Gradients"): with :math:`\delta = T - \perp(T)` (zero in
    value), the geoms are rendered at :math:`T_\delta^{-1}` (the robot's bulk motion removed
    from the ray casting's derivative) and the points that hit the robot are mapped by
    :math:`T_\delta` (rotation by :math:`\delta_\psi` about :math:`\perp(x, y)`, then
    translation by :math:`(\delta_x, \delta_y)`).

    Args:
      key: PRNG key (noise); scene: `Scene`.
      xpos, xmat: world geom poses (from `scene.pose_geoms`).
      pose: [3] torso pose (x, y, yaw) the geoms were posed from.
      size: window side K (static, `window_size`); background_depth: [H, W] (`background`).
      noise: `DepthNoise`; floor_threshold: floor-removal height (m).
      occluders: `Occluders` (people walking by) rendered in the window too, in front of the
        robot where nearer the camera; None: none.
      static: `Occluders` in the camera's stored background image (objects on the floor):
        rendered like ``occluders``, and their points removed with the floor's
        (`static_heights`); None: none.

    Returns:
      ``(points [K*K, 3], mask [K*K])``.

    Example:
      >>> pts, mask = robot_point_cloud(key, sc, xpos, xmat, torso, k, background(sc))
    """
    pose = jnp.asarray(pose, dtype)
    delta = pose - lax.stop_gradient(pose)
    centre = jnp.concatenate([lax.stop_gradient(pose[:2]), jnp.zeros((1,), dtype)])
    shift = jnp.concatenate([delta[:2], jnp.zeros((1,), dtype)])
    c, s = jnp.cos(delta[2]), jnp.sin(delta[2])
    zero, one = jnp.zeros((), dtype), jnp.ones((), dtype)
    rot = jnp.stack([jnp.stack([c, -s, zero]), jnp.stack([s, c, zero]),
                     jnp.stack([zero, zero, one])])
    xpos = jnp.asarray(xpos, dtype)
    xmat = jnp.asarray(xmat, dtype)
    # T_delta^{-1}: p -> R^T (p - centre - shift) + centre; orientations R^T M.
    xpos_rel = (xpos - centre - shift) @ rot + centre
    xmat_rel = jnp.einsum("ji,gjk->gik", rot, xmat)
    win = render_window(scene, xpos_rel, xmat_rel, lax.stop_gradient(pose[:2]), size,
                        background_depth, dtype)
    bg = lax.dynamic_slice(jnp.asarray(background_depth, dtype), (win.row, win.col),
                           (size, size))
    other = (None if occluders is None else
             _render_occluders(scene, occluders, win.row, win.col, size, dtype))
    if static is not None:
        static_depth = _render_occluders(scene, static, win.row, win.col, size, dtype)
        other = static_depth if other is None else jnp.minimum(other, static_depth)
    if other is not None:
        on_robot = (win.depth < jnp.minimum(bg, other)).reshape(-1)
        win = win._replace(depth=jnp.minimum(win.depth, other))
    else:
        on_robot = (win.depth < bg).reshape(-1)
    pts, mask = point_cloud(key, scene, win, noise, floor_threshold)
    if static is not None:
        # background subtraction against the stored image (`static_heights`)
        mask = mask & (pts[:, 2] > _heights(scene, static_depth) + floor_threshold)
    moved = (pts - centre) @ rot.T + centre + shift
    return jnp.where(on_robot[:, None], moved, pts), mask


# ---------------------------------------------------------------------------------------------
# Intersections (geom frame); all return [G, R] distances, inf for no hit.


def _safe_div(a, b):
    tiny = 1e-12
    safe = jnp.where(jnp.abs(b) < tiny, jnp.where(b < 0, -tiny, tiny), b)
    return a / safe


def _quad_roots(a, b, c):
    """Roots of a t^2 + 2 b t + c = 0 (nearest non-negative first), safe square root."""
    det = b * b - a * c
    ok = det > 1e-12
    sq = jnp.sqrt(jnp.where(ok, det, 1.0))
    x0 = _safe_div(-b - sq, a)
    x1 = _safe_div(-b + sq, a)
    x0 = jnp.where(ok & (x0 >= 0), x0, jnp.inf)
    x1 = jnp.where(ok & (x1 >= 0), x1, jnp.inf)
    return x0, x1


def _plane(size, pnt, vec):
    x = -_safe_div(pnt[..., 2], vec[..., 2])
    valid = (vec[..., 2] <= -1e-15) & (x >= 0)
    p = pnt[..., :2] + x[..., None] * vec[..., :2]
    valid &= jnp.all((size[..., :2] <= 0) | (jnp.abs(p) <= size[..., :2]), -1)
    return jnp.where(valid, x, jnp.inf)


def _dot(a, b):
    return jnp.sum(a * b, -1)


def _sphere(size, pnt, vec):
    r = size[..., 0]
    x0, x1 = _quad_roots(_dot(vec, vec), _dot(vec, pnt), _dot(pnt, pnt) - r * r)
    return jnp.minimum(x0, x1)


def _capsule(size, pnt, vec):
    r, h = size[..., 0], size[..., 1]
    x0, x1 = _quad_roots(_dot(vec[..., :2], vec[..., :2]), _dot(vec[..., :2], pnt[..., :2]),
                         _dot(pnt[..., :2], pnt[..., :2]) - r * r)
    x = jnp.where(jnp.isinf(x0), x1, x0)
    x = jnp.where(jnp.abs(pnt[..., 2] + jnp.where(jnp.isinf(x), 0.0, x) * vec[..., 2]) <= h,
                  x, jnp.inf)
    for sign in (1.0, -1.0):
        dif = pnt - jnp.stack([jnp.zeros_like(h), jnp.zeros_like(h), sign * h], -1)
        y0, y1 = _quad_roots(_dot(vec, vec), _dot(vec, dif), _dot(dif, dif) - r * r)
        for y in (y0, y1):
            zc = pnt[..., 2] + jnp.where(jnp.isinf(y), 0.0, y) * vec[..., 2]
            on_cap = sign * zc >= h
            x = jnp.where(on_cap & (y < x), y, x)
    return x


def _ellipsoid(size, pnt, vec):
    s = 1.0 / (size * size)
    x0, x1 = _quad_roots(_dot(s * vec, vec), _dot(s * vec, pnt), _dot(s * pnt, pnt) - 1.0)
    return jnp.minimum(x0, x1)


def _box(size, pnt, vec):
    best = jnp.full(pnt.shape[:-1], jnp.inf, pnt.dtype)
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        for sign in (1.0, -1.0):
            x = _safe_div(sign * size[..., axis] - pnt[..., axis], vec[..., axis])
            xs = jnp.where(jnp.isfinite(x), x, 0.0)
            ok = x >= 0
            for o in others:
                ok &= jnp.abs(pnt[..., o] + xs * vec[..., o]) <= size[..., o]
            best = jnp.where(ok & (x < best), x, best)
    return best


def _quat_to_mat(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
