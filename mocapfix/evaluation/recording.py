"""Corrupting a whole recording the way real capture fails, to score `mocapfix fix` (issue 5):
holes of 0.1-0.9 s (the full skeleton or one limb) where joints are missing, and a few tokens
that jumped to the wrong place. numpy, like the files fix reads and writes."""

from __future__ import annotations

import numpy as np


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
