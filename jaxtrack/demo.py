"""Filter demo: Kalman, extended and unscented Kalman filters over many vmapped episodes.

Each episode draws a person walking on the ground plane (nearly constant velocity, 10 Hz) and
two sensors with per-episode noise: a position detector with 10 % missed detections, and a
range-bearing sensor at the origin. The KF tracks the positions, the EKF and UKF the range and
bearing. Reported per filter: position RMSE against the truth (and of the raw detections),
mean NEES and NIS (consistency: ideally the state and measurement dimensions) and speed.

Run it with ``jaxtrack demo``.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxtrack.filters import _linalg, ekf, kalman, ukf
from jaxtrack.models import measurement, motion

__all__ = ["DemoConfig", "simulate", "episode", "run"]


class DemoConfig(NamedTuple):
    """Episode settings: time step (s), acceleration density q (m^2/s^3), detection miss rate,
    ranges of per-episode position noise std (m) and bearing noise std (rad), range noise std."""

    dt: float = 0.1
    q: float = 0.5
    miss_rate: float = 0.1
    pos_std: tuple[float, float] = (0.05, 0.3)
    range_std: float = 0.1
    bearing_std: tuple[float, float] = (0.01, 0.05)


class Episode(NamedTuple):
    states: jax.Array  # [T, 4]
    positions: jax.Array  # [T, 2] noisy detections
    masks: jax.Array  # [T] detection present
    R_pos: jax.Array  # [2, 2]
    range_bearing: jax.Array  # [T, 2]
    R_rb: jax.Array  # [2, 2]


def simulate(key, num_steps: int, config: DemoConfig = DemoConfig()) -> Episode:
    """One episode of ground truth and measurements (shapes as in `Episode`)."""
    k0, k1, k2, k3, k4, k5, k6 = jax.random.split(key, 7)
    F, Q = motion.constant_velocity(config.dt, config.q)
    low_q = _linalg.cholesky(Q)
    x0 = jnp.concatenate([jax.random.uniform(k0, (2,), minval=2.0, maxval=6.0),
                          jax.random.normal(k1, (2,))])
    noise = jax.random.normal(k2, (num_steps, 4)) @ low_q.T

    def body(x, w):
        x = F @ x + w
        return x, x

    _, states = jax.lax.scan(body, x0, noise)
    pos_std = jax.random.uniform(k3, minval=config.pos_std[0], maxval=config.pos_std[1])
    positions = states[:, :2] + pos_std * jax.random.normal(k4, (num_steps, 2))
    masks = jax.random.uniform(k5, (num_steps,)) > config.miss_rate
    brg_std = jax.random.uniform(k6, minval=config.bearing_std[0], maxval=config.bearing_std[1])
    std_rb = jnp.stack([jnp.asarray(config.range_std, brg_std.dtype), brg_std])
    clean = jax.vmap(measurement.range_bearing)(states)
    rb = clean + std_rb * jax.random.normal(jax.random.fold_in(k6, 1), (num_steps, 2))
    rb = rb.at[:, 1].set(jnp.mod(rb[:, 1] + jnp.pi, 2 * jnp.pi) - jnp.pi)
    return Episode(states, positions, masks, pos_std**2 * jnp.eye(2), rb, jnp.diag(std_rb**2))


def _accuracy(result, truth):
    """Position RMSE [m] and mean NEES of a filter result against the true states."""
    err = truth - result.means
    nees = jax.vmap(lambda e, P: e @ _linalg.cho_solve(_linalg.cholesky(P), e[:, None])[:, 0])(
        err, result.covs)
    pos_err = jnp.sqrt(jnp.mean(jnp.sum(err[:, :2] ** 2, -1)))
    return pos_err, jnp.mean(nees)


def episode(key, num_steps: int = 200, config: DemoConfig = DemoConfig()) -> dict:
    """Simulate one episode and run the three filters; returns a dict of scalar metrics."""
    ep = simulate(key, num_steps, config)
    F, Q = motion.constant_velocity(config.dt, config.q)
    init = kalman.Gaussian(jnp.concatenate([ep.states[0, :2], jnp.zeros(2)]),
                           jnp.diag(jnp.array([1.0, 1.0, 4.0, 4.0])))
    H = measurement.position(4)
    out = {}
    kf = kalman.filter(init, ep.positions, F, Q, H, ep.R_pos, ep.masks)
    out["kf_rmse"], out["kf_nees"] = _accuracy(kf, ep.states)
    f = lambda x: F @ x  # noqa: E731  (linear motion; the nonlinearity is in h)
    ek = ekf.filter(init, ep.range_bearing, f, Q, measurement.range_bearing, ep.R_rb,
                    residual=measurement.range_bearing_residual)
    out["ekf_rmse"], out["ekf_nees"] = _accuracy(ek, ep.states)
    uk = ukf.filter(init, ep.range_bearing, f, Q, measurement.range_bearing, ep.R_rb,
                    points=ukf.merwe_points(alpha=0.5),
                    residual_z=measurement.range_bearing_residual)
    out["ukf_rmse"], out["ukf_nees"] = _accuracy(uk, ep.states)
    raw = jnp.where(ep.masks[:, None], ep.positions - ep.states[:, :2], 0.0)
    out["raw_rmse"] = jnp.sqrt(jnp.sum(raw**2) / jnp.sum(ep.masks))
    out["kf_loglik"], out["ekf_loglik"], out["ukf_loglik"] = (
        kf.log_likelihood, ek.log_likelihood, uk.log_likelihood)
    return out


def run(num_episodes: int = 1000, num_steps: int = 200, seed: int = 0,
        print_fn=print) -> dict:
    """Run ``num_episodes`` vmapped episodes, print a results table and return the metrics."""
    keys = jax.random.split(jax.random.PRNGKey(seed), num_episodes)
    batched = jax.jit(jax.vmap(lambda k: episode(k, num_steps)))
    t0 = time.perf_counter()
    res = jax.block_until_ready(batched(keys))
    compile_and_run = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = jax.block_until_ready(batched(keys))
    elapsed = time.perf_counter() - t0
    per_step_us = elapsed / (num_episodes * num_steps) * 1e6
    devices = jax.devices()
    print_fn(f"jaxtrack filter demo: {num_episodes} episodes x {num_steps} steps on "
             f"{len(devices)} {devices[0].platform} device(s), {jnp.zeros(1).dtype}")
    print_fn(f"{'filter':<34}{'pos RMSE [m]':>13}{'mean NEES':>11}{'  (ideal 4)':>11}")
    rows = [("KF   (position detections)", "kf"), ("EKF  (range-bearing)", "ekf"),
            ("UKF  (range-bearing)", "ukf")]
    for label, k in rows:
        rmse, nees = res[f"{k}_rmse"], res[f"{k}_nees"]
        print_fn(f"{label:<34}{float(jnp.mean(rmse)):>13.3f}{float(jnp.mean(nees)):>11.2f}")
    print_fn(f"{'raw position detections':<34}{float(jnp.mean(res['raw_rmse'])):>13.3f}")
    print_fn(f"speed: {elapsed * 1e3:.1f} ms for all episodes and three filters "
             f"({num_episodes / elapsed:,.0f} episodes/s, {per_step_us:.3f} us per "
             f"episode-step); first call incl. compile {compile_and_run:.1f} s")
    return {k: jax.device_get(v) for k, v in res.items()} | {"seconds": elapsed}
