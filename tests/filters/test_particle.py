"""Tests for `jaxtrack.filters.particle`: weights, resamplers, the SIR filter and its
differentiable variants.

References: numpy (``np.average``, ``np.cov``), scipy.stats (chi-square, normal and t
distributions, ``circmean``), the exact Kalman filter `jaxtrack.filters.kalman.filter` on a
linear-Gaussian model (2-D constant velocity, position measurements) and importance sampling
computed by hand.

Monte-Carlo checks are hypothesis tests with fixed seeds, so they are deterministic; a check
passes when its two-sided p-value (Bonferroni-corrected over the entries it covers) is above
``P_MIN``. Exact properties (masks, degeneracy, regularisation only after resampling, vmap vs
loop, soft resampling at alpha = 1) are checked to 1e-12 in float64; float32 runs are compared
with float64 ones by a Monte-Carlo t-test.

Compiles dominate the cost (about 60 s of CPU for this file, cold cache), so every filter run
goes through a handful of module-level jitted drivers and one problem shape (T = 25 steps,
N = 2000 particles; the gradient tests use the first 10 steps), single steps go through one
jitted `step` on one particle cloud, and the four resamplers are compiled together.

The per-run bound |PF mean - KF mean| < 4 sqrt(KF var / ESS) does not hold for a resampling
filter (the ESS after an update ignores the Monte-Carlo error carried over from earlier steps;
we measured ratios up to 12), so the means are tested across independent keys instead.
"""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from jaxtrack.filters import kalman, particle
from jaxtrack.models import measurement, motion

P_MIN = 1e-3

# The linear-Gaussian problem: constant velocity with q = exp(2 log_std), position sensor.
DT = 0.1
R_STD = 0.3
T = 25
N = 2000
F_NP, Q_UNIT_NP = (np.asarray(a) for a in motion.constant_velocity(DT, 1.0))
LQ_NP = np.linalg.cholesky(Q_UNIT_NP)
H_NP = np.asarray(measurement.position(4))
R_NP = R_STD**2 * np.eye(2)
M0 = np.array([0.0, 0.0, 1.0, 0.5])
P0 = np.diag([0.02, 0.02, 0.1, 0.1])
T_GRAD = 10
LOG_STD_GRAD = 1.5  # q overestimated e^3 = 20 times: a clearly negative score


def transition(log_std):
    """Per particle: ``x' = F x + exp(log_std) L eps`` (reparameterised), L = chol(Q(q=1))."""

    def f(key, x):
        eps = jax.random.normal(key, x.shape, x.dtype)
        low = jnp.asarray(LQ_NP, x.dtype)
        return jnp.asarray(F_NP, x.dtype) @ x + jnp.exp(log_std) * (low @ eps)

    return f


def transition_batch(log_std):
    """The same transition for all particles [N, 4] at once (``vectorized=True``)."""

    def f(key, x):
        eps = jax.random.normal(key, x.shape, x.dtype)
        low = jnp.asarray(LQ_NP, x.dtype)
        return x @ jnp.asarray(F_NP, x.dtype).T + jnp.exp(log_std) * (eps @ low.T)

    return f


def log_likelihood(z, x):
    """log N(z; x[:2], R_STD^2 I) for one particle."""
    d = (z - x[:2]) / R_STD
    return -0.5 * jnp.sum(d**2) - 2.0 * math.log(R_STD) - math.log(2.0 * math.pi)


def log_likelihood_batch(z, x):
    d = (z - x[:, :2]) / R_STD
    return -0.5 * jnp.sum(d**2, -1) - 2.0 * math.log(R_STD) - math.log(2.0 * math.pi)


def simulate(rng, num_steps=T):
    """Measurements [T, 2] of a path drawn from the model (log_std 0)."""
    x = M0 + np.sqrt(np.diag(P0)) * rng.standard_normal(4)
    zs = []
    for _ in range(num_steps):
        x = F_NP @ x + LQ_NP @ rng.standard_normal(4)
        zs.append(H_NP @ x + R_STD * rng.standard_normal(2))
    return np.array(zs)


def _kf(zs, log_std):
    Q = jnp.exp(2.0 * log_std) * jnp.asarray(Q_UNIT_NP)
    return kalman.filter(kalman.Gaussian(jnp.asarray(M0), jnp.asarray(P0)), zs,
                         jnp.asarray(F_NP), Q, jnp.asarray(H_NP), jnp.asarray(R_NP))


@jax.jit
def kf(zs, log_std):
    """The exact Kalman filter (reference), and the gradient in log_std of the log-likelihood
    of the first T_GRAD measurements (the filter is causal: its first T_GRAD steps are those of
    a run on ``zs[:T_GRAD]``)."""
    grad = jax.grad(lambda ls: jnp.sum(_kf(zs, ls).log_likelihoods[:T_GRAD]))(log_std)
    return _kf(zs, log_std), grad


def gaussian_init(key, num, dtype=jnp.float64):
    return particle.init_from_gaussian(key, jnp.asarray(M0, dtype), jnp.asarray(P0, dtype), num)


@functools.partial(jax.jit, static_argnames=("num", "dtype"))
def batch_inits(keys, num=N, dtype=jnp.float64):
    return jax.vmap(lambda k: gaussian_init(jax.random.fold_in(k, 1), num, dtype))(keys)


def bonferroni_p(t, df=None):
    """Smallest two-sided p-value of the statistics ``t`` (normal, or Student t with ``df``
    degrees of freedom), times their number."""
    t = np.abs(np.ravel(t))
    sf = stats.norm.sf(t) if df is None else stats.t.sf(t, df)
    return min(1.0, 2.0 * float(np.min(sf)) * t.size)


# Schemes are built once: a `Resampling` is a static argument, compared by identity of `apply`.
STOP_GRADIENT = particle.stop_gradient_resampling()
SOFT_HALF = particle.soft_resampling(0.5)
SOFT_ONE = particle.soft_resampling(1.0)
OPTIMAL_TRANSPORT = particle.optimal_transport_resampling()

_TRACES = []  # appended to while `_pf` is traced (a Python side effect: never at run time)


def _pf(key, init, zs, masks, ess_threshold, log_std, resampler="systematic", vectorized=False,
        return_particles=False):
    _TRACES.append(resampler)
    f, g = ((transition_batch(log_std), log_likelihood_batch) if vectorized
            else (transition(log_std), log_likelihood))
    return particle.filter(key, init, zs, f, g, resampler, ess_threshold, masks,
                           vectorized=vectorized, return_particles=return_particles)


_run_pf = jax.jit(functools.partial(_pf, return_particles=True), static_argnames="resampler")


def run_pf(key, init, zs, masks, ess_threshold, resampler="systematic"):
    """One filter run (per-particle functions, log_std 0, particles returned). The threshold is
    passed as a float64 array, so every call with the same shapes reuses one compile."""
    return _run_pf(key, init, zs, masks, jnp.asarray(ess_threshold, jnp.float64), 0.0,
                   resampler)


@jax.jit
def run_pf_batch(keys, inits, zs, masks):
    """`_pf` (systematic, threshold 1, log_std 0) vmapped over keys, initial sets and
    measurement sequences (episodes)."""
    return jax.vmap(lambda k, i, z: _pf(k, i, z, masks, 1.0, 0.0))(keys, inits, zs)


@functools.partial(jax.jit, static_argnames=("num", "resampler"))
def pf_value_and_grad(keys, zs, masks, log_std, num, resampler):
    """Per key: ((log-likelihood estimate, means [T, n]), gradient of the estimate in log_std),
    with the vectorized user functions."""

    def one(key):
        init = gaussian_init(jax.random.fold_in(key, 1), num)

        def loss(ls):
            res = _pf(key, init, zs, masks, 1.0, ls, resampler, True)
            return res.log_likelihood, res.means

        return jax.value_and_grad(loss, has_aux=True)(log_std)

    return jax.vmap(one)(keys)


@functools.partial(jax.jit, static_argnames=("transition", "log_likelihood", "resampler",
                                             "regularise", "regularise_scale"))
def jit_step(key, ps, z, ess_threshold, mask, transition, log_likelihood,
             resampler="systematic", regularise=None, regularise_scale=1.0):
    """`particle.step` with vectorized user functions, jitted."""
    return particle.step(key, ps, z, transition, log_likelihood, resampler, ess_threshold,
                         jnp.asarray(mask), vectorized=True, regularise=regularise,
                         regularise_scale=regularise_scale)


@pytest.fixture(scope="module")
def problem():
    """Measurements [T, 2], an initial set of N particles, the KF at log_std 0 and at
    LOG_STD_GRAD (with its gradient)."""
    zs = simulate(np.random.default_rng(2024))
    kf0, _ = kf(jnp.asarray(zs), 0.0)
    kf_grad_point, kf_grad = kf(jnp.asarray(zs), LOG_STD_GRAD)
    return dict(zs=jnp.asarray(zs), init=gaussian_init(jax.random.PRNGKey(100), N),
                masks=jnp.ones(T, bool), kf=kf0, kf_grad_point=kf_grad_point,
                kf_grad=float(kf_grad))


# ---------------------------------------------------------------------------------------------
# Resamplers

N_W = 20
NUM_KEYS = 2000
RESAMPLER_NAMES = ("multinomial", "systematic", "stratified", "residual")
NUMS = (N_W, 35)
RESAMPLE_KEYS = jax.random.split(jax.random.PRNGKey(7), NUM_KEYS)


@functools.partial(jax.jit, static_argnames="nums")
def _offspring_counts_all(keys, log_weights, nums):
    """For every resampler and ``num`` in ``nums``: (counts [K, N], ancestors [K, num]) per key.

    One jitted function for all of them: compiling the resamplers together costs a third of
    compiling them one by one.
    """
    out = {}
    for name in RESAMPLER_NAMES:
        for num in nums:
            resampler = getattr(particle, name)
            ancestors = jax.vmap(lambda k, r=resampler, m=num: r(k, log_weights, m))(keys)
            counts = jax.vmap(lambda a: jnp.bincount(a, length=log_weights.shape[0]))(ancestors)
            out[name, num] = (counts, ancestors)
    return out


_COUNTS_CACHE = {}


def offspring_counts(log_weights, name, num):
    """Offspring counts [K, N] and ancestors [K, num] (numpy) of resampler ``name``, cached.
    float64 covers ``num`` in NUMS, float32 only ``num = N_W`` (a compile less)."""
    lw = np.asarray(log_weights)
    cache_key = (lw.dtype.str, lw.tobytes())
    if cache_key not in _COUNTS_CACHE:
        nums = NUMS if lw.dtype == np.float64 else (N_W,)
        _COUNTS_CACHE[cache_key] = jax.device_get(_offspring_counts_all(RESAMPLE_KEYS,
                                                                        jnp.asarray(lw), nums))
    return _COUNTS_CACHE[cache_key][name, num]


@pytest.fixture(scope="module")
def random_weights():
    rng = np.random.default_rng(3)
    return rng.dirichlet(np.full(N_W, 2.0))


@pytest.mark.parametrize("num,dtype", [(N_W, np.float64), (35, np.float64), (N_W, np.float32)])
@pytest.mark.parametrize("name", RESAMPLER_NAMES)
def test_resampler_offspring_counts_have_expectation_num_times_weights(name, num, dtype,
                                                                        random_weights):
    w = random_weights
    counts, ancestors = offspring_counts(np.log(w).astype(dtype), name, num)
    counts = np.asarray(counts)
    assert ancestors.shape == (NUM_KEYS, num) and ancestors.dtype == jnp.int32
    assert np.all(counts.sum(1) == num)
    expected = num * w
    mean = counts.mean(0)
    sem = counts.std(0, ddof=1) / math.sqrt(NUM_KEYS)
    # a count with zero spread over 2000 keys must equal its expectation exactly
    diff = mean - expected
    z = np.where(sem > 0, diff / np.where(sem > 0, sem, 1.0), np.where(diff == 0, 0.0, np.inf))
    p = bonferroni_p(z)
    assert p > P_MIN, f"{name}: max |z| = {np.max(np.abs(z)):.2f}, corrected p = {p:.2g}"
    if name == "multinomial":
        # pooled counts over keys are Multinomial(K num, w): chi-square goodness of fit
        chi2 = stats.chisquare(counts.sum(0), NUM_KEYS * expected)
        assert chi2.pvalue > P_MIN, chi2


def test_low_variance_resamplers_beat_multinomial(random_weights):
    w = random_weights
    total_var = {name: float(np.sum(np.var(offspring_counts(np.log(w), name, N_W)[0], 0,
                                           ddof=1))) for name in RESAMPLER_NAMES}
    multinomial_theory = N_W * (1.0 - np.sum(w**2))
    assert abs(total_var["multinomial"] / multinomial_theory - 1.0) < 0.1, total_var
    for name in ("systematic", "stratified", "residual"):
        assert total_var[name] < 0.8 * total_var["multinomial"], total_var


@pytest.mark.parametrize("num", [N_W, 35])
def test_residual_resampling_keeps_the_deterministic_copies(num, random_weights):
    w = random_weights
    floors = np.floor(num * w).astype(int)
    counts, ancestors = offspring_counts(np.log(w), "residual", num)
    assert np.all(np.asarray(counts) >= floors[None, :])
    # documented layout: the first sum(floor) slots are the copies in index order
    head = np.asarray(ancestors)[:, :floors.sum()]
    assert np.all(head == np.repeat(np.arange(N_W), floors)[None, :])


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("name", RESAMPLER_NAMES)
def test_zero_weight_particles_are_never_selected(name, dtype, random_weights):
    dead = [0, 7, N_W - 1]
    lw = np.log(random_weights).astype(dtype)
    lw[dead] = -np.inf
    counts, ancestors = offspring_counts(lw, name, N_W)
    assert np.all(np.asarray(counts)[:, dead] == 0)
    assert np.all((np.asarray(ancestors) >= 0) & (np.asarray(ancestors) < N_W))


def test_systematic_float32_never_selects_a_dead_last_particle_when_u_rounds_to_one():
    """In float32, (U + num - 1) / num rounds to 1 when U is within ~num 2^-25 of 1; the search
    must still stop at the last particle with positive weight. The keys with the largest U
    (assuming the single uniform is drawn as ``uniform(key, ())``) make this deterministic."""
    num = 4096
    keys = jax.random.split(jax.random.PRNGKey(5), 200_000)
    u = np.asarray(jax.vmap(lambda k: jax.random.uniform(k, (), jnp.float32))(keys))
    worst = keys[np.argsort(u)[-8:]]
    lw = jnp.zeros(num, jnp.float32).at[-1].set(-jnp.inf)
    ancestors = np.asarray(jax.jit(jax.vmap(lambda k: particle.systematic(k, lw)))(worst))
    assert np.all(ancestors < num - 1), np.sum(ancestors == num - 1, axis=1)


@functools.partial(jax.jit, static_argnames=("name", "num"))
def _ancestors_and_uniforms(keys, log_weights, name, num):
    """Ancestors [K, num] of resampler ``name`` and its uniforms [K, num] (``U + 0 * j`` for
    `systematic`), assuming they are drawn as ``uniform(key, ())`` / ``uniform(key, (num,))``."""
    resampler = getattr(particle, name)
    dtype = log_weights.dtype
    if name == "systematic":
        uniforms = jax.vmap(lambda k: jnp.full((num,), jax.random.uniform(k, (), dtype)))(keys)
    else:
        uniforms = jax.vmap(lambda k: jax.random.uniform(k, (num,), dtype))(keys)
    return jax.vmap(lambda k: resampler(k, log_weights, num))(keys), uniforms


@pytest.mark.parametrize("num", [60, 35])
@pytest.mark.parametrize("name", ["systematic", "stratified"])
def test_offspring_count_ancestors_equal_a_cdf_search(name, num):
    """`systematic` and `stratified` build ancestors from offspring counts, without a search;
    in float64 they equal numpy's ``searchsorted(cdf, (U_j + j) / num, side="right")``
    exactly, zero-weight particles (a third of them) included."""
    rng = np.random.default_rng(11)
    n = 60
    w = rng.dirichlet(np.full(n, 0.5))
    w[rng.random(n) < 1 / 3] = 0.0
    w[[0, n - 1]] = 0.0  # dead at both ends
    with np.errstate(divide="ignore"):
        lw = np.log(w / w.sum())
    keys = jax.random.split(jax.random.PRNGKey(21), 400)
    ancestors, uniforms = (np.asarray(a) for a in
                           _ancestors_and_uniforms(keys, jnp.asarray(lw), name, num))
    cdf = np.cumsum(np.exp(lw))
    cdf /= cdf[-1]
    points = (uniforms + np.arange(num)) / num
    reference = np.clip(np.searchsorted(cdf, points, side="right"), 0, n - 1)
    np.testing.assert_array_equal(ancestors, reference)
    assert np.all(w[ancestors] > 0)


@pytest.mark.parametrize("name", ["systematic", "stratified"])
def test_half_dead_float32_cloud_never_selects_a_dead_particle(name):
    """1000 particles, half of them (at random) with zero weight, in float32: the pairwise
    CDF is not exactly flat across zero weights, yet no dead particle gets a slot."""
    rng = np.random.default_rng(12)
    n = 1000
    lw = rng.standard_normal(n).astype(np.float32)
    lw[rng.random(n) < 0.5] = -np.inf
    keys = jax.random.split(jax.random.PRNGKey(22), 200)
    ancestors, _ = _ancestors_and_uniforms(keys, jnp.asarray(lw), name, n)
    assert np.all(np.isfinite(lw[np.asarray(ancestors)]))


# ---------------------------------------------------------------------------------------------
# ESS, moments

ess = jax.jit(particle.ess)
normalize = jax.jit(particle.normalize)
weighted_mean = jax.jit(particle.weighted_mean, static_argnames="angle_dims")
weighted_cov = jax.jit(particle.weighted_cov, static_argnames="angle_dims")


def test_ess_matches_numpy_and_is_shift_invariant():
    rng = np.random.default_rng(0)
    lw = 3.0 * rng.standard_normal(50)
    w = np.exp(lw - lw.max())
    w /= w.sum()
    ref = 1.0 / np.sum(w**2)
    assert abs(float(ess(jnp.asarray(lw))) - ref) <= 1e-12 * ref
    assert abs(float(ess(jnp.asarray(lw + 1234.5))) - ref) <= 1e-10 * ref
    assert abs(float(ess(jnp.zeros(50))) - 50.0) <= 1e-12
    assert abs(float(ess(jnp.full(50, -7.0))) - 50.0) <= 1e-12
    # all -inf: `normalize` falls back to uniform
    assert abs(float(ess(jnp.full(50, -jnp.inf))) - 50.0) <= 1e-12
    assert np.allclose(normalize(jnp.full(50, -jnp.inf)), -math.log(50), atol=1e-15)
    # one -inf weight is simply dropped
    lw_dead = lw.copy()
    lw_dead[3] = -np.inf
    w_dead = np.delete(w, 3) / np.delete(w, 3).sum()
    ref_dead = 1.0 / np.sum(w_dead**2)
    assert abs(float(ess(jnp.asarray(lw_dead))) - ref_dead) <= 1e-12 * ref_dead


def test_weighted_mean_and_cov_match_numpy():
    rng = np.random.default_rng(1)
    x = rng.standard_normal((200, 3)) @ rng.standard_normal((3, 3)) + rng.standard_normal(3)
    lw = 2.0 * rng.standard_normal(200) - 40.0  # unnormalised on purpose
    w = np.exp(lw - lw.max())
    ps = particle.ParticleSet(jnp.asarray(x), jnp.asarray(lw))
    mean_ref = np.average(x, axis=0, weights=w)
    cov_ref = np.cov(x.T, aweights=w, bias=True)
    np.testing.assert_allclose(weighted_mean(ps), mean_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(weighted_cov(ps), cov_ref, rtol=0, atol=1e-12)


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def test_circular_mean_and_cov_near_pi():
    """Angles clustered around +-pi: the weighted circular mean equals scipy's circmean of the
    samples repeated by integer weights; the covariance uses wrapped deviations."""
    rng = np.random.default_rng(2)
    n = 300
    multiplicity = rng.integers(1, 6, n)
    angle = _wrap(np.pi + 0.4 * rng.standard_normal(n))
    assert np.any(angle > 2.5) and np.any(angle < -2.5)
    x = np.column_stack([rng.standard_normal(n), angle])
    ps = particle.ParticleSet(jnp.asarray(x), jnp.log(jnp.asarray(multiplicity, float)))
    mean = np.asarray(weighted_mean(ps, angle_dims=(1,)))
    circ = stats.circmean(np.repeat(angle, multiplicity), high=np.pi, low=-np.pi)
    w = multiplicity / multiplicity.sum()
    assert abs(_wrap(mean[1] - circ)) < 1e-12
    assert abs(mean[0] - np.average(x[:, 0], weights=w)) < 1e-12
    # the linear mean of the raw angles is near 0, far from the circular mean
    assert abs(_wrap(np.average(angle, weights=w) - circ)) > 2.0
    dev = np.column_stack([x[:, 0] - mean[0], _wrap(angle - circ)])
    cov_ref = (dev.T * w) @ dev
    cov = np.asarray(weighted_cov(ps, angle_dims=(1,)))
    np.testing.assert_allclose(cov, cov_ref, rtol=0, atol=1e-12)
    assert cov[1, 1] < 0.3  # a wrapped spread of ~0.4 rad, not ~pi


# ---------------------------------------------------------------------------------------------
# Linear-Gaussian model: the particle filter against the Kalman filter

K_KEYS = 16


@pytest.fixture(scope="module")
def pf_runs(problem):
    """K_KEYS independent runs (per-particle functions, systematic) on the same measurements."""
    keys = jax.random.split(jax.random.PRNGKey(31), K_KEYS)
    zs = jnp.broadcast_to(problem["zs"], (K_KEYS, T, 2))
    return run_pf_batch(keys, batch_inits(keys), zs, problem["masks"])


def check_means_against_kf(means, kf_means, kf_covs, label):
    """t-test of the key-averaged PF means [K, T, n] against the KF means (Bonferroni over the
    T n entries), and the Monte-Carlo std of one run below a quarter of the posterior std.
    Returns (max |t|, max MC std / posterior std)."""
    means = np.asarray(means)
    k = means.shape[0]
    post_sd = np.sqrt(np.diagonal(np.asarray(kf_covs), axis1=1, axis2=2))
    mc_sd = means.std(0, ddof=1)
    t = (means.mean(0) - np.asarray(kf_means)) / (mc_sd / math.sqrt(k))
    p = bonferroni_p(t, df=k - 1)
    assert p > P_MIN, f"{label}: max |t| = {np.max(np.abs(t)):.2f}, corrected p = {p:.2g}"
    ratio = np.max(mc_sd / post_sd)
    assert ratio < 0.25, f"{label}: Monte-Carlo std / posterior std = {ratio:.3f}"
    return float(np.max(np.abs(t))), float(ratio)


def test_pf_means_and_covs_agree_with_kalman_filter(pf_runs, problem):
    check_means_against_kf(pf_runs.means, problem["kf"].means, problem["kf"].covs,
                           "per-particle functions")
    # the key-averaged PF variances within 15 % of the KF ones
    assert np.all(np.isfinite(np.asarray(pf_runs.covs)))
    cov_ratio = (np.diagonal(np.asarray(pf_runs.covs).mean(0), axis1=1, axis2=2)
                 / np.diagonal(np.asarray(problem["kf"].covs), axis1=1, axis2=2))
    assert np.all(np.abs(cov_ratio - 1.0) < 0.15), cov_ratio
    assert int(np.max(pf_runs.num_degenerate)) == 0


def test_pf_log_likelihood_agrees_with_kalman_filter(pf_runs, problem):
    """The PF estimate is the log of an unbiased estimate: E[log Z^] ~ log Z - s^2 / 2."""
    ll = np.asarray(pf_runs.log_likelihood)
    exact = float(problem["kf"].log_likelihood)
    s = ll.std(ddof=1)
    assert s < 1.0, f"single-run std {s:.3f}"
    assert abs(ll.mean() - exact) < 3.0 * s, (ll.mean(), exact, s)
    t = (ll.mean() + 0.5 * s**2 - exact) / (s / math.sqrt(K_KEYS))
    assert bonferroni_p(t, df=K_KEYS - 1) > P_MIN, f"bias-corrected t = {t:.2f}"


# ---------------------------------------------------------------------------------------------
# Differentiable resampling; vectorized user functions

GRAD_KEYS = jax.random.split(jax.random.PRNGKey(8), 5)


@pytest.fixture(scope="module")
def stop_gradient_runs(problem):
    """5 runs with N = 5000, stop-gradient resampling and vectorized functions, on the first
    T_GRAD measurements at log_std = LOG_STD_GRAD: ((log-likelihoods, means), gradients)."""
    return pf_value_and_grad(GRAD_KEYS, problem["zs"][:T_GRAD], np.ones(T_GRAD, bool),
                             LOG_STD_GRAD, 5000, STOP_GRADIENT)


def test_stop_gradient_score_matches_kalman_gradient(stop_gradient_runs, problem):
    """With reparameterised transitions, the gradient of the stop-gradient estimate is a
    consistent estimate of the exact score (Fisher's identity)."""
    exact = problem["kf_grad"]
    assert abs(exact) > 1.0
    ratios = np.asarray(stop_gradient_runs[1]) / exact
    assert abs(np.median(ratios) - 1.0) < 0.2, ratios


def test_vectorized_functions_agree_with_kalman_filter(stop_gradient_runs, problem):
    """`vectorized=True` draws its noise differently (one batched draw per step), so it cannot
    match the per-particle run draw for draw: it must match the KF statistically. (The forward
    pass of stop-gradient resampling is systematic resampling.)"""
    (ll, means), _ = stop_gradient_runs
    ref = problem["kf_grad_point"]
    check_means_against_kf(means, ref.means[:T_GRAD], ref.covs[:T_GRAD], "vectorized functions")
    ll = np.asarray(ll)
    exact = float(jnp.sum(ref.log_likelihoods[:T_GRAD]))
    assert abs(ll.mean() - exact) < 3.0 * ll.std(ddof=1), (ll, exact)


@pytest.mark.parametrize("scheme,num", [(SOFT_HALF, 256), (OPTIMAL_TRANSPORT, 64)],
                         ids=["soft", "ot"])
def test_soft_and_ot_resampling_give_finite_gradients(scheme, num, problem):
    (values, _), grads = pf_value_and_grad(GRAD_KEYS[:2], problem["zs"][:T_GRAD],
                                           np.ones(T_GRAD, bool), LOG_STD_GRAD, num, scheme)
    assert np.all(np.isfinite(values)) and np.all(np.isfinite(grads))
    assert np.all(np.asarray(grads) != 0.0)


def test_soft_resampling_with_alpha_one_is_standard_resampling(cloud):
    """Checked on one step (the filter is a scan of it): same key, same resampled and
    propagated particles, same weights and log-likelihood increment as `systematic`."""
    key = jax.random.PRNGKey(12)
    z = jnp.array([0.5, 0.0, -1.0])
    soft, soft_inc = jit_step(key, cloud, z, 1.0, True, shift_by_one, patchy_log_likelihood,
                              SOFT_ONE)
    plain, plain_inc = jit_step(key, cloud, z, 1.0, True, shift_by_one, patchy_log_likelihood)
    assert len(np.unique(np.asarray(plain.particles)[:, 0])) < 0.9 * cloud.particles.shape[0]
    np.testing.assert_array_equal(soft.particles, plain.particles)
    np.testing.assert_allclose(soft.log_weights, plain.log_weights, rtol=0, atol=1e-12)
    np.testing.assert_allclose(soft_inc, plain_inc, rtol=0, atol=1e-12)


def test_resampling_schemes_reject_bad_parameters():
    with pytest.raises(ValueError, match="alpha"):
        particle.soft_resampling(1.5)
    with pytest.raises(ValueError, match="epsilon"):
        particle.optimal_transport_resampling(epsilon=0.0)


# ---------------------------------------------------------------------------------------------
# Adaptive resampling


def test_ess_threshold_is_an_array_and_controls_resampling(problem):
    p = problem
    rng = np.random.default_rng(4)
    lw0 = rng.standard_normal(N)  # non-uniform: threshold 1 also resamples at step 0
    init = particle.ParticleSet(p["init"].particles, jnp.asarray(lw0))
    key = jax.random.PRNGKey(13)
    before = len(_TRACES)
    never = run_pf(key, init, p["zs"], p["masks"], 0.0)
    always = run_pf(key, init, p["zs"], p["masks"], 1.0)
    half = run_pf(key, init, p["zs"], p["masks"], 0.5)
    assert len(_TRACES) - before <= 1  # at most the first call traces (if no test did before)
    assert not np.any(never.resampled)
    assert np.all(always.resampled)
    assert 0 < np.sum(half.resampled) < T, half.resampled

    # without resampling the filter is importance sampling along fixed paths
    xs = np.asarray(never.particles)  # [T, N, 4]
    d = (np.asarray(p["zs"])[:, None, :] - xs[:, :, :2]) / R_STD
    ll = -0.5 * np.sum(d**2, -1) - 2.0 * math.log(R_STD) - math.log(2.0 * math.pi)  # [T, N]
    cum = lw0 - np.log(np.sum(np.exp(lw0))) + np.cumsum(ll, 0)
    log_z = np.log(np.sum(np.exp(cum - cum.max(1, keepdims=True)), 1)) + cum.max(1)
    w_t = np.exp(cum - log_z[:, None])
    np.testing.assert_allclose(np.exp(never.final.log_weights), w_t[-1], rtol=1e-9, atol=1e-300)
    np.testing.assert_allclose(never.log_likelihood, log_z[-1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(never.log_likelihoods, np.diff(log_z, prepend=0.0), rtol=0,
                               atol=1e-9)
    np.testing.assert_allclose(never.ess, 1.0 / np.sum(w_t**2, 1), rtol=1e-9)
    np.testing.assert_allclose(never.means, np.einsum("tn,tnd->td", w_t, xs), rtol=0,
                               atol=1e-9)


# ---------------------------------------------------------------------------------------------
# Masks, NaN and degenerate steps


def shift_by_one(key, x):
    del key
    return x + 1.0


_NON_FINITE = (jnp.nan, -jnp.inf, jnp.inf)


def patchy_log_likelihood(z, x):
    """Gaussian in ``z[:2]`` where ``x[0] <= 0``, the value ``z[2]`` elsewhere. A non-finite
    measurement is masked by the filter, so a finite code selects a non-finite value:
    ``z[2] = 1000 + c`` gives NaN, -inf or +inf (c = 0, 1, 2) where ``x[0] > 0``, and
    ``2000 + c`` the same for every particle."""
    code = z[2]
    bad = jnp.asarray(_NON_FINITE)[jnp.clip(jnp.round(code) % 1000, 0, 2).astype(int)]
    value = jnp.where(code >= 1000, bad, code)
    region = (code >= 2000) | (x[:, 0] > 0)
    return jnp.where(region, value, log_likelihood_batch(z[:2], x))


@pytest.fixture(scope="module")
def cloud():
    """4000 weighted particles in 4-D (enough for the jitter statistics of regularisation)."""
    rng = np.random.default_rng(8)
    n = 4000
    x = rng.standard_normal((n, 4)) @ rng.standard_normal((4, 4)) + rng.standard_normal(4)
    return particle.ParticleSet(jnp.asarray(x), jnp.asarray(rng.standard_normal(n)))


def test_masked_step_only_propagates(cloud):
    ps = cloud
    key = jax.random.PRNGKey(0)
    new, inc = jit_step(key, ps, jnp.array([jnp.nan, 0.0, jnp.nan]), 1.0, False, shift_by_one,
                        patchy_log_likelihood)
    assert float(inc) == 0.0
    np.testing.assert_array_equal(new.particles, ps.particles + 1.0)
    np.testing.assert_array_equal(new.log_weights, particle.normalize(ps.log_weights))
    # the same step with a measurement resamples (ESS < N) and reweights
    new, inc = jit_step(key, ps, jnp.array([0.5, 0.0, -1.0]), 1.0, True, shift_by_one,
                        patchy_log_likelihood)
    assert np.isfinite(float(inc)) and float(inc) != 0.0
    assert not np.allclose(new.particles, ps.particles + 1.0)


def test_nan_and_plus_inf_log_likelihoods_count_as_minus_inf(cloud):
    ps = particle.ParticleSet(cloud.particles, jnp.zeros(cloud.log_weights.shape))
    n_p = ps.log_weights.shape[0]
    key = jax.random.PRNGKey(1)
    a = jit_step(key, ps, jnp.array([0.3, -0.2, 1000.0]), 1.0, True, shift_by_one,
                 patchy_log_likelihood)
    b = jit_step(key, ps, jnp.array([0.3, -0.2, 1001.0]), 1.0, True, shift_by_one,
                 patchy_log_likelihood)
    plus = jit_step(key, ps, jnp.array([0.3, -0.2, 1002.0]), 1.0, True, shift_by_one,
                    patchy_log_likelihood)
    for other in (b, plus):
        np.testing.assert_array_equal(a[0].log_weights, other[0].log_weights)
        np.testing.assert_array_equal(a[1], other[1])
    dead = np.asarray(a[0].particles)[:, 0] > 0
    assert 0 < dead.sum() < n_p
    assert np.all(np.isneginf(np.asarray(a[0].log_weights)[dead]))
    assert np.all(np.isfinite(np.asarray(a[0].log_weights)[~dead])) and np.isfinite(float(a[1]))
    # NaN for every particle: a degenerate step, weights reset to uniform
    c = jit_step(key, ps, jnp.array([0.0, 0.0, 2000.0]), 1.0, True, shift_by_one,
                 patchy_log_likelihood)
    assert np.isneginf(float(c[1]))
    np.testing.assert_allclose(c[0].log_weights, -math.log(n_p), rtol=0, atol=1e-15)


def test_nan_measurement_at_masked_step_is_harmless(problem):
    p = problem
    masks = p["masks"].at[3].set(False)
    key = jax.random.PRNGKey(14)
    with_nan = run_pf(key, p["init"], p["zs"].at[3].set(jnp.nan), masks, 1.0)
    placeholder = run_pf(key, p["init"], p["zs"].at[3].set(0.0), masks, 1.0)
    for a, b in [(with_nan.means, placeholder.means), (with_nan.covs, placeholder.covs),
                 (with_nan.log_likelihoods, placeholder.log_likelihoods)]:
        assert np.all(np.isfinite(np.asarray(a)))
        np.testing.assert_array_equal(a, b)
    assert float(with_nan.log_likelihoods[3]) == 0.0
    assert not bool(with_nan.resampled[3])
    assert int(with_nan.num_degenerate) == 0

    # NaN padding must not break tuning either: the gradient ignores it
    zs = p["zs"][:T_GRAD]
    masks = np.ones(T_GRAD, bool)
    masks[5] = False
    (value, _), grad = pf_value_and_grad(GRAD_KEYS[:2], zs.at[5].set(jnp.nan), masks,
                                         LOG_STD_GRAD, 256, SOFT_HALF)
    (value_ref, _), grad_ref = pf_value_and_grad(GRAD_KEYS[:2], zs.at[5].set(0.0), masks,
                                                 LOG_STD_GRAD, 256, SOFT_HALF)
    assert np.all(np.isfinite(np.asarray(grad))), grad
    np.testing.assert_array_equal(value, value_ref)
    np.testing.assert_allclose(grad, grad_ref, rtol=1e-12, atol=0)
    # ... and neither does an unmasked NaN reading: it is masked, so a batch-mean tuning loss
    # over episodes keeps a finite gradient.
    (value_bad, _), grad_bad = pf_value_and_grad(GRAD_KEYS[:2], zs.at[5, 1].set(jnp.nan),
                                                 np.ones(T_GRAD, bool), LOG_STD_GRAD, 256,
                                                 SOFT_HALF)
    np.testing.assert_array_equal(value_bad, value_ref)
    np.testing.assert_allclose(grad_bad, grad_ref, rtol=1e-12, atol=0)
    assert np.isfinite(float(jnp.mean(grad_bad)))


@pytest.mark.parametrize("bad", [np.inf, np.nan], ids=["inf", "nan"])
def test_non_finite_measurement_is_masked_and_counted(bad, problem):
    """An unmasked NaN or inf measurement is treated as missing, as the Kalman filters treat it:
    the same run as with that step masked, and counted."""
    p = problem
    zs = p["zs"].at[4, 0].set(bad)
    res = run_pf(jax.random.PRNGKey(15), p["init"], zs, p["masks"], 1.0)
    ref = run_pf(jax.random.PRNGKey(15), p["init"], zs, p["masks"].at[4].set(False), 1.0)
    assert int(res.num_invalid) == 1 and int(ref.num_invalid) == 0
    assert int(res.num_degenerate) == 0 and float(res.log_likelihoods[4]) == 0.0
    np.testing.assert_array_equal(res.means, ref.means)
    np.testing.assert_array_equal(res.log_likelihood, ref.log_likelihood)
    assert np.isfinite(float(res.log_likelihood))


def test_zero_weight_nan_particle_leaves_the_moments_finite():
    x = jnp.array([[0.0, 1.0], [2.0, 3.0], [jnp.nan, jnp.nan]])
    ps = particle.ParticleSet(x, jnp.array([0.0, 0.0, -jnp.inf]))
    np.testing.assert_allclose(particle.weighted_mean(ps), [1.0, 2.0])
    np.testing.assert_allclose(particle.weighted_cov(ps), [[1.0, 1.0], [1.0, 1.0]])


# ---------------------------------------------------------------------------------------------
# Batching and float32


def test_vmap_over_episodes_equals_loop(problem):
    rng = np.random.default_rng(7)
    zs = jnp.asarray(np.stack([simulate(rng) for _ in range(K_KEYS)]))
    keys = jax.random.split(jax.random.PRNGKey(16), K_KEYS)
    inits = batch_inits(keys)
    batched = run_pf_batch(keys, inits, zs, problem["masks"])
    for b in (0, 7, K_KEYS - 1):
        init = jax.tree_util.tree_map(lambda a: a[b], inits)
        single = run_pf(keys[b], init, zs[b], problem["masks"], 1.0)
        np.testing.assert_allclose(batched.means[b], single.means, rtol=0, atol=1e-12)
        np.testing.assert_allclose(batched.covs[b], single.covs, rtol=0, atol=1e-12)
        np.testing.assert_allclose(batched.log_likelihood[b], single.log_likelihood, rtol=0,
                                   atol=1e-10)
        np.testing.assert_array_equal(batched.resampled[b], single.resampled)


@jax.jit
def _with_and_without_covs(key, init, zs, masks):
    def run(return_covs):
        return particle.filter(key, init, zs, transition_batch(0.0), log_likelihood_batch,
                               masks=masks, vectorized=True, return_covs=return_covs)

    return run(True), run(False)


def test_filter_without_covs_returns_the_same_estimates(problem):
    """``return_covs=False`` drops the covariances and nothing else: same key, same means, ESS,
    log-likelihood increments and final set, to the last bit."""
    p = problem
    init = jax.tree_util.tree_map(lambda a: a[:300], p["init"])
    masks = p["masks"].at[3].set(False)
    full, lean = _with_and_without_covs(jax.random.PRNGKey(19), init, p["zs"], masks)
    assert lean.covs is None and full.covs.shape == (T, 4, 4)
    for name in ("means", "ess", "log_likelihoods", "resampled", "num_degenerate"):
        np.testing.assert_array_equal(getattr(lean, name), getattr(full, name), err_msg=name)
    np.testing.assert_array_equal(lean.final.particles, full.final.particles)
    np.testing.assert_array_equal(lean.final.log_weights, full.final.log_weights)


def test_float32_run_agrees_with_float64(pf_runs, problem):
    """8 float32 runs against the 16 float64 runs on the same measurements: the key-averaged
    means and log-likelihoods differ by no more than their Monte-Carlo error (Welch t-test)."""
    p = problem
    keys = jax.random.split(jax.random.PRNGKey(17), 8)
    inits = batch_inits(keys, N, jnp.float32)
    runs = [run_pf(keys[b], jax.tree_util.tree_map(lambda a: a[b], inits),
                   p["zs"].astype(jnp.float32), p["masks"], 1.0) for b in range(len(keys))]
    for res in runs:
        assert res.means.dtype == jnp.float32 and res.final.log_weights.dtype == jnp.float32
        assert np.all(np.isfinite(np.asarray(res.means)))
        assert np.all(np.isfinite(np.asarray(res.covs)))
    m32 = np.stack([np.asarray(r.means, np.float64) for r in runs])
    ll32 = np.array([float(r.log_likelihood) for r in runs])
    m64, ll64 = np.asarray(pf_runs.means), np.asarray(pf_runs.log_likelihood)
    se = np.sqrt(m32.var(0, ddof=1) / len(m32) + m64.var(0, ddof=1) / len(m64))
    assert bonferroni_p((m32.mean(0) - m64.mean(0)) / se, df=len(m32) - 1) > P_MIN
    se_ll = math.sqrt(ll32.var(ddof=1) / len(ll32) + ll64.var(ddof=1) / len(ll64))
    assert bonferroni_p((ll32.mean() - ll64.mean()) / se_ll, df=len(ll32) - 1) > P_MIN


# ---------------------------------------------------------------------------------------------
# Regularisation and argument checks


@pytest.mark.parametrize("kind", ["roughening", "kernel"])
def test_regularisation_jitters_only_after_resampling(kind, cloud):
    ps = cloud
    n_p, n = ps.particles.shape
    key = jax.random.PRNGKey(18)
    scale = 2.0

    def run(threshold, regularise):
        return jit_step(key, ps, jnp.zeros(3), threshold, True, shift_by_one,
                        patchy_log_likelihood, regularise=regularise,
                        regularise_scale=scale)[0]

    kept = run(0.0, kind)
    assert kept.particles.shape == ps.particles.shape
    np.testing.assert_array_equal(kept.particles, ps.particles + 1.0)
    resampled, jittered = run(1.0, None), run(1.0, kind)
    assert jittered.particles.shape == ps.particles.shape
    # same key, same ancestors: the difference is the jitter alone (ranges and covariances
    # ignore the shift by one of the propagation)
    res_x = np.asarray(resampled.particles)
    assert len(np.unique(res_x[:, 0])) < 0.9 * n_p  # duplicates: resampling happened
    jitter = np.asarray(jittered.particles) - res_x
    assert np.all(np.abs(jitter) > 0)
    if kind == "roughening":
        expected_sd = scale * (res_x.max(0) - res_x.min(0)) * n_p ** (-1.0 / n)
        np.testing.assert_allclose(jitter.std(0), expected_sd, rtol=0.1)
    else:
        h = (4.0 / (n_p * (n + 2))) ** (1.0 / (n + 4))
        expected = (scale * h) ** 2 * np.cov(res_x.T, bias=True)
        err = np.max(np.abs(np.cov(jitter.T) - expected)) / np.max(np.abs(expected))
        assert err < 0.1, err


def test_bad_arguments_raise(problem):
    p = problem
    ps = p["init"]
    key = jax.random.PRNGKey(0)
    f, g = transition(0.0), log_likelihood
    with pytest.raises(ValueError, match="regularise"):
        particle.step(key, ps, p["zs"][0], f, g, regularise="jitter")
    with pytest.raises(ValueError, match="regularise"):
        particle.filter(key, ps, p["zs"], f, g, regularise="jitter")
    with pytest.raises(ValueError, match="unknown resampler"):
        particle.step(key, ps, p["zs"][0], f, g, resampler="sytematic")
    with pytest.raises(ValueError, match="unknown resampler"):
        particle.filter(key, ps, p["zs"], f, g, resampler="bootstrap")
    with pytest.raises(TypeError, match="resampler"):
        particle.step(key, ps, p["zs"][0], f, g, resampler=3)
    with pytest.raises(ValueError, match="particles"):
        particle.step(key, particle.ParticleSet(ps.particles[:, 0], ps.log_weights),
                      p["zs"][0], f, g)
    with pytest.raises(ValueError, match="log_weights"):
        particle.step(key, particle.ParticleSet(ps.particles, ps.log_weights[:-1]),
                      p["zs"][0], f, g)
    with pytest.raises(ValueError, match="log_weights"):
        particle.filter(key, particle.ParticleSet(ps.particles, ps.log_weights[:, None]),
                        p["zs"], f, g)
    with pytest.raises(TypeError, match="ParticleSet"):
        particle.step(key, (ps.particles, ps.log_weights), p["zs"][0], f, g)
    with pytest.raises(ValueError, match="masks"):
        particle.filter(key, ps, p["zs"], f, g, masks=jnp.ones(T + 1, bool))
    with pytest.raises(ValueError, match="leading time axis"):
        particle.filter(key, ps, (p["zs"], p["zs"][:-1]), f, g)


@pytest.mark.parametrize("num", [0, -3, 2.5, True])
def test_init_from_gaussian_needs_a_positive_number_of_particles(num):
    with pytest.raises(ValueError, match="num"):
        particle.init_from_gaussian(jax.random.PRNGKey(0), jnp.zeros(2), jnp.eye(2), num)
