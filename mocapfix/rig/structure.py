"""Which joint of a humanoid rig plays which part, from the rig's structure and motion.

Every humanoid rig has the same shape, whatever its exporter calls the joints: five long
branches (two legs, two arms, the head) off a trunk. Read in steps, each from the ones before
(as Godot's bone map does for a new skeleton; `_read_body` runs them in this order):

1. Extremities. The leaves of the tree without passengers (a leaf at its parent's place, a
   share bone; a leaf on the bone from its parent to a sibling, a twist bone), grouped where
   they are close along the bones (a hand's fingers, a face's bones, a foot's toes: within a
   fifth of the body's longest path), pruned shortest branch first until five remain: breasts,
   props and stray leaves hang off the body by less than the head does off the trunk.
2. Head, hands, feet: the head is the extremity on the shortest branch; the hands are the pair
   closer to it along the bones, the feet the other pair.
3. Hips: where the legs meet the path to the head; a joint there at its parent's place (Character
   Creator's CC_Base_Pelvis under CC_Base_Hip) hands it up to the joint that carries both.
4. Legs and arms, from where each leaves the trunk: passengers along it skipped (share bones;
   twist bones, on the line between their neighbours in every frame); the two consecutive bones
   with the greatest length are the thigh and the shin (upper arm and forearm), which places hip,
   knee and ankle (shoulder, elbow and wrist); the joint after the ankle is the toe, the joint
   before the shoulder the clavicle.
5. Spine: the chest is where the arms meet the path to the head; the joints between the hips and
   the chest are the spine, ranked from the hips up.
6. Neck and head: the first joint past the chest towards the head is the neck; the head is where
   the head's leaves part (face, eyes, jaw), or its last joint.
7. Sides: left and right, one decision for each pair of limbs. Names that state a side
   (rig/names.py side_and_word) and state the two limbs' sides differently are trusted; else the
   body's own axes decide: up from the pelvis to the chest, forward from the ankles to the toes,
   left = up x forward (right-handed axes, as BVH and every format here).

rig/labels.py then lets a name in a known convention override a part (a limb missing a joint
reads one joint off). Labels: "pelvis", "spine_2of3", "neck", "head", "left_thigh",
"right_elbow", ...; None for every joint that plays no part of the body.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapfix.rig.names import side_and_word, sides_and_words
from mocapfix.rig.tree import Tree, bone_lengths, branch_lengths, group_tips, median_direction, path_length, pruned

GROUP_FRACTION = 0.2  # leaves closer than this fraction of the longest path are one extremity
SHARE_FRACTION = 0.02  # a bone shorter than this fraction of the longest path: a share/helper bone
AT_PARENT_FRACTION = 0.005  # a leaf this close to its parent (x the longest path) sits at its place: a share bone
PASSENGER_DEG = 3.0  # a joint within this of the line between its neighbours in every frame: a twist bone
MAX_FRAMES = 240  # frames the structure is read from (evenly spaced)
# ... and at most this many joint positions in all: a rig of thousands of joints (markers, props, a
# hostile file) is read from fewer frames, so that reading it stays within memory (2,000 joints:
# 240 frames; 10,000 joints: 48 frames), never fewer than MIN_FRAMES
MAX_JOINT_FRAMES = 480_000
MIN_FRAMES = 16
HEAD_END_FRACTION = 0.17  # a head leaf this far (x the leg) past its parent is the head's end, not the head
# Two bodies under one root: the rig is cut at bones with at least BODY_LEAVES leaves on either
# side (the most even cuts first, at most BODY_CUTS of them); where two parts read as bodies whose
# legs are within BODY_SIZE_FACTOR of each other, the file holds two people or more (a hand with
# five fingers can read as a small body; its "legs" are a tenth of the body's)
BODY_LEAVES = 5
BODY_CUTS = 4
BODY_SIZE_FACTOR = 2.0
TWO_BODIES = "holds two or more bodies under one root; mocapfix fixes one person per file: split it"


@dataclass
class BodyStructure:
    labels: list[str | None]  # one per joint
    up: np.ndarray  # (3,) unit vector, pelvis to chest, in the positions' axes


def body_structure(parents, positions: np.ndarray, names=None, source=None) -> BodyStructure | None:
    """parents: (J,) with parents[j] < j; positions: (T, J, 3) in any unit and axes, NaN =
    missing; names: (J,) joint names, for sides only -> BodyStructure, or None where the tree is
    not a humanoid's (fewer than five extremities, a limb too short to hold its joints).

    A rig holding two bodies (two people under one root) is a MotionFileError naming source (the
    file): read as one, its legs would be labelled arms and its unit guessed wrong.
    Time and memory are linear in the joints (times the frames read, at most MAX_JOINT_FRAMES)."""
    from mocapfix.core.clip import MotionFileError

    parents = np.asarray(parents, dtype=np.int64)
    J = len(parents)
    if np.ndim(positions) != 3 or np.shape(positions)[1] != J or J < 5:
        return None
    T = len(positions)
    frames = max(MIN_FRAMES, min(MAX_FRAMES, MAX_JOINT_FRAMES // J))
    pos = np.asarray(positions)[np.unique(np.linspace(0, T - 1, min(T, frames)).round().astype(int))]
    pos = pos.astype(np.float64)  # (T', J, 3)
    tree = Tree(parents, bone_lengths(parents, pos))
    if _two_bodies(tree, pos, names):
        raise MotionFileError(source if source is not None else "the rig", TWO_BODIES)
    return _read_body(tree, pos, names)


def _two_bodies(tree: Tree, pos: np.ndarray, names) -> bool:
    """Whether the rig holds two bodies or more: two parts of it, each below a cut (or one below
    and the rest of the rig), read as bodies of a like size (BODY_LEAVES, BODY_CUTS,
    BODY_SIZE_FACTOR). Ordinary rigs have no such cut and cost nothing."""
    J = len(tree.parents)
    leaves_under = np.zeros(J, dtype=np.int64)
    leaves_under[tree.leaves] = 1
    for j in range(J - 1, 0, -1):
        if tree.parents[j] >= 0:
            leaves_under[tree.parents[j]] += leaves_under[j]
    total = len(tree.leaves)

    def evenness(j: int) -> int:
        return int(min(leaves_under[j], total - leaves_under[j]))

    # the top joint of each set of leaves: a chain of joints above the same leaves is one cut
    cuts = [j for j in range(J) if tree.parents[j] >= 0 and evenness(j) >= BODY_LEAVES]
    cuts = [j for j in cuts if leaves_under[tree.parents[j]] > leaves_under[j]]
    bodies: list[tuple[np.ndarray, float]] = []  # (J,) bool of the part, its leg length
    for j in sorted(cuts, key=evenness, reverse=True)[:BODY_CUTS]:
        below = tree.below(j)
        if any((below & part).any() for part, _ in bodies):
            continue  # inside (or around) a part already read as a body
        leg = _leg_length(tree, pos, names, below)
        if leg > 0:
            bodies.append((below, leg))
    if len(bodies) == 1:  # one body below a cut: is the rest of the rig another?
        rest = ~bodies[0][0]
        leg = _leg_length(tree, pos, names, rest)
        if leg > 0:
            bodies.append((rest, leg))
    legs = sorted(leg for _, leg in bodies)
    return any(b <= BODY_SIZE_FACTOR * a for a, b in zip(legs, legs[1:]))


def _leg_length(tree: Tree, pos: np.ndarray, names, part: np.ndarray) -> float:
    """part: (J,) bool, the joints of a connected part of the rig -> the length along the bones
    from the hip to the ankle of the body it reads as, 0.0 when it reads as none."""
    joints = np.flatnonzero(part)
    index = np.full(len(tree.parents), -1)
    index[joints] = np.arange(len(joints))
    above = tree.parents[joints]
    parents = np.where(above >= 0, index[np.maximum(above, 0)], -1)  # the part's top: its root
    bone = np.where(parents >= 0, tree.bone[joints], 0.0)
    sub = Tree(parents, bone)
    body = _read_body(sub, pos[:, joints], None if names is None else [names[j] for j in joints])
    if body is None:
        return 0.0
    legs = [
        sub.depth[body.labels.index(f"{side}_ankle")] - sub.depth[body.labels.index(f"{side}_thigh")]
        for side in ("left", "right")
    ]
    return float(np.median(legs))


def _read_body(tree: Tree, pos: np.ndarray, names) -> BodyStructure | None:
    """The body of a rig: tree with its bone lengths, pos: (T, J, 3) (body_structure), in the
    steps of this module's docstring."""
    tips = _extremities(tree, pos)  # 1.
    if tips is None:
        return None
    head, hands, feet = _head_hands_feet(tree, tips)  # 2.
    pelvis = _hips(tree, feet, head)  # 3.
    chest = tree.median(hands[0], hands[1], head)
    if pelvis == chest or chest not in tree.path(pelvis, head):
        return None
    limbs = {}  # 4. (kind, tip) -> {part: joint}
    for kind, top, (a, b) in (("leg", pelvis, feet), ("arm", chest, hands)):
        for tip in (a, b):
            raw = tree.path(top, tip)[1:]
            parts = _limb_parts(tree, _reduced(tree, raw, pos), kind)
            if parts is None:
                return None
            if kind == "arm" and "clavicle" not in parts and raw.index(parts["upper_arm"]) > 0:
                # a clavicle joint at the chest's place (CMU's LeftShoulder): where the clavicle starts
                parts["clavicle"] = raw[raw.index(parts["upper_arm"]) - 1]
            limbs[(kind, tip)] = parts
    labels: list[str | None] = [None] * len(tree.parents)
    labels[pelvis] = "pelvis"
    spine = [j for j in tree.path(pelvis, chest)[1:] if tree.bone[j] > SHARE_FRACTION * tree.diameter]  # 5.
    for rank, j in enumerate(spine):
        labels[j] = f"spine_{rank + 1}of{len(spine)}"
    leg = float(
        np.median([path_length(pos, p["thigh"], p["knee"], p["ankle"]) for (k, _), p in limbs.items() if k == "leg"])
    )
    raw_neck = tree.path(chest, head)[1:]  # 6.
    neck_chain = _reduced(tree, raw_neck, pos)
    if raw_neck and neck_chain:
        neck = raw_neck[0]  # at the chest's place or above it: where the neck starts
        labels[neck] = "neck"
        head_joint = _head_joint(tree, neck_chain, head, leg, names)
        if head_joint != neck:
            labels[head_joint] = "head"
    up = median_direction(pos[:, chest] - pos[:, pelvis])
    sides = _sides(pos, limbs, feet, hands, pelvis, chest, up, names)  # 7.
    for (_, tip), parts in limbs.items():
        for part, j in parts.items():
            labels[j] = labels[j] or f"{sides[tip]}_{part}"  # a joint of the trunk stays the trunk's
    return BodyStructure(labels, up)


def _extremities(tree: Tree, pos: np.ndarray) -> list[int] | None:
    """Step 1: five tips (one leaf per extremity) or None."""
    if len(tree.leaves) < 5 or tree.diameter <= 0:
        return None
    tips = group_tips(tree, GROUP_FRACTION * tree.diameter, _body_leaves(tree, pos))
    tips = pruned(tree, tips, 5)
    return tips if len(tips) == 5 else None


def _body_leaves(tree: Tree, pos: np.ndarray) -> list[int]:
    """The leaves of the rig without its passengers: leaves at their parent's place (share bones)
    and leaves on the bone from their parent to the sibling that reaches farthest (twist bones
    beside a limb's chain: Character Creator's UpperarmTwist02, Unreal's upperarm_twist_01_l).
    A joint whose children are all passengers is a leaf then (CC_Base_L_ToeBase over its
    ToeBaseShareBone). One sibling per leaf: linear in the joints. A rig whose body leaves are
    fewer than five keeps all its leaves."""
    J = len(tree.parents)
    reach = np.zeros(J)  # the longest way down from a joint to a leaf
    farthest = np.full(J, -1)  # the child on that way
    for j in range(J - 1, 0, -1):
        p = tree.parents[j]
        if p >= 0 and (farthest[p] < 0 or tree.bone[j] + reach[j] > reach[p]):
            reach[p], farthest[p] = tree.bone[j] + reach[j], j
    leaves = np.asarray(tree.leaves, dtype=np.int64)
    above = np.maximum(tree.parents[leaves], 0)
    sibling = farthest[above]  # (L,)
    passenger = np.zeros(J, dtype=bool)
    passenger[leaves] = (tree.parents[leaves] >= 0) & (tree.bone[leaves] <= AT_PARENT_FRACTION * tree.diameter)
    twist = leaves[(sibling != leaves) & (tree.bone[leaves] < tree.bone[sibling]) & ~passenger[leaves]]
    if twist.size:  # all of them at once: a rig may have thousands of leaves
        p, s = tree.parents[twist], farthest[tree.parents[twist]]
        u, v = pos[:, twist] - pos[:, p], pos[:, s] - pos[:, p]  # (T, n, 3)
        with np.errstate(invalid="ignore"):
            cos = (u * v).sum(-1) / (np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1))  # (T, n)
        seen = np.isfinite(cos)
        on_line = (np.where(seen, cos, 1.0) > np.cos(np.deg2rad(PASSENGER_DEG))).all(axis=0)
        passenger[twist] = on_line & seen.any(axis=0)
    carried = np.zeros(J, dtype=np.int64)  # children that are not passengers
    np.add.at(carried, tree.parents[~passenger & (tree.parents >= 0)], 1)
    leaves = [int(j) for j in np.flatnonzero(~passenger & (carried == 0))]
    return leaves if len(leaves) >= 5 else tree.leaves


def _hips(tree: Tree, feet: tuple[int, int], head: int) -> int:
    """Step 3: where the legs meet the path to the head, handed up past joints at their parent's
    place towards the joint where the legs' and the head's ways part (no higher)."""
    pelvis, top = tree.median(feet[0], feet[1], head), tree.lca(feet[0], head)
    while pelvis != top and tree.bone[pelvis] <= SHARE_FRACTION * tree.diameter:
        pelvis = int(tree.parents[pelvis])
    return pelvis


def _head_hands_feet(tree: Tree, tips: list[int]) -> tuple[int, tuple[int, int], tuple[int, int]]:
    """Step 2: the head: the tip on the shortest branch. Of the three ways to pair the other four,
    the one whose pairs are most alike in their distance to the head; the pair nearer the head:
    the hands."""
    d = tree.distances(tips, tips)
    h = int(np.argmin(branch_lengths(d)))
    rest = [i for i in range(5) if i != h]
    a, b, c, e = rest
    pairings = [((a, b), (c, e)), ((a, c), (b, e)), ((a, e), (b, c))]

    def mismatch(pairing):
        return sum(abs(d[h, x] - d[h, y]) for x, y in pairing)

    p, q = min(pairings, key=mismatch)
    arms, legs = (p, q) if d[h, list(p)].sum() < d[h, list(q)].sum() else (q, p)
    return tips[h], (tips[arms[0]], tips[arms[1]]), (tips[legs[0]], tips[legs[1]])


def _reduced(tree: Tree, chain: list[int], pos: np.ndarray) -> list[int]:
    """A limb's path without passengers: joints at their parent's place (share bones) and joints
    that stay on the line between their neighbours in every frame (twist bones)."""
    chain = [j for j in chain if tree.bone[j] > SHARE_FRACTION * tree.diameter]
    out = list(chain)
    k = 1
    while k < len(out) - 1:
        a, j, b = out[k - 1], out[k], out[k + 1]
        u, v = pos[:, a] - pos[:, j], pos[:, b] - pos[:, j]
        with np.errstate(invalid="ignore"):
            cos = (u * v).sum(-1) / (np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1))
        cos = cos[np.isfinite(cos)]
        straight = np.cos(np.deg2rad(180.0 - PASSENGER_DEG))
        if cos.size and (cos < straight).all():
            out.pop(k)
        else:
            k += 1
    return out


def _limb_parts(tree: Tree, chain: list[int], kind: str) -> dict[str, int] | None:
    """chain: a limb's joints from the trunk out -> {part: joint}: the two consecutive bones with
    the greatest length place the limb's three main joints."""
    if len(chain) < 3:
        return None
    sums = [tree.bone[chain[k]] + tree.bone[chain[k + 1]] for k in range(1, len(chain) - 1)]
    k = 1 + int(np.argmax(sums))  # chain[k] ends the first long bone: knee / elbow
    top, middle, end = chain[k - 1], chain[k], chain[k + 1]
    if kind == "leg":
        parts = {"thigh": top, "knee": middle, "ankle": end}
        if k + 2 < len(chain):
            parts["toe"] = chain[k + 2]
    else:
        parts = {"upper_arm": top, "elbow": middle, "wrist": end}
        if k - 2 >= 0:
            parts["clavicle"] = chain[k - 2]
    return parts


def _sides(pos, limbs, legs, arms, pelvis, chest, up, names) -> dict[int, str]:
    """Step 7: tip -> "left" / "right" for the four limbs, one decision per pair: the names where
    each limb's joints state one side and the two limbs' sides differ, else the body's axes
    (forward from the ankles to the toes), else (no toes, no names) the first is called left."""
    stated = [s for s, _ in sides_and_words(names)] if names is not None else None
    toes = [(p["ankle"], p["toe"]) for (k, _), p in limbs.items() if k == "leg" and "toe" in p]
    forward = median_direction(np.concatenate([pos[:, t] - pos[:, a] for a, t in toes])) if toes else None
    left = None
    if forward is not None and np.isfinite(forward).all() and np.isfinite(up).all():
        forward = forward - (forward @ up) * up
        if np.linalg.norm(forward) > 1e-6:
            left = np.cross(up, forward / np.linalg.norm(forward))
    sides: dict[int, str] = {}
    for pair, kind, top, centre in ((legs, "leg", "thigh", pelvis), (arms, "arm", "upper_arm", chest)):
        said = []
        for tip in pair:
            named = {stated[j] for j in limbs[(kind, tip)].values()} - {None} if stated is not None else set()
            said.append(named.pop() if len(named) == 1 else None)
        if said[0] is not None and said[1] is not None and said[0] != said[1]:
            sides.update(zip(pair, said))
            continue
        if left is None:
            sides.update({pair[0]: "left", pair[1]: "right"})
            continue
        lateral = [np.nanmedian((pos[:, limbs[(kind, tip)][top]] - pos[:, centre]) @ left) for tip in pair]
        first_left = lateral[0] > lateral[1]
        sides.update({pair[0]: "left" if first_left else "right", pair[1]: "right" if first_left else "left"})
    return sides


def _head_joint(tree: Tree, neck_chain: list[int], head_tip: int, leg: float, names) -> int:
    """The joint at the base of the skull on the head's branch: the joint below which the head's
    leaves part (face, eyes, jaw); a single leaf is the head unless it sits far past its parent
    (more than HEAD_END_FRACTION of a leg) or is named an end (HeadTop_End): then its parent is."""
    near = tree.distances_from(head_tip) < GROUP_FRACTION * tree.diameter  # (J,)
    inside = tree.below(neck_chain[0])
    leaves = [leaf for leaf in tree.leaves if near[leaf] and inside[leaf]]
    if len(leaves) >= 2:
        top = leaves[0]
        for leaf in leaves[1:]:
            top = tree.lca(top, leaf)
        while tree.bone[top] <= SHARE_FRACTION * tree.diameter and tree.parents[top] >= 0:
            top = int(tree.parents[top])  # the face's helper at the head's place: the head
        return top
    last = neck_chain[-1]
    if len(neck_chain) < 3:
        return last
    word = side_and_word(names[last])[1] if names is not None else ""
    is_end = any(w in word for w in ("end", "top", "nub", "tip", "site"))
    return neck_chain[-2] if is_end or tree.bone[last] > HEAD_END_FRACTION * leg else last
