"""The fill policy measured on recordings as `fix` fills them (fills/recording_policy.py): the
model's fill made by the positions pass itself (windows, blending, anchoring on the data), and
the takes a run's motion-matching fills search."""

from __future__ import annotations

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.fills.motion_matching import MotionLibrary, mirror_of
from mocapfix.fills.policy import FillPolicy
from mocapfix.fills.recording_policy import measure_policy
from mocapfix.fix.fixer import Fixer
from mocapfix.fix.joints import ModelView, model_view
from mocapfix.fix.positions import model_fill, take_keys


def measure_recordings(
    recordings: list[list[Clip]],
    fixer: Fixer,
    mode: str = "infill",
    overlap: float = 0.5,
    batch_size: int = 64,
    joint_map: dict[str, str] | None = None,
    map_takes=None,
    library: MotionLibrary | None = None,
) -> tuple[FillPolicy | None, str | None]:
    """The fill policy of several recordings measured together (the takes of one folder: one
    performer or session, whose holes alone are too few to rank the fills by; recording_policy.py)
    -> (policy, a line for the report); pass it to fix_clips(measured=...). (None, None) for a
    fixer that does not measure its policy (Fixer.measures_policy), one without a policy, or
    denoise. A recording the model's joints cannot be found in is left out (fixing it says why).
    map_takes: measure_on_takes' (workers); library: other takes the motion-matching fills
    search besides these (fix --library)."""
    if not fixer.measures_policy or mode == "denoise" or fixer.policy is None:
        return None, None
    views, mapped = [], []
    for clips in recordings:
        try:
            views.append(model_view(clips, fixer.skeleton, fixer.fps, joint_map))
            mapped.append(clips)
        except MotionFileError:
            continue
    if not views:
        return None, None
    return measure_views(fixer, views, mapped, mode, overlap, batch_size, map_takes, library)


def measure_views(
    fixer: Fixer,
    views: list[ModelView],
    recordings: list[list[Clip]],
    mode: str,
    overlap: float,
    batch_size: int,
    map_takes=None,
    library: MotionLibrary | None = None,
) -> tuple[FillPolicy | None, str | None]:
    """measure_policy over recordings seen at the model's joints (model_view) -> (policy, note)."""
    tracks = [x for v in views for x in v.x_m]  # (K, Jm, 3) per clip, the model's fps
    takes = [(x, c.fps) for v, clips in zip(views, recordings) for x, c in zip(v.x_in, clips)]  # the input's fps
    keys = [key for clips in recordings for key in take_keys(clips)]
    fill = model_fill(fixer, overlap, batch_size)
    return measure_policy(fixer, tracks, takes, fixer.policy, fill, mode == "both", map_takes, keys, library)


def motion_library(
    recordings: list[list[Clip]], fixer: Fixer, joint_map: dict[str, str] | None = None
) -> MotionLibrary | None:
    """The takes of several files (a run's) at the model's joints and their own fps, for the
    motion-matching fills of every file of the run (fills/motion_matching.py); None where none maps."""
    takes, keys = [], []
    for clips in recordings:
        try:
            view = model_view(clips, fixer.skeleton, fixer.fps, joint_map)
        except MotionFileError:
            continue
        takes += [(x, c.fps) for x, c in zip(view.x_in, clips)]
        keys += take_keys(clips)
    return MotionLibrary(takes, keys, mirror_of(fixer.skeleton)) if takes else None
