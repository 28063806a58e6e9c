"""A BVH written back by `fix` keeps what fix did not change: the lines before the frames (HIERARCHY,
MOTION, Frames, Frame Time), every frame line fix left alone and, in a frame it changed, every
value of a joint it did not move, byte for byte; line ends (LF, CRLF, CR) and spaces too. A
changed value is written with the digits its column uses."""

from __future__ import annotations

import re

import numpy as np
import pytest

from mocapfix.apps.main import main
from mocapfix.io.bvh import read_bvh, write_bvh_like

TAKE = "dataset-2_run_normal_003.bvh"  # Bandai Namco, 75 frames at 30 fps, 6 channels a joint, %g digits
CMU_TAKE = "09_02.bvh"  # 129 frames at 120 fps ("Frame Time: .0083333"), 4 decimals


def _layout(text: str) -> tuple[dict[str, int], dict[str, list[int]]]:
    """The HIERARCHY of a BVH text -> {joint: parent joint's index or -1}, by joint order, and
    {joint: its rotation channels' columns}: read here, independently of the reader."""
    parents, rotations, stack, pending, col = {}, {}, [], None, 0
    for line in re.split(r"\r\n|\r|\n", text.split("MOTION")[0]):
        words = line.split()
        if words[:1] in (["ROOT"], ["JOINT"]):
            pending = words[1]
            parents[pending] = list(parents).index(stack[-1]) if stack else -1
            rotations[pending] = []
        elif words[:1] == ["End"]:
            pending = None
        elif words[:1] == ["{"]:
            stack.append(pending)
        elif words[:1] == ["}"]:
            stack.pop()
        elif words[:1] == ["CHANNELS"]:
            for name in words[2:]:
                if name.endswith("rotation"):
                    rotations[stack[-1]].append(col)
                col += 1
    return parents, rotations


def _below(parents: dict[str, int], joint: str) -> list[str]:
    """joint and every joint under it."""
    names = list(parents)
    out = [joint]
    for name in names:  # parents come before their children
        if parents[name] >= 0 and names[parents[name]] in out:
            out.append(name)
    return out


def _frame_lines(data: bytes, end: bytes) -> tuple[list[bytes], list[bytes]]:
    """A BVH's bytes -> (its lines through "Frame Time", its frame lines), each with its end."""
    lines = data.split(end)
    lines = [ln + end for ln in lines[:-1]] + ([lines[-1]] if lines[-1] else [])
    first = next(i for i, ln in enumerate(lines) if ln.lstrip().startswith(b"Frame Time")) + 1
    return lines[:first], lines[first:]


def _with_hole(text: str, columns: list[int], frames: range) -> str:
    """text with the values of `columns` in `frames` written as nan, every other character as it was."""
    head, rows = text.split("Frame Time:")
    rows = rows.split("\n")  # rows[0]: the rest of the Frame Time line
    for t in frames:
        spans = [m.span() for m in re.finditer(r"\S+", rows[1 + t])]
        for c in sorted(columns, reverse=True):
            a, b = spans[c]
            rows[1 + t] = rows[1 + t][:a] + "nan" + rows[1 + t][b:]
    return head + "Frame Time:" + "\n".join(rows)


def _fix(path, out, mode: str = "infill") -> bytes:
    argv = ["fix", str(path), "--model", "xmae-cpu-bandai", "--mode", mode, "-o", str(out), "--progress", "never"]
    assert main(argv) == 0
    return out.read_bytes()


@pytest.fixture(scope="module")
def take(bandai_files):
    [src] = [f for f in bandai_files if f.name == TAKE]
    return src


def test_a_take_fix_leaves_alone_comes_back_byte_identical(take, tmp_path, capsys):
    """Nothing to fill: the output is the input, header and digits included (it was every value
    at 6 decimals and "Frame Time: 0.033333333")."""
    assert _fix(take, tmp_path / "out.bvh") == take.read_bytes()
    assert "0 tokens filled" in capsys.readouterr().out


@pytest.mark.parametrize("end", ["\n", "\r\n", "\r"])
def test_a_hole_changes_only_its_frames_and_joints(take, tmp_path, end, capsys):
    """The left forearm's rotation missing for half a second (its hand missing there): every line
    outside those frames comes back byte-identical, and within them only the channels of the
    forearm and the joints below it change (and no nan is left); line ends as the input's."""
    text = take.read_text()
    parents, rotations = _layout(text)
    frames = range(30, 45)
    holed = _with_hole(text, rotations["LowerArm_L"], frames)
    src = tmp_path / "holed.bvh"
    src.write_bytes(holed.replace("\n", end).encode())
    [clip] = read_bvh(src)  # a rotation's nan: the joints below are missing, not the forearm
    names, missing = clip.skeleton.joint_names, clip.missing_mask()  # (T, J)
    assert missing[30:45, names.index("Hand_L")].all() and not missing[:, names.index("LowerArm_L")].any()
    out = _fix(src, tmp_path / "out.bvh")
    capsys.readouterr()

    e = end.encode()
    head_in, rows_in = _frame_lines(src.read_bytes(), e)
    head_out, rows_out = _frame_lines(out, e)
    assert head_out == head_in and len(rows_out) == len(rows_in)
    assert out.count(e) == src.read_bytes().count(e) and (end == "\n" or b"\n" not in out.replace(e, b""))
    assert {t for t, (a, b) in enumerate(zip(rows_in, rows_out)) if a != b} == set(frames)

    may_change = {c for j in _below(parents, "LowerArm_L") for c in rotations[j]}
    for t in frames:
        before, after = rows_in[t].split(), rows_out[t].split()
        changed = {c for c, (a, b) in enumerate(zip(before, after)) if a != b}
        assert set(rotations["LowerArm_L"]) <= changed <= may_change, (t, changed)
        assert b"nan" not in rows_out[t]


def test_a_cmu_take_keeps_its_header_and_digits(cmu_files, tmp_path, capsys):
    """A 120 fps CMU take keeps "Frame Time: .0083333" (it was 0.0083333333); the values fix
    writes in a hole have the file's 4 decimals; every other line is the input's."""
    [cmu] = [f for f in cmu_files if f.name == CMU_TAKE]
    text = cmu.read_text()
    parents, rotations = _layout(text)
    frames = range(40, 70)
    src = tmp_path / "holed.bvh"
    src.write_text(_with_hole(text, rotations["LeftLeg"], frames))
    out = _fix(src, tmp_path / "out.bvh")
    capsys.readouterr()

    head_in, rows_in = _frame_lines(src.read_bytes(), b"\n")
    head_out, rows_out = _frame_lines(out, b"\n")
    assert head_out == head_in and b"Frame Time: .0083333\n" in head_out
    assert {t for t, (a, b) in enumerate(zip(rows_in, rows_out)) if a != b} == set(frames)
    for t in frames:
        new = [b for a, b in zip(rows_in[t].split(), rows_out[t].split()) if a != b]
        assert new and all(re.fullmatch(rb"-?\d+\.\d{4}", v) for v in new), new


def test_unchanged_rotations_keep_their_tokens_whatever_their_angles(take, tmp_path):
    """write_bvh_like keeps a value whose joint did not turn, as the file wrote it: an angle 360
    degrees round (the Euler angles of the same rotation), tabs between values, trailing spaces.
    A joint turned in some frames gets new values there only, with the file's digits."""
    text = take.read_text()
    parents, rotations = _layout(text)
    col = rotations["LowerLeg_R"][0]
    head, rows = text.split("Frame Time:")
    rows = rows.split("\n")
    for t in range(1, len(rows)):
        values = rows[t].split()
        if values:
            values[col] = f"{float(values[col]) + 360:g}"  # the same rotation
            rows[t] = "\t".join(values) + "  "
    src = tmp_path / "odd.bvh"
    src.write_text(head + "Frame Time:" + "\n".join(rows))

    [clip] = read_bvh(src)  # Hips is its root (joint_Root dropped), as fix reads it
    write_bvh_like(tmp_path / "same.bvh", clip, src)
    assert (tmp_path / "same.bvh").read_bytes() == src.read_bytes()

    j = clip.skeleton.joint_names.index("LowerArm_L")
    rot = clip.rotations.copy()
    rot[10:20, j] += np.float32(0.1)  # radians
    write_bvh_like(tmp_path / "turned.bvh", clip.replace(rotations=rot), src)
    _, rows_in = _frame_lines(src.read_bytes(), b"\n")
    _, rows_out = _frame_lines((tmp_path / "turned.bvh").read_bytes(), b"\n")
    assert {t for t, (a, b) in enumerate(zip(rows_in, rows_out)) if a != b} == set(range(10, 20))
    for t in range(10, 20):
        before, after = rows_in[t].split(b"\t"), rows_out[t].split(b"\t")
        assert {c for c, (a, b) in enumerate(zip(before, after)) if a != b} == set(rotations["LowerArm_L"])
        assert rows_out[t].endswith(b"  \n")
        for c in rotations["LowerArm_L"]:  # the 6 decimals this take writes
            assert re.fullmatch(rb"-?\d+\.\d{6}", after[c].strip()), after[c]
