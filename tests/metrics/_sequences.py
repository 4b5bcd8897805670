"""Random multi-object sequences for the CLEAR MOT tests, built to exercise every event.

Objects are born and die at random times, disappear for a few frames (occlusion), move in a
3 m x 3 m square so that several hypotheses are often within the 1 m threshold of one object,
and sit in shuffled slots (identity is the id, not the slot). The tracker's output detects each
object with probability 0.8 near its position, changes a track id now and then (a switch),
swaps the ids of two tracks, keeps a track alive for a frame or two after its object died, and
adds false positives, some near objects and some with ids used before.
"""

import numpy as np

T, G, H, D = 18, 5, 5, 2
THRESHOLD = 1.0


def random_sequence(seed, T=T, G=G, H=H):
    """One episode: dict of numpy arrays gt_ids [T, G], gt_pos [T, G, 2], hyp_ids [T, H],
    hyp_pos [T, H, 2] (float64), with -1 ids (and NaN positions) in empty slots."""
    rng = np.random.default_rng(seed)
    num_objects = rng.integers(3, 8)
    ids = rng.choice(T * G, size=num_objects, replace=False)
    birth = rng.integers(0, T // 2, num_objects)
    death = np.minimum(T, birth + rng.integers(4, T + 1, num_objects))
    pos = rng.uniform(0.0, 3.0, (num_objects, 2))
    vel = rng.normal(0.0, 0.15, (num_objects, 2))
    gap_until = np.full(num_objects, -1)
    fresh = [1000]

    def new_id():
        fresh[0] += int(rng.integers(1, 3))
        return fresh[0]

    track = np.array([new_id() for _ in range(num_objects)])
    coast = {}  # track id -> (position, frames left) after its object died
    used = list(track)

    gt_ids = np.full((T, G), -1)
    gt_pos = np.full((T, G, 2), np.nan)
    hyp_ids = np.full((T, H), -1)
    hyp_pos = np.full((T, H, 2), np.nan)
    for t in range(T):
        pos = pos + vel + rng.normal(0.0, 0.05, pos.shape)
        alive = (birth <= t) & (t < death)
        start_gap = alive & (gap_until < t) & (rng.random(num_objects) < 0.07)
        gap_until = np.where(start_gap, t + rng.integers(1, 4, num_objects), gap_until)
        visible = np.flatnonzero(alive & (gap_until < t))[:G]
        slots = rng.permutation(G)[:len(visible)] if rng.random() < 0.4 else np.arange(len(visible))
        gt_ids[t, slots] = ids[visible]
        gt_pos[t, slots] = pos[visible]

        # Tracker events.
        for k in visible:
            if rng.random() < 0.06:
                track[k] = new_id()
                used.append(track[k])
        if len(visible) >= 2 and rng.random() < 0.08:
            a, b = rng.choice(visible, 2, replace=False)
            track[a], track[b] = track[b], track[a]
        for k in np.flatnonzero(death == t):
            if rng.random() < 0.5:
                coast[track[k]] = (pos[k].copy(), int(rng.integers(1, 3)))

        out_ids, out_pos = [], []
        for k in visible:
            if rng.random() < 0.8:
                out_ids.append(track[k])
                out_pos.append(pos[k] + rng.normal(0.0, 0.35, 2))
        for tid, (p, left) in list(coast.items()):
            out_ids.append(tid)
            out_pos.append(p + rng.normal(0.0, 0.2, 2))
            coast[tid] = (p, left - 1)
            if left <= 1:
                del coast[tid]
        if rng.random() < 0.35:
            near = len(visible) > 0 and rng.random() < 0.6
            centre = pos[rng.choice(visible)] if near else rng.uniform(0.0, 3.0, 2)
            out_ids.append(int(rng.choice(used)) if rng.random() < 0.3 else new_id())
            out_pos.append(centre + rng.normal(0.0, 0.6, 2))
        keep = {}
        for tid, p in zip(out_ids, out_pos):
            keep.setdefault(int(tid), p)  # unique ids within the frame
        items = list(keep.items())[:H]
        slots = rng.permutation(H)[:len(items)]
        for s, (tid, p) in zip(slots, items):
            hyp_ids[t, s] = tid
            hyp_pos[t, s] = p
    return dict(gt_ids=gt_ids, gt_pos=gt_pos, hyp_ids=hyp_ids, hyp_pos=hyp_pos)


def frame_distances(seq, t, threshold=THRESHOLD):
    """Present object ids, present hypothesis ids and their distance matrix with NaN beyond
    the threshold (the py-motmetrics input)."""
    gm, hm = seq["gt_ids"][t] >= 0, seq["hyp_ids"][t] >= 0
    diff = seq["gt_pos"][t][gm][:, None, :] - seq["hyp_pos"][t][hm][None, :, :]
    dist = np.sqrt(np.sum(diff * diff, -1))
    dist[dist > threshold] = np.nan
    return seq["gt_ids"][t][gm], seq["hyp_ids"][t][hm], dist


def to_boxes(pos, rng):
    """Image boxes (left, top, width, height) around ground-plane points, 100 px per metre."""
    size = rng.uniform(40.0, 120.0, pos.shape[:-1] + (2,))
    return np.concatenate([100.0 * pos - size / 2, size], -1)


def sequences_with_boxes(num, box_seed):
    """``num`` random sequences with boxes ``gt_box`` / ``hyp_box`` around their points, and
    the same stacked: ``(list of dicts, dict of [num, ...] arrays)``."""
    seqs = [random_sequence(seed) for seed in range(num)]
    rng = np.random.default_rng(box_seed)
    for s in seqs:
        s["gt_box"] = to_boxes(s["gt_pos"], rng)
        s["hyp_box"] = to_boxes(s["hyp_pos"], rng)
    return seqs, {k: np.stack([s[k] for s in seqs]) for k in seqs[0]}
