"""A training checkpoint -> a weights-only bf16 copy small enough to bring back from a lent GPU
or to ship (hyperparameters, the model's kind and config and the fill policy kept, optimiser
state dropped): `mocapfix fix` and evaluation read it; training cannot resume from it. --fp32
keeps the weights in float32 (Motion-DVAE runs in fp32). A checkpoint from before checkpoints
named their model gets the entry (from the network fix rebuilds).

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
    keep = ("hyper_parameters", "model", "fill_policy", "global_step", "epoch", "pytorch-lightning_version")
    small = {k: ckpt[k] for k in keep if k in ckpt}
    if "model" not in small:
        from mocapfix.core.clip import MotionFileError
        from mocapfix.fix.fixers import load_fixer
        from mocapfix.models.build import checkpoint_entry

        try:
            fixer = load_fixer(matches[0])
        except MotionFileError:  # not a model fix reads: copied as it is
            fixer = None
        if fixer is not None and fixer.kind == "xmae":
            small["model"] = checkpoint_entry("xmae", fixer.net.config)
    small["state_dict"] = {
        k: v.to(torch.bfloat16) if v.is_floating_point() and not fp32 else v for k, v in ckpt["state_dict"].items()
    }
    torch.save(small, argv[1])
    print(f"{matches[0]} -> {argv[1]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
