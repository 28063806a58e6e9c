"""Each fill's error on holes cut into takes: the evidence a fill policy is fitted on (policy.py),
on the val split's windows (evaluation/policy_fit.py) or on the recording being fixed.

Holes of a kind (body part, length) are cut into a take where the part is observed, with
CONTEXT_S of data on both sides, and every candidate fills them as it fills the take's own: the
classical fills and motion matching with the take's whole context, the model as the Fill it is
handed (fix/: its windows blended over the take and anchored on the data).
"""

from __future__ import annotations

import numpy as np
import torch

from mocapfix.fills.classical import classical_fills
from mocapfix.fills.fill import Fill, blends, made
from mocapfix.fills.holes import PARTS, cut_holes, room_for_holes, share_holes
from mocapfix.fills.motion_matching import MotionLibrary, MotionMatching, library_of

HOLES_PER_CELL = 64  # the budget of holes cut into the recording per (part, gap): a model pass each kind
# A hole is cut only where its joints are observed this long on both sides. Cut right next to
# one of the recording's own holes, it is a hole twice as long for the classical fills, and the
# fills that need the least context win (measured on CMU takes with 0.7-s holes: with a frame of
# context each side the mean of the limb fill and PCHIP came out 3 % ahead of the limb fill,
# and was 2 % behind it on the recording's holes; with 0.1 s the limb fill ranked first, as there).
CONTEXT_S = 0.1


class ErrorSums:
    """Each candidate's error summed per (part, gap) over filled tokens with truth -> the error
    tables of a fill policy (tables: part -> method -> mean error in mm per gap)."""

    def __init__(self, gaps_s):
        self.gaps_s = sorted(float(g) for g in gaps_s)
        self.sums: dict[tuple[str, float, str], list[float]] = {}  # (part, gap, method) -> [error sum m, count]

    def add_infill(
        self, part: str, gap_s: float, method: str, pred: torch.Tensor, target: torch.Tensor, scored: torch.Tensor
    ) -> None:
        """pred, target: (B, T, J, 3) metres; scored: (B, T, J) bool (the filled tokens with truth).
        Pass blends(fills) through add_fills to measure the pairs too."""
        err = (pred.float() - torch.nan_to_num(target.float())).norm(dim=-1)[scored]
        s = self.sums.setdefault((part, float(gap_s), method), [0.0, 0])
        s[0] += float(err.sum())
        s[1] += int(err.numel())

    def add_fills(
        self, part: str, gap_s: float, fills: dict[str, torch.Tensor], target: torch.Tensor, scored: torch.Tensor
    ) -> None:
        """Every single fill and the mean of every pair of them (policy.py's docstring says why)."""
        for method, pred in blends(fills).items():
            self.add_infill(part, gap_s, method, pred, target, scored)

    def add_sums(self, sums: dict) -> None:
        """Another ErrorSums' sums (a take measured elsewhere: a worker of fix --jobs)."""
        for key, (total, count) in sums.items():
            s = self.sums.setdefault(key, [0.0, 0])
            s[0] += total
            s[1] += count

    def tables(self) -> dict[str, dict[str, list[float]]]:
        """part -> method -> mean error (mm) per gap; inf where nothing was measured."""
        error: dict[str, dict[str, list[float]]] = {}
        for part in PARTS:
            methods = sorted({m for (p, _, m) in self.sums if p == part})
            rows = {
                m: [
                    1000.0 * self.sums[(part, g, m)][0] / max(self.sums[(part, g, m)][1], 1)
                    if (part, g, m) in self.sums
                    else float("inf")
                    for g in self.gaps_s
                ]
                for m in methods
            }
            if rows:
                error[part] = rows
        return error


def measure_on_takes(
    takes: list[tuple[np.ndarray, float]],
    skeleton,
    gaps_s,
    cells=None,
    model_fill: Fill | None = None,
    map_takes=None,
    keys=None,
    library: MotionLibrary | None = None,
) -> tuple[dict[str, dict[str, list[float]]] | None, dict[tuple[str, float], int]]:
    """takes: (x (T, J, 3) NaN = missing, fps) per clip, at the model's joints and the input's fps;
    model_fill: the model's fill as fix makes it (None: no model) -> (every fill's error and the
    mean of every two, part -> method -> mm per gap, over holes cut into the takes, inf where none
    could be cut, None where nothing was; the holes cut per (part, gap)). cells: only these
    (part, gap), None: all. map_takes(jobs) -> results: how the takes' measure_take(*job) calls
    run (default: one after another here; fix --jobs hands them to its workers); each take is
    measured alone and the sums are added up in the takes' order, so the result is the same
    either way. The motion-matching fills search the takes (keys: one per take, as fix names them
    to its MotionLibrary; default their order), each take's own with its holes cut, and `library`
    (the user's other takes, fix --library)."""
    errors = ErrorSums(gaps_s)
    keys = list(range(len(takes))) if keys is None else list(keys)
    library = library_of(takes, keys, skeleton, library)
    gaps = tuple(errors.gaps_s)
    budgets = hole_budgets(takes, skeleton, gaps, cells)
    jobs = [(x, fps, skeleton, gaps, cells, b, library, key) for (x, fps), key, b in zip(takes, keys, budgets)]
    results = [measure_take(*job, model_fill=model_fill) for job in jobs] if map_takes is None else map_takes(jobs)
    cut: dict[tuple[str, float], int] = {}
    for sums, take_cut in results:
        errors.add_sums(sums)
        for cell, n in take_cut.items():
            cut[cell] = cut.get(cell, 0) + n
    return (errors.tables() if errors.sums else None), cut


def hole_budgets(takes: list[tuple[np.ndarray, float]], skeleton, gaps_s, cells) -> list[dict[tuple[str, float], int]]:
    """Per take, the holes of each kind (part, gap) to cut into it: HOLES_PER_CELL spread over the
    takes (share_holes), a take crowded with holes of its own cutting fewer and the others more.
    (Bandai's 4-15-s test takes, each with four 0.9-s holes: equal shares cut 19 holes of 64.)"""
    options = part_options(skeleton)
    kinds = [(p, g) for p in PARTS for g in gaps_s if p in options and (cells is None or (p, g) in cells)]
    budgets: list[dict[tuple[str, float], int]] = [{} for _ in takes]
    observed = [np.isfinite(x).all(-1) for x, _ in takes]
    for part, gap in kinds:
        room = [
            room_for_holes(o, options[part], max(1, round(gap * fps)), max(1, round(CONTEXT_S * fps)))
            for o, (_, fps) in zip(observed, takes)
        ]
        for budget, n in zip(budgets, share_holes(room, HOLES_PER_CELL)):
            budget[(part, gap)] = n
    return budgets


def part_options(skeleton) -> dict[str, list[list[int]]]:
    """part -> the joint sets a hole of it takes: the whole body; each arm; each leg."""
    options = {"full": [list(range(skeleton.num_joints))]}
    for group, members in sorted(skeleton.groups.items()):
        options.setdefault(group.split("_")[-1], []).append(list(members))
    return options


def measure_take(
    x: np.ndarray,
    fps: float,
    skeleton,
    gaps_s,
    cells,
    budget: dict[tuple[str, float], int],
    library=None,
    key=None,
    model_fill=None,
):
    """One take's share of measure_on_takes: budget[(part, gap)] holes of each kind (hole_budgets)
    cut into x (T, J, 3) and every fill's error there -> (ErrorSums.sums, holes cut per (part,
    gap)). library: a MotionLibrary (its take `key` left out: this one is searched with its holes
    cut), None: no motion-matching fills; model_fill: a Fill, or None."""
    errors = ErrorSums(gaps_s)
    options = part_options(skeleton)
    observed = np.isfinite(x).all(-1)
    truth = torch.from_numpy(x.astype(np.float64))[None]
    fills = classical_fills()
    if library is not None:  # this take: searched with its holes cut
        fills.append(MotionMatching(library, key))
    if model_fill is not None:
        fills.append(model_fill)
    cut: dict[tuple[str, float], int] = {}
    for part in PARTS:
        for gap in gaps_s:
            if part not in options or (cells is not None and (part, gap) not in cells) or not budget.get((part, gap)):
                continue
            hidden = cut_holes(
                observed, options[part], max(1, round(gap * fps)), budget[(part, gap)], max(1, round(CONTEXT_S * fps))
            )
            if not hidden.any():
                continue
            cut[(part, gap)] = int((np.diff(hidden.any(-1).astype(np.int64), prepend=0) == 1).sum())
            holed = truth.masked_fill(torch.from_numpy(hidden)[None, ..., None], float("nan"))
            obs = torch.from_numpy(observed & ~hidden)[None]
            # only the cut holes are scored: the fills that can skip the take's own holes do
            candidates = made(fills, holed, obs, fps, skeleton, asked=torch.from_numpy(hidden)[None])
            errors.add_fills(part, gap, candidates, truth, torch.from_numpy(hidden)[None])
    return errors.sums, cut
