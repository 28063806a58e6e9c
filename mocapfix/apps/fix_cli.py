"""`mocapfix fix INPUT... --ckpt CKPT`: clean motion files with a trained checkpoint.

Per file: read (any format the data module reads), fix (mocapfix.fix), write positions in the
input's layout (a BVH input comes back as a BVH in its own hierarchy: a rotation model's
rotations, or a positions model's positions through inverse kinematics), one report line. A bad
file is one error line and the others still run; the exit code is 1 when any file failed.
Outputs are written to a temporary file and renamed: never half a file, never over the input,
never over an existing file without --force.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import signal
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np
import torch

from mocapfix.apps.processes import die_with_parent
from mocapfix.core.clip import Clip, MotionFileError, shown
from mocapfix.core.ik import ik_error_mm, inverse_kinematics
from mocapfix.core.render import holes_map, render, tracks_for
from mocapfix.fills.motion_matching import MotionLibrary
from mocapfix.fills.recording_policy import measure_take
from mocapfix.fix import MODES, fix_clips, map_joints, measure_recordings, rotation_clips
from mocapfix.fix.clips import model_fill, motion_library
from mocapfix.fix.fixers import PRECISIONS, load_fixer
from mocapfix.io import add_read_arguments, list_motion_files, read_motion
from mocapfix.io.bvh import read_bvh, write_bvh_like
from mocapfix.io.conventions import metres_per_unit, to_z_up
from mocapfix.io.files import atomic_write, check_output, claimed, staged, writing
from mocapfix.io.joint_map import check_joint_map, read_joint_map
from mocapfix.io.npz import load_npz, npz_array
from mocapfix.io.positions import write_clips, write_positions
from mocapfix.pretrained import pretrained_path

FIXED = ".fixed"  # default output: <stem>.fixed<ext> beside the input
LONG_INPUT_S = 600.0  # progress is shown for inputs this long even when stderr is not a terminal


def output_suffix(clips: list[Clip], path: Path, rotations: bool = False) -> str:
    """Positions files keep their extension; BVH stays BVH (a rotation model's rotations, or a
    positions model's positions put back on the input's hierarchy by inverse kinematics);
    AMASS (rotations in, positions out) and Human3.6M become .npz. rotations: the output has
    rotations to write (a rotation model, or a reference pose for inverse kinematics)."""
    fmt = clips[0].meta.get("format", "")
    if fmt == "bvh" and (rotations or clips[0].has_rotations):
        return ".bvh"
    return path.suffix.lower() if fmt in ("positions-npz", "positions-csv") else ".npz"


def output_path(
    path: Path, clips: list[Clip], out: Path | None, out_dir: Path | None, rel: Path | None, rotations: bool = False
) -> Path:
    suffix = output_suffix(clips, path, rotations)
    if out is not None:
        target = out
    elif out_dir is not None:
        target = out_dir / (rel if rel is not None else Path(path.name)).with_suffix(suffix)
    else:
        target = path.with_name(path.stem + FIXED + suffix)
    fmt = clips[0].meta.get("format", "")
    ext = target.suffix.lower()
    if ext == ".bvh" and fmt == "bvh" and (rotations or clips[0].has_rotations):
        return target
    if ext == ".bvh":
        why = "a BVH output needs a BVH input" if fmt != "bvh" else "the input has no joint rotations"
        raise MotionFileError(path, f"cannot write {target.name}: {why}; write .npz or .csv")
    if ext not in (".npz", ".csv") or (fmt == "h36m" and ext != ".npz"):
        raise MotionFileError(
            path, f"cannot write {target.name}: outputs are {'.npz' if fmt == 'h36m' else '.npz or .csv'}"
        )
    return target


def write_output(target: Path, clips: list[Clip], inputs: list[Clip], path: Path | None = None) -> None:
    """Positions in the input's layout (people, unit, up axis, csv columns); Human3.6M as its
    own {subject: {action: (T, 17, 3)}} npz; a .bvh target: the input BVH file `path` with the
    clip's motion (write_bvh_like). inputs: the clips as read, for exact copies."""
    if target.suffix.lower() == ".bvh":
        write_bvh_like(target, clips[0], path)
        return
    clips = _onto(clips, inputs)
    fmt = clips[0].meta.get("format")
    if fmt == "h36m":
        tree: dict = {}
        for c in clips:
            scale = metres_per_unit(c.meta)  # back to the file's unit
            tree.setdefault(c.meta["subject"], {})[c.meta["action"]] = (c.positions / scale).astype(np.float32)
        atomic_write(target, lambda f: np.savez_compressed(f, positions_3d=np.array(tree, dtype=object)))
        return
    m = clips[0].meta
    if fmt == "positions-npz" and metres_per_unit(m) != 1.0:
        # Metres -> cm/mm -> metres is not exact in float32 (1 value in 8 is off by an ulp): tokens
        # fix left alone are written from the file's own numbers, so they come back bit-identical.
        with load_npz(Path(inputs[0].source)) as data:
            raw = npz_array(Path(inputs[0].source), data, "positions").astype(np.float64)
        raw = to_z_up(raw.reshape((-1,) + raw.shape[-3:]) * metres_per_unit(m), m.get("up_axis", "z"))
        origin = inputs[0].origin  # the positions below are relative to it (a take far from the origin)
        new = np.stack([c.positions for c in clips]).astype(np.float64)  # (P, T, J, 3)
        old = np.stack([c.positions for c in inputs])
        same = ((new == old) & np.isfinite(old)).all(-1, keepdims=True)
        write_positions(
            target,
            np.where(same, raw - origin, new),
            clips[0].fps,
            clips[0].skeleton,
            m["unit"],
            m.get("up_axis", "z"),
            squeeze=m.get("squeeze"),
            origin=origin,
        )
        return
    write_clips(target, clips)


def _bvh_reference(path: Path, clips: list[Clip]) -> list[Clip] | None:
    """For a BVH read without usable rotations (missing channels, or a jump that made positions
    missing): the file again, its missing channel values interpolated per channel (Euler angles:
    a pose to start from, not data), with the unit and axes it was read with; None where that
    does not give the same joints with rotations."""
    c = clips[0]
    if c.meta.get("format") != "bvh" or len(clips) != 1:
        return None
    try:
        [ref] = read_bvh(path, unit=c.meta["unit"], up_axis=c.meta["up_axis"], fill_missing_channels=True)
    except (MotionFileError, KeyError):
        return None
    return [ref] if ref.has_rotations and ref.skeleton.joint_names == c.skeleton.joint_names else None


FILLED_WEIGHT = 1e-3  # a filled joint's pull in the IK against an observed one's (core/ik.py)


def onto_hierarchy(
    fixed: list[Clip], inputs: list[Clip], observed: list[np.ndarray] | None = None
) -> tuple[list[Clip], float, float]:
    """A positions model's fixed clips back on the input BVH's own skeleton (core/ik.py): each
    clip gets rotations and root translation, and the positions their FK gives. inputs: the
    input's clips with rotations (the pose IK starts from); observed: (T, J) per clip, the
    tokens kept as recorded, which filled or replaced ones never pull. -> the clips and the mean and max
    distance (mm) the IK left between those positions and the model's."""
    out, means, worst = [], [], 0.0
    for k, (f, c) in enumerate(zip(fixed, inputs)):
        offsets, parents = torch.from_numpy(c.offsets), c.skeleton.parents
        # the reference may be a second read of the file (_bvh_reference) about another origin
        target = torch.from_numpy(_about(f, c.origin))
        weights = None if observed is None else torch.from_numpy(np.where(observed[k], 1.0, FILLED_WEIGHT))
        rot, root = inverse_kinematics(
            target, parents, offsets, torch.from_numpy(c.rotations), torch.from_numpy(c.root_translation), weights
        )
        posed, mean, top = ik_error_mm(target, parents, offsets, rot, root)
        means.append(mean)
        worst = max(worst, top)
        out.append(
            c.replace(
                positions=posed.float().numpy(), rotations=rot.float().numpy(), root_translation=root.float().numpy()
            )
        )
    return out, float(np.mean(means)), worst


def _onto(fixed: list[Clip], inputs: list[Clip]) -> list[Clip]:
    """Fixed clips on the input's joints: a rotation model fixes a BVH read with its joints only;
    the file's other joints pass through, as with any model."""
    out = []
    for f, c in zip(fixed, inputs):
        if f.skeleton.joint_names == c.skeleton.joint_names:
            out.append(f)
            continue
        positions = c.positions.copy()
        positions[:, map_joints(c.skeleton, f.skeleton, c.source)] = _about(f, c.origin)  # a second read's origin
        out.append(c.replace(positions=positions, rotations=None, root_translation=None, offsets=None))
    return out


def _about(clip: Clip, origin: np.ndarray) -> np.ndarray:
    """clip's positions (T, J, 3) relative to `origin` (Clip.origin) instead of its own: the same
    float32 array when the two agree, as they do for every take near the file's origin."""
    if (clip.origin == origin).all():
        return clip.positions
    return (clip.positions.astype(np.float64) + (clip.origin - origin)).astype(np.float32)


class Progress:
    """A bar on a terminal, a line every 10% otherwise; silent when disabled."""

    def __init__(self, label: str, enabled: bool, stream=None, unit: str = "windows"):
        self.label, self.enabled, self.unit = label, enabled, unit
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.last = -1

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled or total <= 0:
            return
        pct = int(100 * done / total)
        if self.tty:
            bar = "#" * (pct // 4)
            print(
                f"\r{self.label} [{bar:<25}] {pct:3d}% ({done}/{total} {self.unit})",
                end="",
                file=self.stream,
                flush=True,
            )
            if done >= total:
                print(file=self.stream, flush=True)
        elif pct // 10 > self.last // 10 or done >= total:
            print(f"{self.label}: {done}/{total} {self.unit} ({pct}%)", file=self.stream, flush=True)
        self.last = pct


def _one_line(path, e: BaseException) -> str:
    """MotionFileError reads "path: problem"; anything else gets the path and its type. A
    MotionFileError about another file (the body model) gets the input's path in front."""
    text = " ".join(str(e).split())
    if text.startswith(shown(path)):
        return text
    if isinstance(e, MotionFileError):
        return text if Path(e.path).resolve() == Path(path).resolve() else f"{shown(path)}: {text}"
    return f"{shown(path)}: {type(e).__name__}: {text}" if text else f"{shown(path)}: {type(e).__name__}"


def _num(v: float) -> str:
    return f"{v:.2f}" if math.isfinite(v) else "-"


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


def renders_of(target: Path) -> list[Path]:
    """What fix --render writes beside an output: the animation and the joints x time map."""
    return [target.with_suffix(".gif"), target.with_suffix(".holes.png")]


def planned_output(path: Path, rel: Path | None, out: Path | None, out_dir: Path | None) -> Path:
    """Where an input's output will go, from its name alone (output_path knows for sure only once
    the file is read): BVH stays .bvh, .csv stays .csv, everything else becomes .npz. The one
    guess that can miss, a BVH without usable rotations written as .npz, is checked again when
    it is known (RunPlan.problem)."""
    suffix = {".bvh": ".bvh", ".csv": ".csv"}.get(path.suffix.lower(), ".npz")
    if out is not None:
        return out
    if out_dir is not None:
        return out_dir / (rel if rel is not None else Path(path.name)).with_suffix(suffix)
    return path.with_name(path.stem + FIXED + suffix)


def _file_id(path: Path) -> tuple[int, int] | None:
    """(device, inode) of the file at path (through links), None where there is none."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


@dataclasses.dataclass(frozen=True)
class RunPlan:
    """A run's inputs and the outputs they are to get, known before any work (plan_run), so that
    no output of the run is another input of it, or the output of two inputs; checked again per
    file with the output it really gets (problem). Plain values: it travels to worker processes."""

    outputs: dict[str, str]  # resolved output path -> the input it is for, as listed
    inputs: dict[str, str]  # resolved input path -> the input as listed
    input_files: dict[tuple[int, int], str]  # (device, inode) of each input -> the input as listed

    def problem(self, path: Path, output: Path) -> str | None:
        """Why input `path` must not write `output` (one line, naming both), or None."""
        which = self.inputs.get(str(output.resolve()))
        if which is None:
            known = _file_id(output)
            which = self.input_files.get(known) if known is not None else None
        if which is not None:
            if which == str(path):
                return f"{shown(path)}: output {shown(output)} is the input; fix never overwrites its input"
            return (
                f"{shown(path)}: output {shown(output)} is the input {shown(which)} of this run; "
                "fix never overwrites an input, not even with --force"
            )
        owner = self.outputs.get(str(output.resolve()))
        if owner is not None and owner != str(path):
            return (
                f"{shown(output)}: the output of both {shown(owner)} and {shown(path)}; one output per input "
                "(fix them into separate --out-dir folders)"
            )
        return None


def plan_run(
    files: list[tuple[Path, Path | None]], out: Path | None, out_dir: Path | None, render_gif: bool
) -> tuple[RunPlan, list[str]]:
    """The run's plan, and a line per problem with it: an output that is an input of the run
    (by path, through links, or the same file under another name), or the output of two inputs
    (same-named takes of two folders into one --out-dir). Any problem stops the run before any
    file is fixed: with --force an input would be lost, without it one of two results."""
    inputs = {str(p.resolve()): str(p) for p, _ in files}
    input_files = {}
    for p, _ in files:
        known = _file_id(p)
        if known is not None:
            input_files.setdefault(known, str(p))
    plan, problems = RunPlan({}, inputs, input_files), []
    for path, rel in files:
        target = planned_output(path, rel, out, out_dir)
        for output in [target, *(renders_of(target) if render_gif else [])]:
            problem = plan.problem(path, output)
            if problem is not None:
                problems.append(problem)
            else:
                plan.outputs[str(output.resolve())] = str(path)
    return plan, problems


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
    **read_options,
) -> int:
    """Fix every file; -> exit code (0 all written, 1 some failed). mode: MODES, None: the model's
    own (denoise for a jitter remover, else infill). read_options go to read_motion;
    joint_map (input name -> model name) names joints rig/mapping.py does not find;
    render_gif: an animation of the input beside the output next to each output (core/render.py).
    jobs: worker processes fixing files side by side (None: default_jobs), each with its share
    of the cores; shard (i, N): only every N-th file from the i-th (shard_of); resume: inputs
    whose output exists are skipped (outputs appear whole under their name, so it is complete).
    library: files or folders of other takes (the same performers, rig and studio) the
    motion-matching fills search besides the run's own (fills/motion_matching.py)."""
    out_stream, err = stdout or sys.stdout, stderr or sys.stderr
    try:
        fixer = load_fixer(ckpt, device, precision)
    except Exception as e:
        print(f"error: {_one_line(ckpt, e)}", file=err)
        return 1
    mode = mode or ("denoise" if fixer.kind == "jitter" else "infill")
    try:
        if joint_map:
            check_joint_map(joint_map, fixer.skeleton, joint_map_path)
    except MotionFileError as e:
        print(f"error: {e}", file=err)
        return 1
    if fixer.kind == "xmae" and fixer.policy is None:
        print(
            f"note: {ckpt} has no fill policy: the model fills every hole and replaces every token it is "
            "asked to (`mocapfix validate --config CFG --ckpt_path CKPT` calibrates one on the val split)",
            file=err,
        )
    files, failed = _inputs(paths, source, err, out_dir)
    plan, problems = plan_run(files, Path(out) if out else None, Path(out_dir) if out_dir else None, render_gif)
    if problems:  # before any work: nothing of the run is written
        for line in problems:
            print(f"error: {line}", file=err)
        return 1
    extra = _library_takes(library or [], source, err, read_options)
    mine = shard_of(files, shard)  # the policy below is the whole run's, whichever shard this is
    jobs = min(jobs, len(mine)) if jobs else default_jobs(device, len(mine))
    pool = None
    if jobs > 1:  # each worker loads the model once and serves both the measuring and the files
        threads = max(1, torch.get_num_threads() // jobs)
        init = (ckpt, device, precision, threads, overlap, batch_size, os.getpid(), plan)
        pool = ProcessPoolExecutor(jobs, get_context("spawn"), _start_worker, init)
    try:
        map_takes = (lambda work: list(pool.map(_measure_take, work))) if pool else None
        measured, library = _run_policy(
            files, fixer, mode, source, overlap, batch_size, joint_map, read_options, map_takes, extra
        )
        if measured is not None and measured[1]:
            whole = measured[1].replace("this recording", f"the {len(files)} files of this run", 1)
            if as_json:
                measured = (measured[0], whole)
            else:  # once for the run; each file's line refers to it
                print(whole, file=out_stream, flush=True)
                measured = (measured[0], "fill policy measured over this run's files (above)")
        files = mine
        settings = RunSettings(
            out,
            out_dir,
            mode,
            batch_size,
            overlap,
            force,
            resume,
            source,
            progress,
            as_json,
            joint_map,
            render_gif,
            read_options,
            measured,
            library,
        )
        counts = {"fixed": 0, "failed": 0, "skipped": 0}
        failures: list[str] = []

        def report(outcome: FileOutcome) -> None:
            counts[outcome.status] += 1
            if outcome.status == "failed":
                failures.append(outcome.text)
            print(outcome.text, file=err if outcome.status == "failed" else out_stream, flush=True)

        if pool is None:
            for path, rel in files:
                report(fix_one(path, rel, fixer, settings, err, plan))
        else:
            for outcome in run_in_workers(pool, files, settings, err):
                report(outcome)
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    if len(files) > 1:
        summary = f"fix: {counts['fixed']} fixed, {counts['failed']} failed, {counts['skipped']} skipped"
        print(summary + (f" ({jobs} workers)" if jobs > 1 else ""), file=err, flush=True)
        for line in failures[:20]:
            print(f"  {line}", file=err)
    return 1 if failed or counts["failed"] else 0


@dataclasses.dataclass(frozen=True)
class RunSettings:
    """What every file of a run is fixed with (plain values: it travels to worker processes)."""

    out: str | None
    out_dir: str | None
    mode: str
    batch_size: int
    overlap: float
    force: bool
    resume: bool
    source: str
    progress: str
    as_json: bool
    joint_map: dict[str, str] | None
    render_gif: bool
    read_options: dict
    measured: tuple | None
    library: MotionLibrary | None  # the run's takes, for the motion-matching fills


@dataclasses.dataclass(frozen=True)
class FileOutcome:
    status: str  # "fixed", "failed" or "skipped"
    text: str  # the report line (or JSON object), the error line, or why it was skipped


class _Skipped(Exception):
    pass


def fix_one(path: Path, rel: Path | None, fixer, s: RunSettings, err, plan: RunPlan | None = None) -> FileOutcome:
    """One input file read, fixed and written: its output (and with --render its pictures) whole
    under its final name, or none of them. plan: the run's (plan_run), which the output this
    file really gets is checked against again (never an input, never another input's output)."""
    mode, source, joint_map, read_options, measured = s.mode, s.source, s.joint_map, s.read_options, s.measured
    out, out_dir, force, overlap, batch_size, progress = s.out, s.out_dir, s.force, s.overlap, s.batch_size, s.progress
    t0 = time.perf_counter()
    t0 = time.perf_counter()
    try:
        clips = read_motion(path, source, **read_options)
        if not clips:
            raise MotionFileError(path, "no motion in the file")
        rotations = getattr(fixer, "state", "positions") == "rotations"
        # A BVH whose rotations were set aside (missing channels, a jump) still goes back as a
        # BVH: the file re-read with its channels interpolated is the pose IK starts from.
        reference = None if rotations or clips[0].has_rotations else _bvh_reference(path, clips)
        target = output_path(
            path,
            clips,
            Path(out) if out else None,
            Path(out_dir) if out_dir else None,
            rel,
            rotations or reference is not None,
        )
        outputs = [target, *(renders_of(target) if s.render_gif else [])]
        plan = plan or plan_run([(path, rel)], None, None, False)[0]  # a file fixed alone: its own
        for output in outputs:
            problem = plan.problem(path, output)
            if problem is not None:
                raise MotionFileError(path, problem.removeprefix(f"{shown(path)}: "))
        if s.resume and os.path.lexists(target) and not force:  # written whole under its name: complete
            _clear_stale(outputs)
            raise _Skipped(f"{shown(target)} exists (--resume)")
        with contextlib.ExitStack() as claims:
            for output in outputs:  # one run per output: a second one to the same -o fails here
                claims.enter_context(claimed(output, path))  # and a killed run's temporary files go
            for output in outputs:  # an existing file (without --force), a folder, a link: before the work
                check_output(output, force, path)
            seconds = sum(c.duration_s for c in clips)
            show = progress == "always" or (
                progress == "auto" and (getattr(err, "isatty", lambda: False)() or seconds >= LONG_INPUT_S)
            )
            work = (
                rotation_clips(path, clips, fixer.skeleton, source, joint_map, **read_options) if rotations else clips
            )
            progress_bar = Progress(shown(path), show, err)
            fixed, report = fix_clips(
                work,
                fixer,
                mode,
                overlap,
                batch_size,
                progress_bar,
                joint_map,
                None if rotations else measured,
                None if rotations else s.library,
            )
            if target.suffix.lower() == ".bvh" and not rotations:
                # the tokens fix kept as recorded (T, J): only they pull the IK; a filled or
                # replaced one is where the model put it, and must not bend the observed limbs
                seen = [
                    np.isfinite(c.positions).all(-1) & (f.positions == c.positions).all(-1)
                    for c, f in zip(clips, fixed)
                ]
                fixed, ik_mean, ik_max = onto_hierarchy(fixed, reference or clips, seen)
                report.notes.append(
                    f"BVH by inverse kinematics onto the input's skeleton: its bone lengths moved joints "
                    f"{ik_mean:.1f} mm on average from the model's positions (max {ik_max:.1f} mm)"
                )
            # Written beside the outputs under hidden names, then moved into place together without
            # overwriting (unless --force): a file that appeared meanwhile is never lost, and a
            # failure (a full disk) leaves none of them, so a rerun starts clean.
            with staged(outputs, force, path) as temps:
                with writing(target, path):
                    try:
                        write_output(temps[0], fixed, clips, path)
                    except MotionFileError as e:  # name the output, not its temporary file
                        if Path(e.path) != temps[0]:
                            raise
                        raise MotionFileError(path, f"cannot write output {shown(target)}: {e.problem}") from None
                if s.render_gif:  # the first person: a preview, not a report of every clip
                    gif, holes = outputs[1:]
                    tracks = tracks_for(clips[0], [(target.name, fixed[0])])
                    with writing(gif, path):
                        render(tracks, clips[0].skeleton.limbs, clips[0].fps, gif, write_to=temps[1])
                    with writing(holes, path):
                        holes_map(tracks, clips[0].skeleton.joint_names, clips[0].fps, holes, write_to=temps[2])
    except _Skipped as e:
        return FileOutcome("skipped", f"{shown(path)}: skipped, {e}")
    except Exception as e:  # one bad file must not stop the others
        return FileOutcome("failed", f"error: {_one_line(path, e)}")
    elapsed = time.perf_counter() - t0
    notes = list(report.notes)
    fmt = clips[0].meta.get("format")
    if fmt in ("bvh", "amass") and target.suffix.lower() != ".bvh":
        if fmt == "amass":
            note = f"positions .npz/.csv: {fixer.kind.upper()} gives positions, not rotations"
        elif rotations or clips[0].has_rotations:
            note = "positions .npz/.csv: a .bvh output (the default for a BVH input) keeps rotations"
        else:
            why = clips[0].meta.get("no_rotations")
            note = f"positions .npz/.csv: this BVH has no usable joint rotations{f' ({why})' if why else ''}"
        notes.insert(0, note)
    if report.filled_by:
        notes.insert(0, "filled by " + ", ".join(f"{m} {n}" for m, n in sorted(report.filled_by.items())))
    absurd = sum(int(c.meta.get("out_of_reach_tokens", 0)) for c in clips)
    if absurd:
        joints = sorted({j for c in clips for j in c.meta.get("absurd_joints", [])})
        notes.insert(
            0,
            f"{absurd} tokens no body could take (a jump faster than any body part, or out of reach) were "
            f"treated as missing{': ' + ', '.join(joints) if joints else ''}",
        )
    kind = "sequences" if clips[0].meta.get("format") == "h36m" else "person" if report.people == 1 else "people"
    if s.as_json:
        return FileOutcome(
            "fixed",
            json.dumps(
                {
                    "input": str(path),
                    "output": str(target),
                    "mode": mode,
                    "model": fixer.kind,
                    "frames": report.frames,
                    "people": report.people,
                    "filled": report.filled,
                    "replaced": report.replaced,
                    "filled_by": report.filled_by,
                    "windows": report.windows,
                    "limb_sigma_before_mm": _finite_or_none(report.limb_sigma_before_mm),
                    "limb_sigma_after_mm": _finite_or_none(report.limb_sigma_after_mm),
                    "seconds": round(elapsed, 3),
                    "notes": notes,
                }
            ),
        )
    else:
        line = (
            f"{shown(path)} -> {shown(target)}: {report.frames} frames, {report.people} {kind}, "
            f"{report.filled} tokens filled, {report.replaced} replaced ({mode}, {fixer.kind}), "
            f"limb sigma {_num(report.limb_sigma_before_mm)} -> {_num(report.limb_sigma_after_mm)} mm, "
            f"{elapsed:.2f} s"
        )
        return FileOutcome("fixed", line + "".join(f"; {n}" for n in notes))


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


def _clear_stale(outputs: list[Path]) -> None:
    """A killed run's temporary files beside outputs that are complete (--resume skips them):
    claiming an output removes them; one another run holds is left to that run."""
    for output in outputs:
        with contextlib.suppress(MotionFileError, OSError), claimed(output):
            pass


def _start_worker(
    ckpt: str,
    device: str,
    precision: str,
    threads: int,
    overlap: float,
    batch_size: int,
    parent: int,
    plan: RunPlan,
) -> None:
    die_with_parent(parent)  # first: a run killed while this worker starts must not leave it
    # each worker its share of the cores: N workers x all cores each would fight over them
    torch.set_num_threads(threads)
    _WORKER["plan"] = plan
    _WORKER["fixer"] = fixer = load_fixer(ckpt, device, precision)
    _WORKER["model_fill"] = model_fill(fixer, overlap, batch_size)


def _work(item: tuple[Path, Path | None, RunSettings]) -> FileOutcome:
    path, rel, settings = item
    return fix_one(path, rel, _WORKER["fixer"], settings, sys.stderr, _WORKER["plan"])


def _measure_take(job: tuple):
    return measure_take(*job, model_fill=_WORKER["model_fill"])


def run_in_workers(pool: ProcessPoolExecutor, files, settings: RunSettings, err):
    """Outcomes of fix_one over `files` in the pool's workers (started fresh, spawn, as torch
    wants), in the files' order, with one progress line over files."""
    show = settings.progress == "always" or (settings.progress == "auto" and getattr(err, "isatty", lambda: False)())
    bar = Progress("fix", show, err, unit="files")
    settings = dataclasses.replace(settings, progress="never")  # the run's bar, not one per file
    for done, outcome in enumerate(pool.map(_work, [(p, r, settings) for p, r in files]), 1):
        bar(done, len(files))
        yield outcome


POOLED_FILES = 32  # files of a run its fill policy is measured over (evenly spread)


def _library_takes(paths: list[str], source: str, err, read_options: dict) -> list[list[Clip]]:
    """The recordings of fix --library (files or folders); one that cannot be read is a warning
    line and is left out (the library is evidence, not work to do), and so is a folder that cannot
    be listed (the file system root, too many files: list_motion_files)."""

    def left_out(e: MotionFileError) -> None:
        print(f"warning: --library: {' '.join(str(e).split())} (left out)", file=err)

    recordings = []
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
        for path in listed:
            try:
                recordings.append(read_motion(path, source, **read_options))
            except Exception as e:  # noqa: BLE001 -- any unreadable file: said in one line, left out
                print(f"warning: --library: {_one_line(path, e)} (left out)", file=err)
    return recordings


def _run_policy(files, fixer, mode, source, overlap, batch_size, joint_map, read_options, map_takes=None, extra=()):
    """A run of several files (a folder of one performer or session): the fill policy measured
    over their holes together (fix/clips.py: measure_recordings), as each file
    alone has too few holes to rank the fills by (on 14 CMU takes, fix with each file's own
    policy was up to 2.7 mm above the best classical fill in 3 of 15 cells; pooled, within
    0.5 mm in all 15). None for a single file (it measures its own) or where no policy applies. A file that
    cannot be read is left out here; its own turn reports it. extra: the --library recordings
    -> (measured, the motion library of the same files and the extra ones: what every file's
    motion-matching fills search)."""
    if fixer.kind != "xmae" or getattr(fixer, "policy", None) is None or mode == "denoise":
        return None, None
    extra_library = motion_library(list(extra), fixer, joint_map) if extra else None
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
    measured = measure_recordings(recordings, fixer, mode, overlap, batch_size, joint_map, map_takes, extra_library)
    return measured, motion_library(recordings + list(extra), fixer, joint_map)


def _finite_or_none(v: float):
    return v if math.isfinite(v) else None


def _device(name: str) -> str:
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    return name


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="mocapfix fix",
        description=__doc__.split("\n")[0],
        epilog="example: mocapfix fix take.bvh --model xmae-cpu-bandai -o take.fixed.bvh   "
        "(a folder: mocapfix fix takes/ --model xmae-cpu-bandai --out-dir fixed/)",
    )
    ap.add_argument("paths", nargs="+", metavar="INPUT", help="motion files or folders")
    which = ap.add_mutually_exclusive_group(required=True)
    which.add_argument("--ckpt", help="a mocapfix checkpoint (XMAE, Motion-DVAE's denoising stage, a jitter remover)")
    which.add_argument("--model", help="a model shipped with mocapfix (`mocapfix models` lists them)")
    where = ap.add_mutually_exclusive_group()
    where.add_argument("-o", "--out", default=None, help="output file (one input file only)")
    where.add_argument("--out-dir", default=None, help="folder for the outputs (default: <input>.fixed.<ext>)")
    ap.add_argument(
        "--mode",
        default=None,
        choices=MODES,
        help="infill: fill missing tokens only; denoise: replace observed tokens; both: both "
        "(default: denoise for a jitter remover, else infill)",
    )
    ap.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    ap.add_argument("--batch-size", type=int, default=64, help="windows per model call")
    ap.add_argument(
        "--precision",
        default="auto",
        choices=PRECISIONS,
        help="XMAE's matmuls: auto = bf16 on GPUs and CPUs with native bf16, else fp32",
    )
    ap.add_argument("--overlap", type=float, default=0.5, help="fraction of a window shared by neighbours, [0, 1)")
    ap.add_argument("--force", action="store_true", help="overwrite existing outputs")
    ap.add_argument(
        "--resume",
        action="store_true",
        help="skip inputs whose output exists (outputs appear whole under their name): rerun a killed run",
    )
    ap.add_argument(
        "--jobs",
        type=int,
        default=None,
        help="files fixed side by side, each worker with its share of the cores (default: the cores, "
        "if each gets 8 files; 1 on a GPU)",
    )
    ap.add_argument(
        "--shard",
        default="0/1",
        metavar="i/N",
        help="fix only part i of N of the files (e.g. a SLURM array: --shard $SLURM_ARRAY_TASK_ID/N); docs/scaling.md",
    )
    ap.add_argument(
        "--render",
        action="store_true",
        help="also write OUTPUT.gif (the input beside the output) and OUTPUT.holes.png (joints x time)",
    )
    ap.add_argument(
        "--library",
        nargs="+",
        default=None,
        metavar="TAKES",
        help="files or folders of other takes of the same performers and rig: holes are also filled "
        "from the moments of them that match (motion matching), where the recording says it is better",
    )
    ap.add_argument("--json", action="store_true", help="one JSON object per file instead of the report line")
    ap.add_argument(
        "--progress",
        default="auto",
        choices=("auto", "always", "never"),
        help="auto: on a terminal, or for inputs over 10 minutes",
    )
    ap.add_argument(
        "--joint-map",
        default=None,
        help="YAML, `input name: model name` per line, for joints the automatic matching misses",
    )
    add_read_arguments(ap)
    args = ap.parse_args(argv)
    if args.out and (len(args.paths) > 1 or Path(args.paths[0]).is_dir()):
        ap.error("-o/--out takes one input file; use --out-dir for several")
    if args.out_dir and Path(args.out_dir).exists() and not Path(args.out_dir).is_dir():
        ap.error(f"--out-dir {args.out_dir} is a file, not a folder")
    if args.batch_size < 1:
        ap.error("--batch-size must be at least 1")
    if args.jobs is not None and args.jobs < 1:
        ap.error("--jobs must be at least 1")
    try:
        shard = parse_shard(args.shard)
    except ValueError as e:
        ap.error(str(e))
    if not 0.0 <= args.overlap < 1.0:
        ap.error("--overlap must be in [0, 1)")
    if args.device == "cuda" and not torch.cuda.is_available():
        ap.error("--device cuda, but no CUDA device is available")
    try:
        joint_map = read_joint_map(args.joint_map) if args.joint_map else None
        ckpt = str(pretrained_path(args.model)) if args.model else args.ckpt
    except ValueError as e:  # MotionFileError is one
        print(f"error: {e}", file=sys.stderr)
        return 1
    # SIGTERM (a scheduler's time limit, `kill`) ends the run the way Ctrl-C does: as an exception,
    # so the output being written loses its temporary file (atomic_write) instead of the process
    # dying with it on disk.
    previous = (
        signal.signal(signal.SIGTERM, _terminated) if threading.current_thread() is threading.main_thread() else None
    )
    try:
        return fix_files(
            args.paths,
            ckpt,
            args.out,
            args.out_dir,
            args.mode,
            _device(args.device),
            args.batch_size,
            args.overlap,
            args.force,
            args.source,
            args.progress,
            args.json,
            precision=args.precision,
            joint_map=joint_map,
            render_gif=args.render,
            joint_map_path=args.joint_map,
            unit=args.unit,
            up_axis=args.up_axis,
            fps=args.fps,
            body_model_path=args.body_model,
            jobs=args.jobs,
            shard=shard,
            resume=args.resume,
            library=args.library,
        )
    except KeyboardInterrupt:  # outputs are renamed into place whole: nothing half-written is left
        print(
            "mocapfix fix: interrupted (outputs written so far are whole; the one in progress was not written)",
            file=sys.stderr,
        )
        return 130
    except _Terminated:
        print(
            "mocapfix fix: stopped by SIGTERM (outputs written so far are whole; the one in progress was not written)",
            file=sys.stderr,
        )
        return 128 + signal.SIGTERM
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


class _Terminated(BaseException):
    """SIGTERM, raised where the program is: not an Exception, so no per-file handler swallows it."""


def _terminated(signum, frame):
    raise _Terminated()


if __name__ == "__main__":
    sys.exit(main())
