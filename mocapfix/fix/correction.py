"""A learned correction to a classical fill (models/correction.py) applied to whole takes.

The network was trained on one hole at a time with `context_frames` of data on each side, at its
own frame rate. A take's holes are found (runs of frames in which a joint the take has is
missing), each is cropped from the take's base fill with that context, and the crops go through
the network in batches of one length (a crop that meets the take's edge is shorter: the network
knows which of its context frames lie outside, as in training). The base fill itself is made over
the whole take (a spline with seconds of data around the hole, not a crop's third of a second).

A take at another frame rate is seen at the network's: the correction is made there and brought
back to the take's frames (linearly; it is a smooth offset), then added to the base fill made at
the take's own rate. Holes longer than the network was trained on (max_hole_s) keep the base
fill: what it would output there is untested.
"""

from __future__ import annotations

import numpy as np
import torch

from mocapfix.core.resample import frames_around, frames_within, model_frames, resample_frames
from mocapfix.fills.holes import runs
from mocapfix.models.correction import CorrectionNet, base_fill


def hole_runs(missing: np.ndarray, longest: int) -> list[tuple[int, int]]:
    """missing: (T, J) bool -> [(start, end)) of each run of frames with a missing token, those
    no longer than `longest` frames."""
    return [(s, e) for s, e in runs(missing.any(-1)) if e - s <= longest]


@torch.inference_mode()
def corrections(net: CorrectionNet, base: np.ndarray, hole: np.ndarray, runs: list[tuple[int, int]]) -> np.ndarray:
    """base: (T, J, 3) a take's base fill (finite), hole: (T, J) bool, the tokens it filled, runs:
    the holes to correct -> (T, J, 3) float64, the network's correction (zero elsewhere)."""
    T = len(base)
    C = net.config.context_frames
    out = np.zeros(base.shape, dtype=np.float64)
    crops: dict[int, list[tuple[int, int, int]]] = {}  # crop length -> (lo, start, end)
    for s, e in runs:
        lo, hi = max(0, s - C), min(T, e + C)
        crops.setdefault(hi - lo, []).append((lo, s, e))
    dtype = next(net.parameters()).dtype
    device = next(net.parameters()).device
    for length, group in crops.items():
        x = np.stack([base[lo : lo + length] for lo, _, _ in group])  # (B, L, J, 3)
        h = np.zeros(x.shape[:3], dtype=bool)  # (B, L, J): only this crop's own hole is corrected
        for b, (lo, s, e) in enumerate(group):
            h[b, s - lo : e - lo] = hole[s:e]
        xt = torch.from_numpy(x).to(device, dtype)
        ht = torch.from_numpy(h).to(device)
        delta = (net(xt, ht) - xt).double().cpu().numpy()  # (B, L, J, 3), zero outside the hole
        for b, (lo, s, e) in enumerate(group):
            out[s:e] += delta[b, s - lo : e - lo]
    return out


def corrected_take(
    net: CorrectionNet, x: np.ndarray, fps: float, fps_m: float, max_hole_s: float, asked: np.ndarray | None = None
) -> tuple[np.ndarray, int]:
    """x: (T, J, 3) a take at the network's joints and its own fps, NaN = missing; asked: (T,)
    bool, the frames whose holes are wanted (None: all) -> ((T, J, 3) float64 with every hole
    filled by the base fill, corrected where it is one the network takes; observed tokens as
    given), and the holes corrected. A joint the take never shows is no hole (the base fill's
    stand-in, never written)."""
    xt = torch.from_numpy(x.astype(np.float64))[None]
    observed = torch.isfinite(xt).all(-1)  # (1, T, J)
    base = base_fill(net.config, xt, observed)[0].numpy()  # (T, J, 3)
    shown = observed[0].any(0).numpy()  # (J,)
    hole = ~observed[0].numpy() & shown  # (T, J)
    if not hole.any():
        return base, 0
    same_rate = abs(fps - fps_m) < 1e-6 * fps_m
    if same_rate:
        base_m, hole_m, wanted = base, hole, asked
    else:  # the take at the network's rate: its holes there, and its own fill of them
        K = model_frames(len(x), fps, fps_m)
        x_m = _past_end_held(resample_frames(x.astype(np.float64), fps, fps_m, K), frames_within(len(x), fps, fps_m))
        xm = torch.from_numpy(x_m)[None]
        observed_m = torch.isfinite(xm).all(-1)
        base_m = base_fill(net.config, xm, observed_m)[0].numpy()
        hole_m = ~observed_m[0].numpy() & shown
        wanted = None if asked is None else frames_around(asked, fps, fps_m, K)
    holes = hole_runs(hole_m, max(1, round(max_hole_s * fps_m)))
    if wanted is not None:
        holes = [(s, e) for s, e in holes if wanted[s:e].any()]
    if not holes:
        return base, 0
    delta = corrections(net, base_m, hole_m, holes)
    if not same_rate:
        # a take's hole frame between the network's last hole frame and the next one (observed
        # there, no correction) takes the hole's correction, not a ramp down to nothing
        for s, e in holes:
            delta[max(s - 1, 0)] = delta[s]
            delta[min(e, len(delta) - 1)] = delta[e - 1]
        delta = _past_end_held(resample_frames(delta, fps_m, fps, len(x)), frames_within(K, fps_m, fps))
    return np.where(hole[..., None], base + delta, base), len(holes)


def _past_end_held(x: np.ndarray, within: int) -> np.ndarray:
    """x: (K, ...) resampled, its first `within` frames inside the source -> the frames past it
    hold the last one (hold_last_frame would fill the holes too)."""
    within = min(within, len(x))
    x[within:] = x[within - 1]
    return x
