"""Any humanoid rig, by its structure: Bandai Namco takes rewritten (here) under the naming and
extra bones of common rigs, and once with random joint names, map onto the model's 21 joints,
read at their true size, and CMU's takes (../shared/data/cmu-sample) map whole."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import torch

from mocapfix.core.clip import Clip
from mocapfix.core.kinematics import fk_axis_angle
from mocapfix.core.skeleton import Skeleton
from mocapfix.fix import map_joints
from mocapfix.fix.fixers import load_fixer
from mocapfix.io import read_motion
from mocapfix.io.bvh import read_bvh, write_bvh
from mocapfix.io.conventions import metres_per_unit
from mocapfix.pretrained import pretrained_path

BANDAI = (
    "Hips Spine Chest Neck Head Shoulder_L UpperArm_L LowerArm_L Hand_L Shoulder_R UpperArm_R LowerArm_R Hand_R "
    "UpperLeg_L LowerLeg_L Foot_L Toes_L UpperLeg_R LowerLeg_R Foot_R Toes_R"
).split()


def _names(text: str) -> dict[str, str]:
    return dict(zip(BANDAI, text.split()))


# Each rig: its names for Bandai Namco's 21 joints, and which extra bones it has.
RIGS = {
    "mixamo": (
        _names(
            "mixamorig:Hips mixamorig:Spine mixamorig:Spine2 mixamorig:Neck mixamorig:Head mixamorig:LeftShoulder "
            "mixamorig:LeftArm mixamorig:LeftForeArm mixamorig:LeftHand mixamorig:RightShoulder mixamorig:RightArm "
            "mixamorig:RightForeArm mixamorig:RightHand mixamorig:LeftUpLeg mixamorig:LeftLeg mixamorig:LeftFoot "
            "mixamorig:LeftToeBase mixamorig:RightUpLeg mixamorig:RightLeg mixamorig:RightFoot mixamorig:RightToeBase"
        ),
        {"fingers", "toe_end", "head_top"},
    ),
    "character_creator": (
        _names(
            "CC_Base_Hip CC_Base_Spine01 CC_Base_Spine02 CC_Base_NeckTwist01 CC_Base_Head CC_Base_L_Clavicle "
            "CC_Base_L_Upperarm CC_Base_L_Forearm CC_Base_L_Hand CC_Base_R_Clavicle CC_Base_R_Upperarm "
            "CC_Base_R_Forearm CC_Base_R_Hand CC_Base_L_Thigh CC_Base_L_Calf CC_Base_L_Foot CC_Base_L_ToeBase "
            "CC_Base_R_Thigh CC_Base_R_Calf CC_Base_R_Foot CC_Base_R_ToeBase"
        ),
        {"fingers", "twist_leaves", "share", "face", "helper_root", "toe_end"},
    ),
    "daz": (
        _names(
            "hip abdomen chest neck head lCollar lShldr lForeArm lHand rCollar rShldr rForeArm rHand "
            "lThigh lShin lFoot lToe rThigh rShin rFoot rToe"
        ),
        {"fingers", "face"},
    ),
    "unreal": (
        _names(
            "pelvis spine_01 spine_03 neck_01 head clavicle_l upperarm_l lowerarm_l hand_l clavicle_r upperarm_r "
            "lowerarm_r hand_r thigh_l calf_l foot_l ball_l thigh_r calf_r foot_r ball_r"
        ),
        {"fingers", "twist_leaves", "helper_root"},
    ),
    "unity": (
        _names(
            "Hips Spine Chest Neck Head LeftShoulder LeftUpperArm LeftLowerArm LeftHand RightShoulder RightUpperArm "
            "RightLowerArm RightHand LeftUpperLeg LeftLowerLeg LeftFoot LeftToes RightUpperLeg RightLowerLeg "
            "RightFoot RightToes"
        ),
        {"face", "twist_in_chain"},
    ),
    "rokoko": (
        _names(
            "Hips Spine1 Spine4 Neck Head LeftShoulder LeftArm LeftForeArm LeftHand RightShoulder RightArm "
            "RightForeArm RightHand LeftThigh LeftShin LeftFoot LeftToe RightThigh RightShin RightFoot RightToe"
        ),
        {"fingers", "toe_end", "root_offset"},
    ),
    "xsens_mvn": (
        _names(
            "Pelvis L5 T8 Neck Head LeftShoulder LeftUpperArm LeftForeArm LeftHand RightShoulder RightUpperArm "
            "RightForeArm RightHand LeftUpperLeg LeftLowerLeg LeftFoot LeftToe RightUpperLeg RightLowerLeg "
            "RightFoot RightToe"
        ),
        set(),
    ),
    "optitrack": (
        _names(
            "Skeleton_Hip Skeleton_Ab Skeleton_Chest Skeleton_Neck Skeleton_Head Skeleton_LShoulder "
            "Skeleton_LUArm Skeleton_LFArm Skeleton_LHand Skeleton_RShoulder Skeleton_RUArm Skeleton_RFArm "
            "Skeleton_RHand Skeleton_LThigh Skeleton_LShin Skeleton_LFoot Skeleton_LToe Skeleton_RThigh "
            "Skeleton_RShin Skeleton_RFoot Skeleton_RToe"
        ),
        {"share"},
    ),
    "cmu": (
        _names(
            "Hips Spine Spine1 Neck Head LeftShoulder LeftArm LeftForeArm LeftHand RightShoulder RightArm "
            "RightForeArm RightHand LeftUpLeg LeftLeg LeftFoot LeftToeBase RightUpLeg RightLeg RightFoot RightToeBase"
        ),
        {"fingers"},
    ),
    "smpl": (
        _names(
            "pelvis spine1 spine3 neck head left_collar left_shoulder left_elbow left_wrist right_collar "
            "right_shoulder right_elbow right_wrist left_hip left_knee left_ankle left_foot right_hip right_knee "
            "right_ankle right_foot"
        ),
        set(),
    ),
    "h36m": (
        _names(
            "Hip Spine Thorax Neck Head LCollar LShoulder LElbow LWrist RCollar RShoulder RElbow RWrist "
            "LHip LKnee LAnkle LToe RHip RKnee RAnkle RToe"
        ),
        {"toe_end"},
    ),
    "random": (
        _names(" ".join(f"j{(i * 7919) % 1000:03d}x" for i in range(21))),
        {"fingers", "twist_leaves", "share", "face", "helper_root", "toe_end", "twist_in_chain", "root_offset"},
    ),
}


@pytest.fixture(scope="module")
def source(bandai_files) -> Clip:
    """A Bandai take, 4 s, on its 21 joints (joint_Root left out: Hips carries the motion)."""
    clip = read_bvh({f.name: f for f in bandai_files}["dataset-1_walk_active_001.bvh"], drop_joints=["joint_Root"])[0]
    return clip.replace(
        positions=clip.positions[:120], rotations=clip.rotations[:120], root_translation=clip.root_translation[:120]
    )


def _rig(source: Clip, names: dict[str, str], extras: set[str], path: Path) -> Path:
    """source rewritten as a BVH in cm, y up, with the rig's names and extra bones. Extra bones
    never move the body: leaves, zero-length share bones, collinear twist joints inside a chain,
    a helper root with a constant rotation."""
    joints = [
        dict(name=names[n], parent=None if p < 0 else names[BANDAI[p]], offset=o, rot=source.rotations[:, j])
        for j, (n, p, o) in enumerate(zip(BANDAI, source.skeleton.parents, source.offsets))
    ]
    by = {j["name"]: j for j in joints}
    T = source.num_frames
    zero = np.zeros((T, 3), np.float32)

    def add(name, parent, offset):
        joints.append(dict(name=name, parent=parent, offset=np.asarray(offset, np.float32), rot=zero))

    for side in "LR":
        hand, fore, upper = by[names[f"Hand_{side}"]], by[names[f"LowerArm_{side}"]], by[names[f"UpperArm_{side}"]]
        toe, calf, thigh = by[names[f"Toes_{side}"]], by[names[f"LowerLeg_{side}"]], by[names[f"UpperLeg_{side}"]]
        along = hand["offset"] / np.linalg.norm(hand["offset"])  # the forearm's direction, on past the wrist
        if "fingers" in extras:
            for f, spread in enumerate((-0.03, -0.015, 0.0, 0.015, 0.03)):
                prev = hand["name"]
                for k in range(3):
                    name = f"{hand['name']}_f{f}{k}"
                    add(name, prev, along * (0.06 if k == 0 else 0.03) + (np.array([0, 0, spread]) if k == 0 else 0))
                    prev = name
        if "twist_leaves" in extras:
            foot = by[names[f"Foot_{side}"]]
            for limb, child in ((upper, fore), (fore, hand), (thigh, calf), (calf, foot)):
                add(f"{limb['name']}_twist1", limb["name"], 0.5 * child["offset"])
        if "share" in extras:
            add(f"{fore['name']}_share", fore["name"], np.zeros(3))
            add(f"{thigh['name']}_share", thigh["name"], np.zeros(3))
        if "toe_end" in extras:
            add(f"{toe['name']}_End", toe["name"], toe["offset"] * 0.5)
        if "twist_in_chain" in extras:  # a roll joint halfway down the upper arm, the forearm under it
            roll = f"{upper['name']}_roll"
            add(roll, upper["name"], 0.5 * fore["offset"])
            fore["offset"], fore["parent"] = 0.5 * fore["offset"], roll
    head = by[names["Head"]]
    up = head["offset"] / np.linalg.norm(head["offset"])
    if "face" in extras:
        for f, off in enumerate(((0.03, 0.08, 0.06), (-0.03, 0.08, 0.06), (0.0, 0.0, 0.08), (0.0, 0.02, 0.15))):
            add(f"{head['name']}_face{f}", head["name"], np.array(off, np.float32) * 0.5 + up * 0.05)
    if "head_top" in extras:
        add(f"{head['name']}Top_End", head["name"], up * 0.18)
    root_name, root_t = names["Hips"], source.root_translation
    if "helper_root" in extras:  # a constant rotation above the body; Hips turned back under it
        R = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], np.float32)  # 90 degrees about x
        from scipy.spatial.transform import Rotation

        hips = by[names["Hips"]]
        hips["rot"] = (Rotation.from_matrix(R.T) * Rotation.from_rotvec(hips["rot"])).as_rotvec().astype(np.float32)
        hips["parent"], hips["offset"] = "RL_BoneRoot", np.zeros(3, np.float32)
        joints.insert(
            0,
            dict(
                name="RL_BoneRoot",
                parent=None,
                offset=np.zeros(3, np.float32),
                rot=np.broadcast_to(Rotation.from_matrix(R).as_rotvec(), (T, 3)).astype(np.float32),
            ),
        )
        root_name = "RL_BoneRoot"
    # depth-first order: parents before children
    kids: dict = {}
    for j in joints:
        kids.setdefault(j["parent"], []).append(j)
    order, stack = [], [j for j in joints if j["parent"] is None]
    while stack:
        j = stack.pop(0)
        order.append(j)
        stack[:0] = kids.get(j["name"], [])
    index = {j["name"]: i for i, j in enumerate(order)}
    parents = [-1 if j["parent"] is None else index[j["parent"]] for j in order]
    offsets = np.stack([j["offset"] for j in order]).astype(np.float32)
    offsets[0] = 0.0
    rot = np.stack([j["rot"] for j in order], axis=1).astype(np.float32)
    skel = Skeleton([j["name"] for j in order], parents)
    pos = fk_axis_angle(torch.from_numpy(rot), torch.from_numpy(root_t), torch.from_numpy(offsets), parents).numpy()
    clip = Clip(
        pos,
        source.fps,
        skel,
        rotations=rot,
        root_translation=root_t,
        offsets=offsets,
        meta={"unit": "cm", "up_axis": "y"},
    )
    write_bvh(path, clip)
    assert order[0]["name"] == root_name
    if "root_offset" in extras:  # the rest hip height in the root's OFFSET, the channels displacements from it
        text = path.read_text()
        head_, motion = text.split("MOTION\n", 1)
        rows = motion.splitlines()
        height = float(np.median([float(r.split()[1]) for r in rows[2:]]))
        head_ = re.sub(r"(ROOT[^\n]*\n\s*\{\s*\n\s*OFFSET) [^\n]*", rf"\1 0 {height:.6f} 0", head_, count=1)
        body = [
            " ".join([v if i != 1 else f"{float(v) - height:.6f}" for i, v in enumerate(r.split())]) for r in rows[2:]
        ]
        path.write_text(head_ + "MOTION\n" + "\n".join(rows[:2] + body) + "\n")
    return path


@pytest.fixture(scope="module")
def model():
    return load_fixer(str(pretrained_path("xmae-cpu-bandai"))).skeleton


@pytest.mark.parametrize("rig", list(RIGS))
def test_every_rig_maps_all_21_joints_and_reads_at_its_true_size(tmp_path, source, model, rig):
    names, extras = RIGS[rig]
    path = _rig(source, names, extras, tmp_path / f"{rig}.bvh")
    [clip] = read_motion(path)
    index = map_joints(clip.skeleton, model, path)
    got = {model.joint_names[m]: clip.skeleton.joint_names[i] for m, i in enumerate(index)}
    assert got == {b: names[b] for b in model.joint_names}
    np.testing.assert_allclose(clip.positions[:, index], source.positions, atol=1e-3)  # metres
    hip = np.median(clip.positions[:, index[0], 2])
    assert abs(hip / np.median(source.positions[:, 0, 2]) - 1) < 0.03
    assert clip.meta["unit"] == "cm" and clip.meta["up_axis"] == "y"


def test_every_cmu_take_maps_all_21_joints_at_the_asf_unit(cmu_files, model):
    for f in cmu_files:
        [clip] = read_motion(f)
        index = map_joints(clip.skeleton, model, f)
        assert len(set(index.tolist())) == 21
        assert clip.meta["unit"] == "asf", (f.name, clip.meta["unit"])  # 0.0564 m: CMU's ASF unit
        assert abs(metres_per_unit(clip.meta) / 0.0564 - 1) < 0.03


def test_inspect_says_how_each_joint_was_found(tmp_path, source, capsys):
    from mocapfix.apps.main import main

    path = _rig(source, *RIGS["random"], tmp_path / "random.bvh")
    capsys.readouterr()
    assert main(["inspect", str(path), "--model", "xmae-cpu-bandai"]) == 0
    out = capsys.readouterr().out
    assert f"UpperArm_L       <- {RIGS['random'][0]['UpperArm_L']} (body part, from the rig's structure)" in out
    assert "(not found)" not in out


def test_a_file_that_becomes_all_missing_says_so(tmp_path, caplog):
    """A public BVH library's fixture: two joints, the hips 90 units up, a 12-unit bone. No body
    to measure, so metres; every position is then out of reach: read as missing, with a warning."""
    import logging

    (tmp_path / "tiny.bvh").write_text(
        "HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation "
        "Yrotation\n  JOINT Chest\n  {\n    OFFSET 0 12 0\n    CHANNELS 3 Zrotation Xrotation Yrotation\n"
        "    End Site\n    {\n      OFFSET 0 8 0\n    }\n  }\n}\nMOTION\nFrames: 2\nFrame Time: 0.033333\n"
        "0 90 0 0 0 0 0 0 0\n1 90 0 0 0 0 0 0 0\n"
    )
    with caplog.at_level(logging.WARNING, logger="mocapfix"):
        [clip] = read_motion(tmp_path / "tiny.bvh")
    assert clip.missing_mask().all() and "100 % of the observed joint positions" in clip.meta["warning"]
    assert any("--unit" in r.getMessage() for r in caplog.records)
    [clip] = read_motion(tmp_path / "tiny.bvh", unit="cm")
    assert not clip.missing_mask().any() and "warning" not in clip.meta


def _fix_cmu(files, tmp_path, capsys):
    from mocapfix.apps.main import main

    capsys.readouterr()
    rc = main(["fix", *map(str, files), "--model", "xmae-cpu-bandai", "--out-dir", str(tmp_path)])
    out = capsys.readouterr()
    assert rc == 0 and sum(" -> " in line for line in out.out.splitlines()) == len(files), out.err
    for f in files:  # a BVH back (or positions where a jump left the take without usable rotations)
        assert (tmp_path / f"{f.stem}.bvh").exists() or (tmp_path / f"{f.stem}.npz").exists()


def test_fix_runs_on_cmu_takes_of_three_performers(cmu_files, tmp_path, capsys):
    by_subject = {}
    for f in cmu_files:
        by_subject.setdefault(f.parent.name, f)
    _fix_cmu(list(by_subject.values())[:3], tmp_path, capsys)


@pytest.mark.slow
def test_fix_runs_on_every_cmu_take(cmu_files, tmp_path, capsys):
    _fix_cmu(cmu_files, tmp_path, capsys)


def test_one_fit_on_two_studios_and_rigs_maps_both_onto_one_body(tmp_path, bandai_files, cmu_files):
    """Bandai Namco (21 joints, 30 fps, cm) and CMU (31 joints, 120 fps, ASF units) in one run:
    --data.path [a, b] --data.body body21; the test split holds takes of both."""

    from cli_utils import CONFIGS, QUIET, TINY, run_cli

    from mocapfix.data.datamodule import MotionDataModule

    bandai, cmu = tmp_path / "bandai", tmp_path / "cmu"
    for folder, files in ((bandai, bandai_files[:6]), (cmu, [f for f in cmu_files if f.parent.name == "05"][:4])):
        folder.mkdir()
        for f in files:
            (folder / f.name).symlink_to(f)
    test_files = [bandai_files[0].name, "05_01.bvh"]
    data = [
        "--data.path",
        f"[{bandai}, {cmu}]",
        "--data.body",
        "body21",
        "--data.test_patterns",
        f"[{', '.join(test_files)}]",
        "--data.val_patterns",
        f"[{bandai_files[1].name}, 05_02.bvh]",
        "--data.batch_size",
        "8",
        "--data.eval_batch_size",
        "64",
        "--data.cache_dir",
        "null",
    ]
    common = [
        "--config",
        CONFIGS / "xmae_cpu.yaml",
        *TINY,
        *QUIET,
        *data,
        "--experiment",
        "two",
        "--trainer.accelerator",
        "cpu",
    ]
    assert run_cli(["fit", *common, "--trainer.max_steps", "4", "--trainer.val_check_interval", "4"], tmp_path) == 0
    ckpt = tmp_path / "checkpoints" / "two" / "last.ckpt"
    assert run_cli(["test", *common, "--ckpt_path", ckpt, "--trainer.limit_test_batches", "1"], tmp_path) == 0
    assert list((tmp_path / "logs" / "two").rglob("eval.json"))
    dm = MotionDataModule("bvh", [str(bandai), str(cmu)], body="body21", cache_dir=None, test_patterns=test_files)
    dm.setup("test")
    tested = {c.source.split("/")[-2] for c in dm.clips["test"]}
    assert tested == {"bandai", "cmu"} and all(c.skeleton.name == "body21" for c in dm.clips["test"])
    assert all(np.isfinite(c.positions).all() for c in dm.clips["test"])  # every body21 joint found in both rigs
