"""A limb flipped 45-90 degrees for 0.2-0.6 s (an IK solver's flip), found by fix/flips.py and
filled again by `fix --mode both`; the takes as recorded searched the same way.

Takes: Bandai Namco's (30 fps) and the CMU sample's (120 fps, performers no model trained on), on
the models' 21 joints, positions only. Each take of 2 s or more gets one flip, one at a time: an
arm or a leg in turn (every joint below its top turned about the top by an angle of 45-90
degrees about a random axis, for 0.2-0.6 s, seeded). Per set: how many flips were found (a
segment found within 2 frames of the flip's ends), the flipped limb's MPJPE over the flip before
and after fix_clips(--mode both, the shipped XMAE) and its cut, the share of flips whose error
was cut by 80 % or more; and the segments found in the takes as recorded (Bandai's are studio
mocap; CMU subject 05's right knee swings about its hip-ankle line for tenths of a second, a
real solver's flip).

    python bench/flips.py                       # ~5 min on 2 cores
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
from common import describe, print_table, write_result
from scipy.spatial.transform import Rotation

from mocapfix.core.skeleton import preset  # noqa: E402
from mocapfix.fix import fix_clips  # noqa: E402
from mocapfix.fix.fixers import load_fixer  # noqa: E402
from mocapfix.fix.flips import LIMBS, flipped_segments  # noqa: E402
from mocapfix.io import list_motion_files, read_motion  # noqa: E402
from mocapfix.pretrained import pretrained_path  # noqa: E402
from mocapfix.rig.mapping import onto_skeleton  # noqa: E402

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
BODY = preset("body21")


def flipped(x: np.ndarray, limb: list[int], start: int, frames: int, rng) -> np.ndarray:
    """x with the joints below limb[0] turned about it for `frames` frames from `start`."""
    axis = rng.normal(size=3)
    turn = Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.deg2rad(rng.uniform(45, 90))).as_matrix()
    out, top = x.copy(), limb[0]
    for j in limb[1:]:
        out[start : start + frames, j] = (x[start : start + frames, j] - x[start : start + frames, top]) @ turn.T + x[
            start : start + frames, top
        ]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", default="xmae-cpu-bandai")
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    torch.set_grad_enabled(False)
    fixer = load_fixer(str(pretrained_path(args.model)), "cpu")
    rows: list[dict] = []
    result = {"env": describe(torch.device("cpu")), "command": "python bench/flips.py", "model": args.model}
    result["rows"] = rows
    t0 = time.perf_counter()
    for set_name, folder in (("bandai", SHARED / "bandai-namco"), ("cmu", SHARED / "cmu-sample")):
        rng = np.random.default_rng(0)
        found_as_recorded = frames_seen = tried = found = cut80 = 0
        before, after = [], []
        for k, path in enumerate(list_motion_files(str(folder), "bvh")):
            clip = read_motion(path)[0]
            clip = onto_skeleton(clip, BODY).replace(rotations=None, root_translation=None, offsets=None)
            x, fps = clip.positions.astype(np.float64), clip.fps
            found_as_recorded += sum(len(flipped_segments(x, list(BODY.groups[g]), fps)) for g in LIMBS)
            frames_seen += len(x)
            if clip.duration_s < 2.0:
                continue
            limb = list(BODY.groups[("left_arm", "right_leg", "right_arm", "left_leg")[k % 4]])
            frames = int(round(rng.uniform(0.2, 0.6) * fps))
            start = int(rng.integers(round(0.5 * fps), len(x) - frames - round(0.5 * fps)))
            bad = flipped(x, limb, start, frames, rng)
            segments = flipped_segments(bad, limb, fps)
            tried += 1
            found += any(abs(a - start) <= 2 and abs(b - start - frames) <= 2 for a, b in segments)
            out, _ = fix_clips([clip.replace(positions=bad.astype(np.float32))], fixer, "both")
            y = out[0].positions.astype(np.float64)
            span = slice(start, start + frames)
            e0 = np.linalg.norm(bad[span][:, limb] - x[span][:, limb], axis=-1).mean() * 1000
            e1 = np.linalg.norm(y[span][:, limb] - x[span][:, limb], axis=-1).mean() * 1000
            before.append(e0)
            after.append(e1)
            cut80 += e1 <= 0.2 * e0
        row = {"set": set_name, "flips": tried, "found_share": found / max(tried, 1)}
        row.update(before_mm=float(np.mean(before)), after_mm=float(np.mean(after)))
        row.update(error_cut=1 - row["after_mm"] / row["before_mm"], cut_80_share=cut80 / max(tried, 1))
        row.update(frames_as_recorded=frames_seen, found_as_recorded=found_as_recorded)
        rows.append(row)
        print({k: round(v, 3) if isinstance(v, float) else v for k, v in row.items()}, flush=True)
    result["seconds"] = round(time.perf_counter() - t0)
    path = write_result("flips", result, args.json_out)
    columns = [
        ("set", "takes"),
        ("flips", "flips"),
        ("found_share", "found"),
        ("before_mm", "before mm"),
        ("after_mm", "after mm"),
        ("error_cut", "cut"),
        ("cut_80_share", "cut >= 80 %"),
        ("frames_as_recorded", "frames as recorded"),
        ("found_as_recorded", "found there"),
    ]
    print_table(f"limbs flipped 45-90 degrees for 0.2-0.6 s, fix --mode both ({args.model})", rows, columns)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
