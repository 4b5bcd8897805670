"""Shared pieces of the multi-object metrics: the pairwise distance or similarity of the objects
and hypotheses of one frame, and the renumbering of arbitrary ids to dense indices under `jit`.

Positions are ground-plane points ``[.., d]`` (``"euclidean"``) or image boxes ``[.., 4]`` as
``(left, top, width, height)`` in pixels (``"iou"``), the MOTChallenge layout.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import _checks

Array = jax.Array

DISTANCES = ("euclidean", "iou")


def check_distance(distance: str, d: int) -> None:
    """A known distance name, and 4 columns for boxes."""
    if not isinstance(distance, str) or distance not in DISTANCES:
        raise ValueError(f"unknown distance {distance!r}; expected one of {list(DISTANCES)}")
    if distance == "iou" and d != 4:
        raise ValueError(f"distance='iou' needs boxes (left, top, width, height) in the last "
                         f"axis of the positions (size 4); got size {d}")


def euclidean(a: Array, b: Array) -> Array:
    """[G, H] Euclidean distances of a [G, d] and b [H, d], with a finite gradient at 0 (NaN
    stays NaN)."""
    diff = a[:, None, :] - b[None, :, :]
    sq = jnp.sum(diff * diff, -1)
    positive = sq > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, sq, 1.0)), sq)


def box_iou(a: Array, b: Array) -> Array:
    r"""[G, H] intersection over union of boxes a [G, 4] and b [H, 4] (left, top, width, height).

    .. math:: \mathrm{IoU} = |a \cap b| / (|a| + |b| - |a \cap b|)

    0 where the boxes do not overlap, as py-motmetrics' ``boxiou`` (which TrackEval's
    ``_calculate_box_ious`` equals for boxes of positive area). NaN coordinates give NaN.
    """
    a_min, a_max = a[:, None, :2], a[:, None, :2] + a[:, None, 2:]
    b_min, b_max = b[None, :, :2], b[None, :, :2] + b[None, :, 2:]
    size = jnp.maximum(jnp.minimum(a_max, b_max) - jnp.maximum(a_min, b_min), 0.0)
    inter = size[..., 0] * size[..., 1]
    area_a = jnp.prod(jnp.maximum(a_max - a_min, 0.0), -1)
    area_b = jnp.prod(jnp.maximum(b_max - b_min, 0.0), -1)
    union = area_a + area_b - inter
    safe = jnp.where(union > 0, union, 1.0)
    iou = jnp.where(inter == 0, 0.0, inter / safe)
    nan = jnp.isnan(inter) | jnp.isnan(union)
    return jnp.where(nan, jnp.nan, iou)


def distance_matrix(a: Array, b: Array, distance: str) -> Array:
    """[G, H] match distances: metres (``"euclidean"``) or ``1 - IoU`` (``"iou"``, the distance
    py-motmetrics uses for MOTChallenge boxes)."""
    if distance == "iou":
        return 1.0 - box_iou(a, b)
    return euclidean(a, b)


def dense_ids(ids: Array, present: Array, size: int) -> tuple[Array, Array]:
    """Renumber the present ids to 0, 1, ... in increasing id order, under `jit`.

    Args:
      ids: [T, S] integer ids.
      present: [T, S] bools.
      size: static bound on the number of distinct present ids.

    Returns:
      (index [T, S] in [0, size), valid [T, S]): ``valid`` is False where the slot is absent or
      its id is beyond the ``size`` smallest distinct ids (only possible under tracing; callers
      count those as invalid).
    """
    flat = jnp.where(present, ids, jnp.iinfo(ids.dtype).max).reshape(-1)
    table = jnp.unique(flat, size=size, fill_value=jnp.iinfo(ids.dtype).max)
    index = jnp.clip(jnp.searchsorted(table, ids), 0, size - 1)
    valid = present & (table[index] == ids) & (ids != jnp.iinfo(ids.dtype).max)
    return jnp.where(valid, index, 0).astype(jnp.int32), valid


def check_inputs(gt_ids, gt_pos, gt_mask, hyp_ids, hyp_pos, hyp_mask):
    """Shapes and dtypes of the common metric inputs; returns (T, G, H)."""
    _checks.check_ndim("gt_ids", gt_ids, 2, "[T, G] object ids")
    T, G = _checks.shape_of(gt_ids)
    _checks.check_ndim("gt_pos", gt_pos, 3, "[T, G, d] object positions")
    d = _checks.shape_of(gt_pos)[2]
    _checks.check_shape("gt_pos", gt_pos, (T, G, d), "[T, G, d] object positions")
    _checks.check_ndim("hyp_ids", hyp_ids, 2, "[T, H] hypothesis ids")
    H = _checks.shape_of(hyp_ids)[1]
    _checks.check_shape("hyp_ids", hyp_ids, (T, H), f"[T, H] hypothesis ids with T = {T}")
    _checks.check_shape("hyp_pos", hyp_pos, (T, H, d), f"[T, H, d] positions with d = {d}")
    if gt_mask is not None:
        _checks.check_shape("gt_mask", gt_mask, (T, G), "[T, G] bools")
    if hyp_mask is not None:
        _checks.check_shape("hyp_mask", hyp_mask, (T, H), "[T, H] bools")
    for name, ids in (("gt_ids", gt_ids), ("hyp_ids", hyp_ids)):
        if not jnp.issubdtype(jnp.result_type(ids), jnp.integer):
            raise ValueError(f"{name} must be integers; got dtype {jnp.result_type(ids)}")
    for name, pos in (("gt_pos", gt_pos), ("hyp_pos", hyp_pos)):
        if not jnp.issubdtype(jnp.result_type(pos), jnp.floating):
            raise ValueError(f"{name} must be floating point; got dtype {jnp.result_type(pos)}")
    return T, G, H


def check_id_bound(name, value, default, ids, mask):
    """A static bound on the distinct ids (default ``default``), checked when concrete."""
    if value is None:
        value = max(int(default), 1)
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive int; got {value!r}")
    distinct = count_distinct(ids, mask)
    if distinct is not None and distinct > value:
        raise ValueError(f"{name} = {value} is smaller than the {distinct} distinct ids given")
    return int(value)


def count_distinct(ids, mask) -> int | None:
    """Number of distinct present ids when concrete, else None."""
    if not (_checks.is_concrete(ids) and (mask is None or _checks.is_concrete(mask))):
        return None
    ids = np.asarray(ids)
    present = ids >= 0 if mask is None else (ids >= 0) & np.asarray(mask, bool)
    return int(np.unique(ids[present]).size)


def present_slots(ids: Array, mask: Array | None) -> Array:
    present = jnp.asarray(ids) >= 0
    if mask is not None:
        present = present & jnp.asarray(mask, bool)
    return present
