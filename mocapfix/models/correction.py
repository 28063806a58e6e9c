"""A learned correction to a classical fill: what a capture's motion says the fill gets wrong.

A classical fill (the cubic Hermite, or the limb fill: fills/classical.py) is hard to beat on a
hole with data around it; what it gets wrong is not noise. Within one capture (the same studio,
markers and solver; new performers and days) the error follows from the motion around the hole:
a ridge regression from the frames around a centred full-body hole to the fill's error took
5-13 % off the limb fill on Human3.6M's held-out subjects (docs/results.md). XMAE, reading the
fill through attention, learned no correction on a CPU budget (its output layer stayed at zero),
and an MLP over the whole window has to learn every place a hole can sit separately.

So the network reads the hole, not the window: `context_frames` frames before and after it (all
joints), the base fill at `hole_points` points spread over the hole (whatever its length), which
joints are missing and for how long; everything turned to one heading (the hips' left-right
axis) and moved to the context's mean position. An MLP with a linear path beside it (the ridge's)
outputs the correction at those points, read back at every frame of the hole by linear
interpolation in the hole's own time. Both output layers start at zero: an untrained network is
exactly its base fill, so training can only add to it.

Beside them, a bank of linear maps (`length_buckets` > 0): one per kind of hole (a part the
training holes take, `part_groups`, and a range of lengths), fitted in closed form by ridge
regression (training/ridge_bank.py) before the MLP trains on what it leaves. One linear
map over holes of every length and part learns next to nothing (the same features mean other
things for a 3-frame arm hole and a 27-frame body hole: on Bandai's val windows 69.2 -> 67.3 mm
at 0.9 s), one per kind (body holes of 25-30 frames) half of it (69.2 -> 36.1 mm), where the
MLP, trained by gradient steps on a CPU budget, took a fifth off in whole takes.

Shapes: x (B, T, J, 3) metres, z up, every token finite (holes filled by the base fill);
hole (B, T, J) bool, the tokens the fill made. One hole per window is corrected: the longest run
of frames with a missing token (the protocol's gap, a training hole); other missing tokens keep
the base fill.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch
import torch.nn as nn

from mocapfix.fills.classical import hermite_infill, limb_infill

BASES = ("hermite", "limb")
MOTION_SCALE = 2.0  # features per metre: a body about its centre within about 1
# The network outputs centimetres: a fill's error is a few of them, and an optimiser's first
# steps on a wide zero-initialised layer would otherwise move every hole by decimetres.
CORRECTION_UNIT_M = 0.01


@dataclass
class CorrectionConfig:
    num_joints: int
    fps: float  # the frame rate it reads (a hole's length in seconds is an input)
    base: str = "hermite"  # the classical fill it corrects (fills/classical.py)
    context_frames: int = 10  # read on each side of the hole
    hole_points: int = 16  # the correction's samples over the hole
    hidden: int = 512
    depth: int = 2  # hidden layers
    heading_joints: tuple[int, int] = (0, 0)  # (left, right) hip: the body's left-right axis; equal: none
    parents: tuple[int, ...] = ()  # the skeleton's, for the limb fill
    # the linear bank: one map per part (the joints a hole takes: the whole body, each limb) and
    # per range of hole lengths (length_buckets equal ranges of 1..max_hole_frames); 0: none
    length_buckets: int = 0
    max_hole_frames: int = 0
    part_groups: tuple[tuple[int, ...], ...] = ()


class Features(NamedTuple):
    """What CorrectionNet reads of each window's hole (its `features`)."""

    values: torch.Tensor  # (B, inputs): the context, the fill at the hole's points, which frames and joints, the length
    turn: torch.Tensor  # (B, 2, 2): world xy -> the canonical heading
    start: torch.Tensor  # (B,) long: the hole's first frame
    length: torch.Tensor  # (B,) long: its frames
    part: torch.Tensor  # (B, J) bool: its joints
    points: torch.Tensor  # (B, K) float: the frames (fractional) the correction is sampled at


def longest_run(hole: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """hole: (B, T, J) -> (start, length) (B,) long of each window's longest run of frames with a
    missing token (length 0: none)."""
    B, T, _ = hole.shape
    frames = hole.any(-1).long()  # (B, T)
    t = torch.arange(T, device=hole.device)
    # the frame each run started at, carried along it (-1 outside runs)
    opened = torch.where(frames.bool() & (torch.cat([frames.new_zeros(B, 1), frames[:, :-1]], 1) == 0), t, -1)
    began = opened.cummax(1).values
    length = torch.where(frames.bool(), t - began + 1, 0)  # (B, T) the run's length so far
    end = length.argmax(1)  # (B,) the last frame of the longest run
    longest = length.gather(1, end[:, None])[:, 0]
    return end - longest + 1, longest


def at_frames(x: torch.Tensor, frames: torch.Tensor) -> torch.Tensor:
    """x: (B, T, J, 3), frames: (B, F) float, clamped to [0, T - 1] -> (B, F, J, 3) linearly interpolated."""
    T = x.shape[1]
    f = frames.clamp(0, T - 1)
    lo = f.floor().long()
    hi = (lo + 1).clamp_max(T - 1)
    w = (f - lo.to(f.dtype))[..., None, None].to(x.dtype)
    take = lambda i: x.gather(1, i[..., None, None].expand(-1, -1, *x.shape[2:]))  # noqa: E731
    return take(lo) * (1 - w) + take(hi) * w


class CorrectionNet(nn.Module):
    def __init__(self, config: CorrectionConfig):
        super().__init__()
        if config.base not in BASES:
            raise ValueError(f"base fill {config.base!r}: one of {', '.join(BASES)}")
        self.config = config
        C, K, J = config.context_frames, config.hole_points, config.num_joints
        inputs = (2 * C + K) * J * 3 + 2 * C + J + 1  # context and fill; context frames inside; joints; length
        layers, width = [], inputs
        for _ in range(config.depth):
            layers += [nn.Linear(width, config.hidden), nn.GELU()]
            width = config.hidden
        self.body = nn.Sequential(*layers)
        self.out = nn.Linear(width, K * J * 3)
        self.linear = nn.Linear(inputs, K * J * 3)  # the ridge's path
        for layer in (self.out, self.linear):
            nn.init.zeros_(layer.weight)
            nn.init.zeros_(layer.bias)
        self.groups = tuple(tuple(int(j) for j in g) for g in config.part_groups)
        if config.length_buckets:
            if config.max_hole_frames < config.length_buckets or not self.groups:
                raise ValueError("a linear bank needs max_hole_frames >= length_buckets and part_groups")
            masks = torch.zeros(len(self.groups), J, dtype=torch.bool)
            for g, joints in enumerate(self.groups):
                masks[g, list(joints)] = True
            self.register_buffer("group_masks", masks, persistent=False)
            # bank_g: (buckets, inputs + 1, K x joints of g x 3), the last row a bias; buffers:
            # fitted in closed form (training/ridge_bank.py), never by the optimiser
            for g, joints in enumerate(self.groups):
                self.register_buffer(f"bank_{g}", torch.zeros(config.length_buckets, inputs + 1, K * len(joints) * 3))
            self.register_buffer("bank_fitted", torch.zeros((), dtype=torch.bool))

    def features(self, x: torch.Tensor, hole: torch.Tensor) -> Features:
        """x: (B, T, J, 3) the windows with their holes filled by the base fill; hole: (B, T, J)
        -> what the network reads of each window's longest hole, seen in its own place and heading."""
        cfg = self.config
        B, T, J, _ = x.shape
        C, K = cfg.context_frames, cfg.hole_points
        start, length = longest_run(hole)  # (B,)
        n = length.clamp_min(1).to(x.dtype)
        offsets = torch.arange(1, C + 1, device=x.device)
        around = torch.cat([start[:, None] - offsets.flip(0), start[:, None] + length[:, None] - 1 + offsets], 1)
        inside = ((around >= 0) & (around < T)).to(x.dtype)  # (B, 2C): frames of the window
        context = at_frames(x, around.to(x.dtype))  # (B, 2C, J, 3), edge frames repeated outside
        points = start[:, None].to(x.dtype) - 0.5 + (torch.arange(K, device=x.device) + 0.5) * n[:, None] / K
        fill = at_frames(x, points)  # (B, K, J, 3)
        part = hole.gather(1, start.clamp(0, T - 1)[:, None, None].expand(-1, 1, J))[:, 0]  # (B, J)

        # one place and heading: the context's mean xy at 0, the hips' left-right axis along +x
        weight = inside[..., None, None]
        centre = (context * weight).sum((1, 2)) / (weight.sum((1, 2)) * J).clamp_min(1)  # (B, 3)
        left, right = cfg.heading_joints
        axis = ((context[:, :, left, :2] - context[:, :, right, :2]) * inside[..., None]).sum(1)  # (B, 2)
        angle = torch.atan2(axis[:, 1], axis[:, 0])  # 0 where the hips are one joint
        c, s = torch.cos(angle), torch.sin(angle)
        turn = torch.stack([torch.stack([c, s], -1), torch.stack([-s, c], -1)], -2)  # (B, 2, 2): by -angle

        def canonical(p: torch.Tensor) -> torch.Tensor:  # (B, F, J, 3) -> the same, turned and moved
            p = p - centre[:, None, None]
            return torch.cat([torch.einsum("bij,bfkj->bfki", turn, p[..., :2]), p[..., 2:]], -1)

        values = torch.cat(
            [
                (canonical(context) * MOTION_SCALE).reshape(B, -1),
                (canonical(fill) * MOTION_SCALE).reshape(B, -1),
                inside,
                part.to(x.dtype),
                (length.to(x.dtype) / cfg.fps)[:, None],
            ],
            1,
        )
        return Features(values, turn, start, length, part, points)

    def cells(self, f: Features) -> tuple[torch.Tensor, torch.Tensor]:
        """Each window's kind of hole in the bank -> (group, bucket) (B,) long: the part group its
        hole's joints are (-1: none of them, no bank term), its length's range."""
        match = (f.part[:, None, :] == self.group_masks[None]).all(-1)  # (B, G)
        group = torch.where(match.any(1), match.to(torch.uint8).argmax(1), -1)
        cfg = self.config
        n, buckets = (f.length - 1).clamp_min(0), cfg.length_buckets
        bucket = (n * buckets // cfg.max_hole_frames).clamp_max(buckets - 1)
        return group, bucket

    def bank(self, f: Features) -> torch.Tensor:
        """The bank's correction at the hole's points, in the canonical frame and CORRECTION_UNIT_M
        -> (B, K, J, 3); zero for a hole of no part group."""
        K, J = self.config.hole_points, self.config.num_joints
        out = f.values.new_zeros(len(f.values), K, J, 3)
        group, bucket = self.cells(f)
        with_bias = torch.cat([f.values, torch.ones_like(f.values[:, :1])], 1)  # (B, inputs + 1)
        for g, joints in enumerate(self.groups):
            weights = getattr(self, f"bank_{g}")  # (buckets, inputs + 1, K x |g| x 3)
            for b in torch.unique(bucket[group == g]).tolist():
                sel = torch.nonzero((group == g) & (bucket == b)).flatten()
                values = (with_bias[sel] @ weights[b].to(with_bias.dtype)).reshape(len(sel), K, len(joints), 3)
                rows = out.new_zeros(len(sel), K, J, 3)
                rows[:, :, list(joints)] = values
                out[sel] = rows
        return out

    def forward(self, x: torch.Tensor, hole: torch.Tensor) -> torch.Tensor:
        """x: (B, T, J, 3) the windows with their holes filled by the base fill; hole: (B, T, J)
        -> (B, T, J, 3): x plus the correction at the tokens of each window's longest hole."""
        cfg = self.config
        B, T, J, _ = x.shape
        K = cfg.hole_points
        f = self.features(x, hole)
        features, turn, start, length = f.values, f.turn, f.start, f.length
        n = length.clamp_min(1).to(x.dtype)
        delta = (self.out(self.body(features)) + self.linear(features)).reshape(B, K, J, 3)
        if cfg.length_buckets:
            delta = delta + self.bank(f)
        delta = CORRECTION_UNIT_M * delta
        delta = torch.cat([torch.einsum("bji,bkmj->bkmi", turn, delta[..., :2]), delta[..., 2:]], -1)
        # read back at every frame of the hole: u in [0, K - 1] over the hole's own time
        t = torch.arange(T, device=x.device)[None].to(x.dtype)  # (1, T)
        u = (t - start[:, None].to(x.dtype) + 0.5) * K / n[:, None] - 0.5  # (B, T)
        per_frame = at_frames(delta, u)  # (B, T, J, 3)
        in_run = (t >= start[:, None]) & (t < (start + length)[:, None])  # (B, T)
        return x + per_frame * (hole & in_run[..., None])[..., None].to(x.dtype)


def base_fill(config: CorrectionConfig, positions: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
    """positions (B, T, J, 3), NaN allowed at missing tokens; observed (B, T, J) -> the base fill
    of every missing token (B, T, J, 3), observed tokens as given."""
    if config.base == "limb":
        return limb_infill(positions, observed, config.parents)
    return hermite_infill(positions, observed)


def correction_fill(
    net: CorrectionNet, positions: torch.Tensor, observed: torch.Tensor, base: torch.Tensor | None = None
) -> torch.Tensor:
    """The network's fill of windows: positions (B, T, J, 3), NaN allowed at missing tokens;
    observed (B, T, J) -> (B, T, J, 3), observed tokens as given, holes the corrected base fill.
    base: base_fill(net.config, positions, observed) where the caller has it already."""
    base = base_fill(net.config, positions, observed) if base is None else base
    out = net(base.to(next(net.parameters()).dtype), ~observed)
    return torch.where(observed[..., None], positions, out.to(positions.dtype))
