"""CorrectionModule: training and testing of the learned correction to a classical fill
(models/correction.py).

Trained on the case `fix` meets: each training window gets one hole (the whole body, an arm or a
leg, 1 frame to max_hole_s long, data on both sides: corruption.training_holes), the base fill
fills it, and the network learns what the base fill got wrong there. The loss is, per window, the
squared error left over the base fill's (1 for an untrained network): squared, as the ridge
regression that first showed a within-capture signal, and relative, so that short holes count
as much as long ones. With `length_buckets`, the network's linear bank (one map per part and
range of hole lengths) is fitted in closed form when training starts (training/ridge_bank.py),
before the first step: the steps then train the MLP on what it leaves. Validation logs the
corrected fill beside its base on a full-body gap centred in each val window; `test` prints
the XMAE paper's infilling tables (evaluation/tasks.py) with every classical fill beside it.
"""

from __future__ import annotations

import sys

import lightning as L
import torch
import torch.nn as nn

from mocapfix.data.augment import mirror_of
from mocapfix.data.corruption import available, infill_gap, training_holes
from mocapfix.evaluation.harness import abs_and_rel, mpjpe_table
from mocapfix.evaluation.metrics import MPJPE
from mocapfix.evaluation.tasks import format_table, paper_tasks, table_rows
from mocapfix.fills.classical import CLASSICAL, classical_fills
from mocapfix.fills.fill import made
from mocapfix.models.build import build_model
from mocapfix.models.checkpoint import name_model
from mocapfix.models.correction import BASES, CorrectionConfig, CorrectionNet, base_fill, correction_fill
from mocapfix.training.bind_data import BuiltFromData
from mocapfix.training.ridge_bank import fit_bank
from mocapfix.training.schedules import adamw_warmup_cosine
from mocapfix.training.test_report import publish

PARTS = ("full", "arm", "leg")
BASE_ERROR_FLOOR_M = 0.002  # per hole token, added to the base fill's error the loss divides by


class CorrectionModule(BuiltFromData, L.LightningModule):
    def __init__(
        self,
        base: str = "hermite",
        context_frames: int = 10,
        hole_points: int = 16,
        hidden: int = 512,
        depth: int = 2,
        max_hole_s: float = 1.0,
        hole_parts: tuple[str, ...] = PARTS,
        lr: float = 1e-3,
        weight_decay: float = 1e-4,
        warmup_steps: int = 200,
        total_steps: int | None = None,
        val_gap_s: float = 0.5,
        eval_gaps_s: tuple[float, ...] = (0.1, 0.3, 0.5, 0.7, 0.9),
        skeleton: dict | None = None,
        window_fps: float | None = None,
        window_frames: int | None = None,
        length_buckets: int = 0,
        bank_batches: int = 40,
        bank_strengths: tuple[float, ...] = (1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 0.1),
    ):
        """
        Args:
            base: the classical fill corrected: "hermite" (a cubic leaving and meeting the data at
                its velocities; batched torch, fast) or "limb" (bone lengths kept; scipy splines
                per window, slower steps).
            context_frames: frames read on each side of a hole; hole_points: the correction's
                samples over a hole, read back at each of its frames (models/correction.py).
            hidden, depth: the MLP's width and hidden layers (a linear path runs beside it).
            max_hole_s: training holes are 1 frame to this long (within the window).
            hole_parts: the parts a training hole takes: "full" (the whole body), "arm", "leg"
                (one of the skeleton's arm or leg groups).
            lr, weight_decay, warmup_steps, total_steps: AdamW, linear warm-up then cosine to zero
                at total_steps (None: the Trainer's estimated number of optimiser steps).
            val_gap_s: the full-body gap centred in each val window (val/mpjpe_mm, and its base's).
            eval_gaps_s: the `test` tables' gaps.
            skeleton, window_fps, window_frames: filled in from the data module at setup; saved in checkpoints.
            length_buckets: a linear bank beside the MLP (models/correction.py), one map per part
                of hole_parts and per this many ranges of hole lengths, fitted in closed form
                (training/ridge_bank.py) when training starts, before the MLP's first step; 0: none.
            bank_batches: training batches drawn for each of the bank's maps (its ridge strength
                chosen among bank_strengths on the windows of every 5th training take).
        """
        super().__init__()
        if base not in BASES:
            raise ValueError(f"base {base!r}: one of {', '.join(BASES)}")
        unknown = sorted(set(hole_parts) - set(PARTS))
        if unknown or not hole_parts:
            raise ValueError(f"hole_parts {list(hole_parts)}: some of {', '.join(PARTS)}")
        if max_hole_s <= 0:
            raise ValueError(f"max_hole_s must be > 0, got {max_hole_s}")
        if length_buckets < 0 or (length_buckets and (bank_batches < 1 or not bank_strengths)):
            raise ValueError(
                f"length_buckets {length_buckets} must be >= 0, and a bank needs bank_batches >= 1 "
                f"(got {bank_batches}) and bank_strengths"
            )
        self.save_hyperparameters()
        self.net: CorrectionNet | None = None
        if skeleton is not None and window_frames is not None:  # a checkpoint's own weights follow
            self._build()

    def _build(self) -> None:
        hp, skeleton = self.hparams, self.skeleton
        groups = skeleton.groups
        hips = (groups["left_leg"][0], groups["right_leg"][0]) if {"left_leg", "right_leg"} <= set(groups) else (0, 0)
        # (P, J) bool: each part a training hole can take (and the bank's part groups)
        rows = []
        for part in hp.hole_parts:
            if part == "full":
                rows.append([True] * skeleton.num_joints)
            for name, members in sorted(groups.items()):
                if part != "full" and name.endswith(part):
                    rows.append([j in members for j in range(skeleton.num_joints)])
        if not rows:
            raise ValueError(f"hole_parts {list(hp.hole_parts)}: the skeleton has no such group")
        config = CorrectionConfig(
            skeleton.num_joints,
            hp.window_fps,
            hp.base,
            hp.context_frames,
            hp.hole_points,
            hp.hidden,
            hp.depth,
            hips,
            tuple(skeleton.parents),
            hp.length_buckets,
            self._max_hole_frames() if hp.length_buckets else 0,
            tuple(tuple(j for j, inside in enumerate(row) if inside) for row in rows) if hp.length_buckets else (),
        )
        self.net = build_model("correction", config)
        self.register_buffer("part_joints", torch.tensor(rows), persistent=False)
        self.val_mpjpe = nn.ModuleDict({"correction": MPJPE(), "base": MPJPE()})

    def _max_hole_frames(self) -> int:
        return max(1, round(self.hparams.max_hole_s * self.hparams.window_fps))

    def configure_optimizers(self):
        hp = self.hparams
        return adamw_warmup_cosine(self, hp.lr, hp.weight_decay, hp.warmup_steps, hp.total_steps)

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        if self.net is not None:
            name_model(checkpoint, "correction", self.net.config)

    def on_train_start(self) -> None:
        # the bank first, in closed form (a resumed run has it in its checkpoint): the MLP's
        # steps then learn what it leaves
        if self.hparams.length_buckets and not bool(self.net.bank_fitted):
            train = self.trainer.train_dataloader
            fit_bank(
                self.net,
                lambda: ((batch["positions"].to(self.device), batch["clip_index"]) for batch in train),
                self.hparams.bank_batches,
                tuple(self.hparams.bank_strengths),
                BASE_ERROR_FLOOR_M,
                mirror_of(self.skeleton),  # None where the sides do not pair up by name
                lambda line: print(line, file=sys.stderr, flush=True) if self.trainer.is_global_zero else None,
            )

    # --- the objective ---

    def training_step(self, batch, batch_idx):
        hp = self.hparams
        clean = batch["positions"]  # (B, T, J, 3), NaN = missing
        B, T = clean.shape[:2]
        longest = self._max_hole_frames()
        hole = training_holes(B, T, self.part_joints, longest, None, clean, hp.context_frames) & available(clean)
        observed = available(clean) & ~hole
        base = base_fill(self.net.config, torch.where(observed[..., None], clean, torch.nan), observed)
        truth = torch.nan_to_num(clean)
        out = self.net(base, ~observed)
        # per window, the squared error left over the base fill's: every hole counts the same,
        # a 0.1-s arm hole's few mm as much as a 1-s body hole's centimetres (a loss summed over
        # tokens is the long holes', and a correction that blurs the short ones costs it little)
        after = (((out - truth) ** 2).sum(-1) * hole).sum((1, 2))  # (B,) m^2
        before = (((base - truth) ** 2).sum(-1) * hole).sum((1, 2))
        floor = hole.sum((1, 2)) * BASE_ERROR_FLOOR_M**2  # a hole the base fills exactly is not a division by 0
        has = hole.any(-1).any(-1)  # (B,) a window whose hole fell where the data is missing has none
        loss = (after / (before + floor))[has].mean() if has.any() else 0.0 * out.sum()
        count = hole.sum().clamp_min(1)
        self.log("train/left_of_base", loss.detach(), prog_bar=True)
        self.log("train/rms_mm", 1000 * (after.sum() / count).detach().sqrt())
        self.log(f"train/rms_mm/{self.hparams.base}", 1000 * (before.sum() / count).sqrt())
        return loss

    def validation_step(self, batch, batch_idx):
        clean = batch["positions"]
        c = infill_gap(clean, self.hparams.window_fps, self.hparams.val_gap_s)
        scored = available(clean) & ~c.observed
        base = base_fill(self.net.config, c.positions, c.observed)
        out = correction_fill(self.net, c.positions, c.observed, base)
        truth = torch.nan_to_num(clean).float()
        self.val_mpjpe["correction"](out.float(), truth, scored)
        self.val_mpjpe["base"](base.float(), truth, scored)
        self.log("val/mpjpe_mm", self.val_mpjpe["correction"], prog_bar=True, batch_size=len(clean))
        self.log(f"val/mpjpe_mm/{self.hparams.base}", self.val_mpjpe["base"], batch_size=len(clean))

    # --- test: the paper's infilling tables ---

    def on_test_epoch_start(self):
        self._tasks = [t for t in paper_tasks(self.skeleton, self.hparams.eval_gaps_s, ()) if t.task == "infill"]
        self._methods = ("correction", *CLASSICAL)
        self._table = mpjpe_table([t.key for t in self._tasks], self._methods).to(self.device)

    def test_step(self, batch, batch_idx):
        positions = batch["positions"]
        fps = self.hparams.window_fps
        for t in self._tasks:
            c = t.corrupt(positions, fps, self.skeleton, None)
            scored = t.evaluated(c, positions)
            preds = made(classical_fills(), c.positions, c.observed, fps, self.skeleton)
            preds["correction"] = correction_fill(self.net, c.positions, c.observed, preds[self.hparams.base])
            for m, pred in preds.items():
                for rel in ("abs", "rel"):
                    self._table.update((t.key, m, rel), pred.float(), positions.float(), scored)

    def on_test_epoch_end(self):
        cells = self._table.compute()
        results = abs_and_rel(cells)
        rows = table_rows(results, self._tasks)
        scalars = {f"test/{r['task']}/{r['part']}/gap{r['gap_s']}s/{r['method']}_mpjpe_mm": r["mpjpe_mm"] for r in rows}
        self.eval_json_path = publish(self, rows, scalars, format_table(rows))
