"""Small dense linear algebra shared by the Gaussian filters.

Tracking works with tiny matrices (2-8 states) batched over thousands of episodes. XLA's CPU
`cholesky` and `triangular_solve` run one LAPACK call per matrix under `vmap`, which costs far
more than the arithmetic; below ``UNROLL_MAX`` we unroll both at trace time into scalar
operations on the batch axis, which XLA fuses into a single loop (faster on batches of small
matrices: see ``benchmarks/filters.py``, and docs/design_notes.md, "Gaussian filters: unrolled
small-matrix linear algebra"). Larger matrices use LAPACK.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import lax
from jax.scipy.linalg import solve_triangular

UNROLL_MAX = 8


def symmetrize(a):
    """(A + A^T) / 2 over the last two axes."""
    return 0.5 * (a + jnp.swapaxes(a, -1, -2))


def inv2(a):
    """Closed-form inverse of [..., 2, 2] matrices (batched LAPACK calls on tiny matrices are
    slow on the CPU)."""
    p, q, r, t = a[..., 0, 0], a[..., 0, 1], a[..., 1, 0], a[..., 1, 1]
    det = p * t - q * r
    inv = jnp.stack([jnp.stack([t, -q], -1), jnp.stack([-r, p], -1)], -2)
    return inv / det[..., None, None]


def cholesky(a):
    """Lower Cholesky factor of a symmetric positive-definite matrix [..., n, n].

    Returns NaN entries (never raises) when ``a`` is not positive definite, like
    `jnp.linalg.cholesky`.
    """
    n = a.shape[-1]
    if n > UNROLL_MAX:
        return jnp.linalg.cholesky(a)
    low = [[None] * n for _ in range(n)]
    for j in range(n):
        s = a[..., j, j]
        for k in range(j):
            s = s - low[j][k] ** 2
        d = jnp.sqrt(s)
        low[j][j] = d
        for i in range(j + 1, n):
            s = a[..., i, j]
            for k in range(j):
                s = s - low[i][k] * low[j][k]
            low[i][j] = s / d
    zero = jnp.zeros_like(a[..., 0, 0])
    rows = [jnp.stack([low[i][j] if j <= i else zero for j in range(n)], -1) for i in range(n)]
    return jnp.stack(rows, -2)


def solve_lower(low, b):
    """Solve L X = B for lower-triangular L [n, n] and B [n, k] (forward substitution)."""
    n = low.shape[-1]
    if n > UNROLL_MAX:
        return solve_triangular(low, b, lower=True)
    x = []
    for i in range(n):
        s = b[..., i, :]
        for k in range(i):
            s = s - low[..., i, k, None] * x[k]
        x.append(s / low[..., i, i, None])
    return jnp.stack(x, -2)


def solve_upper_t(low, b):
    """Solve L^T X = B for lower-triangular L [n, n] and B [n, k] (back substitution)."""
    n = low.shape[-1]
    if n > UNROLL_MAX:
        return solve_triangular(low, b, lower=True, trans=1)
    x = [None] * n
    for i in reversed(range(n)):
        s = b[..., i, :]
        for k in range(i + 1, n):
            s = s - low[..., k, i, None] * x[k]
        x[i] = s / low[..., i, i, None]
    return jnp.stack(x, -2)


def cho_solve(low, b):
    """Solve (L L^T) X = B given the lower Cholesky factor L [n, n] and B [n, k]."""
    return solve_upper_t(low, solve_lower(low, b))


def gaussian_log_density(low, r):
    """log N(r; 0, L L^T) for a residual r [m] and lower Cholesky factor L [m, m].

    Returns ``(log_density, whitened)`` where ``whitened = L^{-1} r`` [m].
    """
    m = r.shape[-1]
    w = solve_lower(low, r[..., None])[..., 0]
    log_det = 2.0 * jnp.sum(jnp.log(jnp.diagonal(low, axis1=-2, axis2=-1)), -1)
    return -0.5 * (jnp.sum(w * w, -1) + log_det + m * jnp.log(2.0 * jnp.pi)), w


def safe_cholesky(a, rel_jitter=None):
    """Cholesky of a covariance [n, n] that should be positive definite but may have drifted.

    The matrix is symmetrised first. If the factor is not finite, the factorisation is retried on
    ``a + eps * mean(diag(a)) * I`` with ``eps`` = 1e-9 (float64) or 1e-5 (float32); if that also
    fails, the square root of the clipped diagonal is used. The fallback sits behind `lax.cond`,
    so a single episode only pays for it when the first factorisation failed (under `vmap` both
    branches run and the result is selected).
    """
    a = symmetrize(a)
    if rel_jitter is None:
        rel_jitter = 1e-9 if a.dtype == jnp.float64 else 1e-5
    low = cholesky(a)
    ok = jnp.all(jnp.isfinite(low))
    return lax.cond(ok, lambda: low, lambda: _jittered_cholesky(a, rel_jitter))


def _jittered_cholesky(a, rel_jitter):
    n = a.shape[-1]
    diag = jnp.diagonal(a, axis1=-2, axis2=-1)
    scale = jnp.maximum(jnp.mean(jnp.abs(diag), -1), jnp.finfo(a.dtype).tiny)
    eye = jnp.eye(n, dtype=a.dtype)
    low_j = cholesky(a + (rel_jitter * scale)[..., None, None] * eye)
    ok_j = jnp.all(jnp.isfinite(low_j), axis=(-2, -1), keepdims=True)
    low_d = jnp.sqrt(jnp.maximum(diag, rel_jitter * scale[..., None]))[..., None] * eye
    return jnp.where(ok_j, low_j, low_d)
