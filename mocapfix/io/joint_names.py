"""Joint names across humanoid conventions.

A model trained on one skeleton's names (Bandai Namco's `UpperArm_L`) meets recordings named
another way: Mixamo (`mixamorig:LeftArm`), CMU / ASF-style BVH (`LeftArm`, `LHipJoint`), SMPL
(`left_shoulder`), Human3.6M (`LShoulder`), optical-capture labels (`L_Elbow`, `RightKnee`).
Each name gets a label, (side, body part), and two skeletons are matched label to label:
case, separators and namespace prefixes do not matter.

What a word means can depend on the rest of the skeleton, so labels are given per skeleton:
- "shoulder" is the clavicle where the same side also has an upper-arm joint ("arm",
  "upperarm": Bandai, CMU, Mixamo), else the upper arm itself (SMPL, Human3.6M);
- "foot" is the toe joint where the same side also has an "ankle" (SMPL), else the ankle;
- "hip" with a side is the thigh's top (SMPL, Human3.6M) unless the side has an up-leg joint
  ("upleg", "thigh": CMU, Mixamo), where it is CMU's short helper bone (`LHipJoint`);
- the spine joints between the pelvis and the neck (Spine, Spine1, Chest, Thorax, ...) have no
  shared vocabulary: they are labelled by their rank along that chain, from the pelvis up, and
  matched by rank; where the two spines differ in length, each model spine joint takes the
  input's joint nearest in relative height (SMPL's spine3 plays Bandai Namco's Chest: a few cm
  off, inside the tolerance of a fill).
"""

from __future__ import annotations

import re

from mocapfix.core.skeleton import Skeleton

# side-less word (lowercase, separators removed) -> part. Order matters only for readability.
_PART_WORDS: dict[str, str] = {
    # legs
    "upleg": "thigh",
    "upperleg": "thigh",
    "thigh": "thigh",
    "femur": "thigh",
    "leg": "knee",
    "lowerleg": "knee",
    "lowleg": "knee",
    "knee": "knee",
    "shin": "knee",
    "calf": "knee",
    "tibia": "knee",
    "ankle": "ankle",
    "toebase": "toe",
    "toe": "toe",
    "toes": "toe",
    "ball": "toe",
    # arms
    "collar": "clavicle",
    "clavicle": "clavicle",
    "upperarm": "upper_arm",
    "uparm": "upper_arm",
    "arm": "upper_arm",
    "humerus": "upper_arm",
    "forearm": "elbow",
    "lowerarm": "elbow",
    "lowarm": "elbow",
    "elbow": "elbow",
    "radius": "elbow",
    "hand": "wrist",
    "wrist": "wrist",
    # trunk and head
    "hips": "pelvis",
    "pelvis": "pelvis",
    "root": "pelvis",
    "neck": "neck",
    "necknose": "neck",  # Human3.6M's "Neck/Nose"
    "head": "head",
}
# "Left...", "L_...", "..._L", "...Left" in any case; "L" + a capital only as written ("LHip",
# not "LowerArm")
_SIDE_MARK = {
    "left": re.compile(r"^left|^l(?=[_\-.\s])|[_\-.\s]l$|left$", re.I),
    "right": re.compile(r"^right|^r(?=[_\-.\s])|[_\-.\s]r$|right$", re.I),
}
_CASE_SENSITIVE = {"left": re.compile(r"^L(?=[A-Z])"), "right": re.compile(r"^R(?=[A-Z])")}


def _strip_namespace(name: str) -> str:
    """`mixamorig:LeftArm` -> `LeftArm`, `Armature|Hips` -> `Hips`."""
    return re.split(r"[:|]", name.strip())[-1]


def side_and_word(name: str) -> tuple[str | None, str]:
    """(side or None, the rest lowercased without separators): `UpperArm_L` -> ("left",
    "upperarm"), `mixamorig:LeftForeArm` -> ("left", "forearm"), `Neck/Nose` -> (None, "necknose")."""
    n = _strip_namespace(name)
    for side in ("left", "right"):
        m = _CASE_SENSITIVE[side].search(n) or _SIDE_MARK[side].search(n)
        if m is not None:
            rest = n[: m.start()] + n[m.end() :]
            return side, re.sub(r"[_\-.\s/]", "", rest).lower()
    return None, re.sub(r"[_\-.\s/]", "", n).lower()


def joint_labels(skeleton: Skeleton) -> list[str | None]:
    """One label per joint ("left_upper_arm", "pelvis", "spine_2of3", ...), None for joints that
    play no part (fingers, twist bones, helpers): the skeleton's labels from the rig's structure
    (io/body_structure.py) where it has them, and the names' for parts the structure left out."""
    by_name = name_labels(skeleton)
    if not skeleton.labels:
        return by_name
    # A name in a known convention that says another part wins: the structure cannot see a joint
    # that is not there (an arm without its wrist reads as clavicle, upper arm, forearm), a
    # name can. Spine ranks stay the structure's; parts no name places stay the structure's.
    labels = [n if n is not None and not n.startswith("spine_") else s for s, n in zip(skeleton.labels, by_name)]
    for label in {x for x in labels if x is not None}:
        holders = [j for j, x in enumerate(labels) if x == label]
        if len(holders) > 1:  # one joint per part: the one whose name says it
            keep = next((j for j in holders if by_name[j] == label), holders[0])
            for j in holders:
                if j != keep:
                    labels[j] = None
    return labels


def name_labels(skeleton: Skeleton) -> list[str | None]:
    """One label per joint from its name alone, None where the name says nothing known."""
    names = skeleton.joint_names
    split = [side_and_word(n) for n in names]
    words_by_side: dict[str | None, set[str]] = {}
    for side, word in split:
        words_by_side.setdefault(side, set()).add(word)
    labels: list[str | None] = []
    for side, word in split:
        part = _PART_WORDS.get(word)  # exact words only: "Neck1" above "Neck" is not the neck
        same_side = words_by_side.get(side, set())
        if word == "shoulder":
            part = "clavicle" if same_side & {"arm", "upperarm", "uparm"} else "upper_arm"
        elif word == "foot":
            part = "toe" if "ankle" in same_side else "ankle"
        elif word in ("hip", "hipjoint"):
            if side is None:
                part = "pelvis"
            else:
                part = "hip_helper" if same_side & {"upleg", "upperleg", "thigh"} else "thigh"
        if side is None and part in ("thigh", "knee", "ankle", "toe", "clavicle", "upper_arm", "elbow", "wrist"):
            part = None  # a limb joint without a side cannot be placed
        if side is not None and part in ("pelvis", "neck", "head"):
            part = None
        labels.append(None if part is None else part if side is None else f"{side}_{part}")
    # the spine: unlabelled side-less joints on the path from the pelvis to the neck, by rank
    if "pelvis" in labels and "neck" in labels:
        j = labels.index("neck")
        chain = []
        while j >= 0 and labels[j] != "pelvis":
            j = skeleton.parents[j]
            if j >= 0 and labels[j] is None and split[j][0] is None:
                chain.append(j)
        chain.reverse()  # pelvis up
        for rank, j in enumerate(chain):
            labels[j] = f"spine_{rank + 1}of{len(chain)}"
    return labels


def match_joints(skeleton: Skeleton, model: Skeleton, joint_map: dict[str, str] | None = None) -> dict[str, int]:
    """model joint name -> index of the joint of `skeleton` that plays its part, for the model
    joints that can be found: by the user's joint_map (input name -> model name) first, then the
    same name, the same name in any case, then the same label (joint_labels). Spine joints match
    by rank only where both skeletons have as many between pelvis and neck."""
    found: dict[str, int] = {}
    taken: set[int] = set()
    index = {n: i for i, n in enumerate(skeleton.joint_names)}
    for given, target in (joint_map or {}).items():
        if given in index and target in model.joint_names:
            found[target] = index[given]
            taken.add(index[given])
    folded: dict[str, list[int]] = {}
    for i, n in enumerate(skeleton.joint_names):
        folded.setdefault(_strip_namespace(n).lower(), []).append(i)
    for n in model.joint_names:
        if n in found:
            continue
        key = _strip_namespace(n).lower()
        if n in index and index[n] not in taken:
            found[n] = index[n]
        elif len(folded.get(key, [])) == 1 and folded[key][0] not in taken:
            found[n] = folded[key][0]
        if n in found:
            taken.add(found[n])
    mine, theirs = joint_labels(skeleton), joint_labels(model)
    by_label: dict[str, list[int]] = {}
    for i, label in enumerate(mine):
        if label is not None and i not in taken:
            by_label.setdefault(label, []).append(i)
    for n, label in zip(model.joint_names, theirs):
        if n not in found and label is not None and len(by_label.get(label, [])) == 1:
            found[n] = by_label[label][0]
            taken.add(found[n])
    # spines of different lengths: the input's spine joint nearest in relative height along the chain
    spine = [i for i, label in enumerate(mine) if label and label.startswith("spine_") and i not in taken]
    for n, label in zip(model.joint_names, theirs):
        if n in found or not label or not label.startswith("spine_") or not spine:
            continue
        best = min(spine, key=lambda i: abs(_spine_height(mine[i]) - _spine_height(label)))
        found[n] = best
        spine.remove(best)
    return found


def _spine_height(label: str) -> float:
    """ "spine_2of3" -> 0.5: the joint's place between pelvis (0) and neck (1)."""
    rank, count = label[len("spine_") :].split("of")
    return int(rank) / (int(count) + 1)


JOINT_MAP_BYTES = 4 << 20  # a line per joint: 4 MiB is tens of thousands of joints


def read_joint_map(path) -> dict[str, str]:
    """A --joint-map file: YAML, `input name: model name` per line -> dict. Anything else is a
    MotionFileError naming the file."""
    from pathlib import Path

    import yaml

    from mocapfix.core.clip import MotionFileError
    from mocapfix.io.untrusted import printable, read_bytes

    path = Path(path)
    try:  # a regular file only (a FIFO would wait forever), and no larger than a map of 10,000s of joints
        data = yaml.safe_load(read_bytes(path, "joint map", limit=JOINT_MAP_BYTES).decode("utf-8"))
    except OSError as e:
        raise MotionFileError(path, f"cannot read the joint map ({e.strerror or e})") from None
    except UnicodeDecodeError as e:
        raise MotionFileError(path, f"the joint map is not UTF-8 text (byte {e.start})") from None
    except yaml.YAMLError as e:  # its str() quotes the offending line: say where instead
        mark = getattr(e, "problem_mark", None)
        where = f"line {mark.line + 1}: " if mark is not None else ""
        problem = printable(getattr(e, "problem", None) or type(e).__name__, 80)
        raise MotionFileError(path, f"not a YAML joint map ({where}{problem})") from None
    if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
        raise MotionFileError(path, "a joint map is `input name: model name` per line")
    return dict(data)


def check_joint_map(joint_map: dict[str, str], model: Skeleton, path) -> None:
    """A --joint-map names model joints on its right-hand side: one the model does not have is a
    typo that would otherwise be ignored, so it is a MotionFileError naming the map file."""
    from mocapfix.core.clip import MotionFileError
    from mocapfix.io.untrusted import quoted

    unknown = [v for v in joint_map.values() if v not in model.joint_names]
    if unknown:
        more = f" and {len(unknown) - 5} more" if len(unknown) > 5 else ""
        raise MotionFileError(
            path,
            f"maps onto {', '.join(quoted(v) for v in unknown[:5])}{more}, not joints of the model "
            f"({model.name}: {', '.join(model.joint_names)})",
        )


def describe_mapping(skeleton: Skeleton, model: Skeleton, joint_map: dict[str, str] | None = None) -> list[str]:
    """Lines for `inspect --ckpt`: each model joint and the input joint that plays it (and how
    it was found), the model joints not found, and the input joints the model does not use."""
    found = match_joints(skeleton, model, joint_map)
    mine, theirs = joint_labels(skeleton), joint_labels(model)
    lines = []
    for n in model.joint_names:
        if n not in found:
            lines.append(f"{n:<16} <- (not found)")
            continue
        given = skeleton.joint_names[found[n]]
        how = (
            "joint map"
            if (joint_map or {}).get(given) == n
            else "name"
            if _strip_namespace(given).lower() == _strip_namespace(n).lower()
            else "nearest spine joint"
            if mine[found[n]] != theirs[model.index(n)]
            else "body part, from the rig's structure"
            if skeleton.labels and skeleton.labels[found[n]] == mine[found[n]]
            else "body part, from its name"
        )
        lines.append(f"{n:<16} <- {given} ({how})")
    used = set(found.values())
    extra = [skeleton.joint_names[i] for i in range(skeleton.num_joints) if i not in used]
    if extra:
        where = "kept as recorded, moved with the model joint above them where fix replaces it"
        lines.append(f"not used by the model ({where}): {', '.join(extra)}")
    return lines


def onto_skeleton(clip, target: Skeleton):
    """A clip's positions on `target`'s joints, each found by match_joints (name, structure, name's
    body part): the recording of any rig as the canonical body (core/skeleton.py: body21). A
    target joint the recording lacks is missing in every frame; fewer than half found is a
    MotionFileError naming them. Positions only: another rig's rotations are not the target's."""
    import numpy as np

    from mocapfix.core.clip import MotionFileError

    found = match_joints(clip.skeleton, target)
    missing = [n for n in target.joint_names if n not in found]
    if 2 * len(found) < target.num_joints:
        raise MotionFileError(
            clip.source or clip.name,
            f"maps {len(found)} of {target.name}'s {target.num_joints} joints (missing {', '.join(missing)}); "
            "`mocapfix inspect FILE --model NAME` shows the mapping",
        )
    index = np.array([found.get(n, -1) for n in target.joint_names])
    positions = np.where((index >= 0)[None, :, None], clip.positions[:, np.maximum(index, 0)], np.nan)
    meta = {**clip.meta, "mapped_from": clip.skeleton.name}
    if missing:
        meta["absent_joints"] = missing
    return clip.replace(
        positions=positions, skeleton=target, rotations=None, root_translation=None, offsets=None, meta=meta
    )
