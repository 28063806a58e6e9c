"""Depth cameras' body IDs as people: a person whose tracking was lost and found again gets a new
ID from the camera; read as one person, not two halves. Two people seen at once stay two.

Bodies are taken in the order they appear; one continues another when it starts after the other
ends, within MAX_GAP_S, with its root (the layout's joint 0: the pelvis) where the other's could
have got to by then (MAX_JUMP_M, plus MAX_SPEED_M_S for each second of the gap).
"""

from __future__ import annotations

import numpy as np

MAX_GAP_S = 1.0
MAX_JUMP_M = 0.3
MAX_SPEED_M_S = 2.0  # a brisk walk


def one_person_chains(root: np.ndarray, fps: float) -> list[list[int]]:
    """root: (P, N, 3) metres, NaN where body p is not seen -> the bodies as people: lists of body
    indices, each list one person in time order."""
    seen = np.isfinite(root).all(-1)  # (P, N)
    first = [int(np.argmax(s)) if s.any() else len(s) for s in seen]
    last = [int(len(s) - 1 - np.argmax(s[::-1])) if s.any() else -1 for s in seen]
    chains: list[list[int]] = []
    for q in sorted(range(len(root)), key=lambda p: first[p]):
        best, best_distance = None, np.inf
        for chain in chains:
            p = chain[-1]
            gap_s = (first[q] - last[p]) / fps
            if not 0 < gap_s <= MAX_GAP_S:
                continue
            distance = float(np.linalg.norm(root[q, first[q]] - root[p, last[p]]))
            if distance <= MAX_JUMP_M + MAX_SPEED_M_S * gap_s and distance < best_distance:
                best, best_distance = chain, distance
        if best is None:
            chains.append([q])
        else:
            best.append(q)
    return chains


def merged(arrays: np.ndarray, chains: list[list[int]], seen: np.ndarray) -> np.ndarray:
    """arrays: (P, N, ...) per body, seen (P, N) -> (len(chains), N, ...) per person."""
    out = np.stack([arrays[chain[0]] for chain in chains])
    for k, chain in enumerate(chains):
        for p in chain[1:]:
            out[k][seen[p]] = arrays[p][seen[p]]
    return out
