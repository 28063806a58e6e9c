"""Which joint of a humanoid rig plays which part, from the rig's structure, not its names.

Every humanoid rig has the same shape, whatever its exporter calls the joints: five long
branches (two legs, two arms, the head) off a trunk. Read from the tree and the motion:

- Extremities. The leaves of the tree, grouped where they are close along the bones (a hand's
  fingers, a face's bones, a foot's toes: within a fifth of the body's longest path). Groups are
  pruned, shortest branch first, until five remain: twist, "share" and helper bones, breasts,
  props and stray leaves hang off a limb by less than the head does off the trunk.
- Head, arms, legs. The head is the extremity on the shortest branch; the arms are the pair
  closer to it along the bones, the legs the other pair.
- Pelvis and chest: where the legs meet the path to the head, and where the arms meet it. The
  joints between them are the spine (ranked from the pelvis up); the first joint past the chest
  towards the head is the neck.
- Along a limb, from where it leaves the trunk: joints at the place of their parent (share
  bones) and joints that stay on the line between their neighbours in every frame (twist bones)
  are passengers and skipped; the two consecutive bones with the greatest length are the thigh
  and the shin (upper arm and forearm), which places hip, knee and ankle (shoulder, elbow and
  wrist); the joint after the ankle is the toe, the joint before the shoulder the clavicle.
- Left and right from the body's own axes: up from the pelvis to the chest, forward from the
  ankles to the toes, left = up x forward (right-handed axes, as BVH and every format here).
  Where a limb's name says its side, the name wins (a mirrored export); io/joint_names.py lets
  a known name override a part too (a limb missing a joint reads one joint off).

Labels are the vocabulary of io/joint_names.py ("pelvis", "spine_2of3", "neck", "head",
"left_thigh", "right_elbow", ...), None for every joint that plays no part of the body.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

GROUP_FRACTION = 0.2  # leaves closer than this fraction of the longest path are one extremity
SHARE_FRACTION = 0.02  # a bone shorter than this fraction of the longest path: a share/helper bone
PASSENGER_DEG = 3.0  # a joint within this of the line between its neighbours in every frame: a twist bone
MAX_FRAMES = 240  # frames the structure is read from (evenly spaced)
HEAD_END_FRACTION = 0.17  # a head leaf this far (x the leg) past its parent is the head's end, not the head


@dataclass
class BodyStructure:
    labels: list[str | None]  # one per joint
    up: np.ndarray  # (3,) unit vector, pelvis to chest, in the positions' axes


def body_structure(parents, positions: np.ndarray, names=None) -> BodyStructure | None:
    """parents: (J,) with parents[j] < j; positions: (T, J, 3) in any unit and axes, NaN =
    missing; names: (J,) joint names, for sides only -> BodyStructure, or None where the tree is
    not a humanoid's (fewer than five extremities, a limb too short to hold its joints)."""
    parents = np.asarray(parents, dtype=np.int64)
    J = len(parents)
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim != 3 or pos.shape[1] != J or J < 5:
        return None
    pos = pos[np.unique(np.linspace(0, len(pos) - 1, min(len(pos), MAX_FRAMES)).round().astype(int))]
    with warnings.catch_warnings(), np.errstate(invalid="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        bone = np.zeros(J)
        child = np.flatnonzero(parents >= 0)
        d = np.linalg.norm(pos[:, child] - pos[:, parents[child]], axis=-1)  # (T, J-1)
        bone[child] = np.nan_to_num(np.nanmedian(d, axis=0))
        # a "bone" whose length changes is a trajectory (a root carrying the body), not a bone
        spread = np.nanpercentile(d, 90, axis=0) - np.nanpercentile(d, 10, axis=0)
        bone[child[np.nan_to_num(spread) > 0.25 * bone[child] + 1e-12]] = 0.0
    tree = _Tree(parents, bone)
    tips = _extremities(tree)
    if tips is None:
        return None
    head, arms, legs = _head_arms_legs(tree, tips)
    pelvis = tree.median(legs[0], legs[1], head)
    chest = tree.median(arms[0], arms[1], head)
    if pelvis == chest or chest not in tree.path(pelvis, head):
        return None
    labels: list[str | None] = [None] * J

    limbs = {}
    for kind, (a, b) in (("leg", legs), ("arm", arms)):
        for tip in (a, b):
            raw = tree.path(pelvis if kind == "leg" else chest, tip)[1:]
            parts = _limb_parts(tree, _reduced(tree, raw, pos), kind)
            if parts is None:
                return None
            if kind == "arm" and "clavicle" not in parts and raw.index(parts["upper_arm"]) > 0:
                # a clavicle joint at the chest's place (CMU's LeftShoulder): where the clavicle starts
                parts["clavicle"] = raw[raw.index(parts["upper_arm"]) - 1]
            limbs[(kind, tip)] = parts
    up = _median_direction(pos[:, chest] - pos[:, pelvis])
    sides = _sides(pos, limbs, legs, arms, pelvis, chest, up, names)

    for (_, tip), parts in limbs.items():
        for part, j in parts.items():
            labels[j] = f"{sides[tip]}_{part}"
    labels[pelvis] = "pelvis"
    spine = [j for j in tree.path(pelvis, chest)[1:] if tree.bone[j] > SHARE_FRACTION * tree.diameter]
    for rank, j in enumerate(spine):
        labels[j] = f"spine_{rank + 1}of{len(spine)}"
    leg_lengths = [path_length(pos, p["thigh"], p["knee"], p["ankle"]) for (k, _), p in limbs.items() if k == "leg"]
    raw_neck = tree.path(chest, head)[1:]
    neck_chain = _reduced(tree, raw_neck, pos)
    if raw_neck and neck_chain:
        neck = raw_neck[0]  # at the chest's place or above it: where the neck starts
        labels[neck] = "neck"
        head_joint = _head_joint(tree, neck_chain, head, float(np.median(leg_lengths)), names)
        if head_joint != neck:
            labels[head_joint] = "head"
    return BodyStructure(labels, up)


class _Tree:
    """The joint tree with bone lengths: depths, paths, distances along the bones."""

    def __init__(self, parents: np.ndarray, bone: np.ndarray):
        self.parents, self.bone = parents, bone
        J = len(parents)
        self.depth = np.zeros(J)
        self.ancestors = np.zeros((J, J), dtype=bool)  # ancestors[j, a]: a is j or above it
        self.children: list[list[int]] = [[] for _ in range(J)]
        for j in range(J):
            p = parents[j]
            if p >= 0:
                self.depth[j] = self.depth[p] + bone[j]
                self.ancestors[j] = self.ancestors[p]
                self.children[p].append(j)
            self.ancestors[j, j] = True
        self.leaves = [j for j in range(J) if not self.children[j]]
        self.diameter = float(self.distances(self.leaves, self.leaves).max()) if self.leaves else 0.0

    def distances(self, a: list[int], b: list[int]) -> np.ndarray:
        """(len(a), len(b)) lengths of the paths along the bones."""
        common = self.ancestors[a][:, None, :] & self.ancestors[b][None, :, :]  # (A, B, J)
        lca_depth = np.where(common, self.depth, -np.inf).max(-1)
        return self.depth[a][:, None] + self.depth[b][None, :] - 2 * lca_depth

    def lca(self, a: int, b: int) -> int:
        common = np.flatnonzero(self.ancestors[a] & self.ancestors[b])
        return int(common.max())  # the deepest common ancestor comes last (parents before children)

    def path(self, a: int, b: int) -> list[int]:
        """Joints from a to b along the tree, both included."""
        top = self.lca(a, b)
        up, down = [a], [b]
        while up[-1] != top:
            up.append(int(self.parents[up[-1]]))
        while down[-1] != top:
            down.append(int(self.parents[down[-1]]))
        return up + down[-2::-1]

    def median(self, a: int, b: int, c: int) -> int:
        """The one joint on all three paths between a, b and c."""
        on = set(self.path(a, b)) & set(self.path(b, c)) & set(self.path(a, c))
        return min(on, key=lambda j: self.depth[j])


def _extremities(tree: _Tree) -> list[int] | None:
    """Five tips (one leaf per extremity) or None."""
    leaves = tree.leaves
    if len(leaves) < 5 or tree.diameter <= 0:
        return None
    dist = tree.distances(leaves, leaves)
    group = list(range(len(leaves)))  # single linkage: union-find over close leaves

    def find(i):
        while group[i] != i:
            group[i] = group[group[i]]
            i = group[i]
        return i

    for i, k in zip(*np.nonzero(dist < GROUP_FRACTION * tree.diameter)):
        group[find(i)] = find(k)
    tips: dict[int, int] = {}
    for i, leaf in enumerate(leaves):  # a group's tip: its leaf farthest from the root along the bones
        g = find(i)
        if g not in tips or tree.depth[leaf] > tree.depth[tips[g]]:
            tips[g] = leaf
    tips_list = list(tips.values())
    while len(tips_list) > 5:
        branch = _branch_lengths(tree.distances(tips_list, tips_list))
        tips_list.pop(int(np.argmin(branch)))
    return tips_list if len(tips_list) == 5 else None


def _branch_lengths(d: np.ndarray) -> np.ndarray:
    """d: (N, N) distances between tips -> (N,) each tip's distance to the nearest path between two
    others: how far its own branch reaches out of the rest of the tree."""
    n = len(d)
    out = np.full(n, np.inf)
    for t in range(n):
        others = [u for u in range(n) if u != t]
        sub = d[np.ix_(others, others)]
        reach = (d[t, others][:, None] + d[t, others][None, :] - sub) / 2
        reach[np.eye(len(others), dtype=bool)] = np.inf
        out[t] = reach.min()
    return out


def _head_arms_legs(tree: _Tree, tips: list[int]) -> tuple[int, tuple[int, int], tuple[int, int]]:
    """The head: the tip on the shortest branch. Of the three ways to pair the other four, the one
    whose pairs are most alike in their distance to the head; the pair nearer the head: arms."""
    d = tree.distances(tips, tips)
    h = int(np.argmin(_branch_lengths(d)))
    rest = [i for i in range(5) if i != h]
    a, b, c, e = rest
    pairings = [((a, b), (c, e)), ((a, c), (b, e)), ((a, e), (b, c))]

    def mismatch(pairing):
        return sum(abs(d[h, x] - d[h, y]) for x, y in pairing)

    p, q = min(pairings, key=mismatch)
    arms, legs = (p, q) if d[h, list(p)].sum() < d[h, list(q)].sum() else (q, p)
    return tips[h], (tips[arms[0]], tips[arms[1]]), (tips[legs[0]], tips[legs[1]])


def _reduced(tree: _Tree, chain: list[int], pos: np.ndarray) -> list[int]:
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


def _limb_parts(tree: _Tree, chain: list[int], kind: str) -> dict[str, int] | None:
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


def path_length(pos: np.ndarray, *joints: int) -> float:
    """pos: (T, J, 3) -> the median over frames of the length of the polyline through joints
    (NaN frames left out; NaN when there are none)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        with np.errstate(invalid="ignore", over="ignore"):
            seg = np.linalg.norm(np.diff(pos[:, list(joints)], axis=1), axis=-1).sum(-1)  # (T,)
        return float(np.nanmedian(np.where(np.isfinite(seg), seg, np.nan)))


def _median_direction(v: np.ndarray) -> np.ndarray:
    """v: (T, 3) -> the unit vector of their per-axis median (NaN frames left out)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        m = np.nanmedian(v, axis=0)
    n = np.linalg.norm(m)
    return m / n if np.isfinite(n) and n > 0 else np.full(3, np.nan)


def _sides(pos, limbs, legs, arms, pelvis, chest, up, names) -> dict[int, str]:
    """tip -> "left" / "right" for the four limbs: by the names where they say it, else by the
    body's axes (forward from the ankles to the toes)."""
    from mocapfix.io.joint_names import side_and_word

    toes = [(p["ankle"], p["toe"]) for (k, _), p in limbs.items() if k == "leg" and "toe" in p]
    forward = _median_direction(np.concatenate([pos[:, t] - pos[:, a] for a, t in toes])) if toes else None
    left = None
    if forward is not None and np.isfinite(forward).all() and np.isfinite(up).all():
        forward = forward - (forward @ up) * up
        if np.linalg.norm(forward) > 1e-6:
            left = np.cross(up, forward / np.linalg.norm(forward))
    sides: dict[int, str] = {}
    for pair, kind, top, centre in ((legs, "leg", "thigh", pelvis), (arms, "arm", "upper_arm", chest)):
        said = []
        for tip in pair:
            named = [side_and_word(names[j])[0] for j in limbs[(kind, tip)].values()] if names is not None else []
            said.append(next((s for s in named if s is not None), None))
        if said[0] is not None and said[1] is not None and said[0] != said[1]:
            sides.update(zip(pair, said))
            continue
        if left is None:  # nothing to tell them apart by (no toes, no names): the first is called left
            sides.update({pair[0]: "left", pair[1]: "right"})
            continue
        lateral = [np.nanmedian((pos[:, limbs[(kind, tip)][top]] - pos[:, centre]) @ left) for tip in pair]
        first_left = lateral[0] > lateral[1]
        sides.update({pair[0]: "left" if first_left else "right", pair[1]: "right" if first_left else "left"})
    return sides


def _head_joint(tree: _Tree, neck_chain: list[int], head_tip: int, leg: float, names) -> int:
    """The joint at the base of the skull on the head's branch: the joint below which the head's
    leaves part (face, eyes, jaw); a single leaf is the head unless it sits far past its parent
    (more than HEAD_END_FRACTION of a leg) or is named an end (HeadTop_End): then its parent is."""
    from mocapfix.io.joint_names import side_and_word

    near = tree.distances(tree.leaves, [head_tip])[:, 0] < GROUP_FRACTION * tree.diameter
    leaves = [leaf for leaf, n in zip(tree.leaves, near) if n and tree.ancestors[leaf, neck_chain[0]]]
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


def limb_groups(skeleton) -> dict[str, tuple[int, ...]]:
    """left/right arm/leg groups (core/skeleton.py GROUP_NAMES): each limb's top joint (the upper
    arm, the thigh) and everything below it, from the skeleton's labels; by name (guess_groups)
    for the limbs the labels do not place."""
    from mocapfix.core.skeleton import GROUP_NAMES, guess_groups

    groups = dict(guess_groups(skeleton.joint_names, skeleton.parents))
    labels = list(skeleton.labels)
    for side in ("left", "right"):
        for group, top in (("arm", "upper_arm"), ("leg", "thigh")):
            if f"{side}_{top}" in labels:
                groups[f"{side}_{group}"] = tuple(skeleton.descendants(labels.index(f"{side}_{top}")))
    return {g: groups[g] for g in GROUP_NAMES if g in groups}
