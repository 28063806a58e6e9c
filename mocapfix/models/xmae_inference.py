"""One XMAE reconstruction pass, shared by validation, testing, prediction and `fix`.

Normalisation is the paper's: the per-window mean x, y of the observed tokens is removed before
the model and added back after, so the model never sees absolute field coordinates.
"""

from __future__ import annotations

import torch

from mocapfix.data.corruption import denormalize, kept_index, normalize
from mocapfix.evaluation.baselines import lerp_infill
from mocapfix.models.xmae import XMAE


def xmae_reconstruct(net: XMAE, positions: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
    """positions: (B, T, J, 3) metres (values at unobserved tokens are ignored, NaN allowed);
    observed: (B, T, J) bool -> every token's reconstruction (B, T, J, 3), metres."""
    B, T, J, _ = positions.shape
    positions = torch.where(
        observed[..., None], positions, torch.zeros((), dtype=positions.dtype, device=positions.device)
    )
    x, offset = normalize(positions, observed)
    kept, padding = kept_index(observed)
    if not padding.any():  # every window has the same observed count (e.g. fully observed)
        padding = None  # no mask: the fastest attention kernels apply
    fill = xmae_fill(x, observed) if net.fill_input else None
    out = net(x.reshape(B, T * J, 3), kept, padding, fill).reshape(B, T, J, 3)
    return denormalize(out.to(positions.dtype), offset)


def xmae_fill(x: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
    """The classical fill an XMAE built with fill_input corrects: Lerp of the (normalised) tokens.
    x: (B, T, J, 3), observed: (B, T, J) -> (B, T*J, 3). Lerp, not a spline: it runs on the device
    in the training step, with no host round trip."""
    B, T, J, _ = x.shape
    return lerp_infill(x, observed).reshape(B, T * J, 3)
