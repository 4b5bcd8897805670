"""Data association: gating, linear assignment (GNN), PDA, JPDA (exact and LBP), NN-JPDA.

A scan has K track slots (``track_mask`` [K]) and M detection slots (``zs`` [M, m],
``meas_mask`` [M]), optionally from several sensors (``sensor`` [M] indexing ``R`` [S, m, m]).
The usual pipelines, all jit/vmap-able with fixed shapes::

    inn = innovations(means, covs, zs, H, R, meas_mask=mask)          # d2, log N  [K, M]
    gated = gate(inn.d2, m, 0.99)                                      # chi-square gate
    # GNN (seed 001): one optimal assignment, then a Kalman update per track
    col = gnn(inn.d2, gated)
    # JPDA (seed 003): marginals, then combined innovation ... or NN-JPDA (hard MAP choice)
    beta = jpda_marginals(jnp.where(gated, inn.log_likelihood, -jnp.inf), p_d, clutter,
                          meas_mask=mask, log=True)
    posts = jpda_update(Gaussian(means, covs), zs, beta, H, R, meas_mask=mask)
    posts, ll = nn_update(Gaussian(means, covs), zs, nn_jpda(beta), H, R)
    # several overlapping sensors in one scan (seed 003): associate and update sensor by sensor
    out = sequential_jpda_update(Gaussian(means, covs), zs, H, R_per_sensor, sensor,
                                 p_detect=0.9, clutter_density=0.05, meas_mask=mask, hard=True)
"""

from jaxtrack.association.assignment import assignment_cost, gnn, linear_sum_assignment
from jaxtrack.association.detections import noise_per_detection, pad_detections
from jaxtrack.association.gating import Innovations, chi2_ppf, gate, innovations, mahalanobis
from jaxtrack.association.jpda import (MAX_CLUSTER_TRACKS_LIMIT, JPDAInfo, jpda_marginals,
                                       nn_jpda)
from jaxtrack.association.multisensor import SensorScanResult, sequential_jpda_update
from jaxtrack.association.pda import jpda_update, nn_update, pda_update

__all__ = [
    "Innovations", "innovations", "mahalanobis", "chi2_ppf", "gate",
    "linear_sum_assignment", "gnn", "assignment_cost",
    "JPDAInfo", "jpda_marginals", "nn_jpda", "MAX_CLUSTER_TRACKS_LIMIT",
    "pda_update", "jpda_update", "nn_update",
    "SensorScanResult", "sequential_jpda_update",
    "pad_detections", "noise_per_detection",
]
