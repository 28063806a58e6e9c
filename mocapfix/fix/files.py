"""A file fixed from Python as `mocapfix fix` fixes it: read, fixed by the fixer, put back in the
file's own shape (a BVH by inverse kinematics onto its own skeleton for a positions model), with
the report the command prints, as a value; written by the command's writer.

    from mocapfix.fix import fix_file, load_fixer
    fixed = fix_file("take.bvh", load_fixer("model.ckpt"))
    fixed.write("take.fixed.bvh")
    print(fixed.report.filled, fixed.report.notes)

The command (apps/fix_cli.py) adds only what a run of many files needs: where outputs go, that
none is lost or overwritten, workers, printing.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapfix.core.clip import Clip, MotionFileError, shown
from mocapfix.fix.clips import fix_clips
from mocapfix.fix.fixer import Fixer, FixOptions
from mocapfix.fix.hierarchy import bvh_reference, onto_hierarchy
from mocapfix.fix.output import output_path, write_output
from mocapfix.fix.report import FixReport
from mocapfix.io import read_motion
from mocapfix.io.files import check_output


@dataclass
class Recording:
    """A file as fix reads it: its clips, and for a BVH whose rotations were set aside (missing
    channels, a jump) the file read again with its channels interpolated, the pose inverse
    kinematics starts from (hierarchy.bvh_reference)."""

    path: Path
    clips: list[Clip]
    reference: list[Clip] | None
    rotations: bool  # the output has rotations to write: a rotations model's, or IK's from the reference

    def output_path(self, out: Path | None = None, out_dir: Path | None = None, rel: Path | None = None) -> Path:
        """Where the fixed file goes (output.output_path): out, else out_dir/rel, else beside it."""
        return output_path(self.path, self.clips, out, out_dir, rel, self.rotations)


def read_recording(path, fixer: Fixer, source: str = "auto", **read_options) -> Recording:
    clips = read_motion(path, source, **read_options)
    if not clips:
        raise MotionFileError(path, "no motion in the file")
    # A BVH whose rotations were set aside still goes back as a BVH: the file re-read with its
    # channels interpolated is the pose IK starts from.
    reference = None if fixer.gives_rotations or clips[0].has_rotations else bvh_reference(Path(path), clips)
    return Recording(Path(path), clips, reference, fixer.gives_rotations or reference is not None)


@dataclass
class FixedFile:
    """A fixed file: its clips as they are written, the report (FixReport.as_dict is the
    command's --json line without input, output and seconds), and what writing needs."""

    clips: list[Clip]
    report: FixReport
    inputs: list[Clip]  # the clips as read
    path: Path  # the input file
    output: Path  # where the command would write it (its kind: .bvh, .npz, .csv)

    def write(self, target=None, overwrite: bool = False) -> Path:
        """Write the fixed file (to `output` by default) with the command's writer and return
        where. As the command: never onto the input, never through a link, and an existing file
        only with overwrite=True (MotionFileError otherwise, before anything is written)."""
        target = Path(target if target is not None else self.output)
        if target.exists() and self.path.exists() and os.path.samefile(target, self.path):
            raise MotionFileError(self.path, f"output {shown(target)} is the input; fix never overwrites its input")
        check_output(target, overwrite, source=self.path)
        write_output(target, self.clips, self.inputs, self.path)
        return target


def fix_recording(
    recording: Recording, fixer: Fixer, options: FixOptions, output: Path, source: str = "auto", **read_options
) -> FixedFile:
    """The recording fixed for `output` (its suffix says what is written: a .bvh of a positions
    model's fix is put back on the input's skeleton)."""
    clips = recording.clips
    work = fixer.clips_for(recording.path, clips, source, options.joint_map, **read_options)
    fixed, report = fix_clips(
        work,
        fixer,
        options.mode,
        options.overlap,
        options.batch_size,
        options.progress,
        options.joint_map,
        options.measured,
        options.library,
    )
    if output.suffix.lower() == ".bvh" and not fixer.gives_rotations:
        # the tokens fix kept as recorded (T, J): only they pull the IK; a filled or
        # replaced one is where the model put it, and must not bend the observed limbs
        seen = [np.isfinite(c.positions).all(-1) & (f.positions == c.positions).all(-1) for c, f in zip(clips, fixed)]
        fixed, ik_mean, ik_max = onto_hierarchy(fixed, recording.reference or clips, seen)
        report.notes.append(
            f"BVH by inverse kinematics onto the input's skeleton: its bone lengths moved joints "
            f"{ik_mean:.1f} mm on average from the model's positions (max {ik_max:.1f} mm)"
        )
    report.notes = _file_notes(report, clips, output, fixer)
    report.mode, report.model = options.mode, fixer.kind
    return FixedFile(fixed, report, clips, recording.path, output)


def fix_file(
    path,
    fixer: Fixer,
    mode: str | None = None,
    output=None,
    overlap: float = 0.5,
    batch_size: int = 64,
    joint_map: dict[str, str] | None = None,
    source: str = "auto",
    **read_options,
) -> FixedFile:
    """The file at `path` fixed as `mocapfix fix PATH [-o OUTPUT]` fixes it. mode: MODES, None:
    the fixer's own; output: its output's name (its suffix chooses the format; None: the
    command's default, <stem>.fixed<ext> beside the input); read_options: read_motion's."""
    recording = read_recording(path, fixer, source, **read_options)
    target = recording.output_path(Path(output) if output is not None else None)
    options = FixOptions(mode or fixer.default_mode, overlap, batch_size, None, joint_map)
    return fix_recording(recording, fixer, options, target, source, **read_options)


def _file_notes(report: FixReport, clips: list[Clip], output: Path, fixer: Fixer) -> list[str]:
    """The report's notes with what is said about the file itself in front: what the output's
    format keeps, which fills filled, the tokens no body could take."""
    notes = list(report.notes)
    fmt = clips[0].meta.get("format")
    if fmt in ("bvh", "amass") and output.suffix.lower() != ".bvh":
        if fmt == "amass":
            note = f"positions .npz/.csv: {fixer.kind.upper()} gives positions, not rotations"
        elif fixer.gives_rotations or clips[0].has_rotations:
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
    return notes
