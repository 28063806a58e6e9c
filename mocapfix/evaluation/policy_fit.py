"""The fill policy fitted on the val split: every candidate fill (fills/model.py) measured on the
paper's infill tasks over clean val windows, and the model's disagreement with clean tokens (the
replace threshold), summed into a fills.policy.Calibration. XMAEModule calls it at every
validation; the policy is stored in the checkpoint (fills/policy.py)."""

from __future__ import annotations

import torch

from mocapfix.core.skeleton import Skeleton
from mocapfix.evaluation.tasks import paper_tasks
from mocapfix.fills.model import Reconstruct, candidate_fills
from mocapfix.fills.policy import Calibration


def calibrate(
    calibration: Calibration,
    reconstruct: Reconstruct,
    positions: torch.Tensor,
    skeleton: Skeleton,
    fps: float,
    gaps_s: tuple[float, ...],
    generator: torch.Generator | None,
    cells: set[tuple[str, float]] | None = None,
) -> None:
    """Measure on clean windows positions (B, T, J, 3): the model's disagreement with the clean
    tokens, and every candidate on the infill tasks (one side per limb: the policy has no side);
    cells: only these (part, gap) (the holes a recording has), None: all."""
    observed = ~torch.isnan(positions).any(-1)
    calibration.add_clean(reconstruct(positions, observed), positions, observed)
    for t in paper_tasks(skeleton, gaps_s, ()):
        if t.task != "infill" or t.part.startswith("right"):
            continue
        if cells is not None and (t.part.split("_")[-1], t.gap_s) not in cells:
            continue
        c = t.corrupt(positions, fps, skeleton, generator)
        fills = candidate_fills(reconstruct, c.positions, c.observed, skeleton)
        calibration.add_fills(t.part.split("_")[-1], t.gap_s, fills, positions, t.evaluated(c, positions))
