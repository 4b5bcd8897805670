r"""Re-identification of the followed user by colour, over the tracks of a multi-target tracker.

Each track slot accumulates the log-odds :math:`\ell_k` that it is the user from the colour
features of the RGB-D detections nearest to it. A detection's evidence is the log-likelihood
ratio "user vs anyone else",

.. math::
    \Lambda(c) = -\frac{\|c - c_u\|^2}{2 \sigma_c^2} - \frac{3}{2} \log(2 \pi \sigma_c^2),

the user's colour feature Gaussian with std :math:`\sigma_c` (a tunable leaf) around their true
colour, other people's uniform in :math:`[0, 1]^3` (density 1). The true colour is not known:
:math:`c_u` is the mean of the :math:`n` looks taken of the user so far, the first the look the
robot was shown, so a new look is Gaussian around :math:`c_u` with the predictive variance
:math:`\sigma_c^2 (1 + 1/n)` in place of :math:`\sigma_c^2` above. `learn` adds the looks of
the user's track while its identity is settled (`ReidConfig.max_looks`): one shown look is a
noisy draw, and a distractor whose colour lies on the far side of that draw from the user's
true colour otherwise reads as the user. :math:`\Lambda` is clipped to ``evidence`` so that
one detection cannot settle an identity. A
detection informs the nearest live track within ``colour_radius`` when the second nearest is at
least ``colour_margin`` farther (otherwise the colour could be either track's). Evidence fades
every frame, :math:`\ell_k \leftarrow f \ell_k + \Lambda` (tracks can swap people in a crowd, so
a track's past colours say less about who it is now), with a slower fade ``fade_other`` for
evidence *against* (otherwise a distractor seen a second ago becomes a candidate for
re-acquisition as soon as the user is lost near them). A reused slot restarts at 0.

Example:
  >>> state = init(ReidConfig(), colour, tracks.id, user_slot=0)
  >>> state = update(ReidConfig(), state, tracks, live, rgbd_xy, rgbd_colour, rgbd_mask, 0.1)
  >>> state = learn(ReidConfig(), state, tracks, live, user_slot, settled, rgbd_xy,
  ...               rgbd_colour, rgbd_mask, 0.1)
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp

Array = jax.Array

__all__ = ["ReidConfig", "ReidState", "init", "evidence", "update", "learn"]


@dataclasses.dataclass(frozen=True)
class ReidConfig:
    """Static re-identification settings.

    Attributes:
      logodds_max: the log-odds saturate at +-this (6: probability 0.9975).
      evidence: (low, high) clip of one detection's log-likelihood ratio.
      switch: a track is (not) the user beyond +-this log-odds.
      colour_radius: a detection informs the nearest track within this (m) ...
      colour_margin: ... when the second nearest is this much farther (m).
      fade: per-frame fade of the log-odds (0.95: half-life 1.4 s at 10 Hz) ...
      fade_other: ... and of negative log-odds, evidence of being someone else (0.99: 7 s).
      max_looks: `learn` averages at most this many looks of the user into their colour (a
        running mean beyond it, so the colour follows slow changes of light); 0 keeps the
        shown look alone.
      learn_gate: a look joins the user's colour only within this squared Mahalanobis
        distance of it under the predictive variance (11.34: the 99 % point of chi-square
        with 3 degrees of freedom), so a swap onto someone else does not teach their colour.
    """

    logodds_max: float = 6.0
    evidence: tuple = (-4.0, 3.0)
    switch: float = 2.0
    colour_radius: float = 0.45
    colour_margin: float = 0.2
    fade: float = 0.95
    fade_other: float = 0.99
    max_looks: int = 50
    learn_gate: float = 11.34

    def __post_init__(self):
        if not (self.logodds_max > 0 and self.switch > 0 and self.colour_radius > 0
                and self.colour_margin >= 0):
            raise ValueError("logodds_max, switch and colour_radius must be > 0, "
                             "colour_margin >= 0")
        if not (0 < self.fade <= 1 and 0 < self.fade_other <= 1):
            raise ValueError("fade and fade_other must be in (0, 1]")
        if self.max_looks < 0 or not self.learn_gate > 0:
            raise ValueError("max_looks must be >= 0 and learn_gate > 0")
        if not self.evidence[0] <= 0 <= self.evidence[1]:
            raise ValueError(f"evidence must be (low <= 0, high >= 0); got {self.evidence}")


jax.tree_util.register_static(ReidConfig)


class ReidState(NamedTuple):
    """colour: [3] the user's colour feature (the mean of the looks); logodds: [K] per track
    slot that it is the user; ids: [K] the track id each log-odds belongs to (a reused slot
    restarts); looks: how many looks ``colour`` averages (None: one)."""

    colour: Array
    logodds: Array
    ids: Array
    looks: Array | None = None


def init(config: ReidConfig, colour: Array, ids: Array, user_slot: int = 0) -> ReidState:
    """The user, of colour feature ``colour`` [3] (NaN: not known, and no colour gives
    evidence), is the track in ``user_slot`` (saturated log-odds); ``ids`` [K] are the tracks'
    ids."""
    dtype = colour.dtype
    K = ids.shape[0]
    return ReidState(colour, jnp.zeros(K, dtype).at[user_slot].set(config.logodds_max), ids,
                     jnp.ones((), dtype))


def _predictive_variance(state: ReidState, colour_std):
    """sigma_c^2 (1 + 1 / n): a new look of the user about the mean of n looks."""
    looks = 1.0 if state.looks is None else state.looks
    return colour_std**2 * (1.0 + 1.0 / looks)


def _informs(config: ReidConfig, positions, live, rgbd_xy, rgbd_mask):
    """[M, K] detection m informs track k: k is the nearest live track, within
    ``colour_radius``, and the second nearest is ``colour_margin`` farther."""
    d2 = jnp.sum((rgbd_xy[:, None, :] - positions[None, :, :]) ** 2, -1)   # [M, K]
    d2 = jnp.where(live[None], d2, jnp.inf)
    first = jnp.argmin(d2, 1)
    d1 = jnp.take_along_axis(d2, first[:, None], 1)[:, 0]
    second = jnp.min(jnp.where(jnp.arange(d2.shape[1]) == first[:, None], jnp.inf, d2), 1)
    r1 = jnp.sqrt(jnp.minimum(d1, 1e6))
    r2 = jnp.sqrt(jnp.minimum(second, 1e6))
    use = rgbd_mask & (r1 <= config.colour_radius) & (r2 - r1 >= config.colour_margin)
    return (first[:, None] == jnp.arange(d2.shape[1])) & use[:, None]


def evidence(config: ReidConfig, state: ReidState, positions: Array, live: Array,
             rgbd_xy: Array, rgbd_colour: Array, rgbd_mask: Array, colour_std) -> Array:
    """[K] this frame's log-likelihood ratios per track slot (module docstring).

    Args:
      positions: [K, 2] track positions; live: [K] live slots.
      rgbd_xy: [M, 2] RGB-D detections (same frame); rgbd_colour: [M, 3]; rgbd_mask: [M].
      colour_std: :math:`\\sigma_c`.
    """
    dtype = positions.dtype
    s2 = _predictive_variance(state, colour_std)
    known = jnp.all(jnp.isfinite(state.colour))
    colour = jnp.where(known, state.colour, 0.0)  # no NaN in the gradient's unused branch
    dc = jnp.sum((rgbd_colour.astype(dtype) - colour) ** 2, -1)
    llr = -0.5 * dc / s2 - 1.5 * jnp.log(2.0 * jnp.pi * s2)
    # No colour shown (NaN): no evidence either way.
    llr = jnp.where(known, jnp.clip(llr, *config.evidence), 0.0)
    onehot = _informs(config, positions, live, rgbd_xy, rgbd_mask)
    return jnp.sum(jnp.where(onehot, llr[:, None], 0.0), 0)


def update(config: ReidConfig, state: ReidState, positions: Array, ids: Array, live: Array,
           rgbd_xy: Array, rgbd_colour: Array, rgbd_mask: Array, colour_std) -> ReidState:
    """Fade the log-odds, restart reused slots, add this frame's `evidence`, clip.

    Args:
      positions: [K, 2], ids: [K], live: [K] of the tracks after this frame's tracker step;
      the rest as `evidence`.
    """
    fade = jnp.where(state.logodds < 0.0, config.fade_other, config.fade)
    logodds = jnp.where(live & (ids == state.ids), fade * state.logodds, 0.0)
    logodds = jnp.clip(logodds + evidence(config, state, positions, live, rgbd_xy, rgbd_colour,
                                          rgbd_mask, colour_std),
                       -config.logodds_max, config.logodds_max)
    return state._replace(logodds=logodds, ids=ids)


def learn(config: ReidConfig, state: ReidState, positions: Array, live: Array, slot: Array,
          settled: Array, rgbd_xy: Array, rgbd_colour: Array, rgbd_mask: Array, colour_std
          ) -> ReidState:
    r"""Add this frame's looks of the user to their colour (module docstring).

    When ``settled`` (the caller's word that the track in ``slot`` is the user, e.g. its
    log-odds at least ``switch`` and measured now), the detections that inform that track
    (`evidence`'s rule) and lie within ``learn_gate`` of the colour under the predictive
    variance join its mean: :math:`n \leftarrow \min(n + m, N)`,
    :math:`c_u \leftarrow c_u + \sum_j (c_j - c_u) / n` (:math:`N` = ``max_looks``).

    Args:
      positions: [K, 2], live: [K] the tracks (as `update`); slot: the user's track slot;
      settled: bool; rgbd_xy [M, 2], rgbd_colour [M, 3], rgbd_mask [M], colour_std: as
      `evidence`.

    Returns:
      The `ReidState` with ``colour`` and ``looks`` updated (unchanged without a colour shown).

    Example:
      >>> settled = (state.logodds[slot] >= ReidConfig().switch) & (tracks.misses[slot] == 0)
      >>> state = learn(ReidConfig(), state, tracks.mean[:, :2], live, slot, settled, rgbd_xy,
      ...               rgbd_colour, rgbd_mask, 0.05)
    """
    if config.max_looks == 0:
        return state
    dtype = positions.dtype
    looks = jnp.ones((), dtype) if state.looks is None else state.looks
    known = jnp.all(jnp.isfinite(state.colour))
    colour = jnp.where(known, state.colour, 0.0)
    rgbd_colour = rgbd_colour.astype(dtype)
    dc = jnp.sum((rgbd_colour - colour) ** 2, -1)
    near = dc <= config.learn_gate * _predictive_variance(state, colour_std)
    onehot = _informs(config, positions, live, rgbd_xy, rgbd_mask)
    use = jnp.take(onehot, slot, axis=1) & near & settled & known       # [M]
    m = jnp.sum(use).astype(dtype)
    new_looks = jnp.maximum(jnp.minimum(looks + m, float(config.max_looks)), looks)
    step = jnp.sum(jnp.where(use[:, None], rgbd_colour - colour, 0.0), 0) / new_looks
    return state._replace(colour=jnp.where(known, colour + step, state.colour),
                          looks=new_looks)
