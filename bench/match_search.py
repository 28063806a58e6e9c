"""Motion matching's search of a long library three ways: scoring every start with the whole
query (exact), scoring the grid with a proxy of the query first (fills/motion_matching.py:
PROXY_BASINS), and the index of the library's frames by the pose at a hole's edges
(fills/motion_index.py; what fix runs where the skeleton's sides pair up). The takes of --data
(the CMU sample's of 8 s or more by default; mapped onto the shipped model's 21 joints), holes of
the full body, the left arm or the left leg of 0.3-0.9 s, 4 per take, in --max-takes of them
(evenly spread; all by default), each searched in every take of --data (holed or not), as
`fix FOLDER` does, and, with --library, in a folder of other takes too. Per cell and way: MPJPE
(mm) over the holes of "match" and "match_delta", the CPU seconds of the searches, and the
largest difference between a way's fills and the exact search's.

    python bench/match_search.py [--library /other/takes/of/the/same/people]
    python bench/match_search.py --data ../shared/data/bandai-namco --min-seconds 0 --max-takes 40
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
WAYS = ("exact", "proxy", "index")


def searched(way: str, monkey: dict) -> None:
    """Set motion matching's module up for one way of searching (monkey: its settings as shipped)."""
    mm.PROXY_BASINS = 10**9 if way == "exact" else monkey["PROXY_BASINS"]  # no source long enough: all scored
    mm._index_places = monkey["_index_places"] if way == "index" else (lambda *a: None)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(DEFAULT_CMU))
    ap.add_argument("--library", default=None, help="a folder of other takes of the same performers")
    ap.add_argument("--min-seconds", type=float, default=8.0)
    ap.add_argument("--max-takes", type=int, default=None, help="holes in this many takes (evenly spread)")
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    body = preset("body21")
    clips = [read_motion(f)[0] for f in list_motion_files(args.data, "bvh")]
    takes = [onto_skeleton(c, body) for c in clips if c.duration_s >= args.min_seconds]
    queried = list(range(len(takes)))
    if args.max_takes and args.max_takes < len(takes):
        queried = sorted({int(i) for i in np.linspace(0, len(takes) - 1, args.max_takes).round()})
    extra = []
    if args.library:
        extra = [onto_skeleton(read_motion(f)[0], body) for f in list_motion_files(args.library, "bvh")]
    shipped = {"PROXY_BASINS": mm.PROXY_BASINS, "_index_places": mm._index_places}
    rows = []
    for part, group in PARTS.items():
        for gap in GAPS_S:
            holed, hiddens = [], {}
            for i, c in enumerate(takes):
                x = c.positions.astype(np.float64)
                if i in queried:
                    holes = spread_holes(len(x), x.shape[1], c.fps, gap, body.groups.get(group))
                    hiddens[i] = holes & np.isfinite(x).all(-1)
                    x = with_holes(x, hiddens[i])
                holed.append(x)
            library = mm.MotionLibrary(
                [(h, c.fps) for h, c in zip(holed, takes)] + [(e.positions, e.fps) for e in extra],
                list(range(len(takes) + len(extra))),
                mm.mirror_of(body),
                mm.torso_of(body),
            )
            sums = {}
            for way in WAYS:
                searched(way, shipped)
                err, seconds, fills = {n: [] for n in mm.FILLS}, 0.0, []
                for i, hidden in hiddens.items():
                    c, h = takes[i], holed[i].astype(np.float64)
                    observed = np.isfinite(h).all(-1)
                    xt = torch.from_numpy(h)[None]
                    hermite = hermite_infill(xt, torch.from_numpy(observed)[None])[0].numpy()
                    t0 = time.process_time()
                    out = mm.match_fills(h, observed, hermite, library.without(i, c.fps), c.fps)
                    seconds += time.process_time() - t0
                    truth = c.positions.astype(np.float64)
                    for n in mm.FILLS:
                        err[n].append(np.linalg.norm(out[n][hidden] - truth[hidden], axis=-1))
                    fills.append(out)
                sums[way] = ({n: 1000 * float(np.concatenate(e).mean()) for n, e in err.items()}, seconds, fills)
            searched("index", shipped)
            row = {"part": part, "gap": gap}
            for way in WAYS:
                row.update({f"{n} {way}": sums[way][0][n] for n in mm.FILLS})
                row[f"cpu s {way}"] = round(sums[way][1], 2)
                if way != "exact":
                    pairs = zip(sums["exact"][2], sums[way][2])
                    row[f"largest difference mm {way}"] = 1000 * max(
                        float(np.abs(a[n] - b[n]).max()) for a, b in pairs for n in mm.FILLS
                    )
            rows.append(row)
            print(row, flush=True)
    result = {"env": describe(torch.device("cpu")), "data": args.data, "library": args.library, "rows": rows}
    result.update(
        takes=len(takes),
        queried=len(queried),
        proxy_basins=shipped["PROXY_BASINS"],
        index_places=mm.INDEX_PLACES,
        index_kept=mm.INDEX_KEPT,
        index_near=mm.INDEX_NEAR,
    )
    path = write_result("match_search", result, args.json_out, "library" if args.library else None)
    columns = [("part", "part"), ("gap", "gap s")]
    columns += [(f"{n} {w}", f"{n} {w}") for n in mm.FILLS for w in WAYS]
    columns += [(f"cpu s {w}", f"CPU s {w}") for w in WAYS]
    print_table("motion matching: the library searched three ways, MPJPE mm over the holes", rows, columns)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
