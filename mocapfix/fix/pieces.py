"""Long takes fixed in pieces. A take longer than PIECE_S is fixed in pieces of PIECE_S, each with
PIECE_MARGIN_S of the take on both sides as context (more than a window, a jump's MAX_REPLACED_S
and most holes): the memory a run needs is a piece's, whatever the take's length (a 30-minute
take was 2.5x a minute's), and each piece's fill policy is measured on that piece of the recording.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from mocapfix.core.clip import Clip
from mocapfix.fix.fixer import Fixer, FixOptions
from mocapfix.fix.report import FixReport, frames_and_people

PIECE_S = 120.0
PIECE_MARGIN_S = 10.0


def is_long(clip: Clip) -> bool:
    return clip.duration_s > PIECE_S + 2 * PIECE_MARGIN_S


def fix_in_pieces(clips: list[Clip], fixer: Fixer, options: FixOptions) -> tuple[list[Clip], FixReport]:
    """The clips of a file of which some are long fixed by `fixer`: each clip alone, a long one
    piece by piece; one report, its counts those of the pieces' own frames."""
    out, reports, pieces = [], [], 0
    for c in clips:
        T, piece, margin = c.num_frames, round(PIECE_S * c.fps), round(PIECE_MARGIN_S * c.fps)
        starts = range(0, T, piece) if is_long(c) else [0]
        pieces += len(starts) if len(starts) > 1 else 0
        positions = np.empty_like(c.positions)
        for a in starts:
            b = T if len(starts) == 1 else min(T, a + piece)
            lo, hi = max(0, a - margin), min(T, b + margin)
            part = c.replace(positions=c.positions[lo:hi], rotations=None, root_translation=None, offsets=None)
            (fixed,), report = fixer.fix_clips([part], options)
            positions[a:b] = fixed.positions[a - lo : b - lo]
            reports.append((_own_share(report, c.positions[a:b], positions[a:b]), b - a))
        out.append(c.replace(positions=positions, rotations=None, root_translation=None, offsets=None))
    return out, _merged(clips, reports, pieces)


def _own_share(report: FixReport, before: np.ndarray, after: np.ndarray) -> FixReport:
    """A piece's report counts over its margins too: its own frames' share of them."""
    was, now = np.isfinite(before).all(-1), np.isfinite(after).all(-1)
    filled, replaced = int((~was & now).sum()), int((was & (after != before).any(-1)).sum())
    share = filled / report.filled if report.filled else 0.0
    by = {m: round(n * share) for m, n in report.filled_by.items()}
    return dataclasses.replace(report, filled=filled, replaced=replaced, filled_by=by)


def _merged(clips: list[Clip], reports: list[tuple[FixReport, int]], pieces: int) -> FixReport:
    """The pieces' reports (each with its frames) as one."""
    frames, people = frames_and_people(clips)
    notes, filled_by = [], {}
    for report, _ in reports:
        notes += [n for n in report.notes if n not in notes]
        for method, n in report.filled_by.items():
            filled_by[method] = filled_by.get(method, 0) + n
    notes.append(f"fixed in {pieces} pieces of {PIECE_S:g} s (each with {PIECE_MARGIN_S:g} s of context)")

    def mean(field: str) -> float:  # frame-weighted over the pieces
        return sum(getattr(r, field) * n for r, n in reports) / max(1, sum(n for _, n in reports))

    return FixReport(
        frames,
        people,
        sum(r.filled for r, _ in reports),
        sum(r.replaced for r, _ in reports),
        mean("limb_sigma_before_mm"),
        mean("limb_sigma_after_mm"),
        sum(r.windows for r, _ in reports),
        notes,
        filled_by,
    )
