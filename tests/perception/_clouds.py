"""Synthetic point clouds for the RGB-D detector's tests: a floor, a wall and standing people
(a body cylinder under a head sphere), with a fixed seed."""

from __future__ import annotations

import numpy as np


def person(rng, centre, stature=1.75, n=3000):
    """[n + 800, 3] surface points of a person standing at ``centre`` (x, y)."""
    z = rng.uniform(0.0, stature - 0.2, n)
    a = rng.uniform(0.0, 2 * np.pi, n)
    body = np.c_[centre[0] + 0.18 * np.cos(a), centre[1] + 0.18 * np.sin(a), z]
    u = rng.normal(size=(800, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    head = np.array([centre[0], centre[1], stature - 0.11]) + 0.11 * u
    return np.concatenate([body, head])


def floor(rng, n=3000, x=(0.5, 4.5), y=(-2.0, 2.0), noise=0.01):
    return np.c_[rng.uniform(*x, n), rng.uniform(*y, n), rng.normal(0.0, noise, n)]


def wall(rng, n=900, x=4.8, y=(-2.0, 2.0), height=2.2, noise=0.01):
    return np.c_[np.full(n, x) + rng.normal(0.0, noise, n), rng.uniform(*y, n),
                 rng.uniform(0.0, height, n)]


def tilt(points, angle, lift=0.0):
    """Rotate about x by ``angle`` and raise by ``lift`` (a camera that rocks)."""
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    return points @ rot.T + [0.0, 0.0, lift]
