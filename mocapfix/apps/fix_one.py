"""One input file of a `mocapfix fix` run: read, fixed (mocapfix.fix: fix_recording), written
whole under its final name with its pictures (--render), or none of them, and its report line
or JSON object. A bad file is one error line; the run goes on with the others."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import sys
import time
from pathlib import Path

from mocapfix.apps.fix_plan import RunPlan, plan_run, renders_of
from mocapfix.core.clip import MotionFileError, shown
from mocapfix.fills.motion_matching import MotionLibrary
from mocapfix.fix.files import FixedFile, fix_recording, read_recording
from mocapfix.fix.fixer import Fixer, FixOptions
from mocapfix.fix.report import ONE_AFTER_ANOTHER
from mocapfix.io.files import check_output, claimed, staged, writing

LONG_INPUT_S = 600.0  # progress is shown for inputs this long even when stderr is not a terminal


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


def fix_one(
    path: Path, rel: Path | None, fixer: Fixer, s: RunSettings, err, plan: RunPlan | None = None
) -> FileOutcome:
    """One input file read, fixed and written: its output (and with --render its pictures) whole
    under its final name, or none of them. plan: the run's (plan_run), which the output this
    file really gets is checked against again (never an input, never another input's output)."""
    t0 = time.perf_counter()
    try:
        recording = read_recording(path, fixer, s.source, **s.read_options)
        target = recording.output_path(Path(s.out) if s.out else None, Path(s.out_dir) if s.out_dir else None, rel)
        outputs = [target, *(renders_of(target) if s.render_gif else [])]
        _check_outputs(path, rel, outputs, s, plan)
        with contextlib.ExitStack() as claims:
            for output in outputs:  # one run per output: a second one to the same -o fails here
                claims.enter_context(claimed(output, path))  # and a killed run's temporary files go
            for output in outputs:  # an existing file (without --force), a folder, a link: before the work
                check_output(output, s.force, path)
            options = _options(s, path, sum(c.duration_s for c in recording.clips), err)
            fixed = fix_recording(recording, fixer, options, target, s.source, **s.read_options)
            _publish(fixed, outputs, s.force, s.render_gif)
    except _Skipped as e:
        return FileOutcome("skipped", f"{shown(path)}: skipped, {e}")
    except Exception as e:  # one bad file must not stop the others
        return FileOutcome("failed", f"error: {_one_line(path, e)}")
    return FileOutcome("fixed", report_text(fixed, time.perf_counter() - t0, s.as_json))


def _check_outputs(path: Path, rel: Path | None, outputs: list[Path], s: RunSettings, plan: RunPlan | None) -> None:
    """The outputs this file really gets, against the run's plan (a file fixed alone: its own);
    --resume skips a file whose output exists (written whole under its name: complete)."""
    plan = plan or plan_run([(path, rel)], None, None, False)[0]
    for output in outputs:
        problem = plan.problem(path, output)
        if problem is not None:
            raise MotionFileError(path, problem.removeprefix(f"{shown(path)}: "))
    if s.resume and os.path.lexists(outputs[0]) and not s.force:
        _clear_stale(outputs)
        raise _Skipped(f"{shown(outputs[0])} exists (--resume)")


def _options(s: RunSettings, path: Path, seconds: float, err) -> FixOptions:
    show = s.progress == "always" or (
        s.progress == "auto" and (getattr(err, "isatty", lambda: False)() or seconds >= LONG_INPUT_S)
    )
    bar = Progress(shown(path), show, err)
    return FixOptions(s.mode, s.overlap, s.batch_size, bar, s.joint_map, s.measured, s.library)


def _publish(fixed: FixedFile, outputs: list[Path], force: bool, render_gif: bool) -> None:
    """Written beside the outputs under hidden names, then moved into place together without
    overwriting (unless --force): a file that appeared meanwhile is never lost, and a failure
    (a full disk) leaves none of them, so a rerun starts clean."""
    path, target = fixed.path, outputs[0]
    with staged(outputs, force, path) as temps:
        with writing(target, path):
            try:
                fixed.write(temps[0], overwrite=True)  # our own staged file
            except MotionFileError as e:  # name the output, not its temporary file
                if Path(e.path) != temps[0]:
                    raise
                raise MotionFileError(path, f"cannot write output {shown(target)}: {e.problem}") from None
        if render_gif:  # the first person: a preview, not a report of every clip
            # matplotlib, imported only for --render: a third of a second of every run's start
            from mocapfix.core.render import holes_map, render, tracks_for

            gif, holes = outputs[1:]
            first = fixed.inputs[0]
            tracks = tracks_for(first, [(target.name, fixed.clips[0])])
            with writing(gif, path):
                render(tracks, first.skeleton.limbs, first.fps, gif, write_to=temps[1])
            with writing(holes, path):
                holes_map(tracks, first.skeleton.joint_names, first.fps, holes, write_to=temps[2])


def report_text(fixed: FixedFile, seconds: float, as_json: bool) -> str:
    """The file's report line, or its JSON object (--json)."""
    report, path, target = fixed.report, fixed.path, fixed.output
    if as_json:
        fields = report.as_dict()
        notes = fields.pop("notes")
        return json.dumps(
            {"input": str(path), "output": str(target), **fields, "seconds": round(seconds, 3), "notes": notes}
        )
    kind = ONE_AFTER_ANOTHER.get(fixed.inputs[0].meta.get("format")) or ("person" if report.people == 1 else "people")
    line = (
        f"{shown(path)} -> {shown(target)}: {report.frames} frames, {report.people} {kind}, "
        f"{report.filled} tokens filled, {report.replaced} replaced ({report.mode}, {report.model}), "
        f"limb sigma {_num(report.limb_sigma_before_mm)} -> {_num(report.limb_sigma_after_mm)} mm, "
        f"{seconds:.2f} s"
    )
    return line + "".join(f"; {n}" for n in report.notes)


def _clear_stale(outputs: list[Path]) -> None:
    """A killed run's temporary files beside outputs that are complete (--resume skips them):
    claiming an output removes them; one another run holds is left to that run."""
    for output in outputs:
        with contextlib.suppress(MotionFileError, OSError), claimed(output):
            pass


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
