"""XMAE: a masked auto-encoder over joint tokens with a cross-attention decoder.

Björkstrand, Sullivan, Bretzner, Loy and Wang, "Cross-attention Masked Auto-Encoder for Human
3D Motion Infilling and Denoising", BMVC 2023; section 3 and Table 1 of the paper:
one token per joint per frame (joint index fastest), the encoder sees observed tokens only,
the decoder's queries are a learnable mask vector plus positional encodings for ALL J*T
positions and the encoded tokens enter only through cross-attention. Because the queries never
change with the number of missing tokens, there is no train/test gap in the decoder input.

decoder="mae" is the original MAE design (ablation, section 4.3): encoded tokens scattered back
to their positions, mask tokens elsewhere, self-attention only.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn as nn
import torch.nn.functional as F


class Attention(nn.Module):
    """Multi-head attention on top of scaled_dot_product_attention (flash / memory-efficient
    kernels apply on GPU when there is no mask)."""

    def __init__(self, dim: int, head_dim: int = 64, kv_dim: int | None = None):
        super().__init__()
        assert dim % head_dim == 0, f"width {dim} is not a multiple of the head dim {head_dim}"
        self.num_heads, self.head_dim = dim // head_dim, head_dim
        kv_dim = kv_dim or dim
        self.q = nn.Linear(dim, dim)
        self.kv = nn.Linear(kv_dim, 2 * dim)
        self.proj = nn.Linear(dim, dim)

    def forward(
        self, x: torch.Tensor, context: torch.Tensor | None = None, key_padding: torch.Tensor | None = None
    ) -> torch.Tensor:
        # x: (B, Nq, D); context: (B, Nk, Dkv) (x itself for self-attention); key_padding: (B, Nk) True = ignore
        context = x if context is None else context
        B, Nq, D = x.shape
        q = self.q(x).view(B, Nq, self.num_heads, self.head_dim).transpose(1, 2)  # (B, H, Nq, hd)
        k, v = self.kv(context).view(B, -1, 2, self.num_heads, self.head_dim).permute(2, 0, 3, 1, 4)
        attn_mask = None if key_padding is None else ~key_padding[:, None, None, :]  # (B, 1, 1, Nk)
        y = F.scaled_dot_product_attention(q, k, v, attn_mask=attn_mask)  # (B, H, Nq, hd)
        return self.proj(y.transpose(1, 2).reshape(B, Nq, D))


class MLP(nn.Sequential):
    def __init__(self, dim: int, hidden: int):
        super().__init__(nn.Linear(dim, hidden), nn.ReLU(), nn.Linear(hidden, dim))


class EncoderBlock(nn.Module):
    """Pre-norm transformer block: self-attention, MLP."""

    def __init__(self, dim: int, mlp_dim: int, head_dim: int):
        super().__init__()
        self.norm1, self.attn = nn.LayerNorm(dim), Attention(dim, head_dim)
        self.norm2, self.mlp = nn.LayerNorm(dim), MLP(dim, mlp_dim)

    def forward(self, x, key_padding=None):
        x = x + self.attn(self.norm1(x), key_padding=key_padding)
        return x + self.mlp(self.norm2(x))


class DecoderBlock(nn.Module):
    """Pre-norm transformer decoder block: self-attention over the queries, cross-attention into
    the encoded tokens, MLP (the original Transformer's decoder layer)."""

    def __init__(self, dim: int, mlp_dim: int, head_dim: int):
        super().__init__()
        self.norm1, self.self_attn = nn.LayerNorm(dim), Attention(dim, head_dim)
        self.norm2, self.cross_attn = nn.LayerNorm(dim), Attention(dim, head_dim)
        self.norm3, self.mlp = nn.LayerNorm(dim), MLP(dim, mlp_dim)

    def forward(self, q, memory, memory_padding=None):
        return self.attend_memory(self.attend_queries(q), memory, memory_padding)

    def attend_queries(self, q):
        # q: (B, N, Dd)
        return q + self.self_attn(self.norm1(q))

    def attend_memory(self, q, memory, memory_padding=None):
        # q: (B, N, Dd); memory: (B, K, Dd); memory_padding: (B, K) True = ignore
        q = q + self.cross_attn(self.norm2(q), memory, key_padding=memory_padding)
        return q + self.mlp(self.norm3(q))


def _full_precision(layer: nn.Linear, x: torch.Tensor) -> torch.Tensor:
    """layer(x) outside autocast, in the layer's own dtype. For the layers that read and write 3D
    coordinates: bf16 keeps 8 significant bits, which would round a 1.5 m coordinate (15 units) to
    6 mm steps at the input and at the output, a noise floor of up to 3 mm on every estimate (and
    jitter between frames).
    Their cost is negligible (3 channels in or out)."""
    with torch.autocast(x.device.type, enabled=False):
        return layer(x.to(layer.weight.dtype))


@dataclass
class XMAEConfig:
    """Everything that decides the network's shape: saved in every checkpoint (models/build.py)."""

    num_joints: int
    num_frames: int
    enc_dim: int = 256
    enc_depth: int = 6
    enc_mlp_dim: int = 1024
    dec_dim: int = 128
    dec_depth: int = 3
    dec_mlp_dim: int = 512
    head_dim: int = 64
    decoder: str = "cross"
    position_unit_m: float = 0.1
    fill_input: bool = False
    fill_kind: str = "lerp"


# Named sizes (facebookresearch/mae's mae_vit_base_patch16 habit): a config names one and sets
# only what differs. "paper" is Table 1. "cpu" is what a 2-core CPU trains in under an hour
# (configs/xmae_cpu.yaml): narrow layers leave the mean-pose plateau within a few hundred
# steps where wide ones sit on it for thousands, and fill_input starts it at the interpolation.
PRESETS: dict[str, dict] = {
    "paper": {},
    "cpu": dict(
        enc_dim=64, enc_depth=2, enc_mlp_dim=256, dec_dim=64, dec_depth=1, dec_mlp_dim=256, head_dim=32, fill_input=True
    ),
}


def preset_sizes(preset: str, **overrides) -> dict:
    """The network's sizes: the preset's, then every override that is not None (num_joints and
    num_frames come from the data). ValueError for an unknown preset or widths the heads do not
    divide, said in the config's terms before anything is built."""
    if preset not in PRESETS:
        raise ValueError(f"preset must be one of {', '.join(PRESETS)}, got {preset!r}")
    sizes = {**PRESETS[preset], **{k: v for k, v in overrides.items() if v is not None}}
    defaults = XMAEConfig(0, 0)
    enc_dim, dec_dim, head_dim = (sizes.get(k, getattr(defaults, k)) for k in ("enc_dim", "dec_dim", "head_dim"))
    if head_dim < 1 or enc_dim % head_dim or dec_dim % head_dim:
        raise ValueError(
            f"enc_dim ({enc_dim}) and dec_dim ({dec_dim}) must be multiples of head_dim ({head_dim}): "
            "attention splits each width into heads of head_dim channels"
        )
    return sizes


# The classical fills fill_input can correct (models/xmae_inference.py: xmae_fill).
FILL_KINDS = ("lerp", "hermite")


class XMAE(nn.Module):
    def __init__(
        self,
        num_joints: int,
        num_frames: int,
        enc_dim: int = 256,
        enc_depth: int = 6,
        enc_mlp_dim: int = 1024,
        dec_dim: int = 128,
        dec_depth: int = 3,
        dec_mlp_dim: int = 512,
        head_dim: int = 64,
        decoder: str = "cross",
        position_unit_m: float = 0.1,
        fill_input: bool = False,
        fill_kind: str = "lerp",
    ):
        super().__init__()
        if decoder not in ("cross", "mae"):
            raise ValueError(f"decoder must be 'cross' (XMAE) or 'mae' (original MAE), got {decoder!r}")
        if fill_input and decoder != "cross":
            raise ValueError("fill_input needs the cross-attention decoder (decoder='cross')")
        if fill_kind not in FILL_KINDS:
            raise ValueError(f"fill_kind must be one of {', '.join(FILL_KINDS)}, got {fill_kind!r}")
        self.num_joints, self.num_frames, self.decoder_type = num_joints, num_frames, decoder
        # what a checkpoint stores to rebuild this network (models/build.py)
        self.config = XMAEConfig(
            num_joints,
            num_frames,
            enc_dim,
            enc_depth,
            enc_mlp_dim,
            dec_dim,
            dec_depth,
            dec_mlp_dim,
            head_dim,
            decoder,
            position_unit_m,
            fill_input,
            fill_kind,
        )
        # Not in the paper: with fill_input the decoder's queries also carry a classical fill of
        # every token (xmae_inference.py: Lerp) and the network predicts the correction to it. A small
        # network then starts from the interpolation instead of having to learn it, and spends its
        # capacity on what interpolation gets wrong.
        # fill_kind "hermite": a cubic that leaves and meets the data at its velocities
        # (fills/classical.py: hermite_infill), about a cubic spline's accuracy; fix then hands
        # the network the take's whole-context fill at the recording's own frame rate
        # (fix/position_windows.py), and the untrained network is that fill.
        self.fill_input, self.fill_kind = fill_input, fill_kind
        # The network reads and writes positions in units of position_unit_m (default 0.1 m).
        # In metres, a joint's motion within a window (cm) is a tiny signal beside the metre-scale
        # body, and training sits at the mean pose for thousands of steps (docs/xmae-notes.md).
        self.position_unit_m = position_unit_m
        # eq. (2): W x + P_joint[j] + P_time[t]
        self.embed = nn.Linear(3, enc_dim)
        self.enc_pos_joint = nn.Parameter(torch.zeros(num_joints, enc_dim))
        self.enc_pos_time = nn.Parameter(torch.zeros(num_frames, enc_dim))
        self.encoder = nn.ModuleList([EncoderBlock(enc_dim, enc_mlp_dim, head_dim) for _ in range(enc_depth)])
        self.enc_norm = nn.LayerNorm(enc_dim)
        self.enc_to_dec = nn.Linear(enc_dim, dec_dim)
        if decoder == "cross":
            # eq. (4): m + P_joint[j] + P_time[t] with the SAME positional encodings as the token
            # embedding, in the encoder's width, brought to the decoder's width by the same
            # projection as the encoded tokens. Queries and keys then share one positional code:
            # with separate decoder encodings the cross-attention has to learn to align two
            # unrelated codes, and in practice it does not (the output collapses to a mean pose).
            self.mask_token = nn.Parameter(torch.zeros(enc_dim))
            if fill_input:
                self.fill_embed = nn.Linear(3, dec_dim)
        else:
            # original MAE: the decoder has its own positional encodings, added to mask tokens and
            # to the encoded tokens alike (MAE's decoder_pos_embed), which aligns them.
            self.mask_token = nn.Parameter(torch.zeros(dec_dim))
            self.dec_pos_joint = nn.Parameter(torch.zeros(num_joints, dec_dim))
            self.dec_pos_time = nn.Parameter(torch.zeros(num_frames, dec_dim))
        block = DecoderBlock if decoder == "cross" else EncoderBlock
        self.decoder = nn.ModuleList([block(dec_dim, dec_mlp_dim, head_dim) for _ in range(dec_depth)])
        self.dec_norm = nn.LayerNorm(dec_dim)
        self.head = nn.Linear(dec_dim, 3)
        self.apply(self._init_weights)
        # Positional encodings start at unit scale (nn.Embedding's default), not MAE's 0.02:
        # queries find their joint's observed tokens only through them, and from 0.02 the
        # cross-attention takes thousands of steps to start routing (docs/xmae-notes.md).
        for p in (
            self.enc_pos_joint,
            self.enc_pos_time,
            getattr(self, "dec_pos_joint", None),
            getattr(self, "dec_pos_time", None),
        ):
            if p is not None:
                nn.init.normal_(p, std=1.0)
        nn.init.normal_(self.mask_token, std=0.02)
        if fill_input:  # the correction starts at zero: the untrained network answers the fill itself
            nn.init.zeros_(self.head.weight)

    @staticmethod
    def _init_weights(m):
        if isinstance(m, nn.Linear):
            nn.init.xavier_uniform_(m.weight)
            nn.init.zeros_(m.bias)

    @staticmethod
    def _positions(pos_joint: torch.Tensor, pos_time: torch.Tensor) -> torch.Tensor:
        # (J, D), (T, D) -> (T*J, D), joint index fastest as the token order of eq. (1)
        return (pos_time[:, None, :] + pos_joint[None, :, :]).flatten(0, 1)

    def encode(self, tokens: torch.Tensor, kept: torch.Tensor, padding: torch.Tensor | None) -> torch.Tensor:
        # tokens: (B, N, 3) all J*T tokens (values at unobserved ones are never read)
        # kept: (B, K) indices of observed tokens; padding: (B, K) True where kept is padding
        x = torch.gather(tokens, 1, kept[..., None].expand(-1, -1, 3)) / self.position_unit_m  # (B, K, 3)
        pos = self._positions(self.enc_pos_joint, self.enc_pos_time)  # (N, D)
        x = _full_precision(self.embed, x) + pos[kept]  # (B, K, D)
        for blk in self.encoder:
            x = blk(x, key_padding=padding)
        return self.enc_to_dec(self.enc_norm(x))  # (B, K, Dd)

    def decode(
        self, memory: torch.Tensor, kept: torch.Tensor, padding: torch.Tensor | None, fill: torch.Tensor | None = None
    ) -> torch.Tensor:
        B = memory.shape[0]
        if self.decoder_type == "cross":
            pos = self._positions(self.enc_pos_joint, self.enc_pos_time)  # (N, D)
            queries = self.enc_to_dec(self.mask_token + pos)[None]  # (1, N, Dd)
            # The queries are the same for every sample, and so is the first block's
            # self-attention over them (the samples first differ in its cross-attention): run it
            # once, not B times: attention over all J*T queries is the decoder's largest layer, and
            # this one is 13 % of a training step's arithmetic (docs/performance.md).
            first = self.decoder[0]
            x = first.attend_queries(queries).expand(B, -1, -1)  # (B, N, Dd)
            if fill is not None:  # each query learns its token's fill after the shared part
                x = x + _full_precision(self.fill_embed, fill / self.position_unit_m).to(x.dtype)
            x = first.attend_memory(x, memory, padding)  # (B, N, Dd)
            for blk in self.decoder[1:]:
                x = blk(x, memory, memory_padding=padding)
        else:  # MAE: encoded tokens replace the mask tokens at their own positions
            pos = self._positions(self.dec_pos_joint, self.dec_pos_time)  # (N, Dd)
            queries = (self.mask_token + pos).expand(B, -1, -1)  # (B, N, Dd)
            index = kept
            if padding is not None:  # padded slots land on a spare position N, dropped after
                index = kept.masked_fill(padding, queries.shape[1])
            x = torch.cat([queries, queries[:, :1]], dim=1)  # (B, N+1, Dd)
            x = x.scatter(1, index[..., None].expand(-1, -1, memory.shape[-1]), memory + pos[kept])[:, :-1]
            for blk in self.decoder:
                x = blk(x)
        out = _full_precision(self.head, self.dec_norm(x)) * self.position_unit_m  # (B, N, 3) metres
        return out if fill is None else fill + out

    def forward(
        self,
        tokens: torch.Tensor,
        kept: torch.Tensor,
        padding: torch.Tensor | None = None,
        fill: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """tokens: (B, N, 3), N = T*J (t-major, joint fastest); kept: (B, K) observed token indices;
        padding: (B, K) True where a sample has fewer than K observed tokens (None: all real; pass
        None when you know it, the attention then runs without a mask, on the fastest kernels);
        fill: (B, N, 3) a classical fill of every token, in the tokens' frame (fill_input only).
        Returns every token's 3D position (B, N, 3)."""
        if (fill is not None) != self.fill_input:
            raise ValueError("pass fill exactly when the network was built with fill_input")
        if padding is not None:
            # A sample with no observed token would attend to nothing (NaN): let it attend to one
            # zero-valued slot instead; its output is then the model's unconditional guess.
            # (Elementwise, not padding[padding.all(1), 0] = False: boolean indexing waits for the device.)
            first = torch.arange(padding.shape[1], device=padding.device) == 0  # (K,)
            padding = padding & ~(padding.all(1, keepdim=True) & first)
        return self.decode(self.encode(tokens, kept, padding), kept, padding, fill)
