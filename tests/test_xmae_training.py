"""XMAE through the product path: configs, fit/validate/test/predict, checkpoints, resume, TensorBoard."""

from __future__ import annotations

import json
import os
import pickle
import signal

import lightning as L
import numpy as np
import pytest
import torch
from cli_utils import CONFIGS, QUIET, SMALL_DATA, TINY, run_cli

from mocapfix.core.skeleton import Skeleton
from mocapfix.fills.classical import hermite_infill
from mocapfix.io.synthetic import generate_clips
from mocapfix.training.xmae_module import XMAEModule

FAST = [
    "--trainer.fast_dev_run",
    "1",
    "--data.batch_size",
    "4",
    "--data.eval_batch_size",
    "4",
    "--trainer.precision",
    "32-true",
    "--trainer.accelerator",
    "cpu",
    *QUIET,
]


def test_fast_dev_run_xmae_yaml(tmp_path):
    assert (
        run_cli(
            [
                "fit",
                "--config",
                CONFIGS / "xmae.yaml",
                *FAST,
                "--data.synthetic_clips",
                "8",
                "--data.synthetic_seconds",
                "3",
                "--data.cache_dir",
                "null",
                "--data.val_fraction",
                "0.25",
                "--data.test_fraction",
                "0.25",
            ],
            tmp_path,
        )
        == 0
    )


@pytest.mark.slow  # minutes of CPU; `make test-all` runs it
def test_fast_dev_run_xmae_bvh_yaml(tmp_path, bandai_dir):
    assert (
        run_cli(
            [
                "fit",
                "--config",
                CONFIGS / "xmae_bvh.yaml",
                *FAST,
                "--data.path",
                bandai_dir,
                "--data.cache_dir",
                tmp_path / "cache",
            ],
            tmp_path,
        )
        == 0
    )


@pytest.mark.slow  # a minute of CPU; `make test-all` runs it
def test_fast_dev_run_xmae_h36m_yaml(tmp_path):
    rng = np.random.default_rng(0)
    tree = {
        s: {a: (np.cumsum(rng.normal(0, 0.005, (120, 32, 3)), 0) + 1).astype(np.float32) for a in ("Walking", "Eating")}
        for s in ("S1", "S5", "S9", "S11")
    }
    np.savez(tmp_path / "data_3d_h36m.npz", positions_3d=np.array(tree, dtype=object))
    assert (
        run_cli(
            [
                "fit",
                "--config",
                CONFIGS / "xmae_h36m.yaml",
                *FAST,
                "--data.path",
                tmp_path / "data_3d_h36m.npz",
                "--data.cache_dir",
                "null",
            ],
            tmp_path,
        )
        == 0
    )


def test_fast_dev_run_xmae_amass_yaml(tmp_path):
    pytest.importorskip("smplx", reason="AMASS needs the optional smplx extra (pip install mocapfix[smpl])")
    from test_amass import _amass, _model

    models = tmp_path / "models" / "smplh"
    models.mkdir(parents=True)
    with open(models / "SMPLH_MALE.pkl", "wb") as f:
        pickle.dump(_model(52, 10, hands=True), f)
    for split_dir in ("CMU", "HumanEva", "SFU"):
        (tmp_path / "amass" / split_dir / "s1").mkdir(parents=True)
        _amass(tmp_path / "amass" / split_dir / "s1" / "take_poses.npz", 180, 156, 10)
    assert (
        run_cli(
            [
                "fit",
                "--config",
                CONFIGS / "xmae_amass.yaml",
                *FAST,
                "--data.path",
                tmp_path / "amass",
                "--data.body_model_path",
                tmp_path / "models",
                "--data.cache_dir",
                "null",
            ],
            tmp_path,
        )
        == 0
    )


def test_fit_writes_tensorboard_scalars_hparams_and_figures(tmp_path):
    assert (
        run_cli(
            [
                "fit",
                "--config",
                CONFIGS / "xmae.yaml",
                *TINY,
                *SMALL_DATA,
                *QUIET,
                "--experiment",
                "tb",
                "--trainer.max_steps",
                "6",
                "--trainer.val_check_interval",
                "3",
                "--trainer.log_every_n_steps",
                "1",
                "--model.init_args.warmup_steps",
                "2",
            ],
            tmp_path,
        )
        == 0
    )
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    run_dir = tmp_path / "logs" / "tb" / "version_0"
    ea = EventAccumulator(str(run_dir), size_guidance={"images": 0, "scalars": 0})
    ea.Reload()
    scalars = set(ea.Tags()["scalars"])
    for tag in (
        "train/loss",
        "val/loss",
        "val/mpjpe_mm",
        "val/gap0.5s_mpjpe_mm/xmae",
        "val/gap0.5s_mpjpe_mm/lerp",
        "val/gap0.5s_mpjpe_mm/spline",
        "val/gap_vs_spline",
        "hparams/best_val_mpjpe_mm",
        "hparams/val_vs_spline",
        "lr-Adam",
    ):
        assert tag in scalars, f"{tag} missing from {sorted(scalars)}"
    assert "val/infill_example" in ea.Tags()["images"]
    figures = ea.Images("val/infill_example")
    assert len(figures) == 2  # one figure per validation
    # three windows side by side, each from the front and the side: twice as wide as tall
    assert figures[0].width >= 1.9 * figures[0].height
    # the hparams plugin entry TensorBoard's HPARAMS tab reads, and no placeholder hp_metric card
    assert any(t.startswith("_hparams_") for t in ea.summary_metadata), "no hparams summary"
    assert "hp_metric" not in scalars
    lr = [e.value for e in ea.Scalars("lr-Adam")]
    assert lr[0] < lr[1] and lr[-1] < max(lr), "warm-up then decay"
    assert (tmp_path / "checkpoints" / "tb" / "last.ckpt").exists()
    assert list((tmp_path / "checkpoints" / "tb" / "version_0").glob("best-*.ckpt"))  # the run's own folder

    # test: the table as text and MPJPE by gap length as a figure, beside the scalars
    ckpt = tmp_path / "checkpoints" / "tb" / "last.ckpt"
    args = ["test", "--config", CONFIGS / "xmae.yaml", *TINY, *SMALL_DATA, *QUIET, "--experiment", "tb"]
    assert run_cli([*args, "--ckpt_path", ckpt], tmp_path) == 0
    test_dir = max((tmp_path / "logs" / "tb").glob("version_*"), key=lambda p: int(p.name.split("_")[1]))
    ea = EventAccumulator(str(test_dir), size_guidance={"images": 0, "tensors": 0})
    ea.Reload()
    assert "test/mpjpe_by_gap" in ea.Tags()["images"]
    assert "test/table/text_summary" in ea.Tags()["tensors"]
    text = ea.Tensors("test/table/text_summary")[0].tensor_proto.string_val[0].decode()
    assert "xmae" in text and "lerp" in text


def test_resume_continues_step_and_optimiser(tmp_path):
    common = [
        "fit",
        "--config",
        CONFIGS / "xmae.yaml",
        *TINY,
        *SMALL_DATA,
        *QUIET,
        "--experiment",
        "resume",
        "--trainer.val_check_interval",
        "4",
        "--checkpoint_every_n_steps",
        "2",
        "--model.init_args.total_steps",
        "8",
        "--model.init_args.warmup_steps",
        "2",
    ]
    assert run_cli([*common, "--trainer.max_steps", "4"], tmp_path) == 0
    last = tmp_path / "checkpoints" / "resume" / "last.ckpt"
    first = torch.load(last, map_location="cpu", weights_only=True)
    assert first["global_step"] == 4
    assert run_cli([*common, "--trainer.max_steps", "8", "--ckpt_path", "last"], tmp_path) == 0
    second = torch.load(last, map_location="cpu", weights_only=True)
    assert second["global_step"] == 8
    # one last.ckpt, written by both checkpoint callbacks (no last-v1.ckpt beside it)
    assert [p.name for p in last.parent.glob("last*.ckpt")] == ["last.ckpt"]
    adam_steps = {float(s["step"]) for s in second["optimizer_states"][0]["state"].values()}
    assert adam_steps == {8.0}, "Adam's step count must continue from the checkpoint, not restart"
    assert second["lr_schedulers"][0]["last_epoch"] == 8
    # it really resumed: the weights moved on from the first checkpoint
    k = "net.head.weight"
    assert not torch.equal(first["state_dict"][k], second["state_dict"][k])


def test_a_new_fit_of_the_same_experiment_writes_last_ckpt(tmp_path):
    """last.ckpt is the file configs and docs name (e.g. a denoising stage's prior_ckpt): a second
    fit of the same experiment must not leave it stale beside a last-v1.ckpt."""
    common = [
        "fit",
        "--config",
        CONFIGS / "xmae.yaml",
        *TINY,
        *SMALL_DATA,
        *QUIET,
        "--experiment",
        "again",
        "--trainer.val_check_interval",
        "2",
    ]
    assert run_cli([*common, "--trainer.max_steps", "2"], tmp_path) == 0
    assert run_cli([*common, "--trainer.max_steps", "4"], tmp_path) == 0
    folder = tmp_path / "checkpoints" / "again"
    assert [p.name for p in folder.glob("last*.ckpt")] == ["last.ckpt"]
    assert torch.load(folder / "last.ckpt", map_location="cpu", weights_only=True)["global_step"] == 4


def test_resume_draws_new_masks_not_the_first_steps_again(tmp_path):
    """The training corruption and shuffling draw from torch's generator, which seed_everything
    resets at every start: a resumed run goes on from the checkpoint's generator state instead of
    replaying the masks and batches of steps 0, 1, ... (lr 0: a loss depends on its batch and
    masks only)."""
    common = [
        "fit",
        "--config",
        CONFIGS / "xmae.yaml",
        *TINY,
        *SMALL_DATA,
        *QUIET,
        "--experiment",
        "rng",
        "--trainer.val_check_interval",
        "2",
        "--trainer.log_every_n_steps",
        "1",
        "--model.init_args.lr",
        "0",
    ]
    assert run_cli([*common, "--trainer.max_steps", "2"], tmp_path) == 0
    assert run_cli([*common, "--trainer.max_steps", "4", "--ckpt_path", "last"], tmp_path) == 0
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    losses = {}
    for version in ("version_0", "version_1"):
        ea = EventAccumulator(str(tmp_path / "logs" / "rng" / version), size_guidance={"scalars": 0})
        ea.Reload()
        losses.update({e.step: e.value for e in ea.Scalars("train/loss")})
    assert sorted(losses) == [0, 1, 2, 3]
    assert losses[2] != losses[0] and losses[3] != losses[1]
    ckpt = torch.load(tmp_path / "checkpoints" / "rng" / "last.ckpt", map_location="cpu", weights_only=True)
    assert any("RNGStateInCheckpoint" in k for k in ckpt["callbacks"])


def test_resume_from_last_takes_the_checkpoints_model_settings(tmp_path):
    """`--ckpt_path last` builds the model from the checkpoint, as a path does: a run trained with
    other sizes than the config's resumes without repeating them."""
    common = [
        "fit",
        "--config",
        CONFIGS / "xmae.yaml",
        *SMALL_DATA,
        *QUIET,
        "--experiment",
        "sizes",
        "--trainer.val_check_interval",
        "2",
    ]
    assert run_cli([*common, *TINY, "--trainer.max_steps", "2"], tmp_path) == 0
    assert run_cli([*common, "--trainer.max_steps", "4", "--ckpt_path", "last"], tmp_path) == 0
    ckpt = torch.load(tmp_path / "checkpoints" / "sizes" / "last.ckpt", map_location="cpu", weights_only=True)
    assert ckpt["global_step"] == 4 and ckpt["hyper_parameters"]["enc_dim"] == 32


def test_bad_checkpoint_path_is_one_line(tmp_path, capsys):
    (tmp_path / "text.ckpt").write_text("not a checkpoint")
    for path, problem in (
        (tmp_path / "missing.ckpt", "no such checkpoint file"),
        (tmp_path / "text.ckpt", "not a mocapfix checkpoint"),
    ):
        rc = run_cli(["test", "--config", CONFIGS / "xmae.yaml", *QUIET, "--ckpt_path", path], tmp_path)
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and f"{path}: {problem}" in err[-1] and "Traceback" not in "".join(err)


def test_checkpoint_is_self_contained_and_loads_safely(tmp_path):
    assert (
        run_cli(
            [
                "fit",
                "--config",
                CONFIGS / "xmae.yaml",
                *TINY,
                *SMALL_DATA,
                *QUIET,
                "--experiment",
                "ck",
                "--trainer.max_steps",
                "2",
                "--trainer.val_check_interval",
                "2",
            ],
            tmp_path,
        )
        == 0
    )
    path = tmp_path / "checkpoints" / "ck" / "last.ckpt"
    ckpt = torch.load(path, map_location="cpu", weights_only=True)  # plain hyperparameters only
    hp = ckpt["hyper_parameters"]
    assert hp["skeleton"]["name"] == "smpl22" and hp["window_frames"] == 30 and hp["window_fps"] == 30.0
    model = XMAEModule.load_from_checkpoint(path, map_location="cpu")  # no data module needed
    assert model.net is not None and model.net.num_joints == 22
    # a checkpoint moved to another device map (here: "meta" tensors are not allowed, cpu is) loads
    model2 = XMAEModule.load_from_checkpoint(path, map_location={"cuda:0": "cpu"})
    torch.testing.assert_close(model2.net.head.weight, model.net.head.weight)


def test_test_writes_eval_json_in_paper_layout(tmp_path, capsys):
    assert (
        run_cli(
            [
                "fit",
                "--config",
                CONFIGS / "xmae.yaml",
                *TINY,
                *SMALL_DATA,
                *QUIET,
                "--experiment",
                "ev",
                "--trainer.max_steps",
                "2",
                "--trainer.val_check_interval",
                "2",
            ],
            tmp_path,
        )
        == 0
    )
    capsys.readouterr()
    assert (
        run_cli(
            [
                "test",
                "--config",
                CONFIGS / "xmae.yaml",
                *TINY,
                *SMALL_DATA,
                *QUIET,
                "--experiment",
                "ev",
                "--ckpt_path",
                tmp_path / "checkpoints" / "ev" / "last.ckpt",
                "--trainer.limit_test_batches",
                "1",
            ],
            tmp_path,
        )
        == 0
    )
    out = capsys.readouterr().out.strip().splitlines()
    assert out[-1].startswith("eval.json: ")
    path = tmp_path / out[-1].split(": ", 1)[1]
    rows = json.loads(path.read_text())
    keys = {(r["task"], r["part"], r.get("gap_s", r.get("sigma_m")), r["method"]) for r in rows}
    for gap in (0.1, 0.3, 0.5, 0.7, 0.9):
        for part in ("full", "arm", "leg"):
            assert ("infill", part, gap, "xmae") in keys and ("infill", part, gap, "lerp") in keys
        assert ("displacement", "arm", gap, "xmae") in keys
    assert ("noise", "full", 0.02, "xmae") in keys
    assert all(np.isfinite(r["mpjpe_mm"]) and np.isfinite(r["mpjpe_rel_mm"]) for r in rows)
    # Lerp is exact where nothing is missing: on displacement it returns the displaced input,
    # whose error is the displacement itself (0.5-1 m)
    disp = [r for r in rows if r["task"] == "displacement" and r["method"] == "lerp"]
    assert all(500 <= r["mpjpe_mm"] <= 1000 for r in disp)


def test_predict_command_writes_the_windows(tmp_path, capsys):
    common = ["--config", CONFIGS / "xmae.yaml", *TINY, *SMALL_DATA, *QUIET, "--experiment", "pred"]
    assert run_cli(["fit", *common, "--trainer.max_steps", "2", "--trainer.val_check_interval", "2"], tmp_path) == 0
    capsys.readouterr()
    assert run_cli(["predict", *common, "--ckpt_path", tmp_path / "checkpoints" / "pred" / "last.ckpt"], tmp_path) == 0
    path = capsys.readouterr().out.strip().splitlines()[-1].removeprefix("predictions: ")
    with np.load(tmp_path / path) as z:
        assert z["positions"].ndim == 4 and z["positions"].shape[1:] == (30, 22, 3)
        assert np.isfinite(z["positions"]).all() and float(z["fps"]) == 30.0 and len(z["joint_names"]) == 22


def test_predict_fills_only_missing(tmp_path):
    from mocapfix.data.datamodule import MotionDataModule

    assert (
        run_cli(
            [
                "fit",
                "--config",
                CONFIGS / "xmae.yaml",
                *TINY,
                *SMALL_DATA,
                *QUIET,
                "--experiment",
                "pr",
                "--trainer.max_steps",
                "1",
                "--trainer.val_check_interval",
                "1",
            ],
            tmp_path,
        )
        == 0
    )
    model = XMAEModule.load_from_checkpoint(tmp_path / "checkpoints" / "pr" / "last.ckpt", map_location="cpu")
    dm = MotionDataModule(synthetic_clips=4, synthetic_seconds=2.0, cache_dir=None, val_fraction=0, test_fraction=1.0)
    dm.setup("predict")
    batch = dm.datasets["test"].__getitems__([0, 1])
    pos = batch["positions"].clone()
    pos[:, 10:15, 3] = float("nan")
    out = model.predict_step({"positions": pos}, 0)
    assert torch.isfinite(out).all()
    seen = ~torch.isnan(pos)
    assert torch.equal(out[seen], pos[seen])


def test_missing_data_is_one_line_naming_the_path(tmp_path, capsys):
    missing = tmp_path / "no_such_folder"
    rc = run_cli(["fit", "--config", CONFIGS / "xmae_bvh.yaml", "--data.path", missing, *QUIET], tmp_path)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert f"{missing}: no such file or folder" in err[-1] and "Traceback" not in "".join(err)


def test_a_model_setting_error_is_its_own_line(tmp_path, capsys):
    """A setting the module's constructor refuses: its message alone, not jsonargparse's union
    error with every setting of the model dumped after it."""
    rc = run_cli(
        ["fit", "--config", CONFIGS / "xmae.yaml", *TINY, *QUIET, "--model.init_args.mask_ratio", "1.5"], tmp_path
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith("mocapfix fit: mask_ratio must be in [0, 1]")


def test_version(capsys):
    from mocapfix import __version__
    from mocapfix.apps.main import main

    assert main(["--version"]) == 0 and capsys.readouterr().out.strip() == f"mocapfix {__version__}"


def test_wrong_key_is_a_short_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        run_cli(["fit", "--config", CONFIGS / "xmae.yaml", "--model.init_args.mask_ratoi", "0.5"], tmp_path)
    assert e.value.code != 0
    err = capsys.readouterr().err
    assert "mask_ratoi" in err and "Traceback" not in err


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_gpu_checkpoint_resumes_on_cpu_and_back(tmp_path):
    common = [
        "fit",
        "--config",
        CONFIGS / "xmae.yaml",
        *TINY,
        *SMALL_DATA,
        *QUIET,
        "--experiment",
        "dev",
        "--trainer.val_check_interval",
        "2",
        "--checkpoint_every_n_steps",
        "2",
    ]
    assert (
        run_cli(
            [*common, "--trainer.max_steps", "2", "--trainer.accelerator", "gpu", "--trainer.precision", "bf16-mixed"],
            tmp_path,
        )
        == 0
    )
    assert (
        run_cli([*common, "--trainer.max_steps", "4", "--trainer.accelerator", "cpu", "--ckpt_path", "last"], tmp_path)
        == 0
    )
    assert (
        run_cli([*common, "--trainer.max_steps", "6", "--trainer.accelerator", "gpu", "--ckpt_path", "last"], tmp_path)
        == 0
    )
    ckpt = torch.load(tmp_path / "checkpoints" / "dev" / "last.ckpt", map_location="cpu", weights_only=True)
    assert ckpt["global_step"] == 6


def test_training_gaps_apply_in_training_only():
    """gap_ratio reaches the training corruption; validation keeps the paper's (comparable val/mpjpe_mm)."""
    skel = generate_clips(1, 1.0, fps=10, seed=0)[0].skeleton.to_dict()
    m = XMAEModule(
        enc_dim=32,
        enc_depth=1,
        enc_mlp_dim=64,
        dec_dim=32,
        dec_depth=1,
        dec_mlp_dim=64,
        head_dim=16,
        skeleton=skel,
        window_fps=10.0,
        window_frames=10,
        gap_ratio=1.0,
    )
    x = torch.from_numpy(generate_clips(1, 1.0, fps=10, seed=1)[0].positions[:10])[None].repeat(16, 1, 1, 1)

    def frames_without_tokens():
        *_, c, _, _ = m._corrupt_and_predict(x, torch.Generator().manual_seed(0))
        return (~c.observed.any(dim=2)).any(dim=1)  # (B,) some frame empty

    m.train()
    assert frames_without_tokens().all()
    m.eval()
    assert not frames_without_tokens().all()


def test_hole_windows_in_training_and_validation_score_only_the_hole():
    """hole_ratio: the fix case in training and validation alike (val/mpjpe_mm is then the
    objective's): one part missing over one stretch, the loss on exactly those tokens; an
    untrained Hermite-correcting network answers its fill."""
    skel = generate_clips(1, 1.0, fps=10, seed=0)[0].skeleton.to_dict()
    sizes = dict(enc_dim=32, enc_depth=1, enc_mlp_dim=64, dec_dim=32, dec_depth=1, dec_mlp_dim=64, head_dim=16)
    m = XMAEModule(
        **sizes,
        skeleton=skel,
        window_fps=10.0,
        window_frames=10,
        hole_ratio=1.0,
        max_hole_s=0.5,
        fill_input=True,
        fill_kind="hermite",
        rotate_augment=False,
    )
    groups = Skeleton.from_dict(skel).groups
    assert m.part_joints.shape == (2 * len(groups), len(skel["parents"]))  # the body as often as all limbs
    x = torch.from_numpy(generate_clips(1, 1.0, fps=10, seed=1)[0].positions[:10])[None].repeat(32, 1, 1, 1)
    for training in (True, False):
        m.train(training)
        loss, pred, target, c, in_loss, _ = m._corrupt_and_predict(x, torch.Generator().manual_seed(0))
        assert torch.equal(in_loss, ~c.observed)  # nothing displaced: the hole is the loss
        hole_frames = (~c.observed).any(dim=2).sum(dim=1)
        assert hole_frames.min() >= 1 and hole_frames.max() <= 5
        assert c.observed[:, 0].all() and c.observed[:, -1].all()
    # the zero-initialised head: the prediction is the Hermite fill of the observed tokens
    fill = hermite_infill(target, c.observed)
    assert torch.allclose(pred.float(), fill.float(), atol=1e-5)
    with pytest.raises(ValueError, match="hole_ratio must be in"):
        XMAEModule(hole_ratio=1.5)
    with pytest.raises(ValueError, match="max_hole_s > 0"):
        XMAEModule(hole_ratio=0.5, max_hole_s=0.0)


def test_loss_token_settings_are_checked_and_clean_tokens_follow_the_generator():
    with pytest.raises(ValueError, match="max_displacement_m must be >= 0"):
        XMAEModule(max_displacement_m=-1.0)
    with pytest.raises(ValueError, match="mask_ratio must be in"):
        XMAEModule(mask_ratio=1.5)
    with pytest.raises(ValueError, match=r"mask_ratio \+ displace_ratio must be at most 1"):
        XMAEModule(mask_ratio=1.0, displace_ratio=0.05)
    for sizes in (dict(enc_dim=30, head_dim=16), dict(dec_dim=40, head_dim=16), dict(head_dim=0)):
        with pytest.raises(ValueError, match="must be multiples of head_dim"):
            XMAEModule(**sizes)
    with pytest.raises(ValueError, match="no token would be scored"):
        XMAEModule(mask_ratio=0.0, displace_ratio=0.0)
    with pytest.raises(ValueError, match="clean_loss_ratio 0.5"):
        XMAEModule(mask_ratio=0.85, displace_ratio=0.05, clean_loss_ratio=0.5)  # only 10 % of tokens are clean
    skel = generate_clips(1, 1.0, fps=10, seed=0)[0].skeleton.to_dict()
    m = XMAEModule(
        enc_dim=32,
        enc_depth=1,
        enc_mlp_dim=64,
        dec_dim=32,
        dec_depth=1,
        dec_mlp_dim=64,
        head_dim=16,
        skeleton=skel,
        window_fps=10.0,
        window_frames=10,
        clean_loss_ratio=0.05,
    ).eval()
    x = torch.from_numpy(generate_clips(1, 1.0, fps=10, seed=1)[0].positions[:10])[None].repeat(8, 1, 1, 1)
    scored = [m._corrupt_and_predict(x, torch.Generator().manual_seed(3))[4] for _ in range(2)]
    assert torch.equal(scored[0], scored[1])  # validation's generator draws the clean tokens too


def test_a_misspelt_monitor_is_one_line_before_training(tmp_path, capsys):
    rc = run_cli(
        [
            "fit",
            "--config",
            CONFIGS / "xmae.yaml",
            *TINY,
            *SMALL_DATA,
            *QUIET,
            "--experiment",
            "mon",
            "--monitor",
            "val/mpjpe",
            "--trainer.max_steps",
            "4",
        ],
        tmp_path,
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and "--monitor val/mpjpe: the model logs no such metric" in err[-1] and "val/mpjpe_mm" in err[-1]
    assert "Traceback" not in "".join(err)


class SigtermAtStep3(L.Callback):
    """What a scheduler's SIGTERM does in the middle of training."""

    def on_train_batch_end(self, trainer, *args):
        if trainer.global_step == 3:
            os.kill(os.getpid(), signal.SIGTERM)


def test_sigterm_during_fit_keeps_the_step_reached_and_exits_nonzero(tmp_path, capsys):
    common = [
        "fit",
        "--config",
        CONFIGS / "xmae.yaml",
        *TINY,
        *SMALL_DATA,
        *QUIET,
        "--experiment",
        "term",
        "--trainer.val_check_interval",
        "2",
    ]
    rc = run_cli(
        [*common, "--trainer.max_steps", "100", "--trainer.callbacks+=test_xmae_training.SigtermAtStep3"], tmp_path
    )
    assert rc == 128 + signal.SIGTERM and "stopped by SIGTERM" in capsys.readouterr().err
    last = tmp_path / "checkpoints" / "term" / "last.ckpt"
    assert torch.load(last, map_location="cpu", weights_only=True)["global_step"] == 3  # not 2, the last validation
    assert run_cli([*common, "--trainer.max_steps", "5", "--ckpt_path", "last"], tmp_path) == 0


def test_no_command_is_the_usage_and_a_usage_error(capsys):
    from mocapfix.apps.main import main

    assert main([]) == 2
    captured = capsys.readouterr()
    assert captured.err.startswith("usage: mocapfix") and "Traceback" not in captured.err
    assert main(["--help"]) == 0 and "mocapfix fix INPUT" in capsys.readouterr().out


def test_fill_input_trains_resumes_and_fixes(tmp_path):
    """The fill_input switch end to end: a checkpoint that fix loads as the same network."""
    from mocapfix.fix.fixers import load_fixer

    common = [
        "fit",
        "--config",
        CONFIGS / "xmae.yaml",
        *TINY,
        *SMALL_DATA,
        *QUIET,
        "--experiment",
        "fill",
        "--model.init_args.fill_input",
        "true",
        "--trainer.val_check_interval",
        "2",
    ]
    assert run_cli([*common, "--trainer.max_steps", "2"], tmp_path) == 0
    assert run_cli([*common, "--trainer.max_steps", "4", "--ckpt_path", "last"], tmp_path) == 0
    fixer = load_fixer(tmp_path / "checkpoints" / "fill" / "last.ckpt")
    assert fixer.net.fill_input
    x = torch.randn(2, 30, 22, 3)
    observed = torch.rand(2, 30, 22) < 0.5
    out = fixer.estimate(x, observed)
    assert out.shape == x.shape and torch.isfinite(out).all()
