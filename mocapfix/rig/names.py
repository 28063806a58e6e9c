"""What a joint's name says: its side and its body part, across humanoid conventions.

A model trained on one skeleton's names (Bandai Namco's `UpperArm_L`) meets recordings named
another way: Mixamo (`mixamorig:LeftArm`), CMU / ASF-style BVH (`LeftArm`, `LHipJoint`), SMPL
(`left_shoulder`), Human3.6M (`LShoulder`), optical-capture labels (`L_Elbow`, `RightKnee`),
Character Creator (`CC_Base_L_Upperarm`), DAZ/Poser (`lShldr`). Each name gets a label, (side,
body part), and two skeletons are matched label to label (rig/mapping.py): case, separators,
namespaces and a prefix that (nearly) every joint of the rig shares do not matter.

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
from collections import Counter

from mocapfix.core.skeleton import Skeleton

# side-less word (lowercase, separators removed) -> part. Order matters only for readability.
_PART_WORDS: dict[str, str] = {
    # legs
    "upleg": "thigh",
    "upperleg": "thigh",
    "thigh": "thigh",
    "femur": "thigh",
    "thighbend": "thigh",
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
    "uarm": "upper_arm",  # OptiTrack: LUArm, LFArm
    "arm": "upper_arm",
    "humerus": "upper_arm",
    "shldr": "upper_arm",  # DAZ/Poser: lShldr; Genesis 3/8 split the long bones: lShldrBend, lShldrTwist
    "shldrbend": "upper_arm",
    "forearm": "elbow",
    "lowerarm": "elbow",
    "lowarm": "elbow",
    "farm": "elbow",
    "elbow": "elbow",
    "radius": "elbow",
    "forearmbend": "elbow",
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
_UPPER_ARM_WORDS = {w for w, part in _PART_WORDS.items() if part == "upper_arm"}
_THIGH_WORDS = {w for w, part in _PART_WORDS.items() if part == "thigh"}

# The one reading of a side from a name (structure, labels, groups and mirroring all ask it):
# "Left...", "L_...", "..._L", "...Left", "..._L_..." in any case; a single "L"/"l" straight
# before a capital only as written ("LHip", DAZ/Poser's "lShldr"; not "LowerArm", "leg")
_SIDE_MARK = {
    "left": re.compile(r"^left|^l(?=[_\-.\s])|[_\-.\s]l$|left$|[_\-.\s]l[_\-.\s]", re.I),
    "right": re.compile(r"^right|^r(?=[_\-.\s])|[_\-.\s]r$|right$|[_\-.\s]r[_\-.\s]", re.I),
}
_CASE_SENSITIVE = {"left": re.compile(r"^[Ll](?=[A-Z])"), "right": re.compile(r"^[Rr](?=[A-Z])")}
_SEPARATORS = r"[_\-.\s/]"


def strip_namespace(name: str) -> str:
    """`mixamorig:LeftArm` -> `LeftArm`, `Armature|Hips` -> `Hips`."""
    return re.split(r"[:|]", name.strip())[-1]


def side_and_word(name: str) -> tuple[str | None, str]:
    """(side or None, the rest lowercased without separators): `UpperArm_L` -> ("left",
    "upperarm"), `mixamorig:LeftForeArm` -> ("left", "forearm"), `lShldr` -> ("left", "shldr"),
    `L_Thigh` -> ("left", "thigh"), `Neck/Nose` -> (None, "necknose")."""
    n = strip_namespace(name)
    for side in ("left", "right"):
        m = _CASE_SENSITIVE[side].search(n) or _SIDE_MARK[side].search(n)
        if m is not None:
            rest = n[: m.start()] + n[m.end() :]
            return side, re.sub(_SEPARATORS, "", rest).lower()
    return None, re.sub(_SEPARATORS, "", n).lower()


def shared_prefix(names) -> str:
    """The longest prefix ending at a separator that at least three quarters of the names share
    (`CC_Base_`, `Skeleton_`, `DEF-`; a helper root or two named otherwise do not stop it), or
    "". Namespaces (`mixamorig:`) are stripped first."""
    names = [strip_namespace(n) for n in names]
    counts: Counter[str] = Counter()
    for n in names:
        for m in re.finditer(_SEPARATORS, n[:-1]):  # a prefix leaves something of the name
            counts[n[: m.end()]] += 1
    shared = [p for p, c in counts.items() if c >= 0.75 * len(names)]
    return max(shared, key=len, default="")


def sides_and_words(names) -> list[tuple[str | None, str]]:
    """side_and_word of each of a rig's joint names, the prefix they share (shared_prefix) off:
    `CC_Base_L_Thigh` -> ("left", "thigh"), `Skeleton_LShin` -> ("left", "shin")."""
    prefix = shared_prefix(names)
    return [side_and_word(strip_namespace(n).removeprefix(prefix)) for n in names]


def name_labels(skeleton: Skeleton) -> list[str | None]:
    """One label per joint from its name alone, None where the name says nothing known."""
    split = sides_and_words(skeleton.joint_names)
    words_by_side: dict[str | None, set[str]] = {}
    for side, word in split:
        words_by_side.setdefault(side, set()).add(word)
    labels: list[str | None] = []
    for side, word in split:
        part = _PART_WORDS.get(word)  # exact words only: "Neck1" above "Neck" is not the neck
        same_side = words_by_side.get(side, set())
        if word == "shoulder":
            part = "clavicle" if same_side & _UPPER_ARM_WORDS else "upper_arm"
        elif word == "foot":
            part = "toe" if "ankle" in same_side else "ankle"
        elif word in ("hip", "hipjoint"):
            if side is None:
                part = "pelvis"
            else:
                part = "hip_helper" if same_side & _THIGH_WORDS else "thigh"
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
