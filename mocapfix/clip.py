"""Clip: one person's motion, the single representation every reader returns.

Lives beside skeleton.py (not in data/) because io/ readers build clips and data/ consumes
them: both import it and neither imports the other.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from mocapfix.skeleton import Skeleton


class MotionFileError(ValueError):
    """A file that cannot be read as motion. str() is one line naming the file and the problem."""

    def __init__(self, path, problem: str):
        self.path, self.problem = str(path), problem
        super().__init__(f"{path}: {problem}")


@dataclass
class Clip:
    positions: np.ndarray            # (T, J, 3) float32, metres, z up, NaN where a joint is missing
    fps: float
    skeleton: Skeleton
    name: str = ""                   # unique within a dataset: file stem (+ "#person" / "/key")
    source: str = ""                 # the file it came from; splits group clips by this
    # Where the positions came from (rotation-based data: BVH, AMASS, synthetic). Same frame
    # convention as positions: metres, z up. Forward kinematics of these reproduces positions.
    rotations: np.ndarray | None = None         # (T, J, 3) float32 local axis-angle, radians
    root_translation: np.ndarray | None = None  # (T, 3) float32, world position of joint 0
    offsets: np.ndarray | None = None           # (J, 3) float32 bone offsets in the parent's frame
    meta: dict = field(default_factory=dict)    # format, unit, up_axis, ... (plain values)

    def __post_init__(self):
        self.positions = np.asarray(self.positions, dtype=np.float32)
        if self.positions.ndim != 3 or self.positions.shape[2] != 3:
            raise MotionFileError(self.source or self.name, f"positions must be (frames, joints, 3), got {self.positions.shape}")
        if self.positions.shape[1] != self.skeleton.num_joints:
            raise MotionFileError(self.source or self.name, f"positions have {self.positions.shape[1]} joints but the "
                                  f"skeleton has {self.skeleton.num_joints}")
        if not np.isfinite(self.fps) or self.fps <= 0:
            raise MotionFileError(self.source or self.name, f"fps must be positive, got {self.fps}")
        # inf is never data: treat it as missing so it cannot leak into training or output.
        self.positions[~np.isfinite(self.positions)] = np.nan

    @property
    def num_frames(self) -> int:
        return self.positions.shape[0]

    @property
    def duration_s(self) -> float:
        return self.num_frames / self.fps

    @property
    def has_rotations(self) -> bool:
        return self.rotations is not None and self.root_translation is not None and self.offsets is not None

    def missing_mask(self) -> np.ndarray:
        """(T, J) bool, True where a joint is missing."""
        return np.isnan(self.positions).any(axis=-1)

    def replace(self, **changes) -> "Clip":
        return replace(self, **changes)
