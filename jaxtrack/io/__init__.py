"""Recorded data in and out of jaxtrack's fixed-shape arrays.

- `jaxtrack.io.trajectories`: pedestrian-trajectory text files (ETH / UCY ``obsmat.txt`` and the
  plain ``frame id x y`` layout) and MOTChallenge-style CSV, read into ground-truth arrays for
  `jaxtrack.metrics.clear_mot`; tracker output written back in the same CSV layout.
- `jaxtrack.io.synthetic`: noisy detections (misses, clutter, per-sensor noise) simulated from
  recorded trajectories, so that trackers run on real human motion.
- `jaxtrack.io.bags`: ROS 1 and ROS 2 bags (laser scans, depth and colour images, point clouds,
  odometry, person detections) through the pure-Python ``rosbags`` package, installed by the
  ``ros`` extra.
- `jaxtrack.io.replay`: the sensing step and a user estimator replayed on recorded scans
  (``jaxtrack track``), without MuJoCo.
- `jaxtrack.io.rgbd_replay`: the RGB-D people detector and tracker replayed on recorded point
  clouds or depth + colour images (``jaxtrack track --cloud-topic`` / ``--rgbd-topics``).

Import the submodule you need: ``from jaxtrack.io import trajectories``.
"""

__all__ = ["bags", "replay", "synthetic", "trajectories"]
