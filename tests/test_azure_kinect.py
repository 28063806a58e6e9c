"""Azure Kinect body tracking JSON (io/azure_kinect.py): depth-camera axes and millimetres, each
body ID a person, the frames on the camera's clock, and fix's output the file's own structure."""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_utils import run_mocapfix
from test_keypoints import body_take, in_layout  # noqa: F401  (body_take: the fixture)

from mocapfix.core.clip import MotionFileError
from mocapfix.io import read_motion
from mocapfix.io.layouts import LAYOUTS

NAMES = list(LAYOUTS["azure32"].joint_names)


def camera_mm(x: np.ndarray) -> np.ndarray:
    """(T, 32, 3) metres, z up -> the depth camera's mm: x right, y down, z away (the person 3 m off)."""
    return np.stack([x[..., 0], -x[..., 2] + 1.0, x[..., 1] + 3.0], axis=-1) * 1000.0


def document(bodies: dict[int, np.ndarray], frames: list[int]) -> dict:
    """bodies: id -> (T, 32, 3) mm per camera frame index (NaN rows: absent); frames: the frame
    indices written (a gap: a frame the processor dropped)."""
    out = []
    for i in frames:
        present = [
            {"body_id": k, "joint_positions": x[i].tolist(), "joint_orientations": [[1.0, 0.0, 0.0, 0.0]] * 32}
            for k, x in bodies.items()
            if np.isfinite(x[i]).all()
        ]
        out.append({"frame_id": i, "timestamp_usec": 33333 * i + 500, "num_bodies": len(present), "bodies": present})
    return {"joint_names": NAMES, "bone_list": [], "frames": out, "k4abt_sdk_version": "1.1.2"}


def test_two_bodies_a_dropped_frame_and_fix_in_the_files_structure(tmp_path, body_take, capsys):  # noqa: F811
    a = camera_mm(in_layout("azure32", body_take)[:90])
    b = a + np.array([800.0, 0.0, 400.0])
    b[:30] = np.nan  # the second person walks in at frame 30
    frames = [i for i in range(90) if i not in (50, 51)]  # two frames dropped
    path = tmp_path / "take.json"
    path.write_text(json.dumps(document({1: a, 2: b}, frames)))
    clips = read_motion(path)
    assert [c.meta["person_id"] for c in clips] == ["1", "2"]
    first = clips[0]
    assert first.fps == 30.0 and first.num_frames == 90 and first.meta["unit"] == "mm"
    assert np.isnan(first.positions[50:52]).all() and np.isfinite(first.positions[52:]).all()
    head = first.skeleton.index("HEAD")
    assert (first.positions[:, head, 2] > first.positions[:, first.skeleton.index("PELVIS"), 2])[:50].all()  # up is up
    rc, out, err = run_mocapfix(["fix", path, "--model", "xmae-cpu-bandai"], capsys)
    assert rc == 0, err
    back = json.loads((tmp_path / "take.fixed.json").read_text())
    sent = json.loads(path.read_text())
    assert back["joint_names"] == NAMES and [f["frame_id"] for f in back["frames"]] == frames
    for f_back, f_sent in zip(back["frames"], sent["frames"]):  # nothing observed was moved
        for b_back, b_sent in zip(f_back["bodies"], f_sent["bodies"]):
            np.testing.assert_allclose(b_back["joint_positions"], b_sent["joint_positions"], atol=1e-6)
    # the jitter remover moves every position: each written back in the camera's axes and mm
    args = ["fix", path, "--model", "jitter-many", "--mode", "denoise", "--force"]
    rc, out, err = run_mocapfix(args, capsys)
    assert rc == 0, err
    back = json.loads((tmp_path / "take.fixed.json").read_text())
    moved = [
        np.linalg.norm(np.subtract(b_back["joint_positions"], b_sent["joint_positions"]), axis=-1)
        for f_back, f_sent in zip(back["frames"], sent["frames"])
        for b_back, b_sent in zip(f_back["bodies"], f_sent["bodies"])
    ]
    assert 0.01 < np.mean(moved) < 20.0  # mm: moved, and by a jitter remover's amount on a clean take


def test_a_file_that_is_not_body_tracking_is_one_line(tmp_path):
    (tmp_path / "other.json").write_text(json.dumps({"hello": 1}))
    with pytest.raises(MotionFileError, match="no 'frames' list"):
        read_motion(tmp_path / "other.json")
    (tmp_path / "empty.json").write_text(json.dumps({"frames": [{"bodies": []}] * 3}))
    with pytest.raises(MotionFileError, match="3 frames and no body in any"):
        read_motion(tmp_path / "empty.json")


def csv_text(bodies: dict[int, np.ndarray], frames: list[int], confidence: dict[int, np.ndarray]) -> str:
    """The recorder CSV (io/azure_kinect_csv.py) of the same bodies: one row per body and frame,
    its confidence levels (T, 32) beside each joint's mm."""
    header = ["timestamp", "body_idx"] + [f"{n} ({f})" for n in NAMES for f in ("c", "x", "y", "z")]
    rows = [";".join(header)]
    for i in frames:
        for k, x in bodies.items():
            if np.isfinite(x[i]).all():
                cells = [str(33333 * i + 333500), str(k)]
                for j in range(32):
                    cells += [str(int(confidence[k][i, j]))] + [f"{v:.6f}" for v in x[i, j]]
                rows.append(";".join(cells))
    return "\n".join(rows) + "\n"


def test_the_recorder_csv_reads_confidence_people_and_dropped_frames_and_fix_writes_its_own_lines(
    tmp_path,
    body_take,  # noqa: F811
    capsys,
):
    a = camera_mm(in_layout("azure32", body_take)[:120])
    b = a + np.array([800.0, 0.0, 400.0])
    b[:40] = np.nan  # the second person walks in at frame 40
    conf = {k: np.full((120, 32), 2) for k in (1, 2)}
    hand = NAMES.index("HAND_LEFT")
    conf[1][60:66, hand] = 0  # NONE: out of view, its position the SDK's guess
    conf[1][70:72, hand] = 1  # LOW: predicted, kept by default
    frames = [i for i in range(120) if i not in (90, 91)]  # two frames dropped
    path = tmp_path / "take.csv"
    path.write_text(csv_text({1: a, 2: b}, frames, conf))
    clips = read_motion(path)
    assert [c.meta["person_id"] for c in clips] == ["1", "2"]
    first = clips[0]
    assert first.meta["format"] == "keypoints-azure-csv" and first.fps == 30.0 and first.num_frames == 120
    j = first.skeleton.index("HAND_LEFT")
    assert np.isnan(first.positions[60:66, j]).all() and np.isfinite(first.positions[66:90, j]).all()
    assert np.isnan(first.positions[90:92]).all() and np.isfinite(first.positions[92:, 0]).all()
    head, pelvis = first.skeleton.index("HEAD"), first.skeleton.index("PELVIS")
    assert (first.positions[:60, head, 2] > first.positions[:60, pelvis, 2]).all()  # up is up
    (low,) = read_motion(path, min_confidence=1)[:1]
    assert np.isnan(low.positions[70:72, j]).all()  # LOW made missing when asked

    rc, out, err = run_mocapfix(["fix", path, "--model", "jitter-many", "--mode", "denoise"], capsys)
    assert rc == 0, err
    sent, back = path.read_text().split("\n"), (tmp_path / "take.fixed.csv").read_text().split("\n")
    assert back[0] == sent[0] and len(back) == len(sent)
    header = sent[0].split(";")
    changed = 0
    for line_sent, line_back in zip(sent[1:-1], back[1:-1]):
        cells_sent, cells_back = line_sent.split(";"), line_back.split(";")
        assert cells_back[:2] == cells_sent[:2]  # timestamp and body index as written
        for c, (s, w) in enumerate(zip(cells_sent, cells_back)):
            if header[c].endswith("(c)"):
                assert w == s
            elif s != w:
                changed += 1
                assert abs(float(w) - float(s)) < 30.0  # mm: a jitter remover's move, in the file's unit
        hand_cells = [header.index(f"HAND_LEFT ({f})") for f in "cxyz"]
        if cells_sent[hand_cells[0]] == "0":  # a NONE joint is not the tracker's: left as written
            assert [cells_back[c] for c in hand_cells] == [cells_sent[c] for c in hand_cells]
    assert changed > 0.5 * (len(sent) - 2) * 32 * 3


def test_a_broken_recorder_csv_is_one_line(tmp_path, body_take):  # noqa: F811
    a = camera_mm(in_layout("azure32", body_take)[:10])
    conf = {1: np.full((10, 32), 2)}
    good = csv_text({1: a}, list(range(10)), conf).split("\n")
    cases = {
        "columns of 1 of the SDK's 32 joints (EAR_RIGHT)": [good[0].replace("EAR_RIGHT (z)", "EAR_RIGHTZ")] + good[1:],
        "line 3: the timestamp goes back": [good[0], good[2], good[1]] + good[3:],
        "line 3: body 1 a second time in one frame": [good[0], good[1], good[1]] + good[2:],
        "one frame: no steps to tell the frame rate from": good[:2],
        "line 2: a timestamp, body index or joint cell that is not a number": [good[0], good[1].replace("2;", "x;", 1)]
        + good[2:],
        "nothing was tracked": [good[0]]
        + [";".join(c if k < 2 or (k - 2) % 4 else "0" for k, c in enumerate(line.split(";"))) for line in good[1:-1]]
        + [""],
    }
    for message, lines in cases.items():
        path = tmp_path / "broken.csv"
        path.write_text("\n".join(lines))
        with pytest.raises(MotionFileError, match=message.replace("(", r"\(").replace(")", r"\)")):
            read_motion(path)
