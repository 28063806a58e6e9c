"""A recording's joints meet a model's: which joint of the clip plays each model joint (by name
or body part, rig/mapping.py), and each clip seen at the model's joints and frame rate."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.core.resample import model_frames, resample_frames
from mocapfix.core.skeleton import Skeleton
from mocapfix.fix.report import who
from mocapfix.rig.mapping import match_joints


def map_joints(
    skeleton: Skeleton,
    model: Skeleton,
    source="",
    joint_map: dict[str, str] | None = None,
    allow_missing: bool = False,
) -> np.ndarray:
    """(J_model,) index of each model joint in `skeleton`: by `joint_map` (input name -> model
    name), the same name (any case, namespace prefixes aside), else the same body part under
    another convention's name (rig/mapping.py: Mixamo, CMU, SMPL, Human3.6M, ...). A model
    joint the input lacks is an error naming them all, unless allow_missing: then its index is -1
    (a positions model estimates it like any missing token) as long as at least half of the
    model's joints are found. Input joints the model does not know are not in the map (the model
    never sees them; positions.fill_other_joints fills their holes)."""
    found = match_joints(skeleton, model, joint_map)
    missing = [n for n in model.joint_names if n not in found]
    if missing and allow_missing and 2 * len(found) >= model.num_joints:
        return np.array([found.get(n, -1) for n in model.joint_names], dtype=np.int64)
    if missing:
        raise MotionFileError(
            source,
            f"skeleton does not match the model's ({model.name}, {model.num_joints} "
            f"joints): missing {', '.join(missing)} (`mocapfix inspect FILE --ckpt CKPT` shows the "
            "mapping; --joint-map FILE names joints, one `input name: model name` per line)",
        )
    return np.array([found[n] for n in model.joint_names], dtype=np.int64)


class ModelView(NamedTuple):
    """A file's clips at a model's joints: per clip the index (Jm,) into the clip's joints (-1
    where it lacks one), the positions on the clip's frames x_in (T, Jm, 3) and at the model's
    fps x_m (K, Jm, 3); a model joint the recording lacks is missing in every frame, as are
    frames past the input's end."""

    index: list[np.ndarray]
    x_in: list[np.ndarray]
    x_m: list[np.ndarray]

    def has_holes(self) -> bool:
        """Whether a joint the recording has is missing somewhere: a model joint it lacks is
        estimated, never written, and no hole of the recording to fill."""
        return any(not np.isfinite(x[:, i >= 0]).all() for x, i in zip(self.x_in, self.index))


def model_view(clips: list[Clip], model: Skeleton, fps_m: float, joint_map: dict[str, str] | None) -> ModelView:
    source, name = clips[0].source or clips[0].name, who(clips)
    index, x_in, x_m = [], [], []
    for i, c in enumerate(clips):
        idx = map_joints(c.skeleton, model, source, joint_map, allow_missing=True)
        x = np.where((idx >= 0)[None, :, None], c.positions[:, np.maximum(idx, 0)], np.nan).astype(np.float32)
        if not np.isfinite(x).all(-1).any():
            raise MotionFileError(source, f"{name(i)}no data for any of the model's joints in any frame")
        index.append(idx)
        x_in.append(x)
        x_m.append(resample_frames(x, c.fps, fps_m, model_frames(c.num_frames, c.fps, fps_m)))
    return ModelView(index, x_in, x_m)
