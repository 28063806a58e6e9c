"""XMAE's training input: a clean batch -> the corrupted, normalised, rotated tokens the encoder
reads, and the target in the same frame. The corruption is the data's (data/corruption.py), the
normalisation and the token index the model's (models/xmae_inference.py); this is where they meet.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from mocapfix.data.corruption import Corrupted, kept_count, random_z_rotation, rotate_z, xmae_training_corruption
from mocapfix.models.xmae_inference import kept_index, normalize


class TrainingInput(NamedTuple):
    tokens: torch.Tensor  # (B, N, 3) the model's input: normalised (and rotated) corrupted positions
    target: torch.Tensor  # (B, T, J, 3) the clean positions in the same frame (NaN where the data has none)
    corrupted: Corrupted  # which tokens are observed / displaced
    offset: torch.Tensor  # (B, 1, 1, 3) the normalisation offset
    kept: torch.Tensor  # (B, K) observed token indices
    padding: torch.Tensor  # (B, K) True where a sample kept fewer than K tokens


def xmae_training_input(
    positions: torch.Tensor,
    mask_ratio: float,
    displace_ratio: float,
    max_displacement_m: float,
    fixed_kept_count: bool = True,
    rotate: bool = True,
    generator: torch.Generator | None = None,
    gap_ratio: float = 0.0,
    hole_ratio: float = 0.0,
    part_joints: torch.Tensor | None = None,
    max_hole_frames: int = 0,
) -> TrainingInput:
    """XMAE's training input of a batch (B, T, J, 3), all on the batch's device: mask and
    displace (xmae_training_corruption), normalise, rotate about z (rotate=True), index the
    observed tokens. With a fixed kept count, K is known without reading the data: no host-device
    sync. hole_ratio > 0: K is every token, the encoder reads whole windows."""
    B, T, J, _ = positions.shape
    c = xmae_training_corruption(
        positions,
        mask_ratio,
        displace_ratio,
        max_displacement_m,
        fixed_kept_count,
        generator,
        gap_ratio,
        hole_ratio,
        part_joints,
        max_hole_frames,
    )
    x, offset = normalize(c.positions, c.observed)
    target = positions - offset
    if rotate:
        x, angle = random_z_rotation(x, generator)
        target = rotate_z(target, angle)
    if hole_ratio > 0:
        count = T * J
    else:
        count = kept_count(T * J, mask_ratio) if fixed_kept_count else None
    kept, padding = kept_index(c.observed, count)
    return TrainingInput(x.reshape(B, T * J, 3), target, c, offset, kept, padding)
