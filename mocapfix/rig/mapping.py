"""A recording's joints onto a model's: which joint of any rig plays each joint of the model's
skeleton (the canonical body, core/skeleton.py body21, or the skeleton a model was trained on).

In this order, each step for the model joints the steps before left: the user's joint map
(`--joint-map`: input name -> model name), the same name, the same name in any case and
namespace, the same body part (rig/labels.py: the rig's structure and its names), and for spines
of different lengths the input's spine joint nearest in relative height between pelvis and neck.
"""

from __future__ import annotations

from mocapfix.core.skeleton import Skeleton
from mocapfix.rig.labels import joint_labels
from mocapfix.rig.names import strip_namespace


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
        folded.setdefault(strip_namespace(n).lower(), []).append(i)
    for n in model.joint_names:
        if n in found:
            continue
        key = strip_namespace(n).lower()
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
            if strip_namespace(given).lower() == strip_namespace(n).lower()
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
