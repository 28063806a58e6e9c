"""Benchmark (8): XMAE's attention calls under each scaled_dot_product_attention backend.

Attention is a third of the compiled H100 training step's kernel time (5.1 of 16.3 ms, session 7;
docs/performance.md (7)) and PyTorch picks the kernel (cuDNN on the H100). This times each
attention call of a training step (forward + backward) and of a batched inference pass (forward)
with every backend the device has, on the shapes the model runs: paper sizes, the encoder over the
kept tokens (all tokens at inference), the decoder's self-attention over all J*T queries (its first
block once per batch), its cross-attention into the kept tokens. A backend that cannot run a shape
is left blank. The per-step totals say what forcing one backend (torch.nn.attention.sdpa_kernel)
would gain over PyTorch's own choice ("auto").

    python bench/attention_backends.py                         # CUDA: smpl22, 60 frames, batch 128 / 1024
    python bench/attention_backends.py --device cpu --batch 4 --infer-batch 4 --fps 10
"""

from __future__ import annotations

import argparse
import contextlib
import sys

import torch
import torch.nn.functional as F
from common import add_window_arguments, describe, pick_device, print_table, timed, write_result
from torch.nn.attention import SDPBackend, sdpa_kernel

from mocapfix.data.corruption import kept_count  # noqa: E402

BACKENDS = {
    "auto": None,
    "cudnn": SDPBackend.CUDNN_ATTENTION,
    "flash": SDPBackend.FLASH_ATTENTION,
    "efficient": SDPBackend.EFFICIENT_ATTENTION,
    "math": SDPBackend.MATH,
}


def attention_calls(
    J: int,
    T: int,
    batch: int,
    infer_batch: int,
    mask_ratio: float,
    enc_heads: int,
    dec_heads: int,
    enc_depth: int,
    dec_depth: int,
) -> list[dict]:
    """The attention calls of one training step and one inference pass of XMAE (models/xmae.py):
    (batch, heads, queries, keys) and how many times each runs."""
    N, K = J * T, kept_count(J * T, mask_ratio)
    calls = []
    for phase, B, kept, backward in (("train", batch, K, True), ("infer", infer_batch, N, False)):
        calls += [
            {
                "phase": phase,
                "call": "encoder self",
                "B": B,
                "H": enc_heads,
                "Nq": kept,
                "Nk": kept,
                "count": enc_depth,
            },
            {
                "phase": phase,
                "call": "decoder self, first (once)",
                "B": 1,
                "H": dec_heads,
                "Nq": N,
                "Nk": N,
                "count": 1,
            },
            {"phase": phase, "call": "decoder self", "B": B, "H": dec_heads, "Nq": N, "Nk": N, "count": dec_depth - 1},
            {"phase": phase, "call": "decoder cross", "B": B, "H": dec_heads, "Nq": N, "Nk": kept, "count": dec_depth},
        ]
        for c in calls[-4:]:
            c["backward"] = backward
    return calls


def time_call(
    call: dict, backend, head_dim: int, dtype: torch.dtype, device: torch.device, repeat: int
) -> float | None:
    """Seconds per call (forward, + backward of a random output gradient in training), None where
    the backend has no kernel for it (or it does not fit in memory)."""
    g = torch.Generator(device=device).manual_seed(0)
    shape_q = (call["B"], call["H"], call["Nq"], head_dim)
    shape_k = (call["B"], call["H"], call["Nk"], head_dim)
    # q: (B, H, Nq, hd); k, v: (B, H, Nk, hd), as Attention.forward hands them over
    q = torch.randn(shape_q, generator=g, device=device, dtype=dtype, requires_grad=call["backward"])
    k, v = (
        torch.randn(shape_k, generator=g, device=device, dtype=dtype, requires_grad=call["backward"]) for _ in range(2)
    )
    grad = torch.randn(shape_q, generator=g, device=device, dtype=dtype)

    def run():
        with sdpa_kernel(backend) if backend is not None else contextlib.nullcontext():
            if call["backward"]:
                y = F.scaled_dot_product_attention(q, k, v)
                torch.autograd.grad(y, (q, k, v), grad)
            else:
                with torch.no_grad():
                    F.scaled_dot_product_attention(q, k, v)

    try:
        return timed(run, device, repeat=repeat, warmup=3)
    except (RuntimeError, torch.OutOfMemoryError) as e:  # "No available kernel", or too large for math
        if "kernel" not in str(e).lower() and not isinstance(e, torch.OutOfMemoryError):
            raise
        return None
    finally:
        if device.type == "cuda":
            torch.cuda.empty_cache()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_window_arguments(ap)
    ap.add_argument("--batch", type=int, default=128, help="training batch")
    ap.add_argument("--infer-batch", type=int, default=None, help="inference batch (default 1024 on CUDA, 16 on CPU)")
    ap.add_argument("--mask-ratio", type=float, default=0.85)
    ap.add_argument(
        "--backends",
        default=None,
        help=f"comma-separated subset of {', '.join(BACKENDS)} (default: all on CUDA; auto, flash, math on a CPU)",
    )
    ap.add_argument("--repeat", type=int, default=None)
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    device = pick_device(args.device)
    gpu = device.type == "cuda"
    dtype = torch.bfloat16 if gpu else torch.float32
    names = (args.backends or ("auto,cudnn,flash,efficient,math" if gpu else "auto,flash,math")).split(",")
    if unknown := sorted(set(names) - set(BACKENDS)):
        ap.error(f"unknown backends {unknown}: choose from {', '.join(BACKENDS)}")
    repeat = args.repeat or (20 if gpu else 2)
    T = int(round(args.fps * args.window_s))
    # paper sizes (Table 1; models/xmae.py defaults): widths 256 / 128, head dim 64, depths 6 / 3
    head_dim = 64
    calls = attention_calls(
        args.joints,
        T,
        args.batch,
        args.infer_batch or (1024 if gpu else 16),
        args.mask_ratio,
        enc_heads=256 // head_dim,
        dec_heads=128 // head_dim,
        enc_depth=6,
        dec_depth=3,
    )

    for call in calls:
        for name in names:
            seconds = time_call(call, BACKENDS[name], head_dim, dtype, device, repeat)
            call[f"{name}_ms"] = None if seconds is None else 1000 * seconds
        timings = {n: call[f"{n}_ms"] for n in names if call[f"{n}_ms"] is not None}
        call["fastest"] = min(timings, key=timings.get) if timings else None
    totals = []
    for phase in ("train", "infer"):
        row = {"phase": phase, "call": "total per step" if phase == "train" else "total per pass", "count": None}
        for name in names:
            ms = [c[f"{name}_ms"] for c in calls if c["phase"] == phase]
            counts = [c["count"] for c in calls if c["phase"] == phase]
            row[f"{name}_ms"] = None if None in ms else sum(m * n for m, n in zip(ms, counts))
        # every call on its own fastest backend
        row["best_mix_ms"] = sum(
            min(c[f"{n}_ms"] for n in names if c[f"{n}_ms"] is not None) * c["count"]
            for c in calls
            if c["phase"] == phase
        )
        totals.append(row)

    result = {
        "benchmark": "xmae_attention_backends",
        "env": describe(device),
        "command": " ".join(sys.argv),
        "joints": args.joints,
        "frames": T,
        "dtype": str(dtype).replace("torch.", ""),
        "head_dim": head_dim,
        "backends": names,
        "calls": calls,
        "totals": totals,
    }
    path = write_result("attention_backends", result, args.json_out)
    print_table(
        f"XMAE attention calls by SDPA backend, {result['env'].get('gpu', result['env'].get('cpu'))}, "
        f"{args.joints} joints x {T} frames, {result['dtype']}, ms per call (train: forward + backward)",
        calls + totals,
        [
            ("phase", "phase"),
            ("call", "call"),
            ("B", "B"),
            ("H", "H"),
            ("Nq", "queries"),
            ("Nk", "keys"),
            ("count", "count"),
        ]
        + [(f"{n}_ms", n) for n in names]
        + [("fastest", "fastest"), ("best_mix_ms", "best mix")],
    )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
