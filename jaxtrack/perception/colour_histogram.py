r"""Colour histograms of image regions and their Bhattacharyya likelihood: the observation model
of a colour-based particle filter (Nummiaro, Koller-Meier & Van Gool, "An adaptive color-based
particle filter", 2003; after Comaniciu, Ramesh & Meer's kernel histograms), which seed 000
compares with its depth tracker in Experiment 1 (section 5.2).

- `features`: pixels in RGB or HSV (`to_hsv`, the hexcone of ``colorsys``), each channel in
  [0, 1].
- `bin_weights`: every pixel's share of each of the :math:`B = b_1 b_2 b_3` bins. ``"hard"``
  is the usual indicator (``np.histogramdd`` with equal bins on [0, 1]); ``"soft"`` splits a
  value between the two nearest bin centres by linear interpolation (a triangular kernel one
  bin wide; hue wraps around), so a histogram is continuous, and differentiable almost
  everywhere, in the colours.
- `histogram`: the normalised histogram of a masked set of pixels with weights.
- `kernel_histograms`: the histograms of circular regions of radius :math:`a` centred on
  :math:`N` points (particles), pixels weighted by the Epanechnikov profile
  :math:`k(r) = \max(0, 1 - r^2/a^2)` of their distance to the centre,

  .. math:: p_u(\mathbf{y}) = \frac{\sum_i k(\|\mathbf{x}_i - \mathbf{y}\|)\, b_u(c_i)}
     {\sum_i k(\|\mathbf{x}_i - \mathbf{y}\|)},

  smooth in the centre :math:`\mathbf{y}` (pixels far from the centre count less: they are the
  ones most likely to be background or occluded).
- `bhattacharyya`: :math:`\rho[p, q] = \sum_u \sqrt{p_u q_u}` (1 for identical histograms, 0
  for disjoint ones), and `log_likelihood`, the particle weight
  :math:`\log w = -\lambda\, d^2` with :math:`d^2 = 1 - \rho` (Nummiaro et al.'s
  :math:`\exp(-d^2 / 2\sigma^2)`, :math:`\lambda = 1/2\sigma^2`).
- `ratio_histogram` and `backprojection`: Swain & Ballard's histogram back-projection
  ("Color indexing", 1991), :math:`R_u = \min(M_u / I_u, 1)` of a model histogram :math:`M`
  over an image histogram :math:`I`, read back at each pixel: how much a pixel's colour is the
  model's rather than the scene's (the colour tracker's foreground for its PCA heading).

Empty regions (no valid pixel, or all kernel weights zero) have the all-zero histogram, whose
Bhattacharyya coefficient with anything is 0 (the largest distance, :math:`d^2 = 1`).

All functions are pure, jittable and vmappable; masked pixels never count.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import _checks

Array = jax.Array

__all__ = ["HistogramConfig", "SPACES", "BINNINGS", "to_hsv", "features", "bin_weights",
           "histogram", "kernel_histograms", "bhattacharyya", "log_likelihood",
           "ratio_histogram", "backprojection"]

SPACES = ("rgb", "hsv")
BINNINGS = ("soft", "hard")


class HistogramConfig(NamedTuple):
    """How pixels are binned (static).

    Attributes:
      space: "rgb" or "hsv" (hue, saturation, value; hue wraps around).
      bins: bins per channel, e.g. (8, 8, 8) in RGB or (8, 8, 4) in HSV, Nummiaro et al.'s
        choices (HSV with fewer value bins is less sensitive to the brightness).
      binning: "soft" (linear interpolation between bin centres, differentiable) or "hard".
    """

    space: str = "rgb"
    bins: tuple = (8, 8, 8)
    binning: str = "soft"

    @property
    def num_bins(self) -> int:
        return int(np.prod(self.bins))


def to_hsv(rgb: Array) -> Array:
    r"""RGB [..., 3] in [0, 1] to HSV [..., 3] in [0, 1] (hue in turns), the hexcone of
    ``colorsys.rgb_to_hsv``: :math:`V = \max`, :math:`S = (V - \min)/V`, and the hue from the
    largest channel (red first, then green, then blue on ties); grey pixels get hue 0 and
    black ones saturation 0. Divisions only see safe arguments, so gradients stay finite.

    Example:
      >>> to_hsv(jnp.array([1.0, 0.5, 0.0]))      # [1/12, 1, 1]
    """
    rgb = jnp.asarray(rgb)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    v = jnp.max(rgb, -1)
    c = v - jnp.min(rgb, -1)
    s = jnp.where(v > 0, c / jnp.where(v > 0, v, 1.0), 0.0)
    cs = jnp.where(c > 0, c, 1.0)
    h = jnp.where(r == v, (g - b) / cs, jnp.where(g == v, 2.0 + (b - r) / cs,
                                                 4.0 + (r - g) / cs))
    h = jnp.where(c > 0, jnp.mod(h / 6.0, 1.0), 0.0)
    return jnp.stack([h, s, v], -1)


def features(rgb: Array, space: str = "rgb") -> Array:
    """Pixels [..., 3] in the histogram's colour space, each channel in [0, 1]; RGB values
    outside [0, 1] are saturated first (as a camera does).

    Example:
      >>> f = features(image, "hsv")
    """
    _checks.check_options("space", (space,), SPACES)
    _check_pixels("rgb", rgb)
    rgb = jnp.clip(jnp.asarray(rgb), 0.0, 1.0)
    return to_hsv(rgb) if space == "hsv" else rgb


def bin_weights(feats: Array, config: HistogramConfig = HistogramConfig()) -> Array:
    r"""Each pixel's share [..., B] of the :math:`B = b_1 b_2 b_3` bins (C order: channel 1
    slowest, as ``np.histogramdd(...).ravel()``); rows sum to 1.

    Hard: channel value :math:`v` goes to bin :math:`\min(\lfloor v b \rfloor, b - 1)`.
    Soft: with :math:`s = v b - 1/2` (bin centres at integers), bin :math:`k` gets
    :math:`\max(0, 1 - |s - k|)`, with :math:`s` clamped to :math:`[0, b - 1]` on linear
    channels (the outer half-bins belong to the end bins) and distances taken around the
    circle on the hue; the joint share is the product of the channels'.

    Args:
      feats: [..., 3] `features` in [0, 1]; config: `HistogramConfig`.

    Example:
      >>> w = bin_weights(features(pixels))        # [P, 512]
    """
    _check_config(config)
    _check_pixels("feats", feats)
    feats = jnp.asarray(feats)
    circular = (config.space == "hsv", False, False)
    per_channel = [_channel(feats[..., c], n, config.binning, circular[c])
                   for c, n in enumerate(config.bins)]
    w = per_channel[0][..., :, None, None] * per_channel[1][..., None, :, None] \
        * per_channel[2][..., None, None, :]
    return w.reshape(*feats.shape[:-1], config.num_bins)


def histogram(rgb: Array, mask: Array | None = None, weights: Array | None = None,
              config: HistogramConfig = HistogramConfig()) -> Array:
    r"""Normalised colour histogram [B] of a set of pixels,
    :math:`p_u = \sum_i w_i b_u(c_i) / \sum_i w_i` over the valid pixels.

    Args:
      rgb: [P, 3] pixels in [0, 1]; mask: [P] bools (None: all); weights: [P] >= 0 (None:
        ones); config: `HistogramConfig`.

    Returns:
      [B] histogram summing to 1, or all zeros when no valid pixel has weight.

    Example:
      >>> q = histogram(image.reshape(-1, 3))
    """
    _checks.check_shape("rgb", rgb, (None, 3), "[P, 3] pixels")
    n = _checks.shape_of(rgb)[0]
    mask = _mask(rgb, mask, n)
    _check_pixels("rgb", rgb, mask)
    w = jnp.ones((n,), jnp.result_type(jnp.asarray(rgb).dtype, jnp.float32)) \
        if weights is None else weights
    _checks.check_shape("weights", w, (n,), "one weight per pixel")
    _check_nonnegative("weights", w)
    rgb = jnp.where(mask[:, None], jnp.asarray(rgb), 0.0)
    b = bin_weights(features(rgb, config.space), config)
    w = jnp.where(mask, jnp.asarray(w, b.dtype), 0.0)
    return _normalise(w @ b)


def kernel_histograms(rgb: Array, pixel_xy: Array, centres: Array, radius,
                      mask: Array | None = None,
                      config: HistogramConfig = HistogramConfig()) -> Array:
    r"""Epanechnikov-weighted histograms [N, B] of the circular regions of radius :math:`a`
    around ``centres`` (module docstring: :math:`p_u(\mathbf{y})`).

    Args:
      rgb: [P, 3] pixels in [0, 1] (a fixed-size block of the image, flattened).
      pixel_xy: [P, 2] each pixel's position in the plane the regions live in (e.g. world
        metres at the height of the target).
      centres: [N, 2] region centres (particles); radius: :math:`a > 0`, same units.
      mask: [P] valid pixels (None: all); config: `HistogramConfig`.

    Returns:
      [N, B] histograms, each summing to 1, or all zeros for a region with no valid pixel.

    Example:
      >>> p = kernel_histograms(block, block_xy, particles, 0.15)     # [N, B]
    """
    _checks.check_shape("rgb", rgb, (None, 3), "[P, 3] pixels")
    n = _checks.shape_of(rgb)[0]
    _checks.check_shape("pixel_xy", pixel_xy, (n, 2), "one (x, y) per pixel")
    _checks.check_shape("centres", centres, (None, 2), "[N, 2] region centres")
    _checks.check_finite("pixel_xy", pixel_xy)
    _checks.check_finite("centres", centres)
    _check_positive("radius", radius)
    mask = _mask(rgb, mask, n)
    _check_pixels("rgb", rgb, mask)
    dtype = jnp.result_type(jnp.asarray(rgb).dtype, jnp.asarray(centres).dtype, jnp.float32)
    mask = mask & jnp.all(jnp.isfinite(jnp.asarray(pixel_xy)), -1)
    rgb = jnp.where(mask[:, None], jnp.asarray(rgb, dtype), 0.0)
    xy = jnp.where(mask[:, None], jnp.asarray(pixel_xy, dtype), 0.0)
    b = bin_weights(features(rgb, config.space), config)                     # [P, B]
    d = jnp.asarray(centres, dtype)[:, None, :] - xy[None]                   # [N, P, 2]
    k = jnp.maximum(1.0 - jnp.sum(d * d, -1) / jnp.asarray(radius, dtype) ** 2, 0.0)
    k = jnp.where(mask[None], k, 0.0)
    return _normalise(k @ b)


def bhattacharyya(p: Array, q: Array) -> Array:
    r"""Bhattacharyya coefficient :math:`\rho[p, q] = \sum_u \sqrt{p_u q_u}` over the last
    axis (broadcast over the leading ones): 1 for identical normalised histograms, 0 for
    disjoint ones or an empty (all-zero) histogram. The square root is taken only of positive
    products: the derivative of an empty bin's term is 0 (it is infinite in exact arithmetic).

    Example:
      >>> rho = bhattacharyya(p, q)          # p [N, B], q [B] -> [N]
    """
    pq = jnp.asarray(p) * jnp.asarray(q)
    _checks.check_finite("p", p)
    _checks.check_finite("q", q)
    pos = pq > 0
    return jnp.sum(jnp.where(pos, jnp.sqrt(jnp.where(pos, pq, 1.0)), 0.0), -1)


def log_likelihood(p: Array, reference: Array, lam) -> Array:
    r"""Particle log-weight :math:`-\lambda\,(1 - \rho[p, q])` of histograms ``p`` [..., B]
    against the ``reference`` :math:`q` [B] (Nummiaro et al.; :math:`\lambda = 1/2\sigma^2`).

    Example:
      >>> ll = log_likelihood(kernel_histograms(block, xy, particles, 0.15), q, 50.0)
    """
    _check_positive("lam", lam)
    return -lam * (1.0 - bhattacharyya(p, reference))


def ratio_histogram(model: Array, image: Array) -> Array:
    r"""Swain & Ballard's ratio histogram :math:`R_u = \min(M_u / I_u, 1)` ([B]; 0 where
    :math:`I_u = 0`).

    Example:
      >>> R = ratio_histogram(q, histogram(first_image.reshape(-1, 3)))
    """
    _checks.check_shape("image", image, _checks.shape_of(model), "same bins as the model")
    _check_nonnegative("model", model)
    _check_nonnegative("image", image)
    model, image = jnp.asarray(model), jnp.asarray(image)
    pos = image > 0
    return jnp.where(pos, jnp.minimum(model / jnp.where(pos, image, 1.0), 1.0), 0.0)


def backprojection(rgb: Array, ratio: Array, config: HistogramConfig = HistogramConfig()
                   ) -> Array:
    r"""The ratio histogram read back at each pixel, :math:`\sum_u b_u(c_i) R_u` ([...] in
    [0, 1]): large where a pixel's colour belongs to the model rather than the scene.

    Example:
      >>> fg = backprojection(block, R) > 0.5
    """
    _check_config(config)
    _checks.check_shape("ratio", ratio, (config.num_bins,), "one value per bin")
    return bin_weights(features(rgb, config.space), config) @ jnp.asarray(ratio)


# ---------------------------------------------------------------------------------------------
# Private helpers


def _channel(v, n: int, binning: str, circular: bool):
    """[..., n] shares of one channel's bins."""
    dtype = v.dtype
    k = jnp.arange(n, dtype=dtype)
    if binning == "hard":
        idx = jnp.clip(jnp.floor(v * n), 0, n - 1)
        return (idx[..., None] == k).astype(dtype)
    s = v * n - 0.5
    if circular:
        d = jnp.abs(jnp.mod(s[..., None] - k + 0.5 * n, n) - 0.5 * n)
    else:
        d = jnp.abs(jnp.clip(s, 0.0, n - 1.0)[..., None] - k)
    return jnp.maximum(1.0 - d, 0.0)


def _normalise(h):
    total = jnp.sum(h, -1, keepdims=True)
    pos = total > 0
    return jnp.where(pos, h / jnp.where(pos, total, 1.0), 0.0)


def _mask(rgb, mask, n):
    if mask is None:
        return jnp.ones((n,), bool)
    _checks.check_shape("mask", mask, (n,), "one bool per pixel")
    return jnp.asarray(mask, bool)


def _check_config(config):
    if not isinstance(config, HistogramConfig):
        raise TypeError(f"config must be a HistogramConfig; got {type(config).__name__}")
    _checks.check_options("space", (config.space,), SPACES)
    _checks.check_options("binning", (config.binning,), BINNINGS)
    if len(config.bins) != 3 or not all(isinstance(b, (int, np.integer)) and b >= 1
                                        for b in config.bins):
        raise ValueError(f"bins must be three positive ints; got {config.bins}")


def _check_pixels(name, x, mask=None):
    """The last axis holds 3 channels; no NaN in the valid pixels (when concrete)."""
    shape = _checks.shape_of(x)
    if len(shape) < 1 or shape[-1] != 3:
        raise ValueError(f"{name} must be [..., 3] colours; got shape {list(shape)}")
    if _checks.is_concrete(x) and (mask is None or _checks.is_concrete(mask)):
        a = np.asarray(x)
        if mask is not None:
            a = a[np.asarray(mask, bool)]
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} contains NaN or inf in valid pixels (mask them)")


def _check_positive(name, x):
    _checks.check_finite(name, x)
    if _checks.is_concrete(x) and not float(x) > 0:
        raise ValueError(f"{name} must be > 0; got {x}")


def _check_nonnegative(name, x):
    _checks.check_finite(name, x)
    if _checks.is_concrete(x) and np.any(np.asarray(x) < 0):
        raise ValueError(f"{name} must be >= 0")

