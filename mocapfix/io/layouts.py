"""Published keypoint layouts: the joint orders of video lifters, depth cameras and detectors.

A keypoint array ((frames, joints, 3), often without names or a tree) says nothing of its joints
but their count; the layout says which joint each column is. Each layout here is the order its
source publishes, with a tree (the published one where there is one; "derived" where the source
publishes only pairs or nothing: rooted where the body is, so bones join neighbouring joints) and
the body part each joint plays, in rig/labels.py's words, so the rig code maps it onto a model's
body the way it maps a BVH rig (rig/mapping.py). Joints that play no part the models know (eyes,
ears, finger tips, heels) are read, kept and written back, and never used by a model.

A tree need not list parents before children (Kinect v2 hangs the neck and shoulders on joint
20): the reader puts the joints in an order where they do and the writer puts the file's order
back (io/positions.py).

    layout("coco17").joint_names      # the published order
    layouts_for(17)                   # [h36m17, coco17]: a 17-column array needs --layout
"""

from __future__ import annotations

from dataclasses import dataclass

from mocapfix.core.skeleton import PRESETS, Skeleton


@dataclass(frozen=True)
class Layout:
    name: str
    joint_names: tuple[str, ...]
    parents: tuple[int, ...]  # in the file's order: -1 for the root (one), any order otherwise
    labels: tuple[str | None, ...]  # the body part each joint plays (rig/labels.py), None: none
    source: str  # where the order and tree were read
    confidence: str  # what a 4th column means in this layout's files

    def __post_init__(self):
        n = len(self.joint_names)
        if len(self.parents) != n or len(self.labels) != n or list(self.parents).count(-1) != 1:
            raise ValueError(f"layout {self.name}: {n} names, {len(self.parents)} parents, {len(self.labels)} labels")


_H36M = PRESETS["h36m17"]
_SMPL = PRESETS["smpl22"]

# fmt: off
LAYOUTS: dict[str, Layout] = {
    layout.name: layout
    for layout in (
        Layout(
            "h36m17",
            _H36M.joint_names,
            _H36M.parents,
            # Thorax is the top of the spine between the shoulders, "Neck/Nose" the neck's top
            (
                "pelvis", "right_thigh", "right_knee", "right_ankle", "left_thigh", "left_knee", "left_ankle",
                "spine_1of2", "spine_2of2", "neck", "head", "left_upper_arm", "left_elbow", "left_wrist",
                "right_upper_arm", "right_elbow", "right_wrist"),
            "facebookresearch/VideoPose3D common/h36m_dataset.py (32 joints, 15 removed, shoulders on the thorax)",
            "none in the lifters' outputs",
        ),
        Layout(
            "coco17",
            (
                "nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder",
                "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip", "left_knee",
                "right_knee", "left_ankle", "right_ankle"),
            # derived: COCO publishes links, no tree; rooted at the nose, hips under the shoulders
            (
                -1, 0, 0, 1, 2, 0, 0, 5, 6, 7, 8, 5, 6, 11, 12, 13, 14),
            (
                "head", None, None, None, None, "left_upper_arm", "right_upper_arm", "left_elbow", "right_elbow",
                "left_wrist", "right_wrist", "left_thigh", "right_thigh", "left_knee", "right_knee", "left_ankle",
                "right_ankle"),
            "mmpose configs/_base_/datasets/coco.py (names and links; the tree is derived)",
            "a detector's score, 0-1",
        ),
        Layout(
            "mediapipe33",
            (
                "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye",
                "right_eye_outer", "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder",
                "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_pinky",
                "right_pinky", "left_index", "right_index", "left_thumb", "right_thumb", "left_hip", "right_hip",
                "left_knee", "right_knee", "left_ankle", "right_ankle", "left_heel", "right_heel", "left_foot_index",
                "right_foot_index"),
            # derived: MediaPipe publishes connections, no tree; rooted at the nose, hips under the shoulders
            (
                -1, 0, 1, 2, 0, 4, 5, 3, 6, 0, 0, 0, 0, 11, 12, 13, 14, 15, 16, 15, 16, 15, 16, 11, 12, 23, 24, 25,
                26, 27, 28, 27, 28),
            (
                "head", None, None, None, None, None, None, None, None, None, None, "left_upper_arm",
                "right_upper_arm", "left_elbow", "right_elbow", "left_wrist", "right_wrist", None, None, None, None,
                None, None, "left_thigh", "right_thigh", "left_knee", "right_knee", "left_ankle", "right_ankle", None,
                None, "left_toe", "right_toe"),
            "ai.google.dev/mediapipe/solutions/vision/pose_landmarker (names, connections; the tree is derived)",
            "visibility, 0-1",
        ),
        Layout(
            "smpl24",
            _SMPL.joint_names + ("left_hand", "right_hand"),
            _SMPL.parents + (20, 21),
            (
                "pelvis", "left_thigh", "right_thigh", "spine_1of3", "left_knee", "right_knee", "spine_2of3",
                "left_ankle", "right_ankle", "spine_3of3", "left_toe", "right_toe", "neck", "left_clavicle",
                "right_clavicle", "head", "left_upper_arm", "right_upper_arm", "left_elbow", "right_elbow",
                "left_wrist", "right_wrist", None, None),
            "SMPL kintree_table (smplx joint_names.py)",
            "none",
        ),
        Layout(
            "openpose25",
            (
                "Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist", "MidHip", "RHip",
                "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle", "REye", "LEye", "REar", "LEar", "LBigToe", "LSmallToe",
                "LHeel", "RBigToe", "RSmallToe", "RHeel"),
            # derived from the published pairs, rooted at MidHip
            (
                1, 8, 1, 2, 3, 1, 5, 6, -1, 8, 9, 10, 8, 12, 13, 0, 0, 15, 16, 14, 19, 14, 11, 22, 11),
            (
                "head", "neck", "right_upper_arm", "right_elbow", "right_wrist", "left_upper_arm", "left_elbow",
                "left_wrist", "pelvis", "right_thigh", "right_knee", "right_ankle", "left_thigh", "left_knee",
                "left_ankle", None, None, None, None, "left_toe", None, None, "right_toe", None, None),
            "CMU-Perceptual-Computing-Lab/openpose doc/02_output.md (order, pairs; the tree is derived)",
            "a detector's score, 0-1 (pose_keypoints_3d: 0 or 1)",
        ),
        Layout(
            "kinect20",
            (
                "HipCenter", "Spine", "ShoulderCenter", "Head", "ShoulderLeft", "ElbowLeft", "WristLeft", "HandLeft",
                "ShoulderRight", "ElbowRight", "WristRight", "HandRight", "HipLeft", "KneeLeft", "AnkleLeft",
                "FootLeft", "HipRight", "KneeRight", "AnkleRight", "FootRight"),
            # derived from the SDK 1.x skeleton figure
            (
                -1, 0, 1, 2, 2, 4, 5, 6, 2, 8, 9, 10, 0, 12, 13, 14, 0, 16, 17, 18),
            (
                "pelvis", "spine_1of1", "neck", "head", "left_upper_arm", "left_elbow", "left_wrist", None,
                "right_upper_arm", "right_elbow", "right_wrist", None, "left_thigh", "left_knee", "left_ankle",
                "left_toe", "right_thigh", "right_knee", "right_ankle", "right_toe"),
            "Kinect for Windows SDK 1.x NUI_SKELETON_POSITION_INDEX",
            "tracking state: 0 not tracked, 1 inferred, 2 tracked",
        ),
        Layout(
            "kinect25",
            (
                "SpineBase", "SpineMid", "Neck", "Head", "ShoulderLeft", "ElbowLeft", "WristLeft", "HandLeft",
                "ShoulderRight", "ElbowRight", "WristRight", "HandRight", "HipLeft", "KneeLeft", "AnkleLeft",
                "FootLeft", "HipRight", "KneeRight", "AnkleRight", "FootRight", "SpineShoulder", "HandTipLeft",
                "ThumbLeft", "HandTipRight", "ThumbRight"),
            # the SDK's hierarchy: the neck and shoulders hang on joint 20 (SpineShoulder)
            (
                -1, 0, 20, 2, 20, 4, 5, 6, 20, 8, 9, 10, 0, 12, 13, 14, 0, 16, 17, 18, 1, 7, 7, 11, 11),
            (
                "pelvis", "spine_1of2", "neck", "head", "left_upper_arm", "left_elbow", "left_wrist", None,
                "right_upper_arm", "right_elbow", "right_wrist", None, "left_thigh", "left_knee", "left_ankle",
                "left_toe", "right_thigh", "right_knee", "right_ankle", "right_toe", "spine_2of2", None, None, None,
                None),
            "Kinect for Windows SDK 2.0 JointType enumeration; the SDK's body hierarchy",
            "tracking state: 0 not tracked, 1 inferred, 2 tracked",
        ),
        Layout(
            "azure32",
            (
                "PELVIS", "SPINE_NAVEL", "SPINE_CHEST", "NECK", "CLAVICLE_LEFT", "SHOULDER_LEFT", "ELBOW_LEFT",
                "WRIST_LEFT", "HAND_LEFT", "HANDTIP_LEFT", "THUMB_LEFT", "CLAVICLE_RIGHT", "SHOULDER_RIGHT",
                "ELBOW_RIGHT", "WRIST_RIGHT", "HAND_RIGHT", "HANDTIP_RIGHT", "THUMB_RIGHT", "HIP_LEFT", "KNEE_LEFT",
                "ANKLE_LEFT", "FOOT_LEFT", "HIP_RIGHT", "KNEE_RIGHT", "ANKLE_RIGHT", "FOOT_RIGHT", "HEAD", "NOSE",
                "EYE_LEFT", "EAR_LEFT", "EYE_RIGHT", "EAR_RIGHT"),
            (
                -1, 0, 1, 2, 2, 4, 5, 6, 7, 8, 7, 2, 11, 12, 13, 14, 15, 14, 0, 18, 19, 20, 0, 22, 23, 24, 3, 26, 26,
                26, 26, 26),
            (
                "pelvis", "spine_1of2", "spine_2of2", "neck", "left_clavicle", "left_upper_arm", "left_elbow",
                "left_wrist", None, None, None, "right_clavicle", "right_upper_arm", "right_elbow", "right_wrist",
                None, None, None, "left_thigh", "left_knee", "left_ankle", "left_toe", "right_thigh", "right_knee",
                "right_ankle", "right_toe", "head", None, None, None, None, None),
            "learn.microsoft.com/azure/kinect-dk/body-joints (joint hierarchy), k4abttypes.h",
            "confidence level: 0 none (out of view), 1 low (predicted), 2 medium, 3 high",
        ),
    )
}
# fmt: on


# Arrays whose first points are a layout's body and whose others are points no body model has:
# FreeMoCap's output_data/mediapipe_skeleton_3d.npy, MediaPipe's body 33, right hand 21, left hand
# 21 and face mesh (468 points before FreeMoCap 1.4, 478 with the irises after; freemocap
# @a1cd374a, and the 2021 pre-alpha's real (T, 543, 3) outputs) -> the body's layout. The other
# points are carried through as read.
BODY_FIRST = {33 + 21 + 21 + 468: "mediapipe33", 33 + 21 + 21 + 478: "mediapipe33"}


def layout(name: str) -> Layout:
    try:
        return LAYOUTS[name]
    except KeyError:
        raise ValueError(f"unknown keypoint layout {name!r}; known: {', '.join(LAYOUTS)}") from None


def layouts_for(num_joints: int) -> list[Layout]:
    """The layouts of num_joints joints: one tells an array's layout from its shape, two or more
    need --layout."""
    return [lay for lay in LAYOUTS.values() if len(lay.joint_names) == num_joints]


def layout_named(joint_names) -> Layout | None:
    """The layout whose published names these are, in its order (a file that names its joints)."""
    names = tuple(str(n) for n in joint_names)
    return next((lay for lay in LAYOUTS.values() if lay.joint_names == names), None)


def parents_first(parents) -> list[int]:
    """An order of the joints with every parent before its children, the root first, otherwise
    as close to the given order as that allows (depth-first, children in their order): for each
    position the index in the given order."""
    children: dict[int, list[int]] = {}
    for j, p in enumerate(parents):
        children.setdefault(int(p), []).append(j)
    order, stack = [], list(reversed(children.get(-1, [])))
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(reversed(children.get(j, [])))
    if len(order) != len(parents):
        raise ValueError("the parents do not form one tree")
    return order


def layout_skeleton(lay: Layout) -> tuple[Skeleton, list[int]]:
    """The layout's skeleton, parents before children, and its order: skeleton joint k is the
    file's joint order[k] (the identity where the layout's tree already is in that order)."""
    order = list(range(len(lay.parents)))
    if any(not 0 <= p < j for j, p in enumerate(lay.parents[1:], start=1)) or lay.parents[0] != -1:
        order = parents_first(lay.parents)
    position = {j: k for k, j in enumerate(order)}
    parents = [position[lay.parents[j]] if lay.parents[j] >= 0 else -1 for j in order]
    names = [lay.joint_names[j] for j in order]
    labels = [lay.labels[j] for j in order]
    skeleton = Skeleton(names, parents, name=lay.name, labels=labels)
    return skeleton.with_groups(_limb_groups(skeleton)), order


_LIMB_TOPS = {
    "left_arm": "left_upper_arm",
    "right_arm": "right_upper_arm",
    "left_leg": "left_thigh",
    "right_leg": "right_thigh",
}


def _limb_groups(skeleton: Skeleton) -> dict[str, list[int]]:
    """Each limb's top joint and what hangs below it, less the other limbs: a derived tree that
    hangs the hips under the shoulders (COCO, MediaPipe: no pelvis to hang them on) keeps its
    legs out of its arms."""
    tops = {g: skeleton.labels.index(top) for g, top in _LIMB_TOPS.items() if top in skeleton.labels}
    groups = {}
    for g, top in tops.items():
        below = skeleton.descendants(top)
        others = {j for o in tops.values() if o != top and o in below for j in skeleton.descendants(o)}
        groups[g] = [j for j in below if j not in others]
    return groups
