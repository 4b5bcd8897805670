"""Gathers and scatters that stay cheap under `jax.vmap` on a CPU.

``table[index]`` from a batch of tables is, by JAX's batching rule, a gather whose every index
is paired with its batch number: an [..., 2] array of index tuples, built where the gather is
(scatters alike). XLA:CPU runs such gathers and scatters as scalar loops, and builds the pairs
again in every round of a `lax.while_loop` that gathers with a loop-invariant index (the
clustering's label propagation spent 6 of a batch of 8 QVGA frames' 50 ms building them). The
functions here index the flattened batch of tables with offset indices instead: one [N]
index, as without vmap. Unbatched, each is the plain operation.

Example:
  >>> take(labels, neighbours)                    # labels[neighbours], promised in bounds
  >>> jax.vmap(take)(batch_of_labels, batch_of_neighbours)
  >>> segment_sum(weights, voxel_of_point, num_voxels)
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax import custom_batching

Array = jax.Array

__all__ = ["take", "segment_sum", "put", "materialised"]

_INT32_LIMIT = 2**31 - 1


def _flat_offsets(axis_size, size, index):
    """[B, 1, ...] the offset of each batch member's table in the flattened batch."""
    return (jnp.arange(axis_size, dtype=index.dtype) * size).reshape(
        (axis_size,) + (1,) * (index.ndim - 1))


def _both_batched(axis_size, in_batched, *args):
    """``args`` with every unbatched one broadcast along a leading batch axis."""
    return [a if b else jnp.broadcast_to(a, (axis_size,) + a.shape)
            for a, b in zip(args, in_batched)]


@custom_batching.custom_vmap
def take(table: Array, index: Array) -> Array:
    """``table[index]`` for a ``table`` [T, ...] and an integer ``index`` of any shape whose
    entries lie in [0, T) (not checked, and negative entries are not wrapped)."""
    return table.at[index].get(mode="promise_in_bounds", wrap_negative_indices=False)


@take.def_vmap
def _take_batched(axis_size, in_batched, table, index):
    if not in_batched[0]:          # one table: a plain gather with a batch of indices
        return take(table, index), True
    table, index = _both_batched(axis_size, in_batched, table, index)
    size = table.shape[1]
    if axis_size * size >= _INT32_LIMIT:      # offsets beyond int32: JAX's own rule
        return jax.vmap(take.fun)(table, index), True
    flat = table.reshape((axis_size * size,) + table.shape[2:])
    return take(flat, index + _flat_offsets(axis_size, size, index)), True


def segment_sum(data: Array, segment_ids: Array, num_segments: int) -> Array:
    """``jax.ops.segment_sum(data, segment_ids, num_segments)`` for ``data`` [N, ...] and
    ``segment_ids`` [N] in [0, num_segments) (not checked)."""
    return _segment_sum(int(num_segments))(data, segment_ids)


@functools.lru_cache(maxsize=None)
def _segment_sum(num_segments):
    @custom_batching.custom_vmap
    def op(data, ids):
        return jax.ops.segment_sum(data, ids, num_segments)

    @op.def_vmap
    def _batched(axis_size, in_batched, data, ids):
        data, ids = _both_batched(axis_size, in_batched, data, ids)
        if axis_size * num_segments >= _INT32_LIMIT:
            return jax.vmap(op.fun)(data, ids), True
        flat_ids = (ids + _flat_offsets(axis_size, num_segments, ids)).reshape(-1)
        flat = _segment_sum(axis_size * num_segments)(
            data.reshape((axis_size * data.shape[1],) + data.shape[2:]), flat_ids)
        return flat.reshape((axis_size, num_segments) + data.shape[2:]), True

    return op


@custom_batching.custom_vmap
def put(table: Array, index: Array, values: Array) -> Array:
    """``table.at[index].set(values)`` for a ``table`` [T, ...], an integer ``index`` [N] in
    [0, T) (not checked) and ``values`` [N, ...]; where indices repeat, their values must
    agree (which one is written is not specified)."""
    return table.at[index].set(values, mode="promise_in_bounds", wrap_negative_indices=False)


@put.def_vmap
def _put_batched(axis_size, in_batched, table, index, values):
    table, index, values = _both_batched(axis_size, in_batched, table, index, values)
    size = table.shape[1]
    if axis_size * size >= _INT32_LIMIT:
        return jax.vmap(put.fun)(table, index, values), True
    # (explicit leading sizes: -1 is ambiguous when a trailing axis is empty)
    flat = put(table.reshape((axis_size * size,) + table.shape[2:]),
               (index + _flat_offsets(axis_size, size, index)).reshape(-1),
               values.reshape((axis_size * values.shape[1],) + values.shape[2:]))
    return flat.reshape(table.shape), True


def materialised(x: Array) -> Array:
    """``x``, computed once into memory: written by a scatter, which XLA does not fuse into its
    consumers. Without it, XLA fuses a producer into each consumer and recomputes it there, at
    every element a gather reads (an optimization_barrier does not help: XLA:CPU removes
    barriers before fusing)."""
    n = x.shape[0]
    return put(jnp.zeros((n + 1,) + x.shape[1:], x.dtype), jnp.arange(n), x)[:n]
