"""Skeleton: joint names, parent indices, limbs and named joint groups (which joint plays which
body part, and the limb groups of a rig read from a file: rig/labels.py).

A skeleton is plain data (tuples and dicts of ints/strings) so that it can travel inside a
checkpoint and be loaded with torch.load(weights_only=True).
"""

from __future__ import annotations

from dataclasses import dataclass, field

GROUP_NAMES = ("left_arm", "right_arm", "left_leg", "right_leg")


@dataclass(frozen=True)
class Skeleton:
    joint_names: tuple[str, ...]
    parents: tuple[int, ...]  # parents[j] < j for every joint but the root (parents[0] == -1)
    groups: dict[str, tuple[int, ...]] = field(default_factory=dict)
    name: str = "custom"
    # The body part each joint plays ("pelvis", "left_knee", ...; None: none), read from the rig's
    # structure (rig/structure.py) when the skeleton came from a file; () when not known. Not
    # part of a skeleton's identity: two readings of one rig are the same skeleton.
    labels: tuple[str | None, ...] = field(default=(), compare=False)

    def __post_init__(self):
        object.__setattr__(self, "joint_names", tuple(self.joint_names))
        object.__setattr__(self, "labels", tuple(self.labels))
        if self.labels and len(self.labels) != len(self.joint_names):
            raise ValueError(f"skeleton {self.name!r}: {len(self.labels)} labels for {len(self.joint_names)} joints")
        object.__setattr__(self, "parents", tuple(int(p) for p in self.parents))
        object.__setattr__(self, "groups", {k: tuple(int(i) for i in v) for k, v in self.groups.items()})
        if len(self.joint_names) != len(self.parents):
            raise ValueError(
                f"skeleton {self.name!r}: {len(self.joint_names)} joint names but {len(self.parents)} parents"
            )
        if not self.parents or self.parents[0] != -1:
            raise ValueError(f"skeleton {self.name!r}: joint 0 must be the root (parent -1)")
        for j, p in enumerate(self.parents[1:], start=1):
            if not 0 <= p < j:
                raise ValueError(
                    f"skeleton {self.name!r}: joint {j} ({self.joint_names[j]}) has parent {p}; "
                    "parents must come before their children"
                )
        for g, idx in self.groups.items():
            if any(not 0 <= i < len(self.parents) for i in idx):
                raise ValueError(f"skeleton {self.name!r}: group {g!r} has a joint index out of range")

    @property
    def num_joints(self) -> int:
        return len(self.parents)

    @property
    def limbs(self) -> tuple[tuple[int, int], ...]:
        """(parent, child) pairs: one per bone."""
        return tuple((p, j) for j, p in enumerate(self.parents) if p >= 0)

    def index(self, joint_name: str) -> int:
        try:
            return self.joint_names.index(joint_name)
        except ValueError:
            raise KeyError(f"skeleton {self.name!r} has no joint {joint_name!r}") from None

    def descendants(self, joint: int) -> list[int]:
        """The joint and every joint below it, in skeleton order."""
        out, inside = [joint], {joint}  # the set: a rig of thousands of joints stays linear
        for j in range(joint + 1, self.num_joints):
            if self.parents[j] in inside:
                out.append(j)
                inside.add(j)
        return out

    def subset(self, keep: list[int]) -> Skeleton:
        """The skeleton restricted to `keep` (sorted), each joint re-hung under its nearest kept ancestor."""
        keep = sorted(set(int(k) for k in keep))
        new_index = {old: new for new, old in enumerate(keep)}
        parents = []
        for j in keep:
            p = self.parents[j]
            while p >= 0 and p not in new_index:
                p = self.parents[p]
            parents.append(new_index.get(p, -1))
        if parents.count(-1) != 1:
            roots = [self.joint_names[j] for j, p in zip(keep, parents) if p == -1]
            raise ValueError(
                f"skeleton {self.name!r}: keeping these joints leaves {len(roots)} roots {roots}; "
                "the kept joints must form one tree"
            )
        groups = {g: tuple(new_index[i] for i in idx if i in new_index) for g, idx in self.groups.items()}
        labels = tuple(self.labels[j] for j in keep) if self.labels else ()
        return Skeleton(tuple(self.joint_names[j] for j in keep), tuple(parents), groups, self.name, labels)

    def with_groups(self, groups: dict[str, list[str] | list[int]]) -> Skeleton:
        """Replace the named groups; members given by joint name or index."""
        resolved = {
            g: tuple(self.index(m) if isinstance(m, str) else int(m) for m in members) for g, members in groups.items()
        }
        return Skeleton(self.joint_names, self.parents, resolved, self.name, self.labels)

    def with_labels(self, labels) -> Skeleton:
        return Skeleton(self.joint_names, self.parents, self.groups, self.name, tuple(labels))

    def to_dict(self) -> dict:
        """Plain python values (lists, str, int): safe for checkpoints and JSON."""
        d = {
            "name": self.name,
            "joint_names": list(self.joint_names),
            "parents": list(self.parents),
            "groups": {k: list(v) for k, v in self.groups.items()},
        }
        if self.labels:
            d["labels"] = list(self.labels)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Skeleton:
        return cls(
            tuple(d["joint_names"]),
            tuple(d["parents"]),
            d.get("groups", {}),
            d.get("name", "custom"),
            tuple(d.get("labels", ())),
        )


# --- presets (reference.md) ---

_H36M17_NAMES = (
    "Hip",
    "RHip",
    "RKnee",
    "RFoot",
    "LHip",
    "LKnee",
    "LFoot",
    "Spine",
    "Thorax",
    "Neck/Nose",
    "Head",
    "LShoulder",
    "LElbow",
    "LWrist",
    "RShoulder",
    "RElbow",
    "RWrist",
)
_H36M17_PARENTS = (-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 9, 8, 11, 12, 8, 14, 15)
_SMPL22_NAMES = (
    "pelvis",
    "left_hip",
    "right_hip",
    "spine1",
    "left_knee",
    "right_knee",
    "spine2",
    "left_ankle",
    "right_ankle",
    "spine3",
    "left_foot",
    "right_foot",
    "neck",
    "left_collar",
    "right_collar",
    "head",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
)
_SMPL22_PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19)

# The canonical body: the 21 joints the shipped models use, named as in Bandai Namco's rig (the
# data they were trained on). Recordings of any rig are mapped onto it by body part to train
# one model on several studios (data.body: body21).
_BODY21_NAMES = (
    "Hips",
    "Spine",
    "Chest",
    "Neck",
    "Head",
    "Shoulder_L",
    "UpperArm_L",
    "LowerArm_L",
    "Hand_L",
    "Shoulder_R",
    "UpperArm_R",
    "LowerArm_R",
    "Hand_R",
    "UpperLeg_L",
    "LowerLeg_L",
    "Foot_L",
    "Toes_L",
    "UpperLeg_R",
    "LowerLeg_R",
    "Foot_R",
    "Toes_R",
)
_BODY21_PARENTS = (-1, 0, 1, 2, 3, 2, 5, 6, 7, 2, 9, 10, 11, 0, 13, 14, 15, 0, 17, 18, 19)

PRESETS = {
    "body21": Skeleton(
        _BODY21_NAMES,
        _BODY21_PARENTS,
        {"left_arm": (6, 7, 8), "right_arm": (10, 11, 12), "left_leg": (13, 14, 15, 16), "right_leg": (17, 18, 19, 20)},
        "body21",
    ),
    "h36m17": Skeleton(
        _H36M17_NAMES,
        _H36M17_PARENTS,
        {"left_arm": (11, 12, 13), "right_arm": (14, 15, 16), "left_leg": (4, 5, 6), "right_leg": (1, 2, 3)},
        "h36m17",
    ),
    "smpl22": Skeleton(
        _SMPL22_NAMES,
        _SMPL22_PARENTS,
        {"left_arm": (16, 18, 20), "right_arm": (17, 19, 21), "left_leg": (1, 4, 7, 10), "right_leg": (2, 5, 8, 11)},
        "smpl22",
    ),
}


def preset(name: str) -> Skeleton:
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown skeleton preset {name!r}; known: {sorted(PRESETS)}") from None
