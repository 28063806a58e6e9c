"""Unsupervised learned denoising (Motion-DVAE section 4) through the product path: configs, the
frozen prior and decoder, a loss that never reads clean data, regression and optimisation modes,
eval.json."""

from __future__ import annotations

import json
import shutil

import pytest
import torch
from cli_utils import CONFIGS, QUIET, SMALL_DATA, run_cli
from test_dvae_training import CPU, TINY_DVAE, bandai_subset

from mocapfix.data.datamodule import MotionDataModule
from mocapfix.evaluation.denoise_table import METHODS, SMOOTHERS
from mocapfix.models.dvae_state import to_canonical
from mocapfix.training.denoise_module import DVAEDenoiseModule
from mocapfix.training.dvae_module import MotionDVAEModule

# a few Adamax steps that really move the weights, and a short optimisation mode
DENOISE = [
    "--model.init_args.lr",
    "1e-2",
    "--model.init_args.opt_iterations",
    "2",
    "--model.init_args.kl_anneal_steps",
    "2",
]


@pytest.fixture(scope="module")
def prior_ckpt(tmp_path_factory):
    d = tmp_path_factory.mktemp("prior")
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
                "--experiment",
                "prior",
                "--trainer.max_steps",
                "2",
                "--trainer.val_check_interval",
                "2",
                "--trainer.limit_val_batches",
                "1",
            ],
            d,
        )
        == 0
    )
    return d / "checkpoints" / "prior" / "last.ckpt"


@pytest.fixture(scope="module")
def denoised(prior_ckpt, tmp_path_factory):
    """A denoising run of 4 optimiser steps: (its folder, the common CLI arguments)."""
    d = tmp_path_factory.mktemp("denoise")
    common = [
        "--config",
        CONFIGS / "motion_dvae_denoise.yaml",
        *SMALL_DATA,
        *QUIET,
        *CPU,
        "--experiment",
        "dn",
        "--model.init_args.prior_ckpt",
        prior_ckpt,
    ]
    assert (
        run_cli(
            [
                "fit",
                *common,
                *DENOISE,
                "--trainer.max_steps",
                "4",
                "--trainer.val_check_interval",
                "4",
                "--trainer.limit_val_batches",
                "1",
            ],
            d,
        )
        == 0
    )
    return d, common


def test_fast_dev_run_motion_dvae_denoise_yaml(tmp_path, prior_ckpt):
    assert (
        run_cli(
            [
                "fit",
                "--config",
                CONFIGS / "motion_dvae_denoise.yaml",
                *SMALL_DATA,
                *QUIET,
                *CPU,
                "--model.init_args.prior_ckpt",
                prior_ckpt,
                "--trainer.fast_dev_run",
                "1",
            ],
            tmp_path,
        )
        == 0
    )


def test_fast_dev_run_motion_dvae_denoise_bvh_yaml(tmp_path, bandai_files):
    data = bandai_subset(bandai_files, tmp_path / "bvh")
    assert (
        run_cli(
            [
                "fit",
                "--config",
                CONFIGS / "motion_dvae_bvh.yaml",
                *TINY_DVAE,
                *QUIET,
                *CPU,
                *data,
                "--experiment",
                "p",
                "--trainer.max_steps",
                "1",
                "--trainer.limit_val_batches",
                "1",
                "--trainer.val_check_interval",
                "1",
            ],
            tmp_path,
        )
        == 0
    )
    assert (
        run_cli(
            [
                "fit",
                "--config",
                CONFIGS / "motion_dvae_denoise_bvh.yaml",
                *QUIET,
                *CPU,
                *data,
                "--model.init_args.prior_ckpt",
                tmp_path / "checkpoints" / "p" / "last.ckpt",
                "--trainer.fast_dev_run",
                "1",
            ],
            tmp_path,
        )
        == 0
    )


def test_denoising_leaves_prior_and_decoder_bit_identical(prior_ckpt, denoised):
    d, _ = denoised
    before = torch.load(prior_ckpt, map_location="cpu", weights_only=True)["state_dict"]
    after = torch.load(d / "checkpoints" / "dn" / "last.ckpt", map_location="cpu", weights_only=True)
    assert after["global_step"] == 4
    after = after["state_dict"]
    frozen = [k for k in before if k.startswith("net.gen.") or k in ("net.x_mean", "net.x_std")]
    assert len(frozen) > 10
    for k in frozen:
        assert torch.equal(before[k], after[k]), f"{k} changed"
    # the trained parts did move (so the comparison above could fail)
    moved = [k for k in before if k.startswith("net.enc.") and not torch.equal(before[k], after[k])]
    assert len(moved) > 5
    assert any(k.startswith("x0_pred.") for k in after) and any(k.startswith("noise_pred.") for k in after)


def _tiny_denoiser(prior_ckpt) -> tuple[DVAEDenoiseModule, dict]:
    dm = MotionDataModule(
        synthetic_clips=4, synthetic_seconds=2.0, cache_dir=None, with_rotations=True, val_fraction=0, test_fraction=1.0
    )
    dm.setup("test")
    batch = dm.datasets["test"].__getitems__([0, 1, 2])
    return DVAEDenoiseModule(prior_ckpt=str(prior_ckpt), noise_lambda=5.0), batch


def test_first_frame_is_the_decoders_step_back_or_the_papers_x0(prior_ckpt):
    model, batch = _tiny_denoiser(prior_ckpt)
    model.eval()
    model.hparams.estimate = "decoder"  # no fusion: the frames are the model's own
    obs = model.observation(model.add_noise(batch, 0.1, torch.Generator().manual_seed(1)))
    with torch.no_grad():
        inf = model.infer(obs, sample=False)
        decoded = model.estimate(obs)
        model.hparams.first_frame = "predicted"
        predicted = model.estimate(obs)
        x0 = model.codec.step_back(inf.x[:, 1])
        want0 = model.codec.points(x0[:, None], inf.shape).joints[:, 0]  # canonical frame
    assert torch.equal(decoded[:, 1:], predicted[:, 1:])  # only frame 0 differs
    assert not torch.allclose(decoded[:, 0], predicted[:, 0], atol=1e-4)
    assert torch.allclose(to_canonical(decoded[:, 0], inf.canon), want0, atol=1e-5)
    assert torch.allclose(to_canonical(predicted[:, 0], inf.canon), inf.m[:, 0, : model.codec.num_joints], atol=1e-5)
    with pytest.raises(ValueError, match="first_frame"):
        DVAEDenoiseModule(prior_ckpt=str(prior_ckpt), first_frame="zero")


class Untouchable(torch.Tensor):
    """A tensor any torch operation on which fails: proves nobody reads it."""

    @classmethod
    def __torch_function__(cls, func, types, args=(), kwargs=None):
        raise AssertionError(f"clean data read by {getattr(func, '__name__', func)}")


def test_denoising_loss_never_reads_clean_data(prior_ckpt):
    model, batch = _tiny_denoiser(prior_ckpt)
    noisy = model.add_noise(batch, 0.15, torch.Generator().manual_seed(0))

    def loss_of(b):
        torch.manual_seed(0)  # the same reparameterisation noise
        return model.training_step(b, 0)

    loss = loss_of(noisy)
    assert torch.isfinite(loss)
    nan = dict(
        noisy,
        positions=torch.full_like(batch["positions"], float("nan")),
        rotations=torch.full_like(batch["rotations"], float("nan")),
    )
    assert torch.equal(loss_of(nan), loss)
    poisoned = dict(
        noisy,
        positions=torch.Tensor._make_subclass(Untouchable, batch["positions"]),
        rotations=torch.Tensor._make_subclass(Untouchable, batch["rotations"]),
    )
    assert torch.equal(loss_of(poisoned), loss)
    # and the noise really is in what the loss sees (so the checks above compare different inputs)
    assert (noisy["noisy_rotations"][:, :, 1:] - batch["rotations"][:, :, 1:]).abs().mean() > 0.05
    with pytest.raises(AssertionError, match="clean data read"):
        torch.Tensor._make_subclass(Untouchable, batch["positions"]).sum()


def test_optimisation_mode_adapts_then_restores_the_weights(prior_ckpt):
    model, batch = _tiny_denoiser(prior_ckpt)
    model.hparams.opt_iterations, model.hparams.opt_lr = 3, 1e-2
    model.eval()
    obs = model.observation(model.add_noise(batch, 0.1, torch.Generator().manual_seed(1)))
    weights = {k: v.clone() for k, v in model.state_dict().items()}
    with torch.inference_mode():  # as Lightning's test loop would, with trainer.inference_mode left on
        regression = model.estimate(obs)
        optimised = model.optimise_and_estimate(obs)
    assert optimised.shape == regression.shape == batch["positions"].shape
    assert not torch.allclose(optimised, regression)
    for k, v in model.state_dict().items():
        assert torch.equal(v, weights[k]), f"{k} not restored"
    assert not model.training


def test_test_prints_and_writes_eval_json(denoised, capsys):
    d, common = denoised
    capsys.readouterr()
    assert (
        run_cli(
            [
                "test",
                *common,
                "--ckpt_path",
                d / "checkpoints" / "dn" / "last.ckpt",
                "--trainer.limit_test_batches",
                "1",
            ],
            d,
        )
        == 0
    )
    out = capsys.readouterr().out
    lines = out.strip().splitlines()
    assert lines[-1].startswith("eval.json: ")
    assert "dvae_regression" in out and "accel m/s^2" in out
    rows = json.loads((d / lines[-1].split(": ", 1)[1]).read_text())
    keys = {(r["sigma_rad"], r["method"]) for r in rows}
    assert keys == {(s, m) for s in (0.1, 0.15, 0.2) for m in ("ground_truth", *METHODS, *SMOOTHERS)}
    for r in rows:
        assert set(r) == {
            "task",
            "part",
            "sigma_rad",
            "method",
            "mpjpe_mm",
            "mpjpe_rel_mm",
            "accel_ms2",
            "seconds_per_frame",
        }
        assert r["task"] == "noise" and r["part"] == "full"
        assert (r["seconds_per_frame"] is None) == (r["method"] in ("noisy", "ground_truth", *SMOOTHERS))
    by = {(r["sigma_rad"], r["method"]): r for r in rows}
    # noise on the joint rotations moves the joints, more with a larger sigma; the ground truth has its own acceleration
    assert 0 < by[(0.1, "noisy")]["mpjpe_mm"] < by[(0.2, "noisy")]["mpjpe_mm"]
    assert by[(0.1, "noisy")]["accel_ms2"] > by[(0.1, "ground_truth")]["accel_ms2"] > 0
    # the classical smoother takes jitter out: less acceleration than the noisy input, more with a wider kernel
    assert by[(0.2, "smooth4f")]["accel_ms2"] < by[(0.2, "smooth1f")]["accel_ms2"] < by[(0.2, "noisy")]["accel_ms2"]
    spf = by[(0.15, "dvae_regression")]["seconds_per_frame"]
    assert spf > 0
    with capsys.disabled():
        print(
            f"\nregression mode (tiny model, CPU): {spf:.2e} s/frame; optimisation mode (2 iterations): "
            f"{by[(0.15, 'dvae_optimisation')]['seconds_per_frame']:.2e} s/frame"
        )


def test_denoise_checkpoint_rebuilds_without_the_prior_file(denoised, tmp_path):
    d, _ = denoised
    model = DVAEDenoiseModule.load_from_checkpoint(d / "checkpoints" / "dn" / "last.ckpt", map_location="cpu")
    ckpt = torch.load(d / "checkpoints" / "dn" / "last.ckpt", map_location="cpu", weights_only=True)
    assert ckpt["hyper_parameters"]["prior_hparams"]["state"] == "rotations"
    torch.testing.assert_close(model.net.gen.d_x.net[-1].weight, ckpt["state_dict"]["net.gen.d_x.net.6.weight"])


def test_positions_state_runs_both_stages_on_position_noise(tmp_path):
    data = [*SMALL_DATA, *QUIET, *CPU, "--data.with_rotations", "false"]
    assert (
        run_cli(
            [
                "fit",
                "--config",
                CONFIGS / "motion_dvae.yaml",
                *TINY_DVAE,
                *data,
                "--experiment",
                "pp",
                "--model.init_args.state",
                "positions",
                "--trainer.max_steps",
                "1",
                "--trainer.val_check_interval",
                "1",
                "--trainer.limit_val_batches",
                "1",
            ],
            tmp_path,
        )
        == 0
    )
    ckpt = tmp_path / "checkpoints" / "pp" / "last.ckpt"
    assert MotionDVAEModule.load_from_checkpoint(ckpt, map_location="cpu").codec.kind == "positions"
    assert (
        run_cli(
            [
                "fit",
                "--config",
                CONFIGS / "motion_dvae_denoise.yaml",
                *data,
                "--model.init_args.prior_ckpt",
                ckpt,
                "--model.init_args.noise",
                "position",
                "--model.init_args.train_sigmas",
                "[0.02]",
                "--model.init_args.val_sigma",
                "0.02",
                "--trainer.fast_dev_run",
                "1",
            ],
            tmp_path,
        )
        == 0
    )


@pytest.mark.slow
@pytest.mark.skipif(not (shutil.which("cc") or shutil.which("gcc")), reason="torch.compile on CPU needs a C compiler")
def test_compiled_denoiser_estimates_as_the_eager_one(prior_ckpt):
    eager, batch = _tiny_denoiser(prior_ckpt)
    compiled = DVAEDenoiseModule(prior_ckpt=str(prior_ckpt), noise_lambda=5.0, compile_model=True)
    assert compiled.net._compiled_call_impl is not None and eager.net._compiled_call_impl is None
    compiled.load_state_dict(eager.state_dict())
    obs = eager.observation(eager.add_noise(batch, 0.1, torch.Generator().manual_seed(1)))
    with torch.no_grad():
        torch.testing.assert_close(compiled.eval().estimate(obs), eager.eval().estimate(obs), atol=1e-4, rtol=1e-4)
