"""A rig's joint tree with its bone lengths, the two searches over its leaves that find a body's
extremities (rig/structure.py: leaves grouped where they are close along the bones, groups
pruned shortest branch first), and what is measured of a rig over its frames.

Everything here costs time and memory linear in the joints, or n log n (a rig may have thousands
of leaves: markers, props, a hostile file), or linear in the length of the paths it walks.
"""

from __future__ import annotations

import heapq
import warnings

import numpy as np


class Tree:
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


def group_tips(tree: Tree, radius: float, leaves: list[int] | None = None) -> list[int]:
    """Single linkage of the leaves (tree.leaves, or those given, in joint order) closer than
    radius along the bones -> one tip per group (its leaf farthest from the root), groups in the
    order of their first leaf.

    Without comparing leaves pairwise: two leaves are closer than radius exactly when the balls of
    radius / 2 around them meet, so the groups are the connected parts of the tree that lie
    within radius / 2 of some leaf. A bone lies wholly within them when the nearest leaves of its
    two ends and the bone itself add up to less than radius."""
    J = len(tree.parents)
    leaves = tree.leaves if leaves is None else leaves
    near = np.full(J, np.inf)  # distance to the nearest leaf: first below each joint, then anywhere
    near[leaves] = 0.0
    for j in range(J - 1, -1, -1):
        if tree.children[j]:
            near[j] = min(near[j], min(tree.bone[c] + near[c] for c in tree.children[j]))
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
    for leaf in leaves:  # in joint order: a group's first leaf comes first
        g = int(group[leaf])
        if g not in tips or tree.depth[leaf] > tree.depth[tips[g]]:
            tips[g] = leaf
    return list(tips.values())


def pruned(tree: Tree, tips: list[int], keep: int) -> list[int]:
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


def branch_lengths(d: np.ndarray) -> np.ndarray:
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


# --- measured over the frames ---


def bone_lengths(parents: np.ndarray, pos: np.ndarray) -> np.ndarray:
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


def path_length(pos: np.ndarray, *joints: int) -> float:
    """pos: (T, J, 3) -> the median over frames of the length of the polyline through joints
    (NaN frames left out; NaN when there are none)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        with np.errstate(invalid="ignore", over="ignore"):
            seg = np.linalg.norm(np.diff(pos[:, list(joints)], axis=1), axis=-1).sum(-1)  # (T,)
        return float(np.nanmedian(np.where(np.isfinite(seg), seg, np.nan)))


def median_direction(v: np.ndarray) -> np.ndarray:
    """v: (T, 3) -> the unit vector of their per-axis median (NaN frames left out)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        m = np.nanmedian(v, axis=0)
    n = np.linalg.norm(m)
    return m / n if np.isfinite(n) and n > 0 else np.full(3, np.nan)
