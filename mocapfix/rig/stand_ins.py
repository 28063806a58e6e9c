"""Stand-ins for the body joints a rig lacks, placed from the joints it has.

A network that reads every joint of the body (the jitter remover) can still serve a keypoint
layout that lacks some (COCO has no pelvis or spine, Human3.6M no clavicles or toes): each
absent joint is put where the body's own geometry puts it, from the joints the take has, frame by
frame, so it moves as smoothly as they do and adds no jitter of its own. The stand-ins feed the
network and are never written: nothing in the take says where they were.
"""

from __future__ import annotations

import numpy as np

from mocapfix.core.skeleton import Skeleton
from mocapfix.rig.labels import joint_labels

TOE_FORWARD_M = 0.12  # ankle to toe along the body's forward direction, an adult's foot
HEAD_ABOVE_NECK_M = 0.12


def with_stand_ins(x: np.ndarray, present: np.ndarray, model: Skeleton) -> np.ndarray:
    """x: (T, J, 3) metres, z up, at the model's joints, finite where present (J,) -> x with
    every absent joint placed: the pelvis between the thighs, the neck between the upper arms,
    spine joints evenly between pelvis and neck, a clavicle halfway from its parent to the upper
    arm, the head above the neck, a toe ahead of its ankle; any other at its parent's place."""
    x, have = x.astype(np.float64).copy(), present.copy()
    labels = joint_labels(model)
    at = {label: j for j, label in enumerate(labels) if label is not None}

    def put(j: int, value: np.ndarray) -> None:
        x[:, j], have[j] = value, True

    def both(a: str, b: str) -> bool:
        return a in at and b in at and have[at[a]] and have[at[b]]

    if "pelvis" in at and not have[at["pelvis"]] and both("left_thigh", "right_thigh"):
        put(at["pelvis"], 0.5 * (x[:, at["left_thigh"]] + x[:, at["right_thigh"]]))
    if "neck" in at and not have[at["neck"]] and both("left_upper_arm", "right_upper_arm"):
        put(at["neck"], 0.5 * (x[:, at["left_upper_arm"]] + x[:, at["right_upper_arm"]]))
    spine = sorted((label for label in at if label.startswith("spine_")), key=lambda s: int(s[6 : s.index("of")]))
    if both("pelvis", "neck"):
        for rank, label in enumerate(spine, start=1):
            if not have[at[label]]:
                put(at[label], x[:, at["pelvis"]] + rank / (len(spine) + 1) * (x[:, at["neck"]] - x[:, at["pelvis"]]))
    for side in ("left", "right"):
        clavicle, arm = at.get(f"{side}_clavicle"), at.get(f"{side}_upper_arm")
        if clavicle is not None and not have[clavicle] and arm is not None and have[arm]:
            parent = model.parents[clavicle]
            if parent >= 0 and have[parent]:
                put(clavicle, 0.5 * (x[:, parent] + x[:, arm]))
    if "head" in at and not have[at["head"]] and "neck" in at and have[at["neck"]]:
        put(at["head"], x[:, at["neck"]] + np.array([0.0, 0.0, HEAD_ABOVE_NECK_M]))
    if both("left_thigh", "right_thigh"):
        left = x[:, at["left_thigh"]] - x[:, at["right_thigh"]]  # (T, 3) towards the body's left
        forward = np.cross(left, np.array([0.0, 0.0, 1.0]))
        forward /= np.maximum(np.linalg.norm(forward, axis=-1, keepdims=True), 1e-9)
        for side in ("left", "right"):
            toe, ankle = at.get(f"{side}_toe"), at.get(f"{side}_ankle")
            if toe is not None and not have[toe] and ankle is not None and have[ankle]:
                put(toe, x[:, ankle] + TOE_FORWARD_M * forward)
    for j in range(model.num_joints):  # parents first: whatever is left, at its parent's place
        if not have[j] and model.parents[j] >= 0 and have[model.parents[j]]:
            put(j, x[:, model.parents[j]])
    if not have.all():
        lost = ", ".join(model.joint_names[j] for j in np.nonzero(~have)[0])
        raise ValueError(f"no place for {lost} from the joints the rig has")
    return x
