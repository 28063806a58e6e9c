"""A model's fill beside the classical ones, on the evaluation tasks: what a fill policy is
calibrated on (val windows) and what it outputs (test windows, as `fix` would). The model enters
as a function, reconstruct(positions, observed) -> every token's estimate, so this knows no
network and no training code."""

from __future__ import annotations

from collections.abc import Callable

import torch

from mocapfix.core.skeleton import Skeleton
from mocapfix.evaluation.baselines import CLASSICAL
from mocapfix.evaluation.policy import Calibration, FillPolicy, apply_fill_policy, suspect_tokens
from mocapfix.evaluation.tasks import paper_tasks

# positions: (B, T, J, 3) metres, NaN allowed at unobserved tokens; observed: (B, T, J) -> (B, T, J, 3)
Reconstruct = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


def candidate_fills(
    reconstruct: Reconstruct, positions: torch.Tensor, observed: torch.Tensor, skeleton: Skeleton
) -> dict[str, torch.Tensor]:
    """Every candidate fill of the unobserved tokens: the model's ("xmae") and the classical ones
    (which leave observed tokens as given)."""
    return {
        "xmae": reconstruct(positions, observed),
        **{name: fill(positions, observed, skeleton.parents) for name, fill in CLASSICAL.items()},
    }


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


def policy_output(
    policy: FillPolicy,
    reconstruct: Reconstruct,
    positions: torch.Tensor,
    observed: torch.Tensor,
    fills: dict[str, torch.Tensor],
    fps: float,
    skeleton: Skeleton,
) -> torch.Tensor:
    """What `fix --mode both` outputs for windows: the suspect observed tokens taken out, then every
    hole filled by the method the policy names. fills: candidate_fills(..., positions, observed).
    Suspect here is beyond the replace threshold (the paper's displacement task scatters single
    tokens over 1-s windows); fix on whole recordings replaces only excursions, a jump away from
    the estimate and back (evaluation/policy.py: excursions), which leaves smooth disagreement alone."""
    suspect = suspect_tokens(policy, fills["xmae"], positions, observed)
    keep = observed & ~suspect
    if suspect.any():  # other holes: fill again
        fills = candidate_fills(reconstruct, positions, keep, skeleton)
    return apply_fill_policy(policy, positions, keep, fills, fps, skeleton)[0]
