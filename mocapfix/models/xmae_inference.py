"""One XMAE reconstruction pass, shared by validation, testing, prediction and `fix`.

Normalisation is the paper's: the per-window mean x, y of the observed tokens is removed before
the model and added back after, so the model never sees absolute field coordinates.
"""

from __future__ import annotations

import torch

from mocapfix.data.corruption import denormalize, kept_index, normalize
from mocapfix.fills.classical import hermite_infill, lerp_infill
from mocapfix.models.xmae import XMAE


def xmae_reconstruct(
    net: XMAE, positions: torch.Tensor, observed: torch.Tensor, fill: torch.Tensor | None = None
) -> torch.Tensor:
    """positions: (B, T, J, 3) metres (values at unobserved tokens are ignored, NaN allowed);
    observed: (B, T, J) bool -> every token's reconstruction (B, T, J, 3), metres.
    fill: (B, T, J, 3) metres, the classical fill a fill_input network corrects, when the caller
    has a better one than the window's own (fix: the whole take's, at its own frame rate)."""
    B, T, J, _ = positions.shape
    positions = torch.where(
        observed[..., None], positions, torch.zeros((), dtype=positions.dtype, device=positions.device)
    )
    x, offset = normalize(positions, observed)
    kept, padding = kept_index(observed)
    if not padding.any():  # every window has the same observed count (e.g. fully observed)
        padding = None  # no mask: the fastest attention kernels apply
    if not net.fill_input:
        fill = None
    elif fill is None:
        fill = xmae_fill(x, observed, net.fill_kind)
    else:  # in the window's normalised frame, as the tokens
        fill = (fill.to(x.dtype) - offset).reshape(B, T * J, 3)
    out = net(x.reshape(B, T * J, 3), kept, padding, fill).reshape(B, T, J, 3)
    return denormalize(out.to(positions.dtype), offset)


def xmae_fill(x: torch.Tensor, observed: torch.Tensor, kind: str = "lerp") -> torch.Tensor:
    """The classical fill an XMAE built with fill_input corrects, of the (normalised) tokens:
    Lerp, or the cubic Hermite (fill_kind). Both run batched on the device in the training step,
    with no host round trip (scipy's spline would need one).
    x: (B, T, J, 3), observed: (B, T, J) -> (B, T*J, 3)."""
    B, T, J, _ = x.shape
    fill = hermite_infill if kind == "hermite" else lerp_infill
    return fill(x, observed).reshape(B, T * J, 3)
