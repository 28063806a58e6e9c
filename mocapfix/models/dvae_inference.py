"""The denoising stage's posterior pass (Motion-DVAE section 4.3), shared by training and `fix`.

Plain functions of the nets (MotionDVAE, InitialStatePredictor, NoisePredictor) and the state
codec, so the denoising module (training/denoise_module.py) and `mocapfix fix` (which must not
import training code) run the very same computation:

  infer_posterior   noisy observation -> x_0 (q_omega), z_1:T (q_phi), decoded states, noise posterior
  point_estimate    -> denoised joint positions, world frame: the decoder output, or eq. 18
                       (fused with the observation by the estimated noise variance)
  rotation_estimate -> denoised local rotations and root translation, world frame (rotations state)

The first frame of the output (first_frame):
  "predicted"  x_0 as the paper: the initial-state predictor's mean (eq. 16). x_0 has no prior in
               the model and the ELBO's only direct term on it is y_0's likelihood, so it stays as
               far off as the noisy input (Bandai, sigma 0.1 rad: 56 mm at frame 0 against 42 at
               frame 1), and its join to the decoded frames is an acceleration spike (65 m/s^2
               where the window's middle has 5; the session diary (CHANGELOG.md), sessions 6-7).
  "decoded"    one step back from the decoder's x_1 along x_1's own velocities (beyond the paper):
               the decoder's motion carried to frame 0 (45 mm there, 13 m/s^2 at the join).
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from mocapfix.core import lazy_roma as roma
from mocapfix.models.dvae import InitialStatePredictor, MotionDVAE, NoisePredictor
from mocapfix.models.dvae_state import Canonical, MotionState, from_canonical, split_rotation_state

FIRST_FRAMES = ("decoded", "predicted")
GAUSSIAN_LAMBDA = 1e4  # from here on the IG prior is the paper's Gaussian setting: final estimate = decoder output


class Observation(NamedTuple):
    """What the denoiser may see of a window: noisy data and the known shape."""

    positions: torch.Tensor  # (B, T+1, J, 3) noisy joint positions, world
    rotations: torch.Tensor | None  # (B, T+1, J, 3) noisy local axis-angle (rotations state)
    root_translation: torch.Tensor | None  # (B, T+1, 3) observed root translation (the protocol keeps it)
    offsets: torch.Tensor | None  # (B, J, 3) bone offsets: the shape, observed (q(beta | y) of the paper)


class Inference(NamedTuple):
    canon: Canonical
    y3d: torch.Tensor  # (B, T+1, K, 3) observed points, canonical frame, metres
    m: torch.Tensor  # (B, T+1, K, 3) predicted points M(x_0), M(x_hat_t)
    x0_mu: torch.Tensor  # (B, D) standardised
    x0_logvar: torch.Tensor
    q_mu: torch.Tensor  # (B, T, L)
    q_logvar: torch.Tensor
    p_mu: torch.Tensor
    p_logvar: torch.Tensor
    a: torch.Tensor  # (B, T+1, 3K) alpha = lambda/2 e^a
    b: torch.Tensor  # (B, T+1, 3K) beta = lambda/2 e^b
    x: torch.Tensor  # (B, T+1, D) predicted states x_0, x_hat_1..x_hat_T, raw units, canonical frame
    shape: torch.Tensor | None  # the body model's shape (rotations state), None for positions


def gaussian_limit(noise_lambda: float) -> bool:
    """The paper's "very high lambda" (section 5.1): IG(lambda/2, lambda/2) is then a spike at
    v = 1, and so is the best posterior q_gamma(v): the noise variance is 1 (std obs_scale_m)."""
    return noise_lambda >= GAUSSIAN_LAMBDA


def uses_noise_model(estimate: str, noise_lambda: float) -> bool:
    """Whether the final estimate is eq. 18 ("fusion") or the decoder output ("decoder");
    "auto": fusion only when the noise prior is far from the Gaussian setting."""
    if estimate == "auto":
        return not gaussian_limit(noise_lambda)
    return estimate == "fusion"


def infer_posterior(
    net: MotionDVAE,
    codec: MotionState,
    x0_pred: InitialStatePredictor,
    noise_pred: NoisePredictor,
    obs: Observation,
    sample: bool,
) -> Inference:
    """One pass of the inference and generative models over noisy windows. sample=False takes
    the means of q_omega and q_phi (regression mode's posterior-mean path)."""
    y, canon = codec.encode(obs.positions, obs.rotations, obs.root_translation)  # (B, T+1, D) raw state
    shape = codec.shape(obs.offsets)
    y3d = codec.points(y, shape).points()  # (B, T+1, K, 3)
    yn = net.normalize(y)
    x0_mu, x0_logvar = x0_pred(yn)
    x0 = x0_mu + torch.randn_like(x0_mu) * (0.5 * x0_logvar).exp() if sample else x0_mu
    out = net(x0, yn[:, 1:], sample)  # encoder on the noisy states, frozen prior and decoder
    x_all = net.denormalize(torch.cat([x0[:, None], out.x_hat], dim=1).float())  # (B, T+1, D)
    m = codec.points(x_all, shape).points()
    a, b = noise_pred(out.h, y3d.flatten(-2))
    return Inference(
        canon, y3d, m, x0_mu, x0_logvar, out.q_mu, out.q_logvar, out.p_mu, out.p_logvar, a, b, x_all, shape
    )


def output_states(inf: Inference, codec: MotionState, first_frame: str) -> torch.Tensor:
    """The states the output is made of (B, T+1, D), canonical frame: inf.x with frame 0 as
    first_frame says (module docstring)."""
    if first_frame not in FIRST_FRAMES:
        raise ValueError(f"first_frame must be one of {FIRST_FRAMES}, got {first_frame!r}")
    if first_frame == "predicted":
        return inf.x
    return torch.cat([codec.step_back(inf.x[:, 1])[:, None], inf.x[:, 1:]], dim=1)


def output_points(inf: Inference, codec: MotionState, first_frame: str) -> torch.Tensor:
    """Their points (B, T+1, K, 3): inf.m, with frame 0 through the body model again when it changed."""
    x = output_states(inf, codec, first_frame)
    if first_frame == "predicted":
        return inf.m
    m0 = codec.points(x[:, :1], inf.shape).points()  # (B, 1, K, 3)
    return torch.cat([m0.to(inf.m.dtype), inf.m[:, 1:]], dim=1)


def point_estimate(
    inf: Inference,
    codec: MotionState,
    noise_lambda: float,
    fusion: bool,
    observed: torch.Tensor | None = None,
    first_frame: str = "decoded",
) -> torch.Tensor:
    """Denoised joint positions (B, T+1, J, 3), world frame (section 4.3): the decoder output on
    the posterior-mean path, frame 0 as first_frame says, fused with the observation by eq. 18
    when fusion is on (frame 0 too when it is the decoder's).
    observed: (B, T+1, J) bool, joints where there is an observation to fuse with (None: all);
    elsewhere the decoder output stands."""
    est = output_points(inf, codec, first_frame)
    if fusion:
        if gaussian_limit(noise_lambda):
            v = torch.ones_like(est)
        else:
            c = noise_lambda / 2.0
            alpha, beta = c * inf.a.exp(), c * inf.b.exp()
            v = torch.where(alpha > 1, beta / (alpha - 1).clamp_min(1e-6), beta / (alpha + 1))  # E[v], else the mode
            v = v.reshape(est.shape).to(est.dtype)
        fused = (v * est + inf.y3d) / (v + 1)
        if observed is not None:
            keep = torch.zeros(est.shape[:-1], dtype=torch.bool, device=est.device)  # (B, T+1, K)
            keep[:, :, : codec.num_joints] = observed
            fused = torch.where(keep[..., None], fused, est)
        est = fused if first_frame == "decoded" else torch.cat([est[:, :1], fused[:, 1:]], dim=1)
    joints = est[:, :, : codec.num_joints]
    return from_canonical(joints, inf.canon)


def rotation_estimate(
    inf: Inference, codec: MotionState, first_frame: str = "decoded"
) -> tuple[torch.Tensor, torch.Tensor]:
    """Rotations state: the decoded states back in the world frame -> local axis-angle rotations
    (B, T+1, J, 3) (joint 0: root orientation) and root translation (B, T+1, 3). Eq. 18 fuses 3D
    points, not rotations: this is always the decoder's motion (frame 0 as first_frame says)."""
    x = output_states(inf, codec, first_frame)
    r, phi, _ = split_rotation_state(x, codec.num_joints)  # (B, T+1, 3) each
    theta = codec.joint_rotations(x)  # (B, T+1, J-1, 3)
    root_translation = from_canonical(r, inf.canon)
    # the canonical frame is the world turned by -yaw about z: turn the root orientation back
    yaw = torch.zeros(len(r), 3, dtype=r.dtype, device=r.device)
    yaw[:, 2] = inf.canon.yaw.to(r.dtype)
    root = roma.rotvec_to_rotmat(yaw)[:, None] @ roma.rotvec_to_rotmat(phi)  # (B, T+1, 3, 3)
    rotations = torch.cat([roma.rotmat_to_rotvec(root)[:, :, None], theta], dim=2)
    return rotations, root_translation
