"""AMASS through a tiny synthetic SMPL / SMPL-H model written here (no licensed files needed).

Checks the reader's positions against smplx's own forward pass and the FK property of the
clip's rotations, offsets and root translation."""

import pickle
import sys

import numpy as np
import pytest
import torch

from mocapfix.core.clip import MotionFileError
from mocapfix.core.kinematics import fk_axis_angle
from mocapfix.core.skeleton import PRESETS
from mocapfix.io import read_motion
from mocapfix.io.amass import amass_split_of, read_amass

SMPL22 = list(PRESETS["smpl22"].parents)
# smplx picks extra joints from fixed vertex indices of the real mesh: point them at vertex 0.
VERTEX_IDS = {
    k: 0
    for k in ["nose", "reye", "leye", "rear", "lear", "LBigToe", "LSmallToe", "LHeel", "RBigToe", "RSmallToe", "RHeel"]
    + [s + f for s in "lr" for f in ["thumb", "index", "middle", "ring", "pinky"]]
}


def _parents(num_joints):
    if num_joints == 24:  # SMPL: two hand joints under the wrists
        return SMPL22 + [20, 21]
    parents = list(SMPL22)  # SMPL-H: 5 fingers x 3 joints per hand
    for wrist in (20, 21):
        for _ in range(5):
            parents += [wrist, len(parents), len(parents) + 1]
    return parents


def _model(num_joints, num_betas, hands, V=50, seed=0):
    rng = np.random.default_rng(seed)
    parents = _parents(num_joints)
    J_regressor = rng.random((num_joints, V)) * (rng.random((num_joints, V)) < 0.2)
    J_regressor[:, 0] += 1e-3
    weights = rng.random((V, num_joints))
    m = {
        "v_template": rng.normal(scale=0.4, size=(V, 3)),
        "shapedirs": rng.normal(scale=0.03, size=(V, 3, num_betas)),
        "posedirs": rng.normal(scale=0.01, size=(V, 3, 9 * (num_joints - 1))),
        "J_regressor": J_regressor / J_regressor.sum(1, keepdims=True),
        "weights": weights / weights.sum(1, keepdims=True),
        "kintree_table": np.array([[2**32 - 1] + parents[1:], list(range(num_joints))], dtype=np.int64),
        "f": rng.integers(0, V, size=(2 * V, 3)),
    }
    if hands:
        for s in "lr":
            m[f"hands_components{s}"] = np.eye(45)
            m[f"hands_mean{s}"] = np.zeros(45)
    return m


def _amass(path, T, pose_dim, num_betas, gender="male", seed=1):
    rng = np.random.default_rng(seed)
    data = {
        "poses": rng.normal(scale=0.5, size=pose_dim) + np.cumsum(rng.normal(scale=0.02, size=(T, pose_dim)), axis=0),
        "trans": np.cumsum(rng.normal(scale=0.01, size=(T, 3)), axis=0),  # motion, not teleports (io/absurd.py)
        "betas": rng.normal(size=num_betas),
        "gender": np.array(gender),
        "mocap_framerate": np.array(120.0),
    }
    np.savez(path, **data)
    return data


@pytest.fixture
def smplh_folder(tmp_path):
    """smplx layout (pkl with hand components) for 10 betas, AMASS layout (npz without) for 16."""
    root = tmp_path / "models"
    (root / "smplh").mkdir(parents=True)
    with open(root / "smplh" / "SMPLH_MALE.pkl", "wb") as f:
        pickle.dump(_model(52, 10, hands=True), f)
    (root / "amass" / "smplh" / "female").mkdir(parents=True)
    np.savez(root / "amass" / "smplh" / "female" / "model.npz", **_model(52, 16, hands=False, seed=5))
    return root


def _fk(clip):
    return fk_axis_angle(
        torch.from_numpy(clip.rotations).double(),
        torch.from_numpy(clip.root_translation).double(),
        torch.from_numpy(clip.offsets).double(),
        clip.skeleton.parents,
    ).numpy()


def test_smplh_matches_smplx_forward_and_fk(tmp_path, smplh_folder):
    smplx = pytest.importorskip("smplx")
    f = tmp_path / "CMU" / "01" / "01_01_poses.npz"
    f.parent.mkdir(parents=True)
    d = _amass(f, T=6, pose_dim=156, num_betas=10)
    [clip] = read_motion(f, body_model_path=str(smplh_folder), unit="mm")  # unit: not an AMASS option, dropped
    assert clip.positions.shape == (6, 22, 3) and clip.fps == 120.0 and clip.skeleton == PRESETS["smpl22"]
    assert clip.name == "01/01_01_poses" and clip.meta["format"] == "amass" and clip.meta["split"] == "train"
    assert clip.meta["body_model"].endswith("SMPLH_MALE.pkl") and clip.meta["betas_used"] == 10

    model = smplx.SMPLH(
        str(smplh_folder / "smplh" / "SMPLH_MALE.pkl"),
        gender="male",
        use_pca=False,
        flat_hand_mean=True,
        num_betas=10,
        vertex_ids=VERTEX_IDS,
        dtype=torch.float64,
        batch_size=6,
    )
    p = torch.from_numpy(d["poses"])
    out = model(
        betas=torch.from_numpy(d["betas"])[None].expand(6, -1),
        global_orient=p[:, :3],
        body_pose=p[:, 3:66],
        left_hand_pose=p[:, 66:111],
        right_hand_pose=p[:, 111:],
        transl=torch.from_numpy(d["trans"]),
    )
    want = out.joints[:, :22].detach().numpy()
    np.testing.assert_allclose(clip.positions, want, atol=1e-5)
    assert np.abs(want[:, 0] - d["trans"]).max() > 1e-3  # the rest pelvis is off the origin: the test can fail
    np.testing.assert_allclose(_fk(clip), want, atol=1e-5)
    np.testing.assert_allclose(clip.rotations, d["poses"][:, :66].reshape(6, 22, 3), atol=1e-6)


def test_amass_layout_folder_and_all_16_betas(tmp_path, smplh_folder):
    """AMASS's own model.npz (no hand components) and 16 betas: smplx's classes would keep 10."""
    pytest.importorskip("smplx")
    f = tmp_path / "walk_poses.npz"
    d = _amass(f, T=5, pose_dim=156, num_betas=16, gender="female")
    [clip] = read_amass(f, body_model_path=smplh_folder / "amass")
    assert clip.meta["betas_used"] == 16 and clip.meta["gender"] == "female" and clip.meta["split"] is None
    m = _model(52, 16, hands=False, seed=5)
    J_rest = m["J_regressor"] @ (m["v_template"] + m["shapedirs"] @ d["betas"])  # (52, 3)
    np.testing.assert_allclose(clip.root_translation, d["trans"] + J_rest[0], atol=1e-5)
    np.testing.assert_allclose(clip.offsets[1:], (J_rest[1:22] - J_rest[SMPL22[1:]]), atol=1e-6)
    np.testing.assert_allclose(_fk(clip), clip.positions, atol=1e-5)
    # frame with zero pose: the rest joints, shifted by trans
    z = tmp_path / "rest.npz"
    np.savez(z, poses=np.zeros((2, 156)), trans=np.ones((2, 3)), betas=d["betas"], gender="female", mocap_framerate=60)
    [rest] = read_amass(z, body_model_path=smplh_folder / "amass")
    np.testing.assert_allclose(rest.positions[1], J_rest[:22] + 1.0, atol=1e-5)


def test_smpl_72_poses(tmp_path):
    smplx = pytest.importorskip("smplx")
    (tmp_path / "smpl").mkdir()
    model_file = tmp_path / "smpl" / "SMPL_NEUTRAL.pkl"
    with open(model_file, "wb") as fh:
        pickle.dump(_model(24, 10, hands=False, seed=7), fh)
    f = tmp_path / "x.npz"
    d = _amass(f, T=4, pose_dim=72, num_betas=10, gender="male")
    with pytest.raises(MotionFileError, match="gender 'male'"):
        read_amass(f, body_model_path=tmp_path)
    [clip] = read_amass(f, body_model_path=tmp_path, gender="neutral")  # the caller overrides the file's gender
    model = smplx.SMPL(str(model_file), num_betas=10, vertex_ids=VERTEX_IDS, dtype=torch.float64, batch_size=4)
    p = torch.from_numpy(d["poses"])
    out = model(
        betas=torch.from_numpy(d["betas"])[None].expand(4, -1),
        global_orient=p[:, :3],
        body_pose=p[:, 3:],
        transl=torch.from_numpy(d["trans"]),
    )
    np.testing.assert_allclose(clip.positions, out.joints[:, :22].detach().numpy(), atol=1e-5)
    np.testing.assert_allclose(_fk(clip), clip.positions, atol=1e-5)
    assert clip.meta["model_type"] == "smpl"


def test_needs_body_model_path(tmp_path):
    f = tmp_path / "x.npz"
    _amass(f, T=2, pose_dim=156, num_betas=10)
    with pytest.raises(MotionFileError, match="body_model_path") as e:
        read_motion(f)
    assert str(e.value).startswith(str(f)) and "\n" not in str(e.value)


def test_missing_smplx_says_how_to_install(tmp_path, monkeypatch):
    f = tmp_path / "x.npz"
    _amass(f, T=2, pose_dim=156, num_betas=10)
    monkeypatch.setitem(sys.modules, "smplx", None)  # import smplx now raises ImportError
    with pytest.raises(MotionFileError, match=r"mocapfix\[smpl\]"):
        read_amass(f, body_model_path=tmp_path)


def test_bad_amass_files(tmp_path, smplh_folder):
    pytest.importorskip("smplx")
    f = tmp_path / "x.npz"
    np.savez(f, poses=np.zeros((3, 60)), trans=np.zeros((3, 3)), betas=np.zeros(10), gender="male", mocap_framerate=60)
    with pytest.raises(MotionFileError, match="at least 22 joints"):
        read_amass(f, body_model_path=smplh_folder)
    np.savez(f, poses=np.zeros((3, 156)), trans=np.zeros((4, 3)), betas=np.zeros(10), gender="male", mocap_framerate=60)
    with pytest.raises(MotionFileError, match="trans"):
        read_amass(f, body_model_path=smplh_folder)
    bad_model = tmp_path / "SMPLH_MALE.pkl"
    m = _model(52, 10, hands=False)
    m["kintree_table"][0, 5] = 0
    with open(bad_model, "wb") as fh:
        pickle.dump(m, fh)
    np.savez(f, poses=np.zeros((3, 156)), trans=np.zeros((3, 3)), betas=np.zeros(10), gender="male", mocap_framerate=60)
    with pytest.raises(MotionFileError, match="SMPL body tree"):
        read_amass(f, body_model_path=bad_model)


def test_split_of_path():
    assert amass_split_of("/data/AMASS/HumanEva/S1/walk_poses.npz") == "test"
    assert amass_split_of("/data/AMASS/SFU/0005/x.npz") == "val"
    assert amass_split_of("/data/other/x.npz") is None


def test_betas_per_frame_are_one_body_shape(tmp_path, smplh_folder):
    """(T, B) betas, the same on every frame, give the (B,) file's body (they were flattened: row 0
    and part of row 1); rows that differ, or non-finite or non-numeric betas, are one-line errors."""
    pytest.importorskip("smplx")
    one, per_frame = tmp_path / "one.npz", tmp_path / "per_frame.npz"
    d = _amass(one, T=4, pose_dim=156, num_betas=10, gender="female")  # a model with 16 components
    np.savez(per_frame, **dict(d, betas=np.tile(d["betas"], (4, 1))))
    [a] = read_amass(one, body_model_path=smplh_folder / "amass")
    [b] = read_amass(per_frame, body_model_path=smplh_folder / "amass")
    np.testing.assert_allclose(b.positions, a.positions, atol=1e-6)
    assert b.meta["betas_in_file"] == b.meta["betas_used"] == 10
    bad = tmp_path / "bad.npz"
    for betas, match in (
        (np.tile(d["betas"], (4, 1)) + np.arange(4)[:, None], "change from frame to frame"),
        (np.full(10, np.nan), "not all finite"),
        (np.array(["abc"] * 10), "must be numbers"),
        (np.zeros((2, 2, 10)), "must be"),
    ):
        np.savez(bad, **dict(d, betas=betas))
        with pytest.raises(MotionFileError, match=match) as e:
            read_amass(bad, body_model_path=smplh_folder / "amass")
        assert str(e.value).startswith(str(bad)) and "\n" not in str(e.value)
    np.savez(bad, **dict(d, poses=d["poses"] > 0))
    with pytest.raises(MotionFileError, match="poses must be numbers"):
        read_amass(bad, body_model_path=smplh_folder / "amass")
