r"""A colour-histogram particle filter of a humanoid under a ceiling colour camera: the tracker
seed 000 compares with its depth tracker in Experiment 1 (section 5.2), Nummiaro et al.'s
colour-based particle filter with the reference histogram taken from the first frame.

State: particles over the robot's floor position (x, y), as the depth tracker `humanoid.depth_pf`.
Each frame:

1. **Block.** A fixed ``K`` x ``K`` block of the image is cut around the projection of the
   previous estimate (`block_size`: large enough for the particles' regions);
   its pixels are placed in the world at the height of the regions,
   :math:`\mathbf{x}_i = \mathbf{c}_{xy} + (c_z - h)\,((j + \tfrac12 - c_x)/f_x,
   -(i + \tfrac12 - c_y)/f_y)` for pixel (i, j) of a camera at :math:`\mathbf{c}` (a region
   on the robot's shoulders is a disc of the image).
2. **SIR.** Resample, propagate by a Gaussian random walk, weight each particle
   :math:`\mathbf{y}` by :math:`\log w = -\lambda (1 - \rho[p(\mathbf{y}), q])`: the
   Bhattacharyya coefficient between the Epanechnikov-weighted histogram of the disc of radius
   :math:`a` at the particle (`colour_histogram.kernel_histograms`) and the reference
   :math:`q`; the position is the weighted mean.
3. **Heading.** The seed gets the heading by PCA in both of its trackers (section 3.1.2); with
   colour alone there are no points, so the colour tracker fits the PCA ellipse to the block's
   *foreground pixels*: those whose back-projection through Swain & Ballard's ratio histogram
   :math:`R = \min(q / I, 1)` (:math:`I`: the histogram of the first frame's block, the
   scene around the start) is at least ``foreground``, i.e. whose colour is the robot's
   rather than the floor's. The same
   `depth.pca_heading` (continuity window, smoothing) then runs on their world positions. No
   depth enters the colour tracker.

`init` takes a `ColourPrior`: the start pose (the seed's user clicks it on the first image) and
the first image, from which the reference :math:`q` (the disc at the start) and :math:`I` (the
block around it) are taken once and kept.

Example:
  >>> est = colour_pf(ColourPFConfig(camera))
  >>> params = est.params(position_noise=0.035, lam=50.0)
  >>> state = est.init(key, params, ColourPrior(start, first_image, valid))
  >>> state, pose = est.update(key, state, ColourFrame(image, valid, 0.0), params)
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxtrack import _checks
from jaxtrack.angles import wrap
from jaxtrack.filters import particle
from jaxtrack.perception import colour_histogram as ch
from jaxtrack.perception import depth
from jaxtrack.tracking.estimator import Estimator
from jaxtrack.tracking.humanoid import HeadingConfig, SmoothConfig

Array = jax.Array

__all__ = ["ColourFrame", "ColourPrior", "ColourPFParams", "ColourPFConfig", "ColourPFState",
           "colour_pf", "make_params", "block_size"]


class ColourFrame(NamedTuple):
    """One frame of the ceiling colour camera.

    Attributes:
      image: [H, W, 3] RGB in [0, 1]; valid: [H, W] bools (invalid pixels never count).
      turn_rate: the turn rate commanded over the last frame (rad/s), for
        ``HeadingConfig.turn_prediction``.
    """

    image: Array
    valid: Array
    turn_rate: Array


class ColourPrior(NamedTuple):
    """What `colour_pf`'s ``init`` starts from: pose [3] (x, y, theta), the first image
    [H, W, 3] and its valid pixels [H, W]."""

    pose: Array
    image: Array
    valid: Array


class ColourPFParams(NamedTuple):
    """Tunable parameters (traced leaves).

    Attributes:
      log_position_noise: log std (m) of the random-walk propagation per frame.
      log_lam: log :math:`\\lambda` of the weight :math:`\\exp(-\\lambda(1 - \\rho))`.
    """

    log_position_noise: Array
    log_lam: Array


@dataclasses.dataclass(frozen=True)
class ColourPFConfig:
    """Static configuration of `colour_pf` (defaults ours, unless stated).

    Attributes:
      camera: `depth.CeilingCamera` (pinhole, looking straight down).
      num_particles: N. init_spread: std (m) of the initial cloud around the start.
      histogram: `colour_histogram.HistogramConfig` (RGB 8 x 8 x 8 soft bins by default, the
        bins of Nummiaro et al.).
      region_radius: :math:`a`, radius (m) of the disc whose histogram a particle sees (0.15:
        the robot seen from above, 0.27 m across the shoulders with the arms).
      region_height: height (m) of the disc above the floor (0.4: the shoulders).
      block_radius: half-size (m, at ``region_height``) of the image block cut around the
        previous estimate: the discs of the particles must fit in it (0.3: the region plus
        three propagation stds and a frame's walk).
      foreground: back-projection threshold of the heading's foreground pixels.
      heading: `humanoid.HeadingConfig` of the PCA heading (the depth tracker's defaults).
    """

    camera: depth.CeilingCamera
    num_particles: int = 128
    init_spread: float = 0.02
    histogram: ch.HistogramConfig = ch.HistogramConfig()
    region_radius: float = 0.15
    region_height: float = 0.4
    block_radius: float = 0.3
    foreground: float = 0.8
    heading: HeadingConfig = HeadingConfig()

    def __post_init__(self):
        if self.num_particles < 1:
            raise ValueError(f"num_particles must be >= 1; got {self.num_particles}")
        for name in ("init_spread", "region_radius", "block_radius"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite positive number; got {value}")
        if not 0 <= self.region_height < self.camera.position[2]:
            raise ValueError(f"region_height must be in [0, camera height); got "
                             f"{self.region_height}")
        if not 0 < self.foreground <= 1:
            raise ValueError(f"foreground must be in (0, 1]; got {self.foreground}")
        ch.bin_weights(jnp.zeros((1, 3)), self.histogram)   # checks the histogram config


class ColourPFState(NamedTuple):
    """particles: `particle.ParticleSet` [N, 2]; heading: the heading estimate; reference: [B]
    the first frame's histogram :math:`q`; ratio: [B] the ratio histogram :math:`R` of the
    heading's foreground."""

    particles: particle.ParticleSet
    heading: Array
    reference: Array
    ratio: Array


class _Block(NamedTuple):
    rgb: Array      # [K*K, 3]
    xy: Array       # [K*K, 2] world (x, y) at the region height
    mask: Array     # [K*K]


def block_size(config: ColourPFConfig) -> int:
    """Side K (pixels) of the image block of `colour_pf` (``block_radius`` at
    ``region_height`` seen by the camera, plus a pixel each side).

    Example:
      >>> block_size(ColourPFConfig(camera))      # 22 for the 80 x 60 scene at 2.8 m
    """
    cam = config.camera
    scale = max(cam.fx, cam.fy) / (cam.position[2] - config.region_height)
    return int(math.ceil(2.0 * config.block_radius * scale) + 2)


def colour_pf(config: ColourPFConfig, dt: float = 0.25,
              smooth: SmoothConfig | None = None) -> Estimator:
    """The colour-histogram particle tracker (module docstring) at frame period ``dt`` (s);
    ``smooth``: `humanoid.SmoothConfig` for differentiable resampling (its ``resampling``;
    the histogram likelihood is already smooth), or None for SIR with systematic resampling.

    Example:
      >>> est = colour_pf(ColourPFConfig(ceiling_camera), dt=0.25)
    """
    n = config.num_particles
    k = block_size(config)
    resampler = particle.systematic if smooth is None else smooth.resampler()
    hist_cfg = config.histogram

    def init(key, params: ColourPFParams, prior: ColourPrior) -> ColourPFState:
        start = jnp.asarray(prior.pose)
        _checks.check_shape("prior.pose", start, (3,), "(x, y, theta)")
        dtype = start.dtype
        block = _cut(config, k, prior.image, prior.valid, start[:2])
        q = ch.kernel_histograms(block.rgb, block.xy, start[None, :2], config.region_radius,
                                 block.mask, hist_cfg)[0]
        scene = ch.histogram(block.rgb, block.mask, config=hist_cfg)
        eps = jax.random.normal(key, (n, 2), dtype)
        ps = particle.ParticleSet(start[:2] + config.init_spread * eps,
                                  jnp.full((n,), -math.log(n), dtype))
        return ColourPFState(ps, start[2], q.astype(dtype),
                             ch.ratio_histogram(q, scene).astype(dtype))

    def update(key, state: ColourPFState, z: ColourFrame, params: ColourPFParams):
        dtype = state.heading.dtype
        sigma = jnp.exp(params.log_position_noise).astype(dtype)
        lam = jnp.exp(params.log_lam).astype(dtype)
        prev = particle.weighted_mean(state.particles)
        block = _cut(config, k, z.image, z.valid, prev)

        def loglik(b: _Block, x):
            p = ch.kernel_histograms(b.rgb, b.xy, x, config.region_radius, b.mask, hist_cfg)
            return ch.log_likelihood(p, state.reference, lam)

        ps, _ = particle.step(
            key, state.particles, block,
            lambda kk, x: x + sigma * jax.random.normal(kk, x.shape, x.dtype),
            loglik, resampler, vectorized=True)
        position = particle.weighted_mean(ps)
        fg = block.mask & (ch.backprojection(block.rgb, state.ratio, hist_cfg)
                           >= config.foreground)
        h = config.heading
        prior_heading = wrap(state.heading + z.turn_rate * dt) if h.turn_prediction \
            else state.heading
        heading = depth.pca_heading(block.xy, fg, position, h.pca_radius, prior_heading,
                                    h.window, h.gain).heading
        est = jnp.concatenate([position, heading[None]])
        return state._replace(particles=ps, heading=heading), est

    return Estimator(make_params, init, update, "colour_pf")


def make_params(*, position_noise=0.035, lam=50.0, dtype=jnp.float32) -> ColourPFParams:
    """`ColourPFParams` from natural values (the estimator's ``params``): the propagation std
    (m) and :math:`\\lambda` (50: :math:`\\sigma = 0.1` in :math:`\\exp(-d^2/2\\sigma^2)`,
    ours), both finite and positive.

    Example:
      >>> params = make_params(position_noise=0.03, lam=20.0)
    """
    for name, value in (("position_noise", position_noise), ("lam", lam)):
        if _checks.is_concrete(value) and not (math.isfinite(float(value)) and float(value) > 0):
            raise ValueError(f"{name} must be a finite positive number; got {value}")
    return ColourPFParams(_log(position_noise, dtype), _log(lam, dtype))


def _cut(config: ColourPFConfig, k: int, image, valid, centre) -> _Block:
    """The K x K block of the image around the projection of ``centre`` [2] (clipped to the
    image; no gradient through its placement), its pixels at the region height."""
    _checks.check_ndim("image", image, 3, "[H, W, 3] RGB image")
    H, W, C = _checks.shape_of(image)
    if C != 3:
        raise ValueError(f"image must be [H, W, 3]; got {[H, W, C]}")
    _checks.check_shape("valid", valid, (H, W), "one flag per pixel")
    if H < k or W < k:
        raise ValueError(f"the image ({H} x {W}) is smaller than the tracker's {k} x {k} "
                         "block: lower block_radius")
    cam = config.camera
    image = jnp.asarray(image)
    dtype = jnp.result_type(image.dtype, jnp.float32)
    centre = lax.stop_gradient(jnp.asarray(centre, dtype))
    height = cam.position[2] - config.region_height
    u = cam.cx + cam.fx * (centre[0] - cam.position[0]) / height
    v = cam.cy - cam.fy * (centre[1] - cam.position[1]) / height
    finite = jnp.isfinite(u) & jnp.isfinite(v)
    col = jnp.clip(jnp.round(jnp.where(finite, u, cam.cx) - k / 2.0), 0, W - k).astype(jnp.int32)
    row = jnp.clip(jnp.round(jnp.where(finite, v, cam.cy) - k / 2.0), 0, H - k).astype(jnp.int32)
    rgb = lax.dynamic_slice(image.astype(dtype), (row, col, jnp.int32(0)), (k, k, 3))
    ok = lax.dynamic_slice(jnp.asarray(valid, bool), (row, col), (k, k))
    ok = ok & jnp.all(jnp.isfinite(rgb), -1)
    xy = depth.back_project(cam, jnp.full((k, k), height, dtype), ok, row, col)[:, :2]
    return _Block(jnp.where(ok[..., None], rgb, 0.0).reshape(-1, 3), xy, ok.reshape(-1))


def _log(x, dtype):
    if _checks.is_concrete(x):
        return jnp.asarray(math.log(float(x)), dtype)
    return jnp.log(x).astype(dtype)
