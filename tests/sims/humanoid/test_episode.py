"""Closed-loop humanoid episodes (tiny resolution, few particles and frames)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.tracking import humanoid
from sims.humanoid import episode, gait, scene


@pytest.fixture(scope="module")
def sc():
    return scene.build(32, 24)


@pytest.fixture(scope="module")
def small_run(sc):
    """A vmapped episode of 6 frames, 16 particles: one compile for the tests that use it."""
    cfg = episode.EpisodeConfig(sc, humanoid.DepthPFConfig(num_particles=16), num_frames=6,
                                max_points=32)
    return jax.jit(jax.vmap(episode.make_episode(cfg), (0, None)))


def test_one_episode_runs_under_jit_and_vmap(small_run):
    run = small_run
    params = episode.make_params([0.3, 0.2, 0.5])
    m = run(jax.random.split(jax.random.PRNGKey(0), 3), params)
    assert m["truth"].shape == (3, 6, 3) and m["estimate"].shape == (3, 6, 3)
    for name in ("pos_err_median", "heading_err_mean", "frames_to_stop", "final_pos_err"):
        assert m[name].shape == (3,) and np.all(np.isfinite(m[name])), name
    assert np.all(m["frames_to_stop"] == 6)     # too few frames to arrive
    assert np.all(m["pos_err_max"] < 0.15)


def test_preview_qp_planner_walks_the_closed_loop_towards_the_target(sc):
    """The preview-QP planner in the closed loop: the robot walks towards a target 0.3 m ahead
    (the command is 0.03 m/s, so 24 frames of 0.25 s cover about 0.15 m) and the tracker
    follows it."""
    cfg = episode.EpisodeConfig(sc, humanoid.DepthPFConfig(num_particles=16), num_frames=24,
                                max_points=32, planner="preview-qp")
    m = jax.jit(episode.make_episode(cfg))(jax.random.PRNGKey(2),
                                           episode.make_params([0.3, 0.0, 0.0]))
    truth = np.asarray(m["truth"])
    assert np.all(np.isfinite(truth))
    assert 0.08 < truth[-1, 0] < 0.25 and abs(truth[-1, 1]) < 0.06
    assert np.max(m["pos_err"]) < 0.15
    with pytest.raises(ValueError, match="unknown planner"):
        episode.make_episode(episode.EpisodeConfig(sc, planner="herdt"))


def test_particle_filter_converges_on_a_standing_robot(sc):
    """A diffuse initial cloud (6 cm std) around a robot that stands at its target."""
    cfg = episode.EpisodeConfig(sc, humanoid.DepthPFConfig(num_particles=64, init_spread=0.06),
                                num_frames=12, max_points=48, gait_params=gait.GaitParams(
                                    stride_noise=0.0, heading_noise=0.0, slip_noise=0.0))
    run = jax.jit(episode.make_episode(cfg))
    params = episode.make_params([0.5, 0.5, 0.0], start=[0.5, 0.5, 0.0])
    m = run(jax.random.PRNGKey(1), params)
    assert np.all(np.isfinite(m["pos_err"]))
    assert m["success"] == 1.0
    # From a 6 cm-std cloud, the estimate settles within about a centimetre.
    assert np.median(m["pos_err"][4:]) < 0.015


def test_pf3_heading_follows_a_quarter_turn(sc):
    """pf3 on a robot turning by 90 deg: the heading particles are driven by the commanded turn
    and folded to the previous estimate's half-circle. (A pure random walk lagged the turn: the
    controller kept turning and the errors reached 80-105 deg in 24 frames.)"""
    cfg = episode.EpisodeConfig(sc, humanoid.DepthPF3Config(num_particles=32), num_frames=24,
                                max_points=32)
    run = jax.jit(jax.vmap(episode.make_episode(cfg), (0, None)))
    m = run(jax.random.split(jax.random.PRNGKey(0), 4),
            episode.make_params([0.2, 0.0, np.pi / 2]))
    assert np.all(np.rad2deg(m["truth"][:, -1, 2]) > 45)      # it did turn
    assert np.all(m["heading_err"] < 20)
    assert np.mean(m["heading_err"]) < 8


def _quarter_turn_heading_errors(sc, turn_prediction):
    """[4] mean heading errors of pf on a quarter turn at lambda_theta 0.9."""
    heading = humanoid.HeadingConfig(turn_prediction=turn_prediction)
    cfg = episode.EpisodeConfig(sc, humanoid.DepthPFConfig(num_particles=32, heading=heading),
                                num_frames=24, max_points=32)
    run = jax.jit(jax.vmap(episode.make_episode(cfg), (0, None)))
    m = run(jax.random.split(jax.random.PRNGKey(0), 4),
            episode.make_params([0.2, 0.0, np.pi / 2], lambda_theta=0.9))
    assert np.all(np.rad2deg(m["truth"][:, -1, 2]) > 80)      # it did turn
    return np.mean(m["heading_err"], axis=1)


@pytest.fixture(scope="module")
def lagging(sc):
    return _quarter_turn_heading_errors(sc, False)


def test_the_smoothed_pca_heading_lags_a_quarter_turn(lagging):
    assert np.all(np.isfinite(lagging)) and np.mean(lagging) > 3.0


def test_turn_prediction_removes_the_pca_heading_lag_on_a_turn(sc, lagging):
    """pf on a quarter turn at lambda_theta 0.9: the smoothed PCA heading lags the turn unless
    the commanded turn predicts it."""
    predicted = _quarter_turn_heading_errors(sc, True)
    assert np.all(predicted < lagging)
    assert np.mean(predicted) < 0.7 * np.mean(lagging)


def test_traced_temperature_is_the_one_source_and_matters(small_run):
    """params.log_temperature is the likelihood's temperature, a traced value: one compiled
    episode runs T = 3 and T = 30 (and, with another pytree, the seed's weight, None), and the
    estimates differ."""
    keys = jax.random.split(jax.random.PRNGKey(3), 3)
    target = [0.4, 0.1, 0.3]
    params = episode.make_params(target, temperature=3.0)
    assert params.log_temperature.dtype == jnp.float32
    np.testing.assert_allclose(np.log(3.0), params.log_temperature, rtol=1e-6)
    assert params.tracker == humanoid.DepthTrackerParams(params.log_position_noise,
                                                         params.log_temperature)
    t3 = small_run(keys, params)["estimate"]
    t30 = small_run(keys, params._replace(log_temperature=jnp.log(jnp.float32(30.0))))[
        "estimate"]
    seed = small_run(keys, episode.make_params(target))["estimate"]
    assert np.max(np.abs(t30 - t3)) > 1e-3 and np.max(np.abs(seed - t3)) > 1e-3
    # The tasks' default is the seed's weight.
    assert episode.seed_task_params()[0].log_temperature is None
    assert episode.seed_task_params(temperature=2.0)[5].log_temperature is not None


def test_bad_task_input_is_rejected_with_a_clear_message(sc):
    with pytest.raises(ValueError, match="target must be finite"):
        episode.make_params([np.nan, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"target must be a pose \[3\]"):
        episode.make_params([1.0, 0.0])
    with pytest.raises(ValueError, match="lambda_x"):
        episode.make_params([1.0, 0.0, 0.0], lambda_x=-1.0)
    with pytest.raises(ValueError, match="temperature must be a finite positive number"):
        episode.make_params([1.0, 0.0, 0.0], temperature=0.0)
    with pytest.raises(ValueError, match=r"unknown tracker \['kcf'\]"):
        episode.make_episode(episode.EpisodeConfig(sc, tracker="kcf"))
    with pytest.raises(ValueError, match="sway_frames"):
        episode.make_episode(episode.EpisodeConfig(sc, sway_frames=0))
    with pytest.raises(ValueError, match=r"unknown smooth resampling \['sinkhorn'\]"):
        humanoid.SmoothConfig(resampling="sinkhorn")
