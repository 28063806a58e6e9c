"""A take's holes filled as a fill policy says: every fill the policy may name is made for the
whole take (the model's comes made), and each hole takes the one named for its part and length."""

from __future__ import annotations

import numpy as np
import torch

from mocapfix.core.skeleton import Skeleton
from mocapfix.fills.classical import CLASSICAL
from mocapfix.fills.motion_matching import FILLS as MATCH_FILLS
from mocapfix.fills.motion_matching import Searchable, match_fills
from mocapfix.fills.policy import FillPolicy, apply_fill_policy, policy_names


def policy_fill(
    policy: FillPolicy,
    x: np.ndarray,
    obs: np.ndarray,
    model_fill: np.ndarray,
    fps: float,
    skeleton: Skeleton,
    counts: dict[str, int],
    library: Searchable | None = None,
) -> np.ndarray:
    """x: (T, J, 3) one clip's data, obs: (T, J), model_fill: (T, J, 3) the model's fill -> each
    hole filled by the method the policy names for its length and part; counts[method] += tokens.
    library: the other takes the motion-matching fills search (MotionLibrary.without)."""
    xt, ot = torch.from_numpy(x)[None], torch.from_numpy(obs)[None]
    fills = {"xmae": torch.from_numpy(model_fill)[None]}
    methods = set(policy.methods())
    fills.update({m: CLASSICAL[m](xt, ot, skeleton.parents) for m in methods if m in CLASSICAL})
    if methods & set(MATCH_FILLS):
        hermite = fills["hermite"] if "hermite" in fills else CLASSICAL["hermite"](xt, ot, skeleton.parents)
        found = match_fills(x, obs, hermite[0].numpy(), library, fps)
        fills.update({m: torch.from_numpy(f)[None] for m, f in found.items()})
    out, chosen = apply_fill_policy(policy, xt, ot, fills, fps, skeleton)
    names = policy_names(policy, fills)
    for i, n in enumerate(torch.bincount(chosen[chosen >= 0], minlength=len(names)).tolist()):
        if n:
            counts[names[i]] = counts.get(names[i], 0) + n
    return out[0].numpy()
