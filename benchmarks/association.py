"""Multi-target association scans side by side: jaxtrack (GNN, JPDA-LBP, JPDA-exact) vs Stone Soup.

One *scan* is the whole per-frame pipeline of a multi-target filter with known tracks: predict
every track (constant velocity), gate (chi-square), associate, update. Each library runs it over
T scans of the same simulated episodes, with the same models, noise, gate and clutter model.

Scenario (identical for everyone; numpy float64, fixed seed per K):
- K = 5, 10, 20 targets, constant velocity ([p_x, p_y, v_x, v_y], dt = 0.1 s, acceleration
  spectral density q = 0.5 m^2/s^3); initial positions uniform in a square of side ``--area``
  (default 15 m: 20 targets in 15 m x 15 m, a crowded hall), initial velocities N(0, 0.7^2)
  per axis (m/s).
- 2-D position measurements with noise std 0.2 m per axis; each target detected with
  probability 0.9; Poisson clutter with mean 10 per scan, uniform over the square (clutter
  density lambda = 10 / area^2). Detections are shuffled; the frames are padded to a fixed
  capacity M = the largest count in the data, with a mask.
- Every track starts from the true state plus N(0, P0), P0 = diag(0.2^2, 0.2^2, 0.5^2, 0.5^2).
- Gate: chi-square, P_G = 0.99 (d^2 <= 9.21) for everyone.
- JPDA model: Stone Soup's ``PDAHypothesiser`` (P_D = 0.9, P_G = 0.99, clutter_spatial_density =
  lambda) weighs a detection P_D N(z; H x, S) / lambda and a miss 1 - P_D P_G (Bar-Shalom, Daum
  and Huang 2009). jaxtrack's `jpda_marginals` weighs them p N / lambda' and 1 - p; it is given
  p = P_D P_G and lambda' = lambda P_G, which makes every weight ratio, hence every marginal,
  the same.
- GNN cost: squared Mahalanobis distance d^2 inside the gate, leaving a track unassigned costs
  the gate threshold (Stone Soup: ``DistanceHypothesiser(measure=SquaredMahalanobis(),
  missed_distance=9.21)`` + ``GNNWith2DAssignment``; jaxtrack: ``gnn(d2, gated,
  unassigned_cost=9.21)``: the same assignment problem).

Contenders (one row each):
- jaxtrack: ``jit(vmap(episode))`` over ``--episodes`` (default 100) episodes, float32, where
  ``episode`` is a ``lax.scan`` over T scans of predict -> ``association.innovations`` ->
  ``gate`` -> (``gnn`` + ``nn_update``) or (``jpda_marginals(method="lbp" | "exact",
  log=True)`` + ``jpda_update``). The exact method enumerates each gated cluster of up to
  ``max_cluster_tracks`` = 8 tracks (closed forms for 1- and 2-track clusters, a DP over the
  cluster's own detections for larger ones); tracks of larger
  clusters fall back to LBP, which the cluster report counts. The LBP rows use ``lbp_tol``
  ``--lbp-tol`` (default 1e-5 on the log-messages; Stone Soup's JPDAwithLBP stops at its 0.1%
  error bound; 1e-5 is also the library default ``lbp_tol="auto"`` in float32). One extra
  jaxtrack row (not compared with Stone Soup): exact with ``max_cluster_tracks`` 4 (clusters
  of 5 or more tracks then take LBP).
- Stone Soup (float64 numpy, Python loop, one episode): ``GNNWith2DAssignment``,
  ``JPDAwithLBP``, ``JPDAwithEHM`` (exact, per cluster) and ``JPDA`` (brute-force enumeration of
  all joint events, no clustering) with ``KalmanPredictor`` / ``KalmanUpdater`` (GNN) or
  ``PDAUpdater`` (JPDA). Brute-force JPDA at K = 20 enumerates ~2^20 joint events per scan: it
  is timed on one scan, once (skipped when the bound on joint events exceeds
  ``--brute-force-max``), and says so in the notes.

Units: microseconds per scan per episode = call time / (episodes x scans). "SS / jaxtrack" =
Stone Soup time / jaxtrack time of the same method (GNN vs GNN, LBP vs LBP, EHM and brute-force
JPDA vs jaxtrack exact). Timing as in `filters.py` (`_common.time_interleaved`): warm-up call
(its extra time = "first call s", tracing + compilation), then interleaved repeats of every
contender of one K, median of the clean repeats (process CPU time >= 0.9 x wall time).

Agreement (float64): on every scan of episode 0, Stone Soup's track states before the scan are
given to jaxtrack, and jaxtrack's marginals are compared with Stone Soup's probabilities for the
same tracks and detections (max abs difference over all track x (detection + miss) entries),
GNN assignments are compared (scans with any difference), and the whole-episode posterior means
of both libraries are compared (each running its own recursion on the same detections).

Usage:
    python benchmarks/association.py            # full run (20-30 min on a loaded 2-core VM)
    python benchmarks/association.py --quick    # smoke test (8 episodes x 5 scans)
    python benchmarks/association.py --targets 10 --episodes 50 --steps 10

Single core: as `filters.py` (thread variables before jax is imported; the process pins itself
to one CPU, by default the last one it may use; ``--cpu N`` picks core N, ``--no-pin`` none).
"""

from __future__ import annotations

import _common

THREAD_ENV = _common.single_core_from_argv()

import dataclasses  # noqa: E402
import datetime  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxtrack import association  # noqa: E402
from jaxtrack.filters.kalman import Gaussian  # noqa: E402
from jaxtrack.models import measurement, motion  # noqa: E402

PACKAGES = ["jaxtrack", "jax", "jaxlib", "numpy", "scipy", "optax", "stonesoup"]

DT = 0.1              # s
Q_ACCEL = 0.5         # m^2/s^3, CV acceleration spectral density
SIGMA = 0.2           # m, position noise std per axis
P_DETECT = 0.9
GATE_PROB = 0.99
CLUTTER_MEAN = 10.0   # false detections per scan
SPEED_STD = 0.7       # m/s, initial velocity std per axis
P0_DIAG = (SIGMA**2, SIGMA**2, 0.5**2, 0.5**2)
MAX_CLUSTER_TRACKS = 8
LBP_MAX_ITER = 200
GATE_D2 = float(-2.0 * math.log1p(-GATE_PROB))    # chi-square(2) quantile, 9.2103
PERM = [0, 2, 1, 3]   # jaxtrack [x, y, vx, vy] <-> Stone Soup [x, vx, y, vy] (self-inverse)

SS_MATCH = {"GNNWith2DAssignment": "gnn", "JPDAwithLBP": "lbp", "JPDAwithEHM": "exact",
            "JPDA (brute force)": "exact"}


# ---------------------------------------------------------------------------------------------
# Scenario


@dataclasses.dataclass
class Scenario:
    K: int
    area: float
    F: np.ndarray          # [4, 4]
    Q: np.ndarray          # [4, 4]
    m0: np.ndarray         # [E, K, 4] initial track means
    P0: np.ndarray         # [4, 4]
    zs: np.ndarray         # [E, T, M, 2], 0 in padded slots
    mask: np.ndarray       # [E, T, M]
    counts: np.ndarray     # [E, T] detections per scan (true + clutter)
    clutter: np.ndarray    # [E, T] clutter detections per scan

    @property
    def clutter_density(self):
        return CLUTTER_MEAN / self.area**2

    @property
    def shape(self):
        return self.zs.shape[:3]


def make_scenario(K, episodes, steps, area, seed):
    rng = np.random.default_rng(seed)
    with jax.enable_x64(True):
        F, Q = (np.asarray(a, np.float64) for a in motion.constant_velocity(DT, Q_ACCEL))
    P0 = np.diag(P0_DIAG)
    x = np.concatenate([rng.uniform(0.0, area, (episodes, K, 2)),
                        rng.normal(0.0, SPEED_STD, (episodes, K, 2))], -1)
    m0 = x + rng.standard_normal((episodes, K, 4)) @ np.linalg.cholesky(P0).T
    LQ = np.linalg.cholesky(Q)
    frames = np.empty((episodes, steps), object)
    clutter = np.zeros((episodes, steps), np.int64)
    for t in range(steps):
        x = x @ F.T + rng.standard_normal((episodes, K, 4)) @ LQ.T
        for e in range(episodes):
            seen = rng.random(K) < P_DETECT
            z = x[e, seen, :2] + SIGMA * rng.standard_normal((int(seen.sum()), 2))
            n_c = rng.poisson(CLUTTER_MEAN)
            c = rng.uniform(0.0, area, (n_c, 2))
            allz = np.concatenate([z, c])
            frames[e, t] = allz[rng.permutation(len(allz))]
            clutter[e, t] = n_c
    counts = np.vectorize(len)(frames)
    M = int(counts.max())
    zs = np.zeros((episodes, steps, M, 2))
    mask = np.zeros((episodes, steps, M), bool)
    for e in range(episodes):
        for t in range(steps):
            n = counts[e, t]
            zs[e, t, :n], mask[e, t, :n] = frames[e, t], True
    return Scenario(K, area, F, Q, m0, P0, zs, mask, counts, clutter)


# ---------------------------------------------------------------------------------------------
# jaxtrack


def jaxtrack_scan(method, clutter_density, *, lbp_tol=1e-5, max_cluster_tracks=MAX_CLUSTER_TRACKS,
                  info=False):
    """``scan(m, P, zs, mask, F, Q) -> (posterior Gaussian, extra)``: predict + gate + associate
    + update of K tracks (previous posteriors ``m`` [K, 4], ``P`` [K, 4, 4]) with one frame."""
    lam = clutter_density

    def scan(m, P, z, msk, F, Q):
        dtype = m.dtype
        H = measurement.position(4, dtype=dtype)
        R = jnp.asarray(SIGMA**2, dtype) * jnp.eye(2, dtype=dtype)
        m, P = m @ F.T, F @ P @ F.T + Q
        P = 0.5 * (P + jnp.swapaxes(P, -1, -2))
        return associate_update(method, Gaussian(m, P), z, msk, H, R, lam, lbp_tol,
                                max_cluster_tracks, info)

    return scan


def associate_update(method, pred, z, msk, H, R, lam, lbp_tol, max_cluster_tracks, info):
    """Gate, associate and update predicted tracks ``pred``; returns (posterior, extra)."""
    inn = association.innovations(pred.mean, pred.cov, z, H, R, meas_mask=msk)
    gated = association.gate(inn.d2, 2, GATE_PROB, meas_mask=msk)
    if method == "gnn":
        col = association.gnn(inn.d2, gated, unassigned_cost=GATE_D2, meas_mask=msk)
        post, _ = association.nn_update(pred, z, col, H, R)
        return post, col
    g = jnp.where(gated, inn.log_likelihood, -jnp.inf)
    beta, jinfo = association.jpda_marginals(
        g, P_DETECT * GATE_PROB, lam * GATE_PROB, meas_mask=msk, method=method, log=True,
        max_cluster_tracks=max_cluster_tracks, lbp_tol=lbp_tol, lbp_max_iter=LBP_MAX_ITER,
        return_info=True)
    post = association.jpda_update(pred, z, beta, H, R, meas_mask=msk)
    if info:
        return post, (beta, jinfo.cluster_size, jinfo.approximate, jinfo.lbp_iterations)
    return post, None


def jaxtrack_episode(method, clutter_density, **kw):
    """``episode(m0, P0, zs, mask, F, Q)``: T scans; returns the posterior means and covariances
    of every scan ([T, K, 4], [T, K, 4, 4]) and, with ``info``, per-scan diagnostics."""
    scan = jaxtrack_scan(method, clutter_density, **kw)

    def episode(m0, P0, zs, mask, F, Q):
        P0 = jnp.broadcast_to(P0, m0.shape + m0.shape[-1:])

        def body(carry, inp):
            post, extra = scan(*carry, *inp, F, Q)
            return (post.mean, post.cov), (post.mean, post.cov, extra)

        _, out = jax.lax.scan(body, (m0, P0), (zs, mask))
        return out

    return episode


def jaxtrack_batched(method, scn, dtype, **kw):
    """(jitted vmapped episode function, its arguments) for all episodes of ``scn``."""
    fn = jax.jit(jax.vmap(jaxtrack_episode(method, scn.clutter_density, **kw),
                          in_axes=(0, None, 0, 0, None, None)))
    args = (jnp.asarray(scn.m0, dtype), jnp.asarray(scn.P0, dtype), jnp.asarray(scn.zs, dtype),
            jnp.asarray(scn.mask), jnp.asarray(scn.F, dtype), jnp.asarray(scn.Q, dtype))
    return fn, args


# ---------------------------------------------------------------------------------------------
# Stone Soup


def stonesoup_parts(method, clutter_density):
    """(associator, updater, sensor model) of one Stone Soup method."""
    from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
    from stonesoup.dataassociator.probability import JPDA, JPDAwithEHM, JPDAwithLBP
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.hypothesiser.probability import PDAHypothesiser
    from stonesoup.measures import SquaredMahalanobis
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import (CombinedLinearGaussianTransitionModel,
                                                    ConstantVelocity)
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.updater.kalman import KalmanUpdater
    from stonesoup.updater.probability import PDAUpdater

    transition = CombinedLinearGaussianTransitionModel([ConstantVelocity(Q_ACCEL),
                                                        ConstantVelocity(Q_ACCEL)])
    sensor = LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=SIGMA**2 * np.eye(2))
    predictor = KalmanPredictor(transition)
    if method == "GNNWith2DAssignment":
        updater = KalmanUpdater(sensor)
        hyp = DistanceHypothesiser(predictor, updater, measure=SquaredMahalanobis(),
                                   missed_distance=GATE_D2)
        return GNNWith2DAssignment(hyp), updater, sensor
    updater = PDAUpdater(sensor)
    hyp = PDAHypothesiser(predictor, updater, clutter_spatial_density=clutter_density,
                          prob_detect=P_DETECT, prob_gate=GATE_PROB)
    cls = {"JPDAwithLBP": JPDAwithLBP, "JPDAwithEHM": JPDAwithEHM,
           "JPDA (brute force)": JPDA}[method]
    return cls(hyp), updater, sensor


def stonesoup_inputs(scn, episode, steps, sensor):
    """Detections of one episode as Stone Soup objects (built once, outside the timing)."""
    from stonesoup.types.detection import Detection

    start = datetime.datetime(2025, 1, 1)
    times = [start + datetime.timedelta(seconds=DT * (t + 1)) for t in range(steps)]
    dets = []
    for t in range(steps):
        n = int(scn.counts[episode, t])
        dets.append([Detection(scn.zs[episode, t, j].reshape(2, 1), timestamp=times[t],
                               measurement_model=sensor) for j in range(n)])
    return start, times, dets


def stonesoup_episode(method, parts, scn, episode, inputs, steps, record=None):
    """Run one episode (``steps`` scans); returns posterior means [steps, K, 4] (jaxtrack order).

    With ``record`` (a list), appends per scan: (prior means [K, 4], prior covs [K, 4, 4]) in
    jaxtrack order, and the association: GNN [K] detection index (-1 none); JPDA [K, M + 1]
    probabilities (last column: missed).
    """
    from stonesoup.types.state import GaussianState
    from stonesoup.types.track import Track

    associator, updater, _ = parts
    start, times, dets = inputs
    K = scn.K
    P0 = scn.P0[np.ix_(PERM, PERM)]
    tracks = [Track([GaussianState(scn.m0[episode, k][PERM].reshape(4, 1), P0, timestamp=start)])
              for k in range(K)]
    gnn = method == "GNNWith2DAssignment"
    means = np.empty((steps, K, 4))
    for t in range(steps):
        if record is not None:
            prior = (np.stack([np.asarray(tr.state_vector, np.float64)[PERM, 0] for tr in tracks]),
                     np.stack([np.asarray(tr.covar, np.float64)[np.ix_(PERM, PERM)]
                               for tr in tracks]))
        frame = dets[t]
        hyps = associator.associate(tracks, set(frame), times[t])
        for k, track in enumerate(tracks):
            hyp = hyps[track]
            if gnn:
                track.append(updater.update(hyp) if hyp else hyp.prediction)
            else:
                track.append(updater.update(hyp))
            means[t, k] = np.asarray(track.state_vector, np.float64)[PERM, 0]
        if record is not None:
            index = {id(d): j for j, d in enumerate(frame)}
            if gnn:
                assoc = np.array([index[id(hyps[tr].measurement)] if hyps[tr] else -1
                                  for tr in tracks])
            else:
                assoc = np.zeros((K, len(frame) + 1))
                for k, tr in enumerate(tracks):
                    for h in hyps[tr]:
                        j = index[id(h.measurement)] if h else len(frame)
                        assoc[k, j] += float(h.probability)
            record.append((prior, assoc))
    return means


def joint_event_bound(scn, episode, t):
    """prod_k (1 + detections in track k's gate) at scan t of one episode, from the initial
    tracks predicted t + 1 steps without updates (an upper bound for scan 0 exactly): the number
    of combinations brute-force JPDA iterates over."""
    with jax.enable_x64(True):
        F, Q = jnp.asarray(scn.F), jnp.asarray(scn.Q)
        m, P = jnp.asarray(scn.m0[episode]), jnp.broadcast_to(jnp.asarray(scn.P0), (scn.K, 4, 4))
        for _ in range(t + 1):
            m, P = m @ F.T, F @ P @ F.T + Q
        msk = jnp.asarray(scn.mask[episode, t])
        inn = association.innovations(m, P, jnp.asarray(scn.zs[episode, t]),
                                      measurement.position(4, dtype=jnp.float64),
                                      SIGMA**2 * jnp.eye(2), meas_mask=msk)
        n_gated = np.asarray(association.gate(inn.d2, 2, GATE_PROB, meas_mask=msk).sum(1))
    return float(np.prod(1.0 + n_gated))


# ---------------------------------------------------------------------------------------------
# Timing and tables


def time_once(fn, *args):
    """A single call (for the slowest contender): wall and CPU time, one repeat."""
    c0, t0 = time.process_time(), time.perf_counter()
    out = _common.block(fn(*args))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    clean = int(cpu >= _common.CLEAN_CPU_PER_WALL * wall)
    return _common.Timing(wall, cpu, 1, clean, 1, None, cpu / wall, 0.0), out


def jaxtrack_variants(args):
    """(label, method, kwargs, primary, note) of the jaxtrack rows."""
    out = [("GNN", "gnn", {}, True, "gnn(d2, unassigned_cost) + nn_update"),
           ("JPDA-LBP", "lbp", dict(lbp_tol=args.lbp_tol), True,
            f"lbp_tol {args.lbp_tol:g}"),
           ("JPDA-exact", "exact", dict(lbp_tol=args.lbp_tol), True,
            f"max_cluster_tracks {MAX_CLUSTER_TRACKS}")]
    if not args.no_variants:
        out.append(("JPDA-exact", "exact", dict(lbp_tol=args.lbp_tol, max_cluster_tracks=4),
                    False, "max_cluster_tracks 4 (larger clusters: LBP)"))
    return out


def run_k(K, scn, args, rows, store):
    """Time every contender at ``K`` targets; appends their rows to ``rows`` and returns the
    line of Stone Soup / jaxtrack ratios."""
    E, T, M = scn.shape
    print(f"\n[K = {K}: {E} episodes x {T} scans, capacity M = {M}] ...", flush=True)
    calls, meta = {}, {}
    for label, method, kw, primary, note in jaxtrack_variants(args):
        name = f"jaxtrack {label}" + ("" if primary else f", {note}")
        fn, fargs = jaxtrack_batched(method, scn, jnp.float32, **kw)
        calls[name] = (fn, fargs)
        meta[name] = (method, label, E, T, f"f32, jit(vmap); {note}", primary)
    ss_steps = min(T, args.stonesoup_steps or T)
    brute = None
    for method in ("GNNWith2DAssignment", "JPDAwithLBP", "JPDAwithEHM", "JPDA (brute force)"):
        parts = stonesoup_parts(method, scn.clutter_density)
        steps = ss_steps
        note = "f64 numpy, Python loop, episode 0"
        if method == "JPDA (brute force)":
            bound = joint_event_bound(scn, 0, 0)
            if K > args.brute_force_full:
                if args.no_brute_force or bound > args.brute_force_max:
                    print(f"  JPDA (brute force) skipped: {bound:.3g} joint-event combinations "
                          f"at scan 0 (> {args.brute_force_max:.3g})", flush=True)
                    store[(K, "brute_skipped")] = bound
                    continue
                steps = 1
                note += f", 1 scan timed once ({bound:.3g} combinations)"
                brute = (method, parts, steps, note)
                continue
        inputs = stonesoup_inputs(scn, 0, steps, parts[2])
        name = f"stonesoup {method}"
        calls[name] = (stonesoup_episode, (method, parts, scn, 0, inputs, steps))
        meta[name] = (SS_MATCH[method], method, 1, steps, note
                      + (f", {steps} of {T} scans" if steps < T else ""), False)
    results = _common.time_interleaved(
        calls, repeats=args.repeats, min_repeat_s=args.min_repeat_s,
        compiled=[n for n in calls if n.startswith("jaxtrack")])
    if brute is not None:
        method, parts, steps, note = brute
        inputs = stonesoup_inputs(scn, 0, steps, parts[2])
        print(f"  stonesoup {method}: one scan, once ...", flush=True)
        record = []
        results[f"stonesoup {method}"] = time_once(
            stonesoup_episode, method, parts, scn, 0, inputs, steps, record)
        store[(K, "brute_record")] = (results[f"stonesoup {method}"][1], record)
        meta[f"stonesoup {method}"] = (SS_MATCH[method], method, 1, steps, note, False)
    references, pairs = {}, []
    for name, (timing, out) in results.items():
        method, variant, episodes, scans, note, primary = meta[name]
        library = name.split()[0]
        row = _common.timing_row((K, variant, library, episodes, scans), timing, episodes,
                                 scans, unit="scan/ep", note=note)
        store[(K, name)] = out
        _common.progress(name, row, timing)
        if library == "jaxtrack" and primary:
            references[method] = row
        elif library == "stonesoup" and method in references:
            row = row.vs(references[method])
            pairs.append(f"{variant} / jaxtrack {references[method].label[1]} = "
                         f"{row.ratio:.0f}x")
        rows.append(row)
    return f"  K = {K:>2}: " + "; ".join(pairs)


# ---------------------------------------------------------------------------------------------
# Diagnostics: clusters, LBP iterations, stage breakdown


def cluster_report(scn, args):
    """Cluster sizes of the exact method over every scan of every episode (float32 run)."""
    fn, fargs = jaxtrack_batched("exact", scn, jnp.float32, lbp_tol=args.lbp_tol, info=True)
    _, _, (_, size, approx, _) = fn(*fargs)
    size, approx = np.asarray(size), np.asarray(approx)      # [E, T, K]
    largest = size.max(-1)
    n_scans = largest.size
    hist = np.bincount(largest.ravel(), minlength=MAX_CLUSTER_TRACKS + 2)
    if scn.K <= MAX_CLUSTER_TRACKS:
        return (f"  K = {scn.K:>2}: K <= {MAX_CLUSTER_TRACKS}: evaluated cluster by cluster "
                f"as well (the DP over all {scn.K} tracks only gives derivatives)")
    multi = float(np.mean(largest >= 2))
    over = int(np.sum(largest > MAX_CLUSTER_TRACKS))
    shown = ", ".join(f"{s}: {hist[s]}" for s in range(1, len(hist)) if hist[s])
    return (f"  K = {scn.K:>2}: largest cluster per scan (tracks: scans) {shown}; max "
            f"{largest.max()}; {100 * multi:.0f}% of scans have a multi-track cluster; "
            f"{over} of {n_scans} scans have a cluster over the cap of {MAX_CLUSTER_TRACKS} "
            f"({int(approx.sum())} track-scans fell back to LBP); "
            f"{int(np.sum(largest > 4))} scans over a cap of 4")


def lbp_report(scn, tol):
    fn, fargs = jaxtrack_batched("lbp", scn, jnp.float32, lbp_tol=tol, info=True)
    _, _, (_, _, _, iters) = fn(*fargs)
    it = np.asarray(iters)                                   # [E, T]
    per_scan_max = it.max(0)                                  # what vmap pays per scan
    return (f"  K = {scn.K:>2}, lbp_tol {tol:g}: iterations per episode-scan mean "
            f"{it.mean():.1f}, median {np.median(it):.0f}, max {it.max()} "
            f"(cap {LBP_MAX_ITER}); under vmap each scan runs the batch max: mean "
            f"{per_scan_max.mean():.1f}")


def stage_breakdown(scn, args):
    """Time each stage of one scan (scan 0, all episodes, vmapped, float32)."""
    dtype = jnp.float32
    E = scn.shape[0]
    F, Q = jnp.asarray(scn.F, dtype), jnp.asarray(scn.Q, dtype)
    m = jnp.asarray(scn.m0, dtype) @ F.T
    P = F @ jnp.asarray(scn.P0, dtype) @ F.T + Q
    P = jnp.broadcast_to(P, m.shape + (4,))
    z, msk = jnp.asarray(scn.zs[:, 0], dtype), jnp.asarray(scn.mask[:, 0])
    H = measurement.position(4, dtype=dtype)
    R = jnp.asarray(SIGMA**2, dtype) * jnp.eye(2, dtype=dtype)
    lam = scn.clutter_density

    def inn_gate(m, P, z, k):
        inn = association.innovations(m, P, z, H, R, meas_mask=k)
        return inn, association.gate(inn.d2, 2, GATE_PROB, meas_mask=k)

    def marg(method, tol, cap=MAX_CLUSTER_TRACKS):
        def f(inn, gated, k):
            g = jnp.where(gated, inn.log_likelihood, -jnp.inf)
            return association.jpda_marginals(g, P_DETECT * GATE_PROB, lam * GATE_PROB,
                                              meas_mask=k, method=method, log=True,
                                              max_cluster_tracks=cap, lbp_tol=tol,
                                              lbp_max_iter=LBP_MAX_ITER)
        return jax.jit(jax.vmap(f))

    v = lambda f: jax.jit(jax.vmap(f))  # noqa: E731
    inn, gated = v(inn_gate)(m, P, z, msk)
    beta = marg("exact", args.lbp_tol)(inn, gated, msk)
    col = v(lambda d2, gt, k: association.gnn(d2, gt, unassigned_cost=GATE_D2,
                                              meas_mask=k))(inn.d2, gated, msk)
    calls = {
        "predict (K Kalman predictions)": (v(lambda m, P: (m @ F.T, F @ P @ F.T + Q)), (m, P)),
        "innovations + gate": (v(inn_gate), (m, P, z, msk)),
        "gnn (Hungarian, unassigned_cost)": (v(lambda d2, gt, k: association.gnn(
            d2, gt, unassigned_cost=GATE_D2, meas_mask=k)), (inn.d2, gated, msk)),
        "nn_update": (v(lambda m, P, z, c: association.nn_update(Gaussian(m, P), z, c, H, R)),
                      (m, P, z, col)),
        f"jpda_marginals lbp, tol {args.lbp_tol:g}": (marg("lbp", args.lbp_tol),
                                                      (inn, gated, msk)),
        "jpda_marginals exact, cap 8": (marg("exact", args.lbp_tol), (inn, gated, msk)),
        "jpda_marginals exact, cap 4": (marg("exact", args.lbp_tol, 4), (inn, gated, msk)),
        "jpda_update": (v(lambda m, P, z, b, k: association.jpda_update(
            Gaussian(m, P), z, b, H, R, meas_mask=k)), (m, P, z, beta, msk)),
    }
    res = _common.time_interleaved(calls, repeats=args.repeats, min_repeat_s=args.min_repeat_s)
    rows = [[name, _common.fmt_float(1e6 * t.seconds / E), _common.fmt_float(1e6 * t.cpu_seconds
                                                                              / E)]
            for name, (t, _) in res.items()]
    return _common.format_table(["stage (one scan, jit(vmap) over episodes, f32)", "us/ep",
                                 "cpu us/ep"], rows)


# ---------------------------------------------------------------------------------------------
# Agreement


def jaxtrack_on_record(method, scn, t, prior, lbp_tol):
    """jaxtrack's association (float64) of scan ``t`` of episode 0 from Stone Soup's track
    states before that scan: GNN [K] detection index, JPDA [K, n_t + 1] marginals."""
    H = measurement.position(4, dtype=jnp.float64)
    R = SIGMA**2 * jnp.eye(2)
    F, Q = jnp.asarray(scn.F), jnp.asarray(scn.Q)
    pm, pP = (jnp.asarray(a) for a in prior)
    pred_P = F @ pP @ F.T + Q
    pred = Gaussian(pm @ F.T, 0.5 * (pred_P + jnp.swapaxes(pred_P, -1, -2)))
    _, extra = associate_update(method, pred, jnp.asarray(scn.zs[0, t]),
                                jnp.asarray(scn.mask[0, t]), H, R, scn.clutter_density, lbp_tol,
                                MAX_CLUSTER_TRACKS, info=True)
    if method == "gnn":
        return np.asarray(extra)
    beta = np.asarray(extra[0])
    nt, M = int(scn.counts[0, t]), scn.shape[2]
    return np.concatenate([beta[:, :nt], beta[:, M:]], 1)


def agreement(scenarios, store, args):
    """jaxtrack (float64) vs Stone Soup on the same tracks and detections (module docstring)."""
    lines = []
    with jax.enable_x64(True):
        for K, scn in scenarios.items():
            T = scn.shape[1]
            steps = min(T, args.stonesoup_steps or T)
            jt_means = {}
            for method in ("gnn", "lbp", "exact"):
                fn = jax.jit(jaxtrack_episode(method, scn.clutter_density,
                                              lbp_tol=args.lbp_tol))
                jt_means[method] = np.asarray(fn(
                    jnp.asarray(scn.m0[0]), jnp.asarray(scn.P0), jnp.asarray(scn.zs[0]),
                    jnp.asarray(scn.mask[0]), jnp.asarray(scn.F), jnp.asarray(scn.Q))[0])
            for ss_method in ("GNNWith2DAssignment", "JPDAwithLBP", "JPDAwithEHM",
                              "JPDA (brute force)"):
                jt_method = SS_MATCH[ss_method]
                head = f"  K = {K:>2} {ss_method:<20} vs jaxtrack {jt_method:<5}"
                if ss_method == "JPDA (brute force)" and (K, "brute_skipped") in store:
                    lines.append(f"{head} skipped (not run)")
                    continue
                if ss_method == "JPDA (brute force)" and (K, "brute_record") in store:
                    ss_means, record = store[(K, "brute_record")]
                else:
                    parts = stonesoup_parts(ss_method, scn.clutter_density)
                    record = []
                    ss_means = stonesoup_episode(ss_method, parts, scn, 0,
                                                 stonesoup_inputs(scn, 0, steps, parts[2]),
                                                 steps, record)
                n = len(record)
                d_mean = np.max(np.abs(ss_means - jt_means[jt_method][:n]))
                if jt_method == "gnn":
                    bad = sum(int(np.any(jaxtrack_on_record("gnn", scn, t, prior, None) != a))
                              for t, (prior, a) in enumerate(record))
                    lines.append(f"{head} assignments differ in {bad} of {n} scans; episode "
                                 f"posterior means |d| max {d_mean:.1e}")
                    continue
                tol = 1e-12 if jt_method == "lbp" else args.lbp_tol
                diffs = [np.max(np.abs(jaxtrack_on_record(jt_method, scn, t, prior, tol) - a))
                         for t, (prior, a) in enumerate(record)]
                lines.append(f"{head} marginals |d| max {max(diffs):.1e} (median over scans "
                             f"{np.median(diffs):.1e}, {n} scans); episode posterior means "
                             f"|d| max {d_mean:.1e}")
                if jt_method == "lbp":
                    d_exact = [np.max(np.abs(jaxtrack_on_record("exact", scn, t, prior,
                                                                args.lbp_tol) - a))
                               for t, (prior, a) in enumerate(record)]
                    lines.append(f"  K = {K:>2} {ss_method:<20} vs jaxtrack exact marginals "
                                 f"|d| max {max(d_exact):.1e} (median {np.median(d_exact):.1e})"
                                 f": the LBP approximation itself")
    lines.append("  marginals: max abs difference over tracks x (detections + missed) of one "
                 "scan, given the same track states (Stone Soup's, before the scan); jaxtrack "
                 "LBP run to lbp_tol 1e-12 for this check.")
    lines.append("  episode posterior means: each library runs its own recursion over the same "
                 "detections of episode 0 (jaxtrack float64, LBP at --lbp-tol).")
    return lines


# ---------------------------------------------------------------------------------------------


def parse_args(argv=None):
    ap = _common.parser(__doc__, timing=True, single_core=True, agreement=True)
    ap.add_argument("--targets", type=int, nargs="+", default=[5, 10, 20], help="K values")
    ap.sized("--episodes", 100, 8, "jaxtrack batch")
    ap.sized("--steps", 20, 5, "scans per episode T")
    ap.add_argument("--area", type=float, default=15.0,
                    help="side of the square the targets start in and clutter falls in (m)")
    ap.add_argument("--lbp-tol", type=float, default=1e-5,
                    help="jaxtrack lbp_tol of the primary LBP rows (log-message change)")
    ap.add_argument("--stonesoup-steps", type=int, default=None,
                    help="cap on scans timed for Stone Soup (default: T)")
    ap.add_argument("--brute-force-full", type=int, default=10,
                    help="largest K at which brute-force JPDA runs the whole episode; above, "
                         "one scan, once")
    ap.add_argument("--brute-force-max", type=float, default=4e6,
                    help="skip brute-force JPDA when scan 0 has more joint-event combinations")
    ap.add_argument("--no-brute-force", action="store_true",
                    help="skip brute-force JPDA above --brute-force-full (always with --quick)")
    ap.add_argument("--no-variants", action="store_true",
                    help="only the primary jaxtrack rows (no max_cluster_tracks 4 row)")
    ap.add_argument("--no-breakdown", action="store_true", help="skip the per-stage table")
    args = ap.parse_args(argv)
    args.no_brute_force = args.no_brute_force or args.quick
    return args


def main(argv=None):
    return _common.report(run, parse_args(argv))


def run(args):
    _common.setup_jax()
    header = _common.header(
        PACKAGES,
        f"scenario: K = {', '.join(map(str, args.targets))} CV targets starting uniformly in "
        f"{args.area:g} m x {args.area:g} m, dt {DT} s, q {Q_ACCEL}, position noise std "
        f"{SIGMA} m, P_D {P_DETECT}, Poisson clutter mean {CLUTTER_MEAN:g}/scan "
        f"(lambda {CLUTTER_MEAN / args.area**2:.4f} /m^2), gate P_G {GATE_PROB} "
        f"(d2 <= {GATE_D2:.2f}); jaxtrack {args.episodes} episodes x T = {args.steps} scans",
        threads=THREAD_ENV)
    print("\n".join(header), flush=True)

    rows, store, scenarios = [], {}, {}
    ratios, clusters, lbp_lines = [], [], []
    for K in args.targets:
        scn = make_scenario(K, args.episodes, args.steps, args.area, seed=1000 + K + args.seed)
        scenarios[K] = scn
        ratios.append(run_k(K, scn, args, rows, store))
        clusters.append(cluster_report(scn, args))
        lbp_lines.append(lbp_report(scn, args.lbp_tol))
    header.append(_common.load_line("end"))

    breakdown = None
    if not args.no_breakdown:
        print("\n[stage breakdown] ...", flush=True)
        breakdown = stage_breakdown(scenarios[max(args.targets)], args)
    check = None
    if not args.no_check:
        print("\n[agreement] ...", flush=True)
        check = agreement(scenarios, store, args)

    print("\n" + "\n".join(header))
    for K, scn in scenarios.items():
        print(f"K = {K:>2}: detections per scan mean {scn.counts.mean():.1f} (clutter "
              f"{scn.clutter.mean():.1f}), capacity M = {scn.shape[2]}")
    print()
    print(_common.table(["K", "method", "library", "episodes", "scans"], rows,
                        ratio="SS / jaxtrack"))
    print("\nus/scan/ep = wall time per call / (episodes x scans timed); SS / jaxtrack = Stone "
          "Soup / jaxtrack of the same method (EHM and brute-force JPDA vs jaxtrack exact).")
    print("\nStone Soup / jaxtrack per scan per episode:")
    print("\n".join(ratios))
    print("\nClusters of the gating graph (jaxtrack exact, every scan of every episode):")
    print("\n".join(clusters))
    print("\nLBP iterations (jaxtrack, float32):")
    print("\n".join(lbp_lines))
    if breakdown is not None:
        print(f"\nWhere jaxtrack's time goes, K = {max(args.targets)}, scan 0:")
        print(breakdown)
    if check is not None:
        print("\nAgreement (float64, episode 0):")
        print("\n".join(check))
    return rows


if __name__ == "__main__":
    main()
