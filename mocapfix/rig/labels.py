"""The body part each joint of a rig plays, as one list: the rig's structure (rig/structure.py)
and what its names say (rig/names.py) put together; and what is read from those parts: the
pelvis, and the limb groups (each limb's top joint and everything below it).

Labels are "pelvis", "spine_2of3", "neck", "head", "left_clavicle", "left_upper_arm",
"left_elbow", "left_wrist", "left_thigh", "left_knee", "left_ankle", "left_toe" (and right_...),
"left_hip_helper" (CMU's LHipJoint); None for every joint that plays no part of the body.
"""

from __future__ import annotations

import numpy as np

from mocapfix.core.skeleton import GROUP_NAMES, Skeleton
from mocapfix.rig.names import name_labels


def joint_labels(skeleton: Skeleton) -> list[str | None]:
    """One label per joint ("left_upper_arm", "pelvis", "spine_2of3", ...), None for joints that
    play no part (fingers, twist bones, helpers): the skeleton's labels from the rig's structure
    (rig/structure.py) where it has them, and the names' for parts the structure left out."""
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


def pelvis(skeleton: Skeleton) -> int:
    """The pelvis: the joint the structure or a name labels so, else the first joint where three
    or more chains start (legs and spine), else the root."""
    labels = joint_labels(skeleton)
    if "pelvis" in labels:
        return labels.index("pelvis")
    return pelvis_joint(skeleton.parents)


def pelvis_joint(parents) -> int:
    """The first joint where three or more chains start (legs + spine); the root otherwise."""
    nchild = np.bincount(np.array([p for p in parents if p >= 0], dtype=np.int64), minlength=len(parents))
    hits = np.flatnonzero(nchild >= 3)
    return int(hits[0]) if hits.size else 0


def limb_groups(skeleton: Skeleton) -> dict[str, tuple[int, ...]]:
    """left/right arm/leg groups (core/skeleton.py GROUP_NAMES): each limb's top joint (the upper
    arm, the thigh) and everything below it, from the skeleton's labels; by name (guess_groups)
    for the limbs the labels do not place."""
    groups = dict(guess_groups(skeleton.joint_names, skeleton.parents))
    labels = list(skeleton.labels)
    for side in ("left", "right"):
        for group, top in (("arm", "upper_arm"), ("leg", "thigh")):
            if f"{side}_{top}" in labels:
                groups[f"{side}_{group}"] = tuple(skeleton.descendants(labels.index(f"{side}_{top}")))
    return {g: groups[g] for g in GROUP_NAMES if g in groups}


def guess_groups(joint_names, parents) -> dict[str, tuple[int, ...]]:
    """left/right arm/leg groups from joint names alone (rig/names.py name_labels): each limb's
    upper arm or thigh (the elbow or knee where the name of none says it) and everything below.
    Groups that cannot be found are left out; give them explicitly in the config then."""
    skel = Skeleton(tuple(joint_names), tuple(parents))
    labels = name_labels(skel)
    groups: dict[str, tuple[int, ...]] = {}
    for side in ("left", "right"):
        for group, tops in (("arm", ("upper_arm", "elbow")), ("leg", ("thigh", "knee"))):
            top = next((f"{side}_{t}" for t in tops if f"{side}_{t}" in labels), None)
            if top is not None:
                groups[f"{side}_{group}"] = tuple(skel.descendants(labels.index(top)))
    return {g: groups[g] for g in GROUP_NAMES if g in groups}
