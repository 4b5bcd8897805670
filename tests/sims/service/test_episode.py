"""The service scene's closed loop at a small size: one compiled rollout of the TV experiment
with all three trackers (the behaviour's and the single-sensor-group ones), the metrics' rules
on hand-made trajectories, the static layer, the ceiling cameras' coverage, and bad
configurations."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.perception import ceiling_camera
from jaxtrack.tracking import status as status_mod
from sims.service import episode as ep
from sims.service import experiments, flat
from sims.service import people as pm


@pytest.fixture(scope="module")
def scene():
    return ep.build_scene()


@pytest.fixture(scope="module")
def tv_run(scene):
    cfg = ep.ServiceConfig(scene, experiment="tv", duration=24.0, compare_sensors=True)
    params = ep.make_params(cfg)
    roll = jax.jit(jax.vmap(ep.make_rollout(cfg), (0, None)))
    frames = roll(jax.random.split(jax.random.key(3), 2), params)
    metrics = jax.jit(jax.vmap(lambda f: ep.summarize(cfg, f)))(frames)
    return cfg, jax.tree_util.tree_map(np.asarray, frames), \
        {k: np.asarray(v) for k, v in metrics.items()}


def test_the_robot_goes_around_the_couch_without_crossing_the_tv_interaction(tv_run):
    cfg, f, m = tv_run
    T = cfg.num_frames
    assert f.robot.shape == (2, T, 3) and f.hyp_pos.shape[:3] == (2, T, 3)
    assert m["success"].all() and not m["tv_crossing"].any()
    # the way around: behind the couch (x < its back, 1.95 m) at some frame
    assert (f.robot[..., 0].min(1) < 1.95).all()
    # the path is longer than the straight line it was not allowed to take
    straight = np.linalg.norm(f.goal[:, -1] - f.robot[:, 0, :2], axis=-1)
    assert (m["path_length"] > straight + 1.0).all()
    assert np.isfinite(m["time_to_goal"]).all() and (m["time_to_goal"] <= 24.0).all()


# three hand-over episodes of `jaxtrack run service --experiment handover` (seed 0): with the
# status's velocity heading the first stopped 38 deg off the person's heading; in the other two
# the robot, chasing the goal's jitter across its tolerance, turned away from the person
HANDOVER_EPISODES = [29, 75, 112]
HANDOVER_CONFIG = dict(heading_filter="sustained", hold_radius=0.5)


@pytest.fixture(scope="module")
def handover_run(scene):
    cfg = ep.ServiceConfig(scene, experiment="handover", duration=20.0, **HANDOVER_CONFIG)
    params = ep.make_params(cfg)
    roll = jax.jit(jax.vmap(ep.make_rollout(cfg), (0, None)))
    keys = jax.random.split(jax.random.PRNGKey(0), 128)[np.asarray(HANDOVER_EPISODES)]
    frames = roll(keys, params)
    metrics = jax.jit(jax.vmap(lambda f: ep.summarize(cfg, f)))(frames)
    return cfg, jax.tree_util.tree_map(np.asarray, frames), \
        {k: np.asarray(v) for k, v in metrics.items()}


def test_the_hand_over_is_made_from_the_front_and_held(handover_run):
    cfg, f, m = handover_run
    E = len(HANDOVER_EPISODES)
    assert m["success"].all(), m
    for e in range(E):
        done = np.flatnonzero(f.done[e])[0]
        # the waiting person's heading, from the sustained filter on their track, once they
        # stand in the hand-over area (the frames with the hand-over status)
        waiting = f.status[e] == status_mod.HANDOVER                       # [T, K]
        assert waiting[done:].any(1).all()
        err = np.abs(np.angle(np.exp(1j * (f.heading[e] - f.people_heading[e, :, :1]))))
        assert np.median(err[waiting]) < np.radians(10), np.degrees(np.median(err[waiting]))
        # held: from a second after the hand-over pose was reached the robot does not move off
        # it, and keeps facing the person
        drift = np.linalg.norm(f.robot[e, done + 10:, :2] - f.robot[e, done + 10, :2], axis=-1)
        assert drift.max() < 0.1, drift.max()
        to_person = f.people[e, done + 10:, 0] - f.robot[e, done + 10:, :2]
        facing = np.angle(np.exp(1j * (np.arctan2(to_person[:, 1], to_person[:, 0])
                                       - f.robot[e, done + 10:, 2])))
        assert np.abs(facing).max() < np.radians(25), np.degrees(np.abs(facing).max())


def test_seated_people_are_tracked_and_called_seated(tv_run):
    cfg, f, m = tv_run
    late = slice(50, None)                                     # after 5 s
    for e in range(2):
        seated = f.people_mask[e, 0] & (f.people_role[e, 0] == pm.SEATED)
        for p in np.flatnonzero(seated):
            d = np.linalg.norm(f.hyp_pos[e, late, 0] - f.people[e, late, p][:, None], axis=-1)
            near = f.hyp_mask[e, late, 0] & (d < 0.5)
            assert near.any(1).mean() > 0.9                    # tracked
            codes = np.where(near, f.status[e, late], -1)
            assert (codes == status_mod.SEATED).any(1).mean() > 0.9
    # cooperative perception: all sensors at least as good as the robot alone here, where the
    # robot sees the couch only part of the time
    assert (m["mota"] >= m["mota_robot"] - 1e-6).all()
    assert (m["mota"] > 0.8).all()


def _frame(robot, people, heading, role, mask=None):
    """A hand-made `Frame` record: robot [T, 3], people [T, P, 2]."""
    T, P = people.shape[:2]
    K = 2
    mask = np.ones((T, P), bool) if mask is None else mask
    z = np.zeros
    return ep.Frame(jnp.asarray(robot, jnp.float32), jnp.zeros((T, 2)), jnp.zeros(T, bool),
                    jnp.asarray(people, jnp.float32), jnp.asarray(heading, jnp.float32),
                    jnp.asarray(mask), jnp.asarray(role, jnp.int32),
                    jnp.asarray(z((T, 1, K, 2)), jnp.float32), jnp.full((T, 1, K), -1),
                    jnp.zeros((T, 1, K), bool), jnp.full((T, K), -1), jnp.zeros((T, K)),
                    jnp.zeros((T, 2)), jnp.zeros((T, 3)), jnp.zeros(T))


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_overtaking_side_is_scored_from_the_walkers_frame(scene, side):
    T = 60
    t = np.arange(T) * 0.1
    person = np.stack([0.5 * t, np.zeros(T)], -1)[:, None]          # walks along +x
    robot = np.stack([-1.0 + 1.0 * t, side * 0.9 * np.ones(T), np.zeros(T)], -1)
    cfg = ep.ServiceConfig(scene, experiment="overtake")
    m = ep.summarize(cfg, _frame(robot, person, np.zeros((T, 1)), np.zeros((T, 1))))
    assert bool(m["passed"])
    assert bool(m["right_pass"]) == (side < 0) and bool(m["rule"]) == (side > 0)
    np.testing.assert_allclose(float(m["min_distance"][0]), 0.9 - cfg.robot_radius, atol=1e-5)


def test_tv_crossing_and_intimate_intrusion_are_detected(scene):
    T = 40
    seat = flat.SEATS[1]
    person = np.tile(seat, (T, 1))[:, None]
    y = np.linspace(-0.5, 3.0, T)
    cfg = ep.ServiceConfig(scene, experiment="tv")
    through = np.stack([np.full(T, 4.3), y, np.zeros(T)], -1)        # between seat and TV
    behind = np.stack([np.full(T, 1.0), y, np.zeros(T)], -1)
    role = np.full((T, 1), pm.SEATED)
    m_through = ep.summarize(cfg, _frame(through, person, np.zeros((T, 1)), role))
    m_behind = ep.summarize(cfg, _frame(behind, person, np.zeros((T, 1)), role))
    assert bool(m_through["tv_crossing"]) and not bool(m_through["rule"])
    assert not bool(m_behind["tv_crossing"]) and bool(m_behind["rule"])
    # the intimate zone: the body (0.3 m disc) within 0.45 m of the centre
    close = np.stack([np.full(T, seat[0] - 0.7), np.full(T, seat[1]), np.zeros(T)], -1)
    m_close = ep.summarize(ep.ServiceConfig(scene, experiment="avoid"),
                           _frame(close, person, np.zeros((T, 1)), np.full((T, 1), pm.STANDER)))
    assert bool(m_close["intimate"]) and not bool(m_close["rule"])
    np.testing.assert_allclose(float(m_close["intimate_time"][0]), T * 0.1, rtol=1e-5)


def test_the_task_persons_estimate_is_called_lost_beyond_one_metre(scene):
    T = 30
    person = np.zeros((T, 1, 2))
    robot = np.tile([2.0, 0.0, np.pi], (T, 1))
    cfg = ep.ServiceConfig(scene, experiment="approach", interest=0.5)
    frame = _frame(robot, person, np.zeros((T, 1)), np.full((T, 1), pm.WAITER))
    for jump, lost in ((0.9, False), (1.2, True)):
        est = np.zeros((T, 3), np.float32)
        est[20, 0] = jump                                      # one frame off, after settling
        m = ep.summarize(cfg, frame._replace(target_est=jnp.asarray(est)))
        assert bool(m["person_lost"]) == lost
    early = np.zeros((T, 3), np.float32)
    early[5, 0] = 3.0                                          # within the first second: ignored
    assert not bool(ep.summarize(cfg, frame._replace(target_est=jnp.asarray(early)))
                    ["person_lost"])


def test_static_layer_blocks_walls_and_keeps_doors_and_corridor_free(scene):
    cfg = ep.ServiceConfig(scene)
    c = ep.static_cost(cfg)
    g = ep.grid(cfg)
    assert c.shape == g.shape == (80, 120)

    def at(x, y):
        i = int((y + 4.0) / cfg.cell)
        j = int((x + 6.0) / cfg.cell)
        return c[i, j]

    assert np.isinf(at(1.0, -1.4)) and np.isinf(at(0.0, 0.0)) and np.isinf(at(2.4, 1.3))
    assert at(0.0, -2.7) == pytest.approx(0.0, abs=0.01)          # corridor middle
    assert at(3.0, -1.4) < 1.0 and at(-3.0, -1.4) < 1.0 and at(0.0, 1.6) < 1.0   # doors
    assert at(-5.85, 0.0) >= 1.0                                    # too near the outer wall


def test_the_detections_map_filter_does_not_coarsen_with_the_planners_cell(scene):
    """A seated person's detection (near their seat) is kept by the map filter with 0.1 m
    and 0.2 m costmap cells alike, and the filter's answer is the same for both cells on
    random points; points in walls and outside the flat are dropped."""
    rng = np.random.default_rng(4)
    # a seated person's centre, up to 5 cm towards the backrest, 15 cm sideways or forwards
    seats = np.concatenate([flat.SEATS + rng.uniform([-0.05, -0.15], [0.15, 0.15], (3, 2))
                            for _ in range(8)])
    pts = np.concatenate([rng.uniform(-6.5, 6.5, (300, 1)), rng.uniform(-4.5, 4.5, (300, 1))], 1)
    keep = {}
    for cell in (0.1, 0.2):
        cfg = ep.ServiceConfig(scene, experiment="tv", cell=cell)
        f = ep.free_space(cfg)
        assert np.asarray(f(jnp.asarray(seats, jnp.float32))).all(), cell
        keep[cell] = np.asarray(f(jnp.asarray(pts, jnp.float32)))
        assert not np.asarray(f(jnp.asarray([[0.0, 0.0], [7.0, 0.0]], jnp.float32))).any()
    np.testing.assert_array_equal(keep[0.1], keep[0.2])
    assert 0.3 < keep[0.1].mean() < 0.95
    # what the filter was: each cell's own static layer, which at 0.2 m dropped about half of
    # a seated person's detections (0.1 m noise), against a sixth at 0.1 m
    z = flat.SEATS[0] + 0.1 * rng.standard_normal((2000, 2))
    kept = {}
    for cell in (0.1, 0.2):
        layer = ep.static_cost(ep.ServiceConfig(scene, experiment="tv", cell=cell))
        j, i = np.round((z + 0.5 * np.asarray(flat.SIZE)) / cell - 0.5).astype(int).T
        kept[cell] = np.isfinite(layer[i, j]).mean()
    assert kept[0.2] < 0.6 < 0.8 < kept[0.1]
    np.testing.assert_allclose(np.asarray(ep.free_space(cfg)(jnp.asarray(z, jnp.float32))).mean(),
                               kept[0.1], atol=0.01)
    # no detections, and NaN ones (dropped)
    assert np.asarray(f(jnp.zeros((0, 2), jnp.float32))).shape == (0,)
    assert not np.asarray(f(jnp.asarray([[np.nan, 0.6], [3.05, np.nan]], jnp.float32))).any()


def test_each_room_is_covered_by_a_ceiling_camera():
    cams = ep.cameras()
    rooms = experiments.free_floor()
    rng = np.random.default_rng(0)
    for room in rooms:
        x0, y0, x1, y1 = room
        pts = np.stack([rng.uniform(x0 + 0.4, x1 - 0.4, 200),
                        rng.uniform(y0 + 0.4, y1 - 0.4, 200)], -1)
        seen = np.zeros(200, bool)
        for c in range(4):
            cam = jax.tree_util.tree_map(lambda x: x[c], cams)
            seen |= np.asarray(ceiling_camera.in_footprint(cam, jnp.asarray(pts, jnp.float32)))
        assert seen.mean() > 0.9, room


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_inflation_is_the_maximum_over_a_disc_of_cells(dtype):
    """`_inflate` (rows of the disc, then across them) against scipy's maximum filter with the
    disc as its footprint (zeros beyond the map)."""
    from scipy import ndimage

    rng = np.random.default_rng(2)
    cost = (rng.random((23, 31)) ** 6).astype(dtype)
    for cells in (0, 1, 2, 3, 4, 5):
        i, j = np.mgrid[-cells:cells + 1, -cells:cells + 1]
        disc = i * i + j * j <= cells * cells
        want = ndimage.maximum_filter(cost, footprint=disc, mode="constant", cval=0.0)
        got = np.asarray(ep._inflate(jnp.asarray(cost), cells))
        assert got.dtype == dtype
        np.testing.assert_array_equal(got, want)


def test_bad_configurations_are_refused(scene):
    for kw, match in ((dict(experiment="dance"), "experiment"),
                      (dict(perception="radar"), "perception"),
                      (dict(interest=1.5), "interest"),
                      (dict(duration=math.nan), "duration"),
                      (dict(cell=0.01), "cell"),
                      (dict(heading_filter="kalman"), "heading_filter"),
                      (dict(heading_window=0.0), "heading_window"),
                      (dict(still_at_end=61.0), "still_at_end"),
                      (dict(still_at_end=-1.0), "still_at_end"),
                      (dict(heading_frame="world"), "heading_frame"),
                      (dict(park=(0.3, 0.1)), "park"),
                      (dict(hold_radius=-0.1), "hold_radius"),
                      (dict(arc_check=-0.5), "arc_check"),
                      (dict(hold_radius=math.inf), "hold_radius")):
        with pytest.raises(ValueError, match=match):
            ep.ServiceConfig(scene, **kw)
    assert ep.ServiceConfig(scene, heading_filter="sustained").min_heading_distance == 0.8
    assert ep.ServiceConfig(scene, heading_filter="windowed").min_heading_distance == 0.5


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_rgbd_detections_behind_the_laser_scan_are_found(dtype):
    """Against a plain loop: a scan of 181 beams over 180 deg with a wall at 2-4 m."""
    rng = np.random.default_rng(1)
    angles = np.linspace(-np.pi / 2, np.pi / 2, 181).astype(dtype)
    ranges = rng.uniform(2.0, 4.0, 181).astype(dtype)
    laser_pose = np.array([1.0, -2.0, 0.7], dtype)
    xy = laser_pose[:2] + rng.uniform(-5.0, 5.0, (400, 2)).astype(dtype)
    got = np.asarray(ep.behind_the_scan(jnp.asarray(xy), jnp.asarray(ranges),
                                        jnp.asarray(angles), jnp.asarray(laser_pose)))
    want = np.zeros(len(xy), bool)
    for i, p in enumerate(xy.astype(float)):
        d = p - laser_pose[:2]
        r = np.hypot(*d)
        b = np.angle(np.exp(1j * (np.arctan2(d[1], d[0]) - laser_pose[2])))
        if b < -np.pi / 2 - np.pi / 180 or b > np.pi / 2 + np.pi / 180:
            continue                                    # outside the scan
        k = int(np.argmin(np.abs(angles - b)))
        want[i] = r > ranges[k] + 0.5
    # a point within float rounding of two beams' mid-angle may take either
    assert (got == want).mean() > 0.99 and 50 < want.sum() < 350, ((got != want).sum(),
                                                                   want.sum())
    # no detections: no flags
    none = ep.behind_the_scan(jnp.zeros((0, 2), dtype), jnp.asarray(ranges),
                              jnp.asarray(angles), jnp.asarray(laser_pose))
    assert none.shape == (0,) and none.dtype == bool


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_rgbd_detections_are_corroborated_by_a_laser_detection_beside_them(dtype):
    """Against a plain loop over random detections of the three sensors, some masked."""
    rng = np.random.default_rng(2)
    M = 60
    zs = rng.uniform(-3.0, 3.0, (M, 2)).astype(dtype)
    sensor = rng.integers(0, 3, M).astype(np.int32)
    keep = rng.uniform(size=M) < 0.8
    got = np.asarray(ep.corroborated(jnp.asarray(zs), jnp.asarray(keep), jnp.asarray(sensor)))
    want = np.zeros(M, bool)
    for i in range(M):
        if keep[i] and sensor[i] == 1:
            want[i] = any(keep[j] and sensor[j] == 2
                          and np.hypot(*(zs[i] - zs[j])) < ep.CORROBORATION for j in range(M))
    np.testing.assert_array_equal(got, want)
    assert 5 < want.sum() < (sensor == 1).sum()       # both outcomes occur
    # a masked laser detection corroborates nothing; no detections, no flags
    one = ep.corroborated(jnp.asarray([[0.0, 0.0], [0.3, 0.0]], dtype), jnp.asarray([True, False]),
                          jnp.asarray([1, 2]))
    assert not np.any(np.asarray(one))
    none = ep.corroborated(jnp.zeros((0, 2), dtype), jnp.zeros(0, bool), jnp.zeros(0, np.int32))
    assert none.shape == (0,) and none.dtype == bool
    # a NaN position neither corroborates nor is corroborated, and leaves the other rows alone
    nan = ep.corroborated(jnp.asarray([[0.0, 0.0], [0.3, 0.0], [np.nan, 0.0], [5.0, 0.0],
                                       [np.nan, np.nan]], dtype),
                          jnp.ones(5, bool), jnp.asarray([1, 2, 2, 1, 1]))
    np.testing.assert_array_equal(np.asarray(nan), [True, False, False, False, False])


def test_the_short_path_gives_the_long_paths_lookahead_point(scene):
    """The frame extracts `PATH_AHEAD` metres of path, not 48 cells: pure pursuit's lookahead
    point (0.6 m and 2.0 m) is the same on both, from random cells of the flat to random goals
    on its static layer plus a few people's lethal discs."""
    from jaxtrack.control import grid_planner

    config = ep.ServiceConfig(scene)
    g = ep.grid(config)
    pg = ep._planner_grid(g)
    static = ep.static_cost(config)
    free = np.argwhere(static < 0.3)
    rng = np.random.default_rng(4)
    n_short = math.ceil(ep.PATH_AHEAD / config.cell) + 1
    assert n_short < 48
    rows, cols = np.mgrid[0:static.shape[0], 0:static.shape[1]]
    compared = 0
    for _ in range(6):
        cost = static.copy()
        for r, c in free[rng.choice(len(free), 3)]:
            cost[(rows - r) ** 2 + (cols - c) ** 2 <= 16] = ep._LETHAL_PENALTY
        start, goal = free[rng.choice(len(free), 2, replace=False)]
        plan = np.where(np.isfinite(cost), np.minimum(cost, ep._LETHAL_PENALTY), np.inf)
        dist = grid_planner.distance_field(plan, goal, cell=config.cell)
        if not np.isfinite(dist[start[0], start[1]]):
            continue
        robot = np.asarray(grid_planner.centre_of(pg, jnp.asarray(start))) + rng.normal(0, 0.03, 2)
        for lookahead in (0.6, 2.0):
            aims = [grid_planner.lookahead_point(pg, p.cells, p.valid, robot, lookahead)
                    for p in (grid_planner.extract_path(dist, start, n, cost=plan,
                                                        cell=config.cell)
                              for n in (n_short, 48))]
            np.testing.assert_allclose(aims[0], aims[1], atol=1e-6)
        compared += 1
    assert compared >= 3
