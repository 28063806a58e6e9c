"""Inverse kinematics onto a recording's own skeleton: joint positions (what XMAE gives) -> local
rotations and root translation for the input's hierarchy, its bone offsets and rest pose kept,
so a fixed BVH goes back to an animator as a BVH.

Per joint, parents first, from where FK has actually put the joint (so a bone length that
differs between the positions and the skeleton does not carry down the chain):
- one child: the input's own local rotation under the new parent, then the smallest rotation
  that points the bone at the child's target: the swing changes, the input's twist about the
  bone stays (a position says nothing about twist);
- several children (hips, chest): the rotation that best points every child bone at its target
  (Kabsch), which fixes the twist too;
- no child with a target (an end joint): the input's local rotation.
"""

from __future__ import annotations

import torch

from mocapfix.core import lazy_roma as roma
from mocapfix.core.kinematics import forward_kinematics


def _swing(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """(..., 3) vectors -> (..., 3, 3) the smallest rotation taking u's direction to v's."""
    u = u / u.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    v = v / v.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    axis = torch.linalg.cross(u, v)
    angle = torch.atan2(axis.norm(dim=-1), (u * v).sum(-1))
    # antiparallel u, v: any axis perpendicular to u (u x e, e the axis u is least along)
    e = torch.eye(3, dtype=u.dtype)[u.abs().argmin(-1)]
    fallback = torch.linalg.cross(u, e)
    axis = torch.where((axis.norm(dim=-1, keepdim=True) < 1e-9) & (angle[..., None] > 1.0), fallback, axis)
    axis = axis / axis.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return roma.rotvec_to_rotmat(axis * angle[..., None])


def _kabsch(o: torch.Tensor, d: torch.Tensor, w: torch.Tensor | None = None) -> torch.Tensor:
    """o: (K, 3) bone offsets in the joint's frame, d: (T, K, 3) targets, w: (T, K) weights ->
    (T, 3, 3) R minimising sum_k w_k |R o_k - d_k|^2 (a proper rotation)."""
    if w is not None:
        d = w[..., None] * d
    H = o.T.expand(d.shape[0], 3, -1) @ d  # (T, 3, 3) = sum_k w_k o_k d_k^T
    U, _, Vh = torch.linalg.svd(H)
    R = Vh.transpose(-1, -2) @ U.transpose(-1, -2)
    flip = torch.ones(d.shape[0], 3, dtype=d.dtype)
    flip[:, 2] = torch.sign(torch.linalg.det(R))
    return Vh.transpose(-1, -2) @ torch.diag_embed(flip) @ U.transpose(-1, -2)


def inverse_kinematics(
    positions: torch.Tensor,
    parents,
    offsets: torch.Tensor,
    rotations: torch.Tensor,
    root_translation: torch.Tensor,
    weights: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """positions: (T, J, 3) targets, metres (NaN: no target for that joint and frame); offsets
    (J, 3) the skeleton's bones; rotations (T, J, 3) local axis-angle and root_translation (T, 3):
    the input's motion (twist and fallback) -> local axis-angle (T, J, 3) and root translation
    (T, 3) whose FK puts each joint as close to its target as the skeleton's bone lengths allow.
    weights: (T, J) how much each target counts where a joint with several children cannot meet
    them all (observed joints 1, filled ones far less: a fill never pulls an observed joint)."""
    positions, offsets, rotations, root_translation = (
        t.double() for t in (positions, offsets, rotations, root_translation)
    )
    T, J = positions.shape[:2]
    reference = roma.rotvec_to_rotmat(rotations)  # (T, J, 3, 3) the input's local rotations
    children = [[c for c in range(J) if parents[c] == j and offsets[c].norm() > 1e-9] for j in range(J)]
    has = torch.isfinite(positions).all(-1)  # (T, J)
    root = torch.where(has[:, :1], positions[:, 0], root_translation)
    glob_rot, glob_pos, local = [None] * J, [None] * J, [None] * J
    for j in range(J):
        p = parents[j]
        if p < 0:
            glob_pos[j], start = root, reference[:, 0]
        else:
            glob_pos[j] = glob_pos[p] + (glob_rot[p] @ offsets[j][:, None])[..., 0]
            start = glob_rot[p] @ reference[:, j]  # the input's local rotation under the new parent
        kids = children[j]
        rot = start
        if kids:
            d = positions[:, kids] - glob_pos[j][:, None]  # (T, K, 3) where each child bone should point
            ok = has[:, kids] & has[:, j : j + 1]  # (T, K) a target for the child (and the joint)
            # one child (or one with a target): swing from the input's pose
            first = ok.float().argmax(-1)  # (T,) the first child with a target
            o = offsets[kids][first]  # (T, 3)
            target = d.gather(1, first[:, None, None].expand(T, 1, 3))[:, 0]
            swung = _swing((start @ o[..., None])[..., 0], torch.nan_to_num(target)) @ start
            rot = torch.where(ok.any(-1)[:, None, None], swung, start)
            if len(kids) > 1:  # every child with a target: the best rotation for all of them
                every = ok.all(-1)
                if every.any():
                    w = None if weights is None else weights[:, kids].double()
                    rot = torch.where(every[:, None, None], _kabsch(offsets[kids], torch.nan_to_num(d), w), rot)
        glob_rot[j] = rot
        local[j] = rot if p < 0 else glob_rot[p].transpose(-1, -2) @ rot
    return roma.rotmat_to_rotvec(torch.stack(local, dim=1)), root


def ik_error_mm(
    positions: torch.Tensor, parents, offsets: torch.Tensor, rotations: torch.Tensor, root_translation: torch.Tensor
) -> tuple[torch.Tensor, float, float]:
    """FK of the IK's rotations -> (its positions (T, J, 3), mean and max distance to the targets
    in mm over the tokens that have one)."""
    posed = forward_kinematics(
        roma.rotvec_to_rotmat(rotations.double()), root_translation.double(), offsets.double(), parents
    )[0]
    err = (posed - positions.double()).norm(dim=-1)
    err = err[torch.isfinite(err)]
    return posed, 1000 * float(err.mean()) if err.numel() else 0.0, 1000 * float(err.max()) if err.numel() else 0.0
