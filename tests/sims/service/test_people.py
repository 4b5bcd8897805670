"""The service scene's scripted people and experiment starts (sims.service.people,
sims.service.experiments), and the flat's static geometry."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sims.service import experiments, flat
from sims.service import people as pm

_STEP = jax.jit(pm.step)


def _run(people, robot, T, key=0, dt=0.1):
    keys = jax.random.split(jax.random.key(key), T)
    out = []
    for k in keys:
        people = _STEP(k, people, robot, dt)
        out.append(people)
    return out


def test_a_walker_walks_its_route_at_its_speed_and_stands_at_the_end():
    ppl = pm.make(jnp.array([[0.0, 0.0]]), jnp.zeros(1), jnp.array([pm.WALKER]),
                  jnp.array([True]), route=jnp.array([[[2.0, 0.0], [2.0, 1.0]]]),
                  route_len=jnp.array([2]), speed=jnp.array([0.5]))
    far = jnp.array([-5.0, -5.0, 0.0])
    seq = _run(ppl, far, 80)
    x = np.array([np.asarray(p.pos[0]) for p in seq])
    # 0.05 m per 0.1 s along x first, then up
    np.testing.assert_allclose(x[9], [0.5, 0.0], atol=1e-5)
    assert np.isclose(float(seq[9].heading[0]), 0.0, atol=1e-6)
    np.testing.assert_allclose(x[-1], [2.0, 1.0], atol=0.16)
    assert np.isclose(float(seq[50].heading[0]), np.pi / 2, atol=0.1)
    assert np.allclose(np.asarray(seq[-1].vel), 0.0)      # stands at the last waypoint


def test_a_walker_yields_to_a_robot_right_ahead():
    ppl = pm.make(jnp.array([[0.0, 0.0]]), jnp.zeros(1), jnp.array([pm.WALKER]),
                  jnp.array([True]), route=jnp.array([[[3.0, 0.0]]]))
    seq = _run(ppl, jnp.array([0.5, 0.0, np.pi]), 5)
    np.testing.assert_allclose(np.asarray(seq[-1].pos), [[0.0, 0.0]], atol=1e-6)
    seq = _run(ppl, jnp.array([0.5, 1.0, np.pi]), 5)        # beside, not ahead: walks on
    assert float(seq[-1].pos[0, 0]) > 0.2


def test_steps_go_back_or_sideways_at_0_3_m_s_keeping_the_heading_and_seated_never_step():
    n = 64
    ppl = pm.make(jnp.zeros((n, 2)), jnp.full(n, 0.7),
                  jnp.where(jnp.arange(n) < 48, pm.STANDER, pm.SEATED), jnp.ones(n, bool),
                  steps=jnp.ones(n, bool), step_rate=2.0)
    seq = _run(ppl, jnp.array([9.0, 9.0, 0.0]), 30, key=3)
    vel = np.array([np.asarray(p.vel) for p in seq])            # [T, n, 2]
    speed = np.linalg.norm(vel, axis=-1)
    moving = speed > 0
    assert moving[:, :48].any(0).mean() > 0.8                    # most standers stepped
    assert not moving[:, 48:].any()                              # seated people never
    np.testing.assert_allclose(speed[moving], pm.STEP_SPEED, rtol=1e-5)
    rel = np.arctan2(vel[..., 1], vel[..., 0])[moving] - 0.7
    rel = (rel + np.pi) % (2 * np.pi) - np.pi
    # backwards, left or right of the heading, never forwards
    assert np.all(np.min(np.abs(rel[:, None] - np.array([np.pi, -np.pi, np.pi / 2, -np.pi / 2])),
                         1) < 1e-4)
    np.testing.assert_allclose(np.asarray(seq[-1].heading), 0.7, atol=1e-6)
    # a step lasts STEP_DURATION: 10 frames at 0.1 s
    runs = np.diff(np.r_[0, moving[:, 0].astype(int), 0])
    lengths = np.flatnonzero(runs == -1) - np.flatnonzero(runs == 1)
    assert set(lengths[:-1].tolist()) <= {10, 20, 30}


def test_walkers_step_only_at_their_place():
    n = 32
    ppl = pm.make(jnp.zeros((n, 2)), jnp.zeros(n), jnp.full(n, pm.WAITER), jnp.ones(n, bool),
                  route=jnp.tile(jnp.array([[[2.0, 0.0]]]), (n, 1, 1)),
                  speed=jnp.full(n, 0.5), steps=jnp.ones(n, bool), step_rate=2.0)
    seq = _run(ppl, jnp.array([9.0, 9.0, 0.0]), 70, key=5)
    vel = np.array([np.asarray(p.vel) for p in seq])            # [T, n, 2]
    pos = np.array([np.asarray(p.pos) for p in seq])
    leg = np.array([np.asarray(p.leg) for p in seq])
    # not yet arrived, and more than one frame's walk from the place
    on_way = (leg == 0) & (np.linalg.norm(pos - np.array([2.0, 0.0]), axis=-1) > 0.2)
    # on the way: straight along +x at their speed, never a step aside or back
    np.testing.assert_allclose(vel[1:][on_way[:-1]][:, 1], 0.0, atol=1e-6)
    assert (vel[1:][on_way[:-1]][:, 0] > 0.29).all()
    # at their place they step (at 2 steps a second, nearly all of them)
    assert (np.abs(vel[-20:, :, 1]) > 0).any(0).mean() > 0.5


@pytest.mark.parametrize("name", experiments.EXPERIMENTS)
def test_experiment_starts_are_in_the_free_floor_and_keep_their_promises(name):
    rooms = experiments.free_floor()
    f = jax.jit(jax.vmap(lambda k: experiments.sample(k, name)))
    s = f(jax.random.split(jax.random.key(0), 64))
    pos = np.asarray(s.people.pos)
    mask = np.asarray(s.people.mask)

    def free(xy):
        return np.any([(xy[..., 0] >= r[0]) & (xy[..., 0] <= r[2]) & (xy[..., 1] >= r[1])
                       & (xy[..., 1] <= r[3]) for r in rooms], 0)

    assert free(pos[mask]).all() and free(np.asarray(s.robot)[:, :2]).all()
    d_robot = np.linalg.norm(pos - np.asarray(s.robot)[:, None, :2], axis=-1)
    assert d_robot[mask].min() > 1.0                 # nobody starts on the robot
    if name == "avoid":
        assert set(mask.sum(1).tolist()) <= {2, 3} and len(set(mask.sum(1).tolist())) == 2
        p = pos[:, :3]
        d = np.linalg.norm(p[:, :, None] - p[:, None], axis=-1) + 9 * np.eye(3)
        assert d.min() > 1.5                         # a way past each person
    elif name == "tv":
        seated = np.asarray(s.people.role)[mask] == pm.SEATED
        assert seated.all() and set(mask.sum(1).tolist()) <= {1, 2, 3}
        # the straight line from start to goal crosses the seats' TV interaction band
        assert (np.asarray(s.robot)[:, 1] < flat.SEATS[:, 1].min()).all()
        assert (np.asarray(s.goal)[:, 1] > flat.SEATS[:, 1].max()).all()
    elif name == "handover":
        x0, y0, x1, y1 = flat.HANDOVER_AREA
        g = np.asarray(s.goal)
        assert ((g[:, 0] > x0) & (g[:, 0] < x1) & (g[:, 1] > y0) & (g[:, 1] < y1)).all()
    elif name == "approach":
        r = np.linalg.norm(np.asarray(s.goal) - np.asarray(s.robot)[:, :2], axis=-1)
        assert (r <= 3.5 + 1e-5).all() and np.asarray(s.people.steps)[:, 0].all()
        # they walk to their place along their heading
        to_stop = np.asarray(s.goal) - pos[:, 0]
        h = np.asarray(s.people.heading)[:, 0]
        unclipped = np.isclose(np.linalg.norm(to_stop, axis=-1), 2.0, atol=1e-4)
        assert unclipped.mean() > 0.5
        np.testing.assert_allclose(np.arctan2(to_stop[unclipped, 1], to_stop[unclipped, 0]),
                                   h[unclipped], atol=1e-4)
    with pytest.raises(ValueError, match="experiment"):
        experiments.sample(jax.random.key(0), "dance")


def test_pedestrian_view_matches_the_people():
    ppl = pm.make(jnp.array([[1.0, 2.0]]), jnp.array([0.3]), jnp.array([pm.STANDER]),
                  jnp.array([True]))
    ped = pm.as_pedestrians(ppl)
    np.testing.assert_array_equal(np.asarray(ped.pos), np.asarray(ppl.pos))
    np.testing.assert_array_equal(np.asarray(ped.heading), np.asarray(ppl.heading))
    assert ped.mask.dtype == jnp.bool_
