"""Command line: ``jaxtrack demo``, ``jaxtrack run humanoid-reach``, ``jaxtrack run
person-following``, ``jaxtrack run rgbd-people``, ``jaxtrack track``, ``jaxtrack evaluate``,
``jaxtrack train-legs``, ``jaxtrack train-hog`` and ``jaxtrack run service``.

The console command lives in `sims`, the top layer, so that importing `jaxtrack` never imports
MuJoCo; only the ``run`` commands and the scene demos import it. ``demo`` (``all``, ``humanoid``
or ``following``) dispatches to `sims.demo.run`, ``demo filters`` to `jaxtrack.demo.run`, ``run
humanoid-reach`` to `run_humanoid_reach`, ``run person-following`` to
`sims.following.report.run_person_following`, ``track`` (the sensing step and a user estimator
replayed on a ROS bag) to `jaxtrack.io.replay.track_bag` (``--depth-topic``:
`jaxtrack.io.depth_replay.track_depth_bag`; ``--cloud-topic`` / ``--rgbd-topics``:
`jaxtrack.io.rgbd_replay.track_rgbd_bag`), ``evaluate`` (CLEAR MOT of a tracks
file against ground truth) to `jaxtrack.io.trajectories.evaluate_files`, ``run rgbd-people``
and ``train-hog`` to `sims.following.crowd_report`, ``run service`` to
`sims.service.report.run_service`.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import io
import math
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["main", "run_humanoid_reach", "task_table", "TASK_NAMES"]

_HEADINGS = (-90, -45, 0, 45, 90)
_PATHS = ("P1 forward", "P2 lateral", "P3 diagonal")
# The seed's 15 task labels, in `jaxtrack.control.pose.seed_tasks` order.
TASK_NAMES = tuple(f"{p.split()[0]} {h:+d}" for p in _PATHS for h in _HEADINGS)


def main(argv: list[str] | None = None) -> int:
    from jaxtrack.tracking import user

    estimators = tuple(user.CONFIGS)
    parser = argparse.ArgumentParser(prog="jaxtrack", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="both scenes' closed-loop Monte-Carlo evaluations at a "
                                       "small size (75 s or so on two cores), "
                                       "or the KF / EKF / UKF filter demo")
    demo.add_argument("which", nargs="?", choices=("all", "humanoid", "following", "filters"),
                      default="all",
                      help="all (default): the humanoid reach and person following scenes; "
                           "humanoid or following: one of them; filters: KF / EKF / UKF over "
                           "many vmapped episodes, accuracy and speed table (no MuJoCo)")
    demo.add_argument("--episodes", type=int, default=None,
                      help="filters only: episodes (default 1000)")
    demo.add_argument("--steps", type=int, default=None,
                      help="filters only: steps per episode (default 200)")
    demo.add_argument("--seed", type=int, default=0)
    run = sub.add_parser("run", help="run a simulated closed-loop evaluation")
    scenes = run.add_subparsers(dest="scene", required=True)
    reach = scenes.add_parser("humanoid-reach", help="seed 000: a NAO-sized humanoid walks to "
                              "the 15 target poses under a zenithal depth camera")
    reach.add_argument("--episodes", type=int, default=64, help="episodes per task")
    reach.add_argument("--tracker", choices=("pf", "pf3", "ukf"), default="pf")
    reach.add_argument("--out", type=Path, default=None, help="directory for plots and metrics")
    reach.add_argument("--seed", type=int, default=0)
    reach.add_argument("--particles", type=int, default=128)
    reach.add_argument("--frames", type=int, default=200)
    reach.add_argument("--resolution", type=int, nargs=2, default=(80, 60),
                       metavar=("WIDTH", "HEIGHT"))
    reach.add_argument("--lambda-x", type=float, default=0.1,
                       help="controller position gain (1/s)")
    reach.add_argument("--lambda-theta", type=float, default=0.2,
                       help="controller heading gain (1/s)")
    reach.add_argument("--position-noise", type=float, default=0.035,
                       help="tracker propagation std per frame (m)")
    reach.add_argument("--temperature", type=float, default=None,
                       help="tempered likelihood weight exp(n / T) (pf, pf3); default: the "
                            "seed's weight log(n + 1)")
    reach.add_argument("--turn-prediction", action="store_true",
                       help="predict the PCA heading with the commanded turn (pf, ukf)")
    reach.add_argument("--heading-gain", type=float, default=0.5,
                       help="smoothing gain of the PCA heading, in (0, 1]")
    reach.add_argument("--walkers", type=int, default=0,
                       help="people pacing near the robot, occluding it from the camera "
                            "(seed 000 section 5.6)")
    reach.add_argument("--objects", type=int, default=0,
                       help="boxes on the floor beside the route, in the camera's view "
                            "(seed 000 section 5.6)")
    reach.add_argument("--unknown-objects", action="store_true",
                       help="with --objects: the camera's background image holds only the "
                            "floor, so the objects' points enter the robot's cloud (default: "
                            "they are background, stored before the robot entered)")
    reach.add_argument("--planner", choices=("dcm", "preview-qp"), default="dcm",
                       help="footstep planner of the walking pattern generator: the deadbeat "
                            "DCM planner or Herdt et al.'s preview QP")
    routes = scenes.add_parser("humanoid-routes", add_help=False,
                               help="seed 000, Experiment 1: the humanoid walks three routes "
                                    "open loop, tracked by the depth and the colour particle "
                                    "filter (options: jaxtrack run humanoid-routes --help)")
    routes.add_argument("routes_args", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    follow = scenes.add_parser("person-following", help="seeds 001-004: a wheeled robot follows "
                               "its user among other people (laser legs + RGB-D)")
    follow.add_argument("--episodes", type=int, default=256)
    follow.add_argument("--estimator", choices=estimators, default="pf")
    follow.add_argument("--follower", choices=("A", "B"), default="A",
                        help="follower point: A = (1.5, 0), B = (1, 1) m in the robot frame")
    follow.add_argument("--people", type=int, default=4, help="distractors besides the user")
    follow.add_argument("--sensors", choices=("both", "laser", "rgbd"), default="both")
    follow.add_argument("--appearance", action="store_true",
                        help="use the RGB-D colour feature: the multi-target estimators "
                             "re-identify the user by it, and GNN adds seed 001's colour "
                             "classifier term to its cost")
    follow.add_argument("--layout", choices=("shop", "room"), default="shop",
                        help="shop: shelves and aisles, a shopper who leads (default); room: a "
                             "furnished room with wandering people")
    follow.add_argument("--user", choices=("shopper", "wander"), default="shopper",
                        help="in the shop, the user shops (default) or wanders (a stress test)")
    follow.add_argument("--animate", action="store_true",
                        help="with --out, also write an animation of the first episode")
    follow.add_argument("--duration", type=float, default=60.0, help="seconds per episode")
    follow.add_argument("--particles", type=int, default=256)
    follow.add_argument("--batch-size", type=int, default=None)
    follow.add_argument("--out", type=Path, default=None, help="directory for plots and metrics")
    follow.add_argument("--seed", type=int, default=0)
    rgbd = scenes.add_parser("rgbd-people", help="seed 001: a robot drives among 2-6 people "
                             "and tracks them with its Kinect (voxel grid, ground plane, "
                             "head sub-clustering, HOG, GNN); the full pipeline and its "
                             "ablations")
    rgbd.add_argument("--episodes", type=int, default=32, help="episodes per pipeline")
    rgbd.add_argument("--scenario", choices=("simple", "complex", "obstacles"),
                      default="complex")
    rgbd.add_argument("--duration", type=float, default=20.0, help="seconds per episode")
    rgbd.add_argument("--resolution", type=int, nargs=2, default=(160, 120),
                      metavar=("WIDTH", "HEIGHT"),
                      help="Kinect image size (seed 001 acquired 160 x 120; QVGA 320 240)")
    rgbd.add_argument("--ablations", nargs="+", default=None,
                      choices=("full", "no-sub-clustering", "no-velocity", "no-appearance",
                               "no-confidence", "perfect-detections", "noisy-truth"),
                      help="pipelines to run (default: the full one and its four ablations; "
                           "perfect-detections and noisy-truth feed the tracker the visible "
                           "people's true positions, exact or with 0.1 m noise: its floor)")
    rgbd.add_argument("--batch-size", type=int, default=None)
    rgbd.add_argument("--out", type=Path, default=None,
                      help="directory for the table, the metrics and a figure of one frame")
    rgbd.add_argument("--seed", type=int, default=0)
    svc = scenes.add_parser("service", help="seeds 002-003: a service robot in a flat among "
                            "people (ceiling cameras + RGB-D + laser, NN-JPDA, person costmaps "
                            "and a grid planner; seed 002's approach)")
    svc.add_argument("--experiment", required=True,
                     choices=("avoid", "overtake", "tv", "handover", "approach"))
    svc.add_argument("--episodes", type=int, default=256)
    svc.add_argument("--duration", type=float, default=60.0, help="seconds per episode")
    svc.add_argument("--perception", choices=("all", "ceiling", "robot", "truth"),
                     default="all", help="what the robot's tracker is fed")
    svc.add_argument("--compare-sensors", action="store_true",
                     help="also track with the ceiling cameras only and the robot only, and "
                          "compare their MOTA with all sensors'")
    svc.add_argument("--interest", default="0.5",
                     help="approach: the person interest (0-1), or 'estimated'")
    svc.add_argument("--heading-filter", choices=("ar", "windowed", "sustained"),
                     default=None,
                     help="approach: seed 002's AR heading filter on the velocity (default), "
                          "the windowed one that holds the heading through short steps, or "
                          "the sustained one that also holds it through steps in a row; "
                          "handover: the waiting person's heading from their track's velocity "
                          "(ar) or from that filter on its positions (default: sustained)")
    svc.add_argument("--pan", action="store_true",
                     help="approach: the RGB-D camera on its pan unit, turned to the person")
    svc.add_argument("--reverse", action="store_true",
                     help="approach: the robot may drive backwards down the field, its front "
                          "and sensors towards the person")
    svc.add_argument("--settle", type=int, default=0, metavar="ITERATIONS",
                     help="approach: drive to where the field's gradient flow settles (found "
                          "with this many descent steps a frame) instead of along the gradient")
    svc.add_argument("--heading-frame", choices=("odom", "map"), default="odom",
                     help="approach: keep the person's heading in the odometry frame (seed "
                          "002) or in the map frame the robot is localised in")
    svc.add_argument("--still-at-end", type=float, default=0.0, metavar="SECONDS",
                     help="approach: nobody starts a step in the last SECONDS, so the final "
                          "pose is judged once the person has stood still that long")
    svc.add_argument("--line-of-sight", action="store_true",
                     help="drop the RGB-D detections behind the laser's range on their bearing "
                          "(behind a wall or a person)")
    svc.add_argument("--births", choices=("corroborated", "any"), default="corroborated",
                     help="where no ceiling camera sees, an RGB-D detection starts a track only "
                          "with a laser detection beside it (corroborated), or always (any)")
    svc.add_argument("--replan-every", type=int, default=None, metavar="FRAMES",
                     help="navigation: frames between full solves of the planner's distance "
                          "field, refined in the frames between (fewer solves run faster; "
                          "default: the scene's, 20)")
    svc.add_argument("--cell", type=float, default=0.1, metavar="METRES",
                     help="navigation: the costmap's and planner's cell size (0.05-0.5; 0.2 "
                          "runs about 1.4 times as fast)")
    svc.add_argument("--batch-size", type=int, default=None)
    svc.add_argument("--animate", action="store_true",
                     help="with --out, also write an animation of the first episode")
    svc.add_argument("--out", type=Path, default=None, help="directory for plots and metrics")
    svc.add_argument("--seed", type=int, default=0)
    th = sub.add_parser("train-hog", help="train the RGB-D detector's HOG + linear SVM person "
                                          "confidence on simulated Kinect crops")
    th.add_argument("--frames", type=int, default=1500, help="simulated frames (all scenarios)")
    th.add_argument("--out", type=Path, required=True, help=".npz to write (the shipped one is "
                    "jaxtrack/perception/data/hog_svm.npz)")
    th.add_argument("--seed", type=int, default=0)
    th.add_argument("--c", type=float, default=0.01, help="the SVM's C (Dalal and Triggs: 0.01)")
    trk = sub.add_parser("track", help="replay leg detection + a tracker on a ROS 1 / ROS 2 bag; "
                                       "writes tracks.csv and top_view.png")
    trk.add_argument("--bag", type=Path, required=True,
                     help=".bag file or ROS 2 bag directory")
    trk.add_argument("--laser-topic", default=None, nargs="+",
                     help="sensor_msgs/LaserScan topic; several topics (one per laser of the "
                          "robot) are fused, the first one's scans being the frames")
    trk.add_argument("--laser-mount", nargs=3, type=float, action="append", default=None,
                     metavar=("X", "Y", "YAW"),
                     help="a laser's pose on the robot (m, m, rad), once per --laser-topic, in "
                          "the same order (default: at the origin, facing ahead)")
    trk.add_argument("--detections-topic", default=None,
                     help="geometry_msgs/PoseArray or people_msgs/PositionMeasurementArray "
                          "topic (robot frame)")
    trk.add_argument("--odom-topic", default=None, help="nav_msgs/Odometry topic")
    trk.add_argument("--tf-frames", nargs=2, default=None, metavar=("PARENT", "CHILD"),
                     help="odometry from the transform tree (/tf, /tf_static) instead: the "
                          "pose of CHILD (e.g. base_link) in PARENT (e.g. odom)")
    trk.add_argument("--pan-topic", default=None,
                     help="sensor_msgs/JointState topic of the RGB-D camera's pan unit")
    trk.add_argument("--pan-joint", default="camera_pan", help="the pan joint's name")
    trk.add_argument("--estimator", choices=tuple(e for e in estimators if e != "truth"),
                     default="gnn")
    trk.add_argument("--chunk", type=int, default=64, help="frames per compiled scan")
    trk.add_argument("--max-detections", type=int, default=16)
    trk.add_argument("--time-source", choices=("header", "bag"), default="header")
    trk.add_argument("--static-points", type=Path, default=None,
                     help="text file of 'x y' rows (odometry frame): table and chair legs "
                          "from a map; laser people within 0.3 m of one are dropped")
    trk.add_argument("--detector", default="learned",
                     help="leg detector: 'learned' (the shipped classifier), 'geometric', or a "
                          "model file of `jaxtrack train-legs`")
    trk.add_argument("--gt-topic", default=None,
                     help="people ground truth in the bag (a list of entries with an id and a "
                          "position, any message type the bag defines), in the tracks' frame: "
                          "written as gt.csv and scored against the tracks")
    trk.add_argument("--gt-threshold", type=float, default=0.5,
                     help="match distance of the scoring (m)")
    trk.add_argument("--target-only", action="store_true",
                     help="only the followed person is labelled in --gt-topic: tracks away "
                          "from every labelled person are not false positives")
    trk.add_argument("--animate", action="store_true",
                     help="also write an animated top view, replay.gif")
    trk.add_argument("--seed", type=int, default=0)
    trk.add_argument("--depth-topic", default=None,
                     help="instead of --laser-topic: sensor_msgs/Image depth images (16UC1 / "
                          "32FC1) of a ceiling camera looking down on a humanoid; writes "
                          "trajectory.csv")
    trk.add_argument("--camera-position", nargs=3, type=float, default=None,
                     metavar=("X", "Y", "Z"), help="with --depth-topic: the camera's optical "
                                                   "centre (m; Z its height above the floor)")
    trk.add_argument("--cloud-topic", default=None,
                     help="instead of --laser-topic: sensor_msgs/PointCloud2 of an RGB-D "
                          "camera on the robot; people detected (seed 001) and tracked")
    trk.add_argument("--rgbd-topics", nargs=2, default=None, metavar=("DEPTH", "COLOUR"),
                     help="instead of --laser-topic: registered depth (16UC1 / 32FC1) and "
                          "colour (rgb8, bgr8, rgba8, bgra8, mono8) sensor_msgs/Image topics "
                          "of an RGB-D camera on the robot, paired by nearest time; needs "
                          "--focal")
    trk.add_argument("--mount", nargs=3, type=float, default=None, metavar=("X", "Y", "Z"),
                     help="with --cloud-topic / --rgbd-topics: the camera's optical centre in "
                          "the robot's base frame (m; x forward, y left, z up)")
    trk.add_argument("--tilt", type=float, default=0.0,
                     help="with --cloud-topic / --rgbd-topics: the camera's downward pitch "
                          "(degrees)")
    trk.add_argument("--cloud-frame", choices=("optical", "base"), default="optical",
                     help="with --cloud-topic: the clouds' frame, the camera's optical frame "
                          "(x right, y down, z forward) or already the robot's base frame")
    trk.add_argument("--min-confidence", type=float, default=0.5,
                     help="with --cloud-topic / --rgbd-topics: detections with a lower HOG "
                          "confidence are not tracked")
    trk.add_argument("--focal", nargs=2, type=float, default=None, metavar=("FX", "FY"),
                     help="with --depth-topic or --rgbd-topics: focal lengths (pixels); with "
                          "--cloud-topic, an organised cloud's, for the HOG confidence")
    trk.add_argument("--principal", nargs=2, type=float, default=None, metavar=("CX", "CY"),
                     help="with --focal: principal point from the image's corner "
                          "(pixels; ROS CameraInfo K[0,2] + 0.5, K[1,2] + 0.5); default the "
                          "image centre")
    trk.add_argument("--start", nargs=3, type=float, default=None,
                     metavar=("X", "Y", "HEADING"),
                     help="with --depth-topic: the humanoid's initial pose (default the "
                          "first image's points, heading 0)")
    trk.add_argument("--tracker", choices=("pf", "pf3", "ukf"), default="pf",
                     help="with --depth-topic: the humanoid tracker")
    trk.add_argument("--max-points", type=int, default=None,
                     help="with --depth-topic: the highest points the tracker is given "
                          "(default 96); with --cloud-topic: points per cloud (default the "
                          "largest cloud's)")
    trk.add_argument("--max-height", type=float, default=None,
                     help="with --depth-topic: points higher than this (m) are not the "
                          "robot's (people walking by); default no limit")
    trk.add_argument("--out", type=Path, required=True, help="output directory")
    tl = sub.add_parser("train-legs", help="train the learned leg detector (a random forest "
                                           "over scan-segment features) on recorded bags; "
                                           "needs scikit-learn (pip install 'jaxtrack[train]')")
    tl.add_argument("--positive", type=Path, nargs="+", required=True,
                    help="bags with scans and labelled leg positions (PoseArray)")
    tl.add_argument("--negative", type=Path, nargs="*", default=[],
                    help="bags of scans without people (every segment a non-leg)")
    tl.add_argument("--out", type=Path, required=True, help="model file to write (.npz)")
    tl.add_argument("--scan-topic", default="/training_scan",
                    help="LaserScan topic of the positive bags")
    tl.add_argument("--labels-topic", default="/leg_cluster_positions",
                    help="PoseArray topic of the leg labels (each labels the next scan)")
    tl.add_argument("--negative-topics", nargs="+", default=None,
                    help="LaserScan topics of the negative bags (default: all of them)")
    tl.add_argument("--jump", type=float, default=0.13, help="segment break distance (m)")
    tl.add_argument("--match-radius", type=float, default=0.15,
                    help="a segment is a leg within this distance of a label (m)")
    tl.add_argument("--trees", type=int, default=48)
    tl.add_argument("--depth", type=int, default=16)
    tl.add_argument("--seed", type=int, default=0)
    ev = sub.add_parser("evaluate", help="py-motmetrics' MOTChallenge summary (CLEAR MOT, IDF1, "
                                         "HOTA) of tracks files against ground truth")
    ev.add_argument("--gt", type=Path, nargs="+", required=True,
                    help="ground truth per sequence (obsmat.txt, frame id x y, MOT CSV, or "
                         "image-plane MOTChallenge gt.txt)")
    ev.add_argument("--tracks", type=Path, nargs="+", required=True,
                    help="tracks per sequence, in the order of --gt")
    ev.add_argument("--names", nargs="+", default=None,
                    help="sequence names (default: each ground truth's folder)")
    ev.add_argument("--threshold", type=float, default=0.5,
                    help="match distance: metres on the ground plane, 1 - IoU for image boxes")
    ev.add_argument("--format", choices=("auto", "obsmat", "plain", "mot", "mot2d"),
                    default="auto", help="format of every file (auto: sniffed per file)")
    ev.add_argument("--zero-distance", type=float, default=2.0,
                    help="HOTA on the ground plane: the distance of similarity 0 (m)")
    ev.add_argument("--min-confidence", type=float, default=None,
                    help="image-plane ground truth: drop boxes whose conf is below it "
                         "(MOTChallenge: 1)")
    ev.add_argument("--target-only", action="store_true",
                    help="only the followed person is labelled: tracks farther than the "
                         "threshold from every labelled person are not false positives")
    ev.add_argument("--out", type=Path, default=None,
                    help="directory for summary.csv and summary.json")
    # `run humanoid-routes` hands its options to `sims.humanoid.routes.main`, which parses
    # them (argparse's REMAINDER does not take a first argument that starts with "-")
    args, extra = parser.parse_known_args(argv)
    if extra and getattr(args, "scene", None) != "humanoid-routes":
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    if args.command == "track" and (args.cloud_topic or args.rgbd_topics):
        return _track_rgbd(parser, args)
    if args.command == "track" and args.depth_topic:
        return _track_depth(parser, args)
    if args.command == "track":
        if not args.laser_topic:
            parser.error("give --laser-topic (laser scans), --depth-topic (depth images), "
                         "--cloud-topic (point clouds) or --rgbd-topics (depth + colour "
                         "images)")
        if args.chunk < 1 or args.max_detections < 1:
            parser.error("--chunk and --max-detections must be positive")
        if not args.bag.exists():
            parser.error(f"--bag {args.bag} does not exist")
        if args.odom_topic and args.tf_frames:
            parser.error("give --odom-topic or --tf-frames, not both")
        if args.laser_mount is not None:
            if len(args.laser_mount) != len(args.laser_topic):
                parser.error(f"{len(args.laser_mount)} --laser-mount for "
                             f"{len(args.laser_topic)} --laser-topic")
            if not all(math.isfinite(v) for m in args.laser_mount for v in m):
                parser.error("--laser-mount values must be finite")
        if not (math.isfinite(args.gt_threshold) and args.gt_threshold > 0):
            parser.error(f"--gt-threshold must be positive; got {args.gt_threshold}")
        if args.target_only and not args.gt_topic:
            parser.error("--target-only needs --gt-topic")
        if args.static_points is not None:
            _check_points_file(parser, args.static_points)
        if args.detector not in ("learned", "geometric"):
            from jaxtrack.perception import leg_classifier

            try:
                leg_classifier.load(args.detector)
            except (OSError, ValueError) as err:
                parser.error(f"--detector {args.detector}: {err}")
        _check_writable(parser, args.out)
        from jaxtrack.io import bags
        from jaxtrack.io.replay import track_bag

        try:
            topics = args.laser_topic[0] if len(args.laser_topic) == 1 else args.laser_topic
            track_bag(args.bag, topics, args.out, laser_mounts=args.laser_mount,
                      detections_topic=args.detections_topic, odom_topic=args.odom_topic,
                      estimator=args.estimator, chunk=args.chunk,
                      max_detections=args.max_detections, seed=args.seed,
                      time_source=args.time_source, static_points=args.static_points,
                      pan_topic=args.pan_topic, pan_joint=args.pan_joint,
                      detector=args.detector, animate=args.animate,
                      tf_frames=tuple(args.tf_frames) if args.tf_frames else None,
                      gt_topic=args.gt_topic, gt_threshold=args.gt_threshold,
                      target_only=args.target_only)
        except bags.BagError as err:
            parser.exit(2, f"jaxtrack track: {err}\n")
        except ImportError as err:
            if "rosbags" not in str(err):
                raise
            parser.exit(2, f"jaxtrack track: {err}\n")
        return 0
    if args.command == "evaluate":
        return _evaluate(parser, args)
    if args.command == "train-legs":
        return _train_legs(parser, args)
    if args.command == "train-hog":
        if args.frames < 3 or not (math.isfinite(args.c) and args.c > 0):
            parser.error("--frames must be at least 3 and --c positive")
        _check_writable(parser, args.out)
        from sims.following.crowd_report import train_hog

        res = train_hog(args.frames, args.out, args.seed, args.c)
        print(f"HOG + linear SVM: {res['positives']} positive and {res['negatives']} negative "
              f"crops; accuracy {res['train_accuracy']:.1%} (train), "
              f"{res['test_accuracy']:.1%} (held-out fifth); written to {args.out}")
        return 0
    if args.command == "demo":
        if args.which != "filters":
            if args.episodes is not None or args.steps is not None:
                parser.error("--episodes and --steps apply to `jaxtrack demo filters`; run the "
                             "scenes at other sizes with `jaxtrack run`")
            _import_mjx_quietly()
            from sims import demo as scene_demo

            scene_demo.run(args.which, seed=args.seed)
            return 0
        episodes = 1000 if args.episodes is None else args.episodes
        steps = 200 if args.steps is None else args.steps
        if episodes < 1 or steps < 1:
            parser.error("--episodes and --steps must be positive")
        from jaxtrack import demo as demo_mod

        demo_mod.run(episodes, steps, args.seed)
        return 0
    if args.scene == "humanoid-routes":
        _import_mjx_quietly()
        from sims.humanoid import routes

        return routes.main(extra + args.routes_args, prog="jaxtrack run humanoid-routes")
    if args.scene == "service":
        if args.episodes < 1 or not (math.isfinite(args.duration) and args.duration > 0):
            parser.error("--episodes and --duration must be positive (and --duration finite)")
        if args.batch_size is not None and args.batch_size < 1:
            parser.error(f"--batch-size must be positive; got {args.batch_size}")
        if args.animate and args.out is None:
            parser.error("--animate needs --out (the folder the animation is written to)")
        interest = None
        if args.interest != "estimated":
            try:
                interest = float(args.interest)
            except ValueError:
                interest = math.nan
            if not 0.0 <= interest <= 1.0:
                parser.error(f"--interest must be a number in [0, 1] or 'estimated'; got "
                             f"{args.interest!r}")
        if args.settle < 0 or not 0.0 <= args.still_at_end <= args.duration:
            parser.error("--settle must be >= 0 and --still-at-end in [0, --duration]")
        if args.replan_every is not None and args.replan_every < 1:
            parser.error(f"--replan-every must be >= 1; got {args.replan_every}")
        if not 0.05 <= args.cell <= 0.5:
            parser.error(f"--cell must be in [0.05, 0.5] m; got {args.cell}")
        if args.out is not None:
            _check_writable(parser, args.out)
        _import_mjx_quietly()
        from sims.service.report import run_service

        run_service(args.experiment, args.episodes, args.duration, args.perception,
                    args.compare_sensors, interest, args.out, args.seed, args.batch_size,
                    args.animate, heading_filter=args.heading_filter, pan=args.pan,
                    reverse=args.reverse, settle_iterations=args.settle,
                    still_at_end=args.still_at_end, heading_frame=args.heading_frame,
                    line_of_sight=args.line_of_sight, replan_every=args.replan_every,
                    cell=args.cell, corroborated_births=args.births == "corroborated")
        return 0
    if args.scene == "rgbd-people":
        if args.episodes < 1 or not (math.isfinite(args.duration) and args.duration > 0):
            parser.error("--episodes and --duration must be positive (and --duration finite)")
        if min(args.resolution) < 8:
            parser.error(f"--resolution must be at least 8 x 8 pixels; got "
                         f"{args.resolution[0]} x {args.resolution[1]}")
        if args.batch_size is not None and args.batch_size < 1:
            parser.error(f"--batch-size must be positive; got {args.batch_size}")
        if args.out is not None:
            _check_writable(parser, args.out)
        from sims.following.crowd_report import run_rgbd_people

        names = tuple({"full": "full", "no-sub-clustering": "no sub-clustering",
                       "no-velocity": "no velocity", "no-appearance": "no appearance",
                       "no-confidence": "no confidence",
                       "perfect-detections": "perfect detections",
                       "noisy-truth": "truth + 0.1 m noise"}[a]
                      for a in (args.ablations or ("full", "no-sub-clustering", "no-velocity",
                                                   "no-appearance", "no-confidence")))
        run_rgbd_people(args.episodes, args.scenario, args.duration, tuple(args.resolution),
                        names, args.seed, args.out, args.batch_size)
        return 0
    if args.scene == "person-following":
        if args.episodes < 1 or args.particles < 2 or not (math.isfinite(args.duration)
                                                           and args.duration > 0):
            parser.error("--episodes, --particles and --duration must be positive (and "
                         "--duration finite)")
        if args.batch_size is not None and args.batch_size < 1:
            parser.error(f"--batch-size must be positive; got {args.batch_size}")
        if args.animate and args.out is None:
            parser.error("--animate needs --out (the folder the animation is written to)")
        if args.out is not None:
            _check_writable(parser, args.out)
        if not 0 <= args.people <= 15:
            parser.error(f"--people must be in [0, 15] (the scene holds 16 people); got "
                         f"{args.people}")
        _import_mjx_quietly()
        from sims.following.report import run_person_following

        run_person_following(args.episodes, args.estimator, args.follower, args.people,
                             args.out, args.seed, args.duration, args.sensors, args.particles,
                             args.batch_size, appearance=args.appearance, layout=args.layout,
                             wander=args.user == "wander", animate=args.animate)
        return 0
    if args.episodes < 1 or args.particles < 1 or args.frames < 1:
        parser.error("--episodes, --particles and --frames must be positive")
    if min(args.resolution) < 2:
        parser.error(f"--resolution must be at least 2 x 2 pixels; got {args.resolution[0]} x "
                     f"{args.resolution[1]}")
    if args.out is not None:
        _check_writable(parser, args.out)
    for flag, value in (("--lambda-x", args.lambda_x), ("--lambda-theta", args.lambda_theta),
                        ("--position-noise", args.position_noise),
                        ("--temperature", args.temperature)):
        if value is not None and not (math.isfinite(value) and value > 0):
            parser.error(f"{flag} must be a finite positive number; got {value}")
    if not 0 < args.heading_gain <= 1:
        parser.error(f"--heading-gain must be in (0, 1]; got {args.heading_gain}")
    if args.walkers < 0:
        parser.error(f"--walkers must be >= 0; got {args.walkers}")
    if args.objects < 0:
        parser.error(f"--objects must be >= 0; got {args.objects}")
    _import_mjx_quietly()
    run_humanoid_reach(args.episodes, args.tracker, args.out, args.seed, args.particles,
                       args.frames, tuple(args.resolution), lambda_x=args.lambda_x,
                       lambda_theta=args.lambda_theta, position_noise=args.position_noise,
                       temperature=args.temperature, turn_prediction=args.turn_prediction,
                       heading_gain=args.heading_gain, walkers=args.walkers,
                       planner=args.planner, objects=args.objects,
                       static_background=not args.unknown_objects)
    return 0


def _evaluate(parser, args) -> int:
    """``jaxtrack evaluate``: every user error is one line and exit code 2."""
    if len(args.gt) != len(args.tracks):
        parser.error(f"--gt and --tracks must name as many files; got {len(args.gt)} and "
                     f"{len(args.tracks)}")
    if args.names is not None and len(args.names) != len(args.gt):
        parser.error(f"--names must name every sequence; got {len(args.names)} for "
                     f"{len(args.gt)}")
    if args.names is not None and len(set(args.names)) != len(args.names):
        parser.error("--names must be distinct")
    for flag, value in (("--threshold", args.threshold), ("--zero-distance", args.zero_distance)):
        if not (math.isfinite(value) and value > 0):
            parser.error(f"{flag} must be a finite positive number; got {value}")
    if args.min_confidence is not None and not math.isfinite(args.min_confidence):
        parser.error(f"--min-confidence must be finite; got {args.min_confidence}")
    for path in list(args.gt) + list(args.tracks):
        if not path.is_file():
            parser.error(f"no such file: {path}")
    if args.out is not None:
        _check_writable(parser, args.out)
    from jaxtrack.io import trajectories

    pairs = list(zip(args.gt, args.tracks))
    sequences = dict(zip(args.names, pairs)) if args.names else pairs
    try:
        rows = trajectories.evaluate_sequences(sequences, threshold=args.threshold,
                                               fmt=args.format, zero_distance=args.zero_distance,
                                               min_confidence=args.min_confidence,
                                               target_only=args.target_only)
    except (ValueError, OSError) as err:
        parser.exit(2, f"jaxtrack evaluate: {err}\n")
    if len(rows) == 2:  # one sequence: its OVERALL row repeats it
        rows.pop("OVERALL")
    plane = next(iter(rows.values()))["plane"]
    unit = "1 - IoU" if plane == "image" else "m"
    print(f"{len(pairs)} sequence(s), {plane} plane, threshold {args.threshold:g} ({unit}); "
          f"MOTP in {unit}")
    print(trajectories.format_summary(rows))
    if args.out is not None:
        trajectories.write_summary(rows, args.out / "summary.csv", args.out / "summary.json")
        print(f"wrote {args.out / 'summary.csv'} and {args.out / 'summary.json'}")
    return 0


def _train_legs(parser, args) -> int:
    """``jaxtrack train-legs``: arguments checked before any work, then `leg_dataset.train`."""
    for path in [*args.positive, *args.negative]:
        if not path.exists():
            parser.error(f"{path} does not exist")
    if not (args.jump > 0 and args.match_radius > 0 and math.isfinite(args.jump)
            and math.isfinite(args.match_radius)):
        parser.error("--jump and --match-radius must be positive and finite")
    if args.trees < 1 or args.depth < 1:
        parser.error("--trees and --depth must be positive")
    _check_writable(parser, args.out.parent if str(args.out.parent) else Path("."))
    try:
        import sklearn  # noqa: F401
    except ImportError:
        parser.exit(2, "jaxtrack train-legs: needs scikit-learn: pip install 'jaxtrack[train]'\n")
    from jaxtrack.io import bags, leg_dataset
    from jaxtrack.perception import leg_classifier

    try:
        positive = [leg_dataset.read_labelled(p, args.scan_topic, args.labels_topic)
                    for p in args.positive]
        negative = []
        for p in args.negative:
            scan_topics = args.negative_topics or [
                t for t, kind in bags.topics(p).items() if kind == bags.LASER_SCAN]
            if not scan_topics:
                parser.exit(2, f"jaxtrack train-legs: {p} has no LaserScan topic\n")
            negative += [leg_dataset.read_unlabelled(p, t) for t in scan_topics]
        model, report = leg_dataset.train(positive, negative, jump=args.jump,
                                          n_estimators=args.trees, max_depth=args.depth,
                                          seed=args.seed, match_radius=args.match_radius)
    except (bags.BagError, ValueError) as err:
        parser.exit(2, f"jaxtrack train-legs: {err}\n")
    leg_classifier.save(args.out, model, sources="\n".join(report.sources),
                        segments=report.num_segments, legs=report.num_legs,
                        scans=report.num_scans, held_out_precision=report.held_out_precision,
                        held_out_recall=report.held_out_recall)
    print(f"{report.num_scans} scans, {report.num_segments} segments, {report.num_legs} legs "
          f"({report.dropped} segments beyond capacity)")
    print(f"decision threshold {report.decision:.3f}: held-out segment precision "
          f"{report.held_out_precision:.3f}, recall {report.held_out_recall:.3f}")
    print(f"wrote {args.out}")
    return 0


def _track_depth(parser, args) -> int:
    """``jaxtrack track --depth-topic``: a humanoid tracked through ceiling depth images."""
    if args.laser_topic:
        parser.error("give --laser-topic or --depth-topic, not both")
    if args.camera_position is None or args.focal is None:
        parser.error("--depth-topic needs --camera-position X Y Z and --focal FX FY")
    values = [*args.camera_position, *args.focal, *(args.principal or ()), *(args.start or ()),
              *(() if args.max_height is None else (args.max_height,))]
    if not all(math.isfinite(v) for v in values):
        parser.error("--camera-position, --focal, --principal, --start and --max-height must "
                     "be finite")
    if not (args.camera_position[2] > 0 and min(args.focal) > 0):
        parser.error("the camera must be above the floor (Z > 0) with positive focal lengths")
    if args.max_points is None:
        args.max_points = 96
    if args.chunk < 1 or args.max_points < 1:
        parser.error("--chunk and --max-points must be positive")
    if not args.bag.exists():
        parser.error(f"--bag {args.bag} does not exist")
    _check_writable(parser, args.out)
    from jaxtrack.io import bags
    from jaxtrack.io.depth_replay import track_depth_bag

    try:
        track_depth_bag(args.bag, args.depth_topic, args.out,
                        camera_position=tuple(args.camera_position), focal=tuple(args.focal),
                        principal=tuple(args.principal) if args.principal else None,
                        start=tuple(args.start) if args.start else None, tracker=args.tracker,
                        max_points=args.max_points, max_height=args.max_height,
                        seed=args.seed, chunk=args.chunk,
                        time_source=args.time_source)
    except bags.BagError as err:
        parser.exit(2, f"jaxtrack track: {err}\n")
    except ValueError as err:
        parser.exit(2, f"jaxtrack track: {err}\n")
    except ImportError as err:
        if "rosbags" not in str(err):
            raise
        parser.exit(2, f"jaxtrack track: {err}\n")
    return 0


def _track_rgbd(parser, args) -> int:
    """``jaxtrack track --cloud-topic`` / ``--rgbd-topics``: people detected and tracked in
    recorded RGB-D. Every user error is one line and exit code 2."""
    import tempfile

    def fail(message):
        parser.exit(2, f"jaxtrack track: {message}\n")

    if args.cloud_topic and args.rgbd_topics:
        fail("give --cloud-topic or --rgbd-topics, not both")
    option = "--cloud-topic" if args.cloud_topic else "--rgbd-topics"
    for other, given in (("--laser-topic", args.laser_topic), ("--depth-topic", args.depth_topic)):
        if given:
            fail(f"give {other} or {option}, not both")
    if args.mount is None:
        fail(f"{option} needs --mount X Y Z (the camera's optical centre in the robot's base "
             f"frame, m)")
    if args.rgbd_topics and args.focal is None:
        fail("--rgbd-topics needs --focal FX FY (the camera's focal lengths, pixels)")
    if args.rgbd_topics and args.max_points is not None:
        fail("--max-points applies to --cloud-topic and --depth-topic, not --rgbd-topics")
    if args.rgbd_topics and args.cloud_frame != "optical":
        fail("--cloud-frame applies to --cloud-topic")
    values = [*args.mount, args.tilt, args.min_confidence, *(args.focal or ()),
              *(args.principal or ())]
    if not all(math.isfinite(v) for v in values):
        fail("--mount, --tilt, --min-confidence, --focal and --principal must be finite")
    if args.focal is not None and min(args.focal) <= 0:
        fail(f"--focal must be positive; got {args.focal[0]:g} {args.focal[1]:g}")
    if args.principal is not None and args.focal is None:
        fail("--principal needs --focal")
    if args.chunk < 1 or (args.max_points is not None and args.max_points < 1):
        fail("--chunk and --max-points must be positive")
    if args.odom_topic and args.tf_frames:
        fail("give --odom-topic or --tf-frames, not both")
    if not args.bag.exists():
        fail(f"--bag {args.bag} does not exist")
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=args.out):
            pass
    except OSError as err:
        fail(f"--out {args.out} is not a writable directory ({err.strerror or err})")
    from jaxtrack.io import rgbd_replay

    try:
        depth_topic, colour_topic = args.rgbd_topics or (None, None)
        rgbd_replay.track_rgbd_bag(
            args.bag, args.out, mount=rgbd_replay.mount(tuple(args.mount),
                                                        math.radians(args.tilt)),
            cloud_topic=args.cloud_topic, depth_topic=depth_topic, colour_topic=colour_topic,
            focal=tuple(args.focal) if args.focal else None,
            principal=tuple(args.principal) if args.principal else None,
            odom_topic=args.odom_topic,
            tf_frames=tuple(args.tf_frames) if args.tf_frames else None,
            cloud_frame=args.cloud_frame, max_points=args.max_points,
            min_confidence=args.min_confidence, seed=args.seed, chunk=args.chunk,
            time_source=args.time_source)
    except ValueError as err:          # bags.BagError included
        fail(err)
    except ImportError as err:
        if "rosbags" not in str(err):
            raise
        fail(err)
    return 0


def _check_points_file(parser, path: Path) -> None:
    """A text file of ``x y`` rows, read before any work (a 3-column file is an error, not
    silently reshaped)."""
    try:
        rows = np.loadtxt(path, ndmin=2)
    except (OSError, ValueError) as err:
        parser.error(f"--static-points {path}: {err}")
    if rows.size and rows.shape[1] != 2:
        parser.error(f"--static-points {path}: expected 2 columns (x y); got {rows.shape[1]}")
    if not np.all(np.isfinite(rows)):
        parser.error(f"--static-points {path}: NaN or inf in the points")


def _check_writable(parser, out: Path) -> None:
    """Create ``out`` if needed and check that a file can be written there, before any work."""
    import tempfile

    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=out):
            pass
    except OSError as err:
        parser.error(f"--out {out} is not a writable directory ({err.strerror or err})")


def run_humanoid_reach(episodes: int = 64, tracker: str = "pf", out: Path | None = None,
                       seed: int = 0, particles: int = 128, frames: int = 200,
                       resolution=(80, 60), stream=sys.stdout, lambda_x: float = 0.1,
                       lambda_theta: float = 0.2, position_noise: float = 0.035,
                       temperature: float | None = None, turn_prediction: bool = False,
                       heading_gain: float = 0.5, progress: bool = True,
                       walkers: int = 0, planner: str = "dcm", objects: int = 0,
                       static_background: bool = True) -> dict:
    """The seed's 15-task protocol, ``episodes`` per task; prints the table, writes plots.

    ``lambda_x``, ``lambda_theta``, ``position_noise`` and ``temperature`` are the tunable
    values of `sims.humanoid.episode.make_params` (defaults: the seed's), e.g. those tuned in
    ``notebooks/02_humanoid_tuning.ipynb``; ``turn_prediction`` and ``heading_gain`` configure
    the PCA heading (`sims.humanoid.episode.EpisodeConfig`); ``walkers`` people pace near the
    robot (`EpisodeConfig.walkers`); ``objects`` boxes stand on the floor beside the route
    (`EpisodeConfig.floor_objects`), part of the camera's background image unless
    ``static_background`` is False (`EpisodeConfig.static_background`); ``planner`` is the
    gait's footstep planner (`EpisodeConfig.planner`). ``progress`` shows a progress bar on stderr.

    Returns ``{"table": str, "metrics": [per-task metric dicts], "compile_seconds",
    "run_seconds"}``.
    """
    import jax

    from jaxtrack import montecarlo
    from sims.humanoid import episode

    episode_fn = _humanoid_episode(tracker, particles, frames, tuple(resolution), heading_gain,
                                   turn_prediction, int(walkers), planner, int(objects),
                                   bool(static_background))
    tasks = episode.seed_task_params(lambda_x=lambda_x, lambda_theta=lambda_theta,
                                     position_noise=position_noise, temperature=temperature)
    key = jax.random.PRNGKey(seed)
    total = episodes * len(tasks)
    # Compile once (every task has the same shapes: the tasks are traced parameters).
    compile_s = montecarlo.warm_up(episode_fn, tasks[0], key, episodes)
    results = []
    t1 = time.perf_counter()
    with montecarlo.progress_bar(total, disable=not progress) as bar:
        for i, params in enumerate(tasks):
            res = montecarlo.evaluate(episode_fn, params, jax.random.fold_in(key, i), episodes,
                                      progress=False)
            results.append(res.metrics)
            bar.set_postfix_str(f"task {TASK_NAMES[i]}", refresh=False)
            bar.update(episodes)
    run_s = time.perf_counter() - t1
    table = task_table(results, frames)
    print(table, file=stream)
    people = (f", {walkers} walkers" if walkers else "") + (
        f", {objects} floor objects{'' if static_background else ' (unknown)'}" if objects
        else "") + (
        f", {planner} planner" if planner != "dcm" else "")
    print(f"{total} episodes ({tracker}, {particles} particles, {resolution[0]}x{resolution[1]}"
          f"{people}) "
          f"in {run_s:.1f} s after {compile_s:.1f} s of compilation "
          f"({total / run_s:.1f} episodes/s)", file=stream)
    if objects:
        # The gait walks through the boxes (they are seen, not felt): say how often it did.
        clearance = np.concatenate([np.asarray(m["object_clearance"]) for m in results])
        print(f"floor objects: torso within 0.15 m of a footprint in "
              f"{100 * np.mean(clearance < 0.15):.1f} % of episodes (median least distance "
              f"{np.median(clearance):.2f} m)", file=stream)
    if out is not None:
        _write_outputs(Path(out), results, tracker)
    return {"table": table, "metrics": results, "compile_seconds": compile_s,
            "run_seconds": run_s}


@functools.lru_cache(maxsize=8)
def _humanoid_episode(tracker, particles, frames, resolution, heading_gain, turn_prediction,
                      walkers=0, planner="dcm", objects=0, static_background=True):
    """The episode function of a humanoid-reach run. Cached: runs with the same settings in a
    process share it, and so the batches `jaxtrack.montecarlo` compiled for it (it caches them
    by function)."""
    from jaxtrack.tracking import humanoid
    from sims.humanoid import episode, scene

    heading = humanoid.HeadingConfig(gain=heading_gain, turn_prediction=turn_prediction)
    trackers = {"pf": humanoid.DepthPFConfig(num_particles=particles, heading=heading),
                "pf3": humanoid.DepthPF3Config(num_particles=particles),
                "ukf": humanoid.CentroidUKFConfig(heading=heading)}
    cfg = episode.EpisodeConfig(scene.build(*resolution), tracker=trackers[tracker],
                                num_frames=frames, walkers=walkers, planner=planner,
                                floor_objects=objects, static_background=static_background)
    return episode.make_episode(cfg)


# What mujoco.mjx prints (to stdout, from ``mujoco/mjx/warp/__init__.py``) when its optional GPU
# backend, NVIDIA Warp, is not installed; the scenes run on MJX's JAX backend and never need it.
_MJX_BACKEND_NOTICES = ("Failed to import warp:", "Failed to import mujoco_warp:")


def _import_mjx_quietly() -> None:
    """Import ``mujoco.mjx`` without its notices about the missing Warp backend; anything else
    the import prints is passed on."""
    if "mujoco.mjx" in sys.modules:
        return
    captured = io.StringIO()
    try:
        with contextlib.redirect_stdout(captured):
            import mujoco.mjx  # noqa: F401
    finally:
        for line in captured.getvalue().splitlines(keepends=True):
            if not line.startswith(_MJX_BACKEND_NOTICES):
                sys.stdout.write(line)


def task_table(results, frames: int, names=None) -> str:
    """Section 5.5-style table: per task, tracker position error median / 95 % (pooled over
    the frames up to the stop), heading error mean +- std, success rate, frames to stop.

    ``names``: one row label per result (default: the seed's task names in order, i.e. results
    for tasks 0, 1, ...; for another subset pass its names, e.g.
    ``[cli.TASK_NAMES[i] for i in tasks]``)."""
    if names is None:
        names = (list(TASK_NAMES) + ["?"] * len(results))[:len(results)]
    names = list(names)
    if len(names) != len(results):
        raise ValueError(f"task_table got {len(results)} results and {len(names)} names")
    head = (f"{'task':<10}{'pos err med [cm]':>17}{'pos err 95% [cm]':>17}"
            f"{'heading err [deg]':>19}{'success':>9}{'frames to stop':>16}{'final err [cm]':>15}")
    lines = [head, "-" * len(head)]
    pooled = {"pos": [], "head": [], "succ": [], "frames": [], "final": []}
    for name, m in zip(names, results):
        active = np.asarray(m["active"], bool)
        pos = np.asarray(m["pos_err"])[active] * 100
        hd = np.asarray(m["heading_err"])[active]
        succ = np.asarray(m["success"])
        fr = np.asarray(m["frames_to_stop"])
        final = np.asarray(m["final_pos_err"]) * 100
        for k, v in zip(pooled, (pos, hd, succ, fr, final)):
            pooled[k].append(v)
        lines.append(_row(name, pos, hd, succ, fr, final))
    lines.append("-" * len(head))
    lines.append(_row("all", *(np.concatenate(v) for v in pooled.values())))
    lines.append(f"(frames to stop: median [95 %]; {frames} means never stopped)")
    return "\n".join(lines)


def _row(name, pos, hd, succ, fr, final):
    return (f"{name:<10}{np.median(pos):>17.2f}{np.quantile(pos, 0.95):>17.2f}"
            f"{f'{hd.mean():.2f} +- {hd.std():.2f}':>19}{100 * succ.mean():>8.1f}%"
            f"{f'{np.median(fr):.0f} [{np.quantile(fr, 0.95):.0f}]':>16}"
            f"{np.median(final):>15.2f}")


def _write_outputs(out: Path, results, tracker):
    from jaxtrack import plotting

    out.mkdir(parents=True, exist_ok=True)
    names = list(TASK_NAMES)
    # Figs. 10-11 style: per-frame tracker errors per task.
    pos = {n: np.asarray(m["pos_err"])[np.asarray(m["active"], bool)]
           for n, m in zip(names, results)}
    head = {n: np.asarray(m["heading_err"])[np.asarray(m["active"], bool)]
            for n, m in zip(names, results)}
    for i, path in enumerate(_PATHS):
        group = names[5 * i:5 * i + 5]
        fig = plotting.error_boxplot({n: pos[n] for n in group}, ylabel="position error [m]",
                                     title=f"{path} ({tracker})")
        fig.savefig(out / f"position_error_{path.split()[0]}.png", dpi=100)
    for j, h in enumerate(_HEADINGS):
        group = [names[5 * i + j] for i in range(3)]
        fig = plotting.error_boxplot({n: head[n] for n in group}, ylabel="heading error [deg]",
                                     title=f"final heading {h:+d} deg ({tracker})")
        fig.savefig(out / f"heading_error_{h:+d}.png", dpi=100)
    # Fig. 8 style: top view, first episode of every task, truth vs tracker.
    truth = np.stack([np.asarray(m["truth"])[0] for m in results])
    est = np.stack([np.asarray(m["estimate"])[0] for m in results])
    fig = plotting.trajectories(truth[..., :2], est[..., :2], truth[..., 2], est[..., 2],
                                arrow_every=20, arrow_length=0.08,
                                labels=("true CoM", f"{tracker} estimate"),
                                title="humanoid reach: first episode of each task")
    fig.savefig(out / "trajectories.png", dpi=110)
    np.savez(out / "metrics.npz", **{f"task{i:02d}_{k}": np.asarray(v)
                                     for i, m in enumerate(results) for k, v in m.items()
                                     if k not in ("truth", "estimate")})


if __name__ == "__main__":
    sys.exit(main())
