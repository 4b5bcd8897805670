"""The following behaviour: the outline points the avoidance layer checks."""

import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.control import behaviour


def _outline(rng, n=400):
    return rng.uniform([-6.0, -4.0], [6.0, 4.0], (n, 2))


@pytest.mark.parametrize("reach, cell", [(3.0, 0.5), (1.0, 0.25), (2.0, 1.0)])
def test_nearby_outline_holds_every_point_within_reach(reach, cell):
    # Brute force: from anywhere on the map, every outline point within `reach` of the robot
    # is among the table's points for the robot's cell, and no point is listed twice.
    rng = np.random.default_rng(0)
    outline = _outline(rng)
    bounds = ((-6.0, 6.0), (-4.0, 4.0))
    table = behaviour._outline_table(outline, bounds, reach, cell)
    for pos in rng.uniform([-6.0, -4.0], [6.0, 4.0], (300, 2)):
        pose = jnp.array([pos[0], pos[1], 0.3])
        pts, ok = behaviour._nearby_outline(table, jnp.asarray(outline), pose)
        listed = np.asarray(pts)[np.asarray(ok)]
        need = outline[np.linalg.norm(outline - pos, axis=1) <= reach]
        d = np.linalg.norm(need[:, None] - listed[None], axis=-1)
        assert d.size == 0 or np.all(d.min(1) == 0.0)
        assert len(np.unique(listed, axis=0)) == len(listed)
    # The table is a real cut: a cell lists fewer points than the whole outline.
    assert table.index.shape[1] < len(outline)


def test_outline_reach_is_validated():
    with pytest.raises(ValueError, match="outline_reach"):
        behaviour.FollowingConfig(outline_reach=0.0)
