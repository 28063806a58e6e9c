"""Where motion matching looks in a long library: an index of its frames by the pose at a
hole's edges, and by the body a limb's hole leaves.

Scoring every stretch of a library against a hole's query reads all of it for every hole: ten
minutes of takes, six copies each (mirrored, three tempos), J joints times five sums per frame
(a proxy of the query over every start, then the whole query around its best places). That was
most of `fix`'s time on a folder (issue 47). Here each library frame is described once, by
DIMS numbers each (a PCA of the library's frames):
- for a hole's edges (side -1: the frame before a hole, +1: after it): its pose and the poses
  AWAY frames further from the hole, all seen from its own heading and centre;
- for a frame inside a limb's hole (side 0): its pose seen from its torso (the joints no limb's
  hole takes), compared over the joints the take has there (the PCA basis's rows of those).
A hole's places are the stretches whose descriptions at its edges (and middle frame) are nearest
the take's, one matrix-vector product over the library per description (N x DIMS numbers);
motion matching ranks them by the proxy and scores the whole query, exactly, around the best
(motion_matching._search). The heading and centre of one frame stand in for the stretch's best
turn and shift about z, which the whole query finds afterwards.

A frame's heading is its left-right axis (the sum over joint pairs of left minus right, in x, y;
the pairs the library is mirrored by; the torso's pairs inside a hole), so the index exists only
for a library whose skeleton's sides pair up, and looks inside a hole only where the torso holds a
pair; a hole's search without it scores the library by the proxy, as before.
"""

from __future__ import annotations

import numpy as np

DIMS = 16  # PCA coordinates per frame and description (of 3 J 3 numbers at an edge, J 3 inside)
AWAY = (2, 4)  # the other frames described with each edge frame, this many frames away from the hole
FIT_ROWS = 4096  # frames the PCA is fitted on (evenly spread): the library's poses, not all of them
CHUNK = 8192  # frames described at once (memory: CHUNK x 7 J 3 float32)
INSIDE_KEPT = 8  # sets of joints a frame inside a hole has whose library side is kept (N float32 each)


def edge_features(
    here: np.ndarray, theres: list[np.ndarray], pairs: np.ndarray, centre: np.ndarray | None = None
) -> np.ndarray:
    """here: (M, J, 3) metres, NaN where missing; theres: each (M, J, 3), each frame's neighbours
    (before it, or after it); pairs: (P, 2) joints (left, right); centre: the joints whose mean
    x, y is the frame's centre (None: all) -> (M, J 3 (1 + len(theres))) float32: the frame's pose
    and its neighbours', all turned so that the frame's left-right axis (the pairs' left minus
    right, summed) is +x and shifted so that its centre is at x, y = 0 (z as it is); NaN where a
    joint is missing."""
    across = (here[:, pairs[:, 0], :2] - here[:, pairs[:, 1], :2]).sum(1)  # (M, 2)
    across /= np.maximum(np.linalg.norm(across, axis=-1, keepdims=True), 1e-9)
    cos, sin = across[:, 0, None], across[:, 1, None]  # (M, 1): the turn taking it to +x
    middle = here if centre is None else here[:, centre]
    cx, cy = middle[..., 0].mean(1, keepdims=True), middle[..., 1].mean(1, keepdims=True)  # (M, 1)

    def seen(pose: np.ndarray) -> np.ndarray:  # (M, J, 3) -> (M, J 3)
        x, y = pose[..., 0] - cx, pose[..., 1] - cy
        return np.stack([cos * x + sin * y, cos * y - sin * x, pose[..., 2]], -1).reshape(len(pose), -1)

    return np.concatenate([seen(here)] + [seen(there) for there in theres], 1).astype(np.float32)


class MotionIndex:
    """A library's frames described for each edge of a hole (the frame before it, side -1: its
    pose and those AWAY frames before it; the frame after it, side +1) and for a frame inside a
    limb's hole (side 0: its pose alone, seen from its torso, which such a hole leaves). Made with
    a library at one search rate (MotionLibrary.frames), built at the first hole that asks (a
    short library is scored whole and never asks), read by every hole's search after that.
    x, y, z, missing: (J, N) the library's coordinates as motion matching keeps them (shifted over
    the floor or not: each frame is described about its own centre); mirror: each joint's partner;
    torso: the joints no limb's hole takes (None: no description from inside a hole)."""

    def __init__(
        self,
        x: np.ndarray,
        y: np.ndarray,
        z: np.ndarray,
        missing: np.ndarray,
        mirror: list[int],
        torso: list[int] | None = None,
    ):
        self.coordinates = (x, y, z, missing)
        self.pairs = np.array([(j, m) for j, m in enumerate(mirror) if j < m], dtype=np.int64)  # (P, 2)
        inside = [] if torso is None else [(j, m) for j, m in self.pairs.tolist() if j in torso and m in torso]
        self.torso = np.array(torso if inside else [], dtype=np.int64)  # (K,) with a left-right pair in it
        self.torso_pairs = np.array(inside, dtype=np.int64).reshape(-1, 2)
        self.described: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}
        self._inside: dict[bytes, np.ndarray] = {}  # the joints a hole's frame has -> |B_seen c|^2 (N,)

    @property
    def sees_inside(self) -> bool:
        """Whether a frame inside a limb's hole can be looked up (distances_inside)."""
        return len(self.torso) > 0

    def _frames(self, a: int, b: int, every: int = 1) -> np.ndarray:
        """Every `every`-th frame of [a, b), those outside the library NaN -> (M, J, 3) float32,
        NaN where missing."""
        x, y, z, missing = self.coordinates
        at = np.arange(a, b, every)
        inside = (at >= 0) & (at < x.shape[1])
        i = np.clip(at, 0, x.shape[1] - 1)
        out = np.stack([x[:, i].T, y[:, i].T, z[:, i].T], -1)
        out[(missing[:, i].T > 0) | ~inside[:, None]] = np.nan
        return out

    def _described(self, a: int, b: int, every: int = 1) -> dict[int, np.ndarray]:
        """side -> (M, features) the descriptions of every `every`-th frame of [a, b)."""
        here = self._frames(a, b, every)
        out = {
            side: edge_features(here, [self._frames(a + side * k, b + side * k, every) for k in AWAY], self.pairs)
            for side in (-1, 1)
        }
        if self.sees_inside:
            out[0] = edge_features(here, [], self.torso_pairs, self.torso)
        return out

    def _built(self) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """side -> (mean (F,), basis (F, D) orthonormal columns, coordinates (N, D) float32, their
        squared norms (N,) float32, inf where not whole)."""
        if not self.described:
            N = self.coordinates[0].shape[1]
            # the PCA of FIT_ROWS frames evenly spread over the library (from their covariance)
            fitted = {}
            for side, sample in self._described(0, N, max(1, N // FIT_ROWS)).items():
                sample = sample[np.isfinite(sample).all(1)].astype(np.float64)
                mean = sample.mean(0) if len(sample) else np.zeros(sample.shape[1])
                _, vectors = np.linalg.eigh((sample - mean).T @ (sample - mean))
                fitted[side] = (mean, vectors[:, ::-1][:, :DIMS])  # (F,), (F, D): the largest first
            coords = {side: np.zeros((N, basis.shape[1]), np.float32) for side, (_, basis) in fitted.items()}
            norms = {side: np.full(N, np.inf, np.float32) for side in fitted}
            for a in range(0, N, CHUNK):
                b = min(N, a + CHUNK)
                for side, rows in self._described(a, b).items():
                    mean, basis = fitted[side]
                    whole = np.isfinite(rows).all(1)
                    at = (np.where(whole[:, None], rows, 0.0) - mean.astype(np.float32)) @ basis.astype(np.float32)
                    coords[side][a:b] = np.where(whole[:, None], at, 0.0)
                    norms[side][a:b] = np.where(whole, (at**2).sum(1), np.inf)
            self.described = {side: (*fitted[side], coords[side], norms[side]) for side in fitted}
        return self.described

    def distances(self, take: np.ndarray, frame: int, side: int) -> np.ndarray | None:
        """take: (T, J, 3) the hole's take at the library's rate, its other holes filled (the
        frames AWAY from an edge may be in one; those beyond the take's ends are its first or last
        frame); frame: an edge of a hole (the frame before it, side -1; the frame after it, side
        +1) -> (N,) the squared distance of each library frame's description to the take's there
        (inf where not whole), or None where the take's frames there are not whole."""
        at = np.clip([frame] + [frame + side * k for k in AWAY], 0, len(take) - 1)
        if not np.isfinite(take[at]).all():
            return None
        mean, basis, coords, norms = self._built()[side]
        q = edge_features(take[at[:1]], [take[[f]] for f in at[1:]], self.pairs)[0].astype(np.float64)
        q = ((q - mean) @ basis).astype(np.float32)
        d = coords @ q  # (N,), in place from here: norms - 2 c.q + q.q, one array of N, not three
        d *= -2
        d += norms
        d += q @ q
        return d

    def distances_inside(self, pose: np.ndarray) -> np.ndarray | None:
        """pose: (J, 3) a frame inside a limb's hole, NaN at its missing joints -> (N,) about the
        squared distance of each library frame's pose to it over the joints it has (from the
        descriptions: |B_seen (c - c_q)|^2 with B_seen the basis's rows of those joints), inf
        where not whole, or None without a torso or where the frame's torso is not whole."""
        if not self.sees_inside or not np.isfinite(pose[self.torso]).all():
            return None
        mean, basis, coords, norms = self._built()[0]
        q = edge_features(pose[None], [], self.torso_pairs, self.torso)[0].astype(np.float64) - mean
        seen = np.isfinite(q)
        part, q = basis[seen], q[seen]  # (F', D), (F',)
        key = seen.tobytes()  # the library's side of it (|B_seen c|^2 per frame) is the same for every
        if key not in self._inside:  # hole of the same joints: one limb's holes ask for one
            if len(self._inside) >= INSIDE_KEPT:
                self._inside.pop(next(iter(self._inside)))
            metric = (part.T @ part).astype(np.float32)  # (D, D)
            squared = ((coords @ metric) * coords) @ np.ones(coords.shape[1], np.float32)  # (N,)
            self._inside[key] = np.where(np.isfinite(norms), squared, np.inf)
        d = coords @ (part.T @ q).astype(np.float32)  # in place from here, as in distances
        d *= -2
        d += self._inside[key]
        d += q @ q
        return d
