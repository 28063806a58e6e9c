"""The learned correction's linear bank fitted in closed form (models/correction.py: one linear map
per kind of hole, a part group and a range of lengths).

For each kind, training windows get a hole of that part and a length in its range (corruption.
training_holes), the base fill fills it, and a weighted ridge regression maps what the network
reads of the hole (CorrectionNet.features) to the base fill's error at the hole's points, turned
to the canonical heading, in CORRECTION_UNIT_M: the MLP's output, which the bank is added to.
Each window weighs 1 / (its base fill's squared error): the module's relative loss, so that a
hole the base fills well counts as much as one it fills badly. The ridge strength is chosen per
kind among `strengths` on the val split's windows (other takes: the training windows overlap,
and a strength chosen on them is too weak for new ones), holes of the same kind cut into them.
A closed form, not gradient steps: the optimum of the weighted least squares, in seconds a kind.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import torch

from mocapfix.data.corruption import available, training_holes
from mocapfix.models.correction import CORRECTION_UNIT_M, CorrectionNet, at_frames, base_fill

HELD_OUT = 4  # the val batches drawn per kind: one for every HELD_OUT training batches (at least 2)


def bucket_lengths(bucket: int, buckets: int, max_hole_frames: int) -> tuple[int, int]:
    """The hole lengths (first, last) in frames of a bucket: CorrectionNet.cells' inverse."""
    first = next(n for n in range(1, max_hole_frames + 1) if (n - 1) * buckets // max_hole_frames == bucket)
    last = max(n for n in range(1, max_hole_frames + 1) if (n - 1) * buckets // max_hole_frames == bucket)
    return first, last


@torch.no_grad()
def fit_bank(
    net: CorrectionNet,
    windows: Callable[[], Iterator[torch.Tensor]],
    held_out: Callable[[], Iterator[torch.Tensor]],
    batches: int,
    strengths: tuple[float, ...],
    floor_m: float,
    mirror: list[int] | None = None,
) -> list[str]:
    """Fit every kind's map of net's bank (in place; bank_fitted set) -> a line per part group:
    the kinds' error left of the base fill's on the val windows, the strengths chosen, the time.
    windows(), held_out(): a fresh iterator of clean windows (B, T, J, 3) metres, NaN = missing
    (the training loader's, the val loader's); batches: training batches drawn per kind (and
    batches // HELD_OUT val ones, at least 2, cycled); floor_m: per hole token, added to the base
    fill's error a window's weight divides by (the module's BASE_ERROR_FLOOR_M); mirror: each
    joint's partner (data/augment.py: mirror_index): every training window is also fitted on
    mirrored (a left arm's hole learns from the right arm's motion too), None: not."""
    cfg = net.config
    lines = []
    for g, joints in enumerate(net.groups):
        began = time.perf_counter()
        part = net.group_masks[g][None]  # (1, J)
        bank = getattr(net, f"bank_{g}")
        cells = []
        for bucket in range(cfg.length_buckets):
            shortest, longest = bucket_lengths(bucket, cfg.length_buckets, cfg.max_hole_frames)
            fit, held = _Sums(), _Sums()
            for sums, source, count in ((fit, windows, batches), (held, held_out, max(2, batches // HELD_OUT))):
                for clean in _drawn(source, count):
                    clean = clean.to(bank.device)
                    if mirror is not None and sums is fit:
                        clean = torch.cat([clean, mirrored(clean, mirror)])
                    sums.add(*_samples(net, clean, part, list(joints), shortest, longest, floor_m))
            weights, strength, left = _ridge(fit, held, strengths)
            bank[bucket] = weights.to(bank.dtype)
            cells.append(f"{shortest}-{longest} frames {left:.2f} (strength {strength:g})")
        name = "full body" if len(joints) == cfg.num_joints else f"joints {','.join(map(str, joints))}"
        lines.append(
            f"linear bank, {name} ({time.perf_counter() - began:.0f} s): val error left of the base fill's, "
            + "; ".join(cells)
        )
    net.bank_fitted.fill_(True)
    return lines


def mirrored(x: torch.Tensor, mirror: list[int]) -> torch.Tensor:
    """x: (B, T, J, 3), z up -> its mirror image: each joint swapped with its partner, x negated."""
    return x[:, :, mirror] * x.new_tensor([-1.0, 1.0, 1.0])


def _drawn(source: Callable[[], Iterator[torch.Tensor]], count: int) -> Iterator[torch.Tensor]:
    """count batches from source(), started again when it runs out (other holes each time round)."""
    it, drawn = source(), 0
    while drawn < count:
        clean = next(it, None)
        if clean is None:
            it = source()
            clean = next(it, None)
            if clean is None:
                raise ValueError("the linear bank was given no windows to fit on")
        drawn += 1
        yield clean


def _samples(net, clean, part, joints, shortest, longest, floor_m):
    """One batch of windows with a hole of `part` and a length in [shortest, longest] -> features
    (N, inputs + 1), targets (N, K x |joints| x 3), weights (N,), windows whose hole fell on data."""
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

    def left(self, weights: torch.Tensor) -> float:
        """Weighted squared error of F @ weights over the sum of w |y|^2 (what the base fill leaves)."""
        error = self.target - 2 * (weights * self.cross).sum() + (weights * (self.gram @ weights)).sum()
        return float(error) / max(self.target, 1e-30)


def _ridge(fit: _Sums, held: _Sums, strengths) -> tuple[torch.Tensor, float, float]:
    """The map fitted on `fit` with the strength that leaves the least of `held`'s error ->
    (weights (inputs + 1, outputs), strength, held-out error left)."""
    if fit.gram is None or held.gram is None:
        raise ValueError("the linear bank found no window with room for a hole of some kind: longer windows?")
    # the bias is not shrunk: the features and targets centred on their weighted means, the bias
    # what the map leaves of the mean; one eigendecomposition serves every strength
    gram, cross = fit.gram[:-1, :-1], fit.cross[:-1]
    total, f_sum, y_sum = fit.gram[-1, -1], fit.gram[-1, :-1], fit.cross[-1]  # sums of w, w f, w y
    gram = gram - torch.outer(f_sum, f_sum) / total
    cross = cross - torch.outer(f_sum, y_sum) / total
    scale = torch.diagonal(fit.gram)[:-1].mean() / max(fit.count, 1)  # the features' mean square
    values, vectors = torch.linalg.eigh(gram)
    projected = vectors.T @ cross  # (inputs, outputs)

    def solve(strength: float) -> torch.Tensor:
        weights = vectors @ (projected / (values.clamp_min(0) + strength * scale * fit.count)[:, None])
        bias = (y_sum - f_sum @ weights) / total
        return torch.cat([weights, bias[None]])

    maps = {s: solve(s) for s in strengths}
    left = {s: held.left(m) for s, m in maps.items()}
    best = min(left, key=left.get)
    return maps[best], best, left[best]
