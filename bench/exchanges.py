"""Left and right limbs exchanged for 3-30 frames (at 30 fps; 12-120 at the CMU sample's 120),
found and put back by fix/exchanges.py, and clean takes left alone.

Takes: Bandai Namco's (all 384, 30 fps) and the CMU sample's (70, 120 fps, performers no model
trained on), on the models' 21 joints, with Gaussian jitter of --noise-mm per coordinate (a
tracker's; 0 too). Each take gets --per-take exchanges, one at a time (arms or legs in turn,
length and place drawn, seeded): put back exactly (every token where it was) or not; and the
take as it is: any exchange put back there is invented.

    python bench/exchanges.py                       # ~1 min on 2 cores
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
from common import describe, print_table, write_result

from mocapfix.core.skeleton import preset  # noqa: E402
from mocapfix.fix.exchanges import put_back_exchanges  # noqa: E402
from mocapfix.io import list_motion_files, read_motion  # noqa: E402
from mocapfix.rig.mapping import onto_skeleton  # noqa: E402

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
BODY = preset("body21")
PAIRS = (("left_arm", "right_arm"), ("left_leg", "right_leg"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--noise-mm", default="0,10,25")
    ap.add_argument("--per-take", type=int, default=3)
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    sets = {}
    for name, folder in (("bandai", SHARED / "bandai-namco"), ("cmu", SHARED / "cmu-sample")):
        clips = [read_motion(f)[0] for f in list_motion_files(str(folder), "bvh")]
        sets[name] = [(onto_skeleton(c, BODY).positions.astype(np.float64), c.fps) for c in clips]
    rows: list[dict] = []
    result = {"env": describe(torch.device("cpu")), "command": "python bench/exchanges.py", "rows": rows}
    t0 = time.perf_counter()
    for set_name, takes in sets.items():
        for noise_mm in (float(v) for v in args.noise_mm.split(",")):
            rng = np.random.default_rng(0)
            invented_runs = invented_frames = frames_seen = tried = put_back = 0
            for x, fps in takes:
                x = x + rng.normal(scale=noise_mm / 1000, size=x.shape)
                y, runs, n = put_back_exchanges(x, BODY, fps)
                invented_runs, invented_frames, frames_seen = (
                    invented_runs + runs,
                    invented_frames + n,
                    frames_seen + len(x),
                )
                scale = round(fps / 30)  # 3-30 frames at 30 fps: the same seconds at any rate
                for k in range(args.per_take):
                    length = int(rng.integers(3, 31)) * scale
                    if len(x) <= length + 21 * scale:
                        continue
                    start = int(rng.integers(10 * scale, len(x) - length - 10 * scale))
                    left, right = (list(BODY.groups[g]) for g in PAIRS[k % 2])
                    bad = x.copy()
                    bad[start : start + length, left + right] = x[start : start + length, right + left]
                    z, runs, _ = put_back_exchanges(bad, BODY, fps)
                    tried += 1
                    put_back += bool(np.array_equal(z, x, equal_nan=True))  # a take may have missing frames
            row = {"set": set_name, "noise_mm": noise_mm, "takes": len(takes), "exchanges": tried}
            row.update(put_back=put_back, put_back_share=put_back / max(tried, 1))
            row.update(clean_frames=frames_seen, invented_runs=invented_runs, invented_frames=invented_frames)
            rows.append(row)
            print(row, flush=True)
    result["seconds"] = round(time.perf_counter() - t0)
    path = write_result("exchanges", result, args.json_out)
    columns = [
        ("set", "takes"),
        ("noise_mm", "jitter mm"),
        ("exchanges", "exchanges"),
        ("put_back_share", "put back"),
        ("clean_frames", "clean frames"),
        ("invented_runs", "invented"),
    ]
    print_table("left/right exchanges of 3-30 frames (at 30 fps)", rows, columns)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
