r"""Trackers of a humanoid seen from above by a ceiling depth camera (seed 000), as estimators.

Each is an `jaxtrack.tracking.estimator.Estimator` whose measurement is a `DepthScan` (the
floor-removed points of the robot's window, world frame, fixed capacity with a mask, and the
turn rate commanded over the last frame) and whose estimate is the pose ``[x, y, theta]``:

- `depth_pf` (``"pf"``, the seed's tracker): SIR over (x, y) with the point-count likelihood of
  `jaxtrack.perception.depth` rotated by the last heading, then the PCA heading with its
  continuity window;
- `depth_pf3` (``"pf3"``): SIR over (x, y, theta) with the same likelihood and a heading random
  walk driven by the commanded turn; the likelihood is symmetric under a half turn, so the
  heading particles are folded to the half-circle of the previous estimate
  (`depth.fold_half_turn`) before their circular mean;
- `centroid_ukf` (``"ukf"``): a constant-velocity UKF on the centroid of the points near the
  prediction, with the PCA heading.

The parameters (`DepthTrackerParams`) are the propagation noise and the likelihood temperature,
both traced leaves; a `SmoothConfig` makes the particle trackers differentiable (sigmoid-edged
counts, differentiable resampling) for gradient tuning, chosen when the tracker is built.

Example:
  >>> est = depth_pf(DepthPFConfig(num_particles=128), dt=0.25)
  >>> params = est.params(position_noise=0.035)
  >>> state = est.init(key, params, jnp.zeros(3))
  >>> state, pose = est.update(key, state, DepthScan(points, mask, 0.0), params)
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxtrack import _checks
from jaxtrack.angles import wrap
from jaxtrack.filters import kalman, particle, ukf
from jaxtrack.perception import depth
from jaxtrack.tracking.estimator import Estimator

Array = jax.Array

__all__ = ["DepthScan", "DepthTrackerParams", "HeadingConfig", "SmoothConfig", "DepthPFConfig",
           "DepthPF3Config", "CentroidUKFConfig", "ParticleTrackerState", "UKFTrackerState",
           "depth_pf", "depth_pf3", "centroid_ukf", "build", "TRACKERS"]

TRACKERS = ("pf", "pf3", "ukf")


class DepthScan(NamedTuple):
    """One frame of the ceiling camera.

    Attributes:
      points: [P, 3] floor-removed points (world frame, z up); mask: [P].
      turn_rate: the turn rate commanded over the last frame (rad/s), a control input.
    """

    points: Array
    mask: Array
    turn_rate: Array


class DepthTrackerParams(NamedTuple):
    """Tunable parameters (traced leaves).

    Attributes:
      log_position_noise: log std (m) of the random-walk propagation per frame.
      log_temperature: None for the seed's weight log(n + 1), or log T of the tempered weight
        exp(n / T) of `depth.log_likelihood` (particle trackers).
    """

    log_position_noise: Array
    log_temperature: Array | None = None


@dataclasses.dataclass(frozen=True)
class HeadingConfig:
    """The seed's PCA heading (`depth.pca_heading`, section 3.1.2).

    Attributes:
      pca_radius: PCA window radius (m), larger than the robot model.
      window: continuity window (rad, 20 deg): the largest heading change per frame.
      gain: smoothing gain in (0, 1] (the seed smooths but prints no factor).
      turn_prediction: predict the heading with the commanded turn, theta + omega dt, before
        the PCA update (the seed has none: False). The smoothed heading otherwise lags a
        turning robot (measurements: docs/design_notes.md, "Humanoid: turn prediction of the
        PCA heading").
    """

    pca_radius: float = 0.25
    window: float = math.radians(20.0)
    gain: float = 0.5
    turn_prediction: bool = False

    def __post_init__(self):
        if not (self.pca_radius > 0 and self.window > 0 and 0 < self.gain <= 1):
            raise ValueError("need pca_radius > 0, window > 0 and 0 < gain <= 1")


@dataclasses.dataclass(frozen=True)
class SmoothConfig:
    """The differentiable variant of the particle trackers, for gradient tuning.

    Attributes:
      softness: edge width (m) of the sigmoid-edged point count.
      resampling: "stop_gradient" (Scibior & Wood: an unbiased score of the expected estimate,
        whose variance grows with the horizon) or "ot" (entropy-regularised optimal transport,
        ``ot_epsilon``: a pathwise-differentiable surrogate).
    """

    softness: float = 0.01
    resampling: str = "stop_gradient"
    ot_epsilon: float = 0.1

    def __post_init__(self):
        _checks.check_options("smooth resampling", (self.resampling,), ("stop_gradient", "ot"))
        if not self.softness > 0:
            raise ValueError(f"softness must be > 0; got {self.softness}")

    def resampler(self):
        if self.resampling == "ot":
            return particle.optimal_transport_resampling(self.ot_epsilon)
        return particle.stop_gradient_resampling()


@dataclasses.dataclass(frozen=True)
class DepthPFConfig:
    """The seed's tracker (``"pf"``): particles over (x, y), the PCA heading.

    Attributes:
      num_particles: N. init_spread: std (m) of the initial cloud around the start.
      model: `depth.RobotModel` of the likelihood. heading: `HeadingConfig`.
    """

    num_particles: int = 128
    init_spread: float = 0.02
    model: depth.RobotModel = depth.RobotModel()
    heading: HeadingConfig = HeadingConfig()


@dataclasses.dataclass(frozen=True)
class DepthPF3Config:
    """Particles over (x, y, theta) (``"pf3"``).

    Attributes:
      num_particles, init_spread, model: as `DepthPFConfig`.
      init_heading_spread: std (rad) of the initial headings.
      heading_noise: std (rad) of the heading random walk per frame.
    """

    num_particles: int = 128
    init_spread: float = 0.02
    init_heading_spread: float = math.radians(3.0)
    heading_noise: float = math.radians(4.0)
    model: depth.RobotModel = depth.RobotModel()


@dataclasses.dataclass(frozen=True)
class CentroidUKFConfig:
    """A constant-velocity UKF on the points' centroid (``"ukf"``).

    Attributes:
      init_spread: initial position std (m); init_speed_std: initial velocity std (m/s).
      centroid_std: std (m) of the centroid measurement.
      min_points: fewest points near the prediction for an update.
      model: `depth.RobotModel` (the points below its shoulders are not used).
      heading: `HeadingConfig` (its ``pca_radius`` is also the centroid's window).
    """

    init_spread: float = 0.02
    init_speed_std: float = 0.05
    centroid_std: float = 0.015
    min_points: int = 3
    model: depth.RobotModel = depth.RobotModel()
    heading: HeadingConfig = HeadingConfig()


class ParticleTrackerState(NamedTuple):
    """particles: `particle.ParticleSet` ([N, 2] or [N, 3]); heading: the heading estimate."""

    particles: particle.ParticleSet
    heading: Array


class UKFTrackerState(NamedTuple):
    """belief: `kalman.Gaussian` over (x, y, v_x, v_y); heading: the heading estimate."""

    belief: kalman.Gaussian
    heading: Array


def _params(*, position_noise=0.035, temperature=None, dtype=jnp.float32) -> DepthTrackerParams:
    for name, value in (("position_noise", position_noise), ("temperature", temperature)):
        if value is not None and _checks.is_concrete(value) and not (
                math.isfinite(float(value)) and float(value) > 0):
            raise ValueError(f"{name} must be a finite positive number; got {value}")
    log_t = None if temperature is None else _log(temperature, dtype)
    return DepthTrackerParams(_log(position_noise, dtype), log_t)


def _log(x, dtype):
    """log x as a ``dtype`` leaf: concrete values in float64 then rounded (the same leaf
    whatever JAX's default precision), traced ones with `jnp.log`."""
    if _checks.is_concrete(x):
        return jnp.asarray(math.log(float(x)), dtype)
    return jnp.log(x).astype(dtype)


def _temperature(params: DepthTrackerParams, dtype):
    return None if params.log_temperature is None else jnp.exp(params.log_temperature).astype(
        dtype)


def _uniform(x):
    """Particles [N, d] with equal normalised log-weights."""
    n = x.shape[0]
    return particle.ParticleSet(x, jnp.full((n,), -math.log(n), x.dtype))


def _weighting(model, smooth):
    """(resampler, ``loglik(params, dtype) -> (z, x) -> log weights``) of the particle
    trackers: the seed's SIR and hard counts, or the differentiable variant's."""
    resampler = particle.systematic if smooth is None else smooth.resampler()
    softness = None if smooth is None else smooth.softness

    def loglik(params, dtype):
        t = _temperature(params, dtype)
        return lambda z, x: depth.log_likelihood(z, x, model, softness=softness, temperature=t)

    return resampler, loglik


def _pca(cfg: HeadingConfig, dt, points, mask, centre, prev, turn):
    if cfg.turn_prediction:
        prev = wrap(prev + turn * dt)
    return depth.pca_heading(points, mask, centre, cfg.pca_radius, prev, cfg.window,
                             cfg.gain).heading


def depth_pf(config: DepthPFConfig = DepthPFConfig(), dt: float = 0.25,
             smooth: SmoothConfig | None = None) -> Estimator:
    """The seed's particle tracker (module docstring) at frame period ``dt`` (s); ``smooth``:
    the differentiable variant (`SmoothConfig`), or None for the seed's SIR.

    1. Resample (SIR, systematic), propagate by a Gaussian random walk, weight by
       `depth.log_likelihood` with the cuboid rotated by the *previous* heading; the position
       is the weighted mean of the particles (eq. 3).
    2. `depth.pca_heading` around that position with the continuity window.

    Example:
      >>> est = depth_pf(DepthPFConfig(heading=HeadingConfig(turn_prediction=True)))
    """
    n = config.num_particles
    resampler, loglik = _weighting(config.model, smooth)

    def init(key, params, start) -> ParticleTrackerState:
        eps = jax.random.normal(key, (n, 2), start.dtype)
        return ParticleTrackerState(_uniform(start[:2] + config.init_spread * eps), start[2])

    def update(key, state: ParticleTrackerState, z: DepthScan, params: DepthTrackerParams):
        dtype = state.heading.dtype
        sigma = jnp.exp(params.log_position_noise).astype(dtype)
        frame = depth.DepthFrame(z.points, z.mask, state.heading)
        ps, _ = particle.step(
            key, state.particles, frame,
            lambda k, x: x + sigma * jax.random.normal(k, x.shape, x.dtype),
            loglik(params, dtype), resampler, vectorized=True)
        position = particle.weighted_mean(ps)
        heading = _pca(config.heading, dt, z.points, z.mask, position, state.heading,
                       z.turn_rate)
        return ParticleTrackerState(ps, heading), jnp.concatenate([position, heading[None]])

    return Estimator(_params, init, update, "pf")


def depth_pf3(config: DepthPF3Config = DepthPF3Config(), dt: float = 0.25,
              smooth: SmoothConfig | None = None) -> Estimator:
    """Particles over (x, y, theta) (module docstring) at frame period ``dt`` (s); ``smooth``
    as `depth_pf`.

    Example:
      >>> est = depth_pf3()
    """
    n = config.num_particles
    resampler, loglik = _weighting(config.model, smooth)

    def init(key, params, start) -> ParticleTrackerState:
        eps = jax.random.normal(key, (n, 3), start.dtype)
        spread = jnp.array([config.init_spread, config.init_spread, config.init_heading_spread],
                           start.dtype)
        return ParticleTrackerState(_uniform(start + spread * eps), start[2])

    def update(key, state: ParticleTrackerState, z: DepthScan, params: DepthTrackerParams):
        dtype = state.heading.dtype
        sigma = jnp.exp(params.log_position_noise).astype(dtype)
        scale = jnp.stack([sigma, sigma, jnp.asarray(config.heading_noise, dtype)])
        frame = depth.DepthFrame(z.points, z.mask, state.heading)

        def transition(k, x):
            # The commanded turn drives the heading (a control input, as odometry would): a
            # pure random walk of 4 deg per frame lags a 7 deg-per-frame turn, and the count's
            # weak grip on the heading does not pull it back.
            x = x + scale * jax.random.normal(k, x.shape, x.dtype)
            return x.at[:, 2].set(wrap(x[:, 2] + z.turn_rate * dt))

        ps, _ = particle.step(key, state.particles, frame, transition, loglik(params, dtype),
                              resampler, vectorized=True)
        # The likelihood cannot tell theta from theta + pi: fold the heading particles to the
        # half-circle of the previous estimate (weights unchanged) so that they never split
        # between the two modes and the circular mean stays meaningful.
        theta = depth.fold_half_turn(ps.particles[:, 2], state.heading)
        ps = ps._replace(particles=ps.particles.at[:, 2].set(theta))
        est = particle.weighted_mean(ps, angle_dims=(2,))
        return ParticleTrackerState(ps, est[2]), est

    return Estimator(_params, init, update, "pf3")


def centroid_ukf(config: CentroidUKFConfig = CentroidUKFConfig(), dt: float = 0.25,
                 smooth: SmoothConfig | None = None) -> Estimator:
    """A constant-velocity UKF on the centroid of the points near the prediction (above the
    model's shoulder bottom, within the heading's PCA radius), then the PCA heading (already
    differentiable: ``smooth`` changes nothing).

    Example:
      >>> est = centroid_ukf()
    """
    model = config.model
    radius = config.heading.pca_radius

    def init(key, params, start) -> UKFTrackerState:
        dtype = start.dtype
        cov = jnp.diag(jnp.array([config.init_spread ** 2] * 2 + [config.init_speed_std ** 2]
                                 * 2, dtype))
        mean = jnp.concatenate([start[:2], jnp.zeros(2, dtype)])
        return UKFTrackerState(kalman.Gaussian(mean, cov), start[2])

    def update(key, state: UKFTrackerState, z: DepthScan, params: DepthTrackerParams):
        dtype = state.heading.dtype
        F = jnp.array([[1, 0, dt, 0], [0, 1, 0, dt], [0, 0, 1, 0], [0, 0, 0, 1]], dtype)
        sigma = jnp.exp(params.log_position_noise).astype(dtype)
        q = jnp.diag(jnp.stack([sigma ** 2, sigma ** 2, (2 * sigma) ** 2, (2 * sigma) ** 2]))
        pred = ukf.predict(state.belief, lambda x: F @ x, q)
        d = z.points[:, :2] - pred.mean[:2]
        near = z.mask & (jnp.sum(d * d, -1) <= radius ** 2) & (
            z.points[:, 2] >= model.shoulder_bottom)
        w = near.astype(dtype)
        count = jnp.sum(w)
        # Masked points may hold anything (NaN included): zeroed, not weighted by 0.
        xy = jnp.where(near[:, None], z.points[:, :2], 0.0)
        centroid = (w @ xy) / jnp.maximum(count, 1.0)
        r = jnp.eye(2, dtype=dtype) * config.centroid_std ** 2
        post, _ = ukf.update(pred, centroid, lambda x: x[:2], r, mask=count >= config.min_points)
        heading = _pca(config.heading, dt, z.points, z.mask, post.mean[:2], state.heading,
                       z.turn_rate)
        return UKFTrackerState(post, heading), jnp.concatenate([post.mean[:2], heading[None]])

    return Estimator(_params, init, update, "ukf")


_BUILDERS = {DepthPFConfig: depth_pf, DepthPF3Config: depth_pf3, CentroidUKFConfig: centroid_ukf}
_DEFAULTS = {"pf": DepthPFConfig(), "pf3": DepthPF3Config(), "ukf": CentroidUKFConfig()}


def build(config, dt: float = 0.25, smooth: SmoothConfig | None = None) -> Estimator:
    """The `Estimator` of a tracker configuration (or of a name of `TRACKERS`, by default), at
    frame period ``dt``; ``smooth``: the differentiable variant.

    Example:
      >>> est = build("pf3", dt=0.25)
    """
    if isinstance(config, str):
        _checks.check_options("tracker", (config,), TRACKERS)
        config = _DEFAULTS[config]
    builder = _BUILDERS.get(type(config))
    if builder is None:
        raise TypeError(f"not a humanoid tracker configuration: {type(config).__name__}")
    return builder(config, dt, smooth)
