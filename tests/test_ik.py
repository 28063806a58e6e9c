"""A positions model's output back on the input BVH's own skeleton (core/ik.py, fix's BVH output):
the written file, read back and posed by an independent forward kinematics, matches what fix
computed, and the frames fix left alone come back as they were."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from mocapfix.apps.main import main
from mocapfix.core.ik import ik_error_mm, inverse_kinematics
from mocapfix.fix import fix_clips, load_fixer
from mocapfix.fix.hierarchy import onto_hierarchy
from mocapfix.fix.output import write_output
from mocapfix.io import read_motion
from mocapfix.pretrained import pretrained_path


def _scipy_fk(clip) -> np.ndarray:
    """FK written here from the clip's rotations (scipy, not core/kinematics.py) -> (T, J, 3)."""
    T, J = clip.rotations.shape[:2]
    local = Rotation.from_rotvec(clip.rotations.reshape(-1, 3).astype(np.float64)).as_matrix().reshape(T, J, 3, 3)
    glob, pos = np.zeros((T, J, 3, 3)), np.zeros((T, J, 3))
    for j, p in enumerate(clip.skeleton.parents):
        if p < 0:
            glob[:, j], pos[:, j] = local[:, j], clip.root_translation
        else:
            glob[:, j] = glob[:, p] @ local[:, j]
            pos[:, j] = pos[:, p] + glob[:, p] @ clip.offsets[j].astype(np.float64)
    return pos


def test_ik_of_a_recordings_own_positions_gives_them_back(bandai_files):
    c = read_motion(bandai_files[5])[0]
    P, R, t, o = (torch.from_numpy(a) for a in (c.positions, c.rotations, c.root_translation, c.offsets))
    for reference in (R, torch.zeros_like(R)):  # the input's twist, or the rest pose's
        rot, root = inverse_kinematics(P, c.skeleton.parents, o, reference, t)
        _, mean, worst = ik_error_mm(P, c.skeleton.parents, o, rot, root)
        assert worst < 0.01
    rot, _ = inverse_kinematics(P, c.skeleton.parents, o, R, t)
    assert (rot - R.double()).abs().max() < 1e-4  # with the input's twist: its own rotations


@pytest.fixture(scope="module")
def fixed_bvh(bandai_files, tmp_path_factory):
    """A Bandai clip with a 0.5 s hole in its left arm and one in both legs, fixed by the shipped
    model (infill), written as BVH into the input file's hierarchy."""
    d = tmp_path_factory.mktemp("ik")
    src = d / "take.bvh"
    shutil.copy(bandai_files[7], src)
    [clip] = read_motion(src)
    x = clip.positions.copy()
    arm = list(clip.skeleton.groups["left_arm"])
    legs = list(clip.skeleton.groups["left_leg"]) + list(clip.skeleton.groups["right_leg"])
    x[30:45, arm] = np.nan
    x[70:85, legs] = np.nan
    holed = clip.replace(positions=x)
    [fixed], _ = fix_clips([holed], load_fixer(pretrained_path("xmae-cpu-bandai")), "infill")
    posed, mean, worst = onto_hierarchy([fixed], [clip])
    write_output(d / "take.fixed.bvh", posed, [clip], src)
    return clip, x, fixed, read_motion(d / "take.fixed.bvh")[0], (mean, worst)


def test_fixed_bvh_matches_the_fixed_positions(fixed_bvh):
    clip, x, fixed, back, (mean, worst) = fixed_bvh
    assert back.skeleton.joint_names == clip.skeleton.joint_names and back.num_frames == clip.num_frames
    assert np.abs(_scipy_fk(back) - back.positions).max() < 1e-4  # what the reader says is what FK says
    err = np.linalg.norm(back.positions - fixed.positions, axis=-1) * 1000  # mm, every token
    assert err.mean() < 5.0, err.mean()
    assert mean < 5.0 and worst < 200.0  # the report's figures: bone lengths kept, nothing wild
    kept = np.isfinite(x).all(-1).all(-1)  # frames where fix changed nothing
    assert kept.sum() > 0.7 * len(kept)
    assert np.linalg.norm(back.positions[kept] - clip.positions[kept], axis=-1).max() * 1000 < 1.0


def test_fix_on_a_bvh_writes_a_bvh_by_default(bandai_files, tmp_path, capsys):
    shutil.copy(bandai_files[7], tmp_path / "walk.bvh")
    assert main(["fix", str(tmp_path / "walk.bvh"), "--model", "xmae-cpu-bandai", "--progress", "never"]) == 0
    out = capsys.readouterr().out
    assert "walk.fixed.bvh" in out and "inverse kinematics" in out
    [back] = read_motion(tmp_path / "walk.fixed.bvh")
    [orig] = read_motion(tmp_path / "walk.bvh")
    np.testing.assert_allclose(back.positions, orig.positions, atol=1e-3)  # a clean take: nothing to change
