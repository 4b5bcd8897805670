r"""Track stitching: a person lost through an occlusion keeps their reported id.

A confirmed track that dies and a new track confirmed within ``stitch_time`` near where the old
one was last detected are taken for one person: the new track is reported under the old id.
"Near" is within :math:`\min(0.5 + 0.5\,\Delta t, 2)` m of the old track's last detected
position, :math:`\Delta t` the seconds since then (a person walks on while hidden), and the
pairs must be mutual nearest neighbours. The tracker itself is unchanged: only the ids reported
to the metrics and the caller are aliased.

Example:
  >>> state = init(tracks)
  >>> state = step(state, tracks, dt=0.1, stitch_time=10.0)
  >>> reported = state.alias
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxtrack.tracking import tracker

Array = jax.Array

__all__ = ["StitchState", "init", "step"]


class StitchState(NamedTuple):
    """Per track slot [K]: ``alias``, the id the slot's track is reported under; ``prev_id``,
    ``prev_confirmed``: last frame's id and confirmation; ``hit_pos`` [K, 2], ``hit_age``: where
    and how many frames ago the track was last detected. A memory of recently deleted confirmed
    tracks: ``mem_id`` (reported id; -1: empty), ``mem_pos`` [K, 2], ``mem_age`` (frames since
    last detected)."""

    alias: Array
    prev_id: Array
    prev_confirmed: Array
    hit_pos: Array
    hit_age: Array
    mem_id: Array
    mem_pos: Array
    mem_age: Array


def init(tracks: tracker.Tracks) -> StitchState:
    """The stitching state of the tracker state ``tracks`` (no memory)."""
    K = tracks.id.shape[0]
    dtype = tracks.mean.dtype
    return StitchState(tracks.id, tracks.id, tracks.status == tracker.CONFIRMED,
                       tracks.mean[:, :2], jnp.zeros(K, jnp.int32), jnp.full(K, -1, jnp.int32),
                       jnp.zeros((K, 2), dtype), jnp.zeros(K, jnp.int32))


def step(state: StitchState, tracks: tracker.Tracks, dt, stitch_time) -> StitchState:
    """The state after the tracker's step that gave ``tracks`` (module docstring).

    Args:
      state: `StitchState`. tracks: `tracker.Tracks` of this frame.
      dt: frame period (s); stitch_time: longest gap (s) that is stitched.
    """
    st = state
    K = tracks.id.shape[0]
    live = tracks.status != tracker.FREE
    confirmed = tracks.status == tracker.CONFIRMED
    same = live & (tracks.id == st.prev_id)
    died = (st.prev_id >= 0) & ~same & st.prev_confirmed
    mem_id = jnp.where(died, st.alias, st.mem_id)
    mem_pos = jnp.where(died[:, None], st.hit_pos, st.mem_pos)
    mem_age = jnp.where(died, st.hit_age, st.mem_age) + 1
    mem_ok = (mem_id >= 0) & (mem_age * dt <= stitch_time)
    hit = live & (tracks.misses == 0)
    hit_pos = jnp.where((hit | ~same)[:, None], tracks.mean[:, :2], st.hit_pos)
    hit_age = jnp.where(hit | ~same, 0, st.hit_age + 1)
    new = confirmed & ~(same & st.prev_confirmed)
    alias = jnp.where(same, st.alias, tracks.id)
    d = jnp.sqrt(jnp.sum((tracks.mean[:, None, :2] - mem_pos[None]) ** 2, -1) + 1e-12)
    radius = jnp.minimum(0.5 + 0.5 * dt * mem_age, 2.0)
    d = jnp.where(new[:, None] & mem_ok[None] & (d <= radius[None]), d, jnp.inf)
    j = jnp.argmin(d, 1)
    k = jnp.argmin(d, 0)
    mutual = jnp.isfinite(jnp.min(d, 1)) & (k[j] == jnp.arange(K))
    alias = jnp.where(mutual, mem_id[j], alias)
    used = jnp.zeros(K, bool).at[jnp.where(mutual, j, K)].set(True, mode="drop")
    mem_id = jnp.where(used | ~mem_ok, -1, mem_id)
    return StitchState(alias, jnp.where(live, tracks.id, -1), confirmed, hit_pos, hit_age,
                       mem_id, mem_pos, mem_age)
