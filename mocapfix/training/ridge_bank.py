"""The learned correction's linear bank fitted in closed form (models/correction.py: one linear map
per kind of hole, a part group and a range of lengths).

For each kind, training windows get a hole of that part and a length in its range (corruption.
training_holes), the base fill fills it, and a weighted ridge regression maps what the network
reads of the hole (CorrectionNet.features) to the base fill's error at the hole's points, turned
to the canonical heading, in CORRECTION_UNIT_M: the MLP's output, which the bank is added to.
Each window weighs 1 / (its base fill's squared error): the module's relative loss, so that the
holes the base fill nearly gets right are left nearly alone (fitted on plain squared error the
maps moved Bandai's 0.1-s holes 1.8 -> 2.2 mm, and `fix` took them nowhere). The ridge strength is
chosen per kind among `strengths` on the windows of every HELD_OUT-th training take, fitted on the
others, by plain squared error, what MPJPE weighs (by the relative error the strongest strength
wins and keeps nothing of the long body holes), and the map is then fitted on every take (other
takes: a take's windows overlap, and a strength chosen on them is too weak for new ones; not the
val split, which is the test split for Human3.6M).
A closed form, not gradient steps: the optimum of the weighted least squares, in seconds a kind.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import torch

from mocapfix.data.augment import mirrored
from mocapfix.data.corruption import available, training_holes
from mocapfix.models.correction import CORRECTION_UNIT_M, CorrectionNet, at_frames, base_fill

HELD_OUT = 5  # every HELD_OUT-th training take (by its index) judges the ridge strengths


def bucket_lengths(bucket: int, buckets: int, max_hole_frames: int) -> tuple[int, int]:
    """The hole lengths (first, last) in frames of a bucket: CorrectionNet.cells' inverse."""
    first = next(n for n in range(1, max_hole_frames + 1) if (n - 1) * buckets // max_hole_frames == bucket)
    last = max(n for n in range(1, max_hole_frames + 1) if (n - 1) * buckets // max_hole_frames == bucket)
    return first, last


@torch.no_grad()
def fit_bank(
    net: CorrectionNet,
    windows: Callable[[], Iterator[tuple[torch.Tensor, torch.Tensor]]],
    batches: int,
    strengths: tuple[float, ...],
    floor_m: float,
    mirror: list[int] | None = None,
    say: Callable[[str], None] | None = None,
) -> list[str]:
    """Fit every kind's map of net's bank (in place; bank_fitted set) -> a line per part group:
    the kinds' error left of the base fill's on the held-out takes, the strengths chosen, the time.
    windows(): a fresh iterator of (clean windows (B, T, J, 3) metres, NaN = missing; the take
    each is from (B,) long), the training loader's; batches: batches drawn per kind (cycled);
    floor_m: per hole token, added to the base fill's error a window's weight divides by (the
    module's BASE_ERROR_FLOOR_M); mirror: each joint's partner (data/augment.py: mirror_index):
    every window is also fitted mirrored (a left arm's hole learns from the right arm's motion
    too), None: not; say: told each part's line as soon as it is fitted (a bank takes minutes).
    A take played at another tempo (the data module's tempo_factors) is another take here."""
    cfg = net.config
    lines = []
    for g, joints in enumerate(net.groups):
        began = time.perf_counter()
        part = net.group_masks[g][None]  # (1, J)
        bank = getattr(net, f"bank_{g}")
        cells = []
        for bucket in range(cfg.length_buckets):
            shortest, longest = bucket_lengths(bucket, cfg.length_buckets, cfg.max_hole_frames)
            fit, held, judged = _Sums(), _Sums(), _Sums()  # judged: the held-out takes, unweighted
            for clean, take in _drawn(windows, batches):
                clean, out = clean.to(bank.device), (take % HELD_OUT == HELD_OUT - 1).to(bank.device)
                for sums, rows in ((fit, ~out), (held, out)):
                    if rows.any():
                        x = clean[rows] if mirror is None else torch.cat([clean[rows], mirrored(clean[rows], mirror)])
                        f, y, w = _samples(net, x, part, list(joints), shortest, longest, floor_m)
                        sums.add(f, y, w)
                        if sums is held:
                            judged.add(f, y, torch.ones_like(w))
            weights, strength, left = _ridge(fit, held, judged, strengths)
            bank[bucket] = weights.to(bank.dtype)
            cells.append(f"{shortest}-{longest} frames {left:.2f} (strength {strength:g})")
        name = "full body" if len(joints) == cfg.num_joints else f"joints {','.join(map(str, joints))}"
        lines.append(
            f"linear bank, {name} ({time.perf_counter() - began:.0f} s): held-out error left of the base fill's, "
            + "; ".join(cells)
        )
        if say is not None:
            say(lines[-1])
    net.bank_fitted.fill_(True)
    return lines


def _drawn(source: Callable[[], Iterator], count: int) -> Iterator:
    """count batches from source(), started again when it runs out (other holes each time round)."""
    it, drawn = source(), 0
    while drawn < count:
        batch = next(it, None)
        if batch is None:
            it = source()
            batch = next(it, None)
            if batch is None:
                raise ValueError("the linear bank was given no windows to fit on")
        drawn += 1
        yield batch


def _samples(net, clean, part, joints, shortest, longest, floor_m):
    """One batch of windows with a hole of `part` and a length in [shortest, longest] -> features
    (N, inputs + 1), targets (N, K x |joints| x 3), weights (N,): the windows whose hole fell on data."""
    B, T = clean.shape[:2]
    C = net.config.context_frames
    hole = training_holes(B, T, part, longest, None, clean, C, shortest) & available(clean)
    observed = available(clean) & ~hole
    base = base_fill(net.config, torch.where(observed[..., None], clean, torch.nan), observed)
    truth = torch.nan_to_num(clean)
    f = net.features(base, ~observed)
    # the base fill's error at the hole's points, turned to the canonical heading: (B, K, J, 3)
    error = at_frames(truth, f.points) - at_frames(base, f.points)
    error = torch.cat([torch.einsum("bij,bkmj->bkmi", f.turn, error[..., :2]), error[..., 2:]], -1)
    target = (error[:, :, joints] / CORRECTION_UNIT_M).reshape(B, -1)
    before = (((base - truth) ** 2).sum(-1) * hole).sum((1, 2))  # (B,) m^2
    whole = (hole == part[:, None]).all(-1).any(-1) & hole.any(-1).any(-1)  # a hole of the whole part
    keep = whole & (hole.any(-1).sum(1) >= shortest)
    weight = 1.0 / (before + hole.sum((1, 2)) * floor_m**2)
    values = torch.cat([f.values, torch.ones_like(f.values[:, :1])], 1)
    return values[keep].double(), target[keep].double(), weight[keep].double()


class _Sums:
    """Weighted least squares' sufficient statistics: F'WF, F'WY, sum w |y|^2, and the count."""

    def __init__(self):
        self.gram = self.cross = None
        self.target = 0.0
        self.count = 0

    def add(self, f: torch.Tensor, y: torch.Tensor, w: torch.Tensor) -> None:
        fw = f * w[:, None]
        gram, cross = fw.T @ f, fw.T @ y
        self.gram = gram if self.gram is None else self.gram + gram
        self.cross = cross if self.cross is None else self.cross + cross
        self.target += float((w * (y**2).sum(1)).sum())
        self.count += len(f)

    def plus(self, other: _Sums) -> _Sums:
        out = _Sums()
        out.gram, out.cross = self.gram + other.gram, self.cross + other.cross
        out.target, out.count = self.target + other.target, self.count + other.count
        return out

    def left(self, weights: torch.Tensor) -> float:
        """Weighted squared error of F @ weights over the sum of w |y|^2 (what the base fill leaves)."""
        error = self.target - 2 * (weights * self.cross).sum() + (weights * (self.gram @ weights)).sum()
        return float(error) / max(self.target, 1e-30)


def _ridge(fit: _Sums, held: _Sums, judged: _Sums, strengths) -> tuple[torch.Tensor, float, float]:
    """The strength whose map, fitted on `fit`, leaves the least of `judged`'s error (the held-out
    takes' windows, unweighted), and the map fitted with it on `fit` and `held` -> (weights
    (inputs + 1, outputs), strength, held-out error left)."""
    if fit.gram is None or held.gram is None:
        raise ValueError(
            f"the linear bank needs {HELD_OUT} training takes or more, each with room for a hole of every kind"
        )
    left = {s: judged.left(_solve(fit, s)) for s in strengths}
    best = min(left, key=left.get)
    return _solve(fit.plus(held), best), best, left[best]


def _solve(sums: _Sums, strength: float) -> torch.Tensor:
    """The weighted ridge map of sums -> (inputs + 1, outputs), the last row the bias, which is
    not shrunk: the features and targets centred on their weighted means, the bias what the map
    leaves of the mean."""
    gram, cross = sums.gram[:-1, :-1], sums.cross[:-1]
    total, f_sum, y_sum = sums.gram[-1, -1], sums.gram[-1, :-1], sums.cross[-1]  # sums of w, w f, w y
    gram = gram - torch.outer(f_sum, f_sum) / total
    cross = cross - torch.outer(f_sum, y_sum) / total
    scale = torch.diagonal(sums.gram)[:-1].mean() / max(sums.count, 1)  # the features' mean square
    ridge = strength * scale * sums.count * torch.eye(len(gram), dtype=gram.dtype)
    weights = torch.cholesky_solve(cross, torch.linalg.cholesky(gram + ridge))  # symmetric positive definite
    bias = (y_sum - f_sum @ weights) / total
    return torch.cat([weights, bias[None]])
