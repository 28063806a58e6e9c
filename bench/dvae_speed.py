"""Benchmark 4: Motion-DVAE: training sequences/s of the prior through the Trainer loop, then the
denoising stage's regression mode (one forward pass; batched and batch 1) and optimisation mode
(opt_iterations ELBO steps on the batch, then the forward pass), in seconds per frame.

Paper sizes (latent 48, LSTM 1024, MLPs 1024), rotation state, the synthetic smpl22 data with
rotations, 30-frame windows at 30 Hz; weights are the prior after the timed training steps
(speed does not depend on them). Noise: 0.1 rad on the body joints' axis-angle. Paper:
regression 1e-3 s/frame on a GTX 1070.

    python bench/dvae_speed.py                      # CUDA when there is one
    python bench/dvae_speed.py --device cpu --threads 1
    python bench/dvae_speed.py --compile            # also the prior's step with compile_model
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import lightning as L  # noqa: E402
import torch
from common import StepClock, describe, pick_device, print_table, timed, write_result

from mocapfix.data.datamodule import MotionDataModule  # noqa: E402
from mocapfix.training.denoise_module import DVAEDenoiseModule  # noqa: E402
from mocapfix.training.dvae_module import MotionDVAEModule  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    ap.add_argument("--threads", type=int, default=None, help="CPU threads (default: torch's)")
    ap.add_argument("--batch", type=int, default=64, help="training batch (paper: 64)")
    ap.add_argument(
        "--eval-batch", type=int, default=None, help="windows per regression call (default 1024 CUDA, 64 CPU)"
    )
    ap.add_argument("--warmup", type=int, default=None)
    ap.add_argument("--steps", type=int, default=None, help="timed training steps (default 100 CUDA, 3 CPU)")
    ap.add_argument("--opt-iterations", type=int, default=50)
    ap.add_argument("--compile", action="store_true", help="add a training row with compile_model (torch.compile)")
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    device = pick_device(args.device)
    gpu = device.type == "cuda"
    if args.threads:
        torch.set_num_threads(args.threads)
    warmup = args.warmup if args.warmup is not None else (10 if gpu else 1)
    steps = args.steps or (100 if gpu else 3)
    eval_batch = args.eval_batch or (1024 if gpu else 64)

    torch.manual_seed(0)
    dm = MotionDataModule(
        source="synthetic",
        with_rotations=True,
        fps=30,
        window_s=1.0,
        stride_s=1 / 30,
        synthetic_clips=48,
        batch_size=args.batch,
        cache_dir=None,
        val_fraction=0.0,
        test_fraction=0.0,
    )

    def train(compile_model: bool):
        prior = MotionDVAEModule(
            state="rotations", body_model="skeleton", kl_anneal_steps=10, compile_model=compile_model
        )
        clock = StepClock(warmup)
        trainer = L.Trainer(
            accelerator=device.type,
            devices=1,
            precision="32-true",
            max_steps=warmup + steps,
            logger=False,
            enable_checkpointing=False,
            enable_progress_bar=False,
            enable_model_summary=False,
            limit_val_batches=0,
            num_sanity_val_steps=0,
            callbacks=[clock],
        )
        trainer.fit(prior, datamodule=dm)
        seconds = clock.t1 - clock.t0
        return (
            prior,
            trainer,
            {
                "row": "prior training" + (", compiled" if compile_model else ""),
                "batch": args.batch,
                "steps": clock.steps,
                "ms_per_call": 1000 * seconds / clock.steps,
                "seq_per_s": clock.steps * args.batch / seconds,
            },
        )

    prior, trainer, row = train(False)
    rows = [row]
    if args.compile:  # the warm-up steps take the compilation
        rows.append(train(True)[2])

    with tempfile.TemporaryDirectory() as tmp:
        ckpt = Path(tmp) / "prior.ckpt"
        trainer.save_checkpoint(ckpt)
        denoiser = DVAEDenoiseModule(prior_ckpt=str(ckpt), opt_iterations=args.opt_iterations).to(device).eval()
    ds = dm.datasets["train"]
    frames = dm.window_frames
    for name, batch_size in (
        ("regression", eval_batch),
        ("regression, batch 1", 1),
        (f"optimisation ({args.opt_iterations} it.)", min(eval_batch, 256)),
    ):
        batch = {k: v.to(device) for k, v in ds.__getitems__(list(range(batch_size))).items()}
        obs = denoiser.observation(denoiser.add_noise(batch, 0.1, torch.Generator().manual_seed(0)))
        if name.startswith("regression"):
            with torch.inference_mode():
                sec = timed(lambda obs=obs: denoiser.estimate(obs), device, repeat=10 if gpu else 2)
        else:
            # 50 ELBO steps are their own warm-up (and minutes on a CPU): one untimed call only on a GPU
            sec = timed(lambda obs=obs: denoiser.optimise_and_estimate(obs), device, repeat=1, warmup=1 if gpu else 0)
        rows.append(
            {"row": name, "batch": batch_size, "ms_per_call": 1000 * sec, "s_per_frame": sec / (batch_size * frames)}
        )

    result = {
        "benchmark": "dvae_speed",
        "env": describe(device),
        "command": " ".join(sys.argv),
        "frames_per_window": frames,
        "parameters": sum(p.numel() for p in prior.net.parameters()),
        "rows": rows,
    }
    path = write_result("dvae_speed", result, args.json_out)
    print_table(
        f"Motion-DVAE, {result['env'].get('gpu', result['env'].get('cpu'))}, "
        f"{result['parameters'] / 1e6:.1f} M parameters, {frames}-frame windows, fp32, "
        f"{torch.get_num_threads() if not gpu else ''}{' threads' if not gpu else ''}",
        rows,
        [
            ("row", "what"),
            ("batch", "batch"),
            ("ms_per_call", "ms/call"),
            ("seq_per_s", "seq/s"),
            ("s_per_frame", "s/frame"),
        ],
    )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
