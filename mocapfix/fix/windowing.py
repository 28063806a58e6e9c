"""Windows for `fix`: a clip of any length, at the model's fps (core/resample.py) -> windows of the
model's length -> the model's estimates blended back into one track per clip.

Nothing here knows what a frame holds (positions, rotations): blend_windows asks a WindowSource
for the estimate of a batch of windows as flat per-frame vectors and blends them with sin^2
weights. position_windows.py and rotations.py have the two sources (joint positions; joint
rotations); positions.py and rotations.py say what is done with the blended tracks.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import torch

# --- where the windows go ---


def window_layout(num_frames: int, window: int, overlap: float) -> tuple[np.ndarray, int]:
    """Starts of the windows over a clip of num_frames (model fps) and the stride.
    Stride window * (1 - overlap); one more window ends at the clip's end when the stride does
    not land there. A clip shorter than a window gets one window, centred: start < 0."""
    stride = max(1, int(round(window * (1.0 - overlap))))
    if num_frames <= window:
        return np.array([-((window - num_frames) // 2)], dtype=np.int64), stride
    starts = np.arange(0, num_frames - window + 1, stride, dtype=np.int64)
    if starts[-1] != num_frames - window:
        starts = np.append(starts, num_frames - window)
    return starts, stride


def windows_for(need: np.ndarray, window: int, overlap: float) -> tuple[np.ndarray, int]:
    """Starts of the windows that cover the needed frames need (K,) bool, and the stride.

    A run of needed frames no longer than three quarters of a window gets one window centred on
    it: the paper evaluates with the gap in the middle of the window, where the model has
    context on both sides. A longer run gets the regular grid of window_layout over the run and a quarter
    window of context on each side. When that takes more windows than the plain grid (short runs
    close together: scattered missing tokens), the grid's windows that hold a needed frame are
    used instead. With every frame needed it is window_layout's grid."""
    K = len(need)
    stride = max(1, int(round(window * (1.0 - overlap))))
    if K <= window:
        return window_layout(K, window, overlap)
    edges = np.diff(np.concatenate([[0], need.astype(np.int8), [0]]))
    starts = []
    for s, e in zip(np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]):  # runs [s, e)
        if e - s <= 3 * window // 4:
            starts.append([min(max((s + e - window) // 2, 0), K - window)])
        else:
            lo, hi = max(0, s - window // 4), min(K, e + window // 4)
            grid, _ = window_layout(hi - lo, window, overlap)
            starts.append(np.clip(grid + lo, 0, K - window))
    if not starts:
        return np.zeros(0, dtype=np.int64), stride
    starts = np.unique(np.concatenate(starts)).astype(np.int64)
    # Many short runs close together (scattered missing tokens): the plain grid is cheaper.
    grid, _ = window_layout(K, window, overlap)
    grid = grid[[need[g : g + window].any() for g in grid]]
    return (grid if len(grid) < len(starts) else starts), stride


def blend_weights(window: int, stride: int) -> np.ndarray:
    """(W,) weights that rise over the overlap, stay 1 between, and fall over the overlap:
    sin^2 ramps, so two windows one stride apart sum to exactly 1 where they overlap (Hann for
    overlap W/2). Never 0, so a frame that only one window covers (clip ends) keeps it."""
    overlap = window - stride
    w = np.ones(window)
    if overlap > 0:
        ramp = np.sin(0.5 * np.pi * (np.arange(overlap) + 0.5) / overlap) ** 2
        w[:overlap] = ramp
        w[window - overlap :] = np.minimum(w[window - overlap :], ramp[::-1])
    return w


# --- running a model over the windows and blending ---


class WindowSource(Protocol):
    """What blend_windows needs from a representation of the clips (clips.py: positions, rotations)."""

    window: int  # frames per window, model fps
    dim: int  # D, the length of a frame's vector
    fixed_length: bool  # a clip shorter than a window: padded to a window (True) or one window of its length

    def estimate(self, windows: list[tuple[int, np.ndarray]]) -> torch.Tensor:
        """windows: (clip, frames (L,) at the model's fps, -1 for padding), all of one length ->
        the model's estimate as (B, L, D) float64 vectors that may be averaged; a window whose
        estimate is not finite anywhere at a real frame has failed."""
        ...

    def fallback(self, clip: int) -> np.ndarray:
        """(K, D) float64: what a frame gets from a window the model cannot serve (no data in it, or
        a failed estimate), blended like an estimate so there is no seam where they meet."""
        ...


@dataclass
class Blended:
    tracks: list[np.ndarray]  # per clip (K, D): the windows' weighted mean; NaN where no window covers
    by_model: list[np.ndarray]  # per clip (K,) bool: frames a window the model served covers
    windows: int  # windows the model ran on
    failed: int  # of those, windows whose estimate was not finite (the fallback there)


def blend_windows(
    source: WindowSource,
    need: list[np.ndarray],
    has_data: list[np.ndarray],
    overlap: float,
    batch_size: int,
    progress: Callable[[int, int], None] | None = None,
) -> Blended:
    """Every window of every clip that holds a needed frame (need[k]: (K,) bool, windows_for),
    the model run on those with data (has_data[k]: (K,) bool) in batches of windows of one
    length, the fallback on the others, all blended with blend_weights. progress(done, total)
    after each batch."""
    W = source.window
    plan = []  # (clip, frames (L,) with -1 at padding, model or fallback)
    for k, (nd, hd) in enumerate(zip(need, has_data)):
        K = len(nd)
        length = W if source.fixed_length else min(W, K)
        starts, _ = windows_for(nd, length, overlap)
        for s in starts:
            f = np.arange(s, s + length)
            real = (f >= 0) & (f < K)
            if nd[f[real]].any():
                plan.append((k, np.where(real, f, -1), bool(hd[f[real]].any())))
    # Windows of one length run together (short clips of a recurrent model make their own batches).
    plan.sort(key=lambda p: len(p[1]))
    run = [p for p in plan if p[2]]
    fallback = [(k, f) for k, f, served in plan if not served]

    acc = [np.zeros((len(nd), source.dim)) for nd in need]  # weighted sums
    wsum = [np.zeros(len(nd)) for nd in need]
    by_model = [np.zeros(len(nd), dtype=bool) for nd in need]

    weights = {}  # window length -> its blend weights

    def add(k: int, f: np.ndarray, values: np.ndarray) -> None:
        # f: (L,) frames, -1 at padding (weighs nothing); values: (L, D). A window's frames are distinct.
        real = f >= 0
        L = len(f)
        if L not in weights:
            weights[L] = blend_weights(L, max(1, int(round(L * (1.0 - overlap)))))
        w = weights[L][real]
        acc[k][f[real]] += values[real] * w[:, None]
        wsum[k][f[real]] += w

    done = failed = 0
    batches = [run[i : i + batch_size] for i in range(0, len(run), batch_size)]
    batches = [[p for p in b if len(p[1]) == n] for b in batches for n in sorted({len(p[1]) for p in b})]
    for batch in batches:
        est = source.estimate([(k, f) for k, f, _ in batch]).numpy()  # (B, L, D)
        for (k, f, _), e in zip(batch, est):
            if np.isfinite(e[f >= 0]).all():
                add(k, f, e)
                by_model[k][f[f >= 0]] = True
            else:
                failed += 1
                fallback.append((k, f))
        done += len(batch)
        if progress is not None:
            progress(done, len(run))
    for k, f in fallback:
        add(k, f, source.fallback(k)[np.maximum(f, 0)])
    with np.errstate(invalid="ignore", divide="ignore"):
        tracks = [np.where(w[:, None] > 0, a / w[:, None], np.nan) for a, w in zip(acc, wsum)]
    return Blended(tracks, by_model, len(run), failed)
