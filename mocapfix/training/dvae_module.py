"""MotionDVAEModule: training the Motion-DVAE motion prior on clean motion (paper section 3, appendix A).

Loss per window (sums over frames t = 1..T and coordinates, mean over the batch), appendix A.3:
  rec = sum_t ||mu_theta_x(z_1:t, x_0) - x_t||^2       on the standardised state (-log N(x_t; mu, Id) + const, x2)
  kl  = sum_t KL(q_phi(z_t | z_<t, x_t:T, x_0) || p_theta(z_t | z_<t, x_0))
  reg = sum_t ||M(mu_theta_x(z_1:t, x_0)) - M(x_t)||^2  metres, joints (+ markers when the body has a mesh)
  loss = rec + w(step) * kl + reg_weight * reg,  w rising linearly from 0 to kl_weight (KL annealing).
The state is standardised per dimension with training-set statistics (as HuMoR, whose training
recipe the paper follows): raw velocities in rad/s would otherwise outweigh everything else.
The networks are built in setup() from the data module's skeleton and window, stored as plain
hyperparameters so a checkpoint alone rebuilds them (the denoising stage loads it that way).
"""

from __future__ import annotations

from typing import NamedTuple

import lightning as L
import torch

from mocapfix.core.skeleton import Skeleton
from mocapfix.data.spec import DataSpec
from mocapfix.data.windows import complete_windows, select, spread_complete_batches
from mocapfix.evaluation.metrics import MPJPE
from mocapfix.models.body import build_body_model
from mocapfix.models.build import build_model
from mocapfix.models.checkpoint import name_model
from mocapfix.models.dvae import DVAEConfig, MotionDVAE, gaussian_kl
from mocapfix.models.dvae_state import MotionState, mean_joint_rotations
from mocapfix.training.bind_data import BindData, require_same_window
from mocapfix.training.figures import log_validation_figure
from mocapfix.training.schedules import anneal_steps_of, kl_anneal_weight
from mocapfix.training.test_report import publish

STD_FLOOR = 0.05  # dimensions the data never moves (a joint axis the synthetic body never turns) stay finite


def compile_in_place(net: torch.nn.Module, body: torch.nn.Module | None) -> None:
    """torch.compile the networks and the body model (FK's joint walk sits in the regulariser,
    forward and backward) in place: the state dict keeps its names, so checkpoints are the same."""
    net.compile()
    if body is not None:
        body.compile()


def require_complete_windows(data: DataSpec, stage: str) -> None:
    """The DVAE has no notion of a missing joint: it learns from and is scored on complete windows
    only. A split with windows but none complete would train or score nothing (no val/loss for
    the checkpoint to monitor, NaN test tables): say so before the loop starts."""
    for split in {"fit": ("train", "val"), "validate": ("val",), "test": ("test",)}.get(stage, ()):
        if len(data.windows[split]) and not data.complete_windows(split):
            raise ValueError(
                f"data: none of the {split} split's {len(data.windows[split])} windows is complete "
                "(every one misses a joint somewhere); Motion-DVAE learns from and is scored on "
                "complete windows: drop the joints that are always missing (data.drop_joints) or "
                "choose other files for this split"
            )


@torch.no_grad()
def state_statistics(codec: MotionState, dataset, max_windows: int = 4096) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-dimension mean and std (D,) of the state over up to max_windows evenly spread windows."""
    xs = [
        codec.encode(b["positions"], b.get("rotations"), b.get("root_translation"))[0].flatten(0, 1)
        for b in spread_complete_batches(dataset, max_windows)
    ]
    if not xs:
        raise ValueError("no complete training window to standardise the state with")
    x = torch.cat(xs)
    return x.mean(0), x.std(0).clamp_min(STD_FLOOR)


@torch.no_grad()
def mean_rotations(dataset, max_windows: int = 4096) -> torch.Tensor:
    """(J-1, 3, 3) the body joints' mean rotations over up to max_windows evenly spread windows."""
    rots = [b["rotations"].flatten(0, 1) for b in spread_complete_batches(dataset, max_windows)]  # (B T, J, 3) each
    if not rots:
        raise ValueError("no complete training window to take the mean pose from")
    return mean_joint_rotations(torch.cat(rots))


class ELBOTerms(NamedTuple):
    rec: torch.Tensor
    kl: torch.Tensor
    reg: torch.Tensor


class MotionDVAEModule(L.LightningModule):
    def __init__(
        self,
        state: str = "rotations",
        latent_dim: int = 48,
        lstm_hidden: int = 1024,
        mlp_hidden: int = 1024,
        norm_groups: int = 16,
        body_model: str = "skeleton",
        body_model_path: str | None = None,
        gender: str = "neutral",
        model_type: str = "smplh",
        markers: list[int] | None = None,
        reg_weight: float = 1.0,
        kl_weight: float = 1.0,
        normalize: bool = True,
        encoder_velocities: bool = False,
        rotation_reference: str = "mean",
        optimizer: str = "adamax",
        lr: float = 1e-4,
        betas: tuple[float, float] = (0.9, 0.999),
        lr_milestones: list[int] | None = None,
        lr_decay: float = 0.5,
        kl_anneal_epochs: float = 50.0,
        kl_anneal_steps: int | None = None,
        figure_every_n_val: int = 1,
        compile_model: bool = False,
        skeleton: dict | None = None,
        window_fps: float | None = None,
        window_frames: int | None = None,
    ):
        """
        Args:
            state: "rotations" (the paper's state, needs data.with_rotations) or "positions"
                (joint positions and velocities, M = identity: any data the data module reads).
            latent_dim, lstm_hidden: 48 and 1024 (paper A.1). mlp_hidden: width of the 2 hidden
                layers of every MLP (not given by the paper). norm_groups: GroupNorm groups (16).
            body_model: "skeleton" (FK with the clip's bone offsets) or "smpl" (SMPL / SMPL-H from
                body_model_path, gender, model_type; marker vertices `markers`, None = the paper's 43).
            reg_weight: weight of the body-model regulariser (1 in the paper).
            kl_weight: the KL weight annealing ends at (1: the ELBO).
            normalize: standardise the state with training-set statistics (saved in the checkpoint).
            encoder_velocities: the encoder also reads the state's velocity entries (False: poses
                only; velocities of noisy observations are amplified noise, see MotionDVAE).
            rotation_reference: what the rotations state measures joint rotations from: "mean"
                (the training data's mean pose, set at the start of fit and saved in the
                checkpoint) or "identity" (the skeleton's zero pose, the paper's axis-angle; fine
                for SMPL's T-pose, not for a BVH whose zero pose puts joints near half a turn:
                see MotionState).
            optimizer: "adamax" (the paper's: HuMoR's settings, lr 1e-4) or "adam". On Bandai at
                paper width, Adam at lr 1e-4 takes the prior much further in a few hundred steps
                (the session diary (CHANGELOG.md), session 4), which is what a time-limited run needs.
            lr, betas: the optimiser's (1e-4: HuMoR's, which the paper follows; 1e-3 is unstable
                at width 1024). lr_milestones: optimiser steps where lr is multiplied by lr_decay.
            kl_anneal_epochs / kl_anneal_steps: linear KL annealing length (steps win when given).
            compile_model: torch.compile the networks. A training step is hundreds of small kernels
                (the encoder's latent recursion walks the frames one by one), so on a GPU it is
                bound by launches, not arithmetic; compiling fuses them. The nn.LSTM layers stay
                eager (dynamo does not trace them) and keep their cuDNN kernels. Parameter names,
                and so checkpoints, are the same with or without it.
            skeleton, window_fps, window_frames: filled in from the data module at setup; saved in checkpoints.
        """
        if optimizer not in ("adamax", "adam"):
            raise ValueError(f"optimizer must be 'adamax' or 'adam', got {optimizer!r}")
        if rotation_reference not in ("mean", "identity"):
            raise ValueError(f"rotation_reference must be 'mean' or 'identity', got {rotation_reference!r}")
        if norm_groups < 1 or mlp_hidden % norm_groups:
            raise ValueError(
                f"mlp_hidden ({mlp_hidden}) must be a multiple of norm_groups ({norm_groups}): "
                "the MLPs' GroupNorm splits their hidden units into that many groups"
            )
        super().__init__()
        self.save_hyperparameters()
        self.net: MotionDVAE | None = None
        self._anneal_steps = 0
        if skeleton is not None and window_frames is not None:
            self._build()

    # --- construction ---

    @property
    def skeleton(self) -> Skeleton:
        return Skeleton.from_dict(self.hparams.skeleton)

    def _build(self) -> None:
        hp = self.hparams
        skel = self.skeleton
        self.body = (
            build_body_model(hp.body_model, skel.parents, hp.body_model_path, hp.gender, hp.model_type, hp.markers)
            if hp.state == "rotations"
            else None
        )
        self.codec = MotionState(hp.state, skel.parents, skel.groups, hp.window_fps, self.body)
        self.model_config = DVAEConfig(
            hp.state,
            skel.num_joints,
            hp.latent_dim,
            hp.lstm_hidden,
            hp.mlp_hidden,
            hp.norm_groups,
            hp.get("encoder_velocities", False),
        )
        self.net = build_model("motion-dvae-prior", self.model_config)
        if hp.get("compile_model"):
            compile_in_place(self.net, self.body)
        self.val_mpjpe, self.test_mpjpe = MPJPE(), MPJPE()

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        if self.net is not None:
            name_model(checkpoint, "motion-dvae-prior", self.model_config)

    def configure_callbacks(self):
        return [BindData()]

    def bind_data(self, data: DataSpec, stage: str) -> None:
        """The networks for the data's skeleton and window, and at fit the state's reference pose
        and statistics from the training windows (BindData calls it before setup); networks from
        a checkpoint must fit the data."""
        if self.hparams.state == "rotations" and not data.rotations:
            raise ValueError(
                "model.state rotations needs rotation data: set data.with_rotations: true "
                f"(bvh, amass, synthetic sources; {data.source} data here), or model.state: positions"
            )
        require_complete_windows(data, stage)
        skeleton, fps, frames = data.skeleton.to_dict(), data.fps, data.window_frames
        if self.net is None:
            self.hparams.update(skeleton=skeleton, window_fps=fps, window_frames=frames)
            self._build()
            if stage == "fit" and self.hparams.state == "rotations" and self.hparams.rotation_reference == "mean":
                self.codec.joint_reference.copy_(mean_rotations(data.windows["train"]))
            if stage == "fit" and self.hparams.normalize:  # a resumed run then loads the same values back
                mean, std = state_statistics(self.codec, data.windows["train"])
                self.net.x_mean.copy_(mean)
                self.net.x_std.copy_(std)
        else:
            require_same_window(self.hparams, data, "this model was built for")

    def setup(self, stage: str) -> None:
        if self.net is None:
            raise RuntimeError("MotionDVAEModule needs a data module (or a checkpoint) to know the skeleton and window")

    def configure_optimizers(self):
        hp = self.hparams
        if hp.optimizer == "adam":  # fused: one kernel for the update on a GPU (as XMAE's)
            opt = torch.optim.Adam(self.parameters(), lr=hp.lr, betas=tuple(hp.betas), fused=self.device.type == "cuda")
        else:
            opt = torch.optim.Adamax(self.parameters(), lr=hp.lr, betas=tuple(hp.betas))
        sched = torch.optim.lr_scheduler.MultiStepLR(opt, list(hp.lr_milestones or []), gamma=hp.lr_decay)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}

    # --- the objective ---

    def encode_batch(self, batch: dict) -> tuple[torch.Tensor, torch.Tensor | None]:
        """A batch of clean windows -> state x (B, T+1, D) in each window's canonical frame, body shape."""
        x, _ = self.codec.encode(batch["positions"], batch.get("rotations"), batch.get("root_translation"))
        return x, self.codec.shape(batch.get("offsets"))

    def elbo_terms(self, x: torch.Tensor, shape: torch.Tensor | None, sample: bool = True):
        """x (B, T+1, D) raw state -> ELBOTerms (per-window sums, batch means), the decoded states
        x_hat (B, T, D) in raw units, and the network output (standardised).
        sample=False runs the posterior-mean path (z_t = mu_t): deterministic validation."""
        xn = self.net.normalize(x.float())
        out = self.net(xn[:, 0], xn[:, 1:], sample)
        rec = ((out.x_hat.float() - xn[:, 1:]) ** 2).sum((1, 2)).mean()
        kl = (
            gaussian_kl(out.q_mu.float(), out.q_logvar.float(), out.p_mu.float(), out.p_logvar.float())
            .sum((1, 2))
            .mean()
        )
        x_hat = self.net.denormalize(out.x_hat.float())
        # decoded and true states through the body model in one call: half the kernels of two
        pts = self.codec.points(
            torch.cat([x_hat, x[:, 1:].float()]), None if shape is None else torch.cat([shape, shape])
        )
        pred_pts, true_pts = pts.points().chunk(2)
        reg = ((pred_pts - true_pts) ** 2).sum((1, 2, 3)).mean()
        return ELBOTerms(rec, kl, reg), x_hat, out

    def reconstruct(self, batch: dict) -> tuple[ELBOTerms, torch.Tensor, torch.Tensor]:
        """Clean windows -> the ELBO terms on the posterior-mean path, the true joints and their
        reconstruction (B, T+1, J, 3), canonical frame; frame 0 of the reconstruction is the given x_0."""
        x, shape = self.encode_batch(batch)
        terms, x_hat, _ = self.elbo_terms(x, shape, sample=False)
        truth = self.codec.points(x.float(), shape).joints
        return terms, truth, torch.cat([truth[:, :1], self.codec.points(x_hat, shape).joints], dim=1)

    def current_kl_weight(self) -> float:
        return self.hparams.kl_weight * kl_anneal_weight(self.global_step, self._anneal_steps)

    def on_train_start(self) -> None:
        self._anneal_steps = anneal_steps_of(self.trainer, self.hparams.kl_anneal_steps, self.hparams.kl_anneal_epochs)

    def training_step(self, batch, batch_idx):
        keep = complete_windows(batch)
        if not keep.any():
            return None  # nothing to learn from: Lightning skips the step
        x, shape = self.encode_batch(select(batch, keep))
        terms, _, _ = self.elbo_terms(x, shape)
        w = self.current_kl_weight()
        loss = terms.rec + w * terms.kl + self.hparams.reg_weight * terms.reg
        B = len(x)
        self.log("train/loss", loss, prog_bar=True, batch_size=B)
        self.log_dict({"train/rec": terms.rec, "train/kl": terms.kl, "train/reg": terms.reg}, batch_size=B)
        self.log("train/kl_weight", w, batch_size=B)
        return loss

    # --- validation / test: the objective at the end of annealing, and the MPJPE of reconstructions ---

    def _evaluate(self, batch, stage: str):
        keep = complete_windows(batch)
        if not keep.any():
            return None
        batch = select(batch, keep)
        terms, truth, recon = self.reconstruct(batch)
        loss = terms.rec + self.hparams.kl_weight * terms.kl + self.hparams.reg_weight * terms.reg
        B = len(truth)
        self.log(f"{stage}/loss", loss, prog_bar=True, batch_size=B, sync_dist=True)  # every process's windows
        self.log_dict({f"{stage}/rec": terms.rec, f"{stage}/kl": terms.kl, f"{stage}/reg": terms.reg}, batch_size=B)
        metric = self.val_mpjpe if stage == "val" else self.test_mpjpe
        metric(recon[:, 1:], truth[:, 1:])
        self.log(f"{stage}/mpjpe_mm", metric, prog_bar=True, batch_size=B)
        return truth, recon

    def validation_step(self, batch, batch_idx):
        res = self._evaluate(batch, "val")
        if res is not None and batch_idx == 0:
            self._figure_sample = res

    def test_step(self, batch, batch_idx):
        self._evaluate(batch, "test")

    def on_test_epoch_end(self):
        # The prior's own test: how well it reconstructs clean windows (the floor of the
        # denoising stage's MPJPE), in eval.json as XMAE's and the denoiser's tables are.
        if not self.test_mpjpe.update_called:
            return
        mpjpe = round(float(self.test_mpjpe.compute()), 2)
        rows = [{"task": "reconstruction", "part": "full", "method": "dvae_prior", "mpjpe_mm": mpjpe}]
        self.eval_json_path = publish(self, rows, {"test/reconstruction_mpjpe_mm": mpjpe})

    def predict_step(self, batch, batch_idx):
        raise ValueError(
            "a Motion-DVAE prior checkpoint models clean motion and does not denoise: predict "
            "(or fix) with its denoising stage's checkpoint (configs/motion_dvae_denoise*.yaml)"
        )

    def on_validation_epoch_end(self):
        if self.trainer.sanity_checking:
            return
        sample = getattr(self, "_figure_sample", None)
        if sample is not None:
            truth, recon = sample
            log_validation_figure(
                self,
                "val/reconstruction_example",
                truth,
                truth,
                None,
                recon,
                f"Motion-DVAE reconstruction, step {self.global_step}",
            )
