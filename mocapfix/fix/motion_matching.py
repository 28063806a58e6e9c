"""Motion matching: fill a hole with how the body moved at the moments of the recording that
look most like the hole's surroundings.

A cubic through the hole's ends knows nothing of how people move: over 0.9 s of a walk it draws
the swinging foot as a smooth arc between two poses. The recording usually holds the same motion
elsewhere (the next steps of the walk, the same performer's other takes), and a folder of takes
holds much of it. For each hole this finds the stretches of the library whose frames around
the hole (every joint in the context frames; the joints still observed inside the hole) match
best after a turn about the vertical and a shift over the floor (2D Procrustes, closed form),
and fills the hole from the NEIGHBOURS best, weighted by how well each matched. Two fills come
out of one search (the recording's policy picks per kind of hole, fix/recording_policy.py):
- "match": the neighbours' own motion, its residual to the data at the hole's observed tokens
  interpolated across the hole (as fix anchors the model's estimate), so it meets both ends;
- "match_delta": the cubic Hermite fill plus how far each neighbour's motion departs from its own
  Hermite fill (the same hole cut into it): a correction to the interpolation, which shrinks
  to the interpolation where the neighbours disagree.
On CMU subjects 35-39 (the PFNN capture: a full-body hole in the middle of each of 32 takes,
the folder's other takes searched) the 0.5 / 0.9-s holes came out 10.7 / 21.6 mm for "match"
against the cubic spline's 21.7 / 57.4; on the CMU strangers with the same performers' other
takes, "match_delta" wins (docs/results.md, "Motion matching"). The settings below were tuned on
CMU 35-39, never on the stranger benchmark's takes.
Classical in the sense of the test tables: no training, nothing learned beyond the recording.
"""

from __future__ import annotations

import numpy as np
import torch

from mocapfix.evaluation.baselines import hermite_infill, lerp_infill
from mocapfix.fix.windowing import resample_frames

FILLS = ("match", "match_delta")
# Context each side of a hole, as a fraction of its length (at least MIN_CONTEXT frames): on CMU
# 35-39 a quarter of the hole beat a half and the whole hole's length (10.7 / 11.4 / 13.8 mm at 0.5 s).
CONTEXT_RATIO = 0.25
MIN_CONTEXT = 2
FRAMES_PER_SIDE = 8  # context frames compared (evenly spread; 16 gave the same)
HOLE_FRAMES = 8  # hole frames whose observed joints are compared (a limb hole: the rest of the body)
NEIGHBOURS = 16  # stretches averaged (4: 13.5 mm, 16: 10.7, 32: 11.4 at 0.5 s)
# Candidate stretches start every hole/STRIDE_PER_HOLE frames (at least 1): neighbours a frame
# apart are near copies of each other, and the search is the fill's whole cost.
STRIDE_PER_HOLE = 16
CHUNK = 4096  # candidate starts compared at once (memory: CHUNK x points x 3 floats)
LIBRARY_S = 600.0  # the most seconds of takes a library keeps (each hole's search scans them all)
# Holes shorter than this keep the Hermite fill: at 0.1 s the cubic is as good (CMU strangers:
# 3.1 mm, match_delta 3.2, match 4.1), and a take with many dropped frames would search once each.
MIN_HOLE_S = 0.2


class MotionLibrary:
    """Takes to match holes against, at one skeleton's joints: (T, J, 3) arrays in metres (NaN =
    missing) with their fps and a key each (a take of the recording being fixed is left out of
    its own search by key: its own data is searched as it is, holes and all). Over LIBRARY_S,
    the first takes that fit are kept."""

    def __init__(self, takes: list[tuple[np.ndarray, float]], keys: list | None = None):
        keys = list(range(len(takes))) if keys is None else list(keys)
        seconds = np.array([len(x) / fps for x, fps in takes])
        keep = np.arange(len(takes))
        if seconds.sum() > LIBRARY_S:  # whole takes, in order, until the budget is spent
            keep = keep[np.cumsum(seconds) <= LIBRARY_S]
        self.takes = [(takes[i][0].astype(np.float32), float(takes[i][1])) for i in keep]
        self.keys = [keys[i] for i in keep]
        self._at: dict[float, tuple[np.ndarray, list[tuple[int, int]]]] = {}

    def including(self, takes: list[tuple[np.ndarray, float]], keys: list) -> MotionLibrary:
        """A library of `takes` (those of its keys it does not hold yet) and then this one's (the
        budget keeps the new ones first: the recording being fixed before the user's other takes)."""
        new = [(t, k) for t, k in zip(takes, keys) if k not in self.keys]
        if not new:
            return self
        return MotionLibrary([t for t, _ in new] + self.takes, [k for _, k in new] + self.keys)

    def frames(self, fps: float) -> tuple[np.ndarray, list[tuple[int, int]]]:
        """Every take at `fps`, one after another with a NaN frame between them (no stretch spans
        two takes) -> (N, J, 3) and each take's (first, end) frame."""
        if fps not in self._at:
            parts, spans, n = [], [], 0
            for x, f in self.takes:
                inside = int(np.floor((len(x) - 1) * fps / f + 1e-6)) + 1  # the instants within the take
                y = x if f == fps else resample_frames(x, f, fps, inside)
                parts += [y, np.full((1, *x.shape[1:]), np.nan, np.float32)]
                spans.append((n, n + len(y)))
                n += len(y) + 1
            self._at[fps] = (np.concatenate(parts) if parts else np.zeros((0, 0, 3), np.float32), spans)
        return self._at[fps]

    def without(self, key, fps: float) -> np.ndarray:
        """The library at fps with the take of `key` (if it holds one) hidden: NaN."""
        frames, spans = self.frames(fps)
        if key not in self.keys:
            return frames
        first, end = spans[self.keys.index(key)]
        frames = frames.copy()
        frames[first:end] = np.nan
        return frames


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(T,) bool -> the (start, end) of each run of True."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def _spread(frames: np.ndarray, k: int) -> np.ndarray:
    """At most k of `frames`, evenly spread, first and last kept."""
    if len(frames) <= k:
        return frames
    return frames[np.round(np.linspace(0, len(frames) - 1, k)).astype(np.int64)]


def _search(library: np.ndarray, frames, joints, query, need: np.ndarray, width: int, k: int, stride: int):
    """The k best stretches of `library` (N, J, 3) of `width` frames -> list of (distance, start,
    angle, centre): distance the mean squared distance (m^2) between query (P, 3) and the
    stretch's tokens at (frames, joints) after the best turn about z and shift in x, y (angle
    and the stretch's x, y centre); need (J,) the joints the stretch must hold in every frame.
    Starts `stride` frames apart are compared, then every start around the best of them."""
    N = len(library) - width + 1
    if N <= 0:
        return []
    whole = np.isfinite(library[:, need]).all(-1).all(-1)  # (N + width - 1,)
    run = np.concatenate([[0], np.cumsum(whole)])
    # float32 as the library: the gather and the sums below are the whole cost of the fill
    query = query.astype(np.float32)
    q_xy = query[:, :2] - query[:, :2].mean(0)  # (P, 2)

    def compare(start: np.ndarray) -> list[tuple]:
        start = start[run[start + width] - run[start] == width]
        c = library[start[:, None] + frames[None], joints[None]]  # (A, P, 3)
        ok = np.isfinite(c).all((1, 2))
        start, c = start[ok], c[ok]
        centre = c[..., :2].mean(1)  # (A, 2)
        c_xy = c[..., :2] - centre[:, None]
        dot = np.einsum("apc,pc->a", c_xy, q_xy)
        cross = np.einsum("ap,p->a", c_xy[..., 0], q_xy[:, 1]) - np.einsum("ap,p->a", c_xy[..., 1], q_xy[:, 0])
        # min over the angle of |R c - q|^2 = |c|^2 + |q|^2 - 2 |(dot, cross)| (2D Procrustes)
        d = (c_xy**2).sum((1, 2)) + (q_xy**2).sum() - 2 * np.hypot(dot, cross)
        d += ((c[..., 2] - query[None, :, 2]) ** 2).sum(1)
        best = np.argsort(d)[: 8 * k]
        angle = np.arctan2(cross[best], dot[best])
        return [(float(d[i]) / len(query), int(start[i]), float(a), centre[i]) for i, a in zip(best, angle)]

    found = []
    for lo in range(0, N, CHUNK * stride):
        found += compare(np.arange(lo, min(N, lo + CHUNK * stride), stride))
    if stride > 1 and found:  # the frames between the best starts
        found.sort(key=lambda f: f[0])
        near = np.unique(np.array([f[1] for f in found[: 2 * k]])[:, None] + np.arange(1 - stride, stride)[None])
        found += compare(near[(near >= 0) & (near < N)])
    return found


def match_fills(
    positions: np.ndarray,
    observed: np.ndarray,
    hermite: np.ndarray,
    library: np.ndarray | None = None,
    fps: float | None = None,
) -> dict[str, np.ndarray]:
    """positions: (T, J, 3) metres, NaN where missing; observed: (T, J) bool; hermite: (T, J, 3)
    its cubic Hermite fill (evaluation/baselines.py), what a hole nothing matches keeps;
    library: (N, J, 3) other takes at the same fps and joints (MotionLibrary.frames), the take
    itself is always searched; fps: the take's, for MIN_HOLE_S (None: every hole is searched)
    -> {"match", "match_delta"}: (T, J, 3) each, observed tokens as given. A hole at the take's
    start or end (no data on one side), or shorter than MIN_HOLE_S, keeps the Hermite fill's answer."""
    T, J, _ = positions.shape
    x = np.where(observed[..., None], positions, np.nan).astype(np.float64)
    out = {name: hermite.astype(np.float64).copy() for name in FILLS}
    seen = observed.any(0)  # a joint never observed has nothing to match with
    sources = [x] + ([library] if library is not None and len(library) else [])
    for s, e in _runs(~observed[:, seen].all(1)):
        if s == 0 or e == T or (fps is not None and e - s < MIN_HOLE_S * fps):
            continue
        n = e - s
        missing = ~observed[s:e].all(0) & seen  # (J,) observed at s - 1 and e (the run is maximal)
        context = max(MIN_CONTEXT, int(round(CONTEXT_RATIO * n)))
        lo, hi = max(0, s - context), min(T, e + context)
        f_ctx = np.concatenate([_spread(np.arange(lo, s), FRAMES_PER_SIDE), _spread(np.arange(e, hi), FRAMES_PER_SIDE)])
        f_hole = _spread(np.arange(s, e), HOLE_FRAMES)
        frames = np.concatenate([np.repeat(f_ctx, J), np.repeat(f_hole, J)])
        joints = np.concatenate([np.tile(np.arange(J), len(f_ctx)), np.tile(np.arange(J), len(f_hole))])
        query = x[frames, joints]
        ok = np.isfinite(query).all(-1)  # other holes near this one: compare what is there
        frames, joints, query = frames[ok] - lo, joints[ok], query[ok]
        if len(query) < 3:
            continue
        width = hi - lo
        found = [
            (d, i, start, a, c)
            for i, lib in enumerate(sources)
            for d, start, a, c in _search(
                lib, frames, joints, query, missing, width, NEIGHBOURS, max(1, n // STRIDE_PER_HOLE)
            )
        ]
        found.sort(key=lambda f: f[0])
        chosen: list[tuple] = []
        for f in found:  # the best, then the best not overlapping it by half the hole, ...
            if all(f[1] != c[1] or abs(f[2] - c[2]) > n // 2 for c in chosen):
                chosen.append(f)
                if len(chosen) == NEIGHBOURS:
                    break
        if not chosen:
            continue
        # the neighbours turned and shifted onto the query: (K, width, J, 3)
        seg = np.stack([sources[i][start : start + width] for _, i, start, _, _ in chosen]).astype(np.float64)
        angle = np.array([a for *_, a, _ in chosen])
        cos, sin = np.cos(angle)[:, None, None], np.sin(angle)[:, None, None]
        centre = np.stack([c for *_, c in chosen])[:, None, None]  # (K, 1, 1, 2)
        xy = seg[..., :2] - centre
        xy = np.stack([cos * xy[..., 0] - sin * xy[..., 1], sin * xy[..., 0] + cos * xy[..., 1]], -1)
        seg[..., :2] = xy + query[:, :2].mean(0)
        weight = 1.0 / (np.array([d for d, *_ in chosen]) + 1e-8)
        weight = torch.from_numpy(weight / weight.sum())[:, None, None, None]  # (K, 1, 1, 1)

        window = torch.from_numpy(np.broadcast_to(x[lo:hi], seg.shape).copy())  # (K, width, J, 3)
        obs = torch.from_numpy(np.broadcast_to(observed[lo:hi], seg.shape[:3]).copy())
        seg_t = torch.from_numpy(seg)
        # match: the residual to the data at observed tokens, interpolated over the hole (meets both ends)
        residual = lerp_infill(torch.where(obs[..., None], window - seg_t, torch.nan), obs)
        match = ((seg_t + residual) * weight).sum(0).numpy()
        # match_delta: the Hermite fill plus each neighbour's departure from its own Hermite fill
        own = hermite_infill(torch.where(obs[..., None], seg_t, torch.nan), obs)
        delta = ((seg_t - own) * weight).sum(0).numpy() + hermite[lo:hi]
        hole = np.zeros((width, J), dtype=bool)
        hole[s - lo : e - lo] = ~observed[s:e] & missing
        out["match"][lo:hi][hole] = match[hole]
        out["match_delta"][lo:hi][hole] = delta[hole]
    return {name: np.where(observed[..., None], positions, fill) for name, fill in out.items()}
