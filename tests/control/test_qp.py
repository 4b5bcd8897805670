"""Box-constrained QP solver (`jaxtrack.control.qp`): optimality, feasibility, warm start,
vmap, gradients and input checks.

References, all independent of the solver: scipy's BVLS (`scipy.optimize.lsq_linear` on the
Cholesky factor, :math:`\\tfrac12 x^\\top H x + g^\\top x = \\tfrac12 \\|L^\\top x + L^{-1} g\\|^2
+ c` with :math:`H = L L^\\top`; an exact active-set method) and L-BFGS-B
(`scipy.optimize.minimize`); brute-force enumeration of the 3^n active sets; closed forms
(unconstrained :math:`-H^{-1} g`, diagonal :math:`H`, the docstring example); the KKT
conditions; the error bounds of the natural residual of a strongly convex QP,
:math:`\\|x - x^\\star\\|_2 \\le \\tfrac{1 + L}{\\mu} \\|r(x)\\|_2` and
:math:`\\|r(x)\\|_2 \\le (2 + L) \\|x - x^\\star\\|_2`; the implicit-function derivative on the
active set and central finite differences.

x64 is on (tests/conftest.py); float32 tests cast their inputs explicitly. Every solve goes
through a few module-level jitted functions, with shapes [6] and [12], to keep compilations
down.
"""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import lsq_linear, minimize

from jaxtrack.control.qp import BoxQPSolution, check_box_qp, solve_box_qp

INF = np.inf
ITERS = 24  # >= 2n for every problem here (n <= 12): enough for a cold start.
DTYPES = [np.float64, np.float32]

solve = jax.jit(solve_box_qp, static_argnames=("iterations",))
solve_batch = jax.jit(jax.vmap(lambda H, g, lo, hi: solve_box_qp(H, g, lo, hi, ITERS)))


def loss(x):
    """A scalar function of the solution for the gradient tests."""
    c = jnp.linspace(-1.0, 1.0, x.shape[0], dtype=x.dtype)
    return c @ x + 0.5 * x @ x


solve_loss_grad = jax.jit(jax.grad(
    lambda H, g, lo, hi: loss(solve_box_qp(H, g, lo, hi, ITERS).x), argnums=(0, 1, 2, 3)))


# --------------------------------------------------------------------------- helpers


def random_problem(seed, n, cond, p_inf=0.25, spread=2.0):
    """A random SPD problem in float64: H with eigenvalues log-spaced in [1, cond], the
    unconstrained minimiser ~ N(0, spread^2) (so that some variables end on a bound), bounds in
    [-1.5, -0.2] and [0.2, 1.5] (0 is inside the box), a fraction p_inf of them infinite."""
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    H = (Q * np.logspace(0.0, np.log10(cond), n)) @ Q.T
    H = 0.5 * (H + H.T)
    g = -H @ (spread * rng.normal(size=n))
    lo = -rng.uniform(0.2, 1.5, n)
    hi = rng.uniform(0.2, 1.5, n)
    lo[rng.random(n) < p_inf] = -INF
    hi[rng.random(n) < p_inf] = INF
    return H, g, lo, hi


def cast(dtype, *arrays):
    return tuple(jnp.asarray(a, dtype) for a in arrays)


def bvls(H, g, lo, hi):
    """Exact reference: BVLS on the Cholesky factor (float64)."""
    L = np.linalg.cholesky(H)
    res = lsq_linear(L.T, -np.linalg.solve(L, g), bounds=(lo, hi), method="bvls", tol=1e-15)
    return res.x


def lbfgsb(H, g, lo, hi):
    res = minimize(lambda x: (0.5 * x @ H @ x + g @ x, H @ x + g), np.clip(0.0, lo, hi),
                   jac=True, method="L-BFGS-B", bounds=list(zip(lo, hi)),
                   options=dict(ftol=0.0, gtol=1e-13, maxiter=50_000, maxcor=50))
    return res.x


def brute_force(H, g, lo, hi):
    """Minimum over every assignment of each variable to {free, lower, upper} whose
    equality-constrained minimiser is feasible."""
    n = len(g)
    best, best_f = None, INF
    for state in itertools.product((0, 1, 2), repeat=n):
        state = np.array(state)
        x = np.where(state == 1, lo, np.where(state == 2, hi, 0.0))
        if not np.all(np.isfinite(x)):
            continue
        f = state == 0
        if f.any():
            x[f] = np.linalg.solve(H[np.ix_(f, f)], -(g[f] + H[np.ix_(f, ~f)] @ x[~f]))
        if np.all(x >= lo - 1e-12) and np.all(x <= hi + 1e-12):
            val = 0.5 * x @ H @ x + g @ x
            if val < best_f:
                best, best_f = x, val
    return best


def objective(H, g, x):
    return 0.5 * x @ H @ x + g @ x


def natural_residual(H, g, lo, hi, x):
    return x - np.clip(x - (H @ x + g), lo, hi)


def scale(H, g, x):
    """Magnitude of the gradient's terms, to make gradient tolerances relative."""
    return np.linalg.norm(H, 2) * max(1.0, np.abs(x).max()) + np.abs(g).max()


def x_tol(dtype, cond, x_ref):
    """Solution tolerance: float64 tight; float32 to ~ cond * eps32 (the float32 rounding of
    the problem alone moves the solution that much)."""
    if dtype == np.float64:
        return 1e-10 * max(1.0, cond / 1e2) * max(1.0, np.abs(x_ref).max())
    return 5e-7 * cond * max(1.0, np.abs(x_ref).max())


def residual_tol(dtype, H, g, x):
    return 50 * np.finfo(dtype).eps * scale(H, g, x)


def strictly_complementary(H, g, lo, hi, x, margin=1e-6):
    """Every reference variable is either inside the box by a margin or on a bound with a
    multiplier above the margin (so the active set is well defined)."""
    grad = H @ x + g
    inside = (x > lo + margin) & (x < hi - margin)
    on_lo = (x == lo) & (grad > margin)
    on_hi = (x == hi) & (grad < -margin)
    return bool(np.all(inside | on_lo | on_hi))


def reference(H, g, lo, hi):
    """BVLS with the bounds snapped exactly (BVLS ends on them to rounding)."""
    x = bvls(H, g, lo, hi)
    x = np.where(np.isclose(x, lo, rtol=0, atol=1e-12), lo, x)
    return np.where(np.isclose(x, hi, rtol=0, atol=1e-12), hi, x)


# (n, condition number, seeds): sizes 6 and 12 only (two compilations per dtype).
SCIPY_CASES = [(6, 10.0, (0, 1, 2)), (6, 1e4, (3, 4, 5)), (12, 1e2, (6, 7, 8)),
               (12, 1e4, (9, 10, 11))]


# --------------------------------------------------------------------------- 1. scipy


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("n,cond,seeds", SCIPY_CASES)
def test_matches_scipy_on_random_spd_problems(n, cond, seeds, dtype):
    for seed in seeds:
        H, g, lo, hi = random_problem(seed, n, cond)
        x_bvls, x_lb = bvls(H, g, lo, hi), lbfgsb(H, g, lo, hi)
        on_bound = np.isclose(x_bvls, lo, atol=1e-9) | np.isclose(x_bvls, hi, atol=1e-9)
        # The problem mixes infinite bounds, variables on a bound and free variables.
        assert np.isinf(lo).any() or np.isinf(hi).any()
        assert 0 < on_bound.sum() < n, (seed, on_bound)
        # The two scipy references agree (L-BFGS-B to its own accuracy).
        np.testing.assert_allclose(x_lb, x_bvls, atol=1e-6 * max(1.0, cond / 1e3))

        sol = solve(*cast(dtype, H, g, lo, hi), iterations=ITERS)
        assert isinstance(sol, BoxQPSolution)
        assert sol.x.dtype == dtype and sol.residual.dtype == dtype and sol.free.dtype == bool
        x = np.asarray(sol.x, np.float64)
        np.testing.assert_allclose(x, x_bvls, rtol=0, atol=x_tol(dtype, cond, x_bvls),
                                   err_msg=f"seed {seed}")
        assert float(sol.residual) <= residual_tol(dtype, H, g, x), (seed, float(sol.residual))
        if dtype == np.float64:
            # At least as good as L-BFGS-B with tight tolerances, and feasible.
            assert objective(H, g, x) <= objective(H, g, x_lb) + 1e-12 * (
                1.0 + abs(objective(H, g, x_lb)))
            np.testing.assert_allclose(x, x_lb, rtol=0, atol=1e-6 * max(1.0, cond / 1e3))


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("seed", [20, 21, 22, 23])
def test_matches_brute_force_enumeration(seed, dtype):
    H, g, lo, hi = random_problem(seed, 6, 10.0 ** (1 + seed % 4), p_inf=0.2)
    cond = np.linalg.cond(H)
    want = brute_force(H, g, lo, hi)
    sol = solve(*cast(dtype, H, g, lo, hi), iterations=ITERS)
    np.testing.assert_allclose(np.asarray(sol.x, np.float64), want, rtol=0,
                               atol=x_tol(dtype, cond, want))


# --------------------------------------------------------------------------- 2. closed forms


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("iterations", [1, ITERS])
def test_unconstrained_is_the_newton_step(iterations, dtype):
    # With infinite bounds the working set stays empty: one iteration is the exact solve.
    H, g, _, _ = random_problem(30, 12, 1e3)
    lo, hi = np.full(12, -INF), np.full(12, INF)
    sol = solve(*cast(dtype, H, g, lo, hi), iterations=iterations)
    want = np.linalg.solve(H, -g)
    assert np.abs(want).max() > 1.0  # the bounds of `random_problem` would have been active
    np.testing.assert_allclose(np.asarray(sol.x, np.float64), want, rtol=0,
                               atol=x_tol(dtype, 1e3, want))
    assert np.all(np.asarray(sol.free))
    assert float(sol.residual) <= residual_tol(dtype, H, g, want)


@pytest.mark.parametrize("dtype", DTYPES)
def test_diagonal_hessian_is_the_clipped_minimiser(dtype):
    d = np.array([0.3, 2.0, 7.0, 1.1, 5.0, 0.9])
    g = np.array([1.0, -3.0, 0.7, -0.2, 9.0, -1.3])
    lo = np.array([-1.0, -1.0, -INF, 0.0, -1.0, -2.0])
    hi = np.array([1.0, 1.0, 1.0, INF, 1.0, 0.5])
    H, g, lo, hi = (np.asarray(a, dtype) for a in (np.diag(d), g, lo, hi))
    want = np.clip(-g / np.diag(H), lo, hi)
    clipped = (want == lo) | (want == hi)
    assert 0 < clipped.sum() < 6
    sol = solve(*cast(dtype, H, g, lo, hi), iterations=ITERS)
    x = np.asarray(sol.x)
    # On a bound: exactly the bound; free: -g_i / d_i to a few ulps (a Cholesky solve).
    np.testing.assert_array_equal(x[clipped], want[clipped])
    np.testing.assert_allclose(x[~clipped], want[~clipped], rtol=4 * np.finfo(dtype).eps)
    np.testing.assert_array_equal(np.asarray(sol.free), ~clipped)


def test_docstring_example():
    sol = solve(jnp.eye(2), jnp.array([-2.0, 0.5]), jnp.zeros(2), jnp.ones(2), iterations=ITERS)
    np.testing.assert_array_equal(np.asarray(sol.x), [1.0, 0.0])
    assert float(sol.residual) == 0.0
    np.testing.assert_array_equal(np.asarray(sol.free), [False, False])


# --------------------------------------------------------------------------- 3. KKT


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("seed,cond", [(40, 10.0), (41, 1e2), (42, 1e3), (43, 1e4)])
def test_kkt_conditions_and_free_flags(seed, cond, dtype):
    H, g, lo, hi = random_problem(seed, 12, cond)
    x_ref = reference(H, g, lo, hi)
    assert strictly_complementary(H, g, lo, hi, x_ref)
    Hd, gd, lod, hid = (np.asarray(a, dtype) for a in (H, g, lo, hi))
    sol = solve(*cast(dtype, Hd, gd, lod, hid), iterations=ITERS)
    x, free = np.asarray(sol.x), np.asarray(sol.free)
    grad = H @ x.astype(np.float64) + g
    tol = residual_tol(dtype, H, g, x_ref)
    # Fixed variables sit exactly on a bound, with a multiplier of the right sign.
    at_lo, at_hi = ~free & (x == lod), ~free & (x == hid)
    assert np.all(at_lo | at_hi | free)
    assert np.all(grad[at_lo] >= -tol), grad[at_lo]
    assert np.all(grad[at_hi] <= tol), grad[at_hi]
    # Free variables: stationary, inside the box.
    np.testing.assert_array_less(np.abs(grad[free]), tol)
    assert np.all((x[free] >= lod[free]) & (x[free] <= hid[free]))
    # The flags are the reference's active set (strict complementarity makes it unique).
    np.testing.assert_array_equal(free, (x_ref > lo) & (x_ref < hi))
    assert 0 < free.sum() < 12


# ------------------------------------------------------------- 4. feasibility, residual


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("iterations", [1, 2, 3])
def test_every_iterate_is_feasible_and_the_residual_bounds_the_error(iterations, dtype):
    for seed in (50, 51, 52):
        H, g, lo, hi = random_problem(seed, 12, 1e2, spread=3.0)
        x_ref = reference(H, g, lo, hi)
        on_bound = (x_ref == lo) | (x_ref == hi)
        assert on_bound.sum() > 3  # a cold start cannot have finished after 3 iterations
        Hd, gd, lod, hid = (np.asarray(a, dtype) for a in (H, g, lo, hi))
        if iterations == 3:  # also from a start far outside the box (projected into it)
            x0 = 5.0 * np.random.default_rng(seed).normal(size=12)
            sol = solve(*cast(dtype, Hd, gd, lod, hid), iterations=iterations,
                        x0=jnp.asarray(x0, dtype))
        else:
            sol = solve(*cast(dtype, Hd, gd, lod, hid), iterations=iterations)
        x = np.asarray(sol.x)
        assert np.all(np.isfinite(x))
        assert np.all((x >= lod) & (x <= hid)), (seed, x, lod, hid)
        # Not converged: the residual says so, and it bounds the error both ways.
        r = float(sol.residual)
        xd = x.astype(np.float64)
        err = np.linalg.norm(xd - x_ref)
        assert err > 1e-3, seed
        ev = np.linalg.eigvalsh(H)
        assert r > 1e-3
        assert err <= (1 + ev[-1]) / ev[0] * np.sqrt(12) * r * (1 + 1e-4)
        assert r <= (2 + ev[-1]) * err * (1 + 1e-4)
        np.testing.assert_allclose(r, np.abs(natural_residual(H, g, lo, hi, xd)).max(),
                                   rtol=1e-3 if dtype == np.float32 else 1e-9)


@pytest.mark.parametrize("dtype", DTYPES)
def test_the_start_is_projected_into_the_box(dtype):
    # iterations=0 returns the start: x0 clipped to the box, and its natural residual.
    H, g, lo, hi = random_problem(95, 6, 10.0)
    x0 = 5.0 * np.random.default_rng(95).normal(size=6)
    Hd, gd, lod, hid, x0d = (np.asarray(a, dtype) for a in (H, g, lo, hi, x0))
    want = np.clip(x0d, lod, hid)
    assert np.any(want != x0d)
    sol = solve(*cast(dtype, Hd, gd, lod, hid), iterations=0, x0=jnp.asarray(x0d))
    np.testing.assert_array_equal(np.asarray(sol.x), want)
    np.testing.assert_allclose(float(sol.residual),
                               np.abs(natural_residual(H, g, lo, hi, want.astype(float))).max(),
                               rtol=1e-5 if dtype == np.float32 else 1e-12)


@pytest.mark.parametrize("dtype", DTYPES)
def test_enough_iterations_drive_the_residual_to_zero(dtype):
    for seed in (50, 51, 52):
        H, g, lo, hi = random_problem(seed, 12, 1e2, spread=3.0)
        x_ref = reference(H, g, lo, hi)
        sol = solve(*cast(dtype, H, g, lo, hi), iterations=ITERS)
        x = np.asarray(sol.x, np.float64)
        assert float(sol.residual) <= residual_tol(dtype, H, g, x_ref)
        np.testing.assert_allclose(x, x_ref, rtol=0, atol=x_tol(dtype, 1e2, x_ref))


# --------------------------------------------------------------------------- 5. warm start


def active_set(x, lo, hi):
    return np.where(x == lo, -1, np.where(x == hi, 1, 0))


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("seed,changes", [(60, 0), (64, 1), (61, 2), (69, 2)])
def test_warm_start_converges_in_three_iterations(seed, changes, dtype):
    cond = 1e3
    H, g, lo, hi = random_problem(seed, 12, cond, spread=3.0)
    rng = np.random.default_rng(seed + 1000)
    g2 = g + 1e-2 * np.abs(g).max() * rng.normal(size=12)      # the next control period
    x2_ref = reference(H, g2, lo, hi)
    # The perturbation moves `changes` variables onto or off a bound; each iteration changes
    # the working set by one, so three iterations are enough from the last solution.
    assert np.sum(active_set(reference(H, g, lo, hi), lo, hi)
                  != active_set(x2_ref, lo, hi)) == changes
    x_prev = solve(*cast(dtype, H, g, lo, hi), iterations=ITERS).x
    warm = solve(*cast(dtype, H, g2, lo, hi), iterations=3, x0=x_prev)
    cold = solve(*cast(dtype, H, g2, lo, hi), iterations=3, x0=jnp.zeros(12, dtype))
    tol = x_tol(dtype, cond, x2_ref)
    # The cold start needs more than three iterations on this problem ...
    assert np.abs(np.asarray(cold.x, np.float64) - x2_ref).max() > 1e-2
    assert float(cold.residual) > 1e-2
    # ... the warm start does not.
    np.testing.assert_allclose(np.asarray(warm.x, np.float64), x2_ref, rtol=0, atol=tol)
    assert float(warm.residual) <= residual_tol(dtype, H, g2, x2_ref)
    np.testing.assert_array_equal(np.asarray(warm.free), active_set(x2_ref, lo, hi) == 0)


# --------------------------------------------------------------------------- 6. vmap


@pytest.mark.parametrize("dtype", DTYPES)
def test_vmap_equals_per_problem_solves(dtype):
    problems = [random_problem(70 + i, 12, 10.0 ** (1 + i % 3)) for i in range(4)]
    stacked = [np.stack([p[k] for p in problems]).astype(dtype) for k in range(4)]
    batch = solve_batch(*(jnp.asarray(a) for a in stacked))
    assert batch.x.shape == (4, 12) and batch.residual.shape == (4,)
    assert len({tuple(np.asarray(f)) for f in batch.free}) == 4  # different active sets
    for i, p in enumerate(problems):
        one = solve(*cast(dtype, *p), iterations=ITERS)
        np.testing.assert_allclose(np.asarray(batch.x[i]), np.asarray(one.x), rtol=0,
                                   atol=x_tol(dtype, 1e3, np.asarray(one.x)) * 1e-2)
        np.testing.assert_array_equal(np.asarray(batch.free[i]), np.asarray(one.free))
        assert float(batch.residual[i]) <= residual_tol(dtype, p[0], p[1], np.asarray(one.x))


# --------------------------------------------------------------------------- 7. gradients


def active_set_derivatives(H, g, lo, hi, x, free):
    """Implicit-function derivatives of x on a fixed active set: x_F = -H_FF^-1 (g_F + H_FA
    x_A), x_A = the bounds. Returns (d loss / dg, d loss / dlo, d loss / dhi, dx / dH along a
    symmetric direction S as a function)."""
    n = len(g)
    Hinv = np.zeros((n, n))
    Hinv[np.ix_(free, free)] = np.linalg.inv(H[np.ix_(free, free)])
    dloss_dx = np.linspace(-1.0, 1.0, n) + x
    at_lo = ~free & (x == lo)
    at_hi = ~free & (x == hi)
    # dx/dg = -Hinv;  dx/d(bound_j) = e_j - Hinv H e_j for j active at that bound, 0 otherwise.
    dx_dbound = np.eye(n) - Hinv @ H
    d_g = -Hinv.T @ dloss_dx
    d_lo = np.where(at_lo, dx_dbound.T @ dloss_dx, 0.0)
    d_hi = np.where(at_hi, dx_dbound.T @ dloss_dx, 0.0)
    return d_g, d_lo, d_hi, lambda S: dloss_dx @ (-Hinv @ (S @ x))


@pytest.mark.parametrize("bounds", ["finite", "some infinite"])
def test_gradient_matches_active_set_derivative_and_finite_differences(bounds):
    n = 6
    H, g, lo, hi = random_problem(80, n, 50.0, p_inf=0.0, spread=1.5)
    if bounds == "some infinite":
        lo[[1, 4]] = -INF
        hi[[2]] = INF
    x_ref = reference(H, g, lo, hi)
    assert strictly_complementary(H, g, lo, hi, x_ref, margin=1e-3)
    sol = solve(H, g, lo, hi, iterations=ITERS)
    x, free = np.asarray(sol.x), np.asarray(sol.free)
    assert 0 < free.sum() < n

    dH, dg, dlo, dhi = (np.asarray(a) for a in solve_loss_grad(H, g, lo, hi))
    for name, d in (("H", dH), ("g", dg), ("lower", dlo), ("upper", dhi)):
        assert np.all(np.isfinite(d)), f"d loss / d {name} is not finite: {d}"

    want_g, want_lo, want_hi, dx_along = active_set_derivatives(H, g, lo, hi, x, free)
    np.testing.assert_allclose(dg, want_g, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(dlo, want_lo, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(dhi, want_hi, rtol=1e-9, atol=1e-12)

    # Central finite differences of the (linear, on this active set) map; H along symmetric
    # directions, since only symmetric perturbations keep the problem valid.
    f = lambda *args: float(loss(solve(*args, iterations=ITERS).x))  # noqa: E731
    eps = 1e-6
    for k, (name, grad) in enumerate((("g", dg), ("lower", dlo), ("upper", dhi))):
        for i in range(n):
            args_p = [H, g.copy(), lo.copy(), hi.copy()]
            args_m = [H, g.copy(), lo.copy(), hi.copy()]
            if not np.isfinite(args_p[k + 1][i]):
                assert grad[i] == 0.0, (name, i)
                continue
            args_p[k + 1][i] += eps
            args_m[k + 1][i] -= eps
            fd = (f(*args_p) - f(*args_m)) / (2 * eps)
            np.testing.assert_allclose(grad[i], fd, rtol=1e-6, atol=1e-8,
                                       err_msg=f"d loss / d {name}[{i}]")
    rng = np.random.default_rng(81)
    for _ in range(3):
        S = rng.normal(size=(n, n))
        S = S + S.T
        fd = (f(H + eps * S, g, lo, hi) - f(H - eps * S, g, lo, hi)) / (2 * eps)
        np.testing.assert_allclose(np.sum(dH * S), fd, rtol=1e-6, atol=1e-8)
        np.testing.assert_allclose(np.sum(dH * S), dx_along(S), rtol=1e-9, atol=1e-12)


# --------------------------------------------------------------------------- 8. check_box_qp

_H = np.array([[2.0, 0.5, 0.0], [0.5, 1.0, 0.1], [0.0, 0.1, 3.0]])
_g = np.array([1.0, -1.0, 0.5])
_lo, _hi = -np.ones(3), np.ones(3)


def _with(a, index, value):
    a = np.array(a, dtype=float)
    a[index] = value
    return a


@pytest.mark.parametrize("args,match", [
    pytest.param((np.ones((3, 2)), _g, _lo, _hi), r"H must be a square matrix.*\[3, 2\]",
                 id="H not square"),
    pytest.param((np.ones(3), _g, _lo, _hi), r"H must be a square matrix", id="H 1-d"),
    pytest.param((np.ones((2, 3, 3)), _g, _lo, _hi), r"H must be a square matrix", id="H 3-d"),
    pytest.param((_H, _g[:2], _lo, _hi), r"g must have shape \[3\]; got \[2\]", id="g short"),
    pytest.param((_H, _g[:, None], _lo, _hi), r"g must have shape \[3\]; got \[3, 1\]",
                 id="g column"),
    pytest.param((_H, _g, np.zeros(4), _hi), r"lower must have shape \[3\]; got \[4\]",
                 id="lower long"),
    pytest.param((_H, _g, _lo, 1.0), r"upper must have shape \[3\]; got \[\]",
                 id="upper scalar"),
    pytest.param((_with(_H, (0, 1), np.nan), _g, _lo, _hi), r"H and g must be finite",
                 id="NaN in H"),
    pytest.param((_H, _with(_g, 2, np.nan), _lo, _hi), r"H and g must be finite",
                 id="NaN in g"),
    pytest.param((_with(_H, (2, 2), INF), _g, _lo, _hi), r"H and g must be finite",
                 id="inf in H"),
    pytest.param((_H, _g, _with(_lo, 1, np.nan), _hi), r"bounds must not be NaN",
                 id="NaN lower"),
    pytest.param((_H, _g, _lo, _with(_hi, 0, np.nan)), r"bounds must not be NaN",
                 id="NaN upper"),
    pytest.param((_H, _g, _with(_lo, 1, 2.0), _hi), r"lower\[1\] = 2\.0 is above upper\[1\]"
                 r" = 1\.0", id="lower above upper"),
    pytest.param((_H, _g, _with(_lo, 2, INF), _with(_hi, 2, -INF)), r"no feasible point",
                 id="lower +inf above upper -inf"),
    pytest.param((_H, _g, _with(_lo, 2, INF), _with(_hi, 2, INF)), r"no feasible point",
                 id="both bounds +inf"),
    pytest.param((_with(_H, (0, 2), 0.3), _g, _lo, _hi), r"H must be symmetric",
                 id="asymmetric"),
    pytest.param((np.diag([1.0, -1.0, 2.0]), _g, _lo, _hi), r"H must be positive definite",
                 id="indefinite"),
    pytest.param((np.ones((3, 3)), _g, _lo, _hi), r"H must be positive definite",
                 id="singular PSD"),
    pytest.param((np.zeros((3, 3)), _g, _lo, _hi), r"H must be positive definite", id="zero"),
])
def test_check_rejects_malformed_problems(args, match):
    with pytest.raises(ValueError, match=match):
        check_box_qp(*args)


@pytest.mark.parametrize("lower,upper", [
    (_lo, _hi),
    (np.full(3, -INF), np.full(3, INF)),
    (np.array([-INF, 0.0, -1.0]), np.array([1.0, INF, -1.0])),       # infinite and fixed
])
@pytest.mark.parametrize("dtype", DTYPES)
def test_check_accepts_valid_problems(lower, upper, dtype):
    assert check_box_qp(*(np.asarray(a, dtype) for a in (_H, _g, lower, upper))) is None
    assert check_box_qp(*cast(dtype, _H, _g, lower, upper)) is None  # jax arrays too


def test_check_accepts_the_random_test_problems():
    for n, cond, seeds in SCIPY_CASES:
        for seed in seeds:
            check_box_qp(*random_problem(seed, n, cond))


# --------------------------------------------------------------------------- 9. fixed variables


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("seed", [90, 91, 92])
def test_fixed_variables_keep_their_values(seed, dtype):
    n, cond = 12, 1e2
    H, g, lo, hi = random_problem(seed, n, cond, spread=3.0)
    fixed = np.zeros(n, bool)
    fixed[[0, 5, 9]] = True
    values = np.array([0.3, -0.7, 1.25])
    lo[fixed] = hi[fixed] = values
    # Reference: the reduced problem in the other variables.
    r = ~fixed
    x_ref = np.empty(n)
    x_ref[fixed] = values
    x_ref[r] = reference(H[np.ix_(r, r)], g[r] + H[np.ix_(r, fixed)] @ values, lo[r], hi[r])
    Hd, gd, lod, hid = (np.asarray(a, dtype) for a in (H, g, lo, hi))
    sol = solve(*cast(dtype, Hd, gd, lod, hid), iterations=ITERS)
    x = np.asarray(sol.x)
    np.testing.assert_array_equal(x[fixed], values.astype(dtype))
    assert not np.any(np.asarray(sol.free)[fixed])
    np.testing.assert_allclose(x[r].astype(np.float64), x_ref[r], rtol=0,
                               atol=x_tol(dtype, cond, x_ref))
    assert float(sol.residual) <= residual_tol(dtype, H, g, x_ref)


@pytest.mark.parametrize("dtype", DTYPES)
def test_all_variables_fixed(dtype):
    H, g, _, _ = random_problem(93, 6, 1e2)
    values = np.array([0.5, -1.0, 0.0, 2.0, -0.25, 1e-3], dtype)
    sol = solve(*cast(dtype, H, g, values, values), iterations=ITERS)
    np.testing.assert_array_equal(np.asarray(sol.x), values)
    assert not np.any(np.asarray(sol.free))
    assert float(sol.residual) == 0.0


def test_empty_problem_is_valid():
    """n = 0: the check passes and the solve returns an empty solution with zero residual."""
    empty = np.zeros((0, 0)), np.zeros(0), np.zeros(0), np.zeros(0)
    assert check_box_qp(*empty) is None
    sol = solve_box_qp(*(jnp.asarray(a) for a in empty))
    assert sol.x.shape == (0,) and sol.free.shape == (0,)
    assert float(sol.residual) == 0.0
