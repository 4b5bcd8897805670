"""Property-based probe of the public entry points: bad input gets a clear error naming the
argument, valid edge cases (empty frames, zero tracks, T = 0) a finite, defined result.

Every case starts from a valid call of one public function and applies one mutation of a class:

- ``empty``: a zero-size axis where the design makes it valid (no detections, no tracks, no
  frames) -> the call must succeed with finite outputs;
- ``nan``: NaN or inf in one floating argument -> a ``ValueError`` naming it, or a finite result
  where the design masks and counts non-finite data (measurements);
- ``covariance``: a non-symmetric, non-PSD or NaN covariance -> ``ValueError`` naming it;
- ``scale``: a negative or zero scale / noise -> ``ValueError`` naming it;
- ``dtype``: integer, float16 or mixed float32 / float64 arguments -> a finite result in one
  floating dtype, or a ``TypeError`` / ``ValueError`` naming the argument (half precision).

Outcomes: ``clear`` (ValueError / TypeError whose message names the argument), ``handled``
(finite result), ``garbage`` (a non-finite result where a finite one was due) and ``obscure``
(any other exception, or an error not naming the argument). The property is that garbage and
obscure never happen. Every case runs in CI, one test each; ``python -m tests.test_fuzz`` runs
them all and prints the table per class. A hypothesis test draws further mutations of one
filter's measurements; ``JAXTRACK_FUZZ_EXAMPLES`` raises its number of examples (default 25).
"""

from __future__ import annotations

import os
from collections import Counter

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxtrack import association, metrics
from jaxtrack.filters import kalman, particle, ukf
from jaxtrack.filters.kalman import Gaussian
from jaxtrack.models import motion

EXAMPLES = int(os.environ.get("JAXTRACK_FUZZ_EXAMPLES", "25"))
RNG = np.random.default_rng(0)


# ---------------------------------------------------------------------------------------------
# Valid calls and their mutations. Each case: (class, function name, argument named in the
# error, expect) with expect "error" (must be a clear error), "ok" (must be handled) or
# "either" (a clear error or a finite result).

F, Q = (np.asarray(a) for a in motion.constant_velocity(0.1, 0.5))
H, R = np.eye(2, 4), 0.1 * np.eye(2)
ZS = RNG.normal(size=(6, 2))
INIT = Gaussian(np.zeros(4), np.eye(4))


def kf(init=INIT, zs=ZS, F=F, Q=Q, H=H, R=R):
    res = kalman.filter(init, zs, F, Q, H, R)
    return (res.means, res.covs, res.log_likelihood)


def ukf_run(init=INIT, zs=ZS, Q=Q, R=R):
    res = ukf.filter(init, zs, lambda x: jnp.asarray(F, x.dtype) @ x, Q,
                     lambda x: jnp.asarray(H, x.dtype) @ x, R)
    return (res.means, res.covs, res.log_likelihood)


def smoother(Q=Q):
    return tuple(kalman.rts_smoother(kalman.filter(INIT, ZS, F, 0.01 * np.eye(4), H, R), F, Q))


def pf(zs=ZS):
    init = particle.init_from_gaussian(jax.random.PRNGKey(0), jnp.zeros(4), jnp.eye(4), 64)
    res = particle.filter(jax.random.PRNGKey(1), init, jnp.asarray(zs),
                          lambda k, x: x @ F.T + 0.1 * jax.random.normal(k, x.shape),
                          lambda z, x: -0.5 * jnp.sum((x[:, :2] - z) ** 2, -1) / 0.1,
                          vectorized=True)
    return (res.means, res.log_likelihood)


MEANS = RNG.normal(size=(3, 4))
COVS = np.tile(np.eye(4), (3, 1, 1))
DETS = RNG.normal(size=(5, 2))


def innovations(means=MEANS, covs=COVS, zs=DETS, R=R):
    inn = association.innovations(means, covs, zs, H, R)
    return (inn.d2, inn.log_likelihood)


def jpda(likelihoods=np.abs(RNG.normal(size=(3, 5))), p_detect=0.9, clutter_density=0.1):
    return (association.jpda_marginals(likelihoods, p_detect, clutter_density),)


def assign(cost=RNG.uniform(size=(3, 5))):
    return (association.linear_sum_assignment(cost, unassigned_cost=1.0),)


def jpda_update(states=Gaussian(MEANS, COVS), zs=DETS):
    K, M = states.mean.shape[0], zs.shape[0]
    beta = np.full((K, M + 1), 1.0 / (M + 1))
    post = association.jpda_update(states, zs, beta, H, R)
    return (post.mean, post.cov)


GT_IDS = np.tile(np.arange(3), (5, 1))
GT_POS = RNG.normal(size=(5, 3, 2))


def mot(hyp_ids=GT_IDS + 10, hyp_pos=GT_POS + 0.1, threshold=0.5):
    r = metrics.clear_mot(GT_IDS, GT_POS, None, hyp_ids, hyp_pos, None, threshold)
    i = metrics.identity_metrics(GT_IDS, GT_POS, None, hyp_ids, hyp_pos, None, threshold)
    h = metrics.hota(GT_IDS, GT_POS, None, hyp_ids, hyp_pos, None)
    return (r.num_matches, i.idtp, h.hota)


def ospa(estimates=GT_POS[0] + 0.1, c=1.0):
    return (metrics.ospa(GT_POS[0], None, estimates, None, c).distance,)


def cv(dt=0.1, q=0.5):
    return motion.constant_velocity(dt, q)


def kf_step(state=INIT, z=ZS[0], Q=Q, R=R):
    post, ll = kalman.update(kalman.predict(state, F, Q), z, H, R)
    return (post.mean, post.cov, ll)


def ekf_step(state=INIT, z=ZS[0], R=R):
    from jaxtrack.filters import ekf

    post, ll = ekf.update(ekf.predict(state, lambda x: jnp.asarray(F, x.dtype) @ x, Q), z,
                          lambda x: jnp.asarray(H, x.dtype) @ x, R)
    return (post.mean, post.cov, ll)


def gate(d2=np.abs(RNG.normal(size=(3, 5))), prob=0.99):
    return (association.gate(d2, 2, prob),)


def nn_update(states=Gaussian(MEANS, COVS), zs=DETS, col_for_row=np.array([0, -1, 2])):
    post, ll = association.nn_update(states, zs, col_for_row, H, R)
    return (post.mean, post.cov, ll)


def gospa(estimates=GT_POS[0] + 0.1, c=1.0, p=1.0):
    return (metrics.gospa(GT_POS[0], None, estimates, None, c, p).distance,)


def tracker_step(positions=DETS, capacity=6):
    from jaxtrack.tracking import tracker

    cfg = tracker.TrackerConfig(capacity=4)
    params = tracker.TrackerParams.create(cfg, dtype=jnp.float64)
    tracks = tracker.step(tracker.init(cfg, jnp.float64),
                          tracker.make_detections(positions, capacity), params)
    return (tracks.mean, tracks.cov)


def legs_detect(ranges=np.full(90, 3.0)):
    from jaxtrack.perception import legs

    det = legs.detect(ranges, np.linspace(-1.5, 1.5, ranges.shape[0]), max_people=4)
    return (det.people.xy,)


def leg_feats(ranges=np.full(90, 3.0)):
    from jaxtrack.perception import leg_features, legs

    angles = np.linspace(-1.5, 1.5, ranges.shape[0])
    return (leg_features.compute(ranges, angles, legs.segment(ranges, angles, 5.6)),)


def leg_proba(X=np.abs(RNG.normal(size=(5, 14)))):
    from jaxtrack.perception import leg_classifier

    return (leg_classifier.predict_proba(leg_classifier.default(), X),)


def leg_match(det_xy=RNG.normal(size=(4, 3, 2)), labels=RNG.normal(size=(4, 2, 2)),
              radius=0.15):
    from jaxtrack.io import leg_dataset

    return leg_dataset.match_counts(det_xy, np.ones(det_xy.shape[:2], bool), labels,
                                    np.ones(labels.shape[:2], bool), radius)


def leg_threshold(scores=RNG.uniform(size=20), y=np.arange(20) % 2):
    from jaxtrack.io import leg_dataset

    return tuple(x for x in leg_dataset.best_f1_threshold(scores, y) if np.isfinite(x))


def sensing_config(leg_threshold=0.05):
    from jaxtrack.perception import sensing

    return (np.asarray(sensing.SensingConfig(detector="learned",
                                             leg_threshold=leg_threshold).leg_threshold),)


def sensing_mounts(laser_mount=((0.2, 0.0, 0.0), (-0.2, 0.0, 3.14)), merge_radius=0.2):
    from jaxtrack.perception import sensing

    cfg = sensing.SensingConfig(laser_mount=laser_mount, merge_radius=merge_radius)
    return (np.asarray(cfg.mounts), np.asarray(cfg.merge_radius))


def cloud(depth=np.full((6, 8), 2.0), max_points=5):
    from jaxtrack.perception import depth as depth_mod

    cam = depth_mod.CeilingCamera((0.0, 0.0, 2.5), 10.0, 10.0, 4.0, 3.0)
    pts, mask = depth_mod.ceiling_cloud(cam, depth, np.ones(np.shape(depth), bool), max_points)
    return (np.asarray(pts)[np.asarray(mask)],)


# The RGB-D people detector's stages (seed 001) and the service scene's library functions
# (ceiling cameras, person status, costmap, grid planner, person interest; seeds 002 and 003).
CLOUD = np.concatenate([RNG.uniform([-0.3, -0.3, 0.0], [0.3, 0.3, 1.7], size=(40, 3)),
                        RNG.uniform([-2.0, -2.0, 0.0], [2.0, 2.0, 0.01], size=(40, 3))])


def voxels(points=CLOUD, size=0.1):
    from jaxtrack.perception import voxel_grid

    spec = voxel_grid.GridSpec(size, (-2.5, -2.5, -0.5), (50, 50, 25))
    g = voxel_grid.voxelise(spec, points, capacity=64)
    return (np.asarray(g.points)[np.asarray(g.mask)],)


def plane(points=CLOUD, threshold=0.06):
    from jaxtrack.perception import ground_plane

    fit = ground_plane.fit_ground_plane(jax.random.PRNGKey(0), points,
                                        np.ones(points.shape[0], bool),
                                        ground_plane.horizontal_plane(dtype=jnp.float64),
                                        num_hypotheses=8, threshold=threshold)
    return (fit.plane,)


def clusters(neighbours=np.stack([np.arange(1, 7) % 6, np.full(6, -1)], -1), min_size=1):
    from jaxtrack.perception import euclidean_clustering

    c = euclidean_clustering.euclidean_clusters(neighbours, np.ones(neighbours.shape[0], bool),
                                                min_size=min_size, capacity=3)
    return (np.asarray(c.sizes),)


def heads(points=CLOUD):
    from jaxtrack.perception import ground_plane, head_subclustering

    labels = np.zeros(points.shape[0], np.int32)
    h = head_subclustering.subcluster_heads(
        head_subclustering.HeadConfig(), points, np.ones(points.shape[0], bool), labels,
        ground_plane.horizontal_plane(dtype=jnp.float64), np.array([-3.0, 0.0, 1.1]),
        num_clusters=2)
    return (np.asarray(h.position)[np.asarray(h.mask)],)


def hog_features(window=RNG.uniform(size=(128, 64))):
    from jaxtrack.perception import hog

    return (hog.hog(window),)


def rgbd_detect(points=CLOUD):
    from jaxtrack.perception import rgbd_people

    cfg = rgbd_people.RGBDPeopleConfig()
    state = rgbd_people.init_state(cfg, dtype=jnp.float64)
    _, frame = rgbd_people.detect(cfg, state, jax.random.PRNGKey(0), points, None, None,
                                  np.array([-3.0, 0.0, 1.1]))
    return (np.asarray(frame.people.position)[np.asarray(frame.people.mask)],)


CAMERA_PEOPLE = np.array([[0.5, 0.2], [-1.0, 1.0]])


def ceiling_detect(people_xy=CAMERA_PEOPLE, sigma=0.1, p_detect=0.9):
    from jaxtrack.perception import ceiling_camera

    cam = ceiling_camera.look_at((0.0, 0.0, 2.8), (0.5, 0.0, 0.0), fx=300.0, dtype=jnp.float64)
    n = people_xy.shape[0]
    z, ok = ceiling_camera.detect(cam, jax.random.PRNGKey(0), people_xy, np.full(n, 1.7),
                                  np.full(n, 0.2), np.ones(n, bool), capacity=4, sigma=sigma,
                                  p_detect=p_detect)
    return (np.asarray(z)[np.asarray(ok)],)


def camera(position=(0.0, 0.0, 2.8), fx=300.0):
    from jaxtrack.perception import ceiling_camera

    cam = ceiling_camera.look_at(position, (0.5, 0.0, 0.0), fx=fx, dtype=jnp.float64)
    return (ceiling_camera.ground_homography(cam),)


def person_status(position=CAMERA_PEOPLE, velocity=np.array([[0.5, 0.0], [0.0, 0.0]])):
    from jaxtrack.tracking import status

    n = position.shape[0]
    st = status.classify(position, velocity, np.zeros(n))
    return (st.heading, np.asarray(st.status))


def costmap_build(people_xy=CAMERA_PEOPLE, heading=np.zeros(2), edge_cost=0.1):
    from jaxtrack.control import costmap

    grid = costmap.Grid(jnp.asarray([-2.0, -2.0]), jnp.asarray(0.2), (20, 20))
    params = costmap.CostParams.create(edge_cost=edge_cost, dtype=jnp.float64)
    n = people_xy.shape[0]
    return (costmap.build(grid, params, people_xy, heading, np.zeros(n, np.int32)),)


PLAN_COST = RNG.uniform(size=(8, 8))


def plan(cost=PLAN_COST, goal_cell=np.array([7, 7])):
    from jaxtrack.control import grid_planner

    dist = grid_planner.distance_field(cost, goal_cell)
    path = grid_planner.extract_path(dist, np.array([0, 0]), 16, cost=cost)
    return (dist, np.asarray(path.cells))


def follow(v_max=0.5, pose=np.zeros(3)):
    from jaxtrack.control import grid_planner

    return (grid_planner.track_path(pose, np.array([1.0, 0.5]),
                                    grid_planner.Params.create(v_max=v_max, dtype=jnp.float64)),)


def interest(cases=None, bandwidth=0.5, features=np.array([2.0, 0.1, 0.0, 0.0])):
    from jaxtrack.control import person_interest

    kw = {} if cases is None else {"cases": cases}
    cb = person_interest.CaseBase.create(bandwidth=bandwidth, dtype=jnp.float64, **kw)
    return (person_interest.estimate(cb, features),)


def _nan(a):
    a = np.array(a, dtype=np.float64)
    a.flat[0] = np.nan
    return a


CASES = [
    # empty: valid, defined outputs
    ("empty", kf, {"zs": np.zeros((0, 2))}, "zs", "ok"),
    ("empty", ukf_run, {"zs": np.zeros((0, 2))}, "zs", "ok"),
    ("empty", pf, {"zs": np.zeros((0, 2))}, "zs", "either"),
    ("empty", innovations, {"zs": np.zeros((0, 2))}, "zs", "ok"),
    ("empty", innovations, {"means": np.zeros((0, 4)), "covs": np.zeros((0, 4, 4))}, "means",
     "ok"),
    ("empty", jpda, {"likelihoods": np.zeros((3, 0)), "clutter_density": 0.1}, "likelihoods",
     "ok"),
    ("empty", jpda, {"likelihoods": np.zeros((0, 4))}, "likelihoods", "ok"),
    ("empty", assign, {"cost": np.zeros((3, 0))}, "cost", "ok"),
    ("empty", assign, {"cost": np.zeros((0, 3))}, "cost", "ok"),
    ("empty", jpda_update, {"states": Gaussian(np.zeros((0, 4)), np.zeros((0, 4, 4)))},
     "states", "ok"),
    ("empty", jpda_update, {"zs": np.zeros((0, 2))}, "zs", "ok"),
    ("empty", mot, {"hyp_ids": np.zeros((5, 0), int), "hyp_pos": np.zeros((5, 0, 2))},
     "hyp_ids", "ok"),
    ("empty", ospa, {"estimates": np.zeros((0, 2))}, "estimates", "ok"),
    ("empty", gospa, {"estimates": np.zeros((0, 2))}, "estimates", "ok"),
    ("empty", gate, {"d2": np.zeros((3, 0))}, "d2", "ok"),
    ("empty", nn_update, {"zs": np.zeros((0, 2)), "col_for_row": np.full(3, -1)}, "zs", "ok"),
    ("empty", tracker_step, {"positions": np.zeros((0, 2)), "capacity": 0}, "positions", "ok"),
    ("empty", legs_detect, {"ranges": np.zeros(0)}, "ranges", "ok"),
    ("empty", leg_feats, {"ranges": np.zeros(0)}, "ranges", "ok"),
    ("empty", leg_proba, {"X": np.zeros((0, 14))}, "X", "ok"),
    ("empty", leg_match, {"det_xy": np.zeros((4, 0, 2))}, "det_xy", "ok"),
    ("empty", leg_match, {"labels": np.zeros((4, 0, 2))}, "labels", "ok"),
    ("empty", leg_match, {"det_xy": np.zeros((0, 3, 2)), "labels": np.zeros((0, 2, 2))},
     "det_xy", "ok"),
    ("empty", leg_threshold, {"scores": np.zeros(0), "y": np.zeros(0)}, "scores", "ok"),
    ("empty", cloud, {"depth": np.zeros((0, 8))}, "depth", "ok"),
    # nan
    ("nan", kf, {"F": _nan(F)}, "F", "error"),
    ("nan", kf, {"H": _nan(H)}, "H", "error"),
    ("nan", kf, {"Q": _nan(Q)}, "Q", "error"),
    ("nan", kf, {"R": _nan(R)}, "R", "error"),
    ("nan", kf, {"init": Gaussian(_nan(np.zeros(4)), np.eye(4))}, "init", "error"),
    ("nan", kf, {"zs": _nan(ZS)}, "zs", "ok"),  # a missing measurement, masked and counted
    ("nan", ukf_run, {"zs": _nan(ZS)}, "zs", "ok"),
    ("nan", pf, {"zs": _nan(ZS)}, "zs", "ok"),
    ("nan", smoother, {"Q": _nan(Q)}, "Q", "error"),
    ("nan", innovations, {"R": _nan(R)}, "R", "error"),
    ("nan", jpda, {"p_detect": np.nan}, "p_detect", "error"),
    ("nan", jpda, {"clutter_density": np.nan}, "clutter_density", "error"),
    ("nan", assign, {"cost": _nan(RNG.uniform(size=(3, 5)))}, "cost", "ok"),  # forbidden pair
    ("nan", mot, {"hyp_pos": _nan(GT_POS)}, "hyp_pos", "ok"),  # never matches
    ("nan", mot, {"threshold": np.nan}, "threshold", "error"),
    ("nan", ospa, {"c": np.nan}, "c", "error"),
    ("nan", cv, {"q": np.nan}, "q", "error"),
    ("nan", kf_step, {"z": _nan(ZS[0])}, "z", "ok"),  # masked
    ("nan", kf_step, {"Q": _nan(Q)}, "Q", "error"),
    ("nan", ekf_step, {"z": _nan(ZS[0])}, "z", "ok"),
    ("nan", ekf_step, {"R": _nan(R)}, "R", "error"),
    ("nan", gate, {"prob": np.nan}, "prob", "error"),
    ("nan", gospa, {"p": np.nan}, "p", "error"),
    ("nan", tracker_step, {"positions": _nan(DETS)}, "positions", "either"),
    ("nan", legs_detect, {"ranges": _nan(np.full(90, 3.0))}, "ranges", "either"),
    ("nan", leg_feats, {"ranges": _nan(np.full(90, 3.0))}, "ranges", "either"),
    ("nan", leg_proba, {"X": _nan(np.ones((5, 14)))}, "X", "either"),
    ("nan", leg_match, {"radius": np.nan}, "radius", "error"),
    ("nan", sensing_config, {"leg_threshold": np.nan}, "leg_threshold", "error"),
    ("nan", sensing_mounts, {"laser_mount": ((0.0, np.nan, 0.0),)}, "laser_mount", "error"),
    ("nan", sensing_mounts, {"merge_radius": np.nan}, "merge_radius", "error"),
    ("nan", cloud, {"depth": _nan(np.full((6, 8), 2.0))}, "depth", "ok"),  # no return
    # covariance
    ("covariance", kf, {"Q": -Q}, "Q", "error"),
    ("covariance", kf, {"R": np.array([[0.1, 0.05], [0.0, 0.1]])}, "R", "error"),
    ("covariance", kf, {"R": np.zeros((2, 2))}, "R", "error"),
    ("covariance", kf, {"init": Gaussian(np.zeros(4), -np.eye(4))}, "init", "error"),
    ("covariance", ukf_run, {"Q": -Q}, "Q", "error"),
    ("covariance", smoother, {"Q": -Q}, "Q", "error"),
    ("covariance", innovations, {"covs": -COVS}, "covs", "error"),
    ("covariance", jpda_update, {"states": Gaussian(MEANS, -COVS)}, "states", "error"),
    ("covariance", kf_step, {"state": Gaussian(np.zeros(4), -np.eye(4))}, "state", "error"),
    ("covariance", ekf_step, {"R": -R}, "R", "error"),
    ("covariance", nn_update, {"states": Gaussian(MEANS, -COVS)}, "states", "error"),
    # scale
    ("scale", cv, {"q": -0.5}, "q", "error"),
    ("scale", cv, {"dt": 0.0}, "dt", "error"),
    ("scale", jpda, {"p_detect": 1.5}, "p_detect", "error"),
    ("scale", jpda, {"clutter_density": -1.0}, "clutter_density", "error"),
    ("scale", mot, {"threshold": -0.5}, "threshold", "error"),
    ("scale", ospa, {"c": -1.0}, "c", "error"),
    ("scale", gospa, {"p": 0.5}, "p", "error"),
    ("scale", gate, {"prob": 1.5}, "prob", "error"),
    ("scale", legs_detect, {"ranges": np.full(90, -3.0)}, "ranges", "either"),
    ("scale", leg_match, {"radius": -0.15}, "radius", "error"),
    ("scale", sensing_config, {"leg_threshold": 1.5}, "leg_threshold", "error"),
    ("scale", leg_proba, {"X": np.ones((5, 3))}, "X", "error"),
    ("scale", sensing_mounts, {"merge_radius": -0.1}, "merge_radius", "error"),
    ("scale", sensing_mounts, {"laser_mount": ((0.0,),)}, "laser_mount", "error"),
    ("scale", cloud, {"max_points": 0}, "max_points", "error"),
    ("scale", cloud, {"depth": np.full((6, 8), -2.0)}, "depth", "ok"),  # no return
    # dtype
    ("dtype", kf, {"init": Gaussian(np.zeros(4, int), np.eye(4, dtype=int))}, "init", "ok"),
    ("dtype", kf, {"init": Gaussian(np.zeros(4, np.float32), np.eye(4, dtype=np.float32))},
     "init", "ok"),
    ("dtype", kf, {"init": Gaussian(np.zeros(4, np.float16), np.eye(4, dtype=np.float16))},
     "init", "either"),
    ("dtype", kf, {"zs": ZS.astype(np.float32), "F": F.astype(np.float32)}, "zs", "ok"),
    ("dtype", ukf_run, {"init": Gaussian(np.zeros(4, int), np.eye(4, dtype=int))}, "init",
     "ok"),
    ("dtype", innovations, {"means": MEANS.astype(np.float32)}, "means", "ok"),
    ("dtype", jpda, {"likelihoods": np.abs(RNG.normal(size=(3, 5))).astype(np.float32)},
     "likelihoods", "ok"),
    ("dtype", mot, {"hyp_pos": (GT_POS + 0.1).astype(np.float32)}, "hyp_pos", "ok"),
    ("dtype", mot, {"hyp_ids": (GT_IDS + 10).astype(float)}, "hyp_ids", "either"),
    ("dtype", kf_step, {"state": Gaussian(np.zeros(4, np.float32), np.eye(4, dtype=np.float32))},
     "state", "ok"),
    ("dtype", tracker_step, {"positions": DETS.astype(np.float32)}, "positions", "ok"),
    ("dtype", legs_detect, {"ranges": np.full(90, 3, int)}, "ranges", "either"),
    ("dtype", leg_proba, {"X": np.ones((5, 14), int)}, "X", "ok"),
    ("dtype", leg_proba, {"X": np.ones((5, 14), np.float16)}, "X", "either"),
    ("dtype", leg_feats, {"ranges": np.full(90, 3.0, np.float32)}, "ranges", "ok"),
    ("dtype", cloud, {"depth": np.full((6, 8), 2, int)}, "depth", "either"),
    ("dtype", cloud, {"depth": np.full((6, 8), 2.0, np.float32)}, "depth", "ok"),
    # the RGB-D detector's stages and the service scene's library functions
    ("empty", voxels, {"points": np.zeros((0, 3))}, "points", "ok"),
    ("empty", plane, {"points": np.zeros((0, 3))}, "points", "ok"),
    ("empty", clusters, {"neighbours": np.zeros((0, 2), np.int32)}, "neighbours", "ok"),
    ("empty", heads, {"points": np.zeros((0, 3))}, "points", "ok"),
    ("empty", rgbd_detect, {"points": np.zeros((0, 3))}, "points", "ok"),
    ("empty", ceiling_detect, {"people_xy": np.zeros((0, 2))}, "people_xy", "ok"),
    ("empty", person_status, {"position": np.zeros((0, 2)), "velocity": np.zeros((0, 2))},
     "position", "ok"),
    ("empty", costmap_build, {"people_xy": np.zeros((0, 2)), "heading": np.zeros(0)},
     "people_xy", "ok"),
    ("empty", interest, {"cases": np.zeros((0, 5))}, "cases", "ok"),
    ("nan", voxels, {"points": _nan(CLOUD)}, "points", "ok"),          # dropped
    ("nan", rgbd_detect, {"points": _nan(CLOUD)}, "points", "ok"),
    ("nan", hog_features, {"window": _nan(np.ones((128, 64)))}, "window", "error"),
    ("nan", ceiling_detect, {"people_xy": _nan(CAMERA_PEOPLE)}, "people_xy", "either"),
    ("nan", camera, {"position": (0.0, np.nan, 2.8)}, "position", "error"),
    ("nan", person_status, {"velocity": _nan(np.zeros((2, 2)))}, "velocity", "either"),
    ("nan", costmap_build, {"people_xy": _nan(CAMERA_PEOPLE)}, "people_xy", "either"),
    ("nan", plan, {"cost": _nan(PLAN_COST)}, "cost", "either"),
    ("nan", follow, {"pose": _nan(np.zeros(3))}, "pose", "either"),
    ("nan", interest, {"features": _nan(np.ones(4))}, "features", "either"),
    ("scale", voxels, {"size": -0.1}, "size", "error"),
    ("scale", plane, {"threshold": -0.06}, "threshold", "error"),
    ("scale", clusters, {"min_size": -1}, "min_size", "either"),
    ("scale", ceiling_detect, {"sigma": -0.1}, "sigma", "error"),
    ("scale", ceiling_detect, {"p_detect": 1.5}, "p_detect", "error"),
    ("scale", camera, {"fx": -300.0}, "fx", "error"),
    ("scale", camera, {"position": (0.5, 0.0, 0.0)}, "position", "error"),  # at its target
    ("scale", costmap_build, {"edge_cost": 1.5}, "edge_cost", "error"),
    ("scale", plan, {"cost": -PLAN_COST}, "cost", "error"),
    ("scale", plan, {"goal_cell": np.array([9, 0])}, "goal_cell", "either"),
    ("scale", follow, {"v_max": -0.5}, "v_max", "error"),
    ("scale", interest, {"bandwidth": -0.5}, "bandwidth", "error"),
    ("dtype", voxels, {"points": CLOUD.astype(np.float32)}, "points", "ok"),
    ("dtype", voxels, {"points": np.round(CLOUD).astype(int)}, "points", "either"),
    ("dtype", hog_features, {"window": (255 * RNG.uniform(size=(128, 64))).astype(np.uint8)},
     "window", "either"),
    ("dtype", costmap_build, {"people_xy": CAMERA_PEOPLE.astype(np.float32)}, "people_xy", "ok"),
    ("dtype", plan, {"cost": PLAN_COST.astype(np.float32)}, "cost", "ok"),
    ("dtype", person_status, {"position": CAMERA_PEOPLE.astype(int)}, "position", "either"),
]


def classify(case) -> str:
    _, fn, kwargs, arg, expect = case
    try:
        out = fn(**kwargs)
    except (ValueError, TypeError) as err:
        named = arg in str(err) or arg.split(".")[0] in str(err)
        if expect == "ok" or not named:
            return "obscure"
        return "clear"
    except Exception:  # noqa: BLE001 - anything else is the failure this probe looks for
        return "obscure"
    finite = all(np.all(np.isfinite(np.asarray(x, np.float64))) for x in
                 jax.tree_util.tree_leaves(out) if np.asarray(x).size)
    if expect == "error":
        return "garbage"
    return "handled" if finite else "garbage"


@pytest.mark.parametrize("i", range(len(CASES)),
                         ids=[f"{c[0]}-{c[1].__name__}-{c[3]}-{k}" for k, c in enumerate(CASES)])
def test_bad_input_is_a_clear_error_and_edge_cases_are_defined(i):
    case = CASES[i]
    outcome = classify(case)
    assert outcome in ("clear", "handled"), (case[0], case[1].__name__, case[3], outcome)


@settings(max_examples=EXAMPLES, deadline=None, derandomize=True,
          suppress_health_check=list(HealthCheck))
@given(st.sampled_from(["empty", "nan", "inf", "negative", "int", "float32"]),
       st.integers(0, 4))
def test_random_mutations_of_the_kalman_filter_measurements(kind, row):
    # Drawn mutations of one argument of one filter run: every one is a valid input (missing
    # or empty measurements are masked, dtypes promoted), so every result must be finite.
    zs = ZS.copy()
    if kind == "empty":
        zs = zs[:row]
    elif kind in ("nan", "inf"):
        zs[row] = np.nan if kind == "nan" else np.inf
    elif kind == "negative":
        zs = -1e6 * np.abs(zs)
    elif kind == "int":
        zs = np.round(zs).astype(int)
    else:
        zs = zs.astype(np.float32)
    means, covs, ll = kf(zs=zs)
    assert np.all(np.isfinite(means)) and np.all(np.isfinite(covs)) and np.isfinite(ll)


def test_every_class_is_probed():
    assert {c[0] for c in CASES} == {"empty", "nan", "covariance", "scale", "dtype"}


def table() -> str:
    """Outcome counts per class over every case (``python -m tests.test_fuzz``)."""
    counts = {}
    for case in CASES:
        counts.setdefault(case[0], Counter())[classify(case)] += 1
    head = f"{'class':<12}{'tried':>7}{'clear':>7}{'handled':>9}{'garbage':>9}{'obscure':>9}"
    lines = [head, "-" * len(head)]
    for cls, c in counts.items():
        lines.append(f"{cls:<12}{sum(c.values()):>7}{c['clear']:>7}{c['handled']:>9}"
                     f"{c['garbage']:>9}{c['obscure']:>9}")
    return "\n".join(lines)


if __name__ == "__main__":
    jax.config.update("jax_enable_x64", True)
    print(table())
