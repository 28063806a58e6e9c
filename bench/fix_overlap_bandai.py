"""What `fix --overlap` costs in accuracy and buys in time: `fix --mode both` with a trained
checkpoint on the Bandai Namco test clips (split by file, seed 0, as in training), at several
overlaps, in one run.

Three inputs per test clip, each against the clean clip:
- mixed: recording-level corruption (evaluation/recording.py: gaps of 0.1-0.9 s on joints and
  limbs, displaced tokens), seeded per clip;
- displaced arms: every 2 s one arm moved 0.5-1.0 m for 0.5 s (evaluation/recording.py: displace_arms);
- clean: the clip as it is (what fix may not make worse).
The error is the mean distance over every token of the output to the clean clip (mm), and the
acceleration error: the mean distance of the output's second difference in time to the clean
clip's (mm per frame^2; what seams between windows and jitter show as).

    python bench/fix_overlap_bandai.py --model xmae-cpu-bandai
    python bench/fix_overlap_bandai.py --ckpt checkpoints/xmae_cpu/last.ckpt --overlaps 0.5,0.25,0
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from common import describe, pick_device, print_table, write_result
from fix_policy_bandai import DEFAULT_BVH

from mocapfix.data.datamodule import MotionDataModule  # noqa: E402
from mocapfix.evaluation.recording import corrupt_recording, displace_arms  # noqa: E402
from mocapfix.fix import fix_clips  # noqa: E402
from mocapfix.fix.fixers import load_fixer  # noqa: E402
from mocapfix.pretrained import pretrained_path  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    which = ap.add_mutually_exclusive_group(required=True)
    which.add_argument("--ckpt")
    which.add_argument("--model", help="a shipped model (mocapfix models)")
    ap.add_argument("--path", default=str(DEFAULT_BVH), help="the BVH folder the checkpoint was trained on")
    ap.add_argument("--overlaps", default="0.5,0.25,0")
    ap.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    ap.add_argument("--max-clips", type=int, default=None, help="the first N test clips only (a smoke run)")
    ap.add_argument("--cache-dir", default=None, help="the data module's parsed-clips cache (default: none)")
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    device = pick_device(args.device)
    ckpt = args.ckpt or str(pretrained_path(args.model))
    fixer = load_fixer(ckpt, device, precision="auto")
    dm = MotionDataModule(source="bvh", path=args.path, fps=30, cache_dir=args.cache_dir)
    dm.setup("test")
    clips = dm.clips["test"][: args.max_clips]

    rng = np.random.default_rng(0)
    inputs = []  # (case, clean clip, input positions)
    for i, c in enumerate(clips):
        mixed, _, _ = corrupt_recording(c.positions, c.fps, c.skeleton.groups, np.random.default_rng(i))
        inputs.append(("mixed", c, mixed.astype(np.float32)))
        inputs.append(("displaced arms", c, displace_arms(c.positions, c.fps, c.skeleton.groups, rng)[0]))
        inputs.append(("clean", c, c.positions))

    rows = []
    for overlap in (float(o) for o in args.overlaps.split(",")):
        errors, accel, windows = {}, {}, 0
        t0 = time.perf_counter()
        for case, c, x in inputs:
            out, report = fix_clips([c.replace(positions=x)], fixer, "both", overlap)
            windows += report.windows
            e = np.linalg.norm(out[0].positions - c.positions, axis=-1)  # (T, J)
            errors.setdefault(case, []).append(e[np.isfinite(e)])
            a = np.linalg.norm(np.diff(out[0].positions, 2, axis=0) - np.diff(c.positions, 2, axis=0), axis=-1)
            accel.setdefault(case, []).append(a[np.isfinite(a)])
        seconds = time.perf_counter() - t0
        row = {"overlap": overlap, "windows": windows, "seconds": seconds}
        row.update({f"{case}_mm": 1000 * float(np.concatenate(e).mean()) for case, e in errors.items()})
        row.update({f"{case}_accel_mm": 1000 * float(np.concatenate(a).mean()) for case, a in accel.items()})
        rows.append(row)
    for r in rows:
        r["speedup"] = rows[0]["seconds"] / r["seconds"]
        for case in ("mixed", "displaced arms", "clean"):
            r[f"{case}_change_mm"] = r[f"{case}_mm"] - rows[0][f"{case}_mm"]

    result = {
        "benchmark": "fix_overlap_bandai",
        "env": describe(device),
        "command": " ".join(sys.argv),
        "ckpt": ckpt,
        "precision": fixer.precision,
        "clips": len(clips),
        "policy": fixer.policy is not None,
        "rows": rows,
    }
    path = write_result("fix_overlap_bandai", result, args.json_out)
    print_table(
        f"fix --mode both on {len(clips)} Bandai test clips x 3 inputs, {Path(ckpt).name} ({fixer.precision}): "
        f"error to the clean clip by --overlap; speed-up against the first",
        rows,
        [
            ("overlap", "overlap"),
            ("windows", "windows"),
            ("seconds", "seconds"),
            ("speedup", "speed-up"),
            ("mixed_mm", "mixed mm"),
            ("displaced arms_mm", "displaced arms mm"),
            ("clean_mm", "clean mm"),
            ("mixed_accel_mm", "accel: mixed"),
            ("displaced arms_accel_mm", "arms"),
            ("clean_accel_mm", "clean"),
        ],
    )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
