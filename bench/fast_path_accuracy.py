"""Benchmark (10): does XMAE train to the same accuracy on the fast path as on the plain path?

Issue 6 asks that the speed-ups cost no accuracy. Each (path, seed) is one real run of the
product, `python -m mocapfix fit` then `python -m mocapfix test` on its last checkpoint, in its
own folder; the table compares the two paths' test tables (eval.json) against the spread between
seeds of the same path, which is the noise any comparison has to beat.

Paths:
    plain   fp32, eager, the standard DataLoader
    fast    bf16-mixed, compile_model, batches_on_device (the GPU configs' path; test in bf16 too)

Same config, data, split, steps and schedule for both; only the seed (weights, masks, batch
order) changes within a path.

    # the issue's check, on a GPU: paper sizes, the Bandai config
    python bench/fast_path_accuracy.py --device cuda --steps 15000 --seeds 0,1
    # this CPU (small XMAE, paper corruption, 1 thread per run, two runs at a time; ~30 min)
    python bench/fast_path_accuracy.py --device cpu --steps 2000 --seeds 0,1,2 --jobs 2 --threads 1 --small \
        --batch 32 --data-source archive --data-path .device_data/bandai_pos30.npz \
        --model.init_args.lr 1e-3 --model.init_args.gap_ratio 0 --model.init_args.eval_gaps_s "[0.3,0.7]"
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from common import REPO, describe, pick_device, print_table, write_result

PATHS = {
    "plain": [
        "--trainer.precision",
        "32",
        "--data.batches_on_device",
        "false",
        "--model.init_args.compile_model",
        "false",
    ],
    "fast": [
        "--trainer.precision",
        "bf16-mixed",
        "--data.batches_on_device",
        "true",
        "--model.init_args.compile_model",
        "true",
    ],
}
# A CPU-sized XMAE (2-layer encoder 64 wide, 1-layer decoder): with lr 1e-3 and the paper's
# corruption it leaves the mean-pose plateau (docs/xmae-notes.md) within a few hundred steps of
# batch 32 on Bandai, at ~0.2 s a step on one core. Session 2's wider CPU model (enc 128 x 4)
# was still on the plateau after 1,000 steps of batch 32: comparing two mean poses says nothing.
SMALL = [
    "--model.init_args.enc_dim",
    "64",
    "--model.init_args.enc_depth",
    "2",
    "--model.init_args.enc_mlp_dim",
    "256",
    "--model.init_args.dec_dim",
    "64",
    "--model.init_args.dec_depth",
    "1",
    "--model.init_args.dec_mlp_dim",
    "256",
    "--model.init_args.head_dim",
    "32",
]


def run_one(path: str, seed: int, args, workdir: Path) -> dict:
    """fit + test of one (path, seed) in its own folder; returns its eval.json rows and times."""
    folder = workdir / f"{path}-seed{seed}"
    folder.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    if args.threads:
        env["OMP_NUM_THREADS"] = str(args.threads)
    # The runs work in their own folders: a data path must be absolute there.
    data = [
        "--data.source",
        args.data_source,
        *(["--data.path", str(Path(args.data_path).resolve())] if args.data_path != "none" else []),
        "--data.cache_dir",
        "null",
        "--data.batch_size",
        str(args.batch),
        "--trainer.accelerator",
        args.device.type if args.device.type == "cpu" else "gpu",
    ]
    common = [
        "--config",
        str(Path(args.config).resolve()),
        "--experiment",
        "run",
        *data,
        *PATHS[path],
        *(SMALL if args.small else []),
        *args.extra,
    ]
    fit = [
        "fit",
        *common,
        "--seed_everything",
        str(seed),
        "--trainer.max_steps",
        str(args.steps),
        "--model.init_args.total_steps",
        str(args.steps),
        "--model.init_args.warmup_steps",
        str(min(500, args.steps // 10)),
        "--trainer.val_check_interval",
        str(args.steps),
        "--trainer.enable_progress_bar",
        "false",
    ]
    test = ["test", *common, "--ckpt_path", "checkpoints/run/last.ckpt", "--trainer.enable_progress_bar", "false"]
    times = {}
    for name, cmd in (("fit", fit), ("test", test)):
        t0 = time.perf_counter()
        done = subprocess.run(
            [sys.executable, "-m", "mocapfix", *cmd], cwd=folder, env=env, capture_output=True, text=True
        )
        times[f"{name}_s"] = round(time.perf_counter() - t0, 1)
        (folder / f"{name}.log").write_text(done.stdout + done.stderr)
        if done.returncode != 0:
            raise SystemExit(
                f"{path} seed {seed}: `mocapfix {name}` failed (exit {done.returncode}); see {folder / (name + '.log')}"
            )
    match = re.search(r"^eval\.json: (.+)$", done.stdout, re.M)
    if match is None:
        raise SystemExit(f"{path} seed {seed}: test printed no eval.json path; see {folder / 'test.log'}")
    rows = json.loads((folder / match.group(1)).read_text())
    print(f"  {path} seed {seed}: fit {times['fit_s']} s, test {times['test_s']} s", flush=True)
    return {"path": path, "seed": seed, **times, "rows": rows}


def case_name(row: dict) -> str:
    size = f"{row['gap_s']} s" if "gap_s" in row else f"{row['sigma_m'] * 100:g} cm"
    return f"{row['task']} {row['part']} {size}"


def compare(runs: list[dict], paths: list[str]) -> list[dict]:
    """Per test case: each path's mean and seed range of XMAE's MPJPE, and the difference of the
    means against the larger of the two seed ranges."""
    table = {}
    for run in runs:
        for row in run["rows"]:
            if row["method"] == "xmae":
                table.setdefault(case_name(row), {}).setdefault(run["path"], []).append(row["mpjpe_mm"])
    out = []
    for case, by_path in table.items():
        entry = {"case": case}
        for p in paths:
            values = by_path.get(p, [])
            entry[p] = values
            entry[f"{p}_mean"] = round(sum(values) / len(values), 2)
            entry[f"{p}_range"] = round(max(values) - min(values), 2)
        if len(paths) == 2:
            a, b = paths
            entry["difference"] = round(entry[f"{b}_mean"] - entry[f"{a}_mean"], 2)
            noise = max(entry[f"{a}_range"], entry[f"{b}_range"])
            # one seed per path: no estimate of the noise, no verdict
            few = min(len(by_path.get(a, [])), len(by_path.get(b, []))) < 2
            entry["within_seed_range"] = None if few else abs(entry["difference"]) <= noise
        out.append(entry)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter, allow_abbrev=False
    )  # other options pass through to mocapfix
    ap.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    ap.add_argument("--config", default=str(REPO / "configs" / "xmae_bvh.yaml"))
    ap.add_argument("--data-source", default="bvh")
    ap.add_argument(
        "--data-path",
        default=str(REPO.parent / "shared" / "data" / "bandai-namco"),
        help="'none': the source needs no path (synthetic)",
    )
    ap.add_argument("--paths", default="plain,fast")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--small", action="store_true", help="session 2's CPU-sized XMAE instead of the paper's")
    ap.add_argument("--jobs", type=int, default=1, help="runs at a time")
    ap.add_argument("--threads", type=int, default=0, help="OMP_NUM_THREADS per run (0: leave it)")
    ap.add_argument("--workdir", default="/tmp/mocapfix_fast_path_accuracy")
    ap.add_argument("--json-out")
    # Any other option (--model.init_args.X v, --data.X v, --trainer.X v) goes to both fit and test.
    args, args.extra = ap.parse_known_args()
    args.device = pick_device(args.device)
    paths = args.paths.split(",")
    if unknown := set(paths) - set(PATHS):
        ap.error(f"--paths: unknown {sorted(unknown)} (known: {', '.join(PATHS)})")
    seeds = [int(s) for s in args.seeds.split(",")]
    workdir = Path(args.workdir)

    jobs = [(p, s) for s in seeds for p in paths]
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        runs = list(pool.map(lambda job: run_one(*job, args, workdir), jobs))

    table = compare(runs, paths)
    columns = [("case", "case"), *[(f"{p}_cell", f"{p} mm (mean, seed range)") for p in paths]]
    if len(paths) == 2:
        columns += [("difference_cell", f"{paths[1]} - {paths[0]} mm"), ("verdict", "within seed range")]
    cells = [
        {
            "case": e["case"],
            **{f"{p}_cell": f"{e[p + '_mean']} ({e[p + '_range']})" for p in paths},
            "difference_cell": f"{e.get('difference', 0):+.2f}",
            "verdict": {True: "yes", False: "no"}.get(e.get("within_seed_range"), "-"),
        }
        for e in table
    ]
    print_table(
        f"XMAE test MPJPE, {len(seeds)} seeds per path, {args.steps} steps of batch {args.batch}"
        f"{' (small XMAE)' if args.small else ''}, {describe(args.device)['device']}",
        cells,
        columns,
    )
    result = {
        "env": describe(args.device),
        "threads_per_run": args.threads or None,
        "jobs": args.jobs,
        "steps": args.steps,
        "batch": args.batch,
        "small": args.small,
        "seeds": seeds,
        "paths": {p: PATHS[p] for p in paths},
        "extra": args.extra,
        "data": {"source": args.data_source, "path": args.data_path},
        "config": args.config,
        "table": table,
        "runs": runs,
    }
    print(f"wrote {write_result('fast_path_accuracy', result, args.json_out, 'small' if args.small else None)}")


if __name__ == "__main__":
    main()
