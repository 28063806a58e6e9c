"""Rotation models (Motion-DVAE on its rotations state): joint rotations in, joint rotations out.

The clips' local rotations at the model's joints and fps -> windows of the model's length ->
estimates blended as quaternions (RotationWindows) -> the input's frame times; the positions
are the forward kinematics of the result. A BVH input is read again with the model's joints only
(rotation_clips) and gets a BVH output with the model's rotations.
"""

from __future__ import annotations

import numpy as np
import torch

from mocapfix.core import lazy_roma as roma
from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.core.kinematics import fk_axis_angle
from mocapfix.core.resample import model_frames, resample_motion
from mocapfix.fix.fixer import FOR_ANY_RIG, Fixer, FixOptions
from mocapfix.fix.report import NOT_JUDGED, FixReport, LimbSpread, frames_and_people, who
from mocapfix.fix.windowing import blend_windows
from mocapfix.io import read_motion


class RotationFixer(Fixer):
    """A fixer whose estimate is every frame's joint rotations: estimate_rotations(rotations
    (B, W, J, 3) local axis-angle (joint 0: root orientation), root_translation (B, W, 3), offsets
    (B, J, 3)) -> rotations (B, W, J, 3), root translation (B, W, 3), float32 on the CPU. The
    window is the longest; a clip shorter than it is one window of its own length."""

    gives_rotations = True
    notes: list[str] = []  # said once per file in the report

    def fix_clips(self, clips: list[Clip], options: FixOptions) -> tuple[list[Clip], FixReport]:
        return fix_rotations(clips, self, options)

    def clips_for(self, path, clips: list[Clip], source: str = "auto", joint_map=None, **read_options) -> list[Clip]:
        return rotation_clips(path, clips, self, source, joint_map, **read_options)


def rotation_clips(
    path,
    clips: list[Clip],
    fixer: RotationFixer,
    source: str = "auto",
    joint_map: dict[str, str] | None = None,
    **read_options,
) -> list[Clip]:
    """The clips of a file as a rotation model needs them. A BVH file is read again with only
    the model's joints (read_bvh keep_joints), as the model was trained (without a helper root
    such as Bandai Namco's joint_Root): with a joint whose translation moves below the root, the
    whole tree has no exact rotations, the model's joints do. Other formats come as they are.
    A rig whose joints that play the model's do not hang as one tree is a MotionFileError naming
    the shipped models that take it."""
    first = clips[0]
    if first.meta.get("format") != "bvh":
        return clips
    index = fixer.model_joints(first, path, joint_map)
    if first.has_rotations and len(index) == first.skeleton.num_joints:
        return clips
    names, parents, kept = first.skeleton.joint_names, first.skeleton.parents, set(index.tolist())
    tops = []  # the kept joints below no other kept joint: one, the model's root, for one tree
    for j in index:
        a = parents[j]
        while a >= 0 and a not in kept:
            a = parents[a]
        if a < 0:
            tops.append(names[j])
    if len(tops) > 1:
        raise MotionFileError(
            path,
            f"the model ({fixer.kind}) fixes the rotations of its {len(index)} joints as one tree; in this rig the "
            f"joints that play them hang apart ({', '.join(tops)} meet only at joints the model does not have); "
            + FOR_ANY_RIG,
        )
    keep = [names[i] for i in index]
    return read_motion(path, "bvh" if source == "auto" else source, **read_options, keep_joints=keep)


class RotationWindows:
    """Windows of joint rotations for a rotations fixer (windowing.WindowSource): per clip the
    local axis-angle rotations (K, Jm, 3) and root translation (K, 3) at the model's fps, and the
    bone offsets (Jm, 3). The estimate is blended as unit quaternions, each turned to the
    hemisphere of the input's (q and -q are one rotation), and renormalised after (the weighted
    sum); the root translation linearly. The fallback is the input itself."""

    fixed_length = False  # recurrent networks: a short clip is a short window

    def __init__(self, fixer: RotationFixer, rotations: list, roots: list, offsets: list):
        self.fixer, self.rotations, self.roots, self.offsets = fixer, rotations, roots, offsets
        self.window, self.dim = fixer.window, 4 * rotations[0].shape[1] + 3
        self.q_ref = [roma.rotvec_to_unitquat(torch.from_numpy(r).double()) for r in rotations]  # (K, Jm, 4)

    def estimate(self, windows: list[tuple[int, np.ndarray]]) -> torch.Tensor:
        rot = torch.stack([torch.from_numpy(self.rotations[k][f]) for k, f in windows])  # (B, L, Jm, 3)
        root = torch.stack([torch.from_numpy(self.roots[k][f]) for k, f in windows])  # (B, L, 3)
        offs = torch.stack([torch.from_numpy(self.offsets[k]) for k, _ in windows])  # (B, Jm, 3)
        est_rot, est_root = self.fixer.estimate_rotations(rot, root, offs)
        q = roma.rotvec_to_unitquat(est_rot.double())  # (B, L, Jm, 4)
        ref = torch.stack([self.q_ref[k][f] for k, f in windows])
        q = torch.where((q * ref).sum(-1, keepdim=True) < 0, -q, q)
        return torch.cat([q.flatten(2), est_root.double()], -1)  # (B, L, 4 Jm + 3)

    def fallback(self, k: int) -> np.ndarray:
        return torch.cat([self.q_ref[k].flatten(1), torch.from_numpy(self.roots[k]).double()], -1).numpy()


def fix_rotations(clips: list[Clip], fixer: RotationFixer, options: FixOptions) -> tuple[list[Clip], FixReport]:
    """Fix clips with rotations through a rotation model; each keeps its skeleton, frames and fps,
    and comes back with rotations, root translation and the positions their forward kinematics
    gives.

    Rotation data has no missing tokens, so `infill` leaves the clips as they are; `denoise` and
    `both` replace every frame. The model's joints must hang as in the model (the input may have
    more joints: they keep their rotations and move with their parents). Windows as for
    positions (resampled to the model's fps by slerp, windows of the model's length, stride
    window * (1 - overlap)); a clip shorter than a window is kept as it is (too_short: too little
    motion to judge it by). Overlapping windows are blended as RotationWindows says."""
    fps_m, name, source = fixer.fps, who(clips), clips[0].source or clips[0].name
    notes = list(fixer.notes)
    index = [_rotation_joints(c, i, fixer, options.joint_map, name, source) for i, c in enumerate(clips)]
    frames, people = frames_and_people(clips)
    if options.mode == "infill":
        notes.append("rotation input has no missing tokens: nothing to fill (--mode denoise replaces them)")
        return list(clips), FixReport(frames, people, 0, 0, *_spread(fixer, clips, index), 0, notes)

    # Each clip long enough to judge (too_short) at the model's fps; every frame needs the estimate.
    judged = [k for k, c in enumerate(clips) if not fixer.too_short(c)]
    for k in sorted(set(range(len(clips))) - set(judged)):
        notes.append(
            f"{name(k)}{clips[k].num_frames} frames, shorter than the model's window "
            f"({fixer.window} frames at {fps_m:g} fps): {NOT_JUDGED}"
        )
    if not judged:
        return list(clips), FixReport(frames, people, 0, 0, *_spread(fixer, clips, index), 0, notes)
    rot_m, root_m = [], []
    for k in judged:
        c, idx = clips[k], index[k]
        frames_m = model_frames(c.num_frames, c.fps, fps_m)
        r, t = resample_motion(c.rotations[:, idx], c.root_translation, c.fps, fps_m, frames_m)
        rot_m.append(r)
        root_m.append(t)
    windows = RotationWindows(fixer, rot_m, root_m, [clips[k].offsets[index[k]] for k in judged])
    need = [np.ones(len(r), dtype=bool) for r in rot_m]
    blended = blend_windows(windows, need, need, options.overlap, options.batch_size, options.progress)
    out, replaced, posed = _posed(clips, index, dict(zip(judged, blended.tracks)), fixer, name, source)
    if blended.failed:
        notes.append(f"{blended.failed} windows gave non-finite estimates: the input blended in there")
    spread = _spread(fixer, clips, index, posed)
    return out, FixReport(frames, people, 0, replaced, *spread, blended.windows, notes)


def _spread(fixer: RotationFixer, clips: list[Clip], index: list[np.ndarray], posed=None) -> tuple[float, float]:
    """The limbs' spread (LimbSpread) before and after; posed: each clip's positions (T, J, 3) as
    fixed (float64, before they are written as float32), None: as read."""
    spread = LimbSpread(fixer.skeleton)
    for k, (c, idx) in enumerate(zip(clips, index)):
        spread.add(c.positions[:, idx], (c.positions if posed is None else posed[k])[:, idx])
    return spread.values()


def _rotation_joints(c: Clip, i: int, fixer: RotationFixer, joint_map, name, source) -> np.ndarray:
    """(Jm,) clip i's index of each model joint, or a MotionFileError saying why its rotations
    cannot be fixed by the model (none, another hierarchy, not finite)."""
    model = fixer.skeleton
    idx = fixer.model_joints(c, source, joint_map)
    if not c.has_rotations:
        why = c.meta.get("no_rotations")
        if why == "the kept joints have no constant bone offsets":  # the rig's own rotations do not fit
            problem = (
                f"this rig's rotations do not fit its {model.num_joints}-joint hierarchy ({model.name}): "
                "joints of the rig between the model's turn too"
            )
        else:
            problem = f"this input has none{f' ({why})' if why else ''}"
        raise MotionFileError(
            source,
            f"{name(i)}the model ({fixer.kind}, rotations state) needs joint rotations; {problem} ({FOR_ANY_RIG})",
        )
    hangs = [c.skeleton.parents[idx[m]] == (idx[p] if p >= 0 else -1) for m, p in enumerate(model.parents)]
    if not all(hangs):
        bad = model.joint_names[hangs.index(False)]
        raise MotionFileError(
            source,
            f"{name(i)}skeleton hierarchy differs from the model's ({model.name}): joint {bad} has another parent "
            f"({FOR_ANY_RIG})",
        )
    if not (np.isfinite(c.rotations).all() and np.isfinite(c.root_translation).all()):
        raise MotionFileError(source, f"{name(i)}rotations are not finite")
    return idx


def _posed(clips, index, tracks: dict, fixer: RotationFixer, name, source):
    """Each clip with its blended track (K, 4 Jm + 3) at its own frames, posed by forward
    kinematics (a clip without a track as it was) -> (clips, tokens replaced, each clip's
    positions (T, J, 3) as posed)."""
    Jm = fixer.skeleton.num_joints
    out, replaced, posed = [], 0, []
    for k, (c, idx) in enumerate(zip(clips, index)):
        if k not in tracks:
            posed.append(c.positions)
            out.append(c)
            continue
        track = torch.from_numpy(tracks[k])  # (K, 4 Jm + 3)
        q = track[:, : 4 * Jm].reshape(-1, Jm, 4)
        rot = roma.unitquat_to_rotvec(q / q.norm(dim=-1, keepdim=True)).numpy()  # (K, Jm, 3)
        root = track[:, 4 * Jm :].numpy()  # (K, 3)
        rot, root = resample_motion(rot, root, fixer.fps, c.fps, c.num_frames)
        rotations = c.rotations.astype(np.float64)
        rotations[:, idx] = rot
        positions = fk_axis_angle(
            torch.from_numpy(rotations),
            torch.from_numpy(root),
            torch.from_numpy(c.offsets.astype(np.float64)),
            c.skeleton.parents,
        ).numpy()
        if not (np.isfinite(positions).all() and np.isfinite(rotations).all()):  # a bug, never data
            raise MotionFileError(source, f"{name(k)}the estimate is not finite; nothing written")
        replaced += c.num_frames * len(idx)
        posed.append(positions)
        out.append(
            c.replace(
                positions=positions.astype(np.float32),
                rotations=rotations.astype(np.float32),
                root_translation=root.astype(np.float32),
            )
        )
    return out, replaced, posed
