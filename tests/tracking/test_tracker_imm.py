"""The walking / standing IMM motion of the multi-target tracker (``TrackerConfig(motion="imm")``):
with the walking mode forced it is the constant-velocity tracker; a person who stops is seen
standing and located better than by the constant-velocity tracker; its parameters have finite
gradients, float32 runs, bad parameters are refused."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack import tracking
from jaxtrack.tracking import tracker

M = 6
DT = 0.1


def params_for(assoc, motion, dtype=jnp.float64, **kw):
    cfg = tracking.TrackerConfig(capacity=4, association=assoc, motion=motion)
    return tracking.TrackerParams.create(cfg, dt=DT, q=0.5, r_std=(0.1,), clutter_density=0.02,
                                         dtype=dtype, **kw)


def run(det, params, dtype=jnp.float64):
    return jax.jit(tracking.run)(tracking.init(params.config, dtype), det, params)


def detections(points, dtype=jnp.float64):
    """[T, M] `Detections` from a [T, M, 2] array with NaN where there is no detection."""
    mask = np.all(np.isfinite(points), -1)
    T = points.shape[0]
    return tracking.Detections(jnp.asarray(np.where(mask[..., None], points, 0.0), dtype),
                               jnp.asarray(mask), jnp.zeros((T, M), jnp.int32),
                               jnp.ones((T, M), dtype), jnp.zeros((T, M, 0), dtype))


def crossing_scene(seed=0, T=50):
    """Two people crossing, missed detections, clutter: a scripted scene of every stage."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) * DT
    truth = np.stack([np.stack([-2.0 + 0.8 * t, -2.0 + 0.8 * t], -1),
                      np.stack([-2.0 + 0.8 * t, 2.0 - 0.8 * t], -1)], 1)
    pts = np.full((T, M, 2), np.nan)
    for k in range(T):
        dets = [truth[k, i] + 0.1 * rng.standard_normal(2) for i in range(2)
                if rng.random() < 0.9]
        dets += list(rng.uniform(-3, 3, (rng.poisson(1.0), 2)))
        dets = dets[:M]
        if dets:
            pts[k, :len(dets)] = dets
    return detections(pts)


def walk_stop_walk(seed, walk=3.0, stop=3.0, speed=1.0, std=0.1):
    """One person walking along x at ``speed``, standing still for ``stop`` seconds, walking
    again; a detection (noise ``std``) in 95 % of the scans. Returns detections, the truth
    [T, 2] and the [T] bools of the standing scans."""
    rng = np.random.default_rng(seed)
    n_walk, n_stop = round(walk / DT), round(stop / DT)
    v = np.concatenate([np.full(n_walk, speed), np.zeros(n_stop), np.full(n_walk, speed)])
    x = np.concatenate([[0.0], np.cumsum(v[:-1] * DT)])
    truth = np.stack([x, 0.5 * np.ones_like(x)], -1)
    pts = np.full((len(x), M, 2), np.nan)
    seen = rng.random(len(x)) < 0.95
    pts[seen, 0] = truth[seen] + std * rng.standard_normal((seen.sum(), 2))
    return detections(pts), truth, v == 0


def forced_walking(params):
    """The IMM with the walking mode only: identity transition, new tracks walking."""
    dtype = params.dt.dtype
    return params._replace(mode_logits=jnp.array([[0.0, -jnp.inf], [-jnp.inf, 0.0]], dtype),
                           logit_init_standing=jnp.asarray(-jnp.inf, dtype))


@pytest.mark.parametrize("assoc", ["gnn", "jpda", "nn_jpda"])
def test_imm_with_the_walking_mode_forced_is_the_constant_velocity_tracker(assoc):
    det = crossing_scene()
    _, cv = run(det, params_for(assoc, "cv"))
    _, mm = run(det, forced_walking(params_for(assoc, "imm")))
    for name in ("id", "status", "hits", "misses", "history"):
        np.testing.assert_array_equal(getattr(mm, name), getattr(cv, name), err_msg=name)
    assert int(np.max(cv.id)) >= 1  # both people tracked
    np.testing.assert_allclose(mm.mean, cv.mean, rtol=0, atol=1e-9)
    np.testing.assert_allclose(mm.cov, cv.cov, rtol=0, atol=1e-9)
    live = np.asarray(mm.status) != tracking.FREE
    probs = np.exp(np.asarray(mm.modes.log_mode_probs))[live]
    np.testing.assert_array_equal(probs[:, tracker.WALKING], 1.0)


def _stop_statistics(assoc, seeds, dtype=jnp.float64):
    """Per seed: the mean standing probability of the person's track over the standing scans
    (after the first second) and over the walking ones, and the position RMS while standing,
    for the IMM; and the position RMS while standing of the constant-velocity tracker."""
    out = []
    for seed in seeds:
        det, truth, standing = walk_stop_walk(seed)
        settled = standing & (np.cumsum(standing) > round(1.0 / DT))
        walking = ~standing & (np.arange(len(standing)) > round(1.0 / DT))
        row = []
        for motion in ("imm", "cv"):
            _, seq = run(det, params_for(assoc, motion, dtype), dtype)
            assert (np.asarray(seq.id)[:, 0] == 0).all()  # one track, slot 0, from the start
            err = np.linalg.norm(np.asarray(seq.mean)[:, 0, :2] - truth, axis=-1)
            row.append(np.sqrt(np.mean(err[standing] ** 2)))
            if motion == "imm":
                p = np.exp(np.asarray(seq.modes.log_mode_probs, float))[:, 0, tracker.STANDING]
                row[:0] = [p[settled].mean(), p[walking].mean()]
        out.append(row)
    return np.array(out)  # [seeds, (p standing | stopped, p standing | walking, imm, cv)]


def test_a_person_who_stops_is_seen_standing_and_located_better_than_with_cv():
    stats = _stop_statistics("jpda", range(4))
    p_stop, p_walk, rms_imm, rms_cv = stats.T
    # Measured over these 4 seeds (GNN gives the same to 1e-3): standing probability
    # 0.889-0.906 while stopped and 0.092-0.146 while walking; position RMS while stopped
    # 0.051-0.064 m with the IMM against 0.088-0.090 m with constant velocity (ratio <= 0.72).
    assert (p_stop > 0.8).all() and (p_walk < 0.25).all()
    assert (rms_imm < 0.85 * rms_cv).all()


def test_gradients_of_a_tracking_loss_wrt_the_imm_parameters_are_finite():
    det, truth, _ = walk_stop_walk(0, walk=0.8, stop=0.8)
    base = params_for("jpda", "imm")

    def loss(leaves):
        p = base._replace(mode_logits=leaves[0], log_q_standing=leaves[1],
                          logit_init_standing=leaves[2])
        _, seq = tracking.run(tracking.init(p.config, jnp.float64), det, p)
        return jnp.mean(jnp.sum((seq.mean[:, 0, :2] - truth) ** 2, -1))

    leaves = (base.mode_logits, base.log_q_standing, base.logit_init_standing)
    grads = jax.jit(jax.grad(loss))(leaves)
    for g in grads:
        assert np.all(np.isfinite(g))
    assert float(jnp.abs(grads[1])) > 0 and float(jnp.max(jnp.abs(grads[0]))) > 0


def test_float32_runs_and_agrees_with_float64():
    det, truth, standing = walk_stop_walk(1)
    out = {}
    for dtype in (jnp.float32, jnp.float64):
        d = jax.tree.map(lambda x: x.astype(dtype) if x.dtype.kind == "f" else x, det)
        _, seq = run(d, params_for("jpda", "imm", dtype), dtype)
        assert seq.mean.dtype == dtype and seq.modes.log_mode_probs.dtype == dtype
        assert np.all(np.isfinite(np.asarray(seq.mean)))
        out[dtype] = seq
    np.testing.assert_allclose(out[jnp.float32].mean[:, 0], out[jnp.float64].mean[:, 0],
                               atol=1e-4)
    np.testing.assert_allclose(np.exp(out[jnp.float32].modes.log_mode_probs[:, 0]),
                               np.exp(out[jnp.float64].modes.log_mode_probs[:, 0]), atol=1e-3)


def test_tracks_have_fixed_mode_shapes_for_both_motions():
    for motion, D in (("cv", 0), ("imm", 2)):
        state = tracking.init(tracking.TrackerConfig(capacity=5, motion=motion))
        assert state.modes.means.shape == (5, D, 4)
        assert state.modes.covs.shape == (5, D, 4, 4)
        assert state.modes.log_mode_probs.shape == (5, D)


@pytest.mark.parametrize("bad", [dict(mode_transition=((1.0, 0.0), (0.1, 0.9))),
                                 dict(mode_transition=((0.9, 0.2), (0.1, 0.9))),
                                 dict(mode_transition=((float("nan"), 0.5), (0.1, 0.9))),
                                 dict(q_standing=0.0), dict(q_standing=float("inf")),
                                 dict(init_standing=1.0), dict(init_standing=float("nan"))])
def test_bad_imm_parameters_are_refused(bad):
    with pytest.raises(ValueError, match="mode_transition|q_standing|init_standing"):
        tracking.TrackerParams.create(tracking.TrackerConfig(motion="imm"), **bad)


def test_mismatched_motion_is_refused():
    with pytest.raises(ValueError, match="motion"):
        tracking.TrackerConfig(motion="ca")
    with pytest.raises(ValueError, match="mode_transition"):
        tracking.TrackerParams.create(mode_transition=(0.9, 0.1))
    params = params_for("jpda", "imm")
    det = tracking.make_detections([[0.0, 1.0]], capacity=M)
    with pytest.raises(ValueError, match="motion"):
        tracking.step(tracking.init(tracking.TrackerConfig(capacity=4)), det, params)
    with pytest.raises(ValueError, match="motion"):
        tracker.predict_modes(tracking.init(tracking.TrackerConfig(capacity=4)),
                              params_for("jpda", "cv"))
