"""A model's fill beside the classical ones: the candidates a fill policy chooses among, and what
it outputs for windows (test windows, as `fix` would). The model enters as a function,
reconstruct(positions, observed) -> every token's estimate, so this knows no network and no
training code. Measuring the candidates on the val split's windows is evaluation/policy_fit.py."""

from __future__ import annotations

from collections.abc import Callable

import torch

from mocapfix.core.skeleton import Skeleton
from mocapfix.fills.classical import classical_fills
from mocapfix.fills.fill import Fill, made
from mocapfix.fills.jumps import suspect_tokens
from mocapfix.fills.policy import FillPolicy, apply_fill_policy

# positions: (B, T, J, 3) metres, NaN allowed at unobserved tokens; observed: (B, T, J) -> (B, T, J, 3)
Reconstruct = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


class ModelFill(Fill):
    """A model's fill of windows as a Fill: its estimate of every token (observed ones included:
    the replace threshold reads them)."""

    names = ("xmae",)

    def __init__(self, reconstruct: Reconstruct):
        self.reconstruct = reconstruct

    def fill(self, positions, observed, fps, skeleton, asked=None, shared=None) -> dict[str, torch.Tensor]:
        return {self.names[0]: self.reconstruct(positions, observed)}


def candidate_fills(
    reconstruct: Reconstruct, positions: torch.Tensor, observed: torch.Tensor, skeleton: Skeleton
) -> dict[str, torch.Tensor]:
    """Every candidate fill of the unobserved tokens of windows: the model's ("xmae") and the
    classical ones (which leave observed tokens as given)."""
    return made([ModelFill(reconstruct), *classical_fills()], positions, observed, None, skeleton)


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
    the estimate and back (fills/policy.py: excursions), which leaves smooth disagreement alone."""
    suspect = suspect_tokens(policy, fills["xmae"], positions, observed)
    keep = observed & ~suspect
    if suspect.any():  # other holes: fill again
        fills = candidate_fills(reconstruct, positions, keep, skeleton)
    return apply_fill_policy(policy, positions, keep, fills, fps, skeleton)[0]
