"""Colour histograms, kernel-weighted region histograms, the Bhattacharyya coefficient and the
back-projection of `jaxtrack.perception.colour_histogram`.

References: ``np.histogramdd`` on the same pixels (hard binning), ``colorsys`` for the HSV
conversion, closed forms for the soft bins and the Bhattacharyya coefficient, finite
differences for the gradients. float64 matches to 1e-12, float32 to 1e-6 (relative to 1).
"""

import colorsys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.perception import colour_histogram as ch

RGB = ch.HistogramConfig("rgb", (8, 8, 8), "hard")
HSV = ch.HistogramConfig("hsv", (8, 8, 4), "hard")
TOL = {np.float64: 1e-12, np.float32: 1e-6}

# Jitted once per module.
histogram = jax.jit(ch.histogram, static_argnames=("config",))
kernel = jax.jit(ch.kernel_histograms, static_argnames=("config",))
bins = jax.jit(ch.bin_weights, static_argnames=("config",))


@pytest.fixture(scope="module")
def pixels():
    """300 random pixels, 40 of them masked out (10 of those NaN), random weights."""
    rng = np.random.default_rng(0)
    rgb = rng.uniform(0, 1, (300, 3))
    rgb[:5] = [[1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [0.5, 0.5, 0.5], [1.0, 0.0, 0.0],
               [0.0, 1.0, 1.0]]                        # edges of the cube, greys
    mask = np.ones(300, bool)
    mask[rng.choice(np.arange(5, 300), 40, replace=False)] = False
    rgb[np.nonzero(~mask)[0][:10]] = np.nan
    weights = rng.uniform(0.1, 2.0, 300)
    xy = rng.uniform(-0.5, 0.5, (300, 2))
    return rgb, mask, weights, xy


def _reference(feats, weights, nbins):
    h, _ = np.histogramdd(feats, bins=nbins, range=[(0, 1)] * 3, weights=weights)
    return h.ravel() / h.sum()


def _hsv(rgb):
    return np.array([colorsys.rgb_to_hsv(*c) for c in rgb])


def test_to_hsv_matches_colorsys(pixels):
    rgb = np.nan_to_num(pixels[0])
    np.testing.assert_allclose(np.asarray(jax.jit(ch.to_hsv)(rgb)), _hsv(rgb), atol=1e-12)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("config", [RGB, HSV], ids=["rgb", "hsv"])
def test_hard_histogram_matches_numpy_histogramdd(pixels, dtype, config):
    rgb, mask, weights, _ = pixels
    got = histogram(jnp.asarray(rgb, dtype), mask, jnp.asarray(weights, dtype), config)
    assert got.dtype == dtype
    feats = rgb[mask] if config.space == "rgb" else _hsv(rgb[mask])
    want = _reference(feats, weights[mask], config.bins)
    np.testing.assert_allclose(np.asarray(got), want, atol=TOL[dtype])


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_kernel_histograms_match_numpy_with_epanechnikov_weights(pixels, dtype):
    rgb, mask, _, xy = pixels
    centres = np.array([[0.0, 0.0], [0.3, -0.2], [5.0, 5.0]])     # the last sees nothing
    radius = 0.35
    got = np.asarray(kernel(jnp.asarray(rgb, dtype), jnp.asarray(xy, dtype),
                            jnp.asarray(centres, dtype), radius, mask, RGB))
    for c, h in zip(centres, got):
        k = np.maximum(1 - np.sum((xy - c) ** 2, -1) / radius ** 2, 0)[mask]
        if k.sum() == 0:
            np.testing.assert_array_equal(h, 0.0)
        else:
            np.testing.assert_allclose(h, _reference(rgb[mask], k, RGB.bins), atol=TOL[dtype])


def test_soft_bins_closed_forms():
    soft = ch.HistogramConfig("rgb", (8, 8, 8), "soft")
    # Bin centres take everything; 0.25 (between centres 1 and 2) splits half and half; the
    # outer half-bins belong to the end bins.
    w = np.asarray(bins(jnp.array([[0.0625, 0.25, 1.0]]), soft)).reshape(8, 8, 8)
    want = np.zeros((8, 8, 8))
    want[0, 1, 7] = want[0, 2, 7] = 0.5
    np.testing.assert_allclose(w, want, atol=1e-12)
    # Hue wraps: 0.99 turn with 8 bins is s = 7.42, shared by bins 7 and 0.
    hsv = ch.HistogramConfig("hsv", (8, 2, 2), "soft")
    w = np.asarray(bins(jnp.array([[0.99, 0.0, 0.0]]), hsv)).reshape(8, 2, 2)
    np.testing.assert_allclose(w[[7, 0], 0, 0], [0.58, 0.42], atol=1e-12)
    assert np.isclose(w.sum(), 1.0)


def test_soft_histogram_is_hard_on_bin_centres_and_rows_sum_to_one(pixels):
    rng = np.random.default_rng(3)
    centres = (rng.integers(0, 8, (50, 3)) + 0.5) / 8
    soft = RGB._replace(binning="soft")
    np.testing.assert_allclose(np.asarray(histogram(centres, config=soft)),
                               np.asarray(histogram(centres, config=RGB)), atol=1e-12)
    w = np.asarray(bins(jnp.asarray(np.nan_to_num(pixels[0])), soft))
    np.testing.assert_allclose(w.sum(-1), 1.0, atol=1e-12)
    assert np.all(w >= 0)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_bhattacharyya_closed_forms(pixels, dtype):
    rgb, mask, weights, _ = pixels
    p = histogram(jnp.asarray(rgb, dtype), mask, jnp.asarray(weights, dtype), RGB)
    assert abs(float(ch.bhattacharyya(p, p)) - 1.0) < 10 * TOL[dtype]
    q = np.zeros(512, dtype)
    q[np.asarray(p) == 0] = 1.0
    q /= q.sum()
    assert float(ch.bhattacharyya(p, q)) == 0.0                 # disjoint supports
    assert float(ch.bhattacharyya(jnp.zeros(512, dtype), p)) == 0.0   # empty region
    rng = np.random.default_rng(1)
    r = rng.dirichlet(np.ones(512)).astype(dtype)
    np.testing.assert_allclose(float(ch.bhattacharyya(p, r)),
                               np.sum(np.sqrt(np.asarray(p, float) * r)), rtol=10 * TOL[dtype])
    ll = ch.log_likelihood(jnp.stack([p, jnp.asarray(q)]), p, 50.0)
    np.testing.assert_allclose(np.asarray(ll), [0.0, -50.0], atol=1e-9 + 500 * TOL[dtype])


def test_empty_regions_give_the_zero_histogram():
    rgb = np.full((4, 3), 0.5)
    assert np.all(np.asarray(histogram(rgb, np.zeros(4, bool), config=RGB)) == 0.0)
    assert np.all(np.asarray(histogram(rgb, weights=np.zeros(4), config=RGB)) == 0.0)
    h = kernel(rgb, np.zeros((4, 2)), np.array([[1.0, 1.0]]), 0.2, config=RGB)
    assert h.shape == (1, 512) and np.all(np.asarray(h) == 0.0)


def test_nan_pixels_are_masked_inside_jit():
    rgb = np.array([[0.1, 0.2, 0.3], [np.nan, 0.5, 0.5], [0.1, 0.2, 0.3]])
    h = kernel(rgb, np.zeros((3, 2)), np.zeros((1, 2)), 0.5, jnp.ones(3, bool), RGB)
    assert np.all(np.isfinite(np.asarray(h)))
    np.testing.assert_allclose(float(jnp.max(h)), 1.0)


def test_kernel_histogram_likelihood_is_differentiable_in_the_centre(pixels):
    rgb, mask, _, xy = pixels
    soft = RGB._replace(binning="soft")
    q = ch.kernel_histograms(rgb, xy, np.array([[0.05, 0.0]]), 0.3, mask, soft)[0]

    def rho(c):
        return ch.bhattacharyya(ch.kernel_histograms(rgb, xy, c[None], 0.3, mask, soft)[0], q)

    c = jnp.array([0.1, -0.05])
    g = np.asarray(jax.jit(jax.grad(rho))(c))
    eps = 1e-6
    fd = [(rho(c.at[i].add(eps)) - rho(c.at[i].add(-eps))) / (2 * eps) for i in range(2)]
    assert np.all(np.isfinite(g)) and np.any(g != 0)
    np.testing.assert_allclose(g, np.asarray(fd), rtol=1e-5, atol=1e-8)


def test_ratio_histogram_and_backprojection():
    model = np.array([0.5, 0.5, 0.0, 0.0])
    image = np.array([0.05, 0.6, 0.35, 0.0])
    np.testing.assert_allclose(np.asarray(ch.ratio_histogram(model, image)),
                               [1.0, 0.5 / 0.6, 0.0, 0.0])
    cfg = ch.HistogramConfig("rgb", (4, 1, 1), "hard")
    ratio = np.array([1.0, 0.25, 0.0, 0.0])
    rgb = np.array([[0.1, 0.5, 0.5], [0.3, 0.5, 0.5], [0.9, 0.5, 0.5]])
    np.testing.assert_allclose(np.asarray(ch.backprojection(rgb, ratio, cfg)), [1.0, 0.25, 0.0])


@pytest.mark.parametrize("call, match", [
    (lambda: ch.histogram(np.zeros((4, 2))), "rgb must have shape"),
    (lambda: ch.histogram(np.zeros((4, 3)), np.ones(3, bool)), "mask must have shape"),
    (lambda: ch.histogram(np.full((2, 3), np.nan)), "NaN"),
    (lambda: ch.histogram(np.zeros((2, 3)), weights=-np.ones(2)), "weights must be >= 0"),
    (lambda: ch.histogram(np.zeros((2, 3)), config=ch.HistogramConfig("lab")), "unknown space"),
    (lambda: ch.histogram(np.zeros((2, 3)), config=ch.HistogramConfig(binning="kde")),
     "unknown binning"),
    (lambda: ch.histogram(np.zeros((2, 3)), config=ch.HistogramConfig(bins=(8, 0, 8))),
     "bins must be three positive ints"),
    (lambda: ch.features(np.zeros((2, 3)), "xyz"), "unknown space"),
    (lambda: ch.kernel_histograms(np.zeros((3, 3)), np.zeros((3, 2)), np.zeros((1, 2)), 0.0),
     "radius must be > 0"),
    (lambda: ch.kernel_histograms(np.zeros((3, 3)), np.zeros((2, 2)), np.zeros((1, 2)), 0.1),
     "pixel_xy must have shape"),
    (lambda: ch.kernel_histograms(np.zeros((3, 3)), np.zeros((3, 2)), np.full((1, 2), np.nan),
                                  0.1), "centres contains NaN"),
    (lambda: ch.log_likelihood(np.ones(4) / 4, np.ones(4) / 4, -1.0), "lam must be > 0"),
    (lambda: ch.bhattacharyya(np.full(4, np.nan), np.ones(4)), "p contains NaN"),
    (lambda: ch.ratio_histogram(np.ones(4), np.ones(3)), "image must have shape"),
    (lambda: ch.bin_weights(np.zeros((2, 3)), "rgb"), "HistogramConfig"),
])
def test_bad_input_raises_a_clear_error(call, match):
    with pytest.raises((ValueError, TypeError), match=match):
        call()


def test_masked_nan_pixels_are_accepted_at_the_boundary():
    rgb = np.array([[0.1, 0.2, 0.3], [np.nan, np.nan, np.nan]])
    h = ch.histogram(rgb, np.array([True, False]), config=RGB)
    assert np.isclose(float(jnp.sum(h)), 1.0)
