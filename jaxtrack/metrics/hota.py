r"""HOTA (higher order tracking accuracy) with DetA, AssA and LocA, one episode, jittable.

Luiten et al., "HOTA: a higher order metric for evaluating multi-object tracking", IJCV 2021,
as TrackEval's ``HOTA.eval_sequence`` computes it. With a similarity :math:`S \in [0, 1]` of
each object-hypothesis pair (IoU for boxes; :math:`\max(0, 1 - d / d_0)` on the ground plane,
TrackEval's ``_calculate_euclidean_similarity``):

1. a global alignment of ids, :math:`A_{oh} = P_{oh} / (n_o + n_h - P_{oh})`, where
   :math:`P_{oh}` sums over frames the pair's similarity divided by its row plus column sums
   minus itself, and :math:`n_o, n_h` count the frames of each id;
2. per frame, the Hungarian matching maximising :math:`\sum A_{oh} S_{oh}`;
3. for each localisation threshold :math:`\alpha \in \{0.05, 0.10, \dots, 0.95\}`, the matched
   pairs with :math:`S \ge \alpha` are true positives (TP), the rest of the objects misses
   (FN) and of the hypotheses false positives (FP), and

.. math::
    \mathrm{DetA}_\alpha = \frac{|TP|}{|TP| + |FN| + |FP|},\quad
    \mathrm{AssA}_\alpha = \frac{1}{|TP|} \sum_{c \in TP}
        \frac{|TPA(c)|}{|TPA(c)| + |FNA(c)| + |FPA(c)|},\quad
    \mathrm{HOTA}_\alpha = \sqrt{\mathrm{DetA}_\alpha \mathrm{AssA}_\alpha}

with :math:`|TPA(c)|` the frames matched to the same pair of ids as c. ``LocA`` is the mean
similarity of the true positives; every score is reported per :math:`\alpha` and averaged over
the 19 thresholds, as TrackEval reports it.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax import lax

from jaxtrack import _checks
from jaxtrack.metrics import _pairs

Array = jax.Array

__all__ = ["HOTAResult", "hota", "combine", "ALPHAS", "SIMILARITIES"]

#: TrackEval's localisation thresholds, ``np.arange(0.05, 0.99, 0.05)`` (19 values).
ALPHAS = np.arange(0.05, 0.99, 0.05)
SIMILARITIES = ("euclidean", "iou")
_EPS = float(np.finfo(np.float64).eps)  # TrackEval's np.finfo('float').eps


class HOTAResult(NamedTuple):
    """HOTA and its parts (TrackEval's fields), averaged over `ALPHAS`, and per threshold.

    Attributes:
      hota, deta, assa, loca, detre, detpr, assre, asspr: means over the 19 thresholds.
      hota_alpha, deta_alpha, assa_alpha, loca_alpha, detre_alpha, detpr_alpha, assre_alpha,
        asspr_alpha: [19] the same per threshold.
      tp, fn, fp: [19] int32 true positives, misses and false positives per threshold.
    """

    hota: Array
    deta: Array
    assa: Array
    loca: Array
    detre: Array
    detpr: Array
    assre: Array
    asspr: Array
    hota_alpha: Array
    deta_alpha: Array
    assa_alpha: Array
    loca_alpha: Array
    detre_alpha: Array
    detpr_alpha: Array
    assre_alpha: Array
    asspr_alpha: Array
    tp: Array
    fn: Array
    fp: Array


def hota(gt_ids: Array, gt_pos: Array, gt_mask: Array | None, hyp_ids: Array, hyp_pos: Array,
         hyp_mask: Array | None, *, similarity: str = "euclidean", zero_distance: float = 2.0,
         max_ids: int | None = None, max_hyp_ids: int | None = None) -> HOTAResult:
    r"""HOTA, DetA, AssA and LocA of one episode (module doc), as TrackEval computes them.

    Inputs are laid out as for `jaxtrack.metrics.clear_mot`; ids may be any non-negative
    integers. Non-finite positions have similarity 0 to everything.

    Args:
      gt_ids: [T, G] integer object ids, -1 in empty slots; unique per frame.
      gt_pos: [T, G, d] object positions (m), or boxes [T, G, 4] (left, top, width, height)
        with ``similarity="iou"``.
      gt_mask: optional [T, G] bools.
      hyp_ids: [T, H] integer hypothesis ids, -1 in empty slots.
      hyp_pos: [T, H, d] hypothesis positions or boxes.
      hyp_mask: optional [T, H] bools.
      similarity: ``"euclidean"``: :math:`\max(0, 1 - d / d_0)`, or ``"iou"``. Static.
      zero_distance: :math:`d_0` (m), the distance of similarity 0; TrackEval's default 2.0 puts
        the 0.5 threshold at 1 m. May be traced.
      max_ids, max_hyp_ids: static bounds on the distinct object and hypothesis ids (default
        ``T * G`` and ``T * H``); memory is O(19 max_ids max_hyp_ids).

    Returns:
      `HOTAResult`.

    Example:
      >>> from jaxtrack import metrics
      >>> res = metrics.hota(gt_ids, gt_pos, None, hyp_ids, hyp_pos, None, zero_distance=1.0)
      >>> res.hota, res.deta, res.assa
    """
    if not isinstance(similarity, str) or similarity not in SIMILARITIES:
        raise ValueError(f"unknown similarity {similarity!r}; expected one of "
                         f"{list(SIMILARITIES)}")
    T, G, H = _pairs.check_inputs(gt_ids, gt_pos, gt_mask, hyp_ids, hyp_pos, hyp_mask)
    _pairs.check_distance(similarity, np.shape(gt_pos)[2])
    max_ids = _pairs.check_id_bound("max_ids", max_ids, T * G, gt_ids, gt_mask)
    max_hyp_ids = _pairs.check_id_bound("max_hyp_ids", max_hyp_ids, T * H, hyp_ids, hyp_mask)
    if _checks.is_concrete(zero_distance):
        if np.ndim(zero_distance) != 0 or not float(zero_distance) > 0 \
                or not np.isfinite(zero_distance):
            raise ValueError(f"zero_distance must be a positive scalar (m); got "
                             f"{zero_distance!r}")
    dtype = jnp.result_type(gt_pos, hyp_pos, float)
    return _hota(jnp.asarray(gt_ids), jnp.asarray(gt_pos, dtype), gt_mask, jnp.asarray(hyp_ids),
                 jnp.asarray(hyp_pos, dtype), hyp_mask, jnp.asarray(zero_distance, dtype),
                 similarity, max_ids, max_hyp_ids)


def combine(results: HOTAResult) -> HOTAResult:
    """Pool the HOTA results of a batch of episodes as TrackEval's ``combine_sequences``: TP,
    FN and FP summed, AssA, AssRe, AssPr and LocA averaged weighted by TP, then the rest.

    Example:
      >>> metrics.combine_hota(jax.vmap(metrics.hota)(gt_ids, gt_pos, None, ...)).hota
    """
    if not isinstance(results, HOTAResult):
        raise TypeError(f"results must be a HOTAResult; got {type(results).__name__}")
    return _combine(results)


# ---------------------------------------------------------------------------------------------
# Internals


def _similarity(a, b, kind, zero_distance):
    if kind == "iou":
        s = _pairs.box_iou(a, b)
    else:
        s = jnp.maximum(0.0, 1.0 - _pairs.euclidean(a, b) / zero_distance)
    return jnp.where(jnp.isfinite(s), s, 0.0)


@functools.partial(jax.jit, static_argnames=("kind", "max_ids", "max_hyp_ids"))
def _hota(gt_ids, gt_pos, gt_mask, hyp_ids, hyp_pos, hyp_mask, zero_distance, kind, max_ids,
          max_hyp_ids):
    dtype = gt_pos.dtype
    G, H = gt_ids.shape[1], hyp_ids.shape[1]
    gi, gv = _pairs.dense_ids(gt_ids, _pairs.present_slots(gt_ids, gt_mask), max_ids)
    hi, hv = _pairs.dense_ids(hyp_ids, _pairs.present_slots(hyp_ids, hyp_mask), max_hyp_ids)
    sim = jax.vmap(lambda a, b: _similarity(a, b, kind, zero_distance))(gt_pos, hyp_pos)
    pair = gv[:, :, None] & hv[:, None, :]
    sim = jnp.where(pair, sim, 0.0)
    alphas = jnp.asarray(ALPHAS, dtype)
    A = len(ALPHAS)

    # 1. Global alignment of the ids.
    denom = sim.sum(1, keepdims=True) + sim.sum(2, keepdims=True) - sim
    sim_iou = jnp.where(denom > _EPS, sim / jnp.where(denom > _EPS, denom, 1.0), 0.0)
    rows = jnp.broadcast_to(gi[:, :, None], sim.shape).reshape(-1)
    cols = jnp.broadcast_to(hi[:, None, :], sim.shape).reshape(-1)
    potential = jnp.zeros((max_ids, max_hyp_ids), dtype).at[rows, cols].add(sim_iou.reshape(-1))
    gt_count = jnp.zeros((max_ids,), dtype).at[gi.reshape(-1)].add(gv.reshape(-1).astype(dtype))
    hyp_count = jnp.zeros((max_hyp_ids,), dtype).at[hi.reshape(-1)].add(
        hv.reshape(-1).astype(dtype))
    union = gt_count[:, None] + hyp_count[None, :] - potential
    alignment = jnp.where(union > 0, potential / jnp.where(union > 0, union, 1.0), 0.0)

    # 2-3. Per frame: the matching, then the counts per threshold.
    def frame(matches, inp):
        s, g_idx, g_ok, h_idx, h_ok = inp
        n_g = jnp.sum(g_ok).astype(jnp.int32)
        n_h = jnp.sum(h_ok).astype(jnp.int32)
        if G > 0 and H > 0:
            score = alignment[g_idx[:, None], h_idx[None, :]] * s
            # Absent slots score 0 and never pass a threshold; the matching is piecewise
            # constant in the positions, so no gradient flows through it.
            r, c = optax.assignment.hungarian_algorithm(lax.stop_gradient(-score))
            chosen = jnp.zeros((G, H), bool).at[r, c].set(True)
        else:
            chosen = jnp.zeros((G, H), bool)
        ok = chosen[None] & (s[None] >= alphas[:, None, None] - _EPS) & (s[None] > 0)
        num = jnp.sum(ok, (1, 2)).astype(jnp.int32)
        loc = jnp.sum(jnp.where(ok, s[None], 0.0), (1, 2))
        a_idx = jnp.broadcast_to(jnp.arange(A)[:, None, None], ok.shape).reshape(-1)
        r_idx = jnp.broadcast_to(g_idx[None, :, None], ok.shape).reshape(-1)
        c_idx = jnp.broadcast_to(h_idx[None, None, :], ok.shape).reshape(-1)
        matches = matches.at[a_idx, r_idx, c_idx].add(ok.reshape(-1).astype(dtype))
        return matches, (num, n_g - num, n_h - num, loc)

    init = jnp.zeros((A, max_ids, max_hyp_ids), dtype)
    matches, (tp, fn, fp, loc) = lax.scan(frame, init, (sim, gi, gv, hi, hv))
    tp, fn, fp, loc = tp.sum(0), fn.sum(0), fp.sum(0), loc.sum(0)

    tp_f = jnp.maximum(1.0, tp.astype(dtype))
    assa = jnp.sum(matches * matches / jnp.maximum(
        1.0, gt_count[None, :, None] + hyp_count[None, None, :] - matches), (1, 2)) / tp_f
    assre = jnp.sum(matches * matches / jnp.maximum(1.0, gt_count[None, :, None]), (1, 2)) / tp_f
    asspr = jnp.sum(matches * matches / jnp.maximum(1.0, hyp_count[None, None, :]),
                    (1, 2)) / tp_f
    loca = jnp.maximum(1e-10, loc) / jnp.maximum(1e-10, tp.astype(dtype))
    # TrackEval's early return when either side has no detection at all: LocA = 1.
    empty = (jnp.sum(gv) == 0) | (jnp.sum(hv) == 0)
    loca = jnp.where(empty, jnp.ones_like(loca), loca)
    return _finish(tp, fn, fp, assa, assre, asspr, loca)


def _finish(tp, fn, fp, assa, assre, asspr, loca):
    dtype = loca.dtype
    tp_, fn_, fp_ = (x.astype(dtype) for x in (tp, fn, fp))
    detre = tp_ / jnp.maximum(1.0, tp_ + fn_)
    detpr = tp_ / jnp.maximum(1.0, tp_ + fp_)
    deta = tp_ / jnp.maximum(1.0, tp_ + fn_ + fp_)
    hota_a = jnp.sqrt(deta * assa)
    per = dict(hota_alpha=hota_a, deta_alpha=deta, assa_alpha=assa, loca_alpha=loca,
               detre_alpha=detre, detpr_alpha=detpr, assre_alpha=assre, asspr_alpha=asspr)
    means = {k[:-len("_alpha")]: jnp.mean(v, -1) for k, v in per.items()}
    return HOTAResult(**means, **per, tp=tp, fn=fn, fp=fp)


@jax.jit
def _combine(r):
    axes = tuple(range(r.tp.ndim - 1))
    tp = jnp.sum(r.tp, axes)
    dtype = r.loca_alpha.dtype
    w = r.tp.astype(dtype)

    def weighted(x):
        return jnp.sum(x * w, axes) / jnp.maximum(1.0, tp.astype(dtype))

    loca = jnp.maximum(1e-10, jnp.sum(r.loca_alpha * w, axes)) / jnp.maximum(
        1e-10, tp.astype(dtype))
    return _finish(tp, jnp.sum(r.fn, axes), jnp.sum(r.fp, axes), weighted(r.assa_alpha),
                   weighted(r.assre_alpha), weighted(r.asspr_alpha), loca)
