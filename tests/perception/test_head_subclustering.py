"""Head sub-clustering (seed 001 III-B): people standing close are split, one person stays whole."""

import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.perception.euclidean_clustering import euclidean_clusters
from jaxtrack.perception.ground_plane import horizontal_plane
from jaxtrack.perception.head_subclustering import HeadConfig, subcluster_heads
from jaxtrack.perception.voxel_grid import GridSpec, grid_neighbours, voxelise
from tests.perception import _clouds

SPEC = GridSpec(0.06, (0.0, -2.5, -0.1), (90, 90, 40))
EYE = jnp.asarray([0.0, 0.0, 1.1])


def _detect(people, config=HeadConfig(), seed=0):
    rng = np.random.default_rng(seed)
    pts = np.concatenate([_clouds.person(rng, c, s) for c, s in people])
    grid = voxelise(SPEC, jnp.asarray(pts), capacity=4096)
    clusters = euclidean_clusters(grid_neighbours(SPEC, grid, 0.12), grid.mask, capacity=8,
                                  symmetric=True)
    dets = subcluster_heads(config, grid.points, grid.mask, clusters.labels,
                            horizontal_plane(0.0, dtype=jnp.float64), EYE, num_clusters=8)
    return grid, clusters, dets


def test_two_people_035_m_apart_are_split_and_a_lone_person_kept_whole():
    people = [((2.0, 0.0), 1.75), ((2.0, 0.35), 1.65), ((3.0, -1.2), 1.8)]
    grid, clusters, dets = _detect(people)
    assert int(clusters.mask.sum()) == 2                    # the pair is one Euclidean cluster
    m = np.asarray(dets.mask)
    assert m.sum() == 3
    pos = np.asarray(dets.position)[m][:, :2]
    for (c, stature) in people:
        d = np.linalg.norm(pos - np.asarray(c), axis=1)
        assert d.min() < 0.1
        k = d.argmin()
        assert abs(np.asarray(dets.height)[m][k] - stature) < 0.04
    # The lone person's sub-cluster is its whole cluster.
    lone = np.argmin(np.linalg.norm(pos - [3.0, -1.2], axis=1))
    lone_cluster = np.asarray(dets.cluster)[m][lone]
    assert np.asarray(dets.num_points)[m][lone] == np.asarray(clusters.sizes)[lone_cluster]
    # Each point of the pair belongs to the person whose head is nearer on the floor.
    pd = np.asarray(dets.point_detection)
    pts = np.asarray(grid.points)
    pair = np.asarray(clusters.labels) == np.asarray(dets.cluster)[m][np.argmin(
        np.linalg.norm(pos - [2.0, 0.0], axis=1))]
    heads = np.asarray(dets.head)[:, :2]
    joined = pair & (pd >= 0)
    nearest = np.argmin(np.linalg.norm(pts[joined, None, :2] - heads[None, m], axis=-1), 1)
    np.testing.assert_array_equal(np.flatnonzero(m)[nearest], pd[joined])


def test_without_subclustering_the_pair_is_one_detection():
    people = [((2.0, 0.0), 1.75), ((2.0, 0.35), 1.65), ((3.0, -1.2), 1.8)]
    _, _, dets = _detect(people, HeadConfig(subcluster=False))
    assert int(dets.mask.sum()) == 2
    np.testing.assert_allclose(np.sort(np.asarray(dets.height)[np.asarray(dets.mask)]),
                               [1.75, 1.8], atol=0.04)


def test_heads_closer_than_the_intimate_distance_merge():
    _, _, dets = _detect([((2.0, 0.0), 1.75), ((2.0, 0.25), 1.7)])
    assert int(dets.mask.sum()) == 1


def test_too_short_or_too_small_candidates_are_pruned():
    _, _, dets = _detect([((2.0, 0.0), 1.2)])             # a child below min_height 1.3
    assert int(dets.mask.sum()) == 0
    _, _, dets = _detect([((2.0, 0.0), 1.75)], HeadConfig(min_points=5000))
    assert int(dets.mask.sum()) == 0


def test_capacity_keeps_the_highest_heads():
    people = [((2.0, y), 1.6 + 0.05 * i) for i, y in enumerate((-1.5, -0.5, 0.5, 1.5))]
    _, _, dets = _detect(people, HeadConfig(max_detections=2))
    np.testing.assert_allclose(np.asarray(dets.height), [1.75, 1.7], atol=0.04)
    assert int(dets.num_dropped) == 2


def test_empty_input():
    dets = subcluster_heads(HeadConfig(), jnp.zeros((0, 3)), jnp.zeros(0, bool),
                            jnp.zeros(0, jnp.int32), horizontal_plane(), EYE, num_clusters=4)
    assert not bool(dets.mask.any()) and dets.point_detection.shape == (0,)
    dets = subcluster_heads(HeadConfig(), jnp.zeros((5, 3)), jnp.zeros(5, bool),
                            -jnp.ones(5, jnp.int32), horizontal_plane(), EYE, num_clusters=4)
    assert not bool(dets.mask.any())


@pytest.mark.parametrize("kw", [dict(intimate_distance=0.0), dict(min_height=2.0, max_height=1.0),
                                dict(num_bins=0), dict(max_detections=1.5)])
def test_bad_config_is_refused(kw):
    with pytest.raises(ValueError, match="HeadConfig"):
        HeadConfig(**kw)
