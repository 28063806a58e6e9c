"""Left and right limbs exchanged for a few frames (a video lifter or a depth camera that loses
which side is which), found and put back.

Each pair of limbs (the arms, the legs: the skeleton's limb groups, top joint and below) is
followed through the take: each frame is compared with where the limbs were heading (the two
frames before it, as put back so far, at constant velocity). Where the frame's left limb sits
where the right one was heading and the right where the left was, by a clear margin, the two
are exchanged. A run of exchanged frames is put back only if it is short (MAX_EXCHANGE_S) and has
unexchanged frames on both sides: a long one, or one that runs to the take's end, is the take's
own labelling, not a tracker's slip (the first frames of a take that starts exchanged set its
labels; CMU subject 09's 1.2-s runs, their first two frames off, were turned round whole).
The top joints (shoulders, hips) are part of each limb, and they are a shoulder or hip width
apart: a clean take's crossing hands or feet never make the exchanged labelling the nearer one.
"""

from __future__ import annotations

import numpy as np

from mocapfix.core.skeleton import Skeleton
from mocapfix.fills.holes import runs

PAIRS = (("left_arm", "right_arm"), ("left_leg", "right_leg"))
MARGIN_M = 0.05  # the exchanged labelling must be this much nearer, per joint on average,
# and by this many times the take's typical miss of the heading (its jitter and its motion's turns,
# the median over frames): under heavy jitter a heading misses by more than a shoulder's width by
# chance, and each chance win would put a run back (0.1 rad on every joint of the CMU takes: 8-65
# runs invented per take at the fixed margin, the jitter remover's error doubled, 25.8 -> 51 mm)
NOISE_MARGIN = 1.0
MAX_EXCHANGE_S = 1.5  # longer runs are the take's labelling, not a slip


def exchanged_frames(x: np.ndarray, left: list[int], right: list[int]) -> np.ndarray:
    """x: (T, J, 3) metres -> (T,) bool: the frames where the limbs `left` and `right` (joint
    indices, in matching order) are exchanged, following the take from its start."""
    out = np.zeros(len(x), dtype=bool)
    fixed = x[:, left + right].astype(np.float64).copy()  # (T, 2n, 3) as put back so far
    n = len(left)
    miss = np.linalg.norm(fixed[2:] - (2 * fixed[1:-1] - fixed[:-2]), axis=-1).mean(-1)  # (T - 2,)
    miss = miss[np.isfinite(miss)]
    margin = max(MARGIN_M, NOISE_MARGIN * float(np.median(miss))) if len(miss) else MARGIN_M
    for t in range(2, len(x)):
        prev, prev2, now = fixed[t - 1], fixed[t - 2], fixed[t]
        if not (np.isfinite(prev).all() and np.isfinite(prev2).all() and np.isfinite(now).all()):
            continue
        heading = 2 * prev - prev2  # (2n, 3)
        swapped = np.concatenate([now[n:], now[:n]])
        keep_cost = np.linalg.norm(now - heading, axis=-1).mean()
        swap_cost = np.linalg.norm(swapped - heading, axis=-1).mean()
        if swap_cost < keep_cost - margin:
            out[t] = True
            fixed[t] = swapped
    return out


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
        mask = exchanged_frames(x, left, right)
        for start, stop in runs(mask):
            if stop - start > longest or start <= 2 or stop == len(x):
                continue  # long, or with no unexchanged frames on one side: the take's own labelling
            x[start:stop, left + right] = x[start:stop, right + left]
            exchanges, frames = exchanges + 1, frames + stop - start
    return x, exchanges, frames
