"""Motion-DVAE networks (paper section 3.2, appendices A.1, A.2, E.1) and the closed-form KLs.

Fiche, Leglaive, Alameda-Pineda and Séguier, "Motion-DVAE: Unsupervised learning for fast human
motion denoising", ACM SIGGRAPH Conference on Motion, Interaction and Games (MIG) 2023.

Time runs t = 0..T inside a window of T+1 frames: x_0 is the first frame (given in the prior,
predicted in denoising) and z_1..z_T, x_1..x_T the rest.

Generative model p_theta (fixed during denoising):
  (h_0, c_0) = d_ini(x_0); h_t = LSTM(h_{t-1}, z_t)   one LSTM serves as d_hx and d_hz
  x_t ~ N(d_x(h_t), Id);   z_{t+1} ~ N(d_z(h_t))        so p(z_t | z_<t, x_0) reads h_{t-1}
Inference model q_phi(z_t | z_<t, x_t:T, x_0):
  h^data_t = LSTM_backward(h^data_{t+1}, x_t); (h^lat_0, c^lat_0) = e_ini(x_0);
  h^lat_t = LSTM(h^lat_{t-1}, z_t); [mu, logvar] = e_glob([h^lat_{t-1}, h^data_t])
Denoising adds q_omega(x_0 | y_0:T) (anti-causal LSTM + MLP) and q_gamma(v_t | z_1:t, y_t, x_0)
(inverse-gamma per observed coordinate, from the generative LSTM state h_t and y_t).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch
import torch.nn as nn


@dataclass
class DVAEConfig:
    """Everything that decides MotionDVAE's shape: saved in every checkpoint (models/build.py).
    The state's size and velocity entries follow from state and num_joints (dvae_state.py)."""

    state: str  # "rotations" (the paper's) or "positions"
    num_joints: int
    latent_dim: int = 48  # paper A.1
    lstm_hidden: int = 1024  # paper A.1
    mlp_hidden: int = 1024  # the 2 hidden layers of every MLP (not in the paper)
    norm_groups: int = 16
    encoder_velocities: bool = False  # False: the encoder reads poses only (MotionDVAE)


class MLP(nn.Module):
    """Two hidden layers, GroupNorm and ReLU (paper A.1). Works on (..., in)."""

    def __init__(self, in_dim: int, hidden: int, out_dim: int, groups: int = 16):
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(in_dim, hidden),
            nn.GroupNorm(groups, hidden),
            nn.ReLU(),
            nn.Linear(hidden, hidden),
            nn.GroupNorm(groups, hidden),
            nn.ReLU(),
            nn.Linear(hidden, out_dim),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        lead = x.shape[:-1]
        return self.net(x.reshape(-1, x.shape[-1])).reshape(*lead, -1)  # GroupNorm wants (N, C)


class LSTMInit(nn.Module):
    """MLP -> initial (h, c) of a one-layer LSTM: the paper's "h_0 = d_ini(x_0)" for an LSTM,
    whose state is the pair."""

    def __init__(self, in_dim: int, mlp_hidden: int, lstm_hidden: int, groups: int):
        super().__init__()
        self.mlp = MLP(in_dim, mlp_hidden, 2 * lstm_hidden, groups)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h, c = self.mlp(x).chunk(2, dim=-1)  # (B, H) each
        return h, c


class Generative(nn.Module):
    """p_theta(x_1:T, z_1:T | x_0): d_ini, the shared LSTM, d_x, d_z."""

    def __init__(self, x_dim: int, latent_dim: int, lstm_hidden: int, mlp_hidden: int, groups: int):
        super().__init__()
        self.d_ini = LSTMInit(x_dim, mlp_hidden, lstm_hidden, groups)
        self.lstm = nn.LSTM(latent_dim, lstm_hidden, batch_first=True)
        self.d_x = MLP(lstm_hidden, mlp_hidden, x_dim, groups)
        self.d_z = MLP(lstm_hidden, mlp_hidden, 2 * latent_dim, groups)

    def hidden(self, x0: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """x0 (B, D), z (B, T, L) -> h_0..h_T (B, T+1, H); h_t depends on x_0 and z_1..z_t only."""
        h0, c0 = self.d_ini(x0)
        h, _ = self.lstm(z, (h0[None].contiguous(), c0[None].contiguous()))
        return torch.cat([h0[:, None], h], dim=1)

    def forward(self, x0: torch.Tensor, z: torch.Tensor):
        """-> x_hat (B, T, D) = mu_theta_x(z_1:t, x_0), prior mu and logvar of z_1..z_T (B, T, L), h (B, T+1, H)."""
        h = self.hidden(x0, z)
        p_mu, p_logvar = self.d_z(h[:, :-1]).chunk(2, dim=-1)
        return self.d_x(h[:, 1:]), p_mu, p_logvar, h

    @torch.no_grad()
    def sample(self, x0: torch.Tensor, num_steps: int) -> torch.Tensor:
        """Ancestral sampling of the prior: x0 (B, D) -> x_1..x_T (B, T, D) means."""
        h, c = (s[None].contiguous() for s in self.d_ini(x0))
        hs = []
        for _ in range(num_steps):
            mu, logvar = self.d_z(h[0]).chunk(2, dim=-1)
            z = mu + torch.randn_like(mu) * (0.5 * logvar).exp()
            out, (h, c) = self.lstm(z[:, None], (h, c))
            hs.append(out)
        return self.d_x(torch.cat(hs, dim=1))


class Encoder(nn.Module):
    """q_phi(z_t | z_1:t-1, x_t:T, x_0): backward data LSTM, e_ini, forward latent LSTM, e_glob."""

    def __init__(self, x_dim: int, latent_dim: int, lstm_hidden: int, mlp_hidden: int, groups: int):
        super().__init__()
        self.e_data = nn.LSTM(x_dim, lstm_hidden, batch_first=True)
        self.e_ini = LSTMInit(x_dim, mlp_hidden, lstm_hidden, groups)
        self.e_lat = nn.LSTMCell(latent_dim, lstm_hidden)
        self.e_glob = MLP(2 * lstm_hidden, mlp_hidden, 2 * latent_dim, groups)

    def forward(self, x0: torch.Tensor, x: torch.Tensor, sample: bool = True):
        """x0 (B, D), x (B, T, D) = x_1..x_T -> z, mu, logvar (B, T, L).
        sample=False takes z_t = mu_t (the posterior-mean path used for regression)."""
        B, T, _ = x.shape
        h_data = self.e_data(x.flip(1))[0].flip(1)  # (B, T, H): h^data_t summarises x_t..x_T
        h, c = self.e_ini(x0)  # (B, H) each
        # Only h^lat_{t-1} has to wait for z_{t-1}. e_glob's first layer on [h^lat, h^data_t] is
        # W_lat h^lat + (W_data h^data_t + b): the data half, and the sampling noise, for all t
        # at once before the loop. The loop is the DVAE's launch-bound part on a GPU: each op
        # taken out of it is T kernels fewer forward and more backward.
        first, rest = self.e_glob.net[0], self.e_glob.net[1:]
        H = self.e_lat.hidden_size
        w_lat = first.weight[:, :H]
        data_term = nn.functional.linear(h_data, first.weight[:, H:], first.bias).unbind(1)  # T x (B, M)
        noise = torch.randn(B, T, self.e_lat.input_size, device=x.device, dtype=h.dtype).unbind(1) if sample else None
        zs, mus, logvars = [], [], []
        for t in range(T):  # z_t needs h^lat_{t-1}, which needs z_{t-1}: sequential
            mu, logvar = rest(nn.functional.linear(h, w_lat) + data_term[t]).chunk(2, dim=-1)
            z = mu + noise[t] * (0.5 * logvar).exp() if sample else mu
            h, c = self.e_lat(z, (h, c))
            zs.append(z), mus.append(mu), logvars.append(logvar)
        return torch.stack(zs, 1), torch.stack(mus, 1), torch.stack(logvars, 1)


class DVAEOutput(NamedTuple):
    x_hat: torch.Tensor  # (B, T, D) decoder means of x_1..x_T
    z: torch.Tensor  # (B, T, L)
    q_mu: torch.Tensor  # (B, T, L)
    q_logvar: torch.Tensor  # (B, T, L)
    p_mu: torch.Tensor  # (B, T, L)
    p_logvar: torch.Tensor  # (B, T, L)
    h: torch.Tensor  # (B, T+1, H) generative LSTM states h_0..h_T


class MotionDVAE(nn.Module):
    """The generative and inference models. They work on the standardised state
    (x - x_mean) / x_std; the statistics are buffers set from the training data, so they travel
    with the weights (and stay fixed, like the prior, in the denoising stage).

    The encoder reads the state times `enc_keep` (a buffer, saved with the weights): with
    `velocity` given, the velocity entries are zeroed (their standardised mean) and the encoder
    reads poses only. On clean data the velocities are finite differences of the poses the
    encoder reads anyway (x_t:T and, through z_<t, x_t-1); on noisy data they are the noise
    amplified by the frame rate: Gaussian noise of 0.1 rad on the joint rotations puts the
    standardised velocities 10-40 data standard deviations off, far outside anything the encoder
    was trained on, and the denoising stage then starts from a useless encoder (issue 4)."""

    def __init__(
        self,
        x_dim: int,
        latent_dim: int = 48,
        lstm_hidden: int = 1024,
        mlp_hidden: int = 1024,
        groups: int = 16,
        velocity: torch.Tensor | None = None,
    ):
        """velocity: (x_dim,) bool, True at the state's velocity entries, which the encoder then
        does not read; None: the encoder reads the whole state (the paper's wording)."""
        super().__init__()
        self.x_dim, self.latent_dim = x_dim, latent_dim
        self.gen = Generative(x_dim, latent_dim, lstm_hidden, mlp_hidden, groups)
        self.enc = Encoder(x_dim, latent_dim, lstm_hidden, mlp_hidden, groups)
        self.register_buffer("x_mean", torch.zeros(x_dim))
        self.register_buffer("x_std", torch.ones(x_dim))
        keep = torch.ones(x_dim) if velocity is None else (~velocity.bool()).float()
        self.register_buffer("enc_keep", keep)

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # checkpoints from before enc_keep existed: their encoder read the whole state
        if prefix + "x_mean" in state_dict and prefix + "enc_keep" not in state_dict:
            state_dict[prefix + "enc_keep"] = torch.ones_like(state_dict[prefix + "x_mean"])
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def normalize(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.x_mean) / self.x_std

    def denormalize(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.x_std + self.x_mean

    def forward(self, x0: torch.Tensor, x: torch.Tensor, sample: bool = True) -> DVAEOutput:
        """x0 (B, D) first frame, x (B, T, D) the frames after it; standardised states."""
        z, q_mu, q_logvar = self.enc(x0 * self.enc_keep, x * self.enc_keep, sample)
        x_hat, p_mu, p_logvar, h = self.gen(x0, z)
        return DVAEOutput(x_hat, z, q_mu, q_logvar, p_mu, p_logvar, h)


class InitialStatePredictor(nn.Module):
    """q_omega(x_0 | y_0:T) = N(mu, diag exp(logvar)) (paper E.1): an anti-causal LSTM over the
    observed (standardised) states, its state at t = 0 through an MLP. The mean is predicted as a
    correction of the observed first pose with mean velocities: finite differences of noisy
    observations are mostly noise, so the predictor starts from the pose alone, and its LSTM
    reads the observed poses only (velocity entries zeroed), as the encoder does (MotionDVAE)."""

    def __init__(self, x_dim: int, lstm_hidden: int, mlp_hidden: int, groups: int, velocity: torch.Tensor):
        """velocity: (x_dim,) bool, True at the state's velocity entries."""
        super().__init__()
        self.r_h = nn.LSTM(x_dim, lstm_hidden, batch_first=True)
        self.e_ini = MLP(lstm_hidden, mlp_hidden, 2 * x_dim, groups)
        nn.init.zeros_(self.e_ini.net[-1].weight)
        nn.init.zeros_(self.e_ini.net[-1].bias)
        self.register_buffer("pose", (~velocity).float(), persistent=False)

    def forward(self, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """y (B, T+1, D) observed states y_0..y_T -> mu, logvar (B, D)."""
        h = self.r_h((y * self.pose).flip(1))[0][:, -1]  # after reading the poses y_T .. y_0
        delta, logvar = self.e_ini(h).chunk(2, dim=-1)
        return y[:, 0] * self.pose + delta, logvar - 8.0  # starts at a small spread: std e^-4 ~ 0.02


class NoisePredictor(nn.Module):
    """q_gamma(v_t | z_1:t, y_t, x_0) = prod IG(v; alpha, beta) over observed coordinates (paper E.1):
    e_b([h_t, y_t]). Parametrised relative to the prior IG(lambda/2, lambda/2):
    alpha = lambda/2 exp(a), beta = lambda/2 exp(b), so it starts at the prior for any lambda."""

    def __init__(self, lstm_hidden: int, obs_dim: int, mlp_hidden: int, groups: int):
        super().__init__()
        self.e_b = MLP(lstm_hidden + obs_dim, mlp_hidden, 2 * obs_dim, groups)
        nn.init.zeros_(self.e_b.net[-1].weight)
        nn.init.zeros_(self.e_b.net[-1].bias)

    def forward(self, h: torch.Tensor, y3d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """h (B, T+1, H), y3d (B, T+1, K) -> log-ratios a, b (B, T+1, K)."""
        a, b = self.e_b(torch.cat([h, y3d], dim=-1)).chunk(2, dim=-1)
        return a.clamp(-20, 20), b.clamp(-20, 20)


# --- divergences, summed by the caller ---


def gaussian_kl(q_mu: torch.Tensor, q_logvar: torch.Tensor, p_mu: torch.Tensor, p_logvar: torch.Tensor) -> torch.Tensor:
    """Elementwise KL(N(q_mu, e^q_logvar) || N(p_mu, e^p_logvar))."""
    return 0.5 * (p_logvar - q_logvar + (q_logvar.exp() + (q_mu - p_mu) ** 2) / p_logvar.exp() - 1.0)


def inverse_gamma_kl(alpha: torch.Tensor, beta: torch.Tensor, alpha_p: float, beta_p: float) -> torch.Tensor:
    """Elementwise KL(IG(alpha, beta) || IG(alpha_p, beta_p)) (paper C.2.4), in float64: with the
    Gaussian setting's large lambda each term is ~lambda and the KL a small difference of them."""
    a, b = alpha.double(), beta.double()
    ap = torch.as_tensor(alpha_p, dtype=torch.float64, device=a.device)
    bp = torch.as_tensor(beta_p, dtype=torch.float64, device=a.device)
    return (
        (a - ap) * torch.digamma(a) - torch.lgamma(a) + torch.lgamma(ap) + ap * (b.log() - bp.log()) + a * (bp - b) / b
    )
