"""What a fill is: the one interface every way of filling a hole has, and the candidates a fill
policy chooses among (a fill, the mean of two, or a stack: STACK).

A Fill gives one or more named candidates for the same holes: the classical fills one each
(classical.py), motion matching two from one search (motion_matching.py), a model one (model.py;
fix/ hands in its own, its windows blended over the take). Whoever needs fills holds Fill objects
and asks them for the candidates it needs (`made`); nothing here knows which fill is which.
"""

from __future__ import annotations

import torch

from mocapfix.core.skeleton import Skeleton

BLEND = "+"  # "a+b": the mean of fills a and b
# "a*b": the Hermite fill plus a's and b's steps away from it, each weighted as the recording's
# cut holes say (least squares; errors.py measures it, policy.py keeps the weights per kind of
# hole): a model's correction and motion matching's both start from the Hermite fill and err in
# different ways, so part of each step adds to the other.
STACK = "*"
STACK_ORIGIN = "hermite"


class Shared:
    """What the fills made together for the same takes share, made by the first fill that needs it
    (made, made_for_choice): lerp, the takes' Lerp fill (B, T, J, 3), None until then. Each
    classical fill asked for a few holes answers the others with it: made by each, five times per
    kind of hole measured, it was 7 % of `fix --mode both`'s CPU."""

    def __init__(self):
        self.lerp: torch.Tensor | None = None


class Fill:
    """One way to fill holes. names: the candidates it gives.

    fill(positions (B, T, J, 3) metres, NaN allowed at missing tokens; observed (B, T, J) bool;
    fps of the takes (None where unknown); skeleton; asked (B, T, J) bool, the missing tokens
    whose fill is wanted, None: all; shared: what the fills made together for these takes share,
    None: nothing) -> name -> (B, T, J, 3). Where nothing of a hole is asked for, a fill may skip
    its work and give a cheaper answer (a policy measured on holes cut into a take asks for
    those, not for the take's own): the Lerp fill, `shared.lerp`."""

    names: tuple[str, ...] = ()

    def fill(
        self,
        positions: torch.Tensor,
        observed: torch.Tensor,
        fps: float | None,
        skeleton: Skeleton,
        asked: torch.Tensor | None = None,
        shared: Shared | None = None,
    ) -> dict[str, torch.Tensor]:
        raise NotImplementedError


class Made(Fill):
    """A fill already made elsewhere: (B, T, J, 3) under its name (fix's model fill, made by the
    windows that fixed the take); one take's (B = 1) is every take's of a batch of its copies
    (a policy's measurement fills one copy of a take per kind of hole cut into it)."""

    def __init__(self, name: str, values: torch.Tensor):
        self.names, self.values = (name,), values

    def fill(self, positions, observed, fps, skeleton, asked=None, shared=None) -> dict[str, torch.Tensor]:
        if len(self.values) == 1 and len(positions) > 1:
            return {self.names[0]: self.values.expand(len(positions), *self.values.shape[1:])}
        return {self.names[0]: self.values}


def made(
    fills: list[Fill],
    positions: torch.Tensor,
    observed: torch.Tensor,
    fps: float | None,
    skeleton: Skeleton,
    wanted: set[str] | None = None,
    asked: torch.Tensor | None = None,
) -> dict[str, torch.Tensor]:
    """Every candidate of `fills` (in their order), or those that `wanted`'s candidates (blends
    too) are made of: a fill none of whose names is wanted is not run. asked: Fill.fill's."""
    needed = None if wanted is None else {c for m in wanted for c in components(m)}
    out: dict[str, torch.Tensor] = {}
    shared = Shared()
    for f in fills:
        if needed is None or needed & set(f.names):
            out.update(f.fill(positions, observed, fps, skeleton, asked, shared))
    return out


def made_for_choice(
    fills: list[Fill],
    positions: torch.Tensor,
    observed: torch.Tensor,
    fps: float | None,
    skeleton: Skeleton,
    names: list[str],
    choice: torch.Tensor,
) -> dict[str, torch.Tensor]:
    """The candidates of `names`, each Fill asked only for the missing tokens whose chosen
    candidate (choice: (B, T, J) index into names) has one of its fills in it: a fill a hole does
    not take may skip that hole's work (motion matching searches only the holes it fills). The
    tokens taken from each candidate are those of made(fills, ..., names)."""
    out: dict[str, torch.Tensor] = {}
    shared = Shared()
    for f in fills:
        uses = [i for i, m in enumerate(names) if set(components(m)) & set(f.names)]
        if uses:
            asked = ~observed & torch.isin(choice, torch.tensor(uses, device=choice.device))
            out.update(f.fill(positions, observed, fps, skeleton, asked, shared))
    return out


def components(method: str) -> list[str]:
    """The single fills a candidate is made of: "limb+spline" -> ["limb", "spline"],
    "correction*match_delta" -> ["hermite", "correction", "match_delta"]."""
    if STACK in method:
        return [STACK_ORIGIN, *method.split(STACK)]
    return method.split(BLEND)


def stacked(origin: torch.Tensor, steps: list[torch.Tensor], weights: torch.Tensor) -> torch.Tensor:
    """A stack's fill: origin (..., 3) plus each step's (steps: (..., 3) fills) difference from it
    times its weight (weights: (..., K), one per step, for every token)."""
    return origin + sum(weights[..., k, None] * (step - origin) for k, step in enumerate(steps))


def blends(fills: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """fills: name -> (..., 3) -> the same plus the mean of every pair, named "a+b" (sorted)."""
    names = sorted(fills)
    out = dict(fills)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            out[a + BLEND + b] = 0.5 * (fills[a] + fills[b])
    return out


def pick(
    fills: dict[str, torch.Tensor],
    names: list[str],
    choice: torch.Tensor,
    positions: torch.Tensor,
    observed: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Each missing token from the candidate names[choice] (a fill of `fills`, or the mean of the
    fills a blend names) -> (B, T, J, 3) with observed tokens as given, and (B, T, J) the index
    into names of the candidate each token took (-1 for observed tokens).
    choice: (B, T, J) index into names; positions (B, T, J, 3); observed (B, T, J) bool."""
    stacked = torch.stack([_candidate(fills, m) for m in names])  # (M, B, T, J, 3)
    out = stacked.gather(0, choice[None, ..., None].expand(1, *choice.shape, 3))[0]
    return torch.where(observed[..., None], positions, out), torch.where(observed, -1, choice)


def _candidate(fills: dict[str, torch.Tensor], method: str) -> torch.Tensor:
    if method in fills:
        return fills[method]
    if STACK in method:  # its weights are the policy's: FillPolicy.transform makes it
        raise ValueError(f"the stack {method!r} was not made")
    parts = components(method)
    return sum(fills[m] for m in parts) / len(parts)
