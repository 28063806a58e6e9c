"""Body models M_beta of Motion-DVAE: (root translation, root orientation, joint rotations, shape)
-> joint positions, and marker vertices where the model has a mesh. Differentiable, torch,
batched over any leading dims (B, T, ...).

- SkeletonFK: forward kinematics on a Skeleton; "shape" = the subject's bone offsets (BVH data,
  the synthetic default, AMASS clips without a mesh).
- SMPLBody: SMPL / SMPL-H from the user's model file; "shape" = betas. Joints plus the 43
  virtual markers Motion-DVAE observes (HuMoR's KEYPT_VERTS, vertex indices of the SMPL mesh).
  Only those marker vertices are skinned: the 6890-vertex mesh is never built.

Both pose through mocapfix.core.kinematics.forward_kinematics, the project's one FK, so the joints
of the two models agree wherever the offsets are SMPL's rest-joint differences.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple, Protocol

import numpy as np
import torch
import torch.nn as nn

from mocapfix.core import lazy_roma as roma
from mocapfix.core.clip import MotionFileError
from mocapfix.core.kinematics import forward_kinematics

# Virtual mocap markers of HuMoR / Motion-DVAE (eq. 9): vertex indices of the SMPL(-H) mesh.
PAPER_MARKERS = (
    4404,
    920,
    3076,
    3169,
    823,
    4310,
    1010,
    1085,
    4495,
    4569,
    6615,
    3217,
    3313,
    6713,
    6785,
    3383,
    6607,
    3207,
    1241,
    1508,
    4797,
    4122,
    1618,
    1569,
    5135,
    5040,
    5691,
    5636,
    5404,
    2230,
    2173,
    2108,
    134,
    3645,
    6543,
    3123,
    3024,
    4194,
    1306,
    182,
    3694,
    4294,
    744,
)
SMPL_NUM_VERTICES = 6890
NUM_BODY_JOINTS = 22


class BodyOutput(NamedTuple):
    joints: torch.Tensor  # (..., J, 3) metres
    markers: torch.Tensor | None = None  # (..., M, 3) metres; None without a mesh

    def points(self) -> torch.Tensor:
        """Joints then markers: (..., J + M, 3), the 3D observation y^3d of eq. (9)."""
        return self.joints if self.markers is None else torch.cat([self.joints, self.markers], dim=-2)


class BodyModel(Protocol):
    num_joints: int
    num_markers: int

    def __call__(
        self,
        root_translation: torch.Tensor,
        root_orientation: torch.Tensor,
        joint_rotations: torch.Tensor,
        shape: torch.Tensor,
        joint_reference: torch.Tensor | None = None,
    ) -> BodyOutput:
        """root_translation (..., 3) world position of joint 0, root_orientation (..., 3) axis-angle,
        joint_rotations (..., J-1, 3) local axis-angle, shape broadcastable to the leading dims
        (SkeletonFK: offsets (..., J, 3); SMPLBody: betas (..., nb)). joint_reference (J-1, 3, 3):
        the joint rotations are measured from it, R_j = joint_reference_j exp(joint_rotations_j)
        (MotionState); None: identity. Composed here, as matrices, because the model turns the
        axis-angles into matrices anyway: a way back to axis-angle would cost more than the FK."""
        ...

    def shape_from_offsets(self, offsets: torch.Tensor) -> torch.Tensor:
        """offsets (B, J, 3), what the data module delivers -> this model's shape (B, ...)."""
        ...


def with_reference(rotmats: torch.Tensor, joint_reference: torch.Tensor | None) -> torch.Tensor:
    """rotmats (..., J, 3, 3), root first -> the same with joints 1.. turned by their reference
    (J-1, 3, 3) on the left; None: unchanged."""
    if joint_reference is None:
        return rotmats
    joints = joint_reference.to(rotmats.dtype) @ rotmats[..., 1:, :, :]
    return torch.cat([rotmats[..., :1, :, :], joints], dim=-3)


class SkeletonFK(nn.Module):
    """Forward kinematics on a skeleton tree; shape = bone offsets (B, J, 3), or (..., J, 3)."""

    num_markers = 0

    def __init__(self, parents):
        super().__init__()
        self.parents = tuple(int(p) for p in parents)
        self.num_joints = len(self.parents)

    def forward(
        self,
        root_translation: torch.Tensor,
        root_orientation: torch.Tensor,
        joint_rotations: torch.Tensor,
        shape: torch.Tensor,
        joint_reference: torch.Tensor | None = None,
    ) -> BodyOutput:
        rotations = torch.cat([root_orientation[..., None, :], joint_rotations], dim=-2)  # (..., J, 3)
        rotmats = with_reference(roma.rotvec_to_rotmat(rotations.float()), joint_reference)
        offsets = shape.float().expand(*rotmats.shape[:-3], self.num_joints, 3)
        joints, _ = forward_kinematics(rotmats, root_translation.float(), offsets, self.parents)
        return BodyOutput(joints)

    def shape_from_offsets(self, offsets: torch.Tensor) -> torch.Tensor:
        return offsets


class SMPLBody(nn.Module):
    """SMPL / SMPL-H body (22 body joints posed; hand joints, if any, at rest = flat hands).

    shape = betas (..., nb). Joints: the 22 body joints, world positions with joint 0 at
    root_translation (the mocapfix / AMASS-reader convention: trans + rest pelvis). Markers:
    linear blend skinning with pose blend shapes of the chosen vertices only.
    The model arrays are non-persistent buffers: checkpoints never carry the licensed model;
    the module is rebuilt from the user's model file.
    """

    def __init__(self, model: dict, markers: list[int] | None = None, num_betas: int | None = None):
        """model: load_body_model's arrays plus posedirs (V, 3, P) and weights (V, Jall)
        (see from_file). markers: vertex indices; None = the paper's 43 (needs the 6890-vertex mesh)."""
        super().__init__()
        V = model["v_template"].shape[0]
        if markers is None:
            if V != SMPL_NUM_VERTICES:
                raise ValueError(
                    f"the paper's 43 marker vertices index the {SMPL_NUM_VERTICES}-vertex SMPL mesh; "
                    f"this model has {V} vertices: pass markers explicitly"
                )
            markers = list(PAPER_MARKERS)
        markers = [int(m) for m in markers]
        if any(not 0 <= m < V for m in markers):
            raise ValueError(f"marker vertex indices must be in [0, {V})")
        nb = model["shapedirs"].shape[-1] if num_betas is None else min(num_betas, model["shapedirs"].shape[-1])
        parents = [int(p) for p in model["parents"]]
        self.parents, self.num_joints, self.num_markers = tuple(parents), NUM_BODY_JOINTS, len(markers)
        self.num_betas = nb
        Jall = len(parents)
        f = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
        Jreg, vt, sd = model["J_regressor"], model["v_template"], model["shapedirs"][..., :nb]
        # Rest joints are linear in betas: J_rest = J_template + J_shapedirs . betas
        self.register_buffer("J_template", f(Jreg @ vt), persistent=False)  # (Jall, 3)
        self.register_buffer("J_shapedirs", f(np.einsum("jv,vcb->jcb", Jreg, sd)), persistent=False)  # (Jall, 3, nb)
        self.register_buffer("m_template", f(vt[markers]), persistent=False)  # (M, 3)
        self.register_buffer("m_shapedirs", f(sd[markers]), persistent=False)  # (M, 3, nb)
        P = model["posedirs"].shape[-1]
        if P != 9 * (Jall - 1):
            raise ValueError(f"posedirs has {P} components, expected 9 x {Jall - 1} joints")
        self.register_buffer("m_posedirs", f(model["posedirs"][markers].reshape(-1, P).T), persistent=False)  # (P, M*3)
        self.register_buffer("m_weights", f(model["weights"][markers]), persistent=False)  # (M, Jall)
        # betas from bone offsets by least squares: offsets are linear in betas too (see shape_from_offsets)
        par = np.array(parents[1:NUM_BODY_JOINTS])
        Jt, Js = Jreg @ vt, np.einsum("jv,vcb->jcb", Jreg, sd)
        A = (Js[1:NUM_BODY_JOINTS] - Js[par]).reshape(-1, nb)  # (63, nb)
        self.register_buffer("off_template", f(Jt[1:NUM_BODY_JOINTS] - Jt[par]), persistent=False)  # (21, 3)
        self.register_buffer("off_pinv", f(np.linalg.pinv(A)), persistent=False)  # (nb, 63)
        self._num_all_joints = Jall

    @classmethod
    def from_file(
        cls,
        body_model_path: str,
        gender: str = "neutral",
        model_type: str = "smplh",
        markers: list[int] | None = None,
        num_betas: int | None = None,
    ) -> SMPLBody:
        """The user's model file or folder (smplx or AMASS layout, as the AMASS reader takes it)."""
        from mocapfix.io.amass import find_body_model, load_body_model

        model_file = find_body_model(body_model_path, model_type, gender)
        model = load_body_model(model_file)
        model.update(_skinning_arrays(model_file, model["v_template"].shape[0], len(model["parents"])))
        return cls(model, markers, num_betas)

    def rest_joints(self, betas: torch.Tensor) -> torch.Tensor:
        """betas (N, nb) -> rest joints (N, Jall, 3)."""
        return self.J_template + torch.einsum("jcb,nb->njc", self.J_shapedirs, betas)

    def forward(
        self,
        root_translation: torch.Tensor,
        root_orientation: torch.Tensor,
        joint_rotations: torch.Tensor,
        shape: torch.Tensor,
        joint_reference: torch.Tensor | None = None,
    ) -> BodyOutput:
        lead = root_translation.shape[:-1]
        N, Jall = int(np.prod(lead)) if lead else 1, self._num_all_joints
        betas = shape.float()[..., : self.num_betas].expand(*lead, self.num_betas).reshape(N, self.num_betas)
        rot = torch.cat([root_orientation[..., None, :], joint_rotations], dim=-2).float().reshape(N, -1, 3)
        rotmats = with_reference(roma.rotvec_to_rotmat(rot), joint_reference)  # (N, 22, 3, 3)
        eye = torch.eye(3, dtype=rotmats.dtype, device=rotmats.device)
        rotmats = torch.cat([rotmats, eye.expand(N, Jall - rot.shape[1], 3, 3)], dim=1)  # (N, Jall, 3, 3)
        J_rest = self.rest_joints(betas)  # (N, Jall, 3)
        offsets = torch.cat([torch.zeros_like(J_rest[:, :1]), J_rest[:, 1:] - J_rest[:, list(self.parents[1:])]], 1)
        root = root_translation.float().reshape(N, 3)
        joints, glob = forward_kinematics(rotmats, root, offsets, self.parents)  # (N, Jall, 3), (N, Jall, 3, 3)
        # LBS of the marker vertices: shape and pose blend shapes in the rest frame, then the
        # blended rigid transforms: joint j moves a rest point v to G_j v + (p_j - G_j J_rest_j).
        M = self.num_markers
        v = self.m_template + torch.einsum("mcb,nb->nmc", self.m_shapedirs, betas)  # (N, M, 3)
        pose_feature = (rotmats[:, 1:] - eye).reshape(N, -1)  # (N, 9 (Jall-1))
        v = v + (pose_feature @ self.m_posedirs).reshape(N, M, 3)
        trans = joints - (glob @ J_rest[..., None])[..., 0]  # (N, Jall, 3)
        R = torch.einsum("mj,njab->nmab", self.m_weights, glob)  # (N, M, 3, 3)
        t = torch.einsum("mj,nja->nma", self.m_weights, trans)  # (N, M, 3)
        markers = (R @ v[..., None])[..., 0] + t
        return BodyOutput(joints[:, :NUM_BODY_JOINTS].reshape(*lead, NUM_BODY_JOINTS, 3), markers.reshape(*lead, M, 3))

    def shape_from_offsets(self, offsets: torch.Tensor) -> torch.Tensor:
        """Bone offsets (B, 22, 3) of this model's body -> betas (B, nb). Offsets are linear in
        betas (J_rest is), so least squares recovers the betas exactly for clips posed by this
        model (the AMASS reader's offsets); the data module need not carry betas."""
        rhs = (offsets[..., 1:NUM_BODY_JOINTS, :].float() - self.off_template).flatten(-2)  # (B, 63)
        return rhs @ self.off_pinv.T


def _skinning_arrays(model_file: Path, V: int, J: int) -> dict:
    """posedirs (V, 3, 9 (J-1)) and weights (V, J): the arrays load_body_model leaves out."""
    from mocapfix.io.amass import read_model_arrays

    raw = read_model_arrays(model_file, ("posedirs", "weights"))
    missing = [k for k in ("posedirs", "weights") if k not in raw]
    if missing:
        raise MotionFileError(model_file, f"no {', '.join(missing)}: marker vertices need a full SMPL model")
    posedirs = np.asarray(raw["posedirs"], dtype=np.float64)
    weights = np.asarray(raw["weights"], dtype=np.float64)
    if posedirs.shape[:2] != (V, 3) or weights.shape != (V, J):
        raise MotionFileError(model_file, "inconsistent posedirs / weights arrays")
    return {"posedirs": posedirs, "weights": weights}


def build_body_model(
    kind: str,
    parents,
    body_model_path: str | None = None,
    gender: str = "neutral",
    model_type: str = "smplh",
    markers: list[int] | None = None,
) -> nn.Module:
    """ "skeleton" -> SkeletonFK(parents); "smpl" -> SMPLBody from the user's model file."""
    if kind == "skeleton":
        return SkeletonFK(parents)
    if kind == "smpl":
        if not body_model_path:
            raise ValueError("body_model: smpl needs body_model_path (your SMPL / SMPL-H model file or folder)")
        body = SMPLBody.from_file(body_model_path, gender, model_type, markers)
        if tuple(parents) != body.parents[:NUM_BODY_JOINTS]:
            raise ValueError("body_model: smpl needs the data on the smpl22 skeleton (AMASS)")
        return body
    raise ValueError(f"body_model must be 'skeleton' or 'smpl', got {kind!r}")
