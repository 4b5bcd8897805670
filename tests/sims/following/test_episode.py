"""Person-following episode: runs under jit + vmap, its metrics agree with direct recomputation
from the recorded frames (CLEAR MOT with py-motmetrics), bad configurations are refused."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.control import behaviour
from jaxtrack.tracking import user
from sims.following import episode as ep
from sims.following import scene

DURATION = 3.0


@pytest.fixture(scope="module")
def run():
    sc = scene.build(num_people=4)
    gnn = user.MultiTargetConfig(tracker=dataclasses.replace(user.TRACKER, association="gnn",
                                                             capacity=6))
    cfg = ep.EpisodeConfig(sc, gnn, distractors=3, duration=DURATION)
    params = ep.make_params(cfg)
    rollout = jax.jit(jax.vmap(ep.make_rollout(cfg), (0, None)))
    frames = rollout(jax.random.split(jax.random.PRNGKey(3), 2), params)
    return cfg, params, frames


def test_rollout_shapes_and_physics(run):
    cfg, params, f = run
    T = cfg.num_frames
    assert f.robot.shape == (2, T, 3) and f.people.shape == (2, T, 4, 2)
    assert f.pan is None  # a fixed camera by default
    for name, leaf in f._asdict().items():
        if leaf is None:
            continue
        leaf = np.asarray(leaf, float)
        if name in ("laser_user", "rgbd_user"):  # inf: no detection in that frame
            assert not np.any(np.isnan(leaf)) and np.isfinite(leaf).mean() > 0.5
        else:
            assert np.all(np.isfinite(leaf)), name
    # The robot moves by MJX physics under the limited command: never faster than v_max.
    step = np.linalg.norm(np.diff(np.asarray(f.robot)[..., :2], axis=1), axis=-1)
    assert step.max() <= float(params.follower.v_max) * cfg.control_dt * 1.05
    assert step.max() > 0.0
    # The user is tracked from the start.
    assert np.asarray(f.lost).mean() < 0.2
    # No sensor behind: the robot never reverses; its body never touches a table or chair leg.
    assert np.asarray(f.u)[..., 0].min() >= 0.0
    legs, radii = cfg.scene.furniture_circles()
    d = np.linalg.norm(np.asarray(f.robot)[..., None, :2] - legs, axis=-1) - radii
    assert d.min() > cfg.scene.robot_radius


def first_hit_owner(origin, angles, centres, radii, max_range):
    """[B] index of the circle each beam hits first (-1: none), by numpy ray-circle roots."""
    d = np.stack([np.cos(angles), np.sin(angles)], -1)
    m = origin - centres                                   # [C, 2]
    b = d @ m.T                                            # [B, C]
    disc = b**2 - ((m**2).sum(-1) - radii**2)[None]
    t = np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
    t = np.where(t >= 0, t, np.inf)
    owner = np.argmin(t, 1)
    return np.where(t[np.arange(len(angles)), owner] < max_range, owner, -1)


def test_ground_truth_visibility_is_any_beam_whose_return_is_a_leg():
    from sims.following import lidar
    lcfg = lidar.LaserConfig()
    angles = np.asarray(lidar.beam_angles(lcfg, jnp.float64))
    rng = np.random.default_rng(11)
    P = 6
    checked = {True: 0, False: 0}
    for _ in range(20):
        centre = rng.uniform([0.8, -2.5], [4.5, 2.5], (P, 2))
        # Crowd the people along a few bearings so that some hide others, wholly or in part.
        centre[3:] = centre[:3] * rng.uniform(1.3, 1.8, (3, 1)) + rng.normal(0, 0.05, (3, 2))
        legs = centre[:, None] + np.array([[0.0, 0.1], [0.0, -0.1]]) + rng.normal(0, 0.03,
                                                                                   (P, 2, 2))
        radii = np.full((P, 2), 0.06)
        circles = lidar.Circles(jnp.asarray(legs.reshape(-1, 2)), jnp.asarray(radii.ravel()),
                                jnp.ones(2 * P, bool))
        walls = lidar.Walls(jnp.zeros((0, 2, 2)), jnp.zeros(0, bool))
        ranges = lidar.cast(jnp.zeros(3), jnp.asarray(angles), circles, walls, lcfg.max_range)
        got = np.asarray(ep._visible(ranges, jnp.zeros(3), jnp.asarray(legs),
                                     jnp.asarray(radii), lcfg))
        owner = first_hit_owner(np.zeros(2), angles, legs.reshape(-1, 2), radii.ravel(),
                                lcfg.max_range)
        ref = np.array([np.any(owner // 2 == p) for p in range(P)])
        np.testing.assert_array_equal(got, ref)
        for v in ref:
            checked[bool(v)] += 1
    assert checked[True] > 20 and checked[False] > 5  # both cases occur


def test_truth_estimator_hands_the_controller_the_true_user():
    sc = scene.build(num_people=3)
    cfg = ep.EpisodeConfig(sc, user.TruthConfig(), distractors=2, duration=2.0)
    params = ep.make_params(cfg)
    f = jax.jit(ep.make_rollout(cfg))(jax.random.PRNGKey(5), params)
    err = np.linalg.norm(np.asarray(f.user_estimate) - np.asarray(f.people)[:, 0], axis=-1)
    assert err.max() < 1e-4  # through the odometry frame and back, in float32
    m = ep.summarize(cfg, f)
    assert float(m["lost_fraction"]) == 0.0 and np.isnan(float(m["mota"]))
    assert not np.any(np.asarray(f.hyp_mask))


def test_metrics_match_direct_recomputation(run):
    motmetrics = pytest.importorskip("motmetrics")
    cfg, params, frames = run
    for e in range(2):
        f = jax.tree_util.tree_map(lambda x: np.asarray(x[e]), frames)
        got = jax.jit(lambda fr: ep.summarize(cfg, fr))(
            jax.tree_util.tree_map(lambda x: x[e], frames))
        point = np.asarray(params.follower.point)
        th = f.robot[:, 2]
        fp = f.robot[:, :2] + np.stack([np.cos(th) * point[0] - np.sin(th) * point[1],
                                        np.sin(th) * point[0] + np.cos(th) * point[1]], -1)
        err = np.linalg.norm(fp - f.people[:, 0], axis=-1)
        np.testing.assert_allclose(got["following_rms"], np.sqrt(np.mean(err**2)), rtol=1e-5)
        lost = np.linalg.norm(f.user_estimate - f.people[:, 0], axis=-1) > ep.LOST_DISTANCE
        np.testing.assert_allclose(got["lost_fraction"], lost.mean(), atol=1e-6)
        d = np.linalg.norm(f.people - f.robot[:, None, :2], axis=-1) - cfg.scene.robot_radius
        near = np.any(f.people_mask & (d < ep.INTIMATE), -1)
        np.testing.assert_allclose(got["near_fraction"], near.mean(), atol=1e-6)
        acc = motmetrics.MOTAccumulator(auto_id=True)
        for t in range(f.robot.shape[0]):
            gt = np.flatnonzero(f.visible[t])
            hy = np.flatnonzero(f.hyp_mask[t])
            dist = motmetrics.distances.norm2squared_matrix(
                f.people[t, gt], f.hyp_pos[t, hy], max_d2=ep.MOT_THRESHOLD**2)
            acc.update(gt.tolist(), f.hyp_ids[t, hy].tolist(), np.sqrt(dist))
        ref = motmetrics.metrics.create().compute(acc, metrics=["mota", "motp",
                                                                "num_switches", "idf1"])
        np.testing.assert_allclose(got["idf1"], ref["idf1"].iloc[0], atol=1e-5)
        assert int(got["mot_invalid"]) == 0
        np.testing.assert_allclose(got["mota"], ref["mota"].iloc[0], atol=1e-5)
        if np.isfinite(ref["motp"].iloc[0]):
            np.testing.assert_allclose(got["motp"], ref["motp"].iloc[0], atol=1e-5)
        assert int(got["mot_switches"]) == int(ref["num_switches"].iloc[0])
        # User switches: the true person the estimate sits on (within 0.5 m) changes.
        d = np.linalg.norm(f.people - f.user_estimate[:, None], axis=-1)
        d = np.where(f.people_mask, d, np.inf)
        on = np.where(d.min(1) <= ep.LOST_DISTANCE, d.argmin(1), -1)
        last, switches = 0, 0
        for o in on:
            switches += int(o >= 0 and last >= 0 and o != last)
            last = o if o >= 0 else last
        assert int(got["user_switches"]) == switches


def test_bad_configuration():
    sc = scene.build(num_people=2)
    with pytest.raises(ValueError, match="capacity"):
        ep.EpisodeConfig(sc, distractors=4)
    with pytest.raises(ValueError, match="estimator"):
        ep.EpisodeConfig(sc, estimator="particle", distractors=1)
    with pytest.raises(TypeError, match="user-estimator configuration"):
        ep.EpisodeConfig(sc, estimator=behaviour.FollowingConfig(), distractors=1)
    assert ep.EpisodeConfig(sc, "nn_jpda", distractors=1).estimator == user.CONFIGS["nn_jpda"]
    with pytest.raises(ValueError, match="route_cell"):
        ep.EpisodeConfig(sc, distractors=1, behaviour=behaviour.FollowingConfig(route_cell=0.0))
    with pytest.raises(ValueError, match="route_clearance"):
        behaviour.FollowingConfig(route_clearance=-0.1)


def test_cli_rejects_bad_arguments(capsys):
    from sims import cli

    with pytest.raises(SystemExit):
        cli.main(["run", "person-following", "--estimator", "bogus"])
    with pytest.raises(SystemExit):
        cli.main(["run", "person-following", "--people", "40"])
    assert "--people" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["run", "person-following", "--layout", "warehouse"])
    assert "invalid choice: 'warehouse'" in capsys.readouterr().err


def test_cli_passes_the_layout_user_and_animation(monkeypatch, tmp_path):
    from sims import cli
    from sims.following import report

    seen = {}
    monkeypatch.setattr(report, "run_person_following", lambda *a, **kw: seen.update(kw))
    assert cli.main(["run", "person-following", "--layout", "room", "--user", "wander",
                     "--animate", "--out", str(tmp_path)]) == 0
    assert seen["layout"] == "room" and seen["wander"] and seen["animate"]
    assert cli.main(["run", "person-following"]) == 0
    assert seen["layout"] == "shop" and not seen["wander"] and not seen["animate"]


def test_the_shop_scenario_is_followable_with_perfect_perception():
    # The truth floor in the shop, small: the cart keeps its shopper within the following
    # distance, never touches a shelf, and its camera turns with the user.
    cfg = ep.scenario("shop", "truth", distractors=2, duration=15.0, num_people=3)
    frames = jax.jit(jax.vmap(ep.make_rollout(cfg), (0, None)))(
        jax.random.split(jax.random.PRNGKey(1), 2), ep.make_params(cfg))
    f = jax.tree_util.tree_map(np.asarray, frames)
    assert np.sqrt(np.mean(f.follow_error ** 2)) < 0.8
    boxes = cfg.scene.layout.boxes()
    q = np.clip(f.robot[..., None, :2], boxes[:, :2] - boxes[:, 2:], boxes[:, :2] + boxes[:, 2:])
    clearance = np.linalg.norm(f.robot[..., None, :2] - q, axis=-1).min()
    assert clearance > cfg.scene.robot_radius
    assert np.all(np.abs(f.pan) <= np.radians(150.0) + 1e-6) and np.abs(f.pan).max() > 0.05


def test_command_prints_table_and_writes_plots(tmp_path, monkeypatch):
    import io

    from sims.following import report

    plotted = []
    monkeypatch.setattr(report, "write_plots", lambda *a, **kw: plotted.append((a, kw)))
    out = io.StringIO()
    res = report.run_person_following(episodes=2, estimator="kf", people=2, out=tmp_path,
                                      duration=1.0, batch_size=2, stream=out, animate=True)
    text = out.getvalue()
    assert "following RMS error" in text and "user lost" in text
    assert res["metrics"]["following_rms"].shape == (2,)
    assert np.all(np.isfinite(res["metrics"]["following_rms"]))
    assert (tmp_path / "metrics.npz").stat().st_size > 0
    # the plots: of the run's scenario and key (their drawing: the next test)
    (where, cfg, params, key), kw = plotted[0]
    assert where == tmp_path and cfg.duration == 1.0 and kw == {"animate": True}
    np.testing.assert_array_equal(key, jax.random.PRNGKey(0))


def test_plots_of_a_run_are_written(run, tmp_path):
    from sims.following import report

    cfg, params, f = run
    first = jax.tree_util.tree_map(lambda x: np.asarray(x)[0], f)
    report.write_plots(tmp_path, cfg, params, jax.random.PRNGKey(0), frames=first)
    for name in ("top_view.png", "following_error.png", "mot_timeline.png"):
        assert (tmp_path / name).stat().st_size > 10_000, name
