"""core/resample.py: the one resampling in time, for the training data and for `fix`."""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial.transform import Rotation, Slerp

from mocapfix.core.clip import Clip
from mocapfix.core.kinematics import fk_axis_angle
from mocapfix.core.resample import (
    frames_within,
    hold_last_frame,
    model_frames,
    resample_clip,
    resample_frames,
    resample_motion,
)
from mocapfix.core.skeleton import preset


def _rotation_clip(T: int = 31, fps: float = 30.0) -> Clip:
    skeleton = preset("smpl22")
    J, rng = skeleton.num_joints, np.random.default_rng(0)
    # smooth random rotations, some joints turning far from frame to frame
    rotations = (np.cumsum(rng.normal(0, 0.15, (T, J, 3)), axis=0)).astype(np.float32)
    root = np.cumsum(rng.normal(0, 0.01, (T, 3)), axis=0).astype(np.float32)
    offsets = rng.normal(0, 0.1, (J, 3)).astype(np.float32)
    positions = fk_axis_angle(
        torch.from_numpy(rotations), torch.from_numpy(root), torch.from_numpy(offsets), skeleton.parents
    ).numpy()
    return Clip(positions, fps, skeleton, rotations=rotations, root_translation=root, offsets=offsets)


def test_the_training_data_and_fix_resample_the_same_way():
    """resample_clip (the data module's) is fix's resample_frames / resample_motion, bit for bit."""
    clip = _rotation_clip()
    n = frames_within(clip.num_frames, 30.0, 25.0)
    out = resample_clip(clip, 25.0)
    rot, root = resample_motion(clip.rotations, clip.root_translation, 30.0, 25.0, n)
    assert out.num_frames == n == 26
    assert np.array_equal(out.rotations, rot) and np.array_equal(out.root_translation, root)
    plain = Clip(clip.positions, 30.0, clip.skeleton)
    assert np.array_equal(resample_clip(plain, 25.0).positions, resample_frames(clip.positions, 30.0, 25.0, n))


def test_rotations_are_slerped_on_the_shortest_arc():
    clip = _rotation_clip()
    rot, _ = resample_motion(clip.rotations.astype(np.float64), clip.root_translation, 30.0, 70.0, 71)
    times = np.arange(71) * (30.0 / 70.0)  # source frames of the new ones
    for j in (0, 5, 17):
        slerp = Slerp(np.arange(clip.num_frames), Rotation.from_rotvec(clip.rotations[:, j].astype(np.float64)))
        angle = (slerp(times).inv() * Rotation.from_rotvec(rot[:, j])).magnitude()
        assert angle.max() < 1e-9
    # shared instants are the recording's own values, bit for bit
    assert np.array_equal(rot[::7].astype(np.float32), clip.rotations[::3])


def test_positions_keep_missing_neighbours_missing_and_end_where_the_take_ends():
    x = np.arange(10, dtype=np.float32)[:, None] * np.ones((1, 3), np.float32)  # (T, 3)
    x[4] = np.nan
    y = resample_frames(x, 30.0, 45.0, model_frames(10, 30.0, 45.0))  # 2/3-frame steps
    assert np.isnan(y[[5, 6, 7]]).all(-1).all() and np.isfinite(np.delete(y, [5, 6, 7, 14], 0)).all()
    assert y[3, 0] == 2.0 and abs(y[1, 0] - 2 / 3) < 1e-6  # a shared instant exactly, a between one linearly
    assert np.isnan(y[14]).all()  # past the last frame (t = 14 * 2/3 > 9)
    assert np.array_equal(hold_last_frame(y[8:])[-1], y[13])
