"""The jitter remover (`fix --mode denoise --model jitter-many`) on real keypoint recordings from
depth cameras and video lifters, none of them in ../shared: public files the user fetched into
one folder (--root), one sub-folder per set below (SETS: where each was published, its layout,
rate and unit). Each file is read as `mocapfix fix FILE --layout L --fps F` reads it (formats
mocapfix does not read are first written as the .npz keypoint array it does: Kinect SDK .skl
logs, their tracking flag as the confidence column and their timestamps as `times`).

No truth exists for these takes, so this measures what the issue's bars name, over each take's
tokens the tracker reported (confidence above 0), at the joints the models' body has:
- mean acceleration (m/s^2 of |second difference| x fps^2, where three frames in a row are seen);
- limb sigma: the standard deviation over time of each bone's length between two such joints
  (frames where both ends are seen), mm, mean over the bones;
- moved: how far the output is from the input (mm, mean over tokens): the price of the cuts;
of the input, of fix's output and of a zero-phase 4th-order Butterworth low-pass at 6 Hz (the
biomechanics standard; holes bridged linearly before it, measured where the input is seen).
Per set: the mean over takes, and the cut each makes in the input's.

    python bench/keypoints_real.py --root /tmp/realkp      # ~2 min on 2 cores
"""

from __future__ import annotations

import argparse
import hashlib
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from common import describe, print_table, write_result
from keypoints_jitter import in_file_order
from scipy.signal import butter, filtfilt

from mocapfix.core.clip import MotionFileError  # noqa: E402
from mocapfix.core.skeleton import preset  # noqa: E402
from mocapfix.evaluation.recording import with_holes  # noqa: E402
from mocapfix.fix import fix_clips  # noqa: E402
from mocapfix.fix.fixers import load_fixer  # noqa: E402
from mocapfix.io import read_motion  # noqa: E402
from mocapfix.io.layouts import LAYOUTS, layout_skeleton  # noqa: E402
from mocapfix.pretrained import pretrained_path  # noqa: E402
from mocapfix.rig.mapping import match_joints  # noqa: E402

BODY = preset("body21")
MIN_FRAMES = 90  # 3 s at 30 fps: shorter takes say little about jitter over time
GAP_S = 0.1  # a Kinect log's clock jumping this much: the person left the view; the take is split


ALIASES = {"SpineShoulder": "ShoulderCenter"}  # some v2 logs name it as Kinect v1 did


class Set(NamedTuple):
    folders: tuple[str, ...]  # under --root
    pattern: str
    kind: str  # "native": mocapfix reads it; "skl": a Kinect SDK log written as .npz first
    layout: str
    fps: float | None  # None: from the file (its times)
    unit: str
    source: str  # where it was published
    min_frames: int = MIN_FRAMES  # shorter takes are left out


SETS = {
    "NTU RGB+D (Kinect v2)": Set(
        ("ntu_*",),
        "*.skeleton",
        "native",
        "kinect25",
        30.0,
        "auto",
        "open-mmlab/mmaction2@3237bb48 tools/data/skeleton/; "
        "LevelCA/NTU-RGB-D-skeleton-dataset-visualization 'dataset sample/'",
    ),
    "GaitKinect v1 gait (Kinect v1)": Set(
        ("gaitkinect",),
        "inputs__miky__*.skl",
        "skl",
        "kinect20",
        None,
        "m",
        "ranBernstein/GaitKinect Fourier/inputs/miky",
    ),
    "GaitKinect Laban (Kinect v2)": Set(
        ("gaitkinect",),
        "Laban__recordings__Karen__*.skl",
        "skl",
        "kinect25",
        None,
        "m",
        "ranBernstein/GaitKinect Fourier/Laban/recordings/Karen",
    ),
    "GaitKinect moods (Kinect v2)": Set(
        ("gaitkinect",),
        "inputs__Rachelle__*.skl",
        "skl",
        "kinect25",
        None,
        "m",
        "ranBernstein/GaitKinect Fourier/inputs/Rachelle/v2/recordingsByMood",
    ),
    "VideoPose3D skating (video)": Set(
        ("vp3d_skating",),
        "out_3D_vp3d.npz",
        "native",
        "h36m17",
        29.0,
        "m",
        "facebookresearch/VideoPose3D@ae3c0866 (a fork's in-the-wild output)",
    ),
    "MotionBERT boxing (video)": Set(
        ("motionbert_boxing",), "X3D.npy", "native", "h36m17", 29.6, "auto", "Walter0807/MotionBERT@638e8dd outputs/"
    ),
    "MHFormer demos (video)": Set(
        ("mhformer_TurnBody", "mhformer_sample_video"),  # not its 27-frame model's run of the same video
        "output_keypoints_3d.npz",
        "native",
        "h36m17",
        30.0,
        "m",
        "tsaith/MHFormer@dd68391b demo/output/*/output_3D/ (rate not published: 30 assumed)",
    ),
    "UTKinect-Action3D (Kinect v1)": Set(
        ("utkinect",),
        "joints_s*.txt",
        "native",
        "kinect20",
        30.0,  # the frame numbers' rate: the rows go on a 15-fps clock (io/kinect_text.py)
        "m",
        "the dataset's 20 joints_sXX_eXX.txt, as JeslieHCI/UTKinect_3@590aede4 data/UTKinect/joints/ holds them",
    ),
    "Azure Kinect (depth camera)": Set(
        ("azure_kinect",),
        "*positions*.csv",
        "native",
        "azure32",
        None,
        "auto",
        "justamad/PyMoCapViewer@8637135 data/azure_positions.csv; justamad/rpe-prediction's history "
        "(@45e94d7, @ad1bcd6: since deleted) data/*/azure/*_master/positions_3d.csv, eight people's squats",
    ),
    "MSR Action3D (depth camera)": Set(
        ("msr_action3d",),
        "*_skeleton3D.txt",
        "native",
        "kinect20",
        15.0,
        "m",
        "the dataset's 567 *_skeleton3D.txt, JeslieHCI/UTKinect_3@590aede4 data/MSRAction3D/real_world_coordinates/",
        45,  # 3 s at 15 fps
    ),
}


def skl_takes(path: Path, layout: str, out: Path) -> list[Path]:
    """A Kinect SDK log (tab-separated: timestamp, framenum, then X, Y, Z, tracked per joint by
    name) -> its runs without a clock jump, as .npz keypoint arrays (T, J, 4) in the layout's order
    with their times in seconds."""
    lines = path.read_text().splitlines()
    header = lines[0].split("\t")
    rows = np.array([[float(v) for v in line.split("\t")[: len(header)]] for line in lines[1:] if line.strip()])
    names = LAYOUTS[layout].joint_names
    names = [n if f"{n}_X" in header else ALIASES.get(n, n) for n in names]
    columns = [header.index(f"{n}_{c}") for n in names for c in ("X", "Y", "Z", "tracked")]
    x = rows[:, columns].reshape(len(rows), len(names), 4)
    stamp = rows[:, 0]
    # Kinect v2's logs count 100-ns ticks (~333,333 a frame), v1's milliseconds (~33)
    seconds = stamp * (1e-7 if np.median(np.diff(stamp)) > 1e4 else 1e-3)
    starts = np.concatenate([[0], np.flatnonzero(np.diff(seconds) > GAP_S) + 1, [len(rows)]])
    written = []
    for i, (a, b) in enumerate(zip(starts[:-1], starts[1:])):
        if b - a >= MIN_FRAMES:
            file = out / f"{path.stem}.{i}.npz"
            np.savez(file, keypoints=x[a:b], times=seconds[a:b] - seconds[a], unit="m")
            written.append(file)
    return written


def files_of(root: Path, s: Set, tmp: Path) -> list[Path]:
    """The set's files as mocapfix reads them, byte-identical copies once."""
    found, seen = [], set()
    for folder in sorted(f for pattern in s.folders for f in root.glob(pattern)):
        for f in sorted(folder.glob(s.pattern)):
            digest = hashlib.sha1(f.read_bytes()).hexdigest()
            if digest not in seen:
                seen.add(digest)
                found += skl_takes(f, s.layout, tmp) if s.kind == "skl" else [f]
    return found


def measures(x: np.ndarray, seen: np.ndarray, fps: float, joints: list[int], bones) -> dict:
    """x: (T, J, 3) metres; seen: (T, J) the input's observed tokens; measured there only."""
    x = with_holes(x, ~seen)[:, joints]
    acc = np.linalg.norm(np.diff(x, 2, axis=0), axis=-1) * fps**2  # NaN where a frame of three is unseen
    lengths = np.stack([np.linalg.norm(x[:, joints.index(j)] - x[:, joints.index(p)], axis=-1) for p, j in bones], -1)
    return {"acc_m_s2": float(np.nanmean(acc)), "limb_sigma_mm": float(np.nanmean(np.nanstd(lengths, 0)) * 1000)}


def butterworth(x: np.ndarray, seen: np.ndarray, fps: float) -> np.ndarray:
    """Each coordinate's track, its holes bridged linearly, through a 6-Hz zero-phase low-pass."""
    t = np.arange(len(x))
    bridged = x.copy()
    for j in range(x.shape[1]):
        if seen[:, j].sum() >= 2:
            for c in range(3):
                bridged[:, j, c] = np.interp(t, t[seen[:, j]], x[seen[:, j], j, c])
    b, a = butter(4, 6.0 / (fps / 2))
    return filtfilt(b, a, bridged, axis=0)


def set_row(name: str, s: Set, files: list[Path], fixer) -> dict:
    lay = LAYOUTS[s.layout]
    skeleton, order = layout_skeleton(lay)
    joints = sorted(order[k] for k in match_joints(skeleton, BODY).values())  # file columns the body has
    bones = [(p, j) for j, p in enumerate(lay.parents) if p in joints and j in joints]
    measured = {"input": [], "fix": [], "butterworth": []}
    moved = {"fix": [], "butterworth": []}
    frames, refused = 0, []
    for f in files:
        try:
            clips = read_motion(f, layout=s.layout, fps=s.fps, unit=s.unit)
        except MotionFileError as e:  # as fix would: said, and the set goes on
            print(f"refused: {e}")
            refused.append(f.name)
            continue
        for clip in clips:
            x = in_file_order(clip)
            seen = np.isfinite(x).all(-1)
            if seen.any(-1).sum() < s.min_frames:  # a person seen this briefly (a body ID of a moment) says little
                continue
            (out,), _ = fix_clips([clip], fixer, "denoise")
            outputs = {"input": x, "fix": in_file_order(out), "butterworth": butterworth(x, seen, clip.fps)}
            for key, y in outputs.items():
                measured[key].append(measures(y, seen, clip.fps, joints, bones))
                if key in moved:
                    moved[key].append(np.linalg.norm(y - x, axis=-1)[:, joints][seen[:, joints]].mean() * 1000)
            frames += clip.num_frames
    row = {"set": name, "layout": s.layout, "takes": len(measured["input"]), "frames": frames, "source": s.source}
    row["refused"] = refused
    row["files"] = sorted(f.name for f in files)  # what was read: a later run on another fetch compares
    if not row["takes"]:
        return row
    for key, values in measured.items():
        for m in ("acc_m_s2", "limb_sigma_mm"):
            row[f"{key}_{m}"] = float(np.mean([d[m] for d in values]))
    for key in ("fix", "butterworth"):
        row[f"{key}_moved_mm"] = float(np.mean(moved[key]))
        row[f"{key}_acc_cut"] = 1 - row[f"{key}_acc_m_s2"] / row["input_acc_m_s2"]
        row[f"{key}_sigma_cut"] = 1 - row[f"{key}_limb_sigma_mm"] / row["input_limb_sigma_mm"]
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--root", required=True, help="the folder holding the sets' sub-folders (SETS)")
    ap.add_argument("--model", default="jitter-many")
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    torch.set_grad_enabled(False)
    fixer = load_fixer(str(pretrained_path(args.model)), "cpu")
    rows: list[dict] = []
    result = {"env": describe(torch.device("cpu")), "model": args.model, "rows": rows}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="keypoints_real_") as tmp:
        for name, s in SETS.items():
            files = files_of(Path(args.root), s, Path(tmp))
            if not files:
                print(f"{name}: no {s.folders}/{s.pattern} under {args.root}, skipped")
                continue
            rows.append(set_row(name, s, files, fixer))
            print({k: round(v, 3) if isinstance(v, float) else v for k, v in rows[-1].items()}, flush=True)
    result["seconds"] = round(time.perf_counter() - t0)
    path = write_result("keypoints_real", result, args.json_out)
    columns = [
        ("set", "set"),
        ("takes", "takes"),
        ("frames", "frames"),
        ("input_acc_m_s2", "acc in"),
        ("fix_acc_cut", "fix acc cut"),
        ("butterworth_acc_cut", "Bw acc cut"),
        ("input_limb_sigma_mm", "sigma in mm"),
        ("fix_sigma_cut", "fix sigma cut"),
        ("butterworth_sigma_cut", "Bw sigma cut"),
        ("fix_moved_mm", "fix moved mm"),
        ("butterworth_moved_mm", "Bw moved mm"),
    ]
    print_table(f"jitter remover ({args.model}) on real keypoint recordings", rows, columns)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
