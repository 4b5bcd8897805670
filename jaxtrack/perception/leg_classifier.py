r"""A learned leg classifier: a random forest over the segment features of
`jaxtrack.perception.leg_features`, evaluated as a jitted, vmappable JAX function.

Seed 004 detects legs with Arras et al.'s boosted classifier over segment features; the ROS leg
tracker of Leigh et al. (ICRA 2015) trains a random forest on the same kind of features. Here a
scikit-learn ``RandomForestClassifier`` is trained offline (`fit`, or ``jaxtrack train-legs``;
scikit-learn is only needed for training) and converted into fixed-shape arrays,
`LegClassifier`, whose evaluation is

.. math:: P(\text{leg} \mid x) = \frac{1}{T} \sum_{t=1}^{T} v_t(\text{leaf}_t(x)),

:math:`v_t` the fraction of leg samples in the leaf of tree :math:`t` that :math:`x` falls in
(scikit-learn's ``predict_proba``). The trees are walked level by level, all segments and
trees at once: :math:`D` gathers for depth :math:`D`, no data-dependent branching.

Splits compare float32 features, as scikit-learn does (it casts its input to float32); each
stored threshold is the largest float32 not above scikit-learn's float64 threshold, so that
``x <= threshold`` decides the same way in float32 arithmetic, and the JAX probabilities equal
``predict_proba``'s.

A trained model ships with the package (`default`): trained on the six labelled bags and the
negative bag of ``angusleigh/leg_tracker`` (768 beams over 270 deg, 0.35 deg steps).
For a scanner of a different resolution, train a model on its own scans (``jaxtrack
train-legs``): the point counts and steps of a leg depend on the beam spacing.

Example:
  >>> model = leg_classifier.default()
  >>> segs = legs.segment(ranges, angles, 5.6, jump=model.jump)
  >>> p = leg_classifier.predict_proba(model, leg_features.compute(ranges, angles, segs, 5.6))
"""

from __future__ import annotations

import functools
from importlib import resources
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxtrack import _checks
from jaxtrack.perception import leg_features

Array = jax.Array

__all__ = ["LegClassifier", "predict_proba", "candidates", "is_leg", "from_sklearn", "fit",
           "save", "load", "metadata", "default", "resolve", "DEFAULT_MODEL"]

DEFAULT_MODEL = "leg_forest.npz"
_FORMAT = 1


class LegClassifier(NamedTuple):
    """A tree ensemble in fixed-shape arrays (T trees padded to N nodes).

    Attributes:
      feature: [T, N] int32 feature index each node splits on (0 at leaves).
      threshold: [T, N] float32: a sample goes left when ``x[feature] <= threshold``.
      left, right: [T, N] int32 children; leaves (and padding) point to themselves.
      value: [T, N] float32 fraction of leg samples at each node (used at leaves).
      levels: [D] int32, ``arange(D)``, D the depth of the deepest tree. Only its length is
        used: the number of levels to walk, static under `jax.jit`.
      decision: scalar, the probability at or above which a segment is a leg (0.5).
      jump: scalar, the segmentation break distance the model was trained with (m).
      min_points: scalar, segments with fewer points are never legs.
      max_width: scalar, segments wider than this are never legs (m; `train` sets 1.5 times
        the widest leg segment of its training set). With `min_points`, the cheap test that
        decides which segments the forest evaluates at all.
    """

    feature: Array
    threshold: Array
    left: Array
    right: Array
    value: Array
    levels: Array
    decision: Array
    jump: Array
    min_points: Array
    max_width: Array


def predict_proba(model: LegClassifier, X: Array) -> Array:
    """Leg probability of each segment.

    Args:
      model: `LegClassifier`.
      X: [..., NUM_FEATURES] segment features (`leg_features.compute`).

    Returns:
      [...] probabilities in [0, 1] (the mean leaf value over the trees).

    Example:
      >>> p = jax.jit(predict_proba)(model, X)        # X [S, 14] -> p [S]
    """
    shape = _checks.shape_of(X)
    if len(shape) < 1 or shape[-1] != leg_features.NUM_FEATURES:
        raise ValueError(f"X must have {leg_features.NUM_FEATURES} features in its last axis "
                         f"({', '.join(leg_features.FEATURE_NAMES)}); got shape "
                         f"{tuple(shape)}")
    X = jnp.asarray(X)
    lead = X.shape[:-1]
    flat = X.reshape(-1, X.shape[-1]).astype(jnp.float32)
    return _forest(model, flat).reshape(lead)


def candidates(model: LegClassifier, X: Array, mask: Array) -> Array:
    """[S] bools: the segments in ``mask`` that may be legs at all (at least ``min_points``
    points, at most ``max_width`` wide); the forest decides among them."""
    return mask & (X[:, 0] >= model.min_points) & (X[:, 1] <= model.max_width)


def is_leg(model: LegClassifier, X: Array, mask: Array, *, capacity: int | None = None,
           threshold=None) -> tuple[Array, Array, Array]:
    """Leg decisions for the features X [S, F] of the segments in ``mask`` [S].

    The forest runs on the `candidates` only, compacted into ``capacity`` rows (static; None:
    all S rows): a scan has a few dozen segments, of which a handful are leg-sized, and the
    forest is most of the detector's cost. Candidates beyond the capacity (in beam order) are
    not legs, and counted.

    Returns:
      ``(legs [S] bools, probabilities [S] (0 for non-candidates), dropped scalar int32)``;
      a leg is a candidate with probability at least ``threshold`` (default ``decision``).
    """
    S = X.shape[0]
    cand = candidates(model, X, mask)
    threshold = model.decision if threshold is None else threshold
    if capacity is None or int(capacity) >= S:
        p = jnp.where(cand, predict_proba(model, X), 0.0)
        dropped = jnp.zeros((), jnp.int32)
    else:
        K = int(capacity)
        rows = jnp.nonzero(cand, size=K, fill_value=S)[0]
        pk = predict_proba(model, X[jnp.minimum(rows, S - 1)])
        p = jnp.zeros(S, pk.dtype).at[rows].set(pk, mode="drop")
        dropped = jnp.maximum(jnp.sum(cand) - K, 0).astype(jnp.int32)
        cand = cand & (jnp.cumsum(cand) <= K)
    return cand & (p >= threshold), p, dropped


def _forest(model: LegClassifier, X):
    """[M, F] float32 -> [M] mean leaf value. (Packing each node's split into one int32
    record, to gather it once per level, measured 10 % slower on XLA:CPU than these five
    gathers.)"""
    rows = jnp.arange(X.shape[0])

    def tree(feature, threshold, left, right, value):
        def level(_, node):
            x = X[rows, feature[node]]
            return jnp.where(x <= threshold[node], left[node], right[node])

        node = lax.fori_loop(0, model.levels.shape[0], level,
                             jnp.zeros(X.shape[0], jnp.int32))
        return value[node]

    votes = jax.vmap(tree)(model.feature, model.threshold, model.left, model.right, model.value)
    return jnp.mean(votes, 0)


# --------------------------------------------------------------------------- training & files


def from_sklearn(forest, *, decision: float = 0.5, jump: float = 0.13,
                 min_points: int = 3, max_width: float = np.inf) -> LegClassifier:
    """Convert a fitted scikit-learn ``RandomForestClassifier`` (or a single
    ``DecisionTreeClassifier``) with classes {0, 1} (1 = leg) into a `LegClassifier`.

    Example:
      >>> model = from_sklearn(RandomForestClassifier(32).fit(X, y), jump=0.13)
    """
    trees = getattr(forest, "estimators_", None) or [forest]
    classes = list(getattr(forest, "classes_", [0, 1]))
    if classes != [0, 1]:
        raise ValueError(f"the forest's classes must be [0, 1] (1 = leg); got {classes}")
    n_features = getattr(forest, "n_features_in_", None)
    if n_features != leg_features.NUM_FEATURES:
        raise ValueError(f"the forest was fitted on {n_features} features; the leg features "
                         f"are {leg_features.NUM_FEATURES}")
    N = max(t.tree_.node_count for t in trees)
    D = max(max(t.tree_.max_depth for t in trees), 1)
    T = len(trees)
    feature = np.zeros((T, N), np.int32)
    threshold = np.zeros((T, N), np.float32)
    left = np.tile(np.arange(N, dtype=np.int32), (T, 1))
    right = left.copy()
    value = np.zeros((T, N), np.float32)
    for k, est in enumerate(trees):
        t = est.tree_
        n = t.node_count
        internal = t.children_left >= 0
        feature[k, :n] = np.where(internal, t.feature, 0)
        threshold[k, :n] = np.where(internal, _float32_floor(t.threshold), 0.0)
        left[k, :n] = np.where(internal, t.children_left, np.arange(n))
        right[k, :n] = np.where(internal, t.children_right, np.arange(n))
        counts = np.asarray(t.value)[:, 0, :]
        value[k, :n] = counts[:, 1] / np.maximum(counts.sum(1), 1e-300)
    return LegClassifier(jnp.asarray(feature), jnp.asarray(threshold), jnp.asarray(left),
                         jnp.asarray(right), jnp.asarray(value), jnp.arange(D, dtype=jnp.int32),
                         jnp.asarray(decision, jnp.float32), jnp.asarray(jump, jnp.float32),
                         jnp.asarray(float(min_points), jnp.float32),
                         jnp.asarray(max_width, jnp.float32))


def _float32_floor(t: np.ndarray) -> np.ndarray:
    """Largest float32 <= each float64 value: for float32 x, ``x <= t`` iff ``x <= floor(t)``."""
    t = np.asarray(t, np.float64)
    f = t.astype(np.float32)
    above = f.astype(np.float64) > t
    f[above] = np.nextafter(f[above], np.float32(-np.inf))
    return f


def fit(X, y, *, n_estimators: int = 32, max_depth: int = 10, min_samples_leaf: int = 2,
        seed: int = 0, decision: float = 0.5, jump: float = 0.13, min_points: int = 3,
        max_width: float | None = None, class_weight=None, oob_score: bool = False):
    """Train a random forest on segment features (needs scikit-learn: ``pip install
    jaxtrack[train]``).

    Args:
      X: [M, NUM_FEATURES] features; y: [M] labels, 1 = leg, 0 = not a leg.
      n_estimators, max_depth, min_samples_leaf, class_weight, oob_score: the forest's
        (scikit-learn's meanings); seed: its random_state.
      decision, jump, min_points, max_width: stored in the model (see `LegClassifier`;
        ``max_width`` None: 1.5 times the widest leg in X).

    Returns:
      ``(LegClassifier, the fitted sklearn forest)``.
    """
    try:
        from sklearn.ensemble import RandomForestClassifier
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError("training a leg classifier needs scikit-learn: "
                          "pip install 'jaxtrack[train]'") from err
    X = np.asarray(X, np.float64)
    y = np.asarray(y)
    if X.ndim != 2 or X.shape[1] != leg_features.NUM_FEATURES:
        raise ValueError(f"X must be [M, {leg_features.NUM_FEATURES}]; got {X.shape}")
    if y.shape != (X.shape[0],):
        raise ValueError(f"y must be [M] = [{X.shape[0]}]; got {y.shape}")
    if not np.all(np.isfinite(X)):
        raise ValueError("X contains NaN or inf")
    if set(np.unique(y).tolist()) != {0, 1}:
        raise ValueError(f"y must hold both labels 0 and 1; got {np.unique(y).tolist()}")
    forest = RandomForestClassifier(n_estimators=int(n_estimators), max_depth=int(max_depth),
                                    min_samples_leaf=int(min_samples_leaf),
                                    class_weight=class_weight, oob_score=bool(oob_score),
                                    random_state=int(seed), n_jobs=1)
    forest.fit(X, y.astype(int))
    if max_width is None:
        max_width = 1.5 * float(np.max(X[y == 1, 1]))
    return from_sklearn(forest, decision=decision, jump=jump, min_points=min_points,
                        max_width=max_width), forest


def save(path, model: LegClassifier, **metadata) -> Path:
    """Write a model to ``path`` exactly (npz format; with the feature names and any string /
    number metadata, e.g. the bags it was trained on). Returns the path."""
    path = Path(path)
    meta = {f"meta_{k}": np.asarray(v) for k, v in metadata.items()}
    # Through a file object: numpy would append ".npz" to a path without it.
    with open(path, "wb") as f:
        np.savez_compressed(f, format=np.int32(_FORMAT),
                            feature_names=np.asarray(leg_features.FEATURE_NAMES),
                            **{k: np.asarray(v) for k, v in model._asdict().items()}, **meta)
    return path


def load(path) -> LegClassifier:
    """Read a model written by `save` (a clear error for another file or feature set)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no leg classifier file at {path}")
    try:
        with np.load(path, allow_pickle=False) as z:
            fmt = int(z["format"])
            names = tuple(str(n) for n in z["feature_names"])
            arrays = {k: np.asarray(z[k]) for k in LegClassifier._fields}
    except (KeyError, ValueError, OSError) as err:
        raise ValueError(f"{path} is not a jaxtrack leg classifier file ({err})") from err
    if fmt != _FORMAT:
        raise ValueError(f"{path}: leg classifier format {fmt}; this version reads {_FORMAT}")
    if names != leg_features.FEATURE_NAMES:
        raise ValueError(f"{path} was trained on features {names}; this version computes "
                         f"{leg_features.FEATURE_NAMES}")
    return LegClassifier(**{k: jnp.asarray(v) for k, v in arrays.items()})


def metadata(path) -> dict:
    """The metadata stored by `save` (strings and numbers)."""
    with np.load(Path(path), allow_pickle=False) as z:
        return {k[5:]: z[k].tolist() for k in z.files if k.startswith("meta_")}


@functools.lru_cache(maxsize=1)
def default() -> LegClassifier:
    """The model shipped with the package (see the module docstring)."""
    ref = resources.files("jaxtrack.perception") / "data" / DEFAULT_MODEL
    with resources.as_file(ref) as p:
        return load(p)


def resolve(detector: str) -> LegClassifier | None:
    """A leg detector by name: ``"geometric"`` (None: `legs.leg_candidates`' thresholds),
    ``"learned"`` (`default`) or the path of a model file (`load`, cached by path)."""
    if detector == "geometric":
        return None
    if detector == "learned":
        return default()
    return _load_cached(str(Path(detector).resolve()))


@functools.lru_cache(maxsize=8)
def _load_cached(path: str) -> LegClassifier:
    return load(path)
