"""Gaussian filters side by side: jaxtrack vs dynamax, cuthbert, filterpy and Stone Soup.

Two problems, each at N = 1 episode and N = 1000 episodes x T = 200 steps, on one CPU core:

(a) KF: 4-state constant velocity ([p_x, p_y, v_x, v_y], dt = 0.1, q = 0.5), 2-D position
    measurements. Every episode has its own R (random per-axis std 0.05-0.5 m and correlation),
    so the covariance recursion is genuinely batched, and its own initial mean.
(b) UKF: 5-state coordinated turn ([p_x, p_y, v, heading, turn_rate], dt = 0.1, q_accel = 0.1,
    q_turn = 0.01) with range-bearing measurements from the origin, own R and initial mean per
    episode (range std 0.1-0.5 m, bearing std 0.5-2 deg).
    Merwe sigma points with the same (alpha, beta, kappa) in every library, default
    (1, 2, 0): lambda = 0, so every weight is >= 0 and the textbook weighted sums that dynamax,
    filterpy and Stone Soup use do not cancel in float32 (with alpha = 1e-3 the central weight is
    about -1e6). Targets start 80-120 m out along +x (bearings stay within +-0.8 rad, far from
    the +-pi cut): dynamax has no angle-aware residual, and this keeps it computing the same
    thing as the others.

How each library runs:
- JAX libraries (jaxtrack, dynamax, cuthbert): float32 (JAX's default, the fair speed setting).
  N = 1 is ``jit(filter)``; N > 1 is ``jit(vmap(filter))`` with R, z and the initial mean
  batched and F, Q, H shared. Each jitted function returns that library's whole default result
  (jaxtrack and dynamax's UKF also return the predicted moments, dynamax's KF does not).
- filterpy and Stone Soup: numpy float64, one Python loop per episode (predict, update, copy the
  posterior out). Neither computes the log-likelihood in the loop (both only do it on request).
  At N > 1 only ``--python-episodes`` episodes are timed and the time is per episode-step.
  Stone Soup runs at N = 1 only.

Time is the median over repeats of the wall time per call after a warm-up call, blocking on the
outputs; the "first call" column is the warm-up's extra time (tracing + compilation for jitted
code). Table unit: microseconds per episode-step = call time / (N * T). "vs jaxtrack" is
peer time / jaxtrack time (> 1: jaxtrack is faster). The libraries of one (case, N) are timed
interleaved, round-robin, so background load hits them alike. On a shared machine, a repeat
in which the process got less than 0.9 s of CPU per wall second (it was descheduled) is not
clean: rounds continue until each library has ``--repeats`` clean repeats (at most 3x as many
rounds), and the median is over the clean ones ("clean" column: clean / total). "cpu
us/ep-step" is the same median in process CPU time (above the wall time when more than one
thread was busy).

Agreement: after timing, jaxtrack is re-run against each peer in float64 on the same data and the
max abs differences of the log-likelihoods and filtered means are printed (the float32 differences
of the timed runs are printed too). dynamax adds 1e-9 I to S in its ``psd_solve``; it is also run
with that boost set to 0 (for the check only), which isolates it as the whole difference.

Usage:
    python benchmarks/filters.py             # full run (a few minutes)
    python benchmarks/filters.py --quick     # smoke test (N = 1 and 8, T = 20)
    python benchmarks/filters.py --episodes 200 --steps 100

Single core: before jax or numpy is imported, the script sets XLA_FLAGS / *_NUM_THREADS (an
explicit environment wins) and restricts its own CPU affinity to one core, as ``taskset -c``
would (no external tool needed; ``--no-pin`` turns it off). The affinity is what makes it single
core: XLA:CPU runs independent operations of a program concurrently on its intra-op pool (one
thread per core) whatever XLA_FLAGS say, and ``intra_op_parallelism_threads=1`` is not an XLA
flag (XLA ignores it). Unpinned on a 2-core machine, jaxtrack's N = 1 KF kept three threads
busy and took 1.1-1.45x longer than pinned.
"""

from __future__ import annotations

import _common

THREAD_ENV = _common.single_core_from_argv()

import datetime  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxtrack.filters import kalman, ukf  # noqa: E402
from jaxtrack.models import measurement, motion  # noqa: E402

PACKAGES = ["jaxtrack", "jax", "jaxlib", "numpy", "scipy", "dynamax", "cuthbert", "filterpy",
            "stonesoup"]

DT = 0.1
CV_Q = 0.5
CT_Q_ACCEL, CT_Q_TURN = 0.1, 0.01


# ---------------------------------------------------------------------------------------------
# Problems (numpy float64; model matrices come from jaxtrack, built in float64)


class Problem(dict):
    """Named numpy arrays; those named in ``batched`` have a leading episode axis."""

    def __init__(self, arrays, batched):
        super().__init__(arrays)
        self.batched = frozenset(batched)

    def map(self, batched_fn):
        return Problem({k: (batched_fn(v) if k in self.batched else v) for k, v in self.items()},
                       self.batched)


def cv_problem(episodes, steps, seed=0):
    rng = np.random.default_rng(seed)
    with jax.enable_x64(True):
        F, Q = (np.asarray(a, np.float64) for a in motion.constant_velocity(DT, CV_Q))
        H = np.asarray(measurement.position(4, dtype=jnp.float64), np.float64)
    m_prior = np.array([0.0, 0.0, 1.0, 0.5])
    P0 = np.diag([1.0, 1.0, 0.25, 0.25])
    x = m_prior + rng.standard_normal((episodes, 4)) @ np.linalg.cholesky(P0).T
    m0 = m_prior + rng.standard_normal((episodes, 4)) @ np.linalg.cholesky(P0).T * 0.5
    sx, sy = rng.uniform(0.05, 0.5, (2, episodes))
    rho = rng.uniform(-0.5, 0.5, episodes)
    R = np.stack([np.stack([sx**2, rho * sx * sy], -1), np.stack([rho * sx * sy, sy**2], -1)], -2)
    LQ, LR = np.linalg.cholesky(Q), np.linalg.cholesky(R)
    zs = np.empty((episodes, steps, 2))
    for t in range(steps):
        x = x @ F.T + rng.standard_normal((episodes, 4)) @ LQ.T
        zs[:, t] = x @ H.T + np.einsum("eij,ej->ei", LR, rng.standard_normal((episodes, 2)))
    return Problem(dict(m0=m0, P0=P0, F=F, Q=Q, H=H, R=R, zs=zs), ("m0", "R", "zs"))


def ct_step_np(x, dt=DT):
    """jaxtrack's `motion.coordinated_turn` in numpy; x [5] or [5, k] (columns)."""
    px, py, v, heading, turn = x
    half = 0.5 * turn * dt
    chord = v * dt * np.sinc(half / np.pi)
    mid = heading + half
    return np.stack([px + chord * np.cos(mid), py + chord * np.sin(mid), v,
                     heading + turn * dt, turn])


def range_bearing_np(x):
    return np.array([np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])])


def range_bearing_residual_np(a, b):
    d = np.asarray(a, np.float64) - b
    d[1] = np.mod(d[1] + np.pi, 2 * np.pi) - np.pi
    return d


def ct_problem(episodes, steps, seed=1):
    rng = np.random.default_rng(seed)
    with jax.enable_x64(True):
        _, Q = motion.coordinated_turn(DT, CT_Q_ACCEL, CT_Q_TURN)
        Q = np.asarray(Q, np.float64)
    P0 = np.diag([1.0, 1.0, 0.25, 0.1, 0.01])
    x = np.stack([rng.uniform(80, 120, episodes), rng.uniform(-20, 20, episodes),
                  rng.uniform(0.5, 1.5, episodes), rng.uniform(-np.pi, np.pi, episodes),
                  rng.normal(0.0, 0.1, episodes)], -1)
    m0 = x + rng.standard_normal((episodes, 5)) @ np.linalg.cholesky(P0).T
    sr = rng.uniform(0.1, 0.5, episodes)
    sb = np.deg2rad(rng.uniform(0.5, 2.0, episodes))
    R = np.zeros((episodes, 2, 2))
    R[:, 0, 0], R[:, 1, 1] = sr**2, sb**2
    LQ = np.linalg.cholesky(Q)
    zs = np.empty((episodes, steps, 2))
    for t in range(steps):
        x = ct_step_np(x.T).T + rng.standard_normal((episodes, 5)) @ LQ.T
        zs[:, t, 0] = np.hypot(x[:, 0], x[:, 1]) + sr * rng.standard_normal(episodes)
        zs[:, t, 1] = np.arctan2(x[:, 1], x[:, 0]) + sb * rng.standard_normal(episodes)
    return Problem(dict(m0=m0, P0=P0, Q=Q, R=R, zs=zs), ("m0", "R", "zs"))


def take(problem, episodes):
    """The first ``episodes`` episodes (shared arrays unchanged)."""
    return problem.map(lambda v: v[:episodes])


def single(problem):
    """Episode 0 without the batch axis."""
    return Problem({k: (v[0] if k in problem.batched else v) for k, v in problem.items()}, ())


def take_steps(problem, steps):
    out = Problem(problem, problem.batched)
    out["zs"] = problem["zs"][:, :steps]
    return out


def batch(fn, keys, problem):
    """``fn`` vmapped over the episode axis of the batched arrays of ``problem``."""
    return jax.vmap(fn, in_axes=tuple(0 if k in problem.batched else None for k in keys))


# ---------------------------------------------------------------------------------------------
# JAX implementations. Each factory returns ``(keys, run)``: ``run(*problem[keys])`` filters
# one episode and returns the library's whole result; `batch` vmaps it over episodes.


def jaxtrack_kf():
    keys = ("m0", "P0", "F", "Q", "H", "R", "zs")

    # Like-for-like outputs: dynamax returns the filtered moments and the log-likelihood only,
    # so jaxtrack is asked not to store its one-step predictions either.
    def run(m0, P0, F, Q, H, R, zs):
        return kalman.filter(kalman.Gaussian(m0, P0), zs, F, Q, H, R, return_predicted=False)

    return keys, run


def dynamax_kf():
    from dynamax.linear_gaussian_ssm.inference import (ParamsLGSSM, ParamsLGSSMDynamics,
                                                       ParamsLGSSMEmissions, ParamsLGSSMInitial,
                                                       lgssm_filter)

    # dynamax updates first and then predicts, so its "initial" is the prior of x_1:
    # (F m0, F P0 F^T + Q), computed outside the timed call (keys m1, P1).
    keys = ("m1", "P1", "F", "Q", "H", "R", "zs")

    def run(m1, P1, F, Q, H, R, zs):
        n, m = F.shape[0], H.shape[0]
        params = ParamsLGSSM(
            initial=ParamsLGSSMInitial(mean=m1, cov=P1),
            dynamics=ParamsLGSSMDynamics(weights=F, bias=jnp.zeros(n, F.dtype),
                                         input_weights=jnp.zeros((n, 0), F.dtype), cov=Q),
            emissions=ParamsLGSSMEmissions(weights=H, bias=jnp.zeros(m, F.dtype),
                                           input_weights=jnp.zeros((m, 0), F.dtype), cov=R))
        return lgssm_filter(params, zs)

    return keys, run


def cuthbert_kf():
    import cuthbert
    from cuthbert.gaussian import kalman as cb_kalman

    keys = ("m0", "L0", "F", "LQ", "H", "LR", "zs")

    def run(m0, L0, F, LQ, H, LR, zs):
        n, m = F.shape[0], H.shape[0]
        filt = cb_kalman.build_filter(
            m0, L0,
            get_dynamics_params=lambda _: (F, jnp.zeros(n, F.dtype), LQ),
            get_observation_params=lambda z: (H, jnp.zeros(m, F.dtype), LR, z))
        return cuthbert.filter(filt, zs, filt.init_prepare(), parallel=False)

    return keys, run


def cuthbertlib_kf():
    """cuthbertlib's atomic square-root predict / update in a plain lax.scan."""
    from cuthbertlib.kalman import filtering

    keys = ("m0", "L0", "F", "LQ", "H", "LR", "zs")

    def run(m0, L0, F, LQ, H, LR, zs):
        c = jnp.zeros(F.shape[0], F.dtype)
        d = jnp.zeros(H.shape[0], F.dtype)

        def body(carry, z):
            m, L, ll = carry
            m, L = filtering.predict(m, L, F, c, LQ)
            (m, L), ll = filtering.update(m, L, H, d, LR, z, ll)
            return (m, L, ll), (m, L)

        (_, _, ll), (means, chols) = jax.lax.scan(body, (m0, L0, jnp.zeros((), F.dtype)), zs)
        return means, chols, ll

    return keys, run


def ukf_points(alpha, beta, kappa):
    return ukf.merwe_points(alpha=alpha, beta=beta, kappa=kappa)


def jaxtrack_ukf(scheme):
    f, _ = motion.coordinated_turn(DT, CT_Q_ACCEL, CT_Q_TURN)
    points = ukf_points(*scheme)
    keys = ("m0", "P0", "Q", "R", "zs")

    def run(m0, P0, Q, R, zs):
        return ukf.filter(kalman.Gaussian(m0, P0), zs, f, Q, measurement.range_bearing, R,
                          points=points, residual_z=measurement.range_bearing_residual,
                          return_predicted=False)

    return keys, run


def dynamax_ukf(scheme):
    from dynamax.nonlinear_gaussian_ssm import (ParamsNLGSSM, UKFHyperParams,
                                                unscented_kalman_filter)

    f, _ = motion.coordinated_turn(DT, CT_Q_ACCEL, CT_Q_TURN)
    alpha, beta, kappa = scheme
    hyper = UKFHyperParams(alpha=alpha, beta=beta, kappa=kappa)
    keys = ("m1", "P1", "Q", "R", "zs")

    def run(m1, P1, Q, R, zs):
        params = ParamsNLGSSM(initial_mean=m1, initial_covariance=P1, dynamics_function=f,
                              dynamics_covariance=Q, emission_function=measurement.range_bearing,
                              emission_covariance=R)
        return unscented_kalman_filter(params, zs, hyper)

    return keys, run


def with_derived_kf(p):
    """Add dynamax's first prior (m1, P1) and cuthbert's Cholesky factors (numpy float64)."""
    p = Problem(p, p.batched | {"m1", "LR"})
    p["m1"] = p["m0"] @ p["F"].T
    p["P1"] = p["F"] @ p["P0"] @ p["F"].T + p["Q"]
    p["L0"] = np.linalg.cholesky(p["P0"])
    p["LQ"] = np.linalg.cholesky(p["Q"])
    p["LR"] = np.linalg.cholesky(p["R"])
    return p


def with_derived_ukf(p, scheme):
    """Add dynamax's first prior: one jaxtrack UKF predict of (m0, P0), in float64."""
    p = Problem(p, p.batched | {"m1", "P1"})
    points = ukf_points(*scheme)
    with jax.enable_x64(True):
        f, _ = motion.coordinated_turn(DT, CT_Q_ACCEL, CT_Q_TURN)
        pred = jax.vmap(lambda m: ukf.predict(kalman.Gaussian(m, jnp.asarray(p["P0"])), f,
                                              jnp.asarray(p["Q"]), points=points))(
            jnp.asarray(p["m0"]))
        p["m1"] = np.asarray(pred.mean)
        p["P1"] = np.asarray(pred.cov)
    return p


def summary(name, out):
    """(log-likelihood [...], filtered means [..., T, n]) from a library's result."""
    if name == "jaxtrack":
        return out.log_likelihood, out.means
    if name == "dynamax":
        return out.marginal_loglik, out.filtered_means
    if name == "cuthbert":
        return out.log_normalizing_constant[..., -1], out.mean[..., 1:, :]
    if name == "cuthbertlib":
        return out[2], out[0]
    raise KeyError(name)


# ---------------------------------------------------------------------------------------------
# numpy libraries


def filterpy_kf(p, episodes):
    from filterpy.kalman import KalmanFilter

    T = p["zs"].shape[1]
    out = []
    for e in range(episodes):
        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.x = p["m0"][e].reshape(4, 1).copy()
        kf.P = p["P0"].copy()
        kf.F, kf.Q, kf.H, kf.R = p["F"], p["Q"], p["H"], p["R"][e]
        means, covs = np.empty((T, 4)), np.empty((T, 4, 4))
        for t in range(T):
            kf.predict()
            kf.update(p["zs"][e, t])
            means[t], covs[t] = kf.x[:, 0], kf.P
        out.append((means, covs))
    return out


def filterpy_ukf(p, episodes, scheme):
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    alpha, beta, kappa = scheme
    T = p["zs"].shape[1]
    out = []
    for e in range(episodes):
        points = MerweScaledSigmaPoints(5, alpha=alpha, beta=beta, kappa=kappa)
        f = UnscentedKalmanFilter(dim_x=5, dim_z=2, dt=DT, hx=range_bearing_np,
                                  fx=lambda x, dt: ct_step_np(x, dt), points=points,
                                  residual_z=range_bearing_residual_np)
        f.x, f.P = p["m0"][e].copy(), p["P0"].copy()
        f.Q, f.R = p["Q"], p["R"][e]
        means, covs = np.empty((T, 5)), np.empty((T, 5, 5))
        for t in range(T):
            f.predict()
            f.update(p["zs"][e, t])
            means[t], covs[t] = f.x, f.P
        out.append((means, covs))
    return out


def _stonesoup_times(T):
    start = datetime.datetime(2025, 1, 1)
    return [start + datetime.timedelta(seconds=DT * (t + 1)) for t in range(T)], start


def stonesoup_kf(p, steps):
    """Episode 0. Stone Soup orders the state [x, v_x, y, v_y]; permuted in and out."""
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import (CombinedLinearGaussianTransitionModel,
                                                    ConstantVelocity)
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.state import GaussianState
    from stonesoup.updater.kalman import KalmanUpdater

    perm = [0, 2, 1, 3]
    transition = CombinedLinearGaussianTransitionModel([ConstantVelocity(CV_Q),
                                                        ConstantVelocity(CV_Q)])

    sensor = LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=p["R"][0])
    predictor, updater = KalmanPredictor(transition), KalmanUpdater(sensor)
    times, start = _stonesoup_times(steps)
    state = GaussianState(p["m0"][0][perm].reshape(4, 1), p["P0"][np.ix_(perm, perm)],
                          timestamp=start)
    means, covs = np.empty((steps, 4)), np.empty((steps, 4, 4))
    for t in range(steps):
        prediction = predictor.predict(state, timestamp=times[t])
        detection = Detection(p["zs"][0, t].reshape(2, 1), timestamp=times[t],
                              measurement_model=sensor)
        state = updater.update(SingleHypothesis(prediction, detection))
        means[t] = np.asarray(state.state_vector, np.float64)[perm, 0]
        covs[t] = np.asarray(state.covar, np.float64)[np.ix_(perm, perm)]
    return means, covs


def _stonesoup_polar_ct():
    """jaxtrack's coordinated-turn model as a Stone Soup transition model (Stone Soup's own
    ConstantTurn uses Cartesian velocity, a different model)."""
    from stonesoup.base import Property
    from stonesoup.models.base import TimeVariantModel
    from stonesoup.models.transition.nonlinear import GaussianTransitionModel
    from stonesoup.types.array import CovarianceMatrix, StateVectors

    class PolarCoordinatedTurn(GaussianTransitionModel, TimeVariantModel):
        Q: np.ndarray = Property(doc="process-noise covariance for the time step DT")

        @property
        def ndim_state(self):
            return 5

        def function(self, state, noise=False, **kwargs):
            dt = kwargs["time_interval"].total_seconds()
            out = StateVectors(ct_step_np(np.asarray(state.state_vector, np.float64), dt))
            if noise is True:
                noise = self.rvs(num_samples=out.shape[1], **kwargs)
            return out + (0 if noise is False or noise is None else noise)

        def covar(self, time_interval=None, **kwargs):
            return CovarianceMatrix(self.Q)

    return PolarCoordinatedTurn


def stonesoup_ukf(p, steps, scheme):
    """Episode 0; Stone Soup measures [bearing, range] (reordered in)."""
    from stonesoup.models.measurement.nonlinear import CartesianToBearingRange
    from stonesoup.predictor.kalman import UnscentedKalmanPredictor
    from stonesoup.types.angle import Bearing
    from stonesoup.types.array import StateVector
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.state import GaussianState
    from stonesoup.updater.kalman import UnscentedKalmanUpdater

    alpha, beta, kappa = scheme
    transition = _stonesoup_polar_ct()(Q=p["Q"])
    R = p["R"][0][np.ix_([1, 0], [1, 0])]
    sensor = CartesianToBearingRange(ndim_state=5, mapping=(0, 1), noise_covar=R)
    predictor = UnscentedKalmanPredictor(transition, alpha=alpha, beta=beta, kappa=kappa)
    updater = UnscentedKalmanUpdater(sensor, alpha=alpha, beta=beta, kappa=kappa)
    times, start = _stonesoup_times(steps)
    state = GaussianState(p["m0"][0].reshape(5, 1), p["P0"], timestamp=start)
    means, covs = np.empty((steps, 5)), np.empty((steps, 5, 5))
    for t in range(steps):
        rng_, brg = p["zs"][0, t]
        prediction = predictor.predict(state, timestamp=times[t])
        detection = Detection(StateVector([Bearing(brg), rng_]), timestamp=times[t],
                              measurement_model=sensor)
        state = updater.update(SingleHypothesis(prediction, detection))
        means[t] = np.asarray(state.state_vector, np.float64)[:, 0]
        covs[t] = np.asarray(state.covar, np.float64)
    return means, covs


# ---------------------------------------------------------------------------------------------
# Runner


def run_case(case, problem_full, jax_impls, python_impls, args, rows, outputs):
    """Time every implementation at N = 1 and N = args.episodes, interleaved per N."""
    for episodes in sorted({1, args.episodes}):
        batched = episodes > 1
        prob = take(problem_full, episodes)
        p = prob if batched else single(prob)
        print(f"\n[{case} N={episodes}, T={args.steps}] ...", flush=True)
        calls, meta = {}, {}
        for name, factory in jax_impls:
            keys, run = factory()
            fn = jax.jit(batch(run, keys, p) if batched else run)
            calls[name] = (fn, tuple(jnp.asarray(p[k], jnp.float32) for k in keys))
            meta[name] = (episodes, args.steps, "f32, jit(vmap)" if batched else "f32, jit")
        for name, run, n1_only, max_steps in python_impls:
            if batched and n1_only:
                continue
            timed_episodes = min(episodes, args.python_episodes)
            timed_steps = min(args.steps, max_steps or args.steps)
            calls[name] = (run, (prob, timed_episodes, timed_steps))
            note = "f64 numpy, Python loop"
            if timed_episodes < episodes:
                note += f"; timed {timed_episodes} of {episodes} episodes"
            if timed_steps < args.steps:
                note += f"; timed {timed_steps} of {args.steps} steps"
            meta[name] = (timed_episodes, timed_steps, note)
        results = _common.time_interleaved(calls, repeats=args.repeats,
                                           min_repeat_s=args.min_repeat_s,
                                           compiled=[n for n, _ in jax_impls])
        case_rows = {}
        for name, (timing, out) in results.items():
            timed_episodes, timed_steps, note = meta[name]
            outputs[(case, episodes, name)] = out
            case_rows[name] = _common.timing_row((case, name, episodes, args.steps), timing,
                                                 timed_episodes, timed_steps, unit="ep-step",
                                                 note=note)
            _common.progress(name, case_rows[name], timing)
        rows.extend(r.vs(case_rows["jaxtrack"]) for r in case_rows.values())


def linalg_table(args):
    """Backs the claim in `jaxtrack.filters._linalg`: unrolled small Cholesky / triangular solves
    vs XLA's LAPACK calls, on a batch of matrices (float32, one jitted call each)."""
    from jax.scipy.linalg import cho_solve

    from jaxtrack.filters import _linalg

    batch_size = args.episodes
    rng = np.random.default_rng(2 + args.seed)
    rows, calls = [], {}
    for n in (2, 4, 5):
        a = rng.standard_normal((batch_size, n, n))
        spd = jnp.asarray(a @ np.swapaxes(a, -1, -2) + n * np.eye(n), jnp.float32)
        rhs = jnp.asarray(rng.standard_normal((batch_size, n, 3)), jnp.float32)
        calls[f"cholesky {n}x{n}, unrolled"] = (jax.jit(_linalg.cholesky), (spd,))
        calls[f"cholesky {n}x{n}, LAPACK"] = (jax.jit(jnp.linalg.cholesky), (spd,))
        calls[f"chol + solve {n}x{n}, unrolled"] = (
            jax.jit(lambda s_, b: _linalg.cho_solve(_linalg.cholesky(s_), b)), (spd, rhs))
        calls[f"chol + solve {n}x{n}, LAPACK"] = (
            jax.jit(jax.vmap(lambda s_, b: cho_solve((jnp.linalg.cholesky(s_), True), b))),
            (spd, rhs))
    results = _common.time_interleaved(calls, repeats=args.repeats,
                                       min_repeat_s=args.min_repeat_s)
    for name, (timing, _) in results.items():
        if name.endswith("LAPACK"):
            continue
        lapack = results[name.replace("unrolled", "LAPACK")][0]
        rows.append([name.replace(", unrolled", ""), batch_size,
                     _common.fmt_float(1e9 * timing.seconds / batch_size),
                     _common.fmt_float(1e9 * lapack.seconds / batch_size),
                     f"{lapack.seconds / timing.seconds:.2f}"])
    return _common.format_table(["op (float32)", "batch", "unrolled ns/matrix",
                                 "LAPACK ns/matrix", "LAPACK / unrolled"], rows)


def max_abs(a, b):
    return float(np.max(np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64))))


def per_episode(a, b, batched):
    """(max, median) over episodes of the per-episode max abs difference."""
    d = np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64))
    d = d.reshape(d.shape[0], -1).max(1) if batched else d.reshape(1, -1).max(1)
    return float(d.max()), float(np.median(d))


def _dynamax_without_jitter():
    """Context manager: dynamax's psd_solve with diagonal_boost=0 (it adds 1e-9 I to S)."""
    import contextlib
    import functools

    import dynamax.linear_gaussian_ssm.inference as lgssm
    import dynamax.nonlinear_gaussian_ssm.inference_ukf as nlgssm

    @contextlib.contextmanager
    def patched():
        saved = lgssm.psd_solve, nlgssm.psd_solve
        exact = functools.partial(saved[0], diagonal_boost=0.0)
        lgssm.psd_solve = nlgssm.psd_solve = exact
        try:
            yield
        finally:
            lgssm.psd_solve, nlgssm.psd_solve = saved

    return patched()


def agreement(kf_problem, ct_problem_, scheme, outputs, args):
    """jaxtrack vs each peer on the same data; float64 re-runs plus the float32 timed runs."""
    lines = []
    N = args.episodes
    batched = N > 1
    fmt = "max {:.1e} (median {:.1e})"
    for case, problem, peers, jt_factory in (
            ("KF", kf_problem, (("dynamax", dynamax_kf), ("cuthbert", cuthbert_kf),
                                ("cuthbertlib", cuthbertlib_kf)), jaxtrack_kf),
            ("UKF", ct_problem_, (("dynamax", lambda: dynamax_ukf(scheme)),),
             lambda: jaxtrack_ukf(scheme))):
        prob = take(problem, N)
        p_run = prob if batched else single(prob)

        def run64(factory):
            keys, run = factory()
            fn = jax.jit(batch(run, keys, p_run) if batched else run)
            return fn(*(jnp.asarray(p_run[k], jnp.float64) for k in keys))

        def line(label, ll, means, ll_ref, means_ref):
            return (f"  {case:<4} {label:<40} |d loglik| "
                    + fmt.format(*per_episode(ll, ll_ref, batched))
                    + ", |d mean| " + fmt.format(*per_episode(means, means_ref, batched)))

        with jax.enable_x64(True):
            ll_ref, means_ref = summary("jaxtrack", run64(jt_factory))
            for name, factory in peers:
                ll, means = summary(name, run64(factory))
                lines.append(line(f"vs {name}, float64", ll, means, ll_ref, means_ref))
                if name == "dynamax":
                    with _dynamax_without_jitter():
                        ll, means = summary(name, run64(factory))
                    lines.append(line("vs dynamax, float64, psd_solve boost 0", ll, means,
                                      ll_ref, means_ref))
        ll32_ref, m32_ref = summary("jaxtrack", outputs[(case, N, "jaxtrack")])
        for name, _ in peers:
            ll32, m32 = summary(name, outputs[(case, N, name)])
            lines.append(line(f"vs {name}, float32 (the timed run)", ll32, m32, ll32_ref,
                              m32_ref))
        # numpy libraries: episode 0, all steps, float64.
        means_ref0 = np.asarray(means_ref)[0] if batched else np.asarray(means_ref)
        if case == "KF":
            fp_means = filterpy_kf(prob, 1)[0][0]
            ss_means = stonesoup_kf(prob, args.steps)[0]
        else:
            fp_means = filterpy_ukf(prob, 1, scheme)[0][0]
            ss_means = stonesoup_ukf(prob, args.steps, scheme)[0]
        lines.append(f"  {case:<4} {'vs filterpy, float64, episode 0':<40} |d mean| "
                     f"{max_abs(fp_means, means_ref0):.1e}")
        lines.append(f"  {case:<4} {'vs stonesoup, float64, episode 0':<40} |d mean| "
                     f"{max_abs(ss_means, means_ref0):.1e}")
    lines.append(f"  |d| is the max over steps (and state components) within an episode; max and "
                 f"median over the {N} episodes.")
    return lines


def parse_args(argv=None):
    ap = _common.parser(__doc__, timing=True, single_core=True, agreement=True)
    ap.sized("--episodes", 1000, 8, "batched N")
    ap.sized("--steps", 200, 20, "T")
    ap.sized("--python-episodes", 20, 2, "episodes timed for filterpy when N > 1")
    ap.add_argument("--stonesoup-steps", type=int, default=None,
                    help="cap on steps timed for Stone Soup (default: T)")
    ap.add_argument("--alpha", type=float, default=1.0, help="Merwe alpha for every UKF")
    ap.add_argument("--beta", type=float, default=2.0, help="Merwe beta for every UKF")
    ap.add_argument("--kappa", type=float, default=0.0, help="Merwe kappa for every UKF")
    return ap.parse_args(argv)


def main(argv=None):
    return _common.report(run, parse_args(argv))


def run(args):
    _common.setup_jax()
    scheme = (args.alpha, args.beta, args.kappa)
    header = _common.header(
        PACKAGES, f"problem: N = 1 and {args.episodes} episodes x T = {args.steps} steps; "
        f"UKF Merwe points alpha={args.alpha}, beta={args.beta}, kappa={args.kappa}",
        threads=THREAD_ENV)
    print("\n".join(header), flush=True)

    kf_problem = with_derived_kf(cv_problem(args.episodes, args.steps, seed=args.seed))
    ct_prob = with_derived_ukf(ct_problem(args.episodes, args.steps, seed=1 + args.seed),
                               scheme)
    ss_steps = args.stonesoup_steps

    rows, outputs = [], {}
    run_case("KF", kf_problem,
             [("jaxtrack", jaxtrack_kf), ("dynamax", dynamax_kf), ("cuthbert", cuthbert_kf),
              ("cuthbertlib", cuthbertlib_kf)],
             [("filterpy", lambda p, e, t: filterpy_kf(take_steps(p, t), e), False, None),
              ("stonesoup", lambda p, e, t: stonesoup_kf(p, t), True, ss_steps)],
             args, rows, outputs)
    run_case("UKF", ct_prob,
             [("jaxtrack", lambda: jaxtrack_ukf(scheme)),
              ("dynamax", lambda: dynamax_ukf(scheme))],
             [("filterpy", lambda p, e, t: filterpy_ukf(take_steps(p, t), e, scheme), False,
               None),
              ("stonesoup", lambda p, e, t: stonesoup_ukf(p, t, scheme), True, ss_steps)],
             args, rows, outputs)

    header.append(_common.load_line("end"))
    print("\n" + "\n".join(header))
    print()
    print(_common.table(["case", "library", "N", "T"], rows))
    print("\nus/ep-step = wall time per call / (episodes x steps timed); vs jaxtrack = peer / "
          "jaxtrack (> 1: jaxtrack faster).\nJAX libraries: float32, N = 1 jit(filter), N > 1 "
          "jit(vmap(filter)); cuthbert = cuthbert.filter (sequential scan of its associative "
          "square-root element); cuthbertlib = its square-root predict/update in a lax.scan.\n"
          "filterpy / Stone Soup: float64 numpy, Python loop, no log-likelihood.")
    print(f"\nSmall dense linear algebra (jaxtrack.filters._linalg), batch of {args.episodes}:")
    print(linalg_table(args))
    if not args.no_check:
        print("\nAgreement (jaxtrack vs peers, same data):")
        print("\n".join(agreement(kf_problem, ct_prob, scheme, outputs, args)))
    return rows


if __name__ == "__main__":
    main()
