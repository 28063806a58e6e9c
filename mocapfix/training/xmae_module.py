"""XMAEModule: training, validation, the paper's test tables and prediction for XMAE.

The nn.Module (models/xmae.py) knows nothing of this: losses, corruption, schedules and logging
live here. The network is built in setup() from the data module's skeleton and window, and those
are stored as plain hyperparameters so a checkpoint alone rebuilds it (fix, load_from_checkpoint).
"""

from __future__ import annotations

import logging
import time

import lightning as L
import torch
import torch.nn as nn

from mocapfix.core.skeleton import GROUP_NAMES, Skeleton
from mocapfix.data.augment import BodyAugment, BodyAugmenter
from mocapfix.data.corruption import check_training_corruption, uniform_like
from mocapfix.data.spec import DataSpec
from mocapfix.evaluation.harness import abs_and_rel, mpjpe_table
from mocapfix.evaluation.metrics import MPJPE
from mocapfix.evaluation.policy_fit import calibrate
from mocapfix.evaluation.tasks import Task, format_table, paper_tasks, table_rows, window_seeds
from mocapfix.fills.classical import CLASSICAL, lerp_infill, spline_infill
from mocapfix.fills.model import candidate_fills, policy_output
from mocapfix.fills.policy import Calibration, FillPolicy, apply_fill_policy
from mocapfix.models.build import build_model
from mocapfix.models.checkpoint import (
    fill_policy_values,
    hyperparameters,
    name_model,
    network_weights,
    set_fill_policy,
    xmae_config,
)
from mocapfix.models.xmae import XMAE, XMAEConfig, preset_sizes
from mocapfix.models.xmae_inference import xmae_fill, xmae_reconstruct
from mocapfix.training.bind_data import BindData, require_same_window
from mocapfix.training.figures import log_validation_figure
from mocapfix.training.final_policy import FinalFillPolicy
from mocapfix.training.schedules import WarmupCosine
from mocapfix.training.test_report import publish
from mocapfix.training.xmae_input import xmae_training_input

log = logging.getLogger(__name__)

COMPILE_MODES = ("default", "reduce-overhead", "max-autotune", "max-autotune-no-cudagraphs")
CUDA_GRAPH_MODES = ("reduce-overhead", "max-autotune")  # the modes that replay CUDA graphs


class XMAEModule(L.LightningModule):
    def __init__(
        self,
        preset: str = "paper",
        enc_dim: int | None = None,
        enc_depth: int | None = None,
        enc_mlp_dim: int | None = None,
        dec_dim: int | None = None,
        dec_depth: int | None = None,
        dec_mlp_dim: int | None = None,
        head_dim: int | None = None,
        decoder: str | None = None,
        position_unit_m: float | None = None,
        fill_input: bool | None = None,
        fill_kind: str | None = None,
        mask_ratio: float = 0.85,
        displace_ratio: float = 0.05,
        max_displacement_m: float = 1.0,
        clean_loss_ratio: float = 0.0,
        gap_ratio: float = 0.0,
        hole_ratio: float = 0.0,
        max_hole_s: float = 1.0,
        fixed_kept_count: bool = True,
        rotate_augment: bool = True,
        stature_range: float = 0.0,
        limb_range: float = 0.0,
        mirror_prob: float = 0.0,
        joint_shift_m: float = 0.0,
        compile_model: bool = False,
        compile_mode: str = "default",
        lr: float = 3e-4,
        betas: tuple[float, float] = (0.9, 0.999),
        warmup_steps: int = 1200,
        total_steps: int | None = None,
        val_gap_s: float = 0.5,
        eval_gaps_s: tuple[float, ...] = (0.1, 0.3, 0.5, 0.7, 0.9),
        eval_noise_sigmas_m: tuple[float, ...] = (0.02, 0.05),
        eval_seed: int = 0,
        calibration_windows: int = 256,
        calibrate_every_n_val: int = 1,
        figure_every_n_val: int = 1,
        init_weights: str | None = None,
        skeleton: dict | None = None,
        window_fps: float | None = None,
        window_frames: int | None = None,
    ):
        """
        Args:
            preset: the network's sizes by name (models/xmae.py PRESETS: "paper", Table 1; "cpu");
                each of the settings below that is given (not None) overrides the preset's.
            enc_* / dec_* / head_dim: widths and depths.
            decoder: "cross" (XMAE) or "mae" (original MAE decoder, ablation).
            position_unit_m: the network's internal position unit (inputs divided, outputs multiplied).
            fill_input: not in the paper: the decoder also reads a Lerp fill of every token and the
                network predicts the correction to it (models/xmae.py).
            fill_kind: the fill it corrects: "lerp", or "hermite" (a cubic leaving and meeting the
                data at its velocities; fix hands it the whole take's, models/xmae.py).
            mask_ratio, displace_ratio: fractions of all J*T tokens masked / displaced in training.
            max_displacement_m: radius of the ball displacement offsets are drawn from.
            clean_loss_ratio: fraction of all tokens kept clean AND put in the loss ("BERT masking": 0.05).
            gap_ratio: fraction of training windows that also lose the whole skeleton over a random
                stretch of frames (not in the paper, 0 = the paper's corruption; see corruption.training_gaps).
            hole_ratio, max_hole_s: not in the paper: the fraction of windows (training and validation)
                that get what `fix` meets instead of the paper's masking: one hole of the whole body or
                of a limb, up to max_hole_s long, every other token observed and clean
                (corruption.training_holes). Meant for a network correcting a fill (fill_input,
                fill_kind): the correction is then trained where fix uses it (measured so far:
                docs/results.md, "Models trained on many people"). The encoder reads whole windows
                (slower steps).
            fixed_kept_count: every sample keeps the same number of tokens, known from mask_ratio
                without reading the batch (no host-device sync); only samples short of data are padded.
            rotate_augment: random rotation about z after normalisation.
            stature_range, limb_range, mirror_prob, joint_shift_m: not in the paper: each training
                window played by another body (data/augment.py): every bone scaled by a factor in
                [1 - stature_range, 1 + stature_range], arms / legs / spine each by one in
                [1 - limb_range, 1 + limb_range] on top, left and right swapped with probability
                mirror_prob, each joint moved by a constant offset within joint_shift_m metres.
                What a model trained on a few performers needs to fill a stranger's take.
            compile_model: torch.compile the network (faster GPU steps after a minute of compiling;
                checkpoints are the same either way).
            compile_mode: torch.compile's mode. "reduce-overhead" replays the network's forward and
                backward as CUDA graphs: the compiled H100 step launches 967 kernels in 25 ms for
                16 ms of kernel work (docs/performance.md, (7)); the launches are what it removes.
                Not yet measured on a GPU. Ignored on the CPU (no graphs there).
            warmup_steps, total_steps: linear warm-up then cosine to zero at total_steps
                (None: the Trainer's estimated number of optimiser steps).
            val_gap_s: the full-skeleton gap logged every validation, XMAE beside Lerp and the cubic
                spline (val/gap<s>s_mpjpe_mm/<fill>), and XMAE's over the spline's (val/gap_vs_spline).
            eval_gaps_s, eval_noise_sigmas_m: the `test` tables.
            calibration_windows: val windows (the first ones) on which every validation measures
                XMAE against the classical fills per hole length and part (left limbs), and XMAE's
                disagreement with clean tokens: the fill policy saved in each checkpoint
                (fills/policy.py). 0: no policy.
            calibrate_every_n_val: which of fit's validations measure the fill policy: every one
                (1), every N-th, or none (0). It is a validation's largest cost (about 16 network
                passes over those windows: minutes per validation for the paper's network on a CPU,
                docs/training.md). Whatever the validations did, when training ends each of the
                run's final checkpoints (best and last) whose policy was not measured for its own
                weights gets one, measured as a validation would (training/final_policy.py);
                checkpoints written in between carry the last policy measured (or none). `validate`
                always measures.
            init_weights: a checkpoint file or a shipped model's name (`mocapfix models`) whose
                network training starts from: its sizes and weights (every size setting above is
                then the checkpoint's) and its fill policy until a validation (or, where
                calibrate_every_n_val skips them, the end of training) measures one. For
                fine-tuning on your own takes (`mocapfix adapt`); the data must give the
                checkpoint's joints and window (data.body body21 for the shipped models).
            skeleton, window_fps, window_frames: filled in from the data module at setup; saved in checkpoints.
        """
        super().__init__()
        if compile_mode not in COMPILE_MODES:
            raise ValueError(f"compile_mode must be one of {COMPILE_MODES}, got {compile_mode!r}")
        check_training_corruption(mask_ratio, displace_ratio, clean_loss_ratio, max_displacement_m)
        if not 0.0 <= hole_ratio <= 1.0 or max_hole_s <= 0:
            raise ValueError(
                f"hole_ratio must be in [0, 1] (a fraction of the windows) and max_hole_s > 0 (seconds), "
                f"got {hole_ratio} and {max_hole_s}"
            )
        BodyAugment(stature_range, limb_range, mirror_prob, joint_shift_m).check()
        if calibrate_every_n_val < 0:
            raise ValueError(
                f"calibrate_every_n_val: 0 (none of fit's validations) or more, got {calibrate_every_n_val}"
            )
        # the network's sizes (num_joints and num_frames come from the data, at setup)
        self.sizes = preset_sizes(
            preset,
            enc_dim=enc_dim,
            enc_depth=enc_depth,
            enc_mlp_dim=enc_mlp_dim,
            dec_dim=dec_dim,
            dec_depth=dec_depth,
            dec_mlp_dim=dec_mlp_dim,
            head_dim=head_dim,
            decoder=decoder,
            position_unit_m=position_unit_m,
            fill_input=fill_input,
            fill_kind=fill_kind,
        )
        self._init_state: dict | None = None
        self.fill_policy: FillPolicy | None = None  # from the last validation, or the checkpoint
        if init_weights:
            start = _starting_checkpoint(init_weights)
            config = dict(xmae_config(init_weights, start))
            self.sizes = {k: v for k, v in config.items() if k not in ("num_joints", "num_frames")}
            self._init_state = network_weights(start, "net")
            self._init_window = {k: hyperparameters(start)[k] for k in ("skeleton", "window_fps", "window_frames")}
            if fill_policy_values(start) is not None:
                self.fill_policy = FillPolicy.from_dict(fill_policy_values(start))
        self.save_hyperparameters()
        self.net: XMAE | None = None
        self._calibration: Calibration | None = None  # the running validation's measurements
        self._fit_validations = 0  # fit's validations so far (sanity checks not counted)
        self._gap_pass = (0.0, 0, 0.0)
        self.policy_steps: set[int] = set()  # the global steps whose weights the fill policy was measured for
        if skeleton is not None and window_frames is not None:  # a checkpoint's own weights follow
            self._build()
            self._init_state = None

    # --- construction ---

    @property
    def skeleton(self) -> Skeleton:
        return Skeleton.from_dict(self.hparams.skeleton)

    def tracked_hparams(self) -> dict:
        """The settings a run is compared by (training/tracking.py): the network's sizes as the
        preset (or init_weights) resolves them, not the overrides left None."""
        return {**self.hparams, **self.sizes}

    def _build(self) -> None:
        hp = self.hparams
        self.net = build_model("xmae", XMAEConfig(len(hp.skeleton["parents"]), hp.window_frames, **self.sizes))
        if hp.get("compile_model"):
            # in place: parameter names (and so checkpoints) stay as without it
            self.net.compile(mode=hp.get("compile_mode", "default"))
        # hp.get: checkpoints from before the body augmentations have none
        names = ("stature_range", "limb_range", "mirror_prob", "joint_shift_m")
        augment = BodyAugment(*(hp.get(k, 0.0) for k in names))
        self.body_augment = BodyAugmenter(self.skeleton, augment) if augment.active else None
        # the parts training_holes takes out, (P, J) bool: each limb, and the whole body as often
        # as all limbs together (the longest holes of the whole body are where fills differ most)
        skeleton, num_joints = self.skeleton, len(hp.skeleton["parents"])
        limbs = [skeleton.groups[g] for g in GROUP_NAMES if g in skeleton.groups]
        parts = [range(num_joints)] * max(1, len(limbs)) + limbs
        part_joints = torch.zeros(len(parts), num_joints, dtype=torch.bool)
        for row, joints in enumerate(parts):
            part_joints[row, list(joints)] = True
        self.register_buffer("part_joints", part_joints, persistent=False)
        self.val_mpjpe = MPJPE()
        self.val_gap = nn.ModuleDict({"xmae": MPJPE(), "lerp": MPJPE(), "spline": MPJPE()})

    def configure_callbacks(self):
        return [BindData(), FinalFillPolicy()]

    def bind_data(self, data: DataSpec, stage: str) -> None:
        """The network for the data's skeleton and window (BindData calls it before setup); a
        network from a checkpoint must fit the data."""
        skeleton, fps, frames = data.skeleton.to_dict(), data.fps, data.window_frames
        if self.net is None:
            if self._init_state is not None:
                require_same_window(self._init_window, data, f"{self.hparams.init_weights} was built for")
            self.hparams.update(skeleton=skeleton, window_fps=fps, window_frames=frames)
            self._build()
            if self._init_state is not None:
                self.net.load_state_dict({k: v.float() for k, v in self._init_state.items()})
                self._init_state = None
        else:
            require_same_window(self.hparams, data, "this model was built for")

    def _reconstruct(self, positions: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
        return xmae_reconstruct(self.net, positions, observed)

    def setup(self, stage: str) -> None:
        if self.net is None:
            raise RuntimeError("XMAEModule needs a data module (or a checkpoint) to know the skeleton and window")

    def configure_optimizers(self):
        hp = self.hparams
        # fused: one kernel for the whole update on GPU instead of a few per parameter tensor
        # (a checkpoint saved with it resumes on the CPU too: torch has a fused CPU Adam)
        opt = torch.optim.Adam(self.parameters(), lr=hp.lr, betas=tuple(hp.betas), fused=self.device.type == "cuda")
        total = hp.total_steps or int(self.trainer.estimated_stepping_batches)
        sched = torch.optim.lr_scheduler.LambdaLR(opt, WarmupCosine(hp.warmup_steps, total))
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}

    # --- training ---

    def _corrupt_and_predict(self, positions: torch.Tensor, generator: torch.Generator | None = None):
        """The training objective on a batch. positions: (B, T, J, 3) metres, NaN = missing in the data.
        Returns loss, prediction and target (both normalised), and the corruption."""
        hp = self.hparams
        B, T, J, _ = positions.shape
        x, target, c, offset, kept, padding = xmae_training_input(
            positions,
            hp.mask_ratio,
            hp.displace_ratio,
            hp.max_displacement_m,
            hp.fixed_kept_count,
            hp.rotate_augment and self.training,
            generator,
            hp.gap_ratio if self.training else 0.0,
            hp.get("hole_ratio", 0.0),  # checkpoints from before it have none
            self.part_joints,
            max(1, round(hp.get("max_hole_s", 1.0) * hp.window_fps)),
        )
        fill = xmae_fill(x.reshape(B, T, J, 3), c.observed, self.net.fill_kind) if self.net.fill_input else None
        pred = self.net(x, kept, padding, fill).reshape(B, T, J, 3)
        has_truth = ~torch.isnan(target).any(-1)
        in_loss = (~c.observed | c.displaced) & has_truth
        if hp.clean_loss_ratio > 0:  # BERT masking: some clean observed tokens are scored too
            clean = c.observed & ~c.displaced
            p = hp.clean_loss_ratio / (1 - hp.mask_ratio - hp.displace_ratio)
            in_loss |= clean & (uniform_like(clean.shape, generator, clean) < p)  # the val generator too
        err = (pred.float() - torch.nan_to_num(target).float()).abs().sum(-1)  # (B, T, J)
        loss = (err * in_loss).sum() / (3 * in_loss.sum().clamp_min(1))
        return loss, pred, target, c, in_loss, offset

    def training_step(self, batch, batch_idx):
        if self.hparams.get("compile_model") and self.hparams.get("compile_mode") in CUDA_GRAPH_MODES:
            # each step's graph outputs may overwrite the last step's: tell the graph trees a new step began
            torch.compiler.cudagraph_mark_step_begin()
        positions = batch["positions"]
        if self.body_augment is not None:
            positions = self.body_augment(positions)
        loss, *_ = self._corrupt_and_predict(positions)
        self.log("train/loss", loss, prog_bar=True)
        return loss

    # --- validation ---

    def _generator(self, batch_idx: int) -> torch.Generator:  # validation: one per batch
        # CPU generator: the same corruption on any device and precision (see corruption.py).
        return torch.Generator().manual_seed(self.hparams.eval_seed * 100_003 + batch_idx)

    def validation_step(self, batch, batch_idx):
        positions = batch["positions"]
        loss, pred, target, c, in_loss, offset = self._corrupt_and_predict(positions, self._generator(batch_idx))
        self.log("val/loss", loss, prog_bar=True, batch_size=len(positions), sync_dist=True)  # every process's
        self.val_mpjpe(pred.float(), target.float(), in_loss)
        self.log("val/mpjpe_mm", self.val_mpjpe, prog_bar=True)

        start = time.perf_counter()
        task = Task("infill", "full", gap_s=self.hparams.val_gap_s)
        gap = task.corrupt(positions, self.hparams.window_fps, self.skeleton, None)
        scored = task.evaluated(gap, positions)
        xmae = xmae_reconstruct(self.net, gap.positions, gap.observed)
        self.val_gap["xmae"](xmae.float(), positions.float(), scored)
        self.val_gap["lerp"](lerp_infill(gap.positions, gap.observed).float(), positions.float(), scored)
        self.val_gap["spline"](spline_infill(gap.positions, gap.observed).float(), positions.float(), scored)
        seconds, windows, read = self._gap_pass
        read += float(gap.observed.float().mean((1, 2)).sum())  # the tokens the network read, per window
        self._gap_pass = (seconds + time.perf_counter() - start, windows + len(positions), read)
        for name, metric in self.val_gap.items():
            self.log(f"val/gap{self.hparams.val_gap_s}s_mpjpe_mm/{name}", metric)
        if batch_idx == 0:
            self._figure_sample = (positions, gap.positions, gap.observed, xmae)
        if self._calibration is not None:
            self._calibrate(positions, batch_idx)

    # --- the fill policy (fills/policy.py) ---

    def _calibrate(self, positions: torch.Tensor, batch_idx: int) -> None:
        """The running measurement of the fill policy, on this batch's windows up to calibration_windows."""
        hp = self.hparams
        room = hp.calibration_windows - self._calibration.windows
        if room > 0:
            calibrate(
                self._calibration,
                self._reconstruct,
                positions[:room],
                self.skeleton,
                hp.window_fps,
                hp.eval_gaps_s,
                self._generator(batch_idx),
            )

    def measure_fill_policy(self, batches) -> FillPolicy | None:
        """The fill policy of the network's present weights, measured as a validation measures it:
        on the first calibration_windows windows of batches (the val split's, in order), with the
        same corruption. None: no policy (calibration_windows 0, or no windows)."""
        hp = self.hparams
        if hp.get("calibration_windows", 0) <= 0:
            return None
        self._calibration = Calibration(hp.eval_gaps_s)
        try:
            for batch_idx, batch in enumerate(batches):
                if self._calibration.windows >= hp.calibration_windows:
                    break
                self._calibrate(batch["positions"].to(self.device), batch_idx)
            return self._calibration.compute()
        finally:
            self._calibration = None

    def fill_policy_seconds(self, windows: int) -> float | None:
        """About how long measure_fill_policy takes on `windows` windows: per window, it runs the
        network on the clean window and on one hole per part and length (3 x eval_gaps_s), beside
        the classical fills; the last validation timed such a pass over its windows (the network,
        Lerp and the spline on its val_gap_s hole), taken here in proportion to the tokens the
        network reads. None: no validation timed one yet. On a GPU, whose work the clock does not
        wait for, less than it will take."""
        seconds, seen, read = self._gap_pass
        if not seen or read <= 0:
            return None
        hp, skeleton = self.hparams, self.skeleton
        J, T = len(hp.skeleton["parents"]), hp.window_frames
        reads = 1.0  # the clean windows, whole
        for t in paper_tasks(skeleton, hp.eval_gaps_s, ()):
            if t.task == "infill" and not t.part.startswith("right"):  # as calibrate
                joints = J if t.part == "full" else len(skeleton.groups[t.part])
                reads += 1 - joints / J * min(T, round(t.gap_s * hp.window_fps)) / T
        return seconds / read * reads * windows

    def on_validation_epoch_start(self):
        hp = self.hparams
        self._gap_pass = (0.0, 0, 0.0)  # this validation's gap pass, seconds, windows, tokens read: fill_policy_seconds
        measure = hp.get("calibration_windows", 0) > 0 and not self.trainer.sanity_checking
        if measure and self.trainer.state.fn == "fit":  # validate always measures
            self._fit_validations += 1
            every = hp.get("calibrate_every_n_val", 1)  # checkpoints from before it have none
            measure = every > 0 and self._fit_validations % every == 0
        self._calibration = Calibration(hp.eval_gaps_s) if measure else None

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        if self.net is not None:
            name_model(checkpoint, "xmae", self.net.config)
        if self.fill_policy is not None:
            set_fill_policy(checkpoint, self.fill_policy.to_dict())

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        if fill_policy_values(checkpoint) is not None:
            self.fill_policy = FillPolicy.from_dict(fill_policy_values(checkpoint))

    def on_validation_epoch_end(self):
        hp = self.hparams
        if self.trainer.sanity_checking:
            return
        policy = self._calibration.compute() if self._calibration is not None else None
        if policy is not None:
            self.fill_policy = policy
            self.policy_steps.add(self.global_step)
        if self.val_gap["spline"].update_called:  # the run's summary (training/tracking.py) keeps the best's
            ratio = self.val_gap["xmae"].compute() / self.val_gap["spline"].compute()
            self.log("val/gap_vs_spline", ratio, sync_dist=True)  # the same on every process (synced metrics)
        sample = getattr(self, "_figure_sample", None)
        if sample is not None:
            truth, given, observed, output = sample
            log_validation_figure(
                self,
                "val/infill_example",
                truth,
                given,
                observed,
                output,
                f"full-skeleton {hp.val_gap_s} s gap, step {self.global_step}",
            )

    # --- test: the paper's tables ---

    def on_test_epoch_start(self):
        # "policy": what fix outputs (the fill policy of this checkpoint's validation)
        self._methods = ("xmae", *CLASSICAL) + (("policy",) if self.fill_policy is not None else ())
        self._tasks = paper_tasks(self.skeleton, self.hparams.eval_gaps_s, self.hparams.eval_noise_sigmas_m)
        self._table = mpjpe_table([t.key for t in self._tasks], self._methods).to(self.device)

    def test_step(self, batch, batch_idx):
        positions = batch["positions"]
        for k, t in enumerate(self._tasks):
            seeds = window_seeds(batch, batch_idx, k, self.hparams.eval_seed)
            c = t.corrupt_windows(positions, self.hparams.window_fps, self.skeleton, seeds)
            scored = t.evaluated(c, positions)
            # the classical fills fill the missing tokens and leave the observed ones as given
            preds = candidate_fills(self._reconstruct, c.positions, c.observed, self.skeleton)
            fps, policy = self.hparams.window_fps, self.fill_policy
            if policy is not None and t.task == "infill":  # fix --mode infill
                preds["policy"] = apply_fill_policy(policy, c.positions, c.observed, preds, fps, self.skeleton)[0]
            elif policy is not None:  # fix --mode both
                preds["policy"] = policy_output(
                    policy, self._reconstruct, c.positions, c.observed, preds, fps, self.skeleton
                )
            for m, pred in preds.items():
                for rel in ("abs", "rel"):
                    self._table.update((t.key, m, rel), pred.float(), positions.float(), scored)

    def on_test_epoch_end(self):
        cells = self._table.compute()
        results = abs_and_rel(cells)
        self.eval_rows = table_rows(results, self._tasks)
        scalars = {}
        for r in self.eval_rows:
            param = f"gap{r['gap_s']}s" if "gap_s" in r else f"sigma{r['sigma_m']}m"
            scalars[f"test/{r['task']}/{r['part']}/{param}/{r['method']}_mpjpe_mm"] = r["mpjpe_mm"]
        text = format_table(self.eval_rows)
        if self.fill_policy is not None:
            text += "\nfill policy (val split):\n  " + "\n  ".join(self.fill_policy.describe())
        self.eval_json_path = publish(self, self.eval_rows, scalars, text)

    # --- predict ---

    def predict_step(self, batch, batch_idx):
        """Windows with NaN where joints are missing -> completed windows (B, T, J, 3), metres.
        Observed tokens keep their given values; XMAE fills the missing ones."""
        positions = batch["positions"]
        observed = ~torch.isnan(positions).any(-1)
        out = xmae_reconstruct(self.net, positions, observed)
        return torch.where(observed[..., None], positions, out)


def _starting_checkpoint(name_or_path: str) -> dict:
    """init_weights: a checkpoint file, or a shipped model by name -> the checkpoint, which must
    hold an XMAE. Read with weights_only (plain values): a checkpoint runs no code."""
    from pathlib import Path

    from mocapfix.models.checkpoint import named_kind, read_checkpoint
    from mocapfix.pretrained import MODELS, pretrained_path

    path = pretrained_path(name_or_path) if name_or_path in MODELS and not Path(name_or_path).exists() else name_or_path
    ckpt = read_checkpoint(path)
    if named_kind(ckpt) != "xmae":
        raise ValueError(f"model.init_weights {name_or_path}: not an XMAE checkpoint")
    return ckpt
