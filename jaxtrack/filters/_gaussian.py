"""The Gaussian belief type and the boundary checks of Gaussian-filter arguments.

`Gaussian` is re-exported as `jaxtrack.filters.kalman.Gaussian`; it lives here, below kalman,
so that the checks shared by kalman, ekf, ukf and the association updates can name it without
an import cycle. The checks follow `jaxtrack._checks`: shapes always, values only when concrete.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxtrack import _checks

Array = jax.Array


class Gaussian(NamedTuple):
    """A Gaussian belief: ``mean`` [n], ``cov`` [n, n] (shared by kalman, ekf and ukf)."""

    mean: Array
    cov: Array


def working_dtype(**arrays) -> jnp.dtype:
    """The one floating dtype of a filter run (the dtype policy of the ``filter`` drivers).

    The widest floating dtype among the given arrays (float32 with float64 gives float64);
    integer and bool arrays take no part and are promoted to it, and without any floating input
    it is JAX's default float. Half precision (float16, bfloat16) is refused with a
    ``TypeError`` naming the argument: covariance arithmetic in 11 significant bits loses
    definiteness within a few steps, and log-domain constants overflow.
    """
    floats = []
    for name, a in arrays.items():
        if a is None:
            continue
        dt = jnp.result_type(a)
        if dt in (jnp.float16, jnp.bfloat16):
            raise TypeError(f"{name} has dtype {dt}: half precision is not supported; use "
                            "float32 or float64")
        if jnp.issubdtype(dt, jnp.floating):
            floats.append(dt)
    return jnp.result_type(*floats) if floats else jnp.result_type(float)


def as_dtype(state: Gaussian, dtype) -> Gaussian:
    """``state`` with mean and cov in ``dtype``."""
    return Gaussian(jnp.asarray(state.mean, dtype), jnp.asarray(state.cov, dtype))


def check_state(state, name: str = "state") -> int:
    """Check one Gaussian, mean [n] (finite if concrete) and cov [n, n]; return n."""
    if not isinstance(state, Gaussian):
        raise TypeError(f"{name} must be a kalman.Gaussian; got {type(state).__name__}")
    _checks.check_ndim(f"{name}.mean", state.mean, 1, "a [n] vector")
    n = jnp.shape(state.mean)[0]
    _checks.check_covariance(f"{name}.cov", state.cov, n)
    _checks.check_finite(f"{name}.mean", state.mean)
    return n


def check_states(states, name: str = "states") -> tuple[int, int]:
    """Check a batch of K Gaussians, mean [K, n] and cov [K, n, n]; return (K, n)."""
    if not isinstance(states, Gaussian):
        raise TypeError(f"{name} must be a kalman.Gaussian; got {type(states).__name__}")
    _checks.check_ndim(f"{name}.mean", states.mean, 2, "[K, n] track means")
    K, n = _checks.shape_of(states.mean)
    _checks.check_covariance(f"{name}.cov", states.cov, n, batch_axes=1)
    _checks.check_shape(f"{name}.cov", states.cov, (K, n, n))
    return K, n


def check_measurement(z, mask) -> int:
    """Check a measurement z [m] and its mask (None, a scalar or [m] bools); return m."""
    _checks.check_ndim("z", z, 1, "a [m] vector")
    m = jnp.shape(z)[0]
    if mask is not None and jnp.ndim(mask) not in (0, 1):
        raise ValueError(f"mask must be a scalar or [m] bools; got shape {jnp.shape(mask)}")
    if mask is not None and jnp.ndim(mask) == 1:
        _checks.check_shape("mask", mask, (m,))
    return m


def check_sequence(zs, masks) -> tuple[int, int]:
    """Check measurements zs [T, m] and their masks (None, [T] or [T, m]); return (T, m)."""
    _checks.check_ndim("zs", zs, 2, "a [T, m] sequence of measurements")
    T, m = jnp.shape(zs)
    if masks is not None:
        if jnp.ndim(masks) == 1:
            _checks.check_shape("masks", masks, (T,))
        else:
            _checks.check_shape("masks", masks, (T, m), "[T] or [T, m] bools")
    return T, m
