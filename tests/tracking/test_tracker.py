"""The fixed-capacity multi-target tracker: identities through a crossing, births, deaths, slot
recycling, association modes, boundary checks."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack import metrics, tracking

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
