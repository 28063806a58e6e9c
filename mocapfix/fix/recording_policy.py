"""The fill policy measured on the recording being fixed, not only on the model's val split.

A model's val split shares performers, motions and the studio with its training split, so the
policy calibrated there (evaluation/policy.py) believes the model where it has learned a studio,
not human motion: a paper-sized XMAE trained on 70 CMU takes beat the classical fills on its val
split and was 2.5x worse than a cubic spline on other performers. The recording itself is the
only evidence about the recording: holes of the kinds it has (body part and length) are cut into
its own complete stretches (2 s in which every model joint is observed), the model and every
classical fill fill them as fix does, and the policy is the one those errors give (calibrate, as
training does on its val split). Where the recording has too few complete stretches to measure
on, the model has not earned its place there: the classical fills only.
The classical fills need no window: they are measured on the whole recording (holes cut where the
part is observed, filled with the take's own context), as fix fills them. A val split of 1-s
windows ranks them otherwise: with 0.05 s of context a linear fill wins 0.9-s full-body holes,
on whole CMU takes it is the worst of the four (a quarter worse than the limb fill).
"""

from __future__ import annotations

import numpy as np
import torch

from mocapfix.evaluation.baselines import CLASSICAL
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
HOLES_PER_CELL = 64  # the budget of holes cut into the recording per (part, gap) for the classical fills
# A hole is cut only where its joints are observed this long on both sides. Cut right next to
# one of the recording's own holes, it is a hole twice as long for the classical fills, and the
# fills that need the least context win (measured on CMU takes with 0.7-s holes: with a frame of
# context each side the mean of the limb fill and PCHIP came out 3 % ahead of the limb fill,
# and was 2 % behind it on the recording's holes; with 0.1 s the limb fill ranked first, as there).
CONTEXT_S = 0.1


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


def measure_classical(takes: list[tuple[np.ndarray, float]], skeleton, gaps_s, cells=None) -> tuple[FillPolicy, int]:
    """takes: (x (T, J, 3) NaN = missing, fps) per clip, at the model's joints and the input's fps
    -> (every classical fill and blend of two, by part and gap, over holes cut into the takes and
    filled with each take's own context; inf where no hole fitted, the holes cut). cells: only
    these (part, gap), None: all."""
    calibration = Calibration(gaps_s)
    options = {"full": [list(range(skeleton.num_joints))]}
    for group, members in sorted(skeleton.groups.items()):
        options.setdefault(group.split("_")[-1], []).append(list(members))
    cut = 0
    for part in PARTS:
        for gap in gaps_s:
            if part not in options or (cells is not None and (part, gap) not in cells):
                continue
            for x, fps in takes:
                observed = np.isfinite(x).all(-1)
                hidden = cut_holes(
                    observed,
                    options[part],
                    max(1, round(gap * fps)),
                    -(-HOLES_PER_CELL // len(takes)),
                    max(1, round(CONTEXT_S * fps)),
                )
                if not hidden.any():
                    continue
                cut += int((np.diff(hidden.any(-1).astype(np.int64), prepend=0) == 1).sum())
                truth = torch.from_numpy(x.astype(np.float64))[None]
                holed = truth.masked_fill(torch.from_numpy(hidden)[None, ..., None], float("nan"))
                obs = torch.from_numpy(observed & ~hidden)[None]
                fills = {name: fill(holed, obs, skeleton.parents) for name, fill in CLASSICAL.items()}
                calibration.add_fills(part, gap, fills, truth, torch.from_numpy(hidden)[None])
    return calibration.compute(), cut


def measure_policy(
    fixer,
    tracks: list[np.ndarray],
    takes: list[tuple[np.ndarray, float]],
    fallback: FillPolicy | None,
    model_fill,
    every_cell: bool = False,
    seed: int = 0,
) -> tuple[FillPolicy | None, str | None]:
    """The fill policy of this recording for a positions fixer (.skeleton, .fps); tracks: its clips
    at the model's joints and fps; takes: (x, fps) the same at the input's fps; model_fill(
    positions (N, L, J, 3), observed (N, L, J)) -> the model's fill as fix makes it.
    -> (policy, a line for the report).
    Only the kinds of hole the recording has are measured (every_cell: all, for --mode both,
    whose replaced tokens make holes of any kind); the others keep the fallback's numbers. The
    model on complete stretches, the classical fills on the whole takes (measure_classical);
    the classical fills only where fewer than MIN_WINDOWS complete stretches exist. Nothing is
    measured for a checkpoint without a policy (its model fills every hole, as documented)."""
    if fallback is None:
        return None, None
    gaps = tuple(fallback.gaps_s)
    cells = None if every_cell else hole_kinds(tracks, fixer.skeleton, fixer.fps, gaps)
    if cells is not None and not cells:  # no hole to fill
        return fallback, None
    windows = complete_windows(tracks, int(round(STRETCH_S * fixer.fps)))
    on_stretches = None
    if len(windows) >= MIN_WINDOWS:
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
        on_stretches = calibration.compute()
    on_takes, holes = measure_classical(takes, fixer.skeleton, gaps, cells)

    # Per method and cell, the most relevant measurement there is: a model's on the stretches, a
    # classical fill's on the whole takes, else on the stretches; the val split's where neither.
    # Without stretches the model has not earned its place: its candidates are left out.
    policy = fallback if on_stretches is not None else _classical_only(fallback)
    tables = {part: {m: list(e) for m, e in t.items()} for part, t in policy.error_mm.items()}
    for part, table in tables.items():
        for method, errors in table.items():
            sources = [on_stretches] if is_learned(method) else [on_takes, on_stretches]
            for i in range(len(gaps)):
                for measured in sources:
                    e = measured.error_mm.get(part, {}).get(method) if measured is not None else None
                    if e is not None and np.isfinite(e[i]):
                        errors[i] = e[i]
                        break
    # the replace threshold (--mode both) stays the val split's: the recording's own observed tokens
    # include the jumps it is meant to find
    out = FillPolicy(gaps, tables, fallback.replace_threshold_m, fallback.windows, ["measured on the recording"])
    measured = sorted(cells) if cells is not None else [(p, g) for p in tables for g in gaps]
    chosen = ", ".join(f"{p} {g:g}s {out.best(p, g)}" for p, g in measured)
    evidence = (
        f"the model on {len(windows)} complete {STRETCH_S:g}-s stretches, "
        if on_stretches is not None
        else f"classical fills only: {len(windows)} complete {STRETCH_S:g}-s stretches to measure the model "
        f"on, {MIN_WINDOWS} needed; "
    ) + f"the classical fills on {holes} holes cut into it"
    return out, f"fill policy measured on this recording ({evidence}): {chosen}"


def _classical_only(policy: FillPolicy) -> FillPolicy:
    """The policy with the model's candidates taken out: the classical fills as it ranks them."""
    tables = {part: {m: e for m, e in t.items() if not is_learned(m)} for part, t in policy.error_mm.items()}
    return FillPolicy(policy.gaps_s, tables, policy.replace_threshold_m, policy.windows, ["classical only"])
