"""Clip: one person's motion, the single representation every reader returns.

Lives beside skeleton.py (not in data/) because io/ readers build clips and data/ consumes
them: both import it and neither imports the other.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from mocapfix.core.skeleton import Skeleton


class MotionFileError(ValueError):
    """A file that cannot be read as motion. str() is one line naming the file and the problem."""

    def __init__(self, path, problem: str):
        self.path, self.problem = str(path), problem
        super().__init__(f"{shown(path)}: {problem}")


def shown(path) -> str:
    """A path as messages print it: as it is, or escaped (quoted, \\n for a newline) when it holds
    characters that would break a one-line message or fake another line."""
    text = str(path)
    return text if text.isprintable() else ascii(text)


# float32 keeps a coordinate to half a unit in its last place: 4 um within 100 m of the origin,
# 4 mm at 100 km (georeferenced capture), more than fix promises to leave an observed token
# (0.01 mm). A take with coordinates beyond NEAR_ORIGIN_M is kept relative to an origin near it.
NEAR_ORIGIN_M = 100.0


def origin_near(points: np.ndarray) -> np.ndarray:
    """points: (..., 3) float64 metres, z up, NaN = missing -> (3,) float64: the origin a Clip of
    them keeps its float32 positions relative to. Zero along an axis whose every seen value lies
    within NEAR_ORIGIN_M of 0 (an ordinary take: its numbers are not touched); otherwise a whole
    number of metres near the points (whole, so that subtracting it is exact in float64 and the
    same file read twice gets the same origin): the median along x and y (the model removes
    each window's mean there anyway), the lowest whole metre under the body along z (the 1st
    percentile, so that one low glitch does not sink it; the model sees heights)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    origin = np.zeros(3)
    with np.errstate(invalid="ignore"):
        seen = pts[np.isfinite(pts).all(-1)]
    if not seen.size or np.abs(seen).max() <= NEAR_ORIGIN_M:
        return origin
    far = np.abs(seen).max(axis=0) > NEAR_ORIGIN_M  # (3,)
    origin[:2] = np.where(far[:2], np.round(np.median(seen[:, :2], axis=0)), 0.0)
    origin[2] = np.floor(np.percentile(seen[:, 2], 1)) if far[2] else 0.0
    return origin


# Frame rates motion capture has: from a slow pose tracker to a high-speed camera. A rate outside
# is a broken file (a Frame Time of 1e6 s would make resampling allocate gigabytes).
MIN_FPS, MAX_FPS = 1.0, 10_000.0


def check_frame_rate(path, fps: float, what: str = "the frame rate is") -> float:
    """fps, or a MotionFileError naming the file and the value when it is not a number in
    [MIN_FPS, MAX_FPS]."""
    try:
        value = float(fps)
    except (TypeError, ValueError):
        raise MotionFileError(path, f"{what} not a number: {fps!r}") from None
    if not MIN_FPS <= value <= MAX_FPS:  # also NaN
        raise MotionFileError(
            path, f"{what} {value:g} fps, outside {MIN_FPS:g}-{MAX_FPS:g} fps (not a motion-capture frame rate)"
        )
    return value


# Work on (T, J, 3, 3) matrices goes a block of frames at a time, about this many joint-frames a
# block: a rig of 10,000 joints over 146 frames holds 105 MB in each such array, and scipy's
# conversions make several copies. Every step done in blocks is done frame by frame, so the
# blocks change no value.
BLOCK_JOINT_FRAMES = 1 << 15


def frame_blocks(frames: int, joints: int, levels: int = 0, size: int = BLOCK_JOINT_FRAMES) -> list[slice]:
    """Slices that cover range(frames) in order, each of about `size` joint-frames (1 frame at least).

    levels: the depth of the tree, for forward kinematics (a few numpy steps per level and block):
    then no more blocks than joints // levels, so that a deep rig (a chain of thousands) takes
    bigger blocks rather than more steps than one a joint."""
    step = max(1, size // max(joints, 1))
    if levels:
        step = max(step, -(-frames // max(1, joints // levels)))
    return [slice(t, min(t + step, frames)) for t in range(0, frames, step)]


def rotation_matrices(rotvecs: np.ndarray) -> np.ndarray:
    """rotvecs: (..., 3) axis-angle -> (..., 3, 3) float64 matrices, converted in blocks (scipy's
    temporaries stay small)."""
    from scipy.spatial.transform import Rotation

    flat = rotvecs.reshape(-1, 3)
    out = np.empty((len(flat), 3, 3))
    for rows in frame_blocks(len(flat), 1):
        out[rows] = Rotation.from_rotvec(flat[rows].astype(np.float64)).as_matrix()
    return out.reshape(*rotvecs.shape[:-1], 3, 3)


def rotation_vectors(matrices: np.ndarray, dtype=np.float64) -> np.ndarray:
    """matrices: (..., 3, 3) rotations -> (..., 3) axis-angle, converted in blocks."""
    from scipy.spatial.transform import Rotation

    flat = matrices.reshape(-1, 3, 3)
    out = np.empty((len(flat), 3), dtype=dtype)
    for rows in frame_blocks(len(flat), 1):
        out[rows] = Rotation.from_matrix(flat[rows]).as_rotvec()
    return out.reshape(*matrices.shape[:-2], 3)


def depth_levels(parents) -> list[np.ndarray]:
    """parents: J ints (parents[j] < j) -> the joints below the root by depth: [the root's
    children, theirs, ...], each an int array in skeleton order. Forward kinematics takes a level
    at a time (its parents are all in the levels before): a few numpy steps for a rig of
    thousands of leaves, where one a joint costs a Python loop of thousands."""
    p = np.asarray(parents, dtype=np.int64)
    depth = np.zeros(len(p), dtype=np.int64)
    for j in range(1, len(p)):
        depth[j] = depth[p[j]] + 1
    order = np.argsort(depth, kind="stable")
    return np.split(order, np.cumsum(np.bincount(depth)))[1:-1]


@dataclass
class Clip:
    positions: np.ndarray  # (T, J, 3) float32, metres, z up, NaN where a joint is missing
    fps: float
    skeleton: Skeleton
    name: str = ""  # unique within a dataset: file stem (+ "#person" / "/key")
    source: str = ""  # the file it came from; splits group clips by this
    # Where the positions came from (rotation-based data: BVH, AMASS, synthetic). Same frame
    # convention as positions: metres, z up. Forward kinematics of these reproduces positions.
    rotations: np.ndarray | None = None  # (T, J, 3) float32 local axis-angle, radians
    root_translation: np.ndarray | None = None  # (T, 3) float32, world position of joint 0
    offsets: np.ndarray | None = None  # (J, 3) float32 bone offsets in the parent's frame
    meta: dict = field(default_factory=dict)  # format, unit, up_axis, ... (plain values)
    # (3,) float64 metres, z up: where positions and root_translation are measured from. Zero but
    # for a take far from its file's origin (origin_near; readers: Clip.centred); writers add it
    # back in float64 (absolute_positions).
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        self.positions = np.asarray(self.positions, dtype=np.float32)
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(3)
        if not np.isfinite(self.origin).all():
            raise MotionFileError(self.source or self.name, f"the origin must be finite, got {self.origin}")
        if self.positions.ndim != 3 or self.positions.shape[2] != 3:
            raise MotionFileError(
                self.source or self.name, f"positions must be (frames, joints, 3), got {self.positions.shape}"
            )
        if self.positions.shape[1] != self.skeleton.num_joints:
            raise MotionFileError(
                self.source or self.name,
                f"positions have {self.positions.shape[1]} joints but the skeleton has {self.skeleton.num_joints}",
            )
        if not np.isfinite(self.fps) or self.fps <= 0:
            raise MotionFileError(self.source or self.name, f"fps must be positive, got {self.fps}")
        # inf is never data: treat it as missing so it cannot leak into training or output, and
        # count it with the other absurd values (io/absurd.py).
        inf = np.isinf(self.positions)
        if inf.any():
            self.meta = {**self.meta, "absurd_tokens": self.meta.get("absurd_tokens", 0) + int(inf.any(-1).sum())}
            self.positions[inf] = np.nan

    @property
    def num_frames(self) -> int:
        return self.positions.shape[0]

    @property
    def duration_s(self) -> float:
        return self.num_frames / self.fps

    @property
    def has_rotations(self) -> bool:
        return self.rotations is not None and self.root_translation is not None and self.offsets is not None

    @classmethod
    def centred(cls, positions: np.ndarray, *args, **kwargs) -> Clip:
        """A clip of positions (T, J, 3) in float64 metres, z up, as a reader computed them: kept in
        float32 relative to origin_near(positions), the subtraction done in float64, so a take
        far from the origin keeps every value to float32's precision near zero. Other arguments
        as Clip's but origin (a root_translation added later is relative to clip.origin too)."""
        positions = np.asarray(positions, dtype=np.float64)
        origin = origin_near(positions)
        with np.errstate(invalid="ignore", over="ignore"):
            return cls(positions - origin, *args, origin=origin, **kwargs)

    def absolute_positions(self) -> np.ndarray:
        """(T, J, 3) float64 metres, z up: the positions where the file has them (origin added)."""
        return self.positions.astype(np.float64) + self.origin

    def missing_mask(self) -> np.ndarray:
        """(T, J) bool, True where a joint is missing."""
        return np.isnan(self.positions).any(axis=-1)

    def replace(self, **changes) -> Clip:
        return replace(self, **changes)

    def select_joints(self, keep: list[int]) -> Clip:
        """The clip restricted to joints `keep`, each re-hung under its nearest kept ancestor.

        Rotations are re-expressed for the new tree from global rotations (FK of the local ones)
        and the clip's positions: local'(c) = G(p)^T G(c), offset'(c) = time-mean of
        G(p)^T (pos(c) - pos(p)), and the new root takes G(root) and pos(root). This is exact
        when the dropped joints only add constant offsets (a leaf, a fixed joint such as Bandai
        Namco's joint_Root); otherwise no constant offset exists and the clip comes back without
        rotations rather than with wrong ones.
        """
        keep = sorted(set(int(k) for k in keep))
        skeleton = self.skeleton.subset(keep)
        out = self.replace(
            positions=self.positions[:, keep], skeleton=skeleton, rotations=None, root_translation=None, offsets=None
        )
        if not self.has_rotations or not np.isfinite(self.rotations).all():
            return out

        def fk(local, root, offsets, parents, levels):  # numpy FK (this module stays torch-free) -> pos, globals
            pos, glob = np.empty(local.shape[:-1]), np.empty_like(local)
            pos[:, 0], glob[:, 0] = root, local[:, 0]
            up = np.asarray(parents)
            for joints in levels:  # a level of the tree at a time: each joint's parent is done
                pos[:, joints] = pos[:, up[joints]] + (glob[:, up[joints]] @ offsets[joints][..., None])[..., 0]
                glob[:, joints] = glob[:, up[joints]] @ local[:, joints]
            return pos, glob

        # A block of frames at a time (frame_blocks), the arrays of a block let go as soon as they
        # are used: every step is per frame but the offsets' mean over time, so the new local
        # rotations are kept for the check that needs it.
        T, J, K = self.num_frames, self.skeleton.num_joints, len(keep)
        par = np.array(skeleton.parents[1:], dtype=np.int64)  # (K-1,)
        offsets = self.offsets.astype(np.float64)  # (J, 3)
        levels, new_levels = depth_levels(self.skeleton.parents), depth_levels(skeleton.parents)
        new_local = np.empty((T, K, 3, 3))
        rotations = np.empty((T, K, 3), dtype=np.float32)
        rel = np.empty((T, K - 1, 3))
        root = np.empty((T, 3))
        for f in frame_blocks(T, J, len(levels)):
            local = rotation_matrices(self.rotations[f])  # (t, J, 3, 3)
            fk_pos, glob = fk(
                local, self.root_translation[f].astype(np.float64), offsets, self.skeleton.parents, levels
            )
            del local
            # The positions are the data; FK only fills joints the data lacks.
            data = self.positions[f].astype(np.float64)
            pos = np.where(np.isfinite(data), data, fk_pos)[:, keep]  # (t, K, 3)
            G = glob[:, keep]  # (t, K, 3, 3)
            del glob
            Gp_T = np.swapaxes(G[:, par], -1, -2)  # (t, K-1, 3, 3)
            new_local[f, :1] = G[:, :1]
            np.matmul(Gp_T, G[:, 1:], out=new_local[f, 1:])
            rel[f] = (Gp_T @ (pos[:, 1:] - pos[:, par])[..., None])[..., 0]  # (t, K-1, 3)
            root[f] = pos[:, 0]
            del G, Gp_T
            rotations[f] = rotation_vectors(new_local[f], np.float32)
        offsets = np.concatenate([np.zeros((1, 3)), rel.mean(axis=0)])  # (K, 3)

        for f in frame_blocks(T, K, len(new_levels)):
            check = fk(new_local[f], root[f], offsets, skeleton.parents, new_levels)[0]
            data = self.positions[f][:, keep].astype(np.float64)
            seen = np.isfinite(data).all(-1)  # (t, K)
            err = np.linalg.norm(check - data, axis=-1)[seen]
            if not np.all(err < 1e-4):  # NaN fails too
                return out
        return out.replace(
            rotations=rotations,
            root_translation=root.astype(np.float32),
            offsets=offsets.astype(np.float32),
        )


def limb_lengths(positions: np.ndarray, parents) -> np.ndarray:
    """positions: (T, J, 3) -> (T, L) length of each limb (parent, child), NaN where an end is missing."""
    p = np.asarray(parents)
    child = np.nonzero(p >= 0)[0]
    return np.linalg.norm(positions[:, child] - positions[:, p[child]], axis=-1)


def body_limbs(positions: np.ndarray, parents) -> np.ndarray:
    """(L,) bool: the limbs that are bones. A root that never moves (Bandai Namco's joint_Root at
    the origin) is a placeholder, and its link to the moving hips is a translation, not a bone."""
    p = np.asarray(parents)
    child = np.nonzero(p >= 0)[0]
    root = positions[:, 0]
    seen = root[np.isfinite(root).all(axis=-1)]
    fixed_root = len(seen) > 1 and np.abs(seen - seen[0]).max() < 1e-9
    return ~(fixed_root & (p[child] == 0))


HUMAN_BONE_M = (0.01, 1.5)  # median bone length of a human skeleton in metres: far outside = a wrong unit


def check_human_scale(clips: list[Clip], source) -> None:
    """The clips of one file at a human body's scale in metres, or a MotionFileError: a file in mm
    read as metres would be 'fixed' to a model's human-sized guess everywhere, or trained on in
    kilometres, silently; one in metres read as mm shrinks to a point. The median bone says which."""
    lengths = [
        limb_lengths(c.positions, c.skeleton.parents)[:, body_limbs(c.positions, c.skeleton.parents)] for c in clips
    ]
    seen = np.concatenate([L[np.isfinite(L)] for L in lengths])
    if seen.size == 0:
        return
    median = float(np.median(seen))
    if not HUMAN_BONE_M[0] <= median <= HUMAN_BONE_M[1]:
        unit = clips[0].meta.get("unit", "m")
        raise MotionFileError(
            source,
            f"bones are {median:.3g} m long (median), read as {unit}: not a human body; "
            "give the file's unit (--unit or data.unit: m, cm, mm)",
        )
