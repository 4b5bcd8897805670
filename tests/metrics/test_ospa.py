"""Tests for `jaxtrack.metrics.ospa` (OSPA and GOSPA).

References: hand-computed cases, and a brute-force minimum over every injective assignment of
the smaller set into the larger (itertools.permutations) of the defining formulas, on 300 random
masked set pairs with p in {1, 2, 3}, c in {0.5, 1, 3} and alpha in {0.5, 1, 2}. Tolerance 1e-12
(relative) in float64, 1e-5 in float32.
"""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack import metrics

N, M, D = 4, 5, 2
RNG = np.random.default_rng(99)


def brute_force(x, y, c, p, alpha):
    """(OSPA, GOSPA) from the definitions, by enumerating assignments."""
    m, n = len(x), len(y)
    if m > n:
        x, y, m, n = y, x, n, m
    if n == 0:
        return 0.0, 0.0
    best = np.inf
    for perm in itertools.permutations(range(n), m):
        s = sum(min(c, np.linalg.norm(x[i] - y[j])) ** p for i, j in enumerate(perm))
        best = min(best, s)
    ospa = ((best + c**p * (n - m)) / n) ** (1 / p)
    gospa = (best + c**p / alpha * (n - m)) ** (1 / p)
    return ospa, gospa


def random_case(rng):
    x = rng.uniform(0, 3, (N, D))
    y = rng.uniform(0, 3, (M, D))
    xm, ym = rng.random(N) < 0.7, rng.random(M) < 0.7
    x[~xm] = np.nan  # masked slots may hold anything
    y[~ym] = np.nan
    return x, xm, y, ym


@jax.jit
@jax.vmap
def _both(x, xm, y, ym, c, p, alpha):
    """OSPA and GOSPA of a batch of set pairs, one compiled function for the whole file."""
    return metrics.ospa(x, xm, y, ym, c, p), metrics.gospa(x, xm, y, ym, c, p, alpha)


@pytest.fixture(scope="module")
def random_cases():
    rng = np.random.default_rng(5)
    cases = [random_case(rng) for _ in range(300)]
    params = [(c, p, alpha) for c in (0.5, 1.0, 3.0) for p in (1.0, 2.0, 3.0)
              for alpha in (0.5, 1.0, 2.0)]
    chosen = [params[i % len(params)] for i in range(len(cases))]
    stack = [np.stack(a) for a in zip(*cases)]
    c, p, alpha = (np.array(a) for a in zip(*chosen))
    return cases, chosen, stack, (c, p, alpha)


def test_ospa_and_gospa_equal_a_brute_force_minimum_over_assignments(random_cases):
    cases, chosen, (x, xm, y, ym), (c, p, alpha) = random_cases
    o, g = jax.device_get(_both(x, xm, y, ym, c, p, alpha))
    for i, ((xi, xmi, yi, ymi), (ci, pi, ai)) in enumerate(zip(cases, chosen)):
        ref_o, ref_g = brute_force(xi[xmi], yi[ymi], ci, pi, ai)
        np.testing.assert_allclose(o.distance[i], ref_o, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(g.distance[i], ref_g, rtol=1e-12, atol=1e-12)
    # The decompositions add up.
    np.testing.assert_allclose(o.distance**p, o.localisation**p + o.cardinality**p, rtol=1e-10)
    np.testing.assert_allclose(g.distance**p,
                               g.localisation + c**p / alpha * (g.num_missed + g.num_false),
                               rtol=1e-10, atol=1e-12)


def test_gospa_with_alpha_2_assigns_only_pairs_closer_than_c(random_cases):
    _, _, (x, xm, y, ym), _ = random_cases
    c = np.full(len(x), 0.8)
    _, g = jax.device_get(_both(x, xm, y, ym, c, np.full(len(x), 2.0), np.full(len(x), 2.0)))
    for i in range(len(x)):
        assigned = g.assignment[i] >= 0
        assert np.all(xm[i][assigned]) and np.all(ym[i][g.assignment[i][assigned]])
        d = np.linalg.norm(x[i][assigned] - y[i][g.assignment[i][assigned]], axis=-1)
        assert np.all(d < 0.8)
        np.testing.assert_allclose(g.localisation[i], np.sum(d**2), rtol=1e-12, atol=1e-14)
        assert g.num_missed[i] == xm[i].sum() - assigned.sum()
        assert g.num_false[i] == ym[i].sum() - assigned.sum()


def test_hand_computed_cases():
    x = np.array([[0.0, 0.0], [5.0, 0.0]])
    y = np.array([[0.0, 1.0]])
    # One pair at distance 1 and one unpaired point: OSPA (1 + c) / 2, GOSPA 1 + c / 2.
    o = metrics.ospa(x, None, y, None, c=2.0)
    np.testing.assert_allclose([o.distance, o.localisation, o.cardinality], [1.5, 0.5, 1.0])
    g = metrics.gospa(x, None, y, None, c=2.0)
    np.testing.assert_allclose([g.distance, g.localisation], [2.0, 1.0])
    assert (int(g.num_missed), int(g.num_false)) == (1, 0)
    np.testing.assert_array_equal(g.assignment, [0, -1])
    # p = 2: sqrt((1 + 4) / 2) and sqrt(1 + 4 / 2).
    np.testing.assert_allclose(metrics.ospa(x, None, y, None, c=2.0, p=2).distance, np.sqrt(2.5))
    np.testing.assert_allclose(metrics.gospa(x, None, y, None, c=2.0, p=2).distance, np.sqrt(3))
    # Everything beyond the cut-off: OSPA = c; GOSPA alpha = 2 reports misses and false points.
    far = metrics.gospa(x, None, y + 10, None, c=2.0)
    np.testing.assert_allclose([far.distance, far.localisation], [3.0, 0.0])
    assert (int(far.num_missed), int(far.num_false)) == (2, 1)
    np.testing.assert_allclose(metrics.ospa(x, None, y + 10, None, c=2.0).distance, 2.0)
    # Empty sets.
    none = np.zeros(2, bool)
    np.testing.assert_allclose(metrics.ospa(x, none, y, np.zeros(1, bool), c=2.0).distance, 0.0)
    np.testing.assert_allclose(metrics.ospa(x, none, y, None, c=2.0).distance, 2.0)
    np.testing.assert_allclose(metrics.gospa(x, None, y, np.zeros(1, bool), c=2.0).distance, 2.0)
    # The optimal pairing, not the nearest pair first: a0-b1 and a1-b0 cost 1 + 1.5 = 2.5,
    # the greedy a0-b0 (0.5) leaves a1-b1 at 3, 3.5 in all.
    a = np.array([[0.0, 0.0], [2.0, 0.0]])
    b = np.array([[0.5, 0.0], [-1.0, 0.0]])
    np.testing.assert_allclose(metrics.gospa(a, None, b, None, c=10.0).distance, 2.5)
    np.testing.assert_allclose(metrics.ospa(a, None, b, None, c=10.0).distance, 1.25)


def test_float32_matches_float64(random_cases):
    _, _, args, (c, p, alpha) = random_cases
    args = args + [c, p, alpha]
    f32 = [a.astype(np.float32) if a.dtype == np.float64 else a for a in args]
    (o32, g32), (o64, g64) = _both(*f32), _both(*args)
    assert g32.distance.dtype == jnp.float32 and o32.distance.dtype == jnp.float32
    np.testing.assert_allclose(g32.distance, g64.distance, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(o32.distance, o64.distance, rtol=1e-5, atol=1e-6)


def test_gradient_of_gospa_matches_finite_differences():
    x = RNG.uniform(0, 2, (3, 2))
    y = RNG.uniform(0, 2, (4, 2))

    def distance(y):
        return metrics.gospa(x, None, y, None, 1.5, 2.0).distance

    grad = jax.grad(distance)(y)
    eps = 1e-6
    fd = np.zeros_like(y)
    for idx in np.ndindex(y.shape):
        step = np.zeros_like(y)
        step[idx] = eps
        fd[idx] = (distance(y + step) - distance(y - step)) / (2 * eps)
    np.testing.assert_allclose(grad, fd, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("call,match", [
    (lambda: metrics.ospa(np.zeros((3, 2)), None, np.zeros((3, 3)), None, 1.0), "estimates"),
    (lambda: metrics.ospa(np.zeros((3, 2)), np.ones(2, bool), np.zeros((3, 2)), None, 1.0),
     "truth_mask"),
    (lambda: metrics.ospa(np.zeros(3), None, np.zeros((3, 2)), None, 1.0), "truths must be"),
    (lambda: metrics.ospa(np.zeros((3, 2)), None, np.zeros((3, 2)), None, 0.0), "c must be"),
    (lambda: metrics.ospa(np.zeros((3, 2)), None, np.zeros((3, 2)), None, 1.0, p=0.5),
     "p must be"),
    (lambda: metrics.gospa(np.zeros((3, 2)), None, np.zeros((3, 2)), None, 1.0, alpha=3.0),
     "alpha must be"),
])
def test_bad_input_raises_a_clear_value_error(call, match):
    with pytest.raises(ValueError, match=match):
        call()
