"""Limbs held at one length: a tracker's bones breathe, a person's do not.

Depth cameras and video lifters place each joint on its own, so the upper arm of one take is
22 cm in one frame and 26 in the next (Kinect v1: 30-50 mm of standard deviation, docs/results.md),
and no low-pass takes that out: it is as slow as the motion (bench/keypoints_real.py: the 6-Hz
Butterworth and the jitter remover cut it by 0-3 %). The rigid long bones of the limbs (upper arm,
forearm, thigh, shank, foot) are held at their median length over the take: each bone's two ends
are moved along the bone, towards or apart, the shoulder and hip (the torso's joints) staying
put, until every bone has its length (position-based dynamics' distance constraints: each
correction shared between the two ends, which moves the joints less than pushing the whole
error down the chain; a few sweeps settle a chain of three bones). Bone directions are kept.
Joints below a limb's last one (hand tips, thumbs) move with it as every joint the model does not
use moves with the model joint above it (jitter_clips.py). The torso's distances are not held at
one length: a spine bends and a shoulder girdle shrugs, their length between keypoints varies in a
real body. Those the tracker holds steadier than the jitter remover's output are kept as tracked
(hold_torso_lengths): its learned correction moves each joint on its own and made them breathe
where the tracker had them still (MSR Action3D's Kinect v1: spine to shoulder centre 0.4 mm of
standard deviation in, 4.5 out; bench/keypoints_real.py).
"""

from __future__ import annotations

import numpy as np
import torch

from mocapfix.core.skeleton import Skeleton
from mocapfix.models.jitter import lowpass

SWEEPS = 30  # Gauss-Seidel sweeps over the bones: a chain of three settles within ~0.01 mm
TOLERANCE_M = 1e-5  # stop once every bone is this close to its length
LIMBS = ("left_arm", "right_arm", "left_leg", "right_leg")


def limb_bones(model: Skeleton, index: np.ndarray) -> list[tuple[int, int]]:
    """The limbs' rigid bones as (upper, lower) columns of a take: model: the fixer's skeleton,
    its limbs the groups LIMBS (body21: upper arm, forearm; thigh, shank, foot); index: (Jm,)
    the take's column of each model joint, -1 where the take has none (a bone to it is skipped)."""
    bones = []
    for limb in LIMBS:
        group = model.groups.get(limb, ())
        for m in group:
            p = model.parents[m]
            if p in group and index[p] >= 0 and index[m] >= 0:
                bones.append((int(index[p]), int(index[m])))
    return bones


def torso_bones(parents, columns: np.ndarray, limbs: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """The recording's own bones between the columns of a take that are not the limbs' (its tree,
    each column's nearest ancestor that is a column: a Kinect's shoulder centre to its left
    shoulder, not the model's chest, which it lacks): parents: the recording's joints' parents;
    columns: (Jp,) the recording's joint at each column; limbs: limb_bones -> [(upper, lower)]."""
    column = {int(j): k for k, j in enumerate(columns)}
    bones = []
    for k, j in enumerate(columns):
        a = parents[j]
        while a >= 0 and a not in column:
            a = parents[a]
        if a >= 0 and (column[a], k) not in limbs:
            bones.append((column[a], k))
    return bones


def hold_torso_lengths(
    x: np.ndarray, bones: list[tuple[int, int]], recorded: np.ndarray, fps: float, cutoff_hz: float
) -> np.ndarray:
    """x: (T, J, 3) metres, the jitter remover's output, NaN where missing; bones: torso_bones;
    recorded: (T, J, 3) the recording, its holes bridged (finite) -> (T, J, 3) with each bone the
    recording holds steadier than x (a tracker that fits a rigid torso: the network moves each
    joint on its own and made its distances breathe), frame by frame, at the recording's length
    through the jitter remover's low-pass (cutoff_hz), both ends moved along the bone; the other
    bones as x has them (a tracker's jitter, joint by joint, makes the recording's lengths the
    unsteadier ones, and longer on average: they are not kept). A bone with a missing end in a
    frame is left as it is there."""
    if not bones:
        return x
    was, now = _lengths(recorded, bones), _lengths(x, bones)
    shown = np.isfinite(now)  # (T, B): both ends seen; the two takes are compared over those frames
    steadier = np.zeros(len(bones), bool)  # (B,)
    on = np.flatnonzero(shown.any(0))  # the bones shown in some frame
    steadier[on] = np.nanstd(np.where(shown[:, on], was[:, on], np.nan), 0) < np.nanstd(now[:, on], 0)
    if not steadier.any():
        return x
    target = lowpass(torch.from_numpy(was[:, steadier])[None], fps, cutoff_hz)[0].numpy()  # (T, B')
    return _held(x.astype(np.float64), [bone for bone, k in zip(bones, steadier) if k], target, fixed=set())


def hold_limb_lengths(x: np.ndarray, bones: list[tuple[int, int]]) -> tuple[np.ndarray, float]:
    """x: (T, J, 3) metres, NaN where missing; bones: limb_bones -> (T, J, 3) with those bones at
    their median length over the frames that show both ends, and the mean standard deviation
    (mm) of those lengths before. A bone with a missing end in a frame is left as it is there."""
    if not bones:
        return x, 0.0
    out = x.astype(np.float64)
    lengths = _lengths(out, bones)
    if not np.isfinite(lengths).any(0).all():
        keep = np.isfinite(lengths).any(0)
        bones, lengths = [bone for bone, k in zip(bones, keep) if k], lengths[:, keep]
    spread_mm = float(np.nanmean(np.nanstd(lengths, 0)) * 1000)
    tops = {a for a, _ in bones} - {b for _, b in bones}  # the shoulder and hip: the torso's joints
    return _held(out, bones, np.nanmedian(lengths, 0), fixed=tops), spread_mm


def _lengths(x: np.ndarray, bones: list[tuple[int, int]]) -> np.ndarray:
    """x: (T, J, 3) -> (T, B) each bone's length, NaN where an end is missing."""
    return np.stack([np.linalg.norm(x[:, b] - x[:, a], axis=-1) for a, b in bones], -1)


def _held(out: np.ndarray, bones: list[tuple[int, int]], target: np.ndarray, fixed: set[int]) -> np.ndarray:
    """out: (T, J, 3) float64, moved in place; target: (B,) or (T, B) each bone's length; fixed:
    joints that stay put -> out with every bone at its length where both its ends are."""
    target = np.broadcast_to(target, (len(out), len(bones)))  # (T, B)
    moves = {j: 0.0 if j in fixed else 1.0 for bone in bones for j in bone}  # inverse masses
    for _ in range(SWEEPS):
        worst = 0.0
        for (a, b), length in zip(bones, target.T):
            d = out[:, b] - out[:, a]  # (T, 3)
            n = np.linalg.norm(d, axis=-1)
            ok = np.isfinite(n) & (n > 0) & np.isfinite(length)
            error = np.where(ok, n - length, 0.0)
            worst = max(worst, float(np.abs(error).max()))
            step = (error / np.where(ok, n, 1.0))[:, None] * np.where(ok[:, None], d, 0.0)  # (T, 3)
            share = moves[a] + moves[b]
            out[:, a] += moves[a] / share * step
            out[:, b] -= moves[b] / share * step
        if worst < TOLERANCE_M:
            break
    return out
