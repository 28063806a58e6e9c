"""A `mocapfix fix` run over many files: the inputs found in files and folders, the run's plan,
the fill policy measured over the run's files together, the --library takes, this shard's
files fixed one after another or in worker processes, and the run's summary."""

from __future__ import annotations

import dataclasses
import os
import pickle
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import torch

from mocapfix.apps.fix_one import FileOutcome, Progress, RunSettings, _one_line, fix_one
from mocapfix.apps.fix_plan import RunPlan, plan_run
from mocapfix.apps.processes import die_with_run, worker_context
from mocapfix.core.clip import Clip, MotionFileError, shown
from mocapfix.fills.errors import measure_take
from mocapfix.fills.motion_matching import LIBRARY_S, MotionLibrary
from mocapfix.fix import measure_recordings, motion_library
from mocapfix.fix.fixer import Fixer
from mocapfix.fix.fixers import load_fixer
from mocapfix.fix.library_file import library_signature, load_library, save_library
from mocapfix.fix.measure import model_fill
from mocapfix.fix.output import FIXED
from mocapfix.fix.positions import take_keys
from mocapfix.fix.threads import on_one_blas_thread, one_blas_thread
from mocapfix.io import list_motion_files, read_motion
from mocapfix.io.joint_map import check_joint_map


def _inputs(
    paths: list[str], source: str, err, out_dir: str | None = None
) -> tuple[list[tuple[Path, Path | None]], bool]:
    """(file, path relative to the folder it was found in, None for files given by name);
    earlier outputs inside folders are skipped: *.fixed.* files, and the --out-dir folder when it
    is inside an input folder (else every rerun would fix the last run's outputs again). A file
    found twice (a folder and a file in it, both given) is one input, the first. A
    folder that cannot be read is an error line; the files around it still run."""
    files, failed = [], False
    skip = Path(out_dir).resolve() if out_dir else None
    seen: set[Path] = set()

    def new(f: Path) -> bool:
        key = f.resolve()
        if key in seen:
            return False
        seen.add(key)
        return True

    def unreadable(e: MotionFileError):
        nonlocal failed
        print(f"error: {' '.join(str(e).split())}", file=err, flush=True)
        failed = True

    for p in paths:
        p = Path(p)
        if p.is_dir():
            try:
                listed = list_motion_files(p, source, on_error=unreadable)
            except MotionFileError as e:
                unreadable(e)
                continue
            found = [
                f for f in listed if not f.stem.endswith(FIXED) and (skip is None or skip not in f.resolve().parents)
            ]
            if not found:
                print(f"error: {shown(p)}: no motion files in this folder", file=err)
                failed = True
            files.extend((f, f.relative_to(p)) for f in found if new(f))
        elif new(p):
            files.append((p, None))  # a missing file fails in read_motion, with the others still run
    return files, failed


@on_one_blas_thread  # the whole run, its reading and library too (fix/threads.py)
def fix_files(
    paths: list[str],
    ckpt: str,
    out: str | None = None,
    out_dir: str | None = None,
    mode: str | None = None,
    device: str = "auto",
    batch_size: int = 64,
    overlap: float = 0.5,
    force: bool = False,
    source: str = "auto",
    progress: str = "auto",
    as_json: bool = False,
    stdout=None,
    stderr=None,
    precision: str = "fp32",
    joint_map: dict[str, str] | None = None,
    render_gif: bool = False,
    joint_map_path: str = "--joint-map",
    jobs: int | None = 1,
    shard: tuple[int, int] = (0, 1),
    resume: bool = False,
    library: list[str] | None = None,
    library_index: str | None = None,
    **read_options,
) -> int:
    """Fix every file; -> exit code (0 all written, 1 some failed). mode: MODES, None: the model's
    own (Fixer.default_mode). read_options go to read_motion; joint_map (input name -> model
    name) names joints rig/mapping.py does not find; render_gif: an animation of the input beside
    the output next to each output (core/render.py). jobs: worker processes fixing files side by
    side (None: default_jobs), each with its share of the cores; shard (i, N): only every N-th
    file from the i-th (shard_of); resume: inputs whose output exists are skipped (outputs appear
    whole under their name, so it is complete). library: files or folders of other takes (the
    same performers, rig and studio) the motion-matching fills search besides the run's own
    (fills/motion_matching.py); library_index: a file the library is kept in between runs
    (fix/library_file.py)."""
    out_stream, err = stdout or sys.stdout, stderr or sys.stderr
    fixer = _load(ckpt, device, precision, joint_map, joint_map_path, err)
    if fixer is None:
        return 1
    mode = mode or fixer.default_mode
    files, failed = _inputs(paths, source, err, out_dir)
    plan, problems = plan_run(files, Path(out) if out else None, Path(out_dir) if out_dir else None, render_gif)
    if problems:  # before any work: nothing of the run is written
        for line in problems:
            print(f"error: {line}", file=err)
        return 1
    reading = {"source": source, "read_options": read_options, "joint_map": joint_map}
    extra = _library(library, library_index, fixer, reading, err) if library else None
    mine = shard_of(files, shard)  # the policy below is the whole run's, whichever shard this is
    jobs = min(jobs, len(mine)) if jobs else default_jobs(device, len(mine))
    pool = None
    if jobs > 1:  # each worker loads the model once and serves both the measuring and the files
        threads = max(1, torch.get_num_threads() // jobs)
        init = (ckpt, device, precision, threads, overlap, batch_size, os.getpid(), plan)
        pool = ProcessPoolExecutor(jobs, worker_context([__name__]), _start_worker, init)
    try:
        with tempfile.TemporaryDirectory(prefix="mocapfix-run-") as shared:
            shelf = _Shelf(Path(shared))
            map_takes = (lambda work: list(pool.map(_measure_take, shelf.jobs(work)))) if pool else None
            measured, library = _run_policy(
                files, fixer, mode, source, overlap, batch_size, joint_map, read_options, map_takes, extra
            )
            measured = _announce(measured, len(files), as_json, out_stream)
            settings = RunSettings(
                out, out_dir, mode, batch_size, overlap, force, resume, source, progress, as_json, joint_map,
                render_gif, read_options, measured, library,
            )  # fmt: skip
            if pool is not None:
                settings = shelf.settings(settings)
            counts, failures = _run(mine, fixer, settings, plan, pool, out_stream, err)
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    if len(mine) > 1:
        summary = f"fix: {counts['fixed']} fixed, {counts['failed']} failed, {counts['skipped']} skipped"
        print(summary + (f" ({jobs} workers)" if jobs > 1 else ""), file=err, flush=True)
        for line in failures[:20]:
            print(f"  {line}", file=err)
    return 1 if failed or counts["failed"] else 0


def _load(ckpt: str, device: str, precision: str, joint_map, joint_map_path: str, err) -> Fixer | None:
    """The run's fixer, its joint map checked against it; None after an error line."""
    try:
        fixer = load_fixer(ckpt, device, precision)
    except Exception as e:
        print(f"error: {_one_line(ckpt, e)}", file=err)
        return None
    try:
        if joint_map:
            check_joint_map(joint_map, fixer.skeleton, joint_map_path)
    except MotionFileError as e:
        print(f"error: {e}", file=err)
        return None
    note = fixer.load_note(ckpt)
    if note:
        print(note, file=err)
    return fixer


def _announce(measured, files: int, as_json: bool, out_stream):
    """The run's measured policy line: printed once for the run (each file's line refers to it),
    or, with --json, in every file's notes."""
    if measured is None or not measured[1]:
        return measured
    whole = measured[1].replace("this recording", f"the {files} files of this run", 1)
    if as_json:
        return measured[0], whole
    print(whole, file=out_stream, flush=True)
    return measured[0], "fill policy measured over this run's files (above)"


def _run(files, fixer: Fixer, settings: RunSettings, plan: RunPlan, pool, out_stream, err):
    """Every file fixed (here, or in the pool's workers), each outcome printed as it comes ->
    (counts by status, the failure lines)."""
    counts = {"fixed": 0, "failed": 0, "skipped": 0}
    failures: list[str] = []
    if pool is None:
        outcomes = (fix_one(path, rel, fixer, settings, err, plan) for path, rel in files)
    else:
        outcomes = run_in_workers(pool, files, settings, err)
    for outcome in outcomes:
        counts[outcome.status] += 1
        if outcome.status == "failed":
            failures.append(outcome.text)
        print(outcome.text, file=err if outcome.status == "failed" else out_stream, flush=True)
    return counts, failures


def shard_of(files: list, shard: tuple[int, int]) -> list:
    """Part i of N of a run's files (every N-th from the i-th, in the run's order: inputs as
    given, folders sorted): N runs of the same command with i = 0..N-1 (a SLURM array, a
    Kubernetes indexed job) fix disjoint parts that together are the whole run."""
    i, n = shard
    return files[i::n]


def parse_shard(text: str) -> tuple[int, int]:
    """ "i/N" -> (i, N), 0 <= i < N; ValueError otherwise."""
    try:
        i, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise ValueError(f"--shard {text!r}: expected i/N, e.g. 0/4") from None
    if not 0 <= i < n:
        raise ValueError(f"--shard {text!r}: i must be in 0..N-1")
    return i, n


FILES_PER_WORKER = 8  # a worker costs a few seconds to start (torch, the model): it needs files to pay


def default_jobs(device: str, files: int) -> int:
    """One worker per core this process may use, as long as each gets FILES_PER_WORKER files; one
    on a GPU, which the workers would share."""
    if device != "cpu":
        return 1
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    return max(1, min(cores, files // FILES_PER_WORKER))


_WORKER: dict = {}


def _start_worker(
    ckpt: str,
    device: str,
    precision: str,
    threads: int,
    overlap: float,
    batch_size: int,
    run: int,
    plan: RunPlan,
) -> None:
    die_with_run(run)  # first: a run killed while this worker starts must not leave it
    # each worker its share of the cores: N workers x all cores each would fight over them
    torch.set_num_threads(threads)
    one_blas_thread()  # for the worker's life, as in the run's own process (fix/threads.py)
    _WORKER["plan"] = plan
    _WORKER["fixer"] = fixer = load_fixer(ckpt, device, precision)
    _WORKER["model_fill"] = model_fill(fixer, overlap, batch_size)


def _work(item: tuple[Path, Path | None, RunSettings]) -> FileOutcome:
    path, rel, settings = item
    measured, library = (_shelved(settings.measured), _shelved(settings.library))
    settings = dataclasses.replace(settings, measured=measured, library=library)
    return fix_one(path, rel, _WORKER["fixer"], settings, sys.stderr, _WORKER["plan"])


def _measure_take(job: tuple):
    job = tuple(_shelved(v) for v in job)
    return measure_take(*job, model_fill=_WORKER["model_fill"])


LIBRARY_IN_JOB = 6  # measure_take's argument that is the run's motion library


@dataclasses.dataclass(frozen=True)
class _Shelved:
    """A run-wide object (the measured policy, the motion library) a worker reads from `path`."""

    path: str


class _Shelf:
    """The run's objects that every file and every measured take is handed, written once into the
    run's private temporary folder, each worker reading each once (_shelved) and keeping it: handed
    in every task, the motion library (12 MB on 16 CMU copies) was pickled for each file and each
    worker built its search's caches again for each (0.5 s a file: 16 copies with 2 workers took
    3 times the CPU of --jobs 1, numpy's BLAS on one thread in both)."""

    def __init__(self, folder: Path):
        self.folder, self.written = folder, {}

    def put(self, value):
        if value is None:
            return None
        if id(value) not in self.written:  # the same object (one library, every take's job): once
            path = self.folder / f"{len(self.written)}.pickle"
            with open(path, "wb") as f:
                pickle.dump(value, f, protocol=pickle.HIGHEST_PROTOCOL)
            self.written[id(value)] = (_Shelved(str(path)), value)  # value kept: its id stays its own
        return self.written[id(value)][0]

    def jobs(self, work: list[tuple]) -> list[tuple]:
        return [(*job[:LIBRARY_IN_JOB], self.put(job[LIBRARY_IN_JOB]), *job[LIBRARY_IN_JOB + 1 :]) for job in work]

    def settings(self, settings: RunSettings) -> RunSettings:
        return dataclasses.replace(settings, measured=self.put(settings.measured), library=self.put(settings.library))


def _shelved(value):
    """value, or what a _Shelved names (read once by this worker; this run's own file in its own
    temporary folder, written by the process that started the worker: not input from anywhere else)."""
    if not isinstance(value, _Shelved):
        return value
    kept = _WORKER.setdefault("shelf", {})
    if value.path not in kept:
        with open(value.path, "rb") as f:
            kept[value.path] = pickle.load(f)
    return kept[value.path]


def run_in_workers(pool: ProcessPoolExecutor, files, settings: RunSettings, err):
    """Outcomes of fix_one over `files` in the pool's workers (processes.worker_context), in the
    files' order, with one progress line over files."""
    show = settings.progress == "always" or (settings.progress == "auto" and getattr(err, "isatty", lambda: False)())
    bar = Progress("fix", show, err, unit="files")
    settings = dataclasses.replace(settings, progress="never")  # the run's bar, not one per file
    for done, outcome in enumerate(pool.map(_work, [(p, r, settings) for p, r in files]), 1):
        bar(done, len(files))
        yield outcome


POOLED_FILES = 32  # files of a run its fill policy is measured over (evenly spread)


def _library(paths: list[str], index: str | None, fixer: Fixer, reading: dict, err) -> MotionLibrary | None:
    """fix --library's takes at the model's joints (None where none maps), from the index file
    when it was made from the same files and reading settings (fix/library_file.py), else read from them
    (and saved into the index when one is named). reading: source, read_options, joint_map."""
    files = _library_files(paths, reading["source"], err)
    signature = library_signature(files, fixer.skeleton, reading) if index else None
    if index:
        try:
            loaded = load_library(Path(index), signature, fixer.skeleton)
        except MotionFileError as e:
            print(f"warning: --library-index: {' '.join(str(e).split())}; read from the takes again", file=err)
            loaded = None
        if loaded is not None:
            library, read, unread = loaded
            minutes = sum(len(x) / fps for x, fps in library.takes) / 60
            more = f"; {unread} more not read: the search keeps {LIBRARY_S / 60:g} minutes" if unread else ""
            print(f"--library: {read} files ({minutes:.0f} min) from the index {shown(index)}{more}", file=err)
            return library
    recordings, unread = _library_takes(files, reading["source"], err, reading["read_options"])
    library = motion_library(recordings, fixer, reading["joint_map"]) if recordings else None
    if index and library is not None:
        try:
            save_library(Path(index), library, signature, len(recordings), unread)
            print(f"--library: index written to {shown(index)} (the next run with these takes reads it)", file=err)
        except OSError as e:
            print(f"warning: --library-index: {shown(index)}: cannot write it ({e.strerror or e}); not kept", file=err)
    return library


def _library_files(paths: list[str], source: str, err) -> list[Path]:
    """The motion files of fix --library's files and folders, in order; a folder that cannot be
    listed (the file system root, too many files: list_motion_files) is a warning line and is left
    out (the library is evidence, not work to do)."""

    def left_out(e: MotionFileError) -> None:
        print(f"warning: --library: {' '.join(str(e).split())} (left out)", file=err)

    files: list[Path] = []
    for given in paths:
        try:
            listed = list_motion_files(given, source, on_error=left_out)
        except MotionFileError as e:
            left_out(e)
            continue
        if Path(given).is_dir():  # as for inputs: earlier outputs in a folder are not takes
            listed = [f for f in listed if not f.stem.endswith(FIXED)]
            if not listed:
                left_out(MotionFileError(given, "no motion files in this folder"))
        files += listed
    return files


def _library_takes(files: list[Path], source: str, err, read_options: dict) -> tuple[list[list[Clip]], int]:
    """The recordings of fix --library's files -> (them, files not read); one that cannot be read
    is a warning line and is left out. Read in order until LIBRARY_S seconds of takes: the search
    keeps no more (an hour-long library costs the reading of its first 10 minutes), and a line
    says how many files were not read."""
    recordings, seconds, unread = [], 0.0, 0
    for path in files:
        if seconds >= LIBRARY_S:  # the search keeps no more (MotionLibrary): reading them is waste
            unread += 1
            continue
        try:
            clips = read_motion(path, source, **read_options)
        except Exception as e:  # noqa: BLE001 -- any unreadable file: said in one line, left out
            print(f"warning: --library: {_one_line(path, e)} (left out)", file=err)
            continue
        recordings.append(clips)
        seconds += sum(c.duration_s for c in clips)
    if unread:
        print(
            f"--library: {len(recordings)} files ({seconds / 60:.0f} min) read; {unread} more not read: "
            f"motion matching searches the first {LIBRARY_S / 60:g} minutes of takes",
            file=err,
        )
    return recordings, unread


def _run_policy(
    files, fixer, mode, source, overlap, batch_size, joint_map, read_options, map_takes=None, extra_library=None
):
    """A run of several files (a folder of one performer or session): the fill policy measured
    over their holes together (fix/measure.py: measure_recordings), as each file
    alone has too few holes to rank the fills by (on 14 CMU takes, fix with each file's own
    policy was up to 2.7 mm above the best classical fill in 3 of 15 cells; pooled, within
    0.5 mm in all 15). None for a single file (it measures its own) or where no policy applies. A file that
    cannot be read is left out here; its own turn reports it. extra_library: the --library takes
    (_library) -> (measured, the motion library of the same files and then the extra ones: what
    every file's motion-matching fills search)."""
    if not fixer.measures_policy or fixer.policy is None or mode == "denoise":
        return None, None
    if len(files) < 2:  # a single file measures its own policy, with the --library takes
        return None, extra_library
    recordings = []
    for i in np.unique(np.linspace(0, len(files) - 1, min(POOLED_FILES, len(files))).round().astype(int)):
        try:
            clips = read_motion(files[i][0], source, **read_options)
        except Exception:
            continue
        if clips:
            recordings.append(clips)
    if not recordings:
        return None, extra_library
    library = motion_library(recordings, fixer, joint_map, extra_library) or extra_library
    # The measurement makes the same library of the same takes for itself; handed this one, which
    # holds them all, it searches it as it is (library_of), and each worker builds the search's
    # frames once, not twice. One that left a take out (over LIBRARY_S) would be made again with
    # that take first: the measurement then makes its own, as it did.
    keys = [key for clips in recordings for key in take_keys(clips)]
    holds_all = library is not None and all(key in library.keys for key in keys)
    searched = library if holds_all else extra_library
    measured = measure_recordings(recordings, fixer, mode, overlap, batch_size, joint_map, map_takes, searched)
    return measured, library
