"""The models shipped in the package: listed, loaded by name, and fixing recordings of their own
skeleton and of another convention's."""

from __future__ import annotations

import shutil

import numpy as np
import torch

from mocapfix.apps.main import main
from mocapfix.core.skeleton import preset
from mocapfix.fix.fixers import load_fixer
from mocapfix.io import read_motion
from mocapfix.io.positions import write_positions
from mocapfix.io.synthetic import generate_clips
from mocapfix.pretrained import MODELS, pretrained_path


def test_models_lists_every_shipped_model_with_its_license(capsys):
    assert main(["models"]) == 0
    out = capsys.readouterr().out
    for name, m in MODELS.items():
        assert name in out and m.license in out
        fixer = load_fixer(pretrained_path(name))
        if fixer.kind == "xmae":
            assert fixer.policy is not None  # shipped with the fill policy of its val split


def test_fix_by_model_name_on_its_own_skeleton(tmp_path, bandai_files, capsys):
    clip = read_motion(bandai_files[0])[0]
    holes = clip.positions.copy()
    holes[30:45, clip.skeleton.index("Hand_L")] = np.nan  # 0.5 s of the left hand
    write_positions(tmp_path / "take.npz", holes, clip.fps, clip.skeleton)
    capsys.readouterr()
    assert main(["fix", str(tmp_path / "take.npz"), "--model", "xmae-cpu-bandai"]) == 0
    assert "filled by " in capsys.readouterr().out
    out = np.load(tmp_path / "take.fixed.npz")["positions"]
    observed = np.isfinite(holes)
    assert np.isfinite(out).all() and np.array_equal(out[observed], holes[observed])
    # the hand's hole is filled near the truth (the policy's limb fill or better: within a few cm)
    err = np.linalg.norm(
        out[30:45, clip.skeleton.index("Hand_L")] - clip.positions[30:45, clip.skeleton.index("Hand_L")], axis=-1
    )
    assert err.mean() < 0.1


def test_fix_by_model_name_on_an_smpl_recording(tmp_path, capsys):
    """SMPL names onto the Bandai-trained model: joints by body part (rig/mapping.py)."""
    motion = generate_clips(1, 4.0, fps=30, seed=5)[0].positions  # (120, 22, 3) smpl22
    holes = motion.copy()
    holes[50:65, 20] = np.nan  # left wrist, 0.5 s
    write_positions(tmp_path / "smpl.npz", holes, 30, preset("smpl22"))
    assert main(["fix", str(tmp_path / "smpl.npz"), "--model", "xmae-cpu-bandai"]) == 0
    out = np.load(tmp_path / "smpl.fixed.npz")["positions"]
    assert np.isfinite(out).all() and np.array_equal(out[np.isfinite(holes)], holes[np.isfinite(holes)])
    assert np.linalg.norm(out[50:65, 20] - motion[50:65, 20], axis=-1).mean() < 0.1
    capsys.readouterr()
    assert main(["fix", str(tmp_path / "smpl.npz"), "--model", "no-such-model", "--force"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no shipped model 'no-such-model' (shipped: xmae-cpu-bandai" in err[0]


def test_a_recording_without_some_of_the_models_joints(tmp_path, capsys):
    """SMPL without collars and toes (a Human3.6M-like body) onto the Bandai-trained model: the
    four joints it lacks are estimated from the rest and not written; the rest is fixed."""
    motion = generate_clips(1, 4.0, fps=30, seed=6)[0].positions
    keep = [j for j, n in enumerate(preset("smpl22").joint_names) if "collar" not in n and "foot" not in n]
    holes = motion[:, keep].copy()
    holes[40:55, keep.index(20)] = np.nan  # left wrist, 0.5 s
    write_positions(tmp_path / "body18.npz", holes, 30, preset("smpl22").subset(keep))
    capsys.readouterr()
    assert main(["fix", str(tmp_path / "body18.npz"), "--model", "xmae-cpu-bandai", "--mode", "both"]) == 0
    out = capsys.readouterr().out
    assert "model joints not in the recording: Shoulder_L, Shoulder_R, Toes_L, Toes_R" in out
    fixed = np.load(tmp_path / "body18.fixed.npz")["positions"]
    assert fixed.shape == holes.shape and np.isfinite(fixed).all()
    assert np.linalg.norm(fixed[40:55, keep.index(20)] - motion[40:55, 20], axis=-1).mean() < 0.1


def test_the_shipped_denoiser_takes_jitter_out_of_a_bvh(tmp_path, bandai_files, capsys):
    """motion-dvae-bandai on a Bandai take with Gaussian noise on its joint rotations (the test
    table's 0.15 rad): a BVH in the input's hierarchy comes back, nearer the clean take than the
    noisy one and far smoother."""
    from mocapfix.data.corruption import rotation_noise
    from mocapfix.io.bvh import read_bvh, write_bvh

    shutil.copy(bandai_files[9], tmp_path / "clean.bvh")
    [clip] = read_bvh(tmp_path / "clean.bvh")
    rot, pos = rotation_noise(
        torch.from_numpy(clip.rotations)[None],
        torch.from_numpy(clip.root_translation)[None],
        torch.from_numpy(clip.offsets)[None, None],
        clip.skeleton.parents,
        0.15,
        torch.Generator().manual_seed(0),
    )
    noisy = clip.replace(rotations=rot[0].numpy(), positions=pos[0].numpy())
    write_bvh(tmp_path / "noisy.bvh", noisy, template=tmp_path / "clean.bvh")
    assert main(["fix", str(tmp_path / "noisy.bvh"), "--model", "motion-dvae-bandai", "--mode", "denoise"]) == 0
    assert "noisy.fixed.bvh" in capsys.readouterr().out
    [given] = read_motion(tmp_path / "noisy.bvh")
    [out] = read_motion(tmp_path / "noisy.fixed.bvh")
    [truth] = read_motion(tmp_path / "clean.bvh")

    def err(a):
        return np.linalg.norm(a.positions - truth.positions, axis=-1).mean()

    def accel(a):
        return np.linalg.norm(np.diff(a.positions, 2, axis=0), axis=-1).mean()

    assert err(out) < 0.7 * err(given)
    assert accel(out) < 0.2 * accel(given)
