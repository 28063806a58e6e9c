"""What a hole is, as a fill policy reads it: the body part it is in and its length; and holes cut
into a take where its data is, to measure the fills on (errors.py)."""

from __future__ import annotations

import numpy as np
import torch

from mocapfix.core.skeleton import Skeleton

PARTS = ("full", "arm", "leg")


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(T,) bool -> the [start, end) of each run of True."""
    edges = np.diff(np.concatenate([[0], np.asarray(mask).astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


def hole_frames(observed: torch.Tensor) -> torch.Tensor:
    """observed: (B, T, J) bool -> (B, T, J) long: for a missing token, the length in frames of the
    run of missing frames of its joint that it is in; 0 for observed tokens."""
    B, T, J = observed.shape
    t = torch.arange(T, device=observed.device).view(1, T, 1).expand(B, T, J)
    prev = torch.where(observed, t, -1).cummax(dim=1).values  # last observed at or before t
    nxt = torch.where(observed, t, T).flip(1).cummin(dim=1).values.flip(1)  # first observed at or after t
    return torch.where(observed, 0, nxt - prev - 1)


def token_parts(observed: torch.Tensor, skeleton: Skeleton) -> torch.Tensor:
    """observed: (B, T, J) -> (B, T, J) index into PARTS of the table a missing token is filled by:
    "full" in frames that miss at least half the joints (a body-wide hole), else the limb the joint
    belongs to (arm, leg), else "full"."""
    B, T, J = observed.shape
    limb = torch.zeros(J, dtype=torch.long, device=observed.device)
    for group, members in skeleton.groups.items():
        limb[list(members)] = PARTS.index(group.split("_")[-1])
    body_wide = (~observed).float().mean(dim=-1, keepdim=True) >= 0.5  # (B, T, 1)
    return torch.where(body_wide, 0, limb.view(1, 1, J).expand(B, T, J))


def token_cells(observed: torch.Tensor, fps: float, skeleton: Skeleton, gaps_s) -> tuple[torch.Tensor, torch.Tensor]:
    """observed: (B, T, J) -> ((B, T, J) index into PARTS of each token's hole's part, (B, T, J)
    index into gaps_s (ascending) of the measured gap nearest its hole's length)."""
    seconds = hole_frames(observed).float() / fps
    parts = token_parts(observed, skeleton)
    edges = torch.tensor([(a + b) / 2 for a, b in zip(gaps_s, gaps_s[1:])], device=observed.device)
    return parts, torch.bucketize(seconds.contiguous(), edges)


def token_choice(observed: torch.Tensor, fps: float, skeleton: Skeleton, gaps_s, table: torch.Tensor) -> torch.Tensor:
    """observed: (B, T, J) -> (B, T, J): table[part, gap] for each token, its cell (token_cells).
    The choice depends only on the (part, gap) cell: a lookup table, not a per-token loop."""
    return table.to(observed.device)[token_cells(observed, fps, skeleton, gaps_s)]


def hole_kinds(tracks: list[np.ndarray], skeleton, fps: float, gaps_s) -> set[tuple[str, float]]:
    """The (part, measured gap) cells the recording's holes fall in (as apply_fill_policy reads them)."""
    kinds = set()
    for x in tracks:
        observed = torch.from_numpy(np.isfinite(x).all(-1))[None]  # (1, K, J)
        if observed.all():
            continue
        seconds = hole_frames(observed).float() / fps
        parts = token_parts(observed, skeleton)
        for part, s in zip(parts[~observed].tolist(), seconds[~observed].tolist()):
            kinds.add((PARTS[part], min(gaps_s, key=lambda g: abs(g - s))))
    return kinds


def cut_holes(observed: np.ndarray, options: list[list[int]], frames: int, budget: int, margin: int = 1) -> np.ndarray:
    """observed: (T, J) bool -> (T, J) bool, up to `budget` holes of `frames` frames, spread over
    the take, each over the joints of one of `options` in turn (left and right alternate), only
    where those joints are observed for `margin` frames before and after the hole, margins
    included in no other cut hole (each has data at both ends, as the recording's own holes)."""
    T = len(observed)
    hidden = np.zeros_like(observed)
    taken = np.zeros(T, dtype=bool)  # frames in a cut hole
    valid = []
    for joints in options:
        seen = observed[:, joints].all(-1).astype(np.int64)
        run = np.convolve(seen, np.ones(frames + 2 * margin, dtype=np.int64), mode="valid")
        valid.append(np.nonzero(run == frames + 2 * margin)[0] + margin)  # hole starts
    for k in range(budget):
        starts = valid[k % len(options)]
        # the k-th hole of this option near its share of the take, the nearest free place
        want = (k // len(options) + 0.5) / -(-budget // len(options)) * T
        for s in starts[np.argsort(np.abs(starts - want))]:
            if not taken[s - margin : s + frames + margin].any():
                hidden[s : s + frames, options[k % len(options)]] = True
                taken[s : s + frames] = True
                break
    return hidden


def room_for_holes(observed: np.ndarray, options: list[list[int]], frames: int, margin: int = 1) -> int:
    """How many holes cut_holes could cut at most into a take: holes of `frames` frames over the
    joints of one of `options`, each with `margin` observed frames on both sides, apart by a margin
    (observed: (T, J) bool). Counted over every option's places at once (an upper bound where the
    options' places differ), greedily from the start: cheap enough to ask of every take."""
    places, width = [], frames + 2 * margin
    for joints in options:
        seen = np.concatenate([[0], np.cumsum(observed[:, joints].all(-1))])  # observed frames before each
        run = seen[width:] - seen[:-width]  # observed frames in each hole-and-margins stretch
        places.append(np.nonzero(run == width)[0] + margin)
    starts = np.unique(np.concatenate(places))  # sorted
    count, i = 0, 0
    while i < len(starts):  # one step per hole: the first start a margin past the last hole's end
        count += 1
        i = int(np.searchsorted(starts, starts[i] + frames + margin))
    return count


def share_holes(room: list[int], total: int) -> list[int]:
    """Each take's share of `total` holes: an equal share (rounded up) where the take has room for
    it, and what takes without room cannot cut given to those with room, evenly. room: room_for_holes
    per take. A folder of short takes crowded with their own holes still gets its total."""
    n = len(room)
    if n == 0:
        return []
    share = -(-total // n)
    budget = [min(share, r) for r in room]
    left = min(total, n * share) - sum(budget)
    while left > 0:
        open_ = [k for k in range(n) if budget[k] < room[k]]
        if not open_:
            break
        each = max(1, left // len(open_))
        for k in open_:
            give = min(each, room[k] - budget[k], left)
            budget[k] += give
            left -= give
            if left == 0:
                break
    return budget
