"""Human3.6M in the VideoPose3D layout (data_3d_h36m.npz).

The file holds one pickled dict under "positions_3d": {subject: {action: (T, 32, 3) float32}},
read without running the pickle (io/npz.py: npz_object builds containers and arrays only).
VideoPose3D's prepare_data_h36m.py divides the D3_Positions by 1000 and keeps the mocap world
frame, whose z axis is up: the positions are metres, z up already, at 50 Hz. We keep the 17
joints everyone evaluates on (skeleton preset h36m17).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.core.skeleton import PRESETS
from mocapfix.io.conventions import parse_unit
from mocapfix.io.npz import npz_object

H36M_FPS = 50.0
H36M_KEEP = [0, 1, 2, 3, 6, 7, 8, 12, 13, 14, 15, 17, 18, 19, 25, 26, 27]  # 32 -> 17 joints
H36M_SPLIT = {"train": ["S1", "S5", "S6", "S7", "S8"], "test": ["S9", "S11"]}  # by clip.meta["subject"]


def _natural(s: str):
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", s)]


def h36m_skeleton(path, groups=None):
    """Preset h36m17, its limb groups replaced by `groups` ({name: [joint names or indices]})."""
    skel = PRESETS["h36m17"]
    if groups:
        try:
            skel = skel.with_groups(groups)
        except (KeyError, ValueError) as e:
            raise MotionFileError(path, f"bad groups: {e}") from None
    return skel


def read_h36m(path, unit: str = "auto", groups=None) -> list[Clip]:
    """data_3d_h36m.npz -> one Clip per (subject, action), named "S1/Walking 1", 17 joints, 50 fps.

    unit: the file's unit ("auto": metres, as VideoPose3D writes it; "mm" for the raw dataset's).
    groups: {group name: [joint names or indices]} replacing the preset's limb groups."""
    path = Path(path)
    unit = parse_unit(unit, path) or parse_unit("m", path, "VideoPose3D's convention")
    # The dict is pickled: read by the restricted unpickler (io/npz.py), never by np.load's.
    obj = npz_object(path, "positions_3d")
    try:
        tree = obj.item()
    except ValueError:
        tree = None
    if not isinstance(tree, dict) or not all(isinstance(v, dict) for v in tree.values()):
        raise MotionFileError(path, "'positions_3d' must hold {subject: {action: (frames, 32, 3)}}")
    skel = h36m_skeleton(path, groups)
    clips = []
    for subject in sorted(tree, key=_natural):
        for action in sorted(tree[subject], key=_natural):
            pos = np.asarray(tree[subject][action])
            if (
                pos.dtype.kind not in "iuf"
                or pos.ndim != 3
                or pos.shape[1:] not in ((32, 3), (17, 3))
                or pos.shape[0] == 0
            ):
                raise MotionFileError(
                    path, f"{subject}/{action}: expected (frames, 32, 3) numbers, got {pos.dtype} {pos.shape}"
                )
            if pos.shape[1] == 32:
                pos = pos[:, H36M_KEEP]
            clips.append(
                Clip(
                    (pos * unit.metres).astype(np.float32),
                    H36M_FPS,
                    skel,
                    name=f"{subject}/{action}",
                    source=str(path),
                    meta={
                        "format": "h36m",
                        "subject": str(subject),
                        "action": str(action),
                        "split": next((k for k, v in H36M_SPLIT.items() if str(subject) in v), None),
                        "unit": unit.name,
                        "unit_source": unit.how,
                        "up_axis": "z",
                    },
                )
            )
    if not clips:
        raise MotionFileError(path, "'positions_3d' holds no sequences")
    return clips
