"""The model's estimate of a clip merged with the clip as read, as the mode says:

infill   missing tokens get the estimate, anchored on the data at both ends of each hole
         (and, with a fill policy, the fill it names for the hole); observed tokens stay.
denoise  observed tokens get the estimate; missing tokens stay missing.
both     every token gets the estimate.
"""

from __future__ import annotations

import numpy as np
import torch

from mocapfix.core.skeleton import Skeleton
from mocapfix.fills.classical import classical_fills, lerp_infill
from mocapfix.fills.fill import Made
from mocapfix.fills.motion_matching import MotionMatching
from mocapfix.fills.policy import FillPolicy


def merge(
    est: np.ndarray,
    x_in: np.ndarray,
    index: np.ndarray,
    mode: str,
    policy: FillPolicy | None,
    fps: float,
    model: Skeleton,
    filled_by: dict[str, int],
    match: MotionMatching,
    candidate: str = "xmae",
) -> np.ndarray:
    """est: (T, Jm, 3) the model's estimate at a clip's frames, x_in (T, Jm, 3) the clip at the
    model's joints, index (Jm,) the clip's joint of each model joint (-1: none) -> (T, Jm, 3)
    float64, the two merged as the mode says. filled_by counts the policy's fills by method;
    match: the motion-matching fill of this take, should the policy choose it; candidate: the
    estimate's name among the policy's candidates (the fixer's)."""
    x = x_in.astype(np.float64)
    obs = np.isfinite(x).all(-1)  # (T, Jm)
    if mode == "denoise":
        return np.where(obs[..., None], est, np.nan)
    if mode == "both":
        return est
    # Anchor the estimate on the data: the residual at observed tokens, interpolated over each
    # gap, is added to the fill, so the fill meets the data at both gap ends. Where the model ran
    # for no hole (the policy chose no learned fill: often on new performers) there is nothing to
    # anchor, and the take's Lerp was a few per cent of fix's time.
    if np.isnan(est).all():
        new = np.where(obs[..., None], x, np.nan)
    else:
        resid = torch.from_numpy(np.where(obs[..., None], x - est, np.nan))
        resid = lerp_infill(resid[None], torch.from_numpy(obs)[None])[0].numpy()
        new = np.where(obs[..., None], x, est + resid)
    if policy is not None:
        absent = index < 0
        model_fill = new[:, absent]
        fills = [Made(candidate, torch.from_numpy(new)[None]), *classical_fills(), match]
        # counted: the joints the recording has and shows (the fill of one it lacks, or never
        # shows, is not written: write_back.py)
        xt, ot = torch.from_numpy(x)[None], torch.from_numpy(obs)[None]
        counted = torch.from_numpy(~absent & obs.any(0))
        out, counts = policy.transform(xt, ot, fps, model, fills, counted)
        for method, n in counts.items():
            filled_by[method] = filled_by.get(method, 0) + n
        new = out[0].numpy()
        new[:, absent] = model_fill  # no classical fill has anything to go on there
    return new
