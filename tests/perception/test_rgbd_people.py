"""The RGB-D people detector end to end on synthetic clouds (floor, wall, people)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.perception import hog, rgbd_people
from jaxtrack.perception.head_subclustering import HeadConfig
from jaxtrack.perception.voxel_grid import GridSpec
from tests.perception import _clouds

CFG = rgbd_people.RGBDPeopleConfig(
    grid=GridSpec(0.06, (0.3, -3.0, -0.3), (80, 100, 45)), voxel_capacity=8192,
    foreground_capacity=2048)
EYE = jnp.asarray([0.1, 0.0, 1.1])
_detect = jax.jit(rgbd_people.detect, static_argnums=0)
PEOPLE = [((2.0, 0.0), 1.75), ((2.0, 0.45), 1.65), ((3.5, -1.2), 1.85)]   # a touching pair


def _cloud(seed=0, people=PEOPLE, angle=0.0, lift=0.0):
    rng = np.random.default_rng(seed)
    parts = [_clouds.floor(rng, 6000, x=(0.5, 4.7), y=(-2.5, 2.5)),
             _clouds.wall(rng, 12000, x=4.8, y=(-2.5, 2.5), height=2.6)]
    parts += [_clouds.person(rng, c, s) for c, s in people]
    pts = _clouds.tilt(np.concatenate(parts), angle, lift)
    rgb = rng.uniform(size=pts.shape)
    return pts, rgb


def _matched(frame, people=PEOPLE, tol=0.12):
    m = np.asarray(frame.people.mask)
    pos = np.asarray(frame.people.position)[m][:, :2]
    hits = [np.linalg.norm(pos - np.asarray(c), axis=1).min() < tol for c, _ in people]
    return hits, m.sum()


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_finds_each_person_once_including_a_close_pair(dtype):
    pts, rgb = _cloud()
    state, frame = _detect(CFG, rgbd_people.init_state(CFG, dtype=dtype), jax.random.key(0),
                           jnp.asarray(pts, dtype), None, jnp.asarray(rgb, dtype), EYE)
    hits, n = _matched(frame)
    assert all(hits) and n == 3
    assert frame.people.position.dtype == dtype
    np.testing.assert_allclose(np.sort(np.asarray(frame.people.height)[:3]), [1.65, 1.75, 1.85],
                               atol=0.05)
    # The wall and the floor are not people; the ground plane is z = 0.
    np.testing.assert_allclose(np.asarray(state.plane), [0, 0, 1, 0], atol=0.01)
    np.testing.assert_allclose(np.asarray(frame.confidence)[:3], 1.0)
    # The colour histograms are normalised where there is a person.
    h = np.asarray(frame.histograms)
    np.testing.assert_allclose(h[np.asarray(frame.people.mask)].sum(1), 1.0, atol=1e-5)
    assert (h[~np.asarray(frame.people.mask)] == 0).all()


def test_without_subclustering_the_pair_is_missed_as_one():
    cfg = rgbd_people.RGBDPeopleConfig(grid=CFG.grid, voxel_capacity=8192,
                                       heads=HeadConfig(subcluster=False))
    pts, rgb = _cloud()
    _, frame = _detect(cfg, rgbd_people.init_state(cfg), jax.random.key(0), jnp.asarray(pts),
                       None, jnp.asarray(rgb), EYE)
    _, n = _matched(frame)
    assert n == 2


def test_ground_plane_follows_a_rocking_camera_from_frame_to_frame():
    state = rgbd_people.init_state(CFG, dtype=jnp.float64)
    for k, angle in enumerate(np.linspace(0.0, 0.1, 4)):
        pts, rgb = _cloud(k, angle=angle, lift=0.02 * k)
        state, frame = _detect(CFG, state, jax.random.key(k), jnp.asarray(pts), None,
                               jnp.asarray(rgb), EYE)
        up = _clouds.tilt(np.eye(3), angle)[2]
        assert float(np.dot(np.asarray(state.plane)[:3], up)) > np.cos(np.radians(0.5))
        assert sum(_matched(frame, tol=0.2)[0]) == 3


def test_hog_confidence_is_the_svm_on_each_theoretical_box():
    pts, rgb = _cloud()
    rot = jnp.asarray([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    camera = hog.PinholeCamera(jnp.asarray([150.0, 150.0]), jnp.asarray([80.0, 60.0]), EYE, rot)
    image = jax.random.uniform(jax.random.key(1), (120, 160, 3))
    svm = hog.LinearSVM(jax.random.normal(jax.random.key(2), (hog.num_features(),)) * 0.05,
                        jnp.asarray(0.1))
    _, frame = _detect(CFG, rgbd_people.init_state(CFG), jax.random.key(0),
                       jnp.asarray(pts, jnp.float32), None, jnp.asarray(rgb, jnp.float32), EYE,
                       image=image, camera=camera, svm=svm)
    m = np.asarray(frame.people.mask)
    score = jax.jit(lambda b: hog.svm_confidence(svm, hog.hog(hog.crop(image, b))))
    for k in np.flatnonzero(m):
        box = frame.boxes[k]
        want = score(box)
        np.testing.assert_allclose(frame.confidence[k], want, rtol=1e-5)
        head = frame.people.head[k]
        foot = head.at[2].set(head[2] - frame.people.height[k])
        np.testing.assert_allclose(box, hog.person_box(camera, head, foot), atol=0.05)
    assert (np.asarray(frame.confidence)[~m] == 0).all()


def test_empty_and_all_invalid_clouds_give_no_people_and_keep_the_plane():
    prior = rgbd_people.init_state(CFG)
    for pts, mask in ((np.zeros((0, 3)), np.zeros(0, bool)), (np.full((50, 3), np.nan),
                                                               np.ones(50, bool)),
                      (np.zeros((50, 3)), np.zeros(50, bool))):
        state, frame = _detect(CFG, prior, jax.random.key(0), jnp.asarray(pts, jnp.float32),
                               jnp.asarray(mask), None, EYE)
        assert not bool(frame.people.mask.any())
        np.testing.assert_allclose(state.plane, prior.plane)


def _batch(method, hog_=False):
    """Two episodes' clouds (one with a lifted floor and its own plane prior, a point mask),
    detect_batch's output and each episode's `detect` alone."""
    clouds = [_cloud(3), _cloud(4, lift=0.05)]
    pts = jnp.asarray(np.stack([c[0] for c in clouds]), jnp.float32)
    rgb = jnp.asarray(np.stack([c[1] for c in clouds]), jnp.float32)
    mask = jnp.asarray(np.random.default_rng(5).uniform(size=pts.shape[:2]) > 0.1)
    keys = jax.random.split(jax.random.key(0), 2)
    states = rgbd_people.RGBDPeopleState(jnp.stack([rgbd_people.init_state(CFG).plane,
                                                    rgbd_people.init_state(CFG, 0.05).plane]))
    eyes = jnp.stack([EYE, EYE + 0.05])
    extra = {}
    if hog_:
        rot = jnp.asarray([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
        camera = hog.PinholeCamera(jnp.asarray([150.0, 150.0]), jnp.asarray([80.0, 60.0]),
                                   EYE, rot)
        svm = hog.LinearSVM(jax.random.normal(jax.random.key(2), (hog.num_features(),)) * 0.05,
                            jnp.asarray(0.1))
        extra = dict(image=jax.random.uniform(jax.random.key(1), (2, 120, 160, 3)),
                     camera=camera, svm=svm)
    got = rgbd_people.detect_batch(CFG, states, keys, pts, mask, rgb, eyes, method=method,
                                   **extra)
    alone = []
    for i in range(2):
        one = {k: (v[i] if k == "image" else v) for k, v in extra.items()}
        alone.append(_detect(CFG, rgbd_people.RGBDPeopleState(states.plane[i]), keys[i], pts[i],
                             mask[i], rgb[i], eyes[i], **one))
    return got, alone


@pytest.mark.parametrize("method, hog_", [("map", True), ("vmap", False)])
def test_detect_batch_equals_each_episode_alone(method, hog_):
    (states, frames), alone = _batch(method, hog_)
    for i, (state, frame) in enumerate(alone):
        np.testing.assert_array_equal(frames.people.mask[i], frame.people.mask)
        assert int(frame.people.mask.sum()) >= 2
        np.testing.assert_allclose(frames.people.position[i], frame.people.position, atol=1e-5)
        np.testing.assert_allclose(frames.histograms[i], frame.histograms, atol=1e-5)
        np.testing.assert_allclose(frames.confidence[i], frame.confidence, atol=1e-4)
        np.testing.assert_allclose(states.plane[i], state.plane, atol=1e-5)
    if hog_:
        assert float(jnp.abs(frames.confidence).sum()) > 0


@pytest.mark.parametrize("B, N, method", [(2, 0, "vmap"), (0, 10, "map")])
def test_detect_batch_of_empty_clouds_or_no_episodes(B, N, method):
    state = rgbd_people.RGBDPeopleState(jnp.tile(rgbd_people.init_state(CFG).plane, (B, 1)))
    keys = jax.random.split(jax.random.key(0), max(B, 1))[:B]
    new, frames = rgbd_people.detect_batch(CFG, state, keys, jnp.zeros((B, N, 3)), None, None,
                                           jnp.zeros((B, 3)), method=method)
    assert frames.people.mask.shape == (B, CFG.heads.max_detections)
    assert not bool(frames.people.mask.any())
    np.testing.assert_array_equal(new.plane, state.plane)


def test_detect_batch_refuses_bad_input():
    state = rgbd_people.RGBDPeopleState(jnp.stack([rgbd_people.init_state(CFG).plane] * 2))
    keys = jax.random.split(jax.random.key(0), 2)
    pts, eyes = jnp.zeros((2, 5, 3)), jnp.zeros((2, 3))
    with pytest.raises(ValueError, match="method"):
        rgbd_people.detect_batch(CFG, state, keys, pts, None, None, eyes, method="pmap")
    with pytest.raises(ValueError, match="points"):
        rgbd_people.detect_batch(CFG, state, keys, pts[0], None, None, eyes)
    with pytest.raises(ValueError, match="key"):
        rgbd_people.detect_batch(CFG, state, keys[:1], pts, None, None, eyes)
    with pytest.raises(ValueError, match="viewpoint"):
        rgbd_people.detect_batch(CFG, state, keys, pts, None, None, eyes[0])
    with pytest.raises(ValueError, match="mask"):
        rgbd_people.detect_batch(CFG, state, keys, pts, jnp.ones((2, 4), bool), None, eyes)


@pytest.mark.parametrize("kw, match", [(dict(points=np.zeros((5, 2))), "points"),
                                       (dict(colours=np.zeros((4, 3))), "colours"),
                                       (dict(viewpoint=np.zeros(2)), "viewpoint"),
                                       (dict(points=np.zeros((5, 3), np.int32)), "floating")])
def test_bad_input_is_refused(kw, match):
    args = dict(points=np.zeros((5, 3)), colours=None, viewpoint=np.zeros(3)) | kw
    with pytest.raises((ValueError, TypeError), match=match):
        rgbd_people.detect(CFG, rgbd_people.init_state(CFG), jax.random.key(0), args["points"],
                           None, args["colours"], args["viewpoint"])


@pytest.mark.parametrize("kw", [dict(voxel_capacity=0), dict(cluster_tolerance=-0.1),
                                dict(merge_distance=float("nan"))])
def test_bad_config_is_refused(kw):
    with pytest.raises(ValueError, match="RGBDPeopleConfig"):
        rgbd_people.RGBDPeopleConfig(**kw)
