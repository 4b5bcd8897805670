"""Seed 003 ceiling cameras: ground-plane homography, people boxes, occlusion, detections.

References: a pinhole projection written here in numpy from a yaw / pitch rotation (not from
`look_at`), the people's true floor positions, a brute-force grid of the camera's floor
footprint, and the Poisson / binomial / Gaussian laws of the simulated detector checked over
thousands of fixed keys (one compiled, vmapped call per law).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.perception import ceiling_camera as cc

# A camera 3 m up looking 36.9 deg down towards (4, 0) (default 640 x 480, f = 500 px, 10 m).
CAM = cc.look_at(np.array([0.0, 0.0, 3.0]), np.array([4.0, 0.0, 0.0]))
HEIGHT, RADIUS = 1.75, 0.25
P, CAPACITY = 6, 16
project = cc.project_people


def rotation(yaw, pitch):
    """World-to-camera rotation of a camera whose optical axis has heading ``yaw`` and points
    ``pitch`` below the horizon, image rows level (x right, y down, z forward)."""
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    z = np.array([cp * cy, cp * sy, -sp])
    x = np.array([sy, -cy, 0.0])
    y = np.array([-sp * cy, -sp * sy, -cp])
    return np.stack([x, y, z])


def pinhole(position, R, K, xy):
    """Pixels and depths of floor points by the 3-D pinhole model u ~ K R (X - c)."""
    X = np.concatenate([xy, np.zeros((len(xy), 1))], 1)
    pc = (X - position) @ R.T
    uv = (pc / pc[:, 2:]) @ K.T
    return uv[:, :2], pc[:, 2]


def intrinsics(camera):
    return np.array([[float(camera.fx), 0, float(camera.cx)],
                     [0, float(camera.fy), float(camera.cy)], [0, 0, 1]])


def people(xy, radius=RADIUS, dtype=np.float64, pad=P):
    """People at xy [n, 2], padded with masked NaN entries to ``pad`` (one compiled shape)."""
    xy = np.asarray(xy, dtype).reshape(-1, 2)
    n = len(xy)
    out = (np.full((pad, 2), np.nan, dtype), np.full(pad, np.nan, dtype),
           np.full(pad, np.nan, dtype), np.zeros(pad, bool))
    out[0][:n], out[1][:n], out[2][:n], out[3][:n] = xy, HEIGHT, radius, True
    return out


def detect(key, xy, heights, radii, mask, sigma=0.1, p_detect=0.9, clutter_rate=0.0,
           feet_offset=RADIUS):
    """The detector of every statistical test: one capacity, the lean corrected."""
    return cc.detect(CAM, key, xy, heights, radii, mask, capacity=CAPACITY, sigma=sigma,
                     p_detect=p_detect, clutter_rate=clutter_rate, feet_offset=feet_offset,
                     upright=True)


# Shared compiled calls: `cc.project_people` and `cc.detect` keep one compiled program per
# shape, and every batch of keys goes through this one.
@jax.jit
def detect_keys(keys, xy, heights, radii, mask, sigma, p_detect, clutter_rate):
    return jax.vmap(lambda k: detect(k, xy, heights, radii, mask, sigma, p_detect,
                                     clutter_rate))(keys)


def keys(seed):
    return jax.random.split(jax.random.PRNGKey(seed), 2000)


def test_homography_round_trip_float32_and_float64():
    rng = np.random.default_rng(0)
    xy = rng.uniform([0.5, -4.0], [9.0, 4.0], (400, 2))
    for dtype, tol in ((np.float32, 1e-5), (np.float64, 1e-10)):
        cam = cc.look_at(np.array([0.5, -1.0, 3.2], dtype), np.array([4.0, 0.5, 0.0], dtype))
        pts = xy.astype(dtype)
        seen = np.asarray(cc.in_footprint(cam, pts))
        assert seen.sum() > 100
        H, H_inv = cc.ground_homography(cam), cc.inverse_ground_homography(cam)
        assert H.dtype == H_inv.dtype == dtype
        back = cc.image_to_floor(H_inv, cc.floor_to_image(H, pts[seen]))
        assert back.dtype == dtype
        np.testing.assert_allclose(np.asarray(back), pts[seen], atol=tol, rtol=0)
        np.testing.assert_allclose(np.asarray(H_inv @ H), np.eye(3), atol=tol)


@pytest.mark.parametrize("yaw, pitch", [(0.0, 0.6), (2.3, 0.9), (-1.1, 0.35), (0.7, 1.3)])
def test_floor_to_image_matches_a_pinhole_projection(yaw, pitch):
    position = np.array([1.0, -2.0, 2.8])
    target = position + np.array([math.cos(pitch) * math.cos(yaw),
                                  math.cos(pitch) * math.sin(yaw), -math.sin(pitch)])
    cam = cc.look_at(position, target, fx=520.0, fy=510.0, cx=318.0, cy=244.0)
    R = rotation(yaw, pitch)
    np.testing.assert_allclose(np.asarray(cam.rotation), R, atol=1e-12)
    rng = np.random.default_rng(1)
    xy = position[:2] + rng.uniform(-6, 6, (200, 2))
    uv_ref, depth = pinhole(position, R, intrinsics(cam), xy)
    front = depth > 0.1
    uv = np.asarray(cc.floor_to_image(cc.ground_homography(cam), xy))
    np.testing.assert_allclose(uv[front], uv_ref[front], rtol=1e-10, atol=1e-8)
    inside = front & np.all((uv_ref >= 0) & (uv_ref <= [640, 480]), 1)
    inside &= np.hypot(np.linalg.norm(xy - position[:2], axis=1), position[2]) <= 10.0
    np.testing.assert_array_equal(np.asarray(cc.in_footprint(cam, xy)), inside)


def test_feet_point_of_an_unoccluded_person_projects_back_to_the_person():
    """The bottom of a box is the image of the feet's *nearest* rim, so the plain homography
    puts a person one radius nearer the camera; moved back by the radius (``feet_offset``) a
    person on the image's centre column is exact, and one off it, with the lean of vertical
    lines corrected (``upright``), is within 6 cm (the box centre is not exactly on the
    person's axis, and the lowest rim point in the image is not exactly the nearest one)."""
    xy = np.array([[3.0, 0.0], [4.0, 1.0], [5.0, -2.0], [2.5, 1.2], [6.0, 2.5], [3.5, -0.5]])
    proj = project(CAM, *people(xy))
    assert np.all(np.asarray(proj.visible))
    on_axis = np.asarray(cc.boxes_to_floor(CAM, proj.boxes, RADIUS))
    np.testing.assert_allclose(on_axis[0], xy[0], atol=1e-9)
    plain = np.asarray(cc.boxes_to_floor(CAM, proj.boxes, upright=True))
    towards = -xy / np.linalg.norm(xy, axis=1, keepdims=True)    # towards the nadir (0, 0)
    bias = np.sum((plain - xy) * towards, 1)
    np.testing.assert_allclose(bias, RADIUS, atol=0.015)
    corrected = np.asarray(cc.boxes_to_floor(CAM, proj.boxes, RADIUS, upright=True))
    assert np.all(np.linalg.norm(corrected - xy, axis=1) < 0.06)
    # A thin person (2 cm): the same within a few millimetres.
    thin = project(CAM, *people(xy, radius=0.02))
    corrected = np.asarray(cc.boxes_to_floor(CAM, thin.boxes, 0.02, upright=True))
    assert np.all(np.linalg.norm(corrected - xy, axis=1) < 0.005)
    # Without the lean correction, people off the centre column are off by decimetres.
    leaning = np.asarray(cc.boxes_to_floor(CAM, proj.boxes, RADIUS))
    assert np.linalg.norm(leaning[1] - xy[1]) > 0.15


def test_a_person_behind_another_is_hidden_and_visible_again_when_moved_aside():
    proj = project(CAM, *people([[3.0, 0.0], [4.0, 0.0]]))
    np.testing.assert_array_equal(np.asarray(proj.visible)[:2], [True, False])
    assert float(proj.occlusion[1]) > 0.5 and float(proj.occlusion[0]) == 0.0
    proj = project(CAM, *people([[3.0, 0.0], [4.0, 1.0]]))
    np.testing.assert_array_equal(np.asarray(proj.visible)[:2], [True, True])
    # The order does not matter, and a masked-out person hides no one.
    xy, h, r, mask = people([[4.0, 0.0], [3.0, 0.0]])
    np.testing.assert_array_equal(np.asarray(project(CAM, xy, h, r, mask).visible)[:2],
                                  [False, True])
    mask[1] = False
    np.testing.assert_array_equal(np.asarray(project(CAM, xy, h, r, mask).visible)[:2],
                                  [True, False])
    # A looser occlusion threshold lets the hidden person through.
    mask[1] = True
    loose = project(CAM, xy, h, r, mask, max_occlusion=0.9)
    np.testing.assert_array_equal(np.asarray(loose.visible)[:2], [True, True])


def test_a_static_occluder_box_hides_a_person():
    xy, h, r, mask = people([[3.0, 0.0], [4.0, 1.0]])
    box = np.asarray(project(CAM, xy, h, r, mask).boxes[1])
    shelf = box[None] + np.array([[-5.0, 20.0, 5.0, 200.0]])   # covers its lower part
    proj = project(CAM, xy, h, r, mask, occluders=shelf)
    np.testing.assert_array_equal(np.asarray(proj.visible)[:2], [True, False])


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_visible_among_equals_project_people_with_each_query_added(dtype):
    """The reference: for each query, `project_people` of the allowed people plus the query
    (the query last); its visibility is the query's."""
    rng = np.random.default_rng(3)
    Q = 12
    for trial in range(4):
        xy, h, r, _ = people(rng.uniform([1.0, -3.0], [8.0, 3.0], (P, 2)), dtype=dtype)
        h = (h * rng.uniform(0.8, 1.1, P)).astype(dtype)
        query = rng.uniform([1.0, -3.0], [8.0, 3.0], (Q, 2)).astype(dtype)
        query[:3] = xy[:3] + np.array([0.9, 0.1], dtype)          # just behind someone
        qh = np.full(Q, HEIGHT, dtype)
        qr = np.full(Q, RADIUS, dtype)
        allowed = rng.random((Q, P)) < 0.8
        allowed[:, -1] = False
        xy[-1] = np.nan                                           # no row allows it
        shelf = np.array([[300.0, 300.0, 340.0, 480.0]], dtype) if trial % 2 else None
        kw = dict(occluders=shelf, max_occlusion=0.25, min_in_image=0.75, rim_points=8,
                  occlusion_grid=4)
        got = np.asarray(cc.visible_among(CAM, query, qh, qr, xy, h, r, allowed, **kw))
        want = [bool(project(CAM, np.concatenate([xy, query[q:q + 1]]),
                             np.append(h, qh[q]), np.append(r, qr[q]),
                             np.append(allowed[q], True), **kw).visible[-1])
                for q in range(Q)]
        np.testing.assert_array_equal(got, want)
        assert 0 < got.sum() < Q, "both outcomes occur"
    # no people: only the camera's view decides
    none = cc.visible_among(CAM, query, qh, qr, np.zeros((0, 2), dtype), np.zeros(0, dtype),
                            np.zeros(0, dtype), np.zeros((Q, 0), bool))
    alone = [bool(project(CAM, query[q:q + 1], qh[q:q + 1], qr[q:q + 1],
                          np.ones(1, bool)).visible[0]) for q in range(Q)]
    np.testing.assert_array_equal(np.asarray(none), alone)


def test_visible_among_rejects_bad_input():
    xy, h, r, _ = people([[3.0, 0.0], [4.0, 1.0]])
    q = np.array([[5.0, 0.0]])
    ok = np.ones((1, P), bool)
    with pytest.raises(ValueError, match="may_occlude"):
        cc.visible_among(CAM, q, [1.7], [0.25], xy, h, r, ok[:, :2])
    with pytest.raises(TypeError, match="may_occlude"):
        cc.visible_among(CAM, q, [1.7], [0.25], xy, h, r, ok.astype(int))
    with pytest.raises(ValueError, match="people_xy"):
        cc.visible_among(CAM, q, [1.7], [0.25], xy, h, r, ok)    # a NaN person allowed
    with pytest.raises(ValueError, match="query_xy"):
        cc.visible_among(CAM, q[:, :1], [1.7], [0.25], xy, h, r, ok)
    with pytest.raises(ValueError, match="heights"):
        cc.visible_among(CAM, q, [-1.7], [0.25], xy, h, r, ok & False)
    with pytest.raises(ValueError, match="query_xy"):
        cc.visible_among(CAM, q * np.nan, [1.7], [0.25], xy, h, r, ok & False)
    # no queries: an empty answer; under jit a NaN query is not visible
    empty = cc.visible_among(CAM, np.zeros((0, 2)), np.zeros(0), np.zeros(0), xy, h, r,
                             np.zeros((0, P), bool))
    assert empty.shape == (0,) and empty.dtype == bool
    seen = jax.jit(lambda q: cc.visible_among(CAM, q, jnp.array([1.7, 1.7]),
                                              jnp.array([0.25, 0.25]), xy, h, r,
                                              np.zeros((2, P), bool)))(
        jnp.array([[np.nan, 0.0], [5.0, 0.0]]))
    np.testing.assert_array_equal(np.asarray(seen), [False, True])


def test_people_outside_the_field_of_view_or_range_are_not_visible():
    xy = np.array([[4.0, 0.0],      # seen
                   [-3.0, 0.0],     # behind the camera
                   [4.0, 6.0],      # beside the field of view
                   [0.8, 0.0],      # nearly under the camera: feet below the image
                   [4.0, -3.05]])   # at the image's right edge: most of the box out of it
    proj = project(CAM, *people(xy))
    np.testing.assert_array_equal(np.asarray(proj.visible), [True] + [False] * 5)
    np.testing.assert_array_equal(np.asarray(proj.in_front)[:5],
                                  [True, False, True, True, True])
    assert not np.any(np.asarray(proj.in_image)[1:])
    np.testing.assert_array_equal(np.asarray(cc.in_footprint(CAM, xy))[:4],
                                  [True, False, False, False])
    # Beyond the range (5 m from the optical centre, 4.5 m range): in the image, not seen.
    near = cc.look_at(np.array([0.0, 0.0, 3.0]), np.array([4.0, 0.0, 0.0]), max_range=4.5)
    proj = project(near, *people(xy[:1]))
    assert bool(proj.in_image[0]) and not bool(proj.in_range[0])
    assert not bool(proj.visible[0])


def test_detection_noise_std_is_the_seeds_0_1_m():
    scene = people([[4.0, 1.0]])
    truth = detect_keys(keys(0), *scene, 0.0, 1.0, 0.0)[0][0, 0]
    zs, valid = detect_keys(keys(1), *scene, 0.1, 1.0, 0.0)
    N = zs.shape[0]
    assert np.all(np.asarray(valid[:, 0])) and not np.any(np.asarray(valid[:, 1:]))
    res = np.asarray(zs[:, 0]) - np.asarray(truth)
    assert np.all(np.abs(res.mean(0)) < 4 * 0.1 / math.sqrt(N))
    np.testing.assert_allclose(res.std(0), 0.1, rtol=0.06)   # sd of a std: 1.6 % here
    stat = np.sum(res**2) / 0.1**2                           # chi-square, 2N dof
    assert abs(stat - 2 * N) < 4 * math.sqrt(4 * N)
    assert np.linalg.norm(np.asarray(truth) - scene[0][0]) < 0.06


def test_detection_probability_and_clutter_counts_match_their_rates():
    scene = people([[3.0, 0.0], [4.0, 1.5], [5.0, -1.5]])
    p = 0.7
    zs, valid = detect_keys(keys(2), *scene, 0.1, p, 0.0)
    v = np.asarray(valid)
    N = v.shape[0]
    assert abs(v.sum() / (3 * N) - p) < 4 * math.sqrt(p * (1 - p) / (3 * N))
    # People's detections come first; slots after them are empty without clutter.
    assert np.all(v[:, :-1] >= v[:, 1:]) and not np.any(v[:, 3:])

    rate = 2.5
    xy, h, r, mask = scene
    zs, valid = detect_keys(keys(3), xy, h, r, np.zeros_like(mask), 0.1, p, rate)
    counts = np.asarray(valid).sum(1)
    assert abs(counts.mean() - rate) < 4 * math.sqrt(rate / N)
    assert abs(counts.var() - rate) < 0.25 * rate           # Poisson: variance = mean
    clutter = np.asarray(zs)[np.asarray(valid)]
    assert np.all(np.asarray(cc.in_footprint(CAM, clutter)))
    # Uniform on the footprint: its mean and spread are the footprint's (brute-force grid).
    g = np.stack(np.meshgrid(np.linspace(0, 12, 600), np.linspace(-8, 8, 800)), -1)
    g = g.reshape(-1, 2)
    g = g[np.asarray(cc.in_footprint(CAM, g))]
    spread = g.std(0)
    np.testing.assert_allclose(clutter.mean(0), g.mean(0),
                               atol=float(4 * spread.max() / math.sqrt(len(clutter))))
    np.testing.assert_allclose(clutter.std(0), spread, rtol=0.05)


def test_zero_people_and_all_masked_people_give_only_clutter():
    key = jax.random.PRNGKey(5)
    none = people(np.zeros((0, 2)), pad=0)
    zs, valid = cc.detect(CAM, key, *none, capacity=5, p_detect=1.0)
    assert zs.shape == (5, 2) and not np.any(np.asarray(valid))
    zs, valid = cc.detect(CAM, key, *none, capacity=5, clutter_rate=3.0)
    assert np.asarray(valid).sum() > 0
    assert np.all(np.asarray(cc.in_footprint(CAM, np.asarray(zs)[np.asarray(valid)])))
    masked = people(np.zeros((0, 2)))                      # P slots, all masked, NaN
    zs, valid = detect(key, *masked, p_detect=1.0)
    assert not np.any(np.asarray(valid))
    proj = project(CAM, *masked)
    assert not np.any(np.asarray(proj.visible)) and np.all(np.isfinite(np.asarray(proj.boxes)))
    # With clutter, the masked people change nothing: the same draws as no people at all.
    zs0, valid0 = detect_keys(keys(6), *masked, 0.1, 0.9, 3.0)
    zs1, valid1 = detect_keys(keys(6), *people([[3.0, 0.0]]), 0.1, 0.0, 3.0)
    np.testing.assert_array_equal(np.asarray(valid0), np.asarray(valid1))
    np.testing.assert_array_equal(np.asarray(zs0), np.asarray(zs1))


def test_bad_inputs_raise_naming_the_argument():
    key = jax.random.PRNGKey(0)
    xy, h, r, mask = people([[3.0, 0.0], [4.0, 1.0]])
    good = dict(capacity=4)
    cases = [
        (TypeError, "camera", lambda: cc.detect(tuple(CAM), key, xy, h, r, mask, **good)),
        (ValueError, "people_xy", lambda: cc.detect(CAM, key, xy[:, :1], h, r, mask, **good)),
        (ValueError, "heights", lambda: cc.detect(CAM, key, xy, h[:1], r, mask, **good)),
        (ValueError, "heights", lambda: cc.detect(CAM, key, xy, -h, r, mask, **good)),
        (ValueError, "radii", lambda: cc.detect(CAM, key, xy, h, r - 1, mask, **good)),
        (TypeError, "mask", lambda: cc.detect(CAM, key, xy, h, r, mask.astype(int), **good)),
        (ValueError, "people_xy", lambda: cc.detect(CAM, key, xy * np.nan, h, r, mask, **good)),
        (TypeError, "key", lambda: cc.detect(CAM, 0, xy, h, r, mask, **good)),
        (TypeError, "capacity", lambda: cc.detect(CAM, key, xy, h, r, mask, capacity=2.0)),
        (ValueError, "capacity", lambda: cc.detect(CAM, key, xy, h, r, mask, capacity=0)),
        (ValueError, "sigma", lambda: cc.detect(CAM, key, xy, h, r, mask, sigma=-0.1, **good)),
        (ValueError, "p_detect",
         lambda: cc.detect(CAM, key, xy, h, r, mask, p_detect=1.5, **good)),
        (ValueError, "clutter_rate",
         lambda: cc.detect(CAM, key, xy, h, r, mask, clutter_rate=-1.0, **good)),
        (ValueError, "occluders",
         lambda: cc.project_people(CAM, xy, h, r, mask, occluders=np.zeros((2, 3)))),
        (ValueError, "max_occlusion",
         lambda: cc.project_people(CAM, xy, h, r, mask, max_occlusion=2.0)),
        (ValueError, "position", lambda: cc.look_at((0.0, 0.0, -1.0), (1.0, 0.0, 0.0))),
        (ValueError, "target", lambda: cc.look_at((0.0, 0.0, 3.0), (0.0, 0.0, 3.0))),
        (ValueError, "fx", lambda: cc.look_at((0.0, 0.0, 3.0), (1.0, 0.0, 0.0), fx=0.0)),
        (ValueError, "max_range",
         lambda: cc.look_at((0.0, 0.0, 3.0), (1.0, 0.0, 0.0), max_range=math.inf)),
        (ValueError, "uv", lambda: cc.image_to_floor(np.eye(3), np.zeros((4, 3)))),
        (ValueError, "H", lambda: cc.floor_to_image(np.eye(2), np.zeros((4, 2)))),
        (ValueError, "boxes", lambda: cc.boxes_to_floor(CAM, np.zeros((4, 2)))),
    ]
    for error, name, call in cases:
        with pytest.raises(error, match=name):
            call()




def test_jit_equals_eager_and_vmap_over_keys_and_float32():
    scene = people([[3.0, 0.0], [4.0, 1.0], [4.0, 0.0]])
    key = jax.random.PRNGKey(7)
    eager = detect(key, *scene, 0.1, 0.8, 1.5)
    jitted = jax.jit(detect)(key, *scene, 0.1, 0.8, 1.5)
    np.testing.assert_array_equal(np.asarray(eager[1]), np.asarray(jitted[1]))
    np.testing.assert_allclose(np.asarray(eager[0]), np.asarray(jitted[0]), rtol=0, atol=1e-12)
    batch = detect_keys(keys(7), *scene, 0.1, 0.8, 1.5)
    assert batch[0].shape == (2000, CAPACITY, 2) and batch[1].shape == (2000, CAPACITY)
    for i in range(3):
        one = detect(keys(7)[i], *scene, 0.1, 0.8, 1.5)
        np.testing.assert_allclose(np.asarray(batch[0][i]), np.asarray(one[0]), atol=1e-12)
        np.testing.assert_array_equal(np.asarray(batch[1][i]), np.asarray(one[1]))
    # float32 people and camera: float32 detections of the same (noise-free) scene.
    cam32 = cc.look_at(np.array([0.0, 0.0, 3.0], np.float32),
                       np.array([4.0, 0.0, 0.0], np.float32))
    exact = dict(capacity=CAPACITY, sigma=0.0, p_detect=1.0, feet_offset=RADIUS, upright=True)
    z32, v32 = cc.detect(cam32, key, *people(scene[0][:3], dtype=np.float32), **exact)
    z64, v64 = cc.detect(CAM, key, *scene, **exact)
    assert z32.dtype == jnp.float32
    np.testing.assert_array_equal(np.asarray(v32), np.asarray(v64))
    np.testing.assert_allclose(np.asarray(z32), np.asarray(z64), atol=1e-5)
