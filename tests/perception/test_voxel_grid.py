"""The voxel grid against Open3D's ``voxel_down_sample`` and a numpy reference."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.perception.voxel_grid import (GridSpec, cell_lookup, grid_neighbours, open3d_lower, select,
                                            voxelise)
from tests.perception import _clouds
from tests.perception._open3d import cloud, open3d

SIZE = 0.06


def _scene(seed=0):
    rng = np.random.default_rng(seed)
    return np.concatenate([_clouds.floor(rng), _clouds.person(rng, (2.0, 0.0)),
                           _clouds.person(rng, (3.0, 1.0))])


def _numpy_voxels(points, lower, size):
    """Centroids in the order of their cells; the cells computed in the points' own dtype."""
    keys = np.floor((points - np.asarray(lower, points.dtype)) / points.dtype.type(size))
    uniq, inverse = np.unique(keys.astype(np.int64), axis=0, return_inverse=True)
    sums = np.zeros((len(uniq), 3))
    np.add.at(sums, inverse.ravel(), points.astype(np.float64))
    return sums / np.bincount(inverse.ravel())[:, None]


def _sorted_rows(a):
    a = np.asarray(a)
    return a[np.lexsort(a.T[::-1])]


def test_centroids_equal_open3d_voxel_down_sample():
    pts = _scene()
    lower = open3d_lower(pts, SIZE)
    spec = GridSpec(SIZE, lower, (90, 90, 40))
    grid = voxelise(spec, jnp.asarray(pts, jnp.float64 if jax.config.x64_enabled else jnp.float32),
                    capacity=8192)
    mine = np.asarray(grid.points)[np.asarray(grid.mask)]
    ref = np.asarray(cloud(pts).voxel_down_sample(SIZE).points)
    assert int(grid.num_dropped) == 0
    assert mine.shape == ref.shape
    np.testing.assert_allclose(_sorted_rows(mine), _sorted_rows(ref), atol=2e-5)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_centroids_colours_and_counts_equal_numpy(dtype):
    if dtype == jnp.float64 and not jax.config.x64_enabled:
        pytest.skip("float64 needs JAX_ENABLE_X64")
    rng = np.random.default_rng(3)
    pts = _scene(3)
    rgb = rng.uniform(size=pts.shape)
    lower = (0.0, -2.5, -0.2)
    pts = pts.astype(np.dtype(dtype))
    grid = voxelise(GridSpec(SIZE, lower, (90, 90, 40)), jnp.asarray(pts, dtype), None,
                    jnp.asarray(rgb, dtype), capacity=8192)
    m = np.asarray(grid.mask)
    assert grid.points.dtype == dtype
    # Rows come in the order of their cells, as np.unique sorts them.
    np.testing.assert_allclose(np.asarray(grid.points)[m], _numpy_voxels(pts, lower, SIZE),
                               atol=1e-5)
    # Every point's voxel holds it, and the counts add up.
    pv = np.asarray(grid.point_voxel)
    cells = np.floor((pts - np.asarray(lower, pts.dtype)) / pts.dtype.type(SIZE)).astype(int)
    np.testing.assert_array_equal(np.asarray(grid.cells)[pv], cells)
    assert np.asarray(grid.counts)[m].sum() == len(pts)
    mean_rgb = np.zeros((m.sum(), 3))
    np.add.at(mean_rgb, pv, rgb)
    np.testing.assert_allclose(np.asarray(grid.colours)[m], mean_rgb / np.bincount(pv)[:, None],
                               atol=1e-5)


def test_points_outside_masked_or_nan_are_dropped_and_counted():
    pts = np.array([[0.01, 0.01, 0.01], [0.02, 0.02, 0.02], [5.0, 0.0, 0.0], [np.nan, 0, 0],
                    [0.2, 0.2, 0.2], [1e12, 0, 0]])
    mask = np.array([True, True, True, True, False, True])
    grid = voxelise(GridSpec(0.1, (0.0, 0.0, 0.0), (10, 10, 10)), jnp.asarray(pts), mask,
                    capacity=4)
    assert int(grid.mask.sum()) == 1
    np.testing.assert_allclose(grid.points[0], [0.015] * 3, atol=1e-6)
    np.testing.assert_array_equal(grid.point_voxel, [0, 0, -1, -1, -1, -1])
    assert int(grid.num_dropped) == 2          # outside the box (5 m and 1e12 m); NaN is invalid


def test_capacity_overflow_keeps_the_first_cells_and_counts_the_rest():
    pts = np.stack([np.arange(6) * 0.1 + 0.05, np.full(6, 0.05), np.full(6, 0.05)], -1)
    grid = voxelise(GridSpec(0.1, (0.0, 0.0, 0.0), (10, 1, 1)), jnp.asarray(pts), capacity=4)
    np.testing.assert_allclose(grid.points[:, 0], pts[:4, 0], atol=1e-6)
    assert int(grid.num_dropped) == 2
    np.testing.assert_array_equal(grid.point_voxel, [0, 1, 2, 3, -1, -1])


@pytest.mark.parametrize("shape", [(7, 5, 1), (6, 4, 24), (5, 6, 25), (4, 3, 50), (3, 3, 70)])
def test_voxel_rows_follow_the_cell_index_for_any_column_height(shape):
    """The rows are the occupied cells in cell-index order (`jnp.nonzero`'s), whatever the
    grid's last axis (packed in words of 24 cells), with and without capacity overflow."""
    rng = np.random.default_rng(sum(shape))
    spec = GridSpec(0.1, (0.0, 0.0, 0.0), shape)
    pts = rng.uniform(-0.05, 0.1 * np.asarray(shape) + 0.05, (400, 3)).astype(np.float32)
    ijk = np.floor(pts / np.float32(0.1)).astype(np.int64)
    inside = np.all((ijk >= 0) & (ijk < shape), 1)
    linear = np.ravel_multi_index(tuple(ijk[inside].T), shape)
    occupied = np.unique(linear)
    for capacity in (len(occupied) + 3, max(len(occupied) // 2, 1)):
        grid = voxelise(spec, jnp.asarray(pts), capacity=capacity)
        rows = np.asarray(grid.cells)[np.asarray(grid.mask)]
        np.testing.assert_array_equal(np.ravel_multi_index(tuple(rows.T), shape),
                                      occupied[:capacity])
        want = np.full(len(pts), -1)
        row_of = {c: i for i, c in enumerate(occupied[:capacity])}
        want[inside] = [row_of.get(c, -1) for c in linear]
        np.testing.assert_array_equal(np.asarray(grid.point_voxel), want)
        lookup = np.asarray(cell_lookup(spec, grid))
        assert np.sum(lookup >= 0) == min(capacity, len(occupied))
        np.testing.assert_array_equal(lookup[occupied[:capacity]], np.arange(len(rows)))


def test_empty_cloud_is_a_valid_input():
    grid = voxelise(GridSpec(), jnp.zeros((0, 3)), capacity=8)
    assert not bool(grid.mask.any()) and int(grid.num_dropped) == 0
    assert grid.point_voxel.shape == (0,)
    lookup = cell_lookup(GridSpec(), grid)
    assert lookup.shape == (GridSpec().num_cells,) and bool(jnp.all(lookup == -1))


def test_neighbours_are_exactly_the_centroids_within_the_radius():
    pts = _scene(5)[::7]
    spec = GridSpec(SIZE, (0.0, -2.5, -0.2), (90, 90, 40))
    grid = voxelise(spec, jnp.asarray(pts), capacity=4096)
    for radius in (0.06, 0.12):
        nb = np.asarray(jax.jit(lambda g, r=radius: grid_neighbours(spec, g, r))(grid))
        c = np.asarray(grid.points)
        m = np.asarray(grid.mask)
        d = np.linalg.norm(c[:, None] - c[None], axis=-1)
        brute = (d <= radius) & m[:, None] & m[None] & ~np.eye(len(c), dtype=bool)
        mine = np.zeros_like(brute)
        rows = np.repeat(np.arange(len(c)), nb.shape[1])
        ok = nb.ravel() >= 0
        mine[rows[ok], nb.ravel()[ok]] = True
        np.testing.assert_array_equal(mine, brute)


def test_select_renumbers_lookup_and_points():
    pts = _scene(6)
    spec = GridSpec(SIZE, (0.0, -2.5, -0.2), (90, 90, 40))
    grid = voxelise(spec, jnp.asarray(pts), capacity=8192)
    keep = np.asarray(grid.points)[:, 2] > 0.1
    sub = select(grid, jnp.asarray(keep), 4096)
    m = np.asarray(grid.mask) & keep
    np.testing.assert_allclose(np.asarray(sub.points)[np.asarray(sub.mask)],
                               np.asarray(grid.points)[m])
    pv = np.asarray(sub.point_voxel)
    assert (pv >= 0).sum() == np.asarray(grid.counts)[m].sum()
    np.testing.assert_allclose(np.asarray(sub.points)[pv[pv >= 0]][:, 2] > 0.1, True)
    lk = np.asarray(cell_lookup(spec, sub))
    assert (lk >= 0).sum() == m.sum()
    kept_cells = np.ravel_multi_index(tuple(np.asarray(grid.cells)[m].T), spec.shape)
    np.testing.assert_array_equal(lk[kept_cells], np.arange(m.sum()))
    # Neighbours of the selection equal the full grid's neighbours restricted to it.
    full = np.asarray(grid_neighbours(spec, grid, 0.12, keep=jnp.asarray(keep)))
    part = np.asarray(grid_neighbours(spec, sub, 0.12))
    old = np.flatnonzero(m)
    assert sorted(map(tuple, np.sort(np.where(part[:m.sum()] >= 0, old[part[:m.sum()]], -1),
                                     1).tolist())) \
        == sorted(map(tuple, np.sort(full[old], 1).tolist()))


def test_jit_and_vmap_over_frames_match_one_by_one():
    spec = GridSpec(0.1, (0.0, 0.0, 0.0), (20, 20, 20))
    pts = jax.random.uniform(jax.random.key(0), (3, 200, 3), minval=0.0, maxval=2.0)
    batched = jax.jit(jax.vmap(lambda p: voxelise(spec, p, capacity=512)))(pts)
    for i in range(3):
        one = voxelise(spec, pts[i], capacity=512)
        np.testing.assert_allclose(batched.points[i], one.points, atol=1e-6)


@pytest.mark.parametrize("bad, match", [
    (dict(points=np.zeros((4, 2))), "points"),
    (dict(mask=np.ones(3, bool)), "mask"),
    (dict(capacity=0), "capacity"),
    (dict(points=np.zeros((4, 3), np.int32)), "floating"),
])
def test_bad_input_is_refused(bad, match):
    args = dict(points=np.zeros((4, 3)), mask=None, capacity=8) | bad
    with pytest.raises((ValueError, TypeError), match=match):
        voxelise(GridSpec(), args["points"], args["mask"], capacity=args["capacity"])


@pytest.mark.parametrize("kw", [dict(size=0.0), dict(size=float("nan")), dict(shape=(0, 1, 1)),
                                dict(lower=(0.0, 0.0))])
def test_bad_grid_spec_is_refused(kw):
    with pytest.raises(ValueError, match="GridSpec"):
        GridSpec(**kw)


def test_open3d_loads():
    assert hasattr(open3d(), "geometry")
