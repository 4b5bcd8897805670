"""Seed 000 depth tracker: point-count likelihood, PCA heading, particle-filter convergence.

References: a one-point-at-a-time count written with explicit geometry, numpy's eigensolver for
the PCA axis, finite differences for the gradients. Shapes are small and every jitted function
is built once per module.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.filters import particle
from jaxtrack.perception import depth
from tests.perception import references as ref

MODEL = depth.RobotModel()
OTHER_MODEL = depth.RobotModel(head_radius=0.09, z_threshold=0.4, head_top=0.6,
                               shoulder_half_length=0.2, shoulder_half_depth=0.03,
                               shoulder_bottom=0.25)

# Jitted once per module (eager dispatch compiles every primitive and dominates the runtime).
count = jax.jit(depth.point_count)
smooth = jax.jit(depth.smooth_point_count)
smooth_grad = jax.jit(jax.grad(depth.smooth_point_count, argnums=(2, 3)))
loglik = jax.jit(depth.log_likelihood, static_argnames=("temperature",))
pca = jax.jit(depth.pca_heading, static_argnames=("on_jump", "min_points"))


def random_cloud(rng, centre, n=300, capacity=320):
    """Uniform points in a 0.4 m square around ``centre`` over 0-0.8 m of height, some masked
    out, some NaN (masked too), padded to ``capacity``."""
    pts = np.empty((capacity, 3))
    pts[:, :2] = centre + rng.uniform(-0.2, 0.2, (capacity, 2))
    pts[:, 2] = rng.uniform(0.0, 0.8, capacity)
    mask = np.zeros(capacity, bool)
    mask[:n] = True
    mask[rng.choice(n, 30, replace=False)] = False
    pts[n:n + 10] = np.nan
    return pts, mask


@pytest.fixture(scope="module")
def clouds():
    rng = np.random.default_rng(1)
    out = []
    for _ in range(4):
        centre = rng.uniform(-2, 2, 2)
        pts, mask = random_cloud(rng, centre)
        poses = np.concatenate([centre + rng.normal(0, 0.05, (6, 2)),
                                rng.uniform(-np.pi, np.pi, (6, 1))], -1)
        out.append((pts, mask, poses))
    return out


# ---------------------------------------------------------------------------------------------
# Point counts


@pytest.mark.parametrize("model", [MODEL, OTHER_MODEL], ids=["default", "other"])
def test_point_count_equals_brute_force_count(clouds, model):
    for pts, mask, poses in clouds:
        got = np.asarray(count(pts, mask, poses, model))  # [6] poses at once
        want = [ref.brute_force_count(pts, mask, p, model) for p in poses]
        np.testing.assert_array_equal(got, want)
        assert min(want) > 5  # every pose sees part of the cloud


def test_point_count_of_one_pose_matches_the_batched_count(clouds):
    pts, mask, poses = clouds[0]
    batched = count(pts, mask, poses, MODEL)
    single = [count(pts, mask, p, MODEL) for p in poses]
    np.testing.assert_array_equal(batched, single)


def test_rotating_the_model_equals_rotating_the_points_the_other_way(clouds):
    for pts, mask, poses in clouds:
        for x, y, th in poses:
            c, s = np.cos(-th), np.sin(-th)
            d = pts[:, :2] - [x, y]
            rotated = pts.copy()
            rotated[:, :2] = np.stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1]], -1)
            a = count(pts, mask, np.array([x, y, th]), MODEL)
            b = count(rotated, mask, np.zeros(3), MODEL)
            assert float(a) == float(b)


def test_point_count_of_synthetic_robot_peaks_at_its_pose():
    rng = np.random.default_rng(2)
    pose = np.array([0.5, -0.2, 0.7])
    pts, mask = ref.robot_cloud(rng, pose, n_clutter=0)
    at_pose, turned, shifted = np.asarray(count(pts, mask, pose + np.array(
        [[0, 0, 0], [0, 0, np.pi / 2], [0.1, 0, 0]]), MODEL))
    assert at_pose == mask.sum()  # every robot point lies inside the model
    assert turned < 0.7 * at_pose and shifted < 0.7 * at_pose


def test_smooth_count_tends_to_the_hard_count(clouds):
    for pts, mask, poses in clouds:
        hard = np.asarray(count(pts, mask, poses, MODEL))
        errs = [np.max(np.abs(np.asarray(smooth(pts, mask, poses, MODEL, s)) - hard))
                for s in (1e-2, 1e-3, 1e-4, 1e-7)]
        assert errs[0] > 0.5               # a real smoothing at 1 cm
        assert errs[1] < errs[0] and errs[2] < errs[1]
        assert errs[3] < 0.05              # rounds to the hard count


def test_smooth_count_gradients_match_finite_differences(clouds):
    pts, mask, poses = clouds[1]
    soft = 0.01

    def f(pose, model):
        return smooth(pts, mask, pose, model, soft)

    h = 1e-6
    for pose in poses[:3]:
        g_pose, g_model = smooth_grad(pts, mask, pose, MODEL, soft)
        assert np.all(np.isfinite(g_pose)) and np.linalg.norm(g_pose) > 1.0
        for i in range(3):
            e = np.zeros(3)
            e[i] = h
            fd = (f(pose + e, MODEL) - f(pose - e, MODEL)) / (2 * h)
            np.testing.assert_allclose(g_pose[i], fd, rtol=1e-5, atol=1e-6)
        for name in MODEL._fields:
            up = MODEL._replace(**{name: getattr(MODEL, name) + h})
            down = MODEL._replace(**{name: getattr(MODEL, name) - h})
            fd = (f(pose, up) - f(pose, down)) / (2 * h)
            np.testing.assert_allclose(getattr(g_model, name), fd, rtol=1e-5, atol=1e-6)


def test_smooth_count_gradient_is_finite_at_the_head_centre_and_with_nan_points():
    pts = np.array([[0.0, 0.0, 0.55], [np.nan, 0.0, 0.5], [0.1, 0.02, 0.4]])
    mask = np.array([True, True, True])
    g_pose, g_model = smooth_grad(pts, mask, np.zeros(3), MODEL, 0.01)
    assert np.all(np.isfinite(g_pose))
    assert np.all(np.isfinite(jnp.stack(g_model)))


def test_float32_counts_and_gradients(clouds):
    pts, mask, poses = clouds[2]
    p32, pose32 = pts.astype(np.float32), poses[0].astype(np.float32)
    hard = count(p32, mask, pose32, MODEL)
    assert hard.dtype == jnp.float32
    assert float(hard) == float(count(pts, mask, poses[0], MODEL))
    g = smooth_grad(p32, mask, pose32, MODEL, np.float32(0.01))[0]
    g64 = smooth_grad(pts, mask, poses[0], MODEL, 0.01)[0]
    assert g.dtype == jnp.float32
    np.testing.assert_allclose(g, g64, rtol=1e-3, atol=1e-2)


def test_count_rejects_bad_shapes_and_nan_poses():
    pts, mask = np.zeros((5, 3)), np.ones(5, bool)
    with pytest.raises(ValueError, match="points"):
        depth.point_count(np.zeros((5, 2)), mask, np.zeros(3))
    with pytest.raises(ValueError, match="mask"):
        depth.point_count(pts, np.ones(4, bool), np.zeros(3))
    with pytest.raises(ValueError, match="pose"):
        depth.point_count(pts, mask, np.zeros(2))
    with pytest.raises(ValueError, match="pose"):
        depth.point_count(pts, mask, np.array([0.0, np.nan, 0.0]))
    with pytest.raises(ValueError, match="softness"):
        depth.smooth_point_count(pts, mask, np.zeros(3), softness=0.0)


# ---------------------------------------------------------------------------------------------
# Likelihood and particle filter


def test_log_likelihood_is_log_of_count_plus_eps_for_two_and_three_state_particles(clouds):
    pts, mask, poses = clouds[0]
    frame = depth.DepthFrame(pts, mask, poses[0, 2])
    counts = np.array([ref.brute_force_count(pts, mask, [x, y, poses[0, 2]], MODEL)
                       for x, y in poses[:, :2]])
    ll2 = loglik(frame, poses[:, :2])
    ll3 = loglik(frame, np.concatenate([poses[:, :2], np.full((6, 1), poses[0, 2])], -1))
    np.testing.assert_allclose(ll2, np.log(counts + 1.0), rtol=1e-12)
    np.testing.assert_allclose(ll3, ll2, rtol=1e-12)
    np.testing.assert_allclose(loglik(frame, poses[:, :2], eps=0.5), np.log(counts + 0.5),
                               rtol=1e-12)
    np.testing.assert_allclose(loglik(frame, poses[:, :2], temperature=4.0), counts / 4.0,
                               rtol=1e-12)
    # A full (x, y, theta) state uses its own heading, not the frame's.
    other = loglik(frame, poses)
    want = [np.log(ref.brute_force_count(pts, mask, p, MODEL) + 1.0) for p in poses]
    np.testing.assert_allclose(other, want, rtol=1e-12)
    # One particle at a time (particle.step's default, vmapped) gives the same weights.
    one_at_a_time = jax.jit(jax.vmap(depth.log_likelihood, (None, 0)))(frame, poses[:, :2])
    np.testing.assert_allclose(one_at_a_time, ll2, rtol=1e-12)
    with pytest.raises(ValueError, match="particle states"):
        depth.log_likelihood(frame, np.zeros((4, 4)))


def test_empty_frame_leaves_particle_weights_uniform():
    frame = depth.DepthFrame(np.zeros((320, 3)), np.zeros(320, bool), 0.0)
    ll = loglik(frame, np.random.default_rng(0).normal(size=(6, 2)))
    np.testing.assert_array_equal(ll, np.zeros(6))


def test_likelihood_is_half_turn_symmetric_and_folding_keeps_it(clouds):
    """The counts cannot tell theta from theta + pi; `fold_half_turn` maps each heading to the
    representative within a quarter turn of the reference without changing its likelihood."""
    pts, mask, poses = clouds[1]
    frame = depth.DepthFrame(pts, mask, 0.0)
    turned = poses + np.array([0.0, 0.0, np.pi])
    np.testing.assert_allclose(loglik(frame, turned), loglik(frame, poses), rtol=1e-12)
    rng = np.random.default_rng(5)
    theta = rng.uniform(-3 * np.pi, 3 * np.pi, 200)
    ref_heading = rng.uniform(-np.pi, np.pi, 200)
    folded = np.asarray(depth.fold_half_turn(theta, ref_heading))
    # Same heading modulo pi, within [-pi/2, pi/2) of the reference, wrapped.
    k = (folded - theta) / np.pi
    np.testing.assert_allclose(k, np.round(k), atol=1e-9)
    gap = np.angle(np.exp(1j * (folded - ref_heading)))
    assert np.all(np.abs(gap) <= np.pi / 2 + 1e-12)
    assert np.all((folded >= -np.pi) & (folded < np.pi))
    folded_poses = poses.copy()
    folded_poses[:, 2] = depth.fold_half_turn(poses[:, 2], 0.3)
    np.testing.assert_allclose(loglik(frame, folded_poses), loglik(frame, poses), rtol=1e-12)
    np.testing.assert_allclose(depth.fold_half_turn(np.array([3.0, -0.1]), 0.0),
                               [3.0 - np.pi, -0.1], rtol=1e-12)


PF_TRUTH = np.array([0.8, -0.3, 0.6])
PF_FRAMES = 8
PF_PARTICLES = 400


@pytest.fixture(scope="module")
def pf_frames():
    rng = np.random.default_rng(3)
    frames = [ref.robot_cloud(rng, PF_TRUTH) for _ in range(PF_FRAMES)]
    return depth.DepthFrame(np.stack([f[0] for f in frames]), np.stack([f[1] for f in frames]),
                            np.full(PF_FRAMES, PF_TRUTH[2]))


def test_particle_filter_converges_on_a_standing_robot(pf_frames):
    """SIR with the seed's count weights from a wide prior 14 cm off: within 3 cm after 5 frames
    and 2 cm after 8 (over 20 random poses we measured a mean error of 6.3 / 2.8 / 1.7 / 1.0 cm
    after 1 / 3 / 5 / 8 frames, worst 1.7 cm after 8)."""

    def transition(key, x):
        return x + 0.01 * jax.random.normal(key, x.shape, x.dtype)

    def run(key):
        init = particle.init_from_gaussian(key, jnp.asarray(PF_TRUTH[:2] + [0.12, 0.08]),
                                           0.1**2 * jnp.eye(2), PF_PARTICLES)
        res = particle.filter(key, init, pf_frames, transition, depth.log_likelihood,
                              vectorized=True)
        return jnp.linalg.norm(res.means - PF_TRUTH[:2], axis=-1)

    err = np.asarray(jax.jit(jax.vmap(run))(jax.random.split(jax.random.PRNGKey(0), 4)))
    assert np.all(err[:, 4] < 0.03)
    assert np.all(err[:, -1] < 0.02)


# ---------------------------------------------------------------------------------------------
# PCA heading

@pytest.fixture(scope="module")
def ellipses():
    """(points [P, 3], mask, centre, facing) for 12 facings round the circle (incl. near pi)."""
    rng = np.random.default_rng(5)
    facings = np.deg2rad([-179.5, -150, -100, -60, -20, 0, 15, 50, 89, 120, 165, 179.5])
    out = []
    for facing in facings:
        centre = rng.uniform(-1, 1, 2)
        out.append((ref.ellipse_cloud(rng, centre, facing), np.ones(800, bool), centre,
                    float(facing)))
    return out


def test_pca_measured_axis_equals_numpy_eigenvector(ellipses):
    for pts, mask, centre, facing in ellipses:
        out = pca(pts, mask, centre, 0.3, facing, 0.5, 1.0)
        axis = ref.pca_minor_axis(pts[:, :2])
        # Same axis (mod pi) as numpy's minor eigenvector.
        assert abs(ref.wrap(2 * (float(out.measured) - axis))) < 1e-9


def test_pca_heading_error_below_3_degrees_on_noisy_ellipses(ellipses):
    errs = []
    for pts, mask, centre, facing in ellipses:
        out = pca(pts, mask, centre, 0.3, facing + math.radians(8.0), math.radians(20.0), 1.0)
        assert bool(out.accepted)
        assert -np.pi <= float(out.heading) < np.pi
        errs.append(abs(ref.wrap(float(out.heading) - facing)))
    assert np.rad2deg(max(errs)) < 3.0


def test_sign_ambiguity_is_resolved_by_the_previous_heading(ellipses):
    for pts, mask, centre, facing in ellipses:
        back = facing + np.pi
        out = pca(pts, mask, centre, 0.3, float(ref.wrap(back - 0.1)), math.radians(20.0), 1.0)
        assert abs(ref.wrap(float(out.heading) - back)) < math.radians(3.0)


def test_jumps_are_clipped_or_rejected(ellipses):
    pts, mask, centre, facing = ellipses[6]
    window = math.radians(20.0)
    prev = facing + math.radians(60.0)
    clip = pca(pts, mask, centre, 0.3, prev, window, 1.0, on_jump="clip")
    keep = pca(pts, mask, centre, 0.3, prev, window, 1.0, on_jump="keep")
    assert not bool(clip.accepted) and not bool(keep.accepted)
    np.testing.assert_allclose(float(keep.heading), ref.wrap(prev), atol=1e-12)
    np.testing.assert_allclose(float(clip.heading), ref.wrap(prev - window), atol=1e-12)
    assert abs(ref.wrap(float(keep.measured) - facing)) < math.radians(3.0)


def test_smoothing_moves_a_gain_fraction_of_the_way(ellipses):
    pts, mask, centre, facing = ellipses[3]
    prev = facing - math.radians(10.0)
    out = pca(pts, mask, centre, 0.3, prev, math.radians(20.0), 0.3)
    delta = ref.wrap(float(out.measured) - prev)
    np.testing.assert_allclose(float(out.heading), ref.wrap(prev + 0.3 * delta), atol=1e-12)


def test_no_points_few_points_or_a_round_cloud_keep_the_previous_heading():
    rng = np.random.default_rng(6)
    pts = ref.ellipse_cloud(rng, [0.0, 0.0], 0.3)
    none = pca(pts, np.zeros(800, bool), np.zeros(2), 0.3, 1.0, 0.3, 1.0)
    far = pca(pts, np.ones(800, bool), np.array([5.0, 5.0]), 0.3, 1.0, 0.3, 1.0)
    two = pca(pts, np.arange(800) < 2, np.zeros(2), 0.3, 1.0, 0.3, 1.0)
    r = np.sqrt(rng.uniform(size=800)) * 0.1
    a = rng.uniform(0, 2 * np.pi, 800)
    disc = np.stack([r * np.cos(a), r * np.sin(a), np.full(800, 0.5)], -1)
    mask = np.ones(800, bool)
    round_ = pca(disc, mask, np.zeros(2), 0.3, 1.0, 0.3, 1.0, min_elongation=0.2)
    for out in (none, far, two, round_):
        assert float(out.heading) == pytest.approx(1.0, abs=1e-15) and not bool(out.accepted)
    assert float(none.num_points) == 0 and float(far.num_points) == 0
    g = jax.jit(jax.grad(lambda p: depth.pca_heading(pts, np.zeros(800, bool), np.zeros(2), 0.3,
                                                     p, 0.3, 0.5).heading))(1.0)
    assert float(g) == 1.0


def test_masked_and_out_of_window_points_are_ignored(ellipses):
    pts, mask, centre, facing = ellipses[7]
    # A bar along the facing direction: it would turn the axis by 90 deg if it counted.
    bar = np.stack([centre[0] + np.linspace(-0.25, 0.25, 400) * np.cos(facing),
                    centre[1] + np.linspace(-0.25, 0.25, 400) * np.sin(facing),
                    np.full(400, 0.4)], -1)
    far = bar + [3.0, 0.0, 0.0]
    nan = np.full((5, 3), np.nan)
    all_pts = np.concatenate([pts, bar, far, nan])
    all_mask = np.concatenate([mask, np.zeros(400, bool), np.ones(400, bool), np.ones(5, bool)])
    a = pca(all_pts, all_mask, centre, 0.3, facing, 0.5, 1.0)
    b = pca(pts, mask, centre, 0.3, facing, 0.5, 1.0)
    np.testing.assert_allclose(float(a.heading), float(b.heading), atol=1e-12)
    assert float(a.num_points) == 800
    with_bar = pca(np.concatenate([pts, bar]), np.ones(1200, bool), centre, 0.3, facing,
                   math.radians(20.0), 1.0)
    assert not bool(with_bar.accepted)  # the bar does flip the axis when it is not masked


def test_pca_heading_vmaps_over_frames(ellipses):
    pts = np.stack([e[0] for e in ellipses])
    masks = np.stack([e[1] for e in ellipses])
    centres = np.stack([e[2] for e in ellipses])
    facings = np.array([e[3] for e in ellipses])
    batched = jax.jit(jax.vmap(lambda p, m, c, h: depth.pca_heading(p, m, c, 0.3, h, 0.5,
                                                                    1.0).heading))(
        pts, masks, centres, facings)
    loop = [float(pca(p, m, c, 0.3, float(h), 0.5, 1.0).heading)
            for p, m, c, h in zip(pts, masks, centres, facings)]
    np.testing.assert_allclose(batched, loop, atol=1e-12)


def test_pca_heading_rejects_bad_arguments():
    pts, mask = np.zeros((4, 3)), np.ones(4, bool)
    with pytest.raises(ValueError, match="centre"):
        depth.pca_heading(pts, mask, np.zeros(3), 0.3, 0.0, 0.3)
    with pytest.raises(ValueError, match="on_jump"):
        depth.pca_heading(pts, mask, np.zeros(2), 0.3, 0.0, 0.3, on_jump="drop")
    with pytest.raises(ValueError, match="gain"):
        depth.pca_heading(pts, mask, np.zeros(2), 0.3, 0.0, 0.3, gain=1.5)
    with pytest.raises(ValueError, match="prev_heading"):
        depth.pca_heading(pts, mask, np.zeros(2), 0.3, np.nan, 0.3)


def test_ceiling_cloud_keeps_the_highest_points_above_the_floor():
    rng = np.random.default_rng(0)
    cam = depth.CeilingCamera((0.3, -0.2, 2.5), 40.0, 42.0, 16.0, 12.5)
    img = rng.uniform(2.2, 2.6, (24, 32)).astype(np.float32)
    valid = rng.uniform(size=img.shape) > 0.1
    pts, mask = jax.jit(lambda d, m: depth.ceiling_cloud(cam, d, m, 20))(img, valid)
    # Reference: numpy back-projection of every pixel, floor removed, sorted by height.
    i, j = np.mgrid[0:24, 0:32]
    ref = np.stack([0.3 + img * (j + 0.5 - 16.0) / 40.0, -0.2 - img * (i + 0.5 - 12.5) / 42.0,
                    2.5 - img], -1).reshape(-1, 3)
    ok = valid.reshape(-1) & (ref[:, 2] > 0.06)
    best = ref[ok][np.argsort(-ref[ok][:, 2], kind="stable")[:20]]
    assert bool(np.all(mask))
    np.testing.assert_allclose(np.asarray(pts), best, atol=1e-5)
    none, none_mask = depth.ceiling_cloud(cam, img, np.zeros_like(valid), 8)
    assert none.shape == (8, 3) and not bool(none_mask.any())


def test_ceiling_cloud_drops_points_above_max_height():
    cam = depth.CeilingCamera((0.0, 0.0, 3.0), 30.0, 30.0, 8.0, 6.0)
    img = np.full((12, 16), 3.0, np.float32)        # the floor
    img[2:4, 2:4] = 1.3                              # a person's shoulders (1.7 m)
    img[8:10, 10:12] = 2.5                           # a robot's head (0.5 m)
    pts, mask = depth.ceiling_cloud(cam, img, np.ones_like(img, bool), 6, max_height=1.0)
    kept = np.asarray(pts)[np.asarray(mask)]
    assert len(kept) == 4 and np.allclose(kept[:, 2], 0.5, atol=1e-6)
    pts, mask = depth.ceiling_cloud(cam, img, np.ones_like(img, bool), 6)
    assert np.allclose(np.asarray(pts)[:4, 2], 1.7, atol=1e-6) and int(mask.sum()) == 6
