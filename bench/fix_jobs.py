"""`mocapfix fix FOLDER --jobs N` on a machine's cores: the same folder of holed takes fixed with
each N, every run a separate `mocapfix fix` process (as a user starts it), the shipped XMAE on
the CPU. Per N: wall seconds, files per second and its ratio to --jobs 1, CPU seconds (the
process and its workers, user + system) per file, and whether every output is byte-identical
to --jobs 1's. The fill policy is measured over the folder's files on every run (fix FOLDER
does), in the workers when there are some.

The takes: those of --data (BVH or positions files) of --min-seconds or more, taken in turn to
make --count files, each with 16 holes of the full body, an arm or a leg of 0.3-0.9 s
(bench/fix_scaling.py). By default the CMU sample's takes of 8 s or more (120 fps, ~13 s each:
~4.5 CPU-s a file here); on a machine without ../shared, Bandai takes written by
`scripts/gpu_session.sh prepare` (30 fps, ~5 s each). --takes reads a folder of holed takes made
before (`--make-only`).

    python bench/fix_jobs.py                                  # 200 CMU takes, --jobs 1,2 here (~25 min)
    python bench/fix_jobs.py --data .device_data/bandai_takes --min-seconds 0 --jobs 1,16,8,4,2
"""

from __future__ import annotations

import argparse
import filecmp
import os
import tempfile
from pathlib import Path

import torch
from common import describe, print_table, write_result
from fix_scaling import DEFAULT_CMU, fix, holed_takes


def identical(a: Path, b: Path) -> bool:
    """Every file of folder a is in folder b, byte for byte, and b has no other."""
    names = sorted(p.name for p in a.iterdir())
    if names != sorted(p.name for p in b.iterdir()):
        return False
    _, mismatch, errors = filecmp.cmpfiles(a, b, names, shallow=False)
    return not mismatch and not errors


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(DEFAULT_CMU), help="BVH takes to cut holes into")
    ap.add_argument("--min-seconds", type=float, default=8.0, help="the takes of --data used: this long or more")
    ap.add_argument("--count", type=int, default=200, help="files made from --data")
    ap.add_argument("--takes", default=None, help="a folder of holed takes made before (--make-only)")
    ap.add_argument("--make-only", default=None, metavar="FOLDER", help="write the holed takes there and stop")
    ap.add_argument("--jobs", default="1,2", help="comma-separated --jobs values; the first is the baseline")
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    if args.make_only:
        Path(args.make_only).mkdir(parents=True, exist_ok=True)
        minutes = holed_takes(args.data, args.min_seconds, Path(args.make_only), args.count)
        print(f"{args.count} takes, {minutes:.1f} min of motion -> {args.make_only}")
        return 0
    jobs = [int(n) for n in args.jobs.split(",")]
    rows: list[dict] = []
    result = {"env": describe(torch.device("cpu")), "cores": len(os.sched_getaffinity(0)), "rows": rows}
    with tempfile.TemporaryDirectory(prefix="fix_jobs_") as tmp:
        work = Path(tmp)
        takes = Path(args.takes) if args.takes else work / "takes"
        if not args.takes:
            takes.mkdir()
            holed_takes(args.data, args.min_seconds, takes, args.count)
        files = len(list(takes.iterdir()))
        result.update(files=files, takes=str(args.takes or f"{args.count} from {args.data}"))
        print(f"{files} takes; --jobs {args.jobs} on {result['cores']} cores", flush=True)
        for n in jobs:
            run = fix(takes, work / f"out{n}", ["--device", "cpu"], jobs=n)
            row = {"jobs": n, "wall_s": round(run["wall_s"], 2), "files_per_s": round(files / run["wall_s"], 2)}
            row["x_first"] = round(row["files_per_s"] / (rows[0]["files_per_s"] if rows else row["files_per_s"]), 2)
            row["cpu_s"] = round(run["cpu_s"], 1)
            row["cpu_s_per_file"] = round(run["cpu_s"] / files, 3)
            row["peak_mb"] = round(run["peak_mb"])
            row["identical_to_first"] = identical(work / f"out{jobs[0]}", work / f"out{n}")
            rows.append(row)
            print(row, flush=True)
            write_result("fix_jobs", result, args.json_out)  # after each N: a run cut short keeps the rest
    path = write_result("fix_jobs", result, args.json_out)
    columns = [
        ("jobs", "--jobs"),
        ("wall_s", "wall s"),
        ("files_per_s", "files/s"),
        ("x_first", f"x --jobs {jobs[0]}"),
        ("cpu_s", "CPU s"),
        ("cpu_s_per_file", "CPU s/file"),
        ("peak_mb", "peak MB"),
        ("identical_to_first", "identical"),
    ]
    print_table(f"fix FOLDER --jobs N (xmae-cpu-bandai, CPU), {files} takes, {result['cores']} cores", rows, columns)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
