"""Bootstrap particle filters side by side: jaxtrack vs cuthbert, particles, numpy + filterpy,
Stone Soup (and a minimal hand-written JAX filter as a floor).

Problem: 4-state constant velocity ([p_x, p_y, v_x, v_y], ``motion.constant_velocity(0.1,
0.5)``), 2-D position measurements with a Gaussian likelihood (R: std 0.2 / 0.15 m,
correlation 0.3, shared by all episodes), 1000 particles, T = 200 steps, N = 1 and N = 100
episodes (each with its own trajectory, measurements and initial particles drawn from
N(m0, P0) with its own m0). Every library starts from the same initial particles, propagates
with the same F, Q, weighs with the same Gaussian log-likelihood (normalising constant
included) and resamples systematically at every step.

How each library runs:
- jaxtrack: ``particle.filter(key, init, zs, transition, log_likelihood, resampler="systematic",
  ess_threshold=1.0, vectorized=True)`` with vectorized user functions (one batched normal draw
  per step for all particles), float32. N = 1 is ``jit(filter)``, N > 1 ``jit(vmap(filter))``.
  Its result: weighted means and covariances, ESS, log-likelihood increments at every step.
- jaxtrack (no covs): the same call with ``return_covs=False`` (means, ESS and log-likelihood
  increments at every step; the covariances are not computed).
- jax (hand-written): a minimal bootstrap filter in a ``lax.scan`` (always resample with
  ``searchsorted(method="scan")``, one normal draw, log-likelihood, logsumexp, weighted mean):
  the textbook filter without jaxtrack's adaptive-resampling selects, degenerate-step guards
  and covariance output (jaxtrack's search-free resampler makes it the faster of the two).
  float32, jit / jit(vmap).
- cuthbert: ``cuthbert.smc.particle_filter.build_filter`` (per-particle ``propagate_sample`` and
  ``log_potential``, vmapped by cuthbert, one key per particle per step) with
  ``cuthbertlib.resampling.systematic.resampling`` (resamples at every step), run by
  ``cuthbert.filter``, which returns every step's particles, weights and ancestors. float32,
  jit / jit(vmap). On CPU, cuthbertlib's ``inverse_cdf`` is a host callback
  (``jax.pure_callback`` into a numba search, ``vmap_method="sequential"``: one callback per
  episode per step under vmap).
- cuthbert*: the same filter given, as its ``resampling_fn``, cuthbertlib's systematic
  resampling rewritten with ``jnp.searchsorted(method="scan")`` instead of the callback: not the
  library's resampler as shipped; the row shows what the callback costs.
- particles (Chopin): ``particles.SMC(fk=Bootstrap(ssm, data), N=1000,
  resampling="systematic", ESSrmin=1, collect=[Moments(mom_func=wmean_and_cov)])`` with
  ``MvNormal`` dynamics and likelihood, numpy float64, one run per episode.
- numpy + filterpy: a numpy float64 loop per episode (propagate, log-likelihood, logsumexp,
  weighted mean and covariance) resampling with ``filterpy.monte_carlo.systematic_resample``.
- Stone Soup: ``ParticlePredictor`` (``ConstantVelocity`` x 2) + ``ParticleUpdater``
  (``LinearGaussian``, ``SystematicResampler``: resamples after every update), numpy float64,
  N = 1 only. The state order is [x, v_x, y, v_y] (permuted in and out).

The Python libraries run one episode at a time; at N > 1 only ``--python-episodes`` episodes
are timed and the time is per episode-step (notes column).

PRNG: every JAX library draws from ``jax.random.key(seed, impl=--prng)``, threefry2x32 (JAX's
default) unless ``--prng rbg`` or ``--prng unsafe_rbg`` is given; the key type flows into the
user's transition, so all JAX rows of one run use the same generator. On XLA:CPU the
``rbg`` generators are slower than threefry for normal draws (see the README).
``--threefry-partitionable off`` sets ``jax_threefry_partitionable`` to False for the whole run
(every JAX library): threefry2x32 with the bit layout JAX used before 0.5, whose draws are not
invariant to sharding but are about 3x cheaper on XLA:CPU.

Timing, single core, table: as in ``filters.py`` (see ``_common.time_interleaved``): warm-up
call (its extra time = "first call s", tracing + compilation), then the median over clean
interleaved repeats of the wall time per call, blocking on the outputs. Unit: microseconds per
episode-step = call time / (episodes x steps). "vs jaxtrack" = peer / jaxtrack (> 1: jaxtrack
faster). The process pins itself to one CPU before jax is imported (``--no-pin`` to disable).

Agreement: the log-likelihood estimate is random, so every library runs several times on
episode 0 (JAX libraries 5 x ``--check-runs`` seeds, vmapped; particles and numpy + filterpy
``--check-runs``; Stone Soup half of it). Run r of every library starts from the same fresh
draw of initial particles from N(m0, P0), so each estimate targets the likelihood under the
Gaussian prior of the exact Kalman filter (``jaxtrack.filters.kalman.filter``, float64)
printed as the reference. Columns: mean, sd and standard error of the estimates; mean - KF
(a particle filter's estimate of log p(z) is biased low: E[Z_hat] = Z, so by Jensen
E[log Z_hat] < log Z, by about sd^2 / 2 when log Z_hat is close to normal); mean + sd^2/2 -
KF (that bias removed); z vs jaxtrack = (mean - jaxtrack's mean) / standard error of the
difference; and the RMS over steps of the distance between the filtered position mean and the
KF's, averaged over runs (a check that every library filters the same model).

Usage:
    python benchmarks/particle.py             # full run (a few minutes)
    python benchmarks/particle.py --quick     # smoke test
    python benchmarks/particle.py --episodes 100 --steps 200 --repeats 7
"""

from __future__ import annotations

import _common

THREAD_ENV = _common.single_core_from_argv()

import datetime  # noqa: E402
import math  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.scipy.special import logsumexp  # noqa: E402

from jaxtrack.filters import kalman, particle  # noqa: E402
from jaxtrack.models import measurement, motion  # noqa: E402

PACKAGES = ["jaxtrack", "jax", "jaxlib", "numpy", "scipy", "cuthbert", "particles", "filterpy",
            "stonesoup", "numba"]

DT = 0.1
CV_Q = 0.5
R_STD = (0.2, 0.15)
R_RHO = 0.3
LOG_2PI = math.log(2.0 * math.pi)


# ---------------------------------------------------------------------------------------------
# Problem (numpy float64)


def make_problem(episodes, steps, particles, seed=0):
    """Shared model arrays and per-episode data: init particles x0 [E, P, 4], measurements
    zs [E, T, 2], initial mean m0 [E, 4] (the KF reference starts from N(m0, P0))."""
    rng = np.random.default_rng(seed)
    with jax.enable_x64(True):
        F, Q = (np.asarray(a, np.float64) for a in motion.constant_velocity(DT, CV_Q))
        H = np.asarray(measurement.position(4, dtype=jnp.float64), np.float64)
    sx, sy = R_STD
    R = np.array([[sx * sx, R_RHO * sx * sy], [R_RHO * sx * sy, sy * sy]])
    m_prior = np.array([0.0, 0.0, 1.0, 0.5])
    P0 = np.diag([1.0, 1.0, 0.25, 0.25])
    LP0, LQ, LR = (np.linalg.cholesky(a) for a in (P0, Q, R))
    x = m_prior + rng.standard_normal((episodes, 4)) @ LP0.T
    m0 = x + rng.standard_normal((episodes, 4)) @ LP0.T * 0.5
    zs = np.empty((episodes, steps, 2))
    for t in range(steps):
        x = x @ F.T + rng.standard_normal((episodes, 4)) @ LQ.T
        zs[:, t] = x @ H.T + rng.standard_normal((episodes, 2)) @ LR.T
    x0 = m0[:, None, :] + rng.standard_normal((episodes, particles, 4)) @ LP0.T
    return dict(F=F, Q=Q, H=H, R=R, P0=P0, LQ=LQ, LR=LR, m0=m0, x0=x0, zs=zs)


def gaussian_loglik_fn(R, dtype):
    """Vectorized log N(z; x[:, :2], R) for particles x [P, 4] (jnp)."""
    LR = np.linalg.cholesky(R)
    LR_inv = jnp.asarray(np.linalg.inv(LR), dtype)
    const = float(-np.sum(np.log(np.diag(LR))) - LOG_2PI)

    def loglik(z, x):
        r = (z - x[..., :2]) @ LR_inv.T
        return -0.5 * jnp.sum(r * r, -1) + const

    return loglik


# ---------------------------------------------------------------------------------------------
# JAX implementations. Each factory returns ``run(key, x0 [P, 4], zs [T, 2])`` for one episode
# (jit / jit(vmap) by the caller) and ``loglik(out)`` extracting the log-likelihood estimate.


def jaxtrack_pf(p, dtype=jnp.float32, return_covs=True):
    F, LQ = jnp.asarray(p["F"], dtype), jnp.asarray(p["LQ"], dtype)
    loglik_fn = gaussian_loglik_fn(p["R"], dtype)

    def transition(key, x):
        return x @ F.T + jax.random.normal(key, x.shape, x.dtype) @ LQ.T

    def run(key, x0, zs):
        n = x0.shape[0]
        init = particle.ParticleSet(x0, jnp.full((n,), -math.log(n), x0.dtype))
        return particle.filter(key, init, zs, transition, loglik_fn, resampler="systematic",
                               ess_threshold=1.0, vectorized=True, return_covs=return_covs)

    return run, lambda out: out.log_likelihood


def jaxtrack_no_covs_pf(p, dtype=jnp.float32):
    return jaxtrack_pf(p, dtype, return_covs=False)


def handwritten_pf(p, dtype=jnp.float32):
    """Minimal bootstrap PF: always resample (systematic), propagate, weigh, weighted mean."""
    F, LQ = jnp.asarray(p["F"], dtype), jnp.asarray(p["LQ"], dtype)
    loglik_fn = gaussian_loglik_fn(p["R"], dtype)

    def run(key, x0, zs):
        n = x0.shape[0]
        grid = jnp.arange(n, dtype=x0.dtype)

        def body(carry, inp):
            x, lw = carry
            k, z = inp
            k_res, k_prop = jax.random.split(k)
            cdf = jnp.cumsum(jnp.exp(lw))
            u = (jax.random.uniform(k_res, (), x.dtype) + grid) * (cdf[-1] / n)
            a = jnp.clip(jnp.searchsorted(cdf, u, method="scan"), 0, n - 1)
            x = x[a] @ F.T + jax.random.normal(k_prop, x.shape, x.dtype) @ LQ.T
            ll = loglik_fn(z, x)
            total = logsumexp(ll)
            lw = ll - total
            return (x, lw), (jnp.exp(lw) @ x, total - math.log(n))

        lw0 = jnp.full((n,), -math.log(n), x0.dtype)
        _, (means, incs) = jax.lax.scan(body, (x0, lw0), (jax.random.split(key, zs.shape[0]), zs))
        return means, incs, jnp.sum(incs)

    return run, lambda out: out[2]


def cuthbert_pf(p, dtype=jnp.float32, resampling_fn=None):
    import cuthbert
    from cuthbert.smc import particle_filter as cb_pf
    from cuthbertlib.resampling import systematic as cb_systematic

    F, LQ = jnp.asarray(p["F"], dtype), jnp.asarray(p["LQ"], dtype)
    loglik_fn = gaussian_loglik_fn(p["R"], dtype)
    n_particles = p["x0"].shape[-2]

    def init_sample(key):  # only used for its shape (the initial state is built below)
        return jax.random.normal(key, (4,), dtype)

    def propagate_sample(key, x, z):
        return F @ x + LQ @ jax.random.normal(key, (4,), x.dtype)

    def log_potential(x_prev, x, z):
        return loglik_fn(z, x)

    filt = cb_pf.build_filter(init_sample, propagate_sample, log_potential, n_particles,
                              resampling_fn or cb_systematic.resampling)

    def run(key, x0, zs):
        k_init, k_run = jax.random.split(key)
        n = x0.shape[0]
        init = cb_pf.ParticleFilterState(k_init, x0, jnp.zeros((n,), x0.dtype),
                                         jnp.arange(n), None, jnp.zeros((), x0.dtype))
        return cuthbert.filter(filt, zs, init, parallel=False, key=k_run)

    return run, lambda out: out.log_normalizing_constant[..., -1]


def systematic_no_callback(key, logits, positions, n):
    """cuthbertlib's systematic resampling (same uniforms, same inverse CDF) with the search
    done by ``jnp.searchsorted(method="scan")`` instead of its CPU host callback; passed to
    cuthbert's ``build_filter`` as ``resampling_fn`` for the cuthbert* row."""
    us = (jax.random.uniform(key, ()) + jnp.arange(n)) / n
    logits = jnp.asarray(logits)
    cs = jnp.cumsum(jnp.exp(logits - logsumexp(logits)))
    idx = jnp.clip(jnp.searchsorted(cs, us, method="scan"), 0, logits.shape[0] - 1)
    return idx, jnp.zeros_like(us), jax.tree_util.tree_map(lambda x: x[idx], positions)


def cuthbert_no_callback_pf(p, dtype=jnp.float32):
    return cuthbert_pf(p, dtype, resampling_fn=systematic_no_callback)


# ---------------------------------------------------------------------------------------------
# numpy libraries: ``run(p, episodes, steps, seed)`` -> per-episode results (list)


def particles_pf(p, episodes, steps, seed=None):
    import particles
    from particles import collectors
    from particles import distributions as dists
    from particles import resampling as rs
    from particles import state_space_models as ssm

    F, Q, R = p["F"], p["Q"], p["R"]

    class ConstantVelocity(ssm.StateSpaceModel):
        def PX0(self):  # unused: M0 below starts from the given particles
            return dists.MvNormal(loc=np.zeros(4), cov=p["P0"])

        def PX(self, t, xp):
            return dists.MvNormal(loc=xp @ F.T, cov=Q)

        def PY(self, t, xp, x):
            return dists.MvNormal(loc=x[:, :2], cov=R)

    class BootstrapFromParticles(ssm.Bootstrap):
        """Bootstrap FK model whose X_0 is the given particles propagated once (time 0 of
        `particles` is the first measurement)."""

        def __init__(self, ssm_, data, x0):
            super().__init__(ssm=ssm_, data=data)
            self.x0 = x0

        def M0(self, N):
            return self.ssm.PX(0, self.x0).rvs(size=N)

    if seed is not None:
        np.random.seed(seed)  # particles draws from numpy's global generator
    model = ConstantVelocity()
    out = []
    for e in range(episodes):
        fk = BootstrapFromParticles(model, p["zs"][e, :steps], p["x0"][e])
        pf = particles.SMC(fk=fk, N=p["x0"].shape[1], resampling="systematic", ESSrmin=1.0,
                           collect=[collectors.Moments(mom_func=rs.wmean_and_cov)])
        pf.run()
        out.append(pf)
    return out


def filterpy_pf(p, episodes, steps, seed=None):
    """numpy bootstrap PF resampling with filterpy.monte_carlo.systematic_resample."""
    from filterpy.monte_carlo import systematic_resample

    if seed is not None:
        np.random.seed(seed)  # systematic_resample draws from numpy's global generator
    rng = np.random.default_rng(seed)
    F, LQ, LR = p["F"], p["LQ"], p["LR"]
    LR_inv = np.linalg.inv(LR)
    const = -np.sum(np.log(np.diag(LR))) - LOG_2PI
    out = []
    for e in range(episodes):
        x = p["x0"][e].copy()
        n = x.shape[0]
        w = np.full(n, 1.0 / n)
        means, covs, loglik = np.empty((steps, 4)), np.empty((steps, 4, 4)), 0.0
        for t in range(steps):
            x = x[systematic_resample(w)]
            x = x @ F.T + rng.standard_normal(x.shape) @ LQ.T
            r = (p["zs"][e, t] - x[:, :2]) @ LR_inv.T
            ll = -0.5 * np.einsum("ij,ij->i", r, r) + const
            top = ll.max()
            w = np.exp(ll - top)
            total = w.sum()
            loglik += top + np.log(total) - np.log(n)
            w /= total
            means[t] = w @ x
            dev = x - means[t]
            covs[t] = (dev.T * w) @ dev
        out.append((means, covs, loglik))
    return out


def stonesoup_pf(p, steps, seed=None, with_loglik=False):
    """Episode 0. With ``with_loglik`` the log-likelihood increment is recomputed from the
    prediction (an extra logpdf per step: only for the agreement check, not timed)."""
    from scipy.special import logsumexp as np_logsumexp
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import (CombinedLinearGaussianTransitionModel,
                                                    ConstantVelocity)
    from stonesoup.predictor.particle import ParticlePredictor
    from stonesoup.resampler.particle import SystematicResampler
    from stonesoup.types.array import StateVectors
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.state import ParticleState
    from stonesoup.updater.particle import ParticleUpdater

    if seed is not None:
        np.random.seed(seed)  # Stone Soup draws from numpy's global generator
    perm = [0, 2, 1, 3]
    transition = CombinedLinearGaussianTransitionModel([ConstantVelocity(CV_Q),
                                                        ConstantVelocity(CV_Q)])
    sensor = LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=p["R"])
    predictor = ParticlePredictor(transition)
    updater = ParticleUpdater(sensor, resampler=SystematicResampler())
    start = datetime.datetime(2025, 1, 1)
    n = p["x0"].shape[1]
    state = ParticleState(StateVectors(p["x0"][0][:, perm].T), log_weight=np.full(n, -np.log(n)),
                          timestamp=start)
    means, loglik = np.empty((steps, 4)), 0.0
    for t in range(steps):
        time = start + datetime.timedelta(seconds=DT * (t + 1))
        prediction = predictor.predict(state, timestamp=time)
        detection = Detection(p["zs"][0, t].reshape(2, 1), timestamp=time,
                              measurement_model=sensor)
        if with_loglik:
            loglik += np_logsumexp(prediction.log_weight + sensor.logpdf(detection, prediction))
        state = updater.update(SingleHypothesis(prediction, detection))
        means[t] = np.asarray(state.mean, np.float64)[perm, 0]
    return means, loglik


# ---------------------------------------------------------------------------------------------
# Runner


JAX_IMPLS = [("jaxtrack", jaxtrack_pf), ("jaxtrack (no covs)", jaxtrack_no_covs_pf),
             ("jax (hand-written)", handwritten_pf),
             ("cuthbert", cuthbert_pf), ("cuthbert*", cuthbert_no_callback_pf)]


def user_functions_only(p, dtype=jnp.float32):
    """Not a filter: the user's transition and log-likelihood alone, scanned over the steps
    (no resampling, normalisation or moments). What any filter built on these user functions
    costs at least."""
    F, LQ = jnp.asarray(p["F"], dtype), jnp.asarray(p["LQ"], dtype)
    loglik_fn = gaussian_loglik_fn(p["R"], dtype)

    def run(key, x0, zs):
        def body(x, inp):
            k, z = inp
            x = x @ F.T + jax.random.normal(k, x.shape, x.dtype) @ LQ.T
            return x, jnp.sum(loglik_fn(z, x))

        _, lls = jax.lax.scan(body, x0, (jax.random.split(key, zs.shape[0]), zs))
        return lls

    return run, None


FLOOR = ("user functions only", user_functions_only)


def jax_call(factory, p, episodes, key):
    """(jitted fn, args) for one JAX implementation."""
    run, _ = factory(p)
    fn = jax.jit(jax.vmap(run) if episodes > 1 else run)
    x0 = jnp.asarray(p["x0"][:episodes], jnp.float32)
    zs = jnp.asarray(p["zs"][:episodes], jnp.float32)
    keys = jax.random.split(key, episodes)
    args = (keys, x0, zs) if episodes > 1 else (keys[0], x0[0], zs[0])
    return fn, args


def run_case(p, episodes, args, rows, skip):
    batched = episodes > 1
    print(f"\n[N={episodes}, T={args.steps}, {args.particles} particles] ...", flush=True)
    calls, meta, compiled = {}, {}, []
    key = jax.random.key(1 + args.seed, impl=args.prng)
    for name, factory in JAX_IMPLS + [FLOOR]:
        if name in skip:
            continue
        calls[name] = jax_call(factory, p, episodes, key)
        compiled.append(name)
        note = "f32, " + ("jit(vmap)" if batched else "jit")
        if name == "cuthbert":
            note += "; host callback resampler"
        if name == "cuthbert*":
            note += "; resampling_fn without the callback"
        if name == "jaxtrack (no covs)":
            note += "; return_covs=False"
        if name == FLOOR[0]:
            note += "; transition + likelihood, no filter: the floor"
        if args.prng != "threefry2x32":
            note += f"; {args.prng} keys"
        meta[name] = (episodes, args.steps, note)
    timed_e = min(episodes, args.python_episodes)
    py_note = "f64 numpy, Python loop" + (f"; timed {timed_e} of {episodes} episodes"
                                          if timed_e < episodes else "")
    if "particles" not in skip:
        calls["particles"] = (particles_pf, (p, timed_e, args.steps))
        meta["particles"] = (timed_e, args.steps, py_note)
    if "filterpy" not in skip:
        calls["numpy+filterpy"] = (filterpy_pf, (p, timed_e, args.steps))
        meta["numpy+filterpy"] = (timed_e, args.steps, py_note)
    if not batched and "stonesoup" not in skip:
        ss_steps = min(args.steps, args.stonesoup_steps or args.steps)
        calls["stonesoup"] = (stonesoup_pf, (p, ss_steps))
        meta["stonesoup"] = (1, ss_steps, "f64 numpy, Python loop" + (
            f"; timed {ss_steps} of {args.steps} steps" if ss_steps < args.steps else ""))
    results = _common.time_interleaved(calls, repeats=args.repeats,
                                       min_repeat_s=args.min_repeat_s, compiled=compiled)
    case_rows = {}
    for name, (timing, _) in results.items():
        timed_episodes, timed_steps, note = meta[name]
        case_rows[name] = _common.timing_row((name, episodes, args.steps), timing,
                                             timed_episodes, timed_steps, unit="ep-step",
                                             note=note)
        _common.progress(name, case_rows[name], timing)
    reference = case_rows.get("jaxtrack")
    rows.extend(r.vs(reference) if reference else r for r in case_rows.values())


# ---------------------------------------------------------------------------------------------
# Agreement


def kf_loglik(p, episode=0):
    with jax.enable_x64(True):
        res = kalman.filter(kalman.Gaussian(jnp.asarray(p["m0"][episode]), jnp.asarray(p["P0"])),
                            jnp.asarray(p["zs"][episode]), jnp.asarray(p["F"]),
                            jnp.asarray(p["Q"]), jnp.asarray(p["H"]), jnp.asarray(p["R"]))
        return float(res.log_likelihood), np.asarray(res.means)


def jax_summary(name, out):
    """(log-likelihood estimate [...], filtered means [..., T, 4]) of a JAX library's result."""
    if name == "jaxtrack":
        return out.log_likelihood, out.means
    if name == "jax (hand-written)":
        return out[2], out[0]
    # cuthbert: every step's particles and log weights; step 0 is the initial state
    w = jax.nn.softmax(out.log_weights[..., 1:, :], axis=-1)
    return out.log_normalizing_constant[..., -1], jnp.einsum("...tp,...tpd->...td", w,
                                                             out.particles[..., 1:, :, :])


def agreement(p, args, skip):
    """Log-likelihood estimates and filtered means of episode 0 over several seeds per library
    (JAX libraries 5 x ``args.check_runs``, vmapped; Stone Soup half of ``args.check_runs``)."""
    runs = args.check_runs
    steps = args.steps
    jax_runs = 5 * runs
    # Run r of every library starts from the same fresh draw x0[r] ~ N(m0, P0): with one fixed
    # set of initial particles the estimates would target the likelihood under that empirical
    # prior, not the KF's Gaussian one.
    rng = np.random.default_rng(7 + args.seed)
    n_particles = p["x0"].shape[1]
    x0s = p["m0"][0] + rng.standard_normal((jax_runs, n_particles, 4)) @ np.linalg.cholesky(
        p["P0"]).T

    def episode0(r):
        return {**p, "x0": x0s[r:r + 1], "zs": p["zs"][:1], "m0": p["m0"][:1]}

    one = episode0(0)
    results = {}  # name -> (log-likelihoods [R], means [R, T, 4])
    keys = jax.random.split(jax.random.key(123 + args.seed, impl=args.prng), jax_runs)
    x0 = jnp.asarray(x0s, jnp.float32)
    zs = jnp.broadcast_to(jnp.asarray(p["zs"][0], jnp.float32), (jax_runs,) + p["zs"].shape[1:])
    for name, factory in JAX_IMPLS:
        # the no-covs run gives the same estimates as jaxtrack's bit for bit (tested)
        if name in skip or name == "jaxtrack (no covs)":
            continue
        run, _ = factory(one)
        ll, means = jax_summary(name, jax.jit(jax.vmap(run))(keys, x0, zs))
        results[name] = (np.asarray(ll, np.float64), np.asarray(means, np.float64))
    if "particles" not in skip:
        pfs = [particles_pf(episode0(r), 1, steps, seed=1000 + args.seed + r)[0]
               for r in range(runs)]
        results["particles"] = (np.array([pf.logLt for pf in pfs]),
                                np.array([[m for m, _ in pf.summaries.moments] for pf in pfs]))
    if "filterpy" not in skip:
        outs = [filterpy_pf(episode0(r), 1, steps, seed=2000 + args.seed + r)[0]
                for r in range(runs)]
        results["numpy+filterpy"] = (np.array([o[2] for o in outs]),
                                     np.array([o[0] for o in outs]))
    if "stonesoup" not in skip:
        outs = [stonesoup_pf(episode0(r), steps, seed=3000 + args.seed + r, with_loglik=True)
                for r in range(max(2, runs // 2))]
        results["stonesoup"] = (np.array([o[1] for o in outs]), np.array([o[0] for o in outs]))
    ll_kf, means_kf = kf_loglik(p)
    ref = results.get("jaxtrack", (None,))[0]
    rows = []
    for name, (est, means) in results.items():
        mean, sd = float(np.mean(est)), float(np.std(est, ddof=1))
        se = sd / math.sqrt(len(est))
        if ref is not None and name != "jaxtrack":
            se_diff = math.hypot(se, float(np.std(ref, ddof=1)) / math.sqrt(len(ref)))
            z_txt = f"{(mean - float(np.mean(ref))) / se_diff:+.2f}"
        else:
            z_txt = "-"
        # RMS over steps of the position error of the filtered mean w.r.t. the KF mean,
        # averaged over runs.
        err = np.sqrt(np.mean(np.sum((means[..., :2] - means_kf[:, :2]) ** 2, -1), -1))
        rows.append([name, len(est), f"{mean:.2f}", f"{sd:.2f}", f"{se:.2f}",
                     f"{mean - ll_kf:+.2f}", f"{mean + sd * sd / 2 - ll_kf:+.2f}", z_txt,
                     f"{1000 * float(np.mean(err)):.1f}"])
    rows.append(["Kalman filter (exact, f64)", 1, f"{ll_kf:.2f}", "-", "-", "0", "-", "-", "0"])
    return _common.format_table(
        ["episode 0", "runs", "loglik mean", "sd", "se of mean", "mean - KF",
         "+ sd^2/2", "z vs jaxtrack", "RMS |mean - KF mean| pos, mm"], rows,
        align="lrrrrrrrr")


# ---------------------------------------------------------------------------------------------


def parse_args(argv=None):
    ap = _common.parser(__doc__, timing=True, single_core=True, agreement=True)
    ap.sized("--episodes", 100, 4, "batched N")
    ap.sized("--steps", 200, 20, "T")
    ap.add_argument("--particles", type=int, default=1000, help="particles (default 1000)")
    ap.sized("--python-episodes", 3, 1, "episodes timed for the numpy libraries when N > 1")
    ap.add_argument("--stonesoup-steps", type=int, default=None,
                    help="cap on steps timed for Stone Soup (default: T)")
    ap.sized("--check-runs", 20, 4, "seeds per numpy library in the agreement check (JAX "
             "libraries 5x as many, Stone Soup half)")
    ap.add_argument("--skip", default="",
                    help="comma-separated libraries to leave out (jaxtrack, 'jaxtrack (no "
                         "covs)', 'jax (hand-written)', 'user functions only', cuthbert, "
                         "cuthbert*, particles, filterpy, stonesoup)")
    ap.add_argument("--prng", default="threefry2x32",
                    choices=["threefry2x32", "rbg", "unsafe_rbg"],
                    help="jax.random key implementation of every JAX library (default "
                         "threefry2x32, JAX's default)")
    ap.add_argument("--threefry-partitionable", default="on", choices=["on", "off"],
                    help="jax_threefry_partitionable for every JAX library (default on, JAX's "
                         "default since 0.5; off: the earlier threefry bit layout, about 3x "
                         "faster normal draws on XLA:CPU)")
    return ap.parse_args(argv)


def main(argv=None):
    return _common.report(run, parse_args(argv))


def run(args):
    _common.setup_jax()
    jax.config.update("jax_threefry_partitionable", args.threefry_partitionable == "on")
    skip = {s.strip() for s in args.skip.split(",") if s.strip()}
    header = _common.header(
        PACKAGES, f"problem: bootstrap PF, {args.particles} particles, 4-state CV (dt {DT}, "
        f"q {CV_Q}), 2-D position (std {R_STD[0]}/{R_STD[1]} m, rho {R_RHO}); "
        f"N = 1 and {args.episodes} episodes x T = {args.steps} steps; systematic "
        f"resampling every step; JAX PRNG {args.prng}, "
        f"jax_threefry_partitionable={jax.config.jax_threefry_partitionable}",
        threads=THREAD_ENV)
    print("\n".join(header), flush=True)

    p = make_problem(args.episodes, args.steps, args.particles, seed=args.seed)
    rows = []
    for episodes in sorted({1, args.episodes}):
        run_case(p, episodes, args, rows, skip)

    header.append(_common.load_line("end of timing"))
    print("\n" + "\n".join(header))
    print()
    print(_common.table(["library", "N", "T"], rows))
    print("\nus/ep-step = wall time per call / (episodes x steps timed); vs jaxtrack = peer / "
          "jaxtrack (> 1: jaxtrack faster).\nJAX: float32, N = 1 jit(filter), N > 1 "
          "jit(vmap(filter)); numpy libraries: float64, one Python loop per episode.")
    if not args.no_check:
        print(f"\nAgreement (episode 0, T = {args.steps}; run r of every library starts from the "
              f"same initial particles ~ N(m0, P0), with its own seed):")
        print(agreement(p, args, skip))
    return rows


if __name__ == "__main__":
    main()
