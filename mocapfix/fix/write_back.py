"""A positions pass's result written back into a clip: the merged estimate (merge.py) into the
clip's own joints of the model, the holes of the joints the model does not use (fingers, extra
spine joints) filled along the skeleton, and what was written counted for the report
(report.py: PassTally).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.core.skeleton import Skeleton
from mocapfix.fills.classical import limb_infill
from mocapfix.fix.fixer import Fixer
from mocapfix.fix.joints import ModelView
from mocapfix.fix.report import NOT_JUDGED, PassTally


def clip_fixed(
    c: Clip,
    k: int,
    new: np.ndarray,
    view: ModelView,
    fixer: Fixer,
    mode: str,
    keep: bool,
    seen: list[np.ndarray] | None,
    fill_other_joints: bool,
    tally: PassTally,
    name: Callable[[int], str],
    source: str,
) -> Clip:
    """Clip k with the merged estimate `new` (T, Jm, 3) written into its model joints; counted.
    keep: its observed tokens stay bit-identical; seen: see positions_pass."""
    model, x_in, index = fixer.skeleton, view.x_in[k], view.index[k]
    obs = np.isfinite(x_in).all(-1)  # (T, Jm)
    new = new.astype(np.float32)
    if keep:
        new[obs] = x_in[obs]  # bit-identical, whatever float64 did
    if keep and mode != "infill":
        tally.notes.append(
            f"{name(k)}{c.num_frames} frames, shorter than the model's window ({fixer.window} frames at "
            f"{fixer.fps:g} fps): " + NOT_JUDGED
        )
    must = obs if mode == "denoise" else np.ones_like(obs)
    if not np.isfinite(new[must]).all():  # a bug, never data: do not write it
        raise MotionFileError(source, f"{name(k)}the estimate is not finite; nothing written")
    tally.filled += int((~obs).sum()) if mode != "denoise" else 0
    tally.replaced += int(obs.sum()) if not keep else 0
    present = index >= 0
    observed = obs if seen is None else seen[k]
    never = ~observed.any(0) & present  # (Jm,) joints the take has and never shows
    if never.any():
        tally.never[name(k) or ""] = [model.joint_names[j] for j in np.nonzero(never)[0]]
    if not present.all():
        tally.absent[name(k) or ""] = [model.joint_names[j] for j in np.nonzero(~present)[0]]
    # Estimated to fix the rest, not written: a joint the take lacks, or one it never shows (a
    # limb out of a camera's view all take long): nothing in the take says where it was, and a
    # body's guess written as data would be silently wrong.
    written = present & ~never
    tally.filled -= int((~obs[:, ~written]).sum()) if mode != "denoise" else 0

    positions = c.positions.copy()
    positions[:, index[written]] = new[:, written]
    if fill_other_joints and mode != "denoise":
        positions, n = fill_other_joints_of(positions, index, c.skeleton)
        tally.other_filled += n
    tally.limbs.add(x_in, new, index)  # the limbs of the joints the clip has
    return c.replace(positions=positions, rotations=None, root_translation=None, offsets=None)


def fill_other_joints_of(positions: np.ndarray, model_joints: np.ndarray, skeleton: Skeleton) -> tuple[np.ndarray, int]:
    """positions: (T, J, 3) a clip with the model's joints fixed -> the holes of its other joints
    (fingers, extra spine joints) filled by the limb fill (each from its parent, bone length kept,
    fills/classical.py), and how many tokens that filled. Observed tokens stay as they are;
    a joint never seen in the clip stays missing."""
    other = np.setdiff1d(np.arange(skeleton.num_joints), model_joints)
    holes = ~np.isfinite(positions[:, other]).all(-1)  # (T, E)
    if not holes.any():
        return positions, 0
    x = torch.from_numpy(positions.astype(np.float64))[None]
    filled = limb_infill(x, ~torch.isnan(x).any(-1), skeleton.parents)[0].numpy()  # (T, J, 3)
    holes &= (~holes).any(0)  # the limb fill gives a joint never seen the body's mean: not written
    out = positions.copy()
    out[:, other] = np.where(holes[..., None], filled[:, other], positions[:, other])
    return out, int(np.isfinite(out[:, other]).all(-1)[holes].sum())
