"""HOG against scikit-image, the crop against scipy, and the person box by projection."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.perception.hog import (HOGConfig, LinearSVM, PinholeCamera, crop, descriptors,
                                     hog, num_features, person_box, project, svm_confidence)

skimage_feature = pytest.importorskip("skimage.feature")
_hog = jax.jit(hog)


@pytest.mark.parametrize("channels", [None, 3])
def test_descriptor_equals_scikit_image(channels):
    rng = np.random.default_rng(0)
    shape = (128, 64) if channels is None else (128, 64, channels)
    img = rng.uniform(size=shape)
    img[40:100, 20:44] += 0.8                       # a bright body on noise
    ref = skimage_feature.hog(img, orientations=9, pixels_per_cell=(8, 8),
                              cells_per_block=(2, 2), block_norm="L2-Hys",
                              channel_axis=None if channels is None else -1)
    mine = np.asarray(_hog(jnp.asarray(img)))
    assert mine.shape == ref.shape == (num_features(),) == (3780,)
    np.testing.assert_allclose(mine, ref, atol=1e-6)


def test_few_grey_levels_equal_scikit_image():
    # four levels per channel: many gradients exactly along the axes or at 45 deg, flat pixels,
    # and equal magnitudes in several channels (the first channel wins, as skimage's argmax)
    rng = np.random.default_rng(3)
    img = rng.integers(0, 4, size=(128, 64, 3)) / 3.0
    img[:, 30:] = img[:, 30:, :1]                     # grey on the right: three-way ties
    ref = skimage_feature.hog(img, orientations=9, pixels_per_cell=(8, 8),
                              cells_per_block=(2, 2), block_norm="L2-Hys", channel_axis=-1)
    np.testing.assert_allclose(np.asarray(_hog(jnp.asarray(img))), ref, atol=1e-6)


def test_other_geometry_equals_scikit_image():
    cfg = HOGConfig(window=(48, 32), cell=6, block=3, orientations=12)
    img = np.random.default_rng(1).uniform(size=(48, 32))
    ref = skimage_feature.hog(img, orientations=12, pixels_per_cell=(6, 6),
                              cells_per_block=(3, 3), block_norm="L2-Hys")
    np.testing.assert_allclose(np.asarray(hog(jnp.asarray(img), cfg)), ref, atol=1e-6)
    assert ref.shape == (num_features(cfg),)


def test_float32_matches_float64():
    img = np.random.default_rng(2).uniform(size=(128, 64, 3))
    f64 = np.asarray(_hog(jnp.asarray(img)))
    f32 = np.asarray(_hog(jnp.asarray(img, jnp.float32)))
    assert f32.dtype == np.float32
    # A few pixels may change bin at a boundary in float32; the descriptor barely moves.
    assert np.abs(f32 - f64).max() < 0.05 and np.abs(f32 - f64).mean() < 1e-4


def test_crop_equals_scipy_bilinear_resampling():
    from scipy.ndimage import map_coordinates
    rng = np.random.default_rng(3)
    img = rng.uniform(size=(60, 80, 3))
    box = np.array([5.3, 10.7, 45.1, 30.2])
    cfg = HOGConfig(window=(16, 8))
    mine = np.asarray(crop(jnp.asarray(img), jnp.asarray(box), cfg))
    r = box[0] + (np.arange(16) + 0.5) * (box[2] - box[0]) / 16 - 0.5
    c = box[1] + (np.arange(8) + 0.5) * (box[3] - box[1]) / 8 - 0.5
    rr, cc = np.meshgrid(r, c, indexing="ij")
    ref = np.stack([map_coordinates(img[..., k], [rr, cc], order=1) for k in range(3)], -1)
    np.testing.assert_allclose(mine, ref, atol=1e-12)


def test_crop_outside_the_image_takes_the_edge():
    img = jnp.arange(12.0).reshape(3, 4, 1)
    out = crop(img, jnp.asarray([-10.0, -10.0, -5.0, -5.0]), HOGConfig(window=(2, 2)))
    np.testing.assert_allclose(out, 0.0)


def _camera():
    # Optical axis along world +x, camera 1.1 m up: x right = -y world, y down = -z world.
    rot = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    return PinholeCamera(jnp.asarray([100.0, 100.0]), jnp.asarray([80.0, 60.0]),
                         jnp.asarray([0.0, 0.0, 1.1]), jnp.asarray(rot))


def test_projection_and_person_box():
    cam = _camera()
    uv, z = project(cam, jnp.asarray([[2.0, 0.0, 1.1], [2.0, -0.5, 0.1]]))
    np.testing.assert_allclose(uv, [[80.0, 60.0], [105.0, 110.0]])
    np.testing.assert_allclose(z, [2.0, 2.0])
    box = np.asarray(person_box(cam, jnp.asarray([2.0, 0.0, 1.7]), jnp.asarray([2.0, 0.0, 0.0])))
    top, bottom = 60 - 0.6 * 50, 60 + 1.1 * 50                 # head 30 px up, feet 55 px down
    h = bottom - top
    np.testing.assert_allclose(box, [top - h / 12, 80 - (h * 7 / 6) / 4, bottom + h / 12,
                                     80 + (h * 7 / 6) / 4])


def test_svm_confidence_is_the_sigmoid_of_the_margin():
    svm = LinearSVM(jnp.asarray([1.0, -2.0]), jnp.asarray(0.5))
    np.testing.assert_allclose(svm_confidence(svm, jnp.asarray([[1.0, 1.0], [0.0, 0.0]])),
                               1 / (1 + np.exp(-np.array([-0.5, 0.5]))))


def test_vmap_over_detections():
    imgs = jax.random.uniform(jax.random.key(0), (3, 128, 64, 3))
    batched = jax.vmap(hog)(imgs)
    np.testing.assert_allclose(batched[1], hog(imgs[1]), atol=1e-6)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_descriptors_are_the_hog_of_each_crop(dtype):
    # boxes inside, across the edges and degenerate (a masked detection's zeros)
    image = jax.random.uniform(jax.random.key(3), (60, 80, 3), dtype)
    boxes = jnp.asarray([[5.0, 10.0, 50.0, 32.5], [-8.0, 60.0, 70.0, 99.0], [0, 0, 0, 0]], dtype)
    got = jax.jit(descriptors)(image, boxes)
    assert got.shape == (3, num_features()) and got.dtype == dtype
    for b in range(3):
        want = jax.jit(hog)(jax.jit(crop)(image, boxes[b]))
        np.testing.assert_allclose(got[b], want, atol=1e-6 if dtype == jnp.float32 else 1e-12)
    assert descriptors(image, jnp.zeros((0, 4), dtype)).shape == (0, num_features())


def test_masked_descriptors_describe_only_the_masked_boxes():
    # 7 boxes (not a whole number of the loop's rounds), masks of 0, 3 and all boxes, also
    # batched over frames whose loops need different numbers of rounds
    image = jax.random.uniform(jax.random.key(4), (60, 80, 3))
    corner = jax.random.uniform(jax.random.key(5), (7, 2), minval=-5.0, maxval=40.0)
    size = jax.random.uniform(jax.random.key(6), (7, 1), minval=8.0, maxval=50.0)
    boxes = jnp.concatenate([corner, corner + size * jnp.asarray([2.0, 1.0])], -1)
    boxes = boxes[:, jnp.asarray([0, 1, 2, 3])]
    full = jax.jit(descriptors)(image, boxes)
    masks = jnp.asarray([[False] * 7, [True, False, False, True, False, True, False],
                         [True] * 7])
    masked = jax.jit(lambda m: descriptors(image, boxes, mask=m))
    for m in masks:
        np.testing.assert_allclose(masked(m), jnp.where(m[:, None], full, 0), atol=1e-6)
    batched = jax.jit(jax.vmap(lambda m: descriptors(image, boxes, mask=m)))(masks)
    np.testing.assert_allclose(batched, jnp.where(masks[..., None], full, 0), atol=1e-6)
    with pytest.raises(ValueError, match="mask"):
        descriptors(image, boxes, mask=jnp.ones(6, bool))
    # a masked-out NaN box is not described and leaves the others alone; no boxes, no rows
    nan_boxes = boxes.at[2].set(jnp.nan)
    np.testing.assert_allclose(masked(masks[1]), jax.jit(lambda m: descriptors(
        image, nan_boxes, mask=m))(masks[1]), atol=0)
    assert descriptors(image, jnp.zeros((0, 4)), mask=jnp.zeros(0, bool)).shape == (
        0, num_features())


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="image"):
        crop(jnp.zeros((4, 4)), jnp.zeros(4))
    with pytest.raises(ValueError, match="box"):
        crop(jnp.zeros((4, 4, 3)), jnp.zeros(3))
    with pytest.raises(ValueError, match="window"):
        hog(jnp.zeros((4, 4, 3, 1)))
    with pytest.raises(ValueError, match="boxes"):
        descriptors(jnp.zeros((4, 4, 3)), jnp.zeros((2, 3)))
    with pytest.raises(ValueError, match="image contains NaN"):
        descriptors(jnp.full((4, 4, 3), jnp.nan), jnp.zeros((2, 4)))
