"""One pass of a positions model over the clips of one file: each clip at the model's joints and
fps (joints.py) -> windows of the model's length (position_windows.py; every window of every
person in one batched pass, windowing.blend_windows) -> the blended estimate back at the clip's
frames -> merged with the input by mode (merge.py: infill, denoise, both) -> written back into
the clip, the joints the model does not use filled along the skeleton, and counted
(write_back.py) -> the pass's report (report.py: PassTally).

position_fixer.py decides which passes a fix makes (the fill policy, jumps replaced).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from mocapfix.core.clip import Clip
from mocapfix.core.resample import resample_frames
from mocapfix.fills.holes import token_choice
from mocapfix.fills.motion_matching import FILLS as MATCH_FILLS
from mocapfix.fills.motion_matching import MotionMatching, library_of
from mocapfix.fills.policy import FillPolicy, is_learned
from mocapfix.fix.fixer import Fixer, FixOptions
from mocapfix.fix.joints import ModelView, model_view
from mocapfix.fix.merge import merge
from mocapfix.fix.position_windows import PositionWindows, joints_missing_for_a_window, needed_frames
from mocapfix.fix.report import FixReport, PassTally, who
from mocapfix.fix.windowing import blend_windows
from mocapfix.fix.write_back import clip_fixed


def take_keys(clips: list[Clip]) -> list[tuple[str, int]]:
    """What names each clip of a file in a MotionLibrary: (its file, its place in the file). The
    file by its resolved path: `fix takes/a.bvh --library /data/takes` must know the library's
    a.bvh for the take being fixed, or the policy's cut holes find their own truth there."""
    return [(str(Path(c.source).resolve()) if c.source else c.name, i) for i, c in enumerate(clips)]


def positions_pass(
    clips: list[Clip],
    fixer: Fixer,
    options: FixOptions,
    policy: FillPolicy | None,
    fill_other_joints: bool = True,
    seen: list[np.ndarray] | None = None,
    view: ModelView | None = None,
) -> tuple[list[Clip], FixReport]:
    """The clips of one file fixed by one pass of a positions model in options.mode (infill with
    the fill policy where there is one); the holes of joints the model does not use filled too
    (fill_other_joints, unless denoise). A clip shorter than the model's window keeps its
    observed tokens in every mode (Fixer.too_short). seen: (T, Jm) per clip, the tokens the
    recording observed, when `clips` has some taken out (the policy's second pass): the report's
    "never observed" is about the recording. view: model_view(clips, ...) when the caller has it.
    options.library: what the policy's motion-matching fills search besides these clips."""
    model, fps_m, mode = fixer.skeleton, fixer.fps, options.mode
    source = clips[0].source or clips[0].name
    view = view if view is not None else model_view(clips, model, fps_m, options.joint_map)
    keys, library = take_keys(clips), options.library
    if policy is not None and any(m in MATCH_FILLS for m in policy.methods()) and (library is None or len(clips) > 1):
        # what the policy's motion matching searches: these takes too (a copy of each: only when it
        # may, and only for what it adds: a take is always searched itself, mirrored where the
        # library's are; a run's library, built once, is not built again for each file)
        library = library_of([(x, c.fps) for x, c in zip(view.x_in, clips)], keys, model, library)

    asked = learned_frames(clips, view, policy, model) if mode == "infill" and policy is not None else None
    need_m = needed_frames(clips, view, mode, fps_m, asked)
    made = fixer.estimates(clips, view, need_m, options)

    tally, out_clips = PassTally(model), []
    for k, c in enumerate(clips):
        tally.lerped += int(made.unserved[k].sum())
        est = made.clips[k]
        match = MotionMatching(library, keys[k])  # this take's own data searched as it is, holes and all
        new = merge(
            est, view.x_in[k], view.index[k], mode, policy, c.fps, model, tally.filled_by, match, fixer.candidate
        )
        keep = mode == "infill" or fixer.too_short(c)  # its observed tokens kept
        out_clips.append(
            clip_fixed(c, k, new, view, fixer, mode, keep, seen, fill_other_joints, tally, who(clips), source)
        )
    return out_clips, tally.report(clips, fps_m, mode, made.runs, made.failed, made.blind)


def learned_frames(clips: list[Clip], view: ModelView, policy: FillPolicy, model) -> list[np.ndarray] | None:
    """(T,) bool per clip: the frames of the holes the policy fills with a candidate that has the
    model in it, the only ones the model's windows need to run for in infill (on performers a
    model never saw the recording's policy often chooses classical fills everywhere: no window
    runs); None where every hole needs the model (a model joint the recording lacks: only the
    model fills it)."""
    if any((index < 0).any() for index in view.index):
        return None
    names = policy.chosen()
    learned = torch.tensor([is_learned(m) for m in names])
    table = policy.table(names)
    frames = []
    for x, c in zip(view.x_in, clips):
        observed = torch.from_numpy(np.isfinite(x).all(-1))[None]  # (1, T, Jm), as merge reads it
        choice = token_choice(observed, c.fps, model, policy.gaps_s, table)
        frames.append((learned[choice] & ~observed)[0].any(-1).numpy())
    return frames


class Estimates(NamedTuple):
    """A model's estimate of each clip of a file at the clip's own frames, and how it was made."""

    clips: list[np.ndarray]  # (T, Jm, 3) per clip, NaN where none was needed
    unserved: list[np.ndarray]  # (K,) bool per clip: needed model frames the model did not serve (Lerp there)
    runs: int  # the network's runs (windows; a correction's holes)
    failed: int  # of those, runs whose estimate was not finite
    blind: int  # windows with a joint missing throughout (joints_missing_for_a_window), for the report


def model_estimates(
    clips: list[Clip], fixer: Fixer, view: ModelView, need_m: list[np.ndarray], options: FixOptions
) -> Estimates:
    """The model's estimate of each clip at its own frames, (T, Jm, 3) with NaN where no window
    was needed (need_m: (K,) bool per clip at the model's frames, needed_frames). Windows with
    data go to the model; windows without any (a hole longer than a window) get Lerp instead,
    blended the same way, so there is no seam where the estimate meets the fallback."""
    has_data = [np.isfinite(xm).all(-1).any(-1) for xm in view.x_m]  # (K,) per clip
    windows = PositionWindows(fixer, view.x_m, fixer.whole_take_fills(clips, view))
    blended = blend_windows(windows, need_m, has_data, options.overlap, options.batch_size, options.progress)
    estimates = [
        resample_frames(track.reshape(-1, fixer.skeleton.num_joints, 3), fixer.fps, c.fps, c.num_frames)
        for track, c in zip(blended.tracks, clips)
    ]
    unserved = [~served & need for served, need in zip(blended.by_model, need_m)]
    blind = joints_missing_for_a_window(view.x_m, fixer.window, options.overlap)
    return Estimates(estimates, unserved, blended.windows, blended.failed, blind)


def with_mode(options: FixOptions, mode: str) -> FixOptions:
    return dataclasses.replace(options, mode=mode)
