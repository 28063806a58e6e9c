"""DVAEDenoiseModule: unsupervised learned denoising with a trained Motion-DVAE (paper section 4).

Starts from a prior checkpoint (MotionDVAEModule), freezes its prior and decoder (the generative
model), and trains the encoder q_phi, an initial-state predictor q_omega(x_0 | y) and a noise
predictor q_gamma(v_t | z_1:t, y_t, x_0) on NOISY windows only. The clean window is used to make
the noise and, at validation and test, to score; it never enters the loss: every loss input
comes from observation(), which reads the noisy keys of the batch and nothing else.

Negative ELBO per window (eq. 12-15; sums over t, observed points j and axes d; batch mean), with
s = obs_scale_m, y / m the observed / predicted 3D points in units of s, v ~ IG(alpha, beta):
  data  = 1/2 sum_{t=0..T} [E[1/v] (y - m)^2 + E[log v]],  E[1/v] = alpha/beta, E[log v] = log beta - digamma(alpha)
          m_0 = M(x_0), m_t = M(mu_theta_x(x_0, z_1:t))
  kl_z  = sum_{t=1..T} KL(q_phi(z_t | z_<t, y_t:T, x_0) || p_theta(z_t | z_<t, x_0))     (annealed like the prior)
  kl_v  = sum_{t=0..T} KL(IG(alpha, beta) || IG(lambda/2, lambda/2))
The entropy of q_omega is left out as the paper does (C.2.2); E[log v] is kept (eq. 13 drops
it), without it nothing but the prior stops v from growing. The paper's denoising experiment takes
"very high" lambda (a Gaussian noise model); from lambda >= 1e4 (dvae_inference.GAUSSIAN_LAMBDA)
that limit is taken exactly: v = 1, data = 1/2 sum (y - m)^2, kl_v = 0, the noise predictor idle.

test: for each noise level, the noisy input, regression mode (one forward pass) and optimisation
mode (opt_iterations ELBO steps on the test batch, then the forward pass), scored by MPJPE and
joint acceleration against the clean windows, with seconds per frame.
Lightning runs `test` under torch.inference_mode, where no gradient can be taken: the denoise
configs set trainer.inference_mode: false; the optimisation loop also leaves inference mode itself.
"""

from __future__ import annotations

import contextvars
import math
import time
from pathlib import Path

import lightning as L
import torch
import torch.nn as nn

from mocapfix.core.skeleton import Skeleton
from mocapfix.data.corruption import gaussian_noise, rotation_noise
from mocapfix.data.spec import DataSpec
from mocapfix.data.windows import complete_windows, select
from mocapfix.evaluation.denoise_table import SMOOTH_FRAMES, SMOOTHERS, DenoiseTable, format_denoise_table
from mocapfix.evaluation.metrics import MPJPE
from mocapfix.evaluation.tasks import window_seeds
from mocapfix.fills.classical import gaussian_smooth
from mocapfix.models.checkpoint import name_model
from mocapfix.models.dvae import InitialStatePredictor, NoisePredictor, gaussian_kl, inverse_gamma_kl

# the posterior pass is shared with `mocapfix fix`, which must not import training code
from mocapfix.models.dvae_inference import (
    FIRST_FRAMES,
    Inference,
    Observation,
    gaussian_limit,
    infer_posterior,
    point_estimate,
    uses_noise_model,
)
from mocapfix.models.dvae_state import velocity_mask
from mocapfix.training.bind_data import BindData, require_same_window
from mocapfix.training.dvae_module import MotionDVAEModule, compile_in_place, require_complete_windows
from mocapfix.training.figures import log_validation_figure
from mocapfix.training.schedules import anneal_steps_of, kl_anneal_weight
from mocapfix.training.test_report import publish


class DVAEDenoiseModule(L.LightningModule):
    def __init__(
        self,
        prior_ckpt: str | None = None,
        noise: str = "rotation",
        train_sigmas: tuple[float, ...] = (0.1, 0.15, 0.2),
        val_sigma: float = 0.15,
        test_sigmas: tuple[float, ...] = (0.1, 0.15, 0.2),
        noise_lambda: float = 1e6,
        obs_scale_m: float = 0.05,
        estimate: str = "auto",
        first_frame: str = "decoded",
        lr: float = 1e-4,
        betas: tuple[float, float] = (0.9, 0.999),
        kl_weight: float = 1.0,
        kl_anneal_epochs: float = 0.0,
        kl_anneal_steps: int | None = None,
        opt_iterations: int = 50,
        opt_lr: float | None = 1e-4,
        eval_seed: int = 0,
        figure_every_n_val: int = 1,
        compile_model: bool = False,
        prior_hparams: dict | None = None,
    ):
        """
        Args:
            prior_ckpt: a MotionDVAEModule checkpoint (its prior, decoder and encoder start this stage).
            noise: "rotation" (Gaussian on the body joints' axis-angle, sigmas in rad: the paper's
                protocol, needs rotation data) or "position" (Gaussian on joint positions, sigmas in m).
            train_sigmas: each training batch draws one; val_sigma: validation; test_sigmas: the table.
            noise_lambda: lambda of the IG(lambda/2, lambda/2) noise prior; large = Gaussian setting.
            obs_scale_m: the unit of the noise variance v (metres): v = 1 means noise std obs_scale_m.
            estimate: "decoder" (section 5.1), "fusion" (eq. 18) or "auto" (fusion when
                noise_lambda < 1e4, i.e. when the noise model is in use).
            first_frame: frame 0 of the output: "decoded" (one step back from the decoder's first
                frame along its velocities) or "predicted" (the paper's x_0, eq. 16, which stays
                as noisy as the input); models/dvae_inference.py. Output only: training is the same.
            lr, betas: Adamax. The encoder starts trained (the prior's): the prior's from-scratch
                rate 1e-3 wrecks it within ~50 steps at widths of 512 and more (Bandai, width 512:
                val MPJPE 85 -> 255 mm, then a slow climb back; 1e-4: 85 -> 72 mm in 200 steps;
                the session diary (CHANGELOG.md)), so this stage refines at 1e-4.
            kl_weight, kl_anneal_*: KL(q_phi || p_theta) annealing, as the prior's.
            opt_iterations, opt_lr: optimisation mode (50 as the paper). A fresh Adamax on a trained
                network jumps in its first steps: keep opt_lr small (None: lr).
            compile_model: torch.compile the prior's networks (as MotionDVAEModule's flag; a prior
                trained with it compiles anyway).
            prior_hparams: filled in from the prior checkpoint; with it the module rebuilds without the file.
        """
        super().__init__()
        if noise not in ("rotation", "position"):
            raise ValueError(f"noise must be 'rotation' or 'position', got {noise!r}")
        if estimate not in ("auto", "decoder", "fusion"):
            raise ValueError(f"estimate must be 'auto', 'decoder' or 'fusion', got {estimate!r}")
        if first_frame not in FIRST_FRAMES:
            raise ValueError(f"first_frame must be one of {FIRST_FRAMES}, got {first_frame!r}")
        self.save_hyperparameters()
        # LightningCLI hands this module's hyperparameters to save_hyperparameters through a context
        # variable; the prior is built in a fresh context so that it saves its own.
        if prior_hparams is not None:  # from a denoise checkpoint: its state_dict brings the weights
            prior = contextvars.Context().run(
                MotionDVAEModule, **{k: v for k, v in prior_hparams.items() if not k.startswith("_")}
            )
        elif prior_ckpt:
            if not Path(prior_ckpt).is_file():
                raise ValueError(
                    f"{prior_ckpt}: no such prior checkpoint (train the prior first: configs/motion_dvae*.yaml)"
                )
            # plain values only (a checkpoint runs no code); Lightning builds no class the file names
            # but MotionDVAEModule (or an imported subclass)
            prior = contextvars.Context().run(
                MotionDVAEModule.load_from_checkpoint, prior_ckpt, map_location="cpu", weights_only=True
            )
            # plain values only (no Lightning bookkeeping keys): the checkpoint stays weights_only-loadable
            self.hparams.prior_hparams = {k: v for k, v in prior.hparams.items() if not k.startswith("_")}
        else:
            raise ValueError("model.init_args.prior_ckpt: give the Motion-DVAE prior checkpoint to start from")
        if prior.net is None:
            raise ValueError(f"{prior_ckpt}: the prior checkpoint has no network (skeleton and window missing)")
        ph = self.hparams.prior_hparams
        self.net, self.body, self.codec = prior.net, prior.body, prior.codec
        self.model_config = prior.model_config
        self.net.gen.requires_grad_(False)  # prior p_theta_z and decoder p_theta_x stay as trained
        if compile_model:
            compile_in_place(self.net, self.body)
        self.window_fps = float(ph["window_fps"])
        D, H, Hm, G = self.codec.dim, ph["lstm_hidden"], ph["mlp_hidden"], ph["norm_groups"]
        num_points = self.codec.num_joints + (self.body.num_markers if self.body is not None else 0)
        self.x0_pred = InitialStatePredictor(D, H, Hm, G, velocity_mask(self.codec.kind, self.codec.num_joints))
        self.noise_pred = NoisePredictor(H, 3 * num_points, Hm, G)
        if gaussian_limit(noise_lambda):  # v = 1 exactly (elbo_terms): nothing to learn, nothing for DDP to wait on
            self.noise_pred.requires_grad_(False)
        self._anneal_steps = 0
        self.val_mpjpe, self.val_noisy_mpjpe = MPJPE(), MPJPE()

    @property
    def skeleton(self) -> Skeleton:
        return Skeleton.from_dict(self.hparams.prior_hparams["skeleton"])

    def trainable_parameters(self) -> list[nn.Parameter]:
        return [p for p in self.parameters() if p.requires_grad]

    def configure_callbacks(self):
        return [BindData()]

    def bind_data(self, data: DataSpec, stage: str) -> None:
        """The prior's skeleton and window must be the data's (BindData calls it before setup)."""
        ph = self.hparams.prior_hparams
        if self.hparams.noise == "rotation" and not data.rotations:
            raise ValueError(
                "model.noise rotation needs rotation data: set data.with_rotations: true "
                f"(bvh, amass, synthetic sources; {data.source} data here), or model.noise: position"
            )
        if self.hparams.noise == "position" and ph["state"] == "rotations":
            raise ValueError(
                "noise on positions gives no noisy rotations to a rotation-state prior: "
                "use a positions-state prior or noise: rotation"
            )
        require_complete_windows(data, stage)
        require_same_window(ph, data, "the prior was trained on")

    def configure_optimizers(self):
        return torch.optim.Adamax(self.trainable_parameters(), lr=self.hparams.lr, betas=tuple(self.hparams.betas))

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        # the prior's network config: x0_pred and noise_pred follow from it and the body model
        name_model(checkpoint, "motion-dvae", self.model_config)

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        # Before session 5 the noise predictor was trained in the Gaussian setting too; such a
        # checkpoint's optimiser holds more parameters than this module trains.
        saved = checkpoint.get("optimizer_states") or []
        trainer = self._trainer  # None under load_from_checkpoint (the public property raises there)
        if trainer is not None and trainer.training and saved:
            n_saved = sum(len(g["params"]) for g in saved[0]["param_groups"])
            n_trained = len(self.trainable_parameters())
            if n_saved != n_trained:
                raise ValueError(
                    f"this denoising checkpoint's optimiser holds {n_saved} parameters, this module trains "
                    f"{n_trained} (written before the noise predictor was frozen for noise_lambda >= 1e4): "
                    f"it loads for test and fix, but cannot resume training"
                )

    # --- noise and observation ---

    def add_noise(self, batch: dict, sigma: float, generator: torch.Generator | None = None) -> dict:
        """The batch plus its noisy version: noisy_positions (and noisy_rotations for rotation noise)."""
        out = dict(batch)
        if self.hparams.noise == "rotation":
            # offsets (B, 1, J, 3): FK broadcasts them over the window's frames
            rot, pos = rotation_noise(
                batch["rotations"],
                batch["root_translation"],
                batch["offsets"][:, None],
                self.codec.parents,
                sigma,
                generator,
            )
            out.update(noisy_rotations=rot, noisy_positions=pos)
        else:
            out["noisy_positions"] = gaussian_noise(batch["positions"], sigma, generator).positions
        return out

    @staticmethod
    def observation(batch: dict) -> Observation:
        """The loss's only door to the batch: noisy keys, root translation and offsets."""
        return Observation(
            batch["noisy_positions"], batch.get("noisy_rotations"), batch.get("root_translation"), batch.get("offsets")
        )

    # --- inference and the ELBO ---

    def infer(self, obs: Observation, sample: bool) -> Inference:
        return infer_posterior(self.net, self.codec, self.x0_pred, self.noise_pred, obs, sample)

    def elbo_terms(self, inf: Inference) -> dict[str, torch.Tensor]:
        hp = self.hparams
        kl_z = (
            gaussian_kl(inf.q_mu.float(), inf.q_logvar.float(), inf.p_mu.float(), inf.p_logvar.float())
            .sum((1, 2))
            .mean()
        )
        sq = (((inf.y3d - inf.m) / hp.obs_scale_m) ** 2).flatten(-2).double()  # (B, T+1, 3K)
        if gaussian_limit(hp.noise_lambda):
            # lambda -> infinity, taken exactly: q(v) = p(v) = a spike at v = 1, so kl_v = 0 and the
            # data term is half the squared error. Evaluating the IG terms at lambda = 1e6 instead
            # gives the noise predictor gradients of order lambda, which reach the encoder through
            # the LSTM states it shares: in optimisation mode on a trained model kl_v climbed from
            # 86 to 24,508 in 10 steps and MPJPE stayed near twice its start (session 5).
            data = 0.5 * sq.sum((1, 2)).mean()
            return {"data": data.float(), "kl_z": kl_z, "kl_v": torch.zeros_like(kl_z)}
        c = hp.noise_lambda / 2.0
        a, b = inf.a.double(), inf.b.double()
        alpha, beta = c * a.exp(), c * b.exp()
        e_log_v = math.log(c) + b - torch.digamma(alpha)
        data = 0.5 * ((a - b).exp() * sq + e_log_v).sum((1, 2)).mean()
        kl_v = inverse_gamma_kl(alpha, beta, c, c).sum((1, 2)).mean()
        return {"data": data.float(), "kl_z": kl_z, "kl_v": kl_v.float()}

    def denoise_loss(self, obs: Observation, kl_weight: float, sample: bool = True):
        terms = self.elbo_terms(self.infer(obs, sample))
        return terms["data"] + kl_weight * terms["kl_z"] + terms["kl_v"], terms

    def uses_noise_model(self) -> bool:
        return uses_noise_model(self.hparams.estimate, self.hparams.noise_lambda)

    def estimate(self, obs: Observation) -> torch.Tensor:
        """Denoised joint positions (B, T+1, J, 3), world frame (section 4.3; models/dvae_inference.py)."""
        return point_estimate(
            self.infer(obs, sample=False),
            self.codec,
            self.hparams.noise_lambda,
            self.uses_noise_model(),
            first_frame=self.hparams.first_frame,
        )

    # --- training ---

    def on_train_start(self) -> None:
        self._anneal_steps = anneal_steps_of(self.trainer, self.hparams.kl_anneal_steps, self.hparams.kl_anneal_epochs)

    def current_kl_weight(self) -> float:
        return self.hparams.kl_weight * kl_anneal_weight(self.global_step, self._anneal_steps)

    def training_step(self, batch, batch_idx):
        if "noisy_positions" not in batch:
            keep = complete_windows(batch)
            if not keep.any():
                return None
            sigmas = list(self.hparams.train_sigmas)
            sigma = sigmas[int(torch.randint(len(sigmas), ()))]
            batch = self.add_noise(select(batch, keep), sigma)
        w = self.current_kl_weight()
        loss, terms = self.denoise_loss(self.observation(batch), w)
        B = len(batch["noisy_positions"])
        self.log("train/loss", loss, prog_bar=True, batch_size=B)
        self.log_dict({f"train/{k}": v for k, v in terms.items()}, batch_size=B)
        self.log("train/kl_weight", w, batch_size=B)
        return loss

    # --- validation: the noisy ELBO (checkpoint monitor) and, for the reader, the MPJPE ---

    def _generator(self, batch_idx: int) -> torch.Generator:
        # validation, one per batch; CPU generator: the same noise on any device (see corruption.py)
        return torch.Generator().manual_seed(self.hparams.eval_seed * 100_003 + batch_idx * 101)

    def validation_step(self, batch, batch_idx):
        keep = complete_windows(batch)
        if not keep.any():
            return
        batch = self.add_noise(select(batch, keep), self.hparams.val_sigma, self._generator(batch_idx))
        obs = self.observation(batch)
        B = len(obs.positions)
        loss, terms = self.denoise_loss(obs, self.hparams.kl_weight, sample=False)
        self.log("val/loss", loss, prog_bar=True, batch_size=B, sync_dist=True)  # every process's windows
        self.log_dict({f"val/{k}": v for k, v in terms.items()}, batch_size=B, sync_dist=True)
        est = self.estimate(obs)
        self.val_mpjpe(est.float(), batch["positions"].float())
        self.val_noisy_mpjpe(obs.positions.float(), batch["positions"].float())
        self.log("val/mpjpe_mm", self.val_mpjpe, prog_bar=True, batch_size=B)
        self.log("val/noisy_mpjpe_mm", self.val_noisy_mpjpe, batch_size=B)
        if batch_idx == 0:
            self._figure_sample = (batch["positions"], obs.positions, est)

    def on_validation_epoch_end(self):
        if self.trainer.sanity_checking:
            return
        sample = getattr(self, "_figure_sample", None)
        if sample is not None:
            truth, noisy, est = sample
            log_validation_figure(
                self,
                "val/denoise_example",
                truth,
                noisy,
                None,
                est,
                f"denoising, sigma {self.hparams.val_sigma}, step {self.global_step}",
            )

    # --- test: noisy / regression / optimisation for each sigma ---

    def optimise_and_estimate(self, obs: Observation) -> torch.Tensor:
        """Optimisation mode: opt_iterations ELBO steps of the inference networks on these noisy
        windows, then the forward pass; the trained weights are put back afterwards."""
        hp = self.hparams
        was_training = self.training
        self.train()  # cuDNN takes RNN gradients in training mode only; no layer here acts differently in it
        with torch.inference_mode(False), torch.enable_grad():
            params = self.trainable_parameters()
            saved = [p.detach().clone() for p in params]
            obs = Observation(*(t.clone() if t is not None else None for t in obs))  # out of inference mode
            opt = torch.optim.Adamax(params, lr=hp.opt_lr or hp.lr, betas=tuple(hp.betas))
            for _ in range(hp.opt_iterations):
                opt.zero_grad(set_to_none=True)
                loss, _ = self.denoise_loss(obs, hp.kl_weight)
                loss.backward()
                opt.step()
            with torch.no_grad():
                est = self.estimate(obs)
                for p, s in zip(params, saved):
                    p.copy_(s)
        self.train(was_training)
        return est.detach()

    def _sync(self) -> None:
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)

    def _noisy_windows(self, batch: dict, sigma: float, seeds: torch.Tensor) -> dict:
        """add_noise, each window with its own generator (seeds (B,)): a window's noise does not
        depend on the batch or process it is in."""
        parts = [
            self.add_noise(select(batch, torch.arange(len(seeds)) == b), sigma, torch.Generator().manual_seed(int(s)))
            for b, s in enumerate(seeds.tolist())
        ]
        return {k: torch.cat([p[k] for p in parts]) if torch.is_tensor(v) else v for k, v in parts[0].items()}

    def on_test_epoch_start(self):
        self._table = DenoiseTable(self.hparams.test_sigmas, self.window_fps).to(self.device)

    def test_step(self, batch, batch_idx):
        keep = complete_windows(batch)
        if not keep.any():
            return
        batch = select(batch, keep)
        truth = batch["positions"].float()
        self._table.update_truth(truth)
        for i, sigma in enumerate(self._table.sigmas):
            seeds = window_seeds(batch, batch_idx, i + 1, self.hparams.eval_seed)
            obs = self.observation(self._noisy_windows(batch, sigma, seeds))
            self._sync()
            t0 = time.perf_counter()
            regression = self.estimate(obs)
            self._sync()
            t1 = time.perf_counter()
            optimisation = self.optimise_and_estimate(obs) if self.hparams.opt_iterations > 0 else regression
            self._sync()
            t2 = time.perf_counter()
            self._table.update(i, "noisy", obs.positions, truth)
            self._table.update(i, "dvae_regression", regression, truth, t1 - t0)
            optimised = self.hparams.opt_iterations > 0
            self._table.update(i, "dvae_optimisation", optimisation, truth, t2 - t1 if optimised else t1 - t0)
            for frames, name in zip(SMOOTH_FRAMES, SMOOTHERS):  # the classical baseline
                self._table.update(i, name, gaussian_smooth(obs.positions, frames), truth)

    def on_test_epoch_end(self):
        key = "sigma_rad" if self.hparams.noise == "rotation" else "sigma_m"
        result = self._table.rows(key)
        if result is None:  # no complete test window
            return
        self.eval_rows, scalars = result
        self.eval_json_path = publish(self, self.eval_rows, scalars, format_denoise_table(self.eval_rows, key))

    # --- predict: noisy windows in, denoised joint positions out ---

    def predict_step(self, batch, batch_idx):
        """A batch of (noisy) windows as the data module gives them -> denoised positions
        (B, T, J, 3), world frame (regression mode); NaN for windows with missing values."""
        obs = Observation(
            batch["positions"], batch.get("rotations"), batch.get("root_translation"), batch.get("offsets")
        )
        keep = complete_windows(batch)
        out = torch.full_like(batch["positions"], float("nan"))
        if keep.any():
            out[keep] = self.estimate(Observation(*(t[keep] if t is not None else None for t in obs))).to(out.dtype)
        return out
