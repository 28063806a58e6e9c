"""Real exports' rigs, built here from a Bandai Namco take (../shared/data) under their own names
and extra bones: a Character Creator 3/4 rig (a face under the head: jaw, tongue, teeth, eyes;
twist and share bones beside the limbs; fingers; the legs off a pelvis bone beside the waist)
and DAZ/Poser-named rigs without toes. Each maps every joint of the model's body (body21) onto
the joint a rigger would name; a model that cannot take such a rig says which shipped model can."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from mocapfix.core.clip import Clip
from mocapfix.core.kinematics import forward_kinematics
from mocapfix.core.skeleton import Skeleton, preset
from mocapfix.io import read_motion
from mocapfix.io.bvh import read_bvh, write_bvh
from mocapfix.rig.mapping import match_joints

BODY = preset("body21")  # named as in Bandai Namco's rig: the source's joints

# A rig: (name, parent, what it plays) in an order with parents first. What a joint plays:
# - a Bandai joint's name: it moves as that joint does;
# - ("along", f, bandai): f of the way along the bone to that Bandai joint, turning with the bone's
#   top (a twist bone); where a row below it plays that Bandai joint, inside the chain;
# - (forward, left, up): a bone that never moves from its parent, that far (cm) in the body's
#   axes of the first frame (a face's bones, an eye, a share bone at (0, 0, 0)).
Row = tuple[str, str | None, object]


def character_creator(fingers: bool = True) -> list[Row]:
    """Character Creator 3/4's skeleton as its FBX/BVH exports name and hang it (CC_Base_...)."""
    rows: list[Row] = [
        ("CC_Base_Hip", None, "Hips"),
        ("CC_Base_Pelvis", "CC_Base_Hip", (0, 0, 0)),  # the legs' bone, at the hip's place
        ("CC_Base_Waist", "CC_Base_Hip", "Spine"),
        ("CC_Base_Spine01", "CC_Base_Waist", ("along", 0.5, "Chest")),
        ("CC_Base_Spine02", "CC_Base_Spine01", "Chest"),
        ("CC_Base_NeckTwist01", "CC_Base_Spine02", "Neck"),
        ("CC_Base_NeckTwist02", "CC_Base_NeckTwist01", ("along", 0.5, "Head")),
        ("CC_Base_Head", "CC_Base_NeckTwist02", "Head"),
        # the face: a weightless bone in front of the skull's base, the jaw, tongue and teeth below
        # it, the eyes above; all leaves within a few cm of each other
        ("CC_Base_FacialBone", "CC_Base_Head", (2, 0, 4)),
        ("CC_Base_JawRoot", "CC_Base_FacialBone", (1, 0, -1)),
        ("CC_Base_Tongue01", "CC_Base_JawRoot", (3, 0, -2)),
        ("CC_Base_Tongue02", "CC_Base_Tongue01", (2, 0, 0)),
        ("CC_Base_Tongue03", "CC_Base_Tongue02", (1.5, 0, 0.3)),
        ("CC_Base_Teeth02", "CC_Base_JawRoot", (6, 0, -2)),
        ("CC_Base_Teeth01", "CC_Base_FacialBone", (7, 0, -1)),
        ("CC_Base_UpperJaw", "CC_Base_FacialBone", (5, 0, 0)),
        ("CC_Base_L_Eye", "CC_Base_FacialBone", (7, 3.2, 4)),
        ("CC_Base_R_Eye", "CC_Base_FacialBone", (7, -3.2, 4)),
    ]
    for s, side in (("L", "L"), ("R", "R")):
        b = f"CC_Base_{s}_"
        rows += [
            (f"{b}Thigh", "CC_Base_Pelvis", f"UpperLeg_{side}"),
            (f"{b}Calf", f"{b}Thigh", f"LowerLeg_{side}"),
            (f"{b}Foot", f"{b}Calf", f"Foot_{side}"),
            (f"{b}ToeBase", f"{b}Foot", f"Toes_{side}"),
            (f"{b}ToeBaseShareBone", f"{b}ToeBase", (0, 0, 0)),
            (f"{b}CalfTwist01", f"{b}Calf", ("along", 0.0, f"Foot_{side}")),
            (f"{b}CalfTwist02", f"{b}Calf", ("along", 0.5, f"Foot_{side}")),
            (f"{b}KneeShareBone", f"{b}Calf", (0, 0, 0)),
            (f"{b}ThighTwist01", f"{b}Thigh", ("along", 0.0, f"LowerLeg_{side}")),
            (f"{b}ThighTwist02", f"{b}Thigh", ("along", 0.5, f"LowerLeg_{side}")),
            (f"{b}Clavicle", "CC_Base_Spine02", f"Shoulder_{side}"),
            (f"{b}Upperarm", f"{b}Clavicle", f"UpperArm_{side}"),
            (f"{b}Forearm", f"{b}Upperarm", f"LowerArm_{side}"),
            (f"{b}Hand", f"{b}Forearm", f"Hand_{side}"),
            (f"{b}ForearmTwist01", f"{b}Forearm", ("along", 0.0, f"Hand_{side}")),
            (f"{b}ForearmTwist02", f"{b}Forearm", ("along", 0.5, f"Hand_{side}")),
            (f"{b}ElbowShareBone", f"{b}Forearm", (0, 0, 0)),
            (f"{b}UpperarmTwist01", f"{b}Upperarm", ("along", 0.0, f"LowerArm_{side}")),
            (f"{b}UpperarmTwist02", f"{b}Upperarm", ("along", 0.5, f"LowerArm_{side}")),
            (f"{b}RibsTwist", "CC_Base_Spine02", (4, 6 if side == "L" else -6, -8)),
            (f"{b}Breast", f"{b}RibsTwist", (6, 0, -2)),
        ]
        if fingers:
            across = 1 if side == "L" else -1
            for k, finger in enumerate(("Thumb", "Index", "Mid", "Ring", "Pinky")):
                parent = f"{b}Hand"
                for n in (1, 2, 3):
                    # down the hand (the body's -up in the first frame: the arms hang), fanned forward
                    at = (2.5 - 1.2 * k, 0.5 * across, -8.0) if n == 1 else (0, 0, -3.0)
                    rows.append((f"{b}{finger}{n}", parent, at))
                    parent = f"{b}{finger}{n}"
    return rows


def daz_poser(toes: bool = False, right_first: bool = True) -> list[Row]:
    """A DAZ Studio / Poser figure's names (the Poser convention, DAZ's Genesis 1-2): a side as a
    lower case l or r before the word. Poser lists the right limbs first, Genesis the left."""
    rows: list[Row] = [
        ("hip", None, "Hips"),
        ("abdomen", "hip", "Spine"),
        ("chest", "abdomen", "Chest"),
        ("neck", "chest", "Neck"),
        ("head", "neck", "Head"),
    ]
    for s, side in (("r", "R"), ("l", "L")) if right_first else (("l", "L"), ("r", "R")):
        rows += [
            (f"{s}Collar", "chest", f"Shoulder_{side}"),
            (f"{s}Shldr", f"{s}Collar", f"UpperArm_{side}"),
            (f"{s}ForeArm", f"{s}Shldr", f"LowerArm_{side}"),
            (f"{s}Hand", f"{s}ForeArm", f"Hand_{side}"),
            (f"{s}Thigh", "hip", f"UpperLeg_{side}"),
            (f"{s}Shin", f"{s}Thigh", f"LowerLeg_{side}"),
            (f"{s}Foot", f"{s}Shin", f"Foot_{side}"),
        ]
        if toes:
            rows.append((f"{s}Toe", f"{s}Foot", f"Toes_{side}"))
    return rows


# What a rigger maps onto the model's body (Unity's Humanoid, Rokoko's and Blender's retarget
# presets name the same joints).
CC_BODY = {
    "Hips": "CC_Base_Hip",
    "Spine": "CC_Base_Waist",
    "Chest": "CC_Base_Spine02",
    "Neck": "CC_Base_NeckTwist01",
    "Head": "CC_Base_Head",
    **{
        f"{part}_{s}": f"CC_Base_{s}_{cc}"
        for s in "LR"
        for part, cc in (
            ("Shoulder", "Clavicle"),
            ("UpperArm", "Upperarm"),
            ("LowerArm", "Forearm"),
            ("Hand", "Hand"),
            ("UpperLeg", "Thigh"),
            ("LowerLeg", "Calf"),
            ("Foot", "Foot"),
            ("Toes", "ToeBase"),
        )
    },
}
DAZ_BODY = {
    "Hips": "hip",
    "Spine": "abdomen",
    "Chest": "chest",
    "Neck": "neck",
    "Head": "head",
    **{
        f"{part}_{s}": f"{s.lower()}{daz}"
        for s in "LR"
        for part, daz in (
            ("Shoulder", "Collar"),
            ("UpperArm", "Shldr"),
            ("LowerArm", "ForeArm"),
            ("Hand", "Hand"),
            ("UpperLeg", "Thigh"),
            ("LowerLeg", "Shin"),
            ("Foot", "Foot"),
            ("Toes", "Toe"),
        )
    },
}


@pytest.fixture(scope="module")
def source(bandai_files) -> Clip:
    """A Bandai take, 4 s, on its 21 joints (joint_Root left out: Hips carries the motion)."""
    clip = read_bvh({f.name: f for f in bandai_files}["dataset-1_walk_active_001.bvh"], drop_joints=["joint_Root"])[0]
    return clip.replace(
        positions=clip.positions[:120], rotations=clip.rotations[:120], root_translation=clip.root_translation[:120]
    )


def export(source: Clip, rows: list[Row], path: Path) -> Path:
    """source (its rotations) as a BVH of the rig `rows` in cm, y up, written by io/bvh.py."""
    bandai = source.skeleton.joint_names
    T = source.num_frames
    R = torch.from_numpy(Rotation.from_rotvec(source.rotations.reshape(-1, 3)).as_matrix().reshape(T, -1, 3, 3))
    pos, glob = forward_kinematics(
        R, torch.from_numpy(source.root_translation), torch.from_numpy(source.offsets), source.skeleton.parents
    )
    pos, glob = pos[0].numpy(), glob[0].numpy()  # the first frame: (J, 3), (J, 3, 3)
    at = {n: i for i, n in enumerate(bandai)}
    # the body's axes in the first frame: up from the hips to the head, forward from ankle to toe
    up = pos[at["Head"]] - pos[at["Hips"]]
    up /= np.linalg.norm(up)
    forward = pos[at["Toes_L"]] + pos[at["Toes_R"]] - pos[at["Foot_L"]] - pos[at["Foot_R"]]
    forward -= (forward @ up) * up
    forward /= np.linalg.norm(forward)
    axes = np.stack([forward, np.cross(up, forward), up], axis=1)  # (3, 3): body (fwd, left, up) -> world

    below: dict = {}
    for row in rows:
        below.setdefault(row[1], []).append(row)
    ordered, stack = [], list(below[None])
    while stack:  # depth first, siblings in the rig's order: the order write_bvh writes channels in
        row = stack.pop(0)
        ordered.append(row)
        stack[:0] = below.get(row[0], [])
    names, parents, offsets, rotations, turn = [], [], [], [], {}
    for name, parent, plays in ordered:
        p = names.index(parent) if parent is not None else -1
        zero = np.zeros((T, 3))
        if isinstance(plays, str):
            offset, rot = source.offsets[at[plays]].astype(np.float64), source.rotations[:, at[plays]]
            turn[name] = glob[at[plays]]
            above = [r for r in rows if r[0] == parent and isinstance(r[2], tuple) and r[2][0] == "along"]
            if above and above[0][2][2] == plays:  # inside the chain: the rest of the bone
                offset = (1 - above[0][2][1]) * offset
        elif plays[0] == "along":
            offset, rot = plays[1] * source.offsets[at[plays[2]]].astype(np.float64), zero
            turn[name] = turn[parent]
        else:
            offset, rot = turn[parent].T @ (axes @ np.asarray(plays, np.float64) / 100), zero
            turn[name] = turn[parent]
        names.append(name)
        parents.append(p)
        offsets.append(offset)
        rotations.append(rot)
    offsets = np.stack(offsets).astype(np.float32)
    offsets[0] = 0.0
    rotations = np.stack(rotations, axis=1).astype(np.float32)  # (T, J, 3)
    positions = forward_kinematics(
        torch.from_numpy(Rotation.from_rotvec(rotations.reshape(-1, 3)).as_matrix().reshape(T, -1, 3, 3)),
        torch.from_numpy(source.root_translation),
        torch.from_numpy(offsets),
        parents,
    )[0].numpy()
    skeleton = Skeleton(names, parents, name=path.stem)
    clip = Clip(
        positions.astype(np.float32),
        source.fps,
        skeleton,
        rotations=rotations,
        root_translation=source.root_translation,
        offsets=offsets,
        meta={"unit": "cm", "up_axis": "y"},
    )
    write_bvh(path, clip)
    return path


def mapped(path: Path) -> dict[str, str]:
    """body21 joint -> the rig's joint that plays it, as `fix` and `inspect` map it."""
    [clip] = read_motion(path)
    found = match_joints(clip.skeleton, BODY)
    return {n: clip.skeleton.joint_names[i] for n, i in found.items()}


def test_a_character_creator_rig_with_a_face_maps_every_joint(tmp_path, source):
    path = export(source, character_creator(), tmp_path / "cc.bvh")
    assert mapped(path) == CC_BODY
    # the joints a rotation model keeps (read_bvh keep_joints) form one tree: the hips carry both
    # the legs' CC_Base_Pelvis and the spine's CC_Base_Waist (motion-dvae-bandai's "2 roots")
    [clip] = read_bvh(path, keep_joints=list(CC_BODY.values()))
    assert clip.skeleton.num_joints == 21 and clip.has_rotations


@pytest.mark.parametrize("toes", [False, True])
@pytest.mark.parametrize("right_first", [True, False])
def test_a_daz_poser_rig_maps_every_joint_on_its_named_side(tmp_path, source, toes, right_first):
    got = mapped(export(source, daz_poser(toes, right_first), tmp_path / "daz.bvh"))
    want = {n: j for n, j in DAZ_BODY.items() if toes or not n.startswith("Toes")}
    assert got == want


def test_names_state_sides_the_way_each_exporter_writes_them():
    from mocapfix.rig.labels import guess_groups
    from mocapfix.rig.names import side_and_word, sides_and_words

    assert side_and_word("lShldr") == ("left", "shldr") and side_and_word("rThigh") == ("right", "thigh")
    assert side_and_word("leg") == (None, "leg") and side_and_word("root") == (None, "root")
    assert side_and_word("CC_Base_R_Forearm")[0] == "right"
    names = [n for n, _, _ in character_creator(fingers=False)]
    said = dict(zip(names, sides_and_words(names)))  # the prefix every joint shares is not a word
    assert said["CC_Base_L_Upperarm"] == ("left", "upperarm") and said["CC_Base_Head"] == (None, "head")
    rows = daz_poser()
    groups = guess_groups([n for n, _, _ in rows], [-1] + [[n for n, _, _ in rows].index(p) for _, p, _ in rows[1:]])
    top = {g: rows[members[0]][0] for g, members in groups.items()}
    assert top == {"left_arm": "lShldr", "right_arm": "rShldr", "left_leg": "lThigh", "right_leg": "rThigh"}
