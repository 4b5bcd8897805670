r"""Per-track online colour-appearance classifier (the colour term of seed 001's cost).

Seed 001 (Munaro et al.) keeps one online AdaBoost classifier per track over the RGB histogram of
the detection's points, whose weak learners sum the histogram inside random axis-aligned
parallelepipeds; the positive sample is the track's associated detection, the negatives are the
other detections of the frame.

We keep the same samples (positive: the associated detection; negatives: the frame's other
detections) and the same input (a normalised colour histogram), but learn a *logistic
regression* over the histogram bins by one gradient step per frame:

.. math::
    c = \sigma(w^T h + b), \qquad
    (w, b) \leftarrow (w, b) - \eta \nabla \Big[-\log c(h^+) - \tfrac{1}{|N|}\sum_{h^- \in N}
    \log(1 - c(h^-))\Big] - \eta \lambda w.

Why not online AdaBoost: it selects weak learners from a random pool (discrete, data-dependent
choices and a variable-size model), which neither fits fixed shapes under `jit`/`vmap` nor has a
gradient. Every parallelepiped sum is a linear functional of the histogram, so a linear model over
the bins spans every combination the boosted ensemble can express with those features; the
loss is convex, the update is a fixed-size array operation, and its learning rate is a tunable
leaf. What is lost is AdaBoost's sparsity (a few selected boxes), which matters for speed on a
CPU of 2012, not for accuracy here.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

Array = jax.Array

__all__ = ["Appearance", "init", "confidence", "update"]


class Appearance(NamedTuple):
    """Classifier weights of K tracks: ``weights`` [K, F], ``bias`` [K]."""

    weights: Array
    bias: Array


def init(num_tracks: int, num_features: int, dtype=jnp.float32) -> Appearance:
    """Zero classifiers (confidence 0.5 for everything)."""
    return Appearance(jnp.zeros((num_tracks, num_features), dtype), jnp.zeros((num_tracks,), dtype))


def confidence(model: Appearance, features: Array) -> Array:
    """Confidence [K, M] that detection j (histogram ``features[j]`` [F]) looks like track k.

    Example:
      >>> c = confidence(model, hists)  # in (0, 1)
    """
    return jax.nn.sigmoid(model.weights @ features.T + model.bias[:, None])


def update(model: Appearance, features: Array, assigned: Array, det_mask: Array,
           track_mask: Array, learning_rate=0.5, l2=1e-3) -> Appearance:
    """One online step for every track with an associated detection.

    Args:
      model: `Appearance` of K tracks.
      features: [M, F] histograms of the frame's detections.
      assigned: [K] index of each track's detection (-1: none; those tracks are unchanged).
      det_mask: [M] bools, valid detections (the only negatives used).
      track_mask: [K] bools, live tracks.
      learning_rate, l2: step size and weight decay (tunable).

    Returns:
      The updated `Appearance`.
    """
    M = features.shape[0]

    def one(w, b, j):
        def loss(wb):
            w_, b_ = wb
            logits = features @ w_ + b_
            pos = jax.nn.log_sigmoid(logits)
            neg = jax.nn.log_sigmoid(-logits)
            is_pos = jnp.arange(M) == j
            is_neg = det_mask & ~is_pos
            n_neg = jnp.maximum(jnp.sum(is_neg), 1)
            return (-jnp.sum(jnp.where(is_pos, pos, 0.0))
                    - jnp.sum(jnp.where(is_neg, neg, 0.0)) / n_neg
                    + 0.5 * l2 * jnp.sum(w_**2))

        gw, gb = jax.grad(loss)((w, b))
        active = j >= 0
        return (jnp.where(active, w - learning_rate * gw, w),
                jnp.where(active, b - learning_rate * gb, b))

    active = track_mask & (assigned >= 0)
    w, b = jax.vmap(one)(model.weights, model.bias, jnp.where(active, assigned, -1))
    return Appearance(w, b)
