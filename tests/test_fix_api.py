"""The library does what the command does (issue 46): a BVH fixed through `mocapfix.fix.fix_file`
and written with its writer is the command's output byte for byte, and its report value is the
command's --json report; a fixer's class, not a kind string, decides how clips are fixed."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mocapfix.apps.main import main
from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.core.skeleton import preset
from mocapfix.fix import FixReport, fix_clips, fix_file, load_fixer
from mocapfix.fix.fixer import Fixer
from mocapfix.pretrained import pretrained_path


def _holed_bvh(src, dst, frames=90):
    """The take's first `frames` frames with one joint's rotation channels missing (NaN) for 20."""
    head, motion = src.read_text().split("MOTION", 1)
    lines = motion.strip().splitlines()
    rows = [ln.split() for ln in lines[2 : 2 + frames]]
    for t in range(30, 50):
        rows[t][9:12] = ["nan"] * 3
    frame_time = lines[1]
    dst.write_text(f"{head}MOTION\nFrames: {len(rows)}\n{frame_time}\n" + "\n".join(" ".join(r) for r in rows) + "\n")
    return dst


def test_fix_file_writes_the_commands_bytes_and_its_report_is_the_json_report(bandai_files, tmp_path, capsys):
    take = _holed_bvh(bandai_files[0], tmp_path / "take.bvh")
    capsys.readouterr()
    assert main(["fix", str(take), "--model", "xmae-cpu-bandai", "-o", str(tmp_path / "cmd.bvh"), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])

    fixed = fix_file(take, load_fixer(pretrained_path("xmae-cpu-bandai")))
    assert fixed.output == tmp_path / "take.fixed.bvh"  # the command's default output
    fixed.write(tmp_path / "api.bvh")
    assert (tmp_path / "api.bvh").read_bytes() == (tmp_path / "cmd.bvh").read_bytes()
    assert isinstance(fixed.report, FixReport) and fixed.report.filled > 0
    for key in ("input", "output", "seconds"):
        printed.pop(key)
    assert fixed.report.as_dict() == printed
    # and as the command: never onto the input, an existing output only when asked
    before = take.read_bytes()
    with pytest.raises(MotionFileError, match="is the input"):
        fixed.write(take, overwrite=True)
    with pytest.raises(MotionFileError, match="exists"):
        fixed.write(tmp_path / "cmd.bvh")
    assert take.read_bytes() == before
    assert fixed.write(tmp_path / "cmd.bvh", overwrite=True) == tmp_path / "cmd.bvh"


class _Halver(Fixer):
    """A fixer that carries its own way of fixing clips: every position halved."""

    kind, default_mode = "halver", "denoise"
    skeleton, fps, window = preset("smpl22"), 30.0, 30

    def fix_clips(self, clips, options):
        self.mode = options.mode
        out = [c.replace(positions=c.positions / 2) for c in clips]
        return out, FixReport(clips[0].num_frames, len(clips), 0, 0, 0.0, 0.0, 0)


def test_a_fixer_fixes_clips_itself_in_its_own_default_mode():
    rest = np.stack([np.zeros(22), np.linspace(-0.2, 0.2, 22), np.linspace(0.0, 1.7, 22)], axis=-1)
    clip = Clip(np.repeat(rest[None], 10, 0).astype(np.float32), 30.0, preset("smpl22"))
    fixer = _Halver()
    (out,), _ = fix_clips([clip], fixer)
    assert fixer.mode == "denoise"
    np.testing.assert_array_equal(out.positions, clip.positions / 2)
