"""What `fix` tells about one file, as a value: FixReport (counts, the limbs' spread before and
after, notes), what a positions pass counts on its way to one (PassTally), and the names a
message gives a file's clips.

A report is about the file: its counts are of the file's own tokens that fix wrote, and the
limbs it measures are the model's limbs between two joints the file has. A model joint the rig
lacks (toes on a rig without them) is estimated, as the rest of the body needs it, but neither
written, counted nor measured (LimbSpread).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from mocapfix.core.clip import Clip
from mocapfix.core.skeleton import Skeleton
from mocapfix.evaluation.limb_lengths import limb_sigmas

NOT_JUDGED = "observed tokens kept, not judged"


@dataclass
class FixReport:
    frames: int  # per person, at the input's fps
    people: int  # clips of the file (people; sequences for Human3.6M)
    filled: int  # missing tokens given a value
    replaced: int  # observed tokens replaced by the estimate
    limb_sigma_before_mm: float  # the model's limbs the file has (LimbSpread), over the input's tokens
    limb_sigma_after_mm: float
    windows: int  # windows the model ran on
    notes: list[str] = field(default_factory=list)
    filled_by: dict[str, int] = field(default_factory=dict)  # method -> missing tokens it filled (fill policy)
    mode: str = ""  # the mode it was fixed in (a file's report: fix_file)
    model: str = ""  # the fixer's kind

    def as_dict(self) -> dict:
        """The report as `fix --json` writes it (without the input, output and seconds)."""
        return {
            "mode": self.mode,
            "model": self.model,
            "frames": self.frames,
            "people": self.people,
            "filled": self.filled,
            "replaced": self.replaced,
            "filled_by": self.filled_by,
            "windows": self.windows,
            "limb_sigma_before_mm": _finite_or_none(self.limb_sigma_before_mm),
            "limb_sigma_after_mm": _finite_or_none(self.limb_sigma_after_mm),
            "notes": list(self.notes),
        }


def _finite_or_none(v: float) -> float | None:
    return v if math.isfinite(v) else None


class LimbSpread:
    """Limb sigma (the std over time of each limb's length) of a file's clips as read and as
    fixed, over the model's limbs between two joints the file has: a limb to a joint the rig
    lacks has nothing read to compare with, and what the model estimated there is not written.
    The mean over clips and limbs, as metrics.LimbSigma takes it (evaluation/limb_lengths.py)."""

    def __init__(self, model: Skeleton):
        self.limbs = [(int(a), int(b)) for a, b in model.limbs]
        self.sums = {"before": [0.0, 0], "after": [0.0, 0]}  # [sum of stds mm, count]

    def add(self, before: np.ndarray, after: np.ndarray, index: np.ndarray | None = None) -> None:
        """before, after: (T, Jm, 3) one clip at the model's joints as read and as fixed; index:
        (Jm,) the clip's joint of each model joint, -1 where the clip has none (None: it has all)."""
        if index is not None and (index < 0).any():
            before, after = before.copy(), after.copy()
            before[:, index < 0] = np.nan
            after[:, index < 0] = np.nan
        for name, x in (("before", before), ("after", after)):
            sigma, valid = limb_sigmas(torch.from_numpy(x)[None], self.limbs)
            self.sums[name][0] += float(torch.where(valid, sigma, 0.0).sum(dtype=torch.float64))
            self.sums[name][1] += int(valid.sum())

    def values(self) -> tuple[float, float]:
        """(before, after) in mm, as float32 as LimbSigma gives them; NaN (shown "-") where
        nothing was measured."""
        return tuple(float(np.float32(total / count)) if count else float("nan") for total, count in self.sums.values())


@dataclass
class PassTally:
    """What one positions pass counts over the clips of a file (write_back.clip_fixed), and the
    report it makes of them."""

    model: Skeleton
    filled: int = 0
    replaced: int = 0
    lerped: int = 0
    other_filled: int = 0
    filled_by: dict[str, int] = field(default_factory=dict)
    never: dict[str, list[str]] = field(default_factory=dict)  # person -> model joints never observed
    absent: dict[str, list[str]] = field(default_factory=dict)  # person -> model joints the recording lacks
    notes: list[str] = field(default_factory=list)

    def __post_init__(self):
        self.limbs = LimbSpread(self.model)

    def report(self, clips: list[Clip], fps_m: float, mode: str, windows: int, failed: int, whole: int) -> FixReport:
        """windows: the windows the model ran on, failed: of those, the non-finite ones; whole:
        windows with a joint missing throughout (position_windows.joints_missing_for_a_window)."""
        notes = self.notes
        if self.other_filled:
            notes.append(
                f"{self.other_filled} missing tokens of joints the model does not use filled along the skeleton"
            )
            self.filled += self.other_filled
        if self.lerped:
            notes.append(f"{self.lerped} frames at {fps_m:g} fps had no data within a window: linear interpolation")
        if failed:
            notes.append(f"{failed} windows gave non-finite estimates: linear interpolation there")
        for person, joints in self.never.items():
            notes.append(f"{person}joints never observed: {', '.join(joints)} (left missing: never shown)")
        for person, joints in self.absent.items():
            notes.append(f"{person}model joints not in the recording: {', '.join(joints)} (estimated, not written)")
        if whole:
            fate = "left missing" if mode == "denoise" else "estimated from the rest of the body"
            notes.append(f"{whole} windows had a joint missing throughout ({fate})")
        frames, people = frames_and_people(clips)
        before, after = self.limbs.values()
        return FixReport(frames, people, self.filled, self.replaced, before, after, windows, notes, self.filled_by)


def who(clips: list[Clip]) -> Callable[[int], str]:
    """Clip i's name in a message: "" for a file of one clip."""

    def name(i: int) -> str:
        c = clips[i]
        if len(clips) == 1:
            return ""
        if c.meta.get("format") == "h36m":
            return f"sequence {c.name}: "
        word = "take" if c.meta.get("format") in ONE_AFTER_ANOTHER else "person"
        return f"{word} {c.meta.get('person_id', i)}: "

    return name


# Formats whose clips follow one another in time, not people seen together: Human3.6M's sequences
# of one subject, a Kinect log's takes between the pauses -> the word a report counts them by.
ONE_AFTER_ANOTHER = {"h36m": "sequences", "keypoints-kinect-log": "takes"}


def frames_and_people(clips: list[Clip]) -> tuple[int, int]:
    """Frames per person and people, as a report gives them (clips one after another,
    ONE_AFTER_ANOTHER, add their frames up)."""
    total = sum(c.num_frames for c in clips)
    return (total if clips[0].meta.get("format") in ONE_AFTER_ANOTHER else total // len(clips)), len(clips)
