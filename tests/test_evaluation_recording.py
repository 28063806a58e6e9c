"""evaluation/recording.py: the one place benchmarks and tests break whole takes to score fix."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from mocapfix.core.skeleton import preset
from mocapfix.evaluation.recording import (
    corrupt_recording,
    displace_arms,
    error_mm,
    hole_lengths,
    part_holes,
    random_holes,
    spread_holes,
    with_holes,
)
from mocapfix.io.synthetic import generate_clips

REPO = Path(__file__).resolve().parents[1]
SMPL = preset("smpl22")
FPS = 30.0


def _take(seconds: float = 12.0) -> np.ndarray:
    return generate_clips(1, seconds, fps=FPS, seed=0)[0].positions  # (T, 22, 3)


def test_corrupt_recording_cuts_separate_holes_of_the_asked_lengths_and_moves_other_tokens():
    x = _take()
    y, gap, displaced = corrupt_recording(x, FPS, SMPL.groups, np.random.default_rng(0))
    assert gap.any() and displaced.any() and not (gap & displaced).any()
    assert np.isnan(y[gap]).all() and np.isfinite(y[~gap]).all()
    assert not gap[: int(0.5 * FPS)].any() and not gap[-int(FPS) + 1 :].any()
    lengths = hole_lengths(gap)[gap.any(-1)] / FPS  # holes keep 0.7 s apart: a run is one hole
    assert lengths.min() >= 0.1 - 1e-9 and lengths.max() <= 0.9 + 1e-9
    moved = np.linalg.norm(y[displaced] - x[displaced], axis=-1)
    assert 0 < moved.max() <= 1.0 + 1e-6
    assert np.array_equal(y[~gap & ~displaced], x[~gap & ~displaced])
    again = corrupt_recording(x, FPS, SMPL.groups, np.random.default_rng(0))
    assert np.array_equal(again[0], y, equal_nan=True)  # seeded: a rerun breaks the take the same way


def test_spread_holes_are_at_the_same_places_for_every_part():
    T, J = 300, SMPL.num_joints
    body = spread_holes(T, J, FPS, 0.5, None)
    arm = spread_holes(T, J, FPS, 0.5, SMPL.groups["left_arm"])
    assert np.array_equal(body.any(-1), arm.any(-1)) and body.all(-1).sum() == 4 * 15
    assert np.flatnonzero(arm.any(0)).tolist() == sorted(SMPL.groups["left_arm"])
    starts = np.flatnonzero(np.diff(body.any(-1).astype(int)) == 1) + 1
    assert starts.tolist() == [int((k + 1) * T / 5) - 7 for k in range(4)]


def test_spread_holes_in_a_short_take_are_fewer_never_one_long_hole():
    """Four 0.9-s holes in a 4.2-s take (125 frames at 30 fps) would touch: fewer are cut, each its
    own 27 frames with data between; a take with room keeps four."""
    from mocapfix.fills.holes import runs

    short = spread_holes(125, SMPL.num_joints, 30.0, 0.9)
    lengths = [e - s for s, e in runs(short.any(-1))]
    assert lengths == [27, 27, 27]
    gaps = np.diff([s for s, _ in runs(short.any(-1))]) - 27
    assert gaps.min() >= 3  # 0.1 s of data between them
    assert [e - s for s, e in runs(spread_holes(960, SMPL.num_joints, 120.0, 0.9).any(-1))] == [108] * 4


def test_random_holes_cover_one_joint_each_and_repeat_with_the_seed():
    holes = random_holes(300, SMPL.num_joints, FPS, seed=3, count=5)
    assert holes.sum(-1).max() <= 5 and 15 <= holes.sum() <= 5 * 15
    assert np.array_equal(holes, random_holes(300, SMPL.num_joints, FPS, seed=3, count=5))
    assert not np.array_equal(holes, random_holes(300, SMPL.num_joints, FPS, seed=4, count=5))


def test_part_holes_start_evenly_and_take_the_body_or_a_limb():
    holes = part_holes(600, SMPL.num_joints, FPS, SMPL.groups, np.random.default_rng(0))
    parts = [None, *SMPL.groups.values()]
    for start in np.linspace(30, 570, 10).astype(int):
        hidden = set(np.flatnonzero(holes[start]).tolist())
        assert any(hidden == set(range(SMPL.num_joints) if p is None else p) for p in parts)


def test_displace_arms_moves_one_arm_by_a_constant_offset_every_two_seconds():
    x = _take()
    y, moved = displace_arms(x, FPS, SMPL.groups, np.random.default_rng(0))
    assert np.array_equal(y[~moved], x[~moved])
    starts = np.flatnonzero(np.diff(moved.any(-1).astype(int)) == 1) + 1
    assert starts.tolist() == list(range(15, len(x) - 15, 60))
    for s in starts:
        joints = np.flatnonzero(moved[s])
        assert set(joints) in ({*SMPL.groups["left_arm"]}, {*SMPL.groups["right_arm"]})
        offset = y[s : s + 15, joints] - x[s : s + 15, joints]
        assert np.allclose(offset, offset[0, 0], atol=1e-5) and 0.5 - 1e-5 <= np.linalg.norm(offset[0, 0]) <= 1.0


def test_with_holes_marks_missing_as_the_readers_do_and_error_mm_scores_the_tokens():
    x = _take(2.0).astype(np.float64)
    hidden = np.zeros(x.shape[:2], dtype=bool)
    hidden[10:20, 3] = True
    y = with_holes(x, hidden)
    assert y.dtype == np.float32 and np.isnan(y[hidden]).all() and np.isfinite(y[~hidden]).all()
    off = x + np.array([0.003, 0.0, 0.004])  # 5 mm from the truth everywhere
    assert abs(error_mm([off, off], [x, x], [hidden, ~hidden]) - 5.0) < 1e-9


def test_no_benchmark_cuts_holes_of_its_own():
    """A missing token is written in bench/ only through evaluation/recording.py: no NaN put by hand."""
    cutting = [
        f"{p.name}:{i}"
        for p in sorted((REPO / "bench").glob("*.py"))
        for i, line in enumerate(p.read_text().splitlines(), 1)
        if re.search(r"np\.nan\b|float\(\"nan\"\)\s*$", line)
    ]
    assert not cutting
