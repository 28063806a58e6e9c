"""What `fix` tells about one file, as a value: FixReport (counts, the limbs' spread before and
after, notes), and the names a message gives a file's clips."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

from mocapfix.core.clip import Clip

NOT_JUDGED = "observed tokens kept, not judged"


@dataclass
class FixReport:
    frames: int  # per person, at the input's fps
    people: int  # clips of the file (people; sequences for Human3.6M)
    filled: int  # missing tokens given a value
    replaced: int  # observed tokens replaced by the estimate
    limb_sigma_before_mm: float  # the model's limbs, over the input's tokens
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


def who(clips: list[Clip]) -> Callable[[int], str]:
    """Clip i's name in a message: "" for a file of one clip."""

    def name(i: int) -> str:
        c = clips[i]
        if len(clips) == 1:
            return ""
        return f"sequence {c.name}: " if c.meta.get("format") == "h36m" else f"person {c.meta.get('person_id', i)}: "

    return name


def frames_and_people(clips: list[Clip]) -> tuple[int, int]:
    """Frames per person and people, as a report gives them (Human3.6M's clips are sequences of one
    subject, laid end to end, not people)."""
    total = sum(c.num_frames for c in clips)
    return (total if clips[0].meta.get("format") == "h36m" else total // len(clips)), len(clips)
