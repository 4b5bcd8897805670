"""`jaxtrack._gather`: each function equals JAX's own operation, unbatched and under vmap with
every combination of batched arguments, nested vmaps, jit and inside a while loop."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack._gather import put, segment_sum, take

B, T, N = 3, 7, 11


def _arrays(dtype):
    rng = np.random.default_rng(0)
    table = jnp.asarray(rng.normal(size=(B, T, 2)), dtype)
    index = jnp.asarray(rng.integers(0, T, (B, N)), jnp.int32)
    values = jnp.asarray(rng.normal(size=(B, N, 2)), dtype)
    return table, index, values


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
@pytest.mark.parametrize("axes", [(0, 0), (None, 0), (0, None)])
def test_take_equals_indexing(dtype, axes):
    table, index, _ = _arrays(dtype)
    args = [x[0] if a is None else x for x, a in zip((table, index), axes)]
    want = jax.vmap(lambda t, i: t[i], axes)(*args)
    np.testing.assert_array_equal(jax.jit(jax.vmap(take, axes))(*args), want)
    np.testing.assert_array_equal(take(table[1], index[2]), table[1][index[2]])


def test_take_under_nested_vmap_and_in_a_while_loop():
    table, index, _ = _arrays(jnp.float32)
    tables, indices = jnp.stack([table, -table]), jnp.stack([index, index[::-1]])
    want = jax.vmap(jax.vmap(lambda t, i: t[i]))(tables, indices)
    np.testing.assert_array_equal(jax.vmap(jax.vmap(take))(tables, indices), want)

    def rounds(t, i):                                # t <- t[i] three times, i loop-invariant
        return jax.lax.fori_loop(0, 3, lambda _, x: take(x, i), t[:, 0])

    square = jnp.asarray(np.random.default_rng(1).integers(0, T, (B, T)), jnp.int32)
    want = jax.vmap(lambda t, i: t[:, 0][i][i][i])(table, square)
    np.testing.assert_array_equal(jax.jit(jax.vmap(rounds))(table, square), want)


@pytest.mark.parametrize("axes", [(0, 0), (None, 0), (0, None)])
def test_segment_sum_equals_jax(axes):
    _, index, values = _arrays(jnp.float64)
    args = [x[0] if a is None else x for x, a in zip((values, index), axes)]
    want = jax.vmap(lambda d, s: jax.ops.segment_sum(d, s, T), axes)(*args)
    got = jax.jit(jax.vmap(lambda d, s: segment_sum(d, s, T), axes))(*args)
    np.testing.assert_allclose(got, want, rtol=1e-12)
    np.testing.assert_allclose(segment_sum(values[0], index[0], T),
                               jax.ops.segment_sum(values[0], index[0], T), rtol=1e-12)


@pytest.mark.parametrize("axes", [(0, 0, 0), (None, 0, 0), (0, None, None), (0, 0, None)])
def test_put_equals_set(axes):
    table, _, values = _arrays(jnp.float32)
    # distinct indices per batch member, so that the written values are defined
    index = jnp.stack([jnp.asarray(np.random.default_rng(b).permutation(T)[:5], jnp.int32)
                       for b in range(B)])
    args = [x[0] if a is None else x for x, a in zip((table, index, values[:, :5]), axes)]
    want = jax.vmap(lambda t, i, v: t.at[i].set(v), axes)(*args)
    np.testing.assert_array_equal(jax.jit(jax.vmap(put, axes))(*args), want)


def test_batches_too_large_for_int32_offsets_take_jax_rule(monkeypatch):
    # (the limit lowered: a real one needs tables of 2^31 entries)
    from jaxtrack import _gather
    monkeypatch.setattr(_gather, "_INT32_LIMIT", 1)
    table, index, values = _arrays(jnp.float32)
    np.testing.assert_array_equal(jax.vmap(take)(table, index),
                                  jax.vmap(lambda t, i: t[i])(table, index))
    np.testing.assert_allclose(jax.vmap(lambda d, s: segment_sum(d, s, T))(values, index),
                               jax.vmap(lambda d, s: jax.ops.segment_sum(d, s, T))(values,
                                                                                   index))
    first = jnp.tile(jnp.arange(5, dtype=jnp.int32), (B, 1))
    np.testing.assert_array_equal(jax.vmap(put)(table, first, values[:, :5]),
                                  jax.vmap(lambda t, i, v: t.at[i].set(v))(table, first,
                                                                          values[:, :5]))


def test_empty_trailing_axes_and_empty_rows_under_vmap():
    """Rows of zero width, and zero rows: shapes as JAX's own operations give them."""
    index = jnp.zeros((B, 4), jnp.int32)
    empty = jnp.zeros((B, T, 0))
    got = jax.vmap(put)(empty, index, jnp.zeros((B, 4, 0)))
    assert got.shape == (B, T, 0)
    got = jax.vmap(lambda d, s: segment_sum(d, s, T))(jnp.zeros((B, 4, 0)), index)
    assert got.shape == (B, T, 0)
    none = jnp.zeros((B, 0), jnp.int32)
    table = jnp.ones((B, T, 2))
    np.testing.assert_array_equal(jax.vmap(put)(table, none, jnp.zeros((B, 0, 2))), table)
    assert jax.vmap(lambda d, s: segment_sum(d, s, T))(jnp.zeros((B, 0, 2)),
                                                        none).shape == (B, T, 2)
    assert jax.vmap(take)(table, none).shape == (B, 0, 2)
