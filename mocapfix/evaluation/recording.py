"""Breaking whole takes the way capture fails, to score `mocapfix fix` against the take as it was:
the one place the benchmarks (bench/) and the tests cut holes into a recording and move tokens
off it. numpy, like the files fix reads and writes; every cut is seeded or placed by the take's
length, so a rerun breaks a take the same way.

Holes are (T, J) bool masks of the tokens made missing, NaN in the broken copy (`with_holes`):
- `corrupt_recording`: issue 5's mix, holes of 0.1-0.9 s on the body or one limb and a few tokens
  that jumped (bench/fix_bandai.py, bench/fix_overlap_bandai.py);
- `spread_holes`: a few holes of one length on one part, evenly spread (the stranger takes of
  bench/fix_strangers_cmu.py: a cell per part and length);
- `random_holes`: holes of one joint each at random places (work for fix, bench/fix_archive.py);
- `part_holes`: holes evenly placed, each on the body or a limb drawn (work, bench/fix_speed.py);
- `displace_arms`: an arm moved 0.5-1 m every 2 s (the XMAE paper's displacement task on whole
  takes: bench/fix_policy_bandai.py, bench/fix_both_strangers.py).

Training corruption (windows, torch, drawn per batch) is data/corruption.py's; the holes the fill
policy cuts into the user's own recording, where it has data, are the product's (fills/: cut_holes).
"""

from __future__ import annotations

import numpy as np


def with_holes(x: np.ndarray, hidden: np.ndarray) -> np.ndarray:
    """x: (T, J, 3), hidden: (T, J) bool -> float32 (T, J, 3), NaN at the hidden tokens (missing,
    as the readers mark it)."""
    return np.where(hidden[..., None], np.nan, x).astype(np.float32)


def corrupt_recording(
    x: np.ndarray,
    fps: float,
    groups: dict[str, list[int]],
    rng: np.random.Generator,
    gap_s: tuple[float, float] = (0.1, 0.9),
    displace_fraction: float = 0.02,
    max_displacement_m: float = 1.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x: (T, J, 3) metres -> corrupted (T, J, 3), gap (T, J) bool, displaced (T, J) bool.

    Gaps: lengths uniform in gap_s seconds, each on the full skeleton or on one of `groups`
    (equal odds), 0.7-1.3 s of clean motion between them, none in the first 0.5 s or the last
    second; gap tokens are NaN. Displaced: displace_fraction of the other tokens, moved by an
    offset uniform in a ball of radius max_displacement_m.
    """
    T, J, _ = x.shape
    parts = [None] + [list(v) for v in groups.values()]
    gap = np.zeros((T, J), dtype=bool)
    t = int(0.5 * fps)
    while t < T - fps:
        n = max(1, int(round(rng.uniform(*gap_s) * fps)))
        joints = parts[rng.integers(len(parts))]
        gap[t : t + n, slice(None) if joints is None else joints] = True
        t += n + int(rng.integers(int(0.7 * fps), int(1.3 * fps)))
    displaced = ~gap & (rng.random((T, J)) < displace_fraction)
    d = rng.normal(size=(T, J, 3))
    d *= max_displacement_m * (rng.random((T, J, 1)) ** (1 / 3)) / np.linalg.norm(d, axis=-1, keepdims=True)
    y = x.copy()
    y[gap] = np.nan
    y[displaced] += d[displaced].astype(y.dtype)
    return y, gap, displaced


def spread_holes(
    num_frames: int, num_joints: int, fps: float, gap_s: float, joints=None, count=4, between_s=0.1
) -> np.ndarray:
    """(T, J) bool: `count` holes of gap_s over `joints` (None: all), centred at 1/(count+1),
    2/(count+1), ... of the take: the same places for every part and length, so the cells of a
    table differ by what is missing, not where. Fewer where the take cannot hold `count` with
    between_s of data between them (the fill policy's own cut holes keep as much, fills/errors.py:
    CONTEXT_S): four 0.9-s holes in a 4.2-s take would touch and make one 3.4-s hole, scored in
    the 0.9-s cell (four of Bandai's test takes had such holes)."""
    mask = np.zeros((num_frames, num_joints), dtype=bool)
    n = max(1, int(round(gap_s * fps)))
    between = max(1, int(round(between_s * fps)))
    while count > 1 and num_frames / (count + 1) < n + between:
        count -= 1
    for k in range(count):
        start = int((k + 1) * num_frames / (count + 1)) - n // 2
        mask[start : start + n, slice(None) if joints is None else list(joints)] = True
    return mask


def part_holes(
    num_frames: int, num_joints: int, fps: float, groups: dict, rng: np.random.Generator, count=10, hole_s=0.5
) -> np.ndarray:
    """(T, J) bool: `count` holes of hole_s seconds starting evenly from 5 % to 95 % of the take,
    each on the whole body or on one of `groups` (drawn, equal odds): work for every part of fix
    (bench/fix_speed.py)."""
    parts = [None] + [list(v) for v in groups.values()]
    mask = np.zeros((num_frames, num_joints), dtype=bool)
    for start in np.linspace(0.05 * num_frames, 0.95 * num_frames, count).astype(int):
        joints = parts[rng.integers(len(parts))]
        mask[start : start + int(hole_s * fps), slice(None) if joints is None else joints] = True
    return mask


def random_holes(num_frames: int, num_joints: int, fps: float, seed: int, count=12, hole_s=0.5) -> np.ndarray:
    """(T, J) bool: `count` holes of hole_s seconds, each of one joint at a random frame (seeded;
    holes may overlap)."""
    rng = np.random.default_rng(seed)
    mask, n = np.zeros((num_frames, num_joints), dtype=bool), max(1, round(hole_s * fps))
    for _ in range(count):
        start = int(rng.integers(0, max(1, num_frames - n)))
        mask[start : start + n, int(rng.integers(0, num_joints))] = True
    return mask


def displace_arms(
    positions: np.ndarray, fps: float, groups: dict, rng: np.random.Generator, every_s: float = 2.0, span_s: float = 0.5
) -> tuple[np.ndarray, np.ndarray]:
    """positions (T, J, 3) -> (displaced copy, (T, J) bool: the displaced tokens). Every every_s
    from 0.5 s, one arm (left or right, drawn) moved by a constant offset of 0.5-1.0 m in a random
    direction for span_s."""
    out, moved = positions.copy(), np.zeros(positions.shape[:2], dtype=bool)
    arms = [g for g in ("left_arm", "right_arm") if g in groups]
    span = int(round(span_s * fps))
    for start in range(int(fps * 0.5), len(positions) - span, int(round(every_s * fps))):
        joints = list(groups[arms[rng.integers(len(arms))]])
        direction = rng.normal(size=3)
        offset = direction / np.linalg.norm(direction) * rng.uniform(0.5, 1.0)
        out[start : start + span, joints] += offset.astype(np.float32)
        moved[start : start + span, joints] = True
    return out, moved


def hole_lengths(gap: np.ndarray) -> np.ndarray:
    """gap (T, J) bool -> (T,) the length in frames of the run of frames with a missing joint that
    each frame is in (0 outside holes): the hole's length when holes keep apart, as
    corrupt_recording's do."""
    frames = gap.any(-1).astype(int)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], frames, [0]])))  # start, end, start, end, ...
    out = np.zeros(len(frames), dtype=int)
    for start, end in zip(edges[::2], edges[1::2]):
        out[start:end] = end - start
    return out


def error_mm(outputs: list[np.ndarray], truths: list[np.ndarray], where: list[np.ndarray]) -> float:
    """The mean distance (mm) of each take's output to its truth over the tokens `where` marks,
    over all takes together: (T, J, 3), (T, J, 3), (T, J) bool per take."""
    errors = [np.linalg.norm(y - t, axis=-1)[w] for y, t, w in zip(outputs, truths, where)]
    return 1000 * float(np.concatenate(errors).mean())
