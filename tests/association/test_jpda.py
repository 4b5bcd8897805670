"""Tests for `jaxtrack.association.jpda` (JPDA marginals, exact and LBP; NN-JPDA).

References: brute-force enumeration of every feasible joint event (`references.py`), the
single-target PDA formula, Stone Soup 1.9.1's JPDA (with PDAHypothesiser) and its LBP
(`JPDAwithLBP._loopy_belief_propagation`).

Tolerances: exact vs brute force 1e-12 (float64); exact vs Stone Soup 1e-10; LBP vs exact on
forests 1e-9; LBP vs Stone Soup's LBP 1e-7 (their stopping rule differs); float32 vs float64
2e-5. LBP on dense graphs with cycles is approximate: the mean over problems of the max-abs
error is asserted <= 0.03 and its distribution reported (``JAXTRACK_REPORT_ERRORS=1``).
"""

from datetime import datetime, timedelta

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack import association
from jaxtrack.filters.kalman import Gaussian
from tests.association.references import brute_force_marginals, error_summary

CAP = 6                       # track and detection capacity of the random problems
N_RANDOM = 240


def _batched(method, **kw):
    return jax.jit(jax.vmap(lambda L, pd, lam, tm, mm: association.jpda_marginals(
        L, pd, lam, tm, mm, method=method, **kw)))


_exact = _batched("exact")
_lbp = _batched("lbp")
_clustered = jax.jit(jax.vmap(lambda L, pd, lam: association.jpda_marginals(
    L, pd, lam, max_cluster_tracks=4, return_info=True)))      # 12 x 12 problems
_nn_greedy = jax.jit(jax.vmap(association.nn_jpda))
_nn_optimal = jax.jit(jax.vmap(lambda b: association.nn_jpda(b, "optimal")))


def random_problems(seed, n, cap=CAP, sizes=range(1, CAP + 1), density=(0.3, 1.0)):
    """Padded problems: L [n, cap, cap] (garbage and NaN in masked slots), pD [n, cap],
    lambda [n, cap], masks, and the sizes (K, M) of each."""
    rng = np.random.default_rng(seed)
    sizes = np.asarray(list(sizes))
    K = rng.choice(sizes, n)
    M = rng.choice(sizes, n)
    dens = rng.uniform(*density, (n, 1, 1))
    L = rng.exponential(size=(n, cap, cap)) * (rng.uniform(size=(n, cap, cap)) < dens)
    track_mask = np.arange(cap)[None] < K[:, None]
    meas_mask = np.arange(cap)[None] < M[:, None]
    pair = track_mask[:, :, None] & meas_mask[:, None, :]
    L = np.where(pair, L, np.where(rng.uniform(size=L.shape) < 0.5, np.nan, 7.0))
    pd = rng.uniform(0.3, 0.99, (n, cap))
    lam = np.exp(rng.uniform(np.log(0.05), np.log(5.0), (n, cap)))
    return L, pd, lam, track_mask, meas_mask, K, M


def run_padded(fn, L, pd, lam, log=False):
    """One [k, m] problem through a batched [CAP, CAP] function (reuses its compilation)."""
    k, m = L.shape
    Lp = np.full((1, CAP, CAP), -np.inf if log else 0.0)
    Lp[0, :k, :m] = L
    pdp = np.full((1, CAP), 0.5)
    pdp[0, :k] = pd
    lamp = np.ones((1, CAP))
    lamp[0, :m] = lam
    tm, mm = np.arange(CAP)[None] < k, np.arange(CAP)[None] < m
    beta = np.asarray(fn(Lp, pdp, lamp, tm, mm))[0]
    return np.concatenate([beta[:k, :m], beta[:k, -1:]], 1)


def padded_reference(L, pd, lam, k, m):
    """Brute force on the present [k, m] block; masked tracks are 'missed' with certainty."""
    ref = np.zeros((L.shape[0], L.shape[1] + 1))
    ref[:, -1] = 1.0
    beta = brute_force_marginals(L[:k, :m], pd[:k], lam[:m])
    ref[:k, :m] = beta[:, :-1]
    ref[:k, -1] = beta[:, -1]
    return ref


# ---------------------------------------------------------------------------------------------
# Exact marginals


def test_exact_equals_brute_force_enumeration_up_to_6x6_and_rows_sum_to_one():
    L, pd, lam, tm, mm, K, M = random_problems(0, N_RANDOM)
    beta = np.asarray(_exact(L, pd, lam, tm, mm))
    assert np.all(np.isfinite(beta))
    for i in range(N_RANDOM):
        ref = padded_reference(L[i], pd[i], lam[i], K[i], M[i])
        np.testing.assert_allclose(beta[i], ref, atol=1e-12, err_msg=f"problem {i}")
    np.testing.assert_allclose(beta.sum(-1), 1.0, atol=1e-12)
    for i in range(N_RANDOM):
        assert np.all(beta[i, :, :CAP][:, ~mm[i]] == 0)          # masked detections
        assert np.all(beta[i, ~tm[i], -1] == 1)                   # masked tracks: missed


def test_empty_frames_give_missed_detection_everywhere():
    L, pd, lam, tm, mm, K, M = random_problems(13, 4)
    mm[:] = False                                    # a scan without detections
    tm[1] = False                                    # and one with no tracks either
    for fn in (_exact, _lbp):
        beta = np.asarray(fn(L, pd, lam, tm, mm))
        np.testing.assert_array_equal(beta[..., -1], 1.0)
        np.testing.assert_array_equal(beta[..., :-1], 0.0)
    assert association.jpda_marginals(np.zeros((0, 3)), 0.9, 1.0).shape == (0, 4)
    np.testing.assert_array_equal(np.asarray(association.jpda_marginals(np.zeros((2, 0)), 0.9,
                                                                        1.0)), 1.0)


def test_clustered_exact_equals_per_cluster_brute_force_beyond_the_cap():
    """12 tracks, clusters of <= 4 tracks, cap 4: clustering, gather and scatter are exact."""
    rng = np.random.default_rng(1)
    K = M = 12
    blocks = [(range(0, 4), range(0, 4)), (range(4, 7), range(4, 9)), (range(7, 9), []),
              (range(9, 12), range(9, 12))]
    problems, refs = [], []
    for _ in range(12):
        L = np.zeros((K, M))
        ref = np.zeros((K, M + 1))
        pd, lam = rng.uniform(0.5, 0.95, K), rng.uniform(0.1, 2.0, M)
        for tracks, dets in blocks:
            tracks, dets = list(tracks), list(dets)
            block = rng.exponential(size=(len(tracks), len(dets))) \
                * (rng.uniform(size=(len(tracks), len(dets))) < 0.7)
            L[np.ix_(tracks, dets)] = block
            b = brute_force_marginals(block, pd[tracks], lam[dets])
            ref[np.ix_(tracks, dets)] = b[:, :-1]
            ref[tracks, M] = b[:, -1]
        pt, pm = rng.permutation(K), rng.permutation(M)       # clusters are not contiguous
        problems.append((L[pt][:, pm], pd[pt], lam[pm]))
        refs.append(np.concatenate([ref[pt][:, pm], ref[pt][:, M:]], 1))
    beta, info = _clustered(*(np.stack(x) for x in zip(*problems)))
    np.testing.assert_allclose(np.asarray(beta), np.stack(refs), atol=1e-12)
    assert not np.asarray(info.approximate).any()
    assert np.asarray(info.cluster_size).max() <= 4


def test_clusters_above_the_cap_fall_back_to_lbp_and_are_flagged():
    rng = np.random.default_rng(2)
    K = M = 12
    L = np.zeros((K, M))
    L[:6, :6] = rng.exponential(size=(6, 6))          # one dense cluster of 6 tracks > cap 4
    L[6:9, 6:10] = rng.exponential(size=(3, 4)) * (rng.uniform(size=(3, 4)) < 0.6)
    L[9:, 10:] = rng.exponential(size=(3, 2))
    pd, lam = np.full(K, 0.9), np.full(M, 0.5)
    beta, info = _clustered(L[None], pd[None], lam[None])
    beta = np.asarray(beta)[0]
    approx = np.asarray(info.approximate)[0]
    assert approx[:6].all() and not approx[6:].any()
    np.testing.assert_array_equal(np.asarray(info.cluster_size)[0, :6], 6)
    assert bool(info.lbp_converged[0]) and int(info.lbp_iterations[0]) > 0
    lbp = np.asarray(association.jpda_marginals(L, pd, lam, method="lbp"))
    np.testing.assert_allclose(beta[:6], lbp[:6], atol=1e-12)
    for tracks, dets in ((range(6, 9), range(6, 10)), (range(9, 12), range(10, 12))):
        tracks, dets = list(tracks), list(dets)
        ref = brute_force_marginals(L[np.ix_(tracks, dets)], 0.9, 0.5)
        np.testing.assert_allclose(beta[np.ix_(tracks, dets)], ref[:, :-1], atol=1e-12)
        np.testing.assert_allclose(beta[tracks, -1], ref[:, -1], atol=1e-12)
    exact6 = brute_force_marginals(L[:6, :6], 0.9, 0.5)
    assert np.abs(beta[:6, :6] - exact6[:, :-1]).max() < 0.1


# ---------------------------------------------------------------------------------------------
# Loopy belief propagation


def random_forest(rng, k, m, cap=CAP):
    """Likelihoods whose gating graph is a random forest (union-find rejects cycles)."""
    parent = list(range(k + m))

    def find(i):
        while parent[i] != i:
            i = parent[i]
        return i

    L = np.zeros((cap, cap))
    for _ in range(3 * (k + m)):
        t, j = rng.integers(k), rng.integers(m)
        a, b = find(t), find(k + j)
        if a != b:
            parent[a] = b
            L[t, j] = rng.exponential()
    return L


def test_lbp_is_exact_when_the_gating_graph_has_no_cycle():
    rng = np.random.default_rng(3)
    n = 60
    K, M = rng.integers(1, CAP + 1, n), rng.integers(1, CAP + 1, n)
    L = np.stack([random_forest(rng, k, m) for k, m in zip(K, M)])
    # plus problems where no two tracks share a detection
    for i in range(0, n, 3):
        L[i] = 0.0
        for j in range(M[i]):
            L[i, rng.integers(K[i]), j] = rng.exponential()
    tm, mm = np.arange(CAP)[None] < K[:, None], np.arange(CAP)[None] < M[:, None]
    pd, lam = rng.uniform(0.3, 0.99, (n, CAP)), rng.uniform(0.05, 3.0, (n, CAP))
    exact = np.asarray(_exact(L, pd, lam, tm, mm))
    lbp = np.asarray(_lbp(L, pd, lam, tm, mm))
    np.testing.assert_allclose(lbp, exact, atol=1e-9)
    for i in range(0, n, 7):
        np.testing.assert_allclose(exact[i], padded_reference(L[i], pd[i], lam[i], K[i], M[i]),
                                   atol=1e-12)


def test_lbp_error_on_dense_problems_up_to_5x5(report):
    """Every pair gated in, K and M drawn from 2..5, pD ~ U(0.5, 0.99), lambda ~ logU(0.1, 10),
    likelihoods ~ Exp(1): the mean over problems of max |beta_lbp - beta_exact| <= 0.03."""
    rng = np.random.default_rng(4)
    n, cap = 1000, 5
    K, M = rng.integers(2, cap + 1, n), rng.integers(2, cap + 1, n)
    tm, mm = np.arange(cap)[None] < K[:, None], np.arange(cap)[None] < M[:, None]
    L = rng.exponential(size=(n, cap, cap))
    pd = np.repeat(rng.uniform(0.5, 0.99, (n, 1)), cap, 1)
    lam = np.repeat(np.exp(rng.uniform(np.log(0.1), np.log(10.0), (n, 1))), cap, 1)
    exact = np.asarray(_exact(L, pd, lam, tm, mm))
    lbp = np.asarray(_lbp(L, pd, lam, tm, mm))
    err = np.abs(lbp - exact).max(axis=(1, 2))
    mean, median, p95, worst = error_summary(err)
    report("LBP dense K,M in 2..5 (mean, median, p95, max)",
           f"{mean:.4f} {median:.4f} {p95:.4f} {worst:.4f}")
    full = (K == cap) & (M == cap)
    report("LBP dense 5x5 only (mean, median, p95, max)",
           " ".join(f"{x:.4f}" for x in error_summary(err[full])))
    assert mean <= 0.03
    assert worst < 0.3
    np.testing.assert_allclose(lbp.sum(-1), 1.0, atol=1e-12)


def test_lbp_matches_stone_soup_lbp():
    from stonesoup.dataassociator.probability import JPDAwithLBP

    L, pd, lam, tm, mm, K, M = random_problems(6, 8)
    ours = np.asarray(_lbp(L, pd, lam, tm, mm))
    for i in range(8):
        k, m = K[i], M[i]
        w = pd[i, :k, None] * L[i, :k, :m] / lam[i, None, :m] / (1.0 - pd[i, :k, None])
        lm = np.concatenate([np.ones((k, 1)), w], 1)
        ss = JPDAwithLBP._loopy_belief_propagation(lm, 1, 1e-12)
        np.testing.assert_allclose(ours[i, :k, :m], ss[:, 1:], atol=1e-7)
        np.testing.assert_allclose(ours[i, :k, -1], ss[:, 0], atol=1e-7)


def test_lbp_iteration_cap_and_fixed_iterations_are_reported():
    L = np.random.default_rng(7).exponential(size=(4, 4))
    _, info = association.jpda_marginals(L, 0.9, 0.1, method="lbp", lbp_max_iter=2,
                                         return_info=True)
    assert int(info.lbp_iterations) == 2 and not bool(info.lbp_converged)
    fixed = jax.jit(jax.vmap(lambda L, pd, lam, tm, mm: association.jpda_marginals(
        L, pd, lam, tm, mm, method="lbp", lbp_tol=None, lbp_max_iter=300)))
    np.testing.assert_allclose(run_padded(fixed, L, 0.9, 0.1), run_padded(_lbp, L, 0.9, 0.1),
                               atol=1e-9)


# ---------------------------------------------------------------------------------------------
# Reductions to PDA


def test_one_track_jpda_is_pda():
    rng = np.random.default_rng(8)
    g = rng.exponential(size=(1, 5)) * np.array([[1, 1, 0, 1, 1]])
    for fn in (_exact, _lbp):
        beta = run_padded(fn, g, 0.8, 0.3)[0]
        w = 0.8 * g[0] / 0.3
        ref = np.concatenate([w, [0.2]]) / (0.2 + w.sum())
        np.testing.assert_allclose(beta, ref, atol=1e-12)


def test_detection_probability_one_and_no_clutter_gives_likelihood_weights():
    g = np.array([[0.3, 0.0, 1.2, 0.5]])
    beta = run_padded(_exact, g, 1.0, 1e-12)[0]
    np.testing.assert_allclose(beta[:-1], g[0] / g.sum(), atol=1e-12)
    assert beta[-1] < 1e-100
    # a track with p_detect = 1 and no detection still gets a valid row
    none = run_padded(_exact, np.zeros((2, 3)), 1.0, 1.0)
    np.testing.assert_allclose(none[:, -1], 1.0)


# ---------------------------------------------------------------------------------------------
# Stone Soup


def stonesoup_scenario(prob_gate):
    from stonesoup.dataassociator.probability import JPDA, JPDAwithLBP
    from stonesoup.hypothesiser.probability import PDAHypothesiser
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import (CombinedLinearGaussianTransitionModel,
                                                    ConstantVelocity)
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.types.detection import Detection
    from stonesoup.types.state import GaussianState
    from stonesoup.types.track import Track
    from stonesoup.updater.kalman import KalmanUpdater
    from stonesoup.updater.probability import PDAUpdater

    t0 = datetime(2024, 1, 1)
    t1 = t0 + timedelta(seconds=0.5)
    transition = CombinedLinearGaussianTransitionModel([ConstantVelocity(0.05),
                                                        ConstantVelocity(0.05)])
    meas = LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=np.diag([0.09, 0.09]))
    starts = [(0.0, 0.5, 0.0, 0.0), (0.8, 0.0, 0.3, 0.2), (1.6, -0.3, -0.2, 0.1)]
    cov = np.diag([0.1, 0.05, 0.1, 0.05])
    tracks = [Track([GaussianState(np.array(s), cov, timestamp=t0)]) for s in starts]
    zs = np.array([[0.3, 0.1], [0.7, 0.4], [1.1, 0.5], [1.4, -0.2], [3.5, 2.0]])
    dets = [Detection(z.reshape(2, 1), timestamp=t1, measurement_model=meas) for z in zs]
    p_detect, clutter = 0.9, 0.05
    hyp = PDAHypothesiser(predictor=KalmanPredictor(transition), updater=KalmanUpdater(meas),
                          clutter_spatial_density=clutter, prob_detect=p_detect,
                          prob_gate=prob_gate)
    hypotheses = JPDA(hypothesiser=hyp).associate(set(tracks), set(dets), t1)
    lbp_hypotheses = JPDAwithLBP(hypothesiser=hyp).associate(set(tracks), set(dets), t1)

    def marginals(hyps):
        beta = np.zeros((3, 6))
        for k, track in enumerate(tracks):
            for h in hyps[track]:
                col = 5 if not h else next(j for j, d in enumerate(dets) if d is h.measurement)
                beta[k, col] = float(h.probability)
        return beta

    posts = [PDAUpdater(meas).update(hypotheses[track]) for track in tracks]
    pred = [hypotheses[t][0].prediction for t in tracks]
    means = np.stack([np.asarray(p.state_vector, float)[:, 0] for p in pred])
    covs = np.stack([np.asarray(p.covar, float) for p in pred])
    post_means = np.stack([np.asarray(p.state_vector, float)[:, 0] for p in posts])
    post_covs = np.stack([np.asarray(p.covar, float) for p in posts])
    return dict(means=means, covs=covs, zs=zs, H=meas.matrix(), R=np.asarray(meas.covar()),
                p_detect=p_detect, clutter=clutter, beta=marginals(hypotheses),
                beta_lbp=marginals(lbp_hypotheses), post_means=post_means,
                post_covs=post_covs)


@pytest.mark.parametrize("prob_gate", [1.0, 0.95])
def test_marginals_and_update_equal_stone_soup_jpda(prob_gate):
    s = stonesoup_scenario(prob_gate)
    inn = association.innovations(s["means"], s["covs"], s["zs"], s["H"], s["R"])
    g = np.exp(np.asarray(inn.log_likelihood))
    p_detect = s["p_detect"]
    if prob_gate < 1.0:
        # Stone Soup: missed weight 1 - P_D P_G and gated-out pairs dropped. The same model
        # here: the gate-truncated density g / P_G and the detection-in-gate probability P_D P_G.
        gated = np.asarray(association.gate(inn.d2, 2, prob_gate))
        assert gated.any() and not gated.all()
        g = np.where(gated, g / prob_gate, 0.0)
        p_detect = p_detect * prob_gate
    beta = run_padded(_exact, g, p_detect, s["clutter"])
    np.testing.assert_allclose(beta, s["beta"], atol=1e-10)
    # Stone Soup's LBP stops on its own (looser) convergence bound
    np.testing.assert_allclose(run_padded(_lbp, g, p_detect, s["clutter"]), s["beta_lbp"],
                               atol=1e-4)
    post = association.jpda_update(Gaussian(s["means"], s["covs"]), s["zs"], beta, s["H"],
                                   s["R"])
    np.testing.assert_allclose(np.asarray(post.mean), s["post_means"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.asarray(post.cov), s["post_covs"], rtol=1e-9, atol=1e-12)


# ---------------------------------------------------------------------------------------------
# NN-JPDA


def test_nn_jpda_resolves_conflicts_by_the_larger_marginal():
    beta = np.array([[0.7, 0.2, 0.0, 0.1],
                     [0.6, 0.0, 0.1, 0.3],
                     [0.0, 0.5, 0.0, 0.5]])
    # track 0 keeps detection 0 (0.7 > 0.6); track 1 falls back to "none" (0.3 > 0.1);
    # track 2 ties 0.5 / 0.5: the lower index (detection 1) wins
    assert np.asarray(association.nn_jpda(beta)).tolist() == [0, -1, 1]
    # optimal: maximise the product of the chosen marginals (0.7 * 0.3 * 0.5 here), run in the
    # shared [6, 7] shape (masked tracks have beta = [0, ..., 0, 1])
    padded = np.zeros((1, CAP, CAP + 1))
    padded[0, :, -1] = 1.0
    padded[0, :3, :3], padded[0, :3, -1] = beta[:, :3], beta[:, -1]
    assert np.asarray(_nn_optimal(padded))[0, :3].tolist() == [0, -1, 1]


def test_nn_jpda_without_conflicts_is_the_row_argmax_and_never_takes_zero_pairs():
    L, pd, lam, tm, mm, K, M = random_problems(9, 40)
    beta = np.asarray(_exact(L, pd, lam, tm, mm))
    greedy = np.asarray(_nn_greedy(beta))
    optimal = np.asarray(_nn_optimal(beta))
    for b, g, o in zip(beta, greedy, optimal):
        for col in (g, o):
            taken = col[col >= 0]
            assert len(set(taken.tolist())) == len(taken)
            assert np.all(b[np.nonzero(col >= 0)[0], taken] > 0)
        arg = np.argmax(b, 1)
        arg = np.where(arg == CAP, -1, arg)
        picked = arg[arg >= 0]
        if len(set(picked.tolist())) == len(picked):
            np.testing.assert_array_equal(g, arg)
            np.testing.assert_array_equal(o, arg)
        # optimal maximises the product of the chosen marginals
        def score(col):
            return np.sum(np.log(b[np.arange(CAP), np.where(col < 0, CAP, col)]))
        assert score(o) >= score(g) - 1e-12


# ---------------------------------------------------------------------------------------------
# Precision, batching, gradients, bad input


def test_float32_and_log_likelihood_inputs_match_float64():
    L, pd, lam, tm, mm, K, M = random_problems(10, 6)
    ref = np.asarray(_exact(L, pd, lam, tm, mm))
    out = _exact(*(jnp.asarray(a, jnp.float32) for a in (L, pd, lam)), tm, mm)
    assert out.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(out), ref, atol=2e-5)
    # log-likelihood input (-inf for gated out; NaN in masked slots), float32, LBP
    with np.errstate(divide="ignore", invalid="ignore"):
        logs = np.log(L)
    lbp32 = association.jpda_marginals(jnp.asarray(logs[0], jnp.float32), pd[0], lam[0], tm[0],
                                       mm[0], method="lbp", log=True)
    assert lbp32.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(lbp32), np.asarray(_lbp(L, pd, lam, tm, mm))[0],
                               atol=2e-5)


def test_vmap_equals_loop_and_jit_with_static_method():
    L, pd, lam, tm, mm, K, M = random_problems(11, 3)
    vm = np.asarray(_exact(L, pd, lam, tm, mm))
    jitted = jax.jit(association.jpda_marginals, static_argnames=("method",))
    for i in range(3):
        one = np.asarray(jitted(L[i], pd[i], lam[i], tm[i], mm[i], method="exact"))
        np.testing.assert_allclose(vm[i], one, atol=1e-14)


def test_gradients_are_finite_and_match_finite_differences():
    rng = np.random.default_rng(12)
    L = rng.exponential(size=(3, 4)) * (rng.uniform(size=(3, 4)) < 0.7)
    L[0, 0] = 0.8
    weights = rng.standard_normal((3, 5))

    def loss(L, pd, method):
        return jnp.sum(weights * association.jpda_marginals(L, pd, 0.4, method=method,
                                                            lbp_tol=None, lbp_max_iter=60))

    @jax.jit
    def values_and_grads(L, pd):
        return [jax.value_and_grad(loss, argnums=(0, 1))(L, pd, method)
                for method in ("exact", "lbp")]

    for i in range(2):
        gL, gpd = values_and_grads(jnp.asarray(L), 0.85)[i][1]

        def value(L, pd):
            return values_and_grads(L, pd)[i][0]

        assert np.all(np.isfinite(np.asarray(gL))) and np.isfinite(float(gpd))
        eps = 1e-6
        E = np.zeros_like(L)
        E[0, 0] = eps
        fd = (value(L + E, 0.85) - value(L - E, 0.85)) / (2 * eps)
        np.testing.assert_allclose(float(gL[0, 0]), float(fd), rtol=1e-5)
        fd_pd = (value(L, 0.85 + eps) - value(L, 0.85 - eps)) / (2 * eps)
        np.testing.assert_allclose(float(gpd), float(fd_pd), rtol=1e-5)


def test_bad_inputs_are_clear_errors_at_the_boundary():
    L = np.ones((3, 4))
    with pytest.raises(ValueError, match="unknown method 'hungarian'"):
        association.jpda_marginals(L, 0.9, 1.0, method="hungarian")
    with pytest.raises(ValueError, match="p_detect must have shape"):
        association.jpda_marginals(L, np.full(4, 0.9), 1.0)
    with pytest.raises(ValueError, match="clutter_density must have shape"):
        association.jpda_marginals(L, 0.9, np.ones(3))
    with pytest.raises(ValueError, match="meas_mask must have shape"):
        association.jpda_marginals(L, 0.9, 1.0, meas_mask=np.ones(5, bool))
    with pytest.raises(ValueError, match="clutter_density must be positive"):
        association.jpda_marginals(L, 0.9, 0.0)
    with pytest.raises(ValueError, match="p_detect must lie in"):
        association.jpda_marginals(L, 1.2, 1.0)
    with pytest.raises(ValueError, match="likelihoods must be >= 0"):
        association.jpda_marginals(-L, 0.9, 1.0)
    with pytest.raises(ValueError, match="max_cluster_tracks"):
        association.jpda_marginals(L, 0.9, 1.0, max_cluster_tracks=20)
    with pytest.raises(ValueError, match=r"likelihoods must be a \[K, M\]"):
        association.jpda_marginals(np.ones(3), 0.9, 1.0)
    with pytest.raises(ValueError, match="unknown method"):
        association.nn_jpda(np.ones((2, 3)) / 3, method="argmax")


# ---------------------------------------------------------------------------------------------
# Clustered evaluation by size class, LBP tolerance


def _size_class_problem(rng, with_large):
    """16 tracks, 20 detections (3 gated by nobody): clusters of 6, 5, 2, 1, 1 and 1 tracks
    (the 6- and 5-track clusters are chains, so that brute force stays small) or only 1-track
    clusters; returns L [K, M], pd [K], lam [M] and the brute-force reference [K, M + 1]."""
    K, M = 16, 20
    blocks = ([(range(0, 6), range(0, 4)), (range(6, 11), range(4, 11)),
               (range(11, 13), range(11, 14)), (range(13, 14), range(14, 16)),
               (range(14, 15), range(16, 17)), (range(15, 16), [])] if with_large else
              [(range(t, t + 1), range(t, t + 1)) for t in range(16)])
    pd, lam = rng.uniform(0.5, 0.95, K), rng.uniform(0.1, 2.0, M)
    L, ref = np.zeros((K, M)), np.zeros((K, M + 1))
    for tracks, dets in blocks:
        tracks, dets = list(tracks), list(dets)
        k, m = len(tracks), len(dets)
        block = rng.exponential(size=(k, m)) + 0.05
        if k > 2:                 # a chain: track i gates detections i - 1 .. i + 1 (scaled)
            t_i = np.arange(k)[:, None] * (m - 1) / max(k - 1, 1)
            block *= np.abs(np.arange(m)[None, :] - t_i) <= 1.0
        L[np.ix_(tracks, dets)] = block
        if m:
            b = brute_force_marginals(block, pd[tracks], lam[dets])
            ref[np.ix_(tracks, dets)], ref[tracks, M] = b[:, :-1], b[:, -1]
        else:
            ref[tracks, M] = 1.0
    pt, pm = rng.permutation(K), rng.permutation(M)
    return L[pt][:, pm], pd[pt], lam[pm], np.concatenate([ref[pt][:, pm], ref[pt][:, M:]], 1)


_by_size = jax.jit(jax.vmap(lambda L, pd, lam: association.jpda_marginals(
    L, pd, lam, max_cluster_tracks=6, return_info=True)))


def test_every_size_class_is_exact_under_vmap_with_mixed_batches():
    """Clusters of 1, 2, 5 and 6 tracks (closed forms and the DP class 5-6, more detections
    than one DP chunk) next to a problem of 1-track clusters only: every problem equals brute
    force (float64, 1e-12; float32 of the same code: test_float32_and_log_likelihood_inputs)."""
    rng = np.random.default_rng(21)
    problems = [_size_class_problem(rng, big) for big in (True, False, True)]
    L, pd, lam, ref = (np.stack(x) for x in zip(*problems))
    beta, info = _by_size(L, pd, lam)
    np.testing.assert_allclose(np.asarray(beta), ref, atol=1e-12)
    assert np.asarray(info.cluster_size).max(-1).tolist() == [6, 1, 6]
    assert not np.asarray(info.approximate).any()


def test_exact_derivatives_below_the_cap_agree_in_forward_and_reverse_mode():
    rng = np.random.default_rng(22)
    L = rng.exponential(size=(4, 5)) * (rng.uniform(size=(4, 5)) < 0.6)
    L[:, 0] = 0.7                                       # one cluster of all four tracks

    def f(L):
        return association.jpda_marginals(L, 0.8, 0.3)

    rev = np.asarray(jax.jit(jax.jacrev(f))(jnp.asarray(L)))
    fwd = np.asarray(jax.jit(jax.jacfwd(f))(jnp.asarray(L)))
    np.testing.assert_allclose(rev, fwd, atol=1e-12)
    np.testing.assert_allclose(np.asarray(f(L)), brute_force_marginals(L, 0.8, 0.3), atol=1e-12)


def test_lbp_tolerance_follows_the_dtype():
    """A loopy problem: in float32 the default and a tolerance finer than float32 resolves
    both stop before the iteration cap and agree with float64 LBP."""
    rng = np.random.default_rng(23)
    L = rng.exponential(size=(5, 5)) + 0.1                  # fully gated: many cycles
    ref = np.asarray(association.jpda_marginals(L, 0.9, 0.2, method="lbp", lbp_tol=1e-12))
    L32 = jnp.asarray(L, jnp.float32)
    for tol in ("auto", 1e-12):
        beta, info = association.jpda_marginals(L32, 0.9, 0.2, method="lbp", lbp_tol=tol,
                                                lbp_max_iter=500, return_info=True)
        assert bool(info.lbp_converged) and int(info.lbp_iterations) < 500
        np.testing.assert_allclose(np.asarray(beta), ref, atol=1e-4)
    with pytest.raises(ValueError, match="lbp_tol"):
        association.jpda_marginals(L, 0.9, 0.2, method="lbp", lbp_tol="tight")


@pytest.mark.parametrize("method", ["exact", "lbp"])
@pytest.mark.parametrize("K", [1, 3, 5, 9])
def test_empty_scan_gives_every_track_the_no_detection_event(K, method):
    beta = association.jpda_marginals(jnp.zeros((K, 0)), 0.9, 0.5, method=method,
                                      max_cluster_tracks=4)
    np.testing.assert_array_equal(beta, np.ones((K, 1)))
