"""Fixers: a trained checkpoint turned into something that estimates windows of motion, one
class per checkpoint kind (XMAE; the Motion-DVAE denoising stage; the jitter remover), and the loading that picks
the class by the kind the checkpoint names (models/build.py). Nothing here imports training code: a checkpoint holds
everything a fixer needs (skeleton, fps, window, network sizes) as plain values, and it is
loaded with weights_only=True. mocapfix.fix windows, blends and merges what a fixer estimates.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.core.kinematics import fk_axis_angle
from mocapfix.core.resample import hold_last_frame, model_frames, resample_frames
from mocapfix.core.skeleton import Skeleton
from mocapfix.fills.classical import lerp_infill
from mocapfix.fills.policy import FillPolicy
from mocapfix.fix.correction import corrected_take
from mocapfix.fix.fixer import Fixer, FixOptions
from mocapfix.fix.jitter_clips import denoise_clips
from mocapfix.fix.joints import ModelView
from mocapfix.fix.position_fixer import PositionFixer
from mocapfix.fix.position_windows import hermite_take_fills
from mocapfix.fix.positions import Estimates
from mocapfix.fix.report import FixReport
from mocapfix.fix.rotations import RotationFixer
from mocapfix.models.body import build_body_model
from mocapfix.models.build import build_model
from mocapfix.models.checkpoint import (
    fill_policy_values,
    hyperparameters,
    model_kind,
    network_weights,
    read_checkpoint,
    stored_config,
    window_settings,
    xmae_config,
)
from mocapfix.models.correction import CorrectionNet
from mocapfix.models.dvae import DVAEConfig, InitialStatePredictor, MotionDVAE, NoisePredictor
from mocapfix.models.dvae_inference import (
    FIRST_FRAMES,
    Observation,
    infer_posterior,
    point_estimate,
    rotation_estimate,
    uses_noise_model,
)
from mocapfix.models.dvae_state import STATES, MotionState, velocity_mask
from mocapfix.models.jitter import JitterNet, lowpass, residual_noise
from mocapfix.models.xmae import XMAE
from mocapfix.models.xmae_inference import xmae_reconstruct


class XMAEFixer(PositionFixer):
    """XMAE applied as the paper does: every available token observed (denoising is the same
    pass as infilling), the normalisation of mocapfix.models.xmae_inference. Its fill policy
    (calibrated on the val split) is measured again on each recording it fixes."""

    kind = "xmae"
    state = "positions"
    measures_policy = True

    def __init__(
        self,
        net: XMAE,
        skeleton: Skeleton,
        fps: float,
        device: str | torch.device = "cpu",
        precision: str = "fp32",
        policy: FillPolicy | None = None,
    ):
        self.policy = policy
        self.net = net.to(device).eval()
        self.skeleton, self.fps, self.window = skeleton, float(fps), int(net.num_frames)
        self.device = torch.device(device)
        # bf16 matmuls (coordinates stay fp32 at the network's ends: models/xmae.py)
        self.precision = resolve_precision(precision, self.device)

    @classmethod
    def from_checkpoint(cls, path, ckpt: dict, device="cpu", precision: str = "fp32", policy=None) -> XMAEFixer:
        skeleton, fps, _ = window_settings(path, hyperparameters(ckpt))
        try:  # (checkpoints written before they held their config: rebuilt from their hyperparameters)
            net = build_model("xmae", xmae_config(path, ckpt))
        except (TypeError, ValueError, AssertionError) as e:
            raise MotionFileError(path, f"bad XMAE sizes in the checkpoint ({e})") from None
        load_weights(path, net, network_weights(ckpt), "its hyperparameters describe")
        return cls(net, skeleton, fps, device, precision, policy)

    @torch.inference_mode()
    def estimate(
        self, positions: torch.Tensor, observed: torch.Tensor, fill: torch.Tensor | None = None
    ) -> torch.Tensor:
        # fill: (B, T, J, 3) the classical fill the network corrects, from the whole take
        fill = fill.to(self.device) if fill is not None else None
        with torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=self.precision == "bf16"):
            out = xmae_reconstruct(self.net, positions.to(self.device), observed.to(self.device), fill)
        return out.float().cpu()

    def whole_take_fills(self, clips: list[Clip], view: ModelView) -> list[np.ndarray] | None:
        # a network that corrects the cubic Hermite fill gets it from the whole take (fill_kind hermite)
        if getattr(self.net, "fill_input", False) and getattr(self.net, "fill_kind", "") == "hermite":
            return hermite_take_fills(self.fps, clips, view)
        return None

    def load_note(self, ckpt) -> str | None:
        if self.policy is not None:
            return None
        return (
            f"note: {ckpt} has no fill policy: the model fills every hole and replaces every token it is "
            "asked to (`mocapfix validate --config CFG --ckpt_path CKPT` calibrates one on the val split)"
        )


PRECISIONS = ("auto", "fp32", "bf16")


def resolve_precision(precision: str, device: torch.device) -> str:
    """auto -> bf16 where the hardware multiplies bf16 natively (CUDA GPUs since Ampere, CPUs
    with AVX512-BF16 or AMX: 1.5-2x faster here), else fp32."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
    if precision != "auto":
        return precision
    if device.type == "cuda":
        return "bf16" if torch.cuda.is_bf16_supported() else "fp32"
    native = [getattr(torch.cpu, f, lambda: False) for f in ("_is_avx512_bf16_supported", "_is_amx_tile_supported")]
    return "bf16" if device.type == "cpu" and any(f() for f in native) else "fp32"


class DVAEFixer(PositionFixer):
    """The Motion-DVAE denoising stage in regression mode (paper section 4.3), as its module's
    test does: x_0 from the initial-state predictor's mean, z_1:T the encoder's means (one
    forward pass), the decoder output, fused with the observation by eq. 18 when the checkpoint
    uses the noise model (estimate "fusion", or "auto" with noise_lambda < 1e4).

    positions state: windows of joint positions. The model has no notion of a missing joint:
    missing tokens are filled by linear interpolation in time (Lerp) before it, and get the
    decoder output (eq. 18 has no observation to fuse there).
    rotations state: windows of joint rotations (estimate_rotations); the output is the
    decoder's motion, as rotations (eq. 18 fuses 3D points, which would not be a pose)."""

    kind = "motion-dvae"

    def __init__(
        self,
        parts: DVAEParts,
        skeleton: Skeleton,
        fps: float,
        window: int,
        settings: DVAEEstimate,
        device: str | torch.device = "cpu",
        policy: FillPolicy | None = None,
    ):
        self.policy = policy
        self.device = torch.device(device)
        self.net, self.x0_pred, self.noise_pred = (
            m.to(self.device).eval() for m in (parts.net, parts.x0_pred, parts.noise_pred)
        )
        self.codec, self.state = parts.codec.to(self.device), parts.codec.kind  # its body model and joint reference
        self.skeleton, self.fps, self.window = skeleton, float(fps), int(window)
        self.noise_lambda, self.fusion, self.first_frame = settings
        self.notes = (
            ["eq. 18 fuses 3D points, not rotations: the decoder's motion is used"]
            if self.fusion and self.state == "rotations"
            else []
        )

    @classmethod
    def from_checkpoint(cls, path, ckpt: dict, device="cpu", precision: str = "fp32", policy=None) -> DVAEFixer:
        """A DVAEDenoiseModule checkpoint: the prior's hyperparameters (prior_hparams) rebuild the
        nets, the denoising stage's own (noise_lambda, estimate) choose the final estimate.
        precision: fp32 always (auto included): the recurrent state would carry bf16's rounding
        from frame to frame, and the LSTMs are cheap (1e-3 s per frame on a CPU core)."""
        if precision == "bf16":
            raise ValueError("--precision bf16 is for XMAE checkpoints; Motion-DVAE runs in fp32")
        hparams = hyperparameters(ckpt)
        ph = hparams.get("prior_hparams")
        if not isinstance(ph, dict):
            raise MotionFileError(path, "Motion-DVAE checkpoint lacks prior_hparams: cannot rebuild the networks")
        skeleton, fps, frames = window_settings(path, ph)
        missing = [k for k in ("state", "latent_dim", "lstm_hidden", "mlp_hidden", "norm_groups") if ph.get(k) is None]
        missing += [k for k in ("noise_lambda", "estimate") if hparams.get(k) is None]
        if missing:
            raise MotionFileError(
                path, f"Motion-DVAE checkpoint lacks {', '.join(missing)}: cannot rebuild the networks"
            )
        state = ph["state"]
        if state not in STATES:
            raise MotionFileError(path, f"Motion-DVAE checkpoint has an unknown state {state!r}")
        parts = _dvae_parts(path, ckpt, ph, state, skeleton, fps)
        noise_lambda = float(hparams["noise_lambda"])
        fusion = uses_noise_model(str(hparams["estimate"]), noise_lambda)
        first_frame = str(hparams.get("first_frame", "decoded"))  # checkpoints from before it: the module's default
        if first_frame not in FIRST_FRAMES:
            raise MotionFileError(path, f"Motion-DVAE checkpoint has an unknown first_frame {first_frame!r}")
        # the rotations state fixes rotations (DVAERotationFixer), the positions state positions
        return (DVAERotationFixer if state == "rotations" else cls)(
            parts,
            skeleton,
            fps,
            frames,
            DVAEEstimate(noise_lambda, fusion, first_frame),
            device,
            policy,
        )

    def _infer(self, obs: Observation):
        return infer_posterior(self.net, self.codec, self.x0_pred, self.noise_pred, obs, sample=False)

    @torch.inference_mode()
    def estimate(self, positions: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
        if self.state != "positions":
            raise ValueError("this Motion-DVAE works on rotations: use estimate_rotations")
        filled = lerp_infill(positions.double(), observed).float().to(self.device)  # (B, W, J, 3)
        inf = self._infer(Observation(filled, None, None, None))
        est = point_estimate(
            inf, self.codec, self.noise_lambda, self.fusion, observed.to(self.device), self.first_frame
        )
        return est.float().cpu()

    @torch.inference_mode()
    def estimate_rotations(
        self, rotations: torch.Tensor, root_translation: torch.Tensor, offsets: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        if self.state != "rotations":
            raise ValueError("this Motion-DVAE works on positions: use estimate")
        rotations, root_translation, offsets = (
            t.float().to(self.device) for t in (rotations, root_translation, offsets)
        )
        positions = fk_axis_angle(rotations, root_translation, offsets[:, None], self.codec.parents)
        inf = self._infer(Observation(positions, rotations, root_translation, offsets))
        rot, root = rotation_estimate(inf, self.codec, self.first_frame)
        return rot.float().cpu(), root.float().cpu()


class DVAEEstimate(NamedTuple):
    """How the denoising stage makes its final estimate (its own hyperparameters)."""

    noise_lambda: float
    fusion: bool  # eq. 18: the decoder output fused with the observation (uses_noise_model)
    first_frame: str  # FIRST_FRAMES


class DVAEParts(NamedTuple):
    """The Motion-DVAE denoising stage's networks, each named as its weights' prefix in a checkpoint."""

    codec: MotionState  # the state (its body model and joint reference)
    net: MotionDVAE
    x0_pred: InitialStatePredictor
    noise_pred: NoisePredictor


def _dvae_parts(path, ckpt: dict, ph: dict, state: str, skeleton: Skeleton, fps: float) -> DVAEParts:
    """The Motion-DVAE denoising stage's parts rebuilt from the prior's hyperparameters (ph) and
    loaded with the checkpoint's weights."""
    body = None
    if state == "rotations":
        try:  # an SMPL body is rebuilt from the model file the checkpoint names (never stored in it)
            body = build_body_model(
                ph.get("body_model", "skeleton"),
                skeleton.parents,
                ph.get("body_model_path"),
                ph.get("gender", "neutral"),
                ph.get("model_type", "smplh"),
                ph.get("markers"),
            )
        except (ValueError, OSError) as e:
            why = " ".join(str(e).split())
            raise MotionFileError(path, f"cannot rebuild the checkpoint's body model ({why})") from None
    try:
        codec = MotionState(state, skeleton.parents, skeleton.groups, fps, body)
        D, H, Hm, G = codec.dim, int(ph["lstm_hidden"]), int(ph["mlp_hidden"]), int(ph["norm_groups"])
        num_points = codec.num_joints + (body.num_markers if body is not None else 0)
        config = stored_config(path, ckpt)
        if config is None:  # written before checkpoints held their config: the prior's hyperparameters
            velocities = bool(ph.get("encoder_velocities", False))
            config = DVAEConfig(state, skeleton.num_joints, int(ph["latent_dim"]), H, Hm, G, velocities)
        parts = DVAEParts(
            codec,
            build_model("motion-dvae", config),
            InitialStatePredictor(D, H, Hm, G, velocity_mask(state, codec.num_joints)),
            NoisePredictor(H, 3 * num_points, Hm, G),
        )
    except (TypeError, ValueError) as e:
        raise MotionFileError(path, f"bad Motion-DVAE sizes in the checkpoint ({e})") from None
    for prefix, net in parts._asdict().items():
        load_weights(path, net, network_weights(ckpt, prefix), "its hyperparameters describe", prefix)
    return parts


def load_weights(path, net: torch.nn.Module, weights: dict, described: str, part: str = "") -> None:
    """net given a checkpoint's weights (network_weights); MotionFileError naming the file where
    they do not fit the network the checkpoint `described` (the start of the message)."""
    try:
        net.load_state_dict(weights)
    except RuntimeError as e:
        first = " ".join(str(e).split())[:200]
        raise MotionFileError(
            path, f"weights do not fit the network {described} ({f'{part}: ' if part else ''}{first})"
        ) from None


class DVAERotationFixer(RotationFixer, DVAEFixer):
    """The Motion-DVAE denoising stage on its rotations state: it fixes joint rotations
    (rotations.py; estimate_rotations), and a BVH comes back with them."""


class CorrectionFixer(PositionFixer):
    """A learned correction to a classical fill (models/correction.py), trained on a capture's
    archive, applied to each hole of a take (correction.py). It fills holes (infill); which holes
    it takes is measured on holes cut into the recording, as for XMAE: where it beats every
    classical fill there, and nowhere before (FillPolicy.preferred_only)."""

    kind = "correction"
    candidate = "correction"
    measures_policy = True

    def __init__(
        self,
        net: CorrectionNet,
        skeleton: Skeleton,
        fps: float,
        window: int,
        max_hole_s: float,
        gaps_s,
        device: str | torch.device = "cpu",
    ):
        self.net = net.to(device).eval()
        self.skeleton, self.fps, self.window = skeleton, float(fps), int(window)
        self.max_hole_s, self.device = float(max_hole_s), torch.device(device)
        self.policy = FillPolicy.preferred_only(gaps_s)

    @classmethod
    def from_checkpoint(cls, path, ckpt: dict, device="cpu", precision: str = "fp32", policy=None) -> CorrectionFixer:
        """precision: fp32 (auto included): an MLP per hole costs little, and bf16 would round
        the millimetres it adds."""
        if precision == "bf16":
            raise ValueError("--precision bf16 is for XMAE checkpoints; a learned correction runs in fp32")
        hparams = hyperparameters(ckpt)
        skeleton, fps, frames = window_settings(path, hparams)
        try:
            net = build_model("correction", stored_config(path, ckpt))
            max_hole_s = float(hparams.get("max_hole_s", 1.0))
            gaps = [float(g) for g in hparams.get("eval_gaps_s", (0.1, 0.3, 0.5, 0.7, 0.9))]
        except (TypeError, ValueError) as e:
            raise MotionFileError(path, f"bad correction sizes in the checkpoint ({e})") from None
        load_weights(path, net, network_weights(ckpt), "its config describes")
        return cls(net, skeleton, fps, frames, max_hole_s, gaps, device)

    def fix_clips(self, clips: list[Clip], options: FixOptions) -> tuple[list[Clip], FixReport]:
        if options.mode != "infill":
            raise MotionFileError(
                clips[0].source or clips[0].name,
                f"a learned correction fills holes (--mode infill), it does not judge observed tokens "
                f"(--mode {options.mode}): an XMAE does",
            )
        return super().fix_clips(clips, options)

    def estimates(self, clips: list[Clip], view: ModelView, need_m: list[np.ndarray], options: FixOptions) -> Estimates:
        # each clip at its own frames: every hole the base fill's, corrected where need_m asks;
        # no windows (none blind, none served by a fallback)
        out, runs = [], 0
        for c, x, need in zip(clips, view.x_in, need_m):
            at_model = np.round(np.arange(c.num_frames) * self.fps / c.fps).astype(np.int64)
            asked = need[np.minimum(at_model, len(need) - 1)]
            est, corrected = corrected_take(self.net, x, c.fps, self.fps, self.max_hole_s, asked)
            out.append(est)
            runs += corrected
        return Estimates(out, [np.zeros(len(need), dtype=bool) for need in need_m], runs, 0, 0)


# How far the jitter remover's correction may reach, in RMS residuals of the low-pass (capped).
CORRECTION_REACH = 2.0


def capped(correction: np.ndarray, residual: np.ndarray, frames: int) -> np.ndarray:
    """correction, residual (the input less its low-pass): (T, J, 3) -> the correction, each
    token's cut to CORRECTION_REACH times the residual's RMS over `frames` around it (one period
    of the cutoff). The network gives back motion the low-pass took out, so about as much as it
    took out: a correction far longer is a body unlike any it learned (NTU RGB+D's Kinect v2
    takes, their camera pitched 12-18 degrees: 13-18 mm a token where the low-pass moved them
    1-6; 0-3 mm on mocap). Per token against the RMS, not the token's own residual: white noise
    leaves some tokens near their low-pass by chance (that cap cost 1.6 mm on Bandai's noisy
    takes, bench/denoise_strangers.py; this one 0.1)."""
    r2 = (residual**2).sum(-1)  # (T, J)
    sums = np.concatenate([np.zeros((1, r2.shape[1])), np.cumsum(r2, 0)])  # (T + 1, J)
    t = np.arange(len(r2))
    lo, hi = np.clip(t - frames // 2, 0, len(r2)), np.clip(t + frames - frames // 2, 0, len(r2))
    rms = np.sqrt((sums[hi] - sums[lo]) / np.maximum(hi - lo, 1)[:, None])[..., None]  # (T, J, 1)
    length = np.linalg.norm(correction, axis=-1, keepdims=True)
    return correction * np.minimum(1.0, CORRECTION_REACH * rms / np.maximum(length, 1e-12))


class JitterFixer(Fixer):
    """The jitter remover (models/jitter.py) on whole takes: the low-pass and the noise measure at
    the recording's own frame rate, the network's correction at its own (window_fps), brought back
    to the recording's frames. The network is convolutional: a take is read in pieces of
    CHUNK_S seconds with its receptive field on both sides, so memory does not grow with the
    take and the result is the same as in one piece."""

    kind = "jitter"
    state = "positions"
    default_mode = "denoise"  # it takes jitter out; holes stay holes
    CHUNK_S = 60.0

    def __init__(self, net: JitterNet, skeleton: Skeleton, fps: float, device: str | torch.device = "cpu"):
        self.net = net.to(device).eval()
        self.skeleton, self.fps, self.window = skeleton, float(fps), int(net.config.num_frames)
        self.device = torch.device(device)

    @classmethod
    def from_checkpoint(cls, path, ckpt: dict, device="cpu", precision: str = "fp32", policy=None) -> JitterFixer:
        skeleton, fps, _ = window_settings(path, hyperparameters(ckpt))
        try:
            net = build_model("jitter", stored_config(path, ckpt))
        except (TypeError, ValueError) as e:
            raise MotionFileError(path, f"bad jitter-remover sizes in the checkpoint ({e})") from None
        load_weights(path, net, network_weights(ckpt), "its config describes")
        return cls(net, skeleton, fps, device)

    def fix_clips(self, clips: list[Clip], options: FixOptions) -> tuple[list[Clip], FixReport]:
        return denoise_clips(clips, self, options.mode, options.progress, options.joint_map)

    @torch.inference_mode()
    def denoise(self, x: np.ndarray, fps: float, base: np.ndarray | None = None) -> np.ndarray:
        """x: (T, J, 3) one take at the model's joints and its own fps, metres, finite (holes
        filled by the caller); base: its lowpass at the model's cutoff when the caller has it ->
        denoised (T, J, 3) float64 at the take's frames. ValueError where the frame rate cannot
        hold the model's cutoff."""
        cutoff, fps_m = self.net.cutoff_hz, self.fps
        xt = torch.from_numpy(x.astype(np.float64))[None]  # (1, T, J, 3)
        bt = lowpass(xt, fps, cutoff) if base is None else torch.from_numpy(base.astype(np.float64))[None]
        noise = residual_noise(xt, bt, fps, cutoff)[0].numpy()  # (T, J)
        base = bt[0].numpy()
        K = model_frames(len(x), fps, fps_m)
        # Low-passed well below the network's Nyquist rate: plain linear resampling aliases nothing.
        base_m, noise_m = (hold_last_frame(resample_frames(a, fps, fps_m, K)) for a in (base, noise))
        out_m = np.empty_like(base_m)
        chunk, margin = max(1, round(self.CHUNK_S * fps_m)), self.net.receptive_field
        for start in range(0, K, chunk):
            lo, hi = max(0, start - margin), min(K, start + chunk + margin)
            b = torch.from_numpy(base_m[lo:hi]).float()[None].to(self.device)
            n = torch.from_numpy(noise_m[lo:hi]).float()[None].to(self.device)
            out = self.net(b, n)[0].double().cpu().numpy()
            out_m[start : min(K, start + chunk)] = out[start - lo : start - lo + min(chunk, K - start)]
        correction = hold_last_frame(resample_frames(out_m - base_m, fps_m, fps, len(x)))
        return base + capped(correction, x - base, max(1, round(fps / cutoff)))


# kind -> class with from_checkpoint(path, ckpt, device, precision, policy)
FIXERS: dict[str, type] = {
    "xmae": XMAEFixer,
    "motion-dvae": DVAEFixer,
    "jitter": JitterFixer,
    "correction": CorrectionFixer,
}
# Checkpoints fix recognises but cannot use, and why. A prior alone has no initial-state
# predictor, and the paper's "No noisy train" ablation (appendix, Tab. 2) shows that its
# encoder, trained on clean motion only, denoises badly: the denoising stage is what fix runs.
REFUSED = {
    "motion-dvae-prior": "a Motion-DVAE prior checkpoint; fix needs the denoising stage trained from it "
    "(configs/motion_dvae_denoise*.yaml with model.init_args.prior_ckpt set to this file)",
}


def load_fixer(path, device: str | torch.device = "cpu", precision: str = "fp32") -> Fixer:
    """The Fixer for a checkpoint file (FIXERS: XMAE, the Motion-DVAE denoising stage, the jitter
    remover, a learned correction).
    precision: fp32, bf16 or auto (resolve_precision; XMAE only)."""
    ckpt = read_checkpoint(path)
    stored_config(path, ckpt)  # a malformed model entry is said before anything is built from it
    kind = model_kind(ckpt)
    if kind in REFUSED:
        raise MotionFileError(path, REFUSED[kind])
    if kind not in FIXERS:
        raise MotionFileError(
            path, f"not a mocapfix checkpoint of a model fix knows ({', '.join(FIXERS)}): no matching network weights"
        )
    # which fill for which hole, calibrated on the val split (fills/policy.py); None: the
    # model everywhere (checkpoints from before it, until `mocapfix validate --ckpt_path` adds one)
    values = fill_policy_values(ckpt)
    try:
        policy = FillPolicy.from_dict(values) if values is not None else None
    except (KeyError, TypeError, ValueError) as e:
        raise MotionFileError(path, f"the checkpoint's fill policy is malformed ({e})") from None
    return FIXERS[kind].from_checkpoint(path, ckpt, device, precision, policy)
