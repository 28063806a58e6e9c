"""Metrics of the two papers as torchmetrics Metrics: MPJPE (global and root-relative), Limb sigma,
acceleration error and joint acceleration.

Inputs are positions in metres, (B, T, J, 3), NaN where a joint is missing in the data; the
reported numbers are in mm (or m/s^2 for JointAcceleration). Each metric keeps a sum and a count
as "sum"-reduced states, so the mean over several processes (DDP) or merged instances is the
mean over all their data, not a mean of means.

NaN in the target means "no ground truth here": those tokens are never evaluated. NaN in a
prediction at an evaluated token is a model bug and is not hidden: it makes the result NaN.
compute() returns NaN, not an error, when nothing was evaluated (e.g. an all-NaN target).
"""

from __future__ import annotations

import torch
from torchmetrics import Metric

from mocapfix.evaluation.limb_lengths import M_TO_MM, limb_sigmas


def _finite_token(x: torch.Tensor) -> torch.Tensor:
    """x: (..., 3) -> (...) bool, True where no coordinate is NaN."""
    return ~torch.isnan(x).any(dim=-1)


def _second_difference(x: torch.Tensor) -> torch.Tensor:
    """x: (B, T, J, 3) -> x[t-1] - 2 x[t] + x[t+1] for t = 1..T-2: (B, T-2, J, 3)."""
    return x[:, :-2] - 2.0 * x[:, 1:-1] + x[:, 2:]


def _valid_centre(target: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """(B, T-2, J) bool: the three frames around t have data and t is selected by mask (B, T, J)."""
    ok = _finite_token(target)
    valid = ok[:, :-2] & ok[:, 1:-1] & ok[:, 2:]
    if mask is not None:
        valid = valid & mask[:, 1:-1].to(torch.bool)
    return valid


class _MeanMetric(Metric):
    """Mean of per-item values accumulated as a DDP-reduced sum and count."""

    is_differentiable = False
    higher_is_better = False
    full_state_update = False

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        # float64 sums: a test epoch holds millions of tokens; float32 would drift in the 7th digit
        self.add_state("total", default=torch.tensor(0.0, dtype=torch.float64), dist_reduce_fx="sum")
        self.add_state("count", default=torch.tensor(0, dtype=torch.long), dist_reduce_fx="sum")

    def _accumulate(self, values: torch.Tensor, valid: torch.Tensor) -> None:
        # torch.where, not values * valid: values are NaN at invalid items and 0 * NaN = NaN
        self.total += torch.where(valid, values, torch.zeros((), dtype=values.dtype, device=values.device)).sum(
            dtype=torch.float64
        )
        self.count += valid.sum()

    def compute(self) -> torch.Tensor:
        if self.count == 0:
            # nothing evaluated (e.g. every target token NaN): NaN says "no value", an error
            # would kill an evaluation run over many tasks
            return torch.tensor(float("nan"), device=self.total.device)
        return (self.total / self.count).float()


class MPJPE(_MeanMetric):
    """Mean per-joint position error in mm over the evaluated tokens.

    update(pred (B, T, J, 3), target (B, T, J, 3), mask (B, T, J) bool or None = every token).
    root_relative: the root joint of each frame is subtracted from pred and from target first;
    frames whose target root is NaN are then excluded. The root joint itself stays among the
    evaluated tokens (with error 0) when the mask selects it, as the H36M protocols count it.
    """

    def __init__(self, root_relative: bool = False, root_index: int = 0, **kwargs):
        super().__init__(**kwargs)
        self.root_relative, self.root_index = root_relative, root_index

    def update(self, pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> None:
        valid = _finite_token(target)
        if mask is not None:
            valid = valid & mask.to(torch.bool)
        if self.root_relative:
            r = self.root_index
            pred = pred - pred[:, :, r : r + 1]
            target = target - target[:, :, r : r + 1]
            valid = valid & _finite_token(target)  # drops every joint of a frame whose root is NaN
        self._accumulate(M_TO_MM * (pred - target).norm(dim=-1), valid)


class AccelError(_MeanMetric):
    """Acceleration error: mean over (sequence, t, joint) of
    || (x[t-1] - 2 x[t] + x[t+1])_pred - (same)_target || in mm per frame^2 (no division by dt^2,
    as the field reports it; multiply by fps^2 / 1000 for m/s^2).

    update(pred (B, T, J, 3), target (B, T, J, 3), mask (B, T, J) bool or None).
    Evaluated: t = 1..T-2 where the target has data at t-1, t, t+1 and mask selects (t, j).
    """

    def update(self, pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> None:
        err = (_second_difference(pred) - _second_difference(target)).norm(dim=-1)
        self._accumulate(M_TO_MM * err, _valid_centre(target, mask))


class JointAcceleration(_MeanMetric):
    """Plausibility (Motion-DVAE Table 1): mean magnitude of the second difference divided by
    dt^2, in m/s^2. Compare a prediction's value with the ground truth's own.

    update(positions (B, T, J, 3), mask (B, T, J) bool or None). Same evaluated (t, j) as AccelError.
    """

    higher_is_better = None

    def __init__(self, fps: float, **kwargs):
        super().__init__(**kwargs)
        self.fps = float(fps)

    def update(self, positions: torch.Tensor, mask: torch.Tensor | None = None) -> None:
        acc = _second_difference(positions).norm(dim=-1) * self.fps**2
        self._accumulate(acc, _valid_centre(positions, mask))


class LimbSigma(_MeanMetric):
    """Limb sigma (XMAE Table 5): standard deviation over time of each limb's length within a
    sequence, mean over limbs and sequences, in mm.

    limbs: (joint_a, joint_b) pairs, e.g. Skeleton.limbs.
    update(positions (B, T, J, 3)). Population std (ddof=0) over the frames where both joints
    have data; a (sequence, limb) with fewer than 2 such frames is skipped (its std says nothing).
    """

    def __init__(self, limbs: list[tuple[int, int]], **kwargs):
        super().__init__(**kwargs)
        self.limbs = [(int(a), int(b)) for a, b in limbs]
        if not self.limbs:
            raise ValueError("LimbSigma needs at least one limb")

    def update(self, positions: torch.Tensor) -> None:
        self._accumulate(*limb_sigmas(positions, self.limbs))
