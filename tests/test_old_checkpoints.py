"""Checkpoints written by earlier code still load for test, fix and resume.

tests/data/old_checkpoints/*-4ceef7a.ckpt were written by commit 4ceef7a, before checkpoints held
their model's kind and config (models/build.py): tiny models, 4 steps on the synthetic data of
cli_utils.SMALL_DATA (XMAE: cli_utils.TINY sizes; Motion-DVAE: positions state, width 16, and its
denoising stage). Their hyperparameters name the sizes, and fix tells the model by its weights."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from cli_utils import CONFIGS, QUIET, SMALL_DATA, run_cli

from mocapfix.apps.main import main
from mocapfix.core.skeleton import preset
from mocapfix.fix.fixers import DVAEFixer, XMAEFixer, load_fixer
from mocapfix.io import read_motion
from mocapfix.io.bvh import write_bvh
from mocapfix.io.positions import write_positions
from mocapfix.io.synthetic import generate_clips
from mocapfix.models.checkpoint import model_kind, read_checkpoint

OLD = Path(__file__).parent / "data" / "old_checkpoints"
XMAE_OLD = OLD / "xmae-4ceef7a.ckpt"
DENOISE_OLD = OLD / "motion_dvae_denoise-4ceef7a.ckpt"
CPU = ["--trainer.accelerator", "cpu"]


def test_old_checkpoints_have_no_model_entry_and_are_told_by_their_weights():
    for path, kind in ((XMAE_OLD, "xmae"), (DENOISE_OLD, "motion-dvae")):
        ckpt = read_checkpoint(path)
        assert "model" not in ckpt and model_kind(ckpt) == kind


def test_old_checkpoints_fix_a_recording(tmp_path, capsys):
    clip = generate_clips(1, 3.0, fps=30, seed=3)[0]  # 90 frames, smpl22, rotations
    holes = clip.positions.copy()
    holes[30:45, 20] = np.nan  # left wrist, 0.5 s
    write_positions(tmp_path / "a.npz", holes, 30, preset("smpl22"))
    write_bvh(tmp_path / "a.bvh", clip)  # the denoiser's state is rotations
    for path, cls, given in ((XMAE_OLD, XMAEFixer, "a.npz"), (DENOISE_OLD, DVAEFixer, "a.bvh")):
        fixer = load_fixer(path)
        assert isinstance(fixer, cls) and fixer.skeleton.num_joints == 22
        out = tmp_path / f"{path.stem}{Path(given).suffix}"
        assert main(["fix", str(tmp_path / given), "--ckpt", str(path), "-o", str(out)]) == 0
        fixed = read_motion(out)[0].positions
        assert fixed.shape == holes.shape and np.isfinite(fixed).all()
    capsys.readouterr()


def test_old_xmae_checkpoint_tests_and_resumes(tmp_path, capsys):
    assert (
        run_cli(
            [
                "test",
                "--config",
                CONFIGS / "xmae.yaml",
                *SMALL_DATA,
                *QUIET,
                *CPU,
                "--experiment",
                "old",
                "--ckpt_path",
                XMAE_OLD,
            ],
            tmp_path,
        )
        == 0
    )
    rows = json.loads(next(tmp_path.glob("logs/old/version_*/eval.json")).read_text())
    assert any(r["method"] == "xmae" for r in rows) and any(r["method"] == "policy" for r in rows)
    # resume: the sizes come from the old hyperparameters, training goes on from step 4
    assert (
        run_cli(
            [
                "fit",
                "--config",
                CONFIGS / "xmae.yaml",
                *SMALL_DATA,
                *QUIET,
                *CPU,
                "--experiment",
                "old",
                "--trainer.max_steps",
                "6",
                "--trainer.val_check_interval",
                "2",
                "--model.init_args.calibration_windows",
                "8",
                "--ckpt_path",
                XMAE_OLD,
            ],
            tmp_path,
        )
        == 0
    )
    new = torch.load(tmp_path / "checkpoints" / "old" / "last.ckpt", map_location="cpu", weights_only=True)
    assert new["global_step"] == 6 and new["model"]["kind"] == "xmae"
    assert new["model"]["config"]["enc_dim"] == 32 and new["model"]["config"]["num_joints"] == 22
    capsys.readouterr()
