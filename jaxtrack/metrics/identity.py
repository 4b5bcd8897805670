r"""Identity metrics IDF1, IDP and IDR of one episode, jittable and vmappable.

Ristani et al., "Performance measures and a data set for multi-target, multi-camera tracking",
ECCV workshops 2016, as py-motmetrics computes them. Each ground-truth id is matched to at most
one hypothesis id *for the whole sequence*, so that the matched pairs agree in as many frames as
possible:

.. math::
    \mathrm{IDTP} = \max_{\pi} \sum_{(o, h) \in \pi} n_{oh},\qquad
    \mathrm{IDFN} = N_o - \mathrm{IDTP},\qquad \mathrm{IDFP} = N_h - \mathrm{IDTP},

    \mathrm{IDP} = \frac{\mathrm{IDTP}}{\mathrm{IDTP} + \mathrm{IDFP}},\quad
    \mathrm{IDR} = \frac{\mathrm{IDTP}}{\mathrm{IDTP} + \mathrm{IDFN}},\quad
    \mathrm{IDF1} = \frac{2\,\mathrm{IDTP}}{N_o + N_h}

with :math:`n_{oh}` the frames where object o and hypothesis h are both present and within the
match threshold, :math:`\pi` a one-to-one matching of ids, and :math:`N_o, N_h` the object and
hypothesis presences summed over frames. py-motmetrics solves the equivalent min-cost problem
on an :math:`(n_o + n_h)^2` matrix of false negatives plus false positives; its minimum is
:math:`N_o + N_h - 2\,\mathrm{IDTP}`, so the rectangular maximum-weight matching on
:math:`n_{oh}` here (`optax.assignment.hungarian_algorithm`) gives the same counts.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax import lax

from jaxtrack.metrics import _pairs

Array = jax.Array

__all__ = ["IdentityResult", "identity_metrics", "combine"]


class IdentityResult(NamedTuple):
    """Identity scores and counts (field names as in py-motmetrics).

    Attributes:
      idf1: ``2 IDTP / (num_objects + num_predictions)``; NaN if both are 0.
      idp: ``IDTP / num_predictions``; NaN if there is no hypothesis.
      idr: ``IDTP / num_objects``; NaN if there is no object.
      idtp: object presences matched to their sequence-long hypothesis.
      idfp: hypothesis presences not matched to their object.
      idfn: object presences not matched to their hypothesis.
      num_objects: object presences summed over frames.
      num_predictions: hypothesis presences summed over frames.
      num_invalid: present slots left out because their id was beyond the static id bounds
        (only possible under tracing).
    """

    idf1: Array
    idp: Array
    idr: Array
    idtp: Array
    idfp: Array
    idfn: Array
    num_objects: Array
    num_predictions: Array
    num_invalid: Array


_COUNTS = ("idtp", "idfp", "idfn", "num_objects", "num_predictions", "num_invalid")


def identity_metrics(gt_ids: Array, gt_pos: Array, gt_mask: Array | None, hyp_ids: Array,
                     hyp_pos: Array, hyp_mask: Array | None, threshold: float | Array, *,
                     distance: str = "euclidean", max_ids: int | None = None,
                     max_hyp_ids: int | None = None) -> IdentityResult:
    r"""IDF1, IDP and IDR of one episode (module doc), as py-motmetrics computes them.

    Inputs are laid out as for `jaxtrack.metrics.clear_mot`: a slot is present where its mask is
    True (or the mask is None) and its id is >= 0. Ids may be any non-negative integers; they are
    renumbered inside. A pair counts as agreeing in a frame when its distance is <=
    ``threshold``; non-finite positions never agree.

    Args:
      gt_ids: [T, G] integer object ids, -1 in empty slots; unique per frame.
      gt_pos: [T, G, d] object positions (m), or boxes [T, G, 4] with ``distance="iou"``.
      gt_mask: optional [T, G] bools.
      hyp_ids: [T, H] integer hypothesis ids, -1 in empty slots; unique per frame.
      hyp_pos: [T, H, d] hypothesis positions or boxes.
      hyp_mask: optional [T, H] bools.
      threshold: largest distance of an agreement: metres, or ``1 - IoU`` for boxes (0.5 is
        MOTChallenge's IoU >= 0.5); may be traced.
      distance: ``"euclidean"`` (default) or ``"iou"``. Static.
      max_ids, max_hyp_ids: static bounds on the number of distinct object and hypothesis ids
        (default ``T * G`` and ``T * H``). The matching costs O(max_ids^2 max_hyp_ids), so pass
        tight bounds for long sequences.

    Returns:
      `IdentityResult` of scalars; counts are int32.

    Example:
      >>> from jaxtrack import metrics
      >>> res = metrics.identity_metrics(gt_ids, gt_pos, None, hyp_ids, hyp_pos, None, 0.5)
      >>> res.idf1, res.idp, res.idr
    """
    T, G, H = _pairs.check_inputs(gt_ids, gt_pos, gt_mask, hyp_ids, hyp_pos, hyp_mask)
    _pairs.check_distance(distance, np.shape(gt_pos)[2])
    max_ids = _pairs.check_id_bound("max_ids", max_ids, T * G, gt_ids, gt_mask)
    max_hyp_ids = _pairs.check_id_bound("max_hyp_ids", max_hyp_ids, T * H, hyp_ids, hyp_mask)
    threshold = _check_threshold(threshold, gt_pos, hyp_pos)
    return _identity(jnp.asarray(gt_ids), gt_pos, gt_mask, jnp.asarray(hyp_ids), hyp_pos,
                     hyp_mask, threshold, distance, max_ids, max_hyp_ids)


def combine(results: IdentityResult) -> IdentityResult:
    """Pool the identity results of a batch of episodes: sums of the counts, then the ratios
    (py-motmetrics' OVERALL row; each episode keeps its own id matching).

    Example:
      >>> batch = jax.vmap(metrics.identity_metrics, in_axes=(0,) * 6 + (None,))(...)
      >>> metrics.combine_identity(batch).idf1
    """
    if not isinstance(results, IdentityResult):
        raise TypeError(f"results must be an IdentityResult; got {type(results).__name__}")
    return _finish({name: jnp.sum(getattr(results, name)) for name in _COUNTS})


# ---------------------------------------------------------------------------------------------
# Internals


def _check_threshold(threshold, gt_pos, hyp_pos):
    from jaxtrack import _checks

    if _checks.is_concrete(threshold):
        if np.ndim(threshold) != 0 or not float(threshold) > 0:
            raise ValueError(f"threshold must be a positive scalar; got {threshold!r}")
    elif jnp.ndim(threshold) != 0:
        raise ValueError(f"threshold must be a scalar; got shape {list(jnp.shape(threshold))}")
    return jnp.asarray(threshold, jnp.result_type(gt_pos, hyp_pos, float))


def pair_counts(gt_ids, gt_pos, gt_present, hyp_ids, hyp_pos, hyp_present, threshold,
                distance, max_ids, max_hyp_ids):
    """[max_ids, max_hyp_ids] frames where each pair agrees, the dense indices and validity."""
    gi, gv = _pairs.dense_ids(gt_ids, gt_present, max_ids)
    hi, hv = _pairs.dense_ids(hyp_ids, hyp_present, max_hyp_ids)
    dist = jax.vmap(lambda a, b: _pairs.distance_matrix(a, b, distance))(gt_pos, hyp_pos)
    agree = gv[:, :, None] & hv[:, None, :] & (dist <= threshold)
    rows = jnp.broadcast_to(gi[:, :, None], agree.shape)
    cols = jnp.broadcast_to(hi[:, None, :], agree.shape)
    counts = jnp.zeros((max_ids, max_hyp_ids), jnp.int32)
    counts = counts.at[rows.reshape(-1), cols.reshape(-1)].add(agree.reshape(-1).astype(jnp.int32))
    return counts, (gi, gv), (hi, hv)


def max_weight_matching(weights):
    """Value of the maximum-weight one-to-one matching of a non-negative [n, m] matrix."""
    n, m = weights.shape
    if n == 0 or m == 0:
        return jnp.zeros((), weights.dtype)
    # The matching is piecewise constant in the weights: no gradient flows through it.
    cost = lax.stop_gradient(-weights.astype(jnp.result_type(float)))
    r, c = optax.assignment.hungarian_algorithm(cost)
    return jnp.sum(weights[r, c])


@functools.partial(jax.jit, static_argnames=("distance", "max_ids", "max_hyp_ids"))
def _identity(gt_ids, gt_pos, gt_mask, hyp_ids, hyp_pos, hyp_mask, threshold, distance,
              max_ids, max_hyp_ids):
    gt_present = _pairs.present_slots(gt_ids, gt_mask)
    hyp_present = _pairs.present_slots(hyp_ids, hyp_mask)
    counts, (_, gv), (_, hv) = pair_counts(gt_ids, gt_pos, gt_present, hyp_ids, hyp_pos,
                                           hyp_present, threshold, distance, max_ids,
                                           max_hyp_ids)
    num_objects = jnp.sum(gv).astype(jnp.int32)
    num_predictions = jnp.sum(hv).astype(jnp.int32)
    idtp = max_weight_matching(counts).astype(jnp.int32)
    invalid = jnp.sum(gt_present & ~gv) + jnp.sum(hyp_present & ~hv)
    return _finish(dict(idtp=idtp, idfp=num_predictions - idtp, idfn=num_objects - idtp,
                        num_objects=num_objects, num_predictions=num_predictions,
                        num_invalid=invalid.astype(jnp.int32)))


def _ratio(num, den):
    dtype = jnp.result_type(float)
    num, den = jnp.asarray(num, dtype), jnp.asarray(den, dtype)
    return jnp.where(den > 0, num / jnp.where(den > 0, den, 1), jnp.nan)


def _finish(c):
    return IdentityResult(
        idf1=_ratio(2 * c["idtp"], c["num_objects"] + c["num_predictions"]),
        idp=_ratio(c["idtp"], c["idtp"] + c["idfp"]),
        idr=_ratio(c["idtp"], c["idtp"] + c["idfn"]),
        **c)
