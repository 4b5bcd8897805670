"""Humanoid trackers (`jaxtrack.tracking.humanoid`) on synthetic ceiling-camera clouds of a
standing robot (`tests.perception.references.robot_cloud`): each recovers the pose from a
perturbed start, in float32 and float64."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.tracking import estimator, humanoid
from tests.perception import references as ref

TRUTH = np.array([-0.4, 0.9, 2.8])


def _clouds(dtype, n=10, seed=4):
    rng = np.random.default_rng(seed)
    frames = [ref.robot_cloud(rng, TRUTH) for _ in range(n)]
    pts = np.stack([f[0] for f in frames])
    masks = np.stack([f[1] for f in frames])
    return humanoid.DepthScan(jnp.asarray(pts, dtype), jnp.asarray(masks),
                              jnp.zeros(n, dtype))


TRACKERS = {
    "pf": humanoid.DepthPFConfig(num_particles=300, init_spread=0.05),
    "pf3": humanoid.DepthPF3Config(num_particles=300, init_spread=0.05),
    "ukf": humanoid.CentroidUKFConfig(init_spread=0.05),
}


@pytest.mark.parametrize("name,dtype", [("pf", jnp.float32), ("pf", jnp.float64),
                                        ("pf3", jnp.float32), ("ukf", jnp.float64)])
def test_tracker_recovers_position_and_heading(name, dtype):
    est = humanoid.build(TRACKERS[name], dt=0.25)
    assert est.name == name
    params = est.params(position_noise=0.02, dtype=dtype)
    start = jnp.asarray(np.r_[TRUTH[:2] + [0.05, -0.04], TRUTH[2] + 0.25], dtype)
    state = est.init(jax.random.PRNGKey(1), params, start)
    _, poses = jax.jit(lambda s, z, p: estimator.run(est, jax.random.PRNGKey(2), s, z, p))(
        state, _clouds(dtype), params)
    assert poses.dtype == dtype
    final = np.asarray(poses[-1], np.float64)
    assert np.linalg.norm(final[:2] - TRUTH[:2]) < 0.02
    # The heading: pf and ukf by PCA, within 3 deg; pf3 from the counts alone, whose grip on
    # the heading is weak: it only has to move toward the truth from the 14 deg start.
    err = abs(ref.wrap(final[2] - TRUTH[2]))
    assert err < (math.radians(3.0) if name != "pf3" else 0.9 * 0.25)


def test_temperature_is_a_traced_leaf_that_sharpens_the_weights():
    est = humanoid.depth_pf(TRACKERS["pf"])
    seed = est.params(position_noise=0.02)
    sharp = est.params(position_noise=0.02, temperature=0.5)
    assert seed.log_temperature is None and sharp.log_temperature.shape == ()
    z = jax.tree_util.tree_map(lambda x: x[0], _clouds(jnp.float64))
    start = jnp.asarray(TRUTH, jnp.float64)
    s0 = est.init(jax.random.PRNGKey(1), seed, start)
    update = jax.jit(est.update)
    spread = {}
    for name, params in (("seed", seed), ("sharp", sharp)):
        s, _ = update(jax.random.PRNGKey(2), s0, z, params)
        w = np.exp(np.asarray(s.particles.log_weights))
        spread[name] = 1.0 / np.sum(w ** 2)          # effective sample size
    assert spread["sharp"] < 0.5 * spread["seed"]


def test_smooth_variant_has_finite_gradients_in_the_propagation_noise():
    est = humanoid.depth_pf(TRACKERS["pf"], smooth=humanoid.SmoothConfig())
    z = _clouds(jnp.float64, n=3)
    start = jnp.asarray(np.r_[TRUTH[:2] + 0.03, TRUTH[2]], jnp.float64)

    def loss(log_sigma):
        params = humanoid.DepthTrackerParams(log_sigma)
        s = est.init(jax.random.PRNGKey(1), params, start)
        _, poses = estimator.run(est, jax.random.PRNGKey(2), s, z, params)
        return jnp.sum((poses[-1, :2] - TRUTH[:2]) ** 2)

    g = jax.jit(jax.grad(loss))(jnp.log(0.02))
    assert np.isfinite(float(g)) and float(g) != 0.0


def test_bad_configuration_and_values_are_refused():
    with pytest.raises(ValueError, match="tracker"):
        humanoid.build("pf4")
    with pytest.raises(TypeError, match="humanoid tracker configuration"):
        humanoid.build(humanoid.HeadingConfig())
    with pytest.raises(ValueError, match="smooth resampling"):
        humanoid.SmoothConfig(resampling="soft")
    with pytest.raises(ValueError, match="gain"):
        humanoid.HeadingConfig(gain=1.5)
    with pytest.raises(ValueError, match="position_noise"):
        humanoid.depth_pf().params(position_noise=-1.0)
    with pytest.raises(ValueError, match="temperature"):
        humanoid.depth_pf().params(temperature=float("nan"))
