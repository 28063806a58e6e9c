"""`fix` on performers a model never saw: the CMU sample (another studio, rig and frame rate than
Bandai Namco's), holes of the full body, the left arm or the left leg of 0.1-0.9 s, 4 per take,
in every take of 8 s or more. MPJPE (mm) over the hidden tokens of what `fix --mode infill`
outputs (its fill policy measured over the folder's takes, as `fix FOLDER` does; and over each
file alone, as `fix FILE` does), beside every classical fill on the same whole take (Lerp, cubic spline, PCHIP, the
limb fill, the cubic Hermite) and the motion-matching fills (fills/motion_matching.py; searching the
folder's holed takes, as `fix FOLDER` does, and the take alone, as `fix FILE` does), on the
model's joints (each take mapped onto them, rig/structure.py).

Any folder and checkpoint: new performers of the capture a checkpoint was trained on (--data the
test split's files, --source h36m for Human3.6M's exponential-map takes, --max-takes a subset
evenly spread), --name names the result file.

    python bench/fix_strangers_cmu.py --model xmae-cpu-bandai
    python bench/fix_strangers_cmu.py --model-only --library /other/takes/of/the/same/people
    python bench/fix_strangers_cmu.py --ckpt correction.ckpt --data bandai_test/ --min-seconds 4 --name bandai
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
from common import describe, pick_device, print_table, write_result

from mocapfix.evaluation.recording import spread_holes, with_holes  # noqa: E402
from mocapfix.fills.classical import CLASSICAL  # noqa: E402
from mocapfix.fills.motion_matching import FILLS as MATCH_FILLS  # noqa: E402
from mocapfix.fills.motion_matching import match_fills  # noqa: E402
from mocapfix.fix import (  # noqa: E402
    fix_clips,
    measure_recordings,
    motion_library,  # noqa: E402
)
from mocapfix.fix.fixers import load_fixer  # noqa: E402
from mocapfix.fix.measure import model_fill  # noqa: E402
from mocapfix.fix.positions import take_keys  # noqa: E402
from mocapfix.io import list_motion_files, read_motion  # noqa: E402
from mocapfix.pretrained import pretrained_path  # noqa: E402
from mocapfix.rig.mapping import onto_skeleton  # noqa: E402

DEFAULT_CMU = Path(__file__).resolve().parents[2] / "shared" / "data" / "cmu-sample"
GAPS_S = (0.1, 0.3, 0.5, 0.7, 0.9)
PARTS = {"full": None, "arm": "left_arm", "leg": "left_leg"}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    which = ap.add_mutually_exclusive_group()
    which.add_argument("--model", default="xmae-cpu-bandai")
    which.add_argument("--ckpt", default=None)
    ap.add_argument("--data", default=str(DEFAULT_CMU))
    ap.add_argument("--min-seconds", type=float, default=8.0)
    ap.add_argument("--max-takes", type=int, default=None, help="at most this many takes, evenly spread")
    ap.add_argument("--source", default="bvh", help="the files' format (fix --source)")
    ap.add_argument("--name", default=None, help="the result file's suffix")
    ap.add_argument("--parts", default=",".join(PARTS), help="some of " + ",".join(PARTS))
    ap.add_argument("--gaps", default=",".join(f"{g:g}" for g in GAPS_S), help="hole lengths, seconds")
    ap.add_argument("--device", default="cpu")
    ap.add_argument(
        "--model-only",
        action="store_true",
        help="the model alone and the classical fills, not fix's policy (which measures: ~50 min on 2 cores)",
    )
    ap.add_argument(
        "--library",
        default=None,
        help="a folder of other takes of the same performers (none of the evaluated ones): fix --library",
    )
    ap.add_argument("--no-model", action="store_true", help="with --model-only: the fills alone, no model row")
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    device = pick_device(args.device)
    ckpt = args.ckpt or str(pretrained_path(args.model))
    fixer = load_fixer(ckpt, str(device))
    body = fixer.skeleton
    takes = []
    for f in list_motion_files(args.data, args.source):
        clip = read_motion(f, args.source)[0]
        if clip.duration_s >= args.min_seconds:
            takes.append(onto_skeleton(clip, body))
    if args.max_takes and len(takes) > args.max_takes:
        takes = [takes[i] for i in np.linspace(0, len(takes) - 1, args.max_takes).round().astype(int)]
    extra = (
        [[onto_skeleton(read_motion(f, args.source)[0], body)] for f in list_motion_files(args.library, args.source)]
        if args.library
        else []
    )
    extra_library = motion_library(extra, fixer) if extra else None
    model = model_fill(fixer, overlap=0.5, batch_size=64)
    t0 = time.perf_counter()
    sums: dict[tuple[str, float, str], list[float]] = {}
    parts = {p: PARTS[p] for p in args.parts.split(",")}
    gaps = [float(g) for g in args.gaps.split(",")]
    for part, group in parts.items():
        for gap in gaps:
            holed_takes, hiddens = [], []
            for clip in takes:
                truth = clip.positions.astype(np.float64)
                hidden = spread_holes(clip.num_frames, body.num_joints, clip.fps, gap, body.groups.get(group))
                hidden &= np.isfinite(truth).all(-1)
                hiddens.append(hidden)
                holed_takes.append(clip.replace(positions=with_holes(truth, hidden)))
            # the folder's policy and motion library: what `mocapfix fix FOLDER` measures and searches
            recordings = [[c] for c in holed_takes]
            library = motion_library(recordings, fixer)  # the folder's takes first, then the extra ones
            if extra_library is not None:
                library = extra_library.including(library.takes, library.keys)
            folder = None if args.model_only else measure_recordings(recordings, fixer, "infill", library=extra_library)
            for clip, holed_clip, hidden in zip(takes, holed_takes, hiddens):
                truth = clip.positions.astype(np.float64)
                holed = holed_clip.positions
                x = torch.from_numpy(holed.astype(np.float64))[None]
                outputs = {} if args.no_model else {"model": model(holed, clip.fps)}  # alone in every hole
                if not args.model_only:
                    (fixed,), _ = fix_clips([holed_clip], fixer, "infill", measured=folder, library=library)
                    (alone,), _ = fix_clips([holed_clip], fixer, "infill")
                    outputs.update({"fix": fixed.positions.astype(np.float64), "fix (file alone)": alone.positions})
                for name, fill in CLASSICAL.items():
                    outputs[name] = fill(x, ~torch.isnan(x).any(-1), body.parents)[0].numpy()
                observed = np.isfinite(holed).all(-1)
                searched = library.without(take_keys([holed_clip])[0], clip.fps)  # as fix FOLDER searches
                for name, found in match_fills(holed, observed, outputs["hermite"], searched, clip.fps).items():
                    outputs[f"{name} (folder)"] = found
                alone = None if extra_library is None else extra_library.without(None, clip.fps)
                for name, found in match_fills(holed, observed, outputs["hermite"], alone, clip.fps).items():
                    outputs[f"{name} (take alone)"] = found
                for name, out in outputs.items():
                    err = np.linalg.norm(out[hidden] - truth[hidden], axis=-1)
                    s = sums.setdefault((part, gap, name), [0.0, 0])
                    s[0] += 1000 * float(err.sum())
                    s[1] += int(err.size)
    rows = []
    for part in parts:
        matching = [f"{m} ({w})" for w in ("folder", "take alone") for m in MATCH_FILLS]
        for name in ["fix", "fix (file alone)", "model", *CLASSICAL, *matching]:
            if (part, gaps[0], name) not in sums:
                continue
            row = {"part": part, "method": name}
            for gap in gaps:
                s = sums[(part, gap, name)]
                row[f"{gap:g}s"] = s[0] / max(s[1], 1)
            rows.append(row)
        best = {"part": part, "method": "best classical"}
        for gap in gaps:
            best[f"{gap:g}s"] = min(r[f"{gap:g}s"] for r in rows if r["part"] == part and r["method"] in CLASSICAL)
        rows.append(best)
    result = {
        "env": describe(device),
        "checkpoint": ckpt,
        "data": args.data,
        "takes": len(takes),
        "holes_per_take": 4,
        "library": args.library,
        "seconds": round(time.perf_counter() - t0, 1),
        "rows": rows,
    }
    suffix = "-".join(filter(None, [args.name, "model_only" if args.model_only else None])) or None
    path = write_result("fix_strangers_cmu", result, args.json_out, suffix)
    columns = [("part", "part"), ("method", "method")] + [(f"{g:g}s", f"{g:g} s") for g in gaps]
    title = f"fix on {args.data}: takes >= {args.min_seconds:g} s ({len(takes)}), MPJPE mm over the holes"
    print_table(title, rows, columns)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
