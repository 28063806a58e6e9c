"""The models shipped in the package: listed, loaded by name, and fixing recordings of their own
skeleton and of another convention's."""

from __future__ import annotations

import numpy as np

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
    """SMPL names onto the Bandai-trained model: joints by body part (io/joint_names.py)."""
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
