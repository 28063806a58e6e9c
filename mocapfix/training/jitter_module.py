"""JitterModule: training and validation of the jitter remover (models/jitter.py).

Supervised on clean motion made noisy here: each training window gets its own noise level,
rotation jitter up to max_rotation_noise_rad and position jitter up to max_position_noise_m
(data/corruption.py: jitter, on positions, so any rig's recordings mapped onto one body train
it), and some windows none, so that clean input comes back (nearly) as it went in. The loss is
the distance of the output to the clean motion (MPJPE). Validation logs the network beside the
low-pass it corrects and the noisy input, at one fixed noise level.
"""

from __future__ import annotations

import lightning as L
import torch
import torch.nn as nn

from mocapfix.data.augment import BodyAugment, BodyAugmenter
from mocapfix.data.corruption import available, jitter, random_z_rotation, uniform_like
from mocapfix.evaluation.metrics import MPJPE
from mocapfix.fills.classical import lerp_infill
from mocapfix.models.build import build_model
from mocapfix.models.checkpoint import name_model
from mocapfix.models.jitter import JitterConfig, JitterNet, lowpass, residual_noise
from mocapfix.training.bind_data import BuiltFromData
from mocapfix.training.figures import log_validation_figure
from mocapfix.training.schedules import adamw_warmup_cosine
from mocapfix.training.test_report import publish


def denoise(net: JitterNet, noisy: torch.Tensor, fps: float) -> tuple[torch.Tensor, torch.Tensor]:
    """noisy: (B, T, J, 3) finite, at the network's own fps -> (denoised, low-pass), both (B, T, J, 3)."""
    base = lowpass(noisy, fps, net.cutoff_hz)
    return net(base, residual_noise(noisy, base, fps, net.cutoff_hz)), base


class JitterModule(BuiltFromData, L.LightningModule):
    def __init__(
        self,
        cutoff_hz: float = 6.0,
        width: int = 128,
        depth: int = 5,
        kernel_size: int = 3,
        max_rotation_noise_rad: float = 0.2,
        max_position_noise_m: float = 0.04,
        clean_fraction: float = 0.1,
        root_noise_fraction: float = 0.5,
        val_rotation_noise_rad: float = 0.1,
        val_position_noise_m: float = 0.02,
        test_rotation_noise_rad: tuple[float, ...] = (0.0, 0.05, 0.1, 0.2),
        rotate_augment: bool = True,
        stature_range: float = 0.0,
        limb_range: float = 0.0,
        mirror_prob: float = 0.0,
        joint_shift_m: float = 0.0,
        lr: float = 1e-3,
        weight_decay: float = 1e-4,
        warmup_steps: int = 200,
        total_steps: int | None = None,
        eval_seed: int = 0,
        figure_every_n_val: int = 1,
        skeleton: dict | None = None,
        window_fps: float | None = None,
        window_frames: int | None = None,
    ):
        """
        Args:
            cutoff_hz: the low-pass the network corrects (6 Hz: the biomechanics standard).
            width, depth, kernel_size: the network's channels, residual blocks (dilations 1, 2,
                4, ...) and kernel (models/jitter.py).
            max_rotation_noise_rad, max_position_noise_m: each training window's noise levels are
                drawn uniformly up to these (per axis-angle coordinate of every joint's rotation;
                per coordinate of every position), at the data's fps.
            clean_fraction: training windows left without noise (clean input must come back).
            root_noise_fraction: training windows whose root rotation is noisy too (the whole body
                turning about its root: a rig's noisy hip and lower-spine joints); in the others
                it is clean, as in the rotation-noise protocol, and in validation and test.
            val_rotation_noise_rad, val_position_noise_m: the validation's one noise level.
            test_rotation_noise_rad: the `test` table's rotation noise levels (positions at
                val_position_noise_m beside each, none beside 0: clean input).
            rotate_augment: a random heading per training window.
            stature_range, limb_range, mirror_prob, joint_shift_m: body augmentations (data/augment.py).
            lr, weight_decay, warmup_steps, total_steps: AdamW, linear warm-up then cosine to zero
                at total_steps (None: the Trainer's estimated number of optimiser steps).
            skeleton, window_fps, window_frames: filled in from the data module at setup; saved in checkpoints.
        """
        super().__init__()
        for name, value in (
            ("max_rotation_noise_rad", max_rotation_noise_rad),
            ("max_position_noise_m", max_position_noise_m),
        ):
            if value < 0:
                raise ValueError(f"{name} must be >= 0, got {value}")
        for name, value in (("clean_fraction", clean_fraction), ("root_noise_fraction", root_noise_fraction)):
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {value}")
        BodyAugment(stature_range, limb_range, mirror_prob, joint_shift_m).check()
        self.save_hyperparameters()
        self.net: JitterNet | None = None
        if skeleton is not None and window_frames is not None:  # a checkpoint's own weights follow
            self._build()

    def _build(self) -> None:
        hp = self.hparams
        config = JitterConfig(
            len(hp.skeleton["parents"]), hp.window_frames, hp.cutoff_hz, hp.width, hp.depth, hp.kernel_size
        )
        self.net = build_model("jitter", config)
        augment = BodyAugment(hp.stature_range, hp.limb_range, hp.mirror_prob, hp.joint_shift_m)
        self.body_augment = BodyAugmenter(self.skeleton, augment) if augment.active else None
        self.val_mpjpe = nn.ModuleDict({"jitter": MPJPE(), "lowpass": MPJPE(), "noisy": MPJPE()})

    def configure_optimizers(self):
        hp = self.hparams
        return adamw_warmup_cosine(self, hp.lr, hp.weight_decay, hp.warmup_steps, hp.total_steps)

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        if self.net is not None:
            name_model(checkpoint, "jitter", self.net.config)

    # --- the objective ---

    def _noisy(self, clean: torch.Tensor, rotation: torch.Tensor, position: torch.Tensor, generator=None, root=None):
        """clean: (B, T, J, 3), NaN = missing -> (noisy with holes Lerp-filled (B, T, J, 3), observed (B, T, J)):
        the low-pass needs every frame; the holes are left out of the loss."""
        observed = available(clean)
        filled = lerp_infill(clean, observed)
        root = torch.zeros_like(rotation) if root is None else root
        return jitter(filled, self.skeleton.parents, rotation, position, generator, root), observed

    def _loss(self, denoised: torch.Tensor, clean: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
        err = (denoised.float() - torch.nan_to_num(clean).float()).norm(dim=-1)  # (B, T, J)
        return (err * observed).sum() / observed.sum().clamp_min(1)

    def training_step(self, batch, batch_idx):
        hp = self.hparams
        clean = batch["positions"]
        if self.body_augment is not None:
            clean = self.body_augment(clean)
        B = clean.shape[0]
        if hp.rotate_augment:  # a heading per window (the network reads each frame from its root)
            clean, _ = random_z_rotation(clean)
        noisy_windows = (uniform_like((B,), None, clean) >= hp.clean_fraction).to(clean.dtype)
        rotation = hp.max_rotation_noise_rad * uniform_like((B,), None, clean) * noisy_windows
        position = hp.max_position_noise_m * uniform_like((B,), None, clean) * noisy_windows
        root = rotation * (uniform_like((B,), None, clean) < hp.root_noise_fraction).to(clean.dtype)
        noisy, observed = self._noisy(clean, rotation, position, None, root)
        denoised, _ = denoise(self.net, noisy, hp.window_fps)
        loss = self._loss(denoised, clean, observed)
        self.log("train/loss_mm", 1000 * loss, prog_bar=True)
        return loss

    def validation_step(self, batch, batch_idx):
        hp = self.hparams
        clean = batch["positions"]
        B = clean.shape[0]
        # CPU generator: the same noise on any device and precision
        generator = torch.Generator().manual_seed(hp.eval_seed * 100_003 + batch_idx)
        level = torch.ones(B, device=clean.device)
        noisy, observed = self._noisy(
            clean, hp.val_rotation_noise_rad * level, hp.val_position_noise_m * level, generator
        )
        denoised, base = denoise(self.net, noisy, hp.window_fps)
        self.log("val/loss", self._loss(denoised, clean, observed), batch_size=B, sync_dist=True)
        truth = torch.nan_to_num(clean).float()
        for name, estimate in (("jitter", denoised), ("lowpass", base), ("noisy", noisy)):
            self.val_mpjpe[name](estimate.float(), truth, observed)
        self.log("val/mpjpe_mm", self.val_mpjpe["jitter"], prog_bar=True)
        for name in ("lowpass", "noisy"):
            self.log(f"val/mpjpe_mm/{name}", self.val_mpjpe[name])
        if batch_idx == 0 and not self.trainer.sanity_checking:
            log_validation_figure(self, "val/denoised", clean, noisy, None, denoised, "clean / noisy / denoised")

    # --- the test table: each method at each noise level ---

    def on_test_epoch_start(self):
        levels = self.hparams.test_rotation_noise_rad
        self._test = {(lv, m): MPJPE().to(self.device) for lv in levels for m in ("jitter", "lowpass", "noisy")}

    def test_step(self, batch, batch_idx):
        hp = self.hparams
        clean = batch["positions"]
        ones = torch.ones(clean.shape[0], device=clean.device)
        truth = torch.nan_to_num(clean).float()
        for k, level in enumerate(hp.test_rotation_noise_rad):
            generator = torch.Generator().manual_seed((hp.eval_seed * 100_003 + batch_idx) * 31 + k)
            position = hp.val_position_noise_m if level > 0 else 0.0
            noisy, observed = self._noisy(clean, level * ones, position * ones, generator)
            denoised, base = denoise(self.net, noisy, hp.window_fps)
            for name, estimate in (("jitter", denoised), ("lowpass", base), ("noisy", noisy)):
                self._test[(level, name)].update(estimate.float(), truth, observed)

    def on_test_epoch_end(self):
        hp = self.hparams
        rows = [
            {
                "task": "denoise",
                "rotation_noise_rad": level,
                "position_noise_m": hp.val_position_noise_m if level else 0.0,
                "method": name,
                "mpjpe_mm": float(metric.compute()),
            }
            for (level, name), metric in self._test.items()
        ]
        lines = [
            f"jitter test: MPJPE mm at {hp.window_fps:g} fps (rotation noise rad; positions "
            f"{1000 * hp.val_position_noise_m:g} mm beside each but 0)"
        ]
        lines.append("method    " + "".join(f"{lv:>9g}" for lv in hp.test_rotation_noise_rad))
        for name in ("jitter", "lowpass", "noisy"):
            lines.append(f"{name:<10}" + "".join(f"{r['mpjpe_mm']:9.1f}" for r in rows if r["method"] == name))
        scalars = {f"test/mpjpe_mm/{r['method']}/{r['rotation_noise_rad']:g}rad": r["mpjpe_mm"] for r in rows}
        publish(self, rows, scalars, "\n".join(lines))
