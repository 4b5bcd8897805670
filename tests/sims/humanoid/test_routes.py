"""Experiment 1's open-loop routes (`sims.humanoid.routes`): the command schedules' closed
form, and a short walk at a small resolution where both trackers follow the robot."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.tracking import colour_pf, humanoid
from sims.humanoid import routes, scene, sensor

# A small square (0.3 m legs) and two short routes: about 30 frames each.
LOCATIONS = ((0.3, 0.3), (0.6, 0.3), (0.6, 0.6), (0.3, 0.6), (0.45, 0.45))
SHORT = ((0, 1, 2), (0, 3, 4))


def _integrate(start, command, dt):
    """Where a perfect gait would take the robot: turn, then walk along the heading."""
    x, y, th = start
    for v, _, w in command:
        th += w * dt
        x += v * dt * math.cos(th)
        y += v * dt * math.sin(th)
    return np.array([x, y, th])


def test_schedules_end_exactly_at_the_last_location_with_perfect_execution():
    cfg = routes.RoutesConfig(scene.build(8, 6))
    sch = routes.schedule(cfg)
    assert sch.command.shape == (3, sch.num_frames, 3)
    assert sch.num_frames == sch.length.max() + cfg.settle_frames
    for r, route in enumerate(cfg.routes):
        n = sch.length[r]
        assert not sch.stop[r, :n].any() and sch.stop[r, n:].all()
        assert np.all(sch.command[r, n:] == 0)
        end = _integrate(sch.start[r], sch.command[r, :n], cfg.frame_dt)
        np.testing.assert_allclose(end[:2], cfg.locations[route[-1]], atol=1e-9)
        # Speeds and turn rates never exceed the schedule's.
        assert np.all(sch.command[r, :, 0] <= cfg.speed + 1e-12)
        assert np.all(np.abs(sch.command[r, :, 2]) <= cfg.turn_rate + 1e-12)
    # Route A is 3.44 m long: 138 walking frames at 0.1 m/s, plus three turns in place.
    assert sch.length[0] == 138 + sum(
        math.ceil(a / (0.5 * 0.25)) for a in (math.pi / 2, math.pi / 2,
                                              math.pi - math.atan2(0.4, 0.5)))


@pytest.mark.parametrize("bad, match", [
    ({"routes": ((0, 7),)}, "a route must visit"),
    ({"routes": ((0,),)}, "a route must visit"),
    ({"speed": 0.0}, "must be > 0"),
    ({"locations": ((0.0, 0.0, 0.0),)}, "locations must be"),
])
def test_bad_routes_raise(bad, match):
    with pytest.raises(ValueError, match=match):
        routes.schedule(routes.RoutesConfig(scene.build(8, 6), **bad))


def test_make_params_and_main_reject_bad_values():
    with pytest.raises(ValueError, match="route must be"):
        routes.make_params(3)
    with pytest.raises(ValueError, match="position_noise"):
        routes.make_params(0, position_noise=-1.0)
    with pytest.raises(ValueError, match="lam"):
        routes.make_params(0, lam=0.0)
    for argv in (["--episodes", "0"], ["--floor", "1,2"], ["--space", "lab"],
                 ["--temperature", "-1"]):
        with pytest.raises(SystemExit):
            routes.main(argv)


@pytest.fixture(scope="module")
def short_run():
    sc = scene.build(64, 48)
    cfg = routes.RoutesConfig(
        sc, humanoid.DepthPFConfig(num_particles=48),
        colour_pf.ColourPFConfig(sensor.ceiling_camera(sc.camera), num_particles=48),
        locations=LOCATIONS, routes=SHORT, max_points=48)
    return cfg, routes.run(jax.random.PRNGKey(0), 2, cfg)


def test_both_trackers_follow_a_short_open_loop_walk(short_run):
    cfg, res = short_run
    assert len(res.metrics) == len(SHORT)
    for m in res.metrics:
        T = routes.schedule(cfg).num_frames + 1           # frame 0: the first image
        assert m["truth"].shape == (2, T, 3) and m["colour"].shape == (2, T, 3)
        active = m["active"].astype(bool)
        truth = m["truth"][active]
        # The robot walked (open loop: it does not reach the locations exactly).
        assert np.hypot(*(m["truth"][:, -1, :2] - m["truth"][:, 0, :2]).T).min() > 0.2
        for filt in routes.FILTERS:
            err = np.hypot(*(m[filt][active][:, :2] - truth[:, :2]).T)
            assert np.all(np.isfinite(err))
            assert np.median(err) < 0.04 and err.max() < 0.1, (filt, np.median(err), err.max())
        head = np.rad2deg(np.abs((m["depth"][active][:, 2] - truth[:, 2] + np.pi)
                                 % (2 * np.pi) - np.pi))
        assert np.mean(head) < 10.0
    assert res.table.count("\n") == 2 + 2 * len(SHORT) + 2 - 1
    rows = {(r["route"], r["filter"]) for r in res.rows}
    assert len(rows) == 2 * len(SHORT)


def test_the_figure_is_written(short_run, tmp_path):
    cfg, res = short_run
    path = tmp_path / "routes.png"
    routes.plot(res, path, cfg)
    assert path.exists() and 10_000 < path.stat().st_size < 200_000


def test_lighting_varies_between_episodes(short_run):
    _, res = short_run
    b = np.concatenate([m["brightness"] for m in res.metrics])
    assert len(np.unique(np.round(b, 6))) == len(b)
    lo, hi = routes.RoutesConfig(scene.build(8, 6)).lighting.brightness_range
    assert np.all((b >= lo) & (b <= hi))


def test_same_key_same_results(short_run):
    cfg, res = short_run
    again = routes.run(jax.random.PRNGKey(0), 2, cfg)
    for a, b in zip(res.metrics, again.metrics):
        np.testing.assert_array_equal(a["colour"], b["colour"])
        np.testing.assert_array_equal(a["depth"], b["depth"])
    assert jnp.asarray(again.rows[0]["pos_mean"]) == res.rows[0]["pos_mean"]
