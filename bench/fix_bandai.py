"""Issue 5's bar on real data: `mocapfix fix --mode both` on the Bandai Namco test clips with holes
of 0.1-0.9 s (full skeleton or one limb) set to NaN and 2% of the other tokens displaced by up to
1 m, against linear interpolation of the holes (Lerp, which cannot see the displaced tokens).

The test clips are the data module's test split (split by file, seed 0: the split the XMAE
checkpoint was trained without). Each clip is corrupted (seeded), written as a positions .npz
and fixed through the CLI path, then scored: MPJPE on the corrupted tokens (holes and displaced),
on the holes alone by gap length, NaN left, limb sigma before and after.

    python bench/fix_bandai.py --ckpt checkpoints/xmae_bandai_gpu/best-*.ckpt
    python bench/fix_bandai.py --ckpt small.ckpt --source archive --path .device_data/bandai_pos30.npz
"""

from __future__ import annotations

import argparse
import glob
import io
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from common import describe, pick_device, print_table, write_result

from mocapfix.apps.fix_run import fix_files  # noqa: E402
from mocapfix.data.datamodule import MotionDataModule  # noqa: E402
from mocapfix.evaluation.recording import corrupt_recording, hole_lengths  # noqa: E402
from mocapfix.fills.classical import lerp_infill  # noqa: E402
from mocapfix.io.positions import write_positions  # noqa: E402

DEFAULT_BVH = Path(__file__).resolve().parents[2] / "shared" / "data" / "bandai-namco"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ckpt", required=True, help="a trained checkpoint (glob allowed)")
    ap.add_argument("--source", default="bvh", choices=("bvh", "archive"))
    ap.add_argument("--path", default=str(DEFAULT_BVH))
    ap.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    ap.add_argument("--precision", default="auto", choices=("auto", "fp32", "bf16"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    device = pick_device(args.device)
    ckpts = sorted(glob.glob(args.ckpt))
    if not ckpts:
        raise SystemExit(f"no checkpoint matches {args.ckpt}")

    dm = MotionDataModule(source=args.source, path=args.path, drop_joints=["joint_Root"], fps=30, cache_dir=None)
    dm.setup("test")
    clips = dm.clips["test"]
    rng = np.random.default_rng(args.seed)
    truth, bad, gap, disp, lerp, fixed = [], [], [], [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        paths = []
        for i, c in enumerate(clips):
            y, g, d = corrupt_recording(c.positions, c.fps, c.skeleton.groups, rng)
            paths.append(write_positions(tmp / f"clip{i:03d}.npz", y, c.fps, c.skeleton))
            truth.append(c.positions)
            bad.append(y)
            gap.append(g)
            disp.append(d)
            lerp.append(lerp_infill(torch.from_numpy(y)[None].double(), torch.from_numpy(~g)[None])[0].numpy())
        report = io.StringIO()
        t0 = time.perf_counter()
        rc = fix_files(
            [str(p) for p in paths],
            ckpts[0],
            out_dir=str(tmp / "out"),
            mode="both",
            device=device.type,
            precision=args.precision,
            progress="never",
            as_json=True,
            stdout=report,
        )
        seconds = time.perf_counter() - t0
        if rc != 0:
            raise SystemExit(f"fix failed (exit {rc})")
        reports = [json.loads(line) for line in report.getvalue().splitlines() if line.strip()]
        for p in paths:
            with np.load(tmp / "out" / p.name) as z:
                fixed.append(z["positions"])

    def mm(pred, mask):
        return float(
            np.mean(np.concatenate([1000 * np.linalg.norm(p - t, axis=-1)[m] for p, t, m in zip(pred, truth, mask)]))
        )

    corrupted = [g | d for g, d in zip(gap, disp)]
    rows = [
        {"tokens": "corrupted (holes + displaced)", "fix_mm": mm(fixed, corrupted), "lerp_mm": mm(lerp, corrupted)},
        {"tokens": "holes", "fix_mm": mm(fixed, gap), "lerp_mm": mm(lerp, gap)},
        {"tokens": "displaced", "fix_mm": mm(fixed, disp), "lerp_mm": mm(lerp, disp)},
    ]
    # holes by length (corrupt_recording keeps 0.7 s of clean motion between holes: runs of
    # frames with a missing joint are single holes)
    lengths = [hole_lengths(g) for g in gap]
    for lo, hi in ((0.1, 0.3), (0.3, 0.5), (0.5, 0.7), (0.7, 0.9)):
        sel = [g & ((n >= round(lo * 30)) & (n < round(hi * 30) + (hi == 0.9)))[:, None] for g, n in zip(gap, lengths)]
        if sum(s.sum() for s in sel):
            rows.append({"tokens": f"holes {lo}-{hi} s", "fix_mm": mm(fixed, sel), "lerp_mm": mm(lerp, sel)})
    nan_left = int(sum(np.isnan(f).sum() for f in fixed))
    sigma_before = float(np.mean([r["limb_sigma_before_mm"] for r in reports]))
    sigma_after = float(np.mean([r["limb_sigma_after_mm"] for r in reports]))
    frames = sum(len(t) for t in truth)
    result = {
        "benchmark": "fix_bandai",
        "env": describe(device),
        "command": " ".join(sys.argv),
        "ckpt": ckpts[0],
        "clips": len(clips),
        "frames": frames,
        "seconds": seconds,
        "nan_left": nan_left,
        "limb_sigma_before_mm": sigma_before,
        "limb_sigma_after_mm": sigma_after,
        "rows": rows,
    }
    path = write_result("fix_bandai", result, args.json_out)
    print_table(
        f"fix --mode both on {len(clips)} Bandai test clips ({frames / 30:.0f} s at 30 fps), "
        f"{Path(ckpts[0]).name}: NaN left {nan_left}, limb sigma {sigma_before:.1f} -> {sigma_after:.1f} mm "
        f"(mean over clips), {seconds:.1f} s",
        rows,
        [("tokens", "tokens"), ("fix_mm", "fix MPJPE mm"), ("lerp_mm", "Lerp MPJPE mm")],
    )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
