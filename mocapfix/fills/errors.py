"""Each fill's error on holes cut into takes: the evidence a fill policy is fitted on (policy.py),
on the val split's windows (evaluation/policy_fit.py) or on the recording being fixed.

Holes of a kind (body part, length) are cut into a take where the part is observed, with
CONTEXT_S of data on both sides, and every candidate fills them as it fills the take's own: the
classical fills and motion matching with the take's whole context, the model as the Fill it is
handed (fix/: its windows blended over the take and anchored on the data). A stack of a model's
fill and motion matching's (STACKS) is measured with its weights fitted on the other takes' holes.
"""

from __future__ import annotations

import numpy as np
import torch

from mocapfix.fills.classical import classical_fills
from mocapfix.fills.fill import STACK, STACK_ORIGIN, Fill, blends, components, made
from mocapfix.fills.holes import PARTS, cut_holes, room_for_holes, share_holes
from mocapfix.fills.motion_matching import MotionLibrary, MotionMatching, library_of

# The fills are screened after every SCREEN_HOLES holes of a kind (measure_on_takes' screen) and
# measured further only where they may still be chosen; a kind with one candidate left is settled.
SCREEN_HOLES = 16
HOLES_PER_CELL = 64  # the budget of holes cut into the recording per (part, gap): a model pass each kind
# A hole is cut only where its joints are observed this long on both sides. Cut right next to
# one of the recording's own holes, it is a hole twice as long for the classical fills, and the
# fills that need the least context win (measured on CMU takes with 0.7-s holes: with a frame of
# context each side the mean of the limb fill and PCHIP came out 3 % ahead of the limb fill,
# and was 2 % behind it on the recording's holes; with 0.1 s the limb fill ranked first, as there).
CONTEXT_S = 0.1
# The kinds of hole of a take filled in one call of each fill: at most this many frames of the
# take's copies (each holding one kind's holes) at once, each a (B, T, J, 3) float64 per candidate.
BATCH_FRAMES = 8192
# The stacks measured (fill.py STACK): a model's fill (policy.py LEARNED) with motion matching's
# match_delta, both steps from the Hermite fill. On Human3.6M's held-out subjects (every S9/S11
# take, the correction_h36m of docs/results.md, 4 holes a take) the stack, each take's holes
# scored with the weights the other takes' gave, was 2 / 2 / 2 % of the best classical fill below
# the better of the mean of the two and the correction alone for full-body holes of 0.5 / 0.7 /
# 0.9 s, 3 / 3 / 5 % for leg holes, and within 0.5 % of the correction alone for arm holes; with
# the limb fill as the origin it gained a quarter of that or less.
STACKS = (("xmae", "match_delta"), ("correction", "match_delta"))
# A stack's weights: least squares with a ridge of this share of the steps' mean sum of squares,
# which keeps them defined where a step is zero (match_delta where nothing matched is the Hermite).
STACK_RIDGE = 1e-6


class ErrorSums:
    """Each candidate's error summed per (part, gap) over filled tokens with truth -> the error
    tables of a fill policy (tables: part -> method -> mean error in mm per gap); where the holes
    are told apart (add_fills' hole_of), each hole's mean error too, in the order measured, and
    the take it was cut into: the paired evidence policy.py screens candidates out on
    (hopeless) and lets a candidate take a kind on fewer holes by (proven). A stack's numbers
    come from the steps kept for it (stack_data) when settle_stacks is asked."""

    def __init__(self, gaps_s):
        self.gaps_s = sorted(float(g) for g in gaps_s)
        self.sums: dict[tuple[str, float, str], list[float]] = {}  # (part, gap, method) -> [error sum m, count]
        self.holes: dict[tuple[str, float, str], list[float]] = {}  # (part, gap, method) -> mean error m per hole
        self.dropped: set[tuple[str, float, str]] = set()  # screened out: no number, inf in the tables
        self.hole_takes: dict[tuple[str, float], list] = {}  # (part, gap) -> the take of each hole, in order
        # (part, gap, stack) -> per add_fills call: (its holes' numbers from 0 (M,), the steps from
        # the origin (M, K, 3) float32, the truth's (M, 3)); settle_stacks makes its numbers
        self.stack_data: dict[tuple[str, float, str], list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}
        self.stack_weights: dict[tuple[str, float, str], list[float]] = {}  # fitted on every hole

    def add_fills(
        self,
        part: str,
        gap_s: float,
        fills: dict[str, torch.Tensor],
        target: torch.Tensor,
        scored: torch.Tensor,
        hole_of: torch.Tensor | None = None,
        take=None,
    ) -> None:
        """Every single fill and the mean of every pair of them (policy.py's docstring says why).
        fills: name -> (B, T, J, 3) metres, target: (B, T, J, 3), scored: (B, T, J) bool (the
        filled tokens with truth); hole_of: (B, T, J) long, the hole each scored token is in;
        take: the take they were cut into (holes of one take are not independent evidence)."""
        truth = torch.nan_to_num(target[scored].float())  # (M, 3): only the scored tokens are compared
        at = None  # (M,) each scored token's hole, numbered from 0 in order
        if hole_of is not None and scored.any():
            _, at = torch.unique(hole_of[scored], return_inverse=True)
            self.hole_takes.setdefault((part, float(gap_s)), []).extend([take] * (int(at.max()) + 1))
        for method, pred in blends({name: f[scored] for name, f in fills.items()}).items():
            err = (pred.float() - truth).norm(dim=-1)  # (M,)
            key = (part, float(gap_s), method)
            s = self.sums.setdefault(key, [0.0, 0])
            s[0] += float(err.sum())
            s[1] += int(err.numel())
            if at is not None:
                per_hole = torch.zeros(int(at.max()) + 1, dtype=torch.float64).index_add_(0, at, err.double())
                self.holes.setdefault(key, []).extend((per_hole / torch.bincount(at)).tolist())
        if at is not None:
            origin = fills.get(STACK_ORIGIN)
            for names in STACKS:
                if origin is None or not all(n in fills for n in names):
                    continue
                base = origin[scored].float()
                steps = torch.stack([fills[n][scored].float() - base for n in names], dim=1)  # (M, K, 3)
                record = (at.numpy().copy(), steps.numpy(), (truth - base).numpy())
                self.stack_data.setdefault((part, float(gap_s), STACK.join(names)), []).append(record)

    def add(self, other: ErrorSums) -> None:
        """Another ErrorSums' sums and holes (a take measured elsewhere: a worker of fix --jobs)."""
        for key, (total, count) in other.sums.items():
            s = self.sums.setdefault(key, [0.0, 0])
            s[0] += total
            s[1] += count
        for key, errors in other.holes.items():
            self.holes.setdefault(key, []).extend(errors)
        for cell, takes in other.hole_takes.items():
            self.hole_takes.setdefault(cell, []).extend(takes)
        for key, records in other.stack_data.items():
            self.stack_data.setdefault(key, []).extend(records)

    def drop(self, part: str, gap_s: float, methods) -> None:
        """These candidates screened out of the cell: measured no further, inf in its tables."""
        for method in methods:
            key = (part, float(gap_s), method)
            self.sums.pop(key, None)
            self.holes.pop(key, None)
            self.stack_data.pop(key, None)
            self.stack_weights.pop(key, None)
            self.dropped.add(key)

    def settle_stacks(self) -> None:
        """Each stack's numbers from the holes measured so far, as every other candidate's: its
        error on each hole with weights fitted on the other takes' holes (each take's holes share
        its motion; a single take's on its other holes), in sums and holes; and its weights fitted
        on every hole (stack_weights). A stack measured on fewer holes than its kind has (one of
        its fills screened out: errors.measure_on_takes) has no numbers."""
        for key, records in self.stack_data.items():
            part, gap, _ = key
            takes = self.hole_takes.get((part, gap), [])
            sizes = [int(at.max()) + 1 for at, _, _ in records]
            if key in self.dropped or sum(sizes) != len(takes):
                self.sums.pop(key, None)
                self.holes.pop(key, None)
                self.stack_weights.pop(key, None)
                continue
            offsets = np.cumsum([0, *sizes[:-1]])
            hole = np.concatenate([at + o for (at, _, _), o in zip(records, offsets)])  # (M,)
            steps = np.concatenate([r[1] for r in records]).astype(np.float64)  # (M, K, 3)
            target = np.concatenate([r[2] for r in records]).astype(np.float64)  # (M, 3)
            numbers = take_numbers(takes)  # (holes,)
            group = numbers[hole] if numbers.max() > 0 else hole  # (M,) one take: each hole its own
            errors, weights = _stack_errors(steps, target, group)
            per_hole = np.bincount(hole, weights=errors, minlength=len(takes)) / np.bincount(hole, minlength=len(takes))
            self.sums[key] = [float(errors.sum()), int(errors.size)]
            self.holes[key] = per_hole.tolist()
            self.stack_weights[key] = weights.tolist()

    def tables(self) -> dict[str, dict[str, list[float]]]:
        """part -> method -> mean error (mm) per gap; inf where nothing was measured."""
        error: dict[str, dict[str, list[float]]] = {}
        for part in PARTS:
            methods = sorted({m for (p, _, m) in [*self.sums, *self.dropped] if p == part})
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


def take_numbers(takes: list) -> np.ndarray:
    """The take of each hole (ErrorSums.hole_takes' list for a kind) -> (holes,) int, the takes
    numbered from 0: holes of one take are one group of evidence."""
    return np.unique(np.array([str(t) for t in takes]), return_inverse=True)[1]


def _stack_errors(steps: np.ndarray, target: np.ndarray, group: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """steps (M, K, 3) the stacked fills' steps from the origin and target (M, 3) the truth's, at M
    filled tokens of G groups (group (M,) int) -> ((M,) each token's error (m) with the weights
    fitted on the other groups' tokens, (K,) the weights fitted on every token). Least squares
    over the coordinates: the normal equations per group, summed, less the group's own."""
    G = int(group.max()) + 1
    K = steps.shape[1]
    gram = np.einsum("mkc,mlc->mkl", steps, steps)  # (M, K, K)
    cross = np.einsum("mkc,mc->mk", steps, target)  # (M, K)
    gram_g = np.zeros((G, K, K))
    cross_g = np.zeros((G, K))
    np.add.at(gram_g, group, gram)
    np.add.at(cross_g, group, cross)
    ridge = STACK_RIDGE * max(np.trace(gram_g.sum(0)) / K, 1e-12) * np.eye(K)
    total_gram, total_cross = gram_g.sum(0), cross_g.sum(0)
    weights = np.linalg.solve(total_gram + ridge, total_cross)  # (K,)
    if G < 2:  # nothing to hold out: the tokens' error with the weights fitted on them
        held = np.broadcast_to(weights, (G, K))
    else:
        held = np.linalg.solve(total_gram - gram_g + ridge, (total_cross - cross_g)[..., None])[..., 0]  # (G, K)
    residual = target - np.einsum("mkc,mk->mc", steps, held[group])
    return np.linalg.norm(residual, axis=-1), weights


def measure_on_takes(
    takes: list[tuple[np.ndarray, float]],
    skeleton,
    gaps_s,
    cells=None,
    model_fill: Fill | None = None,
    map_takes=None,
    keys=None,
    library: MotionLibrary | None = None,
    screen=None,
) -> tuple[ErrorSums, dict[tuple[str, float], int]]:
    """takes: (x (T, J, 3) NaN = missing, fps) per clip, at the model's joints and the input's fps;
    model_fill: the model's fill as fix makes it (None: no model) -> (every fill's error and the
    mean of every two over holes cut into the takes (ErrorSums: its tables, part -> method -> mm
    per gap, inf where none could be cut); the holes cut per (part, gap)). cells: only these
    (part, gap), None: all. map_takes(jobs) -> results: how the takes' measure_take(*job) calls
    run (default: one after another here; fix --jobs hands them to its workers); each take is
    measured alone and the sums are added up in a fixed order, so the result is the same
    either way. The motion-matching fills search the takes (keys: one per take, as fix names them
    to its MotionLibrary; default their order), each take's own with its holes cut, and `library`
    (the user's other takes, fix --library).
    screen(errors, fills) -> {(part, gap): fill names}: asked after each phase (screening_phases:
    SCREEN_HOLES more holes of each kind, from takes spread over the folder) with the errors so
    far and the names of each fill measured (a tuple per Fill: motion matching's two, a model's,
    each classical fill's); the fills it names are not run on that kind's holes in the later
    phases, and their candidates are dropped from its tables (policy.py: hopeless); a
    kind left with one candidate is settled: no more holes of it are cut. None: every take
    measures every fill."""
    errors = ErrorSums(gaps_s)
    keys = list(range(len(takes))) if keys is None else list(keys)
    library = library_of(takes, keys, skeleton, library)
    gaps = tuple(errors.gaps_s)
    budgets = hole_budgets(takes, skeleton, gaps, cells)
    phases = screening_phases(budgets) if screen is not None else [list(enumerate(budgets))]
    measured = [f.names for f in take_fills(library, None, model_fill)]
    cut: dict[tuple[str, float], int] = {}
    skip: dict[tuple[str, float], set[str]] = {}
    for k, phase in enumerate(phases):
        skipped = {cell: set(names) for cell, names in skip.items()}
        work = [(*takes[i], skeleton, gaps, cells, budget, library, keys[i], skipped) for i, budget in phase]
        results = [measure_take(*job, model_fill=model_fill) for job in work] if map_takes is None else map_takes(work)
        for take_errors, take_cut in results:
            errors.add(take_errors)
            for cell, n in take_cut.items():
                cut[cell] = cut.get(cell, 0) + n
        errors.settle_stacks()
        if k + 1 < len(phases):
            for (part, gap), names in screen(errors, measured).items():
                methods = {m for (p, g, m) in errors.sums if (p, g) == (part, gap) and set(components(m)) & set(names)}
                errors.drop(part, gap, methods)
                skip.setdefault((part, gap), set()).update(names)
    return errors, cut


def screening_phases(
    budgets: list[dict[tuple[str, float], int]],
) -> list[list[tuple[int, dict[tuple[str, float], int]]]]:
    """The holes measure_on_takes measures in each phase, the fills screened after each: per
    phase, (take index, the holes of each kind cut into it then) for the takes with holes in it,
    ascending. The takes are visited every fourth one first, then the ones between (the first
    holes come from across the folder); a kind's holes in a take go to the first phase in which
    the kind has fewer than SCREEN_HOLES more planned than all the phases before (a take's other
    kinds wait for a later phase: a kind is screened on its first 16 holes, not on as many as the
    slowest kind to gather 16 brought in)."""
    order = [i for phase in range(4) for i in range(phase, len(budgets), 4)]
    total: dict[tuple[str, float], int] = {}
    for budget in budgets:
        for cell, n in budget.items():
            total[cell] = total.get(cell, 0) + n
    left = [{cell: n for cell, n in budget.items() if n} for budget in budgets]
    have = dict.fromkeys(total, 0)
    phases, wanted = [], 0
    while any(left):
        wanted += SCREEN_HOLES
        phase: dict[int, dict[tuple[str, float], int]] = {}
        for i in order:
            for cell in [cell for cell in left[i] if have[cell] < wanted]:
                phase.setdefault(i, {})[cell] = left[i].pop(cell)
                have[cell] += phase[i][cell]
        if phase:  # none where the kinds left had more than `wanted` already (a take's share at once)
            phases.append(sorted(phase.items()))
    return phases


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


def take_fills(library: MotionLibrary | None, key, model_fill: Fill | None) -> list[Fill]:
    """The fills measured on a take: every classical fill, motion matching where there is a
    library (the take `key` searched with its holes cut), the model's fill where there is one."""
    fills = classical_fills()
    if library is not None:
        fills.append(MotionMatching(library, key))
    if model_fill is not None:
        fills.append(model_fill)
    return fills


def measure_take(
    x: np.ndarray,
    fps: float,
    skeleton,
    gaps_s,
    cells,
    budget: dict[tuple[str, float], int],
    library=None,
    key=None,
    skip: dict[tuple[str, float], set[str]] | None = None,
    model_fill=None,
) -> tuple[ErrorSums, dict[tuple[str, float], int]]:
    """One take's share of measure_on_takes: budget[(part, gap)] holes of each kind (hole_budgets)
    cut into x (T, J, 3) and every fill's error there -> (ErrorSums, holes cut per (part, gap)).
    library: a MotionLibrary (its take `key` left out: this one is searched with its holes cut),
    None: no motion-matching fills; skip: per kind, the fills (by name) not run there (screened
    out; a kind left with fewer than two candidates is not cut: settled); model_fill: a Fill, or
    None."""
    errors = ErrorSums(gaps_s)
    options = part_options(skeleton)
    observed = np.isfinite(x).all(-1)
    truth = torch.from_numpy(x.astype(np.float64))[None]
    fills = take_fills(library, key, model_fill)
    # (part, gap, hidden (T, J) the cut holes' tokens, (T,) each frame's cut hole numbered from 1, the fills run)
    kinds = []
    cut: dict[tuple[str, float], int] = {}
    for part in PARTS:
        for gap in gaps_s:
            if part not in options or (cells is not None and (part, gap) not in cells) or not budget.get((part, gap)):
                continue
            unskipped = [f for f in fills if not set(f.names) & (skip or {}).get((part, gap), set())]
            if sum(len(f.names) for f in unskipped) < 2:
                continue  # settled: one candidate left, nothing to rank
            hidden = cut_holes(
                observed, options[part], max(1, round(gap * fps)), budget[(part, gap)], max(1, round(CONTEXT_S * fps))
            )
            if hidden.any():
                starts = np.diff(hidden.any(-1).astype(np.int64), prepend=0) == 1  # (T,) a cut hole's first frame
                numbered = np.cumsum(starts)
                kinds.append((part, gap, hidden, numbered, unskipped))
                cut[(part, gap)] = int(numbered[-1])
    # The kinds that run the same fills are filled together, one copy of the take each in a batch
    # (up to BATCH_FRAMES frames): each fill is called once for them, the model's windows of all
    # their holes run in the same batches. Only the cut holes are filled: the fills that can skip
    # the take's own holes do. (Each kind's sums are its own: the order they are added in does
    # not change them.)
    together: dict[tuple[Fill, ...], list[int]] = {}
    for i, (*_, unskipped) in enumerate(kinds):
        together.setdefault(tuple(unskipped), []).append(i)
    per_batch = max(1, BATCH_FRAMES // len(x))
    for run, members in together.items():
        for first in range(0, len(members), per_batch):
            batch = [kinds[i] for i in members[first : first + per_batch]]
            hidden = torch.from_numpy(np.stack([h for _, _, h, _, _ in batch]))  # (B, T, J)
            holed = truth.expand(len(batch), -1, -1, -1).masked_fill(hidden[..., None], float("nan"))
            obs = torch.from_numpy(observed)[None] & ~hidden
            filled = made(list(run), holed, obs, fps, skeleton, asked=hidden)
            for k, (part, gap, h, numbered, _) in enumerate(batch):
                hole_of = torch.from_numpy(np.broadcast_to(numbered[:, None], h.shape).copy())[None]
                mine = {name: fill[k : k + 1] for name, fill in filled.items()}
                errors.add_fills(part, gap, mine, truth, hidden[k : k + 1], hole_of, key)
    return errors, cut
