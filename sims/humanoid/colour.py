r"""Zenithal colour camera: an analytic, differentiable render of the humanoid and the floor in
RGB under varying light, beside the depth render of `sims.humanoid.sensor` (same camera model,
same image size, the same robot window).

Rendering. Each pixel is the mean of ``supersample`` x ``supersample`` sub-pixel rays (a box
filter over the pixel's footprint, so that a pixel on the robot's silhouette mixes the robot's
colour with the floor's, as a camera's does). A ray sees the nearest primitive
(`sensor.geom_distances`, the ray casting of the depth render); its radiance is Lambertian,

.. math::
    c = \operatorname{clip}\Big(\rho_g\, b_t\, \big(1 + \mathbf{g}\cdot(\mathbf{p}_{xy} -
    \mathbf{o})\big)\,\big(k_a + k_d \max(0, \mathbf{n}\cdot\hat{\mathbf{l}})\big)
    + \sigma\varepsilon,\ 0,\ 1\Big),

with :math:`\rho_g` the albedo of the geom hit (`Palette`), :math:`\mathbf{p}` the hit point,
:math:`\mathbf{n}` the surface normal there, :math:`\hat{\mathbf{l}}` the unit vector to a lamp
on the ceiling above the camera's axis, :math:`k_a, k_d` the ambient and diffuse shares,
:math:`b_t` the brightness (per episode, times a per-frame flicker: a camera's automatic
exposure, a cloud passing a window), :math:`\mathbf{g}` a smooth spatial illumination gradient
(per episode, zero at the camera's axis :math:`\mathbf{o}`: daylight from one side of the room)
and :math:`\varepsilon \sim N(0, 1)` pixel noise per channel. The lamp adds a radial falloff
of its own (:math:`\mathbf{n}\cdot\hat{\mathbf{l}}` on the floor is 0.87 at 1.5 m from the
axis). `LightingConfig` holds the ranges; `draw_lighting` draws an episode's light.

Colours (`Palette`): a NAO v4 of the blue edition, simplified to one colour per geom: white
shells (head, chest, arms, thighs, shins), blue trim (shoulders, pelvis, feet), dark grey
joints (neck, hands); a brown-grey floor and light walls (the MJCF's materials).

Speed. As for depth, the room is static: its sub-ray colours, hit points and distances are
rendered once (`background`); each frame casts only the robot's window of ``K`` pixels
(`sensor.window_size`) against the robot's geoms, then applies the light to the whole image.

Gradients. The colour of a pixel on the robot depends smoothly on the robot's pose through
the hit point (illumination gradient) and the surface normal (shading), so `image` has finite,
non-zero derivatives with respect to the geom poses. The motion of the silhouette across the
sub-ray grid is a discontinuity that automatic differentiation does not see (as for the depth
render, `sensor`'s module notes); the box filter makes it a finer one.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from jax import lax

from sims.humanoid import sensor
from sims.humanoid.scene import Camera, Scene

Array = jax.Array

__all__ = ["Palette", "LightingConfig", "Lighting", "Background", "albedo", "background",
           "draw_lighting", "flicker", "render", "add_noise", "image", "sub_rays"]

_PLANE, _SPHERE, _CAPSULE, _ELLIPSOID, _BOX = (int(mujoco.mjtGeom.mjGEOM_PLANE),
                                               int(mujoco.mjtGeom.mjGEOM_SPHERE),
                                               int(mujoco.mjtGeom.mjGEOM_CAPSULE),
                                               int(mujoco.mjtGeom.mjGEOM_ELLIPSOID),
                                               int(mujoco.mjtGeom.mjGEOM_BOX))


class Palette(NamedTuple):
    """Albedos (linear RGB in [0, 1]) of the scene's parts (ours: a NAO v4, blue edition).

    Attributes:
      shell: white body shells: head, chest, upper arms, forearms, thighs, shins.
      trim: blue trim: shoulders, pelvis, feet.
      joint: dark grey: neck, hands.
      floor: the floor (the MJCF's floor material).
      wall: the walls (outside the field of view at the floor).
    """

    shell: tuple = (0.92, 0.92, 0.90)
    trim: tuple = (0.12, 0.30, 0.78)
    joint: tuple = (0.28, 0.28, 0.30)
    floor: tuple = (0.50, 0.45, 0.40)
    wall: tuple = (0.80, 0.80, 0.75)


_TRIM = ("l_shoulder", "r_shoulder", "pelvis", "l_foot", "r_foot")
_JOINT = ("neck", "l_hand", "r_hand")


class LightingConfig(NamedTuple):
    """The light model and its variation (ours; module docstring for the equation).

    Attributes:
      ambient, diffuse: :math:`k_a`, :math:`k_d` (their sum is the brightness under the lamp).
      lamp_height: height (m) of the lamp above the floor, on the camera's axis.
      brightness_range: per-episode brightness :math:`b`, uniform in this range.
      flicker_std: relative std of the per-frame brightness (i.i.d. per frame).
      gradient_max: largest illumination gradient :math:`|\\mathbf{g}|` (relative change per
        metre); per episode uniform in [0, max] in a uniform direction.
      pixel_std: std :math:`\\sigma` of the pixel noise, per channel.
    """

    ambient: float = 0.35
    diffuse: float = 0.65
    lamp_height: float = 2.7
    brightness_range: tuple = (0.75, 1.15)
    flicker_std: float = 0.03
    gradient_max: float = 0.25
    pixel_std: float = 0.02


class Lighting(NamedTuple):
    """The light of one frame (traced leaves).

    Attributes:
      brightness: scalar :math:`b_t`.
      gradient: [2] :math:`\\mathbf{g}` (1/m).
    """

    brightness: Array
    gradient: Array


class Background(NamedTuple):
    """The static room seen through every sub-ray (`background`).

    Attributes:
      radiance: [H s, W s, 3] albedo times shading (before brightness and gradient).
      xy: [H s, W s, 2] world (x, y) of each sub-ray's hit point.
      distance: [H s, W s] distance along each sub-ray (inf: no hit).
      supersample: s (static).
    """

    radiance: Array
    xy: Array
    distance: Array
    supersample: int


def albedo(scene: Scene, palette: Palette = Palette()) -> np.ndarray:
    """[ngeom, 3] albedo of every geom of ``scene`` from its name (`Palette`).

    Example:
      >>> rho = albedo(scene.build(), Palette(floor=(0.75, 0.75, 0.72)))
    """
    out = np.empty((scene.model.ngeom, 3))
    robot = set(scene.robot_geoms.tolist())
    for g in range(scene.model.ngeom):
        name = scene.model.geom(g).name
        if g not in robot:
            out[g] = palette.floor if name == "floor" else palette.wall
        elif name in _TRIM:
            out[g] = palette.trim
        elif name in _JOINT:
            out[g] = palette.joint
        else:
            out[g] = palette.shell
    return out


def sub_rays(camera: Camera, supersample: int, row=0, col=0, height=None, width=None,
             dtype=jnp.float32) -> Array:
    r"""Unit directions [h s, w s, 3] of the sub-pixel rays of an h x w block at (row, col):
    sub-ray (a, b) of pixel (i, j) looks along
    :math:`d \propto ((j + (b + 1/2)/s - c_x)/f_x,\ -(i + (a + 1/2)/s - c_y)/f_y,\ -1)`
    (`scene.camera_rays` for s = 1).

    Example:
      >>> dirs = sub_rays(camera, 2, row, col, 18, 18)       # [36, 36, 3]
    """
    h = camera.height if height is None else height
    w = camera.width if width is None else width
    s = int(supersample)
    j = (jnp.arange(w * s, dtype=dtype) + 0.5) / s + jnp.asarray(col, dtype)
    i = (jnp.arange(h * s, dtype=dtype) + 0.5) / s + jnp.asarray(row, dtype)
    uu, vv = jnp.meshgrid((j - camera.cx) / camera.fx, -(i - camera.cy) / camera.fy)
    d = jnp.stack([uu, vv, -jnp.ones_like(uu)], -1)
    return d / jnp.linalg.norm(d, axis=-1, keepdims=True)


def background(scene: Scene, palette: Palette = Palette(),
               config: LightingConfig = LightingConfig(), supersample: int = 2,
               dtype=jnp.float32) -> Background:
    """The static room through every sub-ray, rendered once per scene.

    Example:
      >>> bg = background(scene.build())
    """
    if int(supersample) < 1:
        raise ValueError(f"supersample must be >= 1; got {supersample}")
    model = scene.model
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    ids = np.asarray(scene.static_geoms)
    xpos = jnp.asarray(data.geom_xpos[ids], dtype)
    xmat = jnp.asarray(data.geom_xmat[ids].reshape(-1, 3, 3), dtype)
    rho = jnp.asarray(albedo(scene, palette)[ids], dtype)
    cam = scene.camera
    s = int(supersample)

    @jax.jit
    def cast():
        dirs = sub_rays(cam, s, dtype=dtype)
        shape = dirs.shape[:2]
        rad, xy, dist = _shade(cam, dirs.reshape(-1, 3), model.geom_type[ids],
                               jnp.asarray(model.geom_size[ids], dtype), xpos, xmat, rho,
                               config)
        return rad.reshape(*shape, 3), xy.reshape(*shape, 2), dist.reshape(shape)

    return Background(*cast(), s)


def draw_lighting(key: Array, config: LightingConfig = LightingConfig(),
                  dtype=jnp.float32) -> Lighting:
    """An episode's light: brightness uniform in ``brightness_range``, a gradient of uniform
    magnitude in [0, ``gradient_max``] and uniform direction.

    Example:
      >>> light = draw_lighting(jax.random.PRNGKey(0))
    """
    k_b, k_m, k_a = jax.random.split(key, 3)
    lo, hi = config.brightness_range
    b = jax.random.uniform(k_b, (), dtype, lo, hi)
    mag = jax.random.uniform(k_m, (), dtype, 0.0, config.gradient_max)
    ang = jax.random.uniform(k_a, (), dtype, -jnp.pi, jnp.pi)
    return Lighting(b, mag * jnp.stack([jnp.cos(ang), jnp.sin(ang)]))


def flicker(key: Array, lighting: Lighting, config: LightingConfig = LightingConfig()
            ) -> Lighting:
    """One frame's light: the episode's brightness times :math:`1 + \\sigma_f \\varepsilon`.

    Example:
      >>> frame_light = flicker(key, draw_lighting(episode_key))
    """
    eps = jax.random.normal(key, (), lighting.brightness.dtype)
    return lighting._replace(brightness=lighting.brightness * (1.0 + config.flicker_std * eps))


def render(scene: Scene, xpos: Array, xmat: Array, centre: Array, bg: Background,
           lighting: Lighting, palette: Palette = Palette(),
           config: LightingConfig = LightingConfig(), dtype=jnp.float32) -> Array:
    """Noise-free colour image [H, W, 3] (linear RGB, not clipped) of the robot posed at
    ``xpos``, ``xmat`` (world geom poses, `scene.pose_geoms`) over the room.

    The robot's geoms are cast in the ``sensor.window_size`` window centred on the image of
    ``centre`` (the true robot), as the depth render does; outside it the image is the room.

    Args:
      scene: `Scene`; xpos: [ngeom, 3]; xmat: [ngeom, 3, 3].
      centre: [2] world (x, y) of the robot.
      bg: `Background` of the scene; lighting: `Lighting` of the frame.
      palette: `Palette` (must be the one ``bg`` was rendered with); config: `LightingConfig`.

    Example:
      >>> img = render(sc, xpos, xmat, torso[:2], background(sc), draw_lighting(key))
    """
    cam = scene.camera
    s = bg.supersample
    k = sensor.window_size(cam)
    row, col = sensor.window_origin(cam, jnp.asarray(centre, dtype), k)
    ids = scene.robot_geoms
    dirs = sub_rays(cam, s, row, col, k, k, dtype)
    rho = jnp.asarray(albedo(scene, palette)[ids], dtype)
    rad, xy, dist = _shade(cam, dirs.reshape(-1, 3), scene.model.geom_type[ids],
                           jnp.asarray(scene.model.geom_size[ids], dtype),
                           jnp.asarray(xpos, dtype)[ids], jnp.asarray(xmat, dtype)[ids], rho,
                           config)
    zero = jnp.int32(0)
    start = (row.astype(jnp.int32) * s, col.astype(jnp.int32) * s)
    bg_dist = lax.dynamic_slice(bg.distance.astype(dtype), start, (k * s, k * s)).reshape(-1)
    bg_rad = lax.dynamic_slice(bg.radiance.astype(dtype), (*start, zero), (k * s, k * s, 3))
    bg_xy = lax.dynamic_slice(bg.xy.astype(dtype), (*start, zero), (k * s, k * s, 2))
    robot = (dist < bg_dist)[:, None]
    win_rad = jnp.where(robot, rad, bg_rad.reshape(-1, 3)).reshape(k * s, k * s, 3)
    win_xy = jnp.where(robot, xy, bg_xy.reshape(-1, 2)).reshape(k * s, k * s, 2)
    radiance = lax.dynamic_update_slice(bg.radiance.astype(dtype), win_rad, (*start, zero))
    hit_xy = lax.dynamic_update_slice(bg.xy.astype(dtype), win_xy, (*start, zero))
    origin = jnp.asarray(cam.position[:2], dtype)
    gain = lighting.brightness * (1.0 + (hit_xy - origin) @ lighting.gradient.astype(dtype))
    sub = radiance * gain[..., None]
    H, W = cam.height, cam.width
    return sub.reshape(H, s, W, s, 3).mean(axis=(1, 3))


def add_noise(key: Array, clean: Array, pixel_std=0.02) -> Array:
    """``clip(clean + pixel_std * N(0, 1), 0, 1)`` per pixel and channel (a camera's noise and
    saturation).

    Example:
      >>> img = add_noise(key, render(sc, xpos, xmat, centre, bg, light), 0.02)
    """
    noise = pixel_std * jax.random.normal(key, clean.shape, clean.dtype)
    return jnp.clip(clean + noise, 0.0, 1.0)


def image(key: Array, scene: Scene, xpos: Array, xmat: Array, centre: Array, bg: Background,
          lighting: Lighting, palette: Palette = Palette(),
          config: LightingConfig = LightingConfig(), dtype=jnp.float32) -> Array:
    """The camera's colour image [H, W, 3] in [0, 1]: `render` with the frame's flicker of
    ``lighting`` (key-driven), then `add_noise`.

    Example:
      >>> img = image(key, sc, xpos, xmat, torso[:2], bg, draw_lighting(k_episode))
    """
    k_f, k_n = jax.random.split(key)
    clean = render(scene, xpos, xmat, centre, bg, flicker(k_f, lighting, config), palette,
                   config, dtype)
    return add_noise(k_n, clean, config.pixel_std)


# ---------------------------------------------------------------------------------------------
# Shading


def _shade(cam: Camera, dirs, types, sizes, xpos, xmat, rho, config: LightingConfig):
    """Radiance [R, 3] (albedo x shading), hit (x, y) [R, 2] and distance [R] of the nearest of
    the given geoms along each ray (radiance 0 and the camera's (x, y) where none is hit)."""
    dtype = dirs.dtype
    origin = jnp.asarray(cam.position, dtype)
    dist = sensor.geom_distances(origin, dirs, types, sizes, xpos, xmat)      # [G, R]
    nearest = jnp.argmin(dist, 0)
    t = jnp.min(dist, 0)
    hit = jnp.isfinite(t)
    t_safe = jnp.where(hit, t, 0.0)
    point = origin + t_safe[:, None] * dirs                                   # [R, 3]
    one_hot = jax.nn.one_hot(nearest, dist.shape[0], dtype=dtype)             # [R, G]
    local = jnp.einsum("gji,rgj->rgi", xmat, point[:, None, :] - xpos[None])  # [R, G, 3]
    normals = _normals(np.asarray(types), sizes, local)                       # [R, G, 3]
    normal = jnp.einsum("rg,gij,rgj->ri", one_hot, xmat, normals)
    lamp = jnp.asarray([cam.position[0], cam.position[1], config.lamp_height], dtype)
    to_lamp = lamp - point
    to_lamp = to_lamp / jnp.sqrt(jnp.sum(to_lamp * to_lamp, -1, keepdims=True) + 1e-12)
    cos = jnp.maximum(jnp.sum(normal * to_lamp, -1), 0.0)
    shading = config.ambient + config.diffuse * cos
    radiance = jnp.where(hit[:, None], (one_hot @ rho) * shading[:, None], 0.0)
    return radiance, point[:, :2], t


def _unit(v):
    return v / jnp.sqrt(jnp.sum(v * v, -1, keepdims=True) + 1e-12)


def _normals(types: np.ndarray, sizes, local):
    """Outward unit normals [R, G, 3] at the points ``local`` [R, G, 3] (each in its geom's
    frame) of each geom's surface."""
    out = jnp.zeros_like(local)
    zero = jnp.zeros_like(local[..., 0])
    for code in np.unique(types):
        idx = np.nonzero(types == code)[0]
        p = local[:, idx]
        size = sizes[idx][None]
        if code == _PLANE:
            n = jnp.stack([zero[:, idx], zero[:, idx], jnp.ones_like(zero[:, idx])], -1)
        elif code == _SPHERE:
            n = _unit(p)
        elif code == _ELLIPSOID:
            n = _unit(p / (size * size))
        elif code == _CAPSULE:
            h = size[..., 1]
            axis = jnp.clip(p[..., 2], -h, h)
            n = _unit(p - jnp.stack([jnp.zeros_like(axis), jnp.zeros_like(axis), axis], -1))
        elif code == _BOX:
            ratio = jnp.abs(p) / size
            face = jax.nn.one_hot(jnp.argmax(ratio, -1), 3, dtype=p.dtype)
            n = face * jnp.sign(p)
        else:
            raise ValueError(f"unsupported geom type {code}")
        out = out.at[:, idx].set(n)
    return out
