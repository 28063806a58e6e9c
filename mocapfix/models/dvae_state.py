"""The Motion-DVAE state x_t and its way back to 3D points.

rotations state (paper eq. 1): x_t = [r, r_dot, phi, phi_dot, Theta, Theta_dot], root translation,
root orientation and the J-1 local joint rotations (axis-angle), velocities by finite differences
(per second): 6 (J + 1) numbers; 3D points by the body model M_beta (eq. 2). Theta is measured
from a reference rotation per joint (R_j = R_ref_j exp(Theta_j)), by default the training data's
mean pose: see MotionState.
positions state (beyond the paper, for position-only data): x_t = [p, p_dot], the J joint
positions and their velocities: 6 J numbers; M = identity.

Each window is canonicalised on its first frame (paper A.4): xy translation zeroed (height
kept) and the heading turned to 0, so the prior learns motion independently of where it starts.
Distances are unchanged by this rigid map, so errors can be measured in the canonical frame.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
import torch.nn as nn

from mocapfix.core import lazy_roma as roma
from mocapfix.models.body import BodyOutput

STATES = ("rotations", "positions")


class Canonical(NamedTuple):
    """The rigid map of a window to its canonical frame: p' = Rz(-yaw) (p - origin)."""

    origin: torch.Tensor  # (B, 3), z = 0
    yaw: torch.Tensor  # (B,) radians


def state_dim(kind: str, num_joints: int) -> int:
    return 6 * (num_joints + 1) if kind == "rotations" else 6 * num_joints


def velocity_mask(kind: str, num_joints: int) -> torch.Tensor:
    """(dim,) bool: True at the velocity entries of the state."""
    mask = torch.zeros(state_dim(kind, num_joints), dtype=torch.bool)
    if kind == "rotations":
        n = 3 * (num_joints - 1)
        mask[3:6] = mask[9:12] = True
        mask[12 + n :] = True
    else:
        mask[3 * num_joints :] = True
    return mask


def finite_difference(x: torch.Tensor, fps: float) -> torch.Tensor:
    """x: (B, T, ...) -> d/dt (B, T, ...): central differences inside, one-sided at both ends."""
    return torch.gradient(x, spacing=1.0 / fps, dim=1, edge_order=1)[0]


def unwrap_rotvec(rotvec: torch.Tensor) -> torch.Tensor:
    """(B, T, ..., 3) axis-angle -> the same rotations, continuous over time (dim 1).

    A rotation has the axis-angle vectors a (theta + 2 pi k) for every integer k; readers give
    the shortest (|theta| <= pi), which jumps by ~2 pi when a joint passes half a turn (Bandai's
    legs sit near pi in the rest pose): the axis flips and the angle restarts. Each frame's axis
    is turned to agree with the previous frame's (the flips cancel), which makes the angle a
    signed angle about one continuous axis; that 1-D angle is unwrapped like a phase (steps of
    more than pi between frames are 2 pi jumps). All of it is whole-window tensor arithmetic:
    a frame-by-frame loop costs ~20 kernel launches per frame on a GPU, where the Motion-DVAE
    training step is launch-bound (docs/performance.md)."""
    theta = rotvec.norm(dim=-1, keepdim=True)  # (B, T, ..., 1)
    axis = rotvec / theta.clamp_min(1e-8)  # 0 at the identity
    flipped = (axis[:, 1:] * axis[:, :-1]).sum(-1, keepdim=True) < 0  # (B, T-1, ..., 1)
    sign = torch.cat([torch.ones_like(theta[:, :1]), 1.0 - 2.0 * flipped.to(theta.dtype)], dim=1).cumprod(dim=1)
    angle = theta * sign  # about the axis sign * axis
    jumps = torch.round(angle.diff(dim=1) / (2 * math.pi)).cumsum(dim=1)
    angle = angle - 2 * math.pi * torch.cat([torch.zeros_like(jumps[:, :1]), jumps], dim=1)
    return axis * sign * angle


def _rz(yaw: torch.Tensor) -> torch.Tensor:
    """(B,) -> (B, 3, 3) rotation about z."""
    c, s, z, o = torch.cos(yaw), torch.sin(yaw), torch.zeros_like(yaw), torch.ones_like(yaw)
    return torch.stack([c, -s, z, s, c, z, z, z, o], dim=-1).reshape(*yaw.shape, 3, 3)


def heading_of_rotation(rotvec: torch.Tensor) -> torch.Tensor:
    """(B, 3) axis-angle -> (B,) heading: the angle of R = Rz(heading) S with S a rotation about a
    horizontal axis (swing-twist about world z). Turning a body by Rz(a) adds a to its heading."""
    q = roma.rotvec_to_unitquat(rotvec)  # (x, y, z, w)
    return 2.0 * torch.atan2(q[..., 2], q[..., 3])


def heading_of_positions(positions: torch.Tensor, groups: dict) -> torch.Tensor:
    """(B, J, 3) -> (B,) the direction of the left-right axis across the hips (or the shoulders),
    from the skeleton's limb groups; 0 when the skeleton has neither pair (translation only)."""
    for left, right in (("left_leg", "right_leg"), ("left_arm", "right_arm")):
        if groups.get(left) and groups.get(right):
            v = positions[:, groups[left][0]] - positions[:, groups[right][0]]
            return torch.atan2(v[:, 1], v[:, 0])
    return torch.zeros(positions.shape[0], dtype=positions.dtype, device=positions.device)


def to_canonical(points: torch.Tensor, canon: Canonical) -> torch.Tensor:
    """points (B, ..., 3) world -> canonical frame."""
    shape = (points.shape[0],) + (1,) * (points.dim() - 2)
    R = _rz(-canon.yaw).to(points.dtype).reshape(*shape, 3, 3)
    return (R @ (points - canon.origin.to(points.dtype).reshape(*shape, 3))[..., None])[..., 0]


def from_canonical(points: torch.Tensor, canon: Canonical) -> torch.Tensor:
    """points (B, ..., 3) canonical frame -> world."""
    shape = (points.shape[0],) + (1,) * (points.dim() - 2)
    R = _rz(canon.yaw).to(points.dtype).reshape(*shape, 3, 3)
    return (R @ points[..., None])[..., 0] + canon.origin.to(points.dtype).reshape(*shape, 3)


def _origin(p0: torch.Tensor) -> torch.Tensor:
    return torch.cat([p0[:, :2], torch.zeros_like(p0[:, 2:])], dim=-1)


def rotation_state(
    rotations: torch.Tensor, root_translation: torch.Tensor, fps: float, reference: torch.Tensor | None = None
) -> tuple[torch.Tensor, Canonical]:
    """rotations (B, T, J, 3) local axis-angle (joint 0 = root orientation), root_translation (B, T, 3)
    -> x (B, T, 6 (J + 1)) in the window's canonical frame, and that frame.
    reference: (J-1, 3, 3) rotation Theta_j is measured from (R_j = reference_j exp(Theta_j));
    None: the rotations as given."""
    B, T, J, _ = rotations.shape
    rotations, root_translation = rotations.float(), root_translation.float()
    canon = Canonical(_origin(root_translation[:, 0]), heading_of_rotation(rotations[:, 0, 0]))
    r = to_canonical(root_translation, canon)  # (B, T, 3)
    root = _rz(-canon.yaw)[:, None] @ roma.rotvec_to_rotmat(rotations[:, :, 0])  # (B, T, 3, 3)
    phi = unwrap_rotvec(roma.rotmat_to_rotvec(root))  # (B, T, 3)
    joints = rotations[:, :, 1:]  # (B, T, J-1, 3)
    if reference is not None:
        joints = roma.rotmat_to_rotvec(reference.transpose(-1, -2) @ roma.rotvec_to_rotmat(joints))
    theta = unwrap_rotvec(joints).reshape(B, T, 3 * (J - 1))
    x = torch.cat(
        [r, finite_difference(r, fps), phi, finite_difference(phi, fps), theta, finite_difference(theta, fps)], dim=-1
    )
    return x, canon


def split_rotation_state(x: torch.Tensor, num_joints: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """x (..., 6 (J + 1)) -> root translation (..., 3), root orientation (..., 3), joint rotations (..., J-1, 3)."""
    n = 3 * (num_joints - 1)
    return x[..., 0:3], x[..., 6:9], x[..., 12 : 12 + n].reshape(*x.shape[:-1], num_joints - 1, 3)


def positions_state(positions: torch.Tensor, groups: dict, fps: float) -> tuple[torch.Tensor, Canonical]:
    """positions (B, T, J, 3) -> x (B, T, 6 J) in the window's canonical frame, and that frame."""
    B, T, J, _ = positions.shape
    positions = positions.float()
    canon = Canonical(_origin(positions[:, 0, 0]), heading_of_positions(positions[:, 0], groups))
    p = to_canonical(positions, canon).reshape(B, T, 3 * J)
    return torch.cat([p, finite_difference(p, fps)], dim=-1), canon


def split_positions_state(x: torch.Tensor, num_joints: int) -> torch.Tensor:
    """x (..., 6 J) -> positions (..., J, 3)."""
    return x[..., : 3 * num_joints].reshape(*x.shape[:-1], num_joints, 3)


class MotionState(nn.Module):
    """One state kind on one skeleton: batch tensors -> state, state -> 3D points (joints, markers).

    body: a body model (models/body.py) for the rotations state; unused by the positions state.

    The rotations state measures each joint's rotation from `joint_reference` (J-1, 3, 3), a
    buffer (saved with the weights; identity until set, e.g. by `mean_joint_rotations`). Why: an
    axis-angle vector is continuous in the rotation only away from half a turn, where the axis
    flips sign. SMPL's rest pose is a T-pose, so its joints stay far from that; a BVH skeleton's
    zero pose is whatever its author chose: Bandai's upper legs sit within 0.3 rad of half a turn
    in almost every frame, so two nearly equal poses can be two vectors 2 pi apart and the first
    frame of a window (which the whole window's branch follows) lands on either. Measured from the
    data's mean pose, the angles are small (median under 0.6 rad on Bandai) and the map smooth."""

    def __init__(self, kind: str, parents, groups: dict, fps: float, body=None):
        if kind not in STATES:
            raise ValueError(f"state must be one of {STATES}, got {kind!r}")
        super().__init__()
        self.kind, self.parents, self.groups, self.fps, self.body = kind, tuple(parents), dict(groups), float(fps), body
        self.num_joints = len(self.parents)
        self.dim = state_dim(kind, self.num_joints)
        if kind == "rotations":
            self.register_buffer("joint_reference", self._identity_reference())

    def _identity_reference(self) -> torch.Tensor:
        return torch.eye(3).repeat(self.num_joints - 1, 1, 1)  # (J-1, 3, 3): the rotations as given

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # checkpoints from before the reference existed measured the rotations as given
        if self.kind == "rotations" and prefix + "joint_reference" not in state_dict:
            state_dict[prefix + "joint_reference"] = self._identity_reference()
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def joint_rotations(self, x: torch.Tensor) -> torch.Tensor:
        """Rotations state x (..., dim) -> the body joints' local axis-angle rotations (..., J-1, 3)
        in the skeleton's own convention (the reference put back)."""
        theta = split_rotation_state(x, self.num_joints)[2]
        return roma.rotmat_to_rotvec(self.joint_reference.to(theta.dtype) @ roma.rotvec_to_rotmat(theta))

    def encode(
        self,
        positions: torch.Tensor | None = None,
        rotations: torch.Tensor | None = None,
        root_translation: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, Canonical]:
        """(B, T, J, 3) positions (positions state) or rotations + root translation (rotations
        state) -> x (B, T, dim), canonical frame."""
        if self.kind == "rotations":
            if rotations is None or root_translation is None:
                raise ValueError(
                    "state 'rotations' needs rotation data: set data.with_rotations: true on a source "
                    "with rotations (bvh, amass, synthetic), or use state: positions"
                )
            return rotation_state(rotations, root_translation, self.fps, self.joint_reference)
        return positions_state(positions, self.groups, self.fps)

    def step_back(self, x: torch.Tensor) -> torch.Tensor:
        """x (..., dim) one frame's state -> the state one frame earlier along its own velocities
        (positions and angles minus velocity / fps; velocities kept): a first-order step."""
        vel = velocity_mask(self.kind, self.num_joints).to(x.device)
        out = x.clone()
        out[..., ~vel] = x[..., ~vel] - x[..., vel] / self.fps  # the state lists values and velocities in one order
        return out

    def shape(self, offsets: torch.Tensor | None) -> torch.Tensor | None:
        """The body model's shape from the batch's bone offsets (B, J, 3); None for positions."""
        return self.body.shape_from_offsets(offsets) if self.kind == "rotations" else None

    def points(self, x: torch.Tensor, shape: torch.Tensor | None) -> BodyOutput:
        """x (B, T, dim) -> BodyOutput with joints (B, T, J, 3) (+ markers (B, T, M, 3)), same frame as x."""
        if self.kind == "positions":
            return BodyOutput(split_positions_state(x, self.num_joints))
        r, phi, theta = split_rotation_state(x, self.num_joints)
        return self.body(r, phi, theta, shape[:, None], self.joint_reference)


@torch.no_grad()
def mean_joint_rotations(rotations: torch.Tensor) -> torch.Tensor:
    """rotations (N, J, 3) local axis-angle (joint 0 = root), finite -> (J-1, 3, 3) the body
    joints' mean rotations: the mean of the rotation matrices projected back onto SO(3) (the
    chordal L2 mean; it does not care on which side of half a turn a vector was written)."""
    return roma.special_procrustes(roma.rotvec_to_rotmat(rotations[:, 1:].double()).mean(0)).float()
