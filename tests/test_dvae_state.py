"""The Motion-DVAE state: canonical first frame, continuous axis-angle, finite differences, and
the way back to joint positions."""

from __future__ import annotations

import math

import roma
import torch

from mocapfix.core.kinematics import fk_axis_angle
from mocapfix.io.synthetic import generate_clips
from mocapfix.models.body import SkeletonFK
from mocapfix.models.dvae_state import (
    MotionState,
    finite_difference,
    heading_of_rotation,
    mean_joint_rotations,
    positions_state,
    rotation_state,
    split_rotation_state,
    to_canonical,
    unwrap_rotvec,
    velocity_mask,
)


def _windows(B=3, T=30, seed=1):
    clips = generate_clips(B, 2.0, 30.0, seed=seed)
    rot = torch.stack([torch.from_numpy(c.rotations[5 : 5 + T]) for c in clips])
    root = torch.stack([torch.from_numpy(c.root_translation[5 : 5 + T]) for c in clips])
    pos = torch.stack([torch.from_numpy(c.positions[5 : 5 + T]) for c in clips])
    off = torch.stack([torch.from_numpy(c.offsets) for c in clips])
    return rot, root, pos, off, clips[0].skeleton


def _turn(rot, root, pos, yaw, shift):
    """The same windows turned about z by yaw (B,) and moved by shift (B, 3)."""
    Rz = roma.rotvec_to_rotmat(torch.stack([torch.zeros_like(yaw), torch.zeros_like(yaw), yaw], -1))  # (B, 3, 3)
    root2 = (Rz[:, None] @ root[..., None])[..., 0] + shift[:, None]
    pos2 = (Rz[:, None, None] @ pos[..., None])[..., 0] + shift[:, None, None]
    rot2 = rot.clone()
    rot2[:, :, 0] = roma.rotmat_to_rotvec(Rz[:, None] @ roma.rotvec_to_rotmat(rot[:, :, 0]))
    return rot2, root2, pos2


def test_rotation_state_layout_and_canonical_first_frame():
    rot, root, pos, off, skel = _windows()
    x, canon = rotation_state(rot, root, 30.0)
    J = skel.num_joints
    assert x.shape == (3, 30, 6 * (J + 1))  # 138 for SMPL's 22 joints, as the paper's 46 x 3
    r, phi, theta = split_rotation_state(x, J)
    assert torch.allclose(r[:, 0, :2], torch.zeros(3, 2), atol=1e-6)  # xy translation zeroed
    assert torch.allclose(r[:, 0, 2], root[:, 0, 2], atol=1e-6)  # height kept
    assert heading_of_rotation(phi[:, 0]).abs().max() < 1e-5  # heading aligned
    assert torch.allclose(theta, rot[:, :, 1:], atol=1e-6)  # local rotations untouched
    # the state gives back the canonicalised positions through the body model
    pts = MotionState("rotations", skel.parents, skel.groups, 30.0, SkeletonFK(skel.parents)).points(x, off).joints
    assert (pts - to_canonical(pos, canon)).abs().max() < 1e-5


def test_canonical_state_ignores_where_and_which_way_the_window_starts():
    rot, root, pos, off, skel = _windows()
    yaw, shift = torch.tensor([0.5, -2.0, 3.0]), torch.tensor([[3.0, -1.0, 0.0], [-5.0, 2.0, 0.0], [0.1, 0.2, 0.0]])
    rot2, root2, pos2 = _turn(rot, root, pos, yaw, shift)
    x1, _ = rotation_state(rot, root, 30.0)
    x2, _ = rotation_state(rot2, root2, 30.0)
    assert (x1 - x2).abs().max() < 1e-3
    p1, _ = positions_state(pos, skel.groups, 30.0)
    p2, _ = positions_state(pos2, skel.groups, 30.0)
    assert (p1 - p2).abs().max() < 1e-4
    assert (pos - pos2).abs().max() > 1.0  # the move was real


def test_unwrap_keeps_axis_angle_continuous_through_half_a_turn():
    angle = torch.linspace(2.8, 3.6, 9)  # passes pi: a reader's shortest form jumps by 2 pi there
    axis = torch.tensor([0.0, 0.6, 0.8])
    shortest = roma.rotmat_to_rotvec(roma.rotvec_to_rotmat(angle[:, None] * axis))[None]  # (1, 9, 3)
    assert (shortest[0, 1:] - shortest[0, :-1]).norm(dim=-1).max() > 5.0
    out = unwrap_rotvec(shortest)
    assert (out[0, 1:] - out[0, :-1]).norm(dim=-1).max() < 0.11
    assert torch.allclose(roma.rotvec_to_rotmat(out), roma.rotvec_to_rotmat(shortest), atol=1e-5)
    assert torch.allclose(out[0], angle[:, None] * axis, atol=1e-5)


def test_unwrap_follows_a_spin_of_several_turns_and_a_pass_through_identity():
    axis = torch.tensor([0.48, -0.6, 0.64])
    spin = torch.linspace(0.5, 9.0, 40)  # about 1.4 turns, 0.22 rad a frame
    through_zero = torch.linspace(0.6, -0.6, 13)  # the shortest form's axis flips at the identity
    for angle in (spin, through_zero):
        shortest = roma.rotmat_to_rotvec(roma.rotvec_to_rotmat(angle[:, None] * axis))[None]
        assert torch.allclose(unwrap_rotvec(shortest)[0], angle[:, None] * axis, atol=1e-4)


def _unwrap_frame_by_frame(rotvec):
    """The frame loop unwrap_rotvec replaced (each frame takes the 2 pi k nearest the previous
    output); on motion that turns by less than a few tenths of a radian a frame both agree."""
    theta = rotvec.norm(dim=-1, keepdim=True)
    axis = rotvec / theta.clamp_min(1e-8)
    out = [rotvec[:, 0]]
    for t in range(1, rotvec.shape[1]):
        k = torch.round(((axis[:, t] * out[-1]).sum(-1, keepdim=True) - theta[:, t]) / (2 * math.pi))
        out.append(axis[:, t] * (theta[:, t] + 2 * math.pi * torch.where(theta[:, t] > 1e-6, k, 0.0)))
    return torch.stack(out, dim=1)


def test_unwrap_matches_the_frame_by_frame_definition_on_smooth_random_motion():
    g = torch.Generator().manual_seed(0)
    # (16 windows, 30 frames, 5 joints): smooth paths that wander through half turns and back
    start = torch.randn(16, 1, 5, 3, generator=g) * 2.0
    velocity = torch.randn(16, 1, 5, 3, generator=g) * 0.05
    wobble = 0.02 * torch.randn(16, 30, 5, 3, generator=g).cumsum(1)
    path = start + velocity * torch.arange(30.0)[None, :, None, None] + wobble
    shortest = roma.rotmat_to_rotvec(roma.rotvec_to_rotmat(path))
    assert (shortest[:, 1:] - shortest[:, :-1]).norm(dim=-1).max() > 5.0  # there are jumps to remove
    out = unwrap_rotvec(shortest)
    assert torch.allclose(out, _unwrap_frame_by_frame(shortest), atol=1e-4)
    assert (out[:, 1:] - out[:, :-1]).norm(dim=-1).max() < 1.0


def test_finite_difference_is_exact_on_lines_and_per_second():
    t = torch.arange(10.0) / 30.0
    x = (2.0 * t - 1.0)[None, :, None].expand(2, 10, 3)
    assert torch.allclose(finite_difference(x, 30.0), torch.full_like(x, 2.0), atol=1e-4)
    q = (t**2)[None, :, None]
    v = finite_difference(q, 30.0)[0, 1:-1, 0]
    assert torch.allclose(v, 2 * t[1:-1], atol=1e-4)  # central differences inside


def test_positions_state_and_its_points():
    _, _, pos, _, skel = _windows()
    codec = MotionState("positions", skel.parents, skel.groups, 30.0)
    x, canon = codec.encode(pos)
    assert x.shape == (3, 30, 6 * skel.num_joints)
    pts = codec.points(x, None).joints
    assert (pts - to_canonical(pos, canon)).abs().max() < 1e-5
    assert pts[:, 0, 0, :2].abs().max() < 1e-6  # root of frame 0 at the xy origin
    # heading: the left-right hip axis of frame 0 along +x
    hips = pts[:, 0, skel.groups["left_leg"][0]] - pts[:, 0, skel.groups["right_leg"][0]]
    assert hips[:, 1].abs().max() < 1e-5 and (hips[:, 0] > 0).all()


def test_fk_of_state_matches_direct_fk_after_turning_back():
    rot, root, pos, off, skel = _windows(B=2)
    x, canon = rotation_state(rot, root, 30.0)
    r, phi, theta = split_rotation_state(x, skel.num_joints)
    direct = fk_axis_angle(torch.cat([phi[..., None, :], theta], -2), r, off[:, None], skel.parents)
    c, s = math.cos, math.sin
    for b in range(2):
        yaw = float(canon.yaw[b])
        Rz = torch.tensor([[c(yaw), -s(yaw), 0.0], [s(yaw), c(yaw), 0.0], [0.0, 0.0, 1.0]])
        world = direct[b] @ Rz.T + canon.origin[b]
        assert (world - pos[b]).abs().max() < 1e-5


def test_velocity_mask_marks_the_finite_differences():
    rot, root, pos, _, skel = _windows(B=1)
    x, _ = rotation_state(rot, root, 30.0)
    vel = velocity_mask("rotations", skel.num_joints)
    assert int(vel.sum()) == 3 + 3 + 3 * (skel.num_joints - 1)
    r, phi, theta = split_rotation_state(x, skel.num_joints)
    want = torch.cat(
        [finite_difference(r, 30.0), finite_difference(phi, 30.0), finite_difference(theta.flatten(-2), 30.0)], -1
    )
    assert torch.equal(x[..., vel], want)
    p, _ = positions_state(pos, skel.groups, 30.0)
    pv = velocity_mask("positions", skel.num_joints)
    assert torch.equal(p[..., pv], finite_difference(p[..., ~pv], 30.0))


def test_joint_reference_changes_the_state_not_the_body():
    rot, root, pos, off, skel = _windows()
    codec = MotionState("rotations", skel.parents, skel.groups, 30.0, SkeletonFK(skel.parents))
    plain, canon = codec.encode(rotations=rot, root_translation=root)
    codec.joint_reference.copy_(roma.random_rotmat(skel.num_joints - 1, generator=torch.Generator().manual_seed(0)))
    x, canon2 = codec.encode(rotations=rot, root_translation=root)
    assert (x - plain).abs().max() > 0.5  # another state...
    assert (codec.points(x, off).joints - to_canonical(pos, canon2)).abs().max() < 1e-5  # ...the same body
    got = roma.rotvec_to_rotmat(codec.joint_rotations(x))  # the skeleton's own rotations back
    assert (got - roma.rotvec_to_rotmat(rot[:, :, 1:])).abs().max() < 1e-5
    assert torch.equal(canon.yaw, canon2.yaw)  # the root is not referenced


def test_mean_pose_reference_takes_joints_away_from_half_a_turn():
    """A joint that sits near half a turn (Bandai's upper legs) is written as vectors on both sides
    of pi, 2 pi apart for nearly the same rotation; from the mean pose its angles are small."""
    g = torch.Generator().manual_seed(0)
    N = 500
    axis = torch.nn.functional.normalize(torch.tensor([0.3, 1.0, 0.2]) + 0.05 * torch.randn(N, 3, generator=g), dim=-1)
    angle = math.pi + 0.2 * torch.randn(N, 1, generator=g)
    rotvec = roma.rotmat_to_rotvec(roma.rotvec_to_rotmat(axis * angle))  # as a reader writes it: |angle| <= pi
    rotations = torch.stack([torch.zeros(N, 3), rotvec], dim=1)  # (N, J=2, 3): root, one joint
    assert (rotvec[:, None] - rotvec[None]).norm(dim=-1).max() > 5  # the same pose in two far places
    ref = mean_joint_rotations(rotations)  # (1, 3, 3)
    rel = roma.rotmat_to_rotvec(ref.transpose(-1, -2) @ roma.rotvec_to_rotmat(rotvec))
    assert rel.norm(dim=-1).max() < 1.0 and rel.norm(dim=-1).median() < 0.3


def test_state_dicts_from_before_the_reference_load_as_identity():
    skel = _windows(B=1)[-1]
    codec = MotionState("rotations", skel.parents, skel.groups, 30.0, SkeletonFK(skel.parents))
    codec.joint_reference.mul_(2.0)
    codec.load_state_dict({})
    assert torch.equal(codec.joint_reference, torch.eye(3).repeat(skel.num_joints - 1, 1, 1))
    assert MotionState("positions", skel.parents, skel.groups, 30.0).state_dict() == {}


def test_step_back_follows_the_state_velocities_one_frame():
    # on motion of constant velocity the first-order step is exact: frame 1 steps back to frame 0
    rot, root, pos, _, skel = _windows(B=2)
    for kind in ("rotations", "positions"):
        codec = MotionState(kind, skel.parents, skel.groups, 30.0)
        vel = velocity_mask(kind, skel.num_joints)
        values = torch.randn(2, codec.dim - int(vel.sum()))
        speeds = torch.randn_like(values)
        t = torch.arange(3.0)[None, :, None] / 30.0
        x = torch.zeros(2, 3, codec.dim)
        x[..., ~vel] = values[:, None] + speeds[:, None] * t
        x[..., vel] = speeds[:, None].expand(-1, 3, -1)
        assert torch.allclose(codec.step_back(x[:, 1]), x[:, 0], atol=1e-6)
        assert torch.allclose(codec.step_back(x[:, 2]), x[:, 1], atol=1e-6)
