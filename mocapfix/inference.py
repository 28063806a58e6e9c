"""One XMAE reconstruction pass, shared by validation, testing, prediction and `fix`.

Normalisation is the paper's: the per-window mean x, y of the observed tokens is removed before
the model and added back after, so the model never sees absolute field coordinates.
"""
from __future__ import annotations

import torch

from mocapfix.data.corruption import denormalize, kept_index, normalize
from mocapfix.models.xmae import XMAE


def xmae_reconstruct(net: XMAE, positions: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
    """positions: (B, T, J, 3) metres (values at unobserved tokens are ignored, NaN allowed);
    observed: (B, T, J) bool -> every token's reconstruction (B, T, J, 3), metres."""
    B, T, J, _ = positions.shape
    positions = torch.where(observed[..., None], positions, torch.zeros((), dtype=positions.dtype,
                                                                        device=positions.device))
    x, offset = normalize(positions, observed)
    kept, padding = kept_index(observed)
    if not padding.any():  # every window has the same observed count (e.g. fully observed)
        padding = None     # no mask: the fastest attention kernels apply
    out = net(x.reshape(B, T * J, 3), kept, padding).reshape(B, T, J, 3)
    return denormalize(out.to(positions.dtype), offset)
