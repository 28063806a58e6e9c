"""The Motion-DVAE prior through the product path: configs, KL annealing, TensorBoard, checkpoints,
resume, and the positions state on data without rotations."""

from __future__ import annotations

import json
import shutil
from types import SimpleNamespace

import pytest
import torch
from cli_utils import CONFIGS, QUIET, SMALL_DATA, run_cli

from mocapfix.core.skeleton import PRESETS
from mocapfix.training.dvae_module import MotionDVAEModule
from mocapfix.training.schedules import anneal_steps_of, kl_anneal_weight

# Tiny networks: these tests exercise the loop, not the model size.
TINY_DVAE = [
    "--model.init_args.lstm_hidden",
    "32",
    "--model.init_args.mlp_hidden",
    "32",
    "--model.init_args.latent_dim",
    "8",
]
CPU = ["--trainer.accelerator", "cpu", "--trainer.precision", "32-true"]


def bandai_subset(bandai_files, dest):
    """Three Bandai clips, one per split (the full set takes ~20 s to parse)."""
    dest.mkdir()
    names = ["dataset-1_walk_normal_002.bvh", "dataset-1_bow_active_001.bvh", "dataset-1_run_normal_001.bvh"]
    by_name = {f.name: f for f in bandai_files}
    for n in names:
        shutil.copy(by_name[n], dest / n)
    return [
        "--data.path",
        dest,
        "--data.cache_dir",
        "null",
        "--data.val_patterns",
        f"[{names[1]}]",
        "--data.test_patterns",
        f"[{names[2]}]",
        "--data.eval_batch_size",
        "8",
        "--data.batch_size",
        "4",
    ]


def test_fast_dev_run_motion_dvae_yaml(tmp_path):
    assert (
        run_cli(
            [
                "fit",
                "--config",
                CONFIGS / "motion_dvae.yaml",
                *TINY_DVAE,
                *SMALL_DATA,
                *QUIET,
                *CPU,
                "--trainer.fast_dev_run",
                "1",
            ],
            tmp_path,
        )
        == 0
    )


def test_fast_dev_run_motion_dvae_bvh_yaml(tmp_path, bandai_files):
    assert (
        run_cli(
            [
                "fit",
                "--config",
                CONFIGS / "motion_dvae_bvh.yaml",
                *TINY_DVAE,
                *QUIET,
                *CPU,
                *bandai_subset(bandai_files, tmp_path / "bvh"),
                "--trainer.fast_dev_run",
                "1",
            ],
            tmp_path,
        )
        == 0
    )


def test_kl_anneal_schedule():
    assert [kl_anneal_weight(s, 4) for s in (0, 1, 2, 4, 9)] == [0.0, 0.25, 0.5, 1.0, 1.0]
    assert kl_anneal_weight(0, 0) == 1.0
    trainer = SimpleNamespace(num_training_batches=10, accumulate_grad_batches=2)
    assert anneal_steps_of(trainer, None, 3.0) == 15 and anneal_steps_of(trainer, 7, 3.0) == 7


def _scalars(run_dir):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    ea = EventAccumulator(str(run_dir), size_guidance={"images": 0, "scalars": 0})
    ea.Reload()
    return ea


def test_kl_weight_follows_the_schedule_across_resume_and_tensorboard_has_every_term(tmp_path):
    common = [
        "fit",
        "--config",
        CONFIGS / "motion_dvae.yaml",
        *TINY_DVAE,
        *SMALL_DATA,
        *QUIET,
        *CPU,
        "--experiment",
        "kl",
        "--trainer.log_every_n_steps",
        "1",
        "--trainer.val_check_interval",
        "3",
        "--model.init_args.kl_anneal_steps",
        "4",
        "--model.init_args.kl_weight",
        "0.5",
        "--checkpoint_every_n_steps",
        "3",
    ]
    assert run_cli([*common, "--trainer.max_steps", "3"], tmp_path) == 0
    assert run_cli([*common, "--trainer.max_steps", "6", "--ckpt_path", "last"], tmp_path) == 0
    weights = {}
    for version in ("version_0", "version_1"):
        ea = _scalars(tmp_path / "logs" / "kl" / version)
        weights.update({e.step: e.value for e in ea.Scalars("train/kl_weight")})
    # logged at the step it was used: 0.5 * min(1, step / 4), continuing after the resume
    assert sorted(weights) == list(range(6))
    for step, w in weights.items():
        assert w == pytest.approx(0.5 * min(1.0, step / 4)), (step, w)
    ea = _scalars(tmp_path / "logs" / "kl" / "version_0")
    for tag in (
        "train/loss",
        "train/rec",
        "train/kl",
        "train/reg",
        "train/kl_weight",
        "val/loss",
        "val/mpjpe_mm",
        "val/rec",
        "val/kl",
        "val/reg",
        "lr-Adamax",
    ):
        assert tag in ea.Tags()["scalars"], tag
    assert "val/reconstruction_example" in ea.Tags()["images"]
    # the run's summary (training/tracking.py), no placeholder hp_metric; the best carried across the resume
    assert "hparams/best_val_mpjpe_mm" in ea.Tags()["scalars"] and "hp_metric" not in ea.Tags()["scalars"]
    runs = [_scalars(tmp_path / "logs" / "kl" / v) for v in ("version_0", "version_1")]
    val_loss = [e.value for run in runs for e in run.Scalars("val/loss")]
    assert runs[1].Scalars("hparams/best_val_loss")[-1].value == pytest.approx(min(val_loss))

    ckpt = torch.load(tmp_path / "checkpoints" / "kl" / "last.ckpt", map_location="cpu", weights_only=True)
    assert ckpt["global_step"] == 6
    assert {float(s["step"]) for s in ckpt["optimizer_states"][0]["state"].values()} == {6.0}
    hp = ckpt["hyper_parameters"]
    assert hp["window_frames"] == 30 and hp["skeleton"]["name"] == "smpl22" and hp["state"] == "rotations"
    # the state statistics travel with the weights
    std = ckpt["state_dict"]["net.x_std"]
    assert std.shape == (138,) and not torch.allclose(std, torch.ones_like(std))
    model = MotionDVAEModule.load_from_checkpoint(tmp_path / "checkpoints" / "kl" / "last.ckpt", map_location="cpu")
    torch.testing.assert_close(model.net.x_std, std)
    # so does the mean pose the joint rotations are measured from
    ref = ckpt["state_dict"]["codec.joint_reference"]
    assert ref.shape == (21, 3, 3) and not torch.allclose(ref, torch.eye(3).expand(21, 3, 3), atol=1e-3)
    torch.testing.assert_close(model.codec.joint_reference, ref)


def test_positions_state_trains_on_data_without_rotations(tmp_path):
    assert (
        run_cli(
            [
                "fit",
                "--config",
                CONFIGS / "motion_dvae.yaml",
                *TINY_DVAE,
                *SMALL_DATA,
                *QUIET,
                *CPU,
                "--model.init_args.state",
                "positions",
                "--data.with_rotations",
                "false",
                "--trainer.fast_dev_run",
                "1",
            ],
            tmp_path,
        )
        == 0
    )


def test_rotation_state_without_rotations_says_what_to_set(tmp_path, capsys):
    rc = run_cli(
        [
            "fit",
            "--config",
            CONFIGS / "motion_dvae.yaml",
            *TINY_DVAE,
            *SMALL_DATA,
            *QUIET,
            *CPU,
            "--data.with_rotations",
            "false",
            "--trainer.fast_dev_run",
            "1",
        ],
        tmp_path,
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and "with_rotations" in err[-1] and "Traceback" not in "".join(err)


def test_a_bvh_without_rotations_among_others_is_named(tmp_path, bandai_files, capsys):
    """One clip with a non-finite channel has no rotations: the windows would lose every clip's
    rotations (the rotation state then failed with KeyError 'rotations'); the file is named."""
    args = bandai_subset(bandai_files, tmp_path / "bvh")
    bad = tmp_path / "bvh" / "dataset-1_bow_active_001.bvh"
    lines = bad.read_text().splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith("Frame Time")) + 5
    lines[i] = " ".join(["inf"] + lines[i].split()[1:])
    bad.write_text("\n".join(lines) + "\n")
    rc = run_cli(
        [
            "fit",
            "--config",
            CONFIGS / "motion_dvae_bvh.yaml",
            *TINY_DVAE,
            *QUIET,
            *CPU,
            *args,
            "--trainer.fast_dev_run",
            "1",
        ],
        tmp_path,
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and f"{bad}: no joint rotations (non-finite channel values)" in err[-1]


def test_a_split_without_complete_windows_is_one_line(tmp_path, capsys):
    """Motion-DVAE learns from and scores complete windows only: data where a joint is always
    missing gave no val/loss (a Lightning traceback about the monitored key) and NaN tables."""
    from mocapfix.io.positions import write_positions
    from mocapfix.io.synthetic import generate_clips

    (tmp_path / "pos").mkdir()
    for i, c in enumerate(generate_clips(4, 3.0, fps=30, seed=0)):
        positions = c.positions.copy()
        positions[:, 5] = float("nan")  # one joint never seen
        write_positions(tmp_path / "pos" / f"take{i}.npz", positions, c.fps, c.skeleton)
    rc = run_cli(
        [
            "fit",
            "--config",
            CONFIGS / "motion_dvae.yaml",
            *TINY_DVAE,
            *SMALL_DATA,
            *QUIET,
            *CPU,
            "--model.init_args.state",
            "positions",
            "--data.with_rotations",
            "false",
            "--data.source",
            "positions",
            "--data.path",
            tmp_path / "pos",
            "--data.max_missing_fraction",
            "0.5",
            "--trainer.fast_dev_run",
            "1",
        ],
        tmp_path,
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and "windows is complete" in err[-1] and "Traceback" not in "".join(err)


def test_predict_with_a_prior_says_to_use_the_denoising_stage(tmp_path, capsys):
    common = ["--config", CONFIGS / "motion_dvae.yaml", *TINY_DVAE, *SMALL_DATA, *QUIET, *CPU, "--experiment", "p"]
    assert run_cli(["fit", *common, "--trainer.max_steps", "1", "--trainer.val_check_interval", "1"], tmp_path) == 0
    capsys.readouterr()
    rc = run_cli(["predict", *common, "--ckpt_path", tmp_path / "checkpoints" / "p" / "last.ckpt"], tmp_path)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and "denoising stage's checkpoint" in err[-1] and "Traceback" not in "".join(err)


def test_optimizer_is_adamax_or_adam():
    sizes = dict(
        latent_dim=4,
        lstm_hidden=16,
        mlp_hidden=16,
        norm_groups=4,
        skeleton=PRESETS["smpl22"].to_dict(),
        window_fps=30.0,
        window_frames=30,
    )
    for name, cls in (("adamax", torch.optim.Adamax), ("adam", torch.optim.Adam)):
        opt = MotionDVAEModule(optimizer=name, lr=3e-4, **sizes).configure_optimizers()["optimizer"]
        assert type(opt) is cls and opt.param_groups[0]["lr"] == 3e-4
    with pytest.raises(ValueError, match="optimizer"):
        MotionDVAEModule(optimizer="sgd", **sizes)


def test_group_norm_setting_names_its_options():
    with pytest.raises(ValueError, match=r"mlp_hidden \(20\) must be a multiple of norm_groups \(16\)"):
        MotionDVAEModule(mlp_hidden=20)


def test_prior_test_writes_eval_json(tmp_path, capsys):
    common = ["--config", CONFIGS / "motion_dvae.yaml", *TINY_DVAE, *SMALL_DATA, *QUIET, *CPU, "--experiment", "t"]
    assert run_cli(["fit", *common, "--trainer.max_steps", "1", "--trainer.val_check_interval", "1"], tmp_path) == 0
    capsys.readouterr()
    assert run_cli(["test", *common, "--ckpt_path", tmp_path / "checkpoints" / "t" / "last.ckpt"], tmp_path) == 0
    path = capsys.readouterr().out.strip().splitlines()[-1].removeprefix("eval.json: ")
    [row] = json.loads((tmp_path / path).read_text())
    assert row["method"] == "dvae_prior" and row["mpjpe_mm"] > 0
