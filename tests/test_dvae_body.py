"""Body models M_beta: SkeletonFK against the readers' positions, SMPLBody against smplx's own
forward pass on the tiny synthetic SMPL-H model of test_amass.py."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import roma
import torch

from mocapfix.io import read_motion
from mocapfix.io.synthetic import generate_clips
from mocapfix.models.body import SkeletonFK, SMPLBody, build_body_model


def _fk_positions(clip, body=None) -> np.ndarray:
    body = body or SkeletonFK(clip.skeleton.parents)
    rot = torch.from_numpy(clip.rotations).double()
    out = body(
        torch.from_numpy(clip.root_translation).double(),
        rot[:, 0],
        rot[:, 1:],
        body.shape_from_offsets(torch.from_numpy(clip.offsets)),
    )
    return out.joints.numpy()


def test_skeleton_fk_reproduces_synthetic_clips_and_batches():
    clips = generate_clips(2, 2.0, 30.0, seed=3)
    for c in clips:
        assert np.abs(_fk_positions(c) - c.positions).max() < 1e-5
    # batched over (B, T) with per-window offsets (B, 1, J, 3)
    body = SkeletonFK(clips[0].skeleton.parents)
    rot = torch.stack([torch.from_numpy(c.rotations[:20]) for c in clips])  # (2, 20, 22, 3)
    root = torch.stack([torch.from_numpy(c.root_translation[:20]) for c in clips])
    off = torch.stack([torch.from_numpy(c.offsets) for c in clips])[:, None]  # (2, 1, 22, 3)
    out = body(root, rot[..., 0, :], rot[..., 1:, :], off)
    assert out.joints.shape == (2, 20, 22, 3) and out.markers is None
    want = np.stack([c.positions[:20] for c in clips])
    assert np.abs(out.joints.numpy() - want).max() < 1e-5
    assert np.abs(clips[0].offsets - clips[1].offsets).max() > 1e-3  # different bodies: the test can fail


def test_skeleton_fk_matches_the_bvh_reader(bandai_files):
    for f in bandai_files[:: max(1, len(bandai_files) // 3)][:3]:
        [clip] = read_motion(f, "bvh", drop_joints=["joint_Root"])
        assert clip.has_rotations
        err = np.abs(_fk_positions(clip) - clip.positions).max()
        assert err < 1e-5, f"{f.name}: {err} m"


def test_skeleton_fk_is_differentiable():
    c = generate_clips(1, 1.0, 30.0, seed=0)[0]
    body = SkeletonFK(c.skeleton.parents)
    rot = torch.from_numpy(c.rotations[:3]).requires_grad_(True)
    body(
        torch.from_numpy(c.root_translation[:3]), rot[:, 0], rot[:, 1:], torch.from_numpy(c.offsets)
    ).joints.sum().backward()
    assert torch.isfinite(rot.grad).all() and rot.grad[:, 1:].abs().sum() > 0


@pytest.fixture
def smplh_file(tmp_path):
    pytest.importorskip("smplx", reason="SMPLBody tests compare with smplx (pip install mocapfix[smpl])")
    from test_amass import _model

    (tmp_path / "smplh").mkdir()
    with open(tmp_path / "smplh" / "SMPLH_MALE.pkl", "wb") as f:
        pickle.dump(_model(52, 10, hands=True), f)
    return tmp_path


def test_smpl_body_matches_smplx_joints_and_marker_vertices(tmp_path, smplh_file):
    import smplx
    from test_amass import VERTEX_IDS, _amass

    f = tmp_path / "take_poses.npz"
    d = _amass(f, T=5, pose_dim=156, num_betas=10)
    d["poses"][:, 66:] = 0.0  # SMPLBody poses the 22 body joints; hands stay at rest
    np.savez(f, **d)
    [clip] = read_motion(f, body_model_path=str(smplh_file))
    markers = [0, 7, 19, 33, 49]
    body = SMPLBody.from_file(str(smplh_file), "male", markers=markers)
    # betas come back from the clip's bone offsets (offsets are linear in betas)
    betas = body.shape_from_offsets(torch.from_numpy(clip.offsets)[None])
    np.testing.assert_allclose(betas[0].numpy(), d["betas"], atol=1e-4)
    rot = torch.from_numpy(clip.rotations)
    out = body(torch.from_numpy(clip.root_translation), rot[:, 0], rot[:, 1:], betas)
    assert out.joints.shape == (5, 22, 3) and out.markers.shape == (5, 5, 3)
    np.testing.assert_allclose(out.joints.numpy(), clip.positions, atol=1e-5)

    model = smplx.SMPLH(
        str(smplh_file / "smplh" / "SMPLH_MALE.pkl"),
        gender="male",
        use_pca=False,
        flat_hand_mean=True,
        num_betas=10,
        vertex_ids=VERTEX_IDS,
        dtype=torch.float64,
        batch_size=5,
    )
    p = torch.from_numpy(d["poses"])
    ref = model(
        betas=torch.from_numpy(d["betas"])[None].expand(5, -1),
        global_orient=p[:, :3],
        body_pose=p[:, 3:66],
        left_hand_pose=p[:, 66:111],
        right_hand_pose=p[:, 111:],
        transl=torch.from_numpy(d["trans"]),
    )
    want = ref.vertices[:, markers].detach().numpy()
    np.testing.assert_allclose(out.markers.numpy(), want, atol=1e-5)
    assert out.points().shape == (5, 27, 3)
    # rotations measured from a reference pose: the same body as the composed rotations
    reference = roma.random_rotmat(21, generator=torch.Generator().manual_seed(0))
    turned = roma.rotmat_to_rotvec(reference @ roma.rotvec_to_rotmat(rot[:, 1:].float()))
    a = body(torch.from_numpy(clip.root_translation), rot[:, 0], rot[:, 1:], betas, reference)
    b = body(torch.from_numpy(clip.root_translation), rot[:, 0], turned, betas)
    assert (a.joints - b.joints).abs().max() < 1e-5 and (a.markers - b.markers).abs().max() < 1e-5
    assert (a.joints - out.joints).abs().max() > 1e-2
    # pose blend shapes matter: without them the markers move (so the comparison above can fail)
    body.m_posedirs.zero_()
    off = body(torch.from_numpy(clip.root_translation), rot[:, 0], rot[:, 1:], betas).markers.numpy()
    assert np.abs(off - want).max() > 1e-4


def test_smpl_body_needs_markers_on_a_small_mesh_and_the_smpl_skeleton(smplh_file):
    with pytest.raises(ValueError, match="43 marker"):
        SMPLBody.from_file(str(smplh_file), "male")  # 50-vertex test mesh: the paper's indices don't exist
    with pytest.raises(ValueError, match="body_model_path"):
        build_body_model("smpl", list(range(-1, 21)))
    with pytest.raises(ValueError, match="smpl22"):
        build_body_model("smpl", [-1, 0, 1], str(smplh_file), "male", markers=[0])
