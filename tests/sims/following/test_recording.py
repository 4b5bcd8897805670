"""Person-following recordings (`sims.following.recording`): the raw sensor data agree with
the true robot and people."""

import jax.numpy as jnp
import numpy as np

from jaxtrack import geometry
from sims.following import lidar

DURATION = 3.0


def test_recording_sensors_agree_with_the_truth(following_recording):
    _, rec, _ = following_recording
    T = int(round(DURATION / 0.1))
    assert rec.ranges.shape == (T, lidar.LaserConfig().num_beams)
    np.testing.assert_allclose(rec.times, 0.1 * np.arange(1, T + 1))
    # Odometry drifts little over 3 s.
    drift = np.linalg.norm(rec.odom_pose[:, :2] - rec.robot[:, :2], axis=-1)
    assert drift.max() < 0.3
    # The laser sees the user's legs: returns within 0.3 m of the user in most frames.
    pts = []
    for t in range(T):
        ok = rec.ranges[t] < lidar.LaserConfig().max_range
        world = geometry.from_frame(jnp.asarray(rec.robot[t]), np.stack(
            [rec.ranges[t] * np.cos(rec.angles), rec.ranges[t] * np.sin(rec.angles)], -1))
        pts.append(np.any(ok & (np.linalg.norm(np.asarray(world) - rec.people[t, 0], axis=-1)
                                < 0.3)))
    assert np.mean(pts) > 0.8
    # RGB-D detections (robot frame) lie near true people, up to clutter and 0.3 m noise.
    near = []
    for t in range(T):
        w = np.asarray(geometry.from_frame(jnp.asarray(rec.robot[t]),
                                           jnp.asarray(rec.det_xy[t][rec.det_mask[t]])))
        d = np.linalg.norm(w[:, None] - rec.people[t][None], axis=-1).min(1)
        near.extend(d < 1.2)
    assert len(near) > T and np.mean(near) > 0.8
