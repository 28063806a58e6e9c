"""Absurd values are missing data: a position no body can take becomes NaN when a file is read.

One 1e30 in one frame (a capture glitch, an export bug) passes every parser. Kept as a number it
reaches a loss and turns a model's weights into NaN, or is copied into a "fixed" file as data.
Two tests, both on robust statistics so that the bad values cannot hide themselves:
- a joint far from the rest of its body in its frame (beyond any reach of a human body from
  the median of its joints), and
- a whole frame far from where the body is around it (a jump no person makes in a fraction of a
  second: the frame's centre against a running median of the centres over about 0.5 s), and
- an excursion: a joint (or the whole body, through the root) that leaves its track faster than
  any body part moves and is back, or the take ends, within a couple of seconds (a 1,000 m jump
  for 0.5 s passes the running median; it cannot pass a speed limit).
Joints that never move (a helper at the origin) are not part of the body and are never absurd.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.ndimage import median_filter

from mocapfix.core.clip import Clip
from mocapfix.io.conventions import REFERENCE_STATURE_M

MIN_REACH_M = 3.0  # a joint farther than max(this, 1.5 statures) from its body's median joint
MIN_JUMP_M = 3.0  # a frame farther than max(this, 2 statures) from the running median: 12 m/s for 0.25 s
MEDIAN_WINDOW_S = 0.5
# Excursions, in statures (the thresholds scale with the body, so a wrong unit cannot make every
# step a jump): no body part moves faster than 18 statures/s (30 m/s for 1.70 m; a pitcher's hand
# peaks near 25 m/s), plus 0.3 statures (0.5 m) a step for noise and marker swaps; a stretch
# away from the track that lasts longer than MAX_EXCURSION_S is the take's, not a glitch. A
# stretch at either end of the take never comes back, so nothing confirms it was a glitch: it
# must be a jump of more than a body (1 stature) to count. (CMU's BVH takes start with a bind
# pose frame whose hands are up to 1.2 m from the next frame's: the take's, not an error.)
MAX_SPEED_STATURES_S = 18.0
STEP_SLACK_STATURES = 0.3
EDGE_SLACK_STATURES = 1.0
MAX_EXCURSION_S = 2.0


def absurd_mask(positions: np.ndarray, fps: float, stature_m: float = REFERENCE_STATURE_M) -> np.ndarray:
    """positions: (T, J, 3) metres, NaN = missing -> (T, J) bool, True where a seen joint is absurd."""
    pos = positions.astype(np.float64)  # 1e30 squared overflows float32
    T, J, _ = pos.shape
    seen = np.isfinite(pos).all(axis=-1)  # (T, J)
    stature = stature_m if np.isfinite(stature_m) else REFERENCE_STATURE_M
    with np.errstate(invalid="ignore", over="ignore"):
        moves = np.nanmax(np.where(seen[..., None], pos, -np.inf), axis=0) - np.nanmin(
            np.where(seen[..., None], pos, np.inf), axis=0
        )  # (J, 3)
    body = (moves > 1e-9).any(axis=-1)  # (J,) joints that ever move
    if not body.any():
        return np.zeros((T, J), dtype=bool)
    with np.errstate(invalid="ignore", over="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # frames with no joint seen
        centre = _median_over_joints(np.where(seen[:, body, None], pos[:, body], np.nan))  # (T, 3)
        far = np.linalg.norm(pos - centre[:, None], axis=-1) > max(MIN_REACH_M, 1.5 * stature)  # (T, J)

    # The running median over frames needs every frame: carry the centre over frames where the
    # whole body is missing (they have nothing to flag).
    has = np.isfinite(centre).all(axis=-1)
    if has.sum() >= 3:
        idx = np.arange(T)
        filled = np.stack([np.interp(idx, idx[has], centre[has, k]) for k in range(3)], axis=-1)
        width = max(3, int(round(MEDIAN_WINDOW_S * fps)) | 1)
        # per axis: scipy's 1-D rank filter, 17x faster than the same median over (width, 1)
        local = np.stack([median_filter(filled[:, k], size=width, mode="nearest") for k in range(3)], -1)  # (T, 3)
        with np.errstate(invalid="ignore", over="ignore"):
            jump = np.linalg.norm(filled - local, axis=-1) > max(MIN_JUMP_M, 2.0 * stature)  # (T,)
        far |= jump[:, None]
    for j in np.nonzero(body)[0]:
        far[:, j] |= excursions(pos[:, j], seen[:, j] & ~far[:, j], fps, stature)
    return far & seen & body[None]


def _median_over_joints(values: np.ndarray) -> np.ndarray:
    """values: (T, J, 3), NaN where missing -> (T, 3) np.nanmedian over J (NaN where none): the
    middle one or the mean of the two middle ones of the sorted seen values, as nanmedian takes
    them, from one sort (nanmedian masks each frame apart: 4 ms for a 1,500-frame take)."""
    ordered = np.sort(values, axis=1)  # NaN last
    seen = np.isfinite(ordered).sum(1, keepdims=True)  # (T, 1, 3)
    lower = np.take_along_axis(ordered, np.maximum(seen - 1, 0) // 2, axis=1)[:, 0]
    upper = np.take_along_axis(ordered, seen // 2, axis=1)[:, 0]
    return np.where(seen[:, 0] > 0, (lower + upper) / 2, np.nan)


def excursions(track: np.ndarray, seen: np.ndarray, fps: float, stature_m: float) -> np.ndarray:
    """track: (T, 3) one joint, metres; seen: (T,) -> (T,) True at the frames of short stretches
    the joint could not have reached: the track is cut where a step is faster than any body part
    moves; the longest piece is the joint's, and each other piece, walking outwards from it in
    time, is the joint's when it is reachable from the last piece that was (at that speed over the
    time between them), or when it lasts longer than MAX_EXCURSION_S (the take moved, say two
    recordings end to end); a piece at an end of the take needs a jump of a body's size more.
    At most half the joint's frames are ever flagged."""
    frames = np.nonzero(seen)[0]
    flagged = np.zeros(len(track), dtype=bool)
    if len(frames) < 3:
        return flagged
    p = track[frames]
    speed, slack = MAX_SPEED_STATURES_S * stature_m, STEP_SLACK_STATURES * stature_m

    def reachable(a: int, b: int, slack: float) -> bool:  # indices into frames
        return bool(np.linalg.norm(p[b] - p[a]) <= speed * abs(frames[b] - frames[a]) / fps + slack)

    with np.errstate(invalid="ignore", over="ignore"):
        cut = np.linalg.norm(np.diff(p, axis=0), axis=-1) > speed * np.diff(frames) / fps + slack
    if not cut.any():
        return flagged
    bounds = np.r_[0, np.nonzero(cut)[0] + 1, len(frames)]
    pieces = list(zip(bounds[:-1], bounds[1:]))  # [start, end) into frames
    anchor = int(np.argmax([e - s for s, e in pieces]))
    bad = []
    for step in (1, -1):
        ref = anchor
        for i in range(anchor + step, len(pieces) if step > 0 else -1, step):
            s, e = pieces[i]
            near_ref = pieces[ref][1] - 1 if step > 0 else pieces[ref][0]
            near_me = s if step > 0 else e - 1
            long = (frames[e - 1] - frames[s] + 1) / fps > MAX_EXCURSION_S
            edge = i in (0, len(pieces) - 1)
            if long or reachable(near_ref, near_me, EDGE_SLACK_STATURES * stature_m if edge else slack):
                ref = i
            else:
                bad.append(i)
    out = np.concatenate([frames[s:e] for s, e in (pieces[i] for i in bad)]) if bad else np.zeros(0, int)
    if 2 * len(out) > len(frames):
        return flagged
    flagged[out] = True
    return flagged


def drop_absurd(clip: Clip, stature_m: float) -> Clip:
    """The clip with its absurd positions made missing; meta["absurd_tokens"] counts them. A
    rotation clip with absurd frames loses its rotations (meta["no_rotations"] says why): they
    made those positions, and a rotation model must not learn from or fix with them."""
    mask = absurd_mask(clip.positions, clip.fps, stature_m)
    meta = {**clip.meta, "absurd_tokens": clip.meta.get("absurd_tokens", 0) + int(mask.sum())}
    if not mask.any():
        return clip.replace(meta=meta)
    names = clip.skeleton.joint_names
    meta["out_of_reach_tokens"] = meta.get("out_of_reach_tokens", 0) + int(mask.sum())
    meta["absurd_joints"] = sorted(
        set(meta.get("absurd_joints", [])) | {names[j] for j in np.nonzero(mask.any(0))[0]}, key=names.index
    )
    positions = clip.positions.copy()
    positions[mask] = np.nan
    if clip.has_rotations:
        meta["no_rotations"] = f"{int(mask.any(axis=1).sum())} frames with absurd values"
    return clip.replace(positions=positions, rotations=None, root_translation=None, offsets=None, meta=meta)
