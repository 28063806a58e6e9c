"""Denoising that leaves clean data alone (issue 18): `fix --mode both` with a checkpoint's fill
policy on the Bandai Namco test clips, clean and with displaced arms.

- clean: the share of observed tokens fix changes (the bar: at most 1 %);
- displaced: every 2 s one arm (left or right, seeded) moved by a constant offset of 0.5-1.0 m
  in a random direction for 0.5 s (the XMAE paper's displacement task, on whole recordings):
  the displaced tokens' error before and after (the bar: cut by at least 80 %), and the clean
  tokens changed.

The test clips are the data module's test split (split by file, seed 0), as in training.

    python bench/fix_policy_bandai.py --ckpt checkpoints/xmae_cpu/last.ckpt
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from common import describe, pick_device, print_table, write_result

from mocapfix.data.datamodule import MotionDataModule  # noqa: E402
from mocapfix.evaluation.recording import displace_arms, error_mm  # noqa: E402
from mocapfix.fix import fix_clips  # noqa: E402
from mocapfix.fix.fixers import load_fixer  # noqa: E402

DEFAULT_BVH = Path(__file__).resolve().parents[2] / "shared" / "data" / "bandai-namco"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ckpt", required=True)
    ap.add_argument("--path", default=str(DEFAULT_BVH), help="the BVH folder the checkpoint was trained on")
    ap.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-clips", type=int, default=None, help="the first N test clips only (a smoke run)")
    ap.add_argument("--cache-dir", default=None, help="the data module's parsed-clips cache (default: none)")
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    device = pick_device(args.device)
    fixer = load_fixer(args.ckpt, device)
    if fixer.policy is None:
        raise SystemExit(f"{args.ckpt} has no fill policy: `mocapfix validate --ckpt_path` calibrates one")
    dm = MotionDataModule(source="bvh", path=args.path, fps=30, cache_dir=args.cache_dir)
    dm.setup("test")
    clips = dm.clips["test"][: args.max_clips]
    rng = np.random.default_rng(args.seed)

    t0 = time.perf_counter()
    changed = observed = 0
    for c in clips:
        out, _ = fix_clips([c], fixer, "both")
        seen = ~np.isnan(c.positions).any(-1)
        changed += int(((out[0].positions != c.positions).any(-1) & seen).sum())
        observed += int(seen.sum())
    bads, outs, moveds, clean_changed, clean_n = [], [], [], 0, 0
    for c in clips:
        bad, moved = displace_arms(c.positions, c.fps, c.skeleton.groups, rng)
        out, _ = fix_clips([c.replace(positions=bad)], fixer, "both")
        bads.append(bad)
        outs.append(out[0].positions)
        moveds.append(moved)
        clean_changed += int(((out[0].positions != bad).any(-1) & ~moved).sum())
        clean_n += int((~moved).sum())
    seconds = time.perf_counter() - t0
    truths, moved_n = [c.positions for c in clips], int(sum(m.sum() for m in moveds))
    err_before, err_after = error_mm(bads, truths, moveds), error_mm(outs, truths, moveds)
    rows = [
        {
            "case": "clean clips",
            "tokens": observed,
            "changed_pct": 100 * changed / observed,
            "before_mm": 0.0,
            "after_mm": float("nan"),
        },
        {
            "case": "displaced arm tokens",
            "tokens": moved_n,
            "changed_pct": float("nan"),
            "before_mm": err_before,
            "after_mm": err_after,
        },
        {
            "case": "clean tokens of those clips",
            "tokens": clean_n,
            "changed_pct": 100 * clean_changed / clean_n,
            "before_mm": 0.0,
            "after_mm": float("nan"),
        },
    ]
    result = {
        "benchmark": "fix_policy_bandai",
        "env": describe(device),
        "command": " ".join(sys.argv),
        "ckpt": args.ckpt,
        "clips": len(clips),
        "seconds": seconds,
        "replace_threshold_m": fixer.policy.replace_threshold_m,
        "displaced_error_cut_pct": 100 * (1 - err_after / err_before),
        "rows": rows,
    }
    path = write_result("fix_policy_bandai", result, args.json_out)
    print_table(
        f"fix --mode both with the fill policy on {len(clips)} Bandai test clips, {Path(args.ckpt).name} "
        f"(replace threshold {1000 * fixer.policy.replace_threshold_m:.0f} mm): displaced error cut "
        f"{result['displaced_error_cut_pct']:.1f} %, {seconds:.0f} s",
        rows,
        [
            ("case", "tokens of"),
            ("tokens", "tokens"),
            ("changed_pct", "changed %"),
            ("before_mm", "error before mm"),
            ("after_mm", "after mm"),
        ],
    )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
