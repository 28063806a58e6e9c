"""`fix --mode denoise` with the jitter remover (models/jitter.py): whole takes of any rig that maps.

Each take at the model's joints (found by structure and names, as for every model) is low-passed
and corrected at its own frame rate (fixers.JitterFixer.denoise). The model's joints a rig lacks
(a keypoint layout's: COCO has no spine, Human3.6M no clavicles) or never shows are placed from
the rest for the network (rig/stand_ins.py) and not written. The rig's other joints (fingers,
toes, extra spine and twist joints) get the same low-pass and move with the nearest model joint
above them by its correction, so a hand brings its fingers along. Holes stay holes: jitter is
taken out of what was recorded and nothing is invented (an XMAE fills holes). A take of joint
positions (keypoints, positions files) then has its limbs held at one length (limbs.py): no
low-pass takes out bones that breathe as slowly as the body moves; the torso's distances that
its tracker holds steadier than the learned correction does are kept as tracked. A take shorter
than MIN_TAKE_S is kept as recorded: too little motion to tell jitter from it.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.fills.classical import lerp_infill
from mocapfix.fix.limbs import hold_limb_lengths, hold_torso_lengths, limb_bones, torso_bones
from mocapfix.fix.report import NOT_JUDGED, FixReport, LimbSpread, frames_and_people, who
from mocapfix.models.jitter import lowpass
from mocapfix.rig.stand_ins import with_stand_ins

MIN_TAKE_S = 1.0  # shorter takes are kept as recorded


def denoise_clips(
    clips: list[Clip],
    fixer,  # fixers.JitterFixer
    mode: str,
    progress: Callable[[int, int], None] | None = None,
    joint_map: dict[str, str] | None = None,
) -> tuple[list[Clip], FixReport]:
    """The clips of one file with their jitter removed; each keeps its skeleton, frames and fps
    (positions only: a BVH goes back into its hierarchy by inverse kinematics, as for XMAE)."""
    model, source = fixer.skeleton, clips[0].source or clips[0].name
    if mode != "denoise":
        raise MotionFileError(
            source,
            f"a jitter remover takes jitter out (--mode denoise), it does not fill holes (--mode {mode}): an XMAE does",
        )
    name = who(clips)
    out, replaced, passengers, notes, held = [], 0, 0, [], []
    spread = LimbSpread(model)
    absent_notes: list[str] = []
    for k, c in enumerate(clips):
        index = fixer.model_joints(c, source, joint_map, allow_missing=True)  # (Jm,) -1: the rig lacks it
        x = torch.from_numpy(c.positions.astype(np.float64))[None]  # (1, T, J, 3)
        observed = ~torch.isnan(x).any(-1)  # (1, T, J)
        if not (index >= 0).all():
            absent = ", ".join(model.joint_names[m] for m in np.nonzero(index < 0)[0])
            absent_notes.append(
                f"{name(k)}model joints not in the recording: {absent} (placed from the rest, not written)"
            )
        never = [m for m, j in enumerate(index) if j >= 0 and not observed[0, :, j].any()]
        if never:  # placed from the rest like a joint the rig lacks; nothing to denoise, left missing
            shown = ", ".join(model.joint_names[m] for m in never)
            absent_notes.append(f"{name(k)}joints never observed: {shown} (left missing: never shown)")
            index = index.copy()
            index[never] = -1
        present = index >= 0
        if c.duration_s < MIN_TAKE_S:  # too little motion to tell jitter from it
            notes.append(f"{name(k)}{c.num_frames} frames, shorter than {MIN_TAKE_S:g} s: {NOT_JUDGED}")
            out.append(c.replace(rotations=None, root_translation=None, offsets=None))
            continue
        # the low-pass needs every frame: holes are bridged for it and put back afterwards
        filled = lerp_infill(x, observed)
        try:
            positions = lowpass(filled, c.fps, fixer.net.cutoff_hz)[0].numpy()  # (T, J, 3) every joint
            at_model = np.zeros((c.num_frames, len(index), 3))  # (T, Jm, 3), absent joints placed from the rest
            at_model[:, present] = filled[0][:, index[present]].numpy()
            at_model = with_stand_ins(at_model, present, model)
            base = with_stand_ins(np.where(present[:, None], positions[:, np.maximum(index, 0)], 0.0), present, model)
            denoised = fixer.denoise(at_model, c.fps, base)[:, present]  # (T, Jp, 3)
        except ValueError as e:  # a frame rate too low for the model's cutoff, a rig too sparse to stand in for
            raise MotionFileError(source, f"{name(k)}{e}") from None
        model_index, index = index, index[present]
        if not c.has_rotations:  # a hierarchy's bones are rigid already; a tracker's breathe
            seen = observed[0][:, index].numpy()  # the lengths and their corrections where recorded
            columns = np.where(present, np.cumsum(present) - 1, -1)  # each model joint's in denoised
            limbs = limb_bones(model, columns)
            torso = torso_bones(c.skeleton.parents, index, limbs)
            kept = np.where(seen[..., None], denoised, np.nan)
            kept = hold_torso_lengths(kept, torso, filled[0][:, index].numpy(), c.fps, fixer.net.cutoff_hz)
            kept, spread_mm = hold_limb_lengths(kept, limbs)
            denoised = np.where(seen[..., None], kept, denoised)
            held.append(spread_mm)
        correction = denoised - positions[:, index]  # the passengers below move with it, held limbs too
        positions[:, index] = denoised
        column = {int(j): m for m, j in enumerate(index)}
        parents = c.skeleton.parents
        for j in range(c.skeleton.num_joints):
            a = j
            while a >= 0 and a not in column:
                a = parents[a]
            if j not in column and a >= 0:  # a passenger: moves with the model joint above it
                positions[:, j] += correction[:, column[a]]
                passengers += 1
        positions = np.where(observed[0, ..., None].numpy(), positions, np.nan).astype(np.float32)
        replaced += int(observed[0][:, index].sum())
        at = np.maximum(model_index, 0)
        spread.add(c.positions[:, at], positions[:, at], model_index)
        out.append(c.replace(positions=positions, rotations=None, root_translation=None, offsets=None))
        if progress is not None:
            progress(k + 1, len(clips))

    notes[:0] = [f"jitter taken out: a {fixer.net.cutoff_hz:g}-Hz zero-phase low-pass and the model's correction to it"]
    if any(held):
        notes.append(
            f"the limbs' long bones held at each take's median length (they varied by {np.mean(held):.1f} mm "
            "after the low-pass), the torso's distances the tracker holds steadier kept as tracked"
        )
    notes += absent_notes
    if passengers:
        notes.insert(
            1, f"{passengers} joints the model does not use low-passed and moved with the model joint above them"
        )
    frames, people = frames_and_people(clips)
    report = FixReport(frames, people, 0, replaced, *spread.values(), len(clips), notes)
    return out, report
