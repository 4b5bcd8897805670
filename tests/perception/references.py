"""Synthetic zenithal point clouds and plain-numpy references for the depth tracker tests."""

import math

import numpy as np

# Sizes of the synthetic robot (inside the default RobotModel with a margin).
HEAD_RADIUS = 0.055
HEAD_Z = (0.50, 0.57)
BODY_HALF_DEPTH = 0.045
BODY_HALF_LENGTH = 0.13
BODY_Z = (0.20, 0.46)


def robot_cloud(rng, pose, n_head=60, n_body=200, n_clutter=40, noise=0.005, capacity=360):
    """Points on a head disc and a shoulder box at ``pose`` (x, y, theta), plus clutter in a
    2 m square, Gaussian noise; padded with NaN rows (masked out) to ``capacity``."""
    x, y, th = pose
    r = HEAD_RADIUS * np.sqrt(rng.uniform(size=n_head))
    a = rng.uniform(0.0, 2.0 * np.pi, n_head)
    head = np.stack([x + r * np.cos(a), y + r * np.sin(a), rng.uniform(*HEAD_Z, n_head)], -1)
    u = rng.uniform(-BODY_HALF_DEPTH, BODY_HALF_DEPTH, n_body)
    v = rng.uniform(-BODY_HALF_LENGTH, BODY_HALF_LENGTH, n_body)
    body = np.stack([x + np.cos(th) * u - np.sin(th) * v, y + np.sin(th) * u + np.cos(th) * v,
                     rng.uniform(*BODY_Z, n_body)], -1)
    clutter = np.stack([rng.uniform(x - 1, x + 1, n_clutter), rng.uniform(y - 1, y + 1, n_clutter),
                        rng.uniform(0.0, 1.0, n_clutter)], -1)
    pts = np.concatenate([head, body, clutter])
    pts = pts + noise * rng.standard_normal(pts.shape)
    out = np.full((capacity, 3), np.nan)
    out[: len(pts)] = pts
    mask = np.zeros(capacity, bool)
    mask[: len(pts)] = True
    return out, mask


def brute_force_count(points, mask, pose, model):
    """The seed's count, one point at a time with explicit geometry."""
    x, y, th = (float(v) for v in pose)
    count = 0
    for p, m in zip(points, mask):
        if not m or not np.all(np.isfinite(p)):
            continue
        px, py, pz = (float(v) for v in p)
        dx, dy = px - x, py - y
        if pz > model.z_threshold:
            if pz <= model.head_top and math.hypot(dx, dy) <= model.head_radius:
                count += 1
        elif pz >= model.shoulder_bottom:
            forward = dx * math.cos(th) + dy * math.sin(th)
            left = -dx * math.sin(th) + dy * math.cos(th)
            in_depth = abs(forward) <= model.shoulder_half_depth
            if in_depth and abs(left) <= model.shoulder_half_length:
                count += 1
    return count


def ellipse_cloud(rng, centre, facing, n=800, across=0.14, along=0.05, noise=0.004):
    """Floor points filling an ellipse whose minor axis points along ``facing``."""
    r = np.sqrt(rng.uniform(size=n))
    a = rng.uniform(0.0, 2.0 * np.pi, n)
    f = along * r * np.cos(a)     # along the facing direction (minor axis)
    s = across * r * np.sin(a)    # across the shoulders (major axis)
    c, sn = np.cos(facing), np.sin(facing)
    xy = np.stack([centre[0] + c * f - sn * s, centre[1] + sn * f + c * s], -1)
    xy = xy + noise * rng.standard_normal(xy.shape)
    z = rng.uniform(0.3, 0.55, n)
    return np.concatenate([xy, z[:, None]], -1)


def pca_minor_axis(xy):
    """Minor-axis angle (mod pi) from numpy's symmetric eigensolver."""
    cov = np.cov(xy.T, bias=True)
    _, vecs = np.linalg.eigh(cov)
    minor = vecs[:, 0]
    return math.atan2(minor[1], minor[0])


def wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi
