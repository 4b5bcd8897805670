"""Seed 001's robot sequences (sims.following.crowd) at a small size: the scripted people, the
ground truth, one episode's scores and the command line."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.perception import hog
from sims.following import crowd, crowd_report, kinect

SMALL = crowd.CrowdConfig(duration=1.5, camera=kinect.KinectConfig(width=64, height=48),
                          max_people=4, tracks=6)


def test_people_are_pairs_standing_close_and_walkers_crossing():
    for seed in range(20):
        for scenario in ("simple", "complex"):
            cfg = dataclasses.replace(SMALL, scenario=scenario)
            p = crowd.sample_people(jax.random.key(seed), cfg)
            m = np.asarray(p.mask)
            assert cfg.min_people <= m.sum() <= cfg.max_people
            w = np.asarray(p.waypoints)
            standing = (np.asarray(p.speed) == 0) & m
            walking = (np.asarray(p.speed) > 0) & m
            assert standing.sum() % 2 == 0                  # standing people come in pairs
            s = np.flatnonzero(standing)
            for a, b in zip(s[::2], s[1::2]):
                assert b == a + 1 and 0.5 - 1e-5 <= np.linalg.norm(w[a, 0] - w[b, 0]) <= 0.7 + 1e-5
            assert (np.abs(np.abs(w[walking][:, [0, 2], 1]) - 3.6) < 1e-5).all()   # wall to wall
            assert ((np.asarray(p.speed)[walking] >= 0.5) & (np.asarray(p.speed)[walking] <= 1.1)).all()
            if scenario == "simple":                        # straight lines
                np.testing.assert_allclose(w[walking, 1], 0.5 * (w[walking, 0] + w[walking, 2]),
                                           atol=1e-5)


def test_people_follow_their_polyline_at_their_speed():
    w = jnp.asarray([[[0.0, 0.0], [3.0, 0.0], [3.0, 4.0]]])
    people = crowd.People(w, jnp.asarray([1.0]), jnp.asarray([2.0]), jnp.zeros(1),
                          jnp.asarray([1.75]), jnp.zeros((1, 3, 3)), jnp.ones(1, bool))
    for t, pos, vel in ((1.0, (0.0, 0.0), (0.0, 0.0)), (3.5, (1.5, 0.0), (1.0, 0.0)),
                        (6.0, (3.0, 1.0), (0.0, 1.0)), (20.0, (3.0, 4.0), (0.0, 0.0))):
        st = crowd.people_at(people, t)
        np.testing.assert_allclose(st.pos[0], pos, atol=1e-6)
        np.testing.assert_allclose(st.vel[0], vel, atol=1e-6)
    assert abs(float(crowd.people_at(people, 6.0).heading[0]) - math.pi / 2) < 1e-6


def test_obstacles_scenario_adds_furniture_a_whiteboard_and_a_coat_stand():
    plain = crowd.static_scene(SMALL)
    full = crowd.static_scene(dataclasses.replace(SMALL, scenario="obstacles"))
    assert plain.box_centre.shape[0] == 4 and plain.capsule_a.shape[0] == 0
    assert full.box_centre.shape[0] == 4 + 6 + 4 + 1 and full.capsule_a.shape[0] == 24 + 4


def test_in_view_is_the_field_of_view_with_a_body_margin():
    cam = kinect.KinectConfig()
    eye, rot = kinect.camera_pose(cam, jnp.asarray([0.0, 0.0, 0.0]))
    half = math.tan(math.radians(28.5))
    xy = jnp.asarray([[2.0, 2.0 * half + 0.25], [2.0, 2.0 * half + 0.35], [-1.0, 0.0],
                      [4.7, 0.0], [4.9, 0.0]]) + eye[:2]
    np.testing.assert_array_equal(crowd._in_view(cam, eye, rot, xy),
                                  [True, False, False, True, False])


@pytest.fixture(scope="module")
def small_episode():
    svm = hog.LinearSVM(jnp.zeros(hog.num_features()), jnp.asarray(1.0))
    fn = jax.jit(lambda k: crowd.frames(k, SMALL, crowd.Pipeline(), svm))
    return fn(jax.random.key(3)), svm


def test_episode_record_and_ground_truth(small_episode):
    rec, _ = small_episode
    T = SMALL.num_frames
    assert rec["visible"].shape == (T, SMALL.max_people)
    assert not bool(jnp.any(rec["visible"] & rec["partial"]))
    # Reported tracks are confirmed ones; detections carry the SVM's constant confidence.
    conf = np.asarray(rec["confidence"])[np.asarray(rec["det_mask"])]
    np.testing.assert_allclose(conf, 1 / (1 + np.exp(-1.0)), rtol=1e-5)
    ids = np.asarray(rec["track_id"])
    assert ((ids >= 0) == np.asarray(rec["track_mask"])).all()
    # The robot drives along +x at its speed.
    np.testing.assert_allclose(np.diff(np.asarray(rec["robot"])[:, 0]),
                               SMALL.robot_speed / SMALL.rate, atol=1e-6)


def test_episode_scores_are_clear_mot_of_the_record(small_episode):
    rec, _ = small_episode
    out = crowd.score(SMALL, rec)
    assert 0 <= float(out["det_precision"]) <= 1 and 0 <= float(out["det_recall"]) <= 1
    objects = int(np.sum(np.asarray(rec["visible"])))
    assert int(out["objects"]) == objects
    assert float(out["mota"]) == pytest.approx(
        1 - (float(out["misses"]) + float(out["false_positives"]) + float(out["id_switches"]))
        / max(objects, 1), abs=1e-6)


def test_the_oracle_feeds_the_tracker_the_visible_peoples_true_positions():
    # the tracker's floor: detections are the visible people, where they are, confidence 1
    svm = hog.LinearSVM(jnp.zeros(hog.num_features()), jnp.asarray(1.0))
    rec = jax.jit(lambda k: crowd.frames(k, SMALL, crowd.FLOORS["perfect detections"],
                                         svm))(jax.random.key(3))
    visible = np.asarray(rec["visible"])
    assert visible.any()
    np.testing.assert_array_equal(np.asarray(rec["det_mask"]), visible)
    np.testing.assert_array_equal(np.asarray(rec["detections"])[visible],
                                  np.asarray(rec["truth"])[visible])
    np.testing.assert_array_equal(np.asarray(rec["confidence"]), 1.0)
    out = crowd.score(SMALL, rec)
    assert int(out["det_false_positives"]) == 0 and int(out["det_misses"]) == 0


def test_ablation_table_pools_episodes_and_pairs_differences():
    full = dict(misses=np.array([1, 2]), false_positives=np.array([0, 2]),
                id_switches=np.array([0, 0]), objects=np.array([10, 20]),
                matches=np.array([9, 18]), motp=np.array([0.1, 0.2]),
                det_matches=np.array([9, 18]), det_false_positives=np.array([1, 2]),
                det_misses=np.array([1, 2]))
    worse = dict(full, misses=np.array([3, 6]))
    table = crowd_report.ablation_table({"full": full, "no velocity": worse})
    assert "83.3%" in table                              # 1 - (3 + 2) / 30
    assert "63.3%" in table                              # 1 - (9 + 2) / 30
    assert "-20.0" in table                              # mean of (-20, -20) points


def test_bad_config_is_refused():
    with pytest.raises(ValueError, match="scenario"):
        crowd.CrowdConfig(scenario="stairs")
    with pytest.raises(ValueError, match="min_people"):
        crowd.CrowdConfig(min_people=0)
    with pytest.raises(ValueError, match="appearance"):
        crowd.Pipeline(oracle=True)
    with pytest.raises(ValueError, match="oracle_noise"):
        crowd.Pipeline(oracle=True, appearance=False, oracle_noise=-0.1)
