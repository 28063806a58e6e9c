"""A training checkpoint -> a weights-only bf16 copy small enough to bring back from a lent GPU
(hyperparameters kept, optimiser state dropped): `mocapfix fix` and evaluation read it; training
cannot resume from it. --fp32 keeps the weights in float32 (Motion-DVAE runs in fp32).

    python bench/shrink_checkpoint.py checkpoints/xmae_bandai_gpu/best-*.ckpt small.ckpt
    python bench/shrink_checkpoint.py --fp32 checkpoints/motion_dvae_denoise_bvh/last.ckpt dn.ckpt
"""

from __future__ import annotations

import glob
import sys

import torch


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    fp32 = "--fp32" in argv
    argv = [a for a in argv if a != "--fp32"]
    if len(argv) != 2:
        raise SystemExit(__doc__)
    matches = sorted(glob.glob(argv[0]))
    if not matches:
        raise SystemExit(f"no checkpoint matches {argv[0]}")
    ckpt = torch.load(matches[0], map_location="cpu", weights_only=True)
    small = {k: ckpt[k] for k in ("hyper_parameters", "global_step", "epoch", "pytorch-lightning_version") if k in ckpt}
    small["state_dict"] = {
        k: v.to(torch.bfloat16) if v.is_floating_point() and not fp32 else v for k, v in ckpt["state_dict"].items()
    }
    torch.save(small, argv[1])
    print(f"{matches[0]} -> {argv[1]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
