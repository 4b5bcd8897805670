r"""Histograms of oriented gradients and a linear SVM: the person confidence of seed 001.

Seed 001 scores each sub-cluster by "a HOG people detector [Dalal and Triggs] applied to the
part of the RGB image corresponding to the cluster theoretical bounding box, namely the bounding
box that should contain the whole person, from the head to the ground". Here:

- `person_box`: that box, from the head point and the foot point projected by a pinhole camera,
  with Dalal and Triggs' 1:2 aspect and a margin;
- `crop`: the box resampled (bilinear) to the detection window, 128 x 64 pixels;
- `hog`: Dalal and Triggs' descriptor, as scikit-image computes it: centred [-1, 0, 1]
  gradients, per pixel the colour channel of largest magnitude, unsigned orientation in 9 bins
  of 20 deg (hard assignment), 8 x 8 pixel cells (mean magnitude per bin), 2 x 2 cell blocks
  normalised by L2-Hys (:math:`v / \sqrt{\|v\|^2 + \epsilon^2}`, clipped at 0.2,
  renormalised), all blocks at a stride of one cell: 7 x 15 blocks x 36 = 3780 features;
- `descriptors`: `hog` of the `crop` of each of several boxes of one image, as the detector
  scores its detections;
- `LinearSVM`: the detector's linear SVM, :math:`s = w^T f + b`, and its confidence
  :math:`\sigma(s)` in (0, 1), which the tracker weighs (seed 001's :math:`c_{HOG}`).

The SVM is trained offline on simulated crops (``jaxtrack train-hog``, scikit-learn's
`LinearSVC`); its weights ship in ``jaxtrack/perception/data``.

Example:
  >>> box = person_box(camera, head, foot)
  >>> f = hog(crop(image, box))
  >>> c = svm_confidence(load_svm(), f)
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxtrack import _checks
from jaxtrack._gather import materialised, put

Array = jax.Array

__all__ = ["HOGConfig", "PinholeCamera", "LinearSVM", "hog", "crop", "person_box", "project",
           "svm_confidence", "load_svm", "num_features", "descriptors"]


@dataclasses.dataclass(frozen=True)
class HOGConfig:
    """Descriptor geometry (static). Dalal and Triggs' defaults.

    Attributes:
      window: (rows, cols) of the detection window; 128 x 64.
      cell: pixels per cell side; 8.
      block: cells per block side; 2.
      orientations: unsigned orientation bins over 180 deg; 9.
      margin: the person box's extra height above the head and below the feet, as a fraction
        of the person's height in the image (Dalal and Triggs' windows keep about 16 of 128
        rows around a 96-row person: 1/12 each side).
    """

    window: tuple[int, int] = (128, 64)
    cell: int = 8
    block: int = 2
    orientations: int = 9
    margin: float = 1.0 / 12.0


def num_features(config: HOGConfig = HOGConfig()) -> int:
    """Length of the descriptor: blocks x block cells x orientations (3780 by default)."""
    rows, cols = config.window[0] // config.cell, config.window[1] // config.cell
    b = config.block
    return (rows - b + 1) * (cols - b + 1) * b * b * config.orientations


class PinholeCamera(NamedTuple):
    """A pinhole camera in the frame of the cloud.

    Attributes:
      focal: [2] (fx, fy) pixels; principal: [2] (cx, cy) pixels (column, row);
      position: [3]; rotation: [3, 3] whose columns are the optical x (right), y (down) and z
      (forward) axes.
    """

    focal: Array
    principal: Array
    position: Array
    rotation: Array


class LinearSVM(NamedTuple):
    """A linear SVM: ``weights`` [F], ``bias`` []."""

    weights: Array
    bias: Array


def project(camera: PinholeCamera, points: Array) -> tuple[Array, Array]:
    """[..., 2] pixel (column, row) of [..., 3] points, and their depth [...] along the axis."""
    rel = (points - camera.position) @ camera.rotation
    z = rel[..., 2]
    safe = jnp.where(jnp.abs(z) > 1e-9, z, 1e-9)
    uv = rel[..., :2] / safe[..., None] * camera.focal + camera.principal
    return uv, z


def person_box(camera: PinholeCamera, head: Array, foot: Array,
               config: HOGConfig = HOGConfig()) -> Array:
    """The theoretical bounding box (top, left, bottom, right) in pixels, [..., 4], of a person
    whose head top is ``head`` [..., 3] and whose feet are at ``foot`` [..., 3]: from the head
    to the ground plus ``margin``, centred on the head's column, with the window's aspect."""
    uh, uf = project(camera, head)[0], project(camera, foot)[0]
    top, bottom = uh[..., 1], uf[..., 1]
    height = jnp.maximum(bottom - top, 1.0)
    top = top - config.margin * height
    bottom = bottom + config.margin * height
    width = (bottom - top) * config.window[1] / config.window[0]
    centre = 0.5 * (uh[..., 0] + uf[..., 0])
    return jnp.stack([top, centre - 0.5 * width, bottom, centre + 0.5 * width], -1)


def crop(image: Array, box: Array, config: HOGConfig = HOGConfig()) -> Array:
    """Resample the box (top, left, bottom, right) of ``image`` [H, W, C] to the window
    [rows, cols, C] (bilinear, pixel centres; outside the image the nearest edge pixel)."""
    _checks.check_ndim("image", image, 3, "[H, W, C] image")
    _checks.check_shape("box", box, (4,), "[4] (top, left, bottom, right)")
    return jnp.moveaxis(_crop_planes(_floating(image), box, config), 0, -1)


def hog(window: Array, config: HOGConfig = HOGConfig()) -> Array:
    """Dalal and Triggs' descriptor of a [rows, cols] or [rows, cols, C] window (module
    docstring), equal to ``skimage.feature.hog(window, 9, (8, 8), (2, 2), "L2-Hys",
    channel_axis=-1)``.

    Returns:
      [F] features (`num_features`), ordered (block row, block col, cell row, cell col, bin).

    Example:
      >>> f = hog(crop(image, box))       # [3780]
    """
    _checks.check_finite("window", window)   # a NaN pixel would spread to every block
    img = jnp.asarray(window)
    if img.ndim == 2:
        img = img[..., None]
    _checks.check_ndim("window", img, 3, "[rows, cols] or [rows, cols, C] window")
    planes = jnp.pad(_planes(img), ((0, 0), (1, 1), (1, 1)))
    return _descriptor(planes[None], config)[0]


def descriptors(image: Array, boxes: Array, config: HOGConfig = HOGConfig(),
                mask: Array | None = None) -> Array:
    """[B, F] descriptors of B boxes (top, left, bottom, right) [B, 4] of one image [H, W, C]:
    ``hog(crop(image, box))`` for each box, each window gathered straight into colour planes.

    With ``mask`` [B] bool, only the masked boxes are described (the others get zeros), a few
    at a time in a loop that stops after the last one: a detector's fixed capacity of boxes is
    mostly empty rows (0-7 of 16 in the rgbd-people frames), and each box costs about 0.1 ms
    on a CPU. Under `vmap` the loop runs as long as the batch's fullest frame needs.

    Example:
      >>> c = svm_confidence(load_svm(), descriptors(image, person_box(camera, head, foot)))
    """
    _checks.check_ndim("image", image, 3, "[H, W, C] image")
    _checks.check_shape("boxes", boxes, (None, 4), "[B, 4] (top, left, bottom, right)")
    _checks.check_finite("image", image)     # a NaN pixel would spread to every block
    # (the image stays [H, W, C]: each window's pixel gathers its C channels together, and
    # the windows come out as colour planes)
    img = _floating(image)
    b = _checks.shape_of(boxes)[0]
    boxes = jnp.asarray(boxes, img.dtype)
    if b == 0:
        return jnp.zeros((0, num_features(config)), img.dtype)
    if mask is None:
        return _describe(img, boxes, config)
    _checks.check_shape("mask", mask, (b,), "[B] bool")
    mask = jnp.asarray(mask, bool)
    k = min(_CHUNK, b)
    chunks = -(-b // k)
    order = jnp.argsort(~mask, stable=True).astype(jnp.int32)     # the described boxes first
    order = jnp.concatenate([order, jnp.zeros(chunks * k - b, jnp.int32)])
    count = jnp.sum(mask)

    def body(state):
        i, out = state
        rows = lax.dynamic_slice(order, (i * k,), (k,))
        return i + 1, lax.dynamic_update_slice(out, _describe(img, boxes[rows], config),
                                               (i * k, jnp.int32(0)))

    out = jnp.zeros((chunks * k, num_features(config)), img.dtype)
    _, out = lax.while_loop(lambda s: s[0] * k < count, body, (jnp.int32(0), out))
    dest = jnp.where(jnp.arange(b) < count, order[:b], b)
    return put(jnp.zeros_like(out, shape=(b + 1, out.shape[1])), dest, out[:b])[:b]


_CHUNK = 2      # boxes described per round of `descriptors`' loop


def _describe(image: Array, boxes: Array, config: HOGConfig) -> Array:
    """[B, F] descriptors of boxes [B, 4] of a floating [H, W, C] image."""
    windows = jax.vmap(lambda box: _crop_planes(image, box, config, border=1))(boxes)
    # Materialised: XLA otherwise fuses the crop's gathers and interpolation into every
    # gradient of the descriptor, recomputing each window pixel several times (13.1 against
    # 6.7 ms for 16 QVGA boxes on a CPU).
    return _descriptor(materialised(windows), config)


def _planes(image: Array) -> Array:
    """[C, H, W] floating colour planes of an [H, W, C] image. Colour planes first, so that
    every step works on one plane at a time: XLA's CPU loops do not vectorise over a trailing
    axis of 3 channels."""
    return jnp.moveaxis(_floating(image), -1, 0)


def _floating(image: Array) -> Array:
    """A floating [H, W, C] image (float32 unless it is floating already)."""
    dtype = image.dtype if jnp.issubdtype(image.dtype, jnp.floating) else jnp.float32
    return jnp.asarray(image).astype(dtype)


def _crop_planes(image: Array, box: Array, config: HOGConfig, border: int = 0) -> Array:
    """`crop` of a floating [H, W, C] image as colour planes: [C, rows + 2 border,
    cols + 2 border], the window with ``border`` more samples of the same grid on each side.
    Gathered from the image as it is laid out (each pixel's C channels together; planes of the
    whole image first cost a transpose of every pixel, 0.1 ms of a QVGA frame on a CPU)."""
    rows, cols = config.window
    H, W = image.shape[:2]
    dtype = image.dtype
    box = jnp.asarray(box, dtype)
    r = box[0] + (jnp.arange(-border, rows + border, dtype=dtype) + 0.5) * (box[2] - box[0]) \
        / rows - 0.5
    c = box[1] + (jnp.arange(-border, cols + border, dtype=dtype) + 0.5) * (box[3] - box[1]) \
        / cols - 0.5
    r = jnp.clip(r, 0, H - 1)
    c = jnp.clip(c, 0, W - 1)
    r0 = jnp.clip(jnp.floor(r), 0, max(H - 2, 0)).astype(jnp.int32)
    c0 = jnp.clip(jnp.floor(c), 0, max(W - 2, 0)).astype(jnp.int32)
    fr = (r - r0)[:, None]
    fc = (c - c0)[None, :]
    r1, c1 = jnp.minimum(r0 + 1, H - 1), jnp.minimum(c0 + 1, W - 1)
    # the window's own pixels (image[r0][:, c0] would first copy whole image rows)
    r0, r1, c0, c1 = r0[:, None], r1[:, None], c0[None], c1[None]
    px = lambda r, c: jnp.moveaxis(image[r, c], -1, 0)     # noqa: E731  [C, R, C']
    top = px(r0, c0) * (1 - fc) + px(r0, c1) * fc
    bot = px(r1, c0) * (1 - fc) + px(r1, c1) * fc
    return top * (1 - fr) + bot * fr


def _descriptor(planes: Array, config: HOGConfig) -> Array:
    """[B, F] `hog` of B windows' [B, C, rows + 2, cols + 2] colour planes: each window with
    one more pixel on every side, which only its gradients read."""
    B, n_ch, R, C = planes.shape[0], planes.shape[1], planes.shape[2] - 2, planes.shape[3] - 2
    # Centred differences, zero on the window's own border as skimage's; computed from the
    # bordered window inside one fusion (padded gradient arrays cost more than the rest).
    row, col = jnp.arange(R)[:, None], jnp.arange(C)[None]
    inner_r, inner_c = (row > 0) & (row < R - 1), (col > 0) & (col < C - 1)
    gr = gc = mag = None
    for ch in range(n_ch):
        q = planes[:, ch]
        g_row = jnp.where(inner_r, q[:, 2:, 1:-1] - q[:, :-2, 1:-1], 0)
        g_col = jnp.where(inner_c, q[:, 1:-1, 2:] - q[:, 1:-1, :-2], 0)
        # (hypot, not squares: 8-bit images tie often, and the tie must break as skimage's)
        m = jnp.hypot(g_row, g_col)
        if ch == 0:
            gr, gc, mag = g_row, g_col, m
        else:                               # the first channel of the largest magnitude
            larger = m > mag
            gr = jnp.where(larger, g_row, gr)
            gc = jnp.where(larger, g_col, gc)
            mag = jnp.where(larger, m, mag)
    # The unsigned orientation's bin, floor(angle / (180 / n)) with the angle of (gc, gr) in
    # [0, 180): the gradient is turned into the upper half-plane, and the bin counts the
    # boundaries k 180 / n it lies at or past, sign(sin(angle - theta_k)). The same bins as
    # skimage's arctan2, which took 90 % of the descriptor's time on a CPU.
    n = config.orientations
    flip = (gr < 0) | ((gr == 0) & (gc < 0))
    gr, gc = jnp.where(flip, -gr, gr), jnp.where(flip, -gc, gc)
    b = jnp.zeros(gr.shape, jnp.int32)
    for k in range(1, n):
        theta = math.pi * k / n
        b += (gr * math.cos(theta) - gc * math.sin(theta) >= 0).astype(jnp.int32)
    cs = config.cell
    nr, nc = R // cs, C // cs
    # The cells' histograms: one segment sum over all windows, of materialised bins and
    # magnitudes (fused into the scatter's [N, 1] index, the pixels' arithmetic ran as scalar
    # code: 2.7x slower).
    b, mag = materialised(b[:, :nr * cs, :nc * cs]), materialised(mag[:, :nr * cs, :nc * cs])
    cell = (jnp.arange(nr * cs)[:, None] // cs) * nc + jnp.arange(nc * cs)[None] // cs
    seg = ((jnp.arange(B)[:, None, None] * (nr * nc) + cell) * n + b).reshape(-1)
    cells = jax.ops.segment_sum(mag.reshape(-1), seg, B * nr * nc * n).reshape(
        B, nr, nc, n) / (cs * cs)
    bs = config.block
    br, bc = nr - bs + 1, nc - bs + 1
    blocks = jnp.stack([jnp.stack([cells[:, i:i + bs, j:j + bs] for j in range(bc)], 1)
                        for i in range(br)], 1)                     # [B, br, bc, bs, bs, n]
    eps = 1e-5
    v = blocks / jnp.sqrt(jnp.sum(blocks ** 2, (3, 4, 5), keepdims=True) + eps ** 2)
    v = jnp.minimum(v, 0.2)
    v = v / jnp.sqrt(jnp.sum(v ** 2, (3, 4, 5), keepdims=True) + eps ** 2)
    return v.reshape(B, -1)


def svm_confidence(svm: LinearSVM, features: Array) -> Array:
    r"""Confidence :math:`\sigma(w^T f + b)` of [..., F] features, in (0, 1)."""
    w = jnp.asarray(svm.weights)
    return jax.nn.sigmoid(features @ w.astype(features.dtype) + jnp.asarray(svm.bias,
                                                                            features.dtype))


def load_svm(name: str = "hog_svm.npz", dtype=jnp.float32) -> LinearSVM:
    """The shipped SVM (``jaxtrack train-hog`` writes it), as a `LinearSVM`."""
    ref = importlib.resources.files("jaxtrack.perception") / "data" / name
    with importlib.resources.as_file(ref) as path, np.load(path) as data:
        return LinearSVM(jnp.asarray(data["weights"], dtype), jnp.asarray(data["bias"], dtype))
