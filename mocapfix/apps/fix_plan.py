"""A run's plan, known before any work: the output each input is to get, checked so that no output
of the run is another input of it (by path, through links, or the same file under another name)
or the output of two inputs; checked again per file with the output it really gets."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

from mocapfix.core.clip import shown
from mocapfix.fix.output import FIXED


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
