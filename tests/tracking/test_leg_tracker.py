"""The leg tracker (seed 004 section III-a, after Arras et al.): leg tracks over synthetic scans
from the following scene's caster, occlusion against a brute-force loop, people from leg tracks
by the four heuristics."""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.perception import legs
from jaxtrack.tracking import leg_tracker, tracker
from sims.following import lidar

LASER = lidar.LaserConfig()
ANGLES = lidar.beam_angles(LASER)
S, P = 32, 8
CFG = leg_tracker.LegTrackerConfig()
DT = 0.1

_scan = jax.jit(lidar.scan, static_argnums=4)
_detect = jax.jit(functools.partial(legs.detect, max_segments=S, max_people=P))
_step = jax.jit(leg_tracker.step, static_argnums=0, static_argnames="max_people")
_occluded = jax.jit(leg_tracker.occluded)


def _circles(centres, radii):
    return lidar.Circles(jnp.asarray(np.array(centres), jnp.float32),
                         jnp.asarray(radii, jnp.float32), jnp.ones(len(radii), bool))


def _no_walls():
    return lidar.Walls(jnp.zeros((0, 2, 2), jnp.float32), jnp.zeros(0, bool))


def _run(frames, config=CFG, seed=0):
    """Leg tracker and the per-scan detector over scans of circle scenes (robot at the origin,
    laser at the robot's centre). Returns per scan: (tracker people, detector people, state)."""
    state = leg_tracker.init(config)
    pose = jnp.zeros(3)
    out = []
    for t, circles in enumerate(frames):
        ranges = _scan(jax.random.PRNGKey(seed * 1000 + t), pose, circles, _no_walls(), LASER)
        det = _detect(ranges, ANGLES, legs.LegParams(single_legs=1.0, max_width=0.4))
        state, people = _step(config, state, det.legs_xy, det.legs_mask, det.points, det.valid,
                              pose, dt=DT, max_people=P)
        out.append((people, det.people, state))
    return out


def _walker(t, start, velocity, sep=0.3, across=math.pi / 2):
    """Leg centres of a person gliding at ``velocity`` from ``start``, legs ``sep`` apart
    along the direction ``across``."""
    mid = np.asarray(start) + t * DT * np.asarray(velocity)
    u = np.array([math.cos(across), math.sin(across)])
    return mid, [mid + 0.5 * sep * u, mid - 0.5 * sep * u]


def _ids(state):
    tr = state.tracks
    return sorted(int(i) for i, s in zip(tr.id, tr.status) if s == tracker.CONFIRMED)


# --- occlusion geometry -------------------------------------------------------------------------


def test_occlusion_matches_a_brute_force_loop():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-4, 4, (20, 2))
    rets = rng.uniform(-4, 4, (60, 2))
    mask = rng.random(60) < 0.8
    origin = np.array([0.2, -0.1])
    got = np.asarray(_occluded(jnp.asarray(pts), jnp.asarray(rets), jnp.asarray(mask),
                               jnp.asarray(origin), 0.4, 0.15))
    want = []
    for p in pts:
        d = p - origin
        rng_ = np.linalg.norm(d)
        u = d / rng_
        hid = False
        for r, m in zip(rets, mask):
            # distance from the return to the segment origin -> p, and its range along it
            a = float(np.dot(r - origin, u))
            perp = np.linalg.norm(r - origin - a * u)
            hid |= bool(m and 0 < a < rng_ - 0.15 and perp < 0.4)
        want.append(hid)
    np.testing.assert_array_equal(got, want)
    assert 0 < sum(want) < len(want)  # the draw has both cases


# --- tracks over scans --------------------------------------------------------------------------


def _with_post(frames_legs, hide_at, post):
    frames = []
    for t, centres in enumerate(frames_legs):
        c, r = list(centres), [0.06] * len(centres)
        if t in hide_at:
            c.append(post)
            r.append(0.3)
        frames.append(_circles(c, r))
    return frames


@pytest.mark.parametrize("tracked", [True, False])
def test_leg_tracks_survive_a_one_scan_occlusion(tracked):
    # A person crosses the laser's view at 3 m; at scan 6 a post between them and the laser
    # hides both legs. With the occlusion excused (heuristic 4) the two leg tracks coast
    # through the scan and the person is still reported there; without it (occlusion_radius
    # 0: nothing is ever occluded) and one miss allowed, both tracks die and come back with
    # new ids.
    config = CFG if tracked else leg_tracker.LegTrackerConfig(occlusion_radius=0.0)
    config = leg_tracker.LegTrackerConfig(**{**config.__dict__, "max_misses": 1})
    walk = [_walker(t, (3.0, -0.6), (0.0, 1.0)) for t in range(12)]
    frames = _with_post([c for _, c in walk], {6}, (1.5, 0.0))
    out = _run(frames, config)
    people6, detected6, state6 = out[6]
    assert int(detected6.mask.sum()) == 0            # the scan itself shows nobody
    before, after = _ids(out[5][2]), _ids(out[11][2])
    assert len(before) == 2
    if tracked:
        assert bool(jnp.all(state6.occluded[state6.tracks.status != tracker.FREE]))
        assert after == before
        assert int(people6.mask.sum()) == 1
        assert np.linalg.norm(np.asarray(people6.xy[0]) - walk[6][0]) < 0.1
    else:
        assert not set(after) & set(before)
        assert int(people6.mask.sum()) == 0
    # Every later scan shows the person at the legs' midpoint.
    for t in range(8, 12):
        people = out[t][0]
        assert int(people.mask.sum()) == 1
        assert np.linalg.norm(np.asarray(people.xy[0]) - walk[t][0]) < 0.1


def test_a_leg_hidden_by_the_other_keeps_the_person_at_the_midpoint():
    # A person crosses the view at 1 m/s at 2.5 m with one leg 0.3 m behind the other: near
    # y = 0 the far leg is hidden by the near one. While its track coasts (occluded) the
    # person stays at the midpoint, where the per-scan detector sees only the near leg, 0.15 m
    # off. The coasting ends when the track's position std passes max_position_std (two
    # scans here); the far leg's track is born again when it reappears.
    frames, mids = [], []
    for t in range(30):
        mid = np.array([2.5, -1.6 + 0.1 * t])
        frames.append(_circles([mid - [0.15, 0], mid + [0.15, 0]], [0.08, 0.05]))
        mids.append(mid)
    out = _run(frames)
    hidden = [t for t in range(30) if int(out[t][2].occluded.sum()) == 1]
    assert len(hidden) >= 2
    for t in hidden:
        people, detected, _ = out[t]
        assert int(detected.mask.sum()) == 1
        assert np.linalg.norm(np.asarray(detected.xy[0]) - mids[t]) > 0.1
        assert int(people.mask.sum()) == 1
        assert np.linalg.norm(np.asarray(people.xy[0]) - mids[t]) < 0.1, t
    both = [t for t in range(30) if int(out[t][0].num_legs[0]) == 2]
    assert both[0] < hidden[0] and both[-1] > hidden[-1] + 5       # reborn after the hiding


def _direct(config, frames):
    """The tracker fed leg positions directly (no scan, nothing occludes)."""
    state = leg_tracker.init(config)
    M = 4
    out = []
    for xy in frames:
        xy = np.asarray(xy, np.float32).reshape(-1, 2)
        pad = np.zeros((M, 2), np.float32)
        pad[:len(xy)] = xy
        mask = np.arange(M) < len(xy)
        state, people = _step(config, state, jnp.asarray(pad), jnp.asarray(mask),
                              jnp.zeros((1, 2)), jnp.zeros(1, bool), jnp.zeros(3), dt=DT,
                              max_people=P)
        out.append((people, state))
    return out


def test_legs_moving_apart_are_two_people_and_legs_moving_alike_one():
    # Heuristic 3: two legs 0.4 m apart (close enough to pair), walking the same way: one
    # person at the midpoint; walking opposite ways: two people (single legs).
    same = [[(1.0 + 0.1 * t, 1.0), (1.0 + 0.1 * t, 1.4)] for t in range(8)]
    apart = [[(1.0 + 0.1 * t, 1.0), (1.3 - 0.1 * t, 1.4)] for t in range(8)]
    people, _ = _direct(CFG, same)[-1]
    assert int(people.mask.sum()) == 1 and int(people.num_legs[0]) == 2
    np.testing.assert_allclose(people.xy[0], [1.7, 1.2], atol=0.03)
    # The opposite walkers are 0.4 m apart only in the middle of the run (x = 1.15).
    people, _ = _direct(CFG, apart)[2]
    assert int(people.mask.sum()) == 2
    assert np.all(np.asarray(people.num_legs[:2]) == 1)
    no_singles = leg_tracker.LegTrackerConfig(single_legs=False)
    people, _ = _direct(no_singles, apart)[2]
    assert int(people.mask.sum()) == 0


def test_unconfirmed_legs_make_no_person_and_empty_scans_are_valid():
    out = _direct(CFG, [[(1.0, 1.0), (1.0, 1.3)], [(1.0, 1.0), (1.0, 1.3)], [], [], []])
    assert int(out[0][0].mask.sum()) == 0          # one hit: tentative
    assert int(out[1][0].mask.sum()) == 1          # two hits: confirmed, one person
    assert int(out[2][0].mask.sum()) == 1          # one miss is still reported
    people, state = out[-1]
    assert int(people.mask.sum()) == 0
    assert bool(jnp.all(state.tracks.status == tracker.FREE))


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_dtypes_and_vmap(dtype):
    state = leg_tracker.init(CFG, dtype)
    xy = jnp.array([[1.0, 1.0], [1.0, 1.3]], dtype)
    f = jax.vmap(lambda s, d: leg_tracker.step(CFG, s, xy + d, jnp.ones(2, bool),
                                              jnp.zeros((1, 2), dtype), jnp.zeros(1, bool),
                                              jnp.zeros(3, dtype), dt=DT))
    batch = jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), state)
    shift = jnp.array([[0.0, 0.0], [0.5, 0.0]], dtype)
    for _ in range(2):
        batch, people = f(batch, shift[:, None])
    assert people.xy.dtype == dtype
    np.testing.assert_allclose(people.xy[:, 0], [[1.0, 1.15], [1.5, 1.15]], atol=1e-5)


def test_bad_input_raises():
    state = leg_tracker.init(CFG)
    with pytest.raises(ValueError, match="legs_xy"):
        leg_tracker.step(CFG, state, jnp.zeros((3, 3)), jnp.ones(3, bool), jnp.zeros((1, 2)),
                         jnp.zeros(1, bool), jnp.zeros(3), dt=DT)
    with pytest.raises(ValueError, match="robot_pose"):
        leg_tracker.step(CFG, state, jnp.zeros((3, 2)), jnp.ones(3, bool), jnp.zeros((1, 2)),
                         jnp.zeros(1, bool), jnp.zeros(2), dt=DT)
    with pytest.raises(ValueError, match="pair_distance"):
        leg_tracker.LegTrackerConfig(pair_distance=0.0)
    with pytest.raises(ValueError, match="confirm"):
        leg_tracker.LegTrackerConfig(confirm_hits=4, confirm_window=3)


def test_only_the_nearest_candidates_are_associated():
    # Five legs in a row, three candidates allowed: the two farthest start no track.
    config = leg_tracker.LegTrackerConfig(max_candidates=3, confirm_hits=1)
    xy = jnp.array([[3.0, 0.0], [1.0, 0.0], [4.0, 0.0], [2.0, 0.0], [5.0, 0.0]])
    state, _ = leg_tracker.step(config, leg_tracker.init(config), xy, jnp.ones(5, bool),
                                jnp.zeros((1, 2)), jnp.zeros(1, bool), jnp.zeros(3), dt=DT)
    live = np.asarray(state.tracks.status) != tracker.FREE
    np.testing.assert_allclose(sorted(np.asarray(state.tracks.mean)[live, 0]), [1.0, 2.0, 3.0])


def test_a_nan_candidate_is_ignored():
    xy = jnp.array([[1.0, 1.0], [1.0, 1.3], [jnp.nan, 0.0]])
    clean = _direct(CFG, [[(1.0, 1.0), (1.0, 1.3)]] * 3)[-1]
    state = leg_tracker.init(CFG)
    for _ in range(3):
        state, people = _step(CFG, state, xy, jnp.ones(3, bool), jnp.zeros((1, 2)),
                              jnp.zeros(1, bool), jnp.zeros(3), dt=DT, max_people=P)
    assert np.all(np.isfinite(np.asarray(state.tracks.mean)))
    np.testing.assert_allclose(people.xy, clean[0].xy, atol=1e-6)


def test_confident_legs_start_tracks_and_less_confident_ones_keep_them():
    # The classifier's confidence initiates leg tracks; any candidate updates them.
    cfg = leg_tracker.LegTrackerConfig(birth_confidence=0.3)
    state = leg_tracker.init(cfg)
    pose = jnp.zeros(3)
    returns, rmask = jnp.zeros((4, 2)), jnp.zeros(4, bool)
    legs_xy = jnp.asarray([[2.0, 0.0], [2.0, 1.0]], jnp.float32)
    mask = jnp.ones(2, bool)

    def step(state, xy, conf):
        return _step(cfg, state, xy, mask, returns, rmask, pose, dt=DT, max_people=P,
                     legs_conf=jnp.asarray(conf, jnp.float32))

    # Leg 0 is confident in the first scans, leg 1 never is: only leg 0 gets a track.
    for t in range(3):
        state, _ = step(state, legs_xy + jnp.asarray([0.02 * t, 0.0]), [0.9, 0.1])
    tr = state.tracks
    live = np.asarray(tr.status) != tracker.FREE
    assert live.sum() == 1
    assert np.linalg.norm(np.asarray(tr.mean)[live][0, :2] - [2.04, 0.0]) < 0.05
    first = _ids(state)
    assert len(first) == 1
    # Then both score 0.1: leg 0's track is kept (updated, confirmed, same id), leg 1 still
    # starts none.
    for t in range(3, 8):
        state, people = step(state, legs_xy + jnp.asarray([0.02 * t, 0.0]), [0.1, 0.1])
    assert _ids(state) == first
    tr = state.tracks
    live = np.asarray(tr.status) != tracker.FREE
    assert live.sum() == 1 and int(np.asarray(tr.misses)[live][0]) == 0
    np.testing.assert_allclose(np.asarray(tr.mean)[live][0, :2], [2.14, 0.0], atol=0.03)
    # The same scans without confidences (all 1) start two tracks.
    plain = leg_tracker.init(cfg)
    for t in range(3):
        plain, _ = _step(cfg, plain, legs_xy, mask, returns, rmask, pose, dt=DT, max_people=P)
    assert int(np.sum(np.asarray(plain.tracks.status) != tracker.FREE)) == 2
    with pytest.raises(ValueError, match="birth_confidence"):
        leg_tracker.LegTrackerConfig(birth_confidence=1.5)
    with pytest.raises(ValueError, match="legs_conf"):
        leg_tracker.step(cfg, state, legs_xy, mask, returns, rmask, pose, dt=DT,
                         legs_conf=jnp.ones(3))
