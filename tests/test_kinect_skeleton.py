"""Kinect v2 skeleton text files (io/kinect_skeleton.py): each body ID a person, a joint's tracking
state its confidence, and fix's output the file's own lines with only the filled positions new."""

from __future__ import annotations

import numpy as np
import pytest
from cli_utils import run_mocapfix
from test_keypoints import body_take, in_layout  # noqa: F401  (body_take: the fixture)

from mocapfix.core.clip import MotionFileError
from mocapfix.io import read_motion
from mocapfix.io.conventions import from_z_up


def skeleton_text(bodies: list[tuple[str, int, np.ndarray, np.ndarray]], frames: int) -> str:
    """bodies: (body id, first frame, positions (T, 25, 3) metres y up, tracking state (T, 25))."""
    lines = [str(frames)]
    for t in range(frames):
        present = [b for b in bodies if b[1] <= t < b[1] + len(b[2])]
        lines.append(str(len(present)))
        for body_id, first, x, state in present:
            lines += [f"{body_id} 0 1 1 1 1 0 0.01 -0.2 2", "25"]
            for j in range(25):
                px, py, pz = (f"{v:.7g}" for v in x[t - first, j])
                lines.append(f"{px} {py} {pz} 251.1 211.3 1001.5 520.2 0.1 0.2 0.3 0.9 {int(state[t - first, j])}")
    return "\n".join(lines) + "\n"


def test_two_bodies_their_tracking_states_and_fix_in_the_files_own_lines(tmp_path, body_take, capsys):  # noqa: F811
    a = from_z_up(in_layout("kinect25", body_take), "y")[:90]  # metres, y up: camera space
    b = a[:60] + np.array([1.0, 0.0, 0.5])  # a second person from frame 30 on
    state_a = np.full(a.shape[:2], 2)
    state_a[40:46, 5:8] = 0  # the left elbow, wrist and hand not tracked for 0.2 s
    state_a[70:72, 13] = 1  # the left knee inferred: kept
    text = skeleton_text([("72057594037931101", 0, a, state_a), ("72057594037931102", 30, b, np.full((60, 25), 2))], 90)
    path = tmp_path / "S001C001P001R001A001.skeleton"
    path.write_text(text)
    clips = read_motion(path)
    assert [c.meta["person_id"] for c in clips] == ["72057594037931101", "72057594037931102"]
    assert all(c.fps == 30.0 and c.num_frames == 90 and c.meta["layout"] == "kinect25" for c in clips)
    elbow = clips[0].skeleton.index("ElbowLeft")
    assert np.isnan(clips[0].positions[40:46, elbow]).all() and np.isfinite(clips[0].positions[70:72]).all()
    assert np.isnan(clips[1].positions[:30]).all() and np.isfinite(clips[1].positions[30:]).all()
    rc, out, err = run_mocapfix(["fix", path, "--model", "xmae-cpu-bandai"], capsys)
    assert rc == 0, err
    back = (tmp_path / "S001C001P001R001A001.fixed.skeleton").read_text().splitlines()
    lines = text.splitlines()
    assert len(back) == len(lines)
    changed = [i for i, (u, v) in enumerate(zip(lines, back)) if u != v]
    assert len(changed) == 18  # the 6 frames x 3 joints not tracked, nothing else
    for i in changed:
        new, old = back[i].split(), lines[i].split()
        assert new[3:] == old[3:]  # every other number as it was
        truth = np.array(old[:3], dtype=float)  # the skeleton text kept the true position
        assert np.linalg.norm(np.array(new[:3], dtype=float) - truth) < 0.05


def test_a_broken_skeleton_file_is_one_line_naming_where(tmp_path):
    path = tmp_path / "bad.skeleton"
    path.write_text("3\n1\n72057594037931101 0 1 1 1 1 0 0.01 -0.2 2\n25\n0.1 0.2 3.0\n")
    with pytest.raises(MotionFileError, match="line 5: a joint's line has 12 numbers"):
        read_motion(path)
    path.write_text("2\n0\n0\n")
    with pytest.raises(MotionFileError, match="2 frames and no body in any"):
        read_motion(path)


def test_a_body_id_in_every_frame_is_refused_before_it_takes_the_memory(tmp_path):
    """2,000 frames with another body ID in each would be 2,000 people over 2,000 frames."""
    lines = ["2000"]
    for t in range(2000):
        lines += ["1", f"{t} 0 1 1 1 1 0 0.01 -0.2 2", "25"] + ["0.1 0.2 3.0 1 1 1 1 0 0 0 1 2"] * 25
    (tmp_path / "many.skeleton").write_text("\n".join(lines) + "\n")
    with pytest.raises(MotionFileError, match="2000 body IDs over 2000 frames"):
        read_motion(tmp_path / "many.skeleton")


def test_a_person_found_again_under_a_new_body_id_is_one_person(tmp_path, body_take):  # noqa: F811
    x = from_z_up(in_layout("kinect25", body_take), "y")[:90]
    state = np.full((90, 25), 2)
    a, b = x[:50], x[55:]  # tracking lost for 5 frames, found again under another ID
    text = skeleton_text([("11", 0, a, state[:50]), ("12", 55, b, state[55:])], 90)
    (tmp_path / "t.skeleton").write_text(text)
    (clip,) = read_motion(tmp_path / "t.skeleton")
    assert clip.meta["person_id"] == "11+12"
    assert np.isnan(clip.positions[50:55]).all() and np.isfinite(np.delete(clip.positions, range(50, 55), 0)).all()
    far = x[55:] + np.array([2.0, 0.0, 0.0])  # someone else, 2 m away, a moment later: two people
    (tmp_path / "two.skeleton").write_text(skeleton_text([("11", 0, a, state[:50]), ("12", 55, far, state[55:])], 90))
    assert [c.meta["person_id"] for c in read_motion(tmp_path / "two.skeleton")] == ["11", "12"]
