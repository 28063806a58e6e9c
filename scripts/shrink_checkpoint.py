"""A training checkpoint -> a weights-only bf16 copy small enough to bring back from a lent GPU
or to ship (mocapfix.models.checkpoint.shrink_checkpoint: hyperparameters, the model's kind and
config and the fill policy kept, optimiser state dropped): `mocapfix fix` and evaluation read it;
training cannot resume from it. --fp32 keeps the weights in float32 (Motion-DVAE runs in fp32).

    python scripts/shrink_checkpoint.py checkpoints/xmae_bandai_gpu/best-*.ckpt small.ckpt
    python scripts/shrink_checkpoint.py --fp32 checkpoints/motion_dvae_denoise_bvh/last.ckpt dn.ckpt
"""

from __future__ import annotations

import glob
import sys

from mocapfix.models.checkpoint import read_checkpoint, save_checkpoint, shrink_checkpoint


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    fp32 = "--fp32" in argv
    argv = [a for a in argv if a != "--fp32"]
    if len(argv) != 2:
        raise SystemExit(__doc__)
    matches = sorted(glob.glob(argv[0]))
    if not matches:
        raise SystemExit(f"no checkpoint matches {argv[0]}")
    save_checkpoint(argv[1], shrink_checkpoint(matches[0], read_checkpoint(matches[0]), fp32))
    print(f"{matches[0]} -> {argv[1]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
