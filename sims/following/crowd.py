r"""Seed 001's robot sequences, simulated: a robot drives through a room among 2-6 people and
tracks them with its Kinect alone.

Seed 001 (section V-A) drove its robot "along one direction in three different scenarios of
increasing difficulty": people on simple (linear) trajectories; people on complex trajectories
who interact; the same with obstacles (chairs, a whiteboard). Here, per episode:

- **The robot** starts near the room's left wall, at :math:`(-3.8, y_0)`, and drives along +x at
  ``robot_speed`` (0.2 m/s), with perfect odometry (the tracker works in the world frame).
- **The people**, 2-6 of them: pairs who stand side by side 0.5-0.7 m apart (shoulders
  0.2 m apart at the least, as the seed's closest pair) in the robot's way, and walkers who
  cross the room at 0.5-1.1 m/s from one side wall to the other, each leaving at a random time.
  A walker goes straight ("simple") or through a random waypoint in the robot's view
  ("complex", "obstacles").
- **Obstacles** ("obstacles"): the room's two tables with their chairs, a whiteboard on legs and
  a coat stand, which look like people to the geometry (a whiteboard is as tall as a person).
- **Sensing**: the Kinect (`sims.following.kinect`, 160 x 120 as seed 001 acquired, or QVGA)
  renders depth and colour; the colour image gets Gaussian noise; the detector
  (`jaxtrack.perception.rgbd_people`) finds people with their HOG confidence.
- **Tracking**: the library's tracker with seed 001's settings: GNN (Munkres), UKF, the
  three-term cost :math:`\gamma D_M - \alpha c_{online} - \beta c_{HOG}` with the Mahalanobis
  distance of position and velocity, tracks born from confident detections, an online colour
  classifier per track fed by the detections' RGB histograms.
- **Ground truth**: a person counts in a frame when at least ``min_visible`` of the pixels they
  would cover unoccluded show them with a depth (seed 001 annotated the people visible in its
  images; a person beyond the Kinect's range has no depth). A person in the camera's field of
  view and range but less visible than that, or hidden, is *ignored*, as MOTChallenge ignores
  its hard cases: a track or a detection near them and near nobody visible is neither a hit nor
  a false positive (a track kept through an occlusion is not an error, nor required).
- **The tracker's output**: the confirmed tracks inside the camera's field of view (tracks
  coasting outside it are kept, not reported).
- **Track births**: an unassociated detection confident enough starts a track even inside
  another track's gate (seed 001: "if there are unassociated detections with HOG confidence
  above a security threshold, new tracks are created"); two tracks closer than 0.3 m are merged.

`Pipeline` switches the parts off for the seed's ablations: sub-clustering, the velocity in the
motion term, the appearance term, the detector confidence.

Example:
  >>> cfg = CrowdConfig()
  >>> out = episode(jax.random.key(0), cfg, Pipeline(), hog.load_svm())
  >>> out["mota"]
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxtrack import metrics, tracking
from jaxtrack.perception import hog, rgbd_people
from jaxtrack.perception.head_subclustering import HeadConfig
from sims.following import kinect, layout as layout_mod, pedestrians

Array = jax.Array

__all__ = ["CrowdConfig", "Pipeline", "ABLATIONS", "FLOORS", "People", "Sensed", "sample_people",
           "people_at", "static_scene", "sense", "base_camera", "to_world", "episode", "frames",
           "score", "training_crops"]

SCENARIOS = ("simple", "complex", "obstacles")


@dataclasses.dataclass(frozen=True)
class CrowdConfig:
    """An episode's settings (static).

    Attributes:
      scenario: "simple", "complex" or "obstacles" (module docstring).
      max_people: P, people slots; an episode has between ``min_people`` and P.
      min_people: fewest people.
      pair_prob: probability that a person slot starts a standing pair (with the next slot).
      duration: seconds; rate: frames per second.
      robot_speed: m/s along +x.
      camera: the `kinect.KinectConfig`; seed 001 acquired 160 x 120.
      colour_noise: std of the colour image's Gaussian noise.
      min_visible: share of a person's unoccluded pixels that makes them ground truth.
      match_distance: ground-plane distance of a correct track or detection (m).
      tracks: tracker capacity.
    """

    scenario: str = "complex"
    max_people: int = 6
    min_people: int = 2
    pair_prob: float = 0.5
    duration: float = 20.0
    rate: float = 10.0
    robot_speed: float = 0.2
    camera: kinect.KinectConfig = kinect.KinectConfig(width=160, height=120)
    colour_noise: float = 0.02
    min_visible: float = 0.25
    match_distance: float = 0.5
    tracks: int = 12

    def __post_init__(self):
        if self.scenario not in SCENARIOS:
            raise ValueError(f"unknown scenario {self.scenario!r}; expected one of {SCENARIOS}")
        if not 1 <= self.min_people <= self.max_people:
            raise ValueError("need 1 <= min_people <= max_people; got "
                             f"{self.min_people}, {self.max_people}")
        if not (self.duration > 0 and self.rate > 0):
            raise ValueError(f"duration and rate must be positive; got {self.duration}, "
                             f"{self.rate}")

    @property
    def num_frames(self) -> int:
        return max(1, int(round(self.duration * self.rate)))


@dataclasses.dataclass(frozen=True)
class Pipeline:
    """Which of seed 001's parts run (static): the full system by default.

    Attributes:
      subcluster: head sub-clustering (else one detection per cluster).
      velocity: velocity in the Mahalanobis motion term, measured over 1 s (open_ptrack).
      appearance: the online colour classifier's term.
      confidence: the HOG confidence in the cost and for track births.
      gamma, alpha, beta: the cost weights of eq. 2.
      min_confidence: detections less confident are dropped before tracking (as the seed's
        implementation, PCL's ground-based people detector, drops detections under its HOG
        threshold). 0.5, chosen on seed 1's "simple" and "obstacles" episodes among 0.4, 0.5
        and 0.6, and checked on seed 0's (`docs/rgbd_people.md`): MOTA +1.3 / +1.4 / +2.4
        points over 0.4 in simple / complex / obstacles; 0.6 loses recall.
      birth_confidence: smallest HOG confidence that starts a track.
      oracle: replace the detector's output by the true positions of the visible people
        (plus ``oracle_noise``, m, per axis), confidence 1, no appearance: the tracker's floor,
        what it reaches when detection is perfect.
    """

    subcluster: bool = True
    velocity: bool = True
    appearance: bool = True
    confidence: bool = True
    gamma: float = 1.0
    alpha: float = 1.0
    beta: float = 2.0
    min_confidence: float = 0.5
    birth_confidence: float = 0.5
    oracle: bool = False
    oracle_noise: float = 0.0

    def __post_init__(self):
        if self.oracle and self.appearance:
            raise ValueError("an oracle pipeline has no colour histograms: set appearance=False")
        if not (math.isfinite(self.oracle_noise) and self.oracle_noise >= 0):
            raise ValueError(f"oracle_noise must be >= 0; got {self.oracle_noise}")

    def detector(self) -> rgbd_people.RGBDPeopleConfig:
        return rgbd_people.RGBDPeopleConfig(heads=HeadConfig(subcluster=self.subcluster))

    def tracker(self, cfg: CrowdConfig, dtype=jnp.float32) -> tracking.TrackerParams:
        bins = self.detector().histogram_bins
        tc = tracking.TrackerConfig(
            capacity=cfg.tracks, association="gnn", filter="ukf",
            motion_term="position_velocity" if self.velocity else "position",
            distance="mahalanobis", num_features=bins ** 3 if self.appearance else 0,
            confirm_hits=3, confirm_window=5, max_misses=10, max_tentative_misses=2,
            merge_distance=0.3, births_in_gates=True,
            velocity_window=max(1, round(cfg.rate)))     # 1 s, as open_ptrack
        return tracking.TrackerParams.create(
            tc, dt=1.0 / cfg.rate, q=1.0, r_std=(0.15,), init_speed_std=1.0,
            gamma=self.gamma, alpha=self.alpha if self.appearance else 0.0,
            beta=self.beta if self.confidence else 0.0,
            birth_confidence=self.birth_confidence if self.confidence else 0.0,
            gate_prob=0.999, dtype=dtype)


ABLATIONS = {
    "full": Pipeline(),
    "no sub-clustering": Pipeline(subcluster=False),
    "no velocity": Pipeline(velocity=False),
    "no appearance": Pipeline(appearance=False),
    "no confidence": Pipeline(confidence=False),
}
FLOORS = {
    "perfect detections": Pipeline(oracle=True, appearance=False),
    "truth + 0.1 m noise": Pipeline(oracle=True, oracle_noise=0.1, appearance=False),
}
"""The tracker on the visible people's true positions: the MOTA floor the detector is held to."""


class People(NamedTuple):
    """Scripted people of one episode ([P] leaves).

    Attributes:
      waypoints: [P, 3, 2] start, middle and end; speed: [P] m/s (0 standing);
      start: [P] departure time (s); facing: [P] heading of a standing person;
      stature: [P] m; clothing: [P, 3, 3]; mask: [P] bool.
    """

    waypoints: Array
    speed: Array
    start: Array
    facing: Array
    stature: Array
    clothing: Array
    mask: Array


_ROOM = (10.0, 8.0)


def sample_people(key: Array, cfg: CrowdConfig, dtype=jnp.float32) -> People:
    """Draw an episode's people (module docstring)."""
    P = cfg.max_people
    ks = jax.random.split(key, 12)
    n = jax.random.randint(ks[0], (), cfg.min_people, P + 1)
    mask = jnp.arange(P) < n
    # Pairs: slot i starts a pair with i + 1 when drawn (and i + 1 is not already a partner).
    draw = jax.random.uniform(ks[1], (P,)) < cfg.pair_prob

    def pair_step(partner_prev, i):
        starts = draw[i] & ~partner_prev & (i + 1 < n)
        return starts, (starts, partner_prev)

    _, (starts, partner) = lax.scan(pair_step, jnp.asarray(False), jnp.arange(P))
    standing = (starts | partner) & mask
    centre = jnp.stack([jax.random.uniform(ks[2], (P,), minval=0.5, maxval=3.5),
                        jax.random.uniform(ks[3], (P,), minval=-1.6, maxval=1.6)], -1)
    facing = jax.random.uniform(ks[4], (P,), minval=-math.pi, maxval=math.pi)
    gap = jax.random.uniform(ks[5], (P,), minval=0.5, maxval=0.7)
    side = jnp.stack([-jnp.sin(facing), jnp.cos(facing)], -1)
    first = centre + 0.5 * gap[:, None] * side
    second = jnp.roll(centre - 0.5 * gap[:, None] * side, 1, axis=0)
    stand_xy = jnp.where(starts[:, None], first, second)
    stand_face = jnp.where(starts, facing, jnp.roll(facing, 1))
    # Walkers cross from one side wall to the other.
    from_left = jax.random.bernoulli(ks[6], 0.5, (P,))
    sgn = jnp.where(from_left, 1.0, -1.0)
    x0 = jax.random.uniform(ks[7], (P,), minval=-1.5, maxval=4.0)
    x2 = jax.random.uniform(ks[8], (P,), minval=-1.5, maxval=4.0)
    w0 = jnp.stack([x0, -sgn * 3.6], -1)
    w2 = jnp.stack([x2, sgn * 3.6], -1)
    if cfg.scenario == "simple":
        w1 = 0.5 * (w0 + w2)
    else:
        w1 = jnp.stack([jax.random.uniform(ks[9], (P,), minval=-0.5, maxval=4.0),
                        jax.random.uniform(ks[10], (P,), minval=-1.8, maxval=1.8)], -1)
    walk = jnp.stack([w0, w1, w2], 1)
    still = jnp.broadcast_to(stand_xy[:, None], walk.shape)
    waypoints = jnp.where(standing[:, None, None], still, walk).astype(dtype)
    kspeed, kstart, kstat, kcl = jax.random.split(ks[11], 4)
    speed = jnp.where(standing, 0.0, jax.random.uniform(kspeed, (P,), minval=0.5, maxval=1.1))
    start = jax.random.uniform(kstart, (P,), minval=0.0, maxval=0.5 * cfg.duration)
    stature = jax.random.uniform(kstat, (P,), minval=1.6, maxval=1.9)
    clothing = jnp.asarray(kinect.CLOTHING, dtype)[jax.random.permutation(
        kcl, kinect.CLOTHING.shape[0])[:P] % kinect.CLOTHING.shape[0]]
    return People(waypoints, speed.astype(dtype), start.astype(dtype),
                  jnp.where(standing, stand_face, 0.0).astype(dtype), stature.astype(dtype),
                  clothing, mask)


def people_at(people: People, t, gait=pedestrians.GaitParams()) -> pedestrians.PedestrianState:
    """The people's `pedestrians.PedestrianState` at time ``t`` (position along the polyline,
    velocity, heading, gait phase), for rendering."""
    w = people.waypoints
    seg = jnp.linalg.norm(w[:, 1:] - w[:, :-1], axis=-1)               # [P, 2]
    length = jnp.maximum(seg.sum(-1), 1e-9)
    moving = people.speed > 0
    s = jnp.clip((t - people.start) * people.speed, 0.0, length)
    on_first = s <= seg[:, 0]
    frac1 = s / jnp.maximum(seg[:, 0], 1e-9)
    frac2 = (s - seg[:, 0]) / jnp.maximum(seg[:, 1], 1e-9)
    pos = jnp.where(on_first[:, None], w[:, 0] + frac1[:, None] * (w[:, 1] - w[:, 0]),
                    w[:, 1] + frac2[:, None] * (w[:, 2] - w[:, 1]))
    d = jnp.where(on_first[:, None], w[:, 1] - w[:, 0], w[:, 2] - w[:, 1])
    unit = d / jnp.maximum(jnp.linalg.norm(d, axis=-1, keepdims=True), 1e-9)
    walking = moving & (t >= people.start) & (s < length)
    vel = jnp.where(walking[:, None], unit * people.speed[:, None], 0.0)
    heading = jnp.where(moving, jnp.arctan2(unit[:, 1], unit[:, 0]), people.facing)
    phase = jnp.mod(math.pi * pedestrians.cadence(people.speed, gait) * s
                    / jnp.maximum(people.speed, 1e-9), 2 * math.pi)
    zero = jnp.zeros_like(people.speed)
    return pedestrians.PedestrianState(
        pos=pos, vel=vel, heading=heading, phase=jnp.where(walking, phase, 0.0),
        mask=people.mask, goal=w[:, 2], speed=people.speed, stop_timer=zero, goal_timer=zero,
        crossing=jnp.zeros_like(people.mask))


def static_scene(cfg: CrowdConfig, dtype=jnp.float32) -> kinect.Primitives:
    """The room's walls, plus in "obstacles" its tables and chairs, a whiteboard on two legs
    (1.2 x 0.9 m board from 1.0 to 1.9 m) and a coat stand (a 1.75 m pole under a 0.15 m
    knob with coats)."""
    if cfg.scenario != "obstacles":
        empty = layout_mod.Layout("room", _ROOM, ())
        return kinect.layout_primitives(empty, dtype=dtype)
    base = kinect.layout_primitives(layout_mod.room(_ROOM), dtype=dtype)
    f = lambda x: jnp.asarray(np.asarray(x, float), dtype)  # noqa: E731
    extra = kinect.Primitives(
        capsule_a=f([[2.8, -2.0, 0.0], [2.8, -0.8, 0.0], [1.5, 2.4, 0.0], [1.5, 2.4, 1.45]]),
        capsule_b=f([[2.8, -2.0, 1.9], [2.8, -0.8, 1.9], [1.5, 2.4, 1.75], [1.5, 2.4, 1.45]]),
        capsule_radius=f([0.02, 0.02, 0.025, 0.2]),
        capsule_colour=f([[0.6, 0.6, 0.6], [0.6, 0.6, 0.6], [0.3, 0.2, 0.1], [0.2, 0.25, 0.3]]),
        box_centre=f([[2.8, -1.4, 1.45]]), box_half=f([[0.02, 0.6, 0.45]]),
        box_yaw=f([0.0]), box_colour=f([[0.95, 0.95, 0.97]]), floor_colour=base.floor_colour)
    return kinect.concat(base, extra)


class Sensed(NamedTuple):
    """One Kinect frame (`sense`): the clean render, the measured depth and its mask, the noisy
    colour image, the cloud in the robot's base frame, the camera in the world frame."""

    image: kinect.Frame
    depth: Array
    valid: Array
    colour: Array
    points: Array
    points_ok: Array
    points_rgb: Array
    eye: Array
    rot: Array


def sense(key: Array, cfg: CrowdConfig, robot: Array, crowd: pedestrians.PedestrianState,
          people: People, scene: kinect.Primitives) -> Sensed:
    """Render the people and the room from the robot's Kinect, measure the depth, add colour
    noise and back-project into the robot's base frame."""
    cam = cfg.camera
    k_depth, k_rgb = jax.random.split(key)
    prims = kinect.concat(kinect.people_primitives(crowd, people.stature, people.clothing), scene)
    eye, rot = kinect.camera_pose(cam, robot)
    image = kinect.render(cam, eye, rot, prims)
    depth, valid = kinect.measure(k_depth, cam, image.depth)
    colour = jnp.clip(image.colour + cfg.colour_noise
                      * jax.random.normal(k_rgb, image.colour.shape, image.colour.dtype), 0.0, 1.0)
    eye_b, rot_b = kinect.mount_pose(cam, 0.0, robot.dtype)
    pts, ok, rgb = kinect.point_cloud(cam, depth, valid, eye_b, rot_b, colour)
    return Sensed(image, depth, valid, colour, pts, ok, rgb, eye, rot)


def base_camera(cfg: CrowdConfig, dtype=jnp.float32) -> hog.PinholeCamera:
    """The Kinect as a pinhole camera in the robot's base frame (for the HOG boxes)."""
    cam = cfg.camera
    eye_b, rot_b = kinect.mount_pose(cam, 0.0, dtype)
    fx, fy = cam.focal
    return hog.PinholeCamera(jnp.asarray([fx, fy], dtype),
                             jnp.asarray([0.5 * cam.width, 0.5 * cam.height], dtype), eye_b, rot_b)


def to_world(robot: Array, xy: Array) -> Array:
    """[N, 2] robot-frame points in the world frame."""
    c, s = jnp.cos(robot[2]), jnp.sin(robot[2])
    return jnp.stack([c * xy[:, 0] - s * xy[:, 1], s * xy[:, 0] + c * xy[:, 1]], -1) + robot[:2]


def _person_pixels(cfg, hit, valid, P):
    """[P] pixels with a depth showing each person (`kinect.people_primitives` puts their 6
    capsules first: capsule ``k * P + p`` is person ``p``'s)."""
    h = jnp.where(valid, hit, -1).reshape(-1)
    who = jnp.where((h >= 0) & (h < 6 * P), h % P, P)
    return jax.ops.segment_sum(jnp.ones_like(h), who, P + 1)[:P]


def _in_view(cam, eye, rot, xy, margin=0.3):
    """[N] people standing at ground points ``xy`` whose bodies (``margin`` around the point)
    reach into the camera's horizontal field of view and depth range."""
    axis = rot[:2, 2] / jnp.maximum(jnp.linalg.norm(rot[:2, 2]), 1e-9)
    rel = xy - eye[:2]
    along = rel @ axis
    across = rel @ jnp.stack([-axis[1], axis[0]])
    rng = jnp.linalg.norm(rel, axis=-1)
    return (jnp.abs(across) <= along * math.tan(0.5 * cam.fov_x) + margin) \
        & (rng >= cam.min_range - margin) & (rng <= cam.max_range + margin)


def _expected_pixels(cam, depth, stature):
    """Pixels of an unoccluded person at ``depth`` along the axis: a 0.45 m x stature
    silhouette filling 75 % of its box."""
    fx, fy = cam.focal
    return 0.75 * fx * fy * 0.45 * stature / jnp.maximum(depth, 0.3) ** 2


def frames(key: Array, cfg: CrowdConfig, pipeline: Pipeline, svm: hog.LinearSVM | None,
           dtype=jnp.float32):
    """Run one episode and return its per-frame record (dict of [T, ...] arrays): truth, the
    detector's output and the tracks. `episode` scores it."""
    P, T, dt = cfg.max_people, cfg.num_frames, 1.0 / cfg.rate
    cam = cfg.camera
    k_people, k_robot, k_run = jax.random.split(key, 3)
    people = sample_people(k_people, cfg, dtype)
    y0 = jax.random.uniform(k_robot, (), dtype, -0.5, 0.5)
    scene = static_scene(cfg, dtype)
    dcfg = pipeline.detector()
    params = pipeline.tracker(cfg, dtype)
    det_state = rgbd_people.init_state(dcfg, dtype=dtype)
    tracks = tracking.init(params.config, dtype)
    camera = base_camera(cfg, dtype)

    def frame(carry, inputs):
        det_state, tracks = carry
        i, k = inputs
        t = i * dt
        # World step.
        robot = jnp.stack([-3.8 + cfg.robot_speed * t, y0, jnp.zeros((), dtype)]).astype(dtype)
        crowd = people_at(people, t)
        # Sense.
        k_sense, k_det = jax.random.split(k)
        z = sense(k_sense, cfg, robot, crowd, people, scene)
        det_state, seen = rgbd_people.detect(dcfg, det_state, k_det, z.points, z.points_ok,
                                             z.points_rgb, camera.position, image=z.colour,
                                             camera=camera, svm=svm)
        # Who is visible (the ground truth of the scores, and the oracle's detections).
        eye, rot = z.eye, z.rot
        rel = crowd.pos - eye[:2]
        along = rel @ rot[:2, 2] / jnp.maximum(jnp.linalg.norm(rot[:2, 2]), 1e-9)
        shown = _person_pixels(cam, z.image.hit, z.valid, P)
        visible = people.mask & (shown >= cfg.min_visible
                                 * _expected_pixels(cam, along, people.stature))
        # Estimate (world frame: the robot's odometry is perfect).
        if pipeline.oracle:
            # (k_det's other use, the detector's RANSAC, feeds nothing the oracle returns)
            noise = pipeline.oracle_noise * jax.random.normal(k_det, crowd.pos.shape, dtype)
            world = (crowd.pos + noise).astype(dtype)
            kept = visible
            confidence = jnp.ones(P, dtype)
        else:
            world = to_world(robot, seen.people.position[:, :2])
            kept = seen.people.mask & (seen.confidence >= (pipeline.min_confidence
                                                            if pipeline.confidence else 0.0))
            confidence = seen.confidence
        dets = tracking.Detections(world, kept,
                                   jnp.zeros(world.shape[0], jnp.int32), confidence,
                                   seen.histograms if pipeline.appearance
                                   else jnp.zeros((world.shape[0], 0), dtype))
        tracks = tracking.step(tracks, dets, params)
        # Record.
        confirmed = tracks.status == tracking.CONFIRMED
        in_view = _in_view(cam, eye, rot, crowd.pos)
        partial = people.mask & ~visible & (in_view | (shown > 0))
        shown_track = confirmed & _in_view(cam, eye, rot, tracks.mean[:, :2])
        rec = dict(truth=crowd.pos, visible=visible, partial=partial, detections=world,
                   det_mask=dets.mask,
                   confidence=confidence, track_pos=tracks.mean[:, :2],
                   track_id=jnp.where(shown_track, tracks.id, -1), track_mask=shown_track,
                   track_misses=tracks.misses, robot=robot)
        return (det_state, tracks), rec

    keys = jax.random.split(k_run, T)
    _, rec = lax.scan(frame, (det_state, tracks), (jnp.arange(T, dtype=dtype), keys))
    return rec


def episode(key: Array, cfg: CrowdConfig, pipeline: Pipeline, svm: hog.LinearSVM | None,
            dtype=jnp.float32) -> dict:
    """One episode's scores: CLEAR MOT of the confirmed tracks (MOTA, MOTP in metres,
    id switches, false positives and misses), and the detector's precision and recall, all
    against the visible people within ``match_distance``.

    Example:
      >>> out = jax.jit(episode, static_argnums=(1, 2))(key, CrowdConfig(), Pipeline(), svm)
    """
    return score(cfg, frames(key, cfg, pipeline, svm, dtype))


def score(cfg: CrowdConfig, rec: dict) -> dict:
    """An episode's scores (`episode`) from its record (`frames`)."""
    T, P = rec["visible"].shape
    gt_ids = jnp.where(rec["visible"], jnp.arange(P)[None], -1)
    track_mask = _not_ignored(rec, rec["track_pos"], rec["track_mask"], cfg.match_distance)
    mot = metrics.clear_mot(gt_ids, rec["truth"], rec["visible"], rec["track_id"],
                            rec["track_pos"], track_mask, cfg.match_distance, num_ids=P)
    M = rec["det_mask"].shape[1]
    det_mask = _not_ignored(rec, rec["detections"], rec["det_mask"], cfg.match_distance)
    det_ids = jnp.where(det_mask, jnp.arange(M)[None], -1)
    det = metrics.clear_mot(gt_ids, rec["truth"], rec["visible"], det_ids, rec["detections"],
                            det_mask, cfg.match_distance, num_ids=P)
    return dict(mota=mot.mota, motp=mot.motp, id_switches=mot.num_switches,
                false_positives=mot.num_false_positives, misses=mot.num_misses,
                objects=mot.num_objects, matches=mot.num_matches,
                det_matches=det.num_matches, det_false_positives=det.num_false_positives,
                det_misses=det.num_misses,
                det_precision=det.precision, det_recall=det.recall)


def _not_ignored(rec, pos, mask, radius):
    """Drop the outputs near a partly visible person and near no visible one: neither a hit
    nor a false positive (MOTChallenge's ignored ground truth)."""
    d = jnp.linalg.norm(pos[:, :, None, :] - rec["truth"][:, None, :, :], axis=-1)  # [T, H, P]
    near_partial = jnp.any((d < radius) & rec["partial"][:, None, :], -1)
    near_visible = jnp.any((d < radius) & rec["visible"][:, None, :], -1)
    return mask & ~(near_partial & ~near_visible)


def training_crops(key: Array, cfg: CrowdConfig, num_frames: int, dtype=jnp.float32):
    """HOG features of labelled crops for training the confidence's SVM, from ``num_frames``
    frames spread over random episodes: every detection's theoretical box (positive when a
    visible person is within 0.3 m) and two random boxes per frame (negatives, as Dalal and
    Triggs draw from person-free images, but checked against every person's box).

    Returns:
      (features [N, 3780], labels [N] in {0, 1}, valid [N]) as numpy arrays.
    """
    cam = cfg.camera
    dcfg = Pipeline().detector()
    camera = base_camera(cfg, dtype)

    @jax.jit
    def one(k):
        kp, kt, kr, kd, kb, ks = jax.random.split(k, 6)
        people = sample_people(kp, cfg, dtype)
        t = jax.random.uniform(kt, (), dtype, 0.0, cfg.duration)
        robot = jnp.stack([-3.8 + cfg.robot_speed * t, jax.random.uniform(kr, (), dtype,
                                                                           -0.5, 0.5), 0.0])
        crowd = people_at(people, t)
        z = sense(ks, cfg, robot.astype(dtype), crowd, people, static_scene(cfg, dtype))
        _, seen = rgbd_people.detect(dcfg, rgbd_people.init_state(dcfg, dtype=dtype), kd,
                                     z.points, z.points_ok, z.points_rgb, camera.position,
                                     camera=camera)
        world = to_world(robot, seen.people.position[:, :2])
        eye, rot, colour = z.eye, z.rot, z.colour
        rel = crowd.pos - eye[:2]
        shown = _person_pixels(cam, z.image.hit, z.valid, cfg.max_people)
        along = rel @ rot[:2, 2] / jnp.maximum(jnp.linalg.norm(rot[:2, 2]), 1e-9)
        visible = people.mask & (shown >= cfg.min_visible
                                 * _expected_pixels(cam, along, people.stature))
        d = jnp.linalg.norm(world[:, None] - crowd.pos[None], axis=-1)
        label = jnp.any((d < 0.3) & visible[None], axis=1)
        # Random negatives: boxes of person size anywhere, not overlapping a person's box much.
        h = jax.random.uniform(kb, (2,), dtype, 0.3 * cam.height, 1.0 * cam.height)
        top = jax.random.uniform(jax.random.fold_in(kb, 1), (2,), dtype, -0.2 * cam.height,
                                 cam.height - 0.5 * h)
        left = jax.random.uniform(jax.random.fold_in(kb, 2), (2,), dtype, -0.2 * cam.width,
                                  cam.width - 0.3 * h)
        rand = jnp.stack([top, left, top + h, left + 0.5 * h], -1)
        boxes = jnp.concatenate([seen.boxes, rand])
        feats = hog.descriptors(colour, boxes)
        # A random box is a negative unless it covers a person's foot point.
        feet, _ = hog.project(hog.PinholeCamera(camera.focal, camera.principal, eye, rot),
                              jnp.concatenate([crowd.pos, jnp.zeros((cfg.max_people, 1),
                                                                    dtype)], -1))
        inside = ((feet[None, :, 0] > rand[:, None, 1]) & (feet[None, :, 0] < rand[:, None, 3])
                  & (feet[None, :, 1] > rand[:, None, 0]) & (feet[None, :, 1] < rand[:, None, 2])
                  & visible[None])
        labels = jnp.concatenate([label, jnp.zeros(2, bool)])
        ok_rows = jnp.concatenate([seen.people.mask, ~jnp.any(inside, 1)])
        return feats, labels, ok_rows

    out = [one(k) for k in jax.random.split(key, num_frames)]
    feats = np.concatenate([np.asarray(o[0]) for o in out])
    labels = np.concatenate([np.asarray(o[1]) for o in out])
    valid = np.concatenate([np.asarray(o[2]) for o in out])
    return feats, labels.astype(np.int32), valid
