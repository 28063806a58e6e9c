"""One XMAE reconstruction pass, shared by validation, testing, prediction and `fix`, and the
window as XMAE reads it, shared with training (training/xmae_input.py).

Normalisation is the paper's: the per-window mean x, y of the observed tokens is removed before
the model and added back after, so the model never sees absolute field coordinates. The encoder
reads the observed tokens only, gathered by kept_index.
"""

from __future__ import annotations

import torch

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


# --- the window as XMAE reads it ---


def normalize(positions: torch.Tensor, observed: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Subtract each window's mean x and y over its observed tokens (displaced ones included);
    z (up) is untouched.

    positions: (B, T, J, 3), observed: (B, T, J) bool
    -> normalized (B, T, J, 3) = positions - offset at EVERY token (unobserved ones too, so the
    same offset applies to targets: `target - offset`), offset (B, 1, 1, 3) with offset z = 0.
    A window with no observed token gets offset 0. NaN at unobserved tokens never reaches the mean.
    """
    zero = torch.zeros((), dtype=positions.dtype, device=positions.device)
    obs = observed[..., None]
    total = torch.where(obs, positions, zero).sum(dim=(1, 2), keepdim=True)  # (B, 1, 1, 3)
    count = obs.sum(dim=(1, 2), keepdim=True).clamp_min(1).to(positions.dtype)  # (B, 1, 1, 1)
    offset = total / count
    offset = torch.cat([offset[..., :2], torch.zeros_like(offset[..., 2:])], dim=-1)
    return positions - offset, offset


def denormalize(positions: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
    """Inverse of normalize: positions (B, T, J, 3) + offset (B, 1, 1, 3)."""
    return positions + offset


def kept_index(observed: torch.Tensor, count: int | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Index form of the observed tokens, for an encoder that should not see masked tokens.

    observed: (B, T, J) bool -> idx (B, K) long, pad (B, K) bool.
    idx[b] lists the flat indices (t * J + j) of sample b's observed tokens in increasing order,
    then padding: padded entries have pad=True and idx=0 (a valid index, so gathers stay safe).
    K = count when given (no sample may have more observed tokens: training's fixed kept count),
    else the largest observed count in the batch (0 when nothing is observed). Reading that
    count from the data makes the host wait for the device; a given count keeps the training
    step free of host-device synchronisation.
    """
    B = observed.shape[0]
    flat = observed.reshape(B, -1)
    counts = flat.sum(dim=1)
    K = count if count is not None else int(counts.max()) if flat.numel() else 0
    # stable sort of (not observed) puts observed tokens first, each group in index order
    order = torch.sort((~flat).to(torch.uint8), dim=1, stable=True).indices[:, :K]
    pad = torch.arange(K, device=observed.device)[None, :] >= counts[:, None]
    return order.masked_fill(pad, 0), pad
