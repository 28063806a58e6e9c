"""Kinect body-frame logs (.skl, io/kinect_log.py): joints by their column names, the tracking
state as confidence, the frames on the camera's clock (a dropped frame a hole, a repeated line read
once, a pause a new take), and fix's output the file's own lines with only the changed cells new."""

from __future__ import annotations

import numpy as np
import pytest
from cli_utils import run_mocapfix
from test_keypoints import body_take, in_layout  # noqa: F401  (body_take: the fixture)

from mocapfix.core.clip import MotionFileError
from mocapfix.io import read_motion
from mocapfix.io.conventions import from_z_up
from mocapfix.io.layouts import layout


def log_text(names, stamps, x, state, extra=("framenum", "FloorPlane_A")) -> str:
    """names: the joints in the file's column order; stamps: (T,) the timestamp column; x: (T, J, 3)
    metres y up in that order; state: (T, J) tracking state. CRLF, as the SDK loggers write."""
    header = ["timestamp", *extra] + [f"{n}_{f}" for n in names for f in ("X", "Y", "Z", "tracked")]
    lines = ["\t".join(header)]
    for t, stamp in enumerate(stamps):
        cells = [f"{float(stamp):.15g}", str(1000 + t), "0.05"][: 1 + len(extra)]
        cells += [v for j in range(len(names)) for v in (*(f"{c:.15g}" for c in x[t, j]), str(int(state[t, j])))]
        lines.append("\t".join(cells))
    return "\r\n".join(lines) + "\r\n"


def test_a_v1_log_on_the_clock_and_fix_in_its_own_lines(tmp_path, body_take, capsys):  # noqa: F811
    names = list(layout("kinect20").joint_names)
    x = from_z_up(in_layout("kinect20", body_take), "y")[:120]  # metres, y up: camera space
    stamps = 500000.0 + np.round(np.arange(120) * 1000 / 30)  # ms at 30 fps
    keep = np.ones(120, dtype=bool)
    keep[50] = False  # a frame the SDK dropped
    rows = np.flatnonzero(keep)
    rows = np.insert(rows, 30, 29)  # frame 29's line twice (a repeated frame id)
    stamps = np.concatenate([stamps[rows[:70]], stamps[rows[70:]] + 5000])  # a 5-s pause after frame 69
    state = np.full((len(rows), 20), 2)
    state[40:44, names.index("WristLeft")] = 0  # not tracked: a hole
    order = [names[k] for k in (3, 0, 1, 2, *range(4, 20))]  # columns in the logger's order, not the layout's
    cols = [names.index(n) for n in order]
    text = log_text(order, stamps, x[rows][:, cols], state[:, cols])
    path = tmp_path / "walk.skl"
    path.write_bytes(text.encode())
    clips = read_motion(path)
    assert [c.meta["person_id"] for c in clips] == ["1", "2"] and all(c.fps == 30.0 for c in clips)
    assert [c.num_frames for c in clips] == [70, 50]  # frames 0-69 (29 read once); 70-119 after the pause
    wrist = clips[0].skeleton.index("WristLeft")
    assert np.isnan(clips[0].positions[39:43, wrist]).all()  # lines 40-43 are frames 39-42 (29 twice)
    missing = np.isnan(clips[0].positions).all((1, 2))
    assert missing.nonzero()[0].tolist() == [50] and np.isfinite(clips[1].positions).all()  # the dropped frame
    assert clips[0].meta["layout"] == "kinect20"
    rc, out, err = run_mocapfix(["fix", path, "--model", "xmae-cpu-bandai"], capsys)
    assert rc == 0, err
    assert "120 frames, 2 takes," in err + out  # the takes one after another, not two people at once
    back = (tmp_path / "walk.fixed.skl").read_bytes().decode()
    assert back.count("\r\n") == text.count("\r\n")
    before, after = text.splitlines(), back.splitlines()
    changed = [i for i, (u, v) in enumerate(zip(before, after)) if u != v]
    assert changed == [41, 42, 43, 44]  # the four lines of the untracked wrist (the header is line 0)
    for i in changed:
        new, old = after[i].split("\t"), before[i].split("\t")
        at = 3 + 4 * order.index("WristLeft")
        assert new[:at] == old[:at] and new[at + 3 :] == old[at + 3 :]  # every other cell as it was
        truth = np.array(old[at : at + 3], dtype=float)  # the log kept the true position
        assert np.linalg.norm(np.array(new[at : at + 3], dtype=float) - truth) < 0.05


def test_a_v2_log_in_100ns_ticks_with_v1s_name_for_the_spine_shoulder(tmp_path, body_take):  # noqa: F811
    names = list(layout("kinect25").joint_names)
    x = from_z_up(in_layout("kinect25", body_take), "y")[:60]
    stamps = 6.3e11 + np.arange(60) * 333333.0
    named = ["ShoulderCenter" if n == "SpineShoulder" else n for n in names]
    path = tmp_path / "laban.skl"
    path.write_text(log_text(named, stamps, x, np.full((60, 25), 2), extra=("framenum",)))
    (clip,) = read_motion(path)
    assert clip.meta["layout"] == "kinect25" and clip.fps == 30.0 and clip.num_frames == 60
    spine = clip.skeleton.index("SpineShoulder")
    assert np.isfinite(clip.positions[:, spine]).all()


def test_a_log_that_is_not_kinects_is_one_line_naming_the_problem(tmp_path):
    path = tmp_path / "other.skl"
    path.write_text("time\ta_X\n0\t1\n")
    with pytest.raises(MotionFileError, match="no tab-separated header with a 'timestamp' column"):
        read_motion(path)
    path.write_text("timestamp\tHead_X\tHead_Y\tHead_Z\tHead_tracked\n0\t1\t1\t1\t2\n")
    with pytest.raises(MotionFileError, match="name 1 joints .Head., not Kinect's 20 or 25"):
        read_motion(path)
    names = layout("kinect20").joint_names
    header = "\t".join(["timestamp"] + [f"{n}_{f}" for n in names for f in ("X", "Y", "Z", "tracked")])
    path.write_text(header + "\n0\t" + "\t".join(["0.1"] * 79 + ["0.1x"]) + "\n")
    with pytest.raises(MotionFileError, match="line 2: a timestamp or joint cell that is not a number"):
        read_motion(path)
    path.write_text(header + "\n33\t" + "\t".join(["0.1"] * 80) + "\n0\t" + "\t".join(["0.1"] * 80) + "\n")
    with pytest.raises(MotionFileError, match="line 3: the timestamp goes back"):
        read_motion(path)
    path.write_text(header + "\n0\t" + "\t".join(["0.1"] * 40) + "\n")
    with pytest.raises(MotionFileError, match="line 2 has fewer cells than the header's 81"):
        read_motion(path)
