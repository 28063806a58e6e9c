"""`fix --mode both` on performers a model never saw: does it leave clean data alone and find
displaced joints? The CMU sample (another studio, rig and frame rate than the shipped models'
Bandai Namco data), every take mapped onto the model's 21 joints by structure:

- clean: the share of observed tokens `fix --mode both` moves by more than 1 mm (the bar: 1 %),
  and the largest move;
- displaced: every 2 s one arm (left or right, seeded) moved by a constant offset of 0.5-1.0 m in
  a random direction for 0.5 s (bench/fix_policy_bandai.py's task): the displaced tokens' error
  before and after (the bar: cut by at least 80 %) and the clean tokens moved by more than 1 mm.

    python bench/fix_both_strangers.py --model xmae-cpu-bandai
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from common import describe, pick_device, print_table, write_result

from mocapfix.evaluation.recording import displace_arms, error_mm  # noqa: E402
from mocapfix.fix import fix_clips  # noqa: E402
from mocapfix.fix.fixers import load_fixer  # noqa: E402
from mocapfix.io import list_motion_files, read_motion  # noqa: E402
from mocapfix.io.absurd import drop_absurd  # noqa: E402
from mocapfix.pretrained import pretrained_path  # noqa: E402
from mocapfix.rig.mapping import onto_skeleton  # noqa: E402

DEFAULT_CMU = Path(__file__).resolve().parents[2] / "shared" / "data" / "cmu-sample"
MOVED_M = 0.001  # a token "changed" when fix moved it by more than this


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    which = ap.add_mutually_exclusive_group()
    which.add_argument("--model", default="xmae-cpu-bandai")
    which.add_argument("--ckpt", default=None)
    ap.add_argument("--data", default=str(DEFAULT_CMU))
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-takes", type=int, default=None, help="the first N takes only (a smoke run)")
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    device = pick_device(args.device)
    ckpt = args.ckpt or str(pretrained_path(args.model))
    fixer = load_fixer(ckpt, str(device))
    files = list_motion_files(args.data, "bvh")[: args.max_takes]
    takes = [onto_skeleton(read_motion(f)[0], fixer.skeleton) for f in files]
    rng = np.random.default_rng(args.seed)

    t0 = time.perf_counter()
    clean_moved, clean_n, worst_m, per_take = 0, 0, 0.0, []
    bads, outs, truths, moveds, other_moved, other_n = [], [], [], [], 0, 0
    for f, c in zip(files, takes):
        seen = np.isfinite(c.positions).all(-1)
        (out,), _ = fix_clips([c], fixer, "both")
        move = np.linalg.norm(out.positions - c.positions, axis=-1)[seen]
        clean_moved += int((move > MOVED_M).sum())
        clean_n += int(seen.sum())
        worst_m = max(worst_m, float(move.max(initial=0.0)))
        per_take.append({"take": f.name, "moved_pct": 100 * float((move > MOVED_M).mean())})

        bad, moved = displace_arms(c.positions, c.fps, fixer.skeleton.groups, rng)
        moved &= seen
        # as `fix` reads such a file: a jump faster than any body part is missing data (io/absurd.py)
        read = drop_absurd(c.replace(positions=bad), c.meta["stature_m"])
        (out,), _ = fix_clips([read], fixer, "both")
        bads.append(bad)
        outs.append(out.positions)
        truths.append(c.positions)
        moveds.append(moved)
        rest = seen & ~moved
        other_moved += int((np.linalg.norm(out.positions - bad, axis=-1)[rest] > MOVED_M).sum())
        other_n += int(rest.sum())
    seconds = time.perf_counter() - t0
    err_before, err_after = error_mm(bads, truths, moveds), error_mm(outs, truths, moveds)
    moved_n = int(sum(m.sum() for m in moveds))
    rows = [
        {"case": "clean takes", "tokens": clean_n, "moved_pct": 100 * clean_moved / clean_n, "before_mm": 0.0},
        {"case": "displaced arm tokens", "tokens": moved_n, "before_mm": err_before, "after_mm": err_after},
        {"case": "other tokens of those takes", "tokens": other_n, "moved_pct": 100 * other_moved / other_n},
    ]
    result = {
        "benchmark": "fix_both_strangers",
        "env": describe(device),
        "command": " ".join(sys.argv),
        "checkpoint": ckpt,
        "data": args.data,
        "takes": len(takes),
        "seconds": round(seconds, 1),
        "clean_worst_move_mm": 1000 * worst_m,
        "displaced_error_cut_pct": 100 * (1 - err_after / err_before),
        "rows": rows,
        "per_take": per_take,
    }
    path = write_result("fix_both_strangers", result, args.json_out)
    print_table(
        f"fix --mode both on {len(takes)} CMU takes, {Path(ckpt).name}: displaced error cut "
        f"{result['displaced_error_cut_pct']:.1f} %, worst clean move {result['clean_worst_move_mm']:.0f} mm, "
        f"{seconds:.0f} s",
        rows,
        [
            ("case", "tokens of"),
            ("tokens", "tokens"),
            ("moved_pct", "moved > 1 mm %"),
            ("before_mm", "error before mm"),
            ("after_mm", "after mm"),
        ],
    )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
