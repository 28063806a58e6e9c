"""`fix --mode denoise` on performers and rigs a model never saw, beside the classical filters.

Each take (the CMU sample, subjects 05-09, 120 fps, a 31-joint rig; Bandai Namco's test split,
30 fps) gets Gaussian noise on every joint's rotation but the root's (0.1 rad per axis-angle
coordinate, then forward kinematics) and on every joint's position (2 cm per coordinate), fresh
every frame, seeded per take. The noisy take goes through `fix` (fix_clips, the whole rig, as
`mocapfix fix take.bvh --mode denoise` runs it); MPJPE (mm) over the shipped models' 21 joints
(each take mapped onto them, rig/structure.py) against the clean take, beside a zero-phase
4th-order Butterworth low-pass at 6 Hz (scipy's filtfilt: the biomechanics standard), Gaussian
smoothing at several widths and the model's own low-pass (what it corrects). The same on the
clean takes: how far each method moves motion that had no noise.

    python bench/denoise_strangers.py --model jitter-many
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
from common import describe, print_table, write_result
from scipy.ndimage import gaussian_filter1d
from scipy.signal import butter, filtfilt

from mocapfix.core.skeleton import preset  # noqa: E402
from mocapfix.data.corruption import rotation_noise  # noqa: E402
from mocapfix.data.windows import split_of  # noqa: E402
from mocapfix.fix import fix_clips  # noqa: E402
from mocapfix.fix.fixers import load_fixer  # noqa: E402
from mocapfix.io import list_motion_files, read_motion  # noqa: E402
from mocapfix.models.jitter import lowpass  # noqa: E402
from mocapfix.pretrained import pretrained_path  # noqa: E402
from mocapfix.rig.mapping import onto_skeleton  # noqa: E402

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
GAUSSIAN_S = (0.02, 0.04, 0.06)  # sigma of the Gaussian smoothing, seconds


def takes(name: str, data: Path) -> list[Path]:
    files = list_motion_files(str(data), "bvh")
    if name == "bandai-test":  # the hash split every Bandai table uses (seed 0, 10 % val, 10 % test)
        files = [f for f in files if split_of(str(f), 0.1, 0.1, 0) == "test"]
    return files


def classical(x: np.ndarray, fps: float) -> dict[str, np.ndarray]:
    """x: (T, J, 3) -> each classical filter's output."""
    b, a = butter(4, 6.0 / (fps / 2))
    out = {"butterworth 6 Hz": filtfilt(b, a, x, axis=0)}
    for s in GAUSSIAN_S:
        out[f"gaussian {1000 * s:g} ms"] = gaussian_filter1d(x, s * fps, axis=0, mode="nearest")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    which = ap.add_mutually_exclusive_group()
    which.add_argument("--model", default="jitter-many")
    which.add_argument("--ckpt", default=None)
    ap.add_argument("--cmu", default=str(SHARED / "cmu-sample"))
    ap.add_argument("--bandai", default=str(SHARED / "bandai-namco"))
    ap.add_argument("--rotation-noise-rad", type=float, default=0.1)
    ap.add_argument("--position-noise-m", type=float, default=0.02)
    ap.add_argument("--limit", type=int, default=None, help="at most this many takes per dataset")
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    ckpt = args.ckpt or str(pretrained_path(args.model))
    fixer = load_fixer(ckpt)
    body = preset("body21")
    t0 = time.perf_counter()
    rows, skipped, takes_used = [], [], {}
    for dataset, folder in (("cmu 05-09", Path(args.cmu)), ("bandai-test", Path(args.bandai))):
        sums: dict[tuple[str, str], list[float]] = {}
        files = takes(dataset, folder)[: args.limit]
        for i, f in enumerate(files):
            clip = read_motion(f)[0]
            if not clip.has_rotations:  # CMU 07_12: a teleport read as absurd values
                skipped.append(f"{f.name} ({clip.meta.get('no_rotations')})")
                continue
            g = torch.Generator().manual_seed(i)
            rot, root = torch.from_numpy(clip.rotations)[None], torch.from_numpy(clip.root_translation)[None]
            offsets = torch.from_numpy(clip.offsets)
            _, noisy = rotation_noise(
                rot.double(), root.double(), offsets.double(), clip.skeleton.parents, args.rotation_noise_rad, g
            )
            noisy = (
                noisy[0].numpy()
                + args.position_noise_m * torch.randn(noisy.shape[1:], generator=g, dtype=torch.float64).numpy()
            )
            truth = onto_skeleton(clip, body).positions.astype(np.float64)
            for condition, positions in (("noisy", noisy), ("clean", clip.positions)):
                take = clip.replace(
                    positions=positions.astype(np.float32), rotations=None, root_translation=None, offsets=None
                )
                x = onto_skeleton(take, body).positions.astype(np.float64)
                outputs = {"input": x, **classical(x, clip.fps)}
                xt = torch.from_numpy(x)[None]
                outputs["model's low-pass"] = lowpass(xt, clip.fps, fixer.net.cutoff_hz)[0].numpy()
                (fixed,), _ = fix_clips([take], fixer, "denoise")
                outputs["mocapfix fix"] = onto_skeleton(fixed, body).positions
                for name, out in outputs.items():
                    s = sums.setdefault((condition, name), [0.0, 0])
                    s[0] += 1000 * float(np.linalg.norm(out - truth, axis=-1).sum())
                    s[1] += truth.shape[0] * truth.shape[1]
        for (condition, name), (total, count) in sums.items():
            rows.append({"data": dataset, "input": condition, "method": name, "mpjpe_mm": total / count})
        for r in rows:
            if r["data"] == dataset:
                r["x_input"] = (
                    r["mpjpe_mm"]
                    / next(
                        q["mpjpe_mm"]
                        for q in rows
                        if (q["data"], q["input"], q["method"]) == (dataset, r["input"], "input")
                    )
                    if r["input"] == "noisy"
                    else None
                )
        takes_used[dataset] = len(files) - sum(s.startswith(tuple(f.name for f in files)) for s in skipped)
        print(f"{dataset}: {takes_used[dataset]} takes", flush=True)
    result = {
        "env": describe(torch.device("cpu")),
        "checkpoint": ckpt,
        "rotation_noise_rad": args.rotation_noise_rad,
        "position_noise_m": args.position_noise_m,
        "seconds": round(time.perf_counter() - t0, 1),
        "takes": takes_used,
        "skipped (no joint rotations to put noise on)": skipped,
        "rows": rows,
    }
    path = write_result("denoise_strangers", result, args.json_out)
    columns = [
        ("data", "data"),
        ("input", "input"),
        ("method", "method"),
        ("mpjpe_mm", "MPJPE mm"),
        ("x_input", "x noisy"),
    ]
    print_table("fix --mode denoise against the classical filters, 21 joints", rows, columns)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
