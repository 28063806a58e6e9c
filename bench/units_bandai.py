"""Reading recordings at their true size (issue 17): Bandai Namco clips written back in other
units and with y or z up, read again with unit "auto": the unit found, the hip height against the
original centimetre read, and whether the up axis came back.

    python bench/units_bandai.py [--every 48]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch
from common import describe, print_table, write_result

from mocapfix.io.bvh import read_bvh, write_bvh  # noqa: E402

DEFAULT_BVH = Path(__file__).resolve().parents[2] / "shared" / "data" / "bandai-namco"
UNITS = ("mm", "inch", "0.0564", "0.037")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--path", default=str(DEFAULT_BVH))
    ap.add_argument("--every", type=int, default=48, help="every Nth file of the folder")
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    files = sorted(Path(args.path).rglob("*.bvh"))[:: args.every]
    found: dict[str, list] = {u: [] for u in UNITS}
    with tempfile.TemporaryDirectory() as tmp:
        for f in files:
            clip = read_bvh(f)[0]
            hip = float(np.nanmean(clip.positions[:, clip.skeleton.index("Hips"), 2]))
            for unit in UNITS:
                for up in ("y", "z"):
                    g = Path(tmp) / "converted.bvh"
                    write_bvh(g, clip.replace(meta={**clip.meta, "unit": unit, "up_axis": up}))
                    back = read_bvh(g)[0]
                    ratio = float(np.nanmean(back.positions[:, back.skeleton.index("Hips"), 2])) / hip
                    found[unit].append((back.meta["unit"], ratio, back.meta["up_axis"] == up))
    rows = [
        {
            "written_in": u,
            "unit_found": ", ".join(sorted({x[0] for x in v})),
            "hip_ratio_min": min(x[1] for x in v),
            "hip_ratio_max": max(x[1] for x in v),
            "up_axis_right": f"{sum(x[2] for x in v)} of {len(v)}",
        }
        for u, v in found.items()
    ]
    result = {
        "benchmark": "units_bandai",
        "env": describe(torch.device("cpu")),
        "command": " ".join(sys.argv),
        "files": len(files),
        "rows": rows,
    }
    path = write_result("units_bandai", result, args.json_out)
    print_table(
        f"{len(files)} Bandai files written in other units, y and z up, read with unit auto",
        rows,
        [
            ("written_in", "written in"),
            ("unit_found", "unit found"),
            ("hip_ratio_min", "hip / cm read min"),
            ("hip_ratio_max", "max"),
            ("up_axis_right", "up axis right"),
        ],
    )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
