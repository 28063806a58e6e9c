"""Motion matching: fill a hole with how the body moved at the moments of the recording that
look most like the hole's surroundings.

A cubic through the hole's ends knows nothing of how people move: over 0.9 s of a walk it draws
the swinging foot as a smooth arc between two poses. The recording usually holds the same motion
elsewhere (the next steps of the walk, the same performer's other takes), and a folder of takes
holds much of it. For each hole this finds the stretches of the library whose frames around
the hole (every joint in the context frames; the joints still observed inside the hole) match
best after a turn about the vertical and a shift over the floor (2D Procrustes, closed form),
and fills the hole from the NEIGHBOURS best, weighted by how well each matched. Two fills come
out of one search (the recording's policy picks per kind of hole, policy.py):
- "match": the neighbours' own motion, its residual to the data at the hole's observed tokens
  interpolated across the hole (as fix anchors the model's estimate), so it meets both ends;
- "match_delta": the cubic Hermite fill plus how far each neighbour's motion departs from its own
  Hermite fill (the same hole cut into it): a correction to the interpolation, which shrinks
  to the interpolation where the neighbours disagree.
Library takes are searched as recorded, mirrored and at other tempos (TEMPOS): the take's own
stretches every one (the distance of every stretch is a few correlations: _correlate), a long
library's around the places its frame index finds (motion_index.py; without one, around the best
places of a proxy of the query). On CMU subjects 35-39
(the PFNN capture: 4 full-body holes in each of 32 takes, the folder's other takes searched)
the 0.5 / 0.9-s holes came out 10.1 / 63.8 mm for "match" against the cubic spline's
25.7 / 200.5; on the CMU strangers with the same performers' other takes, "match_delta" wins
(docs/results.md, "Motion matching"). The settings below were chosen on CMU 35-39, never on
the stranger benchmark's takes.
Classical in the sense of the test tables: no training, nothing learned beyond the recording.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from scipy.ndimage import minimum_filter1d

from mocapfix.core.skeleton import Skeleton
from mocapfix.data.augment import mirror_of, mirrored
from mocapfix.fills.classical import Classical, hermite_infill, lerp_infill
from mocapfix.fills.fill import Fill
from mocapfix.fills.holes import runs
from mocapfix.fills.motion_index import MotionIndex

FILLS = ("match", "match_delta")
# Context each side of a hole, as a fraction of its length (at least MIN_CONTEXT frames): on CMU
# 35-39 a quarter of the hole beat a half and the whole hole's length (10.7 / 11.4 / 13.8 mm at 0.5 s).
CONTEXT_RATIO = 0.25
MIN_CONTEXT = 2
FRAMES_PER_SIDE = 8  # context frames compared (evenly spread; 16 gave the same)
HOLE_FRAMES = 8  # hole frames whose observed joints are compared (a limb hole: the rest of the body)
NEIGHBOURS = 16  # stretches averaged (4: 13.5 mm, 16: 10.7, 32: 11.4 at 0.5 s)
# Starts every hole/STRIDE_PER_HOLE frames are scored (at least 1), then every start around the
# best of them: a stretch a frame later is nearly the same stretch, and the search is the cost.
STRIDE_PER_HOLE = 16
# A long source (the library) is scored on the grid first by a proxy of the query (_proxy_frames:
# 5 frames in one phase of the grid, against up to 24 in up to `step` phases), and by the whole
# query only around the PROXY_BASINS best places the proxy finds, half a hole either side of each
# (bench/match_search.py: what it changes).
PROXY_BASINS = 64
# A library with an index (motion_index.py: where its skeleton's sides pair up) is looked up by the
# frames at the hole's two edges (and, for a limb's hole, the body it leaves at its middle frame):
# the INDEX_PLACES stretches lowest there within half a hole of them are ranked by the proxy, and
# the whole query scores every start within INDEX_NEAR frames of the INDEX_KEPT best. On Bandai
# (bench/match_search.py: 40 takes, 10 minutes of takes searched) `match_delta` came out within
# 0.7 mm of scoring every start in 11 of 12 cells (arms 0.9 s +2.8) at 0.65x the proxy's CPU;
# the edges alone and 64 places lost 0.8-1.7 mm on the legs' holes; 1,024 places gained up to
# 0.45 mm for 1.5x the CPU, INDEX_NEAR 4 0.6 mm on arms 0.9 s, 128 kept nothing.
INDEX_PLACES = 512
INDEX_KEPT = 64
INDEX_NEAR = 2
INSIDE_WEIGHT = 2.0  # a limb hole's middle frame against its two edges' (3 frames each) descriptions
WHOLE_KEPT = 8  # joint sets a source keeps its frames' wholeness for (_Coordinates.whole_before)
CHUNK = 16384  # starts scored at once (memory: CHUNK x 10 sums x the query's frames)
LIBRARY_S = 600.0  # the most seconds of takes a library keeps (each hole's search scans them all)
# The search reads a take and the library at about this rate (every search_step-th frame of the
# take; the library resampled), whatever the take's own: the neighbours' mean motion is then
# interpolated back to the take's frames, where the fills meet the data. Motion varies little
# between 30-fps frames over the 0.2 s and more a hole must last to be searched, and a 120-fps
# take searched at its own rate holds four times the library's frames in memory and in every
# product (LIBRARY_S of takes, six copies each: ~180 MB at 120 fps). On the CMU strangers (120
# fps) the searched `match_delta` cells came out lower than searching every frame, at 0.55x the
# CPU. The price: a neighbour meets the hole within 1/60 s of its own timing, so an exact copy of
# a 120-fps take fills its hole a few millimetres off, not exactly (5.8 mm on a CMU walk).
# Moving each neighbour to the take's own frame (its stretch shifted by fractions of a searched
# frame on the cubic) got that to 1.7 mm but changed no CMU cell by more than 0.3 mm, for a
# third more CPU: not done.
SEARCH_FPS = 30.0
# Holes shorter than this keep the Hermite fill: at 0.1 s the cubic is as good (CMU strangers:
# 3.1 mm, match_delta 3.2, match 4.1), and a take with many dropped frames would search once each.
MIN_HOLE_S = 0.2


def search_step(fps: float) -> int:
    """Take frames per searched frame at `fps` (SEARCH_FPS): 1 at 24-44 fps, 4 at 120."""
    return max(1, round(fps / SEARCH_FPS))


class _Coordinates(NamedTuple):
    """A source's frames as the search reads them, each (J, N) float32: x, y, z metres (x and y
    about their mean, `middle`: the search is blind to a shift over the floor, and float32 keeps
    a micrometre within metres of the origin, not 100 km out) and squared (x^2 + y^2 + z^2), 0 where
    missing, and missing (1.0 where missing, else 0; exact for counts of points). Made once per
    source, read by every hole's search. float32 halves the library's memory and the bytes each
    product reads (the products are memory-bound); a distance's rounding is ~1e-6 of the
    stretch's spread, far below the differences between neighbours (bench/match_search.py).
    Joints first: the search's products are (outputs, J) @ (J, N), which BLAS runs several times
    faster than (N, J) @ (J, outputs) for a few dozen outputs."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    squared: np.ndarray
    missing: np.ndarray
    middle: np.ndarray  # (2,) float64: the x, y taken off
    # (5, N, J) float32: x, y, z, squared, missing again (_SUMS's order), frame by frame: what _sums_at
    # gathers (a start's frames are a few contiguous rows here, against J scattered reads joints
    # first: 1.3-2.5x faster per call; a sum's own rows, not all five interleaved, gather straight
    # into the (M, U, J) its product reads: 23 % less than a gather and a transposing copy), for a
    # copy of the source's memory
    by_frame: np.ndarray
    # need (a (J,) bool's bytes) -> whole_before(need), for WHOLE_KEPT joint sets: a hole's search
    # asks for one of a few (a part's joints), and each was a pass over the library per hole
    whole: dict

    def whole_before(self, need: np.ndarray) -> np.ndarray:
        """need: (J,) bool -> (N + 1,) the count of frames holding every joint of `need` among the
        first n: a stretch [a, b) holds them all where whole[b] - whole[a] == b - a."""
        key = need.tobytes()
        if key not in self.whole:
            if len(self.whole) >= WHOLE_KEPT:
                self.whole.pop(next(iter(self.whole)))
            held = ~self.missing[need].any(0)
            self.whole[key] = np.concatenate([np.zeros(1, np.int32), np.cumsum(held, dtype=np.int32)])
        return self.whole[key]


def _coordinates(frames: np.ndarray) -> _Coordinates:
    """frames: (N, J, 3) metres, NaN where missing."""
    frames = np.asarray(frames, dtype=np.float64)
    missing = ~np.isfinite(frames).all(-1)  # (N, J)
    c = np.where(missing[..., None], 0.0, frames)  # (N, J, 3)
    middle = c[..., :2].sum((0, 1)) / max(1, (~missing).sum())
    # Made frame by frame, (N, J) each, as by_frame holds them (stacked from the joints-first
    # arrays' transposes, np.stack kept their joints-first layout: each frame's row of by_frame
    # was J values N apart, and every gather of a row read J cache lines), then transposed.
    frame_major = {
        "x": np.where(missing, 0.0, c[..., 0] - middle[0]).astype(np.float32),
        "y": np.where(missing, 0.0, c[..., 1] - middle[1]).astype(np.float32),
        "z": c[..., 2].astype(np.float32),
        "missing": missing.astype(np.float32),
    }
    frame_major["squared"] = frame_major["x"] ** 2 + frame_major["y"] ** 2 + frame_major["z"] ** 2
    by_frame = np.stack([frame_major[name] for name, _, _ in _SUMS])  # _SUMS's order
    named = {name: np.ascontiguousarray(v.T) for name, v in frame_major.items()}  # (J, N) each
    return _Coordinates(**named, middle=middle, by_frame=by_frame, whole={})


# Each library take is also searched mirrored (left and right swapped: a left leg's hole finds
# the right leg's steps) and played 0.85x and 1.15x as fast (people walk at other paces than
# the library's): on CMU 35-39, full-body 0.9-s holes 162.5 -> 145.0 mm (match_delta), 0.9-s leg
# holes 227.9 -> 195.8, for 6x the frames searched.
TEMPOS = (1.0, 0.85, 1.15)


class Searchable(NamedTuple):
    """Frames a hole's search reads, as their coordinates (made once, read by every hole; the
    frames themselves are not kept beside them: a library holds minutes of takes six times over),
    a span of frames never matched (first, end): a take hidden from its own search, and the joint
    partners its takes were mirrored by (MotionLibrary.mirror): the take being fixed is searched
    mirrored too, and a library's index (motion_index.py), None where it has none."""

    coordinates: _Coordinates
    hidden: tuple[int, int] = (0, 0)
    mirror: list[int] | None = None
    index: MotionIndex | None = None

    @property
    def num_frames(self) -> int:
        return self.coordinates.x.shape[1]

    def stretch(self, start: int, width: int, joints: np.ndarray | None = None) -> np.ndarray:
        """Frames [start, start + width) of `joints` (None: all) -> (width, J', 3) metres, float64,
        NaN where missing."""
        c, rows = self.coordinates, slice(None) if joints is None else joints
        out = np.stack([v[rows, start : start + width].T for v in (c.x, c.y, c.z)], axis=-1).astype(np.float64)
        out[..., :2] += c.middle
        out[c.missing[rows, start : start + width].T > 0] = np.nan
        return out


def searchable(frames: np.ndarray) -> Searchable:
    """frames: (N, J, 3) metres, NaN where missing."""
    return Searchable(_coordinates(frames))


class MotionLibrary:
    """Takes to match holes against, at one skeleton's joints: (T, J, 3) arrays in metres (NaN =
    missing) with their fps and a key each (a take of the recording being fixed is left out of
    its own search by key: its own data is searched as it is, holes and all). Over LIBRARY_S,
    the first takes that fit are kept. mirror: each joint's partner (mirror_of), to search each
    take's mirror image too; None: not mirrored."""

    def __init__(
        self,
        takes: list[tuple[np.ndarray, float]],
        keys: list | None = None,
        mirror=None,
        torso: list[int] | None = None,
    ):
        keys = list(range(len(takes))) if keys is None else list(keys)
        seconds = np.array([len(x) / fps for x, fps in takes])
        keep = np.arange(len(takes))
        if seconds.sum() > LIBRARY_S:  # whole takes, in order, until the budget is spent
            keep = keep[np.cumsum(seconds) <= LIBRARY_S]
        self.takes = [(takes[i][0].astype(np.float32), float(takes[i][1])) for i in keep]
        self.keys = [keys[i] for i in keep]
        self.mirror = None if mirror is None else list(mirror)
        self.torso = None if torso is None else list(torso)
        self._at: dict[float, tuple[Searchable, list[tuple[int, int]]]] = {}

    def __getstate__(self) -> dict:
        # a worker (fix --jobs) makes the searched frames again on first use: pickled, they
        # would copy six times the takes into every job
        return {**self.__dict__, "_at": {}}

    def including(self, takes: list[tuple[np.ndarray, float]], keys: list) -> MotionLibrary:
        """A library of `takes` (those of its keys it does not hold yet) and then this one's (the
        budget keeps the new ones first: the recording being fixed before the user's other takes)."""
        new = [(t, k) for t, k in zip(takes, keys) if k not in self.keys]
        if not new:
            return self
        return MotionLibrary([t for t, _ in new] + self.takes, [k for _, k in new] + self.keys, self.mirror, self.torso)

    def frames(self, fps: float) -> tuple[Searchable, list[tuple[int, int]]]:
        """Every take at `fps` (then its mirror image, each at every tempo of TEMPOS), one after
        another with a NaN frame between them (no stretch spans two) -> the frames and each
        take's (first, end) frame, its copies included."""
        # fills/ sits below fix/: imported here until resampling in time moves down to core/ (issue 46)
        from mocapfix.core.resample import resample_frames

        if fps not in self._at:
            parts, spans, n = [], [], 0
            for x, f in self.takes:
                first = n
                for copy in [x] + ([mirrored(x, self.mirror)] if self.mirror is not None else []):
                    for tempo in TEMPOS:  # played `tempo` times as fast: as if recorded at f * tempo
                        inside = int(np.floor((len(x) - 1) * fps / (f * tempo) + 1e-6)) + 1  # instants within the take
                        y = copy if f * tempo == fps else resample_frames(copy, f * tempo, fps, inside)
                        parts += [y, np.full((1, *x.shape[1:]), np.nan, np.float32)]
                        n += len(y) + 1
                spans.append((first, n - 1))
            frames = np.concatenate(parts) if parts else np.zeros((0, 0, 3), np.float32)
            library = searchable(frames)
            c, pairs = library.coordinates, self.mirror is not None and any(j != m for j, m in enumerate(self.mirror))
            index = MotionIndex(c.x, c.y, c.z, c.missing, self.mirror, self.torso) if pairs else None
            self._at[fps] = (library._replace(mirror=self.mirror, index=index), spans)
        return self._at[fps]

    def without(self, key, fps: float) -> Searchable:
        """The library as a take at `fps` searches it (at fps / search_step(fps)), with the take of
        `key` (if it holds one) and its copies hidden."""
        library, spans = self.frames(fps / search_step(fps))
        if key not in self.keys:
            return library
        return library._replace(hidden=spans[self.keys.index(key)])


def library_of(
    takes: list[tuple[np.ndarray, float]], keys: list, skeleton: Skeleton, library: MotionLibrary | None = None
) -> MotionLibrary:
    """A library of these takes (x (T, J, 3) at the skeleton's joints, fps) first, then `library`'s
    (the run's other files, fix --library), mirrored where the skeleton's sides pair up."""
    if library is not None:
        return library.including(takes, keys)
    return MotionLibrary(takes, keys, mirror_of(skeleton), torso_of(skeleton))


def torso_of(skeleton: Skeleton) -> list[int]:
    """The joints in none of the skeleton's limb groups (the root, spine, head, shoulders): what a
    hole of one limb leaves, for the library's index to look inside such holes by."""
    limbs = {j for members in skeleton.groups.values() for j in members}
    return [j for j in range(skeleton.num_joints) if j not in limbs]


class MotionMatching(Fill):
    """Motion matching as a Fill: "match" and "match_delta" from one search of `library`'s takes
    besides the one of `key` (MotionLibrary.without: a take is searched as it is, holes and all;
    None: the take itself only)."""

    names = FILLS

    def __init__(self, library: MotionLibrary | None, key=None):
        self.library, self.key = library, key

    def fill(self, positions, observed, fps, skeleton, asked=None, shared=None) -> dict[str, torch.Tensor]:
        searched = None if self.library is None else self.library.without(self.key, fps)
        # (B, T, J, 3): what a hole nothing matches keeps, and match_delta's base; asked for a
        # few holes (the policy's cut ones), made on crops around them as the classical fills are
        hermite = Classical("hermite").fill(positions, observed, fps, skeleton, asked, shared)["hermite"]
        asked = [None] * len(positions) if asked is None else asked.numpy()
        found = [
            match_fills(x.numpy(), o.numpy(), h.numpy(), searched, fps, a)
            for x, o, h, a in zip(positions, observed, hermite, asked)
        ]
        return {name: torch.stack([torch.from_numpy(f[name]) for f in found]) for name in FILLS}


def _spread(frames: np.ndarray, k: int) -> np.ndarray:
    """At most k of `frames`, evenly spread, first and last kept."""
    if len(frames) <= k:
        return frames
    return frames[np.round(np.linspace(0, len(frames) - 1, k)).astype(np.int64)]


class _Weights(NamedTuple):
    """A hole's query as weights on a source's coordinates: the query's points at each of U frame
    offsets of the stretch, summed per joint (J, U, outputs) for each of _correlate's sums."""

    offsets: np.ndarray  # (U,) frames from the stretch's start
    on_x: np.ndarray  # (J, U, 3): sum of x, its parts of the dot and cross products
    on_y: np.ndarray  # (J, U, 3): the same for y
    on_z: np.ndarray  # (J, U, 1): z times the query's z
    counted: np.ndarray  # (J, U, 1): points, on squared and (float32) missing
    query: np.ndarray  # (P, 3)


def _weights(frames: np.ndarray, joints: np.ndarray, query: np.ndarray, J: int) -> _Weights:
    q = query.astype(np.float64)
    q_xy = q[:, :2] - q[:, :2].mean(0)  # (P, 2)
    offsets, at = np.unique(frames, return_inverse=True)

    def summed(*values) -> np.ndarray:
        w = np.zeros((J, len(offsets), len(values)))
        for i, v in enumerate(values):
            np.add.at(w[..., i], (joints, at), v)
        return w

    # dot = sum x qx + y qy, cross = sum x qy - y qx (q centred: the stretch's centre drops out)
    on_x, on_y = summed(1.0, q_xy[:, 0], q_xy[:, 1]), summed(1.0, q_xy[:, 1], -q_xy[:, 0])
    return _Weights(offsets, on_x, on_y, summed(q[:, 2]), summed(1.0), q)


# Which of _correlate's sums each coordinate feeds, by its weights.
_SUMS = (
    ("x", "on_x", slice(0, 3)),
    ("y", "on_y", slice(3, 6)),
    ("z", "on_z", slice(6, 7)),
    ("squared", "counted", slice(7, 8)),
    ("missing", "counted", slice(8, 9)),
)


def _correlate(source: _Coordinates, w: _Weights, first: int, count: int, step: int) -> np.ndarray:
    """The sums of the stretches starting at first + step * i, i < count -> (count, 9): sx,
    dot x, cross x, sy, dot y, cross y, z qz, x^2 + y^2 + z^2, missing points.
    Each sum is a correlation over time (the points at one offset weigh one frame), so matrix
    products score every start without gathering (starts, P, 3) stretches; with step > 1 the
    offsets of one phase (offset % step) read every step-th frame, an exact score step times
    cheaper."""
    J = source.x.shape[0]
    sums = np.zeros((9, count))
    for phase in np.unique(w.offsets % step):
        us = np.flatnonzero(w.offsets % step == phase)
        shift = w.offsets[us] // step  # (V,) rows of this phase's frames after each start's
        for a in range(0, count, CHUNK):
            b = min(count, a + CHUNK)
            rows = slice(first + phase + step * a, first + phase + step * (b - 1 + shift[-1]) + 1, step)
            for name, weights, cols in _SUMS:
                values = getattr(source, name)[:, rows]  # (J, rows)
                on = getattr(w, weights)[:, us].astype(values.dtype, copy=False)  # (J, V, k), float32
                per_row = (on.reshape(J, -1).T @ values).reshape(len(us), on.shape[-1], -1)  # (V, k, rows)
                for v, sh in enumerate(shift):
                    sums[cols, a:b] += per_row[v, :, sh : sh + b - a]
    return sums.T


def _sums_at(source: _Coordinates, w: _Weights, starts: np.ndarray) -> np.ndarray:
    """_correlate's sums for any starts (M,) -> (M, 9), every offset's frames gathered at once:
    what refines a coarse search, a few hundred starts. In float64: the distances that rank the
    neighbours and weigh them are differences of sums thousands of times larger (a stretch and
    its copy elsewhere must come out ~0 apart, not float32's rounding of the sums)."""
    J, U = source.x.shape[0], len(w.offsets)
    sums, chunk = np.zeros((len(starts), 9)), max(1, CHUNK // U)
    # each sum's weights offset-major, as the gathered frames are: (U J, outputs)
    weights = {name: getattr(w, name).transpose(1, 0, 2).reshape(U * J, -1) for _, name, _ in _SUMS}
    for a in range(0, len(starts), chunk):
        rows = (starts[a : a + chunk, None] + w.offsets).reshape(-1)  # (M U,) frames, start-major
        M = len(rows) // U
        for k, (_, name, cols) in enumerate(_SUMS):
            # np.take of whole rows: a quarter faster than indexing with the (M, U) frames
            values = np.take(source.by_frame[k], rows, axis=0).astype(np.float64)  # (M U, J)
            sums[a : a + M, cols] += values.reshape(M, U * J) @ weights[name]
    return sums


def _search(
    source: Searchable,
    w: _Weights,
    need: np.ndarray,
    width: int,
    k: int,
    apart: int,
    step: int,
    proxy: _Weights | None = None,
    places: np.ndarray | None = None,
):
    """The k best stretches of `source` of `width` frames, their starts more than `apart` frames
    from each other -> list of (distance, start, angle, centre): distance the mean squared
    distance (m^2) between the query and the stretch's tokens at its points after the best turn
    about z and shift in x, y (angle and the stretch's x, y centre); need (J,) the joints the
    stretch must hold in every frame. Starts `step` frames apart are scored (float32 sums), then
    every start around the best of them (float64: the distances returned). proxy: the query at
    a few of its frames (_proxy_frames): on a long source the grid is scored by it first, and
    the full query scores only the grid's starts near the PROXY_BASINS best places it finds.
    places: (M,) starts of a long source its index found (_index_places): ranked by the proxy
    instead of the grid, the full query scoring every start near the INDEX_KEPT best."""
    N = source.num_frames - width + 1
    if N <= 0:
        return []
    whole = source.coordinates.whole_before(need)  # (N + width,)
    first, end = source.hidden

    def score(at: np.ndarray, sums: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, ...]:
        # at: (M,) starts, sums: (M, 9) theirs for `query` (P, 3) -> distances (M,) (inf: a
        # stretch missing a joint of `need`, or in the hidden span), angles (M,), centres (M, 2)
        P, q_xy = len(query), query[:, :2] - query[:, :2].mean(0)
        sx, dot_x, cross_x, sy, dot_y, cross_y, zq, squared, lost = sums.T
        dot, cross = dot_x + dot_y, cross_x + cross_y
        # min over the angle of |R (c - c_mean) - q|^2 = |c - c_mean|^2 + |q|^2 - 2 |(dot, cross)|,
        # in x, y; z as it is
        dist = squared - (sx**2 + sy**2) / P + (q_xy**2).sum() - 2 * np.hypot(dot, cross)
        dist += -2 * zq + (query[:, 2] ** 2).sum()
        dist[(lost > 0) | (whole[at + width] - whole[at] < width) | ((at < end) & (at + width > first))] = np.inf
        return np.maximum(dist, 0.0) / P, np.arctan2(cross, dot), np.stack([sx, sy], -1) / P

    middle = source.coordinates.middle  # the centres as Searchable.stretch gives the frames
    if places is not None:  # the index's: ranked by the proxy, every start near the best scored
        ranker = proxy if proxy is not None else w
        rough, _, _ = score(places, _sums_at(source.coordinates, ranker, places), ranker.query)
        best = places[_best_apart_of(places, rough, INDEX_KEPT, apart)]
        near = np.unique((best[:, None] + np.arange(-INDEX_NEAR, INDEX_NEAR + 1)).ravel())
        at = near[(near >= 0) & (near < N)]
        d, angle, centre = score(at, _sums_at(source.coordinates, w, at), w.query)
        if step > 1:  # every start around the best of them, as on the grid below
            picks = at[_best_apart_of(at, d, 2 * k, apart)]
            around = np.unique((picks[:, None] + np.arange(1 - step, step)).ravel())
            around = np.setdiff1d(around[(around >= 0) & (around < N)], at, assume_unique=True)
            more = score(around, _sums_at(source.coordinates, w, around), w.query)
            at, d, angle, centre = (np.concatenate(v) for v in zip((at, d, angle, centre), (around, *more)))
            order = np.argsort(at)
            at, d, angle, centre = at[order], d[order], angle[order], centre[order]
        return [(float(d[i]), int(at[i]), float(angle[i]), centre[i] + middle) for i in _best_apart_of(at, d, k, apart)]
    d = np.full(N, np.inf)
    angle, centre = np.zeros(N), np.zeros((N, 2))

    def into_d(at: np.ndarray, sums: np.ndarray) -> None:
        d[at], angle[at], centre[at] = score(at, sums, w.query)

    count = (N - 1) // step + 1
    grid = step * np.arange(count)
    if proxy is not None and _long(N, apart, step):
        rough = np.full(N, np.inf)
        rough[grid] = score(grid, _correlate(source.coordinates, proxy, 0, count, step), proxy.query)[0]
        places = np.array(_best_apart(rough, PROXY_BASINS, apart), dtype=np.int64)  # (B,) starts
        if not len(places):
            return []
        near = (places[:, None] + step * np.arange(-(apart // step), apart // step + 1)).ravel()
        grid = np.unique(near[(near >= 0) & (near < N)])
        into_d(grid, _sums_at(source.coordinates, w, grid))
    else:
        into_d(grid, _correlate(source.coordinates, w, 0, count, step))
    # every start around the best of them (with step 1 the best themselves), in float64 (_sums_at)
    picks = _best_apart(d, 2 * k, apart)
    if picks:
        near = np.unique(np.concatenate([np.arange(max(0, i - step + 1), min(N, i + step)) for i in picks]))
        into_d(near, _sums_at(source.coordinates, w, near))
    return [(float(d[i]), i, float(angle[i]), centre[i] + middle) for i in _best_apart(d, k, apart)]


def _long(starts: int, apart: int, step: int) -> bool:
    """Whether a source with this many starts is too long to score its whole grid (every `step`-th
    start) with the whole query: its places come from the index or the proxy first."""
    return (starts - 1) // step + 1 > 4 * PROXY_BASINS * max(1, apart // step)


def _index_places(
    source: Searchable,
    take: np.ndarray,
    filled: np.ndarray,
    hs: int,
    he: int,
    lo: int,
    width: int,
    apart: int,
    step: int,
) -> np.ndarray | None:
    """Where the search of a long `source` with an index (MotionIndex) looks: the starts of the
    INDEX_PLACES stretches whose frames at the hole's edges, and at its middle frame the joints a
    limb's hole leaves, are described most like the take's, each the lowest within `apart` of it
    (take: (Ts, J, 3) the searched frames, NaN where missing; filled: the same with its holes
    filled, which describes the frames near an edge; the hole [hs, he), its stretch from lo,
    `width` frames) -> (M,) sorted, or None: no index, a source the grid scores whole, or a joint
    missing at an edge (the proxy scores the grid then)."""
    N = source.num_frames - width + 1
    if source.index is None or not _long(N, apart, step):
        return None
    if not (np.isfinite(take[hs - 1]).all() and np.isfinite(take[he]).all()):
        return None
    before, after = source.index.distances(filled, hs - 1, -1), source.index.distances(filled, he, 1)
    if before is None or after is None:
        return None
    d = before[hs - 1 - lo : hs - 1 - lo + N]  # (N,) by the stretch's start; the arrays are this call's own
    d += after[he - lo : he - lo + N]
    mid = (hs + he) // 2
    inside = source.index.distances_inside(take[mid]) if np.isfinite(take[mid]).any() else None
    if inside is not None:  # a limb's hole: the body it leaves at its middle frame
        inside *= INSIDE_WEIGHT
        d += inside[mid - lo : mid - lo + N]
    first, end = source.hidden
    d[max(0, first - width + 1) : end] = np.inf
    # the lowest within `apart` of themselves, then the INDEX_PLACES lowest of those (picked one at
    # a time, _best_apart, hundreds of places cost a millisecond or more)
    lowest = np.flatnonzero((d == minimum_filter1d(d, 2 * apart + 1, mode="constant", cval=np.inf)) & np.isfinite(d))
    if len(lowest) > INDEX_PLACES:
        lowest = lowest[np.argpartition(d[lowest], INDEX_PLACES - 1)[:INDEX_PLACES]]
    return np.sort(lowest) if len(lowest) else None


def _best_apart(of: np.ndarray, n: int, apart: int) -> list[int]:
    """of: (N,) distances by start (inf: not a candidate) -> the starts of the n best, each more
    than `apart` from every better one picked before it (_best_apart_of)."""
    at = np.flatnonzero(np.isfinite(of))
    return at[_best_apart_of(at, of[at], n, apart)].tolist()


def _best_apart_of(starts: np.ndarray, of: np.ndarray, n: int, apart: int) -> np.ndarray:
    """starts: (M,) ascending, distinct; of: (M,) their distances (inf: not a candidate) -> the
    indices into starts of the n best, each more than `apart` frames from every better one picked
    before it: the lowest, then the lowest more than `apart` from it, ... (ties to the lower
    start). Each pick rules out at most 2 apart + 1 starts, so the picks are among the
    n (2 apart + 1) lowest: only those are sorted, not every start."""
    if n <= 0:
        return np.zeros(0, np.int64)
    pool = np.flatnonzero(np.isfinite(of))
    m = n * (2 * apart + 1)
    if len(pool) > m:
        edge = of[pool[np.argpartition(of[pool], m - 1)[:m]]].max()
        pool = pool[of[pool] <= edge]  # ties at the edge kept
    pool = pool[np.lexsort((pool, of[pool]))]
    out: list[int] = []
    blocked = np.zeros(len(starts), dtype=bool)
    for i in pool.tolist():
        if not blocked[i]:
            out.append(i)
            if len(out) == n:
                break
            lo, hi = np.searchsorted(starts, starts[i] - apart), np.searchsorted(starts, starts[i] + apart, "right")
            blocked[lo:hi] = True
    return np.array(out, dtype=np.int64)


def _proxy_frames(width: int, start: int, end: int, step: int) -> np.ndarray:
    """The few frames of a stretch (the hole is [start, end) of `width`) a long source's grid is
    scored by first: each side's outermost and innermost context frame and the hole's middle one,
    each moved to the nearest frame a whole number of steps from the last frame before the hole:
    all in one phase of the grid, so the scoring reads the source once (_correlate), not once per
    phase."""
    first = start - 1

    def snapped(f: int, lo: int, hi: int) -> list[int]:  # f moved onto the phase, kept in [lo, hi)
        g = first + step * round((f - first) / step)
        g += step * ((g < lo) - (g >= hi))
        return [g] if lo <= g < hi else []

    picked = snapped(0, 0, start) + snapped(first, 0, start) + snapped(end, end, width)
    picked += snapped(width - 1, end, width) + snapped((start + end) // 2, start, end)
    return np.unique(np.array(picked, dtype=np.int64))


def _upsampled(frames: np.ndarray, step: int) -> np.ndarray:
    """frames: (W, J, 3), every step-th frame of a stretch -> ((W - 1) step + 1, J, 3), the frames
    between them on a cubic through each frame at its central difference (Catmull-Rom: a linear
    one cuts the corners of a hand's arc by millimetres at 30 fps)."""
    if step == 1:
        return frames
    t = (np.arange(step) / step)[:, None, None, None]  # (step, 1, 1, 1)
    slope = np.gradient(frames, axis=0)  # (W, J, 3) per searched frame
    inner = (
        (2 * t**3 - 3 * t**2 + 1) * frames[:-1]
        + (t**3 - 2 * t**2 + t) * slope[:-1]
        + (3 * t**2 - 2 * t**3) * frames[1:]
        + (t**3 - t**2) * slope[1:]
    )  # (step, W - 1, J, 3)
    return np.concatenate([inner.transpose(1, 0, 2, 3).reshape(-1, *frames.shape[1:]), frames[-1:]])


def match_fills(
    positions: np.ndarray,
    observed: np.ndarray,
    hermite: np.ndarray,
    library: Searchable | np.ndarray | None = None,
    fps: float | None = None,
    asked: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """positions: (T, J, 3) metres, NaN where missing; observed: (T, J) bool; hermite: (T, J, 3)
    its cubic Hermite fill (fills/classical.py), what a hole nothing matches keeps;
    library: other takes at the same joints (MotionLibrary.without(key, fps): at this take's
    search rate; or (N, J, 3) frames at its fps), the take itself is always searched (mirrored too
    where the library's takes are); fps: the take's, for MIN_HOLE_S and the search's rate
    (SEARCH_FPS; None: every hole is searched, every frame); asked: (T, J) bool, the tokens whose
    fill is wanted (None: all) -> {"match", "match_delta"}: (T, J, 3) each, observed tokens as
    given. A hole at the take's start or end (no data on one side), shorter than MIN_HOLE_S, or
    with no token asked for, keeps the Hermite fill's answer."""
    T, J, _ = positions.shape
    x = np.where(observed[..., None], positions, np.nan).astype(np.float64)
    out = {name: hermite.astype(np.float64).copy() for name in FILLS}
    seen = observed.any(0)  # a joint never observed has nothing to match with
    step_in = 1 if fps is None else search_step(fps)  # take frames per searched frame
    if isinstance(library, np.ndarray):
        library = searchable(library[::step_in])
    mirror = None if library is None else library.mirror
    takes = [x] + ([mirrored(x, mirror)] if mirror is not None else [])
    sources: dict[int, list[Searchable]] = {}  # per phase of the take's searched frames, made at its first hole
    found_holes = []  # (s, e, a, cols, the neighbours' mean (b - a, J', 3)): filled together below
    for s, e in runs(~observed[:, seen].all(1)):
        if s == 0 or e == T or (fps is not None and e - s < MIN_HOLE_S * fps):
            continue
        if asked is not None and not asked[s:e].any():
            continue
        missing = ~observed[s:e].all(0) & seen  # (J,) observed at s - 1 and e (the run is maximal)
        # The hole on the searched frames: every step_in-th frame of the take, in the phase that
        # holds its observed frame before (s - 1); [hs, he) the hole there, he the first searched
        # frame at or after e.
        phase = (s - 1) % step_in
        xs = x[phase::step_in]  # (Ts, J, 3)
        hs, he = (s - 1 - phase) // step_in + 1, -(-(e - phase) // step_in)
        if he >= len(xs):
            continue  # no searched frame after the hole
        n = he - hs
        context = max(MIN_CONTEXT, int(round(CONTEXT_RATIO * n)))
        lo, hi = max(0, hs - context), min(len(xs), he + context)
        before, after = _spread(np.arange(lo, hs), FRAMES_PER_SIDE), _spread(np.arange(he, hi), FRAMES_PER_SIDE)
        f_ctx = np.concatenate([before, after])
        f_hole = _spread(np.arange(hs, he), HOLE_FRAMES)
        frames = np.concatenate([np.repeat(f_ctx, J), np.repeat(f_hole, J)])
        joints = np.concatenate([np.tile(np.arange(J), len(f_ctx)), np.tile(np.arange(J), len(f_hole))])
        query = xs[frames, joints]
        ok = np.isfinite(query).all(-1)  # other holes near this one: compare what is there
        frames, joints, query = frames[ok] - lo, joints[ok], query[ok]
        if len(query) < 3:
            continue
        width = hi - lo
        if phase not in sources:
            sources[phase] = [searchable(t[phase::step_in]) for t in takes]
            sources[phase] += [library] if library is not None and library.num_frames else []
        w = _weights(frames, joints, query, J)
        step = max(1, n // STRIDE_PER_HOLE)
        at = _proxy_frames(width, hs - lo, he - lo, step)
        few = xs[lo + at]  # (F, J, 3): every joint there that has data
        f_few, j_few = np.nonzero(np.isfinite(few).all(-1))
        proxy = _weights(at[f_few], j_few, few[f_few, j_few], J) if len(f_few) >= 3 else None
        # the best NEIGHBOURS of all sources, no two of a source within half the hole of each other
        found = [
            (d, i, start, a, c)
            for i, source in enumerate(sources[phase])
            for d, start, a, c in _search(
                source,
                w,
                missing,
                width,
                NEIGHBOURS,
                n // 2,
                step,
                proxy,
                _index_places(source, xs, hermite[phase::step_in], hs, he, lo, width, n // 2, step),
            )
        ]
        chosen = sorted(found, key=lambda f: f[0])[:NEIGHBOURS]
        if not chosen:
            continue
        # Both fills of a neighbour are linear in its frames (an interpolation between the same
        # observed tokens, per joint; the hole's joints are whole in every neighbour): the
        # weighted mean of the neighbours' fills is the fill of their weighted mean. It is made on
        # the take's own frames [a, a + len(mean)) (searched frame k is take frame phase + step_in
        # k: from lo's to hi - 1's), where the fills meet the data (_fill_found).
        a = phase + step_in * lo
        # only the hole's joints (each fill is per joint, and each of them is observed at both ends)
        cols = np.flatnonzero(missing)  # (J',)
        # (K, width, J', 3)
        seg = np.stack([sources[phase][i].stretch(start, width, cols) for _, i, start, *_ in chosen])
        angle = np.array([a for *_, a, _ in chosen])
        cos, sin = np.cos(angle)[:, None, None], np.sin(angle)[:, None, None]
        centre = np.stack([c for *_, c in chosen])[:, None, None]  # (K, 1, 1, 2)
        xy = seg[..., :2] - centre
        xy = np.stack([cos * xy[..., 0] - sin * xy[..., 1], sin * xy[..., 0] + cos * xy[..., 1]], -1)
        seg[..., :2] = xy + query[:, :2].mean(0)  # the neighbours turned and shifted onto the query
        weight = 1.0 / (np.array([d for d, *_ in chosen]) + 1e-8)
        mean = _upsampled(np.einsum("k,ktjc->tjc", weight / weight.sum(), seg), step_in)  # (b - a, J', 3)
        found_holes.append((s, e, a, cols, mean))
    if found_holes:
        _fill_found(found_holes, x, observed, hermite, out)
    return {name: np.where(observed[..., None], positions, fill) for name, fill in out.items()}


def _fill_found(
    holes: list[tuple[int, int, int, np.ndarray, np.ndarray]],
    x: np.ndarray,
    observed: np.ndarray,
    hermite: np.ndarray,
    out: dict[str, np.ndarray],
) -> None:
    """Each hole [s, e) its two fills from its neighbours' mean motion on the take's frames [a, a
    + n) at its joints cols (mean: (n, J', 3)), written into out's arrays (T, J, 3). Both fills are
    per joint: every hole's joints go through one Lerp and one Hermite call, a row each, padded
    at the end with unobserved frames. Those change no hole token's numbers (its ends are
    observed; past a row's last observed frame each fill holds that frame's value, as at the
    window's end): the same as one call per hole, in one call's time."""
    rows = sum(len(cols) for *_, cols, _ in holes)
    longest = max(len(mean) for *_, mean in holes)
    mean = np.zeros((rows, longest, 1, 3))  # (R, L, 1, 3): a hole's joint a row
    window = np.full((rows, longest, 1, 3), np.nan)
    obs = np.zeros((rows, longest, 1), bool)
    r = 0
    for _, _, a, cols, m in holes:
        k, n = len(cols), len(m)
        mean[r : r + k, :n, 0] = m.transpose(1, 0, 2)
        window[r : r + k, :n, 0] = x[a : a + n, cols].transpose(1, 0, 2)
        obs[r : r + k, :n, 0] = observed[a : a + n, cols].T
        r += k
    mean_t, window_t, obs_t = torch.from_numpy(mean), torch.from_numpy(window), torch.from_numpy(obs)
    # match: the residual to the data at observed tokens, interpolated over the hole (meets both ends)
    match = (mean_t + lerp_infill(torch.where(obs_t[..., None], window_t - mean_t, torch.nan), obs_t)).numpy()
    # match_delta: the Hermite fill plus the neighbours' departure from their own Hermite fill
    departure = (mean_t - hermite_infill(torch.where(obs_t[..., None], mean_t, torch.nan), obs_t)).numpy()
    r = 0
    for s, e, a, cols, _ in holes:
        k = len(cols)
        hole = ~observed[s:e, cols]  # (e - s, J') the hole's tokens
        filled = {
            "match": match[r : r + k, s - a : e - a, 0].transpose(1, 0, 2),
            "match_delta": departure[r : r + k, s - a : e - a, 0].transpose(1, 0, 2) + hermite[s:e, cols],
        }
        for name, f in filled.items():
            out[name][s:e, cols] = np.where(hole[..., None], f, out[name][s:e, cols])
        r += k
