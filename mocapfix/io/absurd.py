"""Absurd values are missing data: a position no body can take becomes NaN when a file is read.

One 1e30 in one frame (a capture glitch, an export bug) passes every parser. Kept as a number it
reaches a loss and turns a model's weights into NaN, or is copied into a "fixed" file as data.
Two tests, both on robust statistics so that the bad values cannot hide themselves:
- a joint far from the rest of its body in its frame (beyond any reach of a human body from
  the median of its joints), and
- a whole frame far from where the body is around it (a jump no person makes in a fraction of a
  second: the frame's centre against a running median of the centres over about 0.5 s).
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
        centre = np.nanmedian(np.where(seen[:, body, None], pos[:, body], np.nan), axis=1)  # (T, 3)
        far = np.linalg.norm(pos - centre[:, None], axis=-1) > max(MIN_REACH_M, 1.5 * stature)  # (T, J)

    # The running median over frames needs every frame: carry the centre over frames where the
    # whole body is missing (they have nothing to flag).
    has = np.isfinite(centre).all(axis=-1)
    if has.sum() >= 3:
        idx = np.arange(T)
        filled = np.stack([np.interp(idx, idx[has], centre[has, k]) for k in range(3)], axis=-1)
        width = max(3, int(round(MEDIAN_WINDOW_S * fps)) | 1)
        local = median_filter(filled, size=(width, 1), mode="nearest")  # (T, 3)
        with np.errstate(invalid="ignore", over="ignore"):
            jump = np.linalg.norm(filled - local, axis=-1) > max(MIN_JUMP_M, 2.0 * stature)  # (T,)
        far |= jump[:, None]
    return far & seen & body[None]


def drop_absurd(clip: Clip, stature_m: float) -> Clip:
    """The clip with its absurd positions made missing; meta["absurd_tokens"] counts them. A
    rotation clip with absurd frames loses its rotations (meta["no_rotations"] says why): they
    made those positions, and a rotation model must not learn from or fix with them."""
    mask = absurd_mask(clip.positions, clip.fps, stature_m)
    meta = {**clip.meta, "absurd_tokens": clip.meta.get("absurd_tokens", 0) + int(mask.sum())}
    if not mask.any():
        return clip.replace(meta=meta)
    positions = clip.positions.copy()
    positions[mask] = np.nan
    if clip.has_rotations:
        meta["no_rotations"] = f"{int(mask.any(axis=1).sum())} frames with absurd values"
    return clip.replace(positions=positions, rotations=None, root_translation=None, offsets=None, meta=meta)
