"""Corruption of batched motion: training masks/displacement, the paper's evaluation tasks,
z-rotation augmentation (XMAE sections 3.1 and 4.1). The per-window normalisation is the
model's (models/xmae_inference.py).

Everything works on torch tensors on whatever device the batch lives on. Tokens are the
T*J joint positions of a window, flattened t-major with the joint index fastest
(flat = t * J + j), the order of the paper's eq. (1).

Conventions shared by every function here:
- NaN in the input positions means "joint missing in the data". Such tokens are never
  observed, never displaced, and never handed back as model input.
- Corrupted.positions holds 0 at every unobserved token (never NaN): the model must read the
  observed mask, not the values, to know what is missing.
- Random draws come from `generator` when given (else torch's global RNG). A generator may live
  on another device than the batch: the numbers are drawn on the generator's device and moved,
  so a seeded CPU generator gives the same corruption on CPU and GPU.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch

from mocapfix.core import lazy_roma as roma
from mocapfix.core.kinematics import fk_axis_angle


class Corrupted(NamedTuple):
    positions: torch.Tensor  # (B, T, J, 3) corrupted input; 0 where not observed, never NaN
    observed: torch.Tensor  # (B, T, J) bool: token is given to the model
    displaced: torch.Tensor  # (B, T, J) bool: observed token whose position was moved (subset of observed)


# --- random numbers on the generator's device, moved to the batch's ---

# Drawn in float32 whatever the batch dtype: bf16 scores would tie and bias the token choice,
# and the same seed then gives the same corruption in every precision.


def uniform_like(shape, generator: torch.Generator | None, like: torch.Tensor) -> torch.Tensor:
    device = generator.device if generator is not None else like.device
    return torch.rand(shape, generator=generator, device=device).to(like.device)


def normal_like(shape, generator: torch.Generator | None, like: torch.Tensor) -> torch.Tensor:
    device = generator.device if generator is not None else like.device
    return torch.randn(shape, generator=generator, device=device).to(like.device)


def _index_mask(n: int, index: list[int] | None, device) -> torch.Tensor:
    """(n,) bool, True at `index` (None: everywhere)."""
    if index is None:
        return torch.ones(n, dtype=torch.bool, device=device)
    mask = torch.zeros(n, dtype=torch.bool, device=device)
    mask[torch.as_tensor(list(index), dtype=torch.long, device=device)] = True
    return mask


def available(positions: torch.Tensor) -> torch.Tensor:
    """positions: (..., 3) -> (...) bool, True where the token holds data (no NaN coordinate)."""
    return ~torch.isnan(positions).any(dim=-1)


def _pack(positions: torch.Tensor, observed: torch.Tensor, displaced: torch.Tensor) -> Corrupted:
    # torch.where, not multiplication: 0 * NaN would leak NaN into the model input
    return Corrupted(
        torch.where(observed[..., None], positions, torch.zeros((), dtype=positions.dtype, device=positions.device)),
        observed,
        displaced,
    )


def _pick_random(candidates: torch.Tensor, counts: torch.Tensor, generator, like: torch.Tensor) -> torch.Tensor:
    """candidates: (B, N) bool, counts: (B,) long -> (B, N) bool with min(counts[b], #candidates[b])
    entries per row, drawn uniformly among the candidates."""
    B, N = candidates.shape
    # Random scores, non-candidates pushed past every candidate; a token's rank in the sorted
    # scores decides whether it is among the first counts[b].
    scores = torch.where(candidates, uniform_like((B, N), generator, like), 2.0)
    order = scores.argsort(dim=1)
    rank = torch.empty_like(order).scatter_(1, order, torch.arange(N, device=order.device).expand(B, N))
    return candidates & (rank < counts[:, None])


def kept_count(num_tokens: int, mask_ratio: float) -> int:
    """Tokens each sample keeps under mask_and_displace(fixed_kept_count=True) when it has data."""
    return round((1.0 - mask_ratio) * num_tokens)


def training_gaps(
    B: int, T: int, gap_ratio: float, generator: torch.Generator | None, like: torch.Tensor
) -> torch.Tensor:
    """Whole-skeleton gaps for training: a fraction gap_ratio of the windows get one gap of
    1..T-2 frames (uniform), anywhere in the window (uniform start); the others none.
    -> (B, T) bool, True on the gap's frames.

    Random token masking at 85% leaves a few joints in nearly every frame, so a model trained
    on it alone seldom has to carry the whole body across a long hole, which is exactly the
    evaluation's (and real data's) hardest case: the full skeleton gone for up to 0.9 s."""
    draw = uniform_like((3, B), generator, like)  # (3, B)
    has_gap = draw[0] < gap_ratio
    length = 1 + (draw[1] * max(T - 2, 1)).long().clamp_max(max(T - 3, 0))  # (B,) in 1..T-2
    start = (draw[2] * (T - length + 1)).long().clamp_max(T - length)  # (B,)
    t = torch.arange(T, device=like.device)[None, :]  # (1, T)
    return has_gap[:, None] & (t >= start[:, None]) & (t < (start + length)[:, None])


def training_holes(
    B: int,
    T: int,
    part_joints: torch.Tensor,
    max_hole_frames: int,
    generator: torch.Generator | None,
    like: torch.Tensor,
    margin: int = 1,
    min_hole_frames: int = 1,
) -> torch.Tensor:
    """The case `fix` meets: one contiguous hole per window, of one part, in data observed all
    around it. part_joints: (P, J) bool, one row per part that can go missing (the whole body, an
    arm, a leg); each window draws a part uniformly, a length of min_hole_frames..max_hole_frames frames and a
    start leaving at least `margin` observed frames on either side, or as many as the window
    leaves around a hole that long (a take's holes have data all around; a window's edge is not
    the take's). -> (B, T, J) bool, True in the hole.

    The paper's 85 % random masking teaches a prior over whole poses; a model that corrects a
    classical fill must also learn what the fill gets wrong in a real hole, which random masking
    (a few joints left in nearly every frame) never shows it."""
    P, J = part_joints.shape
    longest = max(1, min(max_hole_frames, T - 2))
    draw = uniform_like((3, B), generator, like)  # (3, B)
    part = (draw[0] * P).long().clamp_max(P - 1)  # (B,)
    shortest = max(1, min(min_hole_frames, longest))
    length = shortest + (draw[1] * (longest - shortest + 1)).long().clamp_max(longest - shortest)  # (B,)
    first = ((T - length) // 2).clamp(max=margin)  # (B,) observed frames kept on either side
    room = (T - length - 2 * first + 1).clamp_min(1)  # (B,) possible starts
    start = first + (draw[2] * room).long().clamp_max(room - 1)  # (B,)
    t = torch.arange(T, device=like.device)[None, :]  # (1, T)
    in_time = (t >= start[:, None]) & (t < (start + length)[:, None])  # (B, T)
    return in_time[:, :, None] & part_joints.to(like.device)[part][:, None, :]  # (B, T, J)


def mask_and_displace(
    positions: torch.Tensor,
    mask_ratio: float = 0.85,
    displace_ratio: float = 0.05,
    max_displacement_m: float = 1.0,
    fixed_kept_count: bool = True,
    generator: torch.Generator | None = None,
    gap_ratio: float = 0.0,
) -> Corrupted:
    """Training corruption of XMAE: mask most tokens, displace a few of the kept ones.

    positions: (B, T, J, 3) metres, NaN = missing (never kept).
    Both ratios are fractions of all N = T*J tokens, as in the paper (85% masked, 5% displaced:
    the displaced tokens are 5/15 of the kept ones).

    fixed_kept_count=True: each sample keeps exactly K = round((1 - mask_ratio) * N) tokens drawn
    uniformly among its non-NaN tokens and displaces D = round(displace_ratio * N) of them. A sample
    with fewer than K non-NaN tokens keeps all of them (its kept count is then smaller) and
    displaces round(kept * D / K) of them, so the displaced share of the kept tokens stays the same.
    fixed_kept_count=False: independent Bernoulli draws, keep with p = 1 - mask_ratio, and displace a
    kept token with p = displace_ratio / (1 - mask_ratio) (same expected counts as above).

    Displacement offsets are uniform inside a ball of radius max_displacement_m.

    gap_ratio > 0 (not in the paper; 0 draws nothing extra): that fraction of the windows also
    loses every joint over one random stretch of frames (training_gaps) before the kept tokens
    are drawn from the rest; a window whose gap leaves fewer than K tokens keeps what is left.
    """
    if not (0.0 <= mask_ratio <= 1.0 and 0.0 <= displace_ratio <= 1.0 - mask_ratio + 1e-9):
        raise ValueError(
            f"need 0 <= mask_ratio <= 1 and 0 <= displace_ratio <= 1 - mask_ratio, "
            f"got mask_ratio={mask_ratio}, displace_ratio={displace_ratio}"
        )
    if not 0.0 <= gap_ratio <= 1.0:
        raise ValueError(f"need 0 <= gap_ratio <= 1, got gap_ratio={gap_ratio}")
    B, T, J, _ = positions.shape
    N = T * J
    avail = available(positions)  # (B, T, J)
    if gap_ratio > 0:
        avail = avail & ~training_gaps(B, T, gap_ratio, generator, positions)[..., None]
    avail = avail.reshape(B, N)
    keep_frac = 1.0 - mask_ratio
    disp_frac_of_kept = displace_ratio / keep_frac if keep_frac > 0 else 0.0

    if fixed_kept_count:
        K, D = kept_count(N, mask_ratio), round(displace_ratio * N)
        observed = _pick_random(avail, torch.full((B,), K, device=avail.device), generator, positions)
        n_kept = observed.sum(dim=1)
        # == D when the sample could keep K tokens; scaled down only for samples short of data
        n_disp = torch.where(n_kept >= K, D, torch.round(n_kept * (D / max(K, 1))).long())
        displaced = _pick_random(observed, n_disp, generator, positions)
    else:
        observed = avail & (uniform_like((B, N), generator, positions) < keep_frac)
        displaced = observed & (uniform_like((B, N), generator, positions) < disp_frac_of_kept)

    observed, displaced = observed.reshape(B, T, J), displaced.reshape(B, T, J)
    # Uniform in a ball: isotropic direction, radius R * u^(1/3) (volume grows as r^3).
    # Drawn for every token to keep shapes static; only displaced tokens use them.
    direction = normal_like((B, T, J, 3), generator, positions)
    direction = direction / direction.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    radius = max_displacement_m * uniform_like((B, T, J, 1), generator, positions).pow(1.0 / 3.0)
    moved = torch.where(displaced[..., None], positions + (direction * radius).to(positions.dtype), positions)
    return _pack(moved, observed, displaced)


def check_training_corruption(
    mask_ratio: float, displace_ratio: float, clean_loss_ratio: float, max_displacement_m: float
) -> None:
    """ValueError, in the config's terms, for settings of XMAE's training corruption that cannot
    be drawn or would score no token."""
    for name, ratio in (("mask_ratio", mask_ratio), ("displace_ratio", displace_ratio)):
        if not 0.0 <= ratio <= 1.0:
            raise ValueError(f"{name} must be in [0, 1] (a fraction of all tokens), got {ratio}")
    if mask_ratio + displace_ratio > 1.0:
        raise ValueError(
            f"mask_ratio + displace_ratio must be at most 1 (fractions of the same tokens), "
            f"got {mask_ratio} + {displace_ratio}"
        )
    if max_displacement_m < 0:
        raise ValueError(f"max_displacement_m must be >= 0 (a distance in metres), got {max_displacement_m}")
    clean = 1.0 - mask_ratio - displace_ratio  # the share of tokens left observed and clean
    if not 0.0 <= clean_loss_ratio <= clean + 1e-9:
        raise ValueError(
            f"clean_loss_ratio {clean_loss_ratio} must be in [0, 1 - mask_ratio - displace_ratio "
            f"= {clean:.3g}]: the share of all tokens that are clean and scored anyway"
        )
    if mask_ratio + displace_ratio + clean_loss_ratio <= 0.0:
        raise ValueError(
            "mask_ratio, displace_ratio and clean_loss_ratio are all 0: no token would be scored "
            "(the loss is over masked, displaced and clean_loss_ratio tokens)"
        )


def xmae_training_corruption(
    positions: torch.Tensor,
    mask_ratio: float,
    displace_ratio: float,
    max_displacement_m: float,
    fixed_kept_count: bool = True,
    generator: torch.Generator | None = None,
    gap_ratio: float = 0.0,
    hole_ratio: float = 0.0,
    part_joints: torch.Tensor | None = None,
    max_hole_frames: int = 0,
) -> Corrupted:
    """XMAE's training corruption of a batch (B, T, J, 3), all on the batch's device: mask and
    displace (mask_and_displace). training/xmae_input.py makes the model's input of it.

    hole_ratio > 0 (not in the paper): that fraction of the windows instead gets one hole of a
    part (part_joints: (P, J) bool) of up to max_hole_frames frames, everything else observed
    and clean (training_holes)."""
    B, T, J, _ = positions.shape
    c = mask_and_displace(
        positions, mask_ratio, displace_ratio, max_displacement_m, fixed_kept_count, generator, gap_ratio
    )
    if hole_ratio > 0:
        if part_joints is None or max_hole_frames < 1:
            raise ValueError("hole_ratio > 0 needs part_joints and max_hole_frames >= 1")
        hole = training_holes(B, T, part_joints, max_hole_frames, generator, positions)  # (B, T, J)
        in_hole_mode = (uniform_like((B,), generator, positions) < hole_ratio)[:, None, None]  # (B, 1, 1)
        observed = torch.where(in_hole_mode, available(positions) & ~hole, c.observed)
        # No displaced tokens in a hole window: scored, their 0.5-1 m errors outweigh the hole's
        # few cm and the network learns to move every token (docs/results.md: the holes_* runs).
        displaced = c.displaced & ~in_hole_mode
        c = _pack(torch.where(displaced[..., None], c.positions, positions), observed, displaced)
    return c


# --- evaluation tasks (XMAE section 4.1) ---


def gap_frames(T: int, fps: float, gap_s: float) -> tuple[int, int]:
    """[start, stop) frames of a gap of round(gap_s * fps) frames centred in a window of T frames:
    start = T//2 - n//2."""
    n = round(gap_s * fps)
    if not 0 <= n <= T:
        raise ValueError(f"a gap of {gap_s} s at {fps} fps is {n} frames, which does not fit a window of {T} frames")
    start = T // 2 - n // 2
    return start, start + n


def _gap_mask(positions: torch.Tensor, fps: float, gap_s: float, joints: list[int] | None) -> torch.Tensor:
    """(B, T, J) bool, True on the given joints (None: all) in the centred gap."""
    B, T, J, _ = positions.shape
    start, stop = gap_frames(T, fps, gap_s)
    in_gap = torch.zeros(T, dtype=torch.bool, device=positions.device)
    in_gap[start:stop] = True
    in_joints = _index_mask(J, joints, positions.device)
    return (in_gap[:, None] & in_joints[None, :]).expand(B, T, J)


def infill_gap(positions: torch.Tensor, fps: float, gap_s: float, joints: list[int] | None = None) -> Corrupted:
    """Infilling task: remove `joints` (None: the full skeleton) for a gap centred in the window.
    positions: (B, T, J, 3). No randomness. Nothing is displaced."""
    removed = _gap_mask(positions, fps, gap_s, joints)
    observed = available(positions) & ~removed
    return _pack(positions, observed, torch.zeros_like(observed))


def constant_displacement(
    positions: torch.Tensor,
    fps: float,
    gap_s: float,
    joints: list[int] | None,
    generator: torch.Generator | None = None,
    min_m: float = 0.5,
    max_m: float = 1.0,
) -> Corrupted:
    """Constant displacement task: per sample, one random direction and a length uniform in
    [min_m, max_m]; the same offset moves `joints` (None: all) over the centred gap.
    Every non-NaN token stays observed; `displaced` marks the moved ones."""
    B = positions.shape[0]
    direction = normal_like((B, 3), generator, positions)
    direction = direction / direction.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    length = min_m + (max_m - min_m) * uniform_like((B, 1), generator, positions)
    offset = (direction * length).to(positions.dtype)[:, None, None, :]  # (B, 1, 1, 3)
    observed = available(positions)
    displaced = observed & _gap_mask(positions, fps, gap_s, joints)
    return _pack(torch.where(displaced[..., None], positions + offset, positions), observed, displaced)


def gaussian_noise(positions: torch.Tensor, sigma_m: float, generator: torch.Generator | None = None) -> Corrupted:
    """Gaussian noise task on positions: N(0, sigma_m^2) on each coordinate of every non-NaN token."""
    observed = available(positions)
    noisy = positions + (sigma_m * normal_like(positions.shape, generator, positions)).to(positions.dtype)
    return _pack(noisy, observed, observed.clone())


def rotation_noise(
    rotations: torch.Tensor,
    root_translation: torch.Tensor,
    offsets: torch.Tensor,
    parents,
    sigma_rad: float,
    generator: torch.Generator | None = None,
    joints: list[int] | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Gaussian noise task on rotations (Pose-NDF / Motion-DVAE protocol): N(0, sigma_rad^2) on each
    axis-angle coordinate of `joints` (default: every joint but the root 0, the root orientation
    stays clean), then forward kinematics.

    rotations: (B, T, J, 3) local axis-angle, root_translation: (B, T, 3), offsets: (B, J, 3) or (J, 3)
    -> noisy_rotations (B, T, J, 3), noisy_positions (B, T, J, 3).
    NaN rotations stay NaN and FK spreads them to the joint's descendants: wrap the positions
    with `observed = available(noisy_positions)` before feeding a model.
    """
    J = rotations.shape[-2]
    noisy_joint = _index_mask(J, list(range(1, J)) if joints is None else joints, rotations.device)
    noise = (sigma_rad * normal_like(rotations.shape, generator, rotations)).to(rotations.dtype)
    noisy_rot = torch.where(noisy_joint[:, None], rotations + noise, rotations)
    return noisy_rot, fk_axis_angle(noisy_rot, root_translation, offsets, parents)


def jitter(
    positions: torch.Tensor,
    parents,
    rotation_sigma_rad: torch.Tensor,
    position_sigma_m: torch.Tensor,
    generator: torch.Generator | None = None,
    root_sigma_rad: torch.Tensor | None = None,
) -> torch.Tensor:
    """Jitter of a rig's joints, on positions alone (no rotations needed): every joint's bones
    turned by a random rotation of N(0, rotation_sigma_rad^2) per axis-angle coordinate, as
    noise on each joint's local rotation turns everything below it (rotation_noise, for any
    skeleton), then N(0, position_sigma_m^2) on every coordinate; fresh noise every frame.

    positions: (B, T, J, 3) metres, parents before children; rotation_sigma_rad,
    position_sigma_m: (B,) one level per window -> (B, T, J, 3). root_sigma_rad (B,): the root's
    own rotation noise, which turns the whole body about it (default: rotation_sigma_rad; 0 as
    the rotation-noise protocol keeps the root's orientation clean). NaN stays NaN (and spreads to
    the joints below)."""
    B, T, J, _ = positions.shape
    sigma = rotation_sigma_rad.view(B, 1, 1).expand(B, 1, J)
    if root_sigma_rad is not None:
        sigma = torch.cat([root_sigma_rad.view(B, 1, 1).to(sigma), sigma[:, :, 1:]], dim=-1)
    axis_angle = sigma[..., None] * normal_like((B, T, J, 3), generator, positions)  # (B, T, J, 3)
    turn = roma.rotvec_to_rotmat(axis_angle.to(positions.dtype))  # (B, T, J, 3, 3)
    noisy = positions.clone()
    frame = [turn[:, :, 0]] + [None] * (J - 1)  # each joint's accumulated turn
    for j in range(1, J):
        p = parents[j]
        bone = positions[:, :, j] - positions[:, :, p]
        noisy[:, :, j] = noisy[:, :, p] + (frame[p] @ bone[..., None])[..., 0]
        frame[j] = frame[p] @ turn[:, :, j]
    return noisy + position_sigma_m.view(B, 1, 1, 1).to(positions.dtype) * normal_like(
        positions.shape, generator, positions
    ).to(positions.dtype)


# --- augmentation (XMAE section 4.1, implementation details) ---


def rotate_z(positions: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Rotate each sample about the z axis through the origin by angle (B,) radians
    (counter-clockwise seen from +z). rotate_z(rotate_z(x, a), -a) == x.
    positions: (B, ...,  3). Zeros (masked tokens) stay zero, NaN stays NaN."""
    shape = (-1,) + (1,) * (positions.dim() - 2)
    c, s = torch.cos(angle).reshape(shape).to(positions.dtype), torch.sin(angle).reshape(shape).to(positions.dtype)
    x, y, z = positions.unbind(dim=-1)
    return torch.stack([c * x - s * y, s * x + c * y, z], dim=-1)


def random_z_rotation(
    positions: torch.Tensor, generator: torch.Generator | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Augmentation: each sample rotated about z by an angle uniform in [0, 2 pi).
    Apply after normalize so that the rotation axis passes through the window's centre.
    positions: (B, T, J, 3) -> rotated (B, T, J, 3), angle (B,); rotate targets with rotate_z(x, angle)."""
    angle = 2.0 * math.pi * uniform_like((positions.shape[0],), generator, positions)
    return rotate_z(positions, angle), angle
