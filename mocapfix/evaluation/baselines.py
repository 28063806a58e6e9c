"""Lerp: the linear-interpolation baseline of the XMAE tables."""
from __future__ import annotations

import torch


def lerp_infill(positions: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
    """Fill every unobserved token by linear interpolation in time between the nearest observed
    frames of the same joint.

    positions: (B, T, J, 3) (values at unobserved tokens are ignored, NaN allowed there)
    observed: (B, T, J) bool
    -> (B, T, J, 3), never NaN where something could be filled:
    - observed tokens are returned bit-identical (a token marked observed but holding NaN is
      treated as unobserved);
    - a gap touching the window border holds the nearest observed value;
    - a joint never observed in the window takes, at each frame, the mean of the (interpolated)
      joints that are observed somewhere in the window: a crude guess that at least stays on the
      body; 0 if no joint of the window is observed at all.
    """
    B, T, J, _ = positions.shape
    obs = observed.to(torch.bool) & ~torch.isnan(positions).any(dim=-1)
    t = torch.arange(T, device=positions.device).view(1, T, 1).expand(B, T, J)

    # Index of the last observed frame at or before t (-1 if none), and of the first at or
    # after t (T if none): running max forward, running min backward.
    prev = torch.where(obs, t, -1).cummax(dim=1).values
    nxt = torch.where(obs, t, T).flip(1).cummin(dim=1).values.flip(1)
    has_prev, has_next = prev >= 0, nxt < T
    p_val = positions.gather(1, prev.clamp(0, T - 1)[..., None].expand(B, T, J, 3))
    n_val = positions.gather(1, nxt.clamp(0, T - 1)[..., None].expand(B, T, J, 3))

    # Weight of the next frame; one-sided gaps get 0 or 1 (hold the edge value).
    span = (nxt - prev).clamp_min(1).to(positions.dtype)
    w = ((t - prev).to(positions.dtype) / span)
    w = torch.where(has_prev, torch.where(has_next, w, 0.0), 1.0)[..., None]
    # the branch not taken may hold NaN (clamped gathers of missing tokens): where() keeps it out
    filled = torch.where(w == 0, p_val, torch.where(w == 1, n_val, p_val + w * (n_val - p_val)))

    # Joints with no observation in the window: per-frame mean of the joints that have one.
    seen = obs.any(dim=1, keepdim=True)  # (B, 1, J)
    zero = torch.zeros((), dtype=positions.dtype, device=positions.device)
    n_seen = seen.sum(dim=2, keepdim=True)[..., None]  # (B, 1, 1, 1)
    body_mean = torch.where(seen[..., None], filled, zero).sum(dim=2, keepdim=True) / n_seen.clamp_min(1)
    filled = torch.where(seen[..., None], filled, body_mean)

    return torch.where(obs[..., None], positions, filled)
