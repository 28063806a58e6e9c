"""A positions model's fix put back on the input BVH's own skeleton: inverse kinematics from the
input's pose (or, for a BVH whose rotations were set aside, from the file read again with its
missing channels interpolated), pulled by the tokens fix kept as recorded."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.core.ik import ik_error_mm, inverse_kinematics
from mocapfix.fix.output import about_origin
from mocapfix.io.bvh import read_bvh


def bvh_reference(path: Path, clips: list[Clip]) -> list[Clip] | None:
    """For a BVH read without usable rotations (missing channels, or a jump that made positions
    missing): the file again, its missing channel values interpolated per channel (Euler angles:
    a pose to start from, not data), with the unit and axes it was read with; None where that
    does not give the same joints with rotations."""
    c = clips[0]
    if c.meta.get("format") != "bvh" or len(clips) != 1:
        return None
    try:
        [ref] = read_bvh(path, unit=c.meta["unit"], up_axis=c.meta["up_axis"], fill_missing_channels=True)
    except (MotionFileError, KeyError):
        return None
    return [ref] if ref.has_rotations and ref.skeleton.joint_names == c.skeleton.joint_names else None


FILLED_WEIGHT = 1e-3  # a filled joint's pull in the IK against an observed one's (core/ik.py)


def onto_hierarchy(
    fixed: list[Clip], inputs: list[Clip], observed: list[np.ndarray] | None = None
) -> tuple[list[Clip], float, float]:
    """A positions model's fixed clips back on the input BVH's own skeleton (core/ik.py): each
    clip gets rotations and root translation, and the positions their FK gives. inputs: the
    input's clips with rotations (the pose IK starts from); observed: (T, J) per clip, the
    tokens kept as recorded, which filled or replaced ones never pull. -> the clips and the mean and max
    distance (mm) the IK left between those positions and the model's."""
    out, means, worst = [], [], 0.0
    for k, (f, c) in enumerate(zip(fixed, inputs)):
        offsets, parents = torch.from_numpy(c.offsets), c.skeleton.parents
        # the reference may be a second read of the file (bvh_reference) about another origin
        target = torch.from_numpy(about_origin(f, c.origin))
        weights = None if observed is None else torch.from_numpy(np.where(observed[k], 1.0, FILLED_WEIGHT))
        rot, root = inverse_kinematics(
            target, parents, offsets, torch.from_numpy(c.rotations), torch.from_numpy(c.root_translation), weights
        )
        posed, mean, top = ik_error_mm(target, parents, offsets, rot, root)
        means.append(mean)
        worst = max(worst, top)
        out.append(
            c.replace(
                positions=posed.float().numpy(), rotations=rot.float().numpy(), root_translation=root.float().numpy()
            )
        )
    return out, float(np.mean(means)), worst
