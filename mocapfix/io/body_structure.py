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

import heapq
import warnings
from dataclasses import dataclass

import numpy as np

GROUP_FRACTION = 0.2  # leaves closer than this fraction of the longest path are one extremity
SHARE_FRACTION = 0.02  # a bone shorter than this fraction of the longest path: a share/helper bone
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
    tree = _Tree(parents, _bone_lengths(parents, pos))
    if _two_bodies(tree, pos, names):
        raise MotionFileError(source if source is not None else "the rig", TWO_BODIES)
    return _read_body(tree, pos, names)


def _bone_lengths(parents: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """pos: (T, J, 3) -> (J,) each joint's distance to its parent, median over the frames (0 for
    the root, for joints never seen, and for a "bone" whose length changes: a trajectory, a root
    carrying the body, not a bone)."""
    bone = np.zeros(len(parents))
    child = np.flatnonzero(parents >= 0)
    with warnings.catch_warnings(), np.errstate(invalid="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        d = np.linalg.norm(pos[:, child] - pos[:, parents[child]], axis=-1)  # (T, J-1)
        bone[child] = np.nan_to_num(np.nanmedian(d, axis=0))
        low, high = column_percentiles(d, (10, 90))
        spread = high - low
        bone[child[np.nan_to_num(spread) > 0.25 * bone[child] + 1e-12]] = 0.0
    return bone


def column_percentiles(x: np.ndarray, percents) -> list[np.ndarray]:
    """x: (T, N), NaN = missing -> per percent, (N,) the column's percentile over its other values
    (as np.nanpercentile, linear; NaN for a column without one). np.nanpercentile goes column by
    column in Python: seconds for a rig of 10,000 joints."""
    if len(x) == 0:
        return [np.full(x.shape[1], np.nan) for _ in percents]
    ordered = np.sort(x, axis=0)  # NaN last
    last = np.maximum((~np.isnan(ordered)).sum(axis=0) - 1, 0)  # (N,) the last value's row
    columns = np.arange(x.shape[1])
    out = []
    with np.errstate(invalid="ignore"):
        for q in percents:
            at = q / 100.0 * last
            lo = np.floor(at).astype(np.int64)
            a, b, t = ordered[lo, columns], ordered[np.minimum(lo + 1, last), columns], at - lo
            step = b - a  # numpy's interpolation, from whichever end is nearer (the same at inf)
            out.append(np.where(t >= 0.5, b - step * (1 - t), a + step * t))
    return out


def _two_bodies(tree: _Tree, pos: np.ndarray, names) -> bool:
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


def _leg_length(tree: _Tree, pos: np.ndarray, names, part: np.ndarray) -> float:
    """part: (J,) bool, the joints of a connected part of the rig -> the length along the bones
    from the hip to the ankle of the body it reads as, 0.0 when it reads as none."""
    joints = np.flatnonzero(part)
    index = np.full(len(tree.parents), -1)
    index[joints] = np.arange(len(joints))
    above = tree.parents[joints]
    parents = np.where(above >= 0, index[np.maximum(above, 0)], -1)  # the part's top: its root
    bone = np.where(parents >= 0, tree.bone[joints], 0.0)
    sub = _Tree(parents, bone)
    body = _read_body(sub, pos[:, joints], None if names is None else [names[j] for j in joints])
    if body is None:
        return 0.0
    legs = [
        sub.depth[body.labels.index(f"{side}_ankle")] - sub.depth[body.labels.index(f"{side}_thigh")]
        for side in ("left", "right")
    ]
    return float(np.median(legs))


def _read_body(tree: _Tree, pos: np.ndarray, names) -> BodyStructure | None:
    """The body of a rig: tree with its bone lengths, pos: (T, J, 3) (body_structure)."""
    J = len(tree.parents)
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
    """The joint tree with bone lengths: depths, paths, distances along the bones. Everything here
    costs time and memory linear in the joints (a rig may have thousands of leaves: markers,
    props, a hostile file), or linear in the length of the paths it walks."""

    def __init__(self, parents: np.ndarray, bone: np.ndarray):
        self.parents, self.bone = parents, bone
        J = len(parents)
        self.depth = np.zeros(J)  # along the bones from the root
        self.level = np.zeros(J, dtype=np.int64)  # joints above
        self.children: list[list[int]] = [[] for _ in range(J)]
        for j in range(J):
            p = parents[j]
            if p >= 0:
                self.depth[j] = self.depth[p] + bone[j]
                self.level[j] = self.level[p] + 1
                self.children[p].append(j)
        self.leaves = [j for j in range(J) if not self.children[j]]
        self.diameter = self._longest_leaf_path()

    def _longest_leaf_path(self) -> float:
        """The longest path between two leaves: its top joint joins the two deepest branches
        below it (heights from the leaves up, children after their parents)."""
        height = np.zeros(len(self.parents))  # the longest way down from a joint to a leaf
        longest = 0.0
        for j in range(len(self.parents) - 1, -1, -1):
            down = sorted((self.bone[c] + height[c] for c in self.children[j]), reverse=True)[:2]
            height[j] = down[0] if down else 0.0
            if len(down) == 2:
                longest = max(longest, down[0] + down[1])
        return float(longest)

    def lca(self, a: int, b: int) -> int:
        while self.level[a] > self.level[b]:
            a = int(self.parents[a])
        while self.level[b] > self.level[a]:
            b = int(self.parents[b])
        while a != b:
            a, b = int(self.parents[a]), int(self.parents[b])
        return a

    def distances(self, a: list[int], b: list[int]) -> np.ndarray:
        """(len(a), len(b)) lengths of the paths along the bones; for a few joints (a walk per pair)."""
        return np.array([[self.depth[x] + self.depth[y] - 2 * self.depth[self.lca(x, y)] for y in b] for x in a])

    def below(self, top: int) -> np.ndarray:
        """(J,) bool: top and every joint under it."""
        inside = np.zeros(len(self.parents), dtype=bool)
        inside[top] = True
        for j in range(top + 1, len(self.parents)):  # parents come before their children
            inside[j] = self.parents[j] >= 0 and inside[self.parents[j]]
        return inside

    def distances_from(self, a: int) -> np.ndarray:
        """(J,) the length of the path along the bones from a to every joint."""
        on_path = np.zeros(len(self.parents), dtype=bool)  # a and the joints above it
        j = a
        while j >= 0:
            on_path[j] = True
            j = int(self.parents[j])
        meet = np.arange(len(self.parents))  # where each joint's way up meets a's
        for j in range(len(self.parents)):
            if not on_path[j] and self.parents[j] >= 0:
                meet[j] = meet[self.parents[j]]
        return self.depth + self.depth[a] - 2 * self.depth[meet]

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
    if len(tree.leaves) < 5 or tree.diameter <= 0:
        return None
    tips = _group_tips(tree, GROUP_FRACTION * tree.diameter)
    tips = _pruned(tree, tips, 5)
    return tips if len(tips) == 5 else None


def _group_tips(tree: _Tree, radius: float) -> list[int]:
    """Single linkage of the leaves closer than radius along the bones -> one tip per group (its
    leaf farthest from the root), groups in the order of their first leaf.

    Without comparing leaves pairwise: two leaves are closer than radius exactly when the balls of
    radius / 2 around them meet, so the groups are the connected parts of the tree that lie
    within radius / 2 of some leaf. A bone lies wholly within them when the nearest leaves of its
    two ends and the bone itself add up to less than radius."""
    J = len(tree.parents)
    near = np.zeros(J)  # distance to the nearest leaf: first below each joint, then anywhere
    for j in range(J - 1, -1, -1):
        if tree.children[j]:
            near[j] = min(tree.bone[c] + near[c] for c in tree.children[j])
    for j in range(J):
        p = tree.parents[j]
        if p >= 0:
            near[j] = min(near[j], tree.bone[j] + near[p])
    group = np.arange(J)
    for j in range(J):
        p = tree.parents[j]
        if p >= 0 and near[p] + tree.bone[j] + near[j] < radius:
            group[j] = group[p]
    tips: dict[int, int] = {}
    for leaf in tree.leaves:  # in joint order: a group's first leaf comes first
        g = int(group[leaf])
        if g not in tips or tree.depth[leaf] > tree.depth[tips[g]]:
            tips[g] = leaf
    return list(tips.values())


def _pruned(tree: _Tree, tips: list[int], keep: int) -> list[int]:
    """tips pruned, shortest branch first, until `keep` remain. A tip's branch is the path from it
    to where the tree spanned by the other tips begins; removing a tip lengthens the branches
    that met it there. Kept in the order given; ties go to the tip given first.

    On the tree spanned by the tips with its joints of two bones merged away (tips and forks
    left), a tip's branch is its one bone: a heap of branches and a merge per removal make this
    n log n in the tips."""
    n = len(tips)
    if n <= keep:
        return list(tips)
    J = len(tree.parents)
    count = np.zeros(J, dtype=np.int64)  # tips under each joint
    count[tips] = 1
    for j in range(J - 1, 0, -1):
        if tree.parents[j] >= 0:
            count[tree.parents[j]] += count[j]
    # The spanned tree: joints with a tip under them and one outside, and the lowest joint with all
    # of them under it (its top). Kept of it: tips, forks and its top.
    spanned = (count > 0) & (count < n)
    forks = np.zeros(J, dtype=np.int64)
    for j in np.flatnonzero(spanned):
        forks[tree.parents[j]] += 1
    top = int(np.flatnonzero((count == n) & (forks >= 2))[-1])
    kept = (spanned & (forks >= 2)) | np.isin(np.arange(J), tips)
    kept[top] = True
    links: dict[int, dict[int, float]] = {int(j): {} for j in np.flatnonzero(kept)}
    nearest_kept = np.full(J, -1)  # the joint itself if kept, else the nearest kept joint above it
    for j in range(J):
        p = tree.parents[j]
        if j != top and spanned[j]:
            above = int(nearest_kept[p])
            if kept[j]:
                links[j][above] = links[above][j] = tree.depth[j] - tree.depth[above]
        nearest_kept[j] = j if kept[j] else nearest_kept[p] if p >= 0 else -1
    is_tip = {int(t): k for k, t in enumerate(tips)}  # tip -> its place in the order given

    def merge_away(j: int) -> None:
        """j has two bones left and is no tip: one bone from its two neighbours instead."""
        (a, la), (b, lb) = links.pop(j).items()
        del links[a][j], links[b][j]
        links[a][b] = links[b][a] = la + lb
        for t in (a, b):
            if t in is_tip:
                heapq.heappush(heap, (la + lb, is_tip[t], t))

    heap = [(next(iter(links[t].values())), k, t) for k, t in enumerate(tips)]
    heapq.heapify(heap)
    if len(links[top]) == 2:
        merge_away(top)
    alive = n
    while alive > keep:
        length, _, t = heapq.heappop(heap)
        if t not in links or next(iter(links[t].values())) != length:
            continue  # removed, or its branch has grown since this entry
        (fork,) = links.pop(t)
        del links[fork][t]
        alive -= 1
        if len(links[fork]) == 2 and fork not in is_tip:
            merge_away(fork)
    return [t for t in tips if t in links]


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
