"""Seed 003 person costmaps: each status's shape against the seed's description (Hall's zones,
walking elongated ahead and passed on the left, seated kept clear behind, hand-over reachable
in front), interaction zones between a person and what they attend, the combined map against
an independent numpy re-implementation, masks, dtypes, jit / vmap, gradients and errors."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.control import costmap as cm

PARAMS = cm.CostParams.create()
GRID = cm.Grid(origin=jnp.array([-3.0, -3.0]), resolution=0.15, shape=(40, 40))
STATUSES = (cm.WALKING, cm.STANDING, cm.SEATED, cm.HANDOVER)

build = jax.jit(cm.build)
person_cost = jax.jit(cm.person_cost)
interaction_cost = jax.jit(cm.interaction_cost)


def ref_person(xy, p, phi, extents, core=0.375, edge=0.1):
    """The person cost written independently from the module docstring."""
    d = np.asarray(xy, float) - p
    qx = np.cos(phi) * d[..., 0] + np.sin(phi) * d[..., 1]
    qy = -np.sin(phi) * d[..., 0] + np.cos(phi) * d[..., 1]
    f, b, l, r = extents
    rho2 = (qx / np.where(qx >= 0, f, b)) ** 2 + (qy / np.where(qy >= 0, l, r)) ** 2
    return np.minimum(1.0, edge ** ((rho2 - core ** 2) / (1 - core ** 2)))


def ref_zone(xy, a, b, scale=1.0, margin=0.1):
    centre, radius = (np.asarray(a) + b) / 2, scale * np.linalg.norm(np.subtract(b, a)) / 2
    gap = np.maximum(np.linalg.norm(np.asarray(xy) - centre, axis=-1) - radius, 0.0)
    return np.exp(-0.5 * (gap / margin) ** 2)


def ref_cells(origin, res, shape):
    h, w = shape
    x = origin[0] + (np.arange(w) + 0.5) * res
    y = origin[1] + (np.arange(h) + 0.5) * res
    return np.stack(np.meshgrid(x, y), -1)          # [H, W, 2], rows along y


def ref_build(xy, heading, status, mask, objects=None, attended=None, static=None,
              pair_distance=2.0, pair_angle=math.radians(60)):
    cells = ref_cells(np.asarray(GRID.origin), GRID.resolution, GRID.shape)
    cost = np.zeros(GRID.shape) if static is None else np.array(static, float)
    n = len(xy)
    for i in range(n):
        if mask[i]:
            cost = np.maximum(cost, ref_person(cells, xy[i], heading[i],
                                               np.asarray(cm.EXTENTS)[status[i]]))
        if mask[i] and attended is not None and attended[i] >= 0:
            cost = np.maximum(cost, ref_zone(cells, xy[i], objects[attended[i]]))
        partners = []
        for j in range(n):
            if j == i or not (mask[i] and mask[j]) or cm.WALKING in (status[i], status[j]):
                continue
            d = np.subtract(xy[j], xy[i])
            dist = np.linalg.norm(d)
            ang_i = abs(math.remainder(math.atan2(d[1], d[0]) - heading[i], 2 * math.pi))
            ang_j = abs(math.remainder(math.atan2(-d[1], -d[0]) - heading[j], 2 * math.pi))
            if dist < pair_distance and ang_i <= pair_angle and ang_j <= pair_angle:
                partners.append((dist, j))
        if partners:            # one zone per person, with its nearest interacting partner
            cost = np.maximum(cost, ref_zone(cells, xy[i], xy[min(partners)[1]]))
    return cost


def along(direction, distances, phi=0.0):
    """Points at ``distances`` from the origin person, ``direction`` radians off heading phi."""
    a = phi + direction
    return np.asarray(distances)[:, None] * np.array([np.cos(a), np.sin(a)])


def extent(status, direction, phi=0.7, level=0.1):
    """Distance from the person where the cost falls to ``level`` along ``direction``."""
    r = np.linspace(0.0, 4.0, 4001)
    c = np.asarray(person_cost(PARAMS, jnp.asarray(along(direction, r, phi)), jnp.zeros(2), phi,
                               status))
    return r[np.argmax(c < level)]


def test_cell_centres_follow_the_occupancy_grid_layout():
    grid = cm.Grid(jnp.array([1.0, -2.0]), 0.5, (3, 4))
    xy = np.asarray(cm.cell_centers(grid))
    assert xy.shape == (3, 4, 2)
    np.testing.assert_allclose(xy[0, 0], [1.25, -1.75])
    np.testing.assert_allclose(xy[2, 1], [1.75, -0.75])     # row i along y, column j along x
    np.testing.assert_allclose(xy, ref_cells([1.0, -2.0], 0.5, (3, 4)))


@pytest.mark.parametrize("status", STATUSES)
def test_person_cost_matches_an_independent_numpy_implementation(status):
    rng = np.random.default_rng(status)
    xy = rng.uniform(-4, 4, (500, 2))
    for p, phi in [((0.0, 0.0), 0.0), ((1.0, -0.5), 2.3), ((-0.7, 0.2), -1.9)]:
        got = np.asarray(person_cost(PARAMS, jnp.asarray(xy), jnp.asarray(p), phi, status))
        np.testing.assert_allclose(got, ref_person(xy, p, phi, cm.EXTENTS[status]),
                                   rtol=1e-12, atol=1e-15)


def test_standing_is_hall_intimate_zone_lethal_and_personal_zone_edge_cheap():
    # seed 003 III-A: intimate space up to 0.45 m, personal space up to 1.2 m
    for direction in np.linspace(-np.pi, np.pi, 9):
        r = np.array([0.0, 0.2, 0.44, 0.46, 0.8, 1.2, 1.8, 3.6])
        c = np.asarray(person_cost(PARAMS, jnp.asarray(along(direction, r, 0.4)),
                                   jnp.zeros(2), 0.4, cm.STANDING))
        np.testing.assert_array_equal(c[:3], 1.0)               # lethal inside 0.45 m
        assert 0.9 < c[3] < 1.0 and np.all(np.diff(c[3:]) < 0)  # then decreasing
        assert c[5] == pytest.approx(0.1)                      # the edge cost at 1.2 m
        assert c[7] < 1e-8                                     # nothing in the social zone
    assert extent(cm.STANDING, 0.0) == pytest.approx(cm.PERSONAL, abs=2e-3)
    np.testing.assert_array_equal(np.asarray(person_cost(PARAMS, jnp.ones((3, 2)), jnp.ones(2),
                                                         0.0, cm.STANDING)),
                                  np.asarray(cm.standing_cost(PARAMS, jnp.ones((3, 2)),
                                                              jnp.ones(2), 0.0)))


def test_walking_is_longer_ahead_than_behind_and_sideways_and_wider_on_the_right():
    ahead, behind = extent(cm.WALKING, 0.0), extent(cm.WALKING, np.pi)
    left, right = extent(cm.WALKING, np.pi / 2), extent(cm.WALKING, -np.pi / 2)
    assert ahead > max(behind, left, right) and ahead > 1.9 * behind
    assert right > left          # the cheaper side is the person's left: overtake by the left
    np.testing.assert_allclose([ahead, behind, left, right], cm.EXTENTS[cm.WALKING], atol=2e-3)
    # the intimate zone stays lethal all round, also for a walking person
    ring = along(0.0, [cm.INTIMATE - 0.01])[0]
    for a in np.linspace(0, 2 * np.pi, 12):
        q = np.array([np.cos(a), np.sin(a)]) * np.linalg.norm(ring)
        assert float(cm.walking_cost(PARAMS, jnp.asarray(q), jnp.zeros(2), 0.0)) == 1.0
    # overtaking from behind: passing 1 m to the left is cheaper than 1 m to the right
    c_left = float(cm.walking_cost(PARAMS, jnp.array([0.0, 1.0]), jnp.zeros(2), 0.0))
    c_right = float(cm.walking_cost(PARAMS, jnp.array([0.0, -1.0]), jnp.zeros(2), 0.0))
    assert c_left < 0.5 * c_right


def test_seated_keeps_the_robot_away_from_behind_and_hand_over_lets_it_reach_in_front():
    assert extent(cm.SEATED, np.pi) > 1.3 * extent(cm.SEATED, 0.0)
    assert extent(cm.SEATED, np.pi / 2) == pytest.approx(extent(cm.STANDING, np.pi / 2), abs=1e-3)
    ahead = extent(cm.HANDOVER, 0.0)
    assert ahead < 0.6 * extent(cm.HANDOVER, np.pi)
    assert ahead < 0.6 * extent(cm.HANDOVER, np.pi / 2)
    # at arm's reach in front (0.5 m) a standing person is all but lethal, a hand-over one not
    front = jnp.asarray(along(0.3, [0.5], 0.3)[0])
    assert float(cm.standing_cost(PARAMS, front, jnp.zeros(2), 0.3)) > 0.9
    assert float(cm.handover_cost(PARAMS, front, jnp.zeros(2), 0.3)) < 0.3
    # every shape peaks (lethal) at the person
    for s in STATUSES:
        assert float(person_cost(PARAMS, jnp.array([1.0, 2.0]), jnp.array([1.0, 2.0]), 0.3,
                                 s)) == 1.0


def test_interaction_zone_covers_the_segment_and_not_behind_either_party():
    person, tv = np.array([0.5, -1.0]), np.array([2.0, 1.5])
    u = (tv - person) / np.linalg.norm(tv - person)
    t = np.linspace(0.0, 1.0, 21)[:, None]
    segment = person + t * (tv - person)
    c = np.asarray(interaction_cost(PARAMS, jnp.asarray(segment), jnp.asarray(person),
                                    jnp.asarray(tv)))
    np.testing.assert_array_equal(c, 1.0)                      # never cross it
    behind = np.concatenate([person - np.array([0.3, 0.5, 1.0])[:, None] * u,
                             tv + np.array([0.3, 0.5, 1.0])[:, None] * u])
    c = np.asarray(interaction_cost(PARAMS, jnp.asarray(behind), jnp.asarray(person),
                                    jnp.asarray(tv)))
    assert np.all(c < 0.02), c
    xy = np.random.default_rng(1).uniform(-2, 4, (300, 2))
    np.testing.assert_allclose(
        np.asarray(interaction_cost(PARAMS, jnp.asarray(xy), jnp.asarray(person),
                                    jnp.asarray(tv))), ref_zone(xy, person, tv), atol=1e-12)


def test_person_object_interaction_in_the_map_blocks_the_way_between_couch_and_tv():
    # seed 003, experiment 3: the robot must not pass between a seated person and the TV
    people = jnp.array([[-1.5, 0.0]])
    kw = dict(objects_xy=jnp.array([[1.5, 0.0]]), object_mask=jnp.array([True]))
    on = np.asarray(build(GRID, PARAMS, people, jnp.zeros(1), jnp.array([cm.SEATED]),
                          attended=jnp.array([0]), **kw))
    off = np.asarray(build(GRID, PARAMS, people, jnp.zeros(1), jnp.array([cm.SEATED]),
                           attended=jnp.array([-1]), **kw))
    cells = ref_cells(np.asarray(GRID.origin), GRID.resolution, GRID.shape)
    between = (np.abs(cells[..., 0]) < 1.2) & (np.abs(cells[..., 1]) < 0.15)
    clear = between & (cells[..., 0] > -0.3)          # beyond the seated person's own zone
    assert np.all(on[between] == 1.0) and np.all(off[clear] < 0.11)
    np.testing.assert_allclose(on, ref_build(np.asarray(people), [0.0], [cm.SEATED], [True],
                                             np.array([[1.5, 0.0]]), [0]), atol=1e-12)
    # a masked object makes no zone
    masked = np.asarray(build(GRID, PARAMS, people, jnp.zeros(1), jnp.array([cm.SEATED]),
                              objects_xy=kw["objects_xy"], attended=jnp.array([0]),
                              object_mask=jnp.array([False])))
    np.testing.assert_array_equal(masked, off)


def test_people_facing_each_other_close_by_interact_back_to_back_or_walking_do_not():
    xy = np.array([[-0.8, 0.0], [0.8, 0.0]])
    cases = {
        "facing": ([0.0, np.pi], [cm.STANDING, cm.SEATED], True),
        "back_to_back": ([np.pi, 0.0], [cm.STANDING, cm.STANDING], False),
        "one_walking": ([0.0, np.pi], [cm.WALKING, cm.STANDING], False),
        "side_glance": ([0.9, np.pi - 0.9], [cm.STANDING, cm.STANDING], True),
    }
    for name, (heading, status, interact) in cases.items():
        pairs = np.asarray(cm.interacting_pairs(jnp.asarray(xy), jnp.asarray(heading),
                                                jnp.asarray(status)))
        assert pairs[0, 1] == pairs[1, 0] == interact and not pairs.diagonal().any(), name
    far = np.asarray(cm.interacting_pairs(jnp.asarray(3 * xy), jnp.array([0.0, np.pi]),
                                          jnp.array([cm.STANDING, cm.STANDING])))
    assert not far.any()
    got = np.asarray(build(GRID, PARAMS, jnp.asarray(xy), jnp.array([0.0, np.pi]),
                           jnp.array([cm.STANDING, cm.STANDING])))
    np.testing.assert_allclose(got, ref_build(xy, [0.0, np.pi], [1, 1], [True, True]),
                               atol=1e-12)


SCENE_XY = np.array([[-1.5, -1.0], [0.5, 0.3], [1.6, 0.3], [-0.5, 2.0], [2.0, -2.0]])
SCENE_HEADING = np.array([0.4, 0.0, np.pi, -1.2, 2.0])
SCENE_STATUS = np.array([cm.WALKING, cm.STANDING, cm.SEATED, cm.HANDOVER, cm.STANDING])
OBJECTS = np.array([[-2.5, 2.5], [2.5, 2.5]])


def scene(dtype=jnp.float64, mask=(True, True, True, True, False)):
    return dict(people_xy=jnp.asarray(SCENE_XY, dtype), heading=jnp.asarray(SCENE_HEADING, dtype),
                status=jnp.asarray(SCENE_STATUS), mask=jnp.asarray(mask),
                objects_xy=jnp.asarray(OBJECTS, dtype), attended=jnp.array([-1, -1, -1, 0, 1]))


def test_build_matches_the_numpy_maximum_of_every_layer():
    static = np.zeros(GRID.shape)
    static[:, :3] = 1.0                                        # a wall
    static[5:8, 30:34] = 0.5
    got = np.asarray(build(GRID, PARAMS, static_cost=jnp.asarray(static), **scene()))
    want = ref_build(SCENE_XY, SCENE_HEADING, SCENE_STATUS, [1, 1, 1, 1, 0], OBJECTS,
                     [-1, -1, -1, 0, 1], static)
    np.testing.assert_allclose(got, want, atol=1e-12)
    assert got.shape == GRID.shape and got.min() >= 0.0 and got.max() == 1.0


def test_masked_people_contribute_nothing_and_zero_people_give_the_static_layer():
    full = np.asarray(build(GRID, PARAMS, **scene()))
    # the fifth person is masked: any position or heading, even NaN, leaves the map unchanged
    moved = scene()
    moved["people_xy"] = moved["people_xy"].at[4].set(jnp.array([np.nan, 0.0]))
    moved["heading"] = moved["heading"].at[4].set(np.inf)
    np.testing.assert_array_equal(np.asarray(build(GRID, PARAMS, **moved)), full)
    # masking everyone leaves the static layer (or zeros)
    static = jnp.asarray(np.random.default_rng(4).uniform(0, 1, GRID.shape))
    none = scene(mask=(False,) * 5)
    np.testing.assert_array_equal(np.asarray(build(GRID, PARAMS, static_cost=static, **none)),
                                  np.asarray(static))
    empty = cm.build(GRID, PARAMS, jnp.zeros((0, 2)), jnp.zeros(0), jnp.zeros(0, jnp.int32),
                     static_cost=static)
    np.testing.assert_array_equal(np.asarray(empty), np.asarray(static))
    zeros = cm.build(GRID, PARAMS, jnp.zeros((0, 2)), jnp.zeros(0), jnp.zeros(0, jnp.int32))
    np.testing.assert_array_equal(np.asarray(zeros), 0.0)


@pytest.mark.parametrize("dtype,atol", [(jnp.float32, 2e-6), (jnp.float64, 1e-12)])
def test_dtypes_and_jit_equals_no_jit(dtype, atol):
    grid = cm.Grid(jnp.asarray(GRID.origin, dtype), GRID.resolution, GRID.shape)
    params = cm.CostParams.create(dtype=dtype)
    jitted = build(grid, params, **scene(dtype))
    eager = cm.build(grid, params, **scene(dtype))
    assert jitted.dtype == eager.dtype == dtype
    np.testing.assert_allclose(np.asarray(jitted), np.asarray(eager), atol=atol)
    want = ref_build(SCENE_XY, SCENE_HEADING, SCENE_STATUS, [1, 1, 1, 1, 0], OBJECTS,
                     [-1, -1, -1, 0, 1])
    np.testing.assert_allclose(np.asarray(jitted), want, atol=1e-5 if dtype == jnp.float32
                               else 1e-12)


def test_vmap_over_a_batch_of_scenes_and_grids():
    rng = np.random.default_rng(5)
    xy = jnp.asarray(rng.uniform(-2, 2, (4, 5, 2)))
    heading = jnp.asarray(rng.uniform(-3, 3, (4, 5)))
    status = jnp.asarray(rng.integers(0, 4, (4, 5)))
    mask = jnp.asarray(rng.uniform(size=(4, 5)) < 0.7)
    origins = jnp.asarray(rng.uniform(-3.5, -2.5, (4, 2)))
    grids = cm.Grid(origins, jnp.full(4, 0.15), GRID.shape)

    @jax.jit
    def batched(grids, xy, heading, status, mask):
        return jax.vmap(lambda g, a, b, c, d: cm.build(g, PARAMS, a, b, c, d))(
            grids, xy, heading, status, mask)
    out = np.asarray(batched(grids, xy, heading, status, mask))
    assert out.shape == (4, *GRID.shape)
    for e in range(4):
        g = cm.Grid(origins[e], 0.15, GRID.shape)
        np.testing.assert_allclose(out[e], np.asarray(build(g, PARAMS, xy[e], heading[e],
                                                            status[e], mask[e])), atol=1e-12)


@jax.jit
def _loss_and_grads(u, xy, heading):
    def loss(u, xy):
        cost = cm.build(GRID, cm.from_unconstrained(u), xy, heading, jnp.asarray(SCENE_STATUS),
                        objects_xy=jnp.asarray(OBJECTS), attended=jnp.array([-1, -1, -1, 0, 1]))
        # the cost a straight path across the map collects
        return jnp.sum(cost[18:22, :])
    return jax.value_and_grad(loss, (0, 1))(u, xy)


def test_gradients_are_finite_wrt_parameters_and_positions():
    u = cm.to_unconstrained(PARAMS)
    value, (gu, gxy) = _loss_and_grads(u, jnp.asarray(SCENE_XY), jnp.asarray(SCENE_HEADING))
    leaves = jax.tree_util.tree_leaves((gu, gxy))
    assert all(np.all(np.isfinite(np.asarray(x))) for x in leaves)
    assert np.any(np.asarray(gu.log_extents) != 0) and float(gu.logit_edge_cost) != 0
    assert float(gu.log_interaction_margin) != 0 and np.any(np.asarray(gxy) != 0)
    # the position gradient agrees with a central difference of the numpy map
    h = 1e-5
    for i, k in [(1, 1), (2, 0)]:
        e = np.zeros_like(SCENE_XY)
        e[i, k] = h
        f = [ref_build(SCENE_XY + s * e, SCENE_HEADING, SCENE_STATUS, [1] * 5, OBJECTS,
                       [-1, -1, -1, 0, 1])[18:22, :].sum() for s in (1, -1)]
        assert float(gxy[i, k]) == pytest.approx((f[0] - f[1]) / (2 * h), rel=1e-4, abs=1e-6)


def test_unconstrained_round_trip():
    params = cm.CostParams.create(edge_cost=0.2, core=0.3, interaction_scale=1.3)
    back = cm.from_unconstrained(cm.to_unconstrained(params))
    for a, b in zip(params, back):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12)


def test_bad_input_raises_naming_the_argument():
    xy, h, s = jnp.zeros((2, 2)), jnp.zeros(2), jnp.array([cm.STANDING, cm.WALKING])
    with pytest.raises(ValueError, match="heading must have shape"):
        cm.build(GRID, PARAMS, xy, jnp.zeros(3), s)
    with pytest.raises(ValueError, match="people_xy must have shape"):
        cm.build(GRID, PARAMS, jnp.zeros((2, 3)), h, s)
    with pytest.raises(ValueError, match="status has unknown codes \\[7\\]"):
        cm.build(GRID, PARAMS, xy, h, jnp.array([1, 7]))
    # an unknown code under a False mask is nobody's business
    cm.build(GRID, PARAMS, xy, h, jnp.array([1, 7]), jnp.array([True, False]))
    with pytest.raises(TypeError, match="status must be integer"):
        cm.build(GRID, PARAMS, xy, h, jnp.array([1.0, 0.0]))
    with pytest.raises(ValueError, match="people_xy or heading contains NaN"):
        cm.build(GRID, PARAMS, jnp.array([[np.nan, 0.0], [0.0, 0.0]]), h, s)
    with pytest.raises(ValueError, match="static_cost must have shape"):
        cm.build(GRID, PARAMS, xy, h, s, static_cost=jnp.zeros((3, 3)))
    with pytest.raises(ValueError, match="static_cost must be finite and in"):
        cm.build(GRID, PARAMS, xy, h, s, static_cost=jnp.full(GRID.shape, 2.0))
    with pytest.raises(ValueError, match="attended needs objects_xy"):
        cm.build(GRID, PARAMS, xy, h, s, attended=jnp.array([0, -1]))
    with pytest.raises(ValueError, match="attended must be -1 or an index"):
        cm.build(GRID, PARAMS, xy, h, s, objects_xy=jnp.zeros((1, 2)), attended=jnp.array([1, -1]))
    with pytest.raises(ValueError, match="edge_cost must be > 0"):
        cm.CostParams.create(edge_cost=-0.1)
    with pytest.raises(ValueError, match="core must be in \\(0, 1\\)"):
        cm.CostParams.create(core=1.5)
    with pytest.raises(ValueError, match="extents contains NaN"):
        cm.CostParams.create(extents=np.full((4, 4), np.nan))
    with pytest.raises(ValueError, match="extents must have shape"):
        cm.CostParams.create(extents=np.ones((3, 4)))
    with pytest.raises(ValueError, match="interaction_margin must be > 0"):
        cm.build(GRID, PARAMS._replace(interaction_margin=jnp.asarray(0.0)), xy, h, s)
    with pytest.raises(TypeError, match="params must be a costmap.CostParams"):
        cm.build(GRID, (1.0,), xy, h, s)
    with pytest.raises(TypeError, match="grid must be a costmap.Grid"):
        cm.build((0.0, 0.0), PARAMS, xy, h, s)
    with pytest.raises(ValueError, match="grid.resolution must be > 0"):
        cm.build(cm.Grid(jnp.zeros(2), -0.1, (4, 4)), PARAMS, xy, h, s)
    with pytest.raises(ValueError, match="grid.shape must be"):
        cm.cell_centers(cm.Grid(jnp.zeros(2), 0.1, (4,)))
    with pytest.raises(ValueError, match="pair_angle must be > 0"):
        cm.build(GRID, PARAMS, xy, h, s, pair_angle=0.0)
    with pytest.raises(ValueError, match="position must have shape"):
        cm.person_cost(PARAMS, xy, jnp.zeros(3), 0.0, cm.STANDING)
