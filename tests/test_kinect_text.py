"""The action datasets' Kinect v1 skeleton text (.txt, io/kinect_text.py): UTKinect-Action3D's
frame-numbered rows put on their clock, MSR Action3D's joint lines in its own order and
left-handed frame, and fix's output the file's own lines with only the changed numbers new."""

from __future__ import annotations

import numpy as np
import pytest
from cli_utils import run_mocapfix
from test_keypoints import body_take, in_layout  # noqa: F401  (body_take: the fixture)

from mocapfix.core.clip import MotionFileError
from mocapfix.io import detect_source, read_motion
from mocapfix.io.conventions import from_z_up
from mocapfix.io.kinect_text import MSR_ORDER, write_kinect_text
from mocapfix.io.layouts import layout

KINECT20 = layout("kinect20").joint_names


def utkinect_text(numbers, x) -> str:
    """numbers: (T,) frame numbers; x: (T, 20, 3) metres, y up, kinect20 order: the dataset's lines."""
    return "".join(f"{n}   " + "  ".join(f"{v:.6f}" for v in row.ravel()) + "  \n" for n, row in zip(numbers, x))


def msr_text(x, c) -> str:
    """x: (T, 20, 3) metres, y up, kinect20 order, right-handed; c: (T, 20) the 4th number -> the
    dataset's lines: MSR's joint order, x along the image's columns (negated)."""
    order = [KINECT20.index(n) for n in MSR_ORDER]
    lines = [f"{-x[t, j, 0]:.6f} {x[t, j, 1]:.6f} {x[t, j, 2]:.6f} {c[t, j]:.6f}" for t in range(len(x)) for j in order]
    return "\n".join(lines) + "\n"


def test_utkinect_rows_on_their_clock_and_written_back_in_place(tmp_path, body_take):  # noqa: F811
    camera = from_z_up(in_layout("kinect20", body_take), "y")  # (T, 20, 3) m, y up
    steps = np.array([0, 4, 2, 6, 4, 4, 0, 2, 8, 4] * 6)  # 2-8 camera frames apart, two numbers repeated
    numbers = 190 + np.cumsum(steps)
    clock = (numbers - 190) // 2  # the rows' frames at 15 fps
    rows = camera[2 * clock]  # the body at each row's camera frame (30 fps)
    path = tmp_path / "joints_s01_e01.txt"
    path.write_text(utkinect_text(numbers, rows))
    assert detect_source(path) == "keypoints"
    (clip,) = read_motion(path, fps=30)
    assert clip.fps == 15.0 and clip.num_frames == clock[-1] + 1 and clip.meta["layout"] == "kinect20"
    back = from_z_up(clip.positions.astype(np.float64) + clip.origin, "y")
    first = np.concatenate([[True], np.diff(numbers) > 0])  # a repeated number read once: its first row
    names = clip.skeleton.joint_names
    on_file = rows[:, [KINECT20.index(n) for n in names]]
    assert np.allclose(back[clock[first]], on_file[first], atol=1e-6)
    held = np.zeros(clip.num_frames, dtype=bool)
    held[clock] = True
    assert np.isnan(clip.positions[~held]).all() and np.isfinite(clip.positions[held]).all()  # holes between rows
    # the writer: one joint of one frame moved 2 cm -> the line read for that frame changes there
    # only, not the line repeating its number (unread: sometimes another body)
    moved = clip.positions.copy()
    wrist, t = names.index("WristLeft"), clock[6]  # numbers[6] repeats numbers[5]
    moved[t, wrist, 0] += 0.02
    out = tmp_path / "out.txt"
    write_kinect_text(out, [clip.replace(positions=moved)], [clip])
    before, after = path.read_text().splitlines(), out.read_text().splitlines()
    changed = [i for i, (u, v) in enumerate(zip(before, after)) if u != v]
    assert len(after) == len(before) and changed == [5]
    k = 1 + 3 * KINECT20.index("WristLeft")
    for i in changed:
        old, new = before[i].split(), after[i].split()
        assert new[:k] == old[:k] and new[k + 3 :] == old[k + 3 :] and new[k + 1 : k + 3] == old[k + 1 : k + 3]
        assert abs(float(new[k]) - float(old[k]) - 0.02) < 2e-6  # camera x is body x
        assert len(after[i]) == len(before[i]) + (len(new[k]) - len(old[k]))  # every space kept


def test_msr_action3d_in_its_order_and_frame_and_fix_keeps_its_lines(tmp_path, body_take, capsys):  # noqa: F811
    camera = from_z_up(in_layout("kinect20", body_take), "y")[:90]
    c = np.ones((90, 20))
    c[:, [KINECT20.index(n) for n in ("HipCenter", "Spine", "FootLeft")]] = 0.0  # not a tracking state
    path = tmp_path / "a01_s01_e01_skeleton3D.txt"
    lost = camera.copy()
    lost[:3] = 0.0  # frames the tracker lost: zeros
    path.write_text(msr_text(lost, c))
    (clip,) = read_motion(path, fps=15)
    assert clip.fps == 15.0 and clip.num_frames == 90
    assert np.isnan(clip.positions[:3]).all() and np.isfinite(clip.positions[3:]).all()
    path.write_text(msr_text(camera, c))
    (clip,) = read_motion(path, fps=15)
    assert np.isfinite(clip.positions).all()
    names = clip.skeleton.joint_names
    truth = in_layout("kinect20", body_take)[:90][:, [KINECT20.index(n) for n in names]]
    # the right shoulder where the body's right shoulder is: MSR's left-handed x read negated
    assert np.allclose(clip.positions + clip.origin, truth, atol=1e-5)
    rc, out, err = run_mocapfix(
        ["fix", path, "--fps", "15", "--mode", "denoise", "--model", "jitter-many", "--out-dir", tmp_path / "o"], capsys
    )
    assert rc == 0, err
    before, after = path.read_text().splitlines(), (tmp_path / "o" / path.name).read_text().splitlines()
    assert len(after) == len(before) == 90 * 20
    assert [line.split()[3] for line in after] == [line.split()[3] for line in before]  # the 4th number as read
    moved = np.array([[float(v) for v in u.split()[:3]] for u in after]) - np.array(
        [[float(v) for v in u.split()[:3]] for u in before]
    )
    assert 0 < np.linalg.norm(moved, axis=-1).mean() < 0.01  # a clean take's jitter taken out: millimetres


def test_what_is_not_a_kinect_skeleton_text_is_one_line_naming_the_problem(tmp_path):
    path = tmp_path / "a01_s01_e01_skeleton.txt"  # MSR's screen coordinates: pixels, depth / 4
    path.write_text("".join(f"{120 + j} {80 + 2 * j} 669 1\n" for j in range(40)))
    with pytest.raises(MotionFileError, match="screen coordinates .* read the take's _skeleton3D.txt"):
        read_motion(path, fps=15)
    path = tmp_path / "take.txt"
    path.write_text("".join("0.000000 0.000000 0.000000 0.000000\n" for _ in range(40)))
    with pytest.raises(MotionFileError, match="no joint tracked in any frame"):
        read_motion(path, fps=15)
    path.write_text("".join("0.1 0.2 0.3 1\n" for _ in range(30)))
    with pytest.raises(MotionFileError, match="30 joint lines: MSR Action3D has 20 a frame"):
        read_motion(path, fps=15)
    with pytest.raises(MotionFileError, match="no frame rate: give --fps, MSR Action3D's: 15"):
        read_motion(path)
    path.write_text("1 2 3 4 5 6 7\n")
    with pytest.raises(MotionFileError, match="7 value.s. on its first line: neither Human3.6M"):
        read_motion(path)
    row = "  ".join(["0.5"] * 60)
    path.write_text(f"12 {row}\n10 {row}\n")
    with pytest.raises(MotionFileError, match="line 2: the frame number goes back"):
        read_motion(path, fps=30)
    path.write_text(f"12 {row}\n14 {row[:-1]}x\n")
    with pytest.raises(MotionFileError, match="line 2: a cell that is not a number"):
        read_motion(path, fps=30)
    path.write_text("0.0," * 98 + "0.0\n")  # Human3.6M's exponential maps: still theirs
    assert detect_source(path) == "h36m"
