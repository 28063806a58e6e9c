"""Joint names across conventions: labels, matching a recording onto a model's skeleton, and
`fix` / `inspect` on a recording named another way than the model's training data."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mocapfix.apps.main import main
from mocapfix.core.clip import MotionFileError
from mocapfix.core.skeleton import Skeleton, preset
from mocapfix.fix import map_joints
from mocapfix.io import read_motion
from mocapfix.io.positions import write_positions
from mocapfix.models.checkpoint import xmae_checkpoint
from mocapfix.models.xmae import XMAE
from mocapfix.rig.labels import joint_labels
from mocapfix.rig.mapping import match_joints
from mocapfix.rig.names import side_and_word

# Bandai Namco's names (after the reader drops joint_Root) -> Mixamo's for the same joints
MIXAMO = {
    "Hips": "mixamorig:Hips",
    "Spine": "mixamorig:Spine",
    "Chest": "mixamorig:Spine1",
    "Neck": "mixamorig:Neck",
    "Head": "mixamorig:Head",
    "Shoulder_L": "mixamorig:LeftShoulder",
    "UpperArm_L": "mixamorig:LeftArm",
    "LowerArm_L": "mixamorig:LeftForeArm",
    "Hand_L": "mixamorig:LeftHand",
    "Shoulder_R": "mixamorig:RightShoulder",
    "UpperArm_R": "mixamorig:RightArm",
    "LowerArm_R": "mixamorig:RightForeArm",
    "Hand_R": "mixamorig:RightHand",
    "UpperLeg_L": "mixamorig:LeftUpLeg",
    "LowerLeg_L": "mixamorig:LeftLeg",
    "Foot_L": "mixamorig:LeftFoot",
    "Toes_L": "mixamorig:LeftToeBase",
    "UpperLeg_R": "mixamorig:RightUpLeg",
    "LowerLeg_R": "mixamorig:RightLeg",
    "Foot_R": "mixamorig:RightFoot",
    "Toes_R": "mixamorig:RightToeBase",
}
FINGERS = [f"mixamorig:LeftHand{f}1" for f in ("Thumb", "Index", "Middle", "Ring", "Pinky")]


def test_side_and_word_across_conventions():
    assert side_and_word("UpperArm_L") == ("left", "upperarm")
    assert side_and_word("mixamorig:RightForeArm") == ("right", "forearm")
    assert side_and_word("LHipJoint") == ("left", "hipjoint")
    assert side_and_word("LowerArm") == (None, "lowerarm")  # "L" + capital is a side only as written
    assert side_and_word("l_elbow") == ("left", "elbow") and side_and_word("hand.r") == ("right", "hand")


def test_labels_put_the_same_body_part_under_each_conventions_name():
    smpl = dict(zip(preset("smpl22").joint_names, joint_labels(preset("smpl22"))))
    h36m = dict(zip(preset("h36m17").joint_names, joint_labels(preset("h36m17"))))
    # SMPL's "shoulder" is the upper arm (its clavicle is "collar"), its "foot" the toe
    assert smpl["left_shoulder"] == "left_upper_arm" and smpl["left_collar"] == "left_clavicle"
    assert smpl["left_foot"] == "left_toe" and smpl["left_ankle"] == "left_ankle"
    assert smpl["spine1"] == "spine_1of3" and smpl["spine3"] == "spine_3of3"
    assert h36m["LShoulder"] == "left_upper_arm" and h36m["RFoot"] == "right_ankle" and h36m["LHip"] == "left_thigh"
    # CMU: "LeftShoulder" is the clavicle beside "LeftArm"; "LHipJoint" a helper beside "LeftUpLeg"
    names = (
        "Hips",
        "LHipJoint",
        "LeftUpLeg",
        "LeftLeg",
        "LeftFoot",
        "LowerBack",
        "Spine",
        "Neck",
        "LeftShoulder",
        "LeftArm",
        "LeftForeArm",
        "LeftHand",
    )
    cmu = Skeleton(names, (-1, 0, 1, 2, 3, 0, 5, 6, 6, 8, 9, 10))
    labels = dict(zip(names, joint_labels(cmu)))
    assert labels["LeftShoulder"] == "left_clavicle" and labels["LeftArm"] == "left_upper_arm"
    assert labels["LHipJoint"] == "left_hip_helper" and labels["LeftUpLeg"] == "left_thigh"
    assert labels["LeftFoot"] == "left_ankle" and labels["LowerBack"] == "spine_1of2"


@pytest.fixture(scope="module")
def bandai_clip(bandai_files):
    return read_motion(bandai_files[0])[0]


def _odd(name: str) -> str:
    """A name no convention uses, for the left forearm."""
    return "LeftBendy" if name == "mixamorig:LeftForeArm" else name


def _renamed(clip, fingers: bool):
    """The clip's skeleton with Mixamo names, five finger joints under the left hand (and their
    positions: a few cm off the hand, some frames missing)."""
    names = [MIXAMO[n] for n in clip.skeleton.joint_names]
    parents = list(clip.skeleton.parents)
    positions = clip.positions
    if fingers:
        hand = clip.skeleton.index("Hand_L")
        names += FINGERS
        parents += [hand] * len(FINGERS)
        offsets = np.array([[0.02 * k, 0.01, -0.03] for k in range(1, 6)], dtype=np.float32)
        extra = positions[:, hand][:, None] + offsets[None]  # (T, 5, 3)
        extra[10:20, 2] = np.nan  # a finger missing for 10 frames
        positions = np.concatenate([positions, extra], axis=1)
    return Skeleton(tuple(names), tuple(parents), {}, "mixamo"), positions


def test_a_mixamo_named_recording_maps_joint_for_joint(bandai_clip):
    renamed, _ = _renamed(bandai_clip, fingers=True)
    index = map_joints(renamed, bandai_clip.skeleton)
    assert index.tolist() == list(range(bandai_clip.skeleton.num_joints))  # the fingers are not the model's
    # a joint the matching cannot place: named by --joint-map, else a one-line error naming it
    odd = Skeleton(tuple(_odd(n) for n in renamed.joint_names), renamed.parents)
    with pytest.raises(MotionFileError, match="missing LowerArm_L .*--joint-map"):
        map_joints(odd, bandai_clip.skeleton, "take.npz")
    assert match_joints(odd, bandai_clip.skeleton, {"LeftBendy": "LowerArm_L"})["LowerArm_L"] == odd.index("LeftBendy")
    # spine joints between pelvis and neck match by rank whatever their names
    torso = Skeleton(tuple("Torso" if n == "mixamorig:Spine1" else n for n in renamed.joint_names), renamed.parents)
    assert match_joints(torso, bandai_clip.skeleton)["Chest"] == torso.index("Torso")


def test_fix_on_renamed_joints_matches_the_native_run(tmp_path, bandai_clip, capsys):
    torch.manual_seed(0)
    sizes = dict(enc_dim=32, enc_depth=1, enc_mlp_dim=64, dec_dim=32, dec_depth=1, dec_mlp_dim=64, head_dim=16)
    net = XMAE(bandai_clip.skeleton.num_joints, 30, **sizes)
    torch.save(xmae_checkpoint(net, bandai_clip.skeleton, 30.0), tmp_path / "m.ckpt")
    clip = bandai_clip
    holes = clip.positions[:150].copy()
    holes[40:55, clip.skeleton.index("Hand_L")] = np.nan  # 0.5 s
    holes[80:86] = np.nan  # the whole body, 0.2 s
    write_positions(tmp_path / "native.npz", holes, clip.fps, clip.skeleton)
    renamed, with_fingers = _renamed(clip.replace(positions=holes), fingers=True)
    renamed = Skeleton(tuple(_odd(n) for n in renamed.joint_names), renamed.parents, {}, "mixamo")
    write_positions(tmp_path / "mixamo.npz", with_fingers, clip.fps, renamed)
    (tmp_path / "map.yaml").write_text("LeftBendy: LowerArm_L\n")
    for name, extra in (("native", []), ("mixamo", ["--joint-map", str(tmp_path / "map.yaml")])):
        assert main(["fix", str(tmp_path / f"{name}.npz"), "--ckpt", str(tmp_path / "m.ckpt"), *extra]) == 0
    native = np.load(tmp_path / "native.fixed.npz")["positions"]
    mixamo = np.load(tmp_path / "mixamo.fixed.npz")["positions"]
    J = clip.skeleton.num_joints
    assert np.isfinite(native).all() and np.abs(mixamo[:, :J] - native).max() < 1e-3  # within 1 mm
    # the finger joints the model does not know: as they were where observed, filled along the
    # skeleton (from the fixed hand, bone length kept) where missing
    seen = np.isfinite(with_fingers[:, J:])
    np.testing.assert_array_equal(mixamo[:, J:][seen], with_fingers[:, J:][seen])
    hand = clip.skeleton.index("Hand_L")
    truth = native[10:20, hand] + np.array([0.06, 0.01, -0.03], dtype=np.float32)  # the middle finger's offset
    assert np.isfinite(mixamo).all() and np.abs(mixamo[10:20, J + 2] - truth).max() < 0.005
    capsys.readouterr()
    args = ["inspect", str(tmp_path / "mixamo.npz"), "--ckpt", str(tmp_path / "m.ckpt")]
    assert main([*args, "--joint-map", str(tmp_path / "map.yaml")]) == 0
    out = capsys.readouterr().out
    assert "Chest            <- mixamorig:Spine1 (body part, from the rig's structure)" in out
    assert "UpperArm_L       <- mixamorig:LeftArm (body part, from the rig's structure)" in out
    assert "LowerArm_L       <- LeftBendy (joint map)" in out
    where = "kept as recorded, moved with the model joint above them where fix replaces it"
    assert f"not used by the model ({where}): " + ", ".join(FINGERS) in out


def test_an_smpl_recording_maps_onto_a_bandai_model_with_the_nearest_spine_joints(bandai_clip):
    found = match_joints(preset("smpl22"), bandai_clip.skeleton)
    smpl = preset("smpl22").joint_names
    named = {model: smpl[i] for model, i in found.items()}
    assert len(found) == bandai_clip.skeleton.num_joints  # every model joint found
    assert named["Spine"] == "spine1" and named["Chest"] == "spine3"  # 2 spine joints from 3, by height
    assert named["Shoulder_L"] == "left_collar" and named["UpperArm_L"] == "left_shoulder"
    assert named["Foot_R"] == "right_ankle" and named["Toes_R"] == "right_foot"
