"""The colour-histogram particle tracker (`jaxtrack.tracking.colour_pf`) on synthetic ceiling
images: a robot seen from above as an ellipse (white, blue shoulders) across its heading, on a
brown floor, with pixel noise. The tracker follows it in float32 and float64."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.perception import colour_histogram as ch
from jaxtrack.perception import depth
from jaxtrack.tracking import colour_pf, estimator, humanoid

W, H = 80, 60
CAMERA = depth.CeilingCamera((0.0, 0.0, 2.8), (W / 2) / math.tan(math.radians(28.5)),
                             (H / 2) / math.tan(math.radians(21.5)), W / 2, H / 2)
CONFIG = colour_pf.ColourPFConfig(CAMERA, num_particles=64)
FLOOR = np.array([0.5, 0.45, 0.4])


def synthetic_image(rng, pose, brightness=1.0):
    """[H, W, 3] image of an ellipse (half axes 0.05 m along the heading, 0.13 m across) at the
    region height, blue beyond 0.08 m from the centre across the heading, else white."""
    h = CAMERA.position[2] - CONFIG.region_height
    j, i = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    x = CAMERA.position[0] + h * (j - CAMERA.cx) / CAMERA.fx - pose[0]
    y = CAMERA.position[1] - h * (i - CAMERA.cy) / CAMERA.fy - pose[1]
    c, s = math.cos(pose[2]), math.sin(pose[2])
    u, v = c * x + s * y, -s * x + c * y
    inside = (u / 0.05) ** 2 + (v / 0.13) ** 2 <= 1
    img = np.broadcast_to(FLOOR, (H, W, 3)).copy()
    img[inside] = [0.92, 0.92, 0.9]
    img[inside & (np.abs(v) > 0.08)] = [0.12, 0.3, 0.78]
    return np.clip(brightness * img + rng.normal(0, 0.02, img.shape), 0, 1)


def trajectory(n=14):
    t = np.arange(n + 1)
    return np.stack([-0.3 + 0.025 * t, 0.1 + 0.01 * t, 0.2 + np.deg2rad(3.0) * t], -1)


@pytest.fixture(scope="module")
def frames():
    rng = np.random.default_rng(0)
    poses = trajectory()
    images = np.stack([synthetic_image(rng, p) for p in poses])
    return poses, images


@pytest.fixture(scope="module")
def tracker():
    est = colour_pf.colour_pf(CONFIG, dt=0.25)

    @jax.jit
    def track(key, params, start, first, images, turn):
        valid = jnp.ones(images.shape[1:3], bool)
        state = est.init(key, params, colour_pf.ColourPrior(start, first, valid))
        zs = colour_pf.ColourFrame(images, jnp.broadcast_to(valid, images.shape[:3]), turn)
        return estimator.run(est, key, state, zs, params)

    return est, track


def _errors(out, poses):
    err = np.hypot(*(np.asarray(out[:, :2], float) - poses[1:, :2]).T)
    head = np.rad2deg(np.abs((np.asarray(out[:, 2], float) - poses[1:, 2] + np.pi)
                             % (2 * np.pi) - np.pi))
    return err, head


def _run(frames, tracker, dtype, lam):
    poses, images = frames
    est, track = tracker
    params = est.params(position_noise=0.035, lam=lam, dtype=dtype)
    turn = jnp.full(len(poses) - 1, np.deg2rad(3.0) / 0.25, dtype)
    _, out = track(jax.random.PRNGKey(0), params, jnp.asarray(poses[0], dtype),
                   jnp.asarray(images[0], dtype), jnp.asarray(images[1:], dtype), turn)
    assert out.dtype == dtype and out.shape == (len(poses) - 1, 3)
    return _errors(out, poses)


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_tracks_a_moving_synthetic_robot(frames, tracker, dtype):
    """The robot walks 38 cm in 14 frames (2.7 cm per frame); pixels are 3 cm at the region
    height. The histogram's Bhattacharyya coefficient is flat near its peak (0.997 at the
    truth, 0.99 at 4 cm), so the default weight (lambda 50) trails the walk by a few cm."""
    err, head = _run(frames, tracker, dtype, 50.0)
    assert np.median(err) < 0.05 and err.max() < 0.08, err
    assert np.mean(head) < 5.0 and head.max() < 12.0, head


def test_a_sharper_likelihood_trails_less(frames, tracker):
    soft, _ = _run(frames, tracker, jnp.float64, 50.0)
    sharp, _ = _run(frames, tracker, jnp.float64, 400.0)
    assert np.mean(sharp) < 0.8 * np.mean(soft), (np.mean(sharp), np.mean(soft))
    assert np.median(sharp) < 0.035


def test_the_reference_is_the_first_frames_disc_histogram(frames, tracker):
    poses, images = frames
    est, _ = tracker
    start = jnp.asarray(poses[0])
    valid = jnp.ones((H, W), bool)
    state = est.init(jax.random.PRNGKey(1), est.params(dtype=jnp.float64),
                     colour_pf.ColourPrior(start, jnp.asarray(images[0]), valid))
    # The reference: every pixel of the first image (the block covers the disc), placed at
    # the region height, through the Epanechnikov kernel.
    h = CAMERA.position[2] - CONFIG.region_height
    pts = depth.back_project(CAMERA, jnp.full((H, W), h), valid)[:, :2]
    want = ch.kernel_histograms(images[0].reshape(-1, 3), pts, start[None, :2],
                                CONFIG.region_radius, config=CONFIG.histogram)[0]
    np.testing.assert_allclose(np.asarray(state.reference), np.asarray(want), atol=1e-12)
    assert float(ch.bhattacharyya(state.reference, want)) > 1 - 1e-12
    assert state.particles.particles.shape == (CONFIG.num_particles, 2)
    # Robot colours are the model's (ratio 1), the floor's are not.
    cfg = CONFIG.histogram
    robot = ch.backprojection(jnp.array([[0.92, 0.92, 0.9], [0.12, 0.3, 0.78]]), state.ratio,
                              cfg)
    floor = ch.backprojection(jnp.asarray(FLOOR[None]), state.ratio, cfg)
    assert np.all(np.asarray(robot) > 0.9) and float(floor[0]) < CONFIG.foreground


def test_a_frame_without_valid_pixels_keeps_the_estimate_finite(frames, tracker):
    poses, images = frames
    est, _ = tracker
    params = est.params(dtype=jnp.float64)
    valid = jnp.ones((H, W), bool)
    state = est.init(jax.random.PRNGKey(2), params,
                     colour_pf.ColourPrior(jnp.asarray(poses[0]), jnp.asarray(images[0]), valid))
    update = jax.jit(est.update)
    blank = jnp.full((H, W, 3), jnp.nan)
    state, out = update(jax.random.PRNGKey(3), state,
                        colour_pf.ColourFrame(blank, jnp.zeros((H, W), bool), 0.0), params)
    assert np.all(np.isfinite(np.asarray(out)))
    assert np.hypot(*(np.asarray(out[:2]) - poses[0, :2])) < 0.1
    assert float(out[2]) == pytest.approx(poses[0, 2])      # no foreground: heading kept


def test_differentiable_resampling_gives_finite_parameter_gradients(frames):
    poses, images = frames
    est = colour_pf.colour_pf(CONFIG, smooth=humanoid.SmoothConfig(resampling="stop_gradient"))
    valid = jnp.ones((H, W), bool)

    def loss(params):
        state = est.init(jax.random.PRNGKey(0), params,
                         colour_pf.ColourPrior(jnp.asarray(poses[0]), jnp.asarray(images[0]),
                                               valid))
        zs = colour_pf.ColourFrame(jnp.asarray(images[1:5]), jnp.broadcast_to(valid, (4, H, W)),
                                   jnp.zeros(4))
        _, out = estimator.run(est, jax.random.PRNGKey(1), state, zs, params)
        return jnp.sum((out[:, :2] - poses[1:5, :2]) ** 2)

    g = jax.jit(jax.grad(loss))(est.params(dtype=jnp.float64))
    leaves = np.array([float(x) for x in jax.tree_util.tree_leaves(g)])
    assert np.all(np.isfinite(leaves)) and np.any(leaves != 0)


@pytest.mark.parametrize("make, match", [
    (lambda: colour_pf.ColourPFConfig(CAMERA, num_particles=0), "num_particles"),
    (lambda: colour_pf.ColourPFConfig(CAMERA, region_radius=-0.1), "region_radius"),
    (lambda: colour_pf.ColourPFConfig(CAMERA, region_height=3.0), "region_height"),
    (lambda: colour_pf.ColourPFConfig(CAMERA, foreground=0.0), "foreground"),
    (lambda: colour_pf.ColourPFConfig(CAMERA, histogram=ch.HistogramConfig("luv")),
     "unknown space"),
    (lambda: colour_pf.make_params(position_noise=0.0), "position_noise"),
    (lambda: colour_pf.make_params(lam=float("nan")), "lam"),
])
def test_bad_configuration_raises(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_bad_frames_raise_at_the_boundary(frames, tracker):
    poses, images = frames
    est, _ = tracker
    params = est.params(dtype=jnp.float64)
    valid = jnp.ones((H, W), bool)
    with pytest.raises(ValueError, match="image must be"):
        est.init(jax.random.PRNGKey(0), params,
                 colour_pf.ColourPrior(jnp.asarray(poses[0]), jnp.zeros((H, W)), valid))
    with pytest.raises(ValueError, match="smaller than the tracker's"):
        est.init(jax.random.PRNGKey(0), params,
                 colour_pf.ColourPrior(jnp.asarray(poses[0]), jnp.zeros((8, 8, 3)),
                                       jnp.ones((8, 8), bool)))
    with pytest.raises(ValueError, match="valid must have shape"):
        est.init(jax.random.PRNGKey(0), params,
                 colour_pf.ColourPrior(jnp.asarray(poses[0]), jnp.asarray(images[0]),
                                       jnp.ones((H, W + 1), bool)))
    with pytest.raises(ValueError, match="prior.pose"):
        est.init(jax.random.PRNGKey(0), params,
                 colour_pf.ColourPrior(jnp.zeros(2), jnp.asarray(images[0]), valid))
