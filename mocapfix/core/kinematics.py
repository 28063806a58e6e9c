"""Forward kinematics: local joint rotations + bone offsets + root translation -> joint positions.

The one FK of the project: readers (BVH, synthetic), rotation-noise corruption and the
Motion-DVAE body model all call it. Batched over any leading dims, differentiable, torch.
"""

from __future__ import annotations

import torch

from mocapfix.core import lazy_roma as roma


def forward_kinematics(
    local_rotmats: torch.Tensor, root_translation: torch.Tensor, offsets: torch.Tensor, parents
) -> tuple[torch.Tensor, torch.Tensor]:
    """local_rotmats: (..., J, 3, 3) rotation of each joint in its parent's frame
    root_translation: (..., 3) world position of joint 0
    offsets: (..., J, 3) or (J, 3) position of each joint in its parent's frame (row 0 unused)
    parents: J ints, parents[0] == -1, parents[j] < j
    returns positions (..., J, 3) and global rotations (..., J, 3, 3)."""
    J = local_rotmats.shape[-3]
    offsets = offsets.to(local_rotmats.dtype).expand(*local_rotmats.shape[:-3], J, 3)
    # unbind once, not index per joint: the backward of one unbind is one stack, that of J
    # indexings is J zero-filled full-size gradients (FK sits in the Motion-DVAE training loss)
    local, offset = local_rotmats.unbind(-3), offsets.unbind(-2)  # J x (..., 3, 3), J x (..., 3)
    glob_rot = [local[0]]
    glob_pos = [root_translation.to(local_rotmats.dtype)]
    for j in range(1, J):
        p = parents[j]
        glob_pos.append(glob_pos[p] + (glob_rot[p] @ offset[j][..., None])[..., 0])
        glob_rot.append(glob_rot[p] @ local[j])
    return torch.stack(glob_pos, dim=-2), torch.stack(glob_rot, dim=-3)


def fk_axis_angle(
    rotations: torch.Tensor, root_translation: torch.Tensor, offsets: torch.Tensor, parents
) -> torch.Tensor:
    """rotations: (..., J, 3) local axis-angle (radians) -> positions (..., J, 3)."""
    return forward_kinematics(roma.rotvec_to_rotmat(rotations), root_translation, offsets, parents)[0]
