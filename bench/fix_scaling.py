"""`mocapfix fix FOLDER` against the folder's size: 4, 16 and 64 copies of the same holed takes
(the CMU sample's takes of 8 s or more, performers the shipped model never saw, mapped onto its
21 joints; holes of the full body, an arm or a leg of 0.3-0.9 s, 16 per take), each run a
separate `mocapfix fix` process with --jobs 1, as a user starts it. Per run: CPU seconds (user +
system, of the process and every process it started), CPU seconds per minute of motion, the
marginal CPU seconds per minute between two sizes (the slope: what one more minute costs once
the run's fixed costs are paid), wall seconds and peak resident memory. The policy is measured
on every run (fix FOLDER does).

    python bench/fix_scaling.py                     # 4, 16, 64 copies (~15 min on 2 cores)
    python bench/fix_scaling.py --copies 1,4 --library /other/takes   # with fix --library
    python bench/fix_scaling.py --copies 4,16 --library /other/takes --library-index
        # the library read once into an index by a run on one take (its cost a row of its own),
        # every timed run reading the index (fix --library-index)
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from common import describe, print_table, write_result

from mocapfix.core.skeleton import preset  # noqa: E402
from mocapfix.evaluation.recording import spread_holes, with_holes  # noqa: E402
from mocapfix.io import list_motion_files, read_motion  # noqa: E402
from mocapfix.rig.mapping import onto_skeleton  # noqa: E402

DEFAULT_CMU = Path(__file__).resolve().parents[2] / "shared" / "data" / "cmu-sample"
PARTS = (None, "left_arm", "left_leg")
GAPS_S = (0.3, 0.5, 0.7, 0.9)


def holed_takes(data: str, min_seconds: float, folder: Path, count: int | None = None) -> float:
    """The long takes of `data` with holes, written as positions .npz into folder -> minutes.
    count: that many files, the takes taken in turn (each copy's holes in other parts)."""
    body, seconds = preset("body21"), 0.0
    takes = [read_motion(f)[0] for f in list_motion_files(data)]  # BVH or positions files
    takes = [onto_skeleton(c, body) for c in takes if c.duration_s >= min_seconds]
    for i in range(count or len(takes)):
        clip = takes[i % len(takes)]
        x = clip.positions.astype(np.float64)
        hidden = np.zeros(x.shape[:2], dtype=bool)
        for j, gap in enumerate(GAPS_S):  # 4 holes of each length, each length a part, shifted apart
            part = PARTS[(i + j) % len(PARTS)]
            holes = spread_holes(len(x), x.shape[1], clip.fps, gap, body.groups.get(part) if part else None)
            hidden |= np.roll(holes, int((j - 1.5) * 0.1 * len(x)), axis=0)
        np.savez(
            folder / f"take{i:03d}.npz",
            positions=with_holes(x, hidden),
            fps=np.float64(clip.fps),
            joint_names=np.array(body.joint_names),
            parents=np.array(body.parents),
        )
        seconds += clip.duration_s
    return seconds / 60


def fix(inputs: Path, out_dir: Path, extra: list[str], jobs: int = 1) -> dict:
    """One `mocapfix fix` process -> its CPU seconds (every process it started included), wall
    seconds and peak memory (of the process itself)."""
    cmd = [sys.executable, "-m", "mocapfix", "fix", str(inputs), "--model", "xmae-cpu-bandai"]
    cmd += ["--out-dir", str(out_dir), "--jobs", str(jobs), "--progress", "never", *extra]
    orphans_come_here()
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    err = proc.stderr.read()
    _, status, usage = os.wait4(proc.pid, 0)  # its own resources and those of the children it waited for
    cpu_s = usage.ru_utime + usage.ru_stime + orphans_cpu_s()
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode:
        raise SystemExit(f"fix failed ({proc.returncode}): {err[-2000:]}")
    return {"cpu_s": cpu_s, "wall_s": time.perf_counter() - t0, "peak_mb": usage.ru_maxrss / 1024}


def orphans_come_here() -> None:
    """Make this process the one that reaps the orphans of the processes it starts (Linux's
    PR_SET_CHILD_SUBREAPER): fix's workers are forked by a fork server that ends after the run,
    no process waits for it, and its workers' CPU (which it waited for) would be lost."""
    import ctypes

    if ctypes.CDLL(None, use_errno=True).prctl(36, 1, 0, 0, 0) != 0:  # PR_SET_CHILD_SUBREAPER
        raise SystemExit("this benchmark counts the CPU of fix's workers on Linux only")


def orphans_cpu_s() -> float:
    """CPU seconds of the orphans that came here (orphans_come_here), each waited for until it ends."""
    total = 0.0
    while True:
        try:
            _, _, usage = os.wait4(-1, 0)
        except ChildProcessError:
            return total
        total += usage.ru_utime + usage.ru_stime


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(DEFAULT_CMU))
    ap.add_argument("--min-seconds", type=float, default=8.0)
    ap.add_argument("--copies", default="4,16,64", help="comma-separated copies of the takes")
    ap.add_argument("--mode", default="infill", choices=("infill", "both"))
    ap.add_argument("--library", default=None, help="fix --library: a folder of other takes")
    ap.add_argument("--library-index", action="store_true", help="with --library: read it once into an index")
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    if args.library_index and not args.library:
        ap.error("--library-index needs --library")
    extra = ["--mode", args.mode] + (["--library", args.library] if args.library else [])
    variant = args.mode + ("-library" if args.library else "") + ("-index" if args.library_index else "")
    with tempfile.TemporaryDirectory(prefix="fix_scaling_") as tmp:
        work = Path(tmp)
        (work / "takes").mkdir()
        minutes = holed_takes(args.data, args.min_seconds, work / "takes")
        files = sorted((work / "takes").iterdir())
        print(f"{len(files)} takes, {minutes:.2f} min of motion; copies {args.copies}", flush=True)
        rows: list[dict] = []
        result = {"env": describe(torch.device("cpu")), "data": args.data, "mode": args.mode, "library": args.library}
        result.update(rows=rows, stopped_early=True)
        if args.library_index:  # made once, by a run on one take; every timed run below reads it
            extra += ["--library-index", str(work / "library.index.npz")]
            (work / "one").mkdir()
            os.link(files[0], work / "one" / files[0].name)
            build = fix(work / "one", work / "out_one", extra)
            result["index_build"] = {k: round(v, 1) for k, v in build.items()}
            print(f"index made by a run on one take: {result['index_build']}", flush=True)
        for copies in [int(c) for c in args.copies.split(",")]:
            folder = work / f"in{copies}"
            folder.mkdir()
            for c in range(copies):  # hard links: each a regular file of its own name
                for f in files:
                    os.link(f, folder / f"c{c:03d}_{f.name}")
            run = fix(folder, work / f"out{copies}", extra)
            row = {"copies": copies, "files": copies * len(files), "minutes": round(copies * minutes, 2)}
            row.update({k: round(v, 1) for k, v in run.items()})
            row["cpu_s_per_min"] = round(run["cpu_s"] / row["minutes"], 2)
            if rows:  # what one more minute costs, between this size and the one before
                row["marginal_cpu_s_per_min"] = round(
                    (run["cpu_s"] - rows[-1]["cpu_s"]) / (row["minutes"] - rows[-1]["minutes"]), 2
                )
            rows.append(row)
            print(row, flush=True)
            # written after every size: a run stopped at a large size keeps the smaller ones
            write_result("fix_scaling", result, args.json_out, variant)
    for row in rows:
        row["x_first_per_min"] = round(row["cpu_s_per_min"] / rows[0]["cpu_s_per_min"], 2)
        row["x_first_peak"] = round(row["peak_mb"] / rows[0]["peak_mb"], 2)
    result["stopped_early"] = False
    path = write_result("fix_scaling", result, args.json_out, variant)
    columns = [
        ("copies", "copies"),
        ("files", "files"),
        ("minutes", "min"),
        ("cpu_s", "CPU s"),
        ("cpu_s_per_min", "CPU s/min"),
        ("marginal_cpu_s_per_min", "marginal"),
        ("x_first_per_min", "x first"),
        ("wall_s", "wall s"),
        ("peak_mb", "peak MB"),
        ("x_first_peak", "x peak"),
    ]
    print_table(f"fix FOLDER --jobs 1 --mode {args.mode} (xmae-cpu-bandai), CMU takes copied", rows, columns)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
