"""The fixed-capacity multi-target tracker: identities through a crossing, births, deaths, slot
recycling, association modes, boundary checks; and each stage of a scan (predict, hypothesise,
associate_gnn / _jpda / _nn_jpda, manage, births) against numpy references: the Kalman
prediction and update, scipy's chi-square quantile and Gaussian density, brute-force GNN
assignments and JPDA marginals, and the M-of-N / miss / birth rules written as plain loops."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import chi2, multivariate_normal

from jaxtrack import metrics, tracking
from jaxtrack.filters.kalman import Gaussian
from jaxtrack.tracking import tracker
from tests.association.references import (brute_force_marginals, kalman_posterior,
                                          mixture_reference)

M = 8
CFG = {a: tracking.TrackerConfig(capacity=6, association=a) for a in ("gnn", "jpda", "nn_jpda")}


def params_for(assoc, **kw):
    return tracking.TrackerParams.create(CFG[assoc], dt=0.1, q=0.5, r_std=(0.1,),
                                         clutter_density=0.02, dtype=jnp.float64, **kw)


_RUN = {a: jax.jit(lambda s, d, p: tracking.run(s, d, p)) for a in CFG}


def run(assoc, det, **kw):
    p = params_for(assoc, **kw)
    return _RUN[assoc](tracking.init(p.config, jnp.float64), det, p)


def scenario(seed, T=70, p_detect=0.95, clutter=1.5, appear=None, vanish=None):
    """Two people crossing at right angles (X pattern), Poisson clutter in a 10 x 10 m room.

    Returns detections [T, M] and the ground truth (ids [T, 2], positions [T, 2, 2], mask)."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) * 0.1
    truth = np.stack([np.stack([-2.5 + 0.7 * t, -2.5 + 0.7 * t], -1),
                      np.stack([-2.5 + 0.7 * t, 2.5 - 0.7 * t], -1)], 1)  # [T, 2, 2]
    present = np.ones((T, 2), bool)
    if appear is not None:
        present[:appear, 1] = False
    if vanish is not None:
        present[vanish:, 0] = False
    pos = np.full((T, M, 2), np.nan)
    mask = np.zeros((T, M), bool)
    for k in range(T):
        dets = [truth[k, i] + 0.1 * rng.standard_normal(2) for i in range(2)
                if present[k, i] and rng.random() < p_detect]
        dets += list(rng.uniform(-5, 5, (rng.poisson(clutter), 2)))
        dets = dets[:M]
        if dets:
            pos[k, :len(dets)] = dets
            mask[k, :len(dets)] = True
    det = tracking.Detections(jnp.asarray(pos), jnp.asarray(mask), jnp.zeros((T, M), jnp.int32),
                              jnp.ones((T, M)), jnp.zeros((T, M, 0)))
    gt_ids = np.where(present, np.arange(2)[None], -1)
    return det, (gt_ids, truth, present)


def clear(seq, gt):
    gt_ids, truth, present = gt
    confirmed = np.asarray(seq.status) == tracking.CONFIRMED
    hyp_ids = np.where(confirmed, np.asarray(seq.id), -1)
    return metrics.clear_mot(jnp.asarray(gt_ids), jnp.asarray(truth), jnp.asarray(present),
                             jnp.asarray(hyp_ids), jnp.asarray(seq.mean[..., :2]),
                             jnp.asarray(confirmed), 0.5)


@pytest.mark.parametrize("assoc", ["jpda", "gnn", "nn_jpda"])
def test_two_people_crossing_in_clutter_keep_their_ids(assoc):
    switches, motas = [], []
    for seed in range(3):
        det, gt = scenario(seed)
        _, seq = run(assoc, det)
        res = clear(seq, gt)
        switches.append(int(res.num_switches))
        motas.append(float(res.mota))
    assert sum(switches) == 0, switches
    assert min(motas) > 0.8, motas


def test_births_and_deaths_happen_when_they_should():
    det, gt = scenario(5, appear=20, vanish=50, clutter=0.0, p_detect=1.0)
    _, seq = run("jpda", det)
    status, ids = np.asarray(seq.status), np.asarray(seq.id)
    confirmed = status == tracking.CONFIRMED
    # the first person is confirmed after 3 hits (M-of-N = 3 of 5) ...
    assert not confirmed[1].any() and confirmed[2].sum() == 1
    # ... the second appears at scan 20 and is confirmed at scan 22 with a new id
    assert confirmed[21].sum() == 1 and confirmed[22].sum() == 2
    assert len(set(ids[22][confirmed[22]])) == 2
    # the first disappears at scan 50 and is deleted after max_misses = 5 misses
    first_id = ids[22][confirmed[22]].min()
    alive = [bool((ids[k] == first_id).any()) for k in range(status.shape[0])]
    last_alive = max(k for k, a in enumerate(alive) if a)
    assert last_alive == 53, last_alive  # misses at scans 50..54, deleted at the fifth


def test_slots_are_recycled_and_ids_never_repeat_over_1000_scans():
    T = 1000
    pos = np.full((T, M, 2), np.nan)
    mask = np.zeros((T, M), bool)
    # a new person every 3 scans, walking 1.6 s then vanishing: with the scans a lost track
    # coasts, 6-7 tracks want a slot at once, so every slot is used again and again (and a few
    # births find the tracker full: they are counted in num_dropped)
    for idx, start in enumerate(range(0, T, 3)):
        x0, y0 = -4.0 + 2.0 * (idx % 5), -4.0 + 2.0 * ((idx // 5) % 5)
        for k in range(start, min(start + 16, T)):
            pos[k, idx % M] = [x0 + 0.05 * (k - start), y0]
            mask[k, idx % M] = True
    det = tracking.Detections(jnp.asarray(pos), jnp.asarray(mask), jnp.zeros((T, M), jnp.int32),
                              jnp.ones((T, M)), jnp.zeros((T, M, 0)))
    final, seq = run("gnn", det)
    ids = np.asarray(seq.id)
    status = np.asarray(seq.status)
    # every slot was used by several different tracks
    for k in range(CFG["gnn"].capacity):
        assert len(set(ids[:, k][status[:, k] != tracking.FREE])) > 3
    # an id never appears in two slots at once nor comes back after it died
    seen_alive = {}
    for t in range(T):
        live_ids = ids[t][status[t] != tracking.FREE]
        assert len(live_ids) == len(set(live_ids))
        for i in live_ids:
            if i in seen_alive:
                assert seen_alive[i] == t - 1, (i, t)
            seen_alive[i] = t
    assert int(final.next_id) == len(seen_alive)


def test_nan_detections_under_a_false_mask_are_ignored():
    det, gt = scenario(2, T=30)
    poisoned = det._replace(positions=jnp.where(det.mask[..., None], det.positions, jnp.inf))
    _, a = run("jpda", det)
    _, b = run("jpda", poisoned)
    np.testing.assert_array_equal(a.id, b.id)
    np.testing.assert_allclose(a.mean, b.mean, rtol=1e-12)


def test_birth_confidence_threshold_and_walking_status():
    det, _ = scenario(1, T=30, clutter=0.0, p_detect=1.0)
    low = det._replace(confidence=jnp.full(det.confidence.shape, 0.2))
    _, seq = run("gnn", low, birth_confidence=0.5)
    assert (np.asarray(seq.status) == tracking.FREE).all()
    final, _ = run("gnn", det)
    walking = tracking.is_walking(final, params_for("gnn"))
    assert int(walking.sum()) == 2  # both people walk at 1 m/s


def test_vmap_over_episodes_equals_loop():
    dets = [scenario(s, T=25)[0] for s in (11, 12)]
    batched = jax.tree.map(lambda *x: jnp.stack(x), *dets)
    p = params_for("jpda")
    fv = jax.jit(jax.vmap(lambda d: tracking.run(tracking.init(p.config, jnp.float64), d, p)[0]))
    out = fv(batched)
    for i, d in enumerate(dets):
        single, _ = run("jpda", d)
        np.testing.assert_array_equal(out.id[i], single.id)
        np.testing.assert_allclose(out.mean[i], single.mean, rtol=1e-9, atol=1e-12)


def test_bad_input_is_rejected_at_the_boundary():
    p = params_for("gnn")
    state = tracking.init(p.config, jnp.float64)
    with pytest.raises(ValueError, match="capacity"):
        tracking.make_detections(np.zeros((9, 2)), capacity=8)
    with pytest.raises(ValueError, match="association"):
        tracking.TrackerConfig(association="mht")
    det = tracking.make_detections([[0.0, 1.0]], capacity=4, sensor=[3])
    with pytest.raises(ValueError, match="sensor"):
        tracking.step(state, det, p)
    with pytest.raises(ValueError, match="capacity"):
        tracking.step(tracking.init(tracking.TrackerConfig(capacity=3)),
                      tracking.make_detections([[0.0, 1.0]], capacity=4), p)
    with pytest.raises(ValueError, match="p_detect"):
        tracking.TrackerParams.create(p_detect=1.0)
    with pytest.raises(ValueError, match="must be > 0"):
        tracking.TrackerParams.create(r_std=(0.1, -0.3))
    with pytest.raises(ValueError, match="gate_prob"):
        tracking.TrackerParams.create(gate_prob=1.0)


def test_params_can_be_built_from_traced_values():
    # A sweep of noise values under vmap builds the parameters inside the trace.
    def build(q, r, pd):
        p = tracking.TrackerParams.create(q=q, r_std=(r, 0.3), p_detect=pd)
        return p.log_q, p.log_r_std, p.logit_p_detect

    qs, rs, pds = jnp.array([0.5, 2.0]), jnp.array([0.1, 0.2]), jnp.array([0.8, 0.9])
    log_q, log_r, logit = jax.jit(jax.vmap(build))(qs, rs, pds)
    for i in range(2):
        ref = tracking.TrackerParams.create(q=float(qs[i]), r_std=(float(rs[i]), 0.3),
                                            p_detect=float(pds[i]))
        np.testing.assert_allclose(log_q[i], ref.log_q, rtol=1e-6)
        np.testing.assert_allclose(log_r[i], ref.log_r_std, rtol=1e-6)
        np.testing.assert_allclose(logit[i], ref.logit_p_detect, rtol=1e-5)


def _two_sensor_scenario(seed=0, T=40):
    """One person walking, seen by a precise sensor (0.05 m, index 0) and a coarse one
    (0.3 m, index 1) whose detection often falls outside the person's gate."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) * 0.1
    truth = np.stack([-1.0 + 0.8 * t, 0.5 * np.ones(T)], -1)
    pos = np.stack([truth + 0.05 * rng.standard_normal((T, 2)),
                    truth + 0.3 * rng.standard_normal((T, 2))], 1)
    det = tracking.Detections(jnp.asarray(pos), jnp.ones((T, 2), bool),
                              jnp.tile(jnp.arange(2, dtype=jnp.int32), (T, 1)), jnp.ones((T, 2)),
                              jnp.zeros((T, 2, 0)))
    return det, truth


@pytest.mark.parametrize("merge", [0.0, 0.4])
def test_merge_distance_keeps_one_track_per_person(merge):
    det, truth = _two_sensor_scenario()
    cfg = tracking.TrackerConfig(capacity=6, association="gnn", merge_distance=merge)
    p = tracking.TrackerParams.create(cfg, dt=0.1, q=0.5, r_std=(0.05, 0.3), dtype=jnp.float64)
    _, seq = jax.jit(tracking.run)(tracking.init(cfg, jnp.float64), det, p)
    live = np.asarray(seq.status) != tracking.FREE
    near = live & (np.linalg.norm(np.asarray(seq.mean)[..., :2] - truth[:, None], axis=-1)
                   < 0.4)
    if merge:
        # Never two live tracks within the merge distance of each other, and the person's
        # first track (id 0) survives every merge.
        m = np.asarray(seq.mean)[..., :2]
        d = np.linalg.norm(m[:, :, None] - m[:, None], axis=-1)
        both = live[:, :, None] & live[:, None] & ~np.eye(6, dtype=bool)
        assert not np.any(both & (d < merge))
        assert np.all(np.any(live & (np.asarray(seq.id) == 0), 1))
        assert near.sum(1).max() == 1
    else:
        # Without merging the coarse sensor starts duplicates on the same person (so the check
        # above can fail).
        assert near.sum(1).max() >= 2


def test_merge_distance_must_be_non_negative():
    with pytest.raises(ValueError, match="merge_distance"):
        tracking.TrackerConfig(merge_distance=-0.1)


# ---------------------------------------------------------------------------------------------
# The stages of one scan (predict -> hypothesise -> associate -> manage -> births), each
# against a plain numpy / brute-force reference.

SENSOR_STD = (0.1, 0.3)


def stage_params(assoc="gnn", **kw):
    cfg = tracking.TrackerConfig(capacity=6, association=assoc,
                                 **{k: kw.pop(k) for k in list(kw) if k in _CONFIG_FIELDS})
    return tracking.TrackerParams.create(cfg, dt=0.1, q=0.5, r_std=SENSOR_STD,
                                         clutter_density=0.05, dtype=jnp.float64, **kw)


_CONFIG_FIELDS = {f.name for f in tracking.TrackerConfig.__dataclass_fields__.values()}


def stage_scene(params, seed=0):
    """Six slots (0-3 live, 0 and 1 close enough to compete for detections; 4, 5 free) and a
    scan of eight slots: detections near the tracks from two sensors, far clutter, a NaN
    detection under a True mask and an empty slot."""
    rng = np.random.default_rng(seed)
    K, F = params.config.capacity, params.config.num_features
    pos = np.array([[0.0, 0.0], [0.35, 0.1], [3.0, 3.0], [-3.0, 2.0], [9.0, 9.0], [0.0, 0.0]])
    mean = np.concatenate([pos, rng.uniform(-0.5, 0.5, (K, 2))], 1)
    cov = np.stack([np.diag([0.04, 0.05, 0.3, 0.3]) + 0.005 * (a @ a.T)
                    for a in rng.standard_normal((K, 4, 4))])
    status = np.array([2, 2, 1, 2, 0, 0])
    state = tracking.init(params.config, jnp.float64)._replace(
        mean=jnp.asarray(mean), cov=jnp.asarray(cov), status=jnp.asarray(status, jnp.int32),
        id=jnp.asarray(np.where(status > 0, [4, 2, 6, 5, -1, -1], -1), jnp.int32),
        hits=jnp.asarray([9, 7, 2, 4, 0, 0], jnp.int32),
        age=jnp.asarray([12, 9, 2, 6, 0, 0], jnp.int32),
        history=jnp.asarray([31, 29, 3, 15, 0, 0], jnp.int32), next_id=jnp.int32(7),
        appearance=tracker.appearance.Appearance(jnp.asarray(rng.standard_normal((K, F))),
                                                 jnp.asarray(rng.standard_normal(K))))
    z = np.array([[0.05, 0.02], [0.25, 0.05], [0.4, 0.15], [3.05, 2.9], [2.8, 3.2],
                  [-4.5, -4.0], [np.nan, 0.0], [0.0, 0.0]])
    z[:6] += 0.01 * rng.standard_normal((6, 2))
    det = tracking.Detections(jnp.asarray(z), jnp.asarray([True] * 7 + [False]),
                              jnp.asarray([0, 1, 0, 0, 1, 0, 0, 0], jnp.int32),
                              jnp.asarray(rng.uniform(0.2, 1.0, 8)),
                              jnp.asarray(rng.uniform(0, 1, (8, F))))
    return state, det


def reference_prediction(state, params):
    F = np.kron(np.array([[1.0, 0.1], [0.0, 1.0]]), np.eye(2))
    Q = 0.5 * np.kron(np.array([[0.1**3 / 3, 0.1**2 / 2], [0.1**2 / 2, 0.1]]), np.eye(2))
    live = np.asarray(state.status) != tracking.FREE
    mean, cov = np.array(state.mean), np.array(state.cov)
    mean[live] = mean[live] @ F.T
    cov[live] = F @ cov[live] @ F.T + Q
    return mean, cov, live


def reference_gates(state, det, params):
    """d2 and log N(z; Hm, S) [K, M] with each detection's sensor noise, and the chi-square
    gate, in numpy / scipy."""
    mean, cov, live = reference_prediction(state, params)
    z, present = np.asarray(det.positions), np.asarray(det.mask)
    present = present & np.all(np.isfinite(z), -1)
    H = np.eye(2, 4)
    K, M = len(mean), len(z)
    d2, ll = np.full((K, M), np.inf), np.full((K, M), -np.inf)
    for k in np.flatnonzero(live):
        for j in np.flatnonzero(present):
            S = H @ cov[k] @ H.T + SENSOR_STD[np.asarray(det.sensor)[j]] ** 2 * np.eye(2)
            y = z[j] - H @ mean[k]
            d2[k, j] = y @ np.linalg.solve(S, y)
            ll[k, j] = multivariate_normal.logpdf(y, np.zeros(2), S)
    gated = d2 <= chi2.ppf(float(params.gate_prob), 2)
    return d2, gated, mean, cov, live, present, ll


@pytest.mark.parametrize("filt", ["kf", "ukf"])
def test_predict_is_the_constant_velocity_kalman_prediction_of_live_slots(filt):
    params = stage_params(filter=filt)
    state, _ = stage_scene(params)
    pred = tracker.predict(state, params)
    mean, cov, live = reference_prediction(state, params)
    np.testing.assert_allclose(np.asarray(pred.mean), mean, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(np.asarray(pred.cov), cov, rtol=1e-10, atol=1e-14)
    np.testing.assert_array_equal(np.asarray(pred.mean)[~live], np.asarray(state.mean)[~live])


def test_hypothesise_gates_with_each_sensors_noise_and_the_chi_square_quantile():
    params = stage_params(num_features=3)
    state, det = stage_scene(params)
    hyp = tracker.hypothesise(state, tracker.predict(state, params), det, params)
    d2, gated, _, _, live, present, ll = reference_gates(state, det, params)
    np.testing.assert_array_equal(np.asarray(hyp.live), live)
    np.testing.assert_array_equal(np.asarray(hyp.mask), present)
    np.testing.assert_allclose(np.asarray(hyp.innovations.d2), d2, rtol=1e-10)
    np.testing.assert_allclose(np.asarray(hyp.innovations.log_likelihood), ll, rtol=1e-10)
    np.testing.assert_array_equal(np.asarray(hyp.gated), gated)
    assert gated[0, :3].sum() >= 2 and gated[1, :3].sum() >= 2   # tracks 0 and 1 compete
    assert not gated[:, 5].any()                                  # clutter gated by nobody
    w, b = (np.asarray(a) for a in state.appearance)
    np.testing.assert_allclose(np.asarray(hyp.appearance),
                               1 / (1 + np.exp(-(w @ np.asarray(det.features).T + b[:, None]))),
                               rtol=1e-12)
    assert np.all(np.asarray(hyp.zs)[~present] == 0)


def brute_force_gnn(cost, gated):
    """Max-cardinality, then min-cost assignment inside the gates, by enumeration."""
    K = cost.shape[0]
    best = [(0, 0.0), [-1] * K]

    def visit(k, chosen, n, total):
        if k == K:
            if n > best[0][0] or (n == best[0][0] and total < best[0][1]):
                best[:] = [(n, total), list(chosen)]
            return
        visit(k + 1, chosen + [-1], n, total)
        for j in np.flatnonzero(gated[k]):
            if j not in chosen:
                visit(k + 1, chosen + [int(j)], n + 1, total + cost[k, j])

    visit(0, [], 0, 0.0)
    return np.array(best[1])


def check_hard_update(assoc, col, mean, cov, det, live):
    """The posterior of a hard association: a Kalman update with each track's detection."""
    H = np.eye(2, 4)
    z = np.asarray(det.positions)
    np.testing.assert_array_equal(np.asarray(assoc.col), col)
    np.testing.assert_array_equal(np.asarray(assoc.hit), col >= 0)
    used = np.zeros(z.shape[0], bool)
    used[col[col >= 0]] = True
    np.testing.assert_array_equal(np.asarray(assoc.used), used)
    for k in range(len(col)):
        if col[k] >= 0:
            R = SENSOR_STD[np.asarray(det.sensor)[col[k]]] ** 2 * np.eye(2)
            m, P = kalman_posterior(mean[k], cov[k], z[col[k]], H, R)
        else:
            m, P = mean[k], cov[k]
        np.testing.assert_allclose(np.asarray(assoc.posterior.mean[k]), m, rtol=1e-9,
                                   atol=1e-12)
        np.testing.assert_allclose(np.asarray(assoc.posterior.cov[k]), P, rtol=1e-8,
                                   atol=1e-12)


def test_associate_gnn_is_the_brute_force_optimum_of_the_three_term_cost():
    params = stage_params(num_features=3, alpha=0.7, beta=2.0)
    state, det = stage_scene(params)
    hyp = tracker.hypothesise(state, tracker.predict(state, params), det, params)
    assoc = tracker.associate_gnn(hyp, params)
    d2, gated, mean, cov, live, _, _ = reference_gates(state, det, params)
    cost = (d2 - 0.7 * np.asarray(hyp.appearance)
            - 2.0 * np.asarray(det.confidence)[None, :])
    col = brute_force_gnn(cost, gated)
    assert (col[:2] >= 0).all()
    check_hard_update(assoc, col, mean, cov, det, live)


def velocity_stage_scene(params, seed=0):
    """`stage_scene` with a trail of earlier positions and ages / misses that exercise each
    clamp of open_ptrack's baseline (window 4 scans): a full window, a young track, a miss
    streak longer than the window, one longer than twice the window."""
    state, det = stage_scene(params, seed)
    rng = np.random.default_rng(seed + 1)
    K, T = params.config.capacity, params.config.trail_length
    trail = np.asarray(state.mean)[:, None, :2] - 0.07 * np.arange(1, T + 1)[None, :, None]
    trail = trail + 0.03 * rng.standard_normal((K, T, 2))
    state = state._replace(trail=jnp.asarray(trail),
                           age=jnp.asarray([12, 9, 2, 12, 0, 0], jnp.int32),
                           misses=jnp.asarray([0, 5, 1, 9, 0, 0], jnp.int32))
    return state, det


def reference_baseline(state, params):
    """open_ptrack's ``Track::getMahalanobisDistance`` in seconds: the baseline starts at
    max(first detection, now - 1 window), then min(., last detection), then
    max(., now - 2 windows); the position there is the track's estimate of that scan."""
    dt, L = 0.1, params.config.velocity_window
    now = 100.0
    first = now - (np.asarray(state.age) + 1) * dt
    last = now - (np.asarray(state.misses) + 1) * dt
    t = np.maximum(first, now - L * dt)
    t = np.minimum(t, last)
    t = np.maximum(t, now - 2 * L * dt)
    lag = np.rint((now - t) / dt).astype(int)
    earlier = np.concatenate([np.asarray(state.mean)[:, None, :2], np.asarray(state.trail)], 1)
    return earlier[np.arange(len(lag)), lag - 1], lag * dt


def reference_position_velocity_d2(state, det, params):
    """Seed 001's motion distance as open_ptrack computes it, in numpy: position and the
    velocity measured from the track's position at the baseline's start, against the
    prediction, S = P + diag(R, 16 R)."""
    mean, cov, live = reference_prediction(state, params)
    past, span = reference_baseline(state, params)
    z, present = np.asarray(det.positions), np.asarray(det.mask)
    present = present & np.all(np.isfinite(z), -1)
    K, M = len(mean), len(z)
    d2, vel = np.full((K, M), np.inf), np.zeros((K, M, 2))
    for k in np.flatnonzero(live):
        for j in np.flatnonzero(present):
            r2 = SENSOR_STD[np.asarray(det.sensor)[j]] ** 2
            vel[k, j] = (z[j] - past[k]) / span[k]
            y = np.r_[z[j] - mean[k, :2], vel[k, j] - mean[k, 2:]]
            S = cov[k] + np.diag([r2, r2, 16 * r2, 16 * r2])
            d2[k, j] = y @ np.linalg.solve(S, y)
    return d2, d2 <= chi2.ppf(float(params.gate_prob), 4), vel


@pytest.mark.parametrize("distance", ["squared", "mahalanobis"])
def test_gnn_with_seed_001s_position_and_velocity_distance_is_the_brute_force_optimum(distance):
    params = stage_params(num_features=3, alpha=0.7, beta=2.0, motion_term="position_velocity",
                          velocity_window=4, distance=distance)
    state, det = velocity_stage_scene(params)
    _, span = reference_baseline(state, params)
    np.testing.assert_allclose(span[:4], [0.4, 0.6, 0.3, 0.8])   # each clamp once
    hyp = tracker.hypothesise(state, tracker.predict(state, params), det, params)
    d2, gated, vel = reference_position_velocity_d2(state, det, params)
    finite = np.isfinite(d2)
    np.testing.assert_allclose(np.asarray(hyp.motion_d2)[finite], d2[finite], rtol=1e-9)
    assert not np.isfinite(np.asarray(hyp.motion_d2)[~finite]).any()
    np.testing.assert_allclose(np.asarray(hyp.velocity)[finite], vel[finite], rtol=1e-12)
    np.testing.assert_array_equal(np.asarray(hyp.gated), gated)
    assoc = tracker.associate_gnn(hyp, params)
    motion = np.sqrt(d2) if distance == "mahalanobis" else d2
    cost = motion - 0.7 * np.asarray(hyp.appearance) - 2.0 * np.asarray(det.confidence)[None]
    col = brute_force_gnn(cost, gated)
    assert (col >= 0).sum() >= 2
    np.testing.assert_array_equal(np.asarray(assoc.col), col)
    # The update measures position and velocity (open_ptrack's 4-output observe model).
    mean, cov, live = reference_prediction(state, params)
    z = np.asarray(det.positions)
    for k in range(len(col)):
        m, P = mean[k], cov[k]
        if col[k] >= 0:
            r2 = SENSOR_STD[np.asarray(det.sensor)[col[k]]] ** 2
            m, P = kalman_posterior(m, P, np.r_[z[col[k]], vel[k, col[k]]], np.eye(4),
                                    np.diag([r2, r2, 16 * r2, 16 * r2]))
        np.testing.assert_allclose(np.asarray(assoc.posterior.mean[k]), m, rtol=1e-9,
                                   atol=1e-12)
        np.testing.assert_allclose(np.asarray(assoc.posterior.cov[k]), P, rtol=1e-8,
                                   atol=1e-12)


def test_over_one_scan_the_velocity_term_only_rescales_the_position_term():
    """With a baseline of one scan the velocity's innovation is the position's over dt (the
    prediction is p + v dt): the distance is a fixed quadratic form of the position innovation
    alone. Checked through the closed form with S's Schur complement."""
    params = stage_params(motion_term="position_velocity", velocity_window=1)
    state, det = stage_scene(params)
    state = state._replace(age=jnp.zeros(6, jnp.int32))
    hyp = tracker.hypothesise(state, tracker.predict(state, params), det, params)
    mean, cov, live = reference_prediction(state, params)
    z = np.asarray(det.positions)
    for k in np.flatnonzero(live):
        for j in range(4):
            r2 = SENSOR_STD[np.asarray(det.sensor)[j]] ** 2
            e = z[j] - mean[k, :2]
            y = np.r_[e, e / 0.1]
            S = cov[k] + np.diag([r2, r2, 16 * r2, 16 * r2])
            np.testing.assert_allclose(float(hyp.motion_d2[k, j]), y @ np.linalg.solve(S, y),
                                       rtol=1e-9)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_the_trail_holds_each_tracks_earlier_estimates_newest_first(dtype):
    """Run over scans of two walkers with gaps: after each scan, trail[k, i] is the track's
    mean i + 1 scans earlier while it lived, and its first position before that."""
    cfg = tracking.TrackerConfig(capacity=4, association="gnn", motion_term="position_velocity",
                                 velocity_window=3, confirm_hits=2, max_misses=4)
    params = tracking.TrackerParams.create(cfg, dt=0.1, q=0.5, r_std=(0.1,), dtype=dtype)
    T = 14
    t = np.arange(T) * 0.1
    z = np.stack([np.stack([-1 + 0.8 * t, 0.3 * t], -1), np.stack([2 - 0.5 * t, 1 + 0 * t], -1)],
                 1)
    mask = np.ones((T, 2), bool)
    mask[5:7, 0] = False                     # the first walker is missed twice
    mask[:4, 1] = False                      # the second appears at scan 4
    det = tracking.Detections(jnp.asarray(z, dtype), jnp.asarray(mask),
                              jnp.zeros((T, 2), jnp.int32), jnp.ones((T, 2), dtype),
                              jnp.zeros((T, 2, 0), dtype))
    _, seq = jax.jit(tracking.run)(tracking.init(cfg, dtype), det, params)
    assert seq.trail.dtype == dtype and np.isfinite(np.asarray(seq.mean)).all()
    ids, mean, trail = (np.asarray(seq.id), np.asarray(seq.mean), np.asarray(seq.trail))
    assert trail.shape == (T, 4, 5, 2)
    checked = 0
    for s in range(T):
        for k in np.flatnonzero(ids[s] >= 0):
            born = s - int(np.asarray(seq.age)[s, k])
            for i in range(5):
                src = s - 1 - i
                want = mean[src, k, :2] if src >= born else mean[born, k, :2]
                np.testing.assert_allclose(trail[s, k, i], want, rtol=0, atol=1e-12)
                checked += 1
    assert checked > 80
    # Tracks built for a config without the trail are refused with a clear error.
    plain = tracking.init(tracking.TrackerConfig(capacity=4, association="gnn"), dtype)
    with pytest.raises(ValueError, match="trail"):
        tracking.step(plain, jax.tree_util.tree_map(lambda x: x[0], det), params)


def test_detections_without_features_never_train_the_colour_classifier():
    """A NaN feature row (a laser person) scores 1/2 for every track, and an update that
    assigns it changes no classifier, nor serves as a negative for the others."""
    params = stage_params(num_features=3, alpha=0.7, beta=2.0)
    state, det = stage_scene(params)
    feats = np.array(det.features)
    feats[[0, 3]] = np.nan                                  # detections near tracks 0 and 2
    with_nan = det._replace(features=jnp.asarray(feats))
    hyp = tracker.hypothesise(state, tracker.predict(state, params), with_nan, params)
    np.testing.assert_allclose(np.asarray(hyp.appearance)[:, [0, 3]], 0.5)
    assoc = tracker.associate_gnn(hyp, params)
    new = tracker.manage(state, hyp, assoc, params)
    # Reference: the same update with the featureless detections masked out and unassigned.
    clean = det._replace(features=jnp.asarray(np.nan_to_num(feats)),
                         mask=det.mask.at[jnp.asarray([0, 3])].set(False))
    hyp_ref = tracker.hypothesise(state, tracker.predict(state, params), clean, params)
    col = np.where(np.isin(np.asarray(assoc.col), [0, 3]), -1, np.asarray(assoc.col))
    ref = tracker.appearance.update(state.appearance, hyp_ref.features, jnp.asarray(col),
                                    hyp_ref.mask, np.asarray(new.status) != tracking.FREE,
                                    params.appearance_lr)
    k = np.flatnonzero(np.isin(np.asarray(assoc.col), [0, 3]))
    assert k.size >= 1                                      # some track took a NaN detection
    np.testing.assert_allclose(np.asarray(new.appearance.weights)[k],
                               np.asarray(state.appearance.weights)[k])
    live = np.asarray(new.status) != tracking.FREE
    np.testing.assert_allclose(np.asarray(new.appearance.weights)[live],
                               np.asarray(ref.weights)[live], rtol=1e-9)
    assert np.isfinite(np.asarray(new.appearance.weights)).all()


def test_velocity_term_needs_gnn():
    with pytest.raises(ValueError, match="position_velocity"):
        tracking.TrackerConfig(association="jpda", motion_term="position_velocity")
    for bad in (0, 2.5, True):
        with pytest.raises(ValueError, match="velocity_window"):
            tracking.TrackerConfig(association="gnn", velocity_window=bad)
    cfg = tracking.TrackerConfig(association="gnn", motion_term="position_velocity",
                                 velocity_window=np.int64(3))
    assert cfg.trail_length == 5
    for bad in (0.0, float("nan")):
        with pytest.raises(ValueError, match="velocity_noise_ratio"):
            tracking.TrackerConfig(association="gnn", velocity_noise_ratio=bad)
    with pytest.raises(ValueError, match="distance"):
        tracking.TrackerConfig(association="gnn", distance="l1")


def test_associate_jpda_is_the_brute_force_marginals_and_the_mixture_update():
    params = stage_params("jpda", p_detect=0.9)
    state, det = stage_scene(params)
    hyp = tracker.hypothesise(state, tracker.predict(state, params), det, params)
    assoc = tracker.associate_jpda(hyp, params)
    _, gated, mean, cov, live, present, ll = reference_gates(state, det, params)
    beta = reference_marginals(ll, gated, live, present)
    M = beta.shape[1] - 1
    hit = live & (beta[:, M] < 0.5)
    col = np.where(hit & (beta[:, :M].max(1) > 0.5), beta[:, :M].argmax(1), -1)
    np.testing.assert_array_equal(np.asarray(assoc.hit), hit)
    np.testing.assert_array_equal(np.asarray(assoc.col), col)
    np.testing.assert_array_equal(np.asarray(assoc.used), beta[live, :M].sum(0) >= 0.5)
    assert hit[:2].all() and not hit[3]
    z = np.where(present[:, None], np.asarray(det.positions), 0.0)
    Rs = np.array([SENSOR_STD[s] ** 2 * np.eye(2) for s in np.asarray(det.sensor)])
    for k in range(len(live)):
        m, P = (mixture_reference(mean[k], cov[k], z[present], beta[k][np.append(present, True)],
                                  np.eye(2, 4), Rs[present]) if live[k] else (mean[k], cov[k]))
        np.testing.assert_allclose(np.asarray(assoc.posterior.mean[k]), m, rtol=1e-9,
                                   atol=1e-12)
        np.testing.assert_allclose(np.asarray(assoc.posterior.cov[k]), P, rtol=1e-8,
                                   atol=1e-12)


def reference_marginals(ll, gated, live, present):
    """Brute-force JPDA marginals [K, M + 1] over the live tracks and present detections."""
    K, M = gated.shape
    L = np.where(gated, np.exp(ll), 0.0)
    rows, cols = np.flatnonzero(live), np.flatnonzero(present)
    sub = brute_force_marginals(L[np.ix_(rows, cols)], 0.9, 0.05)
    beta = np.zeros((K, M + 1))
    beta[:, M] = 1.0
    beta[np.ix_(rows, np.r_[cols, M])] = sub
    return beta


def greedy_nn(beta):
    """NN-JPDA choice: the largest marginal first among open tracks and free detections."""
    K, M = beta.shape[0], beta.shape[1] - 1
    col, open_rows, taken = np.full(K, -1), set(range(K)), set()
    for _ in range(K):
        cands = [(beta[t, j], -t, -j) for t in open_rows for j in range(M + 1)
                 if j == M or (beta[t, j] > 0 and j not in taken)]
        _, t, j = max(cands)
        t, j = -t, -j
        open_rows.discard(t)
        if j < M:
            col[t] = j
            taken.add(j)
    return col


def test_associate_nn_jpda_takes_the_map_detection_greedily_then_a_kalman_update():
    params = stage_params("nn_jpda", p_detect=0.9)
    state, det = stage_scene(params)
    hyp = tracker.hypothesise(state, tracker.predict(state, params), det, params)
    assoc = tracker.associate_nn_jpda(hyp, params)
    _, gated, mean, cov, live, present, ll = reference_gates(state, det, params)
    col = np.where(live, greedy_nn(reference_marginals(ll, gated, live, present)), -1)
    assert (col[:2] >= 0).all()
    check_hard_update(assoc, col, mean, cov, det, live)


@pytest.mark.parametrize("assoc", ["gnn", "jpda", "nn_jpda"])
def test_step_is_its_stages_in_order(assoc):
    """`step` (jitted, as the closed loops call it) equals the stages called one by one, with
    the association picked by name; bit for bit."""
    params = params_for(assoc)
    associate = {"gnn": tracker.associate_gnn, "jpda": tracker.associate_jpda,
                 "nn_jpda": tracker.associate_nn_jpda}[assoc]

    def stages(state, det, params):
        hyp = tracker.hypothesise(state, tracker.predict(state, params), det, params)
        a = associate(hyp, params)
        return tracker.births(tracker.manage(state, hyp, a, params), hyp, a, params).tracks

    step, chain = jax.jit(tracking.step), jax.jit(stages)
    det, _ = scenario(3, T=25)
    a = b = tracking.init(params.config, jnp.float64)
    for t in range(25):
        frame = jax.tree.map(lambda x: x[t], det)
        a, b = step(a, frame, params), chain(b, frame, params)
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert int(a.next_id) >= 2


def managed_reference(state, hit, cov, params):
    """Plain-Python M-of-N confirmation and miss / std deletion of every slot."""
    cfg = params.config
    out = []
    for k in range(cfg.capacity):
        status, history = int(state.status[k]), int(state.history[k])
        hits, misses, age = int(state.hits[k]), int(state.misses[k]), int(state.age[k])
        if status != tracking.FREE:
            history = ((history << 1) | int(hit[k])) & ((1 << cfg.confirm_window) - 1)
            hits, misses, age = hits + hit[k], 0 if hit[k] else misses + 1, age + 1
            if status == tracking.TENTATIVE and bin(history).count("1") >= cfg.confirm_hits:
                status = tracking.CONFIRMED
            limit = (cfg.max_tentative_misses if status == tracking.TENTATIVE
                     else cfg.max_misses)
            if misses >= limit or max(cov[k][0, 0], cov[k][1, 1]) > cfg.max_position_std**2:
                status = tracking.FREE
        if status == tracking.FREE:
            out.append((tracking.FREE, -1, 0, 0, 0, 0))
        else:
            out.append((status, int(state.id[k]), age, hits, misses, history))
    return np.array(out)


def fake_association(hyp, hit, cov=None):
    cov = hyp.predicted.cov if cov is None else jnp.asarray(cov)
    K, M = hit.shape[0], hyp.zs.shape[0]
    return tracker.Association(Gaussian(hyp.predicted.mean, cov), jnp.asarray(hit),
                               jnp.full(K, -1, jnp.int32), jnp.zeros(M, bool))


def test_manage_confirms_m_of_n_and_deletes_after_misses_or_a_wide_covariance():
    params = stage_params()
    cfg = params.config
    state, det = stage_scene(params)
    # slot 0 confirmed, one miss short of deletion; slot 1 confirmed, two short; slot 2
    # tentative, one short; slot 3 tentative with 2 of 3 hits; slot 4 confirmed but too wide
    state = state._replace(
        status=jnp.asarray([2, 2, 1, 1, 2, 0], jnp.int32),
        id=jnp.asarray([4, 2, 6, 5, 1, -1], jnp.int32),
        misses=jnp.asarray([cfg.max_misses - 1, cfg.max_misses - 2,
                            cfg.max_tentative_misses - 1, 0, 0, 0], jnp.int32),
        history=jnp.asarray([1, 3, 1, 3, 31, 0], jnp.int32))
    hyp = tracker.hypothesise(state, tracker.predict(state, params), det, params)
    hit = np.array([False, False, False, True, True, False])
    cov = np.array(hyp.predicted.cov)
    cov[4, 0, 0] = 1.6**2
    out = tracker.manage(state, hyp, fake_association(hyp, hit, cov), params)
    ref = managed_reference(state, hit, cov, params)
    got = np.stack([np.asarray(x) for x in (out.status, out.id, out.age, out.hits, out.misses,
                                            out.history)], 1)
    np.testing.assert_array_equal(got, ref)
    assert got[:, 0].tolist() == [0, 2, 0, 2, 0, 0]
    assert int(out.next_id) == 7


def test_manage_deletes_a_confirmed_track_at_its_max_misses_th_miss():
    params = stage_params(max_misses=4)
    state, det = stage_scene(params)
    no_hit = np.zeros(6, bool)
    alive = []
    for _ in range(6):
        hyp = tracker.hypothesise(state, tracker.predict(state, params), det, params)
        state = tracker.manage(state, hyp, fake_association(hyp, no_hit), params)
        alive.append(int(state.status[0]))
    assert alive == [2, 2, 2, 0, 0, 0], alive


def test_manage_merges_the_weaker_of_two_close_tracks():
    params = stage_params(merge_distance=0.4)
    state, det = stage_scene(params)
    hyp = tracker.hypothesise(state, tracker.predict(state, params), det, params)
    hit = np.array([True, True, True, True, False, False])
    cases = {  # (status, hits, id) of slots 0 and 1 -> the slot that survives
        "confirmed beats tentative": ([1, 2], [9, 3], [1, 2], 1),
        "more hits win": ([2, 2], [5, 6], [1, 2], 1),
        "the older id wins": ([2, 2], [6, 6], [3, 2], 1),
    }
    for name, (status, hits, ids, keep) in cases.items():
        s = state._replace(status=state.status.at[:2].set(jnp.asarray(status, jnp.int32)),
                           history=state.history.at[:2].set(0),
                           hits=state.hits.at[:2].set(jnp.asarray(hits, jnp.int32) - 1),
                           id=state.id.at[:2].set(jnp.asarray(ids, jnp.int32)))
        out = tracker.manage(s, hyp, fake_association(hyp, hit), params)
        live = np.asarray(out.status[:2]) != tracking.FREE
        assert live.tolist() == [keep == 0, keep == 1], name
        assert (np.asarray(out.status[2:4]) != tracking.FREE).all(), name


def test_births_fill_free_slots_in_order_with_increasing_ids():
    params = stage_params(birth_confidence=0.5, init_speed_std=0.8)
    state, _ = stage_scene(params)
    K, M = 6, 8
    state = state._replace(status=jnp.asarray([0, 2, 0, 1, 0, 0], jnp.int32),
                           id=jnp.asarray([-1, 2, -1, 5, -1, -1], jnp.int32),
                           num_dropped=jnp.int32(3))
    z = np.array([[0.35, 0.1], [1.5, -2.0], [-1.0, -1.0], [4.0, 0.0], [5.0, -3.0],
                  [-4.0, -4.0], [0.0, 4.5], [2.0, -4.5]])
    conf = np.array([1.0, 1.0, 0.2, 0.9, 0.6, 1.0, 0.7, 0.8])
    det = tracking.Detections(jnp.asarray(z), jnp.ones(M, bool),
                              jnp.asarray([0, 0, 0, 1, 0, 1, 0, 0], jnp.int32),
                              jnp.asarray(conf), jnp.zeros((M, 0)))
    hyp = tracker.hypothesise(state, tracker.predict(state, params), det, params)
    used = np.zeros(M, bool)
    used[1] = True
    assoc = tracker.Association(hyp.predicted, jnp.zeros(K, bool), jnp.full(K, -1, jnp.int32),
                                jnp.asarray(used))
    out = tracker.births(state, hyp, assoc, params)
    # detection 0 is in track 1's gate, 1 is used, 2 is below the confidence threshold; 3..7
    # are eligible and the four free slots 0, 2, 4, 5 take 3, 4, 5, 6; 7 finds no slot
    assert bool(np.asarray(hyp.gated)[1, 0])
    np.testing.assert_array_equal(np.asarray(out.born), [0, 0, 0, 1, 1, 1, 1, 0])
    np.testing.assert_array_equal(np.asarray(out.slot), [6, 6, 6, 0, 2, 4, 5, 6])
    tr = out.tracks
    np.testing.assert_array_equal(np.asarray(tr.id), [7, 2, 8, 5, 9, 10])
    assert int(tr.next_id) == 11 and int(tr.num_dropped) == 4
    for j, k in zip([3, 4, 5, 6], [0, 2, 4, 5]):
        r2 = SENSOR_STD[int(det.sensor[j])] ** 2
        np.testing.assert_array_equal(np.asarray(tr.mean[k]), [*z[j], 0.0, 0.0])
        np.testing.assert_allclose(np.asarray(tr.cov[k]), np.diag([r2, r2, 0.64, 0.64]),
                                   rtol=1e-12)
        assert [int(tr.status[k]), int(tr.hits[k]), int(tr.history[k]), int(tr.age[k]),
                int(tr.misses[k])] == [tracking.TENTATIVE, 1, 1, 0, 0]
    for k in (1, 3):  # live tracks are untouched
        for x, y in zip(jax.tree.leaves(tr), jax.tree.leaves(state)):
            if np.ndim(x):
                np.testing.assert_array_equal(np.asarray(x)[k], np.asarray(y)[k])


def test_births_with_merge_distance_start_one_track_per_cluster_of_detections():
    params = stage_params(merge_distance=0.4)
    state = tracking.init(params.config, jnp.float64)
    z = np.array([[1.0, 1.0], [1.2, 1.1], [3.0, 0.0], [1.0, 1.35], [3.5, 0.0]])
    det = tracking.make_detections(z, 6, sensor=[1, 0, 0, 1, 0])
    hyp = tracker.hypothesise(state, tracker.predict(state, params), det, params)
    assoc = tracker.Association(hyp.predicted, jnp.zeros(6, bool), jnp.full(6, -1, jnp.int32),
                                jnp.zeros(6, bool))
    out = tracker.births(state, hyp, assoc, params)
    # 1 and 3 are within 0.4 m of the earlier 0; 4 is 0.5 m from 2
    np.testing.assert_array_equal(np.asarray(out.born), [1, 0, 1, 0, 1, 0])
    np.testing.assert_array_equal(np.asarray(out.tracks.id[:3]), [0, 1, 2])


def test_stages_reject_arguments_of_the_wrong_kind():
    params = stage_params()
    state, det = stage_scene(params)
    pred = tracker.predict(state, params)
    hyp = tracker.hypothesise(state, pred, det, params)
    assoc = tracker.associate(hyp, params)
    with pytest.raises(TypeError, match="params must be TrackerParams"):
        tracker.predict(state, params.config)
    with pytest.raises(TypeError, match="predicted must be"):
        tracker.hypothesise(state, (pred.mean, pred.cov), det, params)
    with pytest.raises(TypeError, match="hypotheses must be a tracker.Hypotheses"):
        tracker.associate_jpda(assoc, params)
    with pytest.raises(TypeError, match="assoc must be a tracker.Association"):
        tracker.manage(state, hyp, hyp, params)
    with pytest.raises(ValueError, match="capacity"):
        tracker.births(tracking.init(tracking.TrackerConfig(capacity=3)), hyp, assoc, params)


@pytest.mark.parametrize("assoc", ["jpda", "gnn", "nn_jpda", "gnn+velocity"])
def test_an_empty_frame_equals_an_all_masked_frame_and_zero_scans_change_nothing(assoc):
    extra = {}
    if assoc == "gnn+velocity":
        assoc, extra = "gnn", dict(motion_term="position_velocity", velocity_window=2)
    cfg = tracker.TrackerConfig(capacity=4, association=assoc, **extra)
    params = tracker.TrackerParams.create(cfg, dtype=jnp.float64)
    state = tracker.step(tracker.init(cfg, jnp.float64),
                         tracker.make_detections([[1.0, 2.0], [3.0, 0.5]], 3), params)
    empty = tracker.step(state, tracker.make_detections(np.zeros((0, 2)), 0), params)
    masked = tracker.step(state, tracker.make_detections(np.zeros((0, 2)), 3), params)
    for a, b in zip(jax.tree_util.tree_leaves(empty), jax.tree_util.tree_leaves(masked)):
        np.testing.assert_array_equal(a, b)
    none = jax.tree_util.tree_map(lambda x: x[None][:0], tracker.make_detections([[1.0, 2.0]], 3))
    final, seq = tracker.run(state, none, params)
    for a, b in zip(jax.tree_util.tree_leaves(final), jax.tree_util.tree_leaves(state)):
        np.testing.assert_array_equal(a, b)
    assert seq.id.shape == (0, 4)


@pytest.mark.parametrize("bad", [dict(q=float("nan")), dict(r_std=(0.1, float("nan"), 0.2)),
                                 dict(dt=float("inf")), dict(gamma=float("nan"))])
def test_non_finite_parameters_are_refused(bad):
    with pytest.raises(ValueError, match="finite"):
        tracker.TrackerParams.create(tracker.TrackerConfig(), **bad)


# ---------------------------------------------------------------------------------------------
# Several sensors in one scan: the sequential per-sensor update (seed 003).

THREE_STD = (0.1, 0.3, 0.2)


def _three_sensor_scan():
    """Two confirmed tracks 3 m apart, each seen once by each of three sensors."""
    rng = np.random.default_rng(3)
    mean = np.array([[0.0, 0.0, 0.5, 0.0], [3.0, 1.0, 0.0, -0.4], [0, 0, 0, 0], [0, 0, 0, 0]])
    cov = np.stack([np.diag([0.05, 0.06, 0.2, 0.25])] * 4)
    z = np.concatenate([mean[:2, :2] + 0.05 + s * 0.02 + 0.02 * rng.standard_normal((2, 2))
                        for s in range(3)])
    sensor = np.repeat(np.arange(3), 2)
    return mean, cov, z, sensor


@pytest.mark.parametrize("assoc", ["jpda", "nn_jpda"])
def test_sequential_sensor_update_equals_the_stacked_kalman_update(assoc):
    """With certain association (P_D ~ 1, negligible clutter, people far apart), updating
    sensor by sensor is the Kalman update with the three sensors' measurements stacked (block
    diagonal R): the linear-Gaussian updates commute. A joint JPDA instead lets each track take
    one of its three detections, so its covariance stays larger."""
    mean, cov, z, sensor = _three_sensor_scan()
    out = {}
    for update in ("sequential", "joint"):
        cfg = tracking.TrackerConfig(capacity=4, association=assoc, sensor_update=update)
        params = tracking.TrackerParams.create(cfg, dt=0.1, r_std=THREE_STD, p_detect=0.999,
                                               clutter_density=1e-6, dtype=jnp.float64)
        state = tracking.init(cfg, jnp.float64)._replace(
            mean=jnp.asarray(mean), cov=jnp.asarray(cov),
            status=jnp.asarray([2, 2, 0, 0], jnp.int32))
        det = tracking.Detections(jnp.asarray(z), jnp.ones(6, bool), jnp.asarray(sensor, jnp.int32),
                                  jnp.ones(6), jnp.zeros((6, 0)))
        pred = tracker.predict(state, params)
        hyp = tracker.hypothesise(state, pred, det, params)
        out[update] = (tracker.associate(hyp, params), pred)
    assoc_seq, pred = out["sequential"]
    H = np.eye(2, 4)
    for k in range(2):
        rows = np.flatnonzero(np.arange(6) % 2 == k)
        Hs = np.concatenate([H] * 3)
        Rs = np.diag(np.repeat(np.square(THREE_STD), 2))
        m, P = np.asarray(pred.mean[k]), np.asarray(pred.cov[k])
        S = Hs @ P @ Hs.T + Rs
        K = P @ Hs.T @ np.linalg.inv(S)
        m_ref = m + K @ (z[rows].reshape(-1) - Hs @ m)
        P_ref = P - K @ S @ K.T
        np.testing.assert_allclose(np.asarray(assoc_seq.posterior.mean[k]), m_ref, atol=1e-6)
        np.testing.assert_allclose(np.asarray(assoc_seq.posterior.cov[k]), P_ref, atol=1e-7)
        joint_cov = np.asarray(out["joint"][0].posterior.cov[k])
        assert np.trace(joint_cov[:2, :2]) > 1.2 * np.trace(P_ref[:2, :2])
    np.testing.assert_array_equal(np.asarray(assoc_seq.hit), [True, True, False, False])
    np.testing.assert_array_equal(np.asarray(assoc_seq.col), [0, 1, -1, -1])
    assert np.asarray(assoc_seq.used).all()
    # the free slots keep their predictions
    np.testing.assert_array_equal(np.asarray(assoc_seq.posterior.mean[2:]),
                                  np.asarray(pred.mean[2:]))


def test_sequential_sensor_update_runs_a_scan_sequence_and_needs_jpda_with_cv():
    det, truth = _two_sensor_scenario()
    cfg = tracking.TrackerConfig(capacity=6, association="nn_jpda", sensor_update="sequential",
                                 merge_distance=0.4)
    p = tracking.TrackerParams.create(cfg, dt=0.1, q=0.5, r_std=(0.05, 0.3), dtype=jnp.float64)
    _, seq = jax.jit(tracking.run)(tracking.init(cfg, jnp.float64), det, p)
    confirmed = np.asarray(seq.status) == tracking.CONFIRMED
    assert confirmed[10:].sum(1).min() == 1 and confirmed[10:].sum(1).max() == 1
    err = np.linalg.norm(np.asarray(seq.mean)[..., :2] - truth[:, None], axis=-1)
    assert np.all(err[10:][confirmed[10:]] < 0.15)
    for bad in (dict(association="gnn"), dict(motion="imm")):
        with pytest.raises(ValueError, match="sensor_update"):
            tracking.TrackerConfig(sensor_update="sequential", **bad)
    with pytest.raises(ValueError, match="sensor_update"):
        tracking.TrackerConfig(sensor_update="stacked")


@pytest.mark.parametrize("assoc, update", [("gnn", "joint"), ("jpda", "joint"),
                                           ("nn_jpda", "joint"), ("jpda", "sequential"),
                                           ("nn_jpda", "sequential")])
def test_a_tentative_track_takes_no_detection_inside_a_confirmed_tracks_gate(assoc, update):
    """A confirmed track at the origin (seen by the 0.1 m sensor) and a tentative one 1.6 m
    away. A 0.3 m detection between them lies in both gates: without the option the tentative
    track takes it, with it the tentative track misses (its posterior is its prediction) and
    the detection starts no track. One outside the confirmed gate still updates it."""
    mean = np.array([[0.0, 0.0, 0.0, 0.0], [1.6, 0.0, 0.0, 0.0], [0, 0, 0, 0], [0, 0, 0, 0]])
    cov = np.stack([np.diag([0.01, 0.01, 0.1, 0.1]), np.diag([0.09, 0.09, 0.25, 0.25])]
                   + [np.eye(4)] * 2)
    between, beyond = [1.2, 0.0], [2.0, 0.05]
    out = {}
    for option in (False, True):
        cfg = tracking.TrackerConfig(capacity=4, association=assoc, sensor_update=update,
                                     tentative_outside_confirmed=option)
        params = tracking.TrackerParams.create(cfg, dt=0.1, q=0.5, r_std=(0.1, 0.3),
                                               clutter_density=0.05, dtype=jnp.float64)
        state = tracking.init(cfg, jnp.float64)._replace(
            mean=jnp.asarray(mean), cov=jnp.asarray(cov),
            status=jnp.asarray([2, 1, 0, 0], jnp.int32), id=jnp.asarray([0, 1, -1, -1],
                                                                         jnp.int32),
            hits=jnp.asarray([5, 1, 0, 0], jnp.int32), history=jnp.asarray([31, 1, 0, 0],
                                                                             jnp.int32))
        pred = tracker.predict(state, params)
        for name, z in (("between", between), ("beyond", beyond)):
            det = tracking.Detections(jnp.asarray([[0.02, 0.0], z]), jnp.ones(2, bool),
                                      jnp.asarray([0, 1], jnp.int32), jnp.ones(2),
                                      jnp.zeros((2, 0)))
            hyp = tracker.hypothesise(state, pred, det, params)
            a = tracker.associate(hyp, params)
            born = tracker.births(tracker.manage(state, hyp, a, params), hyp, a, params).born
            out[option, name] = (np.asarray(hyp.gated), a, np.asarray(born))
        # an empty scan: no pair, no hit, every track as predicted
        empty = tracking.Detections(jnp.zeros((0, 2)), jnp.zeros(0, bool),
                                    jnp.zeros(0, jnp.int32), jnp.ones(0), jnp.zeros((0, 0)))
        hyp = tracker.hypothesise(state, pred, empty, params)
        a = tracker.associate(hyp, params)
        assert hyp.gated.shape == (4, 0) and not np.asarray(a.hit).any()
        np.testing.assert_allclose(np.asarray(a.posterior.mean), np.asarray(pred.mean))
    off, on = out[False, "between"], out[True, "between"]
    np.testing.assert_array_equal(off[0][:2], [[True, True], [False, True]])
    np.testing.assert_array_equal(on[0][:2], [[True, True], [False, False]])
    assert bool(off[1].hit[1]) and not bool(on[1].hit[1])
    np.testing.assert_allclose(np.asarray(on[1].posterior.mean[1]), np.asarray(pred.mean[1]))
    np.testing.assert_allclose(np.asarray(on[1].posterior.cov[1]), np.asarray(pred.cov[1]))
    assert bool(on[1].hit[0]) and not on[2].any()
    # outside the confirmed track's gate: the option changes nothing
    off_b, on_b = out[False, "beyond"], out[True, "beyond"]
    assert not off_b[0][0, 1] and bool(on_b[1].hit[1])
    np.testing.assert_array_equal(off_b[0], on_b[0])
    np.testing.assert_allclose(np.asarray(on_b[1].posterior.mean),
                               np.asarray(off_b[1].posterior.mean))


@pytest.mark.parametrize("assoc, update", [("gnn", "joint"), ("nn_jpda", "joint"),
                                           ("nn_jpda", "sequential")])
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_a_detection_that_may_not_start_a_track_confirms_none(assoc, update, dtype):
    """A confirmed track at the origin and a tentative one at (2, 0), each with a detection on
    it. With ``tentative_from_births``, a detection under the birth confidence updates the
    confirmed track but not the tentative one (its posterior is its prediction, no hit); at
    the birth confidence it updates both. Without the option confidence changes nothing."""
    mean = np.array([[0.0, 0.0, 0.0, 0.0], [2.0, 0.0, 0.0, 0.0], [0, 0, 0, 0]])
    cov = np.stack([np.diag([0.01, 0.01, 0.1, 0.1]), np.diag([0.09, 0.09, 0.25, 0.25]),
                    np.eye(4)])
    hits = {}
    for option in (False, True):
        cfg = tracking.TrackerConfig(capacity=3, association=assoc, sensor_update=update,
                                     tentative_from_births=option)
        params = tracking.TrackerParams.create(cfg, dt=0.1, q=0.5, r_std=(0.1, 0.3),
                                               clutter_density=0.05, birth_confidence=0.75,
                                               dtype=dtype)
        state = tracking.init(cfg, dtype)._replace(
            mean=jnp.asarray(mean, dtype), cov=jnp.asarray(cov, dtype),
            status=jnp.asarray([2, 1, 0], jnp.int32), id=jnp.asarray([0, 1, -1], jnp.int32),
            hits=jnp.asarray([5, 1, 0], jnp.int32), history=jnp.asarray([31, 1, 0], jnp.int32))
        pred = tracker.predict(state, params)
        for conf in (0.5, 0.75):
            det = tracking.Detections(jnp.asarray([[0.05, 0.0], [2.1, 0.05]], dtype),
                                      jnp.ones(2, bool), jnp.asarray([1, 1], jnp.int32),
                                      jnp.full(2, conf, dtype), jnp.zeros((2, 0), dtype))
            hyp = tracker.hypothesise(state, pred, det, params)
            a = tracker.associate(hyp, params)
            hits[option, conf] = np.asarray(a.hit)[:2]
            if option and conf == 0.5:
                np.testing.assert_allclose(np.asarray(a.posterior.mean[1]),
                                           np.asarray(pred.mean[1]), rtol=1e-6)
    np.testing.assert_array_equal(hits[True, 0.5], [True, False])
    for key in ((False, 0.5), (False, 0.75), (True, 0.75)):
        np.testing.assert_array_equal(hits[key], [True, True])
