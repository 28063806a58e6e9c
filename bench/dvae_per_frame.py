"""Issue 4's joint-acceleration question, frame by frame: where in a window a Motion-DVAE's
output departs from the truth (error in mm and acceleration in m/s^2 at each frame), for the
prior reconstructing clean windows and for the denoising stage (regression mode) at each noise
level. The window mean that `test` reports hides whether the excess acceleration sits at the
window's ends (x_0 from the initial-state predictor, then the decoder's frames) or in every frame
(noise passed through); this says which.

    python bench/dvae_per_frame.py --prior checkpoints/motion_dvae_bvh/last.ckpt \\
        --denoiser checkpoints/motion_dvae_denoise_bvh/last.ckpt --drop-joints joint_Root
    python bench/dvae_per_frame.py --denoiser dn.ckpt --source archive --path .device_data/bandai_rot30.npz

Windows: the data module's split (by file, seed 0, 80/10/10: the split the configs train
without), complete windows only, one batch of up to --max-windows.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch
from common import describe, pick_device, write_result

from mocapfix.data.datamodule import MotionDataModule  # noqa: E402
from mocapfix.data.windows import (
    complete_windows,  # noqa: E402
    select,  # noqa: E402
)
from mocapfix.evaluation.metrics import _second_difference  # noqa: E402
from mocapfix.models.dvae_inference import FIRST_FRAMES  # noqa: E402
from mocapfix.training.denoise_module import DVAEDenoiseModule  # noqa: E402
from mocapfix.training.dvae_module import MotionDVAEModule  # noqa: E402

DEFAULT_BVH = Path(__file__).resolve().parents[2] / "shared" / "data" / "bandai-namco"


def per_frame(est: torch.Tensor, truth: torch.Tensor, fps: float, first: int) -> dict:
    """est, truth (B, T+1, J, 3) metres -> error per frame (mm) and acceleration per centre frame.
    first: the first frame the MPJPE counts (1 where x_0 was given, as the prior's `test`)."""

    def accel(p):  # (T-1,): JointAcceleration's quantity at frames 1..T-1, mean over windows and joints
        return (_second_difference(p).norm(dim=-1) * fps**2).mean(dim=(0, 2))

    err = (est - truth).norm(dim=-1).mean(dim=(0, 2)) * 1000
    acc, acc_true = accel(est), accel(truth)
    return {
        "mpjpe_mm": err[first:].mean().item(),
        "error_mm_per_frame": err.tolist(),
        "accel": acc.mean().item(),
        "accel_truth": acc_true.mean().item(),
        "accel_per_frame": acc.tolist(),
        "accel_truth_per_frame": acc_true.tolist(),
        # the summary: the join at x_0, the next frame, the middle, the window's last frame
        "accel_first": acc[0].item(),
        "accel_second": acc[1].item(),
        "accel_middle": acc[2:-2].mean().item(),
        "accel_last": acc[-1].item(),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--prior", default=None, help="a MotionDVAEModule checkpoint (clean reconstruction)")
    ap.add_argument("--denoiser", default=None, help="a DVAEDenoiseModule checkpoint (regression mode)")
    ap.add_argument("--source", default="bvh", help="data source as the data module reads it (bvh, archive, synthetic)")
    ap.add_argument("--path", default=str(DEFAULT_BVH))
    ap.add_argument("--drop-joints", nargs="*", default=[], help="as the model's training config (Bandai: joint_Root)")
    ap.add_argument("--synthetic-clips", type=int, default=48)
    ap.add_argument("--split", default="test", choices=("val", "test"))
    ap.add_argument(
        "--sigmas",
        type=float,
        nargs="*",
        default=[0.0, 0.1, 0.15, 0.2],
        help="noise levels for the denoiser (the configs' unit: rad for rotation noise)",
    )
    ap.add_argument(
        "--first-frames",
        nargs="*",
        default=None,
        choices=FIRST_FRAMES,
        help="the denoiser's output frame 0, each in turn (default: the checkpoint's first_frame)",
    )
    ap.add_argument("--max-windows", type=int, default=1024)
    ap.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    if not (args.prior or args.denoiser):
        raise SystemExit("give --prior, --denoiser or both")
    device = pick_device(args.device)
    prior = MotionDVAEModule.load_from_checkpoint(args.prior, map_location=device).eval() if args.prior else None
    denoiser = (
        DVAEDenoiseModule.load_from_checkpoint(args.denoiser, map_location=device).eval() if args.denoiser else None
    )
    hp = prior.hparams if prior is not None else denoiser.hparams.prior_hparams
    fps, frames = float(hp["window_fps"]), int(hp["window_frames"])
    dm = MotionDataModule(
        source=args.source,
        path=args.path,
        drop_joints=args.drop_joints or None,
        with_rotations=hp["state"] == "rotations",
        fps=fps,
        window_s=frames / fps,
        stride_s=0.1,
        val_fraction=0.1,
        test_fraction=0.1,
        split_seed=0,
        eval_batch_size=args.max_windows,
        cache_dir=None,
        synthetic_clips=args.synthetic_clips,
    )
    dm.setup("fit" if args.split == "val" else "test")
    if dm.window_frames != frames:
        raise SystemExit(f"the model takes {frames}-frame windows, the data module cuts {dm.window_frames}")
    if tuple(dm.skeleton.parents) != tuple(hp["skeleton"]["parents"]):
        raise SystemExit(
            f"the model was trained on {len(hp['skeleton']['parents'])} joints, the data has "
            f"{dm.skeleton.num_joints}: give --drop-joints as in its training config"
        )
    loader = dm.val_dataloader() if args.split == "val" else dm.test_dataloader()
    batch = next(iter(loader))
    batch = {k: v.to(device) for k, v in select(batch, complete_windows(batch)).items()}

    rows = []
    with torch.no_grad():
        if prior is not None:
            _, truth, recon = prior.reconstruct(batch)  # canonical frame
            rows.append({"model": "prior (clean, x_0 given)", "sigma": 0.0, **per_frame(recon, truth, fps, first=1)})
        if denoiser is not None:
            truth = batch["positions"].float()
            for sigma in args.sigmas:
                # a CPU generator: the same noise on any device, as the modules' own evaluation
                noisy = denoiser.add_noise(batch, sigma, torch.Generator().manual_seed(1))
                obs = denoiser.observation(noisy)
                for first_frame in args.first_frames or [denoiser.hparams.first_frame]:
                    denoiser.hparams.first_frame = first_frame
                    row = {
                        "model": f"denoiser, frame 0 {first_frame}",
                        "sigma": sigma,
                        "first_frame": first_frame,
                        "noisy_mpjpe_mm": 1000 * (obs.positions.float() - truth).norm(dim=-1).mean().item(),
                    }
                    rows.append({**row, **per_frame(denoiser.estimate(obs).float(), truth, fps, first=0)})

    result = {
        "benchmark": "dvae_per_frame",
        "env": describe(device),
        "command": " ".join(sys.argv),
        "split": args.split,
        "windows": len(batch["positions"]),
        "fps": fps,
        "frames": frames,
        "rows": rows,
    }
    path = write_result("dvae_per_frame", result, args.json_out)
    print(
        f"{result['windows']} {args.split} windows of {frames} frames at {fps:g} fps; acceleration m/s^2 "
        f"(truth {rows[0]['accel_truth']:.1f}), error mm"
    )
    print(
        f"{'model':<30} {'sigma':>5} {'noisy':>6} {'MPJPE':>6} {'accel':>6} {'first':>6} {'second':>6} "
        f"{'middle':>6} {'last':>6}"
    )
    for r in rows:
        noisy = f"{r['noisy_mpjpe_mm']:6.1f}" if "noisy_mpjpe_mm" in r else f"{'':>6}"
        print(
            f"{r['model']:<30} {r['sigma']:5.2f} {noisy} {r['mpjpe_mm']:6.1f} {r['accel']:6.1f} "
            f"{r['accel_first']:6.1f} {r['accel_second']:6.1f} {r['accel_middle']:6.1f} {r['accel_last']:6.1f}"
        )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
