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


def leg_features(xy, valid, first, last, mask, max_radius=10.0, max_gap=100.0):
    """Arras et al.'s segment features, one segment and one point at a time (the definitions
    of `jaxtrack.perception.leg_features`, written out independently)."""
    xy = np.asarray(xy, np.float64)
    valid_idx = np.flatnonzero(valid)
    rows = []
    for f, l, m in zip(first, last, mask):
        if not m:
            rows.append(np.zeros(14))
            continue
        p = xy[f:l + 1]
        n = len(p)
        c = p.mean(0)
        u = p - c
        scatter = u.T @ u
        lam, vec = np.linalg.eigh(scatter)
        lam_min = max(lam[0], 0.0)
        proj = u @ vec[:, 1]
        length = proj.max() - proj.min()
        std = math.sqrt(np.sum(u * u) / (n - 1)) if n > 1 else 0.0
        width = float(np.linalg.norm(p[-1] - p[0]))
        # Kasa circle: least squares of x^2 + y^2 + D x + E y + F = 0 on centred points.
        rho = None
        det = np.linalg.det(scatter)
        half_tr = 0.5 * np.trace(scatter)
        if n >= 3 and det > 1e-6 * max(half_tr, 1e-30) ** 2:
            A = np.column_stack([u, np.ones(n)])
            sol = np.linalg.lstsq(A, -np.sum(u * u, 1), rcond=None)[0]
            D, E, F = sol
            rho_sq = (D * D + E * E) / 4 - F
            if rho_sq > 0:
                rho = math.sqrt(rho_sq)
                centre = np.array([-D / 2, -E / 2])
        if rho is None:
            circularity, radius = lam_min, max_radius
        else:
            circularity = float(np.sum((np.linalg.norm(u - centre, axis=1) - rho) ** 2))
            radius = min(rho, max_radius)
        steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
        boundary = float(steps.sum())
        regularity = float(np.std(steps)) if n >= 3 else 0.0
        curv, turn = [], []
        for j in range(1, n - 1):
            a, b = p[j] - p[j - 1], p[j + 1] - p[j]
            chord = np.linalg.norm(p[j + 1] - p[j - 1])
            cross = a[0] * b[1] - a[1] * b[0]
            denom = np.linalg.norm(a) * np.linalg.norm(b) * chord
            curv.append(2 * abs(cross) / denom if denom > 0 else 0.0)
            turn.append(math.atan2(cross, a @ b) if (abs(cross) + abs(a @ b)) > 0 else 0.0)
        mean_curv = float(np.mean(curv)) if curv else 0.0
        mean_turn = float(np.mean(turn)) if turn else 0.0
        before = valid_idx[valid_idx < f]
        after = valid_idx[valid_idx > l]
        gap_before = float(np.linalg.norm(p[0] - xy[before[-1]])) if len(before) else max_gap
        gap_after = float(np.linalg.norm(xy[after[0]] - p[-1])) if len(after) else max_gap
        rows.append(np.array([n, width, length, std, lam_min, circularity, radius, boundary,
                              regularity, mean_curv, mean_turn, gap_before, gap_after,
                              float(np.linalg.norm(c))]))
    return np.array(rows)


def laser_scan(rng, angles, circles, walls, max_range, *, num_circles, num_walls,
               noise=0.005):
    """One simulated scan [B] float32 (misses inf, Gaussian range noise) from a laser at the
    origin: ``circles`` [(xy, radius)] and ``walls`` [((x0, y0), (x1, y1))], padded to fixed
    capacities so that the caster compiles once per capacity."""
    import jax.numpy as jnp

    from sims.following import lidar

    centres, radii = np.zeros((num_circles, 2)), np.full(num_circles, 0.05)
    cmask = np.zeros(num_circles, bool)
    for i, (c, r) in enumerate(circles):
        centres[i], radii[i], cmask[i] = c, r, True
    ends = np.tile([[0.0, 0.0], [1.0, 0.0]], (num_walls, 1, 1))
    wmask = np.zeros(num_walls, bool)
    for i, w in enumerate(walls):
        ends[i], wmask[i] = w, True
    r = np.asarray(_cast()(jnp.zeros(3), jnp.asarray(angles, jnp.float64),
                           lidar.Circles(jnp.asarray(centres), jnp.asarray(radii),
                                         jnp.asarray(cmask)),
                           lidar.Walls(jnp.asarray(ends), jnp.asarray(wmask)), max_range))
    hit = r < max_range
    return np.where(hit, r + noise * rng.standard_normal(r.shape), np.inf).astype(np.float32)


_CAST = []


def _cast():
    import jax

    from sims.following import lidar

    if not _CAST:
        _CAST.append(jax.jit(lidar.cast))
    return _CAST[0]
