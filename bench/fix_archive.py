"""`mocapfix fix` over an archive: workers, shards, a killed run resumed, memory against take length.

Inputs: the first --takes Bandai Namco takes (sorted), each with holes cut into it (12 holes of
0.5 s of one joint, seeded per take: fix has work to do) and written as positions .npz (--as-is:
the BVH files as recorded, each fixed back into a BVH); a long
take and a 60-s take of Bandai motion played end to end. Every run is a separate `mocapfix fix`
process (as a user or a scheduler starts it), the shipped XMAE, on this machine:

1. --jobs 1 and --jobs N (N = the cores here): wall time, files per second, outputs compared byte
   for byte;
2. --shard 0/2 and --shard 1/2: together, the same files and bytes as the unsharded run;
3. --jobs N killed with SIGKILL when half the outputs are written (until then, every file under a
   final name is checked against the uninterrupted run's), then rerun with --resume: every
   output there and identical;
4. `fix --mode both` of the long take and of the 60-s take: peak memory (/usr/bin/time -v) and
   seconds per minute of motion.

    python bench/fix_archive.py                       # 200 takes, a 30-min take (~25 min on 2 cores)
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch  # noqa: E402
from common import describe, write_result

from mocapfix.evaluation.recording import random_holes, with_holes  # noqa: E402
from mocapfix.io import read_motion  # noqa: E402

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "bandai-namco"
MODEL = "xmae-cpu-bandai"


def write_take(path: Path, positions: np.ndarray, clip) -> None:
    np.savez(
        path,
        positions=positions.astype(np.float32),
        fps=np.float64(clip.fps),
        joint_names=np.array(clip.skeleton.joint_names),
        parents=np.array(clip.skeleton.parents),
    )


def holed(positions: np.ndarray, fps: float, seed: int, holes: int = 12) -> np.ndarray:
    """positions (T, J, 3) with `holes` holes of one joint for 0.5 s each (seeded): fix has work."""
    return with_holes(positions, random_holes(*positions.shape[:2], fps, seed, count=holes))


def fix(inputs: Path, out_dir: Path, *extra: str) -> tuple[float, int]:
    """-> (seconds, exit code) of one `mocapfix fix` process."""
    cmd = [sys.executable, "-m", "mocapfix", "fix", str(inputs), "--model", MODEL, "--out-dir", str(out_dir), *extra]
    t0 = time.perf_counter()
    rc = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True).returncode
    return time.perf_counter() - t0, rc


def contents(folder: Path) -> dict[str, bytes]:
    """Outputs under their final names (hidden partial and lock files are not outputs)."""
    return {p.name: p.read_bytes() for p in sorted(folder.glob("*")) if not p.name.startswith(".")}


def peak_memory(take: Path, out: Path) -> tuple[float, float]:
    """-> (peak resident MB, seconds) of `fix --mode both` on one take."""
    cmd = ["/usr/bin/time", "-v", sys.executable, "-m", "mocapfix", "fix", str(take), "--model", MODEL]
    cmd += ["--mode", "both", "-o", str(out), "--force", "--progress", "never"]
    t0 = time.perf_counter()
    run = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, check=True)
    seconds = time.perf_counter() - t0
    kb = next(int(line.split(":")[1]) for line in run.stderr.splitlines() if "Maximum resident set size" in line)
    return kb / 1024, seconds


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(SHARED))
    ap.add_argument("--takes", type=int, default=200)
    ap.add_argument("--long-minutes", type=float, default=30.0, help="0: no memory part")
    ap.add_argument("--jobs", type=int, default=len(os.sched_getaffinity(0)))
    ap.add_argument("--as-is", action="store_true", help="the takes as they are (BVH), no holes cut")
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="fix_archive_"))
    result: dict = {"env": describe(torch.device("cpu")), "model": MODEL, "takes": args.takes, "jobs": args.jobs}
    result["inputs"] = "BVH as recorded" if args.as_is else "positions .npz, 12 holes of 0.5 s each"
    try:
        inputs = work / "in"
        inputs.mkdir()
        files = sorted(Path(args.data).rglob("*.bvh"))[: args.takes]
        motion, first = [], None
        for k, f in enumerate(files):
            clip = read_motion(f)[0]
            first = first or clip
            motion.append(clip.positions)
            if args.as_is:  # the BVH files themselves: a BVH back for each
                (inputs / f.name).symlink_to(f)
            else:
                write_take(inputs / f"{f.stem}.npz", holed(clip.positions, clip.fps, k), clip)
        minutes = sum(len(m) for m in motion) / first.fps / 60
        result["minutes_of_motion"] = round(minutes, 2)
        print(f"{len(files)} takes, {minutes:.1f} min of motion", flush=True)

        # 1. one worker against N
        runs = {}
        for jobs in (1, args.jobs):
            seconds, rc = fix(inputs, work / f"jobs{jobs}", "--jobs", str(jobs))
            runs[jobs] = {"seconds": round(seconds, 1), "files_per_s": round(len(files) / seconds, 3), "rc": rc}
            print(f"--jobs {jobs}: {seconds:.1f} s, {len(files) / seconds:.2f} files/s (rc {rc})", flush=True)
        reference = contents(work / "jobs1")
        result["workers"] = {
            "runs": runs,
            "speedup": round(runs[1]["seconds"] / runs[args.jobs]["seconds"], 3),
            "outputs": len(reference),
            "identical": contents(work / f"jobs{args.jobs}") == reference,
        }

        # 2. two shards into one folder
        for i in (0, 1):
            fix(inputs, work / "shards", "--jobs", str(args.jobs), "--shard", f"{i}/2")
        result["shards_identical"] = contents(work / "shards") == reference

        # 3. killed halfway, then resumed
        killed = work / "killed"
        cmd = [sys.executable, "-m", "mocapfix", "fix", str(inputs), "--model", MODEL, "--out-dir", str(killed)]
        proc = subprocess.Popen(
            [*cmd, "--jobs", str(args.jobs)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
        deadline, partial_seen = time.perf_counter() + 2 * runs[args.jobs]["seconds"], []
        while time.perf_counter() < deadline:  # until half the outputs are there
            now = contents(killed) if killed.exists() else {}
            partial_seen += [name for name, data in now.items() if data != reference.get(name)]
            if len(now) >= len(reference) // 2:
                break
            time.sleep(0.1)
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        before = len(contents(killed))
        seconds, rc = fix(inputs, killed, "--jobs", str(args.jobs), "--resume")
        result["kill_resume"] = {
            "outputs_when_killed": before,
            "wrong_final_files_seen": sorted(set(partial_seen)),
            "resume_seconds": round(seconds, 1),
            "resume_rc": rc,
            "identical_after_resume": contents(killed) == reference,
        }
        print(result["kill_resume"], flush=True)

        # 4. memory and time against take length
        if args.long_minutes <= 0:
            return finish(result, args)
        all_motion = np.concatenate(motion)
        memory = {}
        for label, minutes_long in (("60 s", 1.0), (f"{args.long_minutes:g} min", args.long_minutes)):
            frames = round(minutes_long * 60 * first.fps)
            take = np.concatenate([all_motion] * int(np.ceil(frames / len(all_motion))))[:frames]
            path = work / f"take_{frames}.npz"
            write_take(path, holed(take, first.fps, 0, holes=max(1, frames // 300)), first)
            mb, seconds = peak_memory(path, work / f"out_{frames}.npz")
            memory[label] = {"frames": frames, "peak_mb": round(mb, 1), "seconds": round(seconds, 1)}
            memory[label]["seconds_per_minute"] = round(seconds / minutes_long, 2)
            print(label, memory[label], flush=True)
        long_key = f"{args.long_minutes:g} min"
        memory["peak_ratio"] = round(memory[long_key]["peak_mb"] / memory["60 s"]["peak_mb"], 3)
        memory["time_per_minute_ratio"] = round(
            memory[long_key]["seconds_per_minute"] / memory["60 s"]["seconds_per_minute"], 3
        )
        result["memory"] = memory
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return finish(result, args)


def finish(result: dict, args) -> int:
    path = write_result("fix_archive", result, args.json_out, "bvh_as_recorded" if args.as_is else None)
    print(result)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
