"""The clips of one file fixed by a fixer: the library's entry below fix_file (files.py).

    infill   missing tokens (NaN) get the estimate; observed tokens stay bit-identical.
    denoise  observed tokens get the estimate; missing tokens stay missing.
    both     every token gets the estimate (denoised and filled).

In denoise and both, left and right limbs exchanged for a few frames (a tracker's slip) are put
back first (exchanges.py); in both with an XMAE, a limb held in a flipped pose for a moment (an
IK solver's flip) is made a hole for the fill policy (flips.py). How a model fixes clips is its
Fixer's own (fixers.py): a positions model through windows of joint positions
(position_fixer.py), a rotations model through windows of joint rotations (rotations.py), the
jitter remover on whole takes (jitter_clips.py).
"""

from __future__ import annotations

from collections.abc import Callable

from mocapfix.core.clip import Clip, check_human_scale
from mocapfix.fills.motion_matching import MotionLibrary
from mocapfix.fills.policy import FillPolicy
from mocapfix.fix.exchanges import put_back_exchanges
from mocapfix.fix.fixer import Fixer, FixOptions
from mocapfix.fix.flips import flips_as_holes
from mocapfix.fix.report import FixReport
from mocapfix.fix.threads import on_one_blas_thread


@on_one_blas_thread  # fix/threads.py
def fix_clips(
    clips: list[Clip],
    fixer: Fixer,
    mode: str | None = None,
    overlap: float = 0.5,
    batch_size: int = 64,
    progress: Callable[[int, int], None] | None = None,
    joint_map: dict[str, str] | None = None,
    measured: tuple[FillPolicy | None, str | None] | None = None,
    library: MotionLibrary | None = None,
) -> tuple[list[Clip], FixReport]:
    """Fix the clips of one file; each keeps its skeleton, frames and fps. mode: MODES, None: the
    fixer's own (Fixer.default_mode). progress(done, total) is called after each batch of
    windows. measured: (policy, note) from measure_recordings over several files (a folder's
    takes) instead of this file's own; library: other takes the motion-matching fills search
    besides this file's (motion_library: the run's files, fix --library)."""
    options = FixOptions(mode or fixer.default_mode, overlap, batch_size, progress, joint_map, measured, library)
    if not clips:
        raise ValueError("fix_clips needs at least one clip")
    check_human_scale(clips, clips[0].source or clips[0].name)
    notes = []
    if options.mode != "infill":  # infill leaves observed tokens as they are, labels too
        clips, runs, frames = _exchanges_put_back(clips)
        if runs:
            notes.append(f"left and right limbs exchanged in {frames} frames ({runs} runs): put back")
    if options.mode == "both" and fixer.kind == "xmae":  # its fill policy fills them (a Motion-DVAE has no holes)
        clips, runs, tokens = _flips_as_holes(clips)
        if runs:
            notes.append(f"{runs} limbs held in a flipped pose for a moment: {tokens} tokens filled again")
    fixed, report = fixer.fix_clips(clips, options)
    report.notes[:0] = notes
    return fixed, report


def _exchanges_put_back(clips: list[Clip]) -> tuple[list[Clip], int, int]:
    """Positions clips with their short left/right limb exchanges put back (exchanges.py); a
    clip with rotations keeps its own (its hierarchy says which side is which)."""
    out, runs, frames = [], 0, 0
    for c in clips:
        if c.has_rotations:
            out.append(c)
            continue
        x, r, f = put_back_exchanges(c.positions, c.skeleton, c.fps)
        out.append(c.replace(positions=x.astype(c.positions.dtype)) if r else c)
        runs, frames = runs + r, frames + f
    return out, runs, frames


def _flips_as_holes(clips: list[Clip]) -> tuple[list[Clip], int, int]:
    """Clips with each limb held in a flipped pose for a moment made missing there (flips.py),
    for the fill to fill again; a clip with rotations too (its positions are what is fixed)."""
    out, runs, tokens = [], 0, 0
    for c in clips:
        x, r, n = flips_as_holes(c.positions, c.skeleton, c.fps)
        out.append(c.replace(positions=x) if r else c)
        runs, tokens = runs + r, tokens + n
    return out, runs, tokens
