"""The fill policy measured on the recording being fixed, not only on the model's val split.

A model's val split shares performers, motions and the studio with its training split, so the
policy calibrated there (evaluation/policy.py) believes the model where it has learned a studio,
not human motion: a paper-sized XMAE trained on 70 CMU takes beat the classical fills on its val
split and was 2.5x worse than a cubic spline on other performers. The recording itself is the
only evidence about the recording: holes of the kinds it has (body part and length) are cut into
its own complete stretches (2 s in which every model joint is observed), the model and every
classical fill fill them as fix does, and the policy is the one those errors give (calibrate, as
training does on its val split). Where the recording has too few complete stretches to measure
on, the model has not earned its place there: the classical fills only, ranked by the val split.
The checkpoint's replace threshold (for --mode both) is kept: the recording's own observed tokens
include the jumps it is meant to find.
"""

from __future__ import annotations

import numpy as np
import torch

from mocapfix.evaluation.model_fills import calibrate
from mocapfix.evaluation.policy import PARTS, Calibration, FillPolicy, hole_frames, is_learned, token_parts

MAX_WINDOWS = 32  # the budget: complete stretches measured on per file (a model pass per kind of hole)
# Holes are cut into stretches of this length, and every fill is made as fix makes it (the model
# through its windows, blended and anchored; the classical fills from the stretch's context): in
# a 1-s window a 0.9-s hole leaves the classical fills 1.5 frames of context each side, so they
# lose there and win on a whole take (measured on CMU takes: the window-sized policy chose the
# model for 0.9-s arm holes, 15 mm worse than the limb fill; 2-s stretches chose the limb fill).
STRETCH_S = 2.0
MIN_WINDOWS = 4  # fewer: too little to measure the model on, the classical fills only


def complete_windows(tracks: list[np.ndarray], window: int, max_windows: int = MAX_WINDOWS) -> np.ndarray:
    """tracks: per clip (K, J, 3) at the model's fps, NaN = missing -> (N, window, J, 3) stretches
    in which every joint is observed, half a stretch apart, N <= max_windows spread evenly over all."""
    found = []
    for x in tracks:
        complete = np.isfinite(x).all(axis=(1, 2))  # (K,)
        run = np.convolve(complete.astype(np.int64), np.ones(window, dtype=np.int64), mode="valid")  # (K-W+1,)
        s = 0
        while s < len(run):
            if run[s] == window:
                found.append(x[s : s + window])
                s += max(1, window // 2)
            else:
                s += 1
    if len(found) > max_windows:
        found = [found[i] for i in np.linspace(0, len(found) - 1, max_windows).round().astype(int)]
    return np.stack(found) if found else np.zeros((0, window) + tracks[0].shape[1:], dtype=np.float32)


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


def measure_policy(
    fixer,
    tracks: list[np.ndarray],
    fallback: FillPolicy | None,
    model_fill,
    every_cell: bool = False,
    seed: int = 0,
) -> tuple[FillPolicy | None, str | None]:
    """The fill policy of this recording for a positions fixer (.skeleton, .fps); tracks: its clips
    at the model's joints and fps; model_fill(positions (N, L, J, 3), observed (N, L, J)) -> the
    model's fill as fix makes it. -> (policy, a line for the report).
    Only the kinds of hole the recording has are measured (every_cell: all, for --mode both,
    whose replaced tokens make holes of any kind); the others keep the fallback's choice. The
    classical fills only where fewer than MIN_WINDOWS complete stretches exist; nothing is
    measured for a checkpoint without a policy (its model fills every hole, as documented)."""
    if fallback is None:
        return None, None
    windows = complete_windows(tracks, int(round(STRETCH_S * fixer.fps)))
    gaps = tuple(fallback.gaps_s)
    if len(windows) < MIN_WINDOWS:  # the model has not earned its place here
        why = f"{len(windows)} complete {STRETCH_S:g}-s stretches, {MIN_WINDOWS} needed"
        return _classical_only(fallback), (
            "fill policy: classical fills only, as the val split ranks them (too little of the recording "
            f"to measure the model on: {why})"
        )
    cells = None if every_cell else hole_kinds(tracks, fixer.skeleton, fixer.fps, gaps)
    calibration = Calibration(gaps)
    positions = torch.from_numpy(windows.astype(np.float32))
    calibrate(
        calibration,
        model_fill,
        positions,
        fixer.skeleton,
        fixer.fps,
        gaps,
        torch.Generator().manual_seed(seed),
        cells,
    )
    policy = calibration.compute()
    if policy is None:  # no kind of hole could be measured (a limb the model has no group for)
        return _classical_only(fallback), "fill policy: classical fills only, as the val split ranks them"
    for part, table in fallback.error_mm.items():  # cells not measured here: the val split's numbers
        for method, errors in table.items():
            mine = policy.error_mm.setdefault(part, {}).setdefault(method, [float("inf")] * len(gaps))
            for i, g in enumerate(gaps):
                if cells is not None and (part, g) not in cells:
                    mine[i] = errors[i]
    # the replace threshold (--mode both) stays the val split's: the recording's own observed tokens
    # include the jumps it is meant to find
    policy.replace_threshold_m = fallback.replace_threshold_m
    policy.notes.append("measured on the recording")
    measured = sorted(cells) if cells is not None else [(p, g) for p in policy.error_mm for g in policy.gaps_s]
    chosen = [f"{p} {g:g}s {policy.best(p, g)}" for p, g in measured]
    return policy, f"fill policy measured on this recording ({len(windows)} complete stretches): {', '.join(chosen)}"


def _classical_only(policy: FillPolicy) -> FillPolicy:
    """The policy with the model's candidates taken out: the classical fills as it ranks them."""
    tables = {part: {m: e for m, e in t.items() if not is_learned(m)} for part, t in policy.error_mm.items()}
    return FillPolicy(policy.gaps_s, tables, policy.replace_threshold_m, policy.windows, ["classical only"])
