"""Floor plans (`sims.following.layout`): the shop's aisles have the widths a cart needs, its
aisle graph stays in free space and reaches everywhere, and its tour visits every shelf spot."""

import numpy as np
import pytest

from sims.following import layout


@pytest.fixture(scope="module")
def shop():
    return layout.shop()


def _gap_to_blocks(xy, boxes):
    """[N] distance from points to the nearest block (0 inside)."""
    lo, hi = boxes[:, :2] - boxes[:, 2:], boxes[:, :2] + boxes[:, 2:]
    q = np.clip(xy[:, None], lo, hi)
    return np.linalg.norm(xy[:, None] - q, axis=-1).min(1)


def test_the_shop_has_aisles_of_1_5_to_2_5_m(shop):
    W, H = shop.room
    assert 13.0 <= W <= 15.0 and 9.5 <= H <= 11.5
    shelves = sorted({b["centre"][1] for b in shop.blocks if b["kind"] == "shelf"})
    depth = [b["size"][1] for b in shop.blocks if b["kind"] == "shelf"][0]
    gaps = np.diff(shelves) - depth
    assert np.all((gaps >= 1.5) & (gaps <= 2.5)), gaps
    kinds = {b["kind"] for b in shop.blocks}
    assert {"shelf", "end_cap", "counter"} <= kinds
    assert shop.furniture and all(f["kind"] == "display" for f in shop.furniture)


def test_the_aisle_graph_stays_in_free_space(shop):
    g, boxes = shop.aisles, shop.boxes()
    # Every node and every point of every edge keeps a person's width from the blocks.
    assert _gap_to_blocks(g.nodes, boxes).min() >= 0.25
    N = len(g.nodes)
    edges = [(i, j) for i in range(N) for j in range(N) if i != j and g.next_hop[i, j] == j]
    s = np.linspace(0.0, 1.0, 21)[:, None]
    for i, j in edges:
        seg = g.nodes[i] + s * (g.nodes[j] - g.nodes[i])
        assert _gap_to_blocks(seg, boxes).min() >= 0.25, (i, j)
    W, H = shop.room
    assert np.all(np.abs(g.nodes) < [W / 2 - 0.4, H / 2 - 0.4])


def test_routes_reach_every_node_and_are_shortest(shop):
    g = shop.aisles
    N = len(g.nodes)
    rng = np.random.default_rng(0)
    for i, j in rng.integers(0, N, (40, 2)):
        path, k = [i], i
        while k != j:
            k = int(g.next_hop[k, j])
            path.append(k)
            assert len(path) <= N
        length = np.sum(np.linalg.norm(np.diff(g.nodes[path], axis=0), axis=-1))
        assert length == pytest.approx(g.length[i, j], abs=1e-9)
        # No route is shorter than the straight line.
        assert length >= np.linalg.norm(g.nodes[j] - g.nodes[i]) - 1e-9


def test_the_tour_visits_every_spot_once_facing_a_shelf(shop):
    g, boxes = shop.aisles, shop.boxes()
    spots = np.flatnonzero(g.spot)
    assert sorted(g.tour.tolist()) == spots.tolist()
    assert np.all(g.rank[g.tour] == np.arange(len(g.tour)))
    assert np.all(g.rank[~g.spot] == -1)
    # Each spot faces a shelf 0.6 m away; its pair is 0.6 m along the shelf.
    ahead = g.nodes[spots] + 0.6 * np.stack([np.cos(g.facing[spots]),
                                            np.sin(g.facing[spots])], -1)
    assert _gap_to_blocks(ahead, boxes).max() < 1e-9
    assert np.allclose(np.linalg.norm(g.nodes[g.pair[spots]] - g.nodes[spots], axis=-1), 0.6)
    # The tour walks the aisles in turn: consecutive spots are mostly in the same aisle.
    step = np.linalg.norm(np.diff(g.nodes[g.tour], axis=0), axis=-1)
    assert np.median(step) < 1.5


def test_unknown_layout_is_refused():
    with pytest.raises(ValueError, match="unknown layout"):
        layout.by_name("warehouse")
