"""Input checks for public entry points.

Shapes are static under `jit`, so they are always checked. Values (NaN, symmetry, definiteness)
can only be read from concrete arrays: they are checked when the caller passes concrete arrays
and skipped for tracers, where the filters mask bad data instead.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence

import jax
import numpy as np


def is_concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def shape_of(x) -> tuple[int, ...]:
    return tuple(np.shape(x))


def check_ndim(name: str, x, ndim: int, what: str) -> None:
    if np.ndim(x) != ndim:
        raise ValueError(f"{name} must be {what} (ndim {ndim}); got shape {shape_of(x)}")


def check_shape(name: str, x, expected: Sequence[int | None], what: str = "") -> None:
    """Raise unless ``x.shape`` matches ``expected`` (None matches any size)."""
    shape = shape_of(x)
    ok = len(shape) == len(expected) and all(e is None or e == s for e, s in zip(expected, shape))
    if not ok:
        exp = "[" + ", ".join("?" if e is None else str(e) for e in expected) + "]"
        extra = f" ({what})" if what else ""
        raise ValueError(f"{name} must have shape {exp}{extra}; got {list(shape)}")


def check_square(name: str, x, n: int | None = None) -> int:
    shape = shape_of(x)
    if len(shape) != 2 or shape[0] != shape[1]:
        raise ValueError(f"{name} must be a square matrix; got shape {list(shape)}")
    if n is not None and shape[0] != n:
        raise ValueError(f"{name} must be [{n}, {n}]; got {list(shape)}")
    return shape[0]


def check_covariance(name: str, x, n: int | None = None, *, batch_axes: int = 0,
                     definite: bool = False) -> None:
    """Square; and if concrete: finite, symmetric and positive semi-definite (positive definite
    with ``definite``, e.g. a measurement noise that every innovation covariance must invert)."""
    shape = shape_of(x)
    core = shape[batch_axes:]
    if len(core) != 2 or core[0] != core[1] or (n is not None and core[0] != n):
        want = f"[{n}, {n}]" if n is not None else "square"
        lead = "leading batch axes + " if batch_axes else ""
        raise ValueError(f"{name} must be {lead}{want}; got shape {list(shape)}")
    if not is_concrete(x):
        return
    a = np.asarray(x, dtype=np.float64)
    if a.size == 0:  # a batch of zero covariances (zero tracks): nothing to check
        return
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains NaN or inf")
    scale = max(float(np.max(np.abs(a))), np.finfo(np.float64).tiny)
    tol = 1e-6 if np.asarray(x).dtype == np.float32 else 1e-9
    asym = float(np.max(np.abs(a - np.swapaxes(a, -1, -2))))
    if asym > tol * scale:
        raise ValueError(f"{name} is not symmetric (max |A - A^T| = {asym:.3g})")
    min_eig = float(np.min(np.linalg.eigvalsh(0.5 * (a + np.swapaxes(a, -1, -2)))))
    if min_eig < -1e3 * tol * scale:
        raise ValueError(f"{name} is not positive semi-definite (smallest eigenvalue {min_eig:.3g})")
    if definite and not min_eig > 0:
        raise ValueError(f"{name} must be positive definite (smallest eigenvalue {min_eig:.3g})")


def check_finite(name: str, x) -> None:
    if is_concrete(x) and not np.all(np.isfinite(np.asarray(x))):
        raise ValueError(f"{name} contains NaN or inf")


def check_probability(name: str, p) -> None:
    """If concrete: every entry finite and in [0, 1]."""
    if not is_concrete(p):
        return
    a = np.asarray(p, dtype=np.float64)
    if not (np.all(np.isfinite(a)) and np.all(a >= 0) and np.all(a <= 1)):
        raise ValueError(f"{name} must be a probability in [0, 1]; got {p!r}")


def check_options(name: str, value: Collection[str], allowed: Collection[str]) -> frozenset:
    if isinstance(value, str):
        value = (value,)
    unknown = set(value) - set(allowed)
    if unknown:
        raise ValueError(
            f"unknown {name} {sorted(unknown)}; expected a subset of {sorted(allowed)}"
        )
    return frozenset(value)


def check_callable(name: str, f) -> None:
    if not callable(f):
        raise TypeError(f"{name} must be callable; got {type(f).__name__}")
