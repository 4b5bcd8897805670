"""Seed 004 particle clustering against a plain Python transcription of Algorithms 2-5."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.tracking import clustering

N_K = 6


# --- Reference: the paper's pseudo-code, line by line ------------------------------------------

def ref_find_cluster_in_order(P, delta, n_k):
    """Algorithm 3 with line 6 appending in visiting order (``priority="order"``)."""
    K = []
    for p in P:
        is_far = True
        for k in K:
            if not is_far:
                break
            is_far = math.dist(p, k) > delta
        if is_far and len(K) < n_k:
            K.append(p)
    return K


def ref_find_cluster(P, delta, n_k):
    """Algorithm 3 with line 6 as the paper says: "a priority queue principle, considering the
    distance", so that "K will contain the most distant N_K points". Lines 1-5 find the far
    particles; the queue hands out the one most distant from the centroids so far (the first
    in visiting order among equals), which line 6 adds; until N_K or no far particle is left."""
    K = []
    while len(K) < n_k:
        queue = []                              # (priority, visiting order, particle)
        for order, p in enumerate(P):           # line 1
            is_far = True                       # line 2
            d_min = math.inf
            for k in K:                         # line 3
                if not is_far:
                    break
                d = math.dist(p, k)
                is_far = d > delta              # line 4
                d_min = min(d_min, d)
            if is_far:                          # line 5
                queue.append((-d_min, order, p))
        if not queue:
            break
        K.append(min(queue)[2])                 # line 6: the most distant first
    return K


def ref_classify(K, P, delta):
    labels, O = [], []
    for i, p in enumerate(P):
        added = False
        lab = -1
        for j, k in enumerate(K):
            if added:
                break
            if math.dist(p, k) < delta:
                lab, added = j, True
        if not added:
            O.append(i)
        labels.append(lab)
    return labels, O


def ref_spread(K, P, labels, O):
    labels = list(labels)
    for i in O:
        d_min, cand = math.inf, None
        for j, k in enumerate(K):
            d = math.dist(P[i], k)
            if d < d_min:
                cand, d_min = j, d
        labels[i] = cand
    return labels


def ref_threshold(PL, PK):
    total = sum(math.dist(a, b) for i, a in enumerate(PL) for j, b in enumerate(PL) if i != j)
    total += sum(math.dist(a, b) for i, a in enumerate(PK) for j, b in enumerate(PK) if i != j)
    return total / (len(PL) + len(PK))


# --- Tests ---------------------------------------------------------------------------------------

_kclusterise = jax.jit(clustering.kclusterise, static_argnames=("max_clusters", "position_dims"))


@pytest.mark.parametrize("seed", range(5))
def test_kclusterise_equals_python_transcription_of_algorithms_2_to_5(seed):
    rng = np.random.default_rng(seed)
    P = rng.uniform(-3, 3, size=(60, 2))
    delta = rng.uniform(0.8, 2.5)
    K = ref_find_cluster([tuple(p) for p in P], delta, N_K)
    labels, O = ref_classify(K, [tuple(p) for p in P], delta)
    labels = ref_spread(K, [tuple(p) for p in P], labels, O)
    lw = jnp.asarray(rng.normal(size=60))
    res = _kclusterise(jnp.asarray(P), lw, delta, max_clusters=N_K, position_dims=2)
    assert int(res.mask.sum()) == len(K)
    np.testing.assert_allclose(np.asarray(res.centroids)[: len(K)], np.array(K), atol=0)
    np.testing.assert_array_equal(np.asarray(res.labels), labels)
    # Gaussian summaries equal numpy on the reference partition
    w = np.exp(np.asarray(lw) - np.logaddexp.reduce(np.asarray(lw)))
    for j in range(len(K)):
        sel = np.asarray(labels) == j
        np.testing.assert_allclose(res.weights[j], w[sel].sum(), rtol=1e-12)
        np.testing.assert_allclose(res.means[j], np.average(P[sel], 0, w[sel]), rtol=1e-10)
        np.testing.assert_allclose(res.covs[j], np.cov(P[sel].T, aweights=w[sel], bias=True),
                                   atol=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_find_clusters_in_visiting_order_equals_the_plain_loop(seed):
    rng = np.random.default_rng(seed + 10)
    P = rng.uniform(-3, 3, size=(60, 2))
    delta = rng.uniform(0.8, 2.5)
    K = ref_find_cluster_in_order([tuple(p) for p in P], delta, N_K)
    cents, cmask = clustering.find_clusters(jnp.asarray(P), delta, N_K, priority="order")
    assert int(cmask.sum()) == len(K)
    np.testing.assert_allclose(np.asarray(cents)[: len(K)], np.array(K), atol=0)
    # The priority queue takes different, more spread out centroids.
    Kq = ref_find_cluster([tuple(p) for p in P], delta, N_K)
    assert Kq[0] == K[0] and Kq != K


def test_the_paper_s_clustering_is_the_default():
    from jaxtrack.tracking import people_pf, user

    cfg = people_pf.PeoplePFConfig()
    assert cfg.threshold_mode == "paper" and cfg.cluster_priority == "distance"
    assert cfg.threshold_cap == math.inf
    pf = user.ParticleConfig().pf
    assert pf.threshold_mode == "paper" and pf.cluster_priority == "distance"
    assert pf.threshold_cap == math.inf
    # eq. 5 itself: the dynamic threshold's default mode is the printed formula.
    PL, PK = [(0.0, 0.0), (2.0, 0.0), (0.0, 3.0)], [(1.0, 1.0), (4.0, 0.0)]
    got = float(clustering.dynamic_threshold(jnp.asarray(PL), jnp.asarray(PK)))
    assert got == pytest.approx(ref_threshold(PL, PK), rel=1e-12)


def test_individual_algorithms_match_the_transcription_with_a_mask():
    rng = np.random.default_rng(7)
    P = rng.uniform(-2, 2, size=(40, 2))
    mask = rng.random(40) > 0.3
    delta = 1.1
    Pm = [tuple(p) for p in P[mask]]
    K = ref_find_cluster(Pm, delta, N_K)
    cents, cmask = clustering.find_clusters(jnp.asarray(P), delta, N_K, jnp.asarray(mask))
    np.testing.assert_allclose(np.asarray(cents)[np.asarray(cmask)], np.array(K))
    labels = clustering.classify_particles(jnp.asarray(P), cents, cmask, delta, jnp.asarray(mask))
    ref_labels, O = ref_classify(K, Pm, delta)
    np.testing.assert_array_equal(np.asarray(labels)[mask], ref_labels)
    assert np.all(np.asarray(labels)[~mask] == -1)
    spread = clustering.spread_outliers(jnp.asarray(P), cents, cmask, labels, jnp.asarray(mask))
    np.testing.assert_array_equal(np.asarray(spread)[mask], ref_spread(K, Pm, ref_labels, O))


def test_three_well_separated_people_give_three_clusters_with_the_right_means():
    rng = np.random.default_rng(3)
    people = np.array([[0.0, 0.0], [3.0, 1.0], [-1.0, 4.0]])
    parts = np.concatenate([p + 0.15 * rng.standard_normal((200, 2)) for p in people])
    vel = rng.standard_normal((600, 2)) * 0.1
    particles = np.concatenate([parts, vel], -1)[rng.permutation(600)]
    # Threshold from one detection per person per sensor; the printed eq. 5 would give about
    # 8 m here and merge everybody (see dynamic_threshold), half the mean distance does not.
    thr = clustering.dynamic_threshold(jnp.asarray(people), jnp.asarray(people + 0.05),
                                       mode="half_mean")
    assert float(clustering.dynamic_threshold(jnp.asarray(people), jnp.asarray(people))) > 5.0
    res = _kclusterise(jnp.asarray(particles), jnp.zeros(600), thr, max_clusters=N_K,
                       position_dims=2)
    assert int(res.mask.sum()) == 3
    means = np.asarray(res.means)[np.asarray(res.mask)][:, :2]
    for p in people:
        assert np.min(np.linalg.norm(means - p, axis=1)) < 0.05
    np.testing.assert_allclose(np.sort(np.asarray(res.weights)[np.asarray(res.mask)]),
                               [1 / 3] * 3, atol=1e-12)


def test_dynamic_threshold_equals_eq_5_with_masks():
    rng = np.random.default_rng(2)
    PL, PK = rng.uniform(-4, 4, (5, 2)), rng.uniform(-4, 4, (4, 2))
    lm, km = np.array([1, 1, 0, 1, 1], bool), np.array([1, 0, 1, 1], bool)
    ref = ref_threshold([tuple(p) for p in PL[lm]], [tuple(p) for p in PK[km]])
    PL_nan = PL.copy()
    PL_nan[2] = np.nan  # masked-out rows may hold garbage
    out = clustering.dynamic_threshold(jnp.asarray(PL_nan), jnp.asarray(PK), jnp.asarray(lm),
                                       jnp.asarray(km))
    np.testing.assert_allclose(out, ref, rtol=1e-12)
    assert float(clustering.dynamic_threshold(jnp.zeros((0, 2)), jnp.zeros((0, 2)))) == 0.0
    pairs = [(a, b) for S in (PL[lm], PK[km]) for i, a in enumerate(S) for j, b in enumerate(S)
             if i != j]
    half_mean = 0.5 * np.mean([math.dist(a, b) for a, b in pairs])
    out_half = clustering.dynamic_threshold(jnp.asarray(PL_nan), jnp.asarray(PK), jnp.asarray(lm),
                                            jnp.asarray(km), mode="half_mean")
    np.testing.assert_allclose(out_half, half_mean, rtol=1e-12)
    two = jnp.array([[0.0, 0.0], [3.0, 0.0]])
    np.testing.assert_allclose(clustering.dynamic_threshold(two, two), 3.0)
    np.testing.assert_allclose(clustering.dynamic_threshold(two, two, mode="half_mean"), 1.5)
    with pytest.raises(ValueError, match="mode"):
        clustering.dynamic_threshold(two, two, mode="mean")
    assert float(clustering.dynamic_threshold(jnp.zeros((1, 2)), jnp.zeros((0, 2)),
                                              floor=0.4)) == 0.4


def test_dynamic_threshold_has_finite_gradients_with_coincident_detections():
    g = jax.grad(lambda x: clustering.dynamic_threshold(x, jnp.zeros((0, 2))))(jnp.zeros((2, 2)))
    assert np.all(np.isfinite(g))


def test_nan_particles_are_ignored_and_vmap_equals_loop():
    rng = np.random.default_rng(4)
    P = rng.uniform(-3, 3, size=(3, 50, 2))
    P[0, 5] = np.nan
    lw = jnp.zeros((3, 50))
    batched = jax.vmap(lambda p, w: clustering.kclusterise(p, w, 1.5, N_K))(jnp.asarray(P), lw)
    assert np.all(np.isfinite(np.asarray(batched.means)))
    assert int(batched.labels[0, 5]) == -1
    for b in range(3):
        single = clustering.kclusterise(jnp.asarray(P[b]), lw[b], 1.5, N_K)
        np.testing.assert_array_equal(batched.labels[b], single.labels)
        np.testing.assert_allclose(batched.means[b], single.means, rtol=1e-12)


def test_float32_matches_float64_partition():
    rng = np.random.default_rng(5)
    P = rng.uniform(-3, 3, size=(60, 2))
    r64 = _kclusterise(jnp.asarray(P), jnp.zeros(60), 1.3, max_clusters=N_K, position_dims=2)
    r32 = _kclusterise(jnp.asarray(P, jnp.float32), jnp.zeros(60, jnp.float32),
                       jnp.float32(1.3), max_clusters=N_K, position_dims=2)
    assert r32.means.dtype == jnp.float32
    np.testing.assert_array_equal(r32.labels, r64.labels)
    np.testing.assert_allclose(r32.means, r64.means, atol=1e-5)


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="position_dims"):
        clustering.kclusterise(jnp.zeros((5, 2)), jnp.zeros(5), 1.0, 3, position_dims=3)
    with pytest.raises(ValueError, match="log_weights"):
        clustering.kclusterise(jnp.zeros((5, 2)), jnp.zeros(4), 1.0, 3)
    with pytest.raises(ValueError, match="max_clusters"):
        clustering.kclusterise(jnp.zeros((5, 2)), jnp.zeros(5), 1.0, 0)
