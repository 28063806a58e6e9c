"""How long `mocapfix fix` takes on a 60-second, 22-joint, 30 fps clip with the paper-sized XMAE.

The model is randomly initialised (speed does not depend on the weights) and saved as a
checkpoint of the shape fix reads. Each case times the whole file path: read, fix, write.

    python bench/fix_speed.py                     # CPU, the default cases
    python bench/fix_speed.py --device cuda --batch-size 256
    python bench/fix_speed.py --precision fp32      # without bf16 matmuls
    python bench/fix_speed.py --model xmae-cpu-bandai   # a shipped model (its fill policy too)

Cases:
    denoise        --mode both on a clean clip: the model runs on every window
    infill-gaps    --mode infill, ten 0.5 s gaps (full skeleton or one limb): only the windows
                   around the gaps run
    infill-spread  --mode infill, 5% of tokens missing at random: every window runs
"""

from __future__ import annotations

import argparse
import io
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mocapfix.apps.fix_run import fix_files  # noqa: E402
from mocapfix.core.skeleton import preset  # noqa: E402
from mocapfix.evaluation.recording import part_holes, with_holes  # noqa: E402
from mocapfix.fix.fixers import load_fixer, resolve_precision  # noqa: E402
from mocapfix.io.positions import write_positions  # noqa: E402
from mocapfix.io.synthetic import generate_clips  # noqa: E402
from mocapfix.models.checkpoint import save_checkpoint, xmae_checkpoint  # noqa: E402
from mocapfix.models.xmae import XMAE  # noqa: E402
from mocapfix.pretrained import pretrained_path  # noqa: E402

CASES = ("denoise", "infill-gaps", "infill-spread")


def make_inputs(folder: Path, seconds: float, fps: float, seed: int = 0) -> dict[str, Path]:
    skel = preset("smpl22")
    clean = generate_clips(1, seconds, fps=fps, seed=seed)[0].positions  # (T, 22, 3)
    T = len(clean)
    rng = np.random.default_rng(seed)
    gaps = with_holes(clean, part_holes(T, skel.num_joints, fps, skel.groups, rng))
    spread = with_holes(clean, rng.random(clean.shape[:2]) < 0.05)
    paths = {}
    for case, pos in (("denoise", clean), ("infill-gaps", gaps), ("infill-spread", spread)):
        paths[case] = write_positions(folder / f"{case}.npz", pos, fps, skel)
    return paths


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--fps", type=float, default=30.0, help="the clip's and the model's frame rate")
    ap.add_argument("--window-s", type=float, default=1.0, help="the model's window (paper: 1 s)")
    ap.add_argument("--overlaps", default="0.5,0.25,0", help="comma-separated --overlap values")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--device", default="cpu", choices=("cpu", "cuda"))
    ap.add_argument("--batch-size", type=int, default=64)
    ap.add_argument("--precision", default="auto", choices=("auto", "fp32", "bf16"), help="fix --precision")
    ap.add_argument("--repeat", type=int, default=1, help="timed runs per case (the best is reported)")
    ap.add_argument("--model", default=None, help="a shipped model (mocapfix models), not the paper-sized one")
    ap.add_argument(
        "--json-out", default=None, help="where to write the results (default bench/results/fix_speed-<device>.json)"
    )
    args = ap.parse_args(argv)

    torch.manual_seed(0)
    frames = int(round(args.window_s * args.fps))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if args.model:  # its joints are matched to the clip's SMPL names by body part
            ckpt = pretrained_path(args.model)
            fixer = load_fixer(ckpt)
            net, frames, label = fixer.net, fixer.window, f"{args.model} (shipped, fill policy)"
        else:
            net, label = XMAE(22, frames), "XMAE paper size (random init)"  # Table 1
            ckpt = tmp / "xmae_paper_random.ckpt"
            save_checkpoint(ckpt, xmae_checkpoint(net, preset("smpl22"), args.fps))
        params = sum(p.numel() for p in net.parameters())
        inputs = make_inputs(tmp, args.seconds, args.fps)
        # warm-up: first calls pay for thread pools and kernel selection
        fix_files(
            [str(inputs["denoise"])],
            str(ckpt),
            out=str(tmp / "warm.npz"),
            mode="both",
            device=args.device,
            batch_size=args.batch_size,
            force=True,
            progress="never",
            stdout=io.StringIO(),
            precision=args.precision,
        )
        for case in args.cases.split(","):
            mode = "both" if case == "denoise" else "infill"
            for overlap in (float(o) for o in args.overlaps.split(",")):
                best, report = float("inf"), None
                for _ in range(args.repeat):
                    out = io.StringIO()
                    t0 = time.perf_counter()
                    rc = fix_files(
                        [str(inputs[case])],
                        str(ckpt),
                        out=str(tmp / "out.npz"),
                        mode=mode,
                        device=args.device,
                        batch_size=args.batch_size,
                        overlap=overlap,
                        force=True,
                        progress="never",
                        as_json=True,
                        stdout=out,
                        precision=args.precision,
                    )
                    elapsed = time.perf_counter() - t0
                    if rc != 0:
                        raise SystemExit(f"fix failed on {case}")
                    if elapsed < best:
                        best, report = elapsed, json.loads(out.getvalue())
                rows.append(
                    {
                        "case": case,
                        "mode": mode,
                        "overlap": overlap,
                        "windows": report["windows"],
                        "seconds": round(best, 3),
                        "realtime_x": round(args.seconds / best, 1),
                        "ms_per_window": round(1000 * best / max(report["windows"], 1), 1),
                    }
                )
    result = {
        "clip_s": args.seconds,
        "fps": args.fps,
        "joints": 22,
        "window_frames": frames,
        "model": label,
        "parameters": params,
        "device": args.device,
        "precision": resolve_precision(args.precision, torch.device(args.device)),
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "cpus": os.cpu_count(),
        "machine": platform.processor() or platform.machine(),
        "batch_size": args.batch_size,
        "rows": rows,
    }

    head = f"{'case':<14} {'mode':<7} {'overlap':>7} {'windows':>7} {'seconds':>8} {'x realtime':>10} {'ms/window':>9}"
    print(
        f"mocapfix fix: {args.seconds:g} s clip, 22 joints, {args.fps:g} fps, {label} ({params / 1e6:.2f} M "
        f"parameters), {args.device}, {result['precision']}, {torch.get_num_threads()} threads"
    )
    print(head)
    for r in rows:
        print(
            f"{r['case']:<14} {r['mode']:<7} {r['overlap']:>7.2f} {r['windows']:>7d} {r['seconds']:>8.2f} "
            f"{r['realtime_x']:>10.1f} {r['ms_per_window']:>9.1f}"
        )
    out = (
        Path(args.json_out)
        if args.json_out
        else Path(__file__).resolve().parent / "results" / f"fix_speed-{args.device}.json"
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
