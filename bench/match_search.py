"""Motion matching's search with the proxy first (fills/motion_matching.py: PROXY_BASINS) against
the exact search of every grid start: the CMU sample's takes of 8 s or more (mapped onto the
shipped model's 21 joints), holes of the full body, the left arm or the left leg of 0.3-0.9 s,
4 per take, each searched in the folder's holed takes (as `fix FOLDER` does) and, with
--library, in a folder of other takes too. Per cell: MPJPE (mm) over the holes of "match" and
"match_delta" both ways, the largest difference between the two searches' fills, and the CPU
seconds of each search.

    python bench/match_search.py [--library /other/takes/of/the/same/people]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
from common import describe, print_table, write_result

import mocapfix.fills.motion_matching as mm  # noqa: E402
from mocapfix.core.skeleton import preset  # noqa: E402
from mocapfix.evaluation.recording import spread_holes, with_holes  # noqa: E402
from mocapfix.fills.classical import hermite_infill  # noqa: E402
from mocapfix.io import list_motion_files, read_motion  # noqa: E402
from mocapfix.rig.mapping import onto_skeleton  # noqa: E402

DEFAULT_CMU = Path(__file__).resolve().parents[2] / "shared" / "data" / "cmu-sample"
GAPS_S = (0.3, 0.5, 0.7, 0.9)
PARTS = {"full": None, "arm": "left_arm", "leg": "left_leg"}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(DEFAULT_CMU))
    ap.add_argument("--library", default=None, help="a folder of other takes of the same performers")
    ap.add_argument("--min-seconds", type=float, default=8.0)
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    body = preset("body21")
    clips = [read_motion(f)[0] for f in list_motion_files(args.data, "bvh")]
    takes = [onto_skeleton(c, body) for c in clips if c.duration_s >= args.min_seconds]
    extra = []
    if args.library:
        extra = [onto_skeleton(read_motion(f)[0], body) for f in list_motion_files(args.library, "bvh")]
    exact_basins = mm.PROXY_BASINS
    rows = []
    for part, group in PARTS.items():
        for gap in GAPS_S:
            holed, hiddens = [], []
            for c in takes:
                x = c.positions.astype(np.float64)
                hidden = spread_holes(len(x), x.shape[1], c.fps, gap, body.groups.get(group)) & np.isfinite(x).all(-1)
                holed.append(with_holes(x, hidden))
                hiddens.append(hidden)
            library = mm.MotionLibrary(
                [(h, c.fps) for h, c in zip(holed, takes)] + [(e.positions, e.fps) for e in extra],
                list(range(len(takes) + len(extra))),
                mm.mirror_of(body),
            )
            sums = {}
            for way, basins in (("exact", 10**9), ("proxy", exact_basins)):
                mm.PROXY_BASINS = basins
                err, seconds, fills = {n: [] for n in mm.FILLS}, 0.0, []
                for i, (c, h, hidden) in enumerate(zip(takes, holed, hiddens)):
                    observed = np.isfinite(h).all(-1)
                    xt = torch.from_numpy(h.astype(np.float64))[None]
                    hermite = hermite_infill(xt, torch.from_numpy(observed)[None])[0].numpy()
                    t0 = time.process_time()
                    out = mm.match_fills(h, observed, hermite, library.without(i, c.fps), c.fps)
                    seconds += time.process_time() - t0
                    truth = c.positions.astype(np.float64)
                    for n in mm.FILLS:
                        err[n].append(np.linalg.norm(out[n][hidden] - truth[hidden], axis=-1))
                    fills.append(out)
                sums[way] = ({n: 1000 * float(np.concatenate(e).mean()) for n, e in err.items()}, seconds, fills)
            mm.PROXY_BASINS = exact_basins
            apart = max(
                float(np.abs(a[n] - b[n]).max()) for a, b in zip(sums["exact"][2], sums["proxy"][2]) for n in mm.FILLS
            )
            row = {"part": part, "gap": gap}
            for way in ("exact", "proxy"):
                row.update({f"{n} {way}": sums[way][0][n] for n in mm.FILLS})
                row[f"cpu s {way}"] = round(sums[way][1], 2)
            row["largest difference mm"] = 1000 * apart
            rows.append(row)
            print(row, flush=True)
    result = {"env": describe(torch.device("cpu")), "data": args.data, "library": args.library, "rows": rows}
    result["proxy_basins"] = exact_basins
    path = write_result("match_search", result, args.json_out, "library" if args.library else None)
    columns = [("part", "part"), ("gap", "gap s")]
    columns += [(f"{n} {w}", f"{n} {w}") for n in mm.FILLS for w in ("exact", "proxy")]
    columns += [
        ("cpu s exact", "CPU s exact"),
        ("cpu s proxy", "CPU s proxy"),
        ("largest difference mm", "max diff mm"),
    ]
    print_table("motion matching: proxy search against the exact one, MPJPE mm over the holes", rows, columns)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
