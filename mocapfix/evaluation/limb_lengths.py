"""Limb sigma's arithmetic, in plain torch: the standard deviation over time of each limb's length
within a sequence. metrics.LimbSigma accumulates it as a torchmetrics Metric; fix's report
(fix/report.py) sums it itself, so that `fix` never imports torchmetrics (over a second of every
run's start)."""

from __future__ import annotations

import torch

M_TO_MM = 1000.0


def limb_sigmas(positions: torch.Tensor, limbs: list[tuple[int, int]]) -> tuple[torch.Tensor, torch.Tensor]:
    """positions: (B, T, J, 3) metres, NaN where missing; limbs: (joint_a, joint_b) pairs ->
    (B, L) each sequence's std of each limb's length in mm (population std, ddof=0, over the
    frames where both joints have data), and (B, L) bool: valid where there were 2 such frames or
    more (a std of fewer says nothing)."""
    a = torch.tensor([parent for parent, _ in limbs], device=positions.device)
    b = torch.tensor([child for _, child in limbs], device=positions.device)
    length = (positions[:, :, a] - positions[:, :, b]).norm(dim=-1)  # (B, T, L)
    ok = ~torch.isnan(length)
    zero = torch.zeros((), dtype=length.dtype, device=length.device)
    n = ok.sum(dim=1)  # (B, L)
    mean = torch.where(ok, length, zero).sum(dim=1) / n.clamp_min(1)
    var = torch.where(ok, (length - mean[:, None]) ** 2, zero).sum(dim=1) / n.clamp_min(1)
    return M_TO_MM * var.sqrt(), n >= 2
