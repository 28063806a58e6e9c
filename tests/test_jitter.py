"""The jitter remover (models/jitter.py, training/jitter_module.py, fix/jitter_clips.py): its
low-pass and noise measure, its noise, its training, and `fix --mode denoise` on any rig."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from cli_utils import CONFIGS, QUIET, run_cli
from test_dvae_training import CPU, bandai_subset

from mocapfix.apps.fix_cli import main as main_fix
from mocapfix.core.clip import MotionFileError
from mocapfix.core.skeleton import preset
from mocapfix.data.corruption import jitter
from mocapfix.fix import fix_clips
from mocapfix.fix.fixers import load_fixer
from mocapfix.io import read_motion
from mocapfix.models.checkpoint import jitter_checkpoint
from mocapfix.models.jitter import JitterConfig, JitterNet, lowpass, residual_noise


def _sine(fps: float, hz: float, seconds: float = 4.0) -> torch.Tensor:
    t = torch.arange(int(seconds * fps), dtype=torch.float64) / fps
    return torch.sin(2 * math.pi * hz * t).view(1, -1, 1, 1).expand(1, -1, 1, 3)


@pytest.mark.parametrize("fps", [30.0, 120.0])
def test_lowpass_keeps_motion_and_takes_out_what_is_above_the_cutoff(fps):
    slow, fast = _sine(fps, 1.0), _sine(fps, 12.0)
    inner = slice(int(fps), -int(fps))  # away from the ends
    assert (lowpass(slow, fps, 6.0) - slow)[:, inner].abs().max() < 0.01
    assert lowpass(fast, fps, 6.0)[:, inner].abs().max() < 0.01
    # a take's trend survives its ends (odd reflection, not zeros or a held frame)
    ramp = torch.linspace(0, 3, int(2 * fps), dtype=torch.float64).view(1, -1, 1, 1).expand(1, -1, 2, 3)
    assert (lowpass(ramp, fps, 6.0) - ramp).abs().max() < 1e-9
    with pytest.raises(ValueError, match="cannot be low-passed at 6 Hz"):
        lowpass(slow, 10.0, 6.0)


def test_residual_noise_reads_the_same_noise_the_same_at_any_frame_rate():
    """White noise of sigma per sample leaves sigma sqrt(2 cutoff / fps) below the cutoff: the
    measure says so at 30 and at 120 fps (within 10 %), and about 0 on smooth motion."""
    g = torch.Generator().manual_seed(0)
    for fps in (30.0, 120.0):
        x = 0.03 * torch.randn(1, int(20 * fps), 4, 3, generator=g, dtype=torch.float64)
        level = residual_noise(x, lowpass(x, fps, 6.0), fps, 6.0)[:, int(fps) : -int(fps)].mean().item()
        assert level == pytest.approx(0.03 * math.sqrt(12.0 / fps), rel=0.1)
    smooth = 0.3 * _sine(120.0, 1.0)
    assert residual_noise(smooth, lowpass(smooth, 120.0, 6.0), 120.0, 6.0).max() < 1e-3


def test_untrained_network_is_the_lowpass_and_reads_a_take_in_pieces_as_whole():
    net = JitterNet(JitterConfig(21, 90))
    base, noise = torch.randn(2, 200, 21, 3), 0.01 * torch.rand(2, 200, 21)
    assert torch.equal(net(base, noise), base)
    torch.nn.init.normal_(net.out.weight, std=0.1)  # a trained-looking output layer
    m = net.receptive_field
    whole = net(base, noise)
    piece = net(base[:, 50 - m : 150 + m], noise[:, 50 - m : 150 + m])[:, m:-m]
    assert torch.allclose(whole[:, 50:150], piece, atol=1e-5)
    moved = base + torch.tensor([40.0, -7.0, 0.0])  # another place on the floor: the same correction
    assert torch.allclose(net(moved, noise) - moved, whole - base, atol=1e-4)


def test_jitter_turns_bones_without_changing_their_length_then_moves_joints():
    body = preset("body21")
    g = torch.Generator().manual_seed(0)
    x = torch.randn(2, 10, 21, 3, generator=g, dtype=torch.float64)
    none = torch.zeros(2, dtype=torch.float64)
    assert torch.allclose(jitter(x, body.parents, none, none, g), x, atol=1e-12)
    turned = jitter(x, body.parents, torch.full((2,), 0.2, dtype=torch.float64), none, g)
    parents = torch.tensor(body.parents[1:])

    def bones(p):
        return (p[:, :, 1:] - p[:, :, parents]).norm(dim=-1)

    assert torch.allclose(bones(turned), bones(x))
    assert (turned - x).norm(dim=-1).mean() > 0.05
    still_root = jitter(x, body.parents, torch.full((2,), 0.2, dtype=torch.float64), none, g, root_sigma_rad=none)
    children = [j for j, p in enumerate(body.parents) if p == 0]
    assert torch.allclose(still_root[:, :, children], x[:, :, children])  # the root's own bones stay
    moved = jitter(x, body.parents, none, torch.full((2,), 0.02, dtype=torch.float64), g)
    assert (moved - x).std().item() == pytest.approx(0.02, rel=0.1)


@pytest.fixture(scope="module")
def trained(tmp_path_factory, bandai_files):
    """configs/jitter.yaml for a few steps on three Bandai takes (the loop, not the accuracy)."""
    tmp = tmp_path_factory.mktemp("jitter")
    data = bandai_subset(bandai_files, tmp / "bvh")
    common = [*QUIET, *CPU, *data, "--experiment", "j", "--data.batch_size", "4", "--data.window_s", "0.5"]
    args = ["fit", "--config", CONFIGS / "jitter.yaml", *common, "--model.init_args.width", "16"]
    args += ["--model.init_args.depth", "2", "--trainer.max_steps", "3", "--trainer.val_check_interval", "3"]
    assert run_cli([*args, "--trainer.limit_val_batches", "1"], tmp) == 0
    ckpt = tmp / "checkpoints" / "j" / "last.ckpt"
    assert run_cli(["test", "--config", CONFIGS / "jitter.yaml", *common, "--ckpt_path", ckpt], tmp) == 0
    return ckpt


def test_fit_logs_the_network_beside_its_lowpass_and_fix_reads_the_checkpoint(trained):
    ckpt = torch.load(trained, map_location="cpu", weights_only=True)
    assert ckpt["model"]["kind"] == "jitter"
    best = next(v for k, v in ckpt["callbacks"].items() if "ModelCheckpoint" in k and v.get("monitor"))
    assert best["monitor"] == "val/mpjpe_mm" and torch.isfinite(best["best_model_score"])
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(next((trained.parents[2] / "logs" / "j").glob("version_*"))))
    events.Reload()
    tags = {"val/mpjpe_mm", "val/mpjpe_mm/lowpass", "val/mpjpe_mm/noisy", "hparams/best_val_mpjpe_mm"}
    assert tags <= set(events.Tags()["scalars"])
    [table] = (trained.parents[2] / "logs" / "j").glob("version_*/eval.json")
    rows = json.loads(table.read_text())
    assert {r["method"] for r in rows} == {"jitter", "lowpass", "noisy"}
    clean = {r["method"]: r["mpjpe_mm"] for r in rows if r["rotation_noise_rad"] == 0}
    assert clean["noisy"] < 1e-3 and all(r["mpjpe_mm"] > 5 for r in rows if r["rotation_noise_rad"] == 0.2)
    fixer = load_fixer(trained)
    assert fixer.kind == "jitter" and fixer.skeleton.num_joints == 21 and fixer.fps == 30.0


def test_fix_denoises_another_rig_at_its_own_frame_rate_and_keeps_holes(cmu_files, tmp_path):
    """An untrained network is its low-pass: on a CMU take (31 joints, 120 fps) with jitter,
    fix's output at the 21 model joints is the low-pass of the input; fingers and toes move with
    the model joint above them; holes stay holes; other modes refuse in one line."""
    net = JitterNet(JitterConfig(21, 90))
    torch.save(jitter_checkpoint(net, preset("body21"), 30.0), tmp_path / "j.ckpt")
    fixer = load_fixer(tmp_path / "j.ckpt")
    [clip] = read_motion(cmu_files[0])
    g = np.random.default_rng(0)
    noisy = clip.positions + 0.02 * g.standard_normal(clip.positions.shape).astype(np.float32)
    noisy[100:110, 5] = np.nan
    take = clip.replace(positions=noisy, rotations=None, root_translation=None, offsets=None)
    (out,), report = fix_clips([take], fixer, "denoise")
    assert np.array_equal(np.isnan(out.positions), np.isnan(noisy))
    err_in = np.nanmean(np.linalg.norm(noisy - clip.positions, axis=-1))
    err_out = np.nanmean(np.linalg.norm(out.positions - clip.positions, axis=-1))
    assert err_out < 0.5 * err_in
    assert report.limb_sigma_after_mm < 0.5 * report.limb_sigma_before_mm
    assert any("low-pass" in n for n in report.notes)
    for mode in ("infill", "both"):
        with pytest.raises(MotionFileError, match="does not fill holes"):
            fix_clips([take], fixer, mode)
    slow = take.replace(fps=10.0)
    with pytest.raises(MotionFileError, match="cannot be low-passed"):
        fix_clips([slow], fixer, "denoise")


def test_the_shipped_jitter_remover_cleans_another_studios_bvh(cmu_files, tmp_path, capsys):
    """jitter-many on a CMU take (a rig, performer and frame rate it never trained on) with the
    issue's noise, 0.1 rad on every joint's rotation and 2 cm on every position: `fix` writes a
    BVH back in the take's hierarchy whose 21 model joints are within 0.7x the noisy input's
    error and below scipy's zero-phase 4th-order Butterworth at 6 Hz."""
    from scipy.signal import butter, filtfilt

    from mocapfix.data.corruption import rotation_noise
    from mocapfix.io.bvh import read_bvh, write_bvh
    from mocapfix.rig.mapping import onto_skeleton

    take = next(f for f in cmu_files if f.name == "05_02.bvh")
    [clip] = read_bvh(take)
    g = torch.Generator().manual_seed(0)
    rot, pos = rotation_noise(
        torch.from_numpy(clip.rotations)[None],
        torch.from_numpy(clip.root_translation)[None],
        torch.from_numpy(clip.offsets)[None, None],
        clip.skeleton.parents,
        0.1,
        g,
    )
    pos = pos[0] + 0.02 * torch.randn(pos.shape[1:], generator=g)
    write_bvh(tmp_path / "noisy.bvh", clip.replace(rotations=rot[0].numpy(), positions=pos.numpy()), template=take)
    assert main_fix([str(tmp_path / "noisy.bvh"), "--model", "jitter-many"]) == 0
    assert "(denoise, jitter)" in capsys.readouterr().out
    body = preset("body21")
    truth, noisy, out = (
        onto_skeleton(read_bvh(p)[0], body).positions.astype(np.float64)
        for p in (take, tmp_path / "noisy.bvh", tmp_path / "noisy.fixed.bvh")
    )
    b, a = butter(4, 6.0 / (clip.fps / 2))

    def err(x):
        return np.linalg.norm(x - truth, axis=-1).mean()

    assert err(out) < 0.7 * err(noisy)
    assert err(out) < err(filtfilt(b, a, noisy, axis=0))


def test_the_rotations_denoiser_on_another_rig_names_the_real_reason(cmu_files, tmp_path, capsys):
    """motion-dvae-bandai reads Bandai's hierarchy: on a CMU BVH (which has rotations) the one
    line says the rig's rotations do not fit, not that there are none, and where to go."""
    rc = main_fix(
        [str(cmu_files[0]), "--model", "motion-dvae-bandai", "--mode", "denoise", "-o", str(tmp_path / "o.bvh")]
    )
    err = capsys.readouterr().err
    assert rc == 1 and err.count("\n") == 1
    assert "rotations do not fit" in err and "--model jitter-many" in err and "has none" not in err


def test_the_correction_reaches_no_further_than_twice_what_the_low_pass_took_out():
    """fixers.capped: a correction within CORRECTION_REACH RMS residuals (over the window) is
    kept as it is; a longer one (a body unlike any the network learned) is cut to that length,
    its direction kept; the RMS is over the window, so a token whose own residual is ~0 by
    chance (white noise) is not cut to nothing."""
    from mocapfix.fix.fixers import CORRECTION_REACH, capped

    rng = np.random.default_rng(0)
    residual = rng.normal(0, 0.01, (200, 3, 3))  # 1 cm of white noise: RMS ~1.7 cm a token
    residual[100] = 0.0  # this frame's tokens happen to sit on their low-pass
    small = rng.normal(0, 0.002, (200, 3, 3))
    np.testing.assert_array_equal(capped(small, residual, 5), small)
    far = np.zeros((200, 3, 3))
    far[:, :, 0] = 0.5  # half a metre along x everywhere
    out = capped(far, residual, 5)
    rms = np.sqrt((residual**2).sum(-1).mean())
    assert np.abs(out[..., 1:]).max() == 0 and (out[..., 0] > 0).all()  # direction kept
    assert 0.5 * CORRECTION_REACH * rms < np.median(out[..., 0]) < 2 * CORRECTION_REACH * rms
    assert out[100, :, 0].min() > 0.3 * CORRECTION_REACH * rms  # the window's RMS, not the token's 0
