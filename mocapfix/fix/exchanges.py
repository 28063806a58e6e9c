"""Left and right limbs exchanged for a few frames (a video lifter or a depth camera that loses
which side is which), found and put back.

Each pair of limbs (the arms, the legs: the skeleton's limb groups, top joint and below) gets a
labelling per frame, as recorded or exchanged, chosen over the whole take at once (Viterbi over the
two labellings): the labelling whose limbs move least from frame to frame (the mean joint distance
between consecutive frames, as labelled), each change of labelling costing a switch. A frame-by-
frame test against where the limbs were heading (constant velocity) needed a margin of the take's
own misses, and under a tracker's 25 mm of jitter a heading misses by ~10 cm: it put back 75 % of
the exchanges of 3-30 frames on Bandai's takes; the whole-take labelling, whose consecutive-frame
distances carry sqrt(2) times the jitter (a heading sqrt(6)) and see the frames after a run too,
puts back 98.6 % (bench/exchanges.py). The switch costs SWITCH_M or SWITCH_NOISE times the take's
median frame-to-frame distance, whichever is more: under 6-12 cm of jitter on every joint a switch
at 0.4 of it invented runs (3 in 228 takes), at 0.5 none.
The take's own labelling is that of its first stretch of MIN_LABEL_S or more (a CMU take's first
frame, a calibration pose 20-30 cm from the next, labels nothing). A run of the other labelling is
put back only if it is short (MAX_EXCHANGE_S) and has frames of the take's own on both sides: a
long one, or one that runs to the take's end, is the take's own labelling, not a tracker's slip.
The top joints (shoulders, hips) are part of each limb, and they are a shoulder or hip width apart:
a clean take's crossing hands or feet never make the exchanged labelling the nearer one.
"""

from __future__ import annotations

import numpy as np

from mocapfix.core.skeleton import Skeleton
from mocapfix.fills.holes import runs

PAIRS = (("left_arm", "right_arm"), ("left_leg", "right_leg"))
SWITCH_M = 0.03  # the least a change of labelling costs, in mean joint distance (m)
SWITCH_NOISE = 0.75  # ... and this many times the take's median frame-to-frame distance
MIN_LABEL_S = 0.2  # the take's own labelling: its first stretch of one labelling this long
MAX_EXCHANGE_S = 1.5  # longer runs are the take's labelling, not a slip


def exchanged_frames(x: np.ndarray, left: list[int], right: list[int], fps: float) -> np.ndarray:
    """x: (T, J, 3) metres -> (T,) bool: the frames where the limbs `left` and `right` (joint
    indices, in matching order) are exchanged from the take's own labelling. A frame where a limb
    joint is missing takes the label of the frames seen on both sides where they agree, else is
    left out (False): a run is as long as the time it spans, holes included (a depth camera's
    take on a clock with a row every few frames, UTKinect's, is otherwise cut into runs of one
    frame, each short enough to be put back)."""
    out = np.zeros(len(x), dtype=bool)
    n = len(left)
    limbs = x[:, left + right].astype(np.float64)  # (T, 2n, 3)
    seen = np.flatnonzero(np.isfinite(limbs).all((1, 2)))  # (S,) the frames compared
    if len(seen) < 2:
        return out
    kept = limbs[seen]
    swapped = np.concatenate([kept[:, n:], kept[:, :n]], axis=1)
    # moving from frame t-1 to t with the same labelling, or changing it (symmetric in the two)
    same = np.linalg.norm(kept[1:] - kept[:-1], axis=-1).mean(-1)  # (S - 1,)
    change = np.linalg.norm(swapped[1:] - kept[:-1], axis=-1).mean(-1)
    switch = max(SWITCH_M, SWITCH_NOISE * float(np.median(same)))
    labels = _cheapest_labels(same.tolist(), (change + switch).tolist())  # (S,) 0/1
    own = _own_label(labels, seen, max(1, round(MIN_LABEL_S * fps)))
    exchanged = labels != own  # (S,)
    out[seen] = exchanged
    both = exchanged[:-1] & exchanged[1:]  # consecutive seen frames both exchanged: the frames between too
    for a, b in zip(seen[:-1][both], seen[1:][both]):
        out[a + 1 : b] = True
    return out


def _cheapest_labels(same: list[float], change: list[float]) -> np.ndarray:
    """Viterbi over two labellings: the per-frame labels (0/1, up to which is which) with the
    least total cost, staying costing same[t] and changing change[t] from frame t to t + 1."""
    cost = [0.0, 0.0]
    came_across = np.zeros((len(same), 2), dtype=bool)  # the best way into (t + 1, label) changed label
    for t, (s, c) in enumerate(zip(same, change)):
        stay, across = (cost[0] + s, cost[1] + s), (cost[1] + c, cost[0] + c)
        came_across[t] = across[0] < stay[0], across[1] < stay[1]
        cost = [min(stay[0], across[0]), min(stay[1], across[1])]
    labels = np.zeros(len(same) + 1, dtype=np.int8)
    label = int(cost[1] < cost[0])
    for t in range(len(same), 0, -1):
        labels[t] = label
        label ^= int(came_across[t - 1, label])
    labels[0] = label
    return labels


def _own_label(labels: np.ndarray, frames: np.ndarray, min_frames: int) -> int:
    """The take's own label: that of its first stretch of one label spanning min_frames or more
    (frames: each label's frame in the take), else the label of most frames."""
    starts = np.concatenate([[0], np.flatnonzero(np.diff(labels)) + 1])
    ends = np.concatenate([starts[1:], [len(labels)]])
    for a, b in zip(starts, ends):
        if frames[b - 1] - frames[a] + 1 >= min_frames:
            return int(labels[a])
    return int(2 * labels.sum() > len(labels))


def put_back_exchanges(x: np.ndarray, skeleton: Skeleton, fps: float) -> tuple[np.ndarray, int, int]:
    """x: (T, J, 3) one take's positions -> (x with short exchanges of left and right limbs put
    back, how many runs, how many frames). A joint below a limb's top moves with its limb."""
    x = x.copy()
    exchanges = frames = 0
    longest = max(1, round(MAX_EXCHANGE_S * fps))
    for a, b in PAIRS:
        left, right = list(skeleton.groups.get(a, ())), list(skeleton.groups.get(b, ()))
        if not left or len(left) != len(right):
            continue
        mask = exchanged_frames(x, left, right, fps)
        for start, stop in runs(mask):
            if stop - start > longest or start <= 2 or stop == len(x):
                continue  # long, or with no unexchanged frames on one side: the take's own labelling
            x[start:stop, left + right] = x[start:stop, right + left]
            exchanges, frames = exchanges + 1, frames + stop - start
    return x, exchanges, frames
