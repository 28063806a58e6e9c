"""A jitter remover for joint positions of any rig: a learned correction to a low-pass filter.

Jitter (sensor noise, noisy joint rotations, a wobbling marker) is removed in two steps. A
zero-phase low-pass at `cutoff_hz` (the biomechanics habit: human motion lives below ~6 Hz, white
noise everywhere) takes out the noise above the cutoff. What stays is the noise below it, which no
filter can tell from motion. The network sees the low-passed motion and how much noise is left in
it (residual_noise, measured on the input itself), and predicts a correction from what bodies do:
bones keep their length, joints of a limb move together, a still foot stays still. Its last layer
starts at zero, so an untrained network is exactly the low-pass: training can only add to it.

The low-pass and the noise measure are defined in Hz and metres, not in frames: fix applies them
at the recording's own frame rate (say 120 fps) and runs the network on the result resampled to
the network's rate (window_fps); the low-passed motion has nothing left to alias there.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn as nn
import torch.nn.functional as F

LOWPASS_SPAN_S = 1.6  # FIR length: a transition band ~2 Hz wide whatever the frame rate
NOISE_SPAN_S = 1.0  # the noise level is a running measure over this long


def lowpass_taps(fps: float, cutoff_hz: float, dtype=torch.float64) -> torch.Tensor:
    """A Hamming-windowed sinc (symmetric: zero phase), unit gain at 0 Hz -> (2 half + 1,)."""
    if not 0 < cutoff_hz < fps / 2:
        raise ValueError(f"a {fps:g} fps recording cannot be low-passed at {cutoff_hz:g} Hz (at most half its rate)")
    half = max(1, round(LOWPASS_SPAN_S * fps / 2))
    n = torch.arange(-half, half + 1, dtype=dtype)
    fc = cutoff_hz / fps  # cycles per frame
    h = 2 * fc * torch.sinc(2 * fc * n) * torch.hamming_window(2 * half + 1, periodic=False, dtype=dtype)
    return h / h.sum()


def _extend(c: torch.Tensor, pad: int) -> torch.Tensor:
    """c: (N, C, T) -> (N, C, T + 2 pad): each end continued by odd reflection (2 x_0 - x_k, as
    scipy's filtfilt does), so a take keeps its trend at the ends instead of being pulled flat;
    beyond what a short take can reflect, its end frame repeats."""
    T = c.shape[-1]
    r = min(pad, T - 1)
    if r:
        left = 2 * c[..., :1] - c[..., 1 : r + 1].flip(-1)
        right = 2 * c[..., -1:] - c[..., T - r - 1 : T - 1].flip(-1)
        c = torch.cat([left, c, right], dim=-1)
    return F.pad(c, (pad - r, pad - r), mode="replicate") if pad > r else c


def lowpass(x: torch.Tensor, fps: float, cutoff_hz: float) -> torch.Tensor:
    """x: (B, T, ...) sampled at fps -> the same shape, every channel low-passed along time (dim 1),
    zero phase. x must be finite (fill holes first)."""
    B, T = x.shape[:2]
    h = lowpass_taps(fps, cutoff_hz, x.dtype).to(x.device)
    c = x.reshape(B, T, -1).transpose(1, 2)  # (B, C, T)
    C = c.shape[1]
    c = _extend(c, (len(h) - 1) // 2)
    y = F.conv1d(c.reshape(B * C, 1, -1), h.view(1, 1, -1)).reshape(B, C, T)
    return y.transpose(1, 2).reshape(x.shape)


def residual_noise(x: torch.Tensor, base: torch.Tensor, fps: float, cutoff_hz: float) -> torch.Tensor:
    """How much noise the low-pass left in base = lowpass(x), per joint and frame, metres.

    x, base: (B, T, J, 3) -> (B, T, J). The part of x above the cutoff is measured (a running
    mean of its power over NOISE_SPAN_S); white noise spreads evenly over 0..fps/2, so the part
    below the cutoff, still in base, is that power times cutoff / (fps/2 - cutoff). The same
    noise therefore reads the same at 30 and at 120 fps, which is what lets a network trained at
    one rate run on recordings of another."""
    nyquist = fps / 2
    if not 0 < cutoff_hz < nyquist:
        raise ValueError(f"a {fps:g} fps recording cannot be low-passed at {cutoff_hz:g} Hz (at most half its rate)")
    power = ((x - base) ** 2).mean(-1)  # (B, T, J) per coordinate
    B, T, J = power.shape
    half = max(1, round(NOISE_SPAN_S * fps / 2))
    c = F.pad(power.transpose(1, 2).reshape(B * J, 1, T), (half, half), mode="replicate")
    local = F.avg_pool1d(c, 2 * half + 1, stride=1).reshape(B, J, T).transpose(1, 2)
    return (local * (cutoff_hz / (nyquist - cutoff_hz))).clamp_min(0).sqrt()


@dataclass
class JitterConfig:
    num_joints: int
    num_frames: int  # the training window; the network is convolutional and runs on any length
    cutoff_hz: float = 6.0
    width: int = 128
    depth: int = 5  # residual blocks, dilations 1, 2, 4, ...: ~2 s of context at 30 fps
    kernel_size: int = 3
    unit_m: float = 0.01  # the network reads noise levels and writes corrections in centimetres


class ResidualBlock(nn.Module):
    def __init__(self, width: int, kernel_size: int, dilation: int):
        super().__init__()
        self.conv = nn.Conv1d(width, width, kernel_size, dilation=dilation, padding=dilation * (kernel_size // 2))
        self.mix = nn.Conv1d(width, width, 1)

    def forward(self, h: torch.Tensor) -> torch.Tensor:  # (B, width, T)
        return h + self.mix(F.gelu(self.conv(F.gelu(h))))


class JitterNet(nn.Module):
    """(low-passed positions, residual noise) -> denoised positions, at window_fps."""

    def __init__(self, config: JitterConfig):
        super().__init__()
        if config.kernel_size % 2 == 0:
            raise ValueError(f"kernel_size must be odd (centred in time), got {config.kernel_size}")
        self.config = config
        J, width = config.num_joints, config.width
        self.inp = nn.Conv1d(4 * J + 2, width, 5, padding=2)  # per joint x, y, z, noise; the root's velocity
        self.blocks = nn.ModuleList(ResidualBlock(width, config.kernel_size, 2**i) for i in range(config.depth))
        self.out = nn.Conv1d(width, 3 * J, 1)
        nn.init.zeros_(self.out.weight)  # untrained: the correction is 0, the output the low-pass
        nn.init.zeros_(self.out.bias)

    @property
    def cutoff_hz(self) -> float:
        return self.config.cutoff_hz

    @property
    def receptive_field(self) -> int:
        """Frames on each side of a frame that its output depends on: the root's velocity (1), the
        input layer (2) and the residual blocks."""
        k = self.config.kernel_size // 2
        return 1 + 2 + sum(k * 2**i for i in range(self.config.depth))

    def forward(self, base: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        """base: (B, T, J, 3) low-passed positions, metres, z up; noise: (B, T, J) residual_noise
        -> (B, T, J, 3) denoised positions, metres."""
        B, T, J, _ = base.shape
        unit = self.config.unit_m
        # Where the body is on the floor says nothing about jitter: every frame is seen from its
        # root's place over the ground (height kept: the floor matters), and the root's path as
        # its velocity. So the network reads a take in pieces exactly as it reads it whole
        # (receptive_field), and a long walk does not take it far from its training windows.
        root = base[:, :, :1, :2]  # (B, T, 1, 2)
        local = torch.cat([base[..., :2] - root, base[..., 2:]], dim=-1)  # (B, T, J, 3)
        velocity = (
            torch.gradient(root[:, :, 0], dim=1)[0] if T > 1 else torch.zeros_like(root[:, :, 0])
        )  # (B, T, 2) m/frame
        h = torch.cat([local.flatten(2), velocity / unit, noise / unit], dim=-1).transpose(1, 2)  # (B, 4 J + 2, T)
        h = self.inp(h)
        for block in self.blocks:
            h = block(h)
        correction = self.out(F.gelu(h)).transpose(1, 2).reshape(B, T, J, 3)
        return base + unit * correction
