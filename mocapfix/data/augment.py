"""Body augmentations: each training window played by another body, so that a model trained on a
few studios' performers learns human motion rather than those performers.

A model trained on three actors learns their proportions, their rig's joint placement and which
way they turn (docs/results.md, "Strangers"). Here every window gets, on the device, per sample:
- a stature: every bone scaled by one factor (a shorter or taller person), the root's height and
  its path over the ground scaled by the same factor times the legs' (longer legs, longer strides;
  feet on the floor stay on the floor);
- limb proportions: arms, legs and the spine with neck and head scaled each by its own factor
  (both arms alike, both legs alike: people are roughly symmetric), on top of the stature;
- a mirror image (left and right swapped, x negated): left-handed motion for right-handed actors;
- joint placement: every joint moved by a constant offset within a small ball, as another rig or
  another marker set puts the same joint a few cm elsewhere.
Heading (a rotation about z) is drawn later, in training/xmae_input.py, and tempo in the data module
(MotionDataModule.tempo_factors: windows from clips resampled faster and slower).

Everything works on (B, T, J, 3) metre batches, z up, NaN = missing; a joint whose chain to the
root holds a missing bone in a frame becomes missing there (its new place is not known).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from mocapfix.core.skeleton import Skeleton
from mocapfix.data.corruption import normal_like, uniform_like
from mocapfix.rig.names import side_and_word


@dataclass(frozen=True)
class BodyAugment:
    """Ranges of the body augmentations (1.0 / 0 / 0.0: off). Factors are drawn uniformly in
    [1 - x, 1 + x]: stature_range 0.1 plays people 10 % shorter to 10 % taller than the actor."""

    stature_range: float = 0.0
    limb_range: float = 0.0
    mirror_prob: float = 0.0
    joint_shift_m: float = 0.0

    @property
    def active(self) -> bool:
        return self.stature_range > 0 or self.limb_range > 0 or self.mirror_prob > 0 or self.joint_shift_m > 0

    def check(self) -> None:
        for name in ("stature_range", "limb_range"):
            value = getattr(self, name)
            if not 0.0 <= value < 0.5:
                raise ValueError(f"{name} must be in [0, 0.5) (a relative change of bone length), got {value}")
        if not 0.0 <= self.mirror_prob <= 1.0:
            raise ValueError(f"mirror_prob must be in [0, 1], got {self.mirror_prob}")
        if not 0.0 <= self.joint_shift_m <= 0.2:
            raise ValueError(f"joint_shift_m must be in [0, 0.2] m (a joint's placement), got {self.joint_shift_m}")


def mirror_index(skeleton: Skeleton) -> list[int]:
    """Each joint's mirror partner by name (`Hand_L` <-> `Hand_R`, `LeftArm` <-> `RightArm`),
    itself for joints on the midline. ValueError when a sided joint has no partner: mirroring
    would then move a left arm onto the body's midline."""
    keys = [side_and_word(n) for n in skeleton.joint_names]
    index = {k: j for j, k in enumerate(keys)}
    flip = {"left": "right", "right": "left"}
    out = []
    for j, (side, word) in enumerate(keys):
        if side is None:
            out.append(j)
            continue
        partner = index.get((flip[side], word))
        if partner is None:
            raise ValueError(
                f"mirror augmentation: joint {skeleton.joint_names[j]!r} has no {flip[side]} partner in this skeleton"
            )
        out.append(partner)
    return out


def mirror_of(skeleton: Skeleton) -> list[int] | None:
    """mirror_index, or None for a skeleton whose sides do not pair up by name (nothing mirrored)."""
    try:
        return mirror_index(skeleton)
    except ValueError:
        return None


def mirrored(x, partner):
    """x: (..., J, 3), z up, numpy or torch -> its mirror image: each joint swapped with its partner
    (mirror_index), x negated (a reflection in a vertical plane: any plane will do for a body that
    may face any way)."""
    out = x[..., partner, :]  # advanced indexing: a copy
    out[..., 0] = -out[..., 0]
    return out


def _limb_of(skeleton: Skeleton) -> list[int]:
    """0 for the root, 1 arms (and shoulders), 2 legs, 3 spine, neck and head: each joint's
    part, from the skeleton's groups and the joints below the arms' first joints."""
    groups = skeleton.groups
    arm = {j for g in ("left_arm", "right_arm") for j in groups.get(g, ())}
    leg = {j for g in ("left_leg", "right_leg") for j in groups.get(g, ())}
    parts = []
    for j, p in enumerate(skeleton.parents):
        parts.append(0 if p < 0 else 1 if j in arm else 2 if j in leg else 3)
    return parts


class BodyAugmenter(torch.nn.Module):
    """BodyAugment applied to batches of one skeleton (a Module so that its index buffers follow
    the batch's device)."""

    def __init__(self, skeleton: Skeleton, augment: BodyAugment):
        super().__init__()
        augment.check()
        self.augment = augment
        parents = list(skeleton.parents)
        J = len(parents)
        if sum(p < 0 for p in parents) != 1 or any(p >= j for j, p in enumerate(parents) if p >= 0):
            raise ValueError("body augmentation needs one tree with parents before children")
        # chain[j, a] = 1 when bone a (from a's parent to a) lies on the way from the root to j
        chain = torch.zeros(J, J)
        for j in range(J):
            a = j
            while parents[a] >= 0:
                chain[j, a] = 1.0
                a = parents[a]
        self.register_buffer("chain", chain, persistent=False)
        self.register_buffer("parents", torch.tensor([max(p, 0) for p in parents]), persistent=False)
        self.register_buffer("part", torch.tensor(_limb_of(skeleton)), persistent=False)
        self.root = parents.index(-1)
        mirror = mirror_index(skeleton) if augment.mirror_prob > 0 else list(range(J))
        self.register_buffer("mirror", torch.tensor(mirror), persistent=False)

    def forward(self, positions: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        # positions: (B, T, J, 3) metres, NaN = missing -> (B, T, J, 3)
        a = self.augment
        if not a.active:
            return positions
        B, T, J, _ = positions.shape
        x = positions
        if a.stature_range > 0 or a.limb_range > 0:
            x = self._proportions(x, generator)
        if a.mirror_prob > 0:
            flip = uniform_like((B,), generator, x) < a.mirror_prob  # (B,)
            x = torch.where(flip[:, None, None, None], mirrored(x, self.mirror), x)
        if a.joint_shift_m > 0:
            # uniform in a ball: a direction, and a radius with density growing as r^2
            direction = torch.nn.functional.normalize(normal_like((B, 1, J, 3), generator, x), dim=-1)
            radius = a.joint_shift_m * uniform_like((B, 1, J, 1), generator, x) ** (1 / 3)
            x = x + (direction * radius).to(x.dtype)
        return x

    def _proportions(self, x: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
        a = self.augment
        B = x.shape[0]
        stature = 1 + a.stature_range * (2 * uniform_like((B, 1), generator, x) - 1)  # (B, 1)
        limb = 1 + a.limb_range * (2 * uniform_like((B, 4), generator, x) - 1)  # (B, 4) root arms legs spine
        limb[:, 0] = 1.0
        scale = (stature * limb)[:, self.part].to(x.dtype)  # (B, J) each bone's factor
        bones = x - x[:, :, self.parents]  # (B, T, J, 3), the root's own is 0
        missing = torch.isnan(bones).any(-1)  # (B, T, J)
        bones = torch.where(missing[..., None], 0.0, bones) * scale[:, None, :, None]
        # every joint = the new root + the scaled bones on its chain; a missing bone on the chain
        # makes the joint missing
        chain = self.chain.to(x.dtype)
        lost = torch.einsum("ja,bta->btj", chain, missing.to(x.dtype)) > 0  # (B, T, J)
        root = x[:, :, self.root]  # (B, T, 3)
        # the root's height and its path over the ground follow the legs: feet on the floor stay there
        ground = (stature * limb[:, 2:3]).to(x.dtype)[:, :, None]  # (B, 1, 1)
        centre = torch.nanmean(root[..., :2], dim=1, keepdim=True)  # (B, 1, 2)
        centre = torch.nan_to_num(centre)
        root = torch.cat([centre + (root[..., :2] - centre) * ground, root[..., 2:] * ground], dim=-1)
        out = root[:, :, None] + torch.einsum("ja,btac->btjc", chain, bones)
        return torch.where(lost[..., None] | torch.isnan(x).any(-1, keepdim=True), torch.nan, out)
