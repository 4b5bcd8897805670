"""Plain reference implementations for the association tests (numpy, no jaxtrack code).

- `feasible_events`: every feasible JPDA joint event of K tracks and M detections, by
  enumeration of all maps track -> detection-or-nothing and rejection of the non-injective ones.
- `brute_force_marginals`: JPDA marginals by summing the event weights of seed 003 eq. 6.
- `pda_reference`: Bar-Shalom's combined-innovation PDA update (single R), textbook form.
- `mixture_reference`: moment matching of the per-detection Kalman posteriors (any R_j).
"""

import functools
import itertools

import numpy as np


@functools.lru_cache(maxsize=None)
def feasible_events(K, M):
    """[E, K] int array: the detection of each track (-1 = none) in every feasible event."""
    events = [ev for ev in itertools.product(range(-1, M), repeat=K)
              if len([c for c in ev if c >= 0]) == len({c for c in ev if c >= 0})]
    return np.array(events, dtype=int).reshape(len(events), K)


def brute_force_marginals(L, p_detect, clutter_density):
    """beta [K, M + 1] of P(A) ~ prod_assigned pD_t L_tj / lam_j * prod_missed (1 - pD_t).

    ``p_detect`` scalar or [K], ``clutter_density`` scalar or [M]. Computed in float64 with
    plain products (the problems are small and well scaled).
    """
    L = np.asarray(L, np.float64)
    K, M = L.shape
    pd = np.broadcast_to(np.asarray(p_detect, np.float64), (K,))
    lam = np.broadcast_to(np.asarray(clutter_density, np.float64), (M,))
    events = feasible_events(K, M)
    # factor[t, c]: weight of track t taking detection c, the last column is "missed"
    factor = np.concatenate([pd[:, None] * L / lam[None, :], (1.0 - pd)[:, None]], 1)
    cols = np.where(events < 0, M, events)                      # [E, K]
    weights = np.prod(factor[np.arange(K)[None, :], cols], axis=1)   # [E]
    beta = np.zeros((K, M + 1))
    for t in range(K):
        np.add.at(beta[t], cols[:, t], weights)
    return beta / weights.sum()


def kalman_posterior(mean, cov, z, H, R):
    """Standard-form Kalman update (not Joseph), for references."""
    S = H @ cov @ H.T + R
    K = cov @ H.T @ np.linalg.inv(S)
    return mean + K @ (z - H @ mean), cov - K @ S @ K.T


def pda_reference(mean, cov, zs, beta, H, R):
    """Bar-Shalom, Daum and Huang (2009) eqs. 11-18: combined innovation, spread term."""
    S = H @ cov @ H.T + R
    K = cov @ H.T @ np.linalg.inv(S)
    nus = zs - H @ mean                                          # [M, m]
    b = beta[:-1]
    b0 = beta[-1]
    nu = b @ nus
    Pc = cov - K @ S @ K.T
    spread = K @ (np.einsum("j,ja,jb->ab", b, nus, nus) - np.outer(nu, nu)) @ K.T
    return mean + K @ nu, b0 * cov + (1.0 - b0) * Pc + spread


def mixture_reference(mean, cov, zs, beta, H, Rs):
    """Moment-matched mixture of the prior (weight beta[-1]) and per-detection posteriors."""
    comps = [(mean, cov, beta[-1])]
    for z, R, b in zip(zs, Rs, beta[:-1]):
        m_j, P_j = kalman_posterior(mean, cov, z, H, R)
        comps.append((m_j, P_j, b))
    mu = sum(w * m for m, _, w in comps)
    P = sum(w * (C + np.outer(m - mu, m - mu)) for m, C, w in comps)
    return mu, P


def random_spd(rng, n, scale=1.0, floor=0.1):
    a = rng.standard_normal((n, n))
    return scale * (a @ a.T / n + floor * np.eye(n))


def error_summary(errors):
    """(mean, median, 95th percentile, max) of a 1-D array of errors."""
    e = np.asarray(errors)
    return float(e.mean()), float(np.median(e)), float(np.percentile(e, 95)), float(e.max())
