"""`--mode both` and `denoise` with a fill policy: observed tokens are replaced only where a joint
jumped away from the model's estimate and back. Two passes: the model's estimate of every token
(pass 1) says which observed tokens jumped (fills/jumps.py: excursions); they are taken out and
filled like holes with the rest (pass 2: the model's estimate with the wrong value in view would
be pulled towards it). Every other observed token stays bit-identical: a model that disagrees
with an unusual motion does not move it.
"""

from __future__ import annotations

import numpy as np
import torch

from mocapfix.core.clip import Clip
from mocapfix.fills.jumps import excursions, recording_step_floor
from mocapfix.fills.policy import FillPolicy
from mocapfix.fix.fixer import Fixer, FixOptions
from mocapfix.fix.joints import ModelView, map_joints, model_view
from mocapfix.fix.measure import measure_views
from mocapfix.fix.positions import positions_pass, with_mode
from mocapfix.fix.report import NOT_JUDGED, FixReport

# A joint's observed tokens are replaced where it jumped away from the model's estimate by more
# than JUMP_STEP x the checkpoint's replace threshold (0.15 m for the shipped XMAE), and by more
# than the recording's own residual steps allow (recording_step_floor), and back within
# MAX_REPLACED_S (fills/jumps.py: excursions).
JUMP_STEP = 2 / 3
MAX_REPLACED_S = 2.0


def replace_jumps(
    clips: list[Clip],
    fixer: Fixer,
    options: FixOptions,
    policy: FillPolicy,
    policy_note: str | None,
    view: ModelView | None,
) -> tuple[list[Clip], FixReport]:
    """The clips of one file in options.mode (denoise or both) with their jumps replaced and, in
    both, their holes filled by the policy (policy_note: where it was measured, if it was)."""
    # Pass 1: the model's estimate of every token; the observed tokens it disagrees with are suspect.
    # (only the model's joints of it are used: the other joints are left as they are)
    estimates, first = positions_pass(clips, fixer, with_mode(options, "both"), None, False, view=view)
    masked, seen, replaced, min_step = _take_out_jumps(clips, estimates, fixer, options, policy)
    suspects = sum(int(bad.sum()) for _, bad in replaced)
    if fixer.measures_policy and policy_note is None:
        masked_view = model_view(masked, fixer.skeleton, fixer.fps, options.joint_map)
        if masked_view.has_holes():  # holes or jumps to fill
            policy, policy_note = measure_views(
                fixer, [masked_view], [masked], "infill", options.overlap, options.batch_size, library=options.library
            )
    # Pass 2: the holes and the suspect tokens filled by the policy; the rest stays bit-identical.
    out, report = positions_pass(masked, fixer, with_mode(options, "infill"), policy, options.mode != "denoise", seen)
    report.filled, report.replaced = report.filled - suspects, suspects
    out = [carry_passengers(o, c, idx, bad) for o, c, (idx, bad) in zip(out, clips, replaced)]
    if options.mode == "denoise":  # holes of the input stay holes
        out = [
            o.replace(positions=np.where(np.isnan(c.positions), np.nan, o.positions).astype(np.float32))
            for o, c in zip(out, clips)
        ]
        report.filled = 0
    report.windows += first.windows
    report.limb_sigma_before_mm = first.limb_sigma_before_mm
    report.notes.insert(
        0,
        f"replaced where a joint jumped more than {1000 * min_step:.0f} mm away from "
        f"the model's estimate and back within {MAX_REPLACED_S:g} s"
        if policy.replace_threshold_m is not None
        else "no replace threshold: observed tokens kept",
    )
    report.notes[:0] = [n for n in first.notes if n.endswith(NOT_JUDGED)] + ([policy_note] if policy_note else [])
    return out, report


def _take_out_jumps(clips, estimates, fixer: Fixer, options: FixOptions, policy: FillPolicy):
    """The clips with the tokens that jumped away from the estimates made missing -> (the clips,
    per clip the tokens the recording observed (T, Jm), per clip (the clip's index of each model
    joint it has, the tokens taken out (T, Jm')), the smallest jump that counted (m))."""
    masked, seen, replaced, min_step = [], [], [], 0.0
    for c, e in zip(clips, estimates):
        idx = map_joints(c.skeleton, fixer.skeleton, c.source, options.joint_map, allow_missing=True)
        seen.append(np.isfinite(c.positions[:, np.maximum(idx, 0)]).all(-1) & (idx >= 0))  # (T, Jm)
        idx = idx[idx >= 0]  # the model joints the recording has
        x = torch.from_numpy(c.positions[:, idx])
        obs = ~torch.isnan(x).any(-1)
        if policy.replace_threshold_m is None:
            bad = np.zeros(obs.shape, dtype=bool)
        else:  # (T, Jm) the tokens that jumped away from the estimate and back
            residual = torch.nan_to_num(x - torch.from_numpy(e.positions[:, idx]))
            step = max(JUMP_STEP * policy.replace_threshold_m, recording_step_floor(residual, obs))
            min_step = max(min_step, step)
            bad = excursions(residual, obs, step, round(MAX_REPLACED_S * c.fps)).numpy()
        if fixer.too_short(c):  # no evidence to judge a token against: kept (pass 1 said so)
            bad[:] = False
        positions = c.positions.copy()
        positions[:, idx] = np.where(bad[..., None], np.nan, positions[:, idx])
        masked.append(c.replace(positions=positions))
        replaced.append((idx, bad))
    return masked, seen, replaced, min_step


def carry_passengers(fixed: Clip, clip: Clip, model_joints: np.ndarray, replaced: np.ndarray) -> Clip:
    """The joints the model does not use (fingers, toes, twist bones) move with the nearest model
    joint above them where that one was replaced: a hand that jumped and was put back brings its
    fingers. model_joints: (Jm,) the clip's index of each model joint; replaced: (T, Jm)."""
    if not replaced.any():
        return fixed
    parents, positions = clip.skeleton.parents, fixed.positions.copy()
    column = {int(j): k for k, j in enumerate(model_joints)}
    for j in range(clip.skeleton.num_joints):
        if j in column:
            continue
        a = parents[j]
        while a >= 0 and a not in column:
            a = parents[a]
        if a < 0:
            continue
        moved = replaced[:, column[a]] & np.isfinite(clip.positions[:, j]).all(-1)  # (T,)
        positions[moved, j] = clip.positions[moved, j] + fixed.positions[moved, a] - clip.positions[moved, a]
    return fixed.replace(positions=positions)
