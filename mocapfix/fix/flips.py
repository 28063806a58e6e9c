"""A limb held in a wrong pose for a moment (an IK solver's flip: a knee swung about the hip-ankle
line, an upper arm turned 60 degrees for 0.4 s), found so that `fix --mode both` fills it again.

Such a flip is a step, not a spike: the limb (every joint below its top, relative to the top)
jumps into the wrong pose in one frame, moves smoothly there, and jumps back. The search, per
limb: a frame whose jump stands out (JUMP_M, and RATIO times the limb's usual frame-to-frame
motion around it), then a frame MIN_S to MAX_S later that stands out the same way, with nothing
between them half as large, and between them the limb away from where the cubic Hermite through
the frames outside puts it (RESIDUAL_M on average). Every limb of the model's body is searched
(arms, legs); a flip's tokens become holes that the fill policy fills like any other.
Natural motion does not pass: a fast swing moves the limb a lot in many frames, not in two.
"""

from __future__ import annotations

import numpy as np
import torch

from mocapfix.core.skeleton import Skeleton
from mocapfix.fills.classical import hermite_infill

LIMBS = ("left_arm", "right_arm", "left_leg", "right_leg")
JUMP_M = 0.06  # a flip's step, mean over the limb's joints below its top
RATIO = 4.0  # ... and this many times the limb's median step around it
RESIDUAL_M = 0.05  # the held pose this far from the Hermite through the frames around it
MIN_S, MAX_S = 0.1, 0.7
CONTEXT_S = 0.5  # the frames around a step that say what the limb's usual motion is


def flipped_segments(x: np.ndarray, limb: list[int], fps: float) -> list[tuple[int, int]]:
    """x: (T, J, 3) metres; limb: joint indices, its top first -> [(start, stop)] frames held in
    a flipped pose."""
    top, below = limb[0], limb[1:]
    r = x[:, below] - x[:, top][:, None]  # (T, k, 3) the limb about its top, NaN where missing
    seen = np.isfinite(r).all(-1)  # (T, k)
    with np.errstate(invalid="ignore"):
        step = np.concatenate([[np.nan], np.linalg.norm(np.diff(r, axis=0), axis=-1).mean(-1)])  # (T,) into frame t
    T, ctx = len(x), max(3, round(CONTEXT_S * fps))
    shortest, longest = max(2, round(MIN_S * fps)), max(3, round(MAX_S * fps))

    def stands_out(t: int, quiet_from: int) -> bool:  # a missing step (NaN) never does
        around = np.concatenate([step[max(1, t - ctx) : quiet_from], step[t + 1 : t + 1 + ctx]])
        around = around[np.isfinite(around)]
        return step[t] > JUMP_M and around.size > 0 and step[t] > RATIO * np.median(around)

    found, t = [], 2
    while t < T - 2:
        best = None
        if stands_out(t, t):
            for b in range(t + shortest, min(T - 2, t + longest) + 1):
                inside = step[t + 1 : b]
                if not stands_out(b, t) or (inside > 0.5 * min(step[t], step[b])).any():
                    continue
                lo, hi = max(0, t - ctx), min(T, b + ctx)
                outside = torch.from_numpy(seen[lo:hi].copy())[None]  # (1, W, k)
                outside[0, t - lo : b - lo] = False
                fill = hermite_infill(torch.from_numpy(np.nan_to_num(r[lo:hi]))[None], outside)[0].numpy()
                residual = np.nanmean(np.linalg.norm(fill[t - lo : b - lo] - r[t:b], axis=-1))
                if residual > RESIDUAL_M and (best is None or residual > best[2]):
                    best = (t, b, residual)
        if best is not None:
            found.append(best[:2])
            t = best[1] + 1
        else:
            t += 1
    return found


def flips_as_holes(x: np.ndarray, skeleton: Skeleton, fps: float) -> tuple[np.ndarray, int, int]:
    """x: (T, J, 3) one take -> (x with each flipped limb's joints below its top missing over the
    flip, how many flips, how many tokens made missing)."""
    x = x.copy()
    runs = tokens = 0
    for name in LIMBS:
        limb = list(skeleton.groups.get(name, ()))
        if len(limb) < 2:
            continue
        for a, b in flipped_segments(x.astype(np.float64), limb, fps):
            x[a:b, limb[1:]] = np.nan
            runs, tokens = runs + 1, tokens + (b - a) * (len(limb) - 1)
    return x, runs, tokens
