"""Pedestrian model of the person-following scene: room, separation, speeds, stops, gait."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sims.following import pedestrians as pd

OBSTACLES = np.array([[-2.5, 1.6, 1.0], [2.5, -1.6, 1.0]])
# The robot stands still in these scenarios, so the user does not wait for it.
CFG = pd.PedestrianConfig(obstacles=OBSTACLES, distractors=4,
                          user=pd.UserBehaviour(wait=None))
ROBOT = jnp.array([0.0, 0.5, 0.0])
STEPS = 400  # 40 s at 10 Hz
KEYS = 8

# One compiled rollout per state shape; the config is traced, so tests share compilations.
_rollout = jax.jit(pd.rollout, static_argnums=(4, 5))


@pytest.fixture(scope="module")
def crowd():
    """8 episodes of 40 s: the user, 4 distractors and an inactive slot, a still robot."""
    keys = jax.random.split(jax.random.PRNGKey(0), KEYS)
    states = [pd.init(k, CFG, 6) for k in keys]
    init = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *states)
    run = jax.vmap(lambda k, s: _rollout(k, CFG, s, ROBOT, STEPS, 0.1)[1])
    traj = run(jax.random.split(jax.random.PRNGKey(1), KEYS), init)
    return init, jax.tree_util.tree_map(np.asarray, traj)


def _single(cfg, pos, goal, heading=0.0, steps=STEPS, robot=(50.0, 50.0, 0.0), dtype=jnp.float32):
    """One person walking from ``pos`` to a far ``goal`` (no stops, no replanning)."""
    st = pd.init(jax.random.PRNGKey(3), cfg, 1, dtype)
    st = st._replace(pos=jnp.asarray([pos], dtype), goal=jnp.asarray([goal], dtype),
                     heading=jnp.asarray([heading], dtype),
                     goal_timer=jnp.full((1,), 1e6, dtype))
    return jax.tree_util.tree_map(np.asarray, _rollout(jax.random.PRNGKey(4), cfg, st,
                                                       jnp.asarray(robot, dtype), steps, 0.05)[1])


CORRIDOR = pd.PedestrianConfig(room=(40.0, 6.0), distractors=0,
                               walks=pd.Walks(speed_range=(1.2, 1.2), stop_prob=0.0,
                                              stop_rate=0.0, cross_prob=0.0),
                               user=pd.UserBehaviour(wait=None))


def test_the_user_waits_for_a_still_robot():
    # Walking away from a robot that does not move, the user slows down past 3 m and stands
    # at 4.5 m (plus what the 0.5 s relaxation to the preferred velocity carries them); without
    # waiting they walk on.
    cfg = CORRIDOR._replace(user=pd.UserBehaviour(wait=(3.0, 4.5), return_distance=None))
    tr = _single(cfg, (-15.0, 0.0), (15.0, 0.0), robot=(-16.0, 0.0, 0.0))
    gap = tr.pos[:, 0, 0] + 16.0
    assert 4.0 < gap.max() <= 4.6
    speed = np.linalg.norm(tr.vel[:, 0], axis=-1)
    assert speed[-20:].max() < 0.05
    free = _single(CORRIDOR, (-15.0, 0.0), (15.0, 0.0), robot=(-16.0, 0.0, 0.0))
    assert free.pos[:, 0, 0].max() + 16.0 > 10.0


def test_the_user_comes_back_to_a_robot_that_lost_them():
    # Beyond user.return_distance the user walks back toward the robot: starting 7 m from a still
    # robot, they end standing within half a metre of 4 m, inside the RGB-D range.
    cfg = CORRIDOR._replace(user=pd.UserBehaviour(wait=(3.0, 4.0), return_distance=4.0))
    tr = _single(cfg, (-9.0, 0.0), (15.0, 0.0), robot=(-16.0, 0.0, 0.0))
    gap = tr.pos[:, 0, 0] + 16.0
    assert gap[0] > 6.5
    assert np.all(np.abs(gap[-100:] - 4.0) < 0.5)
    assert np.linalg.norm(tr.vel[-20:, 0], axis=-1).max() < 0.1
    # Walking away from it, they stop near 4 m and do not walk on.
    tr = _single(cfg, (-15.0, 0.0), (15.0, 0.0), robot=(-16.0, 0.0, 0.0))
    gap = tr.pos[:, 0, 0] + 16.0
    assert 3.5 < gap[-1] < 4.5 and gap.max() < 4.6


@pytest.mark.parametrize("wait, ret", [((4.0, 3.0), None), ((3.0, 4.5), 4.0)])
def test_bad_waiting_distances_are_refused(wait, ret):
    with pytest.raises(ValueError, match="user.wait|user.return_distance"):
        pd.init(jax.random.PRNGKey(0), CORRIDOR._replace(
            user=pd.UserBehaviour(wait=wait, return_distance=ret)), 1)


def test_people_stay_inside_the_room_and_out_of_the_furniture(crowd):
    _, tr = crowd
    m = tr.mask
    half = np.array(CFG.room) / 2 - CFG.forces.wall_margin
    assert np.all(np.abs(tr.pos[m]) <= half + 1e-4)
    d = np.linalg.norm(tr.pos[..., None, :] - OBSTACLES[:, :2], axis=-1) - OBSTACLES[:, 2]
    assert d[m].min() > CFG.forces.person_radius - 1e-3
    assert np.all(np.isfinite(tr.pos))


def test_people_never_overlap(crowd):
    _, tr = crowd
    d = np.linalg.norm(tr.pos[..., :, None, :] - tr.pos[..., None, :, :], axis=-1)
    both = tr.mask[..., :, None] & tr.mask[..., None, :] & ~np.eye(6, dtype=bool)
    assert both.any()
    # Legs (hip width 0.2 m, radius 6 cm) of two people never touch above 0.5 m.
    assert d[both].min() > 0.5


def test_speeds_are_pedestrian_speeds_and_people_walk(crowd):
    _, tr = crowd
    speed = np.linalg.norm(tr.vel, axis=-1)
    m = tr.mask
    assert speed[m].max() <= CFG.forces.max_speed + 1e-4
    walking = m & (tr.stop_timer <= 0)
    assert 0.5 < np.median(speed[walking]) < 1.5
    assert np.all(speed[~m] == 0)
    # The user walks a long, varied path.
    user = tr.pos[:, :, 0]
    length = np.linalg.norm(np.diff(user, axis=1), axis=-1).sum(1)
    assert np.all(length > 12.0)
    assert np.all(np.ptp(user[..., 0], axis=1) > 2.0) and np.all(np.ptp(user[..., 1], axis=1) > 1.0)


def test_stops_and_crossings_occur(crowd):
    _, tr = crowd
    stopped = tr.mask & (tr.stop_timer > 0)
    assert 0.02 < stopped[tr.mask].mean() < 0.5
    # People come to rest during a stop: after 1.5 s of stopping, speed is low.
    long_stop = tr.mask[:, 15:] & (tr.stop_timer[:, 15:] > 0) & np.all(
        [tr.stop_timer[:, 15 - k:tr.stop_timer.shape[1] - k] > 0 for k in range(1, 16)], 0)
    assert long_stop.any()
    assert np.median(np.linalg.norm(tr.vel[:, 15:], axis=-1)[long_stop]) < 0.2
    assert tr.crossing[:, :, 1:].any() and not tr.crossing[:, :, 0].any()


def test_inactive_people_are_masked_and_their_legs_parked(crowd):
    init, tr = crowd
    assert np.array_equal(np.asarray(init.mask[0]), [True] * 5 + [False])
    st = jax.tree_util.tree_map(lambda x: x[0, 10], tr)
    p0, p1, r = pd.leg_capsules(st)
    assert np.all(np.asarray(r)[5] == 0) and np.all(np.asarray(r)[:5] == CFG.gait.leg_radius)
    assert np.all(np.asarray(p1)[5, :, 2] < -10)


def test_legs_midpoint_tracks_the_body_and_step_length_follows_speed(crowd):
    _, tr = crowd
    st = jax.tree_util.tree_map(lambda x: x[:, 50:300:7].reshape((-1,) + x.shape[2:]), tr)
    p0, p1, r = jax.vmap(pd.leg_capsules)(st)
    p0, p1 = np.asarray(p0), np.asarray(p1)
    m = st.mask
    np.testing.assert_allclose(p0[..., :2].mean(-2)[m], st.pos[m], atol=1e-5)
    np.testing.assert_allclose(p1[..., :2].mean(-2)[m], st.pos[m], atol=1e-5)
    # Fixed-length capsules, feet on the floor.
    np.testing.assert_allclose(np.linalg.norm(p1 - p0, axis=-1)[m], CFG.gait.leg_length, rtol=1e-5)
    np.testing.assert_allclose(p0[..., 2][m], CFG.gait.leg_radius, atol=1e-6)
    # Feet: hip width sideways, +-(L/2) sin(phase) along the heading with L = |v| / cadence.
    e = np.stack([np.cos(st.heading), np.sin(st.heading)], -1)
    rel = p0[:, :, 0, :2] - p0[:, :, 1, :2]
    speed = np.linalg.norm(st.vel, axis=-1)
    f = CFG.gait.cadence_offset + CFG.gait.cadence_slope * speed
    L = np.where(speed > CFG.gait.stand_speed, speed / f, 0.0)
    np.testing.assert_allclose(np.sum(rel * e, -1)[m], (L * np.sin(st.phase))[m], atol=1e-5)
    lateral = np.abs(rel[..., 0] * e[..., 1] - rel[..., 1] * e[..., 0])
    np.testing.assert_allclose(lateral[m], CFG.gait.hip_width, atol=1e-5)


def test_gait_at_normal_speed_cadence_step_length_and_sway_frequency():
    """Straight walk at 1.2 m/s: cadence ~1.96 Hz, step ~0.6 m, sway 2.5 cm once per stride."""
    dt, n = 0.05, STEPS
    tr = _single(CORRIDOR, (-15.0, 0.0), (15.0, 0.0))
    st = jax.tree_util.tree_map(lambda x: x[100:], tr)  # steady walk
    speed = np.linalg.norm(st.vel[:, 0], axis=-1)
    np.testing.assert_allclose(speed, 1.2, atol=1e-3)
    cadence = float(pd.cadence(1.2))
    assert 1.8 <= cadence <= 2.0
    p0, _, _ = jax.vmap(pd.leg_capsules)(st)
    sep = np.asarray(p0)[:, 0, 0, 0] - np.asarray(p0)[:, 0, 1, 0]  # left minus right, along x
    assert 0.55 < sep.max() - sep.min() < 2 * 0.65  # step length L: feet +-L/2 apart
    # The legs pass each other (merge) once per step: zero crossings at the cadence.
    t = dt * (n - 100)
    crossings = np.sum(np.signbit(sep[1:]) != np.signbit(sep[:-1]))
    assert abs(crossings / t - cadence) < 2.5 / t
    # Sideways torso sway (y, the walk is along +x): amplitude and FFT peak at the stride rate.
    sway = np.asarray(jax.vmap(pd.torso_position)(st))[:, 0, 1] - st.pos[:, 0, 1]
    assert 0.02 <= np.abs(sway).max() <= 0.03
    spec = np.abs(np.fft.rfft(sway - sway.mean()))
    freqs = np.fft.rfftfreq(len(sway), dt)
    peak = freqs[np.argmax(spec)]
    assert abs(peak - cadence / 2) <= freqs[1]
    # The sway leans toward the stance foot: its peak is half the legs' merge frequency.
    sep_spec = np.abs(np.fft.rfft(np.abs(sep) - np.abs(sep).mean()))
    assert abs(freqs[np.argmax(sep_spec)] - cadence) <= freqs[1]


def test_standing_people_have_their_legs_together():
    st = pd.init(jax.random.PRNGKey(0), CFG, 6)
    st = st._replace(phase=jnp.full((6,), 1.3))  # mid-stride phase, but at rest
    p0, p1, _ = pd.leg_capsules(st)
    rel = np.asarray(p0)[:, 0, :2] - np.asarray(p0)[:, 1, :2]
    np.testing.assert_allclose(np.linalg.norm(rel, axis=-1)[:5], CFG.gait.hip_width, atol=1e-6)
    np.testing.assert_allclose(np.asarray(pd.torso_position(st))[:5, :2], np.asarray(st.pos)[:5],
                               atol=1e-7)


def test_people_walk_around_the_robot():
    """A walker whose straight path runs through the robot keeps clear of it and gets past."""
    tr = _single(CORRIDOR, (-8.0, 0.0), (8.0, 0.0), robot=(0.0, 0.0, 0.0))
    d = np.linalg.norm(tr.pos[:, 0], axis=-1)
    assert d.min() >= CORRIDOR.robot_radius + CORRIDOR.forces.person_radius - 1e-3
    assert tr.pos[:, 0, 0].max() > 5.0
    # Social avoidance, not only the hard projection: the path bends before contact.
    assert np.abs(tr.pos[:, 0, 1]).max() > 0.3


def test_float64_state_stays_float64():
    st = pd.init(jax.random.PRNGKey(0), CFG, 6, jnp.float64)
    new = pd.step(jax.random.PRNGKey(1), CFG, st, jnp.zeros(3), 0.1)
    assert new.pos.dtype == jnp.float64 and new.vel.dtype == jnp.float64
    assert new.phase.dtype == jnp.float64
    assert np.all(np.isfinite(np.asarray(new.pos)))


def test_bad_input_raises_clearly():
    with pytest.raises(ValueError, match="capacity"):
        pd.init(jax.random.PRNGKey(0), CFG._replace(distractors=8), 8)
    with pytest.raises(ValueError, match="obstacles"):
        pd.init(jax.random.PRNGKey(0), CFG._replace(obstacles=np.zeros((2, 2))), 6)
    with pytest.raises(ValueError, match="speed_range"):
        pd.init(jax.random.PRNGKey(0), CFG._replace(walks=pd.Walks(speed_range=(0.5, 2.0))), 6)
    st = pd.init(jax.random.PRNGKey(0), CFG, 6)
    with pytest.raises(ValueError, match="robot_pose"):
        pd.step(jax.random.PRNGKey(0), CFG, st, jnp.zeros(2), 0.1)


# ---------------------------------------------------------------------------------------------
# The shop: shoppers on the aisle graph


@pytest.fixture(scope="module")
def shop_cfg():
    from sims.following import scene

    return scene.pedestrian_config(scene.build(num_people=6, layout="shop"), distractors=5)


def _shop_rollout(cfg, state, robot, steps=400, seed=1):
    return jax.jit(lambda k, s, r: pd.rollout(k, cfg, s, r, steps, 0.1))(
        jax.random.PRNGKey(seed), state, robot)


@pytest.fixture(scope="module")
def shop_run(shop_cfg):
    """40 s of five shoppers and the user around a cart standing at its start."""
    st = pd.init(jax.random.PRNGKey(0), shop_cfg, 6)
    robot = jnp.asarray(pd.robot_start(shop_cfg, st))
    return st, robot, _shop_rollout(shop_cfg, st, robot)[1]


def test_shoppers_keep_out_of_the_shelves_and_the_cart(shop_cfg, shop_run):
    cfg = shop_cfg
    st, robot, traj = shop_run
    pos, mask = np.asarray(traj.pos), np.asarray(traj.mask)
    boxes = np.asarray(cfg.boxes)
    lo, hi = boxes[:, :2] - boxes[:, 2:], boxes[:, :2] + boxes[:, 2:]
    q = np.clip(pos[..., None, :], lo, hi)
    gap = np.linalg.norm(pos[..., None, :] - q, axis=-1).min(-1)
    r = cfg.forces.person_radius
    assert gap[mask].min() > r - 0.05          # nobody walks into a shelf (the route stays free)
    d = np.linalg.norm(pos - np.asarray(robot[:2]), axis=-1)
    assert d[mask].min() > r + cfg.robot_radius - 0.05    # nor through the cart
    # They walk: every shopper covers ground, and stops at shelves some of the time.
    travelled = np.linalg.norm(np.diff(pos, axis=0), axis=-1).sum(0)
    assert np.all(travelled[np.asarray(st.mask)] > 3.0)
    stopped = np.asarray(traj.stop_timer)[:, np.asarray(st.mask)] > 0
    assert 0.05 < stopped.mean() < 0.9


def test_a_shopper_stops_facing_the_shelf(shop_run):
    _, _, traj = shop_run
    stop = np.asarray(traj.stop_timer) > 0
    facing = np.asarray(traj.face)
    heading = np.asarray(traj.heading)
    speed = np.linalg.norm(np.asarray(traj.vel), axis=-1)
    # A second into a shelf stop a shopper stands, turned to the shelf (+-90 deg).
    late = stop & (np.roll(stop, 10, axis=0)) & (speed < 0.2)
    late[:10] = False
    # Most long stops are at shelves (the others: someone standing in the aisle).
    shelf = late & np.isclose(np.abs(facing), np.pi / 2, atol=1e-5)
    assert late.sum() > 50 and shelf.sum() > 0.7 * late.sum()
    err = np.abs((heading - facing + np.pi) % (2 * np.pi) - np.pi)[shelf]
    assert np.median(err) < 0.2


def test_the_user_passes_beside_a_cart_standing_in_the_aisle(shop_cfg):
    cfg = shop_cfg._replace(distractors=0, user=pd.UserBehaviour(wait=None))
    g = cfg.aisles
    nodes = np.asarray(g.nodes)
    start = int(np.argmin(np.linalg.norm(nodes - [-3.8, -1.3], axis=1)))
    far = [i for i in np.flatnonzero(g.spot)
           if np.allclose(nodes[i], [3.8, -0.95], atol=1e-6)][0]
    st = pd.init(jax.random.PRNGKey(0), cfg, 6)
    xy = jnp.asarray(nodes[start], st.pos.dtype)
    st = st._replace(pos=st.pos.at[0].set(xy), node=st.node.at[0].set(jnp.int32(start)),
                     target=st.target.at[0].set(jnp.int32(far)), goal=st.goal.at[0].set(xy))
    # The cart stands in the middle of the aisle, between the user and the shelf spot.
    robot = jnp.array([-2.0, -1.3, np.pi])
    _, traj = _shop_rollout(cfg, st, robot, steps=150)
    x = np.asarray(traj.pos[:, 0])
    assert x[-1, 0] > 0.0                        # past the cart
    assert np.linalg.norm(x - np.asarray(robot[:2]), axis=-1).min() > (
        cfg.robot_radius + cfg.forces.person_radius - 0.05)
