"""Resampling in time: a recording at one frame rate -> the same motion at another.

Frame k of a recording at fps is the instant t = k / fps. Positions (and root translations) are
interpolated linearly between the two frames around an instant, rotations by slerp on the
shortest arc; an instant both rates share is copied exactly (bit for bit). Everything is numpy
in float64, returned in the input's dtype: the training data (resample_clip, once per dataset)
and `fix` (its windows at the model's rate and back) use the same routines.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from mocapfix.core import lazy_roma as roma
from mocapfix.core.clip import Clip
from mocapfix.core.kinematics import fk_axis_angle


def frames_within(num_frames: int, fps: float, new_fps: float) -> int:
    """Frames at new_fps whose instants lie within a recording of num_frames at fps."""
    return int(math.floor((num_frames - 1) * new_fps / fps + 1e-9)) + 1


def model_frames(num_frames: int, fps: float, model_fps: float) -> int:
    """Frames at the model's fps that cover the input's time span (the last one may be past it)."""
    return int(math.ceil((num_frames - 1) * model_fps / fps - 1e-6)) + 1


def _source_frames(num: int, src_fps: float, dst_fps: float, num_src: int):
    """Where each of num frames at dst_fps falls among num_src frames at src_fps: the frame
    before (i0), the frame after (i1), the weight of the one after (w, float64), and whether
    the instant is past the last frame (past). Within 1e-6 frame of a source frame is on it."""
    f = np.arange(num) * (src_fps / dst_fps)
    f = np.where(np.abs(f - np.round(f)) < 1e-6, np.round(f), f)
    past = f > num_src - 1
    f = np.minimum(f, num_src - 1)
    i0 = np.floor(f).astype(np.int64)
    i1 = np.minimum(i0 + 1, num_src - 1)
    return i0, i1, f - i0, past


def resample_frames(x: np.ndarray, src_fps: float, dst_fps: float, num: int) -> np.ndarray:
    """x: (T, ...) sampled at t = k / src_fps -> (num, ...) at t = k / dst_fps, linear.
    A sample takes NaN from a neighbour it uses (a token next to a missing one stays missing: no
    invented data); shared instants are copied exactly; times past the last frame are NaN (the
    caller decides what they mean: hold_last_frame)."""
    i0, i1, w, past = _source_frames(num, src_fps, dst_fps, x.shape[0])
    w = w.reshape(-1, *([1] * (x.ndim - 1)))
    out = x[i0] * (1 - w) + x[i1] * w
    exact = (w == 0).reshape(-1)
    out[exact] = x[i0[exact]]  # bit-identical, and no NaN from an unused neighbour
    out[past] = np.nan
    return out.astype(x.dtype, copy=False)


def frames_around(marked: np.ndarray, src_fps: float, dst_fps: float, num: int) -> np.ndarray:
    """marked: (T,) bool at src_fps -> (num,) bool at dst_fps: the frames each marked instant lies
    between (both; the one frame it falls on), the last frame for instants past the end."""
    f = np.nonzero(marked)[0] * (dst_fps / src_fps)
    out = np.zeros(num, dtype=bool)
    out[np.minimum(np.floor(f + 1e-6).astype(np.int64), num - 1)] = True
    out[np.minimum(np.ceil(f - 1e-6).astype(np.int64), num - 1)] = True
    return out


def hold_last_frame(x: np.ndarray) -> np.ndarray:
    """(T, ...) with NaN frames past the last finite one (resample_frames' end) -> those hold it."""
    ok = np.isfinite(x.reshape(len(x), -1)).all(-1)
    return x[np.maximum.accumulate(np.where(ok, np.arange(len(x)), 0))]


def resample_motion(
    rotations: np.ndarray, root: np.ndarray, src_fps: float, dst_fps: float, num: int
) -> tuple[np.ndarray, np.ndarray]:
    """rotations (T, J, 3) axis-angle and root translation (T, 3) sampled at t = k / src_fps ->
    (num, J, 3), (num, 3) at t = k / dst_fps: rotations by slerp, the root linearly. Shared
    instants are copied exactly; times past the last frame hold it; NaN stays NaN."""
    i0, i1, w, _ = _source_frames(num, src_fps, dst_fps, rotations.shape[0])
    r0, r1 = (roma.rotvec_to_rotmat(torch.from_numpy(rotations[i]).double()) for i in (i0, i1))  # (num, J, 3, 3)
    step = roma.rotmat_to_rotvec(r0.transpose(-1, -2) @ r1) * torch.from_numpy(w)[:, None, None]
    rot = roma.rotmat_to_rotvec(r0 @ roma.rotvec_to_rotmat(step)).numpy()  # slerp: R0 exp(w log(R0^T R1))
    out_root = root[i0] * (1 - w[:, None]) + root[i1] * w[:, None]
    exact = w == 0
    rot[exact], out_root[exact] = rotations[i0[exact]], root[i0[exact]]
    return rot.astype(rotations.dtype), out_root.astype(root.dtype)


def resample_clip(clip: Clip, fps: float) -> Clip:
    """The clip at `fps`, frame times 0, 1/fps, ... within its duration (frames_within).
    A clip with rotations is resampled in rotation space (resample_motion) and its positions
    recomputed by forward kinematics, so bone lengths stay exact."""
    if abs(clip.fps - fps) < 1e-6:
        return clip
    num = frames_within(clip.num_frames, clip.fps, fps)
    if not clip.has_rotations:
        return clip.replace(positions=resample_frames(clip.positions, clip.fps, fps, num), fps=float(fps))
    rotations, root = resample_motion(clip.rotations, clip.root_translation, clip.fps, fps, num)
    positions = fk_axis_angle(
        torch.from_numpy(rotations), torch.from_numpy(root), torch.from_numpy(clip.offsets), clip.skeleton.parents
    ).numpy()
    return clip.replace(positions=positions, rotations=rotations, root_translation=root, fps=float(fps))
