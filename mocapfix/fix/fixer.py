"""What every fixer is: a trained model that fixes the clips of one file itself, and the options
one fix runs with. A model kind's class (fixers.py) says what differs by what it is, never by a
kind string: how it fixes clips (positions.py, rotations.py, jitter_clips.py), its default mode,
whether it gives rotations back and whether its fill policy is measured again on each recording.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.core.resample import model_frames
from mocapfix.core.skeleton import Skeleton
from mocapfix.fix.joints import map_joints

if TYPE_CHECKING:
    from mocapfix.fills.motion_matching import MotionLibrary
    from mocapfix.fills.policy import FillPolicy
    from mocapfix.fix.report import FixReport

MODES = ("infill", "denoise", "both")
# What a message names where a model cannot take a rig: the shipped models (mocapfix/pretrained)
# that can. Both work on joint positions, so any rig whose joints map; XMAE also estimates the
# model joints a rig lacks (toes), which the others need.
FOR_ANY_RIG = "jitter on any rig: --model jitter-many; holes and jumps: --model xmae-cpu-bandai"
FOR_A_RIG_LACKING_JOINTS = "a model that estimates joints a rig lacks: --model xmae-cpu-bandai"


@dataclass(frozen=True)
class FixOptions:
    """How the clips of one file are fixed. measured: (policy, note), the fill policy a run
    measured over several files (measure_recordings) instead of each file's own; library: other
    takes the motion-matching fills search besides the file's own (fix --library)."""

    mode: str = "infill"
    overlap: float = 0.5
    batch_size: int = 64
    progress: Callable[[int, int], None] | None = None  # progress(done, total) after each batch
    joint_map: dict[str, str] | None = None  # input name -> model name
    measured: tuple[FillPolicy | None, str | None] | None = None
    library: MotionLibrary | None = None

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        if not 0.0 <= self.overlap < 1.0:
            raise ValueError(f"overlap must be in [0, 1), got {self.overlap}")


class Fixer:
    """A model applied to recordings. Every kind has a skeleton (the model's joints, in its
    order), a frame rate and a window (frames); the class attributes below are what differs."""

    kind = "fixer"  # the model's name in reports ("xmae", "motion-dvae", "jitter")
    default_mode = "infill"  # the mode `fix` runs without --mode
    gives_rotations = False  # fixes joint rotations: a BVH comes back with the model's rotations
    measures_policy = False  # its fill policy is measured again on each recording (FillPolicy.fit)
    policy: FillPolicy | None = None  # which fill for which hole (fills/policy.py), given when it is built
    skeleton: Skeleton
    fps: float
    window: int

    def fix_clips(self, clips: list[Clip], options: FixOptions) -> tuple[list[Clip], FixReport]:
        """The clips of one file fixed; each keeps its skeleton, frames and fps."""
        raise NotImplementedError

    def clips_for(self, path, clips: list[Clip], source: str = "auto", joint_map=None, **read_options) -> list[Clip]:
        """The clips of the file at `path` (read as `clips`) as this model fixes them."""
        return clips

    def too_short(self, clip: Clip) -> bool:
        """A clip shorter than the model's window gives the model too little motion to judge an
        observed token against (mostly padding in view): denoise and both keep its observed tokens
        and only fill its holes. (A 1-frame take once had its feet moved 0.8 m.)"""
        return model_frames(clip.num_frames, clip.fps, self.fps) < self.window

    def model_joints(
        self, clip: Clip, source, joint_map: dict[str, str] | None = None, allow_missing: bool = False
    ) -> np.ndarray:
        """(Jm,) the clip's joint that plays each model joint, for a model that needs every one of
        them (allow_missing: -1 for those the clip lacks, as long as it has half of them); a
        MotionFileError naming those the clip lacks and the shipped model that takes it."""
        try:
            return map_joints(clip.skeleton, self.skeleton, source, joint_map, allow_missing)
        except MotionFileError as e:
            raise MotionFileError(e.path, f"{e.problem}; {FOR_A_RIG_LACKING_JOINTS}") from None

    def load_note(self, ckpt) -> str | None:
        """A line `fix` prints once about the checkpoint it loaded, or None."""
        return None
