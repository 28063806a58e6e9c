"""`fix --mode denoise` (the jitter remover) on keypoint arrays in each published layout.

Clean takes (Bandai Namco's test split, 30 fps; the CMU sample's takes of 8 s or more, 120 fps,
performers no model trained on) are written in each layout of io/layouts.py (each joint the
layout shares with the body at the body's place, the others 5 cm from their parent), saved as
.npy and read back as `fix` reads them, then denoised by `fix_clips` as `mocapfix fix take.npy
--layout NAME --fps F --model jitter-many --mode denoise` runs it; `body21` is the models' own
21 joints, today's case. Over the layout's joints that the body has:

- clean: how far fix moves a take that had no jitter (mm, mean over tokens);
- noisy: Gaussian noise of --noise-mm per coordinate, fresh every frame, seeded per take: MPJPE
  to the clean take (mm), mean acceleration (m/s^2) and limb sigma (std over time of each bone's
  length between two such joints, mm, mean over bones) of the input, of fix's output and of a
  zero-phase 4th-order Butterworth low-pass at 6 Hz (the biomechanics standard), with the cut
  each makes in the input's.

    python bench/keypoints_jitter.py                  # ~10 min on 2 cores
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from common import describe, print_table, write_result
from scipy.signal import butter, filtfilt

from mocapfix.core.skeleton import preset  # noqa: E402
from mocapfix.data.windows import split_of  # noqa: E402
from mocapfix.fix import fix_clips  # noqa: E402
from mocapfix.fix.fixers import load_fixer  # noqa: E402
from mocapfix.io import list_motion_files, read_motion  # noqa: E402
from mocapfix.io.layouts import LAYOUTS, layout_skeleton, parents_first  # noqa: E402
from mocapfix.io.positions import write_positions  # noqa: E402
from mocapfix.pretrained import pretrained_path  # noqa: E402
from mocapfix.rig.mapping import match_joints, onto_skeleton  # noqa: E402

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
BODY = preset("body21")


def takes(name: str, data: Path, min_seconds: float) -> list[np.ndarray]:
    """Each take on body21: (T, 21, 3) metres, z up, with its fps."""
    files = list_motion_files(str(data), "bvh")
    if name == "bandai-test":  # the hash split every Bandai table uses (seed 0, 10 % val, 10 % test)
        files = [f for f in files if split_of(str(f), 0.1, 0.1, 0) == "test"]
    out = []
    for f in files:
        clip = read_motion(f)[0]
        if clip.duration_s >= min_seconds:
            clip = onto_skeleton(clip, BODY)
            out.append((clip.positions.astype(np.float64) + clip.origin, clip.fps))
    return out


def in_layout(name: str, body: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """body (T, 21, 3) -> (T, J, 3) in the layout's file order, and the file columns the body has."""
    if name == "body21":
        return body, list(range(BODY.num_joints))
    lay = LAYOUTS[name]
    skeleton, order = layout_skeleton(lay)
    found = match_joints(skeleton, BODY)  # body joint -> layout skeleton index
    out, placed = np.zeros((len(body), len(lay.joint_names), 3)), np.zeros(len(lay.joint_names), dtype=bool)
    for body_name, k in found.items():
        out[:, order[k]], placed[order[k]] = body[:, BODY.index(body_name)], True
    for j in parents_first(lay.parents):  # joints the body lacks: 5 cm from their parent
        if not placed[j]:
            out[:, j], placed[j] = out[:, lay.parents[j]] + np.array([0.05, 0.0, 0.02]), True
    return out, sorted(order[k] for k in found.values())


def bones(name: str, mapped: list[int]) -> list[tuple[int, int]]:
    parents = BODY.parents if name == "body21" else LAYOUTS[name].parents
    keep = set(mapped)
    return [(p, j) for j, p in enumerate(parents) if p >= 0 and p in keep and j in keep]


def measures(x: np.ndarray, clean: np.ndarray, fps: float, mapped: list[int], bone_list) -> dict:
    """x, clean: (T, J, 3) metres in the file's order; measured at the mapped joints and bones."""
    acc = np.linalg.norm(np.diff(x[:, mapped], 2, axis=0), axis=-1).mean() * fps**2
    lengths = np.stack([np.linalg.norm(x[:, j] - x[:, p], axis=-1) for p, j in bone_list], -1)  # (T, B)
    return {
        "mpjpe_mm": float(np.linalg.norm(x[:, mapped] - clean[:, mapped], axis=-1).mean() * 1000),
        "acc_m_s2": float(acc),
        "limb_sigma_mm": float(lengths.std(0).mean() * 1000),
    }


def in_file_order(clip) -> np.ndarray:
    """clip -> (T, J, 3) metres, z up, in the file's joint order, NaN where missing."""
    x = clip.positions.astype(np.float64) + clip.origin
    order = clip.meta.get("joint_order")
    if order is None:
        return x
    back = np.empty_like(x)
    back[:, order] = x
    return back


def denoised(path: Path, name: str, fps: float, fixer) -> np.ndarray:
    """The file as fix reads it, denoised -> (T, J, 3) metres z up in the file's order."""
    clips = read_motion(path, fps=fps, layout=None if name == "body21" else name)
    out, _ = fix_clips(clips, fixer, "denoise")
    return in_file_order(out[0])


def layout_row(name: str, clips, fixer, noise_mm: float, tmp: Path) -> dict:
    """One layout over one set of takes: the clean takes' movement and the noisy takes' measures."""
    moved, measured = [], {"input": [], "fix": [], "butterworth": []}
    for i, (body, fps) in enumerate(clips):
        clean, mapped = in_layout(name, body)
        bone_list = bones(name, mapped)
        noisy = clean + np.random.default_rng(i).normal(scale=noise_mm / 1000, size=clean.shape)
        outputs = {}
        for kind, x in (("clean", clean), ("noisy", noisy)):
            if name == "body21":  # today's case: a positions file with the body's names
                path = write_positions(tmp / f"{kind}.npz", x, fps, BODY)
            else:  # metres, z up (the reader tells the axis from the body)
                path = tmp / f"{kind}.npy"
                np.save(path, x.astype(np.float32))
            outputs[kind] = denoised(path, name, fps, fixer)
        moved.append(np.linalg.norm(outputs["clean"] - clean, axis=-1)[:, mapped].mean() * 1000)
        b, a = butter(4, 6.0 / (fps / 2))
        for key, z in (("input", noisy), ("fix", outputs["noisy"]), ("butterworth", filtfilt(b, a, noisy, axis=0))):
            measured[key].append(measures(z, clean, fps, mapped, bone_list))
    row = {"layout": name, "takes": len(clips), "clean_moved_mm": float(np.mean(moved))}
    for key, values in measured.items():
        for m in ("mpjpe_mm", "acc_m_s2", "limb_sigma_mm"):
            row[f"{key}_{m}"] = float(np.mean([d[m] for d in values]))
    for key in ("fix", "butterworth"):
        row[f"{key}_acc_cut"] = 1 - row[f"{key}_acc_m_s2"] / row["input_acc_m_s2"]
        row[f"{key}_sigma_cut"] = 1 - row[f"{key}_limb_sigma_mm"] / row["input_limb_sigma_mm"]
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", default="jitter-many")
    ap.add_argument("--noise-mm", type=float, default=10.0)
    ap.add_argument("--layouts", default="body21," + ",".join(LAYOUTS))
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    torch.set_grad_enabled(False)
    fixer = load_fixer(str(pretrained_path(args.model)), "cpu")
    sets = {
        "bandai-test": takes("bandai-test", SHARED / "bandai-namco", 2.0),
        "cmu-strangers": takes("cmu", SHARED / "cmu-sample", 8.0),
    }
    rows: list[dict] = []
    result = {"env": describe(torch.device("cpu")), "model": args.model, "noise_mm": args.noise_mm, "rows": rows}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="keypoints_jitter_") as tmp:
        for set_name, clips in sets.items():
            for name in args.layouts.split(","):
                rows.append({"set": set_name, **layout_row(name, clips, fixer, args.noise_mm, Path(tmp))})
                print({k: round(v, 3) if isinstance(v, float) else v for k, v in rows[-1].items()}, flush=True)
                write_result("keypoints_jitter", result, args.json_out)
    result["seconds"] = round(time.perf_counter() - t0)
    path = write_result("keypoints_jitter", result, args.json_out)
    columns = [
        ("set", "takes"),
        ("layout", "layout"),
        ("clean_moved_mm", "clean moved mm"),
        ("input_mpjpe_mm", "noisy mm"),
        ("fix_mpjpe_mm", "fix mm"),
        ("butterworth_mpjpe_mm", "Butterworth mm"),
        ("fix_acc_cut", "fix acc cut"),
        ("butterworth_acc_cut", "Bw acc cut"),
        ("fix_sigma_cut", "fix sigma cut"),
        ("butterworth_sigma_cut", "Bw sigma cut"),
    ]
    print_table(f"jitter remover ({args.model}) on keypoint layouts, noise {args.noise_mm:g} mm", rows, columns)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
