r"""The estimator protocol: an estimator is a value holding pure functions over a named state.

Every people and robot tracker of jaxtrack is an `Estimator`, built by a function of its own
static configuration (`jaxtrack.tracking.user`, `jaxtrack.tracking.humanoid`), as cuthbert
builds its filters: a closed loop picks a method by building a value, not by passing a string,
and calls the same three functions whatever it got:

- ``params(**natural) -> P``: the tunable parameter pytree from natural values (unconstrained
  leaves: log-stds, logits), for optax;
- ``init(key, params, prior) -> S``: the state, a NamedTuple with named fields;
- ``update(key, state, measurement, params) -> (S, E)``: one frame; ``E`` is the estimate the
  caller reads (a NamedTuple too).

`run` drives any estimator over a sequence of measurements with one ``lax.scan``.

Example:
  >>> est = user.multi_target(user.MultiTargetConfig())
  >>> params = est.params(dt=0.1)
  >>> state = est.init(key, params, user.Prior(jnp.array([1.5, 0.0]), jnp.zeros(3)))
  >>> state, estimate = est.update(key, state, sensed, params)
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax

Array = jax.Array

__all__ = ["Estimator", "run"]


class Estimator(NamedTuple):
    """Pure functions of one estimator (see the module docstring for their signatures).

    Attributes:
      params: ``(**natural values) -> parameter pytree``.
      init: ``(key, params, prior) -> state``.
      update: ``(key, state, measurement, params) -> (state, estimate)``.
      name: the estimator's one spelling (as the command line names it).
    """

    params: Callable[..., Any]
    init: Callable[..., Any]
    update: Callable[..., Any]
    name: str


def run(estimator: Estimator, key: Array, state, measurements, params):
    """``update`` over a sequence of measurements (leaves with a leading [T] axis), with the key
    ``fold_in(key, t)`` at frame ``t``.

    Returns:
      ``(final state, estimates stacked over T)``.

    Example:
      >>> final, estimates = run(est, key, state, sensed_sequence, params)
    """
    leaves = jax.tree_util.tree_leaves(measurements)
    T = leaves[0].shape[0] if leaves else 0

    def body(s, xs):
        t, z = xs
        return estimator.update(jax.random.fold_in(key, t), s, z, params)

    return jax.lax.scan(body, state, (jax.numpy.arange(T), measurements))
