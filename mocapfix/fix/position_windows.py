"""A file's clips as windows of joint positions for a positions model (windowing.WindowSource):
which of the model's frames need an estimate, what a window holds (the positions, NaN where
missing; with XMAE's Hermite variant the whole take's fill), and what the windows cannot see
(a joint missing throughout a window), for the report.
"""

from __future__ import annotations

import numpy as np
import torch

from mocapfix.core.clip import Clip
from mocapfix.core.resample import frames_around, hold_last_frame, resample_frames
from mocapfix.fills.classical import hermite_infill, lerp_infill
from mocapfix.fix.fixer import Fixer
from mocapfix.fix.joints import ModelView
from mocapfix.fix.windowing import window_layout


class PositionWindows:
    """Windows of joint positions for a positions fixer (windowing.WindowSource): x_m[k] (K, Jm, 3)
    each clip at the model's joints and fps, NaN at missing tokens; padding is missing too.
    fills: each clip's whole-take fill at the model's frames, the fill the network corrects
    (hermite_take_fills), or None. Estimates are blended as positions; the fallback is Lerp over the clip."""

    fixed_length = True  # XMAE's positional embedding has one length

    def __init__(self, fixer: Fixer, x_m: list[np.ndarray], fills: list[np.ndarray] | None = None):
        self.fixer, self.x_m, self.fills = fixer, x_m, fills
        self.window, self.dim = fixer.window, 3 * x_m[0].shape[1]
        self._lerp: dict[int, np.ndarray] = {}

    def estimate(self, windows: list[tuple[int, np.ndarray]]) -> torch.Tensor:
        pos = np.stack([np.where((f >= 0)[:, None, None], self.x_m[k][np.maximum(f, 0)], np.nan) for k, f in windows])
        pos = torch.from_numpy(pos.astype(np.float32))  # (B, W, Jm, 3)
        if self.fills is None:
            return self.fixer.estimate(pos, ~torch.isnan(pos).any(-1)).double().flatten(2)  # (B, W, 3 Jm)
        # past the take's ends (padding; NaN in the resampled fill too) the fill holds the nearest frame
        fill = np.stack([self.fills[k][np.clip(f, 0, len(self.fills[k]) - 1)] for k, f in windows])
        fill = torch.from_numpy(np.nan_to_num(fill))  # (B, W, Jm, 3)
        return self.fixer.estimate(pos, ~torch.isnan(pos).any(-1), fill).double().flatten(2)

    def fallback(self, k: int) -> np.ndarray:
        if k not in self._lerp:
            x = torch.from_numpy(self.x_m[k]).double()[None]  # (1, K, Jm, 3)
            self._lerp[k] = lerp_infill(x, ~torch.isnan(x).any(-1))[0].flatten(1).numpy()
        return self._lerp[k]


def hermite_take_fills(fps_m: float, clips: list[Clip], view: ModelView) -> list[np.ndarray]:
    """For an XMAE that corrects the cubic Hermite fill (fill_kind hermite): each take's Hermite
    fill over the whole take at the recording's own frame rate, brought to the model's (K, Jm, 3).
    A window of the model sees at most a second; the fill from the whole take at, say, 120 fps is
    a better start (on the CMU strangers it beats a cubic spline, docs/results.md)."""
    fills = []
    for c, x, xm in zip(clips, view.x_in, view.x_m):
        xt = torch.from_numpy(x.astype(np.float64))[None]  # (1, T, Jm, 3)
        filled = hermite_infill(xt, ~torch.isnan(xt).any(-1))[0].numpy()
        # NaN past the take's last frame in the model's frames: those hold the last frame
        fills.append(hold_last_frame(resample_frames(filled, c.fps, fps_m, len(xm))).astype(np.float32))
    return fills


def needed_frames(
    clips: list[Clip], view: ModelView, mode: str, fps_m: float, asked: list[np.ndarray] | None = None
) -> list[np.ndarray]:
    """(K,) bool per clip: the model frames that need an estimate. Infill only uses it at missing
    tokens and at the observed frames next to them (anchors); the other modes use it wherever
    there is data. asked: (T,) bool per clip, in infill the frames whose holes are wanted (the
    holes a fill policy is measured on); None: every frame with a missing token."""
    need_m = []
    for k, (c, x, xm) in enumerate(zip(clips, view.x_in, view.x_m)):
        obs = np.isfinite(x).all(-1)  # (T, Jm)
        if mode == "infill":
            gap = ~obs.all(-1) if asked is None else asked[k] & ~obs.all(-1)
            need = gap.copy()
            need[1:] |= gap[:-1]
            need[:-1] |= gap[1:]
        elif mode == "denoise":
            need = obs.any(-1)
        else:
            need = np.ones(len(obs), dtype=bool)
        need_m.append(frames_around(need, c.fps, fps_m, len(xm)))  # the model frames each interpolates from
    return need_m


def joints_missing_for_a_window(x_m: list[np.ndarray], W: int, overlap: float) -> int:
    """Windows (with data) in which some model joint is missing in every frame, joints that are
    missing in the whole clip aside (reported on their own)."""
    count = 0
    for xm in x_m:
        obs = np.isfinite(xm).all(-1)  # (K, Jm)
        starts, _ = window_layout(len(xm), W, overlap)
        sometimes = obs.any(0)
        for s in starts:
            o = obs[max(s, 0) : s + W]
            if o.any() and (~o.any(0) & sometimes).any():
                count += 1
    return count
