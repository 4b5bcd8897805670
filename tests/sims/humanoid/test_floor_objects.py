"""Boxes on the floor beside the humanoid's route (seed 000 section 5.6): their layout, the
distance to their footprints, their points in the robot's cloud, and the episode among them."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.tracking import humanoid
from sims import cli
from sims.humanoid import episode, gait, scene, sensor

_CORNERS = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], float)


def _footprints(occ):
    """[G, 4, 2] corners of each box's footprint, by numpy."""
    c = np.asarray(occ.xpos, float)[:, :2]
    rot = np.asarray(occ.xmat, float)[:, :2, :2]
    half = np.asarray(occ.sizes, float)[:, :2]
    return c[:, None] + np.einsum("gij,gkj->gki", rot, _CORNERS[None] * half[:, None])


def _segment_distance(p, a, b):
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, -1) / np.sum(ab * ab, -1), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


def _polygon_distance(p, poly):
    """Distance of point p [2] to a convex polygon [4, 2] (0 inside), brute force."""
    edges = [_segment_distance(p, poly[i], poly[(i + 1) % 4]) for i in range(4)]
    def cross(u, v):
        return u[0] * v[1] - u[1] * v[0]

    cross = [cross(poly[(i + 1) % 4] - poly[i], p - poly[i]) for i in range(4)]
    inside = all(c >= 0 for c in cross) or all(c <= 0 for c in cross)
    return 0.0 if inside else min(edges)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_boxes_stand_on_the_floor_beside_the_route(dtype):
    start = jnp.asarray([0.2, -0.1, 0.0], dtype)
    target = jnp.asarray([1.2, 0.4, 0.5], dtype)
    occ = episode.floor_object_layout(jax.random.PRNGKey(3), start, target, 500)
    assert occ.xpos.dtype == dtype and occ.xmat.dtype == dtype
    assert np.all(occ.types == 6) and occ.sizes.shape == (500, 3)
    sizes, xpos = np.asarray(occ.sizes), np.asarray(occ.xpos)
    # Half sides 0.05-0.2 m, heights 0.1-0.5 m, standing on z = 0, upright.
    assert np.all((sizes[:, :2] >= 0.05) & (sizes[:, :2] <= 0.2))
    assert np.all((2 * sizes[:, 2] >= 0.1) & (2 * sizes[:, 2] <= 0.5))
    np.testing.assert_allclose(xpos[:, 2] - sizes[:, 2], 0.0, atol=1e-6)
    rot = np.asarray(occ.xmat, float)
    np.testing.assert_allclose(np.einsum("gji,gjk->gik", rot, rot),
                               np.broadcast_to(np.eye(3), rot.shape), atol=1e-6)
    np.testing.assert_allclose(rot[:, 2], np.broadcast_to([0, 0, 1], (500, 3)), atol=1e-7)
    # The nearest footprint corner is 0.2-0.5 m from the route's line, every corner on one
    # side; both sides are used, and the centres lie 0.1-0.9 of the way along.
    route = np.asarray(target[:2] - start[:2], float)
    normal = np.array([-route[1], route[0]]) / np.linalg.norm(route)
    across = (_footprints(occ) - np.asarray(start[:2], float)) @ normal       # [G, 4]
    same_side = np.all(across > 0, 1) | np.all(across < 0, 1)
    assert np.all(same_side)
    nearest = np.min(np.abs(across), 1)
    assert nearest.min() >= 0.2 - 1e-5 and nearest.max() <= 0.5 + 1e-5
    assert nearest.min() < 0.21 and nearest.max() > 0.49
    assert 0.35 < np.mean(across[:, 0] > 0) < 0.65
    along = (xpos[:, :2] - np.asarray(start[:2])) @ route / (route @ route)
    assert along.min() >= 0.1 - 1e-5 and along.max() <= 0.9 + 1e-5


def test_the_footprint_distance_is_the_polygon_distance():
    occ = episode.floor_object_layout(jax.random.PRNGKey(1), jnp.zeros(3),
                                      jnp.asarray([1.0, 0.0, 0.0]), 3)
    rng = np.random.default_rng(0)
    xy = rng.uniform([-0.3, -1.0], [1.3, 1.0], (400, 2))
    # Include points inside each footprint (its centre).
    xy = np.concatenate([xy, np.asarray(occ.xpos)[:, :2]])
    got = np.asarray(episode.footprint_distance(occ, jnp.asarray(xy, jnp.float32)))
    polys = _footprints(occ)
    want = np.array([min(_polygon_distance(p, poly) for poly in polys) for p in xy])
    np.testing.assert_allclose(got, want, atol=2e-6)
    assert np.all(got[-3:] == 0.0) and np.sum(want == 0.0) >= 3
    # No boxes: every point is infinitely far from one; no points: no distances.
    none = episode.floor_object_layout(jax.random.PRNGKey(1), jnp.zeros(3),
                                       jnp.asarray([1.0, 0.0, 0.0]), 0)
    assert none.sizes.shape == (0, 3)
    assert np.all(np.isinf(np.asarray(episode.footprint_distance(none, jnp.asarray(xy)))))
    assert episode.footprint_distance(occ, jnp.zeros((0, 2))).shape == (0,)


def test_a_box_beside_the_robot_shows_its_top_in_the_cloud():
    sc = scene.build(80, 60)
    gp = gait.GaitParams()
    pose = jnp.array([1.0, 0.6, 0.0])
    g = gait.init(pose, gp)
    xpos, xmat = scene.pose_geoms(sc, gait.qpos(sc, g, gp))
    truth = gait.torso_pose(g, gp)
    k = sensor.window_size(sc.camera)
    bg = sensor.background(sc)
    # A 0.3 m tall box 0.25 m from the robot, on the side away from the camera at (0.5, 0.5).
    box = sensor.Occluders(np.array([6]), jnp.asarray([[0.06, 0.06, 0.15]]),
                           jnp.asarray([[1.25, 0.6, 0.15]]), jnp.eye(3)[None])

    def cloud(occ, static=None):
        return jax.jit(lambda: sensor.robot_point_cloud(
            jax.random.PRNGKey(0), sc, xpos, xmat, truth, k, bg, sensor.DepthNoise(dropout=0.0),
            occluders=occ, static=static))()

    pts0, mask0 = map(np.asarray, cloud(None))
    pts1, mask1 = map(np.asarray, cloud(box))
    on_box = mask1 & (np.abs(pts1[:, 0] - 1.25) < 0.05) & (np.abs(pts1[:, 1] - 0.6) < 0.05)
    # Its top is seen at 0.3 m (the camera's noise at 2.5 m is about 1 cm) ...
    assert on_box.sum() >= 1
    np.testing.assert_allclose(pts1[on_box, 2], 0.3, atol=0.05)
    # ... where the floor was, and the robot's own points are those of the cloud without it.
    assert not np.any(mask0 & (np.abs(pts0[:, 0] - 1.25) < 0.05)
                      & (np.abs(pts0[:, 1] - 0.6) < 0.05))
    robot = np.linalg.norm(pts0[:, :2] - np.asarray(pose[:2]), axis=1) < 0.15
    np.testing.assert_array_equal(mask1[robot], mask0[robot])
    np.testing.assert_allclose(pts1[robot & mask0], pts0[robot & mask0])
    # Stored in the background image, the box is background: the cloud is the empty room's.
    pts2, mask2 = map(np.asarray, cloud(None, box))
    np.testing.assert_array_equal(mask2, mask0)
    np.testing.assert_allclose(pts2[mask0], pts0[mask0])


def test_a_stored_background_holds_the_boxes_heights():
    sc = scene.build(80, 60)
    k = sensor.window_size(sc.camera)
    centre = jnp.array([1.0, 0.6])
    box = sensor.Occluders(np.array([6]), jnp.asarray([[0.08, 0.05, 0.15]]),
                           jnp.asarray([[1.1, 0.6, 0.15]]), jnp.eye(3)[None])
    heights = np.asarray(sensor.static_heights(sc, box, centre, k))
    assert heights.shape == (k * k,)
    # A pixel's background height is the box's top (0.3 m) where its ray meets the top face,
    # between 0 and 0.3 m on a side face, and the floor's 0 elsewhere: brute force from the
    # pixel's ray.
    row, col = map(int, sensor.window_origin(sc.camera, centre, k))
    cam = np.asarray(sc.camera.position, float)
    j, i = np.meshgrid(np.arange(k) + 0.5 + col, np.arange(k) + 0.5 + row)
    floor = np.stack([cam[0] + cam[2] * (j - sc.camera.cx) / sc.camera.fx,
                      cam[1] - cam[2] * (i - sc.camera.cy) / sc.camera.fy], -1).reshape(-1, 2)
    # The ray's first point inside the box, marching down from the top in 1 mm steps.
    z = np.linspace(0.3, 0.0, 301)
    along = cam[:2] + (floor[:, None] - cam[:2]) * ((cam[2] - z) / cam[2])[None, :, None]
    inside = (np.abs(along[..., 0] - 1.1) <= 0.08) & (np.abs(along[..., 1] - 0.6) <= 0.05)
    want = np.where(inside.any(1), z[np.argmax(inside, 1)], 0.0)
    assert np.sum(want == 0.3) >= 2 and np.sum((want > 0) & (want < 0.3)) >= 2
    np.testing.assert_allclose(heights, want, atol=1.01e-3)


def test_stored_boxes_leave_the_cloud_and_unknown_ones_enter_it():
    """The same episode (keys, and boxes within the robot's window at the start) in an empty
    room, with the boxes in the camera's background image, and with the floor only known:
    the stored boxes change nothing the tracker sees, the unknown ones do."""
    params = episode.make_params([0.5, 0.0, 0.0])
    start, target = jnp.zeros(3, jnp.float32), jnp.asarray(params.target, jnp.float32)
    for seed in range(200):
        key = jax.random.PRNGKey(seed)
        occ = episode.floor_object_layout(jax.random.fold_in(key, 2), start, target, 3)
        if float(jnp.min(episode.footprint_distance(occ, start[None, :2]))) < 0.22:
            break
    else:
        raise AssertionError("no layout with a box in the window")

    def run(**kw):
        cfg = episode.EpisodeConfig(scene.build(40, 30), humanoid.DepthPFConfig(num_particles=8),
                                    num_frames=4, max_points=32, **kw)
        return np.asarray(jax.jit(episode.make_episode(cfg))(key, params)["estimate"])

    empty = run()
    stored = run(floor_objects=3)
    unknown = run(floor_objects=3, static_background=False)
    np.testing.assert_allclose(stored, empty, atol=1e-6)
    assert np.max(np.abs(unknown - empty)) > 1e-3


def test_an_episode_among_boxes_and_a_walker_reports_its_clearance(capsys):
    cfg = episode.EpisodeConfig(scene.build(24, 18), humanoid.DepthPFConfig(num_particles=16),
                                num_frames=12, max_points=32, walkers=1, floor_objects=2)
    params = episode.seed_task_params()[0]
    key = jax.random.PRNGKey(0)
    m = jax.jit(episode.make_episode(cfg))(key, params)
    assert np.all(np.isfinite(np.asarray(m["pos_err"])))
    assert float(m["pos_err_median"]) < 0.15
    # The clearance is that of the true torso to the boxes the episode drew.
    occ = episode.floor_object_layout(jax.random.fold_in(key, 2),
                                      jnp.asarray(params.start, jnp.float32),
                                      jnp.asarray(params.target, jnp.float32), 2)
    truth = np.asarray(m["truth"], float)[:, :2]
    want = min(_polygon_distance(p, poly) for p in truth for poly in _footprints(occ))
    np.testing.assert_allclose(float(m["object_clearance"]), want, atol=1e-5)
    with pytest.raises(ValueError, match="floor_objects"):
        episode.make_episode(episode.EpisodeConfig(scene.build(24, 18), floor_objects=-1))
    with pytest.raises(SystemExit) as exc:
        cli.main(["run", "humanoid-reach", "--objects", "-1"])
    assert exc.value.code == 2 and "--objects" in capsys.readouterr().err
