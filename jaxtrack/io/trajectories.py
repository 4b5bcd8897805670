r"""Pedestrian-trajectory files and MOTChallenge-style CSV, read into fixed-shape ground truth.

Files are parsed with plain Python / numpy at the boundary; everything returned is a
`jax.numpy` array in the layout of `jaxtrack.metrics.clear_mot`: per frame, a fixed number P of
person slots with ids (-1 in empty slots), ground-plane positions (m) and a mask. Within a frame
the people are sorted by id, so the layout of a file is unique.

Formats (``#`` comments and blank lines are skipped everywhere):

- **ETH / UCY** ``obsmat.txt`` (Pellegrini et al., "You'll never walk alone", ICCV 2009):
  whitespace-separated rows ``frame id x z y vx vz vy`` (8 floats; frame and id are stored as
  floats such as ``7.8000000e+02``). ``x, y`` are the ground plane, ``z`` the height (0 in the
  published files); positions in m, velocities in m/s. ``read_obsmat`` keeps ``x, y, vx, vy``.
- **Plain**: rows ``frame id x y``, separated by whitespace or commas (`read_plain`).
- **MOTChallenge CSV** (Milan et al., "MOT16: a benchmark for multi-object tracking", 2016),
  ground-plane "3D" form: ``frame, id, bb_left, bb_top, bb_width, bb_height, conf, x, y, z``
  (10 columns). `read_mot_csv` reads columns 1 (frame), 2 (id), 8 (x) and 9 (y), 1-based; the
  image columns, ``conf`` and ``z`` are not interpreted. It also accepts the short form
  ``frame,id,x,y`` (4 columns). A file whose ``x, y, z`` are -1 in every row (an image-plane
  MOT file) is refused.
  `write_mot_csv` writes the 10-column form with ``-1`` in the four image columns, ``conf = 1``,
  ``z = 0``, ids as given (no shift to 1-based) and positions with the shortest decimal that
  reads back to the same float, so its output reads back identically.
- **MOTChallenge image-plane files** (`read_mot_boxes`, format ``"mot2d"``): rows ``frame, id,
  bb_left, bb_top, bb_width, bb_height, conf, ...`` with 9 (MOT16 and later ground truth) or 10
  columns (MOT15, and every results file), separated by commas or whitespace. The boxes are
  matched by IoU (py-motmetrics: ``1 - IoU <= 0.5``). Rows below ``min_confidence`` are dropped,
  as py-motmetrics' loader does; MOT16+'s class and visibility columns are not interpreted.

`evaluate_files` scores one pair of files, `evaluate_sequences` several, with an OVERALL row:
CLEAR MOT, the identity metrics and HOTA, the columns of py-motmetrics' MOTChallenge summary
(`format_summary`, `write_summary`).

Every reader skips one header row whose first field is ``frame``, and raises
`FileNotFoundError` for a missing file and `ValueError` naming the file and the 1-based line
for a malformed row (wrong number of columns, a non-number, a non-integer or negative frame /
id, a non-finite value) and for a repeated (frame, id) pair; a file without data rows is an
error too.
"""

from __future__ import annotations

import os
import re
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import _checks
from jaxtrack.metrics import clear_mot, combine_hota, combine_identity, hota, identity_metrics
from jaxtrack.metrics import combine_clear_mot as clear_mot_combine

Array = jax.Array

__all__ = ["Trajectories", "read_obsmat", "read_plain", "read_mot_csv", "read_mot_boxes",
           "write_mot_csv", "read", "evaluate_files", "evaluate_sequences", "format_clear_mot",
           "format_summary", "write_summary", "FORMATS", "SUMMARY_COLUMNS"]

FORMATS = ("auto", "obsmat", "plain", "mot", "mot2d")


class Trajectories(NamedTuple):
    """Ground-truth (or tracker) trajectories with P person slots per frame.

    Attributes:
      frames: [T] int32 frame numbers, sorted increasing, each once.
      ids: [T, P] int32 person ids (>= 0), -1 in empty slots; sorted within a frame.
      pos: [T, P, 2] ground-plane positions (m), or [T, P, 4] image boxes (left, top, width,
        height; pixels) from `read_mot_boxes`; 0 in empty slots.
      mask: [T, P] bools, True where a slot holds a person.
      vel: [T, P, 2] velocities (m/s) when the file has them (obsmat), 0 in empty slots; else
        None.
      times: [T] times (s), ``frames / fps``, when ``fps`` was given; else None.
    """

    frames: Array
    ids: Array
    pos: Array
    mask: Array
    vel: Array | None = None
    times: Array | None = None


def read_obsmat(path, *, fps: float | None = None, max_people: int | None = None,
                dtype=None) -> Trajectories:
    """Read an ETH / UCY ``obsmat.txt`` (rows ``frame id x z y vx vz vy``; module doc).

    Args:
      path: file path.
      fps: frame rate; when given, ``times = frames / fps`` (ETH and UCY: 25 fps, annotated
        every 10 frames in ETH ``seq_eth``, every 6 in ``seq_hotel``).
      max_people: number of slots P; default the largest number of people in one frame. A
        ``ValueError`` names the first frame with more people.
      dtype: float dtype of ``pos``, ``vel``, ``times`` (default: JAX's default float).

    Returns:
      `Trajectories` with ``vel`` ([T, P, 2], from ``vx, vy``).

    Example:
      >>> traj = read_obsmat("seq_eth/obsmat.txt", fps=25.0)
      >>> traj.pos.shape  # [T, P, 2]
    """
    rows, lines = _parse(path, "obsmat", (8,), r"\s+")
    return _assemble(path, rows[:, 0], rows[:, 1], rows[:, [2, 4]], rows[:, [5, 7]], lines,
                     fps, max_people, dtype)


def read_plain(path, *, fps: float | None = None, max_people: int | None = None,
               dtype=None) -> Trajectories:
    """Read rows ``frame id x y`` separated by whitespace or commas (``vel`` is None).

    Args and Returns as `read_obsmat`.

    Example:
      >>> traj = read_plain("crowd.txt", fps=2.5)
    """
    rows, lines = _parse(path, "plain", (4,), r"[\s,]+")
    return _assemble(path, rows[:, 0], rows[:, 1], rows[:, 2:4], None, lines, fps, max_people,
                     dtype)


def read_mot_csv(path, *, fps: float | None = None, max_people: int | None = None,
                 dtype=None) -> Trajectories:
    """Read a MOTChallenge-style ground-plane CSV: the 10-column "3D" form
    ``frame, id, bb_left, bb_top, bb_width, bb_height, conf, x, y, z`` (columns 1, 2, 8, 9 are
    read) or the short form ``frame,id,x,y``.

    Args and Returns as `read_obsmat` (``vel`` is None).

    Example:
      >>> tracks = read_mot_csv("tracks.csv")
    """
    rows, lines = _parse(path, "MOT CSV", (4, 10), r"\s*,\s*")
    return _assemble(path, rows[:, 0], rows[:, 1], rows[:, 2:4], None, lines, fps, max_people,
                     dtype)


def read_mot_boxes(path, *, min_confidence: float | None = None, fps: float | None = None,
                   max_people: int | None = None, dtype=None) -> Trajectories:
    """Read an image-plane MOTChallenge file: rows ``frame, id, bb_left, bb_top, bb_width,
    bb_height, conf, ...`` (9 or 10 columns; commas or whitespace).

    Args:
      path: file path.
      min_confidence: drop rows whose ``conf`` (column 7) is below it (py-motmetrics'
        MOTChallenge evaluation passes 1 for ground truth, whose ignored boxes have conf 0);
        default: keep every row.
      fps, max_people, dtype: as `read_obsmat`.

    Returns:
      `Trajectories` whose ``pos`` holds boxes [T, P, 4] (left, top, width, height).

    Example:
      >>> gt = read_mot_boxes("MOT17-02/gt/gt.txt", min_confidence=1)
      >>> gt.pos.shape  # [T, P, 4]
    """
    if min_confidence is not None and not np.isfinite(min_confidence):
        raise ValueError(f"min_confidence must be a finite number; got {min_confidence!r}")
    rows, lines = _parse(path, "MOT image-plane", (9, 10), r"[\s,]+", boxes=True)
    name = os.fspath(path)
    if np.all(rows[:, 2:6] == -1):
        raise ValueError(f"{name}: every box is -1 (a ground-plane MOT file, without image "
                         "boxes)")
    if np.any(rows[:, 4:6] < 0):
        k = int(np.argmax(np.any(rows[:, 4:6] < 0, 1)))
        raise ValueError(f"{name}, line {int(lines[k])}: negative box width or height")
    if min_confidence is not None:
        keep = rows[:, 6] >= min_confidence
        if not np.any(keep):
            raise ValueError(f"{name}: no row has conf >= {min_confidence}")
        rows, lines = rows[keep], lines[keep]
    return _assemble(path, rows[:, 0], rows[:, 1], rows[:, 2:6], None, lines, fps, max_people,
                     dtype)


def write_mot_csv(path, frames, ids, pos, mask) -> int:
    """Write trajectories or tracker output as 10-column MOTChallenge ground-plane CSV.

    One row ``frame,id,-1,-1,-1,-1,1,x,y,0`` per present slot (``mask`` True and ``id >= 0``),
    frame by frame, slots in id order. `read_mot_csv` reads the file back to the same
    (frame, id, x, y) rows; frames without anyone are not written.

    Args:
      path: output file (overwritten).
      frames: [T] integer frame numbers.
      ids: [T, P] integer ids (>= 0 where present).
      pos: [T, P, 2] ground-plane positions (m), finite where present.
      mask: [T, P] bools, or None (present where ``id >= 0``).

    Returns:
      The number of rows written.

    Example:
      >>> final, seq = jax.jit(tracking.run)(tracking.init(cfg), dets, params)
      >>> confirmed = seq.status == tracking.CONFIRMED
      >>> write_mot_csv("tracks.csv", traj.frames, seq.id, seq.mean[..., :2], confirmed)
    """
    frames = np.asarray(frames)
    _checks.check_ndim("frames", frames, 1, "[T] frame numbers")
    T = frames.shape[0]
    ids = np.asarray(ids)
    _checks.check_ndim("ids", ids, 2, "[T, P] ids")
    P = ids.shape[1]
    _checks.check_shape("ids", ids, (T, P), f"[T, P] ids with T = {T}")
    pos = np.asarray(pos)
    _checks.check_shape("pos", pos, (T, P, 2), "[T, P, 2] positions")
    for name, a in (("frames", frames), ("ids", ids)):
        if not np.issubdtype(a.dtype, np.integer):
            raise ValueError(f"{name} must be integers; got dtype {a.dtype}")
    present = ids >= 0
    if mask is not None:
        mask = np.asarray(mask)
        _checks.check_shape("mask", mask, (T, P), "[T, P] bools")
        present &= mask.astype(bool)
    if np.any(frames < 0):
        raise ValueError("frames must be >= 0")
    if len(np.unique(frames)) != T:
        raise ValueError("frames must be distinct")
    if not np.all(np.isfinite(pos[present])):
        t = int(np.argmax(~np.all(np.isfinite(np.where(present[..., None], pos, 0.0)), (1, 2))))
        raise ValueError(f"pos contains NaN or inf in a present slot (frame {int(frames[t])})")
    pos64 = pos.astype(np.float64)
    out = []
    for t in np.argsort(frames, kind="stable"):
        slots = np.flatnonzero(present[t])
        slot_ids = ids[t, slots]
        if len(np.unique(slot_ids)) != len(slot_ids):
            raise ValueError(f"ids repeat within frame {int(frames[t])}: "
                             f"{sorted(slot_ids.tolist())}")
        for k in slots[np.argsort(slot_ids, kind="stable")]:
            x, y = (float(v) for v in pos64[t, k])
            out.append(f"{int(frames[t])},{int(ids[t, k])},-1,-1,-1,-1,1,{x!r},{y!r},0\n")
    with open(os.fspath(path), "w") as f:
        f.writelines(out)
    return len(out)


def read(path, fmt: str = "auto", **kwargs) -> Trajectories:
    """Read any supported file: ``fmt`` is ``"obsmat"``, ``"plain"``, ``"mot"``, ``"mot2d"`` or
    ``"auto"`` (8 columns: obsmat; 10 columns: MOT CSV, or image-plane MOT when ``x, y, z`` are -1
    in every row; 9 columns: image-plane MOT; 4 columns: plain, which also reads the short MOT
    form). Keyword arguments go to the reader.

    Example:
      >>> gt = read("obsmat.txt", fps=25.0)
    """
    _checks.check_options("fmt", (fmt,), FORMATS)
    if fmt == "auto":
        fmt = _sniff(path)
    reader = {"obsmat": read_obsmat, "plain": read_plain, "mot": read_mot_csv,
              "mot2d": read_mot_boxes}[fmt]
    return reader(path, **kwargs)


def evaluate_files(gt_path, tracks_path, threshold: float = 0.5, fmt: str = "auto", *,
                   zero_distance: float = 2.0, min_confidence: float | None = None,
                   target_only: bool = False) -> dict:
    """CLEAR MOT, identity metrics and HOTA of a tracks file against a ground-truth file.

    The frames evaluated are those present in either file; a frame missing from the tracks
    file has no hypotheses (its people are misses), a frame missing from the ground truth has
    no objects (its tracks are false positives). Ground-plane files are matched by Euclidean
    distance (m); image-plane MOT files by ``1 - IoU``, so that MOTP is ``1 - IoU`` as
    py-motmetrics reports it. CLEAR MOT uses the ``"motmetrics"`` convention
    (`jaxtrack.metrics.clear_mot`), the identity metrics are py-motmetrics' and HOTA TrackEval's
    (`jaxtrack.metrics.identity_metrics`, `jaxtrack.metrics.hota`).

    Args:
      gt_path, tracks_path: files in any supported format, both ground plane or both image
        plane.
      threshold: largest distance of a correspondence, > 0: metres, or ``1 - IoU`` for boxes
        (0.5 is MOTChallenge's IoU >= 0.5).
      fmt: format of both files, ``"auto"`` (each file sniffed, see `read`), ``"obsmat"``,
        ``"plain"``, ``"mot"`` or ``"mot2d"``.
      zero_distance: HOTA's distance of similarity 0 on the ground plane (m; TrackEval's 2.0).
      min_confidence: image-plane ground truth only: drop boxes whose ``conf`` is below it.
      target_only: score as person-following benchmarks do, where only the followed person
        is labelled: hypotheses farther than ``threshold`` from every labelled object of their
        frame are left out, so tracks of unlabelled people are not false positives.

    Returns:
      dict with the `SUMMARY_COLUMNS` keys (``idf1, idp, idr, recall, precision,
      num_unique_objects, mostly_tracked, partially_tracked, mostly_lost, num_false_positives,
      num_misses, num_switches, num_fragmentations, mota, motp, hota``) plus ``deta, assa,
      loca, num_frames, num_objects, num_predictions, num_matches, idtp, idfp, idfn,
      threshold`` and ``plane`` (``"ground"`` or ``"image"``). Ratios are NaN when undefined.

    Example:
      >>> res = evaluate_files("gt.txt", "tracks.csv", threshold=0.5)
      >>> print(format_summary({"seq": res}))
    """
    return _row(_score_pair(gt_path, tracks_path, threshold, fmt, zero_distance,
                            min_confidence, target_only))


def evaluate_sequences(sequences, threshold: float = 0.5, fmt: str = "auto", *,
                       zero_distance: float = 2.0, min_confidence: float | None = None,
                       target_only: bool = False) -> dict:
    """`evaluate_files` over several sequences, plus an ``"OVERALL"`` row.

    OVERALL pools the counts as py-motmetrics' ``generate_overall`` (MOTA, MOTP, IDF1 and the
    rest from summed counts, each sequence keeping its own id matching) and HOTA as TrackEval's
    ``combine_sequences``. Every sequence must be on the same plane.

    Args:
      sequences: mapping name -> (gt_path, tracks_path), or a sequence of such pairs (named by
        the ground truth's parent folder, or its file name when that repeats).
      threshold, fmt, zero_distance, min_confidence, target_only: as `evaluate_files`.

    Returns:
      dict name -> row (as `evaluate_files`), in the given order, then ``"OVERALL"``.

    Example:
      >>> rows = evaluate_sequences({"TUD-Campus": ("TUD-Campus/gt.txt", "TUD-Campus/test.txt")})
      >>> print(format_summary(rows))
    """
    if isinstance(sequences, dict):
        named = list(sequences.items())
    else:
        pairs = [tuple(p) for p in sequences]
        names = [os.path.basename(os.path.dirname(os.path.abspath(os.fspath(g))))
                 for g, _ in pairs]
        if len(set(names)) != len(names):
            names = [os.fspath(g) for g, _ in pairs]
        named = list(zip(names, pairs))
    if not named:
        raise ValueError("sequences is empty: give at least one (gt, tracks) pair")
    scored = []
    for name, pair in named:
        if len(pair) != 2:
            raise ValueError(f"sequence {name!r}: expected a (gt, tracks) pair; got {pair!r}")
        scored.append((name, _score_pair(pair[0], pair[1], threshold, fmt, zero_distance,
                                         min_confidence, target_only)))
    planes = {sc["plane"] for _, sc in scored}
    if len(planes) > 1:
        raise ValueError("the sequences mix ground-plane and image-plane files")
    rows = {name: _row(sc) for name, sc in scored}
    pooled = dict(scored[0][1])
    pooled["clear"] = clear_mot_combine(_stack([sc["clear"]._replace(frames=None)
                                                for _, sc in scored]))
    pooled["identity"] = combine_identity(_stack([sc["identity"] for _, sc in scored]))
    pooled["hota"] = combine_hota(_stack([sc["hota"] for _, sc in scored]))
    pooled["num_frames"] = sum(sc["num_frames"] for _, sc in scored)
    rows["OVERALL"] = _row(jax.device_get(pooled))
    return rows


#: The columns of py-motmetrics' MOTChallenge summary, and HOTA: (key, header, kind).
SUMMARY_COLUMNS = (
    ("idf1", "IDF1", "%"), ("idp", "IDP", "%"), ("idr", "IDR", "%"), ("recall", "Rcll", "%"),
    ("precision", "Prcn", "%"), ("num_unique_objects", "GT", "int"),
    ("mostly_tracked", "MT", "int"), ("partially_tracked", "PT", "int"),
    ("mostly_lost", "ML", "int"), ("num_false_positives", "FP", "int"),
    ("num_misses", "FN", "int"), ("num_switches", "IDs", "int"),
    ("num_fragmentations", "FM", "int"), ("mota", "MOTA", "%"), ("motp", "MOTP", "float"),
    ("hota", "HOTA", "%"),
)


def format_summary(rows: dict) -> str:
    """py-motmetrics' MOTChallenge summary table of `evaluate_sequences` (or of a dict name ->
    `evaluate_files` row): percentages with one decimal, MOTP with three (``1 - IoU`` for
    boxes, metres on the ground plane).

    Example:
      >>> print(format_summary(evaluate_sequences(pairs)))
    """
    if not rows:
        raise ValueError("rows is empty")
    header = [""] + [h for _, h, _ in SUMMARY_COLUMNS]
    body = []
    for name, row in rows.items():
        cells = [str(name)]
        for key, _, kind in SUMMARY_COLUMNS:
            v = row[key]
            if kind == "int":
                cells.append(str(int(v)))
            elif not np.isfinite(v):
                cells.append("nan")
            elif kind == "%":
                cells.append(f"{100 * v:.1f}%")
            else:
                cells.append(f"{v:.3f}")
        body.append(cells)
    widths = [max(len(r[i]) for r in [header] + body) for i in range(len(header))]
    lines = [" ".join(c.ljust(w) if i == 0 else c.rjust(w)
                      for i, (c, w) in enumerate(zip(r, widths))) for r in [header] + body]
    return "\n".join(lines)


def write_summary(rows: dict, csv_path=None, json_path=None) -> None:
    """Write `evaluate_sequences` rows as CSV (one line per sequence, the `SUMMARY_COLUMNS`
    keys plus ``deta, assa, loca``; full precision) and / or JSON (every field of every row).

    Example:
      >>> write_summary(rows, "summary.csv", "summary.json")
    """
    import csv
    import json

    keys = [k for k, _, _ in SUMMARY_COLUMNS] + ["deta", "assa", "loca"]
    if csv_path is not None:
        with open(os.fspath(csv_path), "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["name"] + keys)
            for name, row in rows.items():
                w.writerow([name] + [row[k] for k in keys])
    if json_path is not None:
        def plain(v):
            if isinstance(v, float) and not np.isfinite(v):
                return None
            return v

        with open(os.fspath(json_path), "w") as f:
            json.dump({name: {k: plain(v) for k, v in row.items()} for name, row in rows.items()},
                      f, indent=2)


def _score_pair(gt_path, tracks_path, threshold, fmt, zero_distance, min_confidence,
                target_only=False):
    """Read two files and run the three metrics; numpy results and the file facts."""
    for name, value in (("threshold", threshold), ("zero_distance", zero_distance)):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) \
                or not np.isfinite(value) or value <= 0:
            raise ValueError(f"{name} must be a positive number; got {value!r}")
    _checks.check_options("fmt", (fmt,), FORMATS)
    gt_fmt = _sniff(gt_path) if fmt == "auto" else fmt
    hyp_fmt = _sniff(tracks_path) if fmt == "auto" else fmt
    # A 10-column MOT file holds boxes and ground-plane positions (MOT15 "3D" ground truth);
    # paired with an image-only file it is read for its boxes.
    image = "mot2d" in (gt_fmt, hyp_fmt)
    if image:
        for path, f in ((gt_path, gt_fmt), (tracks_path, hyp_fmt)):
            if f not in ("mot", "mot2d"):
                raise ValueError(f"{os.fspath(path)!r} is {f}, without the image boxes that the "
                                 f"other, image-plane MOT file needs")
        gt = read_mot_boxes(gt_path, min_confidence=min_confidence)
        hyp = read_mot_boxes(tracks_path)
    else:
        gt = read(gt_path, gt_fmt)
        hyp = read(tracks_path, hyp_fmt)
    frames = np.union1d(np.asarray(gt.frames), np.asarray(hyp.frames))
    gt_ids, gt_pos = _on_frames(gt, frames)
    hyp_ids, hyp_pos = _on_frames(hyp, frames)
    distance = "iou" if image else "euclidean"
    if target_only:
        hyp_ids = _near_labels(gt_ids, gt_pos, hyp_ids, hyp_pos, float(threshold), distance)
    _, dense = np.unique(gt_ids, return_inverse=True)
    dense = dense.reshape(gt_ids.shape) - (1 if np.any(gt_ids < 0) else 0)
    gt_ids = np.where(gt_ids >= 0, dense, -1).astype(np.int32)
    num_ids = max(int(gt_ids.max()) + 1, 1)
    num_hyp_ids = max(int(np.unique(hyp_ids[hyp_ids >= 0]).size), 1)
    args = (jnp.asarray(gt_ids), jnp.asarray(gt_pos), None, jnp.asarray(hyp_ids),
            jnp.asarray(hyp_pos), None)
    clear = clear_mot(*args, float(threshold), num_ids=num_ids, distance=distance)
    ident = identity_metrics(*args, float(threshold), distance=distance, max_ids=num_ids,
                             max_hyp_ids=num_hyp_ids)
    h = hota(*args, similarity=distance, zero_distance=float(zero_distance), max_ids=num_ids,
             max_hyp_ids=num_hyp_ids)
    return jax.device_get(dict(clear=clear._replace(frames=None), identity=ident, hota=h,
                               num_frames=len(frames), threshold=float(threshold),
                               plane="image" if image else "ground"))


def _near_labels(gt_ids, gt_pos, hyp_ids, hyp_pos, threshold, distance):
    """Target-only scoring: hypothesis ids with those farther than ``threshold`` from every
    labelled object of their frame set to -1 (absent). Where only the followed person is
    labelled, the other tracks are of unlabelled people, not false positives; a hypothesis
    within the threshold of the target may still be one (a second track on the target)."""
    from jaxtrack.metrics import _pairs

    d = np.asarray(jax.vmap(lambda a, b: _pairs.distance_matrix(a, b, distance))(
        jnp.asarray(gt_pos, jnp.float64 if jax.config.jax_enable_x64 else jnp.float32),
        jnp.asarray(hyp_pos, jnp.float64 if jax.config.jax_enable_x64 else jnp.float32)))
    d = np.where((gt_ids >= 0)[:, :, None] & np.isfinite(d), d, np.inf)     # [T, G, H]
    near = np.any(d <= threshold, axis=1) if d.shape[1] else np.zeros(hyp_ids.shape, bool)
    return np.where(near, hyp_ids, -1)


def _stack(results):
    return jax.tree.map(lambda *a: np.stack(a), *results)


def _row(scored) -> dict:
    c, i, h = scored["clear"], scored["identity"], scored["hota"]
    out = {name: float(getattr(c, name)) for name in ("mota", "motp", "precision", "recall")}
    for name in ("num_objects", "num_predictions", "num_matches", "num_switches", "num_misses",
                 "num_false_positives", "num_fragmentations", "mostly_tracked",
                 "partially_tracked", "mostly_lost", "num_unique_objects"):
        out[name] = int(getattr(c, name))
    out.update(idf1=float(i.idf1), idp=float(i.idp), idr=float(i.idr), idtp=int(i.idtp),
               idfp=int(i.idfp), idfn=int(i.idfn))
    out.update(hota=float(h.hota), deta=float(h.deta), assa=float(h.assa), loca=float(h.loca))
    out.update(num_frames=int(scored["num_frames"]), threshold=float(scored["threshold"]),
               plane=str(scored["plane"]))
    return out


def format_clear_mot(result: dict) -> str:
    """A short table of an `evaluate_files` result.

    Example:
      >>> print(format_clear_mot(evaluate_files("gt.txt", "tracks.csv")))
    """
    r = result
    rows = [
        ("MOTA", f"{r['mota']:.4f}"),
        ("MOTP", f"{r['motp']:.4f} m"),
        ("precision", f"{r['precision']:.4f}"),
        ("recall", f"{r['recall']:.4f}"),
        ("matches", f"{r['num_matches']}"),
        ("id switches", f"{r['num_switches']}"),
        ("misses", f"{r['num_misses']}"),
        ("false positives", f"{r['num_false_positives']}"),
        ("fragmentations", f"{r['num_fragmentations']}"),
        ("objects", f"{r['num_objects']}"),
        ("hypotheses", f"{r['num_predictions']}"),
        ("MT / PT / ML", f"{r['mostly_tracked']} / {r['partially_tracked']} / "
                         f"{r['mostly_lost']}"),
    ]
    head = f"CLEAR MOT over {r['num_frames']} frames, threshold {r['threshold']:g} m"
    width = max(len(k) for k, _ in rows)
    return "\n".join([head] + [f"  {k:<{width}}  {v}" for k, v in rows])


# ---------------------------------------------------------------------------------------------
# Internals


def _open_lines(path):
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"no such trajectory file: {path!r}")
    with open(path, encoding="utf-8") as f:
        return path, f.read().splitlines()


def _data_lines(lines):
    """(1-based line number, stripped text) of the lines that are neither blank nor comments."""
    for i, line in enumerate(lines, 1):
        text = line.split("#", 1)[0].strip()
        if text:
            yield i, text


def _sniff(path):
    name, lines = _open_lines(path)
    for i, text in _data_lines(lines):
        fields = re.split(r"[\s,]+", text)
        if fields[0].lower() == "frame":
            continue
        fmt = {8: "obsmat", 10: "mot", 9: "mot2d", 4: "plain"}.get(len(fields))
        if fmt is None:
            raise ValueError(f"{name}, line {i}: cannot tell the format from {len(fields)} "
                             "columns (obsmat has 8, MOT CSV 10, image-plane MOT 9 or 10, "
                             "plain / short MOT 4)")
        if fmt == "mot" and _image_only(lines):
            fmt = "mot2d"
        return fmt
    raise ValueError(f"{name}: no data rows")


def _image_only(lines):
    """Every 10-column data row has x = y = z = -1 (an image-plane MOT file)."""
    for _, text in _data_lines(lines):
        fields = re.split(r"[\s,]+", text)
        if fields[0].lower() == "frame":
            continue
        try:
            if len(fields) != 10 or any(float(v) != -1 for v in fields[7:10]):
                return False
        except ValueError:
            return False
    return True


def _parse(path, what, ncols, sep, boxes=False):
    """Rows as a float64 array [N, 4 or 8] (MOT rows reduced to frame, id, x, y; with ``boxes``
    the first 7 columns, frame, id, box and conf) and the line number of each row."""
    name, lines = _open_lines(path)
    rows, numbers = [], []
    first = True
    image_only = True  # every row a 10-column one with x = y = z = -1
    for i, text in _data_lines(lines):
        fields = re.split(sep, text)
        if first and fields[0].strip().lower() == "frame":
            first = False
            continue
        first = False
        if len(fields) not in ncols:
            want = " or ".join(str(n) for n in ncols)
            raise ValueError(f"{name}, line {i}: expected {want} columns ({what}); got "
                             f"{len(fields)}: {text!r}")
        try:
            values = [float(v) for v in fields]
        except ValueError:
            raise ValueError(f"{name}, line {i}: not a number in {text!r}") from None
        if boxes:
            values = values[:7]
            image_only = False
        elif len(fields) == 10:
            image_only &= values[7] == values[8] == values[9] == -1
            values = [values[0], values[1], values[7], values[8]]
        else:
            image_only = False
        if not all(np.isfinite(values)):
            raise ValueError(f"{name}, line {i}: NaN or inf in {text!r}")
        for label, v in (("frame", values[0]), ("id", values[1])):
            if v != int(v) or v < 0 or v >= 2**31:
                raise ValueError(f"{name}, line {i}: {label} must be a non-negative integer; "
                                 f"got {fields[0 if label == 'frame' else 1]!r}")
        rows.append(values)
        numbers.append(i)
    if not rows:
        raise ValueError(f"{name}: no data rows (empty file, or only comments)")
    if image_only:
        raise ValueError(f"{name}: x, y, z (columns 8-10) are -1 in every row: an image-plane "
                         "MOT file, without the ground-plane positions this reader needs")
    return np.asarray(rows, np.float64), np.asarray(numbers)


def _assemble(path, frame, pid, xy, vel, lines, fps, max_people, dtype):
    name = os.fspath(path)
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number; got {fps!r}")
    if max_people is not None and (not isinstance(max_people, (int, np.integer))
                                   or max_people < 1):
        raise ValueError(f"max_people must be a positive int; got {max_people!r}")
    frame = frame.astype(np.int64)
    pid = pid.astype(np.int64)
    order = np.lexsort((lines, pid, frame))
    frame, pid, lines = frame[order], pid[order], lines[order]
    xy = xy[order]
    same = (frame[1:] == frame[:-1]) & (pid[1:] == pid[:-1])
    if np.any(same):
        k = int(np.argmax(same))
        raise ValueError(f"{name}, line {int(lines[k + 1])}: frame {int(frame[k])}, id "
                         f"{int(pid[k])} already given on line {int(lines[k])}")
    frames, row_t, counts = np.unique(frame, return_inverse=True, return_counts=True)
    P = int(counts.max())
    if max_people is not None:
        if P > max_people:
            t = int(np.argmax(counts > max_people))
            raise ValueError(f"{name}: frame {int(frames[t])} has {int(counts[t])} people, "
                             f"more than max_people = {max_people}")
        P = int(max_people)
    T = len(frames)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot = np.arange(len(frame)) - starts[row_t]
    ids = np.full((T, P), -1, np.int32)
    ids[row_t, slot] = pid
    pos = np.zeros((T, P, xy.shape[1]))
    pos[row_t, slot] = xy
    mask = ids >= 0
    dtype = jnp.result_type(float) if dtype is None else dtype
    out_vel = None
    if vel is not None:
        v = np.zeros((T, P, 2))
        v[row_t, slot] = vel[order]
        out_vel = jnp.asarray(v, dtype)
    times = None if fps is None else jnp.asarray(frames / float(fps), dtype)
    return Trajectories(jnp.asarray(frames, jnp.int32), jnp.asarray(ids), jnp.asarray(pos, dtype),
                        jnp.asarray(mask), out_vel, times)


def _on_frames(traj, frames):
    """ids [T, P] and positions [T, P, d] (numpy) of ``traj`` on the sorted ``frames``, which
    contain ``traj.frames``; frames it lacks are empty."""
    P = max(traj.ids.shape[1], 1)
    ids = np.full((len(frames), P), -1, np.int32)
    pos = np.zeros((len(frames), P, traj.pos.shape[2]))
    where = np.searchsorted(frames, np.asarray(traj.frames))
    ids[where, :traj.ids.shape[1]] = np.asarray(traj.ids)
    pos[where, :traj.ids.shape[1]] = np.asarray(traj.pos)
    return ids, pos
