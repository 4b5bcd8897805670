"""Euclidean clustering against Open3D's DBSCAN (one point per core) and scipy's connected
components."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components as scipy_components

from jaxtrack.perception.euclidean_clustering import connected_components, euclidean_clusters
from jaxtrack.perception.voxel_grid import GridSpec, grid_neighbours, voxelise
from tests.perception import _clouds
from tests.perception._open3d import cloud


def _same_partition(a, b):
    """Two labellings describe the same partition (a bijection between their labels)."""
    a, b = np.asarray(a), np.asarray(b)
    pairs = set(zip(a.tolist(), b.tolist()))
    return len(pairs) == len(set(a.tolist())) == len(set(b.tolist()))


def _people_without_floor(seed):
    rng = np.random.default_rng(seed)
    pts = np.concatenate([_clouds.person(rng, (2.0, 0.0)), _clouds.person(rng, (2.0, 0.45)),
                          _clouds.person(rng, (3.2, -1.0)), _clouds.wall(rng, 600)])
    return pts[pts[:, 2] > 0.05]


@pytest.mark.parametrize("seed", [0, 1])
def test_clusters_equal_open3d_dbscan_with_one_point_cores(seed):
    pts = _people_without_floor(seed)
    spec = GridSpec(0.06, (0.0, -2.5, 0.0), (90, 90, 40))
    grid = voxelise(spec, jnp.asarray(pts), capacity=4096)
    nbrs = grid_neighbours(spec, grid, 0.12)
    clusters = euclidean_clusters(nbrs, grid.mask, capacity=256, symmetric=True)
    m = np.asarray(grid.mask)
    centroids = np.asarray(grid.points)[m]
    ref = np.asarray(cloud(centroids).cluster_dbscan(eps=0.12, min_points=1))
    mine = np.asarray(clusters.labels)[m]
    assert (mine >= 0).all() and int(clusters.num_dropped) == 0
    assert _same_partition(mine, ref)
    assert len(set(ref.tolist())) >= 3


def test_components_equal_scipy_on_random_asymmetric_graphs():
    rng = np.random.default_rng(2)
    for _ in range(5):
        v, k = 60, 3
        nbrs = rng.integers(-1, v, size=(v, k))
        nbrs[rng.uniform(size=(v, k)) < 0.5] = -1
        mask = rng.uniform(size=v) < 0.9
        labels = np.asarray(connected_components(jnp.asarray(nbrs, jnp.int32), jnp.asarray(mask)))
        rows, cols = np.nonzero(nbrs >= 0)
        ok = mask[rows] & mask[nbrs[rows, cols]]
        graph = coo_matrix((np.ones(ok.sum()), (rows[ok], nbrs[rows, cols][ok])), shape=(v, v))
        _, ref = scipy_components(graph, directed=True, connection="weak")
        assert _same_partition(labels[mask], ref[mask])
        assert (labels[~mask] == v).all()
        # Each label is the smallest index of its component.
        for lab in set(labels[mask].tolist()):
            assert lab == np.flatnonzero(labels == lab).min()


def test_components_equal_scipy_on_random_symmetric_graphs_with_long_paths():
    # shuffled chains and trees: every component's smallest index sits far along its paths,
    # where the hooking and jumping shortcuts (not the neighbour pulls alone) must carry it
    rng = np.random.default_rng(5)
    for _ in range(4):
        v, k = 300, 4
        perm = rng.permutation(v)
        parent = np.array([-1] + [int(rng.integers(max(0, i - 3), i)) for i in range(1, v)])
        parent[rng.uniform(size=v) < 0.05] = -1                     # cut into a forest
        edges = [(perm[i], perm[parent[i]]) for i in range(v) if parent[i] >= 0]
        nbrs = -np.ones((v, k), np.int64)
        fill = np.zeros(v, int)
        for a, b in edges:
            if fill[a] < k and fill[b] < k:
                nbrs[a, fill[a]], nbrs[b, fill[b]] = b, a
                fill[a] += 1
                fill[b] += 1
        mask = rng.uniform(size=v) < 0.95
        labels = np.asarray(connected_components(jnp.asarray(nbrs, jnp.int32), jnp.asarray(mask),
                                                 symmetric=True))
        rows, cols = np.nonzero(nbrs >= 0)
        ok = mask[rows] & mask[nbrs[rows, cols]]
        graph = coo_matrix((np.ones(ok.sum()), (rows[ok], nbrs[rows, cols][ok])), shape=(v, v))
        _, ref = scipy_components(graph, directed=False)
        assert _same_partition(labels[mask], ref[mask])
        assert (labels[~mask] == v).all()
        for lab in set(labels[mask].tolist()):
            assert lab == np.flatnonzero(labels == lab).min()


def test_a_long_chain_is_one_cluster():
    v = 200
    nbrs = np.stack([np.arange(v) - 1, np.arange(v) + 1], -1)
    nbrs[nbrs >= v] = -1
    labels = connected_components(jnp.asarray(nbrs, jnp.int32), jnp.ones(v, bool), symmetric=True)
    assert (np.asarray(labels) == 0).all()


def test_clusters_are_ranked_by_size_with_min_size_and_capacity():
    # Components {0..4}, {5..7}, {8, 9}, {10}: sizes 5, 3, 2, 1.
    edges = [(i, i + 1) for i in range(4)] + [(5, 6), (6, 7), (8, 9)]
    nbrs = -np.ones((11, 2), np.int32)
    for i, j in edges:
        nbrs[i, 1] = j
        nbrs[j, 0] = i
    c = euclidean_clusters(jnp.asarray(nbrs), jnp.ones(11, bool), min_size=2, capacity=2,
                           symmetric=True)
    np.testing.assert_array_equal(c.sizes, [5, 3])
    np.testing.assert_array_equal(c.labels, [0] * 5 + [1] * 3 + [-1] * 3)
    assert int(c.num_dropped) == 1                      # {8, 9} is big enough but has no room


def test_empty_and_fully_masked_inputs():
    c = euclidean_clusters(jnp.zeros((0, 4), jnp.int32), jnp.zeros(0, bool), capacity=3)
    assert c.labels.shape == (0,) and not bool(c.mask.any())
    c = euclidean_clusters(jnp.zeros((5, 2), jnp.int32), jnp.zeros(5, bool), capacity=3)
    assert (np.asarray(c.labels) == -1).all()


def test_vmap_over_frames():
    nbrs = jnp.asarray([[[1], [0], [-1]], [[-1], [2], [1]]], jnp.int32)
    labels = jax.vmap(lambda n: connected_components(n, jnp.ones(3, bool)))(nbrs)
    np.testing.assert_array_equal(labels, [[0, 0, 2], [0, 1, 1]])


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="mask"):
        connected_components(jnp.zeros((3, 2), jnp.int32), jnp.ones(4, bool))
    with pytest.raises(ValueError, match="capacity"):
        euclidean_clusters(jnp.zeros((3, 2), jnp.int32), jnp.ones(3, bool), capacity=0)
    with pytest.raises(ValueError, match="min_size"):
        euclidean_clusters(jnp.zeros((3, 2), jnp.int32), jnp.ones(3, bool), capacity=2,
                           min_size=0)
